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


def part_rigid_modes(points: np.ndarray, labels: np.ndarray, parts: np.ndarray,
                     free_dofs: np.ndarray | None = None) -> np.ndarray:
    """The 6 rigid-body fields of each part in ``parts``, each zero off its part: shape (3m or n_free, 6 len(parts)).

    A model of several loose parts has 6 zero-frequency modes per part, and LOBPCG finds them at
    once only when its start holds them (the global 6 of :func:`rigid_body_modes` span a sixth of a
    two-part model's): the toy truck of two bodies took 36 iterations from these, 52 from the global 6.

    Parameters
    ----------
    points : ndarray, shape (m, 3)
        Node positions (any unit).
    labels : ndarray of int, shape (m,)
        Part of each node.
    parts : ndarray of int, shape (p,)
        The parts whose fields are wanted (columns ``6 i .. 6 i + 5`` are ``parts[i]``'s).
    free_dofs : ndarray of int, optional
        Rows kept (interleaved DOFs ``3 i + c``).

    Returns
    -------
    ndarray, shape (3m or n_free, 6 p)
        Translations then rotations about each part's centroid, scaled by its extent.
    """
    p = np.asarray(points, dtype=float)
    labels = np.asarray(labels)
    col = np.full(int(labels.max(initial=-1)) + 1, -1)
    col[np.asarray(parts, dtype=int)] = np.arange(len(parts))
    c = col[labels]                                       # the column group of every node (-1: none)
    on = c >= 0
    count = np.bincount(c[on], minlength=len(parts))
    centre = np.stack([np.bincount(c[on], weights=p[on, d], minlength=len(parts)) for d in range(3)], 1)
    centre /= np.maximum(count, 1)[:, None]
    q = p[on] - centre[c[on]]
    extent = np.zeros(len(parts))
    np.maximum.at(extent, c[on], np.abs(q).max(axis=1))
    out = np.zeros((len(p), 3, len(parts), 6))
    out[np.flatnonzero(on), :, c[on], :] = rigid_block(q / np.maximum(extent, 1e-300)[c[on], None])
    out = out.reshape(3 * len(p), 6 * len(parts))
    return out if free_dofs is None else out[free_dofs]


def loose_start(points: np.ndarray, labels: np.ndarray, loose: np.ndarray, columns: int,
                free_dofs: np.ndarray | None = None) -> np.ndarray | None:
    """LOBPCG's start for a model of several loose parts: the rigid fields of the largest of them
    (:func:`part_rigid_modes`), as many whole parts as ``columns`` hold; None for one loose part or
    none (the global :func:`rigid_body_modes` are then the start).

    Parameters
    ----------
    points : ndarray, shape (m, 3)
        Node positions.
    labels : ndarray of int, shape (m,)
        Part of each node.
    loose : ndarray of int
        The parts free to move rigidly (unsupported).
    columns : int
        Columns of the start block (LOBPCG's block size).
    free_dofs : ndarray of int, optional
        Rows kept.

    Returns
    -------
    ndarray, shape (3m or n_free, 6 p) or None
    """
    loose = np.asarray(loose, dtype=int)
    if len(loose) < 2:
        return None
    largest = loose[np.argsort(-np.bincount(labels, minlength=int(labels.max()) + 1)[loose], kind="stable")]
    return part_rigid_modes(points, labels, largest[:max(columns // 6, 1)], free_dofs)
