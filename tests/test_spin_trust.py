"""Right, or flagged: the cross-check on the halves of a window, the uncertainty, windows of many turns."""

import math
from dataclasses import replace

import numpy as np
import pytest

import sim
import spin
import spin.fast as fast
from spin.estimate import CIRCLE_RATE_PER_PCT, prepare, with_circle_sigma


def _axis_err_deg(axis, truth_axis):
    return float(np.degrees(np.arccos(np.clip(np.dot(axis, truth_axis), -1, 1))))


def _rotated(w, angle_deg):
    """``w`` turned by ``angle_deg`` about an axis perpendicular to it."""
    w = np.asarray(w, float)
    perp = np.cross(w, [1.0, 0.0, 0.0])
    perp /= np.linalg.norm(perp)
    a = math.radians(angle_deg)
    return w * math.cos(a) + np.linalg.norm(w) * perp * math.sin(a)


@pytest.fixture(scope="module")
def ball():
    events, truth = sim.spinning_ball("volleyball", rps=100, axis=(0.3, -0.5, 0.8), radius_px=50, n_events=30_000,
                                      seed=4)
    ev, _ = prepare(events, truth["center"], truth["radius_px"], dither=True)
    return ev, truth


@pytest.mark.parametrize("half_angles_deg, half_ratios, expect", [
    ((1.0, -1.0), (1.0, 1.0), "trusted"),     # halves agree: the whole's confidence stands
    ((4.0, 30.0), (1.0, 1.0), "flagged"),     # a half lands on another axis
    ((1.0, 1.0), (1.0, 2.0), "flagged"),      # a half lands on another speed (an alias)
    ((0.0, 0.0), (1.0, 1.12), "flagged"),     # halves 12 % apart: 2 sigma of the rate exceeds 5 %
    ((4.0, 4.0), (1.0, 1.0), "trusted"),      # halves agree, 4 deg from the whole: within its limits
    ((5.5, 5.5), (1.0, 1.0), "flagged"),      # halves agree, but 5.5 deg from the whole
])
def test_cross_check_scales_the_confidence(monkeypatch, ball, half_angles_deg, half_ratios, expect):
    ev, _ = ball
    w_whole = np.array([100.0, -200.0, 500.0])
    calls = []

    def fake_window(events, velocity_px_s, assess=True, **_):
        k = len(calls)
        calls.append(len(events))
        w = w_whole if k == 0 else _rotated(w_whole, half_angles_deg[k - 1]) * half_ratios[k - 1]
        return fast.FastResult(w, np.zeros(2), 1.0, True, 1.0 if assess else float("nan"), None, 1, 1, 10, 1, 1)

    monkeypatch.setattr(fast, "estimate_window", fake_window)
    monkeypatch.setattr(fast, "_half_answer", lambda half, own, whole, **_: own.w_rad_s)
    res = fast.estimate_fast(ev, (0.0, 0.0))
    assert calls == [len(ev), len(ev) // 2, len(ev) - len(ev) // 2]  # the whole, then each half
    np.testing.assert_allclose(res.w_rad_s, w_whole)
    if expect == "trusted":
        spread = max(res.axis_sigma_deg, res.rps_sigma_pct) / 2.5
        assert res.confidence == pytest.approx(min(1.0, 1.75 - spread) ** 2) and res.confidence >= 0.5
        apart = abs(half_angles_deg[0] - half_angles_deg[1])  # (both turn about the same axis)
        assert res.axis_sigma_deg == pytest.approx(max(fast.SIGMA_SCALE_AXIS * apart, fast.SIGMA_FLOOR_DEG), rel=1e-6)
        assert res.rps_sigma_pct == fast.SIGMA_FLOOR_PCT
    else:
        assert res.confidence < 0.5


def test_half_that_misses_defers_to_the_whole_where_it_scores_higher(ball):
    ev, truth = ball
    w_true = truth["axis"] * truth["omega_rad_s"]
    half = fast._recentred(ev.take(slice(0, len(ev) // 2)))
    whole = fast.FastResult(w_true * 1.01, np.zeros(2), 1.0, True, 1.0, None, 1, 1, 10, 1, 1)
    wrong = fast.FastResult(_rotated(w_true, 40.0) * 1.7, np.zeros(2), 1.0, True, 1.0, None, 1, 1, 10, 1, 1)
    w = fast._half_answer(half, wrong, whole)
    assert _axis_err_deg(w / np.linalg.norm(w), truth["axis"]) < 3
    # and the other way round: a wrong whole does not capture a half that found the truth
    w = fast._half_answer(half, whole, wrong)
    assert _axis_err_deg(w / np.linalg.norm(w), truth["axis"]) < 3


def test_a_part_that_strays_far_from_the_whole_stops_refining(monkeypatch, ball):
    """A cross-check's part refines level after level only while its answer stays within
    STRAY_FACTORS times the check's limits of the whole window's (beyond, _half_answer refines it again)."""
    ev, truth = ball
    w_true = truth["axis"] * truth["omega_rad_s"]
    half = fast._recentred(ev.take(slice(0, len(ev) // 2)))
    levels_run = []
    maximise = fast.maximise
    monkeypatch.setattr(fast, "maximise", lambda *a, **k: levels_run.append(1) or maximise(*a, **k))
    free = fast.estimate_window(half, (0.0, 0.0), assess=False)
    near = fast.estimate_window(half, (0.0, 0.0), assess=False, reference_w_rad_s=w_true * 1.02)
    assert len(levels_run) == 2 * len(fast.LEVELS)
    np.testing.assert_array_equal(near.w_rad_s, free.w_rad_s)
    assert _axis_err_deg(free.w_rad_s / np.linalg.norm(free.w_rad_s), truth["axis"]) < 2
    levels_run.clear()
    far = fast.estimate_window(half, (0.0, 0.0), assess=False, reference_w_rad_s=_rotated(w_true, 90.0))
    assert len(levels_run) == 1  # the first level's answer is far from the reference: no further level
    assert _axis_err_deg(far.w_rad_s / np.linalg.norm(far.w_rad_s), truth["axis"]) < 30


@pytest.mark.parametrize("seed", [1, 2])
def test_trusted_estimates_are_right_and_their_uncertainty_covers_the_error(seed):
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    events, truth = sim.spinning_ball("soccer", rps=150, axis=axis, radius_px=40, n_events=40_000, seed=seed)
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], velocity=truth["velocity_px_s"])
    axis_err = _axis_err_deg(est.axis, truth["axis"])
    rps_err = 100 * abs(est.rps / truth["rps"] - 1)
    assert est.confidence >= 0.5
    assert axis_err < 5 and rps_err < 5
    assert axis_err <= 2 * est.axis_sigma_deg + 0.5 and rps_err <= 2 * est.rps_sigma_pct + 0.5
    assert 0 < est.axis_sigma_deg < 2.5 and 0 < est.rps_sigma_pct < 2.5


def test_window_of_many_turns_is_right():
    # 20 ms of a 30 rps ball: 216 deg of rotation (before the levels' span was capped at 1.5 rad this
    # window came out 11 deg / 15 % off at confidence 1.00)
    rng = np.random.default_rng(4)
    events, truth = sim.spinning_ball("volleyball", rps=30, axis=rng.normal(size=3), radius_px=29, n_events=None,
                                      duration_s=0.02, seed=4)
    assert truth["rps"] * (events["t"][-1] - events["t"][0]) * 1e-6 * 360 > 200
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], velocity=(0.0, 0.0))
    assert est.confidence >= 0.5
    assert _axis_err_deg(est.axis, truth["axis"]) < 5 and abs(est.rps / truth["rps"] - 1) < 0.05


def test_paper_method_reports_no_uncertainty(ball):
    events, truth = sim.spinning_ball("volleyball", rps=100, axis=(0, 0, 1), radius_px=40, n_events=8000, seed=2)
    est = spin.estimate_spin(events, truth["center"], truth["radius_px"], method="paper", iterations=5)
    assert math.isnan(est.axis_sigma_deg) and math.isnan(est.rps_sigma_pct)


def _many_turns(monkeypatch, ev, part_answer, half_answer):
    """:func:`spin.fast.estimate_fast` on ``ev`` with its searches faked: the whole window turns 13 rad
    about the optical axis, part ``k`` (1, 2, ...) answers ``part_answer(k, w_whole)``, and a straying
    part defers to ``half_answer``; returns the event counts of the searches and the result."""
    span_s = float(ev.tau_s[0] - ev.tau_s[-1])
    w_whole = np.array([0.0, 0.0, 13.0 / span_s])
    calls = []

    def fake_window(events, velocity_px_s, assess=True, **_):
        calls.append(len(events))
        w = w_whole if len(calls) == 1 else part_answer(len(calls) - 1, w_whole)
        return fast.FastResult(w, np.zeros(2), 1.0, True, 1.0 if assess else float("nan"), None, 1, 1, 10, 1, 1)

    monkeypatch.setattr(fast, "estimate_window", fake_window)
    monkeypatch.setattr(fast, "_half_answer", half_answer)
    return calls, fast.estimate_fast(ev, (0.0, 0.0))


def test_window_over_many_turns_is_checked_on_quarters(monkeypatch, ball):
    ev, _ = ball
    # the third quarter aliases (twice the speed)
    calls, res = _many_turns(monkeypatch, ev, lambda k, w: w * (2.0 if k == 3 else 1.0),
                             lambda half, own, whole, **_: own.w_rad_s)
    assert len(calls) == 5 and sum(calls[1:]) == len(ev)
    assert res.confidence < 0.5


@pytest.mark.parametrize("found_alone", [0, 1, 2])
def test_quarters_agreeing_only_through_the_whole_are_no_check(monkeypatch, ball, found_alone):
    # every quarter's own search lands 30 deg off, but the whole's answer refined on each quarter
    # scores as high there: the quarters then agree only through it (a sparse or symmetric texture
    # over many turns); two quarters that find it on their own restore the trust, one does not
    ev, _ = ball
    calls, res = _many_turns(monkeypatch, ev, lambda k, w: w if k <= found_alone else _rotated(w, 30.0),
                             lambda half, own, whole, **_: whole.w_rad_s)
    assert len(calls) == 5
    assert res.axis_sigma_deg == fast.SIGMA_FLOOR_DEG  # the parts all read the whole's answer
    if found_alone >= 2:
        assert res.confidence >= 0.5
    else:
        assert res.confidence <= 0.25


def test_the_circle_s_uncertainty_goes_into_the_spin_s():
    """A radius a few % too large lifts the events onto too large a sphere and moves the rate; given the
    circle's uncertainty (the track's sigma_px) the estimate's sigma covers that, and a circle known
    too roughly for the rate to be within 5 % takes the trust away."""
    events, truth = sim.spinning_ball("volleyball", rps=100, axis=(0.3, -0.5, 0.8), radius_px=40, n_events=20_000,
                                      seed=2, threshold=0.6)
    c, r = truth["center"], truth["radius_px"]
    exact, off = spin.estimate_spin(events, c, r), spin.estimate_spin(events, c, 1.05 * r)  # 2 px out
    assert abs(exact.rps / truth["rps"] - 1) < 0.01 and abs(off.rps / exact.rps - 1) > 0.015
    told = spin.estimate_spin(events, c, 1.05 * r, circle_sigma_px=0.04 * r)
    rate_err_pct = abs(100 * (off.rps / truth["rps"] - 1))
    assert 2 * off.rps_sigma_pct < rate_err_pct < 2 * told.rps_sigma_pct  # covered only with the circle's share
    assert told.rps == off.rps and told.axis_sigma_deg > off.axis_sigma_deg  # the same answer, its sigma wider
    unknown = spin.estimate_spin(events, c, r, circle_sigma_px=float("nan"))
    assert (unknown.rps, unknown.confidence, unknown.rps_sigma_pct) == (exact.rps, exact.confidence, exact.rps_sigma_pct)
    # the trust: full while the circle's share of the rate's sigma is at most 1.5 %, none from 2.5 %
    sure = replace(exact, confidence=1.0)
    for sigma_px, confidence in ((0.2, 1.0), (0.04 * r, 0.0), (2.0 / CIRCLE_RATE_PER_PCT * r / 100, 0.5)):
        got = with_circle_sigma(sure, r, sigma_px)
        assert got.confidence == pytest.approx(confidence)
        rate_share = CIRCLE_RATE_PER_PCT * 100 * sigma_px / r
        assert got.rps_sigma_pct == pytest.approx(math.hypot(exact.rps_sigma_pct, rate_share))
