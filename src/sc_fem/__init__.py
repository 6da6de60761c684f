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
    "ModeFileError": ".errors", "RenderError": ".errors",
    # foundation
    "load_mesh": ".mesh", "Material": ".material", "lame": ".material",
    "CubeModel": ".lattice", "Embedding": ".embed",
    # FEM core
    "Assembler": ".assemble",
    "FixSpec": ".boundary", "parse_fix": ".boundary", "fixed_nodes": ".boundary",
    "fixed_dofs": ".boundary", "read_vertex_file": ".boundary",
    "factorize": ".linsolve", "Factorization": ".linsolve",
    "solve_static": ".static", "StaticResult": ".static",
    "ELEMENTS": ".elements", "DEFAULT_ELEMENT": ".elements",
    # files
    "save_model": ".modelfile", "load_model": ".modelfile",
    "Animation": ".animfile", "save_animation": ".animfile", "load_animation": ".animfile",
    # XPBD and the cube-rope scene
    "XPBDSolver": ".xpbd", "XPBDState": ".xpbd", "XPBDEnergy": ".xpbd", "simulate_xpbd": ".xpbd",
    "rope_scene": ".rope_scene", "RopeScene": ".rope_scene",
    # modal analysis
    "ModalBasis": ".modal", "save_modes": ".modefile", "load_modes": ".modefile",
    "ModalPlayer": ".player", "run_batch": ".batch", "BatchResult": ".batch",
    "solve_eigen": ".eigen", "EigenResult": ".eigen", "EigenSolver": ".eigen",
    # dynamics (loads and contact classes live in sc_fem.integrators)
    "simulate": ".integrators", "make_integrator": ".integrators",
    "Newmark": ".integrators.newmark", "Corotational": ".integrators.corotational",
    "CentralDifference": ".integrators.central", "critical_time_step": ".integrators.central",
}

_SUBMODULES = ("models", "xpbd", "reconstruct", "render", "integrators")

# Functions that share their module's name are imported eagerly: otherwise ``import
# sc_fem.voxelize`` (the submodule) would replace the function attribute with the module.
from .assemble import assemble  # noqa: E402
from .embed import embed  # noqa: E402
from .modal import modal  # noqa: E402
from .voxelize import voxelize  # noqa: E402

__all__ = sorted([*_LAZY, *_SUBMODULES, "assemble", "embed", "modal", "voxelize", "__version__"])


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    if name in _SUBMODULES:
        mod = importlib.import_module(f".{name}", __name__)
        globals()[name] = mod
        return mod
    raise AttributeError(f"module 'sc_fem' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
