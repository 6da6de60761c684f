"""Compiled stratified surface samples of :func:`sc_fem.geometry.sampling.surface_grid_samples` (numba, optional).

The numpy path expands every (face, sample) pair into index arrays before it computes a point; this
kernel writes each face's ``k_s x k_t`` samples in place, faces split over the cores, with the same
arithmetic in the same order, so both give the same samples. Without numba (the optional extra
``sc_fem[fast]``) the numpy path runs.
"""

from __future__ import annotations

from .._jit import compiled_parallel, prange


def _grid_samples_py(A, B, C, area, k_s, k_t, start, pts, w, face):  # pragma: no cover - compiled
    """Samples of the faces (apex ``A``, ``B``, ``C``, each (f, 3); ``area`` (f,); grid ``k_s x k_t``)
    into rows ``start[f]:start[f + 1]`` of ``pts`` (n, 3), ``w`` (n,) and ``face`` (n,)."""
    for f in prange(A.shape[0]):
        ks, kt = k_s[f], k_t[f]
        count = ks * kt
        twice = 2.0 * area[f]
        for i in range(ks):
            s = (i + 0.5) / ks
            for j in range(kt):
                st = s * ((j + 0.5) / kt)
                r = start[f] + i * kt + j
                for d in range(3):
                    pts[r, d] = A[f, d] + s * (B[f, d] - A[f, d]) + st * (C[f, d] - B[f, d])
                w[r] = twice * s / count
                face[r] = f


grid_samples = compiled_parallel(_grid_samples_py)
"""The compiled :func:`_grid_samples_py` (None without numba)."""
