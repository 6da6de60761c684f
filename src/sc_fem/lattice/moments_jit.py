"""Compiled surface integrals of :func:`sc_fem.lattice.moments.piece_integrals` and the positive
definiteness certificate of :func:`sc_fem.lattice.moments.valid_moments` (numba, optional).

The numpy path builds (pieces, 16 points, 3 axes, 4 powers) arrays; this kernel integrates piece
after piece with the same collapsed Gauss rule, so both agree to round-off. Without
numba (the optional extra ``sc_fem[fast]``) the numpy path runs.
"""

from __future__ import annotations

import numpy as np

from .._jit import compiled, compiled_parallel, prange


def _piece_integrals_py(pieces, cells, origin, pitch, st, w, inner, column):  # pragma: no cover - compiled
    """Fill ``inner`` (p, 27) and ``column`` (p, 9) for the pieces (p, 3, 3) in their cubes (p, 3)."""
    for i in prange(pieces.shape[0]):
        t = (pieces[i] - origin) / pitch
        for a in range(3):
            for c in range(3):
                t[a, c] -= cells[i, c]
        az = 0.5 * ((t[1, 0] - t[0, 0]) * (t[2, 1] - t[0, 1]) - (t[1, 1] - t[0, 1]) * (t[2, 0] - t[0, 0]))
        acc_in = inner[i]
        acc_col = column[i]
        acc_in[:] = 0.0
        acc_col[:] = 0.0
        for k in range(st.shape[0]):
            x = t[0, 0] + st[k, 0] * (t[1, 0] - t[0, 0]) + st[k, 1] * (t[2, 0] - t[0, 0])
            y = t[0, 1] + st[k, 0] * (t[1, 1] - t[0, 1]) + st[k, 1] * (t[2, 1] - t[0, 1])
            z = t[0, 2] + st[k, 0] * (t[1, 2] - t[0, 2]) + st[k, 1] * (t[2, 2] - t[0, 2])
            z1, z2, z3 = z, z * z / 2.0, z * z * z / 3.0          # zeta^(c+1) / (c+1)
            xa = 1.0
            for a in range(3):
                yb = 1.0
                for b in range(3):
                    v = w[k] * xa * yb
                    m = 3 * a + b
                    acc_col[m] += v
                    acc_in[3 * m] += v * z1
                    acc_in[3 * m + 1] += v * z2
                    acc_in[3 * m + 2] += v * z3
                    yb *= y
                xa *= x
        for m in range(27):
            acc_in[m] *= az
        for m in range(9):
            acc_col[m] *= az


piece_integrals = compiled(_piece_integrals_py)
"""The compiled :func:`_piece_integrals_py` (None without numba)."""


def _positive_definite_py(moments, pair, shift, out):  # pragma: no cover - compiled
    """Whether the Gram matrix ``G = moments[i, pair]`` (8, 8) of each row of ``moments`` (n, 27)
    less ``shift * trace(G)`` times the identity has a Cholesky factor (all pivots positive), into
    ``out`` (n,) bool: a certificate that ``G`` is positive definite with that margin."""
    for i in prange(moments.shape[0]):
        L = np.zeros((8, 8))
        tr = 0.0
        for a in range(8):
            tr += moments[i, pair[a, a]]
        s = shift * tr
        ok = tr > 0
        for j in range(8):
            if not ok:
                break
            d = moments[i, pair[j, j]] - s
            for k in range(j):
                d -= L[j, k] * L[j, k]
            if not d > 0:
                ok = False
                break
            L[j, j] = np.sqrt(d)
            for r in range(j + 1, 8):
                v = moments[i, pair[r, j]]
                for k in range(j):
                    v -= L[r, k] * L[j, k]
                L[r, j] = v / L[j, j]
        out[i] = ok


positive_definite = compiled_parallel(_positive_definite_py)
"""The compiled :func:`_positive_definite_py`, its rows split over the cores (None without numba)."""
