"""Ball textures: albedo as a smooth function of a unit vector in the ball's own frame.

Every texture takes points ``q`` (M, 3) on the unit sphere (ball frame) and
``edge_rad``, the angular width (radians) over which colour edges are blended
(about one pixel divided by the radius in pixels), and returns albedo in 0..1,
shape (M,). Colour changes only ever happen under a seam whose core is a flat
colour, so the albedo is continuous: a moving edge gives a smooth intensity
ramp at each pixel, which the event generator can interpolate.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np

SQRT2 = np.sqrt(2.0)


def _seam_weight(dist_rad: np.ndarray, half_width_rad: float, edge_rad: float) -> np.ndarray:
    """1 inside the seam core (``dist <= half_width``), smooth fall to 0 over ``edge_rad``."""
    x = np.clip((half_width_rad + edge_rad - dist_rad) / edge_rad, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def volleyball(q: np.ndarray, edge_rad: float = 0.01, *, colors=(0.92, 0.62, 0.22),
               seam_albedo: float = 0.3, seam_half_rad: float = 0.012) -> np.ndarray:
    """Classic 18-panel volleyball: six faces of a cube, three parallel strips each.

    Strips on the faces normal to x run along z, on y-faces along x, on z-faces
    along y, so neighbouring three-strip groups are perpendicular. Panel colour
    ``colors[(strip + face) % len(colors)]`` (two or three grey levels).
    """
    q = np.asarray(q, dtype=np.float64)
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    ax, ay, az = np.abs(x), np.abs(y), np.abs(z)
    kx = (ax >= ay) & (ax >= az)
    ky = ~kx & (ay >= az)
    ak = np.where(kx, ax, np.where(ky, ay, az))
    second = ax + ay + az - ak - np.minimum(np.minimum(ax, ay), az)
    d_face = (ak - second) / SQRT2
    qj = np.where(kx, y, np.where(ky, z, x))  # strips vary along axis k + 1
    qk = np.where(kx, x, np.where(ky, y, z))
    norm = np.sqrt(1.0 + 1.0 / 9.0)
    third = ak / 3.0
    d_strip = np.minimum(np.abs(qj - third), np.abs(qj + third)) / norm
    strip = (qj >= -third).astype(np.int64) + (qj > third)
    face = 2 * np.where(kx, 0, np.where(ky, 1, 2)) + (qk > 0)
    colors = np.asarray(colors, dtype=np.float64)
    panel = colors[(strip + face) % colors.size]
    w = _seam_weight(np.minimum(d_face, d_strip), seam_half_rad, edge_rad)
    return panel + w * (seam_albedo - panel)


@lru_cache(maxsize=1)
def _soccer_faces() -> tuple[np.ndarray, np.ndarray]:
    """Face planes of a truncated icosahedron: (32, 3) normals / plane distance, pentagon mask."""
    phi = (1.0 + np.sqrt(5.0)) / 2.0
    v = []
    for s1 in (-1, 1):
        for s2 in (-1, 1):
            v += [(0, s1, s2 * phi), (s1, s2 * phi, 0), (s2 * phi, 0, s1)]
    v = np.array(v, dtype=np.float64)
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    d = v @ v.T
    edge_dot = np.max(d[~np.eye(12, dtype=bool)])
    adj = np.isclose(d, edge_dot)
    i0, i1 = np.nonzero(np.triu(adj))
    # pentagon planes: through the truncation points 1/3 along each edge
    d_pent = float(v[i0[0]] @ (2 * v[i0[0]] + v[i1[0]]) / 3.0)
    tris = [(a, b, c) for a in range(12) for b in range(a + 1, 12) for c in range(b + 1, 12)
            if adj[a, b] and adj[b, c] and adj[a, c]]
    hexn = np.array([v[a] + v[b] + v[c] for a, b, c in tris])
    hexn /= np.linalg.norm(hexn, axis=1, keepdims=True)
    a, b, _ = tris[0]
    d_hex = float(hexn[0] @ (2 * v[a] + v[b]) / 3.0)
    g = np.vstack([v / d_pent, hexn / d_hex])
    pent = np.r_[np.ones(12, bool), np.zeros(len(tris), bool)]
    return g, pent


def soccer(q: np.ndarray, edge_rad: float = 0.01, *, pentagon_albedo: float = 0.08,
           hexagon_albedo: float = 0.9, seam_albedo: float = 0.4,
           seam_half_rad: float = 0.01) -> np.ndarray:
    """Truncated-icosahedron soccer ball: 12 dark pentagons, 20 white hexagons, seams."""
    g, pent = _soccer_faces()
    q = np.asarray(q, dtype=np.float64)
    s = q.astype(np.float32) @ g.T.astype(np.float32)  # (M, 32) face scores
    i1 = s.argmax(axis=1)[:, None]
    s1 = np.take_along_axis(s, i1, axis=1)[:, 0]
    np.put_along_axis(s, i1, -np.inf, axis=1)
    i2 = s.argmax(axis=1)[:, None]
    s2 = np.take_along_axis(s, i2, axis=1)[:, 0]
    i1, i2 = i1[:, 0], i2[:, 0]
    # distance to the plane through the origin that separates the two best faces
    gd = g[i1] - g[i2]
    dist = (s1 - s2) / np.sqrt(np.sum(gd * gd, axis=1))
    panel = np.where(pent[i1], pentagon_albedo, hexagon_albedo)
    w = _seam_weight(dist, seam_half_rad, edge_rad)
    return panel + w * (seam_albedo - panel)


def basketball(q: np.ndarray, edge_rad: float = 0.01, *, ball_albedo: float = 0.55,
               line_albedo: float = 0.06, line_half_rad: float = 0.012) -> np.ndarray:
    """Basketball: orange-grey ball with the two great circles x=0, z=0 and two curved seams."""
    q = np.asarray(q, dtype=np.float64)
    # curved seams: circles of angular radius 50 deg around +y and -y
    d_curve = np.abs(np.abs(q[:, 1]) - np.cos(np.radians(50.0)))
    dist = np.minimum(np.minimum(np.abs(q[:, 0]), np.abs(q[:, 2])), d_curve)
    w = _seam_weight(dist, line_half_rad, edge_rad)
    return ball_albedo + w * (line_albedo - ball_albedo)


def tennis(q: np.ndarray, edge_rad: float = 0.01, *, ball_albedo: float = 0.7,
           seam_albedo: float = 0.95, seam_half_rad: float = 0.02) -> np.ndarray:
    """Tennis ball: uniform felt with the curved 'baseball' seam (white)."""
    q = np.asarray(q, dtype=np.float64)
    lon = np.arctan2(q[:, 1], q[:, 0])
    lat_seam = 0.45 * np.cos(2.0 * lon)  # seam latitude (rad) as a function of longitude
    lat = np.arcsin(np.clip(q[:, 2], -1.0, 1.0))
    dist = np.abs(lat - lat_seam) / np.sqrt(1.0 + (0.9 * np.sin(2.0 * lon)) ** 2)
    w = _seam_weight(dist, seam_half_rad, edge_rad)
    return ball_albedo + w * (seam_albedo - ball_albedo)


def logo(q: np.ndarray, edge_rad: float = 0.01, *, ball_albedo: float = 0.85,
         logo_albedo: float = 0.1) -> np.ndarray:
    """Plain ball with one dark round logo (25 deg radius) around +x and a small one around -y."""
    q = np.asarray(q, dtype=np.float64)
    d1 = np.arccos(np.clip(q[:, 0], -1, 1)) - np.radians(25.0)
    d2 = np.arccos(np.clip(-q[:, 1], -1, 1)) - np.radians(10.0)
    inside = np.minimum(d1, d2)
    w = np.clip(0.5 - inside / edge_rad, 0.0, 1.0)
    w = w * w * (3.0 - 2.0 * w)
    return ball_albedo + w * (logo_albedo - ball_albedo)


def plain(q: np.ndarray, edge_rad: float = 0.01, *, ball_albedo: float = 0.8) -> np.ndarray:
    """Plain ball of one colour: only its rim (and shading) can fire events."""
    return np.full(len(np.asarray(q)), float(ball_albedo))


def _segment_distance(x: np.ndarray, y: np.ndarray, x0: float, y0: float, x1: float, y1: float) -> np.ndarray:
    """Euclidean distance of points ``(x, y)`` from the segment ``(x0, y0)``-``(x1, y1)``."""
    dx, dy = x1 - x0, y1 - y0
    t = np.clip(((x - x0) * dx + (y - y0) * dy) / (dx * dx + dy * dy), 0.0, 1.0)
    return np.hypot(x - x0 - t * dx, y - y0 - t * dy)


@lru_cache(maxsize=4)
def _seam_arc_length(amp_rad: float, n: int = 4096) -> tuple[np.ndarray, np.ndarray]:
    """Longitudes (n + 1,) over [-pi, pi] and the arc length (rad) of the seam ``lat = amp cos(2 lon)`` up to each."""
    lon = np.linspace(-np.pi, np.pi, n + 1)
    lat = amp_rad * np.cos(2.0 * lon)
    speed = np.hypot(np.cos(lat), -2.0 * amp_rad * np.sin(2.0 * lon))
    return lon, np.r_[0.0, np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(lon))]


def baseball(q: np.ndarray, edge_rad: float = 0.01, *, ball_albedo: float = 0.9, stitch_albedo: float = 0.35,
             seam_amp_rad: float = 0.45, n_stitches: int = 108, stitch_in_rad: float = 0.02,
             stitch_out_rad: float = 0.10, stitch_slant_rad: float = 0.035,
             stitch_half_rad: float = 0.012) -> np.ndarray:
    """Baseball: white leather and two rows of red stitches along the curved figure-eight seam.

    The seam is the curve ``lat = seam_amp_rad * cos(2 lon)`` (as on the tennis ball).
    It carries ``n_stitches`` evenly spaced stitches (108 on a real ball, 2.4 mm apart);
    each is a chevron of two strokes, one on each side of the seam, from
    ``stitch_in_rad`` to ``stitch_out_rad`` away from it and slanted back along it by
    ``stitch_slant_rad``, ``2 * stitch_half_rad`` thick (angles on the ball; at the
    real radius of 36.6 mm the strokes are about 3 mm long and 0.9 mm thick). Red
    thread on white leather is dark for a monochrome sensor (``stitch_albedo``).
    The texture is sparse (the strokes cover about 4.4 % of the ball) and nearly
    symmetric (the two rows mirror each other across the seam).

    Positions are taken in seam coordinates: arc length ``s`` of the foot point on the
    seam and distance ``n`` from it, both to first order in the distance from the seam
    (the strokes reach 0.11 rad from it; its geodesic radius of curvature is 0.58 rad
    or more).
    """
    q = np.asarray(q, dtype=np.float64)
    lon = np.arctan2(q[:, 1], q[:, 0])
    lat = np.arcsin(np.clip(q[:, 2], -1.0, 1.0))
    lat_s = seam_amp_rad * np.cos(2.0 * lon)
    slope = -2.0 * seam_amp_rad * np.sin(2.0 * lon)  # d lat_s / d lon
    cos_s = np.cos(lat_s)
    norm = np.hypot(cos_s, slope)  # arc length of the seam per radian of longitude
    d_lat = lat - lat_s
    n = np.abs(d_lat * cos_s / norm)  # both rows alike: mirror across the seam
    lon_t, s_t = _seam_arc_length(seam_amp_rad)
    s = np.interp(lon, lon_t, s_t) + d_lat * slope / norm
    period = s_t[-1] / n_stitches
    k0 = np.floor(s / period)
    dist = np.full(q.shape[0], np.inf)
    for dk in (0, 1, 2):  # the nearest of the identical strokes is among these
        x = s - (k0 + dk) * period
        dist = np.minimum(dist, _segment_distance(x, n, 0.0, stitch_in_rad, -stitch_slant_rad, stitch_out_rad))
    w = _seam_weight(dist, stitch_half_rad, edge_rad)
    return ball_albedo + w * (stitch_albedo - ball_albedo)


TABLETENNIS_LOGO = (((0.0, 0.0), (0.0, 1.0)), ((0.6, 0.0), (0.6, 1.0)), ((0.0, 0.5), (0.6, 0.5)),  # H
                    ((0.9, 0.0), (0.9, 1.0)),  # I
                    ((1.2, 1.0), (1.8, 1.0)), ((1.5, 0.0), (1.5, 1.0)))  # T
"""Strokes of the table-tennis logo, the letters "HIT", in letter heights (x right, y up)."""


def tabletennis(q: np.ndarray, edge_rad: float = 0.01, *, ball_albedo: float = 0.9, logo_albedo: float = 0.1,
                logo_width_deg: float = 17.0, stroke_half_rad: float = 0.018) -> np.ndarray:
    """Table-tennis ball: plain (white; orange is about 0.6 grey) with one small printed text logo.

    The logo, centred on +x, is the word of :data:`TABLETENNIS_LOGO`: six dark strokes
    ``2 * stroke_half_rad`` thick (2 deg), the word ``logo_width_deg`` across between
    stroke centres (about 19 deg overall, 11 deg tall), laid out in the tangent plane
    at +x (gnomonic coordinates ``(q_y, q_z) / q_x``, so that +z is up). It covers
    about 0.3 % of the ball: a sparse, strongly asymmetric texture.
    """
    q = np.asarray(q, dtype=np.float64)
    pts = np.asarray(TABLETENNIS_LOGO, np.float64)
    scale = np.radians(logo_width_deg) / np.ptp(pts[..., 0])
    centre = 0.5 * (pts.min(axis=(0, 1)) + pts.max(axis=(0, 1)))
    front = q[:, 0] > 0.5  # the logo lies within 15 deg of +x
    dist = np.full(q.shape[0], np.inf)
    a = q[front, 1] / q[front, 0] / scale + centre[0]
    b = q[front, 2] / q[front, 0] / scale + centre[1]
    d = np.full(a.shape, np.inf)
    for (x0, y0), (x1, y1) in pts:
        d = np.minimum(d, _segment_distance(a, b, x0, y0, x1, y1))
    dist[front] = d * scale
    w = _seam_weight(dist, stroke_half_rad, edge_rad)
    return ball_albedo + w * (logo_albedo - ball_albedo)


TEXTURES: dict[str, Callable[..., np.ndarray]] = {
    "volleyball": volleyball, "soccer": soccer, "basketball": basketball,
    "tennis": tennis, "logo": logo, "baseball": baseball, "tabletennis": tabletennis, "plain": plain,
}
"""Texture functions by name."""


def get_texture(name: str) -> Callable[..., np.ndarray]:
    """Texture function by name; ``ValueError`` naming the choices otherwise."""
    try:
        return TEXTURES[name]
    except KeyError:
        raise ValueError(f"unknown texture {name!r}; choose one of {sorted(TEXTURES)}") from None
