"""sc_fem: Squashing Cubes -- any graphics mesh becomes a physically based deformable object.

Pipeline: :func:`load_mesh` -> :func:`voxelize` (a :class:`CubeModel` of elastic cubes) ->
:func:`assemble` (sparse K, M of hexahedral elements) -> :func:`solve_static`, :func:`modal`
or a time integrator -> :func:`embed` (trilinear map W) back onto the source mesh.

Units are SI: metres, kilograms, seconds, pascals. Public arrays of points are ``(n, 3)``.
The public names are imported lazily, so ``import sc_fem`` is cheap and the command line starts fast.
"""

from __future__ import annotations

import importlib
from typing import Any

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
    "solve_static": ".fem.static", "StaticResult": ".fem.static",
    "ELEMENTS": ".fem.hexahedron", "DEFAULT_ELEMENT": ".fem.hexahedron",
    "solve_eigen": ".fem.eigen", "EigenResult": ".fem.eigen", "EigenSolver": ".fem.eigen",
    "EigenOptions": ".fem.options",
    # files
    "save_model": ".io.model", "load_model": ".io.model",
    "Animation": ".io.animation", "save_animation": ".io.animation", "load_animation": ".io.animation",
    "save_modes": ".io.modes", "load_modes": ".io.modes",
    # modal analysis
    "ModalBasis": ".modes.basis", "ModalPlayer": ".modes.player", "run_batch": ".io.batch",
    "Damping": ".modes.options", "AutoResolution": ".modes.options",
    "BatchResult": ".io.batch",
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
from .modes.modal import modal  # noqa: E402

__all__ = sorted([*_LAZY, *_SUBMODULES, "assemble", "embed", "modal", "voxelize", "__version__"])


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
