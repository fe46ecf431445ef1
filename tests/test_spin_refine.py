"""Local maximisation: starts refined together in one pass match starts refined alone."""

import numpy as np

import sim
from spin.estimate import prepare
from spin.objective import IweGeometry, contrast
from spin.refine import maximise

AXIS = np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81])


def _ball():
    events, truth = sim.spinning_ball("volleyball", rps=60, axis=AXIS, radius_px=40, n_events=6000, seed=2,
                                      threshold=0.3)
    ev, _ = prepare(events, truth["center"], truth["radius_px"], rim_fraction=0.95, dither=True)
    return ev, truth["axis"] * truth["omega_rad_s"]


def test_starts_refined_together_match_starts_refined_alone():
    ev, w_true = _ball()
    geo = IweGeometry(ev.radius_px, 0.5, 1.0)
    starts = [w_true * 1.04 + [15.0, -10.0, 0.0], w_true * 0.96 - [0.0, 12.0, 8.0], -w_true]
    together = maximise(ev, starts, (0.0, 0.0), geo, max_iterations=10)
    for start, m in zip(starts, together):
        alone = maximise(ev, [start], (0.0, 0.0), geo, max_iterations=10)[0]
        assert np.allclose(m.w_rad_s, alone.w_rad_s, rtol=1e-3)
        assert m.n_evaluations == alone.n_evaluations
        assert m.contrast > contrast(ev, start, (0.0, 0.0), geo, gradient=False)  # it climbed
    # the two starts near the truth end near it, above the reversed spin
    for m in together[:2]:
        assert np.degrees(np.arccos(np.dot(m.w_rad_s, w_true) / np.linalg.norm(m.w_rad_s) / np.linalg.norm(w_true))) < 3
        assert m.contrast > together[2].contrast


def test_a_start_that_reaches_the_first_one_stops():
    ev, w_true = _ball()
    geo = IweGeometry(ev.radius_px, 0.5, 1.0)
    starts = [w_true * 1.02, w_true * 0.85 + [5.0, 8.0, -6.0]]

    def same(a, b):
        return np.linalg.norm(a - b) < 0.05 * np.linalg.norm(b)

    free = maximise(ev, starts, (0.0, 0.0), geo, max_iterations=10)
    stopped = maximise(ev, starts, (0.0, 0.0), geo, max_iterations=10, stop_same=same)
    assert np.allclose(stopped[0].w_rad_s, free[0].w_rad_s)  # the first start is never stopped
    assert stopped[1].n_evaluations < free[1].n_evaluations and not stopped[1].success
    assert stopped[1].stopped and not stopped[0].stopped and not free[1].stopped
    assert stopped[1].contrast <= free[1].contrast + 1e-12
