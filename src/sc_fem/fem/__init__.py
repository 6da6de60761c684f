"""Finite elements on the lattice: hexahedral elements (trilinear and higher-order cubes), sparse
K/M assembly, linear solvers, static and eigen solves, and the conforming tetrahedral reference.
(Materials: :mod:`sc_fem.material`; fixed nodes: :mod:`sc_fem.lattice.boundary`.)"""

from .._lazy import lazy_getattr
from .assemble import assemble  # bound eagerly: it shares its module's name

_NAMES = {
    "Assembler": ".assemble", "HighOrderCubes": ".highorder", "HighOrderAssembler": ".highorder",
    "factorize": ".linsolve", "Factorization": ".linsolve",
    "solve_static": ".static", "StaticResult": ".static",
    "ELEMENTS": ".hexahedron", "DEFAULT_ELEMENT": ".hexahedron",
    "solve_eigen": ".eigen", "EigenResult": ".eigen", "EigenSolver": ".eigen", "EigenOptions": ".options",
    "solve_reference": ".reference", "ReferenceSolution": ".reference",
}
__all__ = sorted([*_NAMES, "assemble"])
__getattr__ = lazy_getattr(__name__, _NAMES)
