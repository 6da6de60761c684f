"""Build the Squashing Cubes model of a geometric model: :func:`voxelize`.

Sample the model's surface with many small point samples and hash them to the voxels of a grid
fitted to the bounding box: every voxel the surface (or a mesh vertex) occupies is an elastic
cube. Mass comes from the geometry: parts that enclose volume are solids (the winding-number
inside test of :mod:`sc_fem.geometry.inside` fills the interior and measures the filled part of
each boundary cube), open parts are shells of a physical thickness. Each cube's E, nu and rho are
the mass-weighted averages of its samples' (the seed's rule for mixed materials). The options are
one :class:`~sc_fem.lattice.options.VoxelOptions`.

Modules: :mod:`.grid` (the grid, the memory guard, hashing samples to voxels), :mod:`.mass` (the
samples that carry mass), :mod:`.pieces` (bodies and the components kept).
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from .._jit import blas_single_threaded
from .._memory import available_memory
from .._progress import stage_bar, step
from ..errors import InputError, ScFemWarning
from ..geometry import models
from ..geometry.mesh import load_mesh
from ..geometry.sampling import Samples, surface_grid, surface_random_samples
from ..material import Material
from .cubes import CubeModel
from .grid import SPACING_FRACTION, _memory_guard, _point_cloud_pitch, _point_spacing, grid_for, hash_samples
from .mass import _sample_material
from .moments import FULL, ROW_CHUNK, valid_moments
from .options import DEFAULT_RESOLUTION, DEFAULT_SUBSAMPLES, FILLS, STIFFNESS, VoxelOptions  # noqa: F401 (re-exported)
from .pieces import _body_samples, _find_bodies, _keep

DEFAULT_MATERIAL = Material(1.0e7, 0.30, 1000.0, "generic soft solid")
"""Material used for files that do not come with one: E = 10 MPa, nu = 0.3, rho = 1000 kg/m^3."""

DEFAULT_SHELL_FRACTION = 0.01   # default shell thickness: 1 % of the longest extent
PLAUSIBLE_SIZE = (1e-3, 1e3)   # metres: outside, voxelize warns that the scale may be wrong
STAGES = ("load", "sample", "bodies", "fill", "cubes")
"""The sub-stages of :func:`voxelize` that its progress bar counts: load the mesh, sample its
surface, find the bodies, fill the solids (the inside tests: the longest), hash samples to cubes."""


def _material_defaults(mesh, youngs, poisson, density) -> tuple[Any, Any, Any, str]:
    src = str(mesh.metadata.get("source", ""))
    base = DEFAULT_MATERIAL
    if src.startswith("builtin:"):
        base = models.material(src)
    return (base.youngs if youngs is None else youngs, base.poisson if poisson is None else poisson,
            base.density if density is None else density, base.name)


def _full_within_roundoff(moments: np.ndarray, origin, pitch: float, dims) -> np.ndarray:
    """Cubes (mask, shape (n,)) whose 27 moments differ from a full cube's only by round-off.

    The grid-cut integrals are evaluated from coordinates up to ``|origin| / pitch + dims`` cells
    from the grid's zero, so their round-off grows with that extent (measured on a 4 x 1 x 1 box at
    40 cubes per metre: 1.3e-11); without this, a third of the cubes of a million-cube solid box
    counted as partly filled and took the slow per-cube integration path."""
    extent = 1.0 + float(np.max(np.abs(origin))) / pitch + float(np.max(dims))
    tol = 1e3 * np.finfo(float).eps * extent
    full = np.abs(moments[:, 0] - FULL[0]) <= tol          # the volume first: most partial cubes fail there
    at = np.flatnonzero(full)
    for s in range(0, len(at), ROW_CHUNK):                 # row chunks: no (n, 27) temporaries
        rows = at[s:s + ROW_CHUNK]
        d = moments[rows]
        d -= FULL
        full[rows] = np.abs(d, out=d).max(axis=1) <= tol
    return full


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
    # the BLAS on one thread: its few small products would leave its threads spinning against the
    # compiled kernels' (~4 % of the bunny at 64 in one run)
    with blas_single_threaded(), stage_bar("voxelize", len(STAGES), unit="stage", tick=1.0, rate=False) as bar:
        step(bar, STAGES[0], 0)
        return _voxelize(mesh, opts, bar)


def _voxelize(mesh: Any, opts: VoxelOptions, bar: Any) -> CubeModel:
    """:func:`voxelize`, counting its :data:`STAGES` in ``bar``."""
    mesh = load_mesh(mesh)
    step(bar, STAGES[1])
    vertices = np.asarray(mesh.vertices, dtype=float)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    cloud = len(faces) == 0
    if opts.occupancy == "exact" and cloud:
        raise InputError("occupancy='exact' needs faces; a point cloud can only be sampled")
    youngs, poisson, density, mat_name = _material_defaults(mesh, opts.youngs, opts.poisson, opts.density)
    connectivity = opts.connectivity or ("vertex" if cloud else "face")

    bounds = np.array([vertices.min(axis=0), vertices.max(axis=0)])
    longest = float((bounds[1] - bounds[0]).max())
    pitch = opts.pitch            # else the resolution's (a point cloud's own without one)
    if pitch is None:
        pitch = (_point_cloud_pitch(vertices, bounds) if cloud and opts.resolution is None
                 else longest / (opts.resolution or DEFAULT_RESOLUTION))
    origin, pitch, dims = grid_for(bounds, pitch=pitch)
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
        sample_grid = surface_grid(vertices, faces, spacing)
        est = sample_grid.n_samples
    # boundary cubes (about 1.5 area / pitch^2 = est / 40) get n_sub^3 inside-test samples each
    _memory_guard(vertices, faces, bounds, dims, est + est * opts.subsamples**3 // 32, budget)
    if cloud:       # each point stands for the area of a square of the typical point spacing
        surf = Samples(points=vertices, weight=np.full(len(vertices), _point_spacing(vertices) ** 2),
                       face=np.full(len(vertices), -1))
    elif opts.n_samples is not None:
        surf = surface_random_samples(vertices, faces, est, np.random.default_rng(opts.seed))
    else:
        surf = sample_grid.samples()

    step(bar, STAGES[2])
    bodies, face_body, parts = _find_bodies(vertices, faces, opts, longest, cloud)
    step(bar, STAGES[3])
    samples, sample_body, parts_info, shells, counts = _body_samples(surf, vertices, faces, grid, opts, thick,
                                                                    face_body, bodies, parts)
    step(bar, STAGES[4])
    E, nu, rho, m = _sample_material(samples, surf, len(faces), youngs, poisson, density, opts)

    # ---- hash samples to voxels and accumulate (vectorized: unique + bincount); one cube per body and voxel
    # the moments: each cube's even share (FULL x its filled fraction) plus what its cut samples add
    rows = np.zeros(0, np.int64) if samples.moment_rows is None else samples.moment_rows
    given = np.zeros((0, 27)) if samples.moments is None else samples.moments
    cells, cube_mass, avg = hash_samples(samples.points, m, {"E": E, "nu": nu, "rho": rho}, origin, pitch, dims,
                                         sums={"volume": samples.weight}, piece=sample_body,
                                         row_sums={"uneven": (rows, given)})
    volume = avg["volume"]                             # filled volume per cube, model units^3
    moments = (volume / pitch**3)[:, None] * FULL
    moments += avg["uneven"]
    fraction = np.clip(volume / pitch**3, 0.0, 1.0)
    full = _full_within_roundoff(moments, origin, pitch, dims)
    moments[full], fraction[full] = FULL, 1.0
    moments, repaired = valid_moments(moments, even=full)   # positive semi-definite element matrices
    cube_rho = cube_mass / (volume * opts.scale**3) if opts.mass is not None else avg["rho"]

    info = {"occupancy": opts.occupancy, "repaired_moments": int(repaired.sum()), "fill": opts.fill, "stiffness": opts.stiffness,
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
                      f"meant? A model in millimetres needs scale=0.001 (--scale 0.001)", ScFemWarning, stacklevel=3)
    return _keep(model, opts.keep, info)
