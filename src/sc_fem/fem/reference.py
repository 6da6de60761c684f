"""A reference from outside the cube model: conforming quadratic tetrahedra (scikit-fem P2).

To check what the cubes get right, the same shape is meshed with TetGen (a conforming
tetrahedral mesh of the surface, after making it one closed manifold: overlapping parts are
united with Manifold, holes closed with MeshFix) and solved with scikit-fem's
``ElementVector(ElementTetP2())``: total mass, free-free natural frequencies, and the
displacement of a clamped case under gravity. These are optional dependencies (the
``sc_fem[reference]`` extra); nothing else in sc_fem needs them.
"""

from __future__ import annotations

import importlib
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, eigsh

from ..errors import InputError, MeshError, ScFemError
from ..geometry.inside import mesh_parts
from ..geometry.mesh import load_mesh
from ..units import GRAVITY
from .linsolve import factorize



def _require(module: str):
    try:
        return importlib.import_module(module)
    except ImportError:
        raise ScFemError(f"the conforming reference needs the optional package {module!r}: "
                         f"pip install 'sc_fem[reference]'") from None


@dataclass(frozen=True, eq=False)
class TetMesh:
    """A conforming tetrahedral mesh.

    Attributes
    ----------
    nodes : ndarray, shape (n, 3)
        Vertex positions, metres.
    tets : ndarray of int, shape (m, 4)
        Tetrahedra.
    volume : float
        Volume of the closed surface it fills, m^3.
    repair : str
        What was done to make the surface one closed manifold.
    """

    nodes: np.ndarray
    tets: np.ndarray
    volume: float
    repair: str


@dataclass(frozen=True, eq=False)
class ReferenceSolution:
    """Results of the conforming P2 reference.

    Attributes
    ----------
    mass : float
        Total mass, kg.
    frequencies : ndarray, shape (k,)
        Lowest free-free natural frequencies, Hz (6 rigid-body modes removed).
    max_displacement : float or None
        Largest displacement magnitude (m) of the clamped case under gravity (None if not asked).
    n_tets, n_dofs : int
        Mesh size.
    timings : dict
        Seconds per stage (mesh, assemble, eigen, static).
    repair : str
        What was done to the surface before meshing.
    max_displacement_vector : ndarray, shape (3,), or None
        The displacement (m) of the node that moves most in the clamped case.
    """

    mass: float
    frequencies: np.ndarray
    max_displacement: float | None
    n_tets: int
    n_dofs: int
    timings: dict = field(default_factory=dict)
    repair: str = ""
    max_displacement_vector: np.ndarray | None = None

    @property
    def seconds(self) -> float:
        """Total wall time, s."""
        return float(sum(self.timings.values()))


def closed_manifold(mesh: Any):
    """One closed, outward-oriented manifold surface of ``mesh`` (a trimesh.Trimesh).

    Parts that enclose volume (:func:`sc_fem.geometry.inside.mesh_parts`) are united (Manifold); a
    surface with holes is closed by MeshFix. Open parts (sheets) are dropped: a conforming
    solid mesh has no place for them.
    """
    import trimesh

    mesh = load_mesh(mesh)
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    if len(f) == 0:
        raise MeshError("a conforming reference needs a surface, not a point cloud")
    parts = mesh_parts(v, f)
    steps = []
    pieces = []
    for k in np.flatnonzero(parts.closed):      # loop over parts (a handful), not elements
        piece = trimesh.Trimesh(v, parts.faces[parts.label == k], process=True)
        if not piece.is_watertight:
            fix = _require("pymeshfix")
            pv, pf = fix.clean_from_arrays(np.asarray(piece.vertices), np.asarray(piece.faces))
            piece = trimesh.Trimesh(pv, pf, process=True)
            steps.append("MeshFix closed holes")
        pieces.append(piece)
    if not pieces:
        raise MeshError("the mesh encloses no volume: nothing for a solid reference to fill")
    if len(pieces) > 1:
        _require("manifold3d")
        out = trimesh.boolean.union(pieces, engine="manifold")
        steps.append(f"Manifold united {len(pieces)} parts")
    else:
        out = pieces[0]
    if parts.closed.sum() < parts.n_parts:
        steps.append(f"{int(parts.n_parts - parts.closed.sum())} open parts dropped")
    if not out.is_watertight or out.volume <= 0:
        raise MeshError("could not make the surface one closed manifold for the reference")
    return out, "; ".join(steps) or "none (watertight)"


def tetrahedralize(mesh: Any, *, scale: float = 1.0, n_tets: int = 20000, max_faces: int = 6000) -> TetMesh:
    """Conforming tetrahedral mesh of a closed surface with about ``n_tets`` tetrahedra (TetGen,
    radius-edge ratio <= 2, dihedral angles >= 10 degrees). ``scale``: metres per model unit.
    A surface of more than ``max_faces`` triangles is decimated first (VTK's quadric decimation
    through pyvista), since TetGen keeps every surface triangle and a 70k-triangle scan would
    need millions of quadratic tetrahedra; the volume changes by the reported amount."""
    tetgen = _require("tetgen")
    surf, repair = closed_manifold(mesh)
    if n_tets < 10:
        raise InputError(f"n_tets must be >= 10, got {n_tets}")
    if len(surf.faces) > max_faces:
        import pyvista as pv
        import trimesh

        poly = pv.PolyData(np.asarray(surf.vertices), np.c_[np.full(len(surf.faces), 3), surf.faces].ravel())
        dec = poly.decimate(1.0 - max_faces / len(surf.faces)).triangulate()
        v0 = float(surf.volume)
        surf = trimesh.Trimesh(np.asarray(dec.points), np.asarray(dec.faces).reshape(-1, 4)[:, 1:], process=True)
        if not surf.is_watertight:
            fix = _require("pymeshfix")
            pv_, pf_ = fix.clean_from_arrays(np.asarray(surf.vertices), np.asarray(surf.faces))
            surf = trimesh.Trimesh(pv_, pf_, process=True)
        repair += f"; decimated to {len(surf.faces)} triangles (volume {100 * (surf.volume / v0 - 1):+.2f} %)"
    tg = tetgen.TetGen(np.asarray(surf.vertices, dtype=float) * scale, np.asarray(surf.faces))
    vol = float(surf.volume) * scale**3
    nodes, tets = tg.tetrahedralize(order=1, mindihedral=10.0, minratio=2.0, fixedvolume=True,
                                    maxvolume=vol / n_tets)[:2]
    return TetMesh(np.asarray(nodes, dtype=float), np.asarray(tets, dtype=np.int64), vol, repair)


def uniform_field(basis, c: np.ndarray) -> np.ndarray:
    """The P2 field ``u = c`` everywhere (c (3,)) as a DOF vector of the vector ``basis`` (nodal and
    edge DOFs of each of the 3 components)."""
    out = np.zeros(basis.N)
    for k in range(3):                                    # the 3 components, not a loop over nodes
        out[basis.nodal_dofs[k]] = c[k]
        out[basis.edge_dofs[k]] = c[k]
    return out


def _free_free(K, M, n_modes: int, shift: float) -> np.ndarray:
    A = (K + shift * M).tocsc()
    fac = factorize(A)
    op = LinearOperator(A.shape, matvec=fac.solve, dtype=float)
    vals = eigsh(K, k=n_modes + 6, M=M, sigma=-shift, OPinv=op, which="LM", return_eigenvectors=False)
    omega2 = np.sort(vals)[6:]
    return np.sqrt(np.maximum(omega2, 0.0)) / (2 * np.pi)


def solve_reference(mesh: Any, *, youngs: float, poisson: float, density: float, scale: float = 1.0,
                    n_tets: int = 20000, n_modes: int = 10, max_faces: int = 6000,
                    clamp: Callable[[np.ndarray], np.ndarray] | None = None,
                    gravity=(0.0, 0.0, -GRAVITY)) -> ReferenceSolution:
    """Solve the shape with conforming P2 tetrahedra.

    Parameters
    ----------
    mesh : mesh-like
        A surface that encloses volume (see :func:`closed_manifold`).
    youngs, poisson, density : float
        Material: Pa, -, kg/m^3.
    scale : float
        Metres per model unit.
    n_tets : int
        About how many tetrahedra.
    n_modes : int
        Free-free elastic modes to compute.
    clamp : callable, optional
        ``clamp(points (n, 3) metres) -> bool (n,)``: nodes held for the gravity case; None
        skips it.
    gravity : array_like, shape (3,)
        Acceleration of the gravity case, m/s^2 (default ``(0, 0, -9.81)``): give the same vector
        as the model it is compared with (a y-up mesh sags along -y).
    """
    from skfem import Basis, BilinearForm, ElementTetP2, ElementVector, MeshTet, asm
    from skfem.helpers import dot
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    g = np.asarray(gravity, dtype=float)
    if g.shape != (3,) or not np.all(np.isfinite(g)):
        raise InputError(f"gravity must be 3 finite numbers (m/s^2), got {gravity!r}")
    timings = {}
    t0 = time.perf_counter()
    tm = tetrahedralize(mesh, scale=scale, n_tets=n_tets, max_faces=max_faces)
    timings["mesh"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    m = MeshTet(np.ascontiguousarray(tm.nodes.T), np.ascontiguousarray(tm.tets.T))
    basis = Basis(m, ElementVector(ElementTetP2()), intorder=2)      # grad P2 x grad P2: degree 2, exact
    lam, mu = lame_parameters(youngs, poisson)
    K = asm(linear_elasticity(lam, mu), basis)
    mbasis = basis.with_quadrature(4) if hasattr(basis, "with_quadrature") else \
        Basis(m, ElementVector(ElementTetP2()), intorder=4)               # P2 x P2: degree 4, exact

    @BilinearForm
    def mass_form(u, v, w):
        return density * dot(u, v)

    M = asm(mass_form, mbasis)

    ones = uniform_field(basis, np.array([0.0, 0.0, 1.0]))
    total_mass = float(ones @ (M @ ones))
    timings["assemble"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    k_typ = float(K.diagonal().mean() / max(M.diagonal().mean(), 1e-300))
    freqs = _free_free(K, M, n_modes, 1e-4 * k_typ)
    timings["eigen"] = time.perf_counter() - t0
    umax = uvec = None
    if clamp is not None:
        t0 = time.perf_counter()
        held = np.asarray(clamp(basis.doflocs.T), dtype=bool)
        if not held.any():
            raise InputError("clamp selects no node of the reference mesh")
        f = M @ uniform_field(basis, g)
        free = np.flatnonzero(~held)
        u = np.zeros(basis.N)
        u[free] = factorize(sp.csr_matrix(K)[free][:, free].tocsc()).solve(f[free])
        un = u[basis.nodal_dofs].T                                      # (nodes, 3)
        i = int(np.argmax(np.linalg.norm(un, axis=1)))
        umax, uvec = float(np.linalg.norm(un[i])), un[i].copy()
        timings["static"] = time.perf_counter() - t0
    return ReferenceSolution(total_mass, freqs, umax, len(tm.tets), int(basis.N), timings, tm.repair, uvec)
