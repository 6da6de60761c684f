"""Rigid-body modes: the 6 displacement fields (3 translations, 3 rotations) that strain nothing --
the near-null space of a free body's stiffness (:mod:`sc_fem.fem.eigen`'s AMG preconditioner) and
the rigid part of a load (:mod:`sc_fem.fem.static`)."""

from __future__ import annotations

import numpy as np


def rigid_body_modes(points: np.ndarray, free_dofs: np.ndarray | None = None) -> np.ndarray:
    """The 6 rigid-body displacement fields of ``points`` (m, 3): shape (3m or n_free, 6).

    Columns: translations x, y, z, then rotations about x, y, z (about the centroid, scaled
    by the extent so all columns have similar norms). Rows are interleaved DOFs ``3i + c``,
    restricted to ``free_dofs`` when given.
    """
    p = np.asarray(points, dtype=float)
    q = p - p.mean(axis=0)
    B = rigid_block(q / max(float(np.abs(q).max()), 1e-300)).reshape(3 * len(p), 6)
    return B if free_dofs is None else B[free_dofs]


def rigid_block(q: np.ndarray) -> np.ndarray:
    """Rigid-body displacement of points at offsets ``q`` (n, 3) from a centre: shape (n, 3, 6),
    ``[I, -[q]x]`` (translations x, y, z, then rotations about x, y, z)."""
    B = np.zeros((len(q), 3, 6))
    B[:, [0, 1, 2], [0, 1, 2]] = 1.0
    x, y, z = np.asarray(q, dtype=float).T
    B[:, 1, 3], B[:, 2, 3] = -z, y
    B[:, 0, 4], B[:, 2, 4] = z, -x
    B[:, 0, 5], B[:, 1, 5] = -y, x
    return B
