"""GoPro-like frame camera looking at the same scene.

The frame camera's pixels map onto the event camera's image plane through a
homography ``frame_to_event`` (3, 3) (identity: same viewpoint; a shift, scale or
rotation models a second viewpoint of the court plane). Each frame averages
sub-renders over its exposure (motion blur), then applies gamma, noise and 8-bit
quantisation. Frame times are the exposure midpoints on the event clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import Scene, disjoint_groups


@dataclass
class SyncBox:
    """LED sync box wired to the event camera's trigger input, visible in the frames.

    The LED is on during ``[r_k, r_k + pulse_s)`` with ``r_k = phase_s + k period_s + j_k``; the
    jitter ``j_k`` is 0 for a periodic box, or a pseudo-random value in ``[0, jitter_s)`` fixed
    by ``seed`` (a box whose edges do not keep one phase against the frames, so that frames time
    them at every phase). It sits at ``led_box_px = (x0, y0, x1, y1)`` (frame pixels,
    inclusive-exclusive).
    """

    period_s: float = 0.1
    pulse_s: float = 0.02
    phase_s: float = 0.01
    led_box_px: tuple[int, int, int, int] = (8, 8, 24, 24)
    jitter_s: float = 0.0
    seed: int = 0

    def __post_init__(self):
        if not 0.0 <= self.jitter_s < self.period_s - self.pulse_s:
            raise ValueError(f"jitter_s must be in [0, period_s - pulse_s), got {self.jitter_s}")

    def _rise_s(self, k: np.ndarray) -> np.ndarray:
        """Rising edge of pulse ``k`` (s)."""
        k = np.asarray(k, np.float64)
        rise = self.phase_s + k * self.period_s
        if self.jitter_s:  # a fixed pseudo-random fraction per pulse (integer hash of k and the seed)
            h = (k.astype(np.int64) * 0x9E3779B1 + self.seed * 0x85EBCA77) & 0xFFFFFFFF
            h = (h ^ (h >> 15)) * 0x2C1B3C6D & 0xFFFFFFFF
            rise = rise + self.jitter_s * ((h ^ (h >> 12)) & 0xFFFFFF) / float(1 << 24)
        return rise

    def edges_s(self, t0_s: float, t1_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Rising and falling edge times (s) inside ``[t0_s, t1_s)``."""
        k0 = int(np.floor((t0_s - self.phase_s) / self.period_s)) - 1
        k1 = int(np.ceil((t1_s - self.phase_s) / self.period_s)) + 1
        rise = self._rise_s(np.arange(k0, k1 + 1))
        fall = rise + self.pulse_s
        return rise[(rise >= t0_s) & (rise < t1_s)], fall[(fall >= t0_s) & (fall < t1_s)]

    def on_fraction(self, a_s: np.ndarray, b_s: np.ndarray) -> np.ndarray:
        """Fraction of each interval ``[a, b)`` during which the LED is on."""
        a_s = np.asarray(a_s, float)
        b_s = np.asarray(b_s, float)
        k0 = np.floor((a_s - self.phase_s) / self.period_s) - 1
        out = np.zeros_like(a_s)
        for dk in range(0, int(np.ceil(np.max(b_s - a_s) / self.period_s)) + 3):
            on0 = self._rise_s(k0 + dk)
            out += np.clip(np.minimum(b_s, on0 + self.pulse_s) - np.maximum(a_s, on0), 0, None)
        return out / np.maximum(b_s - a_s, 1e-12)


def _map(h: np.ndarray, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    w = h[2, 0] * u + h[2, 1] * v + h[2, 2]
    return (h[0, 0] * u + h[0, 1] * v + h[0, 2]) / w, (h[1, 0] * u + h[1, 1] * v + h[1, 2]) / w


def render_frames(scene: Scene, t_mid_s: np.ndarray, *, exposure_s, width: int, height: int,
                  frame_to_event: np.ndarray | None = None, rng: np.random.Generator | None = None,
                  noise_dn: float = 2.0, gamma: float = 2.2, gain: float = 1.0,
                  sub_px: float = 1.0, max_sub: int = 24, sync: SyncBox | None = None) -> np.ndarray:
    """Grey 8-bit frames (T, height, width) of ``scene`` exposed around ``t_mid_s`` (T,) for
    ``exposure_s`` (s; one for all frames, or one per frame).

    Sub-renders are spread over the exposure so that moving objects advance at most
    ``sub_px`` pixels between them (at most ``max_sub``); pixels away from every
    moving object are the static background.
    """
    h = np.eye(3) if frame_to_event is None else np.asarray(frame_to_event, np.float64)
    h_inv = np.linalg.inv(h)
    vf, uf = np.divmod(np.arange(width * height), width)
    ue, ve = _map(h, uf.astype(float), vf.astype(float))
    bg = scene.background_at(ue, ve)
    out = np.empty((len(t_mid_s), height, width), np.uint8)
    exposures = np.broadcast_to(np.asarray(exposure_s, float), np.shape(t_mid_s))
    for i, (tm, exposure) in enumerate(zip(np.asarray(t_mid_s, float), exposures)):
        a, b = tm - exposure / 2, tm + exposure / 2
        img = bg.copy()
        items = []
        for o in scene.objects:
            speed = max(o.max_speed_px_s(scene.camera, a), o.max_speed_px_s(scene.camera, b))
            n_sub = int(np.clip(np.ceil(speed * exposure / sub_px), 1, max_sub))
            x0, y0, x1, y1 = o.bbox(scene.camera, a, b)
            cu, cv = _map(h_inv, np.array([x0, x1, x0, x1]), np.array([y0, y0, y1, y1]))
            fx0, fx1 = max(int(np.floor(cu.min())) - 1, 0), min(int(np.ceil(cu.max())) + 1, width - 1)
            fy0, fy1 = max(int(np.floor(cv.min())) - 1, 0), min(int(np.ceil(cv.max())) + 1, height - 1)
            if fx1 >= fx0 and fy1 >= fy0:
                yy, xx = np.mgrid[fy0:fy1 + 1, fx0:fx1 + 1]
                items.append(((yy * width + xx).ravel(), n_sub))
        for flat, n_sub in disjoint_groups(items, width * height):
            times = a + (np.arange(n_sub) + 0.5) * (exposure / n_sub)
            img[flat] = scene.render(ue[flat], ve[flat], times, bg=bg[flat]).mean(axis=0)
        img = img.reshape(height, width)
        if sync is not None:
            x0, y0, x1, y1 = sync.led_box_px
            img[y0:y1, x0:x1] = 0.05 + 0.95 * sync.on_fraction([a], [b])[0]
        dn = 255.0 * np.clip(gain * img, 0, 1) ** (1.0 / gamma)
        if rng is not None and noise_dn > 0:
            dn = dn + rng.normal(0.0, noise_dn, dn.shape)
        out[i] = np.clip(np.rint(dn), 0, 255).astype(np.uint8)
    return out
