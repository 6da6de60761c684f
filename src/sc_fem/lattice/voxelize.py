"""Build the Squashing Cubes model of a geometric model: :func:`voxelize`.

Sample the model's surface with many small point samples and hash them to the voxels of a grid
fitted to the bounding box: every voxel the surface (or a mesh vertex) occupies is an elastic
cube. Mass comes from the geometry: parts that enclose volume are solids (the winding-number
inside test of :mod:`sc_fem.geometry.inside` fills the interior and measures the filled part of
each boundary cube), open parts are shells of a physical thickness. Each cube's E, nu and rho are
the mass-weighted averages of its samples' (the seed's rule for mixed materials). The options are
one :class:`~sc_fem.lattice.options.VoxelOptions`.
"""

from __future__ import annotations

import os
import warnings
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from .._validate import check_material, positive_int, positive_scalar
from ..errors import InputError, MaterialError, ResolutionError, ScFemWarning
from .fill import solid_fill
from .moments import FULL
from .cubes import CubeModel, voxel_index
from .options import DEFAULT_SUBSAMPLES, FILLS, STIFFNESS, VoxelOptions  # noqa: F401 (re-exported)
from ..fem.material import Material, resolve_field
from ..geometry.mesh import load_mesh
from ..geometry.overlap import overlapping_cells
from ..geometry.sampling import Samples, grid_counts, surface_grid_samples, surface_random_samples

DEFAULT_MATERIAL = Material(1.0e7, 0.30, 1000.0, "generic soft solid")
"""Material used for files that do not come with one: E = 10 MPa, nu = 0.3, rho = 1000 kg/m^3."""

DEFAULT_RESOLUTION = 32
SPACING_FRACTION = 0.125   # default sample spacing = pitch / 8
_BYTES_PER_GRID_CELL = 6   # bool occupancy + int32 labels
_BYTES_PER_SAMPLE = 160    # positions, weights, faces, temporaries
_MAX_RESOLUTION = 100_000
SNAP_CELLS = 0.01          # largest round-off (in cubes) absorbed by grid_for
DEFAULT_SHELL_FRACTION = 0.01   # default shell thickness: 1 % of the longest extent
PLAUSIBLE_SIZE = (1e-3, 1e3)   # metres: outside, voxelize warns that the scale may be wrong


def available_memory() -> int:
    """Bytes of memory available to this process (MemAvailable, else 4 GiB)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 4 << 30


def grid_for(bounds: np.ndarray, *, resolution: int | None = None, pitch: float | None = None):
    """Grid fitted to ``bounds`` (2, 3): returns ``(origin (3,), pitch, dims (3,) int)``.

    ``resolution`` cubes along the longest axis, or the given ``pitch`` (model units). A box
    whose extents are whole multiples of the pitch gets exactly that many cubes, also when its
    coordinates went through single precision (STL): extents within ``8 * eps_float32 * |x|``
    (at most :data:`SNAP_CELLS` cubes) of a whole multiple count as that multiple.
    """
    lo, hi = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    extent = hi - lo
    if resolution is not None and pitch is not None:
        raise InputError("give resolution or pitch, not both")
    if pitch is None:
        res = positive_int(DEFAULT_RESOLUTION if resolution is None else resolution, "resolution")
        if res > _MAX_RESOLUTION:
            raise ResolutionError(f"resolution {res} is beyond any machine's memory (max {_MAX_RESOLUTION})")
        pitch = float(extent.max()) / res
    else:
        pitch = positive_scalar(pitch, "pitch")
    ratio = extent / pitch
    # round-off of single-precision files (STL) must not add a layer: extents within a few float32
    # ulps of the coordinates' magnitude of a whole multiple of the pitch count as that multiple
    mag = np.maximum(np.abs(lo), np.abs(hi))
    tol = np.clip(8.0 * np.finfo(np.float32).eps * mag / pitch, 1e-9 * np.maximum(1.0, ratio), SNAP_CELLS)
    dims = np.maximum(1, np.ceil(ratio - tol)).astype(np.int64)
    if np.any(dims > _MAX_RESOLUTION):
        raise ResolutionError(f"pitch {pitch:g} gives a grid of {tuple(dims)} cubes: too fine "
                              f"(at most {_MAX_RESOLUTION} along an axis)")
    return lo, float(pitch), dims


def _estimate_bytes(vertices, faces, bounds, res) -> int:
    origin, pitch, dims = grid_for(bounds, resolution=res)
    n = len(vertices)
    if len(faces):
        k_s, k_t = grid_counts(vertices, faces, pitch * SPACING_FRACTION)
        n = int((k_s * k_t).sum())
    return int(np.prod(dims.astype(float)) * _BYTES_PER_GRID_CELL + n * _BYTES_PER_SAMPLE)


def _memory_guard(vertices, faces, bounds, dims, n_samples, budget, resolution) -> None:
    need = float(np.prod(dims.astype(float))) * _BYTES_PER_GRID_CELL + n_samples * _BYTES_PER_SAMPLE
    if need <= budget:
        return
    longest = int(dims.max())
    lo, hi = 1, longest
    while lo < hi:                      # bisection on resolution (a handful of cheap estimates)
        mid = (lo + hi + 1) // 2
        if _estimate_bytes(vertices, faces, bounds, mid) <= budget:
            lo = mid
        else:
            hi = mid - 1
    raise ResolutionError(
        f"a grid of {tuple(int(d) for d in dims)} cubes with {n_samples:,} samples needs about "
        f"{need / 2**30:.1f} GiB, more than the {budget / 2**30:.1f} GiB allowed; "
        f"try resolution <= {lo} (currently {resolution or longest})")


def hash_samples(points: np.ndarray, masses: np.ndarray, values: dict[str, np.ndarray], origin: np.ndarray,
                 pitch: float, dims: np.ndarray, sums: dict[str, np.ndarray] | None = None,
                 piece: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Hash samples to voxels; sum their masses and mass-average their values per voxel.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Sample positions, model units. A sample on an upper grid face belongs to the last cell.
    masses : ndarray, shape (n,)
        Sample masses, kg.
    values : dict of name -> ndarray (n,)
        Per-sample properties to average (E, nu, rho, ...).
    origin, pitch, dims
        The grid (see :func:`grid_for`).
    sums : dict of name -> ndarray (n,), optional
        Per-sample quantities to sum (not average) per voxel; returned in ``averages`` too.
    piece : ndarray of int, shape (n,), optional
        Body of each sample: samples of different bodies in one voxel make separate cubes
        (returned as ``averages["piece"]``, int).

    Returns
    -------
    cells : ndarray of int, shape (k, 3)
        Occupied voxels, sorted by linear index.
    mass : ndarray, shape (k,)
        Sum of sample masses per voxel.
    averages : dict of name -> ndarray (k,)
        Mass-weighted average of each value per voxel.
    """
    lin = np.ravel_multi_index(voxel_index(points, origin, pitch, dims).T, dims)
    n_p = 1 if piece is None or not len(piece) else int(piece.max()) + 1
    if n_p > 1:
        lin = lin * n_p + piece
    uniq, inv = np.unique(lin, return_inverse=True)
    cube_mass = np.bincount(inv, weights=masses, minlength=len(uniq))
    if np.any(cube_mass <= 0):
        raise MaterialError("a cube received zero mass; check density/mass values")
    averages = {k: np.bincount(inv, weights=masses * v, minlength=len(uniq)) / cube_mass for k, v in values.items()}
    averages.update({k: np.bincount(inv, weights=v, minlength=len(uniq)) for k, v in (sums or {}).items()})
    cells = np.stack(np.unravel_index(uniq // n_p, dims), axis=1).astype(np.int64)
    if piece is not None:
        averages["piece"] = (uniq % n_p).astype(np.int64)
    return cells, cube_mass, averages


def _material_defaults(mesh, youngs, poisson, density) -> tuple[Any, Any, Any, str]:
    src = str(mesh.metadata.get("source", ""))
    base = DEFAULT_MATERIAL
    if src.startswith("builtin:"):
        from ..geometry import models

        base = models.material(src)
    return (base.youngs if youngs is None else youngs, base.poisson if poisson is None else poisson,
            base.density if density is None else density, base.name)


def _point_spacing(points: np.ndarray) -> float:
    """Typical spacing of a point cloud: the median nearest-neighbour distance (model units)."""
    if len(points) < 2:
        return float(np.ptp(points, axis=0).max() or 1.0)
    d, _ = cKDTree(points).query(points, k=2)
    positive = d[:, 1][d[:, 1] > 0]
    return float(np.median(positive)) if len(positive) else float(np.ptp(points, axis=0).max())


def _point_cloud_pitch(points: np.ndarray, bounds: np.ndarray) -> float:
    """Default pitch of a point cloud: 32 cubes along the longest axis, but never finer than 1.5x
    the 90th percentile of the nearest-neighbour distance (finer grids fall apart into single cubes)."""
    d, _ = cKDTree(points).query(points, k=2)
    gap = float(np.percentile(d[:, 1], 90)) if len(points) > 1 else 0.0
    return max(float((bounds[1] - bounds[0]).max()) / DEFAULT_RESOLUTION, 1.5 * gap)


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
        from ..geometry.inside import mesh_parts

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
    unit = normal / np.maximum(np.linalg.norm(normal, axis=1), 1e-300)[:, None]
    step = INWARD_NUDGE * pitch
    pts = surf.points - step * unit[surf.face]
    vn = np.zeros_like(vertices)
    np.add.at(vn, parts.faces[tight].ravel(), np.repeat(normal[tight], 3, axis=0))
    verts = vertices - step * vn / np.maximum(np.linalg.norm(vn, axis=1), 1e-300)[:, None]
    return pts, verts


def _occupied_cells(surf: Samples, vertices, faces, grid, occupancy: str, own_vertices=None,
                    located=None) -> tuple[np.ndarray, dict]:
    """Cubes touched by the surface samples, the mesh vertices and (``"exact"``) the triangles:
    a boolean grid of shape ``dims``, and the counts recorded in ``info``. ``located``: the
    positions (samples, vertices) to locate instead (:func:`_inward`)."""
    origin, pitch, dims = grid
    pts, verts = (surf.points, vertices) if located is None else located
    occupied = np.zeros(tuple(int(d) for d in dims), dtype=bool)
    occupied[tuple(voxel_index(pts, origin, pitch, dims).T)] = True
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
    solid = Samples(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64))
    shell_face = np.ones(len(surf), dtype=bool)           # a point cloud is all shell
    if len(faces):
        parts, solid_part = _solid_parts(vertices, faces, opts.fill) if solids is None else solids
        solid_faces = solid_part[parts.label]
        shell_face = ~solid_faces[surf.face]
        parts_info = {"parts": parts.n_parts, "solid_parts": int(solid_part.sum()),
                      "shell_parts": int((~solid_part).sum())}
        if solid_faces.any():
            solid = solid_fill(occupied, vertices, parts, solid_part, surf, origin, pitch, n_sub)
            occupied[tuple(voxel_index(solid.points, origin, pitch, dims).T)] = True
            if opts.fill == "solid" and len(solid) == 0:
                raise InputError("fill='solid' but the surface encloses no volume at this resolution; "
                                 "use fill='auto' or 'surface' (open sheets become shells)")
    shell = Samples(surf.points[shell_face], surf.weight[shell_face] * thick, surf.face[shell_face])

    filled = np.zeros(occupied.shape, dtype=bool)
    for pts in (solid.points, shell.points):
        filled[tuple(voxel_index(pts, origin, pitch, dims).T)] = True
    empty = np.argwhere(occupied & ~filled)
    floor = Samples(origin + pitch * (empty + 0.5), np.full(len(empty), 0.5 * pitch**3 / n_sub**3),
                    np.full(len(empty), -1, dtype=np.int64))
    smeared = np.r_[shell.weight, floor.weight][:, None] * FULL / pitch**3   # shells: spread over the cube
    samples = Samples(np.vstack([solid.points, shell.points, floor.points]),
                      np.r_[solid.weight, shell.weight, floor.weight],
                      np.r_[solid.face, shell.face, floor.face].astype(np.int64),
                      np.vstack([solid.moments if solid.moments is not None else np.zeros((0, 27)), smeared]))
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


def _full_within_roundoff(moments: np.ndarray, origin, pitch: float, dims) -> np.ndarray:
    """Cubes (mask, shape (n,)) whose 27 moments differ from a full cube's only by round-off.

    The grid-cut integrals are evaluated from coordinates up to ``|origin| / pitch + dims`` cells
    from the grid's zero, so their round-off grows with that extent (measured on a 4 x 1 x 1 box at
    40 cubes per metre: 1.3e-11); without this, a third of the cubes of a million-cube solid box
    counted as partly filled and took the slow per-cube integration path."""
    extent = 1.0 + float(np.max(np.abs(origin))) / pitch + float(np.max(dims))
    return np.abs(moments - FULL).max(axis=1) <= 1e3 * np.finfo(float).eps * extent


LOOSE_FRACTION = 0.01
"""``keep="bodies"``: bodies lighter than this fraction of the heaviest are loose (not kept)."""


def _find_bodies(vertices, faces, opts: VoxelOptions, longest: float, cloud: bool):
    """The bodies of ``topology="pieces"`` (None for ``"grid"`` and point clouds), the body of
    every face, shape (m,), and the mesh's parts (None when not needed), found once."""
    if cloud or opts.topology == "grid":
        return None, np.zeros(len(faces), np.int64), None
    from ..geometry.bodies import DEFAULT_WELD_FRACTION, find_bodies
    from ..geometry.inside import mesh_parts

    parts = mesh_parts(vertices, faces)
    weld = DEFAULT_WELD_FRACTION * longest if opts.weld is None else opts.weld
    bodies = find_bodies(vertices, parts, weld)
    return bodies, bodies.of_part[parts.label], parts


def _batches(vertices, faces, face_body, n_bodies: int, grid) -> tuple[list[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """Bodies in batches whose cell boxes do not overlap, so one voxelization pass per batch can
    tell every cube's body by where it lies (greedy, over bodies). Returns the batches (arrays of
    body indices) and every body's lowest and highest cell, each (n_bodies, 3)."""
    origin, pitch, dims = grid
    lo = np.full((n_bodies, 3), np.inf)
    hi = np.full((n_bodies, 3), -np.inf)
    fb = np.repeat(face_body, 3)
    np.minimum.at(lo, fb, vertices[faces.ravel()])
    np.maximum.at(hi, fb, vertices[faces.ravel()])
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
        out.append(Samples(smp.points, smp.weight, np.where(smp.face >= 0, fsel[np.maximum(smp.face, 0)], -1),
                           smp.moments))
        body.append(sb)
        shells |= sh
        for key, v in {**c, **pinfo}.items():
            counts[key] = counts.get(key, 0) + v
    parts_info = {key: counts.pop(key) for key in ("parts", "solid_parts", "shell_parts") if key in counts}
    samples = Samples(np.vstack([q.points for q in out]), np.concatenate([q.weight for q in out]),
                      np.concatenate([q.face for q in out]), np.vstack([q.moments for q in out]))
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


def voxelize(mesh: Any, options: VoxelOptions | None = None, **fields: Any) -> CubeModel:
    """Voxelize a model into elastic cubes (the Squashing Cubes model).

    Parameters
    ----------
    mesh : mesh-like
        Anything :func:`sc_fem.load_mesh` accepts (path, ``"builtin:NAME"``, trimesh, arrays,
        point cloud).
    options : VoxelOptions or dict, optional
        Grid, units, material and fill options (:class:`~sc_fem.lattice.options.VoxelOptions`,
        which documents each one); default ``VoxelOptions()``.
    **fields
        Any field of :class:`~sc_fem.lattice.options.VoxelOptions` (``resolution``, ``scale``,
        ``youngs``, ``fill``, ...), overriding ``options``.

    Returns
    -------
    CubeModel
        ``fraction`` holds each cube's filled volume fraction; ``piece`` each cube's body;
        ``info`` records occupancy, fill, parts that became solids and shells, samples, the
        bodies (``topology``, ``weld``, ``bodies``, ``welds_by_distance``,
        ``welds_by_containment``, ``loose_bodies``), components before ``keep``, dropped cubes.

    Notes
    -----
    Every cube the surface enters deeper than ``spacing`` holds a sample, and every cube that
    holds a mesh vertex is occupied, so the trilinear embedding of every vertex lies in its own
    cube. Cubes the surface only grazes get the small mass of ``1 / (2 subsamples^3)`` of a cube.
    """
    opts = VoxelOptions.coerce(options, **fields)
    mesh = load_mesh(mesh)
    vertices = np.asarray(mesh.vertices, dtype=float)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    cloud = len(faces) == 0
    if opts.occupancy == "exact" and cloud:
        raise InputError("occupancy='exact' needs faces; a point cloud can only be sampled")
    youngs, poisson, density, mat_name = _material_defaults(mesh, opts.youngs, opts.poisson, opts.density)
    connectivity = opts.connectivity or ("vertex" if cloud else "face")

    bounds = np.array([vertices.min(axis=0), vertices.max(axis=0)])
    longest = float((bounds[1] - bounds[0]).max())
    pitch = opts.pitch
    if cloud and opts.resolution is None and pitch is None:
        pitch = _point_cloud_pitch(vertices, bounds)
    origin, pitch, dims = grid_for(bounds, resolution=opts.resolution, pitch=pitch)
    grid = (origin, pitch, dims)
    spacing = pitch * SPACING_FRACTION if opts.spacing is None else opts.spacing
    thick = DEFAULT_SHELL_FRACTION * longest if opts.shell_thickness is None else opts.shell_thickness
    budget = 0.5 * available_memory() if opts.max_memory is None else opts.max_memory

    # ---- surface samples (the memory guard runs before anything grid-sized is allocated)
    if cloud:
        est = len(vertices)
    elif opts.n_samples is not None:
        est = opts.n_samples
    else:
        k_s, k_t = grid_counts(vertices, faces, spacing)
        est = int((k_s * k_t).sum())
    # boundary cubes (about 1.5 area / pitch^2 = est / 40) get n_sub^3 inside-test samples each
    _memory_guard(vertices, faces, bounds, dims, est + est * opts.subsamples**3 // 32, budget, opts.resolution)
    if cloud:       # each point stands for the area of a square of the typical point spacing
        surf = Samples(points=vertices, weight=np.full(len(vertices), _point_spacing(vertices) ** 2),
                       face=np.full(len(vertices), -1))
    elif opts.n_samples is not None:
        surf = surface_random_samples(vertices, faces, est, np.random.default_rng(opts.seed))
    else:
        surf = surface_grid_samples(vertices, faces, spacing)

    bodies, face_body, parts = _find_bodies(vertices, faces, opts, longest, cloud)
    samples, sample_body, parts_info, shells, counts = _body_samples(surf, vertices, faces, grid, opts, thick,
                                                                    face_body, bodies, parts)
    E, nu, rho, m = _sample_material(samples, surf, len(faces), youngs, poisson, density, opts)

    # ---- hash samples to voxels and accumulate (vectorized: unique + bincount); one cube per body and voxel
    cells, cube_mass, avg = hash_samples(samples.points, m, {"E": E, "nu": nu, "rho": rho}, origin, pitch, dims,
                                         sums={"volume": samples.weight,
                                               **{f"m{k}": samples.moments[:, k] for k in range(27)}},
                                         piece=sample_body)
    volume = avg["volume"]                             # filled volume per cube, model units^3
    moments = np.stack([avg[f"m{k}"] for k in range(27)], axis=1)
    fraction = np.clip(volume / pitch**3, 0.0, 1.0)
    full = _full_within_roundoff(moments, origin, pitch, dims)
    moments[full], fraction[full] = FULL, 1.0
    cube_rho = cube_mass / (volume * opts.scale**3) if opts.mass is not None else avg["rho"]

    info = {"occupancy": opts.occupancy, "fill": opts.fill, "stiffness": opts.stiffness,
            "n_samples": int(len(surf)), "mass_samples": int(len(samples)),
            "sampler": "random" if opts.n_samples is not None else ("points" if cloud else "grid"),
            "spacing": spacing, "shell_thickness": thick if shells else 0.0, **counts,
            "filled_volume": float(volume.sum() * opts.scale**3),
            "material": mat_name, "source": mesh.metadata.get("source", ""),
            "sha256": mesh.metadata.get("sha256", ""), "resolution": int(dims.max()), **parts_info}
    sites = site_piece = None
    if bodies is not None:
        info.update(topology=opts.topology, weld=bodies.weld, bodies=bodies.n_bodies,
                    welds_by_distance=bodies.joined_by_distance, welds_by_containment=bodies.joined_by_containment)
        if bodies.n_bodies > 1:      # where a point lies: the body of the nearest vertex or face centre
            used = np.unique(faces)
            vb = np.zeros(len(vertices), np.int64)
            vb[faces.ravel()] = np.repeat(face_body, 3)
            sites = np.vstack([vertices[used], vertices[faces].mean(axis=1)])
            site_piece = np.r_[vb[used], face_body]
    else:
        info.update(topology="grid" if not cloud else "points", bodies=1)
    model = CubeModel.from_cells(cells, origin=origin, pitch=pitch, scale=opts.scale, dims=dims, mass=cube_mass,
                                 youngs=avg["E"], poisson=avg["nu"], density=cube_rho, fraction=fraction,
                                 stiffness=opts.stiffness, moments=moments,
                                 connectivity=connectivity, info=info, piece=avg["piece"],
                                 sites=sites, site_piece=site_piece)
    size_m = longest * opts.scale
    if not PLAUSIBLE_SIZE[0] <= size_m <= PLAUSIBLE_SIZE[1]:
        warnings.warn(f"the model is {size_m:.4g} m long (scale={opts.scale:g} metres per model unit): is that "
                      f"meant? A model in millimetres needs scale=0.001 (--scale 0.001)", ScFemWarning, stacklevel=2)
    return _keep(model, opts.keep, info)
