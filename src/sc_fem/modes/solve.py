"""One lattice's eigenpairs (:func:`solve_scene`) and their baking onto the source mesh (:func:`finish`).

Rigid-body modes (6 per unsupported connected part) are recognised by their frequency
(``omega^2 < RIGID_FRACTION * mean(diag K) / mean(diag M)``, i.e. numerically zero next to the
stiffest element) and removed unless ``keep_rigid=True`` (then flagged in ``ModalBasis.rigid``).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np

from .._log import say
from ..errors import InputError, ScFemWarning
from ..fem.assemble import Assembler
from ..fem.eigen import EigenSolver
from ..fem.choice import choose_element
from ..fem.highorder import DEGREES, HighOrderAssembler, HighOrderCubes
from ..fem.fill import lobpcg_block
from ..fem.rigid import loose_start, rigid_body_modes
from ..fem.multigrid import lattice_aggregates
from ..fem.static import held_parts, node_parts
from ..lattice.cubes import CubeModel
from .basis import ModalBasis
from .options import ModalRequest

DEFAULT_N_MODES = 10
"""Modes computed when neither ``n_modes`` nor ``max_frequency`` is given."""

RIGID_FRACTION = 1e-10
"""A mode is rigid when ``omega^2 < RIGID_FRACTION * lambda_scale`` (``lambda_scale`` =
``mean(diag K) / mean(diag M)``, the order of the highest eigenvalue). Rigid modes come out at
about ``1e-17 .. 1e-16 * lambda_scale`` (round-off); the first elastic (bending) mode of a free
200 x 1 x 1-cube rod (q1i), a very floppy voxel model, is at ``4.6e-9 * lambda_scale`` -- 46x above
the threshold (measured with ``solve_eigen`` on ``CubeModel.box((200, 1, 1), ...)``)."""


def _unsupported_parts(model: CubeModel, labels: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """Connected parts (node ``labels``) whose fixed nodes leave some rigid motion free (each may
    have up to 6)."""
    n_parts = int(labels.max()) + 1
    return np.flatnonzero(~held_parts(model, labels, fixed, n_parts))


@dataclass(frozen=True, eq=False)
class Solved:
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


def solve_scene(scene, req: ModalRequest) -> Solved:
    """Eigenpairs of one lattice; the shifted operator is set up once however often ``k`` grows."""
    model, fixed = scene.model, scene.fixed_nodes
    n_modes, max_frequency, max_modes, progress = req.n_modes, req.max_frequency, req.max_modes, req.progress
    t = {}
    t0 = time.perf_counter()
    element, why, note = choose_element(scene, req.element, lumped=req.lumped)
    if note is not None:
        warnings.warn(note, ScFemWarning, stacklevel=4)
    if element in DEGREES:
        asm = HighOrderAssembler(HighOrderCubes(scene, element))
        nodes_m = asm.nodes_m
    else:
        asm = Assembler(model, element, fixed_dofs=scene.fixed_dofs)
        nodes_m = model.nodes_m
    K = asm.stiffness()
    if isinstance(asm, Assembler):            # M's nonzeros alone; the pattern is K's now, freed with K's CSR
        M = asm.mass(lumped=req.lumped, compact=True)
        asm.release()
    else:
        M = asm.mass(lumped=req.lumped)
    t["assemble"] = time.perf_counter() - t0
    n = K.shape[0]
    if n == 0:
        raise InputError("every node is fixed: no modes to compute")
    labels = node_parts(model)
    loose = _unsupported_parts(model, labels, fixed)
    n_rigid_expected = 6 * len(loose)
    want = DEFAULT_N_MODES if (n_modes is None and max_frequency is None) else n_modes
    lam_max = None if max_frequency is None else (2.0 * np.pi * max_frequency) ** 2
    k_cap = min(n - 1, max_modes + n_rigid_expected + 6)
    k = n_rigid_expected + (want if want is not None else 12)
    t0 = time.perf_counter()
    aggregates = None if element in DEGREES else lattice_aggregates(model, labels, asm.free_dofs)
    near_null = rigid_body_modes(nodes_m, asm.free_dofs)
    # several loose parts of a lattice: LOBPCG starts from each one's rigid motions (as many parts as
    # its block holds; higher-order cubes have nodes of their own, which the part labels do not cover)
    start = (loose_start(nodes_m, labels, loose, lobpcg_block(min(k, k_cap)), asm.free_dofs)
             if element not in DEGREES else None)
    solver = EigenSolver(K, M, method=req.eigen.solver, backend=req.eigen.backend, aggregates=aggregates,
                         near_null=near_null, start=start, max_memory=req.eigen.max_memory,
                         lattice=element not in DEGREES, overwrite=True)
    del K, M                                                      # the solver's now: it frees what it need not keep
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
        say(f"  eigensolve: {k} pairs, {eig.method}/{eig.backend}, {n_el} elastic, "
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
    info = {"element": element, "element_reason": why, "method": eig.method, "backend": eig.backend, "reason": eig.reason, "sigma": eig.sigma,
            "seconds": eig.seconds, "k_computed": int(len(lam)), "passes": passes, "setups": solver.n_setups,
            "n_rigid_expected": n_rigid_expected, "n_rigid_found": int(rigid.sum()), "lambda_scale": scale,
            **eig.info}
    if cut or not done:
        target = f"{max_frequency:g} Hz" if lam_max is not None else f"{want} elastic modes"
        info["truncated"] = f"max_modes={max_modes} (or the model size) reached before {target}"
    return Solved(scene=scene, lam=lam[sel], X=eig.vectors[:, sel], rigid=rigid[sel],
                   res=eig.residuals[sel], n_removed=0 if req.keep_rigid else int(rigid.sum()), asm=asm, info=info,
                   timings=t)


def _bake(asm, X: np.ndarray, W) -> tuple[np.ndarray, np.ndarray]:
    """Node modes (k, m, 3) at the cube corners and vertex modes (k, n, 3) from free-DOF vectors
    (n_free, k): ``W @ phi`` (trilinear cubes) or the higher-order field at the vertices."""
    node = asm.expand(X)                                          # (m, 3, k)
    m, _, k = node.shape
    if isinstance(asm, HighOrderAssembler):
        vert = asm.vertex_field(X, asm.cubes.W)
    else:
        vert = np.asarray(W @ node.reshape(m, 3 * k)).reshape(-1, 3, k)
    return np.ascontiguousarray(node.transpose(2, 0, 1)), np.ascontiguousarray(vert.transpose(2, 0, 1))


def finish(s: Solved, req: ModalRequest, resolution_table: list | None = None) -> ModalBasis:
    """Bake the modes of ``s`` onto its scene's source mesh (or the lattice nodes): the ModalBasis."""
    scene = s.scene
    model = scene.model
    timings = dict(s.timings)
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
        resolution=int(model.info.get("resolution", int(model.dims.max()))), element=s.info["element"],
        material=scene.material_record(), fix_record=scene.fix_record(),
        source=scene.source, source_sha256=scene.sha256, n_cubes=model.n_cubes,
        n_dofs=s.asm.cubes.n_dofs if isinstance(s.asm, HighOrderAssembler) else model.n_dofs, eigen=s.info,
        timings=timings, resolution_table=resolution_table, lattice=model if keep else None,
        node_modes=node_modes if keep else None, fixed_points=model.nodes[scene.fixed_nodes])
