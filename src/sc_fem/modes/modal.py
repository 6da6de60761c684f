"""Modal analysis of a cube lattice, baked onto the source mesh: :func:`modal` -> :class:`ModalBasis`.

The generalized eigenproblem ``K phi = omega^2 M phi`` (consistent mass by default) is solved by
:func:`sc_fem.fem.eigen.solve_eigen` (shift-invert with a negative shift through the Cholesky
backend, or LOBPCG + AMG when a factorization would not fit). Modes are mass-normalized
(``phi^T M phi = 1``), frequencies are in Hz, and the relative residual
``||K phi - omega^2 M phi|| / ||K phi||`` of every mode is reported.

Rigid-body modes (6 per unsupported connected part) are recognised by their frequency
(``omega^2 < RIGID_FRACTION * mean(diag K) / mean(diag M)``, i.e. numerically zero next to the
stiffest element) and removed unless ``keep_rigid=True`` (then flagged in ``ModalBasis.rigid``).

The modes are then *baked*: with the trilinear embedding ``W`` (:func:`sc_fem.lattice.embed.embed`),
each mode on the source mesh is ``W @ phi`` -- an ``(n_vertices, 3)`` array -- and the lattice is
thrown away unless ``keep_lattice=True``.

Units: a mode value is a displacement in metres per unit modal coordinate (m kg^-1/2), so a
modal coordinate ``q`` (m kg^1/2) gives the displacement ``sum_k q_k phi_k`` in metres; an
impulse ``J`` (N s) on a vertex ``v`` gives the modal velocity ``phi_k(v) . J``.

Damping (stored per mode as a ratio ``zeta_k``): ``damping=`` a ratio (one value or one per mode,
default :data:`~sc_fem.modes.options.DEFAULT_DAMPING_RATIO`) or a :class:`~sc_fem.modes.options.Damping`
(``Damping(rayleigh=(alpha, beta))`` for ``C = alpha M + beta K``).

*A model no bigger than the scene needs*: ``n_modes=K``, ``max_frequency=F`` (all modes below
``F`` Hz, e.g. half the playback frame rate -- faster modes only alias), and
``resolution="auto"`` (or an :class:`~sc_fem.modes.options.AutoResolution`): the coarsest grid
whose first ``K`` frequencies agree with those of the next finer grid; the table it decided from
is in :attr:`ModalBasis.resolution_table`.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError
from ..fem.eigen import EigenOptions
from ..fem.elements import DEFAULT_ELEMENT
from ..lattice.cubes import CubeModel
from ..lattice.options import VoxelOptions
from .options import (AUTO_RESOLUTIONS, DEFAULT_DAMPING_RATIO, DEFAULT_RESOLUTION_TOLERANCE,  # noqa: F401
                      AutoResolution, Damping, ModalRequest, parse_resolution)

DEFAULT_N_MODES = 10
"""Modes computed when neither ``n_modes`` nor ``max_frequency`` is given."""

RIGID_FRACTION = 1e-10
"""A mode is rigid when ``omega^2 < RIGID_FRACTION * lambda_scale`` (``lambda_scale`` =
``mean(diag K) / mean(diag M)``, the order of the highest eigenvalue). Rigid modes come out at
about ``1e-17 .. 1e-16 * lambda_scale`` (round-off); the first elastic (bending) mode of a free
200 x 1 x 1-cube rod (q1i), a very floppy voxel model, is at ``4.6e-9 * lambda_scale`` -- 46x above
the threshold (measured with ``solve_eigen`` on ``CubeModel.box((200, 1, 1), ...)``)."""


@dataclass(frozen=True, eq=False)
class ModalBasis:
    """Mass-normalized vibration modes baked onto a mesh.

    Attributes
    ----------
    frequencies : ndarray, shape (k,)
        Natural frequencies, Hz, ascending (0 for rigid modes).
    modes : ndarray, shape (k, n, 3)
        Mode shapes at the ``vertices``: displacement in metres per unit modal coordinate
        (m kg^-1/2); ``phi^T M phi = 1`` on the lattice.
    vertices : ndarray, shape (n, 3)
        Rest positions of the mesh the modes are baked on, model units.
    faces : ndarray of int, shape (f, 3)
        Triangles of that mesh ((0, 3) for a point set).
    damping : ndarray, shape (k,)
        Damping ratio ``zeta`` of each mode (0 for rigid modes).
    damping_spec : dict
        How ``damping`` was specified: ``{"kind": "ratio", "zeta": ...}`` or
        ``{"kind": "rayleigh", "alpha": ..., "beta": ...}``.
    rigid : ndarray of bool, shape (k,)
        Which modes are rigid-body modes (frequency 0). All False unless ``keep_rigid=True``:
        rigid modes are removed by default. Stored (not derived from ``frequencies == 0``) because
        the mode file format has it.
    residuals : ndarray, shape (k,)
        ``||K phi - omega^2 M phi|| / ||K phi||`` of each mode (see :func:`sc_fem.fem.eigen.relative_residuals`).
    n_rigid_removed : int
        Rigid-body modes found and dropped.
    scale : float
        Metres per model unit (divide a displacement in metres by it to get model units).
    pitch : float
        Cube edge, model units.
    resolution : int
        Cubes along the longest axis of the lattice the modes were computed on.
    element : str
        Element type.
    material : dict
        ``name``, ``youngs`` / ``poisson`` / ``density`` (min and max over cubes), ``mass`` (kg).
    fix_record : dict
        ``specs`` (the ``--fix`` specs), ``vertices`` (count of ``--fix-vertices``),
        ``n_nodes`` (fixed lattice nodes).
    source : str
        Source model name / file name.
    source_sha256 : str
        Checksum of the source file (or of the arrays).
    n_cubes, n_dofs : int
        Size of the lattice problem.
    eigen : dict
        Solver report: ``method``, ``backend``, ``reason``, ``sigma``, ``seconds``, memory estimate.
    timings : dict
        Wall seconds per stage.
    resolution_table : list of dict or None
        ``resolution="auto"``: one row per grid tried (resolution, cubes, DOFs, seconds,
        frequencies, max relative change to the next finer grid, chosen).
    lattice : CubeModel or None
        The lattice (``keep_lattice=True`` only).
    node_modes : ndarray, shape (k, m, 3) or None
        Modes at the lattice nodes, m kg^-1/2 (``keep_lattice=True`` only).
    fixed_points : ndarray, shape (q, 3) or None
        Positions of the fixed lattice nodes, model units (drawn on mode sheets).
    """

    frequencies: np.ndarray
    modes: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    damping: np.ndarray
    damping_spec: dict
    rigid: np.ndarray
    residuals: np.ndarray
    n_rigid_removed: int
    scale: float
    pitch: float
    resolution: int
    element: str
    material: dict = field(default_factory=dict)
    fix_record: dict = field(default_factory=dict)
    source: str = ""
    source_sha256: str = ""
    n_cubes: int = 0
    n_dofs: int = 0
    eigen: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    resolution_table: list | None = None
    lattice: CubeModel | None = None
    node_modes: np.ndarray | None = None
    fixed_points: np.ndarray | None = None

    @property
    def n_modes(self) -> int:
        """Number of modes ``k``."""
        return len(self.frequencies)

    @property
    def n_vertices(self) -> int:
        """Number of vertices ``n``."""
        return len(self.vertices)

    @property
    def omegas(self) -> np.ndarray:
        """Angular frequencies ``2 pi f``, rad/s, shape (k,)."""
        return 2.0 * np.pi * self.frequencies

    def summary(self) -> str:
        """A short text table: frequencies, damping ratios and residuals."""
        rows = [f"  {'mode':>4}  {'f [Hz]':>12}  {'zeta':>8}  {'residual':>9}"]
        for i in range(self.n_modes):
            tag = "  rigid" if self.rigid[i] else ""
            rows.append(f"  {i:>4}  {self.frequencies[i]:>12.5g}  {self.damping[i]:>8.4g}  "
                        f"{self.residuals[i]:>9.2e}{tag}")
        return "\n".join(rows)

    def __repr__(self) -> str:
        f = ", ".join(f"{x:.4g}" for x in self.frequencies[:6])
        more = ", ..." if self.n_modes > 6 else ""
        return (f"ModalBasis({self.n_modes} modes on {self.n_vertices} vertices, f = [{f}{more}] Hz, "
                f"{self.n_cubes} cubes, element {self.element!r}, {self.n_rigid_removed} rigid removed)")


# ---------------------------------------------------------------------------------------- helpers
def damping_ratios(omegas: np.ndarray, *, damping_ratio=None, rayleigh=None) -> tuple[np.ndarray, dict]:
    """Per-mode damping ratios (k,) and their record: ``Damping(damping_ratio, rayleigh).ratios(omegas)``."""
    return Damping(ratio=damping_ratio, rayleigh=rayleigh).ratios(omegas)


def _unsupported_parts(model: CubeModel, fixed: np.ndarray) -> int:
    """Connected parts whose fixed nodes leave some rigid motion free (each may have up to 6)."""
    from ..fem.static import held_parts, node_parts

    labels = node_parts(model)
    n_parts = int(labels.max()) + 1
    return int(n_parts - held_parts(model, labels, fixed, n_parts).sum())


def _log(msg: str, progress: bool) -> None:
    if progress:
        print(msg, file=sys.stderr, flush=True)


@dataclass(frozen=True, eq=False)
class _Solved:
    """Eigenpairs of one lattice before baking (internal)."""

    scene: Any                 # the Scene (model, mesh, fixed nodes)
    lam: np.ndarray            # (k,) kept eigenvalues, 1/s^2
    X: np.ndarray              # (n_free, k) kept eigenvectors
    rigid: np.ndarray          # (k,) bool
    res: np.ndarray            # (k,) relative residuals
    n_removed: int
    asm: Any                   # the Assembler (maps free DOFs to nodes)
    info: dict
    timings: dict

    @property
    def elastic_frequencies(self) -> np.ndarray:
        """Frequencies of the kept elastic modes, Hz."""
        return np.sqrt(np.maximum(self.lam[~self.rigid], 0.0)) / (2.0 * np.pi)


def solve_scene(scene, req: ModalRequest) -> _Solved:
    """Eigenpairs of one lattice; the shifted operator is set up once however often ``k`` grows."""
    from ..fem.assemble import Assembler
    from ..fem.eigen import EigenSolver, rigid_body_modes

    model, fixed = scene.model, scene.fixed_nodes
    n_modes, max_frequency, max_modes, progress = req.n_modes, req.max_frequency, req.max_modes, req.progress
    t = {}
    t0 = time.perf_counter()
    asm = Assembler(model, req.element, fixed_dofs=scene.fixed_dofs)
    K = asm.stiffness()
    M = asm.mass(lumped=req.lumped)
    t["assemble"] = time.perf_counter() - t0
    n = K.shape[0]
    if n == 0:
        raise InputError("every node is fixed: no modes to compute")
    n_rigid_expected = 6 * _unsupported_parts(model, fixed)
    want = DEFAULT_N_MODES if (n_modes is None and max_frequency is None) else n_modes
    lam_max = None if max_frequency is None else (2.0 * np.pi * max_frequency) ** 2
    k_cap = min(n - 1, max_modes + n_rigid_expected + 6)
    k = n_rigid_expected + (want if want is not None else 12)
    t0 = time.perf_counter()
    solver = EigenSolver(K, M, method=req.eigen.solver, backend=req.eigen.backend,
                         near_null=rigid_body_modes(model.nodes_m, asm.free_dofs), max_memory=req.eigen.max_memory)
    scale = solver.lambda_scale
    passes = 0
    while True:                                                   # loop: grow k until enough modes
        k = min(k, k_cap)
        if k < 1:
            raise InputError(f"the model has only {n} free DOFs: too few for a modal analysis")
        eig = solver.solve(k)
        passes += 1
        lam = eig.eigenvalues
        rigid = lam < RIGID_FRACTION * scale
        n_el = int((~rigid).sum())
        _log(f"  eigensolve: {k} pairs, {eig.method}/{eig.backend}, {n_el} elastic, "
             f"top {np.sqrt(max(lam[-1], 0)) / 2 / np.pi:.4g} Hz", progress)
        done = (want is not None and n_el >= want) or (lam_max is not None and lam[-1] >= lam_max)
        if done or k >= k_cap:
            break
        k *= 2
    t["eigensolve"] = time.perf_counter() - t0
    sel = np.ones(len(lam), dtype=bool)
    if lam_max is not None:
        sel &= rigid | (lam < lam_max)
    within = rigid | (np.cumsum(~rigid) <= (max_modes if want is None else min(want, max_modes)))
    cut = bool(np.any(sel & ~within))                             # modes asked for beyond max_modes
    sel &= within
    if not req.keep_rigid:
        sel &= ~rigid
    if lam_max is not None and not np.any(sel & ~rigid):
        first = np.sqrt(max(float(lam[~rigid][0]), 0.0)) / (2 * np.pi) if np.any(~rigid) else float("nan")
        raise InputError(f"no elastic mode below max_frequency={max_frequency:g} Hz: the first one is at "
                         f"{first:.4g} Hz; raise max_frequency or give n_modes")
    info = {"method": eig.method, "backend": eig.backend, "reason": eig.reason, "sigma": eig.sigma,
            "seconds": eig.seconds, "k_computed": int(len(lam)), "passes": passes, "setups": solver.n_setups,
            "n_rigid_expected": n_rigid_expected, "n_rigid_found": int(rigid.sum()), "lambda_scale": scale,
            **eig.info}
    if cut or not done:
        target = f"{max_frequency:g} Hz" if lam_max is not None else f"{want} elastic modes"
        info["truncated"] = f"max_modes={max_modes} (or the model size) reached before {target}"
    return _Solved(scene=scene, lam=lam[sel], X=eig.vectors[:, sel], rigid=rigid[sel],
                   res=eig.residuals[sel], n_removed=0 if req.keep_rigid else int(rigid.sum()), asm=asm, info=info,
                   timings=t)


def _bake(asm, X: np.ndarray, W) -> tuple[np.ndarray, np.ndarray]:
    """Node modes (k, m, 3) and vertex modes ``W @ phi`` (k, n, 3) from free-DOF vectors (n_free, k)."""
    node = asm.expand(X)                                          # (m, 3, k)
    m, _, k = node.shape
    flat = node.reshape(m, 3 * k)
    vert = np.asarray(W @ flat).reshape(-1, 3, k)
    return np.ascontiguousarray(node.transpose(2, 0, 1)), np.ascontiguousarray(vert.transpose(2, 0, 1))


def finish(s: _Solved, req: ModalRequest, timings: dict, resolution_table: list | None = None) -> ModalBasis:
    """Bake the modes of ``s`` onto its scene's source mesh (or the lattice nodes): the ModalBasis."""
    scene = s.scene
    model = scene.model
    timings = {**timings, **s.timings}
    t0 = time.perf_counter()
    node_modes, vertex_modes = _bake(s.asm, s.X, scene.W)
    timings["bake"] = time.perf_counter() - t0
    omegas = np.where(s.rigid, 0.0, np.sqrt(np.maximum(s.lam, 0.0)))
    zeta, spec = req.damping.ratios(omegas)
    keep = req.keep_lattice
    return ModalBasis(
        frequencies=omegas / (2.0 * np.pi), modes=vertex_modes, vertices=scene.rest_vertices, faces=scene.faces,
        damping=zeta, damping_spec=spec, rigid=s.rigid, residuals=s.res, n_rigid_removed=s.n_removed,
        scale=float(model.scale), pitch=float(model.pitch),
        resolution=int(model.info.get("resolution", int(model.dims.max()))), element=req.element,
        material=scene.material_record(), fix_record=scene.fix_record(),
        source=scene.source, source_sha256=scene.sha256, n_cubes=model.n_cubes, n_dofs=model.n_dofs, eigen=s.info,
        timings=timings, resolution_table=resolution_table, lattice=model if keep else None,
        node_modes=node_modes if keep else None, fixed_points=model.nodes[scene.fixed_nodes])


def modal(model: Any, *, n_modes: int | None = None, max_frequency: float | None = None, max_modes: int = 200,
          mesh: Any = None, resolution: int | str | AutoResolution | None = None,
          voxel: VoxelOptions | dict | None = None, fix=None, fix_vertices=None, element: str = DEFAULT_ELEMENT,
          lumped: bool = False, damping: Damping | float | None = None, eigen: EigenOptions | str | None = None,
          keep_rigid: bool = False, keep_lattice: bool = False, progress: bool = False) -> ModalBasis:
    """Vibration modes of a model, baked onto its source mesh.

    Parameters
    ----------
    model : Scene, CubeModel or mesh-like
        A :class:`~sc_fem.Scene` (mesh, lattice and fixed nodes together; then ``mesh``, ``fix``,
        ``fix_vertices``, ``resolution`` and ``voxel`` are not given), a lattice, or anything
        :func:`sc_fem.load_mesh` accepts (then voxelized with ``resolution`` and ``voxel``).
    n_modes : int, optional
        Number of (elastic) modes. Default :data:`DEFAULT_N_MODES` unless ``max_frequency`` is given.
    max_frequency : float, optional
        Keep all modes below this frequency, Hz (at most ``n_modes`` when both are given).
    max_modes : int
        Upper limit on the elastic modes returned (``eigen["truncated"]`` says when it cut the
        ``max_frequency`` or ``n_modes`` request short).
    mesh : mesh-like, optional
        Source mesh to bake onto when ``model`` is a :class:`CubeModel`; without it the modes are
        given at the lattice nodes (``vertices = model.nodes``, no faces).
    resolution : int, "auto" or AutoResolution, optional
        Grid for a mesh-like ``model`` (cubes along the longest axis; default 32). ``"auto"`` or
        :class:`~sc_fem.modes.options.AutoResolution` (``resolutions``, ``tolerance``): the
        coarsest grid whose first ``n_modes`` frequencies (or those below ``max_frequency``)
        agree with the next finer grid.
    voxel : VoxelOptions or dict, optional
        How a mesh-like ``model`` is voxelized (:class:`~sc_fem.lattice.options.VoxelOptions`:
        ``scale``, ``youngs``, ``fill``, ...).
    fix : str, FixSpec, callable or list, optional
        Fixed nodes (:func:`sc_fem.fem.boundary.fixed_nodes`), e.g. ``"z<min+0.01"``;
        ``"default"`` = a built-in model's supports.
    fix_vertices : array_like of int, optional
        Source-mesh vertex indices whose cubes are fixed (needs a mesh).
    element : {"q1i", "q1", "q1sri"}
        Element type.
    lumped : bool
        Lumped instead of consistent mass.
    damping : float, array_like (k,) or Damping, optional
        Modal damping ratio(s), or :class:`~sc_fem.modes.options.Damping` (e.g. Rayleigh);
        default :data:`~sc_fem.modes.options.DEFAULT_DAMPING_RATIO`.
    eigen : EigenOptions or str, optional
        Eigensolver options (:class:`~sc_fem.fem.eigen.EigenOptions`: ``solver``, ``backend``,
        ``max_memory``) or just the solver's name (``"lobpcg"``). ``"auto"`` (default) takes the
        one predicted faster on this machine whose memory fits (the reason is in
        ``eigen["reason"]`` of the result).
    keep_rigid : bool
        Keep rigid-body modes (flagged in ``rigid``) instead of removing them.
    keep_lattice : bool
        Keep the lattice and the node modes in the result.
    progress : bool
        Print stage messages to stderr.

    Returns
    -------
    ModalBasis

    Raises
    ------
    InputError
        Bad arguments (e.g. ``resolution="auto"`` with a :class:`CubeModel`).
    SolverError
        The eigensolver failed or the problem does not fit in memory.
    """
    from ..scene import Scene

    req = ModalRequest(n_modes=n_modes, max_frequency=max_frequency, max_modes=max_modes, element=element,
                       lumped=lumped, damping=damping, eigen=eigen, keep_rigid=keep_rigid,
                       keep_lattice=keep_lattice, progress=progress)
    if isinstance(model, (Scene, CubeModel)):
        given = [k for k, v in (("resolution", resolution), ("voxel", voxel)) if v is not None]
        if isinstance(model, Scene):
            given += [k for k, v in (("mesh", mesh), ("fix", fix), ("fix_vertices", fix_vertices)) if v is not None]
        if given:
            raise InputError(f"a {type(model).__name__} already has its grid{' and fixed nodes' if isinstance(model, Scene) else ''}: "
                             f"do not pass {', '.join(given)} (pass the mesh as model= to voxelize it)")
        scene = model if isinstance(model, Scene) else Scene.from_model(model, mesh, fix=fix, fix_vertices=fix_vertices)
        return finish(solve_scene(scene, req), req, {})
    if mesh is not None:
        raise InputError("mesh= is only used with a CubeModel; pass the mesh as model=")
    from ..geometry.mesh import load_mesh

    vopts = VoxelOptions.coerce(voxel)
    resolution = parse_resolution(resolution)
    t0 = time.perf_counter()
    src_mesh = load_mesh(model)
    timings = {"load": time.perf_counter() - t0}
    if isinstance(resolution, AutoResolution):
        from .auto import modal_auto

        return modal_auto(src_mesh, resolution, vopts, req, fix=fix, fix_vertices=fix_vertices, timings=timings)
    if resolution is not None:
        if vopts.resolution not in (None, resolution) or vopts.pitch is not None:
            raise InputError(f"resolution={resolution} contradicts voxel options {vopts!r}")
        vopts = vopts.replace(resolution=resolution)
    t0 = time.perf_counter()
    scene = Scene.from_mesh(src_mesh, vopts, fix=fix, fix_vertices=fix_vertices)
    timings["voxelize"] = time.perf_counter() - t0
    _log(f"  voxelized: {scene.model.n_cubes} cubes, {scene.model.n_dofs} DOFs", progress)
    return finish(solve_scene(scene, req), req, timings)
