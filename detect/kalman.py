"""Kalman filter and RTS smoother for the ball's image circle.

State ``[x, y, vx, vy, ax, ay, r]`` (px, px/s, px/s², px). Two motion models:

* ``"ca"``: constant acceleration driven by white jerk noise (the acceleration,
  e.g. gravity and drag as seen in the image, is estimated);
* ``"cv"``: constant velocity plus a known image acceleration ``gravity_px_s2``
  (the acceleration states are pinned to it), driven by white acceleration noise.

The radius follows a random walk. Measurements are ``[cx, cy, r]`` with their own
standard deviations (events and frames differ).
"""

from __future__ import annotations

import numpy as np

from detect._kernels import kf_mahalanobis, kf_predict, kf_update, rts_gain


class CircleKalman:
    """Kalman filter over one flight, keeping the history needed for smoothing.

    Parameters
    ----------
    t_us : int
        Time of the first measurement, µs.
    z : (float, float, float)
        First measurement ``(cx, cy, r)``, px.
    velocity_px_s : (float, float)
        Initial velocity guess, px/s, with standard deviation ``velocity_sigma_px_s``.
    model : {"ca", "cv"}
        Motion model (see module docstring).
    gravity_px_s2 : (float, float)
        Known (``"cv"``) or initial (``"ca"``) image acceleration, px/s².
    q_px_s3 : float
        Process noise density: jerk (``"ca"``) in px/s³, or acceleration (``"cv"``)
        in px/s² per √s.
    q_r_px : float
        Radius random-walk density, px per √s.
    sigma_px : float
        Standard deviation of the first measurement, px.
    """

    def __init__(self, t_us: int, z, *, velocity_px_s=(0.0, 0.0), velocity_sigma_px_s: float = 2000.0,
                 model: str = "ca", gravity_px_s2=(0.0, 0.0), accel_sigma_px_s2: float = 5000.0,
                 q_px_s3: float = 3.0e4, q_r_px: float = 20.0, sigma_px: float = 1.0):
        if model not in ("ca", "cv"):
            raise ValueError(f"model must be 'ca' or 'cv', got {model!r}")
        self.model = model
        self.q = float(q_px_s3)
        self.q_r = float(q_r_px)
        self.t_us = int(t_us)
        self._cache: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self._gains: list[np.ndarray] = []
        self.x = np.array([z[0], z[1], velocity_px_s[0], velocity_px_s[1], gravity_px_s2[0],
                           gravity_px_s2[1], z[2]], dtype=np.float64)
        a_var = accel_sigma_px_s2 ** 2 if model == "ca" else 0.0
        self.P = np.diag([sigma_px ** 2, sigma_px ** 2, velocity_sigma_px_s ** 2, velocity_sigma_px_s ** 2,
                          a_var, a_var, sigma_px ** 2])
        # history for RTS smoothing: (t_us, x_prior, P_prior, F, x_post, P_post)
        self.history: list[tuple[int, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = [
            (self.t_us, self.x.copy(), self.P.copy(), np.eye(7), self.x.copy(), self.P.copy())]

    def _transition(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        if dt in self._cache:
            return self._cache[dt]
        f = np.eye(7)
        q = np.zeros((7, 7))
        for i in (0, 1):
            p, v, a = i, i + 2, i + 4
            f[p, v] = dt
            f[p, a] = 0.5 * dt * dt
            f[v, a] = dt
            if self.model == "ca":
                blk = self.q ** 2 * np.array([[dt ** 5 / 20, dt ** 4 / 8, dt ** 3 / 6],
                                              [dt ** 4 / 8, dt ** 3 / 3, dt ** 2 / 2],
                                              [dt ** 3 / 6, dt ** 2 / 2, dt]])
                idx = [p, v, a]
            else:
                blk = self.q ** 2 * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
                idx = [p, v]
            q[np.ix_(idx, idx)] = blk
        q[6, 6] = self.q_r ** 2 * dt
        if len(self._cache) < 64:
            self._cache[dt] = (f, q)
        return f, q

    def predict(self, t_us: int) -> tuple[np.ndarray, np.ndarray]:
        """State and covariance predicted to ``t_us`` (does not change the filter; an earlier time
        extrapolates back)."""
        f, q = self._transition((t_us - self.t_us) * 1e-6)
        return kf_predict(f, q, self.x, self.P)

    def propagate(self, x: np.ndarray, t_from_us: int, t_to_us: int) -> np.ndarray:
        """State ``x`` (shape (7,)) at ``t_from_us`` moved by the motion model to ``t_to_us`` (either way)."""
        return self._transition((t_to_us - t_from_us) * 1e-6)[0] @ x

    def innovation(self, t_us: int, z, sigma_px: float) -> tuple[float, np.ndarray]:
        """Squared Mahalanobis distance of centre measurement ``z`` (px, centre sigma ``sigma_px``)
        against the prediction to ``t_us``, and that predicted state (shape (7,))."""
        x, p = self.predict(t_us)
        return float(kf_mahalanobis(x, p, float(z[0]), float(z[1]), float(sigma_px) ** 2)), x

    def update(self, t_us: int, z, sigma_px: float, sigma_r_px: float) -> None:
        """Predict to ``t_us`` and fuse measurement ``z = (cx, cy, r)``."""
        f, q = self._transition((t_us - self.t_us) * 1e-6)
        var = float(sigma_px) ** 2
        xp, pp, self.x, self.P = kf_update(f, q, self.x, self.P, np.asarray(z, np.float64),
                                           np.array([var, var, float(sigma_r_px) ** 2]))
        self.t_us = int(t_us)
        self.history.append((self.t_us, xp, pp, f, self.x.copy(), self.P.copy()))

    def _gain(self, k: int) -> np.ndarray:
        """RTS smoother gain from update ``k`` to ``k + 1`` (computed once; the filter never revisits it)."""
        while len(self._gains) <= k:
            j = len(self._gains)
            _, _, _, _, _, pj = self.history[j]
            _, _, pp1, f1, _, _ = self.history[j + 1]
            self._gains.append(rts_gain(pj, f1, pp1))
        return self._gains[k]

    def smoothed(self, start: int = 0, stop: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Rauch-Tung-Striebel smoothed states of updates ``start .. stop - 1``, given the
        updates before ``stop`` (default: all of them).

        Returns
        -------
        t_us : ndarray of int64, shape (K,)
        states : ndarray of float64, shape (K, 7)
        """
        stop = len(self.history) if stop is None else stop
        xs = np.empty((stop - start, 7))
        xs[-1] = self.history[stop - 1][4]
        for k in range(stop - 2, start - 1, -1):
            _, _, _, _, xk, _ = self.history[k]
            _, xp1, _, _, _, _ = self.history[k + 1]
            xs[k - start] = xk + self._gain(k) @ (xs[k + 1 - start] - xp1)
        return np.array([h[0] for h in self.history[start:stop]], dtype=np.int64), xs
