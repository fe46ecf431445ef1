"""A ball whose image drifts faster than its rim turns: the contrast's blur pulls its rate low; moved to
zero blur, and the move counted in the uncertainty."""

import numpy as np
import pytest

import sim
import spin
import spin.fast as fast
from spin.estimate import prepare

# a soccer ball of r 14 px at 30 rps (its rim at 2,700 px/s), its axis 17 deg off the optical axis
AXIS = np.array([0.18154361, -0.22361075, -0.95762213])
KW = dict(rps=30, axis=AXIS / np.linalg.norm(AXIS), radius_px=14.3, center=(1150.0, 360.0), width=1280, height=720,
          n_events=60_000, duration_s=0.02, sensor="ideal")


def _ball(seed, vx_px_s):
    return sim.spinning_ball("soccer", velocity_px_s=(vx_px_s, 0.0), seed=seed, **KW)


def _rate_err_pct(est, truth):
    return 100.0 * (est.omega_rad_s / truth["omega_rad_s"] - 1.0)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_ball_drifting_faster_than_it_turns_is_right_or_flagged(monkeypatch, seed):
    # flying at 2,700 px/s: without the blur's shift the rate came out 3.5-8.5 % low at confidence 1.00
    # and 0.7 % sigma (a wrong number trusted); moved to zero blur it is within 3 % and its 2 sigma
    events, truth = _ball(seed, -2681.8)
    kw = dict(velocity=truth["velocity_px_s"], sensor_size=(1280, 720))
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], **kw)
    err = _rate_err_pct(est, truth)
    assert abs(err) < 3.0 and abs(err) <= 2 * est.rps_sigma_pct
    assert est.confidence < 0.5 or abs(err) < 1.5  # right, or flagged
    monkeypatch.setattr(fast, "BLUR_SHIFT_FROM_DRIFT", np.inf)  # the shift never measured
    raw = spin.estimate_spin(events, truth["center"], truth["radius_px"], **kw)
    raw_err = _rate_err_pct(raw, truth)
    assert raw_err < -3.0 and raw.confidence >= 0.5 and abs(raw_err) > 2 * raw.rps_sigma_pct
    assert est.omega_rad_s > raw.omega_rad_s


def test_the_blur_shift_is_nil_on_a_still_ball_and_raises_a_drifting_ball_s_rate():
    for vx, low, high in ((0.0, -0.5, 0.5), (-2681.8, 2.0, 12.0)):
        events, truth = _ball(2, vx)
        v = np.asarray(truth["velocity_px_s"])
        ev, _ = prepare(events, truth["center"], truth["radius_px"], velocity_px_s=v, rim_fraction=0.95, dither=True)
        w = truth["axis"] * truth["omega_rad_s"]
        shift = fast._blur_shift(ev, w, v, truth["omega_rad_s"])
        # the shift, projected on the spin, as a share of its rate (%)
        assert low < 100.0 * float(shift @ w) / truth["omega_rad_s"] ** 2 < high


def test_a_still_ball_is_not_shifted(monkeypatch):
    # the still ball's image does not drift: its estimate never measures the shift, and stays tight
    def fail(*args, **kwargs):
        raise AssertionError("the blur's shift measured on a still ball")

    monkeypatch.setattr(fast, "_blur_shift", fail)
    events, truth = _ball(1, 0.0)
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], velocity=(0.0, 0.0), sensor_size=(1280, 720))
    assert est.confidence >= 0.5 and abs(_rate_err_pct(est, truth)) < 1.0 and est.rps_sigma_pct < 1.0
