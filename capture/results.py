"""Results per flight, in the terms coaches and sports scientists use.

:func:`window_table` gives every spin window its flight and its spin in the flight's own frame;
:func:`flight_table` sums the windows of each flight up into one row: spin rate in rpm with an
uncertainty, the axis, topspin / sidespin / gyro components, spin efficiency, the axis tilt as a
clock face, the share of windows trusted, the image speed and, with the camera's intrinsics and
the ball's size, the distance and the ball's 3D velocity (:func:`flight_velocity`). Flights
without a trusted window are listed with NaN spin (that is the yield), never left out.
:func:`format_flight_table` prints the table, :func:`write_csv` and :func:`write_parquet` export
either table with the units in the column names.

Flight frame (camera frame: X right, Y down, Z forward; see ``docs/conventions.md``):

* ``f``: the direction of flight, the ball's image velocity (the camera sees the flight side-on);
* ``u``: "up", the image's up direction (-Y) made perpendicular to ``f``; for a flight within
  20 deg of vertical in the image, the direction towards the camera (-Z) instead;
* spin vector ``w = axis * rps`` (right-hand rule), split into
  ``topspin = w . (f x u)`` (> 0 topspin: the top of the ball turns forward; < 0 backspin),
  ``sidespin = w . u`` (> 0: counter-clockwise seen from above) and ``gyro = w . f``
  (rifle spin, > 0: counter-clockwise seen from behind);
* efficiency ``sqrt(topspin^2 + sidespin^2) / |w|`` (the share of spin that bends the flight);
* tilt, seen from behind the ball: 12:00 pure backspin, 3:00 pure sidespin (> 0), 6:00 pure
  topspin, 9:00 pure sidespin (< 0).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from capture.events import Track

TRUST = 0.5
"""Least confidence of a trusted spin window."""


_VERTICAL_DEG = 20.0


def flight_frame(velocity_px_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flight direction ``f``, up ``u`` and topspin axis ``f x u`` (unit vectors, camera frame) of
    an image velocity ``(vx, vy)`` px/s (see the module docstring)."""
    v = np.array([float(velocity_px_s[0]), float(velocity_px_s[1]), 0.0])
    speed = np.linalg.norm(v)
    f = v / speed if speed > 0 else np.array([1.0, 0.0, 0.0])
    up = np.array([0.0, -1.0, 0.0])
    u = up - (up @ f) * f
    if np.linalg.norm(u) < np.sin(np.radians(_VERTICAL_DEG)):
        u = np.array([0.0, 0.0, -1.0])
    u = u / np.linalg.norm(u)
    return f, u, np.cross(f, u)


def spin_components(w_rps: np.ndarray, velocity_px_s) -> tuple[float, float, float]:
    """``(topspin, sidespin, gyro)`` in rev/s of spin vector ``w_rps`` (3,) for a flight with image
    velocity ``velocity_px_s``."""
    f, u, t = flight_frame(velocity_px_s)
    return float(w_rps @ t), float(w_rps @ u), float(w_rps @ f)


def tilt_clock(topspin: float, sidespin: float) -> str:
    """The axis tilt seen from behind the ball as a clock time ``"h:mm"`` (12:00 backspin)."""
    if not (np.isfinite(topspin) and np.isfinite(sidespin)) or (topspin == 0 and sidespin == 0):
        return "-"
    minutes = int(round(np.degrees(np.arctan2(sidespin, -topspin)) % 360.0 * 2.0)) % 720  # 0.5 deg/min
    h, m = divmod(minutes, 60)
    return f"{h or 12}:{m:02d}"


def _flight_of(track: Track, t_us: np.ndarray) -> np.ndarray:
    """Flight of each time: the flight whose rows span it, else of the nearest row (-1: no track)."""
    out = np.full(len(t_us), -1, np.int32)
    if len(track) == 0:
        return out
    best = np.full(len(t_us), np.inf)
    for fl in track.flight_ids():
        t = track.t_us[track.flight == fl]
        d = np.maximum(t[0] - t_us, 0) + np.maximum(t_us - t[-1], 0)  # 0 inside the span
        closer = d < best
        out[closer], best[closer] = int(fl), d[closer]
    return out


def window_table(track: Track, spin: dict) -> dict[str, np.ndarray]:
    """Per-window table: each spin window with its flight (the spin table's; where that is not known,
    the flight whose track rows span the window), rate in rpm and components.

    Columns: ``flight``, ``t_start_s``, ``t_end_s``, ``rps``, ``rpm``, ``axis_x``, ``axis_y``,
    ``axis_z``, ``topspin_rpm``, ``sidespin_rpm``, ``gyro_rpm``, ``efficiency``, ``tilt``,
    ``confidence``, ``trusted``, ``rps_sigma_pct`` (of which ``rps_lag_pct`` from the sensor's
    lag), ``axis_sigma_deg``, ``image_speed_px_s``.
    """
    n = len(spin["rps"])
    t0, t1 = np.asarray(spin["t_start_us"], np.int64), np.asarray(spin["t_end_us"], np.int64)
    rps = np.asarray(spin["rps"], np.float64)
    axis = np.asarray(spin["axis"], np.float64).reshape(n, 3)
    vel = np.asarray(spin["velocity_px_s"], np.float64).reshape(n, 2)
    comp = np.array([spin_components(axis[i] * rps[i], vel[i]) for i in range(n)]).reshape(n, 3)
    total = np.linalg.norm(comp, axis=1)
    eff = np.where(total > 0, np.hypot(comp[:, 0], comp[:, 1]) / np.where(total > 0, total, 1.0), np.nan)
    conf = np.asarray(spin["confidence"], np.float64)
    flight = np.array(spin["flight"], np.int32) if "flight" in spin else np.full(n, -1, np.int32)
    unknown = flight < 0
    flight[unknown] = _flight_of(track, ((t0 + t1) // 2)[unknown])
    return {
        "flight": flight, "t_start_s": t0 * 1e-6, "t_end_s": t1 * 1e-6,
        "rps": rps, "rpm": 60.0 * rps, "axis_x": axis[:, 0], "axis_y": axis[:, 1], "axis_z": axis[:, 2],
        "topspin_rpm": 60.0 * comp[:, 0], "sidespin_rpm": 60.0 * comp[:, 1], "gyro_rpm": 60.0 * comp[:, 2],
        "efficiency": eff, "tilt": np.array([tilt_clock(a, b) for a, b in comp[:, :2]], dtype=object),
        "confidence": conf, "trusted": conf >= TRUST,
        "rps_sigma_pct": np.asarray(spin["rps_sigma_pct"], np.float64),
        "rps_lag_pct": np.asarray(spin["rps_lag_pct"], np.float64) if "rps_lag_pct" in spin else np.full(n, np.nan),
        "axis_sigma_deg": np.asarray(spin["axis_sigma_deg"], np.float64),
        "image_speed_px_s": np.hypot(vel[:, 0], vel[:, 1]),
    }


def _spread_sigma(values: np.ndarray, window_sigmas: np.ndarray, shared: np.ndarray | None = None) -> float:
    """Standard error of the median of ``values``: from their spread, and never below the median
    of the windows' own sigmas over sqrt(n) (one window: its own sigma), nor below the median of
    ``shared``, the part of the windows' sigmas that they all share (a bias: no average shrinks it)."""
    n = len(values)
    own = float(np.nanmedian(window_sigmas)) if np.isfinite(window_sigmas).any() else np.nan
    common = float(np.nanmedian(shared)) if shared is not None and np.isfinite(shared).any() else np.nan
    if n == 1:
        return own
    spread = 1.2533 * float(np.std(values, ddof=1)) / np.sqrt(n)
    return float(np.nanmax([spread, own / np.sqrt(n), common]))


RADIUS_SIGMA_PX = 0.6
"""Uncertainty (1 sigma, px) of a tracked ball radius as a measure of the ball's silhouette: the
rim fit came out 0.5-0.8 px larger than the silhouette on simulated flights of 12-50 px radius."""
DIAMETER_SIGMA_REL = 0.015
"""Relative uncertainty (1 sigma) of a preset ball diameter: match balls vary by about 1.5 %."""


def flight_velocity(t_us, cx_px, cy_px, r_px, camera, ball_diameter_m: float, *,
                    radius_sigma_px: float = RADIUS_SIGMA_PX,
                    diameter_sigma_rel: float = DIAMETER_SIGMA_REL) -> dict[str, float]:
    """The ball's distance and 3D velocity over a flight from its track and its known size.

    Each track row puts the ball's centre on the ray through its image centre (``camera.rays``:
    lens distortion undone) at depth ``Z = f * D / (2 r)``: the apparent radius gives the distance.
    Each coordinate is fitted over the flight with a quadratic in time (gravity in any direction;
    a line for fewer than 5 rows) and the velocity is taken at the middle of the flight.

    Its sigma has two parts. The fit's residuals (radius noise moves ``Z`` most), propagated to
    the speed; and the scale, which moves distance and speed alike: a bias of the radius
    (``radius_sigma_px`` over the median radius) and of the ball's diameter (``diameter_sigma_rel``).

    Parameters
    ----------
    t_us, cx_px, cy_px, r_px : array_like, shape (N,)
        The flight's track rows: time (µs) and circle (px).
    camera : object with ``focal_px`` and ``rays(uv_px) -> (N, 3)``
        The event camera (:class:`calib.intrinsics.Intrinsics`).
    ball_diameter_m : float
    radius_sigma_px, diameter_sigma_rel : float
        The scale's uncertainties (1 sigma): px, and relative.

    Returns
    -------
    dict
        ``distance_m`` (from the camera to the ball's centre at mid-flight), ``distance_sigma_m``,
        ``velocity_m_s`` (3, camera frame), ``speed_m_s``, ``speed_sigma_m_s`` (1 sigma; NaN with
        fewer than 3 rows), ``speed_los_m_s`` (along the line of sight, > 0 away from the camera)
        and ``speed_across_m_s`` (across it); NaN where not measurable (fewer than 2 rows).
    """
    nan = float("nan")
    out = {"distance_m": nan, "distance_sigma_m": nan, "velocity_m_s": np.full(3, nan), "speed_m_s": nan,
           "speed_sigma_m_s": nan, "speed_los_m_s": nan, "speed_across_m_s": nan}
    t = (np.asarray(t_us, np.float64) - np.mean(t_us)) * 1e-6
    r = np.asarray(r_px, np.float64)
    ok = r > 0
    if ok.sum() < 2 or np.ptp(t[ok]) <= 0:
        return out
    rays = np.asarray(camera.rays(np.column_stack([cx_px, cy_px])[ok]), np.float64)
    t = t[ok]
    p = rays * (camera.focal_px * 0.5 * ball_diameter_m / r[ok])[:, None]  # (n, 3) m
    a = np.vander(t, 3 if len(t) >= 5 else 2, increasing=True)  # 1, t, (t^2)
    coef, _, rank, _ = np.linalg.lstsq(a, p, rcond=None)
    if rank < a.shape[1]:
        return out
    position, velocity = coef[0], coef[1]
    dof = len(t) - a.shape[1]
    speed = float(np.linalg.norm(velocity))
    sigma = nan
    if dof > 0:
        var_v = np.sum((p - a @ coef) ** 2, axis=0) / dof * np.linalg.inv(a.T @ a)[1, 1]  # per coordinate
        sigma = float(np.sqrt(np.sum((velocity / speed) ** 2 * var_v))) if speed > 0 else float(np.sqrt(var_v.max()))
    distance = float(np.linalg.norm(position))
    los = float(velocity @ position / distance)
    scale = float(np.hypot(radius_sigma_px / np.median(r[ok]), diameter_sigma_rel))
    out.update(distance_m=distance, distance_sigma_m=distance * scale, velocity_m_s=velocity, speed_m_s=speed,
               speed_sigma_m_s=float(np.hypot(sigma, speed * scale)), speed_los_m_s=los,
               speed_across_m_s=float(np.sqrt(max(speed ** 2 - los ** 2, 0.0))))
    return out


FOLDS_MAX = 6
"""Most repeats per turn a texture may show about its axis (a soccer ball's five-fold symmetry
gave five on the tuning flights)."""
FOLD_TOLERANCE = 0.07
"""A fold is the one whose rate lies within this share of the windows' (folds 5 and 6 lie 20 % apart)."""
PERIOD_SIGMA_REPEATS_PCT = 6.0
"""1-sigma uncertainty of a period's rate, % times the repeats it is measured over. On tuning
flights (640x480, 0.35 s, 10–150 rps, radius 20–40 px, realistic sensor, 41 periods found; a probe
before ``bench/spin_bench.py --flights``) the error times the repeats had a median of 0.13 and a
largest value of 3.5; smaller balls (18 px) falling on a steep arc across a 320x240 sensor came out
up to 1.2 % fast over 9 repeats (11), where the same ball flying straight, or still, gave the
period exactly [cause not found: the arc's acceleration and the sensor's lag are suspected]."""
PERIOD_SIGMA_FLOOR_PCT = 0.05
"""... and at least this. Both count turns, not repeats, where the image repeats more than once a turn (a
fold above 1: :func:`period_sigma_pct`): such a repeat is a near-symmetry of the texture, and its lag a little
off. On the bench's tracked flights of seeds 1-10 (``bench/spin_bench.py --flights``' cases, 240 periods),
the 225 at one repeat a turn all lay within 2 sigma counted in repeats, but 2 of the 15 at folds 2-5 did not
(a baseball at 10 rps, fold 2, 2.9 % fast at 3.6 sigma; a soccer ball at 150 rps, fold 5, 0.26 % at 5.2);
counted in turns, all 15 do (1.8 and 1.0 sigma)."""


def period_folds(period_s: float) -> np.ndarray:
    """The rates (rev/s) a ball whose image repeats every ``period_s`` (s) may turn at: one turn per
    1 to :data:`FOLDS_MAX` repeats, fastest first."""
    return 1.0 / (period_s * np.arange(1, FOLDS_MAX + 1))


def period_rate(period_s: float, span_s: float, window_rps) -> tuple[float, float] | None:
    """The spin rate (rev/s) and its 1-sigma uncertainty (%) of a flight whose image repeats every
    ``period_s`` (s) over ``span_s`` (s): the fold (:func:`period_folds`) within
    :data:`FOLD_TOLERANCE` of ``window_rps`` (a median rate of the flight's windows, rev/s; folds lie
    at least 20 % apart, so at most one does), or None. The uncertainty is the period's alone: a
    wrong fold, where the windows mislead, is off by a whole factor."""
    if not (np.isfinite(window_rps) and window_rps > 0 and period_s > 0):
        return None
    rates = period_folds(period_s)
    near = np.flatnonzero(np.abs(rates / window_rps - 1.0) <= FOLD_TOLERANCE)
    if not len(near):
        return None
    return float(rates[near[0]]), period_sigma_pct(period_s, span_s, int(near[0]) + 1)


def period_sigma_pct(period_s: float, span_s: float, fold: int = 1) -> float:
    """1-sigma uncertainty (%) of a rate from an image period ``period_s`` (s) measured over ``span_s`` (s),
    the image repeating ``fold`` times a turn: :data:`PERIOD_SIGMA_REPEATS_PCT` over the number of repeats,
    at least :data:`PERIOD_SIGMA_FLOOR_PCT`, times ``fold`` (a repeat within a turn holds only as well as the
    turn)."""
    return fold * max(PERIOD_SIGMA_FLOOR_PCT, PERIOD_SIGMA_REPEATS_PCT * period_s / span_s)


PERIOD_CONTRADICTS = 0.05
"""Trusted windows whose median rate lies farther than this share from every rate a flight's image
period allows (:func:`period_folds`) are not trusted (the 5 % a trusted spin stands for). On the
tuning flights of ``bench/spin_bench.py --flights`` two flights, each on one trusted window of 18,
were 7 % and 10 % off, their period right; the right ones lay within 2.8 % of it."""


def flight_table(track: Track, spin: dict, *, camera=None, ball_diameter_m: float | None = None,
                 ball: str | None = None, periods: dict | None = None,
                 flight_spins: dict | None = None) -> dict[str, np.ndarray]:
    """One row per flight of ``track`` from the spin windows of ``spin`` (:data:`SPIN_COLUMNS`).

    Spin is the median of the flight's trusted windows (confidence >= :data:`TRUST`), its sigma
    the standard error from their spread (at least the windows' own sigma over sqrt(n)); the axis
    is their mean, the components are those of the mean spin vector in the flight frame of the
    flight's median image velocity. ``camera`` (the event camera's intrinsics) and
    ``ball_diameter_m`` give the distance and the ball's 3D velocity (:func:`flight_velocity`);
    ``ball`` names the ball (a key of :data:`capture.events.BALL_DIAMETER_M`, or None).

    Columns: ``flight``, ``ball``, ``t_start_s``, ``t_end_s``, ``duration_ms``, ``n_windows``,
    ``n_trusted``, ``trusted_share``, ``rpm``, ``rpm_sigma``, ``rps``, ``axis_x``, ``axis_y``,
    ``axis_z``, ``axis_sigma_deg``, ``topspin_rpm``, ``sidespin_rpm``, ``gyro_rpm``, ``efficiency``,
    ``tilt``, ``image_speed_px_s``, ``radius_px``, ``distance_m``, ``distance_sigma_m``, ``speed_m_s`` (3D),
    ``speed_sigma_m_s``, ``speed_km_h``, ``speed_los_m_s`` (along the line of sight, > 0 away),
    ``speed_across_m_s``, ``period_rpm``, ``period_rpm_sigma``, ``period_fold_from``, ``period_contradicts``,
    ``spin_from``.

    ``periods`` (``{flight: (period_s, peak, span_s) or None}``, as the analysis stores them:
    :func:`capture.pipeline.replay.flight_analysis`) gives each flight's rate from the period of its
    image, for any texture (``period_rpm``, ``period_rpm_sigma``; NaN where no repeat was found, or
    where the windows' median rate, the trusted ones' where they stand, singles out no fold of it:
    :func:`period_rate`). It does not give the axis (``flight_spins`` does), and needs at least one window. Where the
    trusted windows' median rate lies more than :data:`PERIOD_CONTRADICTS` from every rate the
    period allows, the flight's spin is not trusted (``period_contradicts``; its spin columns NaN).

    ``flight_spins`` (``{flight: spin.flight.FlightSpin or its stored dict (capture.pipeline.replay.spin_attrs)
    or None}``) gives a flight's spin from all its events at the period's speed: where its windows give no
    trusted spin, a trusted whole-flight spin fills the spin columns (its rate, axis and their sigmas).
    ``spin_from`` says where they come from: ``"windows"``, ``"flight"`` or ``"-"``. Where the windows
    single out no fold of the period, a whole-flight spin whose rate stands (``rate_trusted``: its map tells
    its fold from the others, whether or not its axis is trusted) gives the fold: a slow ball's few turns,
    whose axis is not trusted, still give its rate. ``period_fold_from`` says which: ``"windows"``,
    ``"flight"`` or ``"-"`` (no period rate).
    """
    win = window_table(track, spin)
    rows = []
    nan = float("nan")
    for fl in track.flight_ids():
        sel = track.flight == fl
        t = track.t_us[sel]
        vx, vy, r = np.median(track.vx[sel]), np.median(track.vy[sel]), float(np.median(track.r[sel]))
        mine = win["flight"] == fl
        ok = mine & win["trusted"]
        row = {"flight": int(fl), "ball": ball or "-", "t_start_s": t[0] * 1e-6, "t_end_s": t[-1] * 1e-6,
               "duration_ms": (t[-1] - t[0]) * 1e-3, "n_windows": int(mine.sum()), "n_trusted": int(ok.sum()),
               "trusted_share": float(ok.sum() / mine.sum()) if mine.any() else 0.0,
               "image_speed_px_s": float(np.hypot(vx, vy)), "radius_px": r}
        row.update(rpm=nan, rpm_sigma=nan, rps=nan, axis_x=nan, axis_y=nan, axis_z=nan, axis_sigma_deg=nan,
                   topspin_rpm=nan, sidespin_rpm=nan, gyro_rpm=nan, efficiency=nan, tilt="-",
                   period_rpm=nan, period_rpm_sigma=nan)
        found = (periods or {}).get(int(fl))
        trusted_rps = float(np.median(win["rps"][ok])) if ok.any() else nan
        # a spin at a rate the image's period does not allow is not trusted, whatever its windows' confidence
        contradicted = found is not None and ok.any() and bool(
            np.abs(period_folds(found[0]) / trusted_rps - 1.0).min() > PERIOD_CONTRADICTS)
        row["period_contradicts"] = contradicted
        # the fold: the trusted windows' where they stand, else all the flight's windows' (their rates
        # are mostly right where a sparse ball's axes are not)
        by_period = None if found is None or not mine.any() else period_rate(
            found[0], found[2], float(np.median(win["rps"][mine])) if contradicted or not ok.any() else trusted_rps)
        stored_whole = (flight_spins or {}).get(int(fl))
        fold = _flight_fold(stored_whole)
        row["period_fold_from"] = "windows" if by_period is not None else "-"
        if by_period is None and found is not None and fold is not None:
            # no window singles out the period's fold: the whole flight's map does, where it tells its fold apart
            by_period = float(period_folds(found[0])[fold - 1]), period_sigma_pct(found[0], found[2], fold)
            row["period_fold_from"] = "flight"
        if by_period is not None:
            row.update(period_rpm=60.0 * by_period[0], period_rpm_sigma=60.0 * by_period[0] * by_period[1] / 100.0)
        whole = _trusted_flight_spin(stored_whole)
        row["spin_from"] = "windows" if ok.any() and not contradicted else "flight" if whole else "-"
        if row["spin_from"] == "flight":
            axis, rate = whole
            top, side, gyro = spin_components(axis * rate["rps"], (vx, vy))
            row.update(rps=rate["rps"], rpm=60.0 * rate["rps"], rpm_sigma=60.0 * rate["rps"] * rate["rps_sigma_pct"] / 100.0,
                       axis_x=float(axis[0]), axis_y=float(axis[1]), axis_z=float(axis[2]),
                       axis_sigma_deg=rate["axis_sigma_deg"], topspin_rpm=60.0 * top, sidespin_rpm=60.0 * side,
                       gyro_rpm=60.0 * gyro, efficiency=float(np.hypot(top, side) / rate["rps"]),
                       tilt=tilt_clock(top, side))
        if row["spin_from"] == "windows":
            rps = win["rps"][ok]
            axes = np.column_stack([win["axis_x"][ok], win["axis_y"][ok], win["axis_z"][ok]])
            mean_axis = axes.mean(axis=0)
            mean_axis /= np.linalg.norm(mean_axis)
            ang = np.degrees(np.arccos(np.clip(axes @ mean_axis, -1.0, 1.0)))
            rate = float(np.median(rps))
            top, side, gyro = spin_components(mean_axis * rate, (vx, vy))
            row.update(rps=rate, rpm=60.0 * rate,
                       rpm_sigma=60.0 * _spread_sigma(rps, win["rps_sigma_pct"][ok] / 100.0 * rps,
                                                      win["rps_lag_pct"][ok] / 100.0 * rps),
                       axis_x=float(mean_axis[0]), axis_y=float(mean_axis[1]), axis_z=float(mean_axis[2]),
                       axis_sigma_deg=_spread_sigma(ang, win["axis_sigma_deg"][ok]) if len(ang) > 1
                       else float(win["axis_sigma_deg"][ok][0]),
                       topspin_rpm=60.0 * top, sidespin_rpm=60.0 * side, gyro_rpm=60.0 * gyro,
                       efficiency=float(np.hypot(top, side) / rate) if rate > 0 else nan,
                       tilt=tilt_clock(top, side))
        motion = {"distance_m": nan, "distance_sigma_m": nan, "speed_m_s": nan, "speed_sigma_m_s": nan,
                  "speed_los_m_s": nan, "speed_across_m_s": nan}
        if camera is not None and ball_diameter_m:
            found = flight_velocity(t, track.cx[sel], track.cy[sel], track.r[sel], camera, ball_diameter_m)
            motion = {k: found[k] for k in motion}
        row.update(motion, speed_km_h=3.6 * motion["speed_m_s"])
        rows.append(row)
    names = ["flight", "ball", "t_start_s", "t_end_s", "duration_ms", "n_windows", "n_trusted", "trusted_share",
             "rpm", "rpm_sigma", "rps", "axis_x", "axis_y", "axis_z", "axis_sigma_deg", "topspin_rpm",
             "sidespin_rpm", "gyro_rpm", "efficiency", "tilt", "image_speed_px_s", "radius_px", "distance_m",
             "distance_sigma_m", "speed_m_s", "speed_sigma_m_s", "speed_km_h", "speed_los_m_s", "speed_across_m_s",
             "period_rpm", "period_rpm_sigma", "period_fold_from", "period_contradicts", "spin_from"]
    return {k: np.array([row[k] for row in rows], dtype=object if k in ("tilt", "ball", "spin_from", "period_fold_from") else None)
            for k in names}


def _whole_flight_field(found):
    """``get(key, default=None)`` for a whole-flight spin given as a ``spin.flight.FlightSpin`` or as its
    stored dict (:func:`capture.pipeline.replay.spin_attrs`)."""
    return found.get if isinstance(found, dict) else lambda k, d=None: getattr(found, k, d)


def _flight_fold(found) -> int | None:
    """The fold (repeats of the image per turn) of a whole-flight spin (a ``spin.flight.FlightSpin`` or its
    stored dict) whose rate stands (``rate_trusted``; in a dict stored before that was: ``trusted``), or None."""
    if found is None:
        return None
    get = _whole_flight_field(found)
    return int(get("fold")) if get("rate_trusted", get("trusted")) else None


def _trusted_flight_spin(found) -> tuple[np.ndarray, dict] | None:
    """``(axis (3,), {rps, rps_sigma_pct, axis_sigma_deg})`` of a trusted whole-flight spin (a
    ``spin.flight.FlightSpin`` or its stored dict), or None."""
    if found is None:
        return None
    get = _whole_flight_field(found)
    if not get("trusted"):
        return None
    return (np.asarray(get("axis"), np.float64),
            {"rps": float(get("omega_rad_s")) / (2.0 * np.pi), "rps_sigma_pct": float(get("rps_sigma_pct")),
             "axis_sigma_deg": float(get("axis_sigma_deg"))})


def format_flight_table(table: dict) -> str:
    """The flight table as aligned text, one line per flight, with a yield line."""
    n = len(table["flight"])
    if n == 0:
        return "no flight found"
    speed = np.isfinite(np.asarray(table["speed_m_s"], float)).any()
    period = np.isfinite(np.asarray(table.get("period_rpm", [np.nan]), float)).any()
    balls = [b for b in table.get("ball", ()) if b != "-"]
    width = max([4, *map(len, balls)])
    head = ((f"{'ball':<{width}} " if balls else "")
            + f"{'flight':>6} {'start s':>8} {'ms':>6} {'trusted':>8} {'rpm':>13} {'topspin':>8} {'sidespin':>8} "
            f"{'gyro':>7} {'eff':>5} {'tilt':>6} {'px/s':>7}" + (f" {'m':>5} {'km/h':>12}" if speed else "")
            + (f" {'period rpm':>13}" if period else ""))
    lines = [head]
    for i in range(n):
        whole = table.get("spin_from", ["-"] * n)[i] == "flight"
        trusted = f"{'*' if whole else ''}{table['n_trusted'][i]}/{table['n_windows'][i]}"
        if np.isfinite(table["rpm"][i]):
            # whole rpm as integers: a float rounding to zero would print "-0"
            topspin, sidespin, gyro = (round(float(table[k][i])) for k in ("topspin_rpm", "sidespin_rpm", "gyro_rpm"))
            spin = (f"{table['rpm'][i]:>6.0f} ± {table['rpm_sigma'][i]:<4.0f} {topspin:>8d} "
                    f"{sidespin:>8d} {gyro:>7d} "
                    f"{100 * table['efficiency'][i]:>4.0f}% {table['tilt'][i]:>6}")
        else:
            rate_only = np.isfinite(table.get("period_rpm", [np.nan] * n)[i])
            why = ("contradicted by the period" if table.get("period_contradicts", [False] * n)[i]
                   else "no trusted axis: rate from the period" if rate_only else "no trusted estimate")
            spin = f"{why:>51}"
        line = ((f"{table['ball'][i]:<{width}} " if balls else "")
                + f"{table['flight'][i]:>6} {table['t_start_s'][i]:>8.3f} {table['duration_ms'][i]:>6.0f} "
                f"{trusted:>8} {spin} {table['image_speed_px_s'][i]:>7.0f}")
        if speed:
            kmh = f"{table['speed_km_h'][i]:.1f} ± {3.6 * table['speed_sigma_m_s'][i]:.1f}"
            line += f" {table['distance_m'][i]:>5.1f} {kmh:>12}"
        if period:
            p_rpm, p_sigma = table["period_rpm"][i], table["period_rpm_sigma"][i]
            whole_fold = table.get("period_fold_from", ["-"] * n)[i] == "flight"
            by_period = f"{'*' if whole_fold else ''}{p_rpm:.0f} ± {p_sigma:.0f}" if np.isfinite(p_rpm) else "-"
            line += f" {by_period:>13}"
        lines.append(line)
    ok = int(np.isfinite(np.asarray(table["rpm"], float)).sum())
    n_period = int(np.isfinite(np.asarray(table.get("period_rpm", []), float)).sum())
    n_whole = sum(f == "flight" for f in table.get("spin_from", ()))
    n_fold = sum(f == "flight" for f in table.get("period_fold_from", ()))
    lines.append(f"yield: {ok} of {n} flight(s) with a trusted spin"
                 + (f" ({n_whole} marked *: from all the flight's events at the period's speed, where its windows give none)"
                    if n_whole else "")
                 + (f", {n_period} with a rate from the image's period" if period else "")
                 + (f" ({n_fold} marked *: its turn from all the flight's events, where its windows give none)"
                    if n_fold else "")
                 + " (rpm = 60 x rps; topspin, sidespin, gyro in rpm; "
                 "tilt seen from behind, 12:00 backspin" + ("; m: distance, km/h: 3D speed ± 1 sigma" if speed else "")
                 + ("; period rpm: how often the ball's image repeats, ± 1 sigma" if period else "") + ")")
    return "\n".join(lines)


def write_csv(table: dict, path) -> Path:
    """Write a table (columns of equal length) as CSV with a header row; returns the path."""
    path = Path(path)
    names = list(table)
    n = len(table[names[0]]) if names else 0
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(names)
        for i in range(n):
            w.writerow([_cell(table[k][i]) for k in names])
    return path


def write_parquet(table: dict, path) -> Path:
    """Write a table (columns of equal length) as Parquet (pyarrow); returns the path."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    path = Path(path)
    cols = {k: (np.asarray(v, dtype=str) if np.asarray(v).dtype == object else np.asarray(v)) for k, v in table.items()}
    pq.write_table(pa.table(cols), path)
    return path


def _cell(v):
    if isinstance(v, (bool, np.bool_)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return "" if not np.isfinite(v) else repr(float(v))
    if isinstance(v, (np.integer,)):
        return int(v)
    return v


def stored_ball(session) -> tuple[str | None, float | None]:
    """The ball ``(type, diameter_m)`` recorded with a session (attrs ``ball``, written by
    ``--ball/--ball-diameter`` of ``capture.run``, ``capture.replay`` and ``capture.ingest raw``);
    None for what it does not say."""
    ball = session.attrs.get("ball")
    if not isinstance(ball, dict):
        return None, None
    d, kind = ball.get("diameter_m"), ball.get("type")
    diameter = float(d) if isinstance(d, (int, float)) and not isinstance(d, bool) and d > 0 else None
    return (kind if isinstance(kind, str) else None), diameter


def session_results(session, *, ball_diameter_m: float | None = None,
                    ball_type: str | None = None) -> tuple[dict, dict]:
    """``(flights, windows)`` tables of an analysed session (see :mod:`capture.results`).

    Parameters
    ----------
    session : path or capture.session.Session
        The session's directory, or the session already open.
    ball_diameter_m : float, optional
        The ball's diameter, m, for the distance and speed columns (with the event camera's
        calibration). Default: the ball recorded with the session (:func:`stored_ball`), if any.
    ball_type : str, optional
        The ball's name for the ``ball`` column, with ``ball_diameter_m``.

    Raises
    ------
    ValueError
        The session holds no track (it was not analysed yet).
    """
    from calib.store import event_camera
    from capture.session import Session, open_session

    s = session if isinstance(session, Session) else open_session(session)
    track = Track.from_columns(s.track())
    if len(track) == 0 and "track" not in s.root:
        raise ValueError(f"{s.path}: not analysed yet (no ball track); run: python -m capture.replay {s.path}")
    spin_columns = s.spin()
    if ball_diameter_m is None:
        ball_type, ball_diameter_m = stored_ball(s)
    camera = event_camera(s) if ball_diameter_m else None
    periods = {int(k): v for k, v in (s.attrs.get("flight_periods") or {}).items()}
    spins = {int(k): v for k, v in (s.attrs.get("flight_spins") or {}).items()}
    flights = flight_table(track, spin_columns, camera=camera, ball_diameter_m=ball_diameter_m, ball=ball_type,
                           periods=periods, flight_spins=spins)
    return flights, window_table(track, spin_columns)
