"""Build the Squashing Cubes model of a geometric model: :func:`voxelize`.

Sample the model's surface with many small point samples and hash them to the voxels of a grid
fitted to the bounding box: every voxel the surface (or a mesh vertex) occupies is an elastic
cube. Mass comes from the geometry: parts that enclose volume are solids (the winding-number
inside test of :mod:`sc_fem.geometry.inside` fills the interior and measures the filled fraction of each
boundary cube), open parts are shells of a physical thickness. Each cube's E, nu and rho are the
mass-weighted averages of its samples' (the seed's rule for mixed materials) and, by default, its
stiffness is scaled by its filled volume fraction. Optionally keep only the largest connected
component.
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
from .cubes import CONNECTIVITY, CubeModel, voxel_index
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
DEFAULT_SUBSAMPLES = 4     # n: n^3 inside-test samples per boundary cube
FILLS = ("auto", "solid", "surface")
PLAUSIBLE_SIZE = (1e-3, 1e3)   # metres: outside, voxelize warns that the scale may be wrong
STIFFNESS = ("moments", "fraction", "full")


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
                 pitch: float, dims: np.ndarray,
                 sums: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
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
    uniq, inv = np.unique(lin, return_inverse=True)
    cube_mass = np.bincount(inv, weights=masses, minlength=len(uniq))
    if np.any(cube_mass <= 0):
        raise MaterialError("a cube received zero mass; check density/mass values")
    averages = {k: np.bincount(inv, weights=masses * v, minlength=len(uniq)) / cube_mass for k, v in values.items()}
    averages.update({k: np.bincount(inv, weights=v, minlength=len(uniq)) for k, v in (sums or {}).items()})
    cells = np.stack(np.unravel_index(uniq, dims), axis=1).astype(np.int64)
    return cells, cube_mass, averages


def _material_defaults(mesh, youngs, poisson, density) -> tuple[Any, Any, Any, str]:
    src = str(mesh.metadata.get("source", ""))
    base = DEFAULT_MATERIAL
    if src.startswith("builtin:"):
        from ..geometry import models

        base = models.material(src)
    return (base.youngs if youngs is None else youngs, base.poisson if poisson is None else poisson,
            base.density if density is None else density, base.name)


def _check_options(fill, occupancy, keep, connectivity, stiffness, n_faces) -> None:
    for name, value, allowed in (("fill", fill, FILLS), ("occupancy", occupancy, ("sample", "exact")),
                                 ("keep", keep, ("largest", "all")), ("stiffness", stiffness, STIFFNESS)):
        if value not in allowed:
            raise InputError(f"{name} must be one of {', '.join(repr(a) for a in allowed)}, got {value!r}")
    if connectivity is not None and connectivity not in CONNECTIVITY:
        raise InputError(f"connectivity must be one of {sorted(CONNECTIVITY)}, got {connectivity!r}")
    if occupancy == "exact" and n_faces == 0:
        raise InputError("occupancy='exact' needs faces; a point cloud can only be sampled")


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


def voxelize(mesh: Any, *, resolution: int | None = None, pitch: float | None = None, scale: float = 1.0,
             youngs: Any = None, poisson: Any = None, density: Any = None, mass: float | None = None,
             fill: str = "auto", occupancy: str = "sample", keep: str = "largest",
             connectivity: str | None = None, n_samples: int | None = None, spacing: float | None = None,
             shell_thickness: float | None = None, stiffness: str = "moments",
             subsamples: int = DEFAULT_SUBSAMPLES, seed: int = 0, max_memory: float | None = None,
             method: str | None = None) -> CubeModel:
    """Voxelize a model into elastic cubes (the Squashing Cubes model).

    Parameters
    ----------
    mesh : mesh-like
        Anything :func:`sc_fem.load_mesh` accepts (path, ``"builtin:NAME"``, trimesh, arrays,
        point cloud).
    resolution : int, optional
        Cubes along the longest bounding-box axis (default 32). Exclusive with ``pitch``.
    pitch : float, optional
        Cube edge in model units.
    scale : float
        Metres per model unit (a model in millimetres: ``scale=0.001``).
    youngs, poisson, density : float, array_like (n_faces,) or callable, optional
        Young's modulus (Pa), Poisson's ratio, density (kg/m^3): a scalar, one value per source
        face, or ``f(points (n, 3) model units) -> (n,)``. Defaults: the built-in model's material,
        else :data:`DEFAULT_MATERIAL`.
    mass : float, optional
        Total mass in kg; rescales the mass implied by ``density`` and the geometry.
    fill : {"auto", "solid", "surface"}
        How the mass is found from the geometry. Parts are sets of faces connected through
        shared vertices; a part *encloses volume* when the generalized winding number just inside
        and outside its faces sums to about 1 (:mod:`sc_fem.geometry.inside`; works on broken meshes).
        ``"auto"`` (default): parts that enclose volume are solids, the others shells.
        ``"solid"``: every part is a solid (inside = winding number > 1/2).
        ``"surface"``: every part is a shell of ``shell_thickness``.
        A solid's mass is ``rho`` times the volume inside each cube (boundary cubes by
        ``subsamples^3`` inside tests); a shell's is ``rho * area * shell_thickness``.
    occupancy : {"sample", "exact"}
        Which cubes the surface occupies: ``"sample"``, the paper's point sampling; ``"exact"``,
        conservative triangle-box overlap, so no touched voxel is ever lost.
    keep : {"largest", "all"}
        Keep only the largest connected component, or everything. Dropping more than half the
        cubes warns (:class:`sc_fem.errors.ScFemWarning`).
    connectivity : {"face", "edge", "vertex"}, optional
        Which cubes count as connected. Default ``"face"`` (cubes that touch only along an edge
        or a corner share 1--2 nodes and would act as free hinges), ``"vertex"`` for point clouds.
    n_samples : int, optional
        Use N random area-weighted samples (the paper's scheme) instead of the stratified grid.
    spacing : float, optional
        Stratified-grid sample spacing in model units (default ``pitch / 8``).
    shell_thickness : float, optional
        Physical thickness of shell parts, model units. Default: 1 % of the longest bounding-box
        extent (independent of the resolution).
    stiffness : {"fraction", "full"}
        ``"fraction"`` (default): a cube's Young's modulus is its material's times its filled volume
        fraction (partly filled boundary cubes and shells are softer, as they are lighter).
        ``"full"``: every cube at the full material stiffness (the original Squashing Cubes).
    subsamples : int
        Inside tests per boundary-cube edge (``subsamples^3`` per cube; default 4).
    seed : int
        Random seed (only ``n_samples`` sampling is random).
    max_memory : float, optional
        Bytes the grid and samples may use; default half the available memory. A grid that
        would not fit is refused before allocation with a suggested resolution.
    method : str, optional
        Deprecated name of ``occupancy`` (warns).

    Returns
    -------
    CubeModel
        ``fraction`` holds each cube's filled volume fraction; ``info`` records occupancy, fill,
        parts that became solids and shells, samples, components before ``keep``, dropped cubes.

    Notes
    -----
    Every cube the surface enters deeper than ``spacing`` holds a sample, and every cube that
    holds a mesh vertex is occupied, so the trilinear embedding of every vertex lies in its own
    cube. Cubes the surface only grazes get the small mass of ``1 / (2 subsamples^3)`` of a cube.
    """
    mesh = load_mesh(mesh)
    vertices = np.asarray(mesh.vertices, dtype=float)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    scale = positive_scalar(scale, "scale")
    if method is not None:                                   # the old name of occupancy
        warnings.warn("voxelize(method=...) is now occupancy=...", DeprecationWarning, stacklevel=2)
        if occupancy not in ("sample", method):
            raise InputError(f"method={method!r} (the old name of occupancy) contradicts occupancy={occupancy!r}")
        occupancy = method
    _check_options(fill, occupancy, keep, connectivity, stiffness, len(faces))
    n_sub = positive_int(subsamples, "subsamples")
    youngs, poisson, density, mat_name = _material_defaults(mesh, youngs, poisson, density)
    if mass is not None:
        mass = positive_scalar(mass, "mass")
    cloud = len(faces) == 0
    if connectivity is None:
        connectivity = "vertex" if cloud else "face"

    bounds = np.array([vertices.min(axis=0), vertices.max(axis=0)])
    longest = float((bounds[1] - bounds[0]).max())
    if cloud and resolution is None and pitch is None:
        pitch = _point_cloud_pitch(vertices, bounds)
    origin, pitch, dims = grid_for(bounds, resolution=resolution, pitch=pitch)
    spacing = pitch * SPACING_FRACTION if spacing is None else positive_scalar(spacing, "spacing")
    thick = DEFAULT_SHELL_FRACTION * longest if shell_thickness is None else \
        positive_scalar(shell_thickness, "shell_thickness")
    budget = 0.5 * available_memory() if max_memory is None else positive_scalar(max_memory, "max_memory")

    # ---- surface samples
    if cloud:
        est = len(vertices)
    elif n_samples is not None:
        est = positive_int(n_samples, "n_samples")
    else:
        k_s, k_t = grid_counts(vertices, faces, spacing)
        est = int((k_s * k_t).sum())
    # boundary cubes (about 1.5 area / pitch^2 = est / 40) get n_sub^3 inside-test samples each
    _memory_guard(vertices, faces, bounds, dims, est + est * n_sub**3 // 32, budget, resolution)

    if cloud:       # each point stands for the area of a square of the typical point spacing
        surf = Samples(points=vertices, weight=np.full(len(vertices), _point_spacing(vertices) ** 2),
                       face=np.full(len(vertices), -1))
    elif n_samples is not None:
        surf = surface_random_samples(vertices, faces, est, np.random.default_rng(seed))
    else:
        surf = surface_grid_samples(vertices, faces, spacing)

    shape = tuple(int(d) for d in dims)
    occupied = np.zeros(shape, dtype=bool)
    occupied[tuple(voxel_index(surf.points, origin, pitch, dims).T)] = True
    vertex_cells = voxel_index(vertices, origin, pitch, dims)
    n_vertex_only = int((~occupied[tuple(vertex_cells.T)]).sum())
    occupied[tuple(vertex_cells.T)] = True      # every vertex's cube is in the model
    n_exact_only = 0
    if occupancy == "exact":
        xcells, _ = overlapping_cells(vertices, faces, origin, pitch, dims)
        new = ~occupied[tuple(xcells.T)]
        n_exact_only = int(new.sum())
        occupied[tuple(xcells[new].T)] = True
    surface_cells = int(occupied.sum())

    # ---- which parts are solids, which shells
    parts_info: dict[str, Any] = {}
    solid_samples = Samples(np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.int64))
    shell_face = np.zeros(len(surf), dtype=bool) if not cloud else np.ones(len(surf), dtype=bool)
    if not cloud:
        from ..geometry.inside import mesh_parts

        parts = mesh_parts(vertices, faces)
        solid_part = {"auto": parts.closed, "solid": np.ones(parts.n_parts, bool),
                      "surface": np.zeros(parts.n_parts, bool)}[fill]
        solid_faces = solid_part[parts.label]
        shell_face = ~solid_faces[surf.face]
        parts_info = {"parts": parts.n_parts, "solid_parts": int(solid_part.sum()),
                      "shell_parts": int((~solid_part).sum())}
        if solid_faces.any():
            solid_samples = solid_fill(occupied, vertices, parts, solid_part, surf, origin, pitch, n_sub)
            occupied[tuple(voxel_index(solid_samples.points, origin, pitch, dims).T)] = True
            if fill == "solid" and len(solid_samples) == 0:
                raise InputError("fill='solid' but the surface encloses no volume at this resolution; "
                                 "use fill='auto' or 'surface' (open sheets become shells)")
    shell = Samples(surf.points[shell_face], surf.weight[shell_face] * thick, surf.face[shell_face])

    # ---- cubes the surface or a vertex touches but no mass sample reached: a small floor volume
    filled = np.zeros(shape, dtype=bool)
    for pts in (solid_samples.points, shell.points):
        filled[tuple(voxel_index(pts, origin, pitch, dims).T)] = True
    empty = np.argwhere(occupied & ~filled)
    floor = Samples(origin + pitch * (empty + 0.5), np.full(len(empty), 0.5 * pitch**3 / n_sub**3),
                    np.full(len(empty), -1, dtype=np.int64))
    smeared = np.r_[shell.weight, floor.weight][:, None] * FULL / pitch**3   # shells: spread over the cube
    samples = Samples(np.vstack([solid_samples.points, shell.points, floor.points]),
                      np.r_[solid_samples.weight, shell.weight, floor.weight],
                      np.r_[solid_samples.face, shell.face, floor.face].astype(np.int64),
                      np.vstack([solid_samples.moments if solid_samples.moments is not None
                                 else np.zeros((0, 27)), smeared]))

    # ---- per-sample material (volume samples take the face of the nearest surface sample)
    face_for = None
    if not cloud:
        face_for = samples.face.copy()
        need = face_for < 0
        if need.any() and (np.ndim(youngs) == 1 or np.ndim(poisson) == 1 or np.ndim(density) == 1):
            _, nearest = cKDTree(surf.points).query(samples.points[need])
            face_for[need] = surf.face[nearest]
    E = resolve_field(youngs, "youngs", samples.points, face_for, len(faces))
    nu = resolve_field(poisson, "poisson", samples.points, face_for, len(faces))
    rho = resolve_field(density, "density", samples.points, face_for, len(faces))
    check_material(E, nu, rho, where="sample values")
    m = rho * samples.weight * scale**3
    if mass is not None:
        m = m * (mass / m.sum())

    # ---- hash samples to voxels and accumulate (vectorized: unique + bincount)
    cells, cube_mass, avg = hash_samples(samples.points, m, {"E": E, "nu": nu, "rho": rho}, origin, pitch, dims,
                                         sums={"volume": samples.weight,
                                               **{f"m{k}": samples.moments[:, k] for k in range(27)}})
    volume = avg["volume"]                             # filled volume per cube, model units^3
    moments = np.stack([avg[f"m{k}"] for k in range(27)], axis=1)
    fraction = np.clip(volume / pitch**3, 0.0, 1.0)
    cube_rho = cube_mass / (volume * scale**3) if mass is not None else avg["rho"]

    info = {"occupancy": occupancy, "fill": fill, "stiffness": stiffness, "n_samples": int(len(surf)),
            "mass_samples": int(len(samples)),
            "sampler": "random" if n_samples is not None else ("points" if cloud else "grid"),
            "spacing": spacing, "shell_thickness": thick if bool(shell_face.any()) else 0.0,
            "surface_cubes": surface_cells, "exact_only_cubes": n_exact_only, "vertex_only_cubes": n_vertex_only,
            "floor_cubes": int(len(empty)), "filled_volume": float(volume.sum() * scale**3),
            "material": mat_name, "source": mesh.metadata.get("source", ""),
            "sha256": mesh.metadata.get("sha256", ""), "resolution": int(dims.max()), **parts_info}
    model = CubeModel.from_cells(cells, origin=origin, pitch=pitch, scale=scale, dims=dims, mass=cube_mass,
                                 youngs=avg["E"], poisson=avg["nu"], density=cube_rho, fraction=fraction,
                                 stiffness=stiffness, moments=moments,
                                 connectivity=connectivity, info=info)
    size_m = longest * scale
    if not PLAUSIBLE_SIZE[0] <= size_m <= PLAUSIBLE_SIZE[1]:
        warnings.warn(f"the model is {size_m:.4g} m long (scale={scale:g} metres per model unit): is that "
                      f"meant? A model in millimetres needs scale=0.001 (--scale 0.001)", ScFemWarning, stacklevel=2)
    n_comp = model.n_components
    info.update(components_found=n_comp, cubes_found=model.n_cubes)
    if keep == "largest" and n_comp > 1:
        kept = model.subset(model.component == 0)
        dropped = model.n_cubes - kept.n_cubes
        if dropped > kept.n_cubes:
            warnings.warn(
                f"keep='largest' kept {kept.n_cubes} of {model.n_cubes} cubes ({n_comp} components): "
                f"most of the model was dropped; use a coarser resolution, connectivity='vertex' or "
                f"keep='all'", ScFemWarning, stacklevel=2)
        return kept.with_info(**info, dropped_cubes=dropped)
    return model.with_info(**info, dropped_cubes=0)
