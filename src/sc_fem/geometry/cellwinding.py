"""Winding numbers on a voxel grid: the rounded generalized winding number at the centres of cells
and of their sub-cubes, as the solid fill of the lattice asks for them.

:func:`cell_winding` gives what :func:`sc_fem.geometry.inside.winding_number` gives, rounded, at
those points, faster: it visits them along the rays the crossings are counted on, so that the
points on a ray share its crossings, and it skips libigl's winding number of the cone over the
holes in cells where a bound (:func:`_cone_certain`) shows it cannot change the rounded count.
"""

from __future__ import annotations

import numpy as np

from . import inside_jit
from .._arrays import column_bounds
from .._jit import choose_kernel
from .inside import _fast_winding_number, _ray_axis, boundary_cone, cone_winding_number
from .rays import bin_grid, crossing_faces, crossing_number
from .sampling import sub_offsets

CONE_CERTAIN = 0.4
""":func:`cell_winding` skips the cone's winding number in a cell where a bound says it is below this
everywhere in the cell (it cannot change the rounded count; libigl's far-field error is ~5e-3)."""

CONE_PIECES_BOUNDED = 256
""":func:`cell_winding` bounds the cone's winding number piece by piece up to this many cone pieces
(holes); past that, it is evaluated at every point."""


RIM_PAIRS = 1 << 25
"""The second bound of :func:`_cone_certain` runs up to this many (cell, cone triangle) pairs (0.12 s
for 32,768 cells and 1,024 cone triangles, compiled, one run);
past that (a large hole near most cells), libigl is evaluated wherever the first bound leaves it."""


def _rim_bounds(centres: np.ndarray, tri: np.ndarray, half_diagonal: float,
                kernel: str = "auto") -> tuple[np.ndarray, np.ndarray]:
    """For cells (centres (k, 3)) near the cone's triangles ``tri`` (f, 3, 3), whose first two corners
    are an edge of a hole's rim: the distance of each centre to the nearest triangle's box, and a
    bound of the cone's winding number's gradient in the cell, ``1/(4 pi) * sum over rim edges of
    length / (distance - half_diagonal)^2`` (Biot--Savart: the gradient of a surface's solid angle
    is the field of its rim; inf where an edge is within the half diagonal). Compiled
    (:data:`sc_fem.geometry.inside_jit.rim_bounds`, with numba) or numpy; both agree to round-off.
    Returns two arrays of shape (k,), model units and 1 / model units."""
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    a, e = np.ascontiguousarray(tri[:, 0]), np.ascontiguousarray(tri[:, 1] - tri[:, 0])
    c = np.ascontiguousarray(centres, dtype=np.float64)
    if choose_kernel(kernel) == "numba":
        box, grad = np.empty(len(c)), np.empty(len(c))
        inside_jit.rim_bounds(c, lo, hi, a, e, float(half_diagonal), box, grad)
        return box, grad
    box, grad = np.empty(len(c)), np.empty(len(c))
    step = max(1, (1 << 20) // max(len(tri), 1))
    for s in range(0, len(c), step):                      # chunks of cells x triangles (bounded memory)
        q = c[s:s + step, None, :]
        box[s:s + step] = np.linalg.norm(np.maximum(np.maximum(lo[None] - q, q - hi[None]), 0.0), axis=2).min(axis=1)
        t = np.clip(np.einsum("kfj,fj->kf", q - a[None], e) / np.maximum(np.einsum("ij,ij->i", e, e), 1e-300), 0.0, 1.0)
        dist = np.linalg.norm(q - a[None] - t[..., None] * e[None], axis=2) - half_diagonal
        grad[s:s + step] = np.sum(np.where(dist > 0, np.linalg.norm(e, axis=1) / np.where(dist > 0, dist, 1.0) ** 2,
                                           np.inf), axis=1) / (4 * np.pi)
    return box, grad


def _cone_certain(closed_v: np.ndarray, apex: np.ndarray, cone: np.ndarray, centres: np.ndarray,
                  half_diagonal: float, kernel: str = "auto") -> np.ndarray:
    """Cells (centres (c, 3), model units) in which the cone's winding number is certainly below
    :data:`CONE_CERTAIN` in magnitude, in two steps (``half_diagonal`` 0: at the centres alone).

    1. Far from the holes: a surface of area ``A`` at distance ``>= d`` subtends a solid angle of at
       most ``A / d^2``; summed over the cone's pieces (one fan per apex), each piece's distance
       bounded by its apex, the radius of the fan and the cell's half diagonal ``h``.
    2. The others, when no cone triangle's box comes within ``h`` of the centre (so the winding
       number is smooth in the cell): its value at the centre (libigl) plus ``h`` times the bound of
       its gradient of :func:`_rim_bounds`.

    ``closed_v``: the mesh's vertices, then the apexes (``apex`` (a, 3)); ``cone`` (c, 3) indexes it.
    On the bunny at 64 the first step leaves 14 % of the 11,288 cells of its vertices, the second
    3.4 %; the winding number exceeds 0.4 in 1.1 % (at 64 points a cell). ``kernel``: the first
    step compiled (:data:`sc_fem.geometry.inside_jit.area_bounds`, with numba) or numpy.
    """
    if len(apex) > CONE_PIECES_BOUNDED:
        return np.zeros(len(centres), dtype=bool)
    tri = closed_v[cone]
    piece = cone[:, 2] - (len(closed_v) - len(apex))
    area = np.bincount(piece, weights=0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                                            axis=1), minlength=len(apex))
    radius = np.zeros(len(apex))
    np.maximum.at(radius, piece, np.linalg.norm(tri[:, :2] - apex[piece][:, None, :], axis=2).max(axis=1))
    bound = np.empty(len(centres))
    if choose_kernel(kernel) == "numba":
        inside_jit.area_bounds(np.ascontiguousarray(centres, dtype=np.float64), np.ascontiguousarray(apex), radius,
                               area, float(half_diagonal), bound)
    else:
        for s in range(0, len(centres), 1 << 16):        # chunks of cells x pieces (bounded memory)
            d = np.linalg.norm(centres[s:s + (1 << 16), None, :] - apex[None], axis=2) - radius - half_diagonal
            bound[s:s + (1 << 16)] = np.sum(np.where(d > 0, area / np.where(d > 0, d, 1.0) ** 2, np.inf),
                                            axis=1) / (4 * np.pi)
    certain = bound < CONE_CERTAIN
    rest = np.flatnonzero(~certain)
    if len(rest) == 0 or len(rest) * len(cone) > RIM_PAIRS or half_diagonal == 0:   # 0: step 2 is libigl's value
        return certain
    box, grad = _rim_bounds(centres[rest], tri, half_diagonal)
    rest, grad = rest[box > half_diagonal], grad[box > half_diagonal]
    certain[rest] = np.abs(cone_winding_number(closed_v, cone, centres[rest])) + half_diagonal * grad < CONE_CERTAIN
    return certain


class CellWinding:
    """The rounded generalized winding number of one surface at the sub-cube centres of cells of
    one grid, set up once for several sets of cells (:func:`cell_winding` is one call of it).

    Equal to ``np.rint(winding_number(vertices, faces, points, cone))``
    (:func:`~sc_fem.geometry.inside.winding_number`) for the points
    ``origin + pitch * (cells[:, None, :] + sub_offsets(n_sub)[None])`` (so ``>= 1`` is its
    ``> 1/2``), found faster: the points are visited along the rays it casts, so that the points
    on one ray share its crossings (:func:`~sc_fem.geometry.rays.crossing_number`), and the
    cone's winding number over the holes is evaluated only where a bound
    (:func:`_cone_certain`) lets it reach :data:`CONE_CERTAIN` (elsewhere it cannot change the
    rounded count). The faces the rays cross, rotated and binned, are kept between calls that
    cast their rays along the same axis with bins of the same size.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
        Model units.
    faces : ndarray of int, shape (m, 3)
    origin : ndarray, shape (3,)
        The grid's corner, model units.
    pitch : float
        The cells' side, model units.
    cone : (apex, cone faces), optional
        :func:`~sc_fem.geometry.inside.boundary_cone` of ``(vertices, faces)`` when the caller has it.
    kernel : {"auto", "numba", "numpy"}
        The crossings counted column by column by a compiled kernel (with numba), or every point
        built and counted by :func:`~sc_fem.geometry.rays.crossing_number`; the same counts.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray, pitch: float,
                 cone: tuple[np.ndarray, np.ndarray] | None = None, kernel: str = "auto") -> None:
        self.v = np.asarray(vertices, dtype=np.float64)
        self.f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        self.origin, self.pitch = np.asarray(origin, dtype=np.float64).reshape(3), float(pitch)
        self.apex, self.cone = boundary_cone(self.v, self.f) if cone is None else cone
        self.closed_v = np.vstack([self.v, self.apex])
        self.compiled = choose_kernel(kernel) == "numba"
        self._binned: dict = {}                  # axis -> rotated faces and box; (axis, n_bins) -> bins

    def __call__(self, cells: np.ndarray, n_sub: int = 1) -> np.ndarray:
        """The rounded winding numbers at the ``n_sub^3`` sub-cube centres of ``cells`` (c, 3) int:
        shape (c, n_sub^3), integer values, sub-cubes in :func:`sub_offsets` order."""
        f, cone, origin, pitch = self.f, self.cone, self.origin, self.pitch
        cells = np.asarray(cells, dtype=np.int64).reshape(-1, 3)
        offs = sub_offsets(n_sub)
        out = np.zeros((len(cells), len(offs)))
        if len(f) == 0 or len(cells) == 0:
            return out
        axis = _ray_axis(self.closed_v, f, cone, out.size) if len(cone) else 2
        if axis is None:                         # the cone would crowd the ray-crossing bins: libigl alone
            pts = origin + pitch * (cells[:, None, :] + offs[None])     # as the callers build them
            return np.rint(_fast_winding_number(self.v, f, pts.reshape(-1, 3))).reshape(out.shape)
        order = [(axis + 1) % 3, (axis + 2) % 3, axis]          # a rotation taking the ray's axis to z
        sub_index = np.arange(len(offs)).reshape((n_sub,) * 3).transpose(order)
        if self.compiled:
            self._column_count(axis, cells[:, order], origin[order], n_sub, sub_index, out)
        else:
            _point_count(self.closed_v[:, order], np.vstack([f, cone]), cells[:, order], origin[order], pitch, n_sub,
                         sub_index, out)
        if len(cone):            # one point a cell, no compiled bound: libigl's far field is cheaper than the bound
            near = np.flatnonzero(~_cone_certain(self.closed_v, self.apex, cone, origin + pitch * (cells + 0.5),
                                                 0.5 * np.sqrt(3) * pitch if n_sub > 1 else 0.0,
                                                 "numba" if self.compiled else "numpy")
                                  if n_sub > 1 or self.compiled else np.ones(len(cells), bool))
            pts = origin + pitch * (cells[near][:, None, :] + offs[None])
            w = cone_winding_number(self.closed_v, cone, pts.reshape(-1, 3))
            out[near] = np.rint(out[near] - w.reshape(len(near), len(offs)))
        return out

    def _column_count(self, axis: int, cells: np.ndarray, o: np.ndarray, n_sub: int, sub_index: np.ndarray,
                      out: np.ndarray) -> None:
        """The signed ray crossings at the sub-cube centres of ``cells`` into ``out`` (c, n_sub^3),
        compiled (:data:`sc_fem.geometry.inside_jit.column_crossings`): the cells grouped into
        columns along the ray, each ray's crossings found once for its column. ``cells`` and ``o``
        are rotated so that the rays run along z; ``sub_index[a, b, k]`` is the column of ``out``
        of the sub-cube ``(a, b, k)`` in that frame."""
        if axis not in self._binned:             # the rotated faces (with their box), then their bins by size
            order = [(axis + 1) % 3, (axis + 2) % 3, axis]
            self._binned[axis] = crossing_faces(self.closed_v[:, order], np.vstack([self.f, self.cone]))
        if self._binned[axis] is None:
            return
        tri, lo, hi = self._binned[axis]
        size, nb = bin_grid(lo, hi, len(tri), out.size)
        if (axis, nb) not in self._binned:
            self._binned[axis, nb] = inside_jit.bin_faces(tri, lo, size, nb)
        start, bin_face = self._binned[axis, nb]
        base, top = column_bounds(cells, 2)
        span = top - base + 1
        perm, col_start = inside_jit.columns((cells[:, 0] - base[0]) * span[1] + cells[:, 1] - base[1], int(span.prod()))
        inside_jit.column_crossings(cells, col_start, perm, o, self.pitch, (np.arange(n_sub) + 0.5) / n_sub,
                                    np.ascontiguousarray(sub_index), tri, lo, hi, size, nb, start, bin_face, out)


def cell_winding(vertices: np.ndarray, faces: np.ndarray, cells: np.ndarray, origin: np.ndarray, pitch: float,
                 n_sub: int = 1, cone: tuple[np.ndarray, np.ndarray] | None = None,
                 kernel: str = "auto") -> np.ndarray:
    """The rounded generalized winding number at the sub-cube centres of grid cells: one call of
    :class:`CellWinding` (which documents the parameters) on ``cells`` (c, 3) int with ``n_sub``
    sub-cubes a side. Returns shape (c, n_sub^3), integer values, sub-cubes in
    :func:`sub_offsets` order."""
    return CellWinding(vertices, faces, origin, pitch, cone, kernel)(cells, n_sub)


def _point_count(v: np.ndarray, faces: np.ndarray, cells: np.ndarray, o: np.ndarray, pitch: float, n_sub: int,
                 sub_index: np.ndarray, out: np.ndarray) -> None:
    """:func:`_column_count` the numpy way: every point built (ray's axis fastest within a cell, the
    cells of one ray in turn when there is one point a cell) and counted by
    :func:`~sc_fem.geometry.rays.crossing_number`."""
    sub = sub_index.ravel()                                # rotated sub-cubes, the ray's axis fastest
    by_ray = np.lexsort((cells[:, 2], cells[:, 1], cells[:, 0])) if n_sub == 1 else np.arange(len(cells))
    offs = sub_offsets(n_sub)                              # rotated offsets: the same (i + 1/2) / n_sub
    q = (o + pitch * (cells[by_ray][:, None, :] + offs[None])).reshape(-1, 3)
    count = crossing_number(v, faces, q).reshape(len(cells), len(offs))
    out[np.ix_(by_ray, sub)] = count
