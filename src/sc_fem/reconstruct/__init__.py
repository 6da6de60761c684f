"""PDE-based dynamic reconstruction of curve animations (Fang et al. 2024, Mathematics 12:3175).

Fit the 32-function closed-form model of the paper's Eq. 17 to curves at a few key frames
(:func:`fit`), evaluate it at any time (skipped frames or continuous ``t``), compare with the
static B-spline baseline (:func:`bspline_baseline`) using the paper's E_A / E_M (:func:`errors`),
and map curves back to a mesh (:func:`curve_mesh_map`, :func:`mesh_vertices`).

Modules: :mod:`.basis` (the 32 functions and the PDE each satisfies), :mod:`.rigid` (Eqs. 18-23),
:mod:`.param` (Eq. 24), :mod:`.pde` (Eq. 25 + (r, alpha) search), :mod:`.bspline`,
:mod:`.metrics` (Eqs. 26-27), :mod:`.meshmap`.
"""

from .basis import basis, paper_scale, pde_sign, space_basis, time_basis
from .bspline import BSplineModel, bspline_baseline
from .meshmap import curve_mesh_map, extract_curves, lattice_lines, mesh_vertices
from .metrics import ReconstructionErrors, curve_diameter, errors
from .param import parametrize
from .pde import PDEModel, fit
from .pipeline import Reconstruction, reconstruct_animation
from .rigid import RigidAlignment, RigidMotion, kabsch, remove_rigid
from .search import SearchResult

__all__ = [
    "BSplineModel", "PDEModel", "Reconstruction", "ReconstructionErrors", "RigidAlignment", "RigidMotion", "SearchResult",
    "basis", "bspline_baseline", "curve_diameter", "curve_mesh_map", "errors", "extract_curves", "fit",
    "kabsch", "lattice_lines", "mesh_vertices", "paper_scale", "parametrize", "pde_sign", "remove_rigid", "space_basis",
    "time_basis", "reconstruct_animation",
]
