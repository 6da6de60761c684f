"""Point samples of a model: the "N near-uniform samples" of Squashing Cubes.

Two surface samplers:

* :func:`surface_grid_samples` (default; :func:`surface_grid` sets it up, so that its size is
  known first): a stratified grid on every triangle (Duffy map of the
  unit square, apex at the vertex opposite the shortest edge) with spacing at most ``spacing``
  in model units. Every point of every triangle lies within ``spacing`` of a sample, which is
  what makes the coverage guarantee of :func:`sc_fem.voxelize` provable. Sample weights are
  the exact triangle area each sample stands for (they sum to the mesh area).
* :func:`surface_random_samples`: the paper's N random area-weighted samples, each weighing
  A / N (no coverage guarantee).

:func:`volume_samples` puts 2 x 2 x 2 samples in each filled voxel (weight = volume).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .._arrays import row_norms
from .._jit import choose_kernel
from ..errors import MeshError
from . import sampling_jit


@dataclass(frozen=True, eq=False)
class Samples:
    """Point samples.

    Attributes
    ----------
    points : ndarray, shape (n, 3)
        Positions, model units.
    weight : ndarray, shape (n,)
        Area (model units^2) for surface samples, volume (model units^3) for volume samples,
        1 for point-cloud samples.
    face : ndarray of int, shape (n,)
        Source face of each sample, -1 where there is none.
    moments : ndarray, shape (k, 27), or None
        Volume samples: what the samples ``moment_rows`` add to their cube's moments
        (:mod:`sc_fem.lattice.moments`, in units of the cube's volume) beyond an even share. A cube's
        moments are a full cube's (``FULL``) times its filled fraction (its samples' ``weight``
        over ``pitch^3``) plus these; whole cubes and shells add nothing and are not listed, and a
        cut cube's sub-samples list their sum on one of them.
    moment_rows : ndarray of int, shape (k,), or None
        The samples ``moments`` belong to (None with ``moments``).
    """

    points: np.ndarray
    weight: np.ndarray
    face: np.ndarray
    moments: np.ndarray | None = None
    moment_rows: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)

    @staticmethod
    def concat(parts: Sequence["Samples"]) -> "Samples":
        """The samples of ``parts``, one after the other (their given moments kept, rows shifted)."""
        start = np.cumsum([0] + [len(q) for q in parts])
        given = [(q.moments, q.moment_rows + s) for q, s in zip(parts, start) if q.moments is not None]
        return Samples(np.vstack([q.points for q in parts]).reshape(-1, 3), np.concatenate([q.weight for q in parts]),
                       np.concatenate([q.face for q in parts]).astype(np.int64),
                       np.vstack([m for m, _ in given]) if given else None,
                       np.concatenate([r for _, r in given]).astype(np.int64) if given else None)


def _apex_frame(vertices: np.ndarray, faces: np.ndarray):
    """Each face's apex (the corner opposite its shortest edge, the first of equal ones) and the
    next two corners, each (m, 3), model units."""
    P = [vertices[faces[:, k]] for k in range(3)]
    opp = np.stack([row_norms(P[(k + 2) % 3] - P[(k + 1) % 3]) for k in range(3)], axis=1)
    a = np.argmin(opp, axis=1)[:, None]                               # edge opposite vertex k
    rolled = np.take_along_axis(faces, (a + np.arange(3)) % 3, axis=1)
    return tuple(vertices[rolled[:, j]] for j in range(3))


def grid_counts(vertices: np.ndarray, faces: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-face grid sizes (k_s, k_t) of :func:`surface_grid_samples` (cheap; for memory estimates)."""
    return _counts(*_apex_frame(vertices, faces), spacing)


def _counts(A: np.ndarray, B: np.ndarray, C: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`grid_counts` of the faces' apex frames."""
    long_edge = np.maximum(row_norms(B - A), row_norms(C - A))
    k_s = np.maximum(1, np.ceil(long_edge / spacing)).astype(np.int64)
    k_t = np.maximum(1, np.ceil(row_norms(C - B) / spacing)).astype(np.int64)
    return k_s, k_t


@dataclass(frozen=True, eq=False)
class SurfaceGrid:
    """The stratified sample grid of :func:`surface_grid_samples`, set up (faces of zero area
    dropped, each face's apex frame and grid size found) before a sample is made, so that a
    caller can size its memory from :attr:`n_samples` first.

    Attributes
    ----------
    face : ndarray of int, shape (f,)
        The faces sampled (those of non-zero area).
    area : ndarray, shape (f,)
        Their areas, model units^2.
    A, B, C : ndarray, shape (f, 3)
        Each face's apex (the vertex opposite its shortest edge) and the next two, model units.
    k_s, k_t : ndarray of int, shape (f,)
        Each face's grid size.
    """

    face: np.ndarray
    area: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    k_s: np.ndarray
    k_t: np.ndarray

    @property
    def n_samples(self) -> int:
        """The number of samples :meth:`samples` makes."""
        return int((self.k_s * self.k_t).sum())

    def samples(self, kernel: str = "auto") -> Samples:
        """The samples (see :func:`surface_grid_samples`, which documents ``kernel``)."""
        counts = self.k_s * self.k_t
        if choose_kernel(kernel) == "numba":
            n = int(counts.sum())
            pts, w, face = np.empty((n, 3)), np.empty(n), np.empty(n, np.int64)
            sampling_jit.grid_samples(self.A, self.B, self.C, self.area, self.k_s, self.k_t, np.cumsum(counts) - counts,
                                      pts, w, face)
            return Samples(points=pts, weight=w, face=self.face[face])
        A, B, C = self.A, self.B, self.C
        face = np.repeat(np.arange(len(self.face)), counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        i, j = np.divmod(local, self.k_t[face])
        s = ((i + 0.5) / self.k_s[face])[:, None]
        t = ((j + 0.5) / self.k_t[face])[:, None]
        pts = A[face] + s * (B[face] - A[face]) + s * t * (C[face] - B[face])
        w = 2.0 * self.area[face] * s[:, 0] / counts[face]
        return Samples(points=pts, weight=w, face=self.face[face])


def surface_grid(vertices: np.ndarray, faces: np.ndarray, spacing: float) -> SurfaceGrid:
    """The sample grid of :func:`surface_grid_samples` (same parameters), before its samples.

    Raises
    ------
    MeshError
        Every face has zero area.
    """
    area = 0.5 * row_norms(np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                                    vertices[faces[:, 2]] - vertices[faces[:, 0]]))
    fidx = np.flatnonzero(area > 1e-12 * spacing**2)
    if len(fidx) == 0:
        raise MeshError("every face has zero area: nothing to sample")
    A, B, C = _apex_frame(vertices, faces[fidx])
    return SurfaceGrid(fidx, area[fidx], A, B, C, *_counts(A, B, C, spacing))


def surface_grid_samples(vertices: np.ndarray, faces: np.ndarray, spacing: float, kernel: str = "auto") -> Samples:
    """Stratified samples with every surface point within ``spacing`` of a sample.

    With apex A opposite the shortest edge BC, sample (i, j) sits at
    ``A + s (B - A) + s t (C - B)`` with ``s = (i + 1/2)/k_s``, ``t = (j + 1/2)/k_t``; the
    Jacobian of this map is ``2 * area * s``, which is the weight each sample carries.
    Faces of zero area carry no material and get no samples.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
        Model units.
    faces : ndarray of int, shape (m, 3)
    spacing : float
        Largest distance from a surface point to its nearest sample, model units.
    kernel : {"auto", "numba", "numpy"}
        The compiled kernel (:mod:`sc_fem.geometry.sampling_jit`, with numba) or the numpy path;
        both give the same samples.

    Returns
    -------
    Samples
        Points (model units), weights (the area each stands for, model units^2) and faces.
    """
    return surface_grid(vertices, faces, spacing).samples(kernel)


def surface_random_samples(vertices: np.ndarray, faces: np.ndarray, n: int,
                           rng: np.random.Generator) -> Samples:
    """``n`` random area-weighted surface samples of equal weight (area / n)."""
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    total = area.sum()
    if not total > 0:
        raise MeshError("every face has zero area: nothing to sample")
    face = rng.choice(len(faces), size=n, p=area / total)
    r1 = np.sqrt(rng.random(n))[:, None]
    r2 = rng.random(n)[:, None]
    t = tri[face]
    pts = (1 - r1) * t[:, 0] + r1 * (1 - r2) * t[:, 1] + r1 * r2 * t[:, 2]
    return Samples(points=pts, weight=np.full(n, total / n), face=face)


def sub_offsets(n_sub: int) -> np.ndarray:
    """Centres of the ``n_sub^3`` sub-cubes of a unit cube, shape (n_sub^3, 3), z fastest."""
    return (np.stack(np.meshgrid(*[np.arange(n_sub)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) / n_sub


def volume_samples(cells: np.ndarray, origin: np.ndarray, pitch: float) -> Samples:
    """2 x 2 x 2 samples at the sub-cell centres of each cell, each weighing ``pitch^3 / 8``."""
    sub = sub_offsets(2)
    pts = np.repeat(np.asarray(cells, dtype=np.float64), 8, axis=0)      # in place: origin + pitch * (cell + sub)
    pts.reshape(-1, 8, 3)[...] += sub
    pts *= pitch
    pts += origin
    return Samples(points=pts, weight=np.full(len(pts), pitch**3 / 8.0),
                   face=np.full(len(pts), -1, dtype=np.int64))
