"""Cut triangles along the planes of a voxel grid, so that every piece lies in one cube.

Used for exact per-cube integrals over a surface (the enclosed volume per cube of
:func:`sc_fem.lattice.moments.column_moments`): integrands that are polynomial on a piece are integrated
exactly by its centroid and area. Orientation (winding) of every piece is that of its triangle.
"""

from __future__ import annotations

import numpy as np


def _split_once(tri: np.ndarray, plane: np.ndarray, axis: int) -> np.ndarray:
    """Split each triangle (k, 3, 3), which the plane ``x[axis] = plane`` (k,) crosses strictly,
    into three triangles (3k, 3, 3) of the same orientation."""
    d = tri[:, :, axis] - plane[:, None]
    above = d > 0
    # the vertex alone on its side: the one whose side differs from the two others
    alone = np.where(above[:, 0] == above[:, 1], 2, np.where(above[:, 0] == above[:, 2], 1, 0))
    rows = np.arange(len(tri))[:, None]
    order = (alone[:, None] + np.arange(3)[None]) % 3               # rotate: alone vertex first
    t = tri[rows, order]
    dd = d[rows, order]
    a, b, c = t[:, 0], t[:, 1], t[:, 2]
    p = a + (b - a) * (dd[:, 0] / (dd[:, 0] - dd[:, 1]))[:, None]
    q = a + (c - a) * (dd[:, 0] / (dd[:, 0] - dd[:, 2]))[:, None]
    return np.concatenate([np.stack([a, p, q], 1), np.stack([p, b, c], 1), np.stack([p, c, q], 1)])


def cut_by_grid(tri: np.ndarray, origin: np.ndarray, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """Cut triangles (m, 3, 3) by all planes ``origin[a] + pitch * k`` of the three axes.

    Returns
    -------
    pieces : ndarray, shape (p, 3, 3)
        Triangles, each inside one grid cell (up to round-off on the planes).
    parent : ndarray of int, shape (p,)
        Index of the input triangle each piece came from.

    Notes
    -----
    Vectorized over triangles: each pass splits every triangle that still crosses a plane at the
    lowest plane it crosses, so the number of passes per axis is the largest number of planes one
    triangle crosses.
    """
    pieces = np.asarray(tri, dtype=np.float64)
    parent = np.arange(len(pieces))
    for axis in range(3):
        done_t, done_p = [], []
        while len(pieces):
            x = (pieces[:, :, axis] - origin[axis]) / pitch
            lo, hi = x.min(axis=1), x.max(axis=1)
            tol = 1e-9 * np.maximum(1.0, np.maximum(np.abs(lo), np.abs(hi)))
            plane = np.floor(lo + tol) + 1.0              # the lowest plane above the piece's bottom
            cross = plane < hi - tol
            done_t.append(pieces[~cross])
            done_p.append(parent[~cross])
            if not cross.any():
                break
            split = _split_once(pieces[cross], origin[axis] + pitch * plane[cross], axis)
            pieces = split
            parent = np.tile(parent[cross], 3)
        pieces = np.concatenate(done_t) if done_t else pieces
        parent = np.concatenate(done_p) if done_p else parent
    return pieces, parent
