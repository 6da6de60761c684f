"""Static solves and the linear solver: cantilever vs converged 3-D values, convergence, floating models."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from sc_fem.fem.assemble import Assembler
from sc_fem.lattice.boundary import fixed_dofs, fixed_nodes
from sc_fem.errors import InputError, SolverError
from sc_fem.lattice.cubes import CubeModel
from sc_fem.fem.linsolve import available_backends, factorize
from sc_fem import solve_static

# steel cantilever L = 1 m, 0.1 x 0.1 m, clamped at x = 0; converged 3-D answers (27-node
# elements extrapolated to zero size): first frequency and tip deflection under 1 kN
F1_REF, TIP_REF, LOAD = 81.26, 2.002e-4, 1000.0


def cantilever(t: int) -> CubeModel:
    return CubeModel.box((10 * t, t, t), 0.1 / t, youngs=200e9, poisson=0.3, density=7850.0)


def tip_weights(model: CubeModel, t: int) -> np.ndarray:
    """Work-equivalent nodal weights of a uniform traction on the tip face (sum 1)."""
    j, k = model.node_index[:, 1], model.node_index[:, 2]
    w = np.where((j == 0) | (j == t), 0.5, 1.0) * np.where((k == 0) | (k == t), 0.5, 1.0)
    w = w * (model.node_index[:, 0] == 10 * t)
    return w / w.sum()


def cantilever_errors(t: int, element: str) -> tuple[float, float]:
    """Relative errors of (tip deflection, first frequency)."""
    model = cantilever(t)
    w = tip_weights(model, t)
    F = np.zeros((model.n_nodes, 3))
    F[:, 2] = -LOAD * w
    res = solve_static(model, element=element, fix="x<min+0", forces=F)
    tip = -np.sum(w * res.displacements[:, 2])
    A = Assembler(model, element, fixed_dofs=fixed_dofs(fixed_nodes(model, "x<min+0")))
    K, M = A.stiffness(), A.mass()
    fac = factorize(K)
    op = sla.LinearOperator(K.shape, matvec=fac.solve, dtype=float)
    lam = sla.eigsh(K, k=2, M=M, sigma=0.0, OPinv=op, return_eigenvectors=False).min()
    f1 = np.sqrt(lam) / (2 * np.pi)
    return tip / TIP_REF - 1.0, f1 / F1_REF - 1.0


@pytest.mark.parametrize("t", [1, 2])
def test_default_element_accurate_in_bending(t):
    e_tip, e_f = cantilever_errors(t, "q1i")
    assert abs(e_tip) < 0.02 and abs(e_f) < 0.02, (e_tip, e_f)


def test_q1sri_within_two_percent_at_two_cubes():
    e_tip, e_f = cantilever_errors(2, "q1sri")
    assert abs(e_tip) < 0.02 and abs(e_f) < 0.02, (e_tip, e_f)


def test_q1_shear_locks_with_one_cube():
    e_tip, e_f = cantilever_errors(1, "q1")
    assert e_tip < -0.25 and e_f > 0.15               # far too stiff


def test_q1_converges_at_second_order():
    errs = np.array([cantilever_errors(t, "q1") for t in (2, 4, 8)])   # (3, 2)
    assert np.all(np.abs(errs[1:]) < np.abs(errs[:-1]))
    ratios = np.abs(errs[:-1] / errs[1:])
    # energy-type quantities of Q1 converge as h^2: error ratio -> 4 per halving
    assert np.all(ratios[1] > 3.3) and np.all(ratios[1] < 4.7), ratios
    assert abs(errs[-1, 1]) < 0.01


def test_gravity_cantilever_matches_beam_theory():
    t = 2
    model = cantilever(t)
    res = solve_static(model, element="q1i", fix="x<min+0", gravity=[0, 0, -9.81])
    assert np.allclose(res.forces.sum(0), [0, 0, -9.81 * model.total_mass], rtol=1e-12)
    w = tip_weights(model, t)
    tip = -np.sum(w * res.displacements[:, 2])
    q = 7850 * 0.01 * 9.81
    eb = q * 1.0**4 / (8 * 200e9 * 0.1**4 / 12)        # Euler-Bernoulli q L^4 / (8 E I)
    assert tip == pytest.approx(eb, rel=0.02)
    assert res.residual < 1e-10 and res.backend in available_backends()
    assert set(res.timings) == {"assemble", "factorize", "solve"}


def test_point_forces_and_vertex_displacements():
    model = CubeModel.box((6, 2, 2), 0.05, youngs=1e9, poisson=0.25)
    node = int(np.flatnonzero(np.all(model.node_index == [6, 2, 2], axis=1))[0])
    pts = np.array([model.nodes[node], [0.13, 0.05, 0.07], [0.3, 0.1, 0.1]])
    pf = np.array([[0, 0, -5.0], [0, 0, 0], [0, 0, 0]])
    r1 = solve_static(model, fix="x<min+0", point_forces=pf, points=pts)
    F = np.zeros((model.n_nodes, 3))
    F[node] = [0, 0, -5.0]
    r2 = solve_static(model, fix="x<min+0", forces=F)
    assert np.allclose(r1.displacements, r2.displacements, rtol=0, atol=1e-12 * r2.max_displacement)
    assert np.allclose(r1.vertex_displacements[0], r2.displacements[node], rtol=1e-12)
    # a point inside a cube gets the trilinear interpolation of its cube's node displacements
    from sc_fem.lattice.embed import embed

    W = embed(model, pts)
    assert np.allclose(r1.vertex_displacements, W @ r1.displacements, rtol=1e-13)
    assert r1.compliance == pytest.approx(5.0 * -r2.displacements[node, 2], rel=1e-12)


def test_fix_vertices_with_mesh():
    model = CubeModel.box((6, 2, 2), 0.05, youngs=1e9, poisson=0.25)
    V = np.array([[0.01, 0.01, 0.01], [0.01, 0.09, 0.09], [0.01, 0.05, 0.02], [0.29, 0.05, 0.05]])
    Fc = np.array([[0, 1, 2], [1, 2, 3]])
    pf = np.zeros((4, 3))
    pf[3] = [0, -2.0, 0]
    res = solve_static(model, mesh=(V, Fc), fix_vertices=[0, 1, 2], point_forces=pf)
    assert res.vertex_displacements.shape == (4, 3)
    assert np.all(res.displacements[res.fixed_nodes] == 0)
    assert res.vertex_displacements[3, 1] < 0 and np.abs(res.vertex_displacements[:3]).max() == 0


def test_floating_model_under_load_is_a_clear_error():
    model = CubeModel.box((3, 2, 2), 0.1)
    F = np.zeros((model.n_nodes, 3))
    F[-1] = [0, 0, 10.0]
    with pytest.raises(SolverError, match="floating"):
        solve_static(model, forces=F)
    with pytest.raises(SolverError, match="floating"):
        solve_static(model, gravity=[0, 0, -9.81])
    # fixed nodes on one line leave a rotation free
    with pytest.raises(SolverError, match="rigid motion"):
        solve_static(model, fix="x<min+0 & y<min+0", forces=F)
    # no load, no support: every node is an unloaded floating node, held at zero
    res = solve_static(model)
    assert res.n_floating_nodes == model.n_nodes and len(res.fixed_nodes) == 0
    assert np.all(res.displacements == 0)


def test_unloaded_floating_part_is_held_loaded_one_is_an_error():
    cells = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [5, 0, 0]])   # a 3-cube bar and a loose cube
    model = CubeModel.from_cells(cells, origin=(0, 0, 0), pitch=0.1, mass=1.0, youngs=1e9, poisson=0.3,
                                 density=1000.0)
    F = np.zeros((model.n_nodes, 3))
    bar_tip = np.flatnonzero(model.node_index[:, 0] == 3)
    F[bar_tip, 2] = -1.0
    res = solve_static(model, fix="x<min+0", forces=F)
    assert res.n_floating_nodes == 8
    assert np.all(res.displacements[model.node_index[:, 0] >= 5] == 0)
    assert res.displacements[bar_tip, 2].max() < 0
    with pytest.raises(SolverError, match="floating"):
        solve_static(model, fix="x<min+0", gravity=[0, 0, -9.81])


@pytest.mark.parametrize("backend", available_backends())
def test_linsolve_backends(backend):
    model = CubeModel.box((4, 2, 2), 0.1)
    A = Assembler(model, "q1i", fixed_dofs=fixed_dofs(fixed_nodes(model, "x<min+0")))
    K = A.stiffness()
    rng = np.random.default_rng(0)
    B = rng.normal(size=(K.shape[0], 3))
    fac = factorize(K, backend)
    assert fac.backend == backend
    X = fac.solve(B)
    assert np.abs(K @ X - B).max() < 1e-9 * np.abs(B).max()
    assert np.allclose(fac.solve(B[:, 1]), X[:, 1], rtol=1e-12, atol=0)
    with pytest.raises(InputError, match="shape"):
        fac.solve(B[:-1])
    # singular (floating) and indefinite matrices
    Kfree = Assembler(model, "q1i").stiffness()
    with pytest.raises(SolverError, match="singular|positive definite"):
        factorize(Kfree, backend)
    with pytest.raises(SolverError, match="positive definite|singular"):
        factorize(-K, backend)


def test_linsolve_bad_input():
    with pytest.raises(InputError, match="backend"):
        factorize(sp.eye(3, format="csr"), "mumps")
    with pytest.raises(InputError, match="square"):
        factorize(sp.csr_matrix(np.ones((2, 3))))
    with pytest.raises(InputError, match="scipy.sparse"):
        factorize(np.eye(3))
