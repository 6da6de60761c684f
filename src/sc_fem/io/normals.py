"""Vertex normals of the exported glTF surfaces (:mod:`sc_fem.io.gltf`): area-weighted, smooth
across UV seams, sharp at creases, for the rest shape and every displaced one."""

from __future__ import annotations

import numpy as np

CREASE_DEGREES = 60.0
"""A vertex's normal takes the faces of the vertices sharing its position whose normal is within this of its own."""


class _Normals:
    """Vertex normals of a triangle mesh with fixed connectivity, for its rest and displaced shapes.

    Area-weighted face normals summed at each vertex. Vertices that share a rest position (a mesh
    split at UV seams, or at creases) also take the faces of their twins whose rest normal lies
    within :data:`CREASE_DEGREES` of their own: a UV seam shows no shading seam and a crease stays
    sharp. Which faces count is decided once, at rest, and used for every displaced shape, so
    normal deltas are continuous.
    """

    def __init__(self, rest: np.ndarray, faces: np.ndarray) -> None:
        rest = np.asarray(rest, dtype=float)
        self.faces = faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        n = len(rest)
        _, group = np.unique(rest, axis=0, return_inverse=True)
        group = group.ravel()
        # every (vertex, corner) pair whose corner lies at the vertex's position
        corner_v = faces.ravel()
        order = np.argsort(group[corner_v], kind="stable")
        per_group = np.bincount(group[corner_v], minlength=int(group.max()) + 1)
        start = np.concatenate([[0], np.cumsum(per_group)[:-1]])
        reps = per_group[group]
        pair_v = np.repeat(np.arange(n), reps)
        offset = np.arange(len(pair_v)) - np.repeat(np.cumsum(reps) - reps, reps)
        pair_c = order[start[group][pair_v] + offset]
        fn = self._face_normals(rest)
        own = _unit(self._sum(fn, pair_v[corner_v[pair_c] == pair_v], (pair_c // 3)[corner_v[pair_c] == pair_v], n))
        cos = np.einsum("ij,ij->i", _unit(fn[pair_c // 3]), own[pair_v])
        keep = (corner_v[pair_c] == pair_v) | (cos >= np.cos(np.radians(CREASE_DEGREES)))
        self.pair_v, self.pair_f, self.n = pair_v[keep], pair_c[keep] // 3, n

    def _face_normals(self, v: np.ndarray) -> np.ndarray:
        tri = v[self.faces]
        return np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])     # area-weighted face normals

    @staticmethod
    def _sum(fn: np.ndarray, pair_v: np.ndarray, pair_f: np.ndarray, n: int) -> np.ndarray:
        return np.column_stack([np.bincount(pair_v, weights=fn[pair_f, i], minlength=n) for i in range(3)])

    def __call__(self, vertices: np.ndarray) -> np.ndarray:
        """Unit vertex normals of ``vertices`` (same vertex order as the rest shape), shape (n, 3)."""
        fn = self._face_normals(np.asarray(vertices, dtype=float))
        return _unit(self._sum(fn, self.pair_v, self.pair_f, self.n), fallback=(0.0, 1.0, 0.0))


def _unit(a: np.ndarray, fallback=None) -> np.ndarray:
    length = np.linalg.norm(a, axis=1, keepdims=True)
    out = a / np.where(length > 0, length, 1.0)
    return out if fallback is None else np.where(length > 0, out, np.asarray(fallback, dtype=float))
