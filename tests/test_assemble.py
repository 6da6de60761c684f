"""Global assembly: fast scatter vs scikit-fem and vs a loop oracle; mass; patch test; re-assembly."""

from __future__ import annotations

import numpy as np
import pytest

from sc_fem.fem.assemble import Assembler, assemble
from sc_fem.lattice.boundary import fixed_dofs
from sc_fem.fem.elements import element_stiffness, reference_mass
from sc_fem.errors import InputError
from sc_fem.lattice.cubes import CubeModel
from sc_fem.fem.linsolve import factorize


def random_model(shape, seed, fill=0.7, pitch=0.05, scale=2.0):
    """An irregular lattice (random cubes of a box) with random per-cube materials and masses."""
    rng = np.random.default_rng(seed)
    occ = rng.random(shape) < fill
    occ[0, 0, 0] = True
    cells = np.argwhere(occ)
    n = len(cells)
    return CubeModel.from_cells(cells, origin=(0.3, -1.0, 2.0), pitch=pitch, scale=scale,
                                mass=rng.uniform(0.5, 2.0, n), youngs=rng.uniform(1e8, 3e11, n),
                                poisson=rng.uniform(-0.2, 0.48, n), density=1000.0)


def rel_err(A, B):
    return abs(A - B).max() / abs(B).max()


def loop_oracle(model, element, fixed=None):
    """Dense K and consistent M by a Python loop over cubes (slow, independent of the scatter)."""
    lam, mu = model.lame()
    nd = model.n_dofs
    K, M = np.zeros((nd, nd)), np.zeros((nd, nd))
    mref = reference_mass()
    for e in range(model.n_cubes):
        dofs = (3 * model.hexes[e][:, None] + np.arange(3)).ravel()
        K[np.ix_(dofs, dofs)] += element_stiffness(element, [lam[e]], [mu[e]], model.h)[0]
        M[np.ix_(dofs, dofs)] += model.mass[e] * mref
    if fixed is not None:
        free = np.setdiff1d(np.arange(nd), fixed)
        K, M = K[np.ix_(free, free)], M[np.ix_(free, free)]
    return K, M


@pytest.mark.parametrize("element", ["q1", "q1sri"])
@pytest.mark.parametrize("shape,seed", [((1, 1, 1), 0), ((3, 2, 2), 1), ((5, 4, 3), 2), ((9, 7, 6), 3)])
def test_fast_equals_skfem(element, shape, seed):
    model = random_model(shape, seed)
    Kf, Mf = assemble(model, element)
    Ks, Ms = assemble(model, element, method="skfem")
    assert Kf.shape == Ks.shape == (model.n_dofs,) * 2
    assert rel_err(Kf, Ks) < 1e-12
    assert rel_err(Mf, Ms) < 1e-12
    Kl, Ml = assemble(model, element, lumped=True)
    _, Msl = assemble(model, element, lumped=True, method="skfem")
    assert rel_err(Ml, Msl) < 1e-12
    assert rel_err(Kl, Kf) == 0                       # lumping changes M only
    np.testing.assert_allclose(Ml.diagonal().reshape(-1, 3).sum(axis=0), model.total_mass, rtol=1e-12)


@pytest.mark.parametrize("element", ["q1", "q1sri"])
def test_fast_equals_skfem_with_fixed_dofs(element):
    model = random_model((6, 5, 4), 7)
    rng = np.random.default_rng(0)
    fixed = rng.choice(model.n_dofs, model.n_dofs // 5, replace=False)   # arbitrary single DOFs
    Kf, Mf = assemble(model, element, fixed_dofs=fixed)
    Ks, Ms = assemble(model, element, fixed_dofs=fixed, method="skfem")
    assert Kf.shape == (model.n_dofs - len(fixed),) * 2
    assert rel_err(Kf, Ks) < 1e-12 and rel_err(Mf, Ms) < 1e-12


@pytest.mark.parametrize("element", ["q1i", "q1", "q1sri"])
def test_fast_equals_loop_oracle(element):
    model = random_model((4, 3, 3), 11)
    fixed = fixed_dofs([0, 5, 9])
    K, M = assemble(model, element, fixed_dofs=fixed)
    Ko, Mo = loop_oracle(model, element, fixed)
    assert rel_err(K.toarray(), Ko) < 1e-12 and rel_err(M.toarray(), Mo) < 1e-12
    K.check_format(full_check=True)
    assert K.has_sorted_indices


def test_skfem_method_rejects_q1i_and_bad_method():
    model = CubeModel.box((1, 1, 1), 1.0)
    with pytest.raises(InputError, match="q1i"):
        assemble(model, "q1i", method="skfem")
    with pytest.raises(InputError, match="method"):
        assemble(model, method="magic")
    with pytest.raises(InputError, match="element"):
        assemble(model, "hex27")
    with pytest.raises(InputError, match="fixed_dofs"):
        assemble(model, fixed_dofs=[24])


def test_reassembly_with_new_materials_and_element_matrices():
    model = random_model((5, 4, 3), 5)
    A = Assembler(model, "q1i", fixed_dofs=fixed_dofs([1, 2]))
    rng = np.random.default_rng(1)
    E2, nu2 = rng.uniform(1e9, 2e9, model.n_cubes), rng.uniform(0.0, 0.45, model.n_cubes)
    K2 = A.stiffness(youngs=E2, poisson=nu2)
    other = CubeModel.from_cells(model.cells, origin=model.origin, pitch=model.pitch, scale=model.scale,
                                 mass=model.mass, youngs=E2, poisson=nu2, density=1000.0)
    K2_ref, _ = assemble(other, "q1i", fixed_dofs=fixed_dofs([1, 2]))
    assert rel_err(K2, K2_ref) < 1e-13
    assert np.array_equal(K2.indices, A.stiffness().indices)

    # per-cube rotated element matrices R K R^T (corotational use) vs a loop oracle
    lam, mu = model.lame()
    Ke = element_stiffness("q1i", lam, mu, model.h)
    q, _ = np.linalg.qr(rng.normal(size=(model.n_cubes, 3, 3)))
    R = np.zeros((model.n_cubes, 24, 24))
    for a in range(8):
        R[:, 3 * a:3 * a + 3, 3 * a:3 * a + 3] = q
    Kr = R @ Ke @ np.swapaxes(R, 1, 2)
    Kasm = A.stiffness(element_matrices=Kr).toarray()
    dense = np.zeros((model.n_dofs,) * 2)
    for e in range(model.n_cubes):
        d = (3 * model.hexes[e][:, None] + np.arange(3)).ravel()
        dense[np.ix_(d, d)] += Kr[e]
    dense = dense[np.ix_(A.free_dofs, A.free_dofs)]
    assert rel_err(Kasm, dense) < 1e-12
    with pytest.raises(InputError, match="element_matrices"):
        A.stiffness(element_matrices=Kr[:-1])


def test_material_and_mass_arguments_are_validated():
    model = random_model((3, 2, 2), 6)
    A = Assembler(model, "q1i")
    n = model.n_cubes
    with pytest.raises(InputError, match=rf"youngs must have shape \({n},\)"):
        A.stiffness(youngs=np.ones(5))
    with pytest.raises(InputError, match="poisson must have shape"):
        A.stiffness(poisson=np.full((n, 2), 0.3))
    with pytest.raises(InputError, match="youngs contains 1 non-finite"):
        A.stiffness(youngs=np.r_[np.nan, np.ones(n - 1)])
    with pytest.raises(InputError, match="masses must have shape"):
        A.mass(masses=np.ones(5))
    with pytest.raises(InputError, match="masses must have shape"):
        model.node_masses(np.ones(n + 1))
    # a scalar material is the same as a uniform per-cube array
    assert rel_err(A.stiffness(youngs=2e9, poisson=0.25),
                   A.stiffness(youngs=np.full(n, 2e9), poisson=np.full(n, 0.25))) == 0
    # explicit per-cube masses reach both mass matrices
    m2 = np.random.default_rng(3).uniform(0.5, 2.0, model.n_cubes)
    Ml = A.mass(lumped=True, masses=m2)
    np.testing.assert_allclose(Ml.diagonal().reshape(-1, 3), np.repeat(model.node_masses(m2)[:, None], 3, 1),
                               rtol=1e-14)
    ex = np.tile([0, 0, 1.0], model.n_nodes)
    assert ex @ (A.mass(masses=m2) @ ex) == pytest.approx(m2.sum(), rel=1e-12)
    assert model.node_masses(m2).sum() == pytest.approx(m2.sum(), rel=1e-12)


@pytest.mark.parametrize("lumped", [False, True])
def test_total_mass_and_rigid_kinetic_energy(lumped):
    model = random_model((6, 5, 4), 9)
    _, M = assemble(model, "q1i", lumped=lumped)
    v = np.array([0.3, -1.2, 2.0])                     # m/s, uniform translation
    V = np.tile(v, model.n_nodes)
    assert 0.5 * V @ (M @ V) == pytest.approx(0.5 * model.total_mass * v @ v, rel=1e-12)
    ex = np.tile([1.0, 0, 0], model.n_nodes)
    assert ex @ (M @ ex) == pytest.approx(model.total_mass, rel=1e-12)
    if lumped:
        assert np.allclose(M.diagonal().reshape(-1, 3)[:, 0], model.node_masses(), rtol=1e-14)


def test_consistent_mass_shares_stiffness_pattern():
    model = random_model((4, 4, 2), 4)
    A = Assembler(model, "q1")
    K, M = A.stiffness(), A.mass()
    assert np.array_equal(K.indptr, M.indptr) and np.array_equal(K.indices, M.indices)


@pytest.mark.parametrize("element", ["q1", "q1i", "q1sri"])
def test_global_invariants_symmetric_psd_six_zero_modes(element):
    model = random_model((3, 3, 2), 6)
    model = model.subset(model.component == 0)
    K = assemble(model, element)[0].toarray()
    assert rel_err(K, K.T) < 1e-15
    ev = np.linalg.eigvalsh(K)
    tol = 1e-10 * ev[-1]
    assert ev[0] > -tol
    assert np.count_nonzero(np.abs(ev) < tol) == 6
    X = model.nodes_m - model.nodes_m.mean(0)
    for w in np.eye(3):                                    # K . rotations = 0
        u = np.cross(w, X).ravel()
        assert np.abs(K @ u).max() < 1e-10 * ev[-1] * np.abs(u).max()


@pytest.mark.parametrize("element", ["q1", "q1i", "q1sri"])
def test_patch_test_linear_field_reproduced(element):
    """Prescribe a linear displacement on the boundary of a 3x3x3 block, solve the interior."""
    model = CubeModel.box((3, 3, 3), 0.1, youngs=7e10, poisson=0.33)
    rng = np.random.default_rng(2)
    G, c = rng.normal(size=(3, 3)) * 1e-3, rng.normal(size=3) * 1e-3
    X = model.nodes_m
    u_exact = X @ G.T + c
    idx = model.node_index
    boundary = np.any((idx == 0) | (idx == 3), axis=1)
    bd = fixed_dofs(np.flatnonzero(boundary))
    K_full, _ = assemble(model, element)
    A = Assembler(model, element, fixed_dofs=bd)
    K = A.stiffness()
    # K_ff u_f = - K_fb u_b
    ub = np.zeros(model.n_dofs)
    ub[bd] = u_exact.ravel()[bd]
    rhs = -(K_full @ ub)[A.free_dofs]
    uf = factorize(K).solve(rhs)
    assert np.abs(uf - u_exact.ravel()[A.free_dofs]).max() < 1e-10 * np.abs(u_exact).max()
