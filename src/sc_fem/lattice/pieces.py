"""The bodies of a voxelized model (``topology="pieces"``): the mesh's bodies found once, voxelized
in batches whose cells cannot meet so that every cube knows its body (its ``piece``), and the
components kept afterwards (``keep=``)."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np

from ..errors import ScFemWarning
from ..geometry.bodies import DEFAULT_WELD_FRACTION, find_bodies
from ..geometry.inside import group_boxes, mesh_parts
from ..geometry.sampling import Samples
from .cubes import CubeModel, voxel_index
from .mass import _inward, _mass_samples, _occupied_cells, _solid_parts
from .options import VoxelOptions

LOOSE_FRACTION = 0.01
"""``keep="bodies"``: bodies lighter than this fraction of the heaviest are loose (not kept)."""


def _find_bodies(vertices, faces, opts: VoxelOptions, longest: float, cloud: bool):
    """The bodies of ``topology="pieces"`` (None for ``"grid"`` and point clouds), the body of
    every face, shape (m,), and the mesh's parts (None when not needed), found once."""
    if cloud or opts.topology == "grid":
        return None, np.zeros(len(faces), np.int64), None
    parts = mesh_parts(vertices, faces)
    weld = DEFAULT_WELD_FRACTION * longest if opts.weld is None else opts.weld
    bodies = find_bodies(vertices, parts, weld)
    return bodies, bodies.of_part[parts.label], parts


def _batches(vertices, faces, face_body, n_bodies: int, grid) -> tuple[list[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Bodies in batches whose cell boxes do not overlap, so one voxelization pass per batch can
    tell every cube's body by where it lies (greedy, over bodies). Returns the batches (arrays of
    body indices) and every body's lowest and highest cell, each (n_bodies, 3)."""
    origin, pitch, dims = grid
    lo, hi = group_boxes(vertices, faces, face_body, n_bodies)
    a, b = voxel_index(lo, origin, pitch, dims), voxel_index(hi, origin, pitch, dims)
    batch = np.full(n_bodies, -1)
    for i in np.argsort(-np.prod(b - a + 1, axis=1), kind="stable"):     # bodies, largest box first
        clash = np.all((a[i] <= b) & (a <= b[i]), axis=1) & (batch >= 0)
        taken = np.unique(batch[clash])
        free = np.setdiff1d(np.arange(len(taken) + 1), taken)
        batch[i] = free[0]
    return [np.flatnonzero(batch == k) for k in range(batch.max() + 1)], (a, b)


def _body_samples(surf: Samples, vertices, faces, grid, opts: VoxelOptions, thick: float, face_body, bodies,
                  parts=None):
    """The mass samples (faces: global indices) and the body of each; one voxelization pass per
    batch of bodies whose cells cannot meet (:func:`_batches`)."""
    origin, pitch, dims = grid
    if bodies is None or bodies.n_bodies == 1 or not len(faces):
        solids = _solid_parts(vertices, faces, opts.fill, parts)       # the parts bodies found, reused
        occupied, counts = _occupied_cells(surf, vertices, faces, grid, opts.occupancy,
                                           located=_inward(vertices, *solids, surf, pitch))
        samples, parts_info, shells, counts["floor_cubes"] = _mass_samples(occupied, surf, vertices, faces, grid,
                                                                          opts, thick, solids)
        return samples, np.zeros(len(samples), np.int64), parts_info, shells, counts
    batches, (a, b) = _batches(vertices, faces, face_body, bodies.n_bodies, grid)
    out, body, counts, parts_info, shells = [], [], {}, {}, False
    vb = np.full(len(vertices), -1)
    vb[faces.ravel()] = np.repeat(face_body, 3)
    for k, members in enumerate(batches):          # a few batches of bodies
        fsel = np.flatnonzero(np.isin(face_body, members))
        local = np.full(len(faces), -1)
        local[fsel] = np.arange(len(fsel))
        ssel = np.isin(face_body[surf.face], members)
        surf_k = Samples(surf.points[ssel], surf.weight[ssel], local[surf.face[ssel]])
        own = np.isin(vb, members) | ((vb < 0) & (k == 0))      # unreferenced vertices: the first batch
        solids = _solid_parts(vertices, faces[fsel], opts.fill)
        occupied, c = _occupied_cells(surf_k, vertices, faces[fsel], grid, opts.occupancy, own_vertices=own,
                                      located=_inward(vertices, *solids, surf_k, pitch))
        smp, pinfo, sh, c["floor_cubes"] = _mass_samples(occupied, surf_k, vertices, faces[fsel], grid, opts, thick,
                                                         solids)
        owner = np.full(tuple(int(d) for d in dims), -1, dtype=np.int64)
        for m in members:                                        # bodies of this batch: their cell boxes
            owner[tuple(slice(int(lo_), int(hi_) + 1) for lo_, hi_ in zip(a[m], b[m]))] = m
        sb = owner[tuple(voxel_index(smp.points, origin, pitch, dims).T)]
        if np.any(sb < 0):                                       # cannot happen: cells lie in their body's box
            raise RuntimeError("a mass sample fell outside its body's cells")
        out.append(dataclasses.replace(smp, face=np.where(smp.face >= 0, fsel[np.maximum(smp.face, 0)], -1)))
        body.append(sb)
        shells |= sh
        for key, v in {**c, **pinfo}.items():
            counts[key] = counts.get(key, 0) + v
    parts_info = {key: counts.pop(key) for key in ("parts", "solid_parts", "shell_parts") if key in counts}
    samples = Samples.concat(out)
    return samples, np.concatenate(body), parts_info, shells, counts


def _keep(model: CubeModel, keep: str, info: dict) -> CubeModel:
    """Apply ``keep`` (see :class:`VoxelOptions`) and record what was dropped."""
    n_comp = model.n_components
    info.update(components_found=n_comp, cubes_found=model.n_cubes)
    if keep == "all" or n_comp == 1:
        return model.with_info(**info, dropped_cubes=0, loose_bodies=0)
    # components are numbered largest first: the largest of each body ("bodies") or of all
    first = np.full(int(model.piece.max()) + 1, n_comp)
    np.minimum.at(first, model.piece, model.component)
    mask = model.component == (first[model.piece] if keep == "bodies" else 0)
    loose = np.zeros(len(first), bool)
    if keep == "bodies":          # ... of the bodies that are not loose
        body_mass = np.bincount(model.piece, weights=model.mass)
        loose = (body_mass < LOOSE_FRACTION * body_mass.max()) & (body_mass > 0)
        mask &= ~loose[model.piece]
    kept = model.subset(mask)
    dropped = model.n_cubes - kept.n_cubes
    if dropped > kept.n_cubes:
        warnings.warn(
            f"keep={keep!r} kept {kept.n_cubes} of {model.n_cubes} cubes ({n_comp} components): "
            f"most of the model was dropped; use a coarser resolution, connectivity='vertex' or "
            f"keep='all'", ScFemWarning, stacklevel=4)
    return kept.with_info(**info, dropped_cubes=dropped, loose_bodies=int(loose.sum()))
