"""Ball flights across the sensor: events, optional frames and sync triggers, ground truth.

:func:`flight` simulates one ballistic flight (textured background, noise, hot
pixels, distractors, optional GoPro-like frames and sync-box triggers) and returns
a :class:`Recording`; :func:`rally` is the quick preset for the built-in demo.
"""

from __future__ import annotations

import numpy as np

from capture.events import TRIGGER_DTYPE, make_triggers
from .balls import BALL_RADIUS_M, make_ball
from .esim import (SensorModel, SensorState, flicker_events, get_sensor_model, merge, noise_events, sensor_truth,
                   simulate)
from .frames import SyncBox, render_frames
from .recording import Recording
from .rotation import random_rotation, unit
from .scene import Arm, Camera, Player, Racket, Scene, court_background

G_M_S2 = 9.81


def _default_path(width, height, radius_px, duration_s, g, rng):
    """Entry at the left edge, exit at the right edge, apex near the middle (px, px/s)."""
    y0 = rng.uniform(0.35, 0.6) * height
    x0 = -radius_px
    vx = (width + 2 * radius_px) / duration_s
    vy = -0.5 * g * duration_s * rng.uniform(0.8, 1.2)
    return (x0, y0), (vx, vy)


def flight(texture: str = "volleyball", rps: float = 8.0, axis=(0.0, 0.0, 1.0), radius_px: float = 35.0,
           width: int = 1280, height: int = 720, duration_s: float = 0.35, *, start_px=None,
           velocity_px_s=None, gravity_px_s2: float | None = None, background: str = "court",
           noise_rate_hz: float = 0.1, hot_pixels: int = 5, hot_rate_hz: float = 2000.0,
           distractors=("player",), fps: float | None = None, exposure_s: float | None = None,
           frame_size=None, frame_to_event=None, frame_noise_dn: float = 2.0,
           frame_clock_offset_s: float = 0.0, frame_clock_drift_ppm: float = 0.0,
           sync: SyncBox | bool | None = None, sensor: str | SensorModel = "ideal", threshold: float | None = None,
           mismatch_sigma: float | None = None, refractory_us: float | None = None, step_px: float = 0.25,
           projection: str = "orthographic",
           focal_px: float = 1000.0, depth_velocity_m_s: float = 0.0, flicker_hz: float | None = None,
           flicker_depth: float = 0.1, flicker_box=None, n_events: int | None = None, t0_us: int = 0,
           track_dt_us: int = 1000, hits=(), seed: int = 0) -> Recording:
    """Simulate one ball flight across the sensor.

    Parameters
    ----------
    texture, rps, axis, radius_px
        Ball (see :func:`sim.spinning_ball`); spin constant through the flight.
    width, height : int
        Event sensor size (px), e.g. 1280x720 (IMX636) or 640x480.
    duration_s : float
        Simulated time (s) from ``t0_us``.
    start_px, velocity_px_s : (float, float), optional
        Ball centre (px) and velocity (px/s) at ``t0_us``; default: enter at the
        left edge, leave at the right edge at ``duration_s`` on an arc.
    gravity_px_s2 : float, optional
        Image-down acceleration (px/s^2); default 9.81 m/s^2 at the scale set by the
        ball's physical radius and ``radius_px``.
    background : {"court", "plain"}
    noise_rate_hz : float
        Background-activity noise per pixel (Hz); ``hot_pixels`` pixels fire at ``hot_rate_hz``.
    distractors : sequence of {"player", "ball", "arm", "racket", "paddle"}
        A walking player-like blob, a second (soccer) ball crossing the view, an arm
        (0.6 m by 9 cm at the ball's scale) swinging past the ball's path at mid-flight, its
        hand passing a few pixels from the ball, and/or such an arm holding a tennis racket or a
        table-tennis bat whose head passes a few pixels from the ball (:class:`sim.scene.Racket`).
    fps : float, optional
        Frame camera rate (60/120/240/480 ...); None: no frames.
    exposure_s : float or callable, optional
        Exposure per frame, s (default half the frame period); or a function of the event-clock
        time (s, array) giving each frame's exposure: auto-exposure. Frames are read at a fixed
        cadence, so exposures end on it and a shorter one starts later (``truth["frames"]
        ["exposure_s"]`` is then one per frame).
    frame_size : (int, int), optional
        Frame (width, height) (default: the sensor size).
    frame_to_event : (3, 3), optional
        Homography from frame pixels to event pixels (default identity).
    frame_clock_offset_s, frame_clock_drift_ppm : float
        The frame camera's own clock: ``t_frame_s = offset + (t_event_s) (1 + drift)``;
        stored per frame in ``truth["frames"]["t_frame_clock_s"]``.
    sync : SyncBox or True, optional
        Sync box: trigger edges (channel 0) in ``triggers`` and an LED in the frames.
    sensor : str or SensorModel
        Pixel model: a :data:`sim.esim.SENSOR_PRESETS` name (``"ideal"``, ``"realistic"``) or a
        :class:`sim.esim.SensorModel`. Its leak and shot noise come on top of ``noise_rate_hz``.
    threshold, mismatch_sigma, refractory_us : float, optional
        Override the sensor model's fields (log units, log units, µs).
    step_px : float
        Largest image motion per render step (px; see :func:`sim.esim.simulate`).
    depth_velocity_m_s : float
        Speed of the ball along the optical axis (m/s, + away from the camera), pinhole only: the
        ball looms (negative) or recedes (positive) and its image radius changes.
    flicker_hz, flicker_depth, flicker_box
        A light flickering at ``flicker_hz`` (100 / 120 Hz) by ``flicker_depth`` over the area
        ``flicker_box`` (default the whole sensor): see :func:`sim.esim.flicker_events`.
    n_events : int, optional
        Stop the ball simulation at this many events.
    track_dt_us : int
        Spacing (µs) of the ground-truth circle samples (the last lies at the recording's end).
    hits : sequence of dict
        Hits or bounces, each ``{"t_s", "velocity_px_s", "rps", "axis"}``: from ``t_s``
        (s after ``t0_us``) the ball flies on with that image velocity and spin.
        Every piece is a flight: ``truth["segments"]`` lists each one's start time,
        spin and velocity, ``truth["track"]["flight"]`` numbers them from 0.

    Returns
    -------
    Recording
        ``truth`` holds ``axis``, ``omega_rad_s``, ``rps``, ``radius_px``,
        ``center``/``velocity_px_s`` at the first event, the ballistic parameters
        (``start_px``, ``velocity0_px_s``, ``gravity_px_s2`` at ``t0_us``), the
        ground-truth circle ``track`` (``t_us``, ``cx``, ``cy``, ``r``, ``vx``, ``vy``,
        ``visible``, ``flight``), ``segments`` (see ``hits``), ``distractors``, ``hot_pixels`` (x, y), ``noise_rate_hz``,
        ``frames`` (fps, exposure, size, homography, times), ``sync`` and ``sensor``
        (:func:`sim.esim.sensor_truth`).
    """
    model = get_sensor_model(sensor)
    overrides = {k: float(v) for k, v in (("threshold", threshold), ("mismatch_sigma", mismatch_sigma),
                                          ("refractory_us", refractory_us)) if v is not None}
    rng = np.random.default_rng(seed)
    path_rng, orient_rng, sensor_rng, noise_rng, bg_rng, dis_rng, frame_rng = rng.spawn(7)
    axis = unit(axis)
    if rps < 0:
        axis, rps = -axis, -rps
    omega = 2 * np.pi * float(rps)
    if duration_s <= 0:
        raise ValueError(f"duration_s must be positive, got {duration_s}")
    px_per_m = radius_px / BALL_RADIUS_M.get(texture, 0.1)
    g = G_M_S2 * px_per_m if gravity_px_s2 is None else float(gravity_px_s2)
    s0, v0 = _default_path(width, height, radius_px, duration_s, g, path_rng)
    start_px = s0 if start_px is None else tuple(map(float, start_px))
    velocity_px_s = v0 if velocity_px_s is None else tuple(map(float, velocity_px_s))
    cam = Camera(width, height, projection, focal_px)
    R0 = random_rotation(orient_rng)
    hit_list = []
    for h in hits:
        missing = {"t_s", "velocity_px_s", "rps", "axis"} - set(h)
        if missing:
            raise ValueError(f"hit {h!r} lacks {sorted(missing)}")
        ax_h = unit(h["axis"]) * (1 if h["rps"] >= 0 else -1)
        hit_list.append((float(h["t_s"]), tuple(map(float, h["velocity_px_s"])), ax_h, 2 * np.pi * abs(h["rps"])))
    if depth_velocity_m_s and projection != "pinhole":
        raise ValueError("depth_velocity_m_s needs projection='pinhole' (an orthographic ball cannot loom)")
    ball = make_ball(cam, texture=texture, radius_px=radius_px, center_px=start_px, velocity_px_s=velocity_px_s,
                     accel_px_s2=(0.0, g), axis=axis, omega_rad_s=omega, R0=R0, hits=hit_list,
                     depth_velocity_m_s=depth_velocity_m_s)
    objects, dis_truth = [], []
    for kind in distractors:
        if kind == "player":
            hgt = 0.6 * height * dis_rng.uniform(0.8, 1.1)
            x0 = dis_rng.uniform(0.15, 0.85) * width
            vx = dis_rng.choice([-1, 1]) * dis_rng.uniform(0.1, 0.3) * width / max(duration_s, 0.5)
            p = Player(x0=x0, y0=dis_rng.uniform(0.9, 1.0) * height, vx=vx, height_px=hgt,
                       bob_px=0.02 * hgt, step_hz=dis_rng.uniform(1.5, 3.0))
            objects.append(p)
            dis_truth.append({"kind": "player", "x0": p.x0, "y0": p.y0, "vx": p.vx, "height_px": p.height_px,
                              "bob_px": p.bob_px, "step_hz": p.step_hz})
        elif kind == "ball":
            r2 = radius_px * dis_rng.uniform(0.6, 0.9)
            c2 = (width + r2, dis_rng.uniform(0.2, 0.5) * height)
            v2 = (-(width + 2 * r2) / duration_s * dis_rng.uniform(0.8, 1.2), 0.2 * g * duration_s)
            ax2 = dis_rng.normal(size=3)
            b2 = make_ball(cam, texture="soccer", radius_px=r2, center_px=c2, velocity_px_s=v2,
                           accel_px_s2=(0.0, g), axis=ax2, omega_rad_s=2 * np.pi * dis_rng.uniform(2, 10),
                           R0=random_rotation(dis_rng))
            objects.append(b2)
            dis_truth.append({"kind": "ball", "texture": "soccer", "radius_px": r2, "start_px": list(c2),
                              "velocity0_px_s": list(v2), "axis": b2.axis.tolist(), "omega_rad_s": b2.omega_rad_s})
        elif kind == "arm":
            t_mid = 0.5 * duration_s
            cx, cy, r_mid = ball.circle(cam, [t_mid])[0]
            length, wid = 0.6 * px_per_m, 0.09 * px_per_m
            side = dis_rng.choice([-1, 1])
            gap = dis_rng.uniform(2.0, 6.0)  # px between the hand and the ball at mid-flight
            omega_arm = side * dis_rng.uniform(6.0, 12.0)  # rad/s, the hand moving past the ball
            pivot = (cx + side * (r_mid + 0.5 * wid + gap), cy + length)
            a = Arm(pivot_px=pivot, length_px=length, width_px=wid, angle0_rad=-np.pi / 2 - omega_arm * t_mid,
                    omega_rad_s=omega_arm)
            objects.append(a)
            dis_truth.append({"kind": "arm", "pivot_px": list(pivot), "length_px": length, "width_px": wid,
                              "angle0_rad": a.angle0_rad, "omega_rad_s": omega_arm})
        elif kind in ("racket", "paddle"):
            # a tennis racket (head 32 x 25 cm, strings every 15 mm) or a table-tennis bat (15 cm across),
            # swung at 8-14 rad/s from the shoulder, its head passing a few pixels from the ball at mid-flight
            # (7.7-13.4 m/s at the head's centre for a tennis racket: a slow stroke)
            t_mid = 0.5 * duration_s
            cx, cy, r_mid = ball.circle(cam, [t_mid])[0]
            m = px_per_m
            dims = dict(arm_px=0.6 * m, arm_width_px=0.09 * m, handle_px=0.2 * m, handle_width_px=0.03 * m,
                        head_a_px=0.16 * m, head_b_px=0.125 * m, rim_px=0.012 * m, string_px=max(0.003 * m, 0.8),
                        string_spacing_px=0.015 * m) if kind == "racket" else \
                dict(arm_px=0.6 * m, arm_width_px=0.09 * m, handle_px=0.1 * m, handle_width_px=0.03 * m,
                     head_a_px=0.08 * m, head_b_px=0.075 * m, rim_px=max(0.004 * m, 1.0))
            side = dis_rng.choice([-1, 1])
            gap = dis_rng.uniform(2.0, 6.0)
            # swung to meet the ball (its head moving against the ball's motion across the image), not
            # carried along beside it
            vx_mid = float(ball.image_velocity(cam, [t_mid])[0, 0])
            omega_r = -(np.sign(vx_mid) or 1.0) * dis_rng.uniform(8.0, 14.0)
            reach = dims["arm_px"] + dims["handle_px"] + dims["head_a_px"]
            pivot = (cx + side * (r_mid + dims["head_b_px"] + gap), cy + reach)
            rk = Racket(pivot_px=pivot, angle0_rad=-np.pi / 2 - omega_r * t_mid, omega_rad_s=omega_r, kind=kind,
                        **dims)
            objects.append(rk)
            dis_truth.append({"kind": kind, "pivot_px": list(pivot), "angle0_rad": rk.angle0_rad,
                              "omega_rad_s": omega_r, **dims})
        else:
            raise ValueError(f"unknown distractor {kind!r}; choose 'player', 'ball', 'arm', 'racket' or 'paddle'")
    objects.append(ball)  # the tracked ball is in front
    if background not in ("court", "plain"):
        raise ValueError(f"background must be 'court' or 'plain', got {background!r}")
    scene = Scene(cam, objects, background=court_background(width, height, bg_rng) if background == "court" else None)
    state = SensorState.new(width, height, sensor_rng, model, **overrides)
    ev = simulate(scene, state, 0.0, duration_s, n_events=n_events, step_px=step_px, t_offset_us=t0_us)
    t_end_us = t0_us + int(round(duration_s * 1e6)) if n_events is None or ev.size < n_events else int(ev["t"][-1]) + 1
    noise, hot_xy = noise_events(width, height, t0_us, t_end_us, noise_rng, rate_hz_per_px=noise_rate_hz,
                                 hot_pixels=hot_pixels, hot_rate_hz=hot_rate_hz)
    if flicker_hz:
        noise = merge(noise, flicker_events(width, height, t0_us, t_end_us, noise_rng, freq_hz=flicker_hz,
                                            depth=flicker_depth, box=flicker_box, threshold=state.model.threshold,
                                            mismatch_sigma=state.model.mismatch_sigma,
                                            min_threshold=state.model.min_threshold))
    ev = merge(ev, noise)
    # ground-truth circle
    t_us = np.arange(t0_us, t_end_us, int(track_dt_us), dtype=np.int64)
    t_us = np.append(t_us, t_end_us) if len(t_us) and t_us[-1] < t_end_us else t_us  # to the recording's end
    ts = (t_us - t0_us) * 1e-6
    circ = ball.circle(cam, ts)
    vel = ball.image_velocity(cam, ts)
    visible = ((circ[:, 0] + circ[:, 2] > 0) & (circ[:, 0] - circ[:, 2] < width - 1)
               & (circ[:, 1] + circ[:, 2] > 0) & (circ[:, 1] - circ[:, 2] < height - 1))
    t_first = int(ev["t"][0]) if ev.size else t0_us
    c_first = ball.circle(cam, [(t_first - t0_us) * 1e-6])[0]
    truth = {
        "axis": axis, "omega_rad_s": omega, "rps": float(rps), "radius_px": float(radius_px),
        "center": c_first[:2].copy(), "velocity_px_s": ball.image_velocity(cam, [(t_first - t0_us) * 1e-6])[0],
        "texture": texture, "seed": seed, "width": width, "height": height, "projection": projection,
        "focal_px": float(focal_px), "principal_px": list(map(float, cam.principal_px)),
        "t0_us": t0_us, "t_first_us": t_first, "t_last_us": int(ev["t"][-1]) if ev.size else t0_us,
        "R0": R0, "start_px": np.asarray(start_px, float), "velocity0_px_s": np.asarray(velocity_px_s, float),
        "gravity_px_s2": g, "threshold": state.model.threshold, "mismatch_sigma": state.model.mismatch_sigma,
        "sensor": sensor_truth(sensor, state.model), "n_events": int(ev.size),
        "noise_rate_hz": noise_rate_hz, "hot_pixels": hot_xy, "distractors": dis_truth,
        "flicker": None if not flicker_hz else {"freq_hz": float(flicker_hz), "depth": float(flicker_depth),
                                                "box": None if flicker_box is None else list(flicker_box)},
        "depth_velocity_m_s": float(depth_velocity_m_s),
        "track": {"t_us": t_us, "cx": circ[:, 0], "cy": circ[:, 1], "r": circ[:, 2],
                  "vx": vel[:, 0], "vy": vel[:, 1], "visible": visible, "flight": ball.segment_at(ts)},
        "segments": [{"t_start_us": t0_us + int(round(t_seg * 1e6)), "axis": ax_seg, "omega_rad_s": float(om_seg),
                      "rps": float(om_seg / (2 * np.pi)),
                      "velocity_px_s": ball.image_velocity(cam, [t_seg])[0]}
                     for t_seg, ax_seg, om_seg in ball.segments()],
        "frames": None, "sync": None,
    }
    triggers = np.zeros(0, TRIGGER_DTYPE)
    if sync is True:
        sync = SyncBox()
    if sync:
        rise, fall = sync.edges_s(0.0, duration_s)
        t_tr = np.r_[rise, fall]
        pol = np.r_[np.ones(rise.size), np.zeros(fall.size)]
        order = np.argsort(t_tr, kind="stable")
        triggers = make_triggers(t0_us + np.rint(t_tr[order] * 1e6).astype(np.int64), 0, pol[order])
        truth["sync"] = {"period_s": sync.period_s, "pulse_s": sync.pulse_s, "phase_s": sync.phase_s,
                         "jitter_s": sync.jitter_s, "seed": sync.seed,
                         "led_box_px": list(sync.led_box_px), "channel": 0}
    frames = frame_times = None
    if fps:
        fw, fh = (width, height) if frame_size is None else map(int, frame_size)
        phase = frame_rng.uniform(0, 1.0 / fps)
        if callable(exposure_s):  # auto-exposure: each exposure ends on the frame cadence
            ends = np.arange(phase + 1.0 / fps, duration_s, 1.0 / fps)
            exp = np.asarray(exposure_s(ends), float)
            if exp.shape != ends.shape or not np.all((exp > 0) & (exp <= 1.0 / fps)):
                raise ValueError("exposure_s(t) must give one exposure per frame in (0, 1/fps]")
            keep = ends - exp >= 0
            ends, exp = ends[keep], exp[keep]
            t_mid = ends - exp / 2
        else:
            exp = 0.5 / fps if exposure_s is None else float(exposure_s)
            t_mid = np.arange(phase + exp / 2, duration_s - exp / 2, 1.0 / fps)
        hmat = np.eye(3) if frame_to_event is None else np.asarray(frame_to_event, float)
        frames = render_frames(scene, t_mid, exposure_s=exp, width=fw, height=fh, frame_to_event=hmat,
                               rng=frame_rng, noise_dn=frame_noise_dn, sync=sync or None)
        frame_times = t0_us + np.rint(t_mid * 1e6).astype(np.int64)
        truth["frames"] = {"fps": float(fps), "exposure_s": exp if np.ndim(exp) == 0 else exp.tolist(),
                           "width": fw, "height": fh,
                           "frame_to_event": hmat, "t_us": frame_times,
                           "t_frame_clock_s": frame_clock_offset_s + (frame_times * 1e-6) * (1 + frame_clock_drift_ppm * 1e-6),
                           "clock_offset_s": frame_clock_offset_s, "clock_drift_ppm": frame_clock_drift_ppm}
    return Recording(ev, triggers, width, height, truth, frames, frame_times)


def rally(seed: int = 0, *, fps: float | None = 120.0, width: int = 1280, height: int = 720,
          sync: bool = True, **kw) -> Recording:
    """Quick demo recording: a volleyball (r = 36 px, 6 rps topspin) crossing a 1280x720 court view.

    About 0.3 s of events with background, noise, hot pixels and a walking player,
    120 fps frames and sync-box triggers every 100 ms. Any :func:`flight` argument
    may be overridden through ``kw``.
    """
    # topspin for a ball flying to the right (+x): the top (-y) moves forward (+x),
    # omega x r at r = (0, -1, 0) must be +x  ->  axis = (0, 0, -1)
    params = dict(texture="volleyball", rps=6.0, axis=(0.0, 0.0, -1.0), radius_px=36.0, duration_s=0.3,
                  distractors=("player",), noise_rate_hz=0.1, hot_pixels=5)
    params.update(kw)
    return flight(width=width, height=height, fps=fps, sync=SyncBox(period_s=0.1, pulse_s=0.02, phase_s=0.015)
                  if sync else None, seed=seed, **params)
