"""Cut triangles along the planes of a voxel grid, so that every piece lies in one cube.

Used for exact per-cube integrals over a surface (the enclosed volume per cube of
:func:`sc_fem.lattice.moments.column_moments`): integrands that are polynomial on a piece are integrated
exactly by its centroid and area. Orientation (winding) of every piece is that of its triangle.

Each triangle is clipped to every cell it crosses (Sutherland-Hodgman, vectorized over all
(polygon, slab) pairs at once, one axis after the other): a triangle clipped by the six planes of a
cell is a convex polygon of at most :data:`MAX_VERTICES` vertices, fanned into triangles at the
end. A flat triangle crossing ``k x k`` cells becomes about ``2 k^2`` pieces (splitting it three
ways at each plane it crosses, plane after plane, made about 40 per cell of slivers).
"""

from __future__ import annotations

import numpy as np

MAX_VERTICES = 9
"""A triangle clipped by the 6 planes of a cell has at most 3 + 6 vertices."""

_TOL = 1e-9
"""A vertex within this fraction of a cell of a plane counts as on it (round-off)."""


def _clip(poly: np.ndarray, count: np.ndarray, axis: int, value: np.ndarray, above: bool) -> tuple[np.ndarray,
                                                                                                       np.ndarray]:
    """Clip convex polygons (n, MAX_VERTICES, 3) with ``count`` (n,) vertices to the half-space
    ``x[axis] >= value`` (``above``) or ``<= value`` (n,), keeping the vertex order."""
    n, m = poly.shape[:2]
    d = poly[:, :, axis] - value[:, None]
    if not above:
        d = -d
    slot = np.arange(m)[None, :]
    valid = slot < count[:, None]
    inside = (d >= 0) & valid
    nxt = np.where(slot + 1 < count[:, None], slot + 1, 0)                 # the edge i -> i + 1, cyclic
    rows = np.arange(n)[:, None]
    dn = d[rows, nxt]
    cross = valid & ((d >= 0) != (dn >= 0))
    t = np.where(cross, d / np.where(cross, d - dn, 1.0), 0.0)
    hit = poly + t[:, :, None] * (poly[rows, nxt] - poly)
    # each edge emits its start vertex (if inside) then its crossing point (if any), in order
    keep = np.stack([inside, cross], axis=2).reshape(n, 2 * m)
    slot_out = np.cumsum(keep, axis=1) - 1                                  # the kept ones first, in order
    r, c = np.nonzero(keep & (slot_out < m))
    out = np.zeros((n, m, 3))
    src = np.stack([poly, hit], axis=2).reshape(n, 2 * m, 3)
    out[r, slot_out[r, c]] = src[r, c]
    return out, np.minimum(keep.sum(axis=1), m)


def _split_axis(poly: np.ndarray, count: np.ndarray, parent: np.ndarray, axis: int, origin: float,
                pitch: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Split every polygon into its parts between consecutive grid planes along ``axis``."""
    m = poly.shape[1]
    x = (poly[:, :, axis] - origin) / pitch
    valid = np.arange(m)[None, :] < count[:, None]
    lo = np.where(valid, x, np.inf).min(axis=1)
    hi = np.where(valid, x, -np.inf).max(axis=1)
    k0 = np.floor(lo + _TOL * np.maximum(1.0, np.abs(lo))).astype(np.int64)
    k1 = np.maximum(np.ceil(hi - _TOL * np.maximum(1.0, np.abs(hi))).astype(np.int64) - 1, k0)
    span = k1 - k0 + 1
    one = span == 1                                                          # already inside one slab
    many = np.flatnonzero(~one)
    rep = np.repeat(many, span[many])
    first = np.cumsum(span[many]) - span[many]
    k = k0[rep] + (np.arange(len(rep)) - np.repeat(first, span[many]))
    p, c = poly[rep], count[rep]
    low = np.flatnonzero(k > k0[rep])                                        # the first slab has no lower plane
    p[low], c[low] = _clip(p[low], c[low], axis, origin + pitch * k[low], above=True)
    up = np.flatnonzero(k < k1[rep])                                         # nor the last an upper one
    p[up], c[up] = _clip(p[up], c[up], axis, origin + pitch * (k[up] + 1), above=False)
    ok = c >= 3
    return (np.concatenate([poly[one], p[ok]]), np.concatenate([count[one], c[ok]]),
            np.concatenate([parent[one], parent[rep][ok]]))


def cut_by_grid(tri: np.ndarray, origin: np.ndarray, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """Cut triangles (m, 3, 3) by all planes ``origin[a] + pitch * k`` of the three axes.

    Parameters
    ----------
    tri : ndarray, shape (m, 3, 3)
        Triangles, model units.
    origin : ndarray, shape (3,)
        The grid's lowest corner.
    pitch : float
        The grid's cell edge.

    Returns
    -------
    pieces : ndarray, shape (p, 3, 3)
        Triangles, each inside one grid cell (up to round-off on the planes), of the orientation
        of the triangle they came from; the pieces of a triangle cover it exactly.
    parent : ndarray of int, shape (p,)
        Index of the input triangle each piece came from.
    """
    tri = np.asarray(tri, dtype=np.float64).reshape(-1, 3, 3)
    origin = np.asarray(origin, dtype=np.float64)
    x = (tri - origin) / pitch
    lo, hi = x.min(axis=1), x.max(axis=1)
    inside = np.all(np.floor(lo + _TOL * np.maximum(1.0, np.abs(lo))) + 1.0 >= hi - _TOL * np.maximum(1.0, np.abs(hi)),
                    axis=1)                                                  # already in one cell: as it is
    cut = np.flatnonzero(~inside)
    poly = np.zeros((len(cut), 5, 3))                                        # 3 vertices, 2 more per axis
    poly[:, :3] = tri[cut]
    count = np.full(len(cut), 3, dtype=np.int64)
    parent = cut
    for axis in range(3):
        poly, count, parent = _split_axis(poly, count, parent, axis, float(origin[axis]), float(pitch))
        if axis < 2:                                                         # room for the next axis' 2 vertices
            poly = np.concatenate([poly, np.zeros((len(poly), 2, 3))], axis=1)
    # fan each polygon from its first vertex: triangles (0, j, j + 1), j = 1 .. count - 2
    j = np.arange(1, poly.shape[1] - 1)
    rows, col = np.nonzero(j[None, :] < (count[:, None] - 1))
    jj = j[col]
    pieces = np.stack([poly[rows, 0], poly[rows, jj], poly[rows, jj + 1]], axis=1)
    keep = np.flatnonzero(inside)
    return np.concatenate([tri[keep], pieces]), np.concatenate([keep, parent[rows]])
