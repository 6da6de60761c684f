"""Exact (conservative) triangle--voxel overlap: the separating-axis test of Akenine-Moeller,
vectorized over (triangle, voxel) pairs.

Touching counts as overlapping (a triangle lying in a grid plane marks the voxels on both
sides), so the result never loses geometry however thin or skinny the triangles are.
"""

from __future__ import annotations

import numpy as np

from .cubes import voxel_index

_AXES = np.eye(3)


def triangle_box_overlap(tri: np.ndarray, centers: np.ndarray, half: float) -> np.ndarray:
    """Do triangles overlap axis-aligned cubes?

    Parameters
    ----------
    tri : ndarray, shape (P, 3, 3)
        Triangle vertices of each pair.
    centers : ndarray, shape (P, 3)
        Cube centres of each pair.
    half : float
        Cube half edge (enlarged slightly by the caller for conservativeness).

    Returns
    -------
    ndarray of bool, shape (P,)
    """
    v = tri - centers[:, None, :]                                    # (P, 3, 3)
    sep = np.zeros(len(v), dtype=bool)
    # 1) box face normals: triangle AABB vs box
    sep |= np.any(v.min(axis=1) > half, axis=1) | np.any(v.max(axis=1) < -half, axis=1)
    # 2) triangle normal: plane vs box
    e = v[:, [1, 2, 0]] - v                                           # edges e0, e1, e2 (P, 3, 3)
    n = np.cross(e[:, 0], e[:, 1])
    d = np.einsum("pi,pi->p", n, v[:, 0])
    sep |= np.abs(d) > half * np.abs(n).sum(axis=1)
    # 3) nine cross-product axes edge_i x unit_j
    for i in range(3):                                                # 3 x 3 fixed axes, not a data loop
        for j in range(3):
            a = np.cross(e[:, i], _AXES[j])                           # (P, 3)
            p = np.einsum("pki,pi->pk", v, a)                         # (P, 3)
            r = half * np.abs(a).sum(axis=1)
            sep |= (p.min(axis=1) > r) | (p.max(axis=1) < -r)
    return ~sep


def overlapping_cells(vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray, pitch: float,
                      dims: np.ndarray, chunk_pairs: int = 2_000_000) -> tuple[np.ndarray, np.ndarray]:
    """All voxels touched by any triangle.

    Returns
    -------
    cells : ndarray of int, shape (k, 3)
        Unique lattice indices of overlapped voxels.
    face_of_cell : ndarray of int, shape (k,)
        One overlapping face per voxel (for material look-up).
    """
    tri_all = vertices[faces]
    lo = voxel_index(tri_all.min(axis=1), origin, pitch, dims)
    hi = voxel_index(tri_all.max(axis=1), origin, pitch, dims)
    span = hi - lo + 1
    count = span.prod(axis=1)
    half = 0.5 * pitch * (1.0 + 1e-9)
    found_lin, found_face = [], []
    ends = np.cumsum(count)
    start = 0
    while start < len(faces):                                         # chunks of pairs, not faces
        stop = int(np.searchsorted(ends, ends[start] - count[start] + chunk_pairs, side="right"))
        stop = max(stop, start + 1)
        f = np.arange(start, stop)
        c = count[f]
        fr = np.repeat(f, c)
        local = np.arange(c.sum()) - np.repeat(np.cumsum(c) - c, c)
        sp = span[fr]
        ijk = lo[fr] + np.stack([local // (sp[:, 1] * sp[:, 2]), (local // sp[:, 2]) % sp[:, 1],
                                 local % sp[:, 2]], axis=1)
        centers = origin + pitch * (ijk + 0.5)
        hit = triangle_box_overlap(tri_all[fr], centers, half)
        found_lin.append(np.ravel_multi_index(ijk[hit].T, dims))
        found_face.append(fr[hit])
        start = stop
    lin = np.concatenate(found_lin)
    face = np.concatenate(found_face)
    uniq, first = np.unique(lin, return_index=True)
    return np.stack(np.unravel_index(uniq, dims), axis=1).astype(np.int64), face[first]
