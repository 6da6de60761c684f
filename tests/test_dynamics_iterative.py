"""Implicit time integration with CG + AMG (``solver="cg-amg"``): the same trajectories as the direct
solve, the automatic choice, and a clear error (never a silent wrong answer) when CG does not converge.

"Same": the largest displacement difference over the run, relative to the largest displacement of
the direct run, below 1e-6 over at least 1 s of simulated time (0.5 s with contact)."""

from __future__ import annotations

import numpy as np
import pytest

from sc_fem import Scene
from sc_fem.dynamics import make_integrator
from sc_fem.dynamics.contact import Contact, Ground
from sc_fem.dynamics.loads import Gravity, LoadSet
from sc_fem.dynamics.newmark import Newmark
from sc_fem.errors import SolverError
from sc_fem.fem import options
from sc_fem.fem.options import DynamicOptions
from sc_fem.lattice.boundary import fixed_nodes
from sc_fem.lattice.cubes import CubeModel

G = (0.0, 0.0, -9.81)


def history(integ, n: int) -> np.ndarray:
    """Node displacements (n + 1, m, 3), m, of ``n`` steps of ``integ``."""
    return np.array([integ.state.u] + [integ.step().u for _ in range(n)])


def rel_diff(a: np.ndarray, b: np.ndarray) -> float:
    """Largest node-displacement difference over the run / largest displacement of ``b``."""
    return float(np.abs(a - b).max() / np.abs(b).max())


def both(make, n: int) -> tuple[np.ndarray, np.ndarray, object]:
    """Histories with the direct solve and with CG + AMG, and the CG integrator."""
    d = make("direct")
    c = make("cg-amg")
    hd, hc = history(d, n), history(c, n)
    assert d.info["linear_solver"] == "direct" and c.info["linear_solver"] == "cg-amg"
    return hd, hc, c


def cantilever(n=24, k=4, pitch=0.025):
    m = CubeModel.box((n, k, k), pitch, youngs=1e7, poisson=0.3, density=1000.0)
    return m, fixed_nodes(m, "x<min+0")


def test_cantilever_under_gravity_equals_the_direct_solve_over_1_s():
    m, fx = cantilever()
    ld = LoadSet(m, [Gravity(G)])
    hd, hc, c = both(lambda s: Newmark(m, 5e-3, fixed_nodes=fx, loads=ld, solver=s), 200)
    assert len(c.effective_solver(None)._amg.levels) >= 2            # a real hierarchy, not one dense solve
    assert np.abs(hd).max() > 1e-3                                  # it sags (m)
    assert rel_diff(hc, hd) < 1e-6
    assert 0 < c.info["cg_iterations"] <= 200 * 20 and c.info["amg_setups"] == 1


def test_free_floating_model_equals_the_direct_solve():
    """No fixed node: S = M / (beta dt^2) + K is SPD all the same; the rigid modes are the AMG's
    near-null space. Thrown spinning under gravity, with an impulse that sets it ringing."""
    m = CubeModel.box((20, 5, 4), 0.025, youngs=1e6, poisson=0.3, density=1000.0)
    c0 = m.nodes_m.mean(axis=0)
    v0 = np.cross([0.0, 0.0, 3.0], m.nodes_m - c0) + [0.5, 0.0, 2.0]     # spin 3 rad/s, thrown up
    J = np.zeros((m.n_nodes, 3))
    J[np.argmax(m.nodes_m[:, 0]), 2] = 0.05                             # N s at a corner
    ld = LoadSet(m, [Gravity(G)])

    def make(s):
        integ = Newmark(m, 5e-3, loads=ld, v0=v0, solver=s)
        integ.set_velocity_from_impulse(J)
        return integ

    hd, hc, _ = both(make, 200)
    assert rel_diff(hc, hd) < 1e-6


def test_thin_walled_multi_part_model_equals_the_direct_solve():
    """The chair (thin legs and seat) held at its feet, plus a loose part: two bodies."""
    scene = Scene.from_mesh("builtin:chair", resolution=16, fix="default")
    m = scene.model
    ld = LoadSet(m, [Gravity(G)])
    hd, hc, _ = both(lambda s: Newmark(m, 5e-3, fixed_nodes=scene.fixed_nodes, loads=ld, solver=s), 200)
    assert rel_diff(hc, hd) < 1e-6


def test_two_separate_plates_equal_the_direct_solve():
    a = np.stack(np.meshgrid(np.arange(16), np.arange(8), np.arange(1), indexing="ij"), -1).reshape(-1, 3)
    cells = np.vstack([a, a + [0, 0, 3]])
    m = CubeModel.from_cells(cells, origin=(0, 0, 0), pitch=0.02, mass=0.02**3 * 1000.0, youngs=2e6, poisson=0.3,
                             density=1000.0)
    fx = fixed_nodes(m, "x<min+0")
    ld = LoadSet(m, [Gravity(G)])
    hd, hc, _ = both(lambda s: Newmark(m, 5e-3, fixed_nodes=fx, loads=ld, solver=s), 200)
    assert rel_diff(hc, hd) < 1e-6


def test_drop_on_the_floor_with_projected_contact_equals_the_direct_solve():
    """Newmark with the vertices projected out of the ground after each step: the same effective
    solve, plus the consistent mass's solve wherever a projection restarts the step."""
    m = CubeModel.box((16, 6, 4), 0.025, youngs=1e6, poisson=0.3, density=1000.0)
    pts = m.nodes / 1.0
    ground = Ground(float(pts[:, 2].min()) - 0.01)

    def make(s):
        return Newmark(m, 2.5e-3, loads=LoadSet(m, [Gravity(G)]), contact=Contact(m, pts, [ground]), solver=s)

    hd, hc, c = both(make, 200)
    assert c.max_contact_depth < 1e-6 and np.abs(hd[:, :, 2]).max() > 0.009    # it reached the ground
    assert rel_diff(hc, hd) < 1e-6


def test_drop_with_barrier_contact_newton_steps_equals_the_direct_solve():
    """IPC: the Newton steps with contact solve their Hessians by CG preconditioned with an earlier
    Hessian's AMG hierarchy (set up again when CG slows); 0.5 s, the block lands and settles."""
    pytest.importorskip("ipctk")
    from sc_fem.dynamics.ipc import IPC

    m = CubeModel.box((12, 6, 4), 0.025, youngs=1e6, poisson=0.3, density=1000.0)
    scene = Scene.from_model(m)
    V = scene.rest_vertices
    z0 = float(V[:, 2].min()) - 0.01

    def make(s):
        contact = IPC.contact_for(m, V, scene.faces, [Ground(z0)], W=scene.W, friction=0.0)
        return make_integrator("ipc", m, 1e-2, loads=LoadSet(m, [Gravity(G)]), contact=contact, solver=s)

    hd, hc, c = both(make, 50)
    assert c.info["contact_steps"] > 10 and c.info["amg_setups"] >= 1
    assert rel_diff(hc, hd) < 1e-6


def test_corotational_cg_amg_equals_the_direct_solve():
    m, fx = cantilever(16, 3, 0.05)
    ld = LoadSet(m, [Gravity((0.0, 0.0, -200.0))])                       # large deflection: rotations change
    hd, hc, c = both(lambda s: make_integrator("corotational", m, 5e-3, fixed_nodes=fx, loads=ld, solver=s), 30)
    assert c.info["amg_setups"] >= 1
    assert rel_diff(hc, hd) < 1e-6


def test_undamped_energy_is_conserved_as_with_the_direct_solve():
    """Average acceleration conserves 1/2 v.Mv + 1/2 u.Ku exactly with exact solves; with CG it stays
    within the bound tests/test_newmark.py sets for the direct path (1e-8 of the energy)."""
    m, fx = cantilever(24, 4)
    tip = np.flatnonzero(m.node_index[:, 0] == 24)
    J = np.zeros((m.n_nodes, 3))
    J[tip, 2] = 1e-3
    for s in ("direct", "cg-amg"):
        integ = Newmark(m, 2e-3, fixed_nodes=fx, solver=s)
        integ.set_velocity_from_impulse(J)
        e0 = integ.energy().total
        e = np.array([(integ.step(), integ.energy().total)[1] for _ in range(500)])
        assert np.max(np.abs(e - e0)) / e0 < 1e-8, s
        assert integ.energy().elastic > 1e-3 * e0


def test_auto_picks_direct_below_the_threshold_and_cg_above(monkeypatch):
    m, fx = cantilever()
    small = Newmark(m, 5e-3, fixed_nodes=fx, loads=LoadSet(m, [Gravity(G)]))
    small.step()
    assert small.info["linear_solver"] == "direct"
    assert f"< {options.DYNAMIC_CG_MIN_DOFS:,}" in small.info["solver_reason"]
    monkeypatch.setattr(options, "DYNAMIC_CG_MIN_DOFS", 1000)
    large = Newmark(m, 5e-3, fixed_nodes=fx, loads=LoadSet(m, [Gravity(G)]))
    large.step()
    assert large.info["linear_solver"] == "cg-amg" and ">= 1,000" in large.info["solver_reason"]
    assert options.choose_dynamic_solver(10, 100, "cg-amg") == ("cg-amg", "requested")


def test_explicit_cg_that_does_not_converge_is_a_clear_error():
    m, fx = cantilever()
    with pytest.raises(SolverError, match=r"relative residual .* > tol 1e-14 after \d+ iterations; use solver="):
        Newmark(m, 5e-3, fixed_nodes=fx, loads=LoadSet(m, [Gravity(G)]),
                solver=DynamicOptions(solver="cg-amg", maxiter=2, tol=1e-14)).step()
    # the effective matrix's own solve (lumped mass: no mass solve before it)
    with pytest.raises(SolverError, match=r"did not converge on the 1,800-DOF system"):
        Newmark(m, 5e-3, fixed_nodes=fx, loads=LoadSet(m, [Gravity(G)]), lumped=True,
                solver=DynamicOptions(solver="cg-amg", maxiter=2, tol=1e-14)).step()


def test_auto_falls_back_to_the_direct_solve_when_cg_does_not_converge(monkeypatch):
    m, fx = cantilever()
    ld = LoadSet(m, [Gravity(G)])
    monkeypatch.setattr(options, "DYNAMIC_CG_MIN_DOFS", 1000)
    monkeypatch.setattr(options, "DYNAMIC_CG_ITERATIONS", 2)
    auto = Newmark(m, 5e-3, fixed_nodes=fx, loads=ld, solver=DynamicOptions(tol=1e-12))
    ha = history(auto, 20)
    assert auto.info["linear_solver"] == "direct" and "solved directly" in auto.info["solver_reason"]
    hd = history(Newmark(m, 5e-3, fixed_nodes=fx, loads=ld, solver="direct"), 20)
    assert rel_diff(ha, hd) < 1e-9


def test_solver_options_are_checked():
    with pytest.raises(Exception, match="must be one of"):
        DynamicOptions(solver="pcg")
    with pytest.raises(Exception, match="solver must be a DynamicOptions"):
        DynamicOptions.coerce(3)
    assert DynamicOptions.coerce("cg-amg").solver == "cg-amg"


def test_mass_solver_equals_the_factorization_and_falls_back_when_cg_fails(monkeypatch):
    """The consistent-mass solve of the initial acceleration (CG on the diagonal-scaled mass) equals
    a factorization's on a model with partial cubes; when CG cannot converge (its iteration limit
    forced to 2) the fallback factorization takes over and the answer is still exact."""
    import sc_fem
    from sc_fem.fem import linsolve

    m = sc_fem.voxelize("builtin:chair", resolution=16)
    M = sc_fem.Assembler(m, "q1i").mass()
    b = np.random.default_rng(3).standard_normal(M.shape[0])
    ref = linsolve.factorize(M).solve(b)
    ms = linsolve.MassSolver(M, lambda: linsolve.factorize(M))
    np.testing.assert_allclose(ms.solve(b), ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    assert ms.stats["iterations"] > 0 and not ms.stats["fallback"]
    monkeypatch.setitem(linsolve.MASS_CG, "maxiter", 2)
    ms = linsolve.MassSolver(M, lambda: linsolve.factorize(M))
    np.testing.assert_allclose(ms.solve(b), ref, rtol=0, atol=1e-10 * np.abs(ref).max())
    assert ms.stats["fallback"]


def test_newmark_initial_acceleration_falls_back_to_a_factorization_in_the_options_backend(monkeypatch):
    """Through Newmark (consistent mass, gravity): the initial acceleration by CG equals the one by
    the fallback when CG is starved (2 iterations), the fallback is a factorization in the backend
    the solver options name (not CG + AMG again), and that backend is the integrator's for every
    direct solve."""
    from sc_fem.fem import linsolve

    m, fixed = cantilever()
    make = lambda: Newmark(m, 1e-3, fixed_nodes=fixed, loads=LoadSet(m, [Gravity(G)]),  # noqa: E731
                           solver=DynamicOptions(solver="cg-amg", backend="splu"))
    ref = make()
    assert ref.backend == "splu" and not ref._mass_solver.stats["fallback"]
    monkeypatch.setitem(linsolve.MASS_CG, "maxiter", 2)
    starved = make()
    assert starved._mass_solver.stats["fallback"]
    assert isinstance(starved._mass_solver._direct, linsolve.Factorization)
    assert starved._mass_solver._direct.backend == "splu"
    np.testing.assert_allclose(starved._a, ref._a, rtol=0, atol=1e-9 * np.abs(ref._a).max())


def test_auto_keeps_iterating_when_the_factorization_does_not_fit(monkeypatch):
    """``"auto"`` caps CG at DYNAMIC_CG_ITERATIONS only when a direct solve can take over; when the
    factorization does not fit in memory, CG keeps the full ``maxiter`` (no way out but on)."""
    A = CubeModel.box((6, 3, 3), 0.05, youngs=1e7, poisson=0.3, density=1000.0)
    from sc_fem.fem.assemble import Assembler

    K = Assembler(A, "q1i", fixed_dofs=np.arange(3 * 16)).stiffness()
    opts = DynamicOptions(solver="auto", maxiter=777)
    assert opts.solver_for(K).maxiter == min(777, options.DYNAMIC_CG_ITERATIONS)
    monkeypatch.setattr(options, "memory_budget", lambda max_memory=None: 1.0)      # nothing fits
    tight = opts.solver_for(K)
    assert tight.kind == "cg-amg" and tight.fallback is None and tight.maxiter == 777
