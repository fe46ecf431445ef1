"""Mapping between the GoPro view and the event-camera view: stereo extrinsics (metric, needs
the ball's size for depth) or a plane homography (fallback for a far ball), JSON-able for the
session attrs, and helpers that map ball circles ``(cx, cy, r)`` between the two images.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from calib.intrinsics import CalibrationError, Intrinsics

VOLLEYBALL_RADIUS_M = 0.105
"""Radius of a volleyball (circumference 65-67 cm)."""


@dataclass
class Extrinsics:
    """Rigid transform from the frame camera to the event camera: ``X_event = R @ X_frame + T``.

    Attributes
    ----------
    R : ndarray, shape (3, 3)
    T : ndarray, shape (3,)
        Translation in metres.
    rms_px : float
        RMS reprojection error of the stereo calibration (pixels).
    """

    R: np.ndarray
    T: np.ndarray
    rms_px: float = 0.0

    def inverse(self) -> Extrinsics:
        """Event camera -> frame camera."""
        return Extrinsics(R=self.R.T, T=-self.R.T @ self.T, rms_px=self.rms_px)

    def to_dict(self) -> dict:
        return {"R": self.R.tolist(), "T": np.ravel(self.T).tolist(), "rms_px": float(self.rms_px)}

    @classmethod
    def from_dict(cls, d: dict) -> Extrinsics:
        return cls(R=np.asarray(d["R"], float).reshape(3, 3), T=np.asarray(d["T"], float).reshape(3),
                   rms_px=float(d.get("rms_px", 0.0)))


def calibrate_stereo(object_points: Sequence[np.ndarray], points_frame: Sequence[np.ndarray],
                     points_event: Sequence[np.ndarray], frame: Intrinsics, event: Intrinsics) -> Extrinsics:
    """Extrinsics from board views seen by both cameras (intrinsics kept fixed).

    Parameters
    ----------
    object_points : sequence of (N_i, 3)
        Board coordinates (m) of each view.
    points_frame, points_event : sequence of (N_i, 2)
        The same corners in the GoPro and event images (pixels).
    frame, event : Intrinsics

    Raises
    ------
    CalibrationError
        With fewer than 3 views or mismatched point counts.
    """
    if len(object_points) < 3:
        raise CalibrationError(f"need at least 3 board views seen by both cameras, got {len(object_points)}")
    for i, (o, a, b) in enumerate(zip(object_points, points_frame, points_event)):
        if not len(o) == len(a) == len(b):
            raise CalibrationError(f"view {i}: {len(o)} board points, {len(a)} frame points, {len(b)} event points")
    obj = [np.asarray(o, np.float32).reshape(-1, 1, 3) for o in object_points]
    pa = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in points_frame]
    pb = [np.asarray(p, np.float32).reshape(-1, 1, 2) for p in points_event]
    rms, _, _, _, _, R, T, _, _ = cv2.stereoCalibrate(obj, pa, pb, frame.K, frame.dist, event.K, event.dist,
                                                      (frame.width, frame.height), flags=cv2.CALIB_FIX_INTRINSIC)
    return Extrinsics(R=np.asarray(R, float), T=np.asarray(T, float).ravel(), rms_px=float(rms))


def fit_homography(points_frame, points_event, *, ransac_px: float = 3.0) -> np.ndarray:
    """Plane homography (3, 3) mapping frame pixels to event pixels (RANSAC).

    Valid for points on one plane (or a ball far away compared with the camera baseline).

    Raises
    ------
    CalibrationError
        With fewer than 4 correspondences or a degenerate configuration.
    """
    a = np.asarray(points_frame, np.float64).reshape(-1, 2)
    b = np.asarray(points_event, np.float64).reshape(-1, 2)
    if len(a) < 4 or len(a) != len(b):
        raise CalibrationError(f"homography needs >= 4 matched points, got {len(a)} frame and {len(b)} event points")
    H, _ = cv2.findHomography(a, b, cv2.RANSAC, ransac_px)
    if H is None:
        raise CalibrationError("homography fit failed (points collinear or inconsistent)")
    return H / H[2, 2]


def _apply_h(H, uv):
    p = np.column_stack([uv, np.ones(len(uv))]) @ H.T
    return p[:, :2] / p[:, 2:3]


def map_circles_homography(circles, H) -> np.ndarray:
    """Map circles (N, 3) ``(cx, cy, r)`` with a homography: centre mapped, radius the mean
    distance of four mapped rim points to the mapped centre."""
    c = np.asarray(circles, np.float64).reshape(-1, 3)
    ctr = _apply_h(H, c[:, :2])
    rims = [_apply_h(H, c[:, :2] + c[:, 2:3] * np.array(d)) for d in ((1, 0), (-1, 0), (0, 1), (0, -1))]
    r = np.mean([np.linalg.norm(p - ctr, axis=1) for p in rims], axis=0)
    return np.column_stack([ctr, r])


def map_circles_stereo(circles, src: Intrinsics, dst: Intrinsics, extr: Extrinsics,
                       ball_radius_m: float = VOLLEYBALL_RADIUS_M) -> np.ndarray:
    """Map ball circles (N, 3) from the ``src`` image to the ``dst`` image through 3-D.

    The ball's distance comes from its apparent radius (``Z = f * R / r``); its centre is put on
    the undistorted ray through the circle centre, moved with ``extr`` (src -> dst camera) and
    projected, with radius ``f_dst * R / Z_dst``.
    """
    c = np.asarray(circles, np.float64).reshape(-1, 3)
    if np.any(c[:, 2] <= 0):
        raise ValueError("circle radii must be > 0 pixels to give a distance")
    rays = src.rays(c[:, :2])
    z = src.focal_px * ball_radius_m / c[:, 2]
    X = rays * z[:, None]
    Xd = X @ extr.R.T + extr.T
    uv = dst.project(Xd)
    return np.column_stack([uv, dst.focal_px * ball_radius_m / Xd[:, 2]])


@dataclass
class CameraPair:
    """Everything needed to map between the GoPro ("frame") and event-camera images.

    Any field may be ``None``; :meth:`frame_to_event` uses the stereo model when ``frame``,
    ``event`` and ``extrinsics`` are all set, else the ``homography``.
    """

    frame: Intrinsics | None = None
    event: Intrinsics | None = None
    extrinsics: Extrinsics | None = None
    homography: np.ndarray | None = None
    ball_radius_m: float = VOLLEYBALL_RADIUS_M

    def _stereo(self) -> bool:
        return self.frame is not None and self.event is not None and self.extrinsics is not None

    def frame_to_event(self, circles) -> np.ndarray:
        """Circles (N, 3) in GoPro pixels -> event-sensor pixels."""
        if self._stereo():
            return map_circles_stereo(circles, self.frame, self.event, self.extrinsics, self.ball_radius_m)
        if self.homography is None:
            raise CalibrationError("camera pair has neither stereo calibration nor homography")
        return map_circles_homography(circles, self.homography)

    def event_to_frame(self, circles) -> np.ndarray:
        """Circles (N, 3) in event-sensor pixels -> GoPro pixels."""
        if self._stereo():
            return map_circles_stereo(circles, self.event, self.frame, self.extrinsics.inverse(), self.ball_radius_m)
        if self.homography is None:
            raise CalibrationError("camera pair has neither stereo calibration nor homography")
        return map_circles_homography(circles, np.linalg.inv(self.homography))

    def to_dict(self) -> dict:
        """JSON-able dict for the session attrs."""
        return {"frame": self.frame.to_dict() if self.frame else None,
                "event": self.event.to_dict() if self.event else None,
                "extrinsics": self.extrinsics.to_dict() if self.extrinsics else None,
                "homography": None if self.homography is None else np.asarray(self.homography).tolist(),
                "ball_radius_m": float(self.ball_radius_m)}

    @classmethod
    def from_dict(cls, d: dict) -> CameraPair:
        return cls(frame=Intrinsics.from_dict(d["frame"]) if d.get("frame") else None,
                   event=Intrinsics.from_dict(d["event"]) if d.get("event") else None,
                   extrinsics=Extrinsics.from_dict(d["extrinsics"]) if d.get("extrinsics") else None,
                   homography=None if d.get("homography") is None else np.asarray(d["homography"], float),
                   ball_radius_m=float(d.get("ball_radius_m", VOLLEYBALL_RADIUS_M)))
