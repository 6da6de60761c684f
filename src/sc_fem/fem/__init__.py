"""Finite elements on the lattice: materials, hexahedral elements, sparse K/M assembly, boundary
conditions, linear solvers, static and eigen solves, and the conforming tetrahedral reference."""

from .._lazy import lazy_getattr
from .assemble import assemble  # bound eagerly: it shares its module's name

_NAMES = {
    "Material": ".material", "lame": ".material",
    "Assembler": ".assemble",
    "FixSpec": ".boundary", "parse_fix": ".boundary", "fixed_nodes": ".boundary",
    "fixed_dofs": ".boundary", "read_vertex_file": ".boundary",
    "factorize": ".linsolve", "Factorization": ".linsolve",
    "solve_static": ".static", "StaticResult": ".static",
    "ELEMENTS": ".elements", "DEFAULT_ELEMENT": ".elements",
    "solve_eigen": ".eigen", "EigenResult": ".eigen", "EigenSolver": ".eigen", "EigenOptions": ".eigen",
    "solve_reference": ".reference", "ReferenceSolution": ".reference",
}
__all__ = sorted([*_NAMES, "assemble"])
__getattr__ = lazy_getattr(__name__, _NAMES)
