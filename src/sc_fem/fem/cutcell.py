"""Cut cubes integrated over their filled region: the degree-``p`` field's integrals over a partly
filled cube from a finer model's fine cubes, each turned into six points of equal weight that
reproduce its exact moments of degree <= 2 (volume, centroid, second moments): the ``"moments"``
partial cubes of :mod:`sc_fem.fem.highorder`."""

from __future__ import annotations

import numpy as np

from ..lattice.moments import EXPONENTS
from .lagrange import shape_functions

CHUNK = 32
"""Partly filled cubes integrated per batched product (memory ~ CHUNK * points * (3 (p+1)^3)^2)."""


def sigma_points(moments: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Six points and weights reproducing a region's moments of total degree <= 2.

    Parameters
    ----------
    moments : ndarray, shape (n, 27)
        Moments of each region (:data:`sc_fem.lattice.moments.EXPONENTS` order), reference units.

    Returns
    -------
    points : ndarray, shape (n, 6, 3)
        ``mu +- sqrt(3 lambda_k) e_k``: the centroid moved along the principal axes of the
        region's second moments (``lambda_k``, ``e_k``).
    weights : ndarray, shape (n, 6)
        ``volume / 6`` each (never negative, so the stiffness stays positive semi-definite).
    """
    col = {tuple(e): k for k, e in enumerate(EXPONENTS.tolist())}
    V = np.maximum(moments[:, col[(0, 0, 0)]], 1e-300)
    unit = np.eye(3, dtype=np.int64)
    mu = np.stack([moments[:, col[tuple(unit[a])]] for a in range(3)], axis=1) / V[:, None]
    second = np.empty((len(V), 3, 3))
    for a in range(3):                                                  # the 6 second moments
        for b in range(3):
            second[:, a, b] = moments[:, col[tuple(unit[a] + unit[b])]] / V
    lam, vec = np.linalg.eigh(second - mu[:, :, None] * mu[:, None, :])
    off = (vec * np.sqrt(3.0 * np.maximum(lam, 0.0))[:, None, :]).transpose(0, 2, 1)   # (n, 3 axes, 3)
    points = np.concatenate([mu[:, None, :] + off, mu[:, None, :] - off], axis=1)
    return points, np.repeat(V[:, None] / 6.0, 6, axis=1)


def moment_integrals(p: int, partial: np.ndarray, cube: np.ndarray, xi: np.ndarray, w: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The degree-``p`` field's integrals over the filled region of the ``partial`` cubes from points.

    Parameters
    ----------
    p : int
        Degree.
    partial : ndarray of int, shape (n,)
        The cubes to integrate, sorted.
    cube, xi, w : ndarray
        Points: their cube (q,), reference coordinates (q, 3) and weights (q,) in units of the cube's
        volume (e.g. :func:`sigma_points` of fine cubes).

    Returns
    -------
    G : ndarray, shape (n, 3, nb, 3, nb)
        ``int dN_i/dxi_a dN_j/dxi_b`` (reference gradients).
    M : ndarray, shape (n, nb, nb)
        ``int N_i N_j``.
    """
    nb = (p + 1) ** 3
    sel = np.isin(cube, partial)
    cube, xi, w = cube[sel], xi[sel], w[sel]
    order = np.argsort(cube, kind="stable")
    cube, xi, w = cube[order], xi[order], w[order]
    starts = np.searchsorted(cube, partial)
    counts = np.searchsorted(cube, partial, side="right") - starts
    G = np.zeros((len(partial), 3, nb, 3, nb))
    M = np.zeros((len(partial), nb, nb))
    for c0 in range(0, len(partial), CHUNK):                   # batches of partly filled cubes
        sl = slice(c0, c0 + CHUNK)
        cnt, st = counts[sl], starts[sl]
        qmax = int(cnt.max()) if len(cnt) else 0
        if qmax == 0:
            continue
        take = st[:, None] + np.arange(qmax)[None, :]
        valid = np.arange(qmax)[None, :] < cnt[:, None]
        take = np.where(valid, take, 0)
        N, dN = shape_functions(p, xi[take.ravel()])
        sw = np.sqrt(np.where(valid, w[take], 0.0)).reshape(-1)
        X = (dN * sw[:, None, None]).reshape(len(cnt), qmax, 3 * nb)
        Y = (N * sw[:, None]).reshape(len(cnt), qmax, nb)
        G[sl] = np.matmul(X.transpose(0, 2, 1), X).reshape(len(cnt), 3, nb, 3, nb)
        M[sl] = np.matmul(Y.transpose(0, 2, 1), Y)
    return G, M
