"""``spinning_ball``: a single spinning (optionally drifting) ball, events + ground truth."""

from __future__ import annotations

import numpy as np

from .esim import SensorModel, SensorState, get_sensor_model, merge, noise_events, sensor_truth, simulate
from .rotation import random_rotation, unit
from .scene import Ball, Camera, Scene, court_background

BALL_RADIUS_M = {"volleyball": 0.105, "soccer": 0.11, "basketball": 0.12, "tennis": 0.033, "logo": 0.1,
                 "baseball": 0.0366, "tabletennis": 0.020, "plain": 0.1}
"""Physical ball radii (m) used by the pinhole projection."""


def make_ball(cam: Camera, *, texture: str, radius_px: float, center_px, velocity_px_s, accel_px_s2,
              axis, omega_rad_s: float, R0, ball_radius_m: float | None = None, gain: float = 1.0,
              hits=(), depth_velocity_m_s: float = 0.0) -> Ball:
    """A :class:`Ball` whose image at ``t = 0`` is the circle ``(center_px, radius_px)``.

    In pinhole mode the ball is placed along the ray through ``center_px`` at the
    distance that gives ``radius_px``; image velocity/acceleration become motion
    parallel to the image plane at that depth, plus ``depth_velocity_m_s`` along the optical axis
    (pinhole only). ``hits`` holds
    ``(t_s, velocity_px_s (2,), axis (3,), omega_rad_s)`` with image velocities.
    """
    c = np.asarray(center_px, np.float64)
    vel = np.asarray(velocity_px_s, np.float64)
    acc = np.asarray(accel_px_s2, np.float64)
    if not cam.pinhole:
        return Ball(texture=texture, radius=radius_px, center=[c[0], c[1], 0.0], velocity=[*vel, 0.0],
                    accel=[*acc, 0.0], axis=axis, omega_rad_s=omega_rad_s, R0=R0, gain=gain,
                    hits=tuple((t, [v[0], v[1], 0.0], a, w) for t, v, a, w in hits))
    rm = BALL_RADIUS_M.get(texture, 0.1) if ball_radius_m is None else ball_radius_m
    dist = rm / np.sin(np.arctan(radius_px / cam.focal_px))
    ray = cam.rays(c[:1], c[1:2])[0]
    centre = dist * ray
    z = centre[2]
    s = z / cam.focal_px
    return Ball(texture=texture, radius=rm, center=centre, velocity=[vel[0] * s, vel[1] * s, float(depth_velocity_m_s)],
                accel=[acc[0] * s, acc[1] * s, 0.0], axis=axis, omega_rad_s=omega_rad_s, R0=R0, gain=gain,
                hits=tuple((t, [v[0] * s, v[1] * s, 0.0], a, w) for t, v, a, w in hits))


def spinning_ball(texture: str = "volleyball", rps: float = 100.0, axis=(0, 0, 1), radius_px: float = 100,
                  center=None, velocity_px_s=(0, 0), width: int = 640, height: int = 480,
                  n_events: int | None = 60000, seed: int = 0, sensor: str | SensorModel = "ideal", **opts):
    """Events of one spinning ball in front of a plain (or textured) background.

    Parameters
    ----------
    texture : str
        A name in :data:`sim.textures.TEXTURES`: ``"volleyball"``, ``"soccer"``,
        ``"basketball"``, ``"tennis"``, ``"logo"``, ``"baseball"`` or ``"tabletennis"``.
    rps : float
        Revolutions per second; a negative value spins the other way (the truth
        then reports the flipped axis and ``rps >= 0``).
    axis : array_like, shape (3,)
        Spin axis in the camera frame (X right, Y down, Z forward), right-hand rule.
    radius_px : float
        Ball radius in pixels (at ``t = 0``).
    center : (float, float), optional
        Ball centre in pixels at ``t = 0`` (default: sensor centre).
    velocity_px_s : (float, float)
        Constant image velocity of the centre (px/s).
    width, height : int
        Sensor size (px).
    n_events : int or None
        Stop at this many events (fewer if ``duration_s`` runs out first; None: run ``duration_s``).
    seed : int
        Seed of every random draw (initial orientation, threshold mismatch, noise).
    sensor : str or SensorModel
        Pixel model: a :data:`sim.esim.SENSOR_PRESETS` name (``"ideal"``, ``"realistic"``)
        or a :class:`sim.esim.SensorModel`; ``threshold``, ``threshold_off``,
        ``mismatch_sigma`` and ``refractory_us`` override its fields when given.

    Other Parameters
    ----------------
    duration_s : float
        Simulated time limit (default 2 s when ``n_events`` is set).
    projection : {"orthographic", "pinhole"}; focal_px : float (default 800)
    gravity_px_s2 : float, image-down acceleration (default 0)
    threshold : float, threshold_off : float, mismatch_sigma : float (log units), refractory_us : float (µs)
        Override the sensor model's fields.
    step_px : float (0.25)
    background : {"plain", "court"} (default "plain"), background_level : float (0.3)
    noise_rate_hz : float per pixel (0), hot_pixels : int (0)
    R0 : (3, 3) initial orientation (default: random from ``seed``)
    t0_us : int, time of the simulation start (default 0)
    light : (3,) direction towards the light (camera frame), ambient : float

    Returns
    -------
    events : ndarray of EVENT_DTYPE, sorted by t
    truth : dict
        ``axis`` (3,) unit, ``omega_rad_s`` >= 0, ``rps``, ``center`` (2,) px at the
        first event's time, ``radius_px``, ``velocity_px_s`` (2,), plus ``texture``,
        ``seed``, ``width``, ``height``, ``projection``, ``t_first_us``,
        ``t_last_us``, ``t0_us`` (time of ``R0``), ``R0`` (3, 3), ``threshold``,
        ``mismatch_sigma``, ``n_events`` and ``sensor`` (:func:`sim.esim.sensor_truth`:
        the preset name and every model field).
    """
    known = {"duration_s", "projection", "focal_px", "gravity_px_s2", "threshold", "threshold_off",
             "mismatch_sigma", "refractory_us", "step_px", "background", "background_level",
             "noise_rate_hz", "hot_pixels", "R0", "t0_us", "light", "ambient", "ball_radius_m"}
    bad = set(opts) - known
    if bad:
        raise TypeError(f"spinning_ball() got unknown option(s) {sorted(bad)}; known: {sorted(known)}")
    if n_events is None and opts.get("duration_s") is None:
        raise ValueError("give n_events or duration_s")
    model = get_sensor_model(sensor)
    rng = np.random.default_rng(seed)
    axis = unit(axis)
    if rps < 0:
        axis, rps = -axis, -rps
    omega = 2 * np.pi * float(rps)
    R0 = np.asarray(opts["R0"], np.float64) if opts.get("R0") is not None else random_rotation(rng)
    cam = Camera(width, height, opts.get("projection", "orthographic"), float(opts.get("focal_px", 800.0)))
    if center is None:
        center = ((width - 1) / 2.0, (height - 1) / 2.0)
    ball = make_ball(cam, texture=texture, radius_px=float(radius_px), center_px=center,
                     velocity_px_s=velocity_px_s, accel_px_s2=(0.0, float(opts.get("gravity_px_s2", 0.0))),
                     axis=axis, omega_rad_s=omega, R0=R0, ball_radius_m=opts.get("ball_radius_m"))
    bg_kind = opts.get("background", "plain")
    if bg_kind not in ("plain", "court"):
        raise ValueError(f"background must be 'plain' or 'court', got {bg_kind!r}")
    sensor_rng, noise_rng, bg_rng = rng.spawn(3)
    scene = Scene(cam, [ball], background=court_background(width, height, bg_rng) if bg_kind == "court" else None,
                  background_level=float(opts.get("background_level", 0.3)))
    if opts.get("light") is not None:
        scene.light = unit(opts["light"])
    if opts.get("ambient") is not None:
        scene.ambient = float(opts["ambient"])
    overrides = {k: float(opts[k]) for k in ("threshold", "threshold_off", "mismatch_sigma", "refractory_us")
                 if opts.get(k) is not None}
    state = SensorState.new(width, height, sensor_rng, model, **overrides)
    t0_us = int(opts.get("t0_us", 0))
    duration = float(opts.get("duration_s") or 2.0)
    ev = simulate(scene, state, 0.0, duration, n_events=n_events, step_px=float(opts.get("step_px", 0.25)),
                  t_offset_us=t0_us)
    rate = float(opts.get("noise_rate_hz", 0.0))
    hot = int(opts.get("hot_pixels", 0))
    if (rate > 0 or hot > 0) and ev.size:
        t_end = int(ev["t"][-1]) + 1 if n_events is not None else t0_us + int(duration * 1e6)
        noise, _ = noise_events(width, height, t0_us, t_end, noise_rng, rate_hz_per_px=rate, hot_pixels=hot)
        ev = merge(ev, noise)
        if n_events is not None:
            ev = ev[:n_events]
    t_first = int(ev["t"][0]) if ev.size else t0_us
    t_first_s = (t_first - t0_us) * 1e-6
    circ = ball.circle(cam, [t_first_s])[0]
    vel = ball.image_velocity(cam, [t_first_s])[0]
    truth = {
        "axis": axis, "omega_rad_s": omega, "rps": float(rps),
        "center": circ[:2].copy(), "radius_px": float(circ[2]), "velocity_px_s": vel,
        "texture": texture, "seed": seed, "width": width, "height": height,
        "projection": cam.projection, "t_first_us": t_first, "t_last_us": int(ev["t"][-1]) if ev.size else t0_us,
        "t0_us": t0_us, "R0": R0, "threshold": state.model.threshold, "mismatch_sigma": state.model.mismatch_sigma,
        "n_events": int(ev.size), "sensor": sensor_truth(sensor, state.model),
    }
    return ev, truth
