"""Solids on the voxel grid: the volume and moments of the enclosed material in every cube.

:func:`solid_fill` turns the parts of a mesh that enclose volume into volume samples carrying the
exact volume and moments (:mod:`sc_fem.lattice.moments`) of the solid in each cube: by the divergence
theorem over the faces cut along the grid planes for parts that close up, with the overlap of
intersecting parts counted once, and by winding-number tests on a sub-grid for leaky parts.
"""

from __future__ import annotations

import numpy as np

from .gridcut import cut_by_grid
from .topology import mark_cells, unique_cells, voxel_index
from .moments import FULL, ROW_CHUNK, box_moments, column_moments
from ..geometry.cellwinding import CellWinding
from ..geometry.inside import boundary_cone
from ..geometry.rays import crossing_number
from ..geometry.sampling import Samples, sub_offsets, volume_samples

OVERLAP_SAMPLES_PER_SIDE = 256
"""Overlaps of intersecting parts are sampled with a spacing of 1/256 of the grid's longest side."""


def bbox_cover(vertices: np.ndarray, parts, which: np.ndarray, origin: np.ndarray, pitch: float,
                dims: np.ndarray) -> np.ndarray:
    """How many of the parts ``which`` (k,) bool have a bounding box covering each grid cell
    (3-D difference array + prefix sums, vectorized over parts)."""
    dims = np.asarray(dims, dtype=np.int64)
    lo, hi = parts.boxes(vertices)
    sel = np.flatnonzero(which)
    a = voxel_index(lo[sel], origin, pitch, dims)
    b = voxel_index(hi[sel], origin, pitch, dims) + 1
    diff = np.zeros(tuple(dims + 1), dtype=np.int32)
    for corner in np.ndindex(2, 2, 2):          # the 8 corners of each box, with inclusion-exclusion signs
        c = np.where(np.array(corner, bool), b, a)
        np.add.at(diff, tuple(c.T), (-1) ** sum(corner))
    return diff.cumsum(0).cumsum(1).cumsum(2)[:dims[0], :dims[1], :dims[2]]


def solid_fill(occupied: np.ndarray, vertices: np.ndarray, parts, solid_part: np.ndarray, surf: Samples,
                origin: np.ndarray, pitch: float, n_sub: int) -> tuple[list[Samples], np.ndarray]:
    """Volume samples (weight = volume, model units^3) of the solid parts on the grid, in pieces
    (for the caller to join with its own in one copy), and the cells that hold them, shape (k, 3) int.

    Cells the surface does not touch are inside when the winding number of the solid parts at
    their centre exceeds 1/2. Every cube of the closed parts gets its volume from
    :func:`sc_fem.lattice.moments.column_moments` (one sample at the cube centre; over all the cubes of a column, so the
    sums telescope to the exact enclosed volume), less the overlap of intersecting parts, which
    is sampled (winding numbers on a sub-grid) only in the cubes where a part's surface lies
    inside another part. Untouched inside cells of other solid parts get 2x2x2 samples of
    ``pitch^3 / 8``.
    Surface cells of closed-but-leaky parts (holes) and of parts forced solid get ``n_sub^3``
    inside-tested sub-cube samples.
    """
    dims = np.array(occupied.shape)
    solid_faces = solid_part[parts.label]
    sf = parts.faces[solid_faces]
    used = np.zeros(len(vertices), dtype=bool)
    used[sf.ravel()] = True
    sv = vertices[used]
    lo = np.clip(np.floor((sv.min(0) - origin) / pitch).astype(np.int64), 0, dims - 1)
    hi = np.clip(np.floor((sv.max(0) - origin) / pitch).astype(np.int64), 0, dims - 1) + 1
    region = np.zeros_like(occupied)
    region[tuple(slice(a, b) for a, b in zip(lo, hi))] = True
    free = np.argwhere(region & ~occupied)
    # closed parts have integer winding numbers: exact ray crossings; leaky ones need the generalized
    leaky_solids = not (parts.watertight | ~solid_part).all()
    # one cone for every call below: the parts' own when every part is solid; closed: crossings alone
    cone = ((parts.cone if parts.cone is not None and solid_faces.all() else boundary_cone(vertices, sf))
            if leaky_solids else (np.zeros((0, 3)), np.zeros((0, 3), np.int64)))
    winding = CellWinding(vertices, sf, origin, pitch, cone)       # set up once for the free and the cut cells
    w_free = winding(free, 1)[:, 0]
    interior, w_interior = free[w_free > 0.5], w_free[w_free > 0.5]

    tight_part = solid_part & parts.watertight
    tight_faces = tight_part[parts.label]
    on_solid = solid_faces[surf.face]
    tight = tight_faces[surf.face]
    leaky = on_solid & ~tight
    offs = sub_offsets(n_sub)
    pieces, cells = [], []
    if tight.any():
        tf = parts.faces[tight_faces]
        if leaky.any():     # interior cells of the closed parts; the others are leaky parts'
            w_interior = crossing_number(vertices, tf, origin + pitch * (interior + 0.5))
        in_tight = w_interior > 0.5
        tight_interior, interior = interior[in_tight], interior[~in_tight]
        # an untouched cube inside k intersecting closed parts is counted k times by the columns
        multiple = np.clip(np.rint(w_interior[in_tight]) - 1.0, 0.0, None)
        at_tight = np.flatnonzero(tight)                    # the closed parts' samples (not copied)
        # all cubes of the columns' solid, so that the column sums telescope to the exact volume
        bcells = np.vstack([np.argwhere(region & occupied), tight_interior])
        excess = np.r_[np.zeros(len(bcells) - len(tight_interior)), multiple]
        order = np.argsort(np.ravel_multi_index(bcells.T, dims), kind="stable")
        bcells, excess = bcells[order], excess[order]
        # each closed part's volume and moments per cube, exact (overlaps count twice): the faces cut
        # along the grid planes, each piece integrated exactly ...
        pieces_t, _ = cut_by_grid(vertices[tf], origin, pitch)
        mom = column_moments(pieces_t, origin, pitch, dims, bcells)
        over = np.flatnonzero(excess)                       # cubes counted more than once (x - 0 is x)
        mom[over] -= excess[over, None] * FULL
        # ... less the overlaps, sampled in the cubes where a part's surface lies inside another part
        eps = 1e-6 * float(np.linalg.norm(np.ptp(vertices, axis=0)))
        # only samples in cubes that two parts' bounding boxes cover can lie inside another part
        cover = bbox_cover(vertices, parts, tight_part, origin, pitch, dims)
        buried = np.zeros(len(at_tight), dtype=bool)
        if cover.max(initial=0) >= 2:
            pts = surf.points[at_tight]
            maybe = np.flatnonzero(cover[tuple(voxel_index(pts, origin, pitch, dims).T)] >= 2)
            tri = vertices[parts.faces[surf.face[tight][maybe]]]
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
            # just inside its own part, a sample sees winding number 1, or more where another part
            # overlaps (this also catches coplanar faces of parts resting flush on one another)
            buried[maybe] = crossing_number(vertices, tf, pts[maybe] - eps * n) >= 1.5
        if buried.any():
            # sub-cube spacing about 1/256 of the grid's longest side, whatever the resolution
            n_ov = max(n_sub, -(-OVERLAP_SAMPLES_PER_SIDE // int(dims.max())))
            o_offs = sub_offsets(n_ov)
            ocells = unique_cells(voxel_index(surf.points[at_tight[buried]], origin, pitch, dims), dims)
            sub = origin + pitch * (ocells[:, None, :] + o_offs[None]).reshape(-1, 3)
            excess = np.clip(np.rint(crossing_number(vertices, tf, sub)) - 1.0, 0.0, None)
            lin_b = np.ravel_multi_index(bcells.T, dims)
            at = np.searchsorted(lin_b, np.ravel_multi_index(ocells.T, dims))
            # every cell has the same sub-boxes: (cells, q) excess times (q, 27) sub-box moments
            mom[at] -= excess.reshape(len(ocells), -1) @ box_moments(o_offs - 0.5 / n_ov, 1.0 / n_ov)
        vol = mom[:, 0] * pitch**3
        keep = vol > 1e-9 * pitch**3
        n_kept = int(keep.sum())
        uneven = mom if n_kept == len(mom) else mom[keep]   # beyond an even share, in place by row chunks
        for r in range(0, n_kept, ROW_CHUNK):
            u = uneven[r:r + ROW_CHUNK]
            u -= u[:, :1] * FULL
        kept = bcells[keep]
        pieces.append(Samples(origin + pitch * (kept + 0.5), vol[keep], np.full(n_kept, -1, dtype=np.int64),
                              uneven, np.arange(n_kept)))
        cells.append(kept)
    pieces.append(volume_samples(interior, origin, pitch))          # whole cubes: even shares, no moments
    cells.append(interior)
    if leaky.any():
        bcells = np.argwhere(mark_cells(np.zeros(occupied.shape, dtype=bool), surf.points, origin, pitch, leaky))
        inside = winding(bcells, n_sub).ravel() >= 1           # a leaky solid part: its cone
        cell, sub = np.divmod(np.flatnonzero(inside), len(offs))
        pts = bcells.astype(np.float64)[cell]                   # the inside sub-cubes' centres, in place:
        pts += offs[sub]                                        # origin + pitch * (cell + offset)
        pts *= pitch
        pts += origin
        if tight_part.any():        # not where a watertight part already counted the volume
            tf = parts.faces[tight_faces]
            outside_tight = crossing_number(vertices, tf, pts) < 0.5
            inside[inside], pts = outside_tight, pts[outside_tight]
        # what each sub-cube adds beyond an even share, summed over a cell's inside ones onto its first
        inside_cq = inside.reshape(len(bcells), len(offs))
        uneven = box_moments(offs - 0.5 / n_sub, 1.0 / n_sub) - FULL / len(offs)          # (q, 27)
        count = inside_cq.sum(axis=1)
        has = count > 0
        n_in = int(count.sum())
        pieces.append(Samples(pts, np.full(n_in, pitch**3 / n_sub**3), np.full(n_in, -1, dtype=np.int64),
                              inside_cq[has].astype(np.float64) @ uneven, (np.cumsum(count) - count)[has]))
        cells.append(bcells[has])
    return pieces, np.vstack(cells)
