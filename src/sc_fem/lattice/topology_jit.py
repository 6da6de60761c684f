"""Compiled cells of points of :func:`sc_fem.lattice.topology.voxel_index` (numba, optional).

The numpy path makes three temporaries the size of the points (shifted, floored, cast) before it
clips; this kernel computes each point's cell in one pass, points split over the cores, with the
same arithmetic, so both give the same cells. Without numba (the optional extra ``sc_fem[fast]``)
the numpy path runs.
"""

from __future__ import annotations

import math

from .._jit import compiled_parallel, prange


def _cells_py(points, origin, pitch, hi, out):  # pragma: no cover - compiled
    """``out[i, d] = clip(floor((points[i, d] - origin[d]) / pitch), 0, hi[d])`` for points (n, 3)."""
    for i in prange(points.shape[0]):
        for d in range(3):
            c = int(math.floor((points[i, d] - origin[d]) / pitch))
            out[i, d] = 0 if c < 0 else (hi[d] if c > hi[d] else c)


cells = compiled_parallel(_cells_py)
"""The compiled :func:`_cells_py` (None without numba)."""
