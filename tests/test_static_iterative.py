"""Static solves by CG + AMG: the same displacements as the direct solve, the automatic choice, and
a clear error (never a silent wrong answer) when CG does not converge."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

import sc_fem
from sc_fem.errors import InputError, SolverError
from sc_fem.fem import options
from sc_fem.fem.assemble import Assembler
from sc_fem.fem.bsr import node_blocks
from sc_fem.fem.multigrid import LatticeAMG, pcg
from sc_fem.fem.options import CG_AMG_MIN_DOFS, StaticOptions, choose_static_solver
from sc_fem.fem.rigid import rigid_body_modes
from sc_fem import solve_static
from sc_fem.lattice.boundary import fixed_dofs, fixed_nodes
from sc_fem.lattice.cubes import CubeModel

G = (0.0, 0.0, -9.81)


def rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def two_bars() -> CubeModel:
    """Two separate bodies: a 16 x 3 x 3 steel bar and, 2 cubes away, a softer 12 x 4 x 2 bar with
    a random stiffness per cube; both roots at x = 0."""
    a = np.stack(np.meshgrid(np.arange(16), np.arange(3), np.arange(3), indexing="ij"), -1).reshape(-1, 3)
    b = np.stack(np.meshgrid(np.arange(12), np.arange(4), np.arange(2), indexing="ij"), -1).reshape(-1, 3)
    cells = np.vstack([a, b + [0, 5, 0]])
    E = np.concatenate([np.full(len(a), 200e9), np.random.default_rng(1).uniform(1e9, 5e9, len(b))])
    return CubeModel.from_cells(cells, origin=(0, 0, 0), pitch=0.05, mass=0.05**3 * 7850.0, youngs=E,
                                poisson=0.3, density=7850.0)


def test_cg_amg_equals_direct_on_a_clamped_cantilever():
    model = CubeModel.box((24, 4, 4), 0.025)
    d = solve_static(model, fix="x<min+0", gravity=G, solver="direct")
    c = solve_static(model, fix="x<min+0", gravity=G, solver="cg-amg")
    assert d.solver == "direct" and c.solver == "cg-amg" and c.backend == "pyamg"
    assert len(c.info["levels"]) >= 2                          # a real hierarchy, not one dense solve
    assert rel(c.displacements, d.displacements) < 1e-6
    assert c.residual <= StaticOptions().tol
    assert set(c.timings) == {"assemble", "setup", "solve"}
    assert c.compliance == pytest.approx(d.compliance, rel=1e-8)


def test_cg_amg_equals_direct_with_a_second_clamped_body():
    model = two_bars()
    F = np.zeros((model.n_nodes, 3))
    F[model.node_index[:, 0] == 16, 1] = 25.0                   # a sideways pull on the first bar's tip
    kw = {"fix": "x<min+0", "gravity": G, "forces": F}
    d = solve_static(model, solver="direct", **kw)
    c = solve_static(model, solver="cg-amg", **kw)
    assert rel(c.displacements, d.displacements) < 1e-6
    second = model.node_index[:, 1] >= 5
    assert rel(c.displacements[second], d.displacements[second]) < 1e-6   # the soft body on its own too


def test_cg_amg_on_a_voxelized_mesh_with_partial_cubes():
    scene = sc_fem.Scene.from_mesh("builtin:chair", resolution=16, fix="default")
    d = sc_fem.solve_static(scene, gravity=G, solver="direct")
    c = sc_fem.solve_static(scene, gravity=G, solver=StaticOptions(solver="cg-amg", tol=1e-9))
    assert rel(c.displacements, d.displacements) < 1e-6
    assert rel(c.vertex_displacements, d.vertex_displacements) < 1e-6


def test_unloaded_floating_part_is_held_with_cg_amg_too():
    cells = np.array([[i, j, k] for i in range(10) for j in range(2) for k in range(2)] + [[14, 0, 0]])
    model = CubeModel.from_cells(cells, origin=(0, 0, 0), pitch=0.1, mass=1.0, youngs=1e9, poisson=0.3,
                                 density=1000.0)
    F = np.zeros((model.n_nodes, 3))
    F[model.node_index[:, 0] == 10, 2] = -1.0
    d = solve_static(model, fix="x<min+0", forces=F, solver="direct")
    c = solve_static(model, fix="x<min+0", forces=F, solver="cg-amg")
    assert c.n_floating_nodes == d.n_floating_nodes == 8
    assert np.all(c.displacements[model.node_index[:, 0] >= 14] == 0)
    assert rel(c.displacements, d.displacements) < 1e-6
    with pytest.raises(SolverError, match="floating"):           # loaded and free: before any solve
        solve_static(model, fix="x<min+0", gravity=G, solver="cg-amg")


def test_auto_picks_the_direct_solve_small_and_cg_amg_large():
    small = CubeModel.box((10, 2, 2), 0.05)
    res = solve_static(small, fix="x<min+0", gravity=G)
    assert res.solver == "direct" and "direct" in res.info["reason"]
    nx = int(np.ceil(CG_AMG_MIN_DOFS / (3 * 5 * 5))) + 1          # (nx + 1) x 5 x 5 nodes, one face held
    large = CubeModel.box((nx, 4, 4), 0.02)
    res = solve_static(large, fix="x<min+0", gravity=G)
    assert res.info["levels"][0] >= CG_AMG_MIN_DOFS
    assert res.solver == "cg-amg" and "CG + AMG" in res.info["reason"]
    assert choose_static_solver(CG_AMG_MIN_DOFS - 3, 10**6)[0] == "direct"
    assert choose_static_solver(CG_AMG_MIN_DOFS, 10**6)[0] == "cg-amg"
    assert choose_static_solver(10**6, 10**8, lattice=False)[0] == "direct"     # higher-order cubes
    assert choose_static_solver(100, 10**4, "cg-amg")[0] == "cg-amg"            # requested is kept


def test_auto_follows_the_threshold(monkeypatch):
    model = CubeModel.box((12, 3, 3), 0.05)
    monkeypatch.setattr(options, "CG_AMG_MIN_DOFS", 100)
    assert solve_static(model, fix="x<min+0", gravity=G).solver == "cg-amg"
    monkeypatch.setattr(options, "CG_AMG_MIN_DOFS", 10**9)
    assert solve_static(model, fix="x<min+0", gravity=G).solver == "direct"


def test_cg_that_does_not_converge_is_a_clear_error():
    model = CubeModel.box((24, 4, 4), 0.025)
    with pytest.raises(SolverError, match=r"did not converge: relative residual .* after 1 iterations"):
        solve_static(model, fix="x<min+0", gravity=G, solver=StaticOptions(solver="cg-amg", maxiter=1))


def test_auto_falls_back_to_the_direct_solve_when_cg_does_not_converge(monkeypatch):
    model = CubeModel.box((24, 4, 4), 0.025)
    monkeypatch.setattr(options, "CG_AMG_MIN_DOFS", 100)
    d = solve_static(model, fix="x<min+0", gravity=G, solver="direct")
    res = solve_static(model, fix="x<min+0", gravity=G, solver=StaticOptions(maxiter=1))
    assert res.solver == "direct" and res.info["cg_failed"]["iterations"] == 1
    assert "solved directly instead" in res.info["reason"]
    np.testing.assert_allclose(res.displacements, d.displacements, rtol=0, atol=1e-14)
    with pytest.raises(SolverError, match="did not converge"):   # no room for the factorization
        solve_static(model, fix="x<min+0", gravity=G, solver=StaticOptions(maxiter=1, max_memory=1.0))


def test_auto_solves_directly_when_cg_is_slow_unless_the_factorization_does_not_fit(monkeypatch):
    model = CubeModel.box((24, 4, 4), 0.025)
    monkeypatch.setattr(options, "CG_AMG_MIN_DOFS", 100)
    monkeypatch.setattr(options, "AUTO_CG_ITERATIONS", 3)        # as if the model were all thin cables
    d = solve_static(model, fix="x<min+0", gravity=G, solver="direct")
    res = solve_static(model, fix="x<min+0", gravity=G)
    assert res.solver == "direct" and res.info["cg_failed"]["iterations"] == 3
    assert "too slow" in res.info["reason"]
    res = solve_static(model, fix="x<min+0", gravity=G, solver=StaticOptions(max_memory=1.0))
    assert res.solver == "cg-amg" and res.info["iterations"] > 3     # no room to factorize: CG goes on
    assert len(res.info["residuals"]) == res.info["iterations"]
    assert rel(res.displacements, d.displacements) < 1e-6


def test_higher_order_cubes_on_request():
    scene = sc_fem.Scene.from_mesh("builtin:beam", resolution=8, fix="x<min+1e-9")
    d = sc_fem.solve_static(scene, element="q3", gravity=G)
    assert d.solver == "direct"
    c = sc_fem.solve_static(scene, element="q3", gravity=G, solver="cg-amg")
    assert rel(c.displacements, d.displacements) < 1e-6


def test_options_are_checked():
    model = CubeModel.box((4, 2, 2), 0.05)
    with pytest.raises(InputError, match="static solver"):
        solve_static(model, fix="x<min+0", gravity=G, solver="gmres")
    with pytest.raises(InputError, match="tol"):
        StaticOptions(tol=2.0)
    with pytest.raises(InputError, match="maxiter"):
        StaticOptions(maxiter=0)
    with pytest.raises(InputError, match="disagree"):
        solve_static(model, fix="x<min+0", gravity=G, backend="splu", solver=StaticOptions(backend="cholmod"))
    assert solve_static(model, fix="x<min+0", gravity=G, backend="splu").backend == "splu"


def test_the_preconditioner_is_symmetric_positive_definite_and_node_blocks_are_exact():
    model = CubeModel.box((20, 4, 3), 0.05)
    asm = Assembler(model, "q1i", fixed_dofs=fixed_dofs(fixed_nodes(model, "x<min+0")))
    K = asm.stiffness()
    Kb = node_blocks(K)
    assert Kb.blocksize == (3, 3) and abs(Kb - K).max() == 0.0
    amg = LatticeAMG(K, rigid_body_modes(model.nodes_m, asm.free_dofs))
    rng = np.random.default_rng(0)
    u, v = rng.standard_normal((2, K.shape[0]))
    Mu, Mv = amg.vcycle(u), amg.vcycle(v)
    assert v @ Mu == pytest.approx(u @ Mv, rel=1e-10)
    assert u @ Mu > 0 and v @ Mv > 0
    b = K @ u                                                     # a warm start from the answer: no iteration
    x, info = amg.solve(b, tol=1e-10)
    assert info["converged"] and rel(x, u) < 1e-6
    assert amg.solve(b, tol=1e-10, x0=x)[1]["iterations"] == 0
    # CG on a plain SPD matrix with the identity preconditioner: the textbook case
    A = sp.diags([np.linspace(1.0, 50.0, 200)], [0]).tocsr() + sp.eye(200) * 0.1
    x, info = pcg(lambda p: A @ p, lambda r: r, np.ones(200), tol=1e-12, maxiter=400)
    assert info["converged"] and np.allclose(A @ x, 1.0, rtol=0, atol=1e-10)
