"""sc_fem: Squashing Cubes -- any graphics mesh becomes a physically based deformable object.

Pipeline: :func:`load_mesh` -> :func:`voxelize` (a :class:`CubeModel` of elastic cubes) ->
:func:`assemble` (sparse K, M of hexahedral elements) -> :func:`solve_static`, :func:`modal`
or a time integrator -> :func:`embed` (trilinear map W) back onto the source mesh.

Units are SI: metres, kilograms, seconds, pascals. Public arrays of points are ``(n, 3)``.
The public names are imported lazily, so ``import sc_fem`` is cheap and the command line starts fast.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from .fem.static import StaticResult
    from .modes.basis import ModalBasis

__version__ = "0.1.0"

# public name -> module that defines it (relative to this package)
_LAZY: dict[str, str] = {
    # errors
    "ScFemError": ".errors", "InputError": ".errors", "MeshError": ".errors",
    "MeshFileError": ".errors", "MaterialError": ".errors", "ResolutionError": ".errors",
    "BoundaryConditionError": ".errors", "SolverError": ".errors", "InstabilityError": ".errors",
    "FileFormatError": ".errors", "RenderError": ".errors",
    # geometry -> lattice
    "load_mesh": ".geometry.mesh", "CubeModel": ".lattice.cubes", "Embedding": ".lattice.embed",
    "VoxelOptions": ".lattice.options", "Scene": ".scene",
    # FEM core
    "Material": ".material", "lame": ".material", "Assembler": ".fem.assemble",
    "FixSpec": ".lattice.boundary", "parse_fix": ".lattice.boundary", "fixed_nodes": ".lattice.boundary",
    "fixed_dofs": ".lattice.boundary", "read_vertex_file": ".lattice.boundary",
    "factorize": ".fem.linsolve", "Factorization": ".fem.linsolve",
    "StaticResult": ".fem.static",
    "ELEMENTS": ".fem.hexahedron", "DEFAULT_ELEMENT": ".fem.hexahedron",
    "solve_eigen": ".fem.eigen", "EigenResult": ".fem.eigen", "EigenSolver": ".fem.eigen",
    "EigenOptions": ".fem.options",
    # files
    "save_model": ".io.model", "load_model": ".io.model",
    "Animation": ".io.animation", "save_animation": ".io.animation", "load_animation": ".io.animation",
    "save_modes": ".io.modes", "load_modes": ".io.modes",
    # modal analysis
    "ModalBasis": ".modes.basis", "ModalPlayer": ".modes.player", "run_batch": ".io.precompute",
    "Damping": ".modes.options", "AutoResolution": ".modes.options",
    "BatchResult": ".io.batch", "modal_converged": ".modes.auto",
    # dynamics (loads and contact classes live in sc_fem.dynamics)
    "simulate": ".dynamics.driver", "make_integrator": ".dynamics.driver",
    "Newmark": ".dynamics.newmark", "Corotational": ".dynamics.corotational",
    "CentralDifference": ".dynamics.central", "critical_time_step": ".dynamics.base",
    "XPBDSolver": ".dynamics.xpbd", "XPBDState": ".dynamics.xpbd", "XPBDEnergy": ".dynamics.xpbd",
    "simulate_xpbd": ".dynamics.xpbd", "rope_scene": ".dynamics.rope_scene", "RopeScene": ".dynamics.rope_scene",
    # messages (the "sc_fem" logger)
    "log_to_stderr": "._log",
}

# subpackages by pipeline stage
_SUBMODULES: dict[str, str] = {
    "geometry": ".geometry", "lattice": ".lattice", "fem": ".fem", "modes": ".modes",
    "dynamics": ".dynamics", "reconstruct": ".reconstruct", "io": ".io",
}

# Functions that share their module's name are imported eagerly: otherwise ``import
# sc_fem.lattice.voxelize`` (the submodule) could shadow the function.
from .fem.assemble import assemble  # noqa: E402
from .lattice.embed import embed  # noqa: E402
from .lattice.voxelize import voxelize  # noqa: E402

# loaded by the voxelizer above anyway; the conveniences below use them
from .errors import InputError  # noqa: E402
from .lattice.options import VoxelOptions  # noqa: E402

__all__ = sorted([*_LAZY, *_SUBMODULES, "assemble", "embed", "modal", "solve_static", "voxelize", "__version__"])


# The solvers take a Scene (sc_fem.modes.modal.modal, sc_fem.fem.static.solve_static); at the top
# level each is also one line that builds the Scene from what it is given (Scene.coerce).
def modal(source: Any, *, voxel: Any = None, mesh: Any = None, fix: Any = None, fix_vertices: Any = None,
          **options: Any) -> ModalBasis:
    """Vibration modes of a mesh, a path, a :class:`CubeModel` or a :class:`Scene`:
    :meth:`Scene.coerce` builds the scene and :func:`sc_fem.modes.modal.modal` solves it.

    Parameters
    ----------
    source : Scene, CubeModel, path, ``"builtin:NAME"``, trimesh.Trimesh or (vertices, faces)
        What to analyse; a mesh is voxelized with ``voxel`` and the grid fields of ``options``.
    voxel : VoxelOptions or dict, optional
        How a mesh is voxelized (:class:`~sc_fem.lattice.options.VoxelOptions`).
    mesh : mesh-like, optional
        Source mesh of a CubeModel to bake the modes onto (without it: the lattice nodes).
    fix : str, FixSpec, callable or list, optional
        Fixed nodes (:func:`sc_fem.fixed_nodes`), e.g. ``"z<min+0.01"``; ``"default"`` = a
        built-in model's supports.
    fix_vertices : array_like of int, optional
        Source-mesh vertex indices whose cubes are fixed.
    **options
        Fields of :class:`~sc_fem.lattice.options.VoxelOptions` (``resolution``: cubes along the
        longest axis, ``youngs`` in Pa, ...) and the keywords of :func:`sc_fem.modes.modal.modal`
        (``n_modes``, ``max_frequency`` in Hz, ``damping``, ``eigen``, ...). The coarsest
        converged grid is :func:`sc_fem.modal_converged`.

    Returns
    -------
    ModalBasis
        Frequencies (Hz) and mass-normalized mode shapes (m kg^-1/2) at the source vertices.
    """
    from .modes.modal import modal as modal_of_scene           # scene, modes, fem: loaded on first use
    from .modes.options import AutoResolution
    from .scene import Scene

    grid = _grid(options)
    if isinstance(grid.get("resolution"), (str, AutoResolution)):
        raise InputError(f"resolution is a number of cubes, got {grid['resolution']!r}: the coarsest converged "
                         "grid is sc_fem.modal_converged(source, AutoResolution(...), ...)")
    return modal_of_scene(Scene.coerce(source, voxel, mesh=mesh, fix=fix, fix_vertices=fix_vertices, **grid),
                          **options)


def solve_static(source: Any, *, fix: Any = None, fix_vertices: Any = None, points: Any = None, mesh: Any = None,
                 **options: Any) -> StaticResult:
    """Static displacement under load of a :class:`CubeModel` or a :class:`Scene`:
    :meth:`Scene.coerce` builds the scene and :func:`sc_fem.fem.static.solve_static` solves it.

    Parameters
    ----------
    source : Scene or CubeModel
        The lattice (or a Scene, then none of the other keywords but the loads and solver).
    fix : str, FixSpec, callable or list, optional
        Fixed nodes (:func:`sc_fem.fixed_nodes`), e.g. ``["x<min+0.01"]``.
    fix_vertices : array_like of int, optional
        Indices of ``mesh`` vertices (or of ``points``) whose cubes are fixed.
    points : array_like, shape (k, 3), optional
        Points in model units whose displacements are returned and where ``point_forces`` act.
    mesh : anything :func:`sc_fem.load_mesh` accepts, optional
        Source mesh; its vertices serve as ``points`` when ``points`` is not given.
    **options
        The keywords of :func:`sc_fem.fem.static.solve_static`: ``element``, ``forces`` (N),
        ``gravity`` (m/s^2), ``point_forces`` (N), ``backend``, ``solver``.

    Returns
    -------
    StaticResult
        Node displacements (m), those of the points or mesh vertices (m), forces (N), timings.
    """
    from .fem.static import solve_static as solve_scene        # scene, fem: loaded on first use
    from .scene import Scene

    return solve_scene(Scene.coerce(source, mesh=points if points is not None else mesh, fix=fix,
                                    fix_vertices=fix_vertices, **_grid(options)), **options)


def _grid(options: dict) -> dict:
    """The :class:`VoxelOptions` fields taken out of a convenience's ``options`` (the rest are the solver's)."""
    return {k: options.pop(k) for k in VoxelOptions.fields() if k in options}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    if name in _SUBMODULES:
        mod = importlib.import_module(_SUBMODULES[name], __name__)
        globals()[name] = mod
        return mod
    raise AttributeError(f"module 'sc_fem' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
