"""Scene description and brightness rendering: camera, textured balls, distractors, background.

Units: with ``Camera(projection="orthographic")`` scene coordinates are pixels
(X = column, Y = row, Z unused except for the visible hemisphere); with
``projection="pinhole"`` they are metres in the camera frame (X right, Y down,
Z forward). Times are float seconds. Rendered brightness is linear, about 0..1.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .rotation import axis_angle_matrices, unit
from .textures import get_texture

LOG_EPS = 1e-3
"""``eps`` in the log intensity ``L = ln(I + eps)``."""


@dataclass
class Camera:
    """Event-camera geometry.

    Parameters
    ----------
    width, height : int
        Sensor size in pixels.
    projection : {"orthographic", "pinhole"}
        Orthographic: scene units are pixels. Pinhole: metres, focal length
        ``focal_px`` (pixels), principal point ``principal_px`` (default: centre).
    """

    width: int
    height: int
    projection: str = "orthographic"
    focal_px: float = 1000.0
    principal_px: tuple[float, float] | None = None

    def __post_init__(self):
        if self.projection not in ("orthographic", "pinhole"):
            raise ValueError(f"projection must be 'orthographic' or 'pinhole', got {self.projection!r}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"sensor size must be positive, got {self.width}x{self.height}")
        if self.principal_px is None:
            self.principal_px = ((self.width - 1) / 2.0, (self.height - 1) / 2.0)

    @property
    def pinhole(self) -> bool:
        return self.projection == "pinhole"

    def project(self, xyz: np.ndarray) -> np.ndarray:
        """Scene points (K, 3) to pixel coordinates (K, 2)."""
        xyz = np.atleast_2d(xyz)
        if not self.pinhole:
            return xyz[:, :2].copy()
        px, py = self.principal_px
        return np.stack([px + self.focal_px * xyz[:, 0] / xyz[:, 2],
                         py + self.focal_px * xyz[:, 1] / xyz[:, 2]], axis=1)

    def rays(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unit viewing rays (N, 3) through pixels ``(u, v)`` (pinhole only)."""
        px, py = self.principal_px
        d = np.stack([(u - px) / self.focal_px, (v - py) / self.focal_px, np.ones_like(u, dtype=np.float64)], 1)
        return d / np.linalg.norm(d, axis=1, keepdims=True)


@dataclass
class Ball:
    """A textured ball in ballistic motion, spinning about a fixed axis, optionally hit.

    Centre ``c(t) = center + velocity t + accel t^2 / 2`` (scene units, s), orientation
    ``R(t) = exp(omega t [axis]x) R0``: ``R`` maps ball-frame points to camera-frame
    offsets, so a surface point at offset ``r`` moves with ``omega * cross(axis, r)``.

    ``hits`` is a sequence of ``(t_s, velocity, axis, omega_rad_s)``: at ``t_s`` the
    ball (where it is, as it is turned) takes a new velocity and spin - a hit or a
    bounce. Each such piece is a segment; :meth:`segment_at` numbers them from 0.
    """

    texture: str = "volleyball"
    radius: float = 100.0
    center: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    accel: np.ndarray = field(default_factory=lambda: np.zeros(3))
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    omega_rad_s: float = 0.0
    R0: np.ndarray = field(default_factory=lambda: np.eye(3))
    gain: float = 1.0
    texture_opts: dict = field(default_factory=dict)
    hits: tuple = ()

    def __post_init__(self):
        self.texture_fn = get_texture(self.texture)
        self.center = np.asarray(self.center, np.float64).reshape(3)
        self.velocity = np.asarray(self.velocity, np.float64).reshape(3)
        self.accel = np.asarray(self.accel, np.float64).reshape(3)
        self.axis = unit(self.axis)
        if self.radius <= 0:
            raise ValueError(f"ball radius must be positive, got {self.radius}")
        t0, c, v, ax, om, rot = [0.0], [self.center], [self.velocity], [self.axis], [float(self.omega_rad_s)], [
            np.asarray(self.R0, np.float64)]
        for t_h, v_h, ax_h, om_h in sorted(self.hits, key=lambda h: h[0]):
            if t_h <= t0[-1]:
                raise ValueError(f"hit times must be increasing and > 0, got {t_h}")
            dt = t_h - t0[-1]
            c.append(c[-1] + v[-1] * dt + 0.5 * self.accel * dt * dt)
            rot.append(axis_angle_matrices(ax[-1], [om[-1] * dt])[0] @ rot[-1])
            t0.append(float(t_h))
            v.append(np.asarray(v_h, np.float64).reshape(3))
            ax.append(unit(ax_h))
            om.append(float(om_h))
        if min(om) < 0:
            raise ValueError(f"omega_rad_s must be >= 0 (flip the axis instead), got {min(om)}")
        self._t0, self._c, self._v = np.array(t0), np.array(c), np.array(v)
        self._axis, self._omega, self._R = np.array(ax), np.array(om), np.array(rot)

    @property
    def translating(self) -> bool:
        return bool(np.any(self._v) or np.any(self.accel))

    def segments(self) -> list[tuple[float, np.ndarray, float]]:
        """``(t_start_s, axis (3,), omega_rad_s)`` of every segment, in time order."""
        return [(float(t), a.copy(), float(w)) for t, a, w in zip(self._t0, self._axis, self._omega)]

    def segment_at(self, t_s) -> np.ndarray:
        """Segment number (K,) at times ``t_s`` (0 before the first hit)."""
        t = np.atleast_1d(np.asarray(t_s, np.float64))
        return np.clip(np.searchsorted(self._t0, t, side="right") - 1, 0, len(self._t0) - 1)

    def _local(self, t_s):
        t = np.atleast_1d(np.asarray(t_s, np.float64))
        k = self.segment_at(t)
        return k, t - self._t0[k]

    def center_at(self, t_s) -> np.ndarray:
        """Centre (K, 3) at times ``t_s`` (K,)."""
        k, dt = self._local(t_s)
        dt = dt[:, None]
        return self._c[k] + self._v[k] * dt + 0.5 * self.accel * dt * dt

    def velocity_at(self, t_s) -> np.ndarray:
        """Centre velocity (K, 3) at times ``t_s`` (K,)."""
        k, dt = self._local(t_s)
        return self._v[k] + self.accel * dt[:, None]

    def spin_at(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Spin axis (K, 3) and angular speed (K,) rad/s at times ``t_s``."""
        k = self.segment_at(t_s)
        return self._axis[k], self._omega[k]

    def orientation(self, t_s) -> np.ndarray:
        """``R(t)`` (K, 3, 3)."""
        k, dt = self._local(t_s)
        if len(self._t0) == 1:
            return axis_angle_matrices(self.axis, self.omega_rad_s * dt) @ self.R0
        return axis_angle_matrices(self._axis[k], self._omega[k] * dt) @ self._R[k]

    def circle(self, cam: Camera, t_s) -> np.ndarray:
        """Image circle ``(cx, cy, r)`` in pixels at times ``t_s``, shape (K, 3)."""
        c = self.center_at(t_s)
        uv = cam.project(c)
        if cam.pinhole:
            dist = np.linalg.norm(c, axis=1)
            r = cam.focal_px * np.tan(np.arcsin(np.clip(self.radius / dist, 0, 1)))
        else:
            r = np.full(len(c), float(self.radius))
        return np.column_stack([uv, r])

    def image_velocity(self, cam: Camera, t_s) -> np.ndarray:
        """Centre velocity in the image (K, 2), px/s."""
        v = self.velocity_at(t_s)
        if not cam.pinhole:
            return v[:, :2].copy()
        c = self.center_at(t_s)
        z = c[:, 2:3]
        return cam.focal_px * (v[:, :2] * z - c[:, :2] * v[:, 2:3]) / (z * z)

    def max_speed_px_s(self, cam: Camera, t_s: float) -> float:
        """Upper bound of any visible point's image speed at ``t_s`` (rim + translation + looming)."""
        cx, cy, r = self.circle(cam, [t_s])[0]
        omega = self.spin_at([t_s])[1][0]
        loom = 0.0
        if cam.pinhole and self.velocity_at([t_s])[0, 2] != 0.0:  # the rim moves as the radius changes
            dt = 1e-4
            loom = 1.05 * abs(self.circle(cam, [t_s + dt])[0, 2] - r) / dt
        return float(np.hypot(*self.image_velocity(cam, [t_s])[0]) + omega * r * 1.05 + loom)

    def footprint(self, cam: Camera, t0_s: float, t1_s: float):
        """Swept capsule over ``[t0_s, t1_s]``: (start uv, end uv, radius px)."""
        c = self.circle(cam, [t0_s, 0.5 * (t0_s + t1_s), t1_s])
        sag = np.hypot(*(c[1, :2] - 0.5 * (c[0, :2] + c[2, :2])))
        return c[0, :2], c[2, :2], float(c[:, 2].max() + sag)

    def bbox(self, cam: Camera, t0_s: float, t1_s: float) -> tuple[float, float, float, float]:
        """Image bounding box ``(x0, y0, x1, y1)`` (px) of the ball over ``[t0_s, t1_s]``."""
        a, b, r = self.footprint(cam, t0_s, t1_s)
        return (min(a[0], b[0]) - r - 0.5, min(a[1], b[1]) - r - 0.5, max(a[0], b[0]) + r + 0.5, max(a[1], b[1]) + r + 0.5)

    def render(self, cam: Camera, u: np.ndarray, v: np.ndarray, t_s: np.ndarray,
               light: np.ndarray, ambient: float) -> tuple[np.ndarray, np.ndarray]:
        """Shaded brightness and coverage at pixels ``(u, v)`` (N,) for times ``t_s`` (K,).

        Returns ``(I, cov)``, both (K, N): ``cov`` is the anti-aliased fraction of the
        pixel covered by the ball (from the signed distance to the silhouette), ``I``
        the ball's brightness there (texture at the sphere point under the pixel
        centre, clamped onto the rim for partly covered pixels, Lambert + ambient).
        """
        t = np.atleast_1d(np.asarray(t_s, np.float64))
        static = not self.translating
        tg = t[:1] if static else t
        c = self.center_at(tg)  # (Kg, 3)
        if cam.pinhole:
            d = cam.rays(u, v)  # (N, 3)
            tc = c @ d.T  # (Kg, N)
            delta = np.sqrt(np.maximum(np.sum(c * c, 1)[:, None] - tc * tc, 0.0))
            sd = (self.radius - delta) * cam.focal_px / np.maximum(tc, 1e-9)
        else:
            wx = u[None, :] - c[:, :1]
            wy = v[None, :] - c[:, 1:2]
            delta = np.hypot(wx, wy)
            sd = self.radius - delta
        r = self.radius
        cov_g = np.clip(sd + 0.5, 0.0, 1.0)
        de_c = np.minimum(delta, r * (1.0 - 1e-9))
        scale = de_c / np.maximum(delta, 1e-12) / r
        s = np.sqrt(1.0 - (de_c / r) ** 2)
        if cam.pinhole:
            n = (tc[..., None] * d[None] - c[:, None, :]) * scale[..., None] - s[..., None] * d[None]
        else:
            n = np.stack([wx * scale, wy * scale, -s], axis=-1)  # (Kg, N, 3) camera-frame normals
        shade = ambient + (1.0 - ambient) * np.maximum(n @ light, 0.0)
        R = self.orientation(t)  # (K, 3, 3)
        edge = 1.0 / max(float(self.circle(cam, tg[:1])[0, 2]), 1.0)
        if static:
            # the camera-frame sphere point under each pixel is fixed: rotate it by R(t)^T
            inside = cov_g[0] > 0
            q = np.matmul(n[0, inside][None], R).reshape(-1, 3)
            alb = self.texture_fn(q, edge, **self.texture_opts).reshape(len(t), -1)
            I = np.zeros((len(t), len(u)))
            I[:, inside] = self.gain * alb * shade[0, inside][None, :]
            return I, np.broadcast_to(cov_g, (len(t), len(u)))
        q = np.matmul(n, R).reshape(-1, 3)  # row vectors: q = R(t)^T n
        I = self.gain * self.texture_fn(q, edge, **self.texture_opts).reshape(len(t), -1) * shade
        return I, cov_g


@dataclass
class Player:
    """Player-like distractor: body ellipse + head disc with a striped shirt, walking sideways.

    Geometry in pixels (orthographic sensor coordinates): feet at ``(x0 + vx t, y0)``,
    ``height_px`` tall, bobbing by ``bob_px`` at ``step_hz``.
    """

    x0: float = 200.0
    y0: float = 700.0
    vx: float = 150.0
    height_px: float = 300.0
    bob_px: float = 6.0
    step_hz: float = 2.0
    shirt: float = 0.65
    shorts: float = 0.12
    skin: float = 0.5

    def _parts(self, t: np.ndarray):
        cx = self.x0 + self.vx * t
        base = self.y0 - self.bob_px * np.abs(np.sin(np.pi * self.step_hz * t))
        h = self.height_px
        # (cx, cy, semi-axis x, semi-axis y) for body and head
        body = (cx, base - 0.42 * h, 0.16 * h, 0.42 * h)
        head = (cx, base - 0.91 * h, 0.08 * h, 0.09 * h)
        return body, head

    def max_speed_px_s(self, cam: Camera, t_s: float) -> float:
        """Fastest image motion (px/s): walking plus bobbing."""
        return abs(self.vx) + self.bob_px * np.pi * self.step_hz

    def bbox(self, cam: Camera, t0_s: float, t1_s: float) -> tuple[float, float, float, float]:
        """Image bounding box ``(x0, y0, x1, y1)`` (px) over ``[t0_s, t1_s]``."""
        t = np.array([t0_s, t1_s])
        x = self.x0 + self.vx * t
        h = self.height_px
        return (x.min() - 0.16 * h - 2, self.y0 - h - self.bob_px - 2, x.max() + 0.16 * h + 2, self.y0 + 2)

    def render(self, cam: Camera, u, v, t_s, light, ambient):
        """Brightness and anti-aliased coverage (K, N) at pixels ``(u, v)``, times ``t_s`` (K,)."""
        t = np.atleast_1d(np.asarray(t_s, np.float64))[:, None]
        body, head = self._parts(t)
        covs, vals = [], []
        for (cx, cy, a, b), kind in ((body, "body"), (head, "head")):
            x = (u[None, :] - cx) / a
            y = (v[None, :] - cy) / b
            rho = np.sqrt(x * x + y * y)
            cov = np.clip((1.0 - rho) * min(a, b) + 0.5, 0.0, 1.0)
            if kind == "body":
                yrel = (v[None, :] - (cy - b)) / (2 * b)  # 0 at shoulders, 1 at feet
                # six shirt stripes with ~1 px soft edges (no aliasing when the player bobs)
                stripes = 0.15 * np.clip(0.5 + np.sin(2 * np.pi * 6.0 * yrel) * (2 * b) / (2 * np.pi * 6.0), 0, 1)
                # shirt above 55 % of the height, shorts below, edge softened over ~1 px
                m = np.clip((yrel - 0.55) * 2 * b + 0.5, 0, 1)
                val = (1 - m) * (self.shirt - stripes) + m * self.shorts
            else:
                val = np.full_like(cov, self.skin)
            covs.append(cov)
            vals.append(val)
        cov = np.maximum(covs[0], covs[1])
        I = np.where(covs[1] > 0, vals[1], vals[0])
        return I, cov


@dataclass
class Arm:
    """Swinging arm (or racket handle): a capsule turning about a shoulder pivot.

    Geometry in pixels (orthographic sensor coordinates): from ``pivot_px`` the arm
    points at ``angle0_rad + omega_rad_s t`` (image angle, x right, y down), is
    ``length_px`` long and ``width_px`` wide, and ends in a rounded hand.
    """

    pivot_px: tuple[float, float] = (300.0, 400.0)
    length_px: float = 120.0
    width_px: float = 30.0
    angle0_rad: float = -np.pi / 2
    omega_rad_s: float = 10.0
    skin: float = 0.55

    def _tip(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        a = self.angle0_rad + self.omega_rad_s * t
        return self.pivot_px[0] + self.length_px * np.cos(a), self.pivot_px[1] + self.length_px * np.sin(a)

    def max_speed_px_s(self, cam: Camera, t_s: float) -> float:
        """Fastest image motion (px/s): the hand's edge."""
        return abs(self.omega_rad_s) * (self.length_px + self.width_px)

    def bbox(self, cam: Camera, t0_s: float, t1_s: float) -> tuple[float, float, float, float]:
        """Image bounding box ``(x0, y0, x1, y1)`` (px) over ``[t0_s, t1_s]``."""
        t = np.linspace(t0_s, t1_s, max(2, int(abs(self.omega_rad_s) * abs(t1_s - t0_s) / 0.1) + 2))
        x, y = self._tip(t)
        m = 0.5 * self.width_px + 2
        return (min(x.min(), self.pivot_px[0]) - m, min(y.min(), self.pivot_px[1]) - m,
                max(x.max(), self.pivot_px[0]) + m, max(y.max(), self.pivot_px[1]) + m)

    def render(self, cam: Camera, u, v, t_s, light, ambient):
        """Brightness and anti-aliased coverage (K, N) at pixels ``(u, v)``, times ``t_s`` (K,)."""
        t = np.atleast_1d(np.asarray(t_s, np.float64))[:, None]
        x1, y1 = self._tip(t)
        x0, y0 = self.pivot_px
        dx, dy = x1 - x0, y1 - y0
        s = np.clip(((u[None, :] - x0) * dx + (v[None, :] - y0) * dy) / (dx * dx + dy * dy), 0.0, 1.0)
        d = np.hypot(u[None, :] - (x0 + s * dx), v[None, :] - (y0 + s * dy))
        cov = np.clip(0.5 * self.width_px - d + 0.5, 0.0, 1.0)
        # a sleeve edge across the arm at 40 % of its length (the forearm's own texture)
        return np.where(s < 0.4, 0.2, self.skin), cov



def _capsule_cover(s, q, s0: float, s1: float, width_px: float):
    """Anti-aliased coverage of a capsule from ``s0`` to ``s1`` along ``s`` (px), ``width_px`` wide."""
    d = np.hypot(s - np.clip(s, s0, s1), q)
    return np.clip(0.5 * width_px - d + 0.5, 0.0, 1.0)


@dataclass
class Racket:
    """A racket or bat swung past the ball: arm, handle and an elliptical head turning about a
    shoulder pivot.

    Geometry in pixels (orthographic sensor coordinates): from ``pivot_px`` everything points at
    ``angle0_rad + omega_rad_s t`` (image angle, x right, y down); the arm (``arm_px`` long,
    ``arm_width_px`` wide) ends at the wrist, the handle (``handle_px`` by ``handle_width_px``)
    follows, then the head, an ellipse with semi-axes ``head_a_px`` along the shaft and
    ``head_b_px`` across it.  ``kind="racket"`` (tennis): a dark frame ``rim_px`` wide round a
    face of bright strings ``string_px`` wide every ``string_spacing_px`` (the court shows
    between them); ``kind="paddle"`` (table tennis): a solid dark rubber face with a light wooden
    edge ``rim_px`` wide, round like a ball and larger than it.
    """

    pivot_px: tuple[float, float] = (300.0, 400.0)
    angle0_rad: float = -np.pi / 2
    omega_rad_s: float = 10.0
    arm_px: float = 300.0
    arm_width_px: float = 45.0
    handle_px: float = 100.0
    handle_width_px: float = 15.0
    head_a_px: float = 80.0
    head_b_px: float = 62.0
    rim_px: float = 6.0
    kind: str = "racket"
    string_px: float = 1.5
    string_spacing_px: float = 7.5
    skin: float = 0.55

    def __post_init__(self):
        if self.kind not in ("racket", "paddle"):
            raise ValueError(f"kind must be 'racket' or 'paddle', got {self.kind!r}")

    @property
    def length_px(self) -> float:
        """From the pivot to the head's far end (px)."""
        return self.arm_px + self.handle_px + 2 * self.head_a_px

    def head_center(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """The head's centre (px) at times ``t_s``."""
        a = self.angle0_rad + self.omega_rad_s * np.asarray(t_s, np.float64)
        reach = self.arm_px + self.handle_px + self.head_a_px
        return self.pivot_px[0] + reach * np.cos(a), self.pivot_px[1] + reach * np.sin(a)

    def max_speed_px_s(self, cam: Camera, t_s: float) -> float:
        """Fastest image motion (px/s): the head's far end."""
        return abs(self.omega_rad_s) * self.length_px

    def bbox(self, cam: Camera, t0_s: float, t1_s: float) -> tuple[float, float, float, float]:
        """Image bounding box ``(x0, y0, x1, y1)`` (px) over ``[t0_s, t1_s]``."""
        t = np.linspace(t0_s, t1_s, max(2, int(abs(self.omega_rad_s) * abs(t1_s - t0_s) / 0.05) + 2))
        a = self.angle0_rad + self.omega_rad_s * t
        x = self.pivot_px[0] + self.length_px * np.cos(a)
        y = self.pivot_px[1] + self.length_px * np.sin(a)
        m = max(self.head_b_px, 0.5 * self.arm_width_px) + 2
        return (min(x.min(), self.pivot_px[0]) - m, min(y.min(), self.pivot_px[1]) - m,
                max(x.max(), self.pivot_px[0]) + m, max(y.max(), self.pivot_px[1]) + m)

    def render(self, cam: Camera, u, v, t_s, light, ambient):
        """Brightness and anti-aliased coverage (K, N) at pixels ``(u, v)``, times ``t_s`` (K,)."""
        t = np.atleast_1d(np.asarray(t_s, np.float64))[:, None]
        a = self.angle0_rad + self.omega_rad_s * t
        dx, dy = u[None, :] - self.pivot_px[0], v[None, :] - self.pivot_px[1]
        s = dx * np.cos(a) + dy * np.sin(a)  # along the shaft
        q = -dx * np.sin(a) + dy * np.cos(a)  # across it
        wrist = self.arm_px
        neck = wrist + self.handle_px
        arm = _capsule_cover(s, q, 0.0, wrist, self.arm_width_px)
        handle = _capsule_cover(s, q, wrist, neck + self.rim_px, self.handle_width_px)
        x, y = (s - neck - self.head_a_px) / self.head_a_px, q / self.head_b_px
        inset = (1.0 - np.sqrt(x * x + y * y)) * min(self.head_a_px, self.head_b_px)  # px inside the rim, about
        head = np.clip(inset + 0.5, 0.0, 1.0)
        rim = np.clip(self.rim_px - inset + 0.5, 0.0, 1.0)  # 1 on the rim, 0 well inside it
        if self.kind == "paddle":
            face_cov, face = head, rim * 0.6 + (1 - rim) * 0.12
        else:  # strings in the head's own frame: the court shows between them
            def strings(c):
                d = np.abs((c + 0.5 * self.string_spacing_px) % self.string_spacing_px - 0.5 * self.string_spacing_px)
                return np.clip(0.5 * self.string_px - d + 0.5, 0.0, 1.0)
            mesh = np.maximum(strings(s - neck), strings(q))
            face_cov, face = head * np.maximum(rim, mesh), rim * 0.08 + (1 - rim) * 0.85
        cov = np.maximum(np.maximum(arm, handle), face_cov)
        I = np.where(face_cov > 0, face, np.where(handle > 0, 0.1, np.where(s < 0.4 * wrist, 0.2, self.skin)))
        return I, cov

def disjoint_groups(items, n_pixels: int) -> list[tuple[np.ndarray, int]]:
    """Merge per-object pixel sets that need ``n`` samples into disjoint groups.

    ``items`` is a sequence of ``(flat_indices, n)``; every pixel lands in the group
    of the largest ``n`` among the items that contain it. Returns ``[(flat, n)]``
    with ``n`` decreasing.
    """
    taken = np.zeros(n_pixels, bool)
    out = []
    for n in sorted({m for _, m in items}, reverse=True):
        parts = []
        for flat, m in items:
            if m == n:
                sel = flat[~taken[flat]]
                taken[sel] = True
                parts.append(sel)
        flat = np.concatenate(parts)
        if flat.size:
            out.append((flat, n))
    return out


def court_background(width: int, height: int, rng: np.random.Generator, *, level: float = 0.35):
    """A static textured background (floor, lines, boards) as a function ``bg(u, v) -> I``.

    Drawn once from ``rng``; evaluable at any (float) pixel coordinates so the frame
    camera can sample it from another viewpoint.
    """
    n_waves = 6
    kx = rng.uniform(-1, 1, n_waves) * 2 * np.pi / rng.uniform(40, 300, n_waves)
    ky = rng.uniform(-1, 1, n_waves) * 2 * np.pi / rng.uniform(40, 300, n_waves)
    ph = rng.uniform(0, 2 * np.pi, n_waves)
    amp = rng.uniform(0.01, 0.04, n_waves)
    line_y = height * rng.uniform(0.7, 0.85)
    line_x = width * rng.uniform(0.2, 0.8)
    board_top = height * rng.uniform(0.25, 0.35)
    n_ads = 5
    ad_x = np.sort(rng.uniform(0, width, n_ads + 1))
    ad_lvl = rng.uniform(0.2, 0.7, n_ads)

    def bg(u, v):
        u = np.asarray(u, np.float64)
        v = np.asarray(v, np.float64)
        out = np.full(np.broadcast(u, v).shape, level)
        for i in range(n_waves):
            out += amp[i] * np.sin(kx[i] * u + ky[i] * v + ph[i])

        def band(dist, half):
            return np.clip(half + 0.5 - np.abs(dist), 0, 1)

        out += 0.4 * np.maximum(band(v - line_y, 3.0), band(u - line_x, 3.0) * (v > board_top + 40))
        # advertising boards: a strip of constant-level panels with soft edges
        in_board = np.clip(np.minimum(v - (board_top - 40), board_top - v) + 0.5, 0, 1)
        idx = np.clip(np.searchsorted(ad_x, u) - 1, 0, n_ads - 1)
        out = out + in_board * (ad_lvl[idx] - out)
        return np.clip(out, 0.02, 1.0)

    return bg


@dataclass
class Scene:
    """Everything the cameras see: background function, objects (back to front), lighting."""

    camera: Camera
    objects: list = field(default_factory=list)
    background: object = None
    background_level: float = 0.3
    light: np.ndarray = field(default_factory=lambda: unit([-0.35, -0.5, -1.0]))
    ambient: float = 0.35

    def __post_init__(self):
        self.light = unit(self.light)
        self._bg_cache: dict = {}

    def background_at(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Background brightness at pixels (N,)."""
        if self.background is None:
            return np.full(np.shape(u), float(self.background_level))
        return self.background(u, v)

    def sensor_background(self) -> np.ndarray:
        """Background brightness over the whole sensor, flat (H*W,), cached."""
        if "sensor" not in self._bg_cache:
            h, w = self.camera.height, self.camera.width
            v, u = np.divmod(np.arange(h * w), w)
            self._bg_cache["sensor"] = self.background_at(u.astype(float), v.astype(float))
        return self._bg_cache["sensor"]

    def render(self, u: np.ndarray, v: np.ndarray, t_s, bg: np.ndarray | None = None) -> np.ndarray:
        """Brightness (K, N) at pixel coordinates ``(u, v)`` (N,) and times ``t_s`` (K,)."""
        t = np.atleast_1d(np.asarray(t_s, np.float64))
        base = self.background_at(u, v) if bg is None else bg
        out = np.broadcast_to(base, (len(t), len(u))).copy()
        if len(u) == 0:
            return out
        umin, umax, vmin, vmax = u.min(), u.max(), v.min(), v.max()
        for obj in self.objects:
            x0, y0, x1, y1 = obj.bbox(self.camera, t[0], t[-1])
            if x1 < umin or x0 > umax or y1 < vmin or y0 > vmax:
                continue
            if x0 <= umin and x1 >= umax and y0 <= vmin and y1 >= vmax:
                I, cov = obj.render(self.camera, u, v, t, self.light, self.ambient)
                out += cov * (I - out)
                continue
            sel = np.flatnonzero((u >= x0) & (u <= x1) & (v >= y0) & (v <= y1))
            if sel.size:
                I, cov = obj.render(self.camera, u[sel], v[sel], t, self.light, self.ambient)
                part = out[:, sel]
                out[:, sel] = part + cov * (I - part)
        return out

    def max_speed_px_s(self, t_s: float) -> float:
        """Fastest image motion of anything in the scene at ``t_s`` (px/s)."""
        return max([o.max_speed_px_s(self.camera, t_s) for o in self.objects], default=0.0)

    def footprint_pixels(self, obj, t0_s: float, t1_s: float, margin_px: float = 2.0) -> np.ndarray:
        """Flat indices (y * width + x) of the pixels ``obj`` may touch during ``[t0_s, t1_s]``.

        A ball's footprint is its swept capsule, any other object's its bounding box,
        both grown by ``margin_px`` (larger than a render step, so a pixel leaving the
        footprint has already been sampled with the object clear of it).
        """
        w, h = self.camera.width, self.camera.height
        x0, y0, x1, y1 = obj.bbox(self.camera, t0_s, t1_s)
        x0 = max(int(np.floor(x0 - margin_px)), 0)
        y0 = max(int(np.floor(y0 - margin_px)), 0)
        x1 = min(int(np.ceil(x1 + margin_px)), w - 1)
        y1 = min(int(np.ceil(y1 + margin_px)), h - 1)
        if x1 < x0 or y1 < y0:
            return np.zeros(0, np.int64)
        yy, xx = np.mgrid[y0:y1 + 1, x0:x1 + 1]
        if isinstance(obj, Ball):
            a, b, r = obj.footprint(self.camera, t0_s, t1_s)
            r += margin_px
            ab = b - a
            L2 = float(ab @ ab)
            s = np.zeros(xx.shape) if L2 == 0 else np.clip(((xx - a[0]) * ab[0] + (yy - a[1]) * ab[1]) / L2, 0, 1)
            keep = np.hypot(xx - a[0] - s * ab[0], yy - a[1] - s * ab[1]) <= r
            yy, xx = yy[keep], xx[keep]
        return (yy * w + xx).ravel().astype(np.int64)
