"""Compiled Gauss-Seidel sweep of the Neo-Hookean cube constraints (numba, optional).

The numpy sweep (:meth:`sc_fem.dynamics.xpbd_constraints.ConstraintSet._project_nh`) handles one colour of
cubes per call -- ~25 array operations on a few hundred cubes, so on lattices of a few thousand
cubes its time goes to numpy's per-call overhead, not to arithmetic (64 ms a frame against 18 ms compiled on the
benchmark bar, ``benchmarks/xpbd.py``). This kernel does the same arithmetic cube after cube in
the same colour order; cubes of one colour share no node, so the result equals the numpy sweep's
up to round-off (tested). Without numba (the optional extra ``sc_fem[fast]``) the numpy sweep runs.
"""

from __future__ import annotations

import math

import numpy as np

from .._jit import available, choose_kernel as _choose, compiled  # noqa: F401 - available: whether it can run


def choose_kernel(kernel: str, applicable: bool) -> str:
    """``"numba"`` or ``"numpy"`` for the requested ``kernel`` (see :class:`~sc_fem.dynamics.xpbd.XPBDSolver`)."""
    return _choose(kernel, applicable, "the compiled kernel covers the Neo-Hookean Gauss-Seidel sweep only "
                                       "(constraints='neohookean', gauss_seidel=True)")


def _nh_sweep_py(x, hexes, order, w, lamD, lamH, aD, aH, gamma, L, DN, h):  # pragma: no cover - compiled
    """One Gauss-Seidel pass over the cubes ``order`` (colour by colour), in place.

    Parameters
    ----------
    x : ndarray, shape (m, 3)
        Node positions, metres (updated).
    hexes : ndarray of int, shape (n, 8)
        Corner nodes of each cube.
    order : ndarray of int, shape (k,)
        Cubes in the order they are projected (colour groups one after the other).
    w : ndarray, shape (m,)
        Inverse node masses, 1/kg (0 = fixed).
    lamD, lamH : ndarray, shape (n,)
        Lagrange multipliers of the deviatoric and hydrostatic constraints (updated).
    aD, aH : ndarray, shape (n,)
        Compliances scaled by the substep (``alpha / ds^2``).
    gamma : ndarray, shape (n,)
        Rest value ``1 + mu / lam_nh`` of ``det F``.
    L : ndarray, shape (8, 8)
        Reference Laplacian of the unit cube.
    DN : ndarray, shape (8, 3)
        Shape-function gradients at the centre of the unit cube.
    h : float
        Cube edge, metres.
    """
    X = np.empty((8, 3))
    LX = np.empty((8, 3))
    F = np.empty((3, 3))
    cof = np.empty((3, 3))
    gH = np.empty((8, 3))
    wc = np.empty(8)
    for t in range(order.shape[0]):
        c = order[t]
        for a in range(8):
            nd = hexes[c, a]
            wc[a] = w[nd]
            for j in range(3):
                X[a, j] = x[nd, j]
        s = 0.0
        for a in range(8):
            for j in range(3):
                acc = 0.0
                for b in range(8):
                    acc += L[a, b] * X[b, j]
                LX[a, j] = acc
                s += X[a, j] * acc
        CD = math.sqrt(max(s, 1e-300)) / h
        gscale = 1.0 / (h * h * CD)
        for j in range(3):
            for k in range(3):
                acc = 0.0
                for a in range(8):
                    acc += X[a, j] * DN[a, k]
                F[j, k] = acc / h
        for i in range(3):
            i1, i2 = (i + 1) % 3, (i + 2) % 3
            for j in range(3):
                j1, j2 = (j + 1) % 3, (j + 2) % 3
                cof[i, j] = F[i1, j1] * F[i2, j2] - F[i1, j2] * F[i2, j1]
        J = F[0, 0] * cof[0, 0] + F[0, 1] * cof[0, 1] + F[0, 2] * cof[0, 2]
        A11 = aD[c]
        A22 = aH[c]
        A12 = 0.0
        for a in range(8):
            for j in range(3):
                g = (DN[a, 0] * cof[j, 0] + DN[a, 1] * cof[j, 1] + DN[a, 2] * cof[j, 2]) / h
                gH[a, j] = g
                d = LX[a, j] * gscale
                A11 += wc[a] * d * d
                A22 += wc[a] * g * g
                A12 += wc[a] * d * g
        r1 = -CD - aD[c] * lamD[c]
        r2 = gamma[c] - J - aH[c] * lamH[c]
        det = A11 * A22 - A12 * A12
        dD = (A22 * r1 - A12 * r2) / det
        dH = (A11 * r2 - A12 * r1) / det
        lamD[c] += dD
        lamH[c] += dH
        for a in range(8):
            if wc[a] == 0.0:
                continue
            nd = hexes[c, a]
            for j in range(3):
                x[nd, j] = X[a, j] + wc[a] * (LX[a, j] * gscale * dD + gH[a, j] * dH)


nh_sweep = compiled(_nh_sweep_py)
"""The compiled sweep (None without numba); arguments as :func:`_nh_sweep_py`."""
