"""Linear static equilibrium ``K u = f`` of a cube lattice with fixed nodes.

Loads (all in newtons or m/s^2, summed): node forces ``(m, 3)``, gravity ``(3,)`` (each node
gets its lumped mass times ``g``; for a uniform field this equals the consistent load), and
forces on arbitrary points such as source-mesh vertices, mapped to the nodes with ``W^T``
(:func:`sc_fem.lattice.embed.embed`). Fixed nodes are condensed out (``K`` stays symmetric) and the
reduced system is solved by a sparse Cholesky factorization (:func:`sc_fem.fem.linsolve.factorize`)
or, for large models, by conjugate gradients preconditioned with algebraic multigrid
(:class:`sc_fem.fem.multigrid.LatticeAMG`; the choice: :class:`~sc_fem.fem.options.StaticOptions`).
The AMG's finest aggregates are blocks of lattice nodes of one part (:func:`sc_fem.fem.multigrid.lattice_aggregates`).

A part of the model that is not held (no fixed node, or fixed nodes that leave a rigid motion
free, e.g. one node or nodes on one line) and carries load raises
:class:`~sc_fem.errors.SolverError` before any factorization; an unloaded floating part (debris)
is held at zero displacement and counted in :attr:`StaticResult.n_floating_nodes`.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.csgraph import connected_components

from .._validate import as_float_array
from .assemble import Assembler
from ..lattice.boundary import fixed_dofs
from .rigid import rigid_block
from .elements import DEFAULT_ELEMENT
from .choice import choose_element
from .highorder import DEGREES, HighOrderAssembler, HighOrderCubes
from ..errors import BoundaryConditionError, InputError, ScFemWarning, SolverError
from ..lattice.cubes import CubeModel
from ..scene import Scene
from . import options as _options
from .linsolve import SystemSolver
from .multigrid import lattice_aggregates
from .options import StaticOptions, choose_static_solver
from .rigid import rigid_body_modes


@dataclass(frozen=True, eq=False)
class StaticResult:
    """Result of :func:`solve_static`.

    Attributes
    ----------
    displacements : ndarray, shape (m, 3)
        Node displacements, m.
    vertex_displacements : ndarray, shape (k, 3) or None
        Displacements of the given points / source-mesh vertices, m.
    forces : ndarray, shape (m, 3)
        Total applied node forces, N (before condensation; for ``"q2"`` / ``"q3"`` the trilinear
        equivalent of the load, which those cubes apply consistently through their own field).
    fixed_nodes : ndarray of int, shape (f,)
        Nodes held fixed by the boundary conditions.
    n_floating_nodes : int
        Nodes of unloaded, unsupported parts held at zero.
    element : str
        Element type used.
    backend : str
        Linear-solver backend.
    residual : float
        ``||K u - f|| / ||f||`` on the free DOFs.
    timings : dict
        Wall seconds of ``"assemble"``, then ``"factorize"`` and ``"solve"`` (direct) or
        ``"setup"`` (the AMG hierarchy) and ``"solve"`` (CG).
    compliance : float
        Work of the load that was solved, ``b . x`` on the free DOFs (J); twice the strain energy.
    solver : str
        ``"direct"`` or ``"cg-amg"`` (``"none"`` when nothing was loaded).
    info : dict
        ``reason`` (why this solver), and for CG: ``iterations``, ``tol``, ``levels`` (DOFs per
        AMG level), ``kernel``, ``residuals`` (relative residual per iteration); ``cg_failed``
        when ``"auto"`` fell back to the direct solve.
    """

    displacements: np.ndarray
    vertex_displacements: np.ndarray | None
    forces: np.ndarray
    fixed_nodes: np.ndarray
    n_floating_nodes: int
    element: str
    backend: str
    residual: float
    timings: dict = field(default_factory=dict)
    compliance: float = 0.0
    solver: str = "direct"
    info: dict = field(default_factory=dict)

    @property
    def max_displacement(self) -> float:
        """Largest node displacement magnitude, m."""
        return float(np.linalg.norm(self.displacements, axis=1).max())


def node_parts(model: CubeModel) -> np.ndarray:
    """Label of each node's part (nodes connected through shared cubes, even at one node), shape (m,)."""
    h = model.hexes
    rows = np.repeat(h[:, 0], 7)
    cols = h[:, 1:].ravel()
    g = sp.coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(model.n_nodes,) * 2)
    return connected_components(g, directed=False)[1]


def held_parts(model: CubeModel, labels: np.ndarray, fixed: np.ndarray, n_parts: int) -> np.ndarray:
    """Per part (``labels`` from :func:`node_parts`): do the fixed nodes suppress all 6 rigid motions?
    shape (n_parts,) bool (a part fixed at one node, or along one line, is not held)."""
    if len(fixed) == 0:
        return np.zeros(n_parts, dtype=bool)
    lab = labels[fixed]
    p = model.nodes[fixed] / model.pitch
    cnt = np.bincount(lab, minlength=n_parts)
    cen = np.stack([np.bincount(lab, p[:, k], minlength=n_parts) for k in range(3)], 1) / np.maximum(cnt, 1)[:, None]
    q = p - cen[lab]
    # 3x6 block [I, -[q]x] of the rigid modes at each fixed node; G = sum B^T B per part
    B = rigid_block(q)
    BtB = np.einsum("nki,nkj->nij", B, B).reshape(len(q), 36)
    G = np.stack([np.bincount(lab, BtB[:, k], minlength=n_parts) for k in range(36)], 1).reshape(n_parts, 6, 6)
    ev = np.linalg.eigvalsh(G)
    return ev[:, 0] > 1e-9 * np.maximum(ev[:, -1], 1e-300)


def solve_static(scene: Scene, *, element: str = DEFAULT_ELEMENT, forces: ArrayLike | None = None,
                 gravity: ArrayLike | None = None, point_forces: ArrayLike | None = None, backend: str = "auto",
                 solver: StaticOptions | str | None = None) -> StaticResult:
    """Static displacement of a scene's cube lattice under load.

    Parameters
    ----------
    scene : Scene
        Lattice, fixed nodes and source mesh (or points of interest) together
        (:meth:`~sc_fem.Scene.from_mesh`, :meth:`~sc_fem.Scene.from_model`);
        :func:`sc_fem.solve_static` builds one from a CubeModel or a mesh.
    element : {"auto", "q1i", "q1", "q1sri", "q2", "q3"}
        Element type (default ``"q1i"``); ``"auto"``: multiscale ``"q3"`` cubes for a thin-walled model,
        ``"q1i"`` otherwise (:func:`sc_fem.fem.choice.choose_element`; the result's ``info["element"]``
        says why); ``"q2"`` / ``"q3"``: degree-2 / 3 cubes (:mod:`sc_fem.fem.highorder`, need the source
        mesh), loaded consistently (gravity through their mass, point forces through their field).
    forces : array_like, shape (m, 3), optional
        Forces on the lattice nodes, N.
    gravity : array_like, shape (3,), optional
        Gravitational acceleration, m/s^2 (e.g. ``(0, 0, -9.81)``); uses ``model.mass``.
    point_forces : array_like, shape (k, 3), optional
        Forces on the scene's source vertices (or points), N; mapped with ``W^T``.
    backend : {"auto", "cholmod", "cholespy", "splu"}
        Sparse factorization backend of the direct solve (also ``StaticOptions.backend``).
    solver : StaticOptions or {"auto", "direct", "cg-amg"}, optional
        How ``K u = f`` is solved (:class:`~sc_fem.fem.options.StaticOptions`: ``solver``, ``tol``,
        ``maxiter``, ...). Default ``"auto"``: CG + AMG for large trilinear models
        (:data:`~sc_fem.fem.options.CG_AMG_MIN_DOFS` free DOFs), else the direct solve.

    Returns
    -------
    StaticResult
        Node displacements (m), the displacements of the scene's source vertices (m; None when
        the scene has no mesh), the applied forces (N), the residual and timings.

    Raises
    ------
    InputError
        ``scene`` is no Scene, or a bad load.
    SolverError
        A loaded part of the model is not held in place (floating), the factorization fails, or
        CG does not reach ``tol`` within ``maxiter`` iterations (``"cg-amg"``; ``"auto"`` solves
        directly when CG has not converged within
        :data:`~sc_fem.fem.options.AUTO_CG_ITERATIONS` and the factorization fits in memory).
    """
    Scene.check(scene, "sc_fem.fem.static.solve_static", "sc_fem.solve_static(model, ...)")
    opts = StaticOptions.coerce(solver)
    if backend != "auto":
        if opts.backend not in ("auto", backend):
            raise InputError(f"backend={backend!r} and solver.backend={opts.backend!r} disagree")
        opts = replace(opts, backend=backend)
    report_points = scene.mesh is not None
    model = scene.model
    element, why, note = choose_element(scene, element)
    higher = element in DEGREES
    if note is not None:
        warnings.warn(note, ScFemWarning, stacklevel=3)
    m = model.n_nodes
    W = scene.W if report_points else None

    f = np.zeros((m, 3))
    if forces is not None:
        f += as_float_array(forces, "forces", (m, 3))
    g = None if gravity is None else as_float_array(gravity, "gravity", (3,))
    pf = None
    if point_forces is not None:
        if W is None:
            raise InputError("point_forces needs a scene with a mesh or points (where the forces act)")
        pf = as_float_array(point_forces, "point_forces", (W.shape[0], 3))
    f_corners = f.copy()                              # point forces at the cube corners only
    if g is not None:
        f += model.node_masses()[:, None] * g[None, :]
    if pf is not None:
        f += scene.forces_to_nodes(pf)
    fixed = scene.fixed_nodes

    # parts that are not held: error if loaded, pin if unloaded
    labels = node_parts(model)
    n_parts = int(labels.max()) + 1
    held = held_parts(model, labels, fixed, n_parts)
    load = np.bincount(labels, np.abs(f).sum(axis=1), minlength=n_parts)
    scale = max(np.abs(f).sum(), 1e-300)
    loaded = load > 1e-12 * scale
    bad = ~held & loaded
    if np.any(bad):
        part = int(np.flatnonzero(bad)[0])
        n_cubes_part = int(np.count_nonzero(labels[model.hexes[:, 0]] == part))
        n_fix = int(np.count_nonzero(labels[fixed] == part))
        how = "has no fixed node" if n_fix == 0 else \
            f"has {n_fix} fixed node(s) that leave a rigid motion free (a single node or nodes on one line)"
        raise SolverError(
            f"the model is floating under load: a part of {n_cubes_part} cube(s) carrying "
            f"{load[part]:.4g} N of load {how}, so it can move as a rigid body and K u = f has no "
            f"solution. Fix nodes with fix=['x<...'] / --fix 'z<min+0.01' or fix_vertices=.")
    floating = np.flatnonzero(~held[labels] & ~np.isin(np.arange(m), fixed))
    t = {}
    if np.all(f == 0):
        u = np.zeros((m, 3))
        t.update(assemble=0.0, factorize=0.0, solve=0.0)
        return StaticResult(u, None if W is None else np.asarray(W @ u), f, fixed, len(floating),
                            element, "none", 0.0, t, solver="none", info={"reason": "no load"})
    all_fixed = np.union1d(fixed, floating)
    t0 = time.perf_counter()
    if higher:                          # point forces imply W (checked above): the field's own map
        asm = HighOrderAssembler(HighOrderCubes(scene, element), fixed_nodes=all_fixed)
        W = None if W is None else asm.cubes.W
    else:
        asm = Assembler(model, element, fixed_dofs=fixed_dofs(all_fixed))
    K = asm.stiffness()
    t["assemble"] = time.perf_counter() - t0
    if K.shape[0] == 0:
        raise BoundaryConditionError("every node is fixed: nothing to solve")
    if higher:                          # consistent loads of the degree-p field
        b = asm.restrict(f_corners)
        if g is not None:
            b = b + asm.mass() @ np.tile(g, asm.cubes.n_nodes)[asm.free_dofs]
        if pf is not None:
            b = b + (W.T @ pf.reshape(-1))[asm.free_dofs]
    else:
        b = asm.restrict(f)
    amg_data = ((lambda: (rigid_body_modes(asm.nodes_m, asm.free_dofs), None)) if higher else
                (lambda: lattice_amg_data(model, asm.free_dofs, labels)))    # built only if CG + AMG is chosen
    linear = _system_solver(K, opts, higher, amg_data)
    x = linear.solve(b)
    how, st, info = linear.kind, linear.stats, {"reason": linear.reason, "element": why}
    if linear.last:                                    # CG + AMG ran (and maybe failed)
        cg = linear.last
        info.update(iterations=cg["iterations"], tol=opts.tol, levels=cg["levels"], kernel=cg["kernel"],
                    residuals=cg["residuals"])
    failed = st["fallback"] or {"setup": 0.0, "solve": 0.0}
    if st["fallback"]:
        info["cg_failed"] = st["fallback"]
    t["factorize" if how == "direct" else "setup"] = st["setup_seconds"] - failed["setup"]
    t["solve"] = st["solve_seconds"] - failed["solve"]
    res = float(np.linalg.norm(K @ x - b) / max(np.linalg.norm(b), 1e-300))
    limit = max(1e-6, 10.0 * opts.tol) if how == "cg-amg" else 1e-6
    if not res < limit:
        raise SolverError(f"the static solve did not converge (relative residual {res:.3g}); the stiffness "
                          "matrix is nearly singular -- is the model held in place?")
    u = asm.expand(x)
    if higher:
        vu = None if W is None else asm.vertex_field(x, W)
    else:
        vu = None if W is None else np.asarray(W @ u)
    return StaticResult(u, vu, f, fixed, len(floating), element, linear.backend_used, res, t,
                        compliance=float(b @ x), solver=how, info=info)


def _system_solver(K: sp.csr_matrix, opts: StaticOptions, higher: bool, amg_data) -> SystemSolver:
    """The :class:`~sc_fem.fem.linsolve.SystemSolver` of ``K u = f`` (N/m) that ``opts`` choose
    (:func:`~sc_fem.fem.options.choose_static_solver`): ``"auto"`` gives CG
    :data:`~sc_fem.fem.options.AUTO_CG_ITERATIONS` iterations, then solves directly when the factorization
    fits in memory (else CG goes on to ``maxiter``); an explicit ``"cg-amg"`` that fails raises.
    ``amg_data``: ``() -> (near_null, aggregates)``, called only if the AMG is set up."""
    how, reason = choose_static_solver(K.shape[0], K.nnz, opts.solver, lattice=not higher,
                                       max_memory=opts.max_memory)
    auto = opts.solver == "auto"
    need, budget = _options.factor_memory_estimate(K.shape[0], K.nnz), _options.memory_budget(opts.max_memory)
    fallback = "solved directly instead" if auto and need <= budget else None
    hint = ("use solver='direct' (or 'auto' to fall back to it)" if not auto else
            f"the direct solve would need ~{need / 2**30:.1f} GiB > budget {budget / 2**30:.1f} GiB")
    return SystemSolver(K, how, reason=reason, tol=opts.tol, backend=opts.backend, fallback=fallback,
                        hint=f"{hint}, or raise maxiter / tol (StaticOptions)", system="", amg_data=amg_data,
                        maxiter=min(opts.maxiter, _options.AUTO_CG_ITERATIONS) if fallback else opts.maxiter)


def lattice_amg_data(model: CubeModel, free_dofs: np.ndarray, labels: np.ndarray | None = None
                     ) -> tuple[np.ndarray, np.ndarray | None]:
    """What the AMG of a trilinear lattice matrix on ``free_dofs`` is built from.

    Parameters
    ----------
    model : CubeModel
    free_dofs : ndarray of int, shape (n,)
        The free DOFs (node-major) the matrix acts on.
    labels : ndarray of int, shape (m,), optional
        Part of every node (:func:`node_parts`; computed when omitted).

    Returns
    -------
    near_null : ndarray, shape (n, 6)
        The rigid-body modes (:func:`~sc_fem.fem.rigid.rigid_body_modes`, m).
    aggregates : ndarray of int, shape (n // 3,) or None
        The finest aggregates (:func:`~sc_fem.fem.multigrid.lattice_aggregates`).
    """
    labels = node_parts(model) if labels is None else labels
    return rigid_body_modes(model.nodes_m, free_dofs), lattice_aggregates(model, labels, free_dofs)
