"""Detection building blocks and the tracker on simple synthetic events.

The inputs are drawn directly (uniform points on a disk or near a rim, noise,
hot pixels, an elongated blob), not rendered: they check the geometry and the
logic, the simulator-based tests check realism.
"""

import numpy as np
import pytest

from capture.events import Track, empty_events, make_events
from detect import BallTracker, track_ball
from detect.event_detector import density_filter, find_candidates, fit_circle
from detect.hot_pixels import HotPixelMap
from detect.kalman import CircleKalman
from detect.tracker import _box_pixels, _continues, _on_a_stem, _surrounded, _touched
from detect.event_detector import CircleFit

W, H = 320, 240


def _disk(rng, n, cx, cy, r, ring=False):
    a = rng.uniform(0, 2 * np.pi, n)
    rr = r - rng.uniform(0, 1.0, n) if ring else r * np.sqrt(rng.uniform(0, 1, n))
    return cx + rr * np.cos(a), cy + rr * np.sin(a)


def _ball_events(rng, t0, t1, c0, v, r, rate=2e6, g=0.0, w=W, h=H):
    n = int(rate * (t1 - t0) * 1e-6)
    t = np.sort(rng.integers(t0, t1, n))
    x, y = _disk(rng, n, 0.0, 0.0, r)
    dt = (t - t0) * 1e-6
    x = np.floor(x + c0[0] + v[0] * dt + 0.5)
    y = np.floor(y + c0[1] + v[1] * dt + 0.5 * g * dt * dt + 0.5)
    ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
    return t[ok], x[ok], y[ok]


def _clutter(rng, t0, t1, *, noise_rate=2e5, hot=10, blob=True):
    parts = []
    n = int(noise_rate * (t1 - t0) * 1e-6)
    parts.append((rng.integers(t0, t1, n), rng.integers(0, W, n), rng.integers(0, H, n)))
    hx, hy = rng.integers(0, W, hot), rng.integers(0, H, hot)
    n = int(hot * 1000 * (t1 - t0) * 1e-6)
    k = rng.integers(0, hot, n)
    parts.append((rng.integers(t0, t1, n), hx[k], hy[k]))
    if blob:  # player-like: tall, elongated, dense, slowly moving
        n = int(1.5e6 * (t1 - t0) * 1e-6)
        t = rng.integers(t0, t1, n)
        x = np.rint(250 + rng.normal(0, 10, n) - 200 * (t - t0) * 1e-6)
        y = np.rint(150 + rng.normal(0, 35, n))
        ok = (x >= 0) & (x < W) & (y >= 0) & (y < H)
        parts.append((t[ok], x[ok], y[ok]))
    return parts


def _events(parts, seed=0):
    t = np.concatenate([p[0] for p in parts]).astype(np.int64)
    x = np.concatenate([p[1] for p in parts]).astype(np.int64)
    y = np.concatenate([p[2] for p in parts]).astype(np.int64)
    o = np.argsort(t, kind="stable")
    return make_events(t[o], x[o], y[o], np.random.default_rng(seed).integers(0, 2, len(t)))


def _truth(t_us, c0, v, t0=0):
    dt = (np.asarray(t_us) - t0) * 1e-6
    return c0[0] + v[0] * dt, c0[1] + v[1] * dt


def test_sector_tops_are_each_sectors_kth_and_deepest_outermost():
    from detect._kernels import sector_tops

    rng = np.random.default_rng(5)
    x, y = np.rint(rng.normal(50, 12, 3000)), np.rint(rng.normal(40, 12, 3000))  # pixels: equal radii abound
    cx, cy, n_sectors, k, depth = 50.3, 39.8, 24, 3, 7
    counts, kth, kth_rho2, deep_rho2 = sector_tops(x, y, cx, cy, n_sectors, k, depth)
    rho2 = (x - cx) ** 2 + (y - cy) ** 2
    sector = ((np.arctan2(y - cy, x - cx) + np.pi) * (n_sectors / (2 * np.pi))).astype(np.int64) % n_sectors
    assert np.array_equal(counts, np.bincount(sector, minlength=n_sectors))
    for s in range(n_sectors):
        idx = np.flatnonzero(sector == s)
        ranked = idx[np.lexsort((idx, -rho2[idx]))]  # outermost first; of equal radii the earlier event
        assert kth[s] == ranked[k - 1] and kth_rho2[s] == rho2[ranked[k - 1]]
        assert deep_rho2[s] == rho2[ranked[depth - 1]]


@pytest.mark.parametrize("n_sectors", [12, 13, 26, 32])
def test_sector_tops_places_events_on_a_quadrant_in_the_sector_holding_it(n_sectors):
    from detect._kernels import sector_tops

    # straight left, down, right and up of the centre: angles (+ pi) 0, pi/2, pi, 3 pi/2 (float formulas
    # put some of these one sector early)
    x, y = np.array([40.0, 50.0, 60.0, 50.0]), np.array([50.0, 40.0, 50.0, 60.0])
    counts = [sector_tops(x[i:i + 1], y[i:i + 1], 50.0, 50.0, n_sectors, 1, 1)[0] for i in range(4)]
    for quarter, c in enumerate(counts):
        expected = quarter * n_sectors // 4  # the sector holding the angle quarter * pi/2
        assert np.flatnonzero(c).tolist() == [expected]


def test_sector_tops_keeps_every_event_in_its_sectors_on_edge_inputs():
    from detect._kernels import sector_tops

    # just below straight left of the centre the pseudo-angle rounds to 4.0 (the last sector's end)
    counts, kth, _, _ = sector_tops(np.array([0.0, 0.0]), np.array([1e-17, 1e-17]), 1.0, 0.0, 12, 1, 2)
    assert counts.tolist() == [0] * 11 + [2] and kth[11] == 0
    # a NaN centre: every event still counted in some sector (none written past the arrays)
    x, y = np.arange(5.0), np.arange(5.0)
    assert sector_tops(x, y, np.nan, 0.0, 12, 1, 2)[0].sum() == len(x)
    assert sector_tops(x, y, np.inf, -np.inf, 12, 1, 2)[0].sum() == len(x)


@pytest.mark.parametrize("ring", [False, True])
@pytest.mark.parametrize("r", [8.0, 30.0])
def test_fit_circle_on_disk_and_rim(ring, r):
    rng = np.random.default_rng(1)
    x, y = _disk(rng, int(15 * r * r), 100.3, 80.6, r, ring=ring)
    if ring:  # a translating ball fires at its leading and trailing rims only
        a = np.arctan2(y - 80.6, x - 100.3)
        keep = np.abs(np.cos(a)) > 0.5
        x, y = x[keep], y[keep]
    fit = fit_circle(np.rint(x), np.rint(y), center0=(x.mean() + 2, y.mean() - 2))
    assert fit is not None
    assert abs(fit.cx - 100.3) < 0.4 and abs(fit.cy - 80.6) < 0.4
    assert abs(fit.r - r) < 0.6
    assert fit.score > 0.4
    # the share of events well inside the rim: about 0.7^2 of a uniformly filled disc, none of a rim
    assert fit.disc_fill < 0.02 if ring else abs(fit.disc_fill - 0.49) < 0.06


def test_fit_circle_scores_an_elongated_blob_low():
    rng = np.random.default_rng(2)
    x = rng.normal(100, 8, 5000)
    y = rng.normal(100, 30, 5000)
    fit = fit_circle(np.rint(x), np.rint(y), center0=(100, 100))
    assert fit is None or fit.score < 0.3


def test_density_filter_drops_isolated_events():
    rng = np.random.default_rng(3)
    x, y = _disk(rng, 2000, 50, 50, 10)
    xn, yn = np.array([150.0, 170.0, 190.0]), np.array([10.0, 30.0, 60.0])
    keep = density_filter(np.r_[np.rint(x), xn], np.r_[np.rint(y), yn])
    assert keep[:2000].mean() > 0.99 and not keep[2000:].any()


def test_find_candidates_sizes_and_ranks_clusters():
    rng = np.random.default_rng(4)
    bx, by = _disk(rng, 3000, 100, 100, 12)
    nx, ny = rng.integers(0, W, 300), rng.integers(0, H, 300)
    x = np.r_[np.rint(bx), nx].astype(int)
    y = np.r_[np.rint(by), ny].astype(int)
    boxes = find_candidates(x, y, width=W, height=H, r_range=(5, 40))
    assert len(boxes) >= 1
    x0, y0, x1, y1 = boxes[0]
    assert x0 <= 88 and x1 >= 112 and y0 <= 88 and y1 >= 112 and x1 - x0 < 45
    assert find_candidates(x, y, width=W, height=H, r_range=(30, 40)) == []  # too small for that range


def test_density_map_counts_and_cluster_statistics_match_numpy():
    from detect._kernels import cell_counts, cluster_stats

    rng = np.random.default_rng(6)
    x, y = rng.integers(0, 641, 30_000).astype(np.int32), rng.integers(0, 481, 30_000).astype(np.int32)
    for cell in (4, 6):  # shifts and divisions
        gw, gh = -(-641 // cell), -(-481 // cell)
        expect = np.bincount((y // cell) * gw + x // cell, minlength=gw * gh).reshape(gh, gw)
        np.testing.assert_array_equal(cell_counts(x, y, cell, gw, gh), expect)
    labels = rng.integers(0, 5, (30, 40)).astype(np.int32)
    labels[:, :3] = 0
    labels[labels == 3] = 0  # a label without cells
    dens = rng.integers(0, 9, (30, 40)).astype(np.float32)
    sums, stats = cluster_stats(labels, dens, 5)
    for lab in range(5):
        cy, cx = np.nonzero(labels == lab)
        if lab in (0, 3):
            assert sums[lab] == 0 and not stats[lab].any()
            continue
        assert sums[lab] == dens[labels == lab].sum()
        np.testing.assert_array_equal(stats[lab], [cx.min(), cy.min(), np.ptp(cx) + 1, np.ptp(cy) + 1])


def test_box_selection_matches_float_comparisons():
    from detect._kernels import box_select

    rng = np.random.default_rng(3)
    x = rng.integers(0, 640, 50_000).astype(np.int32)
    y = rng.integers(0, 480, 50_000).astype(np.int32)
    t = np.arange(len(x), dtype=np.int64)
    for x0, x1, y0, y1 in [(100.3, 180.0, 50.0, 90.7), (-30.5, 20.2, 470.1, 900.0), (-1e9, 1e9, -1e9, 1e9),
                           (300.0, 300.5, 10.0, 20.0), (700.0, 800.0, 10.0, 20.0), (np.nan, 10.0, 0.0, 10.0),
                           (-np.inf, np.inf, -np.inf, 240.0), (-0.5, 639.5, -1.0, 480.0), (-20.0, -3.0, 0.0, 9.0)]:
        expect = np.flatnonzero((x > x0) & (x < x1) & (y > y0) & (y < y1))
        near, tk, xk, yk = box_select(t, x, y, *_box_pixels(x0, x1, y0, y1, 640, 480), np.zeros(0, bool), 640)
        np.testing.assert_array_equal(near, expect)
        for a, b in zip((tk, xk, yk), (t, x, y)):
            np.testing.assert_array_equal(a, b[expect])


def test_compiled_selections_match_numpy():
    from capture.events import EVENT_DTYPE
    from detect._kernels import box_select, kept_events, moved_near, split_checked

    rng = np.random.default_rng(5)
    n, w, h = 40_000, 640, 480
    ev = np.zeros(n, EVENT_DTYPE)
    ev["t"] = np.sort(rng.integers(0, 10_000, n))
    ev["x"], ev["y"] = rng.integers(0, w, n), rng.integers(0, h, n)
    t, x, y, back, x_max, y_max = split_checked(ev["t"], ev["x"], ev["y"], -1)
    assert (t.dtype, x.dtype, y.dtype, t.flags.c_contiguous) == (np.int64, np.int32, np.int32, True)
    np.testing.assert_array_equal(t, ev["t"])
    np.testing.assert_array_equal(x, ev["x"])
    assert (back, x_max, y_max) == (-1, ev["x"].max(), ev["y"].max())
    assert split_checked(ev["t"], ev["x"], ev["y"], int(ev["t"][0]) + 1)[3] == 0  # behind the batch before
    late = ev.copy()
    late["t"][[777, 900]] = -5
    assert split_checked(late["t"], late["x"], late["y"], -1)[3] == 777  # the first one going back
    assert split_checked(ev["t"][:0], ev["x"][:0], ev["y"][:0], 0)[3:] == (-1, -1, -1)

    hot = rng.random(w * h) < 0.2
    for bounds in [(100.3, 180.0, 50.0, 90.7), (-30.5, 20.2, 470.1, 900.0), (-1e9, 1e9, -1e9, 1e9),
                   (np.nan, 10.0, 0.0, 10.0), (700.0, 800.0, 10.0, 20.0)]:
        lo_x, hi_x, lo_y, hi_y = _box_pixels(*bounds, w, h)
        x0, x1, y0, y1 = bounds
        box = np.flatnonzero((x > x0) & (x < x1) & (y > y0) & (y < y1))
        for mask in (hot, np.zeros(0, bool)):
            near, tk, xk, yk = box_select(t, x, y, lo_x, hi_x, lo_y, hi_y, mask, w)
            np.testing.assert_array_equal(near, box)
            kept = box[~mask[y[box] * w + x[box]]] if len(mask) else box
            for a, b in zip((tk, xk, yk), (t, x, y)):
                np.testing.assert_array_equal(a, b[kept])
    keep = rng.random(n) < 0.5
    for k, mask, expect in [(keep, hot, keep & ~hot[y * w + x]), (np.zeros(0, bool), hot, ~hot[y * w + x]),
                            (keep, np.zeros(0, bool), keep)]:
        for a, b in zip(kept_events(t, x, y, k, mask, w), (t, x, y)):
            np.testing.assert_array_equal(a, b[expect])

    m, vx, vy, cx, cy, reach = 5_000, 3000.0, -1500.0, 320.0, 240.0, 90.0
    xc, yc, tn, xn, yn = moved_near(t, x, y, m, vx, vy, cx, cy, reach)
    dt_s = (t - m) * 1e-6
    np.testing.assert_allclose(xc, x - vx * dt_s, atol=1e-9)
    np.testing.assert_allclose(yc, y - vy * dt_s, atol=1e-9)
    near = np.hypot(xc - cx, yc - cy) < reach
    assert 0 < near.sum() < n
    for a, b in zip((tn, xn, yn), (t, x, y)):
        np.testing.assert_array_equal(a, b[near])


def _surrounded_numpy(x, y, cx, cy, r, n_sectors, step):
    """The ring count in NumPy, as the tracker computed it before it was compiled."""
    x, y = x[::step], y[::step]
    dx, dy = np.subtract(x, cx, dtype=np.float32), np.subtract(y, cy, dtype=np.float32)
    d2 = dx * dx
    d2 += dy * dy
    dens_in = np.count_nonzero(d2 < np.float32(r * r)) / (np.pi * r * r)
    r0, r1 = 1.15 * r + 1.0, 1.5 * r + 2.0
    ring = np.flatnonzero((d2 > np.float32(r0 * r0)) & (d2 < np.float32(r1 * r1)))
    angle = np.arctan2(dy.take(ring), dx.take(ring))
    sector = ((angle + np.float32(np.pi)) * np.float32(n_sectors / (2 * np.pi))).astype(np.int64) % n_sectors
    dens_ring = np.bincount(sector, minlength=n_sectors) / (np.pi * (r1 * r1 - r0 * r0) / n_sectors)
    return float(np.mean(dens_ring >= 0.3 * dens_in))


def test_compiled_ring_count_matches_numpy():
    from detect._kernels import surrounded

    rng = np.random.default_rng(7)
    for case in range(40):
        cx, cy, r = 60.0 + rng.uniform(0, 1), 50.0 + rng.uniform(0, 1), rng.uniform(5, 25)
        n = int(rng.integers(50, 3000))
        x, y = rng.uniform(cx - 3 * r, cx + 3 * r, n), rng.uniform(cy - 3 * r, cy + 3 * r, n)
        # points exactly on the disk's and the ring's edges, and straight left of the centre
        edge = np.array([r, 1.15 * r + 1.0, 1.5 * r + 2.0])
        x[:3], y[:3] = cx + edge, cy
        x[3:6], y[3:6] = cx - edge, cy
        for xs, ys in ((x, y), (np.rint(x).astype(np.int32), np.rint(y).astype(np.int32))):
            for step in (1, 3):
                got = surrounded(xs, ys, cx, cy, r, 12, step)
                assert got == _surrounded_numpy(xs, ys, cx, cy, r, 12, step), (case, step, xs.dtype)


def test_loaded_kernels_serve_a_tracker_without_compiling():
    import sim
    from detect import BallTracker, _kernels, track_ball

    _kernels.load()
    kernels = [v for v in vars(_kernels).values() if hasattr(v, "signatures")]
    before = {k.py_func.__name__: len(k.signatures) for k in kernels}
    rec = sim.flight(width=160, height=120, radius_px=10, duration_s=0.05, seed=3, hot_pixels=5)
    ev = rec.events.copy()
    ev.setflags(write=False)
    assert len(track_ball(ev, width=160, height=120).t_us) > 0
    for one in (ev[:1], ev[1:2]):  # a one-event batch: contiguous field views, aligned or not
        BallTracker(160, 120).update(one)
    assert {k.py_func.__name__: len(k.signatures) for k in kernels} == before


def test_surrounded_counts_the_ring_sectors_that_hold_events():
    rng = np.random.default_rng(4)
    fit = CircleFit(cx=100.0, cy=100.0, r=20.0, score=1.0, sigma_px=0.1, n_events=0)
    disk = rng.uniform(-1, 1, (2, 400_000)) * 20
    disk = disk[:, np.hypot(*disk) < 20] + 100.0
    # events in the ring (26-32 px) on the right half only, as dense as the disk
    a = rng.uniform(-np.pi / 2, np.pi / 2, 300_000)
    rho = np.sqrt(rng.uniform(26 ** 2, 32 ** 2, len(a)))
    ring = np.stack([100 + rho * np.cos(a), 100 + rho * np.sin(a)])
    x, y = np.concatenate([disk[0], ring[0]]), np.concatenate([disk[1], ring[1]])
    order = rng.permutation(len(x))
    assert _surrounded(x[order], y[order], fit) == pytest.approx(0.5, abs=1 / 12)
    assert _surrounded(disk[0], disk[1], fit) == 0.0



def _strip(rng, n, x0, x1, y0, y1):
    return rng.uniform(x0, x1, n), rng.uniform(y0, y1, n)


def test_a_round_head_on_a_handle_is_on_a_stem_and_a_ball_beside_an_arm_is_not():
    """_on_a_stem: a disk with a handle reaching out of it (a racket's or a bat's head, a fifth of
    its width) is; the disk alone, the disk beside a wide arm passing it, a hot pixel in its ring, and a
    disk that is all that is there are not."""
    rng = np.random.default_rng(11)
    fit = CircleFit(cx=100.0, cy=100.0, r=30.0, score=1.0, sigma_px=0.1, n_events=0)
    head = _disk(rng, 20_000, 100, 100, 30)
    density = 20_000 / (np.pi * 30 ** 2)
    handle = _strip(rng, int(density * 6 * 40), 97, 103, 128, 168)  # 6 px wide, down from the rim
    arm = _strip(rng, int(density * 40 * 90), 136, 176, 55, 145)  # 40 px wide, 6 px beside the rim
    hot = (np.full(3000, 100.0), np.full(3000, 140.0))
    join = lambda *parts: (np.concatenate([q[0] for q in parts]), np.concatenate([q[1] for q in parts]))
    assert _on_a_stem(*join(head, handle), fit)
    assert not _on_a_stem(*head, fit)
    assert not _on_a_stem(*join(head, arm), fit)
    assert not _on_a_stem(*join(head, hot), fit)
    assert _on_a_stem(*join(head, handle, arm), fit)  # (the arm holding it does not hide the handle)


def test_the_sides_where_something_touches_a_ball_are_told_apart():
    """_touched: a dense blob against the ball's right side marks the directions to its right (and
    none on the left); a ball alone, none."""
    rng = np.random.default_rng(12)
    ball = _disk(rng, 10_000, 100, 100, 20)
    blob = _disk(rng, 60_000, 100 + 20 + 3 + 40, 100, 40)  # a racket's head 3 px from the rim
    x, y = np.concatenate([ball[0], blob[0]]), np.concatenate([ball[1], blob[1]])
    touched = _touched(x, y, 100.0, 100.0, 20.0)
    assert touched is not None and 3 <= touched.sum() <= 12
    angle = -np.pi + (np.flatnonzero(touched) + 0.5) * 2 * np.pi / len(touched)
    assert np.all(np.cos(angle) > 0)  # all to the right
    assert _touched(*ball, 100.0, 100.0, 20.0) is None


def test_thin_edges_beside_a_textured_ball_touch_it_but_a_sparse_ring_all_round_does_not():
    """_touched: an arm's two thin edges ending beside a ball that fires all over its disk are far less
    dense than the disk's band, yet they touch it (the rest of its ring is empty); the same density of
    events all round the ring (a busy background) touches no side, nor do such edges beside a plain ball."""
    rng = np.random.default_rng(13)
    ball = _disk(rng, 4000, 100, 100, 10)
    edges = [np.r_[rng.uniform(111, 140, 300), rng.uniform(111, 140, 300)],
             np.r_[np.full(300, 97.0), np.full(300, 105.0)] + rng.normal(0, 0.3, 600)]
    x, y = np.concatenate([ball[0], edges[0]]), np.concatenate([ball[1], edges[1]])
    touched = _touched(x, y, 100.0, 100.0, 10.0)
    assert touched is not None and touched.sum() <= 8
    angle = -np.pi + (np.flatnonzero(touched) + 0.5) * 2 * np.pi / len(touched)
    assert np.all(np.cos(angle) > 0.5)  # to the right, where the edges are
    phi, rad = rng.uniform(-np.pi, np.pi, 1000), np.sqrt(rng.uniform(12.5 ** 2, 17.0 ** 2, 1000))
    x2, y2 = np.r_[ball[0], 100 + rad * np.cos(phi)], np.r_[ball[1], 100 + rad * np.sin(phi)]
    assert _touched(x2, y2, 100.0, 100.0, 10.0) is None
    # a plain ball firing at its rim only (its disk sparse against its band): trails and noise beside
    # it are not taken for an arm's edges
    rim = _disk(rng, 2000, 100, 100, 10, ring=True)
    assert _touched(np.r_[rim[0], edges[0]], np.r_[rim[1], edges[1]], 100.0, 100.0, 10.0) is None


def test_hot_pixel_map_flags_lonely_busy_pixels_only():
    rng = np.random.default_rng(5)
    hm = HotPixelMap(W, H)
    for _ in range(5):
        bx, by = _disk(rng, 4000, 100, 100, 15)
        x = np.r_[np.rint(bx), np.full(20, 200)].astype(int)
        y = np.r_[np.rint(by), np.full(20, 50)].astype(int)
        hm.update(y * W + x)
    hot = hm.hot[np.array([50, 100, 95]) * W + np.array([200, 100, 105])]
    assert hot.tolist() == [True, False, False]


@pytest.mark.parametrize("decay, n_updates, hot_most", [(0.9, 300, 4), (0.5, 1100, 9)])
def test_hot_pixel_map_follows_its_decaying_count_model_over_many_updates(decay, n_updates, hot_most):
    # the map keeps its counts divided by the decay so far and rescales them now and then: over many
    # updates (at 0.5, far past the decay's float64 underflow) its mask is the model's, recomputed here
    # on every pixel
    rng = np.random.default_rng(9)
    w, h, min_count, ratio = 40, 30, 6.0, 8.0
    hm = HotPixelMap(w, h, decay=decay, min_count=min_count, ratio=ratio)
    counts = np.zeros((h, w))
    hot_px = rng.integers(0, w * h, 6)
    for k in range(n_updates):
        busy = rng.integers(0, w * h, rng.integers(0, 400))  # noise and, now and then, a blob
        if k % 7 == 0:
            busy = np.r_[busy, (rng.integers(5, 25) * w + rng.integers(5, 35) + rng.integers(-2, 3, 300)
                                + w * rng.integers(-2, 3, 300))]
        pixel = np.r_[busy, np.repeat(hot_px[: 1 + k % 6], rng.integers(0, hot_most))]
        hm.update(pixel)
        counts = decay * counts + np.bincount(pixel, minlength=w * h).reshape(h, w)
        padded = np.pad(counts, 1)
        nb = sum(padded[1 + dy:h + 1 + dy, 1 + dx:w + 1 + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                 if dy or dx)
        expected = (counts >= min_count) & (counts >= ratio * nb / 8.0)
        assert np.array_equal(hm.hot.reshape(h, w), expected), k
    assert 0 < expected.sum() <= 6


def test_hot_pixel_map_refuses_thresholds_its_update_cannot_keep():
    for kw in ({"decay": 1.5}, {"decay": -0.1}, {"min_count": 0.0}):
        with pytest.raises(ValueError, match=next(iter(kw))):
            HotPixelMap(10, 10, **kw)


def test_compiled_kalman_algebra_is_the_textbook_filter():
    from detect._kernels import kf_mahalanobis, kf_predict, kf_update, rts_gain

    rng = np.random.default_rng(11)
    h = np.zeros((3, 7))
    h[0, 0] = h[1, 1] = h[2, 6] = 1.0
    for _ in range(20):
        f = np.eye(7) + rng.normal(0, 0.01, (7, 7))
        a, b = rng.normal(size=(7, 7)), rng.normal(size=(7, 7))
        p, q = a @ a.T + np.eye(7), 0.1 * (b @ b.T)
        x, z, r_var = rng.normal(size=7), rng.normal(size=3), rng.uniform(0.1, 2.0, 3)
        xp, pp = f @ x, f @ p @ f.T + q
        np.testing.assert_allclose(kf_predict(f, q, x, p)[0], xp, rtol=1e-12)
        np.testing.assert_allclose(kf_predict(f, q, x, p)[1], pp, rtol=1e-12)
        k = np.linalg.solve(h @ pp @ h.T + np.diag(r_var), h @ pp).T
        p_post = (np.eye(7) - k @ h) @ pp
        out = kf_update(f, q, x, p, z, r_var)
        np.testing.assert_allclose(out[0], xp, rtol=1e-12)
        np.testing.assert_allclose(out[2], xp + k @ (z - h @ xp), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(out[3], 0.5 * (p_post + p_post.T), rtol=1e-9, atol=1e-12)
        np.testing.assert_array_equal(out[3], out[3].T)
        nu, s = z[:2] - xp[:2], pp[:2, :2] + np.eye(2) * r_var[0]
        assert kf_mahalanobis(xp, pp, z[0], z[1], r_var[0]) == pytest.approx(nu @ np.linalg.solve(s, nu), rel=1e-10)
        singular = p.copy()
        singular[4, :] = singular[:, 4] = 0.0  # a pinned state, as in the "cv" model
        np.testing.assert_allclose(rts_gain(p, f, singular), p @ f.T @ np.linalg.pinv(singular), rtol=1e-8,
                                   atol=1e-12)


def test_kalman_recovers_constant_acceleration_and_smooths():
    rng = np.random.default_rng(6)
    t = np.arange(0, 40_000, 2000)
    ts = t * 1e-6
    x = 10 + 3000 * ts + 0.5 * 8000 * ts ** 2
    y = 200 - 1000 * ts
    kf = CircleKalman(0, (x[0], y[0], 20.0), velocity_px_s=(2500, -800), sigma_px=0.5)
    zs = [(x[k] + rng.normal(0, 0.3), y[k] + rng.normal(0, 0.3), 20.0) for k in range(len(t))]
    for k in range(1, len(t)):
        kf.update(int(t[k]), zs[k], 0.3, 0.3)
    assert kf.x[2] == pytest.approx(3000 + 8000 * ts[-1], abs=60)
    tt, xs = kf.smoothed()
    assert np.array_equal(tt, t)
    # a range of updates smoothed with the updates before its end only: as if the flight stopped there
    stopped = CircleKalman(0, (x[0], y[0], 20.0), velocity_px_s=(2500, -800), sigma_px=0.5)
    for k in range(1, 9):
        stopped.update(int(t[k]), zs[k], 0.3, 0.3)
    t5, x5 = kf.smoothed(3, 9)
    np.testing.assert_array_equal(t5, t[3:9])
    np.testing.assert_allclose(x5, stopped.smoothed()[1][3:], rtol=1e-12, atol=1e-9)
    assert np.max(np.abs(x5[:, 0] - xs[3:9, 0])) > 0  # later updates do change the smoothed rows
    assert np.max(np.abs(xs[:, 2] - (3000 + 8000 * ts))) < 80
    assert np.max(np.abs(xs[:, 3] + 1000)) < 40


def test_tracks_ball_among_noise_hot_pixels_and_blob():
    rng = np.random.default_rng(7)
    c0, v = (20.0, 120.0), (3000.0, -400.0)
    ev = _events([_ball_events(rng, 0, 80_000, c0, v, 12.0)] + _clutter(rng, 0, 80_000))
    tr = track_ball(ev, width=W, height=H, r_range=(5, 40))
    assert len(tr) > 25 and len(tr.flight_ids()) == 1
    ex, ey = _truth(tr.t_us, c0, v)
    err = np.hypot(tr.cx - ex, tr.cy - ey)
    assert np.median(err) < 0.5 and err.max() < 2.0
    assert np.median(np.abs(tr.r - 12.0)) < 0.7
    assert np.median(np.abs(tr.vx - v[0])) < 100 and np.median(np.abs(tr.vy - v[1])) < 100
    # never on the blob
    assert np.all(np.hypot(tr.cx - 250, tr.cy - 150) > 40)


@pytest.mark.parametrize("model", ["ca", "cv"])
def test_velocity_follows_image_gravity(model):
    g = 40_000.0  # px/s^2: strong, so that ignoring it would show
    rng = np.random.default_rng(14)
    ev = _events([_ball_events(rng, 0, 60_000, (30.0, 60.0), (3000.0, -1500.0), 12.0, g=g)])
    tr = track_ball(ev, width=W, height=H, r_range=(5, 40), model=model, gravity_px_s2=(0.0, g))
    assert len(tr.flight_ids()) == 1 and len(tr) > 20
    dt = tr.t_us * 1e-6
    assert np.median(np.abs(tr.vy - (-1500.0 + g * dt))) < 40
    assert np.median(np.abs(tr.cy - (60.0 - 1500.0 * dt + 0.5 * g * dt * dt))) < 0.3


def test_empty_and_ball_free_inputs_give_empty_tracks():
    assert len(track_ball(empty_events(), width=W, height=H)) == 0
    rng = np.random.default_rng(8)
    ev = _events(_clutter(rng, 0, 60_000))
    tr = track_ball(ev, width=W, height=H, r_range=(5, 40))
    assert isinstance(tr, Track) and len(tr) == 0


def test_leave_and_reenter_gives_two_flights():
    rng = np.random.default_rng(9)
    a = _ball_events(rng, 0, 60_000, (200.0, 100.0), (3000.0, 0.0), 10.0)  # leaves at x=320 after 40 ms
    b = _ball_events(rng, 90_000, 150_000, (330.0, 160.0), (-3000.0, -300.0), 10.0)  # comes back
    ev = _events([a, b] + _clutter(rng, 0, 150_000, blob=False))
    tr = track_ball(ev, width=W, height=H, r_range=(5, 40))
    ids = tr.flight_ids()
    assert len(ids) == 2
    first, second = tr.select(tr.flight == ids[0]), tr.select(tr.flight == ids[1])
    assert first.t_us.max() < 60_000 <= 90_000 < second.t_us.min()
    assert np.median(first.vx) > 2500 and np.median(second.vx) < -2500


def test_bounce_splits_the_flight():
    rng = np.random.default_rng(10)
    a = _ball_events(rng, 0, 40_000, (60.0, 60.0), (2500.0, 3000.0), 12.0)
    b = _ball_events(rng, 40_000, 80_000, (160.0, 180.0), (2500.0, -3000.0), 12.0)
    tr = track_ball(_events([a, b]), width=W, height=H, r_range=(5, 40))
    ids = tr.flight_ids()
    assert len(ids) == 2
    before, after = tr.select(tr.flight == ids[0]), tr.select(tr.flight == ids[1])
    assert np.median(before.vy) > 2500 and np.median(after.vy) < -2500
    # the 2 ms window holding the bounce is measured on its first and last parts (a few hundred µs
    # each): the first flight reaches the bounce, the next starts within a slice of it (6 ms later
    # when the window's smeared fit was only a miss)
    assert before.t_us.max() >= 40_000 and after.t_us.min() <= 42_000
    for part, v in ((before, (2500.0, 3000.0)), (after, (2500.0, -3000.0))):
        c0 = (60.0, 60.0) if part is before else (160.0, 180.0)
        t0 = 0 if part is before else 40_000
        cx, cy = _truth(part.t_us, c0, v, t0)
        assert np.max(np.hypot(part.cx - cx, part.cy - cy)) < 1.5


def test_no_row_is_stamped_after_the_stream_s_last_event():
    """The stream's last slice ends with its last event (12.5 ms, a quarter into a 2 ms slice): its
    window's row lies within the events (at 13 ms, the nominal slice's middle, before)."""
    rng = np.random.default_rng(13)
    c0, v = (40.0, 100.0), (8000.0, 500.0)
    ev = _events([_ball_events(rng, 0, 12_500, c0, v, 12.0)])
    tr = track_ball(ev, width=W, height=H, r_range=(5, 40))
    assert int(ev["t"][-1]) - 500 <= tr.t_us.max() <= int(ev["t"][-1])
    cx, cy = _truth(tr.t_us, c0, v)
    assert np.max(np.hypot(tr.cx - cx, tr.cy - cy)) < 1.0


def test_streaming_equals_batch():
    rng = np.random.default_rng(11)
    c0, v = (20.0, 120.0), (3000.0, -400.0)
    ev = _events([_ball_events(rng, 0, 60_000, c0, v, 12.0)] + _clutter(rng, 0, 60_000))
    batch = track_ball(ev, width=W, height=H, r_range=(5, 40))
    trk = BallTracker(W, H, r_range=(5, 40))
    live = []
    for chunk in np.array_split(ev, 37):
        live.append(trk.update(chunk))
    whole = trk.finish()
    for c in ("t_us", "cx", "cy", "r", "vx", "flight"):
        np.testing.assert_allclose(getattr(whole, c), getattr(batch, c))
    n_live = sum(len(t) for t in live)
    assert 0 < n_live <= len(whole)
    assert np.all(np.diff(np.concatenate([t.t_us for t in live])) > 0)


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="r_range"):
        BallTracker(W, H, r_range=(10, 5))
    with pytest.raises(ValueError, match="block_us"):
        BallTracker(W, H, slice_us=3000, block_us=20000)
    with pytest.raises(TypeError, match="EVENT_DTYPE"):
        BallTracker(W, H).update(np.zeros(3))
    with pytest.raises(ValueError, match="frame_times_us"):
        track_ball(empty_events(), width=W, height=H, frames=[np.zeros((H, W), np.uint8)])
    with pytest.raises(ValueError, match="model"):
        BallTracker(W, H, model="cj")


def _frames(n, c0, v_px_frame, r, seed=12):
    import cv2

    rng = np.random.default_rng(seed)
    bg = cv2.GaussianBlur(rng.uniform(0, 255, (H, W)).astype(np.float32), (0, 0), 3)
    bg = cv2.normalize(bg, None, 60, 160, cv2.NORM_MINMAX)
    out, truth = [], []
    for k in range(n):
        img = bg.copy()
        cx, cy = c0[0] + v_px_frame[0] * k, c0[1] + v_px_frame[1] * k
        cv2.circle(img, (int(round(cx * 16)), int(round(cy * 16))), int(r * 16), 230, -1, cv2.LINE_AA, shift=4)
        out.append(np.clip(img + rng.normal(0, 3, img.shape), 0, 255).astype(np.uint8))
        truth.append((cx, cy))
    return out, np.array(truth)


def test_frame_detector_finds_drawn_ball_subpixel():
    from detect.frame_detector import FrameDetector

    frames, truth = _frames(8, (40.3, 100.6), (25.0, 5.0), 15)
    fd = FrameDetector((8, 30))
    for k, img in enumerate(frames[:-1]):
        best = fd.detect(img)
        assert best, f"no circle in frame {k}"
        if k >= 4:  # background model warmed up: the ball is the top circle
            assert np.hypot(best[0].cx - truth[k, 0], best[0].cy - truth[k, 1]) < 0.5
            assert abs(best[0].r - 15.5) < 0.6
    roi = fd.detect(frames[-1], roi=(truth[-1, 0] + 5, truth[-1, 1] - 5, 30))
    assert len(roi) >= 1 and np.hypot(roi[0].cx - truth[-1, 0], roi[0].cy - truth[-1, 1]) < 0.5
    assert fd.detect(frames[-1], roi=(250, 30, 20)) == []


def test_frames_are_fused_into_the_track():
    rng = np.random.default_rng(13)
    c0, v = (40.3, 100.6), (2500.0, 500.0)  # 25 px and 5 px per 10 ms frame
    frames, truth = _frames(8, c0, (25.0, 5.0), 15)
    t_frames = np.arange(8) * 10_000 + 500
    ev = _events([_ball_events(rng, 500, 70_500, c0, v, 15.5, rate=1e6)] + _clutter(rng, 0, 75_000, blob=False))
    both = BallTracker(W, H, r_range=(5, 40))
    for img, t in zip(frames, t_frames):
        both.update_frame(img, int(t))
    both.update(ev)
    tr = both.finish()
    assert np.isin(t_frames[4:], tr.t_us).sum() >= 2  # frame updates became rows
    ex, ey = _truth(tr.t_us, c0, v, t0=500)
    assert np.median(np.hypot(tr.cx - ex, tr.cy - ey)) < 0.5


def test_tracker_refuses_bad_input_on_one_line():
    import sim
    from detect import BallTracker, DetectInputError, track_ball

    ev = sim.flight(width=160, height=120, radius_px=10, duration_s=0.05, seed=3).events
    assert len(track_ball(ev[:0], width=160, height=120).t_us) == 0  # empty input: empty track
    shuffled = ev[np.random.default_rng(0).permutation(len(ev))]
    with pytest.raises(DetectInputError, match=r"out of time order: t goes back from \d+ to \d+ µs at index \d+"):
        track_ball(shuffled, width=160, height=120)
    with pytest.raises(DetectInputError, match=r"events reach x=\d+, y=\d+, outside the 80x60 sensor size given"):
        track_ball(ev, width=80, height=60)
    tracker = BallTracker(160, 120)
    tracker.update(ev[len(ev) // 2:])
    with pytest.raises(DetectInputError, match="before the previous batch's last event"):
        tracker.update(ev[: len(ev) // 2])
    assert tracker.last_t_us == int(ev["t"][-1])
    # a frame not in the sensor's geometry (a GoPro frame not yet mapped) is refused, not silently unused
    with pytest.raises(DetectInputError, match=r"frame of shape \(1080, 1920, 3\) is not the 160x120 sensor's size"):
        track_ball(ev, width=160, height=120, frames=[np.zeros((1080, 1920, 3), np.uint8)], frame_times_us=[0])
    tracker.update_frame(np.zeros((120, 160, 3), np.uint8), int(ev["t"][-1]))  # BGR of the sensor's size: taken


def test_sparse_ball_is_tracked_by_joining_slices():
    # a few tens of kev/s in all (a 128x128 sensor, a dim scene): 2 ms hold ~40 ball events, too few
    # for a fit; windows are joined until they hold enough
    rng = np.random.default_rng(21)
    c0, v = (40.0, 120.0), (400.0, -60.0)
    ball = _ball_events(rng, 0, 400_000, c0, v, 12.0, rate=20e3)
    ev = _events([ball] + _clutter(rng, 0, 400_000, noise_rate=5e3, hot=2, blob=False))
    tr = track_ball(ev, width=W, height=H, r_range=(5, 40))
    assert len(tr.flight_ids()) == 1
    assert tr.t_us.max() > 340_000  # the whole flight
    # from its first events on: a row at the first window's first ball event, half a window (12 ms)
    # before the first update, extrapolated back along the chain's velocity
    assert tr.t_us.min() < 1000 and tr.t_us[1] - tr.t_us[0] > 5000
    ex, ey = _truth(tr.t_us, c0, v)
    err = np.hypot(tr.cx - ex, tr.cy - ey)
    assert err[0] < 1.5 and np.median(err) < 1.0 and np.median(np.abs(tr.r - 12.0)) < 1.0
    # with windows capped at one slice the same input gives nothing
    assert len(track_ball(ev, width=W, height=H, r_range=(5, 40), max_window_us=2000)) == 0
    with pytest.raises(ValueError, match="max_window_us"):
        BallTracker(W, H, max_window_us=3000)


def test_a_first_detection_is_continued_from_where_it_was_to_where_its_velocity_predicts():
    # a first detection's velocity is its window's centroid's, which a slow, sparse ball's shading
    # can throw far off: the next detection continues it anywhere along that step (within the
    # usual 0.3 r + 3 px); a longer chain's velocity comes from its displacement and holds
    from dataclasses import replace
    f0 = CircleFit(cx=40.0, cy=60.0, r=16.0, score=0.5, sigma_px=0.2, n_events=300, coverage=0.6)
    at = lambda cx, cy: replace(f0, cx=cx, cy=cy)  # noqa: E731
    first = [(20_000, f0, (240.0, -20.0))]  # 9.6 px in the next 40 ms
    for cx, cy in ((40.5, 60.3), (45.0, 59.5), (49.6, 59.2)):  # unmoved, half way, as predicted
        assert _continues(first, 60_000, at(cx, cy), 128, 128)
    assert not _continues(first, 60_000, at(30.0, 60.0), 128, 128)  # the other way
    assert not _continues(first, 60_000, at(45.0, 70.0), 128, 128)  # off the step
    assert _continues([(60_000, at(41.0, 60.0), (250.0, 0.0))], 100_000, at(41.5, 60.0), 128, 128)
    assert not _continues([*first, (60_000, at(41.0, 60.0), (250.0, 0.0))], 100_000, at(41.5, 60.0), 128, 128)


def test_a_still_ball_whose_lit_side_turns_is_found_in_long_windows():
    # a still plain ball with a light going round it: its rim fires on the lit half only, so the
    # events' centroid drifts (~700 px/s) and moving them along that drift smears the rim; in the
    # long windows of a sparse scene the search also fits them unmoved
    rng = np.random.default_rng(24)
    n = int(20e3 * 0.4)
    t = np.sort(rng.integers(0, 400_000, n))
    a = 2 * np.pi * t / 80_000 + rng.uniform(-np.pi / 2, np.pi / 2, n)
    rr = 14.0 - rng.uniform(0, 1.0, n)
    ball = (t, np.floor(60 + rr * np.cos(a) + 0.5), np.floor(70 + rr * np.sin(a) + 0.5))
    ev = _events([ball] + _clutter(rng, 0, 400_000, noise_rate=3e3, hot=2, blob=False))
    tr = track_ball(ev, width=W, height=H, r_range=(5, 40))
    assert len(tr.flight_ids()) == 1 and tr.t_us.min() < 1000 and tr.t_us.max() > 380_000
    assert np.median(np.hypot(tr.cx - 60, tr.cy - 70)) < 0.5 and abs(np.median(tr.r) - 14.0) < 1.0


def test_ball_touching_an_arm_is_told_apart():
    # a bar (an arm) as dense as the ball, 4 px from its rim and moving with it: one cluster, no
    # circle as a whole
    rng = np.random.default_rng(22)
    c0, v = (60.0, 120.0), (1500.0, 0.0)
    ball = _ball_events(rng, 0, 60_000, c0, v, 10.0)
    n = int(4e6 * 0.06)
    t = np.sort(rng.integers(0, 60_000, n))
    x = np.rint(c0[0] + 10 + 4 + rng.uniform(0, 9, n) + v[0] * t * 1e-6)
    y = np.rint(c0[1] - 30 + rng.uniform(0, 70, n))
    ev = _events([ball, (t, x, y)])
    tr = track_ball(ev, width=W, height=H, r_range=(5, 40))
    assert len(tr) > 25 and len(tr.flight_ids()) == 1
    ex, ey = _truth(tr.t_us, c0, v)
    err = np.hypot(tr.cx - ex, tr.cy - ey)
    assert np.median(err) < 0.5 and np.percentile(err, 90) < 1.0
    assert np.median(np.abs(tr.r - 10.0)) < 1.0


def test_big_ball_is_found_with_the_default_radius_range():
    rng = np.random.default_rng(23)
    c0, v = (200.0, 240.0), (2000.0, 0.0)
    ev = _events([_ball_events(rng, 0, 40_000, c0, v, 140.0, rate=8e6, w=640, h=480)])
    tr = BallTracker(640, 480)
    tr.update(ev)
    out = tr.finish()
    assert len(out.flight_ids()) == 1
    ex, ey = _truth(out.t_us, c0, v)
    assert np.median(np.hypot(out.cx - ex, out.cy - ey)) < 1.0 and np.median(np.abs(out.r - 140.0)) < 1.5


def test_options_that_would_index_outside_the_density_map_or_the_sectors_are_refused():
    for cell_px in (0, -1000, 10_000):
        with pytest.raises(ValueError, match="cell_px"):
            BallTracker(320, 240, cell_px=cell_px)
    x, y = np.random.default_rng(0).uniform(0, 100, (2, 500))
    for bad in (dict(n_sectors=0), dict(k_outer=0), dict(gap_events=0), dict(min_sector_events=0)):
        with pytest.raises(ValueError, match="fit_circle needs"):
            fit_circle(x, y, center0=(50.0, 50.0), **bad)


def test_a_burst_at_one_instant_gives_no_velocity_and_no_runaway_grid():
    # 2,000 events of a ring at one microsecond, its left half first, and one more a microsecond later:
    # the halves' centroids "moved" 20 px in a fraction of a microsecond (10^10 px/s), and the events moved
    # along that velocity asked for a density grid of gigabytes
    from detect.event_detector import estimate_velocity

    n = 2000
    a = np.random.default_rng(0).uniform(0, 2 * np.pi, n)
    a = np.r_[a[np.cos(a) < 0], a[np.cos(a) >= 0]]
    x, y = np.rint(160 + 20 * np.cos(a)), np.rint(120 + 20 * np.sin(a))
    t = np.full(n, 1000)
    t[-1] = 1001
    assert estimate_velocity(x, y, t) == (0.0, 0.0)
    ev = make_events(t, x.astype(np.uint16), y.astype(np.uint16), np.ones(n, np.int8))
    track = track_ball(ev, width=320, height=240)  # (asked for gigabytes before)
    assert len(track) == 0  # one instant is no flight
