"""Vectorized XPBD constraint kernels for batches of cubes: the reference Laplacian of a trilinear
cube, volume / corotational / Neo-Hookean terms and gradients, cube colours and fixed-node masks."""

from __future__ import annotations

import numpy as np

from .._validate import as_indices
from ..errors import BoundaryConditionError
from ..lattice.cubes import HEX_CORNERS, CubeModel
from .kinematics import DN_CENTRE, centre_F, cofactor


def _reference_laplacian() -> np.ndarray:
    """``L_ab = int_unit cube grad N_a . grad N_b`` (8, 8), exact by 2x2x2 Gauss."""
    g = 0.5 + np.array([-0.5, 0.5]) / np.sqrt(3.0)
    q = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)          # (8, 3)
    o = HEX_CORNERS[None, :, :]                                                     # (1, 8, 3)
    f = np.where(o == 1, q[:, None, :], 1.0 - q[:, None, :])                       # (8q, 8a, 3)
    df = np.where(o == 1, 1.0, -1.0) * np.ones_like(f)
    grad = np.stack([df[..., 0] * f[..., 1] * f[..., 2], f[..., 0] * df[..., 1] * f[..., 2],
                     f[..., 0] * f[..., 1] * df[..., 2]], -1)                       # (8q, 8a, 3)
    return np.einsum("qai,qbi->ab", grad, grad) / 8.0


L_REF = _reference_laplacian()
"""Reference Laplacian of the unit cube, shape (8, 8), in :data:`HEX_CORNERS` order."""

# 7 perfect matchings of the 8 corners (3 edge sets, 3 face-diagonal sets, 1 body-diagonal set)
def _matchings() -> tuple[np.ndarray, np.ndarray]:
    pairs, kinds = [], []
    for a in range(8):
        for b in range(a + 1, 8):
            d = np.abs(HEX_CORNERS[a] - HEX_CORNERS[b])
            pairs.append((a, b, int(d.sum()), tuple(d)))
    groups = []
    for kind in (1, 2):   # edges / face diagonals grouped by the axis (edge) or face normal
        for ax in range(3):
            sel = [(a, b) for a, b, n, d in pairs if n == kind and
                   ((kind == 1 and d[ax] == 1) or (kind == 2 and d[ax] == 0))]
            groups.append(sel)
            kinds.append(kind)
    groups.append([(a, b) for a, b, n, _ in pairs if n == 3])
    kinds.append(3)
    return np.array(groups, dtype=np.int64), np.array(kinds)


MATCHINGS, MATCHING_KIND = _matchings()               # (7, 4, 2), (7,) 1=edge 2=face 3=body


def _sqrt_laplacian() -> np.ndarray:
    e, V = np.linalg.eigh(L_REF)
    return (V * np.sqrt(np.maximum(e, 0.0))) @ V.T


S_REF = _sqrt_laplacian()
"""Symmetric square root of :data:`L_REF` (8, 8): ``S S = L_REF``, ``S 1 = 0``."""


def _volume_terms(X: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """``J = det F`` at the cube centre and its gradient ``grad_a J = cof(F) grad N_a``.

    Parameters
    ----------
    X : ndarray, shape (n, 8, 3)
        Corner positions, metres, :data:`HEX_CORNERS` order.
    h : float
        Rest edge, metres.

    Returns
    -------
    J : ndarray, shape (n,)
        Dimensionless.
    gJ : ndarray, shape (n, 8, 3)
        1/m.
    """
    F = centre_F(X, h)                                               # (n, 3, 3), F_jk
    cof = cofactor(F)
    J = np.einsum("ij,ij->i", F[:, 0, :], cof[:, 0, :])
    return J, np.matmul(DN_CENTRE, cof.transpose(0, 2, 1)) * (1.0 / h)


def _scatter_add(x: np.ndarray, nodes: np.ndarray, dX: np.ndarray) -> None:
    """``x[nodes] += dX`` with repeated nodes summed; ``x`` (m, 3), ``nodes`` (k, c), ``dX`` (k, c, 3)."""
    flat = nodes.ravel()
    for j in range(3):
        x[:, j] += np.bincount(flat, weights=dX[..., j].ravel(), minlength=len(x))


def corotational_terms(X: np.ndarray, h: float, R: np.ndarray):
    """Deviatoric (ARAP) constraint vectors of a batch of cubes.

    ``C_D = S (X - X_ref R^T) / h`` with ``S = sqrt(L_REF)``, so that ``|C_D|^2 h^3 =
    int_cube |grad x - R|^2`` exactly for the trilinear cube (``R`` constant in the cube).

    Parameters
    ----------
    X : ndarray, shape (n, 8, 3)
        Corner positions, metres, :data:`HEX_CORNERS` order.
    h : float
        Rest edge, metres.
    R : ndarray, shape (n, 3, 3)
        Rotation per cube (normally :func:`~sc_fem.dynamics.kinematics.polar_rotation` of the centre ``F``).

    Returns
    -------
    ndarray, shape (n, 8, 3)
        ``C_D`` (dimensionless); its gradient w.r.t. corner ``a`` component ``j`` at fixed
        ``R`` is ``S[:, a] / h`` for component ``j``.
    """
    Xr = np.matmul((h * HEX_CORNERS)[None], R.transpose(0, 2, 1))        # (n, 8, 3) = R X_ref
    return np.matmul(S_REF, X - Xr) * (1.0 / h)


def cube_colors(model: CubeModel) -> np.ndarray:
    """Colour 0..7 of each cube from the parities of its lattice index, shape (n,).

    Two cubes of the same colour share no node."""
    p = np.asarray(model.cells) % 2
    return p[:, 0] * 4 + p[:, 1] * 2 + p[:, 2]


def neohookean_terms(X: np.ndarray, h: float):
    """Constraint values and gradients of the stable Neo-Hookean pair for a batch of cubes.

    Parameters
    ----------
    X : ndarray, shape (n, 8, 3)
        Corner positions (metres) in :data:`HEX_CORNERS` order.
    h : float
        Rest edge length, metres.

    Returns
    -------
    CD : (n,) ``sqrt(mean |F|^2)``;  gD : (n, 8, 3) its gradient;
    J : (n,) ``det F`` at the centre;  gH : (n, 8, 3) its gradient (``cof(F) grad N_a``).
    """
    n = X.shape[0]
    LX = np.matmul(L_REF, X)                                       # (n, 8, 3)
    CD = np.sqrt(np.maximum(np.einsum("ij,ij->i", X.reshape(n, 24), LX.reshape(n, 24)), 1e-300)) / h
    gD = LX * (1.0 / (h * h * CD))[:, None, None]
    J, gH = _volume_terms(X, h)
    return CD, gD, J, gH


def _as_fixed(fixed, n_nodes: int) -> np.ndarray:
    """Boolean mask (m,) of fixed nodes from indices or a mask."""
    mask = np.zeros(n_nodes, dtype=bool)
    if fixed is not None:
        mask[as_indices(fixed, n_nodes, "fixed node indices", allow_mask=True, error=BoundaryConditionError)] = True
    return mask
