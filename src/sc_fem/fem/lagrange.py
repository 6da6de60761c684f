"""The tensor-product Lagrange basis of degree ``p`` on the unit cube (equispaced nodes): the field of
the higher-order cubes (:mod:`sc_fem.fem.highorder`) and of the multiscale cubes' faces
(:mod:`sc_fem.fem.multiscale`)."""

from __future__ import annotations

import numpy as np


def lagrange_1d(p: int, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Values and derivatives, each shape (len(t), p + 1), of the degree-``p`` Lagrange basis on
    the equispaced points ``j / p`` of [0, 1] at ``t`` (1-D, reference units)."""
    t = np.asarray(t, dtype=float)
    nodes = np.linspace(0.0, 1.0, p + 1)
    diff = t[:, None] - nodes[None, :]                                  # (n, p + 1)
    val = np.empty((len(t), p + 1))
    der = np.zeros((len(t), p + 1))
    for j in range(p + 1):                                              # loop over the p + 1 basis functions
        others = [m for m in range(p + 1) if m != j]
        den = np.prod(nodes[j] - nodes[others])
        val[:, j] = np.prod(diff[:, others], axis=1) / den
        for k in others:
            der[:, j] += np.prod(diff[:, [m for m in others if m != k]], axis=1) / den
    return val, der


def shape_functions(p: int, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tensor-product basis at reference points ``xi`` (n, 3) in [0, 1]^3: values (n, nb) and
    reference gradients (n, 3, nb), ``nb = (p + 1)^3``, node ``(i, j, k)`` at index
    ``(i (p + 1) + j) (p + 1) + k``."""
    (vx, dx), (vy, dy), (vz, dz) = (lagrange_1d(p, xi[:, a]) for a in range(3))
    n = len(xi)
    N = np.einsum("qi,qj,qk->qijk", vx, vy, vz).reshape(n, -1)
    dN = np.stack([np.einsum("qi,qj,qk->qijk", dx, vy, vz).reshape(n, -1),
                   np.einsum("qi,qj,qk->qijk", vx, dy, vz).reshape(n, -1),
                   np.einsum("qi,qj,qk->qijk", vx, vy, dz).reshape(n, -1)], axis=1)
    return N, dN
