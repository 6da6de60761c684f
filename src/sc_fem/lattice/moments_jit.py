"""Compiled surface integrals of :func:`sc_fem.lattice.moments.piece_integrals` (numba, optional).

The numpy path builds (pieces, 16 points, 3 axes, 4 powers) arrays; this kernel integrates piece
after piece with the same collapsed Gauss rule, so both agree to round-off. Without
numba (the optional extra ``sc_fem[fast]``) the numpy path runs.
"""

from __future__ import annotations

from .._jit import compiled, prange


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
