"""Event generation from a rendered scene: an ESIM-like generator with a DVS pixel model.

Per pixel: log intensity ``L = ln(I + eps)``, a reference level set at the last
event, ON/OFF contrast thresholds ``C+`` / ``C-`` with a fixed per-pixel mismatch
(drawn once per sensor), crossing times interpolated linearly between render
steps, several events when one step spans several thresholds, an optional
refractory period. Render steps adapt so that nothing in the image moves more
than ``step_px`` per step, and only pixels that can change are processed.

:class:`SensorModel` adds the non-idealities of a real DVS pixel, after v2e (Hu,
Liu & Delbruck, "v2e: From Video Frames to Realistic DVS Events", CVPRW 2021;
github.com/SensorsINI/v2e):

- **Finite photoreceptor bandwidth.** The pixel compares its reference not with
  ``L`` but with ``F``, ``L`` through a first-order low-pass whose cutoff grows
  with the photocurrent (``cutoff_hz * (I + dark_level) / (1 + dark_level)``,
  capped at ``cutoff_max_hz``): dim pixels lag more, and an edge's events at one
  pixel spread out over about one time constant. The update is exact for the
  linear interpolation of ``L`` between samples (``a = 1 - exp(-dt / tau)``),
  so it is stable for any step length.
- **Leak events.** The reference drifts towards ON by ``rate * C+`` per second
  (per-pixel ``rate``: ``leak_rate_hz`` with a log-normal spread across pixels);
  a static pixel fires ON events at its rate, each interval with a Gaussian
  jitter of ``leak_jitter`` of its length (where an object covers the pixel the
  drift just adds to the input, without jitter: leak periods are seconds long).
- **Shot noise.** Poisson ON and OFF events, each resetting the pixel's reference
  to its current level, at ``shot_noise_rate_hz`` in the dark, falling to
  ``shot_bright_factor`` of it at full brightness, higher for pixels with a low
  threshold.
- **Readout latency.** An event's timestamp follows its threshold crossing by an
  exponential random delay (mean ``latency_jitter_us``); the refractory period
  starts at the timestamp.

With the ideal model (:data:`SENSOR_PRESETS` ``"ideal"``) none of this runs and
the output is that of the plain generator. Otherwise the leak and shot-noise
events of idle pixels (outside every object's footprint) are generated in closed
form when the pixel is next needed or at the end. With a bandwidth limit the
photoreceptors are warmed up before ``t_start_s`` (the window starts in steady
state), pixels an object left are filtered on until they have settled, and, with
a capped cutoff, render steps need not be much finer than the shortest time
constant.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np

from capture.events import EVENT_DTYPE
from .scene import LOG_EPS, Scene, disjoint_groups

SETTLE_TOL = 1e-3
"""Photoreceptor lag ``|F - L|`` (log units) below which a static pixel counts as settled."""

COARSE_STEP_TAUS = 0.125
"""With a capped bandwidth, render steps may grow to this fraction of the shortest time constant ..."""

COARSE_STEP_PX = 1.0
"""... as long as nothing moves more than this (px) per step (``step_px`` is the floor)."""

LEAK_JITTER_CLIP = 8.0
"""Leak-interval jitter is Gaussian, clipped at this many standard deviations."""

WARMUP_TAUS = 3.0
"""Warm-up length before the start, in time constants of the slowest tenth of the moving pixels."""

WARMUP_STEP_PX = 1.0
"""Largest image motion (px) per render step just before the start, during the warm-up."""

WARMUP_REL_STEP = 0.125
"""Warm-up render step, further back, as a fraction of the time before the start."""


@dataclass(frozen=True)
class SensorModel:
    """Parameters of the simulated DVS pixel (see the module docstring for the model).

    Parameters
    ----------
    threshold : float
        Nominal ON contrast threshold ``C+`` (log units).
    threshold_off : float, optional
        Nominal OFF threshold ``C-`` (log units); default ``threshold``.
    mismatch_sigma : float
        Standard deviation of the per-pixel threshold mismatch (log units).
    min_threshold : float
        Floor of any pixel's threshold (log units).
    refractory_us : float
        Dead time after each event (µs); crossings inside it are lost.
    cutoff_hz : float, optional
        3 dB cutoff of the photoreceptor low-pass at brightness ``I = 1`` (Hz);
        it scales with ``(I + dark_level) / (1 + dark_level)``. None: unlimited bandwidth.
    cutoff_max_hz : float, optional
        Cap of the cutoff at high brightness (Hz); None: no cap.
    dark_level : float
        Photocurrent without light, in units of the brightness ``I`` (sets the
        bandwidth and shot-noise scaling of black pixels).
    leak_rate_hz : float
        Mean leak (ON) event rate per pixel (Hz).
    leak_spread_decades : float
        Standard deviation of ``log10`` of the per-pixel leak rate (mean kept at ``leak_rate_hz``).
    leak_jitter : float
        Standard deviation of each leak interval as a fraction of its length
        (Gaussian, clipped at ``LEAK_JITTER_CLIP`` standard deviations).
    shot_noise_rate_hz : float
        Shot-noise rate per pixel (ON + OFF, Hz) in the dark.
    shot_bright_factor : float
        Shot-noise rate at brightness 1 as a fraction of the dark rate.
    latency_jitter_us : float
        Mean of the exponential delay (µs) between a crossing and its timestamp.
    """

    threshold: float = 0.15
    threshold_off: float | None = None
    mismatch_sigma: float = 0.03
    min_threshold: float = 0.05
    refractory_us: float = 0.0
    cutoff_hz: float | None = None
    cutoff_max_hz: float | None = None
    dark_level: float = 0.078
    leak_rate_hz: float = 0.0
    leak_spread_decades: float = 0.0
    leak_jitter: float = 0.0
    shot_noise_rate_hz: float = 0.0
    shot_bright_factor: float = 0.25
    latency_jitter_us: float = 0.0

    def __post_init__(self):
        if not self.threshold > 0:
            raise ValueError(f"contrast threshold must be positive, got {self.threshold}")
        if self.threshold_off is not None and not self.threshold_off > 0:
            raise ValueError(f"OFF threshold must be positive, got {self.threshold_off}")
        for name in ("mismatch_sigma", "min_threshold", "refractory_us", "dark_level", "leak_rate_hz",
                     "leak_spread_decades", "leak_jitter", "shot_noise_rate_hz", "latency_jitter_us"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        for name in ("cutoff_hz", "cutoff_max_hz"):
            v = getattr(self, name)
            if v is not None and not v > 0:
                raise ValueError(f"{name} must be positive or None, got {v}")
        if self.cutoff_max_hz is not None and self.cutoff_hz is None:
            raise ValueError("cutoff_max_hz needs cutoff_hz")
        if self.cutoff_hz is not None and not self.dark_level > 0:
            raise ValueError("a finite bandwidth needs dark_level > 0 (black pixels would never respond)")
        if not 0 <= self.shot_bright_factor <= 1:
            raise ValueError(f"shot_bright_factor must be in [0, 1], got {self.shot_bright_factor}")

    @property
    def threshold_off_nominal(self) -> float:
        """Nominal OFF threshold (log units)."""
        return self.threshold if self.threshold_off is None else self.threshold_off

    @property
    def ideal(self) -> bool:
        """True when the pixel is the plain ESIM pixel (unlimited bandwidth, no noise, no jitter)."""
        return (self.cutoff_hz is None and self.leak_rate_hz == 0 and self.shot_noise_rate_hz == 0
                and self.latency_jitter_us == 0)

    @property
    def tau_min_s(self) -> float | None:
        """Shortest photoreceptor time constant (s): at the capped cutoff; None without a cap."""
        return None if self.cutoff_max_hz is None else 1.0 / (2.0 * np.pi * self.cutoff_max_hz)

    def relative_photocurrent(self, intensity) -> np.ndarray:
        """Photocurrent relative to brightness 1: ``(I + dark_level) / (1 + dark_level)``."""
        return (np.asarray(intensity, np.float64) + self.dark_level) / (1.0 + self.dark_level)

    def cutoff_hz_at(self, intensity) -> np.ndarray:
        """3 dB cutoff (Hz) of the photoreceptor at brightness ``intensity`` (inf if unlimited)."""
        if self.cutoff_hz is None:
            return np.full(np.shape(intensity), np.inf)
        f = self.cutoff_hz * self.relative_photocurrent(intensity)
        return f if self.cutoff_max_hz is None else np.minimum(f, self.cutoff_max_hz)

    def tau_s_at(self, intensity) -> np.ndarray:
        """Photoreceptor time constant ``1 / (2 pi f_3dB)`` (s) at brightness ``intensity``."""
        return 1.0 / (2.0 * np.pi * self.cutoff_hz_at(intensity))

    def shot_rate_hz_at(self, intensity) -> np.ndarray:
        """Shot-noise rate (ON + OFF, Hz) of a pixel with nominal thresholds at brightness ``intensity``."""
        rel = np.minimum(self.relative_photocurrent(intensity), 1.0)
        return self.shot_noise_rate_hz * (1.0 - (1.0 - self.shot_bright_factor) * rel)


SENSOR_PRESETS: dict[str, SensorModel] = {
    "ideal": SensorModel(),
    "realistic": SensorModel(
        threshold=0.2, mismatch_sigma=0.03, refractory_us=20.0, cutoff_hz=5000.0, cutoff_max_hz=4000.0,
        dark_level=0.078, leak_rate_hz=0.1, leak_spread_decades=0.1, leak_jitter=0.1,
        shot_noise_rate_hz=0.2, shot_bright_factor=0.25, latency_jitter_us=3.0),
}
"""Sensor models by name.

``"ideal"``: the plain ESIM pixel (threshold 0.15 +- 0.03, no refractory period,
unlimited bandwidth, no noise) used by every test and benchmark so far.

``"realistic"``: a Prophesee Gen4 / IMX636-class pixel in indoor sports-hall light
(brightness 1 = a white ball in full light):

- thresholds 0.2 +- 0.03 log units: v2e's defaults (its "clean"/"noisy" presets use
  0.2 with sigma 0.02/0.05); 0.2 is a contrast of about 22 %, near the nominal
  contrast threshold of Prophesee sensors;
- bandwidth: cutoff 5 kHz at brightness 1, capped at 4 kHz (tau = 40 µs in the
  bright parts); about 1.75 kHz (tau 91 µs) on the 0.3 background, 0.8 kHz
  (190 µs) on dark seams (I = 0.1), 0.36 kHz (440 µs) for black. Prophesee quotes a
  pixel latency of the order of 100 µs at 1000 lux (their light levels are
  referred to the focal plane); a ball in a hall lit at ~1000 lux puts a few
  hundred lux on the focal plane, so its bright parts lag by tens of µs and its
  dark parts by a few hundred. The dark offset 0.078 is v2e's (20 of 255 grey
  levels) and so is the proportionality of the cutoff to the photocurrent;
  v2e's own defaults (300 Hz, "noisy" 30 Hz) are for slower DAVIS pixels;
- leak 0.1 Hz per pixel with 0.1 decades spread across pixels and 10 % interval
  jitter: v2e's "noisy" preset;
- shot noise 0.2 Hz per pixel in the dark, 0.05 Hz at full brightness (v2e's
  factor 0.25): between v2e's good-light default (0.001 Hz) and its low-light
  "noisy" preset (5 Hz); with the leak, a mid-grey background fires about 0.25 Hz
  per pixel, the order of the background rate of an IMX636 in indoor light;
- refractory period 20 µs (an assumption: the dead time set by ``bias_refr``;
  v2e's default of 500 µs is for DAVIS pixels);
- readout delay: exponential, mean 3 µs (arbiter queueing; timestamps are 1 µs).
"""


def get_sensor_model(sensor: str | SensorModel) -> SensorModel:
    """A :class:`SensorModel` from a preset name or a model (returned as is).

    Raises
    ------
    ValueError
        For an unknown preset name, naming the choices.
    """
    if isinstance(sensor, SensorModel):
        return sensor
    try:
        return SENSOR_PRESETS[sensor]
    except (KeyError, TypeError):
        raise ValueError(f"unknown sensor {sensor!r}; choose one of {sorted(SENSOR_PRESETS)} "
                         f"or pass a SensorModel") from None


def sensor_truth(sensor: str | SensorModel, model: SensorModel) -> dict:
    """JSON-able record of a sensor: ``preset`` (the name given, or None) and every model field."""
    return {"preset": sensor if isinstance(sensor, str) else None, **asdict(model)}


@dataclass
class SensorState:
    """Per-pixel state of the simulated event sensor, flat arrays of length H*W.

    ``c_on`` / ``c_off``: contrast thresholds (log units), fixed for the sensor's
    life; ``ref``: reference level (log units) the pixel compares with; ``last_t_s``:
    timestamp of the last emitted event (for the refractory period); ``sample_L`` /
    ``sample_t_s``: log level and time of each pixel's latest render sample;
    ``model``: the :class:`SensorModel`; ``rng``: the generator that drew the
    thresholds, then used for the sensor's noise.

    With a bandwidth limit, ``F`` is the photoreceptor output (log units) and
    ``unsettled`` the flat indices of pixels whose ``F`` still lags their static
    input. With leak events, ``leak_drift`` is each pixel's reference drift
    (log units per s); the reference is then kept relative to ``F + leak_drift * t``
    (``t`` in s), so the drift never has to be applied to pixels nobody looks at.
    With shot noise, ``shot_weight_max`` bounds the sums of the pixels' :meth:`shot_weights`.
    """

    width: int
    height: int
    c_on: np.ndarray
    c_off: np.ndarray
    ref: np.ndarray
    last_t_s: np.ndarray
    sample_L: np.ndarray
    sample_t_s: np.ndarray
    model: SensorModel = field(default_factory=SensorModel)
    rng: np.random.Generator | None = None
    F: np.ndarray | None = None
    leak_drift: np.ndarray | None = None
    unsettled: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    shot_weight_max: float = 0.0

    @classmethod
    def new(cls, width: int, height: int, rng: np.random.Generator, model: str | SensorModel = "ideal",
            **overrides) -> SensorState:
        """Fresh sensor: thresholds with mismatch (and leak rates) drawn once from ``rng``.

        Parameters
        ----------
        model : str or SensorModel
            Preset name (see :data:`SENSOR_PRESETS`) or model.
        **overrides
            :class:`SensorModel` fields replacing the model's (e.g. ``threshold=0.2``).
        """
        m = get_sensor_model(model)
        if overrides:
            m = replace(m, **overrides)
        n = width * height
        on = m.threshold + m.mismatch_sigma * rng.standard_normal(n)
        off = m.threshold_off_nominal + m.mismatch_sigma * rng.standard_normal(n)
        c_on = np.maximum(on, m.min_threshold)
        state = cls(width, height, c_on, np.maximum(off, m.min_threshold), np.zeros(n), np.full(n, -np.inf),
                    np.zeros(n), np.zeros(n), m, rng)
        if m.cutoff_hz is not None:
            state.F = np.zeros(n)
        if m.shot_noise_rate_hz > 0:
            state.shot_weight_max = float(np.max(np.add(*state.shot_weights(np.arange(n)))))
        if m.leak_rate_hz > 0:
            s = m.leak_spread_decades * np.log(10.0)
            state.leak_drift = m.leak_rate_hz * np.exp(s * rng.standard_normal(n) - 0.5 * s * s) * c_on
        return state

    def shot_weights(self, flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """ON and OFF shares of the shot-noise rate of pixels ``flat``: ``0.5 * nominal / actual`` threshold."""
        m = self.model
        return 0.5 * m.threshold / self.c_on[flat], 0.5 * m.threshold_off_nominal / self.c_off[flat]


def _lowpass(model: SensorModel, I: np.ndarray, dt) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients of the photoreceptor update over steps ``dt`` (s) ending at brightness ``I``.

    For an input ``L`` linear from ``L0`` to ``L1`` over the step, the first-order
    low-pass with time constant ``tau`` ends at exactly
    ``F1 = F0 + A (L0 - F0) + B (L1 - L0)`` with ``A = 1 - exp(-dt / tau)`` and
    ``B = 1 - A tau / dt``; both lie in [0, 1], so the update is stable for any ``dt``.
    """
    r = (2.0 * np.pi * dt) * model.cutoff_hz_at(I)
    A = -np.expm1(-r)
    return A, 1.0 - A / r


def _refractory(t_cross, t_ev, rank, pix, last_t_s, refractory_s):
    """Keep-mask of events passing the dead time; updates ``last_t_s`` in place.

    Events are numbered ``rank`` = 1, 2, ... in time order within each pixel ``pix``;
    an event is kept if its crossing ``t_cross`` comes at least ``refractory_s``
    after the pixel's last timestamp, which then becomes its own ``t_ev``.
    """
    keep = np.ones(t_cross.size, bool)
    for r in range(1, int(rank.max()) + 1):
        sel = np.flatnonzero(rank == r)
        ok = t_cross[sel] - last_t_s[pix[sel]] >= refractory_s
        keep[sel] = ok
        last_t_s[pix[sel[ok]]] = t_ev[sel[ok]]
    return keep


def _delayed(t_s: np.ndarray, rng, jitter_s: float) -> np.ndarray:
    """Timestamps (s) of crossings at ``t_s``: plus exponential readout delays of mean ``jitter_s``."""
    return t_s + rng.exponential(jitter_s, t_s.size) if jitter_s > 0 else t_s


def step_events(L0: np.ndarray, L1: np.ndarray, t0_s, t1_s, ref: np.ndarray,
                c_on: np.ndarray, c_off: np.ndarray, last_t_s: np.ndarray | None = None,
                refractory_s: float = 0.0, *, rng: np.random.Generator | None = None, jitter_s: float = 0.0):
    """Events of one render step for N pixels (updates ``ref`` and ``last_t_s`` in place).

    Parameters
    ----------
    L0, L1 : ndarray, shape (N,)
        Level (log units) the reference is compared with, at the start and the end of the step.
    t0_s, t1_s : float or ndarray, shape (N,)
        Step start and end times (s), shared or per pixel.
    ref, c_on, c_off : ndarray, shape (N,)
        Reference log level and the pixels' thresholds.
    last_t_s : ndarray, shape (N,), optional
        Timestamp (s) of each pixel's last event.
    refractory_s : float
        Dead time (s) after a timestamp; crossings inside it are dropped (the
        reference still moves past them).
    rng, jitter_s
        Generator and mean (s) of the exponential readout delay added to each crossing.

    Returns
    -------
    t_s, pix, p : ndarray, shape (M,)
        Event timestamps (crossing by linear interpolation inside the step, plus
        the delay), pixel index into the N inputs, polarity (1 ON, 0 OFF).
    """
    d = L1 - ref
    out_t, out_i, out_p = [], [], []
    for pol, sign, c in ((1, 1.0, c_on), (0, -1.0, c_off)):
        idx = np.flatnonzero(sign * d >= c)
        if idx.size == 0:
            continue
        n = np.floor(sign * d[idx] / c[idx]).astype(np.int64)
        rep = np.repeat(idx, n)
        start = np.cumsum(n) - n
        j = np.arange(rep.size) - np.repeat(start, n) + 1
        level = ref[rep] + sign * j * c[rep]
        slope = L1[rep] - L0[rep]
        frac = np.clip(np.divide(level - L0[rep], slope, out=np.ones_like(slope), where=slope != 0), 0.0, 1.0)
        t0 = t0_s[rep] if np.ndim(t0_s) else t0_s
        t1 = t1_s[rep] if np.ndim(t1_s) else t1_s
        t = t0 + frac * (t1 - t0)
        te = _delayed(t, rng, jitter_s)
        ref[idx] += sign * n * c[idx]
        if refractory_s > 0 and last_t_s is not None:
            # events of one pixel are consecutive and in time order: their rank is j
            keep = _refractory(t, te, j, rep, last_t_s, refractory_s)
            rep, te = rep[keep], te[keep]
        elif last_t_s is not None and rep.size:
            last_t_s[idx] = te[np.cumsum(n) - 1]
        out_t.append(te)
        out_i.append(rep)
        out_p.append(np.full(rep.size, pol, np.int8))
    if not out_t:
        return np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int8)
    return np.concatenate(out_t), np.concatenate(out_i), np.concatenate(out_p)


def _draw_shots(sensor: SensorState, flat, times, I, t0_s: float):
    """Shot-noise candidates of pixels ``flat`` over ``(t0_s, times[-1]]``, grouped by render step.

    Thinning of a Poisson process at the largest possible rate; a candidate at
    render step ``k`` is kept with the pixel's rate at that step's brightness
    ``I[k]``. Returns ``(bounds, j, t, p)``: the candidates of step ``k`` are
    ``bounds[k]:bounds[k + 1]`` of the local pixel index ``j``, crossing time ``t``
    (s) and polarity ``p``; None when there are none.
    """
    m, rng = sensor.model, sensor.rng
    if m.shot_noise_rate_hz <= 0 or flat.size == 0:
        return None
    span = times[-1] - t0_s
    r_max = m.shot_noise_rate_hz * sensor.shot_weight_max
    n = rng.poisson(r_max * flat.size * span)
    if n == 0:
        return None
    j = rng.integers(0, flat.size, n)
    t = t0_s + span * rng.random(n)
    k = np.minimum(np.searchsorted(times, t), len(times) - 1)
    w_on, w_off = sensor.shot_weights(flat[j])
    keep = rng.random(n) * r_max < m.shot_rate_hz_at(I[k, j]) * (w_on + w_off)
    p = (rng.random(n) * (w_on + w_off) < w_on).astype(np.int8)
    j, t, p, k = j[keep], t[keep], p[keep], k[keep]
    order = np.argsort(k, kind="stable")
    bounds = np.searchsorted(k[order], np.arange(len(times) + 1))
    return bounds, j[order], t[order], p[order]


def _advance(sensor: SensorState, flat: np.ndarray, times: np.ndarray, t0_s: float, t1_s: float,
             L: np.ndarray, I: np.ndarray, out: list) -> tuple[int, np.ndarray | None]:
    """Run pixels ``flat`` through render samples ``L`` / ``I`` (K, N) at ``times`` (K,).

    Each pixel starts from its latest sample (with a non-ideal model, all samples
    are at ``t0_s``: idle pixels are flushed first); ``t0_s`` is the chunk start and
    ``t1_s`` its end (stored as the pixels' sample time). Events go to ``out`` as
    ``(t_s, flat index, p)``. Returns the number of events and, with a bandwidth
    limit, the mask of pixels whose photoreceptor still lags its last sample.
    """
    m = sensor.model
    rng = sensor.rng
    refractory_s = m.refractory_us * 1e-6
    jitter_s = m.latency_jitter_us * 1e-6
    ref = sensor.ref[flat]
    c_on = sensor.c_on[flat]
    c_off = sensor.c_off[flat]
    last = sensor.last_t_s[flat]
    L_prev, t_prev = sensor.sample_L[flat], sensor.sample_t_s[flat]
    filtered = sensor.F is not None
    drift = None if sensor.leak_drift is None else sensor.leak_drift[flat]
    if filtered:
        F = sensor.F[flat]
        A, B = _lowpass(m, I, np.diff(times, prepend=t0_s)[:, None])  # every sample is at t0_s
    X_prev = F if filtered else L_prev
    if drift is not None:
        X_prev = X_prev + drift * t_prev
    shots = None if m.ideal else _draw_shots(sensor, flat, times, I, t0_s)
    count = 0
    for i in range(len(times)):
        if filtered:
            F = F + A[i] * (L_prev - F) + B[i] * (L[i] - L_prev)
            X = F
        else:
            X = L[i]
        if drift is not None:
            X = X + drift * times[i]
        et, ei, ep = step_events(X_prev, X, t_prev, times[i], ref, c_on, c_off, last, refractory_s,
                                 rng=rng, jitter_s=jitter_s)
        if et.size:
            out.append((et, flat[ei], ep))
            count += et.size
        if shots is not None and shots[0][i + 1] > shots[0][i]:
            b0, b1 = shots[0][i], shots[0][i + 1]
            sj, first = np.unique(shots[1][b0:b1], return_index=True)  # one per pixel and step
            st, sp = shots[2][b0:b1][first], shots[3][b0:b1][first]
            te = _delayed(st, rng, jitter_s)
            ok = st - last[sj] >= refractory_s if refractory_s > 0 else np.ones(st.size, bool)
            last[sj[ok]] = te[ok]
            ref[sj] = X[sj]  # the noise event resets the pixel to its current level
            if ok.any():
                out.append((te[ok], flat[sj[ok]], sp[ok]))
                count += int(ok.sum())
        X_prev, L_prev, t_prev = X, L[i], times[i]
    sensor.ref[flat] = ref
    sensor.last_t_s[flat] = last
    sensor.sample_L[flat] = L[-1]
    sensor.sample_t_s[flat] = t1_s
    if not filtered:
        return count, None
    sensor.F[flat] = F
    return count, np.abs(F - L[-1]) > SETTLE_TOL


def _jitter_factor(rng: np.random.Generator, jitter: float, n: int) -> np.ndarray:
    """Factors ``1 + jitter * N(0, 1)`` of ``n`` leak intervals, the normal clipped at ``LEAK_JITTER_CLIP``."""
    return np.maximum(1.0 + jitter * np.clip(rng.standard_normal(n), -LEAK_JITTER_CLIP, LEAK_JITTER_CLIP), 0.0)


def _flush_idle(sensor: SensorState, pix: np.ndarray, t1_s: float, out: list) -> int:
    """Leak and shot-noise events of static, settled pixels ``pix`` from their last sample to ``t1_s``.

    The level ``F + drift * t`` of such a pixel rises linearly, so its leak events
    are periodic (with jittered intervals) between resets; shot-noise events come
    at Poisson times and reset the pixel. Events go to ``out``; returns their number.
    """
    m, rng = sensor.model, sensor.rng
    pix = pix[sensor.sample_t_s[pix] < t1_s]
    if pix.size == 0:
        return 0
    t0 = sensor.sample_t_s[pix]
    sensor.sample_t_s[pix] = t1_s
    gap = t1_s - t0
    shots = np.zeros(pix.size, np.int64)
    if m.shot_noise_rate_hz > 0:
        w_on, w_off = sensor.shot_weights(pix)
        shots = rng.poisson(m.shot_rate_hz_at(np.exp(sensor.sample_L[pix]) - LOG_EPS) * (w_on + w_off) * gap)
    x = sensor.sample_L[pix] if sensor.F is None else sensor.F[pix]
    drift = np.zeros(pix.size) if sensor.leak_drift is None else sensor.leak_drift[pix]
    D0 = x + drift * t0 - sensor.ref[pix]  # level above the reference at t0
    c_on = sensor.c_on[pix]
    busy = shots > 0
    if sensor.leak_drift is not None:
        busy |= np.maximum(c_on - D0, 0.0) / drift * max(1.0 - LEAK_JITTER_CLIP * m.leak_jitter, 0.0) < gap
    # only pixels with an event in the gap change (their reference moves with the drift)
    pix, t0, gap, x, shots, drift, D0, c_on = (a[busy] for a in (pix, t0, gap, x, shots, drift, D0, c_on))
    if pix.size == 0:
        return 0
    M = pix.size
    # shot noise: Poisson events, each one a reset
    si = np.repeat(np.arange(M), shots)
    st = t0[si] + gap[si] * rng.random(si.size)
    sp = np.zeros(si.size, np.int8)
    if si.size:
        w_on, w_off = sensor.shot_weights(pix)
        sp = (rng.random(si.size) * (w_on + w_off)[si] < w_on[si]).astype(np.int8)
    # segments between resets: start time and level above the reference at the start
    seg_i = np.r_[np.arange(M), si]
    seg_a = np.r_[t0, st]
    seg_D = np.r_[D0, np.zeros(si.size)]
    order = np.lexsort((seg_a, seg_i))
    seg_i, seg_a, seg_D = seg_i[order], seg_a[order], seg_D[order]
    last_seg = np.r_[seg_i[1:] != seg_i[:-1], True]
    seg_b = np.where(last_seg, t1_s, np.r_[seg_a[1:], t1_s])
    g = drift[seg_i]
    D_end = seg_D + g * (seg_b - seg_a)
    li = np.zeros(0, np.int64)
    lt = np.zeros(0)
    if sensor.leak_drift is not None:
        period = c_on[seg_i] / g
        jit = m.leak_jitter
        first = np.maximum(c_on[seg_i] - seg_D, 0.0) / g  # time to the first crossing without jitter
        cur = seg_a + first * _jitter_factor(rng, jit, seg_i.size)
        alive = np.arange(seg_i.size)
        last_leak = np.full(seg_i.size, np.nan)
        parts_t, parts_i = [], []
        while alive.size:
            hit = cur < seg_b[alive]
            alive, cur = alive[hit], cur[hit]
            parts_t.append(cur)
            parts_i.append(seg_i[alive])
            last_leak[alive] = cur
            cur = cur + period[alive] * _jitter_factor(rng, jit, alive.size)
        lt, li = np.concatenate(parts_t), np.concatenate(parts_i)
        fired = ~np.isnan(last_leak)
        D_end[fired] = g[fired] * (seg_b[fired] - last_leak[fired])
    sensor.ref[pix[seg_i[last_seg]]] = (x + drift * t1_s)[seg_i[last_seg]] - D_end[last_seg]
    ev_i = np.r_[si, li]
    if ev_i.size == 0:
        return 0
    ev_t = np.r_[st, lt]
    ev_p = np.r_[sp, np.ones(li.size, np.int8)]
    order = np.lexsort((ev_t, ev_i))
    ev_i, ev_t, ev_p = ev_i[order], ev_t[order], ev_p[order]
    te = _delayed(ev_t, rng, m.latency_jitter_us * 1e-6)
    last = sensor.last_t_s[pix]
    if m.refractory_us > 0:
        starts = np.flatnonzero(np.r_[True, ev_i[1:] != ev_i[:-1]])
        rank = np.arange(ev_i.size) - np.repeat(starts, np.diff(np.r_[starts, ev_i.size])) + 1
        keep = _refractory(ev_t, te, rank, ev_i, last, m.refractory_us * 1e-6)
    else:
        keep = np.ones(ev_i.size, bool)
        np.maximum.at(last, ev_i, te)
    sensor.last_t_s[pix] = last
    out.append((te[keep], pix[ev_i[keep]], ev_p[keep]))
    return int(keep.sum())


def _warm_up(scene: Scene, sensor: SensorState, t_start_s: float, I0: np.ndarray, max_step_s: float,
             chunk_elems: int) -> None:
    """Bring the photoreceptors of moving pixels to steady state at ``t_start_s`` (no events).

    Filters render samples over the ``WARMUP_TAUS`` time constants (of the slowest
    tenth of the pixels objects cover at the start) before ``t_start_s``. A sample
    ``s`` before the start only matters to pixels whose time constant is of the
    order of ``s``, so the samples are ``WARMUP_STEP_PX`` of motion apart near the
    start and ``WARMUP_REL_STEP * s`` apart further back.
    """
    m = sensor.model
    cam = scene.camera
    w = cam.width
    if not scene.objects:
        return
    now = np.unique(np.concatenate([scene.footprint_pixels(o, t_start_s, t_start_s) for o in scene.objects]))
    if now.size == 0:
        return
    span = WARMUP_TAUS * float(np.quantile(m.tau_s_at(I0[now]), 0.9))
    t_w = t_start_s - span
    bg_all = scene.sensor_background()
    items, grids = [], {}
    for o in scene.objects:
        speed = o.max_speed_px_s(cam, t_start_s)
        fine = min(WARMUP_STEP_PX / speed, max_step_s) if speed > 0 else max_step_s
        back = [0.0]
        while back[-1] < span:
            back.append(back[-1] + max(fine, WARMUP_REL_STEP * back[-1]))
        times = t_start_s - np.minimum(back[::-1], span)
        grids[times.size] = times
        items.append((scene.footprint_pixels(o, t_w, t_start_s), times.size))
    for flat, n in disjoint_groups(items, w * cam.height):
        times = grids[n]
        u, v = (flat % w).astype(float), (flat // w).astype(float)
        rows = max(2, chunk_elems // max(flat.size, 1))
        F = L_prev = None
        for b in range(0, n, rows):
            tb = times[b:b + rows]
            I = scene.render(u, v, tb, bg=bg_all[flat])
            L = np.log(I + LOG_EPS)
            if F is None:  # the filter starts at its input
                F = L_prev = L[0]
                tb, I, L, t_before = tb[1:], I[1:], L[1:], tb[0]
            else:
                t_before = times[b - 1]
            A, B = _lowpass(m, I, np.diff(tb, prepend=t_before)[:, None])
            for i in range(len(L)):
                F = F + A[i] * (L_prev - F) + B[i] * (L[i] - L_prev)
                L_prev = L[i]
        sensor.F[flat] = F


def _settle(sensor: SensorState, active: list, lagging: list, t0_s: float, t1_s: float, out: list) -> int:
    """Filter the lagging photoreceptors of pixels no object covers over ``(t0_s, t1_s]``.

    Their input is their last sample; sub-steps of at most half the shortest time
    constant keep the linearly interpolated crossing times close to the
    exponential. Updates ``sensor.unsettled``; returns the number of events.
    """
    covered = np.zeros(sensor.c_on.size, bool)
    for flat in active:
        covered[flat] = True
    cand = sensor.unsettled[~covered[sensor.unsettled]]
    count = 0
    still = [np.zeros(0, np.int64)] + lagging
    if cand.size:
        m = sensor.model
        I = np.exp(sensor.sample_L[cand]) - LOG_EPS
        span = t1_s - t0_s
        n_sub = int(np.clip(np.ceil(span / (0.5 * float(m.tau_s_at(I).min()))), 1, 64))
        times = t0_s + span * np.arange(1, n_sub + 1) / n_sub
        L = np.broadcast_to(sensor.sample_L[cand], (n_sub, cand.size))
        c, lag = _advance(sensor, cand, times, t0_s, t1_s, L, np.broadcast_to(I, L.shape), out)
        count += c
        still.append(cand[lag])
    sensor.unsettled = np.concatenate(still)
    return count


def _n_before(out: list, t_s: float) -> int:
    """Number of events in ``out`` timestamped at or before ``t_s``."""
    return int(sum(np.count_nonzero(t <= t_s) for t, _, _ in out))


def simulate(scene: Scene, sensor: SensorState, t_start_s: float, t_end_s: float, *,
             n_events: int | None = None, step_px: float = 0.25, max_step_s: float = 1e-3,
             chunk_elems: int = 1 << 17, t_offset_us: int = 0, init: bool = True) -> np.ndarray:
    """Events of ``scene`` seen by ``sensor`` between ``t_start_s`` and ``t_end_s``.

    Time advances in chunks. Within a chunk every object gets its own render step
    (``step_px`` divided by its image speed); a pixel is rendered at the finest step
    of the objects whose swept footprint covers it, and pixels covered by none are
    static background and are not touched. Each pixel's first step in a chunk starts
    from its latest render sample, so pixels switch rates without losing changes.
    The pixel model is ``sensor.model`` (see :class:`SensorModel`).

    Parameters
    ----------
    n_events : int, optional
        Stop once at least this many events exist and return exactly the first
        ``n_events`` (by time).
    step_px : float
        Largest image motion (px) of any scene point per render step. With a capped
        bandwidth, steps may grow to ``COARSE_STEP_TAUS`` of the shortest time
        constant, as long as nothing moves more than ``COARSE_STEP_PX`` per step.
    max_step_s : float
        Longest render step (s), used when nothing moves fast.
    t_offset_us : int
        Added to every timestamp (µs): event time = ``t_offset_us + floor(t_s * 1e6)``.
    init : bool
        Start the sensor in front of the scene at ``t_start_s``: every pixel's
        reference at its level (with leak events, at a random point of its leak
        cycle), photoreceptors warmed up (otherwise continue from the sensor's state).

    Returns
    -------
    ndarray of EVENT_DTYPE sorted by ``t``.
    """
    cam = scene.camera
    w, h = cam.width, cam.height
    m = sensor.model
    bg_all = scene.sensor_background()
    if init:
        v, u = np.divmod(np.arange(w * h), w)
        I0 = scene.render(u.astype(float), v.astype(float), [t_start_s], bg=bg_all)[0]
        L = np.log(I0 + LOG_EPS)
        sensor.sample_L[:] = L
        sensor.sample_t_s[:] = t_start_s
        if sensor.F is not None:
            sensor.F[:] = L
            _warm_up(scene, sensor, t_start_s, I0, max_step_s, chunk_elems)
            sensor.unsettled = np.flatnonzero(np.abs(sensor.F - L) > SETTLE_TOL)
        sensor.ref[:] = L if sensor.F is None else sensor.F
        if sensor.leak_drift is not None:
            sensor.ref += sensor.leak_drift * t_start_s - sensor.rng.random(w * h) * sensor.c_on
    out = []
    count = 0
    t = float(t_start_s)
    n_fine = chunk_elems // 8  # pixels rendered per step; sets the chunk length
    while t < t_end_s:
        speeds = np.array([o.max_speed_px_s(cam, t) for o in scene.objects])
        dts = np.where(speeds > 0, step_px / np.maximum(speeds, 1e-12), max_step_s).clip(None, max_step_s)
        if m.tau_min_s is not None:
            # the photoreceptor cannot follow anything faster than its shortest time constant
            coarse = np.minimum(COARSE_STEP_TAUS * m.tau_min_s, COARSE_STEP_PX / np.maximum(speeds, 1e-12))
            dts = np.maximum(dts, coarse).clip(None, max_step_s)
        dt = float(dts.min()) if dts.size else max_step_s
        k = int(np.clip(chunk_elems // max(n_fine, 1), 4, 512))
        t1 = min(t_end_s, t + k * dt)
        span = t1 - t
        items = [(scene.footprint_pixels(o, t, t1), max(1, int(np.ceil(span / dto - 1e-9))))
                 for o, dto in zip(scene.objects, dts)]
        fine_total = 0
        active, lagging = [], []
        for flat, n_steps in disjoint_groups(items, w * h):
            fine_total = max(fine_total, flat.size * n_steps)
            times = t + span * np.arange(1, n_steps + 1) / n_steps
            if not m.ideal:
                count += _flush_idle(sensor, flat, t, out)
            I = scene.render((flat % w).astype(float), (flat // w).astype(float), times, bg=bg_all[flat])
            c, lag = _advance(sensor, flat, times, t, t1, np.log(I + LOG_EPS), I, out)
            count += c
            if lag is not None:
                active.append(flat)
                lagging.append(flat[lag])
        if sensor.F is not None:
            count += _settle(sensor, active, lagging, t, t1, out)
        n_fine = max(fine_total // max(k, 1), 1)
        t = t1
        if (n_events is not None and count >= n_events
                and (m.latency_jitter_us == 0 or _n_before(out, t) >= n_events)):
            break
    if not m.ideal:
        _flush_idle(sensor, np.arange(w * h), t, out)
    ev = _pack(out, w, t_offset_us)
    if n_events is not None:
        ev = ev[:n_events]
    return ev


def _pack(out: list, width: int, t_offset_us: int) -> np.ndarray:
    if not out:
        return np.zeros(0, EVENT_DTYPE)
    t = np.concatenate([e[0] for e in out])
    flat = np.concatenate([e[1] for e in out])
    ev = np.empty(t.size, EVENT_DTYPE)
    ev["t"] = t_offset_us + np.floor(t * 1e6 + 1e-6).astype(np.int64)
    ev["x"] = flat % width
    ev["y"] = flat // width
    ev["p"] = np.concatenate([e[2] for e in out])
    return ev[np.argsort(ev["t"], kind="stable")]


def noise_events(width: int, height: int, t0_us: int, t1_us: int, rng: np.random.Generator, *,
                 rate_hz_per_px: float = 0.1, hot_pixels: int = 0, hot_rate_hz: float = 2000.0,
                 hot_xy: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Background-activity noise and hot pixels over ``[t0_us, t1_us)``.

    Returns ``(events, hot_xy)``: events (EVENT_DTYPE, sorted) with uniform random
    pixels, times and polarities at ``rate_hz_per_px`` per pixel, plus ``hot_pixels``
    pixels (``hot_xy`` (n, 2) columns x, y; drawn if not given) firing at ``hot_rate_hz``.
    """
    span_s = max(t1_us - t0_us, 0) * 1e-6
    n = rng.poisson(rate_hz_per_px * width * height * span_s)
    t = rng.integers(t0_us, max(t1_us, t0_us + 1), n)
    x = rng.integers(0, width, n)
    y = rng.integers(0, height, n)
    p = rng.integers(0, 2, n)
    if hot_xy is None:
        hot_xy = np.column_stack([rng.integers(0, width, hot_pixels), rng.integers(0, height, hot_pixels)])
    hot_xy = np.asarray(hot_xy, np.int64).reshape(-1, 2)
    if len(hot_xy):
        nh = rng.poisson(hot_rate_hz * span_s, len(hot_xy))
        t = np.r_[t, rng.integers(t0_us, max(t1_us, t0_us + 1), nh.sum())]
        x = np.r_[x, np.repeat(hot_xy[:, 0], nh)]
        y = np.r_[y, np.repeat(hot_xy[:, 1], nh)]
        p = np.r_[p, rng.integers(0, 2, nh.sum())]
    ev = np.empty(t.size, EVENT_DTYPE)
    ev["t"], ev["x"], ev["y"], ev["p"] = t, x, y, p
    return ev[np.argsort(ev["t"], kind="stable")], hot_xy


def flicker_events(width: int, height: int, t0_us: int, t1_us: int, rng: np.random.Generator, *,
                   freq_hz: float = 100.0, depth: float = 0.05, box=None, threshold: float = 0.15,
                   mismatch_sigma: float = 0.03, min_threshold: float = 0.05,
                   latency_us: float = 50.0) -> np.ndarray:
    """Events of pixels lit by a flickering light (LED drivers, tubes) over ``[t0_us, t1_us)``.

    The light is ``1 + depth sin(2 pi freq_hz t)`` (100 Hz / 120 Hz on 50 Hz / 60 Hz mains), so the
    log brightness of every lit pixel swings by ``log((1 + depth) / (1 - depth))`` whatever its
    brightness (pixels well above the dark level). Each pixel has its own threshold
    (``threshold`` +- ``mismatch_sigma``, floored at ``min_threshold``) and a random reference
    level, and fires ON events on the rising half and OFF events on the falling half at the
    crossings of its level lattice, each delayed by an exponential latency of mean
    ``latency_us``. ``box`` ``(x0, y0, x1, y1)`` (px, exclusive ends) limits the lit area
    (default: the whole sensor).

    Returns
    -------
    ndarray of EVENT_DTYPE, sorted by time.
    """
    if not 0 < depth < 1:
        raise ValueError(f"flicker depth must be in (0, 1), got {depth}")
    if freq_hz <= 0:
        raise ValueError(f"flicker frequency must be positive, got {freq_hz}")
    x0, y0, x1, y1 = (0, 0, width, height) if box is None else map(int, box)
    yy, xx = np.mgrid[max(y0, 0):min(y1, height), max(x0, 0):min(x1, width)]
    xx, yy = xx.ravel(), yy.ravel()
    c = np.maximum(threshold + mismatch_sigma * rng.standard_normal(xx.size), min_threshold)
    ref = rng.uniform(0.0, 1.0, xx.size) * c
    lo, hi = np.log1p(-depth), np.log1p(depth)
    k0 = np.ceil((lo - ref) / c).astype(np.int64)
    n_lev = np.floor((hi - ref) / c).astype(np.int64) - k0 + 1  # lattice levels inside the swing
    fire = n_lev >= 2
    pix = np.repeat(np.flatnonzero(fire), n_lev[fire])
    j = np.arange(pix.size) - np.repeat(np.cumsum(n_lev[fire]) - n_lev[fire], n_lev[fire])
    level = ref[pix] + (k0[pix] + j) * c[pix]
    top = j == np.repeat(n_lev[fire] - 1, n_lev[fire])
    s = np.clip(np.expm1(level) / depth, -1.0, 1.0)
    period_us = 1e6 / freq_hz
    # ON at every level but the lowest on the way up, OFF at every level but the highest on the way down
    on = j > 0
    ph = np.r_[np.arcsin(s[on]), np.pi - np.arcsin(s[~top])]
    px = np.r_[pix[on], pix[~top]]
    pol = np.r_[np.ones(on.sum(), np.int8), np.zeros((~top).sum(), np.int8)]
    off_us = np.mod(ph / (2 * np.pi), 1.0) * period_us
    n_cyc = int(np.ceil((t1_us - t0_us) / period_us)) + 1
    cyc0 = np.floor(t0_us / period_us)
    t = ((cyc0 + np.arange(n_cyc))[:, None] * period_us + off_us[None, :]).ravel()
    t = t + rng.exponential(latency_us, t.size) if latency_us > 0 else t
    keep = (t >= t0_us) & (t < t1_us)
    ev = np.empty(int(keep.sum()), EVENT_DTYPE)
    ev["t"] = np.floor(t[keep]).astype(np.int64)
    ev["x"] = np.tile(xx[px], n_cyc)[keep]
    ev["y"] = np.tile(yy[px], n_cyc)[keep]
    ev["p"] = np.tile(pol, n_cyc)[keep]
    return ev[np.argsort(ev["t"], kind="stable")]


def merge(*batches: np.ndarray) -> np.ndarray:
    """Merge event batches into one array sorted by ``t`` (stable)."""
    ev = np.concatenate([np.asarray(b, EVENT_DTYPE) for b in batches]) if batches else np.zeros(0, EVENT_DTYPE)
    return ev[np.argsort(ev["t"], kind="stable")]
