"""Perspective geometry of a ball seen through a calibrated lens (pinhole + OpenCV distortion).

The spin estimator (:mod:`spin.fast`, :mod:`spin.objective`) models an orthographic camera: an
event at an offset ``(x, y)`` from the ball's centre lies on the sphere at
``(x, y, -sqrt(r^2 - x^2 - y^2))``.  Through a real lens the ball is seen from a point at a
finite distance, off the optical axis, through a distorting lens: its silhouette is an ellipse
and its texture is foreshortened.  This module maps event pixels to *orthographic-equivalent*
coordinates, so that the unchanged estimator works on them:

1. the pixel is undistorted to a viewing ray (``calib.Intrinsics.rays``);
2. the ray is rotated by ``Rc``, the rotation that takes the ray through the sphere's centre
   (the viewing cone's axis) to ``+Z`` (the *ball frame*; it keeps the camera's X right, Y down
   for a ball on the optical axis);
3. the ray is intersected with the sphere of radius ``R`` whose centre lies at the distance
   ``D = R / sin(alpha)`` (``alpha`` the ball's angular radius), and the intersection's offset
   ``(X, Y, Z)`` from the centre is the point on the ball.

The visible part of the ball (``Z <= -R sin(alpha) < 0``) lies on the camera-facing
hemisphere, so the orthographic lift of ``(X, Y)`` with radius ``R`` gives back exactly ``Z``: an
angular velocity ``w`` estimated from these coordinates is the ball's, in the ball frame, and
``Rc^T w`` is the same vector in the camera frame.  A moving ball is mapped in the ball frame
of the window's reference time ``t0``, with its centre following the image motion (parallel to
the image plane): the changing viewpoint is then not taken for a rotation.

Units: pixels (``(u, v)``, conventions of ``docs/conventions.md``), seconds, radians; ball-frame
coordinates are *ball units*: ``R = f tan(alpha)`` with ``f`` the camera's mean focal length in
pixels, i.e. the ball's image radius in pixels were it seen on the optical axis.  A camera is any
object with ``K`` (3, 3), ``dist`` (OpenCV coefficients), ``width`` and ``height``, such as
``calib.Intrinsics``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

CIRCLES = ("detected", "projected")
"""Meanings of an image circle ``(center, radius)`` of a ball (:func:`viewing_cone`)."""

RIM_SAMPLES = 64
"""Points on a circle's rim (or a cone's) used to turn it into a cone (or back into pixels)."""


def normalised_coordinates(camera, uv_px) -> np.ndarray:
    """Undistorted normalised image coordinates ``(x / z, y / z)`` of pixels.

    Parameters
    ----------
    camera : calib.Intrinsics
    uv_px : array_like, shape (N, 2)
        Pixel coordinates (u right, v down), px.

    Returns
    -------
    ndarray, float64, shape (2, N)
        The rays through the pixels are ``(x, y, 1)`` in the camera frame.  With distortion,
        ``calib.Intrinsics.rays`` inverts it iteratively (``cv2.undistortPoints``: to
        about 1e-4 px within 20 deg of the axis for a strong barrel ``k1 = -0.25``).
    """
    uv = np.ascontiguousarray(uv_px, dtype=np.float64).reshape(-1, 2)
    k = np.asarray(camera.K, dtype=np.float64)
    if not len(uv):
        return np.zeros((2, 0))
    if np.any(camera.dist):
        return camera.rays(uv)[:, :2].T
    inv = np.linalg.inv(k)
    u, v = uv.T
    x, y, w = (inv[i, 0] * u + inv[i, 1] * v + inv[i, 2] for i in range(3))
    return np.stack([x / w, y / w])


def unit_rays(camera, uv_px) -> np.ndarray:
    """Unit viewing rays (N, 3) in the camera frame through pixels ``uv_px`` (N, 2), px."""
    x, y = normalised_coordinates(camera, uv_px)
    rays = np.column_stack([x, y, np.ones(len(x))])
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    return rays


def _circle_points(center_px, radius_px: float, n: int = RIM_SAMPLES) -> np.ndarray:
    phi = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.asarray(center_px, dtype=np.float64) + radius_px * np.column_stack([np.cos(phi), np.sin(phi)])


def viewing_cone(camera, center_px, radius_px: float, circle: str = "detected") -> tuple[np.ndarray, float]:
    """The cone of viewing rays that graze a ball, from its circle in the image.

    Parameters
    ----------
    camera : calib.Intrinsics
    center_px : (float, float)
        Circle centre, px.
    radius_px : float
        Circle radius, px.
    circle : {"detected", "projected"}
        What the circle is.  ``"detected"``: the circle fitted to the ball's silhouette in the
        (distorted) image, as a detector finds it (the silhouette of a ball off the optical axis
        is an ellipse, slightly larger than the ball seen on axis).  The cone is fitted to the
        rays through :data:`RIM_SAMPLES` points of the circle's rim: its axis is the normal of
        the plane through the rays' unit tips (then all rays make the same angle with it, in the
        least-squares sense), its half-angle their mean angle to it.  ``"projected"``: ``center``
        is the image of the sphere's centre (with distortion) and ``radius = f tan(alpha)`` with
        ``f`` the camera's mean focal length (px): what ``sim`` reports as the truth of a pinhole
        camera (``sim.scene.Ball.circle``).

    Returns
    -------
    axis : ndarray, shape (3,)
        Unit direction of the sphere's centre, camera frame.
    alpha : float
        Angular radius of the ball (the cone's half-angle), rad.
    """
    if circle == "projected":
        axis = unit_rays(camera, np.reshape(center_px, (1, 2)))[0]
        return axis, float(np.arctan(radius_px / focal_px(camera)))
    if circle != "detected":
        raise ValueError(f"circle: {circle!r} is not one of {CIRCLES}")
    rays = unit_rays(camera, _circle_points(center_px, radius_px))
    tips = rays - rays.mean(axis=0)
    axis = np.linalg.eigh(tips.T @ tips)[1][:, 0]  # the direction the tips spread least along
    axis *= np.sign(axis @ rays.mean(axis=0))
    return axis, float(np.mean(np.arccos(np.clip(rays @ axis, -1.0, 1.0))))


def focal_px(camera) -> float:
    """Mean focal length ``(fx + fy) / 2`` of a camera, px."""
    return float(0.5 * (camera.K[0, 0] + camera.K[1, 1]))


def centring_rotation(axis) -> np.ndarray:
    """The smallest rotation (3, 3) taking the unit vector ``axis`` (``z > 0``) to ``+Z``."""
    a = np.asarray(axis, dtype=np.float64)
    c = float(a[2])
    cross = np.array([[0.0, 0.0, -a[0]], [0.0, 0.0, -a[1]], [a[0], a[1], 0.0]])  # [a x ez]x
    return np.eye(3) + cross + cross @ cross / (1.0 + c)


@dataclass(frozen=True)
class BallView:
    """How the camera sees one ball at the reference time ``t0`` (see :func:`ball_view`).

    Attributes
    ----------
    rotation : ndarray, shape (3, 3)
        ``Rc``: camera frame -> ball frame; ``Rc @ axis = (0, 0, 1)``.
    alpha_rad : float
        Angular radius of the ball, rad.
    radius : float
        Sphere radius ``R`` in ball units (``f tan(alpha)``).
    distance : float
        Distance ``D = R / sin(alpha)`` of the sphere's centre from the camera, ball units.
    centre_rate : ndarray, shape (3, 2)
        Displacement of the sphere's centre (ball frame, ball units) per pixel of image motion of
        the circle, ``d(Rc C) / d(cx, cy)``, for motion parallel to the image plane (constant
        depth) along the ray through the circle's centre.
    scale : ndarray, shape (2, 2)
        ``d(X, Y) / d(u, v)`` at the centre's image: ball units per pixel.
    reach_px : float
        Largest distance of the silhouette's image from the circle's centre, px.
    camera : calib.Intrinsics
        The camera.
    """

    rotation: np.ndarray
    alpha_rad: float
    radius: float
    distance: float
    centre_rate: np.ndarray
    scale: np.ndarray
    reach_px: float
    camera: object

    @property
    def rim_radius(self) -> float:
        """Radius of the visible disc in ball coordinates, ``R cos(alpha)``: the silhouette."""
        return self.radius * float(np.cos(self.alpha_rad))

    def to_camera(self, w) -> np.ndarray:
        """A vector (3,) of the ball frame in the camera frame, ``Rc^T w``."""
        return self.rotation.T @ np.asarray(w, dtype=np.float64)

    def to_ball(self, w) -> np.ndarray:
        """A vector (3,) of the camera frame in the ball frame, ``Rc w``."""
        return self.rotation @ np.asarray(w, dtype=np.float64)

    def to_px_s(self, velocity) -> np.ndarray:
        """An image velocity (2,) in ball units/s at the centre converted to px/s."""
        return np.linalg.solve(self.scale, np.asarray(velocity, dtype=np.float64))


def ball_view(camera, center_px, radius_px: float, circle: str = "detected") -> BallView:
    """The :class:`BallView` of a ball whose image circle is ``(center_px, radius_px)`` (px).

    ``circle`` says which circle it is (see :func:`viewing_cone`).  Raises ``ValueError`` when
    the ball's viewing cone reaches behind the camera.
    """
    c = np.asarray(center_px, dtype=np.float64).reshape(2)
    axis, alpha = viewing_cone(camera, c, radius_px, circle)
    tilt = float(np.arccos(np.clip(axis[2], -1.0, 1.0)))
    if not 0.0 < alpha < 0.5 * np.pi - tilt - 1e-3:
        raise ValueError(f"circle: centre ({c[0]:.1f}, {c[1]:.1f}) radius {radius_px:.1f} px is a ball "
                         f"{np.degrees(alpha):.1f} deg in radius {np.degrees(tilt):.1f} deg off the optical axis: "
                         "its viewing cone reaches behind the camera")
    rotation = centring_rotation(axis)
    radius = focal_px(camera) * float(np.tan(alpha))
    # the silhouette: the cone's rim rays (rows 0 and 1 of Rc are the ball frame's X and Y axes)
    rim = _circle_points((0.0, 0.0), np.sin(alpha)) @ rotation[:2] + np.cos(alpha) * axis
    reach = float(np.max(np.linalg.norm(camera.project(rim) - c, axis=1)))
    distance = radius / float(np.sin(alpha))
    # the centre moves at constant depth along the ray through the moving circle's centre:
    # d(normalised coordinates) / d(pixel) by central differences over +-0.5 px
    steps = 0.5 * np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    xy = normalised_coordinates(camera, c + steps)
    rate = np.column_stack([xy[:, 0] - xy[:, 1], xy[:, 2] - xy[:, 3]])
    centre_rate = distance * axis[2] * rotation[:, :2] @ rate
    view = BallView(rotation, alpha, radius, distance, centre_rate, np.eye(2), reach, camera)
    xy = ball_coordinates(view, camera.project(axis[None]) + steps, np.zeros(4), (0.0, 0.0))[0]
    return replace(view, scale=np.column_stack([xy[:, 0] - xy[:, 1], xy[:, 2] - xy[:, 3]]))


def ball_coordinates(view: BallView, uv_px, s_s, velocity_px_s) -> tuple[np.ndarray, np.ndarray]:
    """Ball-frame coordinates ``(X, Y)`` of the ball points seen at pixels, and whether a ray hits.

    Parameters
    ----------
    view : BallView
        The ball at the reference time ``t0``.
    uv_px : array_like, shape (N, 2)
        Event pixels (possibly dithered), px.
    s_s : array_like, shape (N,)
        Event times since ``t0``, s.
    velocity_px_s : (float, float)
        Image velocity of the circle's centre, px/s: the sphere's centre at ``t0 + s`` is at
        ``(0, 0, D) + view.centre_rate @ velocity * s`` in the ball frame of ``t0`` (motion
        parallel to the image plane, to first order in the distortion).

    Returns
    -------
    xy : ndarray, float64, shape (2, N)
        ``X`` and ``Y`` of the intersection of each pixel's ray with the sphere (the nearer one),
        relative to the sphere's centre at the event's time, ball frame of ``t0``, ball units;
        the lift ``Z = -sqrt(R^2 - X^2 - Y^2)`` gives its third coordinate.  A ray that misses
        the sphere gets its own point nearest to the centre (outside the sphere).
    hit : ndarray of bool, shape (N,)
        Whether the ray meets the sphere.
    """
    x, y = normalised_coordinates(view.camera, uv_px)
    rot = view.rotation
    # the unit rays in the ball frame
    rx, ry, rz = (rot[i, 0] * x + rot[i, 1] * y + rot[i, 2] for i in range(3))
    norm = np.sqrt(rx * rx + ry * ry + rz * rz)
    rx /= norm
    ry /= norm
    rz /= norm
    # the sphere's centre at each event's time
    s = np.asarray(s_s, dtype=np.float64)
    cx, cy, cz = (float(view.centre_rate[i] @ np.asarray(velocity_px_s, dtype=np.float64)) * s for i in range(3))
    cz += view.distance
    along = rx * cx + ry * cy + rz * cz  # distance along the ray to the point nearest to the centre
    # squared distance of the centre from the ray: |C|^2 - along^2 = |r x C|^2
    off = (ry * cz - rz * cy) ** 2 + (rz * cx - rx * cz) ** 2 + (rx * cy - ry * cx) ** 2
    gap = view.radius * view.radius - off
    hit = gap >= 0.0
    t = along - np.sqrt(np.maximum(gap, 0.0))  # distance along the ray to the nearer intersection
    return np.stack([t * rx - cx, t * ry - cy]), hit
