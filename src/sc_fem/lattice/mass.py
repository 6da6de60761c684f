"""The samples that carry a voxelized model's mass (:func:`sc_fem.voxelize`): which cubes the
surface occupies, solid interiors (winding-number fill), shells of a physical thickness, a small
floor mass for cubes no sample reached, and every sample's material and mass."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .._validate import check_material
from ..errors import InputError
from ..geometry.inside import mesh_parts
from .._arrays import row_norms
from ..geometry.sampling import Samples
from ..material import resolve_field
from .cubes import voxel_index
from .topology import mark_cells
from .fill import solid_fill
from .options import VoxelOptions
from .overlap import overlapping_cells

INWARD_NUDGE = 1e-6
"""Surface samples and vertices of closed solids are located in the grid this far (in cubes)
inside their solid: a face lying exactly on a grid plane then occupies the cube of its material,
not the empty one beyond it (which became a 1/128-mass "floor cube": +0.18 % mass on a box with
a post at resolution 8)."""


def _solid_parts(vertices, faces, fill: str, parts=None):
    """The mesh's parts (``parts`` when already found for these faces) and which of them are
    solids under ``fill`` ((None, None) for a point cloud)."""
    if not len(faces):
        return None, None
    if parts is None:
        parts = mesh_parts(vertices, faces)
    solid_part = {"auto": parts.closed, "solid": np.ones(parts.n_parts, bool),
                  "surface": np.zeros(parts.n_parts, bool)}[fill]
    return parts, solid_part


def _inward(vertices, parts, solid_part, surf: Samples, pitch: float) -> tuple[np.ndarray, np.ndarray]:
    """Where the samples (n, 3) and vertices (v, 3) are located in the grid: nudged by
    :data:`INWARD_NUDGE` cubes into the solid for the faces of watertight solid parts (outward
    oriented by :func:`~sc_fem.geometry.inside.mesh_parts`), unchanged elsewhere."""
    pts, verts = surf.points, vertices
    if parts is None:
        return pts, verts
    tight = (solid_part & parts.watertight)[parts.label]
    if not tight.any():
        return pts, verts
    tri = vertices[parts.faces[tight]]
    normal = np.zeros((len(parts.faces), 3))
    normal[tight] = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])       # area-weighted
    unit = normal / np.maximum(row_norms(normal), 1e-300)[:, None]
    step = INWARD_NUDGE * pitch
    pts = unit[surf.face]                   # in place: surf.points - step * unit[surf.face], the same numbers
    pts *= -step
    pts += surf.points
    vn = np.zeros_like(vertices)
    np.add.at(vn, parts.faces[tight].ravel(), np.repeat(normal[tight], 3, axis=0))
    verts = vertices - step * vn / np.maximum(row_norms(vn), 1e-300)[:, None]
    return pts, verts


def _occupied_cells(surf: Samples, vertices, faces, grid, occupancy: str, own_vertices=None,
                    located=None) -> tuple[np.ndarray, dict]:
    """Cubes touched by the surface samples, the mesh vertices and (``"exact"``) the triangles:
    a boolean grid of shape ``dims``, and the counts recorded in ``info``. ``located``: the
    positions (samples, vertices) to locate instead (:func:`_inward`)."""
    origin, pitch, dims = grid
    pts, verts = (surf.points, vertices) if located is None else located
    occupied = np.zeros(tuple(int(d) for d in dims), dtype=bool)
    mark_cells(occupied, pts, origin, pitch)
    vertex_cells = voxel_index(verts if own_vertices is None else verts[own_vertices], origin, pitch, dims)
    n_vertex_only = int((~occupied[tuple(vertex_cells.T)]).sum())
    occupied[tuple(vertex_cells.T)] = True      # every vertex's cube is in the model
    n_exact_only = 0
    if occupancy == "exact":
        xcells, _ = overlapping_cells(vertices, faces, origin, pitch, dims)
        new = ~occupied[tuple(xcells.T)]
        n_exact_only = int(new.sum())
        occupied[tuple(xcells[new].T)] = True
    return occupied, {"surface_cubes": int(occupied.sum()), "exact_only_cubes": n_exact_only,
                      "vertex_only_cubes": n_vertex_only}


def _mass_samples(occupied: np.ndarray, surf: Samples, vertices, faces, grid, opts: VoxelOptions,
                  thick: float, solids=None) -> tuple[Samples, dict, bool, int]:
    """The samples that carry mass: solid interiors, shells of ``thick``, and a small floor mass
    for cubes the surface touches but no sample reached. Marks solid cubes in ``occupied``.

    ``solids``: the ``(parts, solid_part)`` of :func:`_solid_parts`, when already known.
    Returns the samples (with their 27 moments), the parts record, whether any shell was made
    and the number of floor cubes."""
    origin, pitch, dims = grid
    n_sub = opts.subsamples
    parts_info: dict[str, Any] = {}
    solid: list[Samples] = []
    solid_cells = np.zeros((0, 3), np.int64)
    shell_face = np.ones(len(surf), dtype=bool)           # a point cloud is all shell
    if len(faces):
        parts, solid_part = _solid_parts(vertices, faces, opts.fill) if solids is None else solids
        solid_faces = solid_part[parts.label]
        shell_face = ~solid_faces[surf.face]
        parts_info = {"parts": parts.n_parts, "solid_parts": int(solid_part.sum()),
                      "shell_parts": int((~solid_part).sum())}
        if solid_faces.any():
            solid, solid_cells = solid_fill(occupied, vertices, parts, solid_part, surf, origin, pitch, n_sub)
            occupied[tuple(solid_cells.T)] = True
            if opts.fill == "solid" and not any(len(p) for p in solid):
                raise InputError("fill='solid' but the surface encloses no volume at this resolution; "
                                 "use fill='auto' or 'surface' (open sheets become shells)")
    shell = Samples(surf.points[shell_face], surf.weight[shell_face] * thick, surf.face[shell_face])

    filled = np.zeros(occupied.shape, dtype=bool)
    filled[tuple(solid_cells.T)] = True
    mark_cells(filled, shell.points, origin, pitch)
    empty = np.argwhere(occupied & ~filled)
    floor = Samples(origin + pitch * (empty + 0.5), np.full(len(empty), 0.5 * pitch**3 / n_sub**3),
                    np.full(len(empty), -1, dtype=np.int64))
    samples = Samples.concat(solid + [shell, floor])     # shells and floors: spread evenly over the cube
    return samples, parts_info, bool(shell_face.any()), int(len(empty))


def _sample_material(samples: Samples, surf: Samples, n_faces: int, youngs, poisson, density,
                     opts: VoxelOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """E (Pa), nu, rho (kg/m^3) and mass (kg) of every sample, each shape (n,). Volume samples
    take the face of the nearest surface sample for per-face materials."""
    face_for = None
    if n_faces:
        face_for = samples.face.copy()
        need = face_for < 0
        if need.any() and (np.ndim(youngs) == 1 or np.ndim(poisson) == 1 or np.ndim(density) == 1):
            _, nearest = cKDTree(surf.points).query(samples.points[need])
            face_for[need] = surf.face[nearest]
    E = resolve_field(youngs, "youngs", samples.points, face_for, n_faces)
    nu = resolve_field(poisson, "poisson", samples.points, face_for, n_faces)
    rho = resolve_field(density, "density", samples.points, face_for, n_faces)
    check_material(E, nu, rho, where="sample values")
    m = rho * samples.weight * opts.scale**3
    if opts.mass is not None:
        m = m * (opts.mass / m.sum())
    return E, nu, rho, m
