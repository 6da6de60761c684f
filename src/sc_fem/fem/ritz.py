"""The Rayleigh--Ritz step that ends every eigensolve, and the residuals it gives.

:func:`rayleigh_ritz` refines a subspace to the eigenpairs of ``(X^T K X, X^T M X)`` with
``M``-orthonormal vectors; its products ``K V``, ``M V`` give :func:`relative_residuals`.
``K`` and ``M`` may be sparse matrices or operators with ``@`` (:mod:`sc_fem.fem.shift`).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import eigh

from .shift import SHIFT_FRACTION


def rayleigh_ritz(K, M, X: np.ndarray, k: int | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Refine a subspace ``X`` (n, m): eigenpairs of ``(X^T K X, X^T M X)``, vectors ``M``-orthonormal.

    Returns the ``k`` smallest (default all ``m``) eigenvalues ``lam`` (k,), vectors ``V`` (n, k),
    and ``K V``, ``M V`` (n, k) -- obtained from ``K X``, ``M X`` at no extra sparse product, for
    :func:`relative_residuals`.
    """
    KX, MX = K @ X, M @ X
    A = X.T @ KX
    G = X.T @ MX
    A, G = 0.5 * (A + A.T), 0.5 * (G + G.T)
    lam, C = eigh(A, G)
    C = C[:, :k]
    return lam[:k], X @ C, KX @ C, MX @ C


def relative_residuals(eigenvalues: np.ndarray, KV: np.ndarray, MV: np.ndarray, scale: float) -> np.ndarray:
    """``||K phi - lambda M phi|| / ||K phi||`` per column from the products ``K V``, ``M V`` (n, k).

    For (near-)rigid modes, where ``K phi ~ 0``, the denominator is floored at
    ``SHIFT_FRACTION * scale * ||M phi||`` (the size of the shift term; ``scale`` =
    :func:`~sc_fem.fem.shift.lambda_scale`), which is below ``||K phi||`` for every elastic mode.
    """
    r = np.linalg.norm(KV - MV * eigenvalues[None, :], axis=0)
    den = np.maximum(np.linalg.norm(KV, axis=0), SHIFT_FRACTION * scale * np.linalg.norm(MV, axis=0))
    return r / den
