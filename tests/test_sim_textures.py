"""Ball textures: smooth (no jumps a moving edge could alias on) and laid out as the real balls."""

import numpy as np
import pytest

from sim.rotation import axis_angle_matrices
from sim.textures import TABLETENNIS_LOGO, TEXTURES, _soccer_faces, baseball, soccer, tabletennis, volleyball


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


@pytest.mark.parametrize("name", sorted(TEXTURES))
def test_textures_are_continuous_at_the_edge_width(name):
    rng = np.random.default_rng(1)
    q = _unit(rng.normal(size=(40000, 3)))
    step = 2e-4  # rad, far below the 0.01 rad edge width
    axes = _unit(rng.normal(size=(40000, 3)))
    q2 = _unit(q + step * _unit(np.cross(axes, q)))
    f = TEXTURES[name]
    a, b = f(q, 0.01), f(q2, 0.01)
    assert np.all((a >= 0) & (a <= 1))
    # smoothstep over 0.01 rad: slope at most 1.5 * contrast / 0.01 per rad
    assert np.max(np.abs(a - b)) <= 1.5 * 1.0 / 0.01 * step * 1.05 + 1e-9
    if name == "plain":
        assert np.ptp(a) == 0.0  # one colour: only its rim can fire
    else:
        assert np.ptp(a) > 0.2  # but it is a texture, not a flat colour


def test_soccer_pentagons_are_dark_and_hexagons_light():
    g, pent = _soccer_faces()
    centres = _unit(g)
    alb = soccer(centres)
    assert pent.sum() == 12 and len(g) == 32
    assert np.all(alb[pent] < 0.2) and np.all(alb[~pent] > 0.8)
    # dark area: pentagons are 28.4 % of the polyhedron's surface; their planes lie a bit
    # farther out than the hexagons', so they cover somewhat less of the sphere
    q = _unit(np.random.default_rng(0).normal(size=(100000, 3)))
    dark = np.mean(soccer(q, 0.001) < 0.1)
    assert 0.22 < dark < 0.284


def test_volleyball_has_three_strips_per_face_and_perpendicular_neighbours():
    # on the +x face the strips are bounded by q_y = +-q_x/3: walking along y crosses two
    # seams (three colours), walking along z crosses none until the face edge
    t = np.linspace(-0.9, 0.9, 181)
    along_y = _unit(np.column_stack([np.ones_like(t), t, np.zeros_like(t)]))
    along_z = _unit(np.column_stack([np.ones_like(t), np.zeros_like(t), t]))
    ay, az = volleyball(along_y, 0.005), volleyball(along_z, 0.005)
    levels = [round(v, 2) for v in ay[[10, 90, 170]]]
    assert len(set(levels)) == 3
    assert np.ptp(az) < 1e-12  # the middle strip runs along z
    # the +y face's strips run along x: perpendicular to those of the +x face
    along_x_on_y = _unit(np.column_stack([t, np.ones_like(t), np.zeros_like(t)]))
    assert np.ptp(volleyball(along_x_on_y, 0.005)) < 1e-12
    # the layout is symmetric under the 120 deg turn about (1, 1, 1) that cycles x -> y -> z
    # (seams map onto seams; colours may permute)
    rot = axis_angle_matrices([1, 1, 1], [2 * np.pi / 3])[0]
    q = _unit(np.random.default_rng(2).normal(size=(20000, 3)))
    on_seam = np.isclose(volleyball(q, 0.005), 0.3, atol=1e-9)
    assert on_seam.mean() > 0.02
    np.testing.assert_array_equal(np.isclose(volleyball(q @ rot.T, 0.005), 0.3, atol=1e-9), on_seam)


def _sphere(n, seed=0):
    return _unit(np.random.default_rng(seed).normal(size=(n, 3)))


def test_baseball_stitches_cover_their_designed_area_along_the_seam():
    q = _sphere(400000)
    alb = baseball(q, 1e-4)
    assert alb.min() == pytest.approx(0.35) and alb.max() == pytest.approx(0.9)
    # 108 chevrons of two strokes: 0.024 rad wide, length hypot(0.035, 0.08) between the cap centres
    stroke = 2 * 0.012 * np.hypot(0.035, 0.10 - 0.02) + np.pi * 0.012**2
    designed = 2 * 108 * stroke / (4 * np.pi)
    dark = alb < 0.625
    assert np.mean(dark) == pytest.approx(designed, rel=0.05)
    assert 0.04 < designed < 0.05  # sparse
    # every stitch lies within the stitch band around the seam lat = 0.45 cos(2 lon)
    lon, lat = np.arctan2(q[:, 1], q[:, 0]), np.arcsin(q[:, 2])
    assert np.all(np.abs(lat - 0.45 * np.cos(2 * lon))[dark] < 0.10 + 0.012 + 0.05)
    # nearly symmetric: the half turn about z maps the seam and its 108 stitches onto themselves
    turned = q * [-1.0, -1.0, 1.0]
    assert np.mean(np.abs(baseball(turned, 0.01) - baseball(q, 0.01)) < 0.02) > 0.995


def test_tabletennis_logo_is_small_text_of_the_designed_area():
    q = _sphere(400000, seed=1)
    alb = tabletennis(q, 1e-4)
    assert alb.min() == pytest.approx(0.1) and alb.max() == pytest.approx(0.9)
    dark = alb < 0.5
    # designed area: the union of the strokes (capsules 0.036 rad wide) in the tangent plane at +x,
    # rasterised here independently of the texture
    pts = np.asarray(TABLETENNIS_LOGO, float)
    scale = np.radians(17.0) / np.ptp(pts[..., 0])
    g = np.arange(-0.5, 2.3, 0.002)
    gx, gy = np.meshgrid(g, g)
    inside = np.zeros(gx.shape, bool)
    for (x0, y0), (x1, y1) in pts:
        d = np.array([x1 - x0, y1 - y0])
        t = np.clip(((gx - x0) * d[0] + (gy - y0) * d[1]) / (d @ d), 0, 1)
        inside |= np.hypot(gx - x0 - t * d[0], gy - y0 - t * d[1]) <= 0.018 / scale
    designed = inside.sum() * (0.002 * scale) ** 2 / (4 * np.pi)
    assert np.mean(dark) == pytest.approx(designed, rel=0.08)
    assert designed < 0.004
    # text, not a disc: 15-20 deg across, and most of the logo's cap is still white
    assert 15.0 < np.degrees(np.ptp(np.arctan2(q[dark, 1], q[dark, 0]))) < 20.0
    ang = np.degrees(np.arccos(np.clip(q[dark, 0], -1, 1)))
    cap = np.degrees(np.arccos(np.clip(q[:, 0], -1, 1))) < ang.max()
    assert np.mean(dark[cap]) < 0.5  # a disc would fill it
    assert np.all(np.abs(q[dark, 2]) < np.sin(np.radians(7.0)))  # one line of text: wider than tall
