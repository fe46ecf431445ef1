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


TEXTURES: dict[str, Callable[..., np.ndarray]] = {
    "volleyball": volleyball, "soccer": soccer, "basketball": basketball,
    "tennis": tennis, "logo": logo,
}
"""Texture functions by name."""


def get_texture(name: str) -> Callable[..., np.ndarray]:
    """Texture function by name; ``ValueError`` naming the choices otherwise."""
    try:
        return TEXTURES[name]
    except KeyError:
        raise ValueError(f"unknown texture {name!r}; choose one of {sorted(TEXTURES)}") from None
