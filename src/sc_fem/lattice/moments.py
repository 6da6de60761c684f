"""Where the material sits inside each cube: the moments of its filled region.

A partly filled cube (a boundary cube, or one holding a thin plate) is stiffer in bending the
further its material lies from the cube's centre. The finite cell method captures this by
integrating the element matrices over the filled region only; for the trilinear cube every
integrand is a polynomial of degree at most 2 in each reference coordinate, so the 27 moments

    M_abc = (1 / h^3) * integral over (cube ∩ solid) of xi^a eta^b zeta^c dV,   a, b, c in {0, 1, 2}

(reference coordinates ``xi = (x - x_cube) / h`` in [0, 1]^3) give the exact integrals
(:func:`sc_fem.fem.elements.moment_stiffness`). ``M_000`` is the filled volume fraction.

Moments of a closed surface's solid come from surface integrals (divergence theorem): with the field ``(0, 0, xi^a eta^b zeta^(c+1)/(c+1))``,

    M_abc = sum over surface pieces in the cube of the integral of xi^a eta^b zeta^(c+1)/(c+1) n_z dA
          + 1/(c+1) * (moment xi^a eta^b of the solid's cross-section on the cube's top face),

and that cross-section moment is the integral of ``xi^a eta^b n_z dA`` over the surface above it
in the same column. Point samples (shells, sampled volumes) add ``volume * xi^a eta^b zeta^c``.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from . import moments_jit
from .._jit import choose_kernel
from .cubes import voxel_index

EXPONENTS = np.array([(a, b, c) for a in range(3) for b in range(3) for c in range(3)], dtype=np.int64)
"""The 27 exponent triples (a, b, c), moment ``k`` is ``xi^a eta^b zeta^c`` with ``(a, b, c) = EXPONENTS[k]``."""

FULL = 1.0 / np.prod(EXPONENTS + 1, axis=1)
"""Moments of a full cube, shape (27,) (``M_abc = 1 / ((a+1)(b+1)(c+1))``)."""


def monomials(xi: np.ndarray) -> np.ndarray:
    """All 27 monomials at reference points ``xi`` (n, 3): shape (n, 27)."""
    xi = np.asarray(xi, dtype=np.float64)
    powers = xi[:, None, :] ** np.arange(3)[None, :, None]                  # (n, 3 powers, 3 axes)
    return powers[:, EXPONENTS[:, 0], 0] * powers[:, EXPONENTS[:, 1], 1] * powers[:, EXPONENTS[:, 2], 2]


@lru_cache(maxsize=None)
def _triangle_rule() -> tuple[np.ndarray, np.ndarray]:
    """Collapsed 4x4 Gauss rule on the unit triangle (exact to degree 7): barycentric-like
    coordinates (q, 2) of ``A + s (B - A) + t (C - A)`` and weights (q,) summing to 1."""
    g, w = np.polynomial.legendre.leggauss(4)
    g, w = 0.5 * (g + 1.0), 0.5 * w
    u, v = np.meshgrid(g, g, indexing="ij")
    wu, wv = np.meshgrid(w, w, indexing="ij")
    s, t = u.ravel(), (v * (1.0 - u)).ravel()
    weight = (wu * wv * (1.0 - u)).ravel() * 2.0            # the unit triangle has area 1/2
    return np.stack([s, t], axis=1), weight


def piece_integrals(pieces: np.ndarray, cells: np.ndarray, origin: np.ndarray,
                    pitch: float, chunk: int = 65536, kernel: str = "auto") -> tuple[np.ndarray, np.ndarray]:
    """Surface integrals of the pieces (each inside one cube) in that cube's reference frame.

    Parameters
    ----------
    pieces : ndarray, shape (p, 3, 3)
        Oriented triangles, model units.
    cells : ndarray of int, shape (p, 3)
        The cube of each piece.
    origin, pitch
        The grid.
    chunk : int
        Pieces integrated at a time by the numpy path (bounded memory).
    kernel : {"auto", "numba", "numpy"}
        The compiled kernel (:mod:`sc_fem.lattice.moments_jit`, with numba) or the numpy path;
        they agree to round-off.

    Returns
    -------
    inner : ndarray, shape (p, 27)
        Integral of ``xi^a eta^b zeta^(c+1) / (c+1) n_z dA`` (reference units).
    column : ndarray, shape (p, 9)
        Integral of ``xi^a eta^b n_z dA`` for (a, b) in ``EXPONENTS[::3, :2]`` order (a major).
    """
    st, w = _triangle_rule()
    inner = np.empty((len(pieces), 27))
    column = np.empty((len(pieces), 9))
    div = 1.0 / np.arange(1, 4)                                       # 1 / (c + 1)
    if choose_kernel(kernel) == "numba" and len(pieces):
        moments_jit.piece_integrals(np.ascontiguousarray(pieces, dtype=np.float64), np.ascontiguousarray(cells, dtype=np.int64),
                                    np.asarray(origin, dtype=np.float64), float(pitch), st, w, inner, column)
        return inner, column
    for s in range(0, len(pieces), chunk):          # bounded memory: chunks of pieces
        t = (pieces[s:s + chunk] - origin) / pitch - cells[s:s + chunk, None, :]     # (k, 3, 3) reference
        az = 0.5 * np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])[:, 2]            # signed projected area
        q = t[:, None, 0] + st[None, :, :1] * (t[:, None, 1] - t[:, None, 0]) \
            + st[None, :, 1:] * (t[:, None, 2] - t[:, None, 0])                     # (k, q, 3)
        pw = np.empty(q.shape + (4,))                                               # (k, q, 3 axes, 4 powers)
        pw[..., 0] = 1.0
        for k in range(1, 4):                       # powers by products (4 of them, not per piece)
            pw[..., k] = pw[..., k - 1] * q
        xy = (pw[:, :, 0, :3, None] * pw[:, :, 1, None, :3]).reshape(len(t), -1, 9)
        wxy = xy * w[None, :, None]
        inner[s:s + chunk] = az[:, None] * (np.matmul(wxy.transpose(0, 2, 1), pw[:, :, 2, 1:]) * div).reshape(-1, 27)
        column[s:s + chunk] = az[:, None] * wxy.sum(axis=1)
    return inner, column


ROW_CHUNK = 1 << 15
"""Rows per chunk of the voxelizer's passes over (cubes, 27) moments (7 MB of doubles, in the cache):
a million-cube box's gathers and checks took 2-3x as long as whole-array passes, paying for fresh pages."""


def column_moments(pieces: np.ndarray, origin: np.ndarray, pitch: float, dims: np.ndarray,
                   cells: np.ndarray) -> np.ndarray:
    """Moments (c, 27) of the solid bounded by closed, outward-oriented surface pieces in ``cells``.

    Each piece must lie inside one cube (:func:`sc_fem.lattice.gridcut.cut_by_grid`). ``[:, 0]`` is the
    filled volume fraction. Why it is exact: by the divergence theorem with the field
    ``(0, 0, z - z0)`` on (solid ∩ cube), a cube's volume is the surface integral of
    ``(z - z0) n_z`` over the surface inside the cube plus ``pitch`` times the solid's
    cross-section on the cube's top face, which is the integral of ``n_z`` over the surface above
    it in the same column; higher moments likewise. With the surface cut along the grid planes
    every integral is an exact sum over the pieces, so thin plates cost nothing extra.
    """
    dims = np.asarray(dims, dtype=np.int64)
    idx = voxel_index(pieces.mean(axis=1), origin, pitch, dims)
    lin = np.ravel_multi_index(idx.T, dims)
    order = np.argsort(lin, kind="stable")
    lin_s = lin[order]
    # the pieces in cell order, integrated there (each piece on its own: the same numbers), and summed
    # into buffers with a zero row first (no copy of the (pieces, 27) integrals in order, or of their sums)
    inner, column = piece_integrals(pieces[order], idx[order], origin, pitch)
    cum_in, cum_col = np.zeros((len(inner) + 1, 27)), np.zeros((len(column) + 1, 9))
    np.cumsum(inner, axis=0, out=cum_in[1:])
    np.cumsum(column, axis=0, out=cum_col[1:])
    del inner, column
    q = np.ravel_multi_index(np.asarray(cells).T, dims)
    column_end = (q // dims[2] + 1) * dims[2]
    lo, hi = np.searchsorted(lin_s, q, "left"), np.searchsorted(lin_s, q, "right")
    top = np.searchsorted(lin_s, column_end, "left")
    c1 = EXPONENTS[:, 2] + 1
    ab = EXPONENTS[:, 0] * 3 + EXPONENTS[:, 1]
    # by row chunks, in the cache: the same operations. A cube that no piece crosses has
    # cum_in[hi] - cum_in[lo] = x - x = +0.0 exactly (the sums are finite): its rows stay zeros
    out = np.zeros((len(q), 27))
    crossed = np.flatnonzero(lo != hi) if np.isfinite(cum_in).all() else np.arange(len(q))
    for s in range(0, len(crossed), ROW_CHUNK):
        rows = crossed[s:s + ROW_CHUNK]
        out[rows] = cum_in[hi[rows]] - cum_in[lo[rows]]
    for s in range(0, len(q), ROW_CHUNK):
        r = slice(s, s + ROW_CHUNK)
        section = cum_col[top[r]]
        section -= cum_col[hi[r]]                                          # (rows, 9) moments on the top face
        above = section[:, ab]
        above /= c1
        out[r] += above
    return out


def box_moments(lo: np.ndarray, size: float) -> np.ndarray:
    """Moments (n, 27) of the sub-boxes ``[lo, lo + size]^3`` (reference coordinates, (n, 3))."""
    lo = np.asarray(lo, dtype=np.float64)
    k = np.arange(3)
    # integral of t^k over [lo, lo + size] per axis: shape (n, 3 powers, 3 axes)
    ints = ((lo[:, None, :] + size) ** (k[None, :, None] + 1) - lo[:, None, :] ** (k[None, :, None] + 1)) \
        / (k[None, :, None] + 1)
    return ints[:, EXPONENTS[:, 0], 0] * ints[:, EXPONENTS[:, 1], 1] * ints[:, EXPONENTS[:, 2], 2]


_TRILINEAR = np.array([(a, b, c) for a in range(2) for b in range(2) for c in range(2)], dtype=np.int64)
_PAIR_MOMENT = ((_TRILINEAR[:, None, :] + _TRILINEAR[None, :, :]) * np.array([9, 3, 1])).sum(axis=2)
"""Index (8, 8) into the 27 moments of the product of trilinear monomials ``i`` and ``j``."""


def moment_matrix(moments: np.ndarray) -> np.ndarray:
    """The (n, 8, 8) Gram matrices of the trilinear monomials (1, z, y, yz, x, xz, xy, xyz) under each
    cube's moments: positive semi-definite for the moments of any region, and, when it is, every
    element matrix integrated with those moments (products of trilinear gradients and incompatible
    modes, degree <= 2 per coordinate) is positive semi-definite too."""
    return np.asarray(moments, dtype=np.float64)[:, _PAIR_MOMENT]


CERTAIN_MARGIN = 1e-12
""":func:`valid_moments` skips the eigenvalues of a moment matrix ``G`` whose Cholesky factor of
``G - CERTAIN_MARGIN * trace(G) I`` exists: then ``G`` is positive definite (the factorization's
backward error, ~1e-14 trace(G) for 8 x 8, is below the margin), so its computed smallest eigenvalue
cannot fall below ``-rtol`` times its largest, and the eigenvalues would call it valid too."""


def valid_moments(moments: np.ndarray, rtol: float = 1e-10, even: np.ndarray | None = None,
                  kernel: str = "auto") -> tuple[np.ndarray, np.ndarray]:
    """Moments (n, 27) that some region could have: each set whose :func:`moment_matrix` has a
    negative eigenvalue (below ``-rtol`` times its largest) is moved towards the same volume spread
    evenly over the cube (``M_000 * FULL``, always valid) just far enough, by bisection.

    Sampled corrections can break validity where exact column moments are reduced by sampled
    overlaps of intersecting parts (a soup of overlapping bars: 8 of 1,472 cubes of a truss at
    resolution 64, whose element matrices came out indefinite and made free-free modes fail).

    ``even``: a mask (n,) of rows the caller knows to be a full cube's (not checked; the others are).
    ``kernel``: with numba (``"auto"``, ``"numba"``), sets whose moment matrix a Cholesky factor
    certifies positive definite (:data:`CERTAIN_MARGIN`) skip the eigenvalues; the same result.

    Returns
    -------
    moments : ndarray, shape (n, 27)
        Unchanged where already valid.
    repaired : ndarray of bool, shape (n,)
        The sets that were moved.
    """
    moments = np.array(moments, dtype=np.float64)

    def invalid(m):
        ev = np.linalg.eigvalsh(moment_matrix(m))
        return ev[:, 0] < -rtol * np.maximum(ev[:, -1], 1e-300)

    # a set within round-off of the full cube's (the moment matrix of the whole cube, positive
    # definite with a wide margin) is valid: only the others are checked
    rows = np.arange(len(moments)) if even is None else np.flatnonzero(~np.asarray(even, dtype=bool))
    m_r = moments[rows]
    check = rows[~np.all(np.abs(m_r - m_r[:, :1] * FULL) <= 1e-12 * np.abs(m_r[:, :1]), axis=1)]
    if choose_kernel(kernel) == "numba" and len(check):
        certain = np.empty(len(check), dtype=bool)
        moments_jit.positive_definite(moments[check], _PAIR_MOMENT, CERTAIN_MARGIN, certain)
        check = check[~certain]
    bad = check[invalid(moments[check])]
    if not len(bad):
        return moments, np.zeros(len(moments), dtype=bool)
    m, even = moments[bad], moments[bad, :1] * FULL
    lo, hi = np.zeros(len(bad)), np.ones(len(bad))
    for _ in range(40):                     # bisection on the blend weight (40 halvings, not elements)
        t = 0.5 * (lo + hi)
        still = invalid((1 - t)[:, None] * m + t[:, None] * even)
        lo, hi = np.where(still, t, lo), np.where(still, hi, t)
    moments[bad] = (1 - hi)[:, None] * m + hi[:, None] * even
    repaired = np.zeros(len(moments), dtype=bool)
    repaired[bad] = True
    return moments, repaired
