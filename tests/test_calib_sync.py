"""Clock alignment on simulated signals with known offset and drift."""

import json

import numpy as np
import pytest

from calib.sync import (
    exposure_span_s, refine_led_roi,
    SyncError, TimeMap, fit_activity, fit_linear, fit_sync_box, frame_difference_energy, led_brightness,
)
from capture.events import make_triggers

OFFSET_US = 3_217_456.0   # event-clock time of frame-clock 0
DRIFT_PPM = 37.0


def true_event_us(t_frame_s):
    return OFFSET_US + (1 + DRIFT_PPM * 1e-6) * np.asarray(t_frame_s) * 1e6


def true_frame_s(t_event_us):
    return (np.asarray(t_event_us) - OFFSET_US) / ((1 + DRIFT_PPM * 1e-6) * 1e6)


def led_toggles_us(duration_s, rng, t0_us=0.0, lo_s=0.05, hi_s=0.2):
    """Pseudo-random blink pattern: toggle times (µs, event clock); LED off before the first."""
    gaps = rng.uniform(lo_s, hi_s, int(duration_s / lo_s) + 2) * 1e6
    t = t0_us + np.cumsum(gaps)
    return t[t < t0_us + duration_s * 1e6]


def on_fraction(toggles_frame_s, a_s, b_s):
    """Fraction of [a, b] during which the LED (off before the first toggle) is on."""
    tg = np.asarray(toggles_frame_s)
    state = (np.arange(len(tg)) % 2 == 0).astype(float)  # state after each toggle
    seg = np.diff(tg)
    cum = np.concatenate([[0.0], np.cumsum(seg * state[:-1])])

    def F(x):
        i = np.searchsorted(tg, x, side="right") - 1
        ok = i >= 0
        ic = np.clip(i, 0, len(tg) - 1)
        return np.where(ok, cum[ic] + (x - tg[ic]) * state[ic], 0.0)

    return (F(b_s) - F(a_s)) / (b_s - a_s)


def simulate_sync_box(fps, exposure_frac, duration_s, seed):
    rng = np.random.default_rng(seed)
    t_frame = np.arange(int(duration_s * fps)) / fps
    tog_us = led_toggles_us(duration_s + 4, rng, t0_us=OFFSET_US - 2e6)
    tog_us = np.round(tog_us)  # trigger timestamps are integer µs
    e = exposure_frac / fps
    frac = on_fraction(true_frame_s(tog_us), t_frame, t_frame + e)
    triggers = make_triggers(tog_us.astype(np.int64), 0, (np.arange(len(tog_us)) % 2 == 0).astype(np.int8))
    return t_frame, frac, e, triggers, rng


@pytest.mark.parametrize("fps,exposure_frac", [(240000 / 1001, 1.0), (240000 / 1001, 0.5), (60000 / 1001, 0.5)])
def test_sync_box_meets_half_millisecond(fps, exposure_frac):
    t_frame, frac, e, triggers, rng = simulate_sync_box(fps, exposure_frac, 30.0, seed=int(fps))
    brightness = 255 * (0.05 + 0.9 * frac) ** (1 / 2.2) + rng.normal(0, 1.5, len(frac))  # gamma-encoded video
    tmap, e_used = fit_sync_box(brightness, t_frame, triggers, exposure_s=e)
    assert e_used == e
    err = np.abs(tmap.to_event_us(t_frame) - true_event_us(t_frame))
    print(f"sync box fps={fps:.2f} exp={exposure_frac}: max err {err.max():.1f} us, "
          f"drift {tmap.drift_ppm:.2f} ppm, sigma {tmap.sigma_us(t_frame).max():.1f} us, n={tmap.n}")
    assert err.max() <= 500.0
    # exposure not given: estimated from the fit
    tmap2, e_est = fit_sync_box(brightness, t_frame, triggers)
    err2 = np.abs(tmap2.to_event_us(t_frame) - true_event_us(t_frame))
    print(f"   exposure estimated {e_est * fps:.3f} period (true {exposure_frac}), max err {err2.max():.1f} us")
    assert abs(e_est - e) < 0.1 / fps
    # an exposure error shifts the edges by about half of it: 0.5 ms is met at 240 fps; at 60 fps
    # lock the shutter and pass exposure_s (the estimate still lands within 5 % of a period)
    assert err2.max() <= (500.0 if fps > 100 else 0.05e6 / fps)
    assert abs(tmap.drift_ppm - DRIFT_PPM) < 10
    assert err.max() <= 3 * tmap.sigma_us(t_frame).max()  # the uncertainty is honest
    assert err2.max() <= 3 * tmap2.sigma_us(t_frame).max()
    assert tmap.n > 100
    # a wrong exposure typed in: the frames contradict it, and the sigma says so
    tmap3, _ = fit_sync_box(brightness, t_frame, triggers, exposure_s=0.6 * e)
    err3 = np.abs(tmap3.to_event_us(t_frame) - true_event_us(t_frame))
    print(f"   exposure typed 40 % short: max err {err3.max():.1f} us, sigma {tmap3.sigma_us(t_frame).max():.1f} us")
    assert err3.max() <= 3 * tmap3.sigma_us(t_frame).max()


def test_sync_box_from_images_finds_led_roi():
    fps = 120.0
    t_frame, frac, e, triggers, rng = simulate_sync_box(fps, 1.0, 12.0, seed=5)

    def frames():
        for f in frac:
            img = rng.normal(60, 2, (24, 32)).clip(0, 255)
            img[10:14, 20:24] = 255 * (0.1 + 0.85 * f) ** (1 / 2.2)  # the LED, gamma-encoded
            yield img.astype(np.uint8)

    b, roi = led_brightness(frames(), grid=8)
    assert roi == (20, 9, 24, 12)
    tmap, _ = fit_sync_box(b, t_frame, triggers, exposure_s=e, channel=0)
    err = np.abs(tmap.to_event_us(t_frame) - true_event_us(t_frame))
    print(f"sync box from images: max err {err.max():.1f} us")
    assert err.max() <= 500.0


def test_sync_box_errors():
    t_frame, frac, e, triggers, rng = simulate_sync_box(120.0, 1.0, 5.0, seed=1)
    with pytest.raises(SyncError, match="no trigger events on channel 3"):
        fit_sync_box(frac, t_frame, triggers, exposure_s=e, channel=3)
    with pytest.raises(SyncError, match="constant"):
        fit_sync_box(np.ones_like(frac), t_frame, triggers, exposure_s=e)
    # triggers from a different pattern: no consistent offset
    other = simulate_sync_box(120.0, 1.0, 5.0, seed=99)[3]
    with pytest.raises(SyncError, match="pattern"):
        fit_sync_box(frac, t_frame, other[: len(other) // 3], exposure_s=e)


def simulate_activity(fps, duration_s, seed, n_events=400_000):
    rng = np.random.default_rng(seed)
    t_frame = np.arange(int(duration_s * fps)) / fps
    ev0, ev1 = true_event_us(-1.0), true_event_us(duration_s + 1.0)
    dt_us = 100.0
    grid = np.arange(ev0, ev1, dt_us)
    act = np.full(len(grid), 0.3)
    for c in rng.uniform(ev0, ev1, int(4 * (duration_s + 2))):
        w = rng.uniform(5e3, 40e3)
        act += rng.uniform(1, 5) * np.exp(-0.5 * ((grid - c) / w) ** 2)
    lam = act / act.sum() * n_events
    counts = rng.poisson(lam)
    ev_t = np.repeat(grid, counts) + rng.uniform(0, dt_us, counts.sum())
    ev_t = np.sort(ev_t).astype(np.int64)
    cum = np.concatenate([[0.0], np.cumsum(act * dt_us)])
    half = 0.5 / fps
    lo, hi = true_event_us(t_frame[:-1] + half), true_event_us(t_frame[1:] + half)
    integ = np.interp(hi, np.append(grid, grid[-1] + dt_us), cum) - np.interp(lo, np.append(grid, grid[-1] + dt_us), cum)
    energy = 7.0 * integ / integ.std()
    energy += rng.normal(0, 0.3 * energy.std(), len(energy))
    return t_frame, ev_t, energy


@pytest.mark.parametrize("fps", [120.0, 240000 / 1001])
def test_activity_within_one_frame(fps):
    t_frame, ev_t, energy = simulate_activity(fps, 20.0, seed=int(fps))
    tmap = fit_activity(ev_t, t_frame, energy)
    err = np.abs(tmap.to_event_us(t_frame) - true_event_us(t_frame))
    period_us = 1e6 / fps
    print(f"activity fps={fps:.2f}: max err {err.max():.1f} us = {err.max() / period_us:.3f} frame, "
          f"drift {tmap.drift_ppm:.1f} ppm, sigma {tmap.sigma_us(t_frame).max():.1f} us")
    assert err.max() <= period_us
    assert err.max() <= 2 * tmap.sigma_us(t_frame).max()  # right, or flagged
    assert tmap.method == "activity"


def test_activity_no_common_motion_is_an_error():
    t_frame, ev_t, energy = simulate_activity(120.0, 6.0, seed=3)
    rng = np.random.default_rng(0)
    with pytest.raises(SyncError, match="do not correlate"):
        fit_activity(ev_t, t_frame, rng.permutation(energy))
    with pytest.raises(SyncError, match="expected len"):
        fit_activity(ev_t, t_frame, energy[:-3])


def test_frame_difference_energy():
    frames = [np.zeros((8, 8), np.uint8) for _ in range(4)]
    frames[2][:4] = 100  # change between 1->2 and back 2->3
    e = frame_difference_energy((i, i / 60, f) for i, f in enumerate(frames))
    np.testing.assert_allclose(e, [0.0, 50.0, 50.0])


def test_time_map_roundtrip_inverse_and_dict():
    x = np.linspace(0, 100, 50)
    rng = np.random.default_rng(0)
    y = true_event_us(x) + rng.normal(0, 20, len(x))
    tm = fit_linear(x, y, np.full(len(x), 20.0), method="sync_box")
    assert abs(tm.drift_ppm - DRIFT_PPM) < 1.0
    assert abs(tm.to_event_us(50.0) - true_event_us(50.0)) < 4 * tm.sigma_us(50.0)
    assert tm.sigma_us(0.0) > tm.sigma_us(tm.t_ref_s)
    np.testing.assert_allclose(tm.to_frame_s(tm.to_event_us(x)), x, atol=1e-12)
    d = json.loads(json.dumps(tm.to_dict()))
    tm2 = TimeMap.from_dict(d)
    np.testing.assert_allclose(tm2.to_event_us(x), tm.to_event_us(x))
    np.testing.assert_allclose(tm2.cov, tm.cov)
    assert d["method"] == "sync_box" and d["sigma_drift_ppm"] > 0


def test_exposure_spans_end_together_with_one_exposure_per_frame():
    t = np.arange(5) / 240.0
    a, b = exposure_span_s(t, 1e-3)
    np.testing.assert_allclose(a, t) and np.testing.assert_allclose(b, t + 1e-3)
    e = np.array([1.0, 2.0, 1.5, 0.5, 1.5]) * 1e-3
    a, b = exposure_span_s(t, e)
    np.testing.assert_allclose(b, t + 1.5e-3)  # every exposure ends at the median after its frame time
    np.testing.assert_allclose(b - a, e)


def test_the_led_is_found_beside_a_ball_passing_and_a_player_moving():
    """Frames with a small blinking LED (6 x 5 px, a part of two search blocks), a bright ball
    crossing the frame and a dark body swaying over whole blocks (the largest brightness spread
    over time): the block search picks the LED's block and the refinement its own pixels."""
    rng = np.random.default_rng(0)
    n, h, w = 150, 240, 320
    on = (np.arange(n) // 4 + rng.integers(0, 2, n)) % 3 == 0
    frames = []
    for k in range(n):
        img = np.full((h, w), 150.0) + rng.normal(0, 2, (h, w))
        x_body = int(150 + 60 * np.sin(k / 12))
        img[120:200, x_body:x_body + 40] = 10  # a body swaying
        x = int(k * w / n)
        img[30:42, max(0, x - 6):x + 6] = 250  # the ball crossing once
        img[11:16, 101:107] = 230 if on[k] else 90
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
    b, roi = led_brightness(frames)
    x0, y0, x1, y1 = roi
    assert x0 < 107 and x1 > 101 and y0 < 16 and y1 > 11  # a block holding the LED
    b, roi = refine_led_roi(frames, roi)
    assert roi == (101, 11, 107, 16)
    assert np.array_equal(b > 160, on)


def test_the_led_region_is_not_taken_over_by_a_ball_passing_next_to_it():
    """A bright ball passes over the LED's neighbourhood for 4 of 120 frames: the LED's own pixels
    are kept (the frames far from its two levels are left out of the refinement)."""
    h, w = 360, 640
    yy, xx = np.mgrid[0:h, 0:w]
    rng = np.random.default_rng(0)
    on = np.array([(k // 3) % 2 == 0 or k % 7 == 0 for k in range(120)])
    frames = []
    for k in range(120):
        img = np.full((h, w), 60.0) + rng.normal(0, 2, (h, w))
        if on[k]:
            img[100:106, 200:206] = 250
        if 50 <= k <= 53:
            img[(xx - 170 - 20 * (k - 50)) ** 2 + (yy - 103) ** 2 <= 12 ** 2] = 230
        frames.append(np.clip(img, 0, 255).astype(np.uint8))
    _, roi = led_brightness(frames)
    b, roi = refine_led_roi(frames, roi)
    assert roi == (200, 100, 206, 106)
    assert np.corrcoef(b, on)[0, 1] > 0.95


def test_exposures_that_are_not_finite_and_positive_are_refused_in_one_line():
    t = np.arange(5) / 240.0
    for bad in ([1e-3, np.nan, 1e-3, 1e-3, 1e-3], [1e-3, -1e-3, 1e-3, 1e-3, 1e-3]):
        with pytest.raises(SyncError, match="finite"):
            exposure_span_s(t, bad)
