"""Exact winding numbers of closed surfaces by counting signed ray crossings.

:func:`crossing_number` casts a ray in +z from every query point and sums the signs of the faces it
crosses; faces are binned on an xy grid so that each point tests only the faces over its bin.
The compiled kernels (:mod:`sc_fem.geometry.inside_jit`) and the numpy path count the same
crossings. Used by :mod:`sc_fem.geometry.inside` (the generalized winding number of broken
meshes, closed by a cone) and by the solid fill of the lattice.
"""

from __future__ import annotations

import numpy as np

from . import inside_jit
from .._arrays import column_bounds
from .._jit import choose_kernel


def _edge_signs(a: np.ndarray, b: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Side of the projected edge ``a -> b`` (xy of (n, 3) arrays) on which each point ``p`` lies,
    +1 left, -1 right, 0 for an edge that projects to a point: never 0 for a point on the edge.

    Ties are broken by simulation of simplicity: ``p`` moved by ``(d, d^2)``, ``d -> 0``. The
    orientation is evaluated on the edge's endpoints in lexicographic order and its sign flipped
    for the other direction, so the faces on both sides of an edge compute the same number and
    exactly one of them holds a point on it; a point on a vertex belongs to one face of its fan.
    """
    swap = (a[:, 0] > b[:, 0]) | ((a[:, 0] == b[:, 0]) & (a[:, 1] > b[:, 1]))
    lo = np.where(swap[:, None], b[:, :2], a[:, :2])
    hi = np.where(swap[:, None], a[:, :2], b[:, :2])
    dx, dy = hi[:, 0] - lo[:, 0], hi[:, 1] - lo[:, 1]
    orient = dx * (p[:, 1] - lo[:, 1]) - dy * (p[:, 0] - lo[:, 0])
    tie = np.where(dy != 0, -dy, dx)            # d/dd and d^2 terms of the perturbed orientation
    sign = np.sign(np.where(orient != 0, orient, tie))
    return np.where(swap, -sign, sign)


def crossing_number(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray,
                    max_pairs: int = 1 << 22, kernel: str = "auto") -> np.ndarray:
    """Winding number of a closed surface at ``points``, exactly, by counting signed ray crossings.

    For a surface whose oriented faces close up (every edge used as often in each direction, as
    :attr:`MeshParts.watertight`), the winding number is an integer: the faces crossed by the ray
    from a point in +z, +1 where the face's normal points up and -1 where it points down. Faces
    are binned on an xy grid, so each point tests only the faces over its bin. Points exactly on
    a projected edge or vertex are decided consistently (:func:`_edge_signs`); points on a face
    count it when the face lies strictly above. Far cheaper than :func:`~sc_fem.geometry.inside.winding_number` near the
    surface, where the Barnes--Hut expansion cannot help; for open or leaky surfaces use that.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
        Model units.
    faces : ndarray of int, shape (m, 3)
        A closed surface (any number of closed components, possibly intersecting).
    points : ndarray, shape (q, 3)
        Model units.
    max_pairs : int
        Point-face pairs tested at a time by the numpy path (bounded memory).
    kernel : {"auto", "numba", "numpy"}
        The compiled kernel (:mod:`sc_fem.geometry.inside_jit`, with numba) or the numpy path;
        both count the same crossings.

    Returns
    -------
    ndarray of float, shape (q,)
        Integer winding numbers (1 inside an outward-oriented closed surface, 0 outside, 2 where
        two such surfaces overlap).
    """
    q = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.zeros(len(q))
    faces_box = crossing_faces(vertices, faces)
    if faces_box is None or len(q) == 0:
        return out
    tri, lo, hi = faces_box
    size, nb = bin_grid(lo, hi, len(tri), len(q))
    if choose_kernel(kernel) == "numba":
        start, bin_face = inside_jit.bin_faces(tri, lo, size, nb)
        inside_jit.crossings(q, tri, lo, hi, size, nb, start, bin_face, out)
        return out
    start, bin_face = _bin_faces(tri, lo, size, nb)
    pb = np.floor((q[:, :2] - lo) / size).astype(np.int64)
    outside = np.any((q[:, :2] < lo) | (q[:, :2] > hi), axis=1)   # x = hi may round to bin nb: the last bin
    pbin = np.clip(pb[:, 0], 0, nb - 1) * nb + np.clip(pb[:, 1], 0, nb - 1)
    n_cand = np.where(outside, 0, start[pbin + 1] - start[pbin])
    ends = np.cumsum(n_cand)
    s = 0
    while s < len(q):       # chunks of points holding about max_pairs candidate pairs
        e = max(int(np.searchsorted(ends, (ends[s - 1] if s else 0) + max_pairs, "right")), s + 1)
        c = n_cand[s:e]
        pt = np.repeat(np.arange(s, e), c)
        f = bin_face[np.repeat(start[pbin[s:e]], c) + np.arange(len(pt)) - np.repeat(np.cumsum(c) - c, c)]
        p, t = q[pt], tri[f]
        near = np.all((t[:, :, :2].min(axis=1) <= p[:, :2]) & (p[:, :2] <= t[:, :, :2].max(axis=1)), axis=1) \
            & (t[:, :, 2].max(axis=1) > p[:, 2])            # the face's box is over the point
        pt, f, p, t = pt[near], f[near], p[near], t[near]
        s0, s1, s2 = (_edge_signs(t[:, i], t[:, (i + 1) % 3], p) for i in range(3))
        inside = (s0 != 0) & (s0 == s1) & (s1 == s2)
        pt, f, p, t, sign = pt[inside], f[inside], p[inside], t[inside], s0[inside]
        # height of the face above the point (barycentric weights from the projected sub-areas)
        lam = np.stack([(t[:, j, 0] - p[:, 0]) * (t[:, k2, 1] - p[:, 1]) - (t[:, j, 1] - p[:, 1]) * (t[:, k2, 0] - p[:, 0])
                        for j, k2 in ((1, 2), (2, 0), (0, 1))], axis=1)
        z = np.einsum("ij,ij->i", lam, t[:, :, 2]) / lam.sum(axis=1)
        above = z > p[:, 2]
        out += np.bincount(pt[above], weights=sign[above], minlength=len(q))
        s = e
    return out


def crossing_faces(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The faces :func:`crossing_number` tests: their corners ``tri`` (m, 3, 3) (those seen edge-on
    dropped: they hold no point) and their xy box ``lo``, ``hi`` (2,); None when no face is left."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    x, y = v[:, 0], v[:, 1]
    x0, y0 = x[f[:, 0]], y[f[:, 0]]
    seen = (x[f[:, 1]] - x0) * (y[f[:, 2]] - y0) - (y[f[:, 1]] - y0) * (x[f[:, 2]] - x0) != 0
    tri = v[f[seen]]                                            # faces seen edge-on hold no point
    if len(tri) == 0:
        return None
    lo, hi = column_bounds(tri, 2)                              # the corners' xy box
    return tri, lo, hi


def bin_grid(lo: np.ndarray, hi: np.ndarray, n_faces: int, n_points: int) -> tuple[np.ndarray, int]:
    """The xy bins :func:`crossing_number` sorts ``n_faces`` faces (box ``lo``, ``hi`` (2,)) into for
    ``n_points`` points: the bins' ``size`` (2,) and their number per side (:func:`n_bins`)."""
    nb = n_bins(n_faces, n_points)
    return np.maximum(hi - lo, 1e-300) / nb, nb


def n_bins(n_faces: int, n_points: int) -> int:
    """Bins per side of the xy grid :func:`crossing_number` bins ``n_faces`` faces on for
    ``n_points`` points: about one face, or 16 points, a bin, at most 1024; with few points, no
    more than 16 bins a point (binning the faces costs more than the points' tests: the parts'
    96 probes of the bunny's 69,674 faces bin them on 39^2 bins, not 263^2)."""
    return int(np.clip(np.sqrt(max(min(n_faces, 16 * n_points), n_points / 16)), 1, 1024))


def _bin_faces(tri: np.ndarray, lo: np.ndarray, size: np.ndarray, nb: int) -> tuple[np.ndarray, np.ndarray]:
    """(bin, face) pairs of every face's xy box on the ``nb x nb`` grid of cells ``size`` (2,) from
    ``lo`` (2,), sorted by bin ``ix * nb + iy`` (faces ascending within a bin) and returned as CSR:
    ``start`` (nb^2 + 1,) and ``bin_face``; vectorized box expansion (the numpy path of
    :data:`sc_fem.geometry.inside_jit.bin_faces`)."""
    b_lo = np.clip(np.floor((tri[:, :, :2].min(axis=1) - lo) / size).astype(np.int64), 0, nb - 1)
    b_hi = np.clip(np.floor((tri[:, :, :2].max(axis=1) - lo) / size).astype(np.int64), 0, nb - 1)
    span = b_hi - b_lo + 1
    count = span[:, 0] * span[:, 1]
    face = np.repeat(np.arange(len(tri)), count)
    k = np.arange(len(face)) - np.repeat(np.cumsum(count) - count, count)
    key = (b_lo[face, 0] + k // span[face, 1]) * nb + b_lo[face, 1] + k % span[face, 1]
    order = np.argsort(key, kind="stable")
    return np.searchsorted(key[order], np.arange(nb * nb + 1)), face[order]
