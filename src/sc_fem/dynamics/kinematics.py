"""Kinematics of the trilinear cube shared by the corotational model and XPBD: the deformation gradient
at the cube centre, its cofactor, and the rotation of its polar decomposition, vectorized over cubes.

Units: corner positions and edges in metres; ``F`` and ``R`` are dimensionless.
"""

from __future__ import annotations

import numpy as np

from ..lattice.cubes import HEX_CORNERS

DN_CENTRE = (2.0 * HEX_CORNERS - 1.0) / 4.0   # grad N_a at the centre of the unit cube, (8, 3)
_P1, _P2 = np.array([1, 2, 0]), np.array([2, 0, 1])    # cyclic index shifts for cofactors


def centre_F(X: np.ndarray, h: float) -> np.ndarray:
    """Deformation gradient at the cube centre (= cube mean) ``F = sum_a x_a (x) grad N_a``.

    Parameters
    ----------
    X : ndarray, shape (n, 8, 3)
        Corner positions, metres, in :data:`~sc_fem.lattice.cubes.HEX_CORNERS` order.
    h : float
        Rest edge, metres.

    Returns
    -------
    ndarray, shape (n, 3, 3)
        ``F`` (dimensionless), ``F[n, j, k] = d x_j / d X_k``.
    """
    return np.matmul(X.transpose(0, 2, 1), DN_CENTRE) * (1.0 / h)


def cofactor(F: np.ndarray) -> np.ndarray:
    """Cofactor matrices ``det(F) F^-T`` of a batch (n, 3, 3) (also for singular ``F``)."""
    return (F[:, _P1[:, None], _P1] * F[:, _P2[:, None], _P2]
            - F[:, _P1[:, None], _P2] * F[:, _P2[:, None], _P1])


def polar_rotation(F: np.ndarray, iterations: int = 5) -> np.ndarray:
    """Rotation ``R`` of the polar decomposition ``F = R U`` of a batch, shape (n, 3, 3).

    Newton's iteration ``X <- (X + X^-T) / 2`` from ``X = F`` (quadratic convergence; 5
    iterations reach round-off for strains below ~30 %); matrices with ``det F <= 0`` or that
    did not converge fall back to the SVD ``F = U S V^T``, ``R = U diag(1, 1, det(U V^T)) V^T``
    (the closest proper rotation). ``det R = +1`` always."""
    X = F
    prev = F
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(iterations):
            C = cofactor(X)
            d = np.einsum("nj,nj->n", X[:, 0], C[:, 0])
            prev, X = X, 0.5 * (X + C / d[:, None, None])
        bad = ~(np.einsum("nij,nij->n", X - prev, X - prev) < 1e-20)
        bad |= ~(np.linalg.det(F) > 0)
    if np.any(bad):
        Fb = np.where(np.isfinite(F[bad]), F[bad], 0.0)
        U, _, Vt = np.linalg.svd(Fb)
        s = np.sign(np.linalg.det(np.matmul(U, Vt)))
        U[:, :, 2] *= np.where(s == 0, 1.0, s)[:, None]
        X = X.copy()
        X[bad] = np.matmul(U, Vt)
    return X


def cube_rotations(x_e: np.ndarray, h: float) -> np.ndarray:
    """Per-cube rotations from corner positions ``x_e`` (n, 8, 3) m of cubes of edge ``h`` m: (n, 3, 3)."""
    return polar_rotation(centre_F(x_e, h))
