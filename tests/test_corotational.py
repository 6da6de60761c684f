"""Corotational (warped-stiffness) model: oracle, rigid-rotation invariance, large rotations."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.linalg import polar

from sc_fem.fem.elements import element_stiffness
from sc_fem.dynamics import record
from sc_fem.dynamics import corotational as corot_mod
from sc_fem.dynamics.corotational import Corotational
from sc_fem.dynamics.kinematics import cube_rotations, polar_rotation
from sc_fem.dynamics.loads import Gravity, LoadSet
from sc_fem.dynamics.newmark import Newmark
from sc_fem.errors import InputError
from sc_fem.lattice.cubes import HEX_CORNERS, CubeModel
from sc_fem.lattice.moments import EXPONENTS
from sc_fem.scene import Scene


def bar():
    return CubeModel.box((6, 2, 2), 0.05, youngs=1e6, poisson=0.3, density=1000.0)


def mixed_bar(seed=7):
    """The bar with a different (E, nu) in every cube, like a voxelized model."""
    m = bar()
    r = np.random.default_rng(seed)
    return dataclasses.replace(m, youngs=1e6 * (0.5 + r.random(m.n_cubes)), poisson=0.05 + 0.4 * r.random(m.n_cubes))


def rot(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def oracle_force(model, u):
    """Loop over cubes: F at the centre, R = polar(F), f_e = R K_e (R^T x_e - X_e)."""
    lam, mu = model.lame()
    f = np.zeros((model.n_nodes, 3))
    dN = (2.0 * HEX_CORNERS - 1.0) / 4.0 / model.h
    for e in range(model.n_cubes):
        X = model.nodes_m[model.hexes[e]]
        x = X + u[model.hexes[e]]
        F = sum(np.outer(x[a], dN[a]) for a in range(8))
        R, _ = polar(F)
        Ke = element_stiffness("q1i", lam[e:e + 1], mu[e:e + 1], model.h)[0]
        loc = (x @ R - X).ravel()                       # rows R^T x_a
        fe = (Ke @ loc).reshape(8, 3) @ R.T
        for a in range(8):
            f[model.hexes[e, a]] += fe[a]
    return f


def oracle_warped(model, u, element="q1i"):
    """Loop over cubes: R = polar(F) at the centre, block-diagonal R24 (24, 24), R24 K_e R24^T."""
    lam, mu = model.lame()
    dN = (2.0 * HEX_CORNERS - 1.0) / 4.0 / model.h
    out = np.empty((model.n_cubes, 24, 24))
    for e in range(model.n_cubes):
        x = model.nodes_m[model.hexes[e]] + u[model.hexes[e]]
        R, _ = polar(sum(np.outer(x[a], dN[a]) for a in range(8)))
        R24 = np.kron(np.eye(8), R)
        Ke = element_stiffness(element, lam[e:e + 1], mu[e:e + 1], model.h)[0]
        out[e] = R24 @ Ke @ R24.T
    return out


@pytest.mark.parametrize("model", [bar, mixed_bar])
def test_internal_force_matches_loop_oracle(rng, model):
    m = model()
    integ = Corotational(m, 1e-3)
    u = 0.01 * rng.standard_normal((m.n_nodes, 3)) + ((rot([1, 2, 3], 0.7) - np.eye(3)) @ m.nodes_m.T).T
    got = integ.asm.expand(integ.internal_force(integ.asm.restrict(u)))
    want = oracle_force(m, u)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())


@pytest.mark.parametrize("element", ["q1i", "q1"])
def test_warped_matrices_match_loop_oracle(rng, element):
    m = mixed_bar()
    integ = Corotational(m, 1e-3, element=element)
    u = 0.02 * rng.standard_normal((m.n_nodes, 3)) + ((rot([-1, 2, 0.5], 1.1) - np.eye(3)) @ m.nodes_m.T).T
    _, R = integ._corners(integ.asm.restrict(u))
    got = integ.warped_matrices(R)
    want = oracle_warped(m, u, element)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())
    # and the assembled tangent is their sum
    np.testing.assert_allclose(integ.tangent(integ.asm.restrict(u)).toarray(),
                               integ.asm.stiffness(element_matrices=want).toarray(),
                               atol=1e-9 * np.abs(want).max())


def test_tangent_is_exact_jacobian_at_a_rigid_rotation(rng):
    """At a rigidly rotated (strain-free) state the neglected dR/dx terms vanish (K_e annihilates
    infinitesimal rotations), so the warped stiffness is the Jacobian of the force."""
    m = mixed_bar()
    integ = Corotational(m, 1e-3)
    c = m.nodes_m.mean(axis=0)
    u = (m.nodes_m - c) @ rot([0.4, -1.0, 0.7], 1.3).T + c - m.nodes_m
    uf = integ.asm.restrict(u)
    K = integ.tangent(uf).toarray()
    eps = 1e-7 * m.h
    cols = rng.choice(len(uf), 12, replace=False)
    for j in cols:                                      # central differences on a few columns
        d = np.zeros_like(uf)
        d[j] = eps
        fd = (integ.internal_force(uf + d) - integ.internal_force(uf - d)) / (2 * eps)
        np.testing.assert_allclose(fd, K[:, j], atol=1e-6 * np.abs(K).max())


def test_rotations_computed_once_per_state(monkeypatch):
    """energy() after a step and the next step's tangent share one polar decomposition, HHT's
    force at u_n reuses the tangent's; results equal those without any cache."""
    m = bar()
    fixed = np.flatnonzero(m.node_index[:, 0] == 0)
    calls = []
    real = corot_mod.cube_rotations
    monkeypatch.setattr(corot_mod, "cube_rotations", lambda xe, h: calls.append(1) or real(xe, h))

    def run(alpha, nocache):
        integ = Corotational(m, 2e-3, fixed_nodes=fixed, loads=LoadSet(m, [Gravity()]), alpha=alpha, iterations=3)
        if nocache:                                     # forget the rotations before every use
            orig = integ._corners
            integ._corners = lambda u: (setattr(integ, "_cache_R", None), orig(u))[1]
        integ.step()
        e0 = integ.energy().elastic
        calls.clear()
        integ.step()
        n_step = len(calls)
        calls.clear()
        e1 = integ.energy().elastic
        return n_step, len(calls), e0, e1, integ._u

    for alpha in (0.0, -0.2):
        n_step, n_energy, e0, e1, u = run(alpha, nocache=False)
        # tangent(u_n) (and HHT's f_int(u_n)) reuse energy()'s rotations: one per iterate only
        assert n_step == 3
        assert n_energy == 1
        n_step_nc, _, e0_nc, e1_nc, u_nc = run(alpha, nocache=True)
        assert n_step_nc == 4 + (alpha != 0)
        assert (e0, e1) == (e0_nc, e1_nc)
        np.testing.assert_array_equal(u, u_nc)


def test_polar_rotation_is_proper_rotation(rng):
    F = rng.standard_normal((50, 3, 3))
    R = polar_rotation(F)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    good = np.linalg.det(F) > 0
    for Fi, Ri in zip(F[good][:5], R[good][:5]):                # scipy's polar on a few
        np.testing.assert_allclose(Ri, polar(Fi)[0], atol=1e-10)


def test_rigid_rotation_by_90_degrees_has_no_elastic_force():
    m = bar()
    co, lin = Corotational(m, 1e-3), Newmark(m, 1e-3)
    c = m.nodes_m.mean(axis=0)
    R = rot([0.3, 1.0, 0.2], np.pi / 2)
    u = (m.nodes_m - c) @ R.T + c + np.array([0.1, -0.2, 0.3]) - m.nodes_m
    uf = co.asm.restrict(u)
    f_lin = lin.internal_force(uf)
    f_co = co.internal_force(uf)
    assert np.abs(f_co).max() < 1e-10 * np.abs(f_lin).max()
    assert co.elastic_energy(uf) < 1e-12 * lin.elastic_energy(uf)
    # rotations found per cube are that rotation
    Rs = cube_rotations((m.nodes_m + u)[m.hexes], m.h)
    np.testing.assert_allclose(Rs, np.broadcast_to(R, Rs.shape), atol=1e-12)


def test_small_displacements_reduce_to_linear(rng):
    m = bar()
    co, lin = Corotational(m, 1e-3), Newmark(m, 1e-3)
    u = 1e-7 * rng.standard_normal(co.K.shape[0])
    f_co, f_lin = co.internal_force(u), lin.internal_force(u)
    assert np.linalg.norm(f_co - f_lin) < 1e-4 * np.linalg.norm(f_lin)


def test_spinning_bar_keeps_its_size_where_linear_inflates():
    """A free bar spinning about z by a quarter turn: corotational keeps its length, linear grows."""
    m = CubeModel.box((8, 1, 1), 0.05, youngs=1e6, poisson=0.3, density=1000.0)
    c = m.nodes_m.mean(axis=0)
    omega = 2.0                                          # rad/s
    v0 = np.cross([0.0, 0.0, omega], m.nodes_m - c)
    dt, n = 2e-3, int(round(np.pi / 2 / omega / 2e-3))
    ends = [np.flatnonzero(m.node_index[:, 0] == 0), np.flatnonzero(m.node_index[:, 0] == 8)]

    def length(u):
        x = m.nodes_m + u
        return np.linalg.norm(x[ends[1]].mean(0) - x[ends[0]].mean(0))

    L0 = 0.4
    co = record(Corotational(m, dt, v0=v0), n)
    lin = record(Newmark(m, dt, v0=v0), n)
    assert abs(length(co.u[-1]) / L0 - 1) < 0.01
    assert length(lin.u[-1]) / L0 > 1.1                  # linear elasticity inflates the rotated bar
    # the corotational bar has turned by about 90 degrees
    x = m.nodes_m + co.u[-1]
    d = x[ends[1]].mean(0) - x[ends[0]].mean(0)
    assert abs(np.degrees(np.arctan2(d[1], d[0])) - 90.0) < 3.0
    # and kept its energy (average acceleration, no damping) within 1 %
    assert np.max(np.abs(co.energy - co.energy[0])) < 1e-2 * co.energy[0]


def test_lagged_factor_with_cg_follows_the_factorize_every_step_trajectory():
    """A soft bar sagging through large rotations: the default solver (an earlier step's factor
    preconditioning CG, refactorized when CG slows) gives the trajectory of a factorization every
    step to 1e-8, with far fewer factorizations; the refactorization triggers do fire."""
    m = CubeModel.box((20, 2, 2), 0.05, youngs=1e5, poisson=0.3, density=1000.0)
    fixed = np.flatnonzero(m.node_index[:, 0] == 0)

    def run(**kw):
        integ = Corotational(m, 5e-3, fixed_nodes=fixed, loads=LoadSet(m, [Gravity()]), **kw)
        states = [integ.step().u.copy() for _ in range(60)]
        return integ, np.array(states)

    each, u_each = run(max_cg=0)
    lagged, u_lag = run()
    tight, _ = run(max_cg=1)
    assert each.n_factorizations >= 60 and each.cg_iterations == 0
    assert np.abs(u_each[-1]).max() > 0.1 * m.h * 20          # a large sag: rotations matter
    np.testing.assert_allclose(u_lag, u_each, rtol=0, atol=1e-8 * np.abs(u_each).max())
    assert 1 <= lagged.n_factorizations < 30 and lagged.cg_iterations > 0
    assert tight.n_factorizations > lagged.n_factorizations     # a tighter CG budget refactorizes more
    with pytest.raises(InputError, match="max_cg"):
        Corotational(m, 5e-3, fixed_nodes=fixed, max_cg=-1)
    with pytest.raises(InputError, match="cg_rtol"):
        Corotational(m, 5e-3, fixed_nodes=fixed, cg_rtol=2.0)


# ---------------------------------------------------------------------------------------- stability
def sliver_cube(t=0.1, h=0.05):
    """One cube filled only in a bottom slab ``t h`` thick, ``stiffness="moments"`` (E 1 GPa).

    Its consistent mass follows the slab, so the top corners carry a tiny share of it, while gravity
    is lumped 1/8 of the cube's weight per corner: ``M^-1 f_g`` is hundreds of g at the top."""
    a, b, c = EXPONENTS.T
    mom = t ** (c + 1) / ((a + 1) * (b + 1) * (c + 1))          # moments of [0,1]^2 x [0,t]
    return CubeModel.from_cells([[0, 0, 0]], origin=(0, 0, 0), pitch=h, mass=1000.0 * t * h**3, youngs=1e9,
                                poisson=0.3, density=1000.0, fraction=t, stiffness="moments", moments=mom[None])


def energy_rise(integ, n):
    """Step ``integ`` ``n`` times: (largest rise of the total energy above its start, largest T + U), J."""
    e = integ.energy()
    total, mech = [e.total], [e.kinetic + e.elastic]
    for _ in range(n):                                   # loop over time steps
        integ.step()
        e = integ.energy()
        total.append(e.total)
        mech.append(e.kinetic + e.elastic)
    assert np.all(np.isfinite(total))
    return max(total) - total[0], max(mech)


def test_sliver_cube_start_is_not_the_predictor():
    """The root cause, on one cube: the consistent mass of a slab-filled cube gives its top corners
    ``M^-1 f_g`` = 5,634 m/s^2 under lumped gravity (linear Newmark does not care: its one solve is
    exact from any start). The first iterate of the old step, the Newmark predictor, put them
    ``dt^2/2 a_0`` = 2.8 mm = 0.056 h off, where the frozen tangent diverged: 3.7e6 J at step 1 for a
    motion of 6e-8 J. Now the first step is linearised at ``u_n`` and later ones start from
    ``u_n + dt v_n + dt^2 (a_{n-1} + a_n) / 4``: the run follows linear Newmark (strains are tiny)
    and keeps its energy."""
    m = sliver_cube()
    fixed = np.flatnonzero(m.node_index[:, 0] == 0)
    kw = dict(fixed_nodes=fixed, loads=LoadSet(m, [Gravity()]))
    co, lin = Corotational(m, 1e-3, **kw), Newmark(m, 1e-3, **kw)
    assert np.abs(lin._a).max() > 400 * 9.81                 # the trigger: M^-1 f_g at the top corners
    assert 0.5e-6 * np.abs(lin._a).max() > 0.05 * m.h        # the old first iterate: > 5 % of the cube off
    rise, mech = energy_rise(co, 40)
    assert rise <= 1e-3 * mech
    u_lin = np.array([lin.step().u for _ in range(40)])[-1]
    np.testing.assert_allclose(co.state.u, u_lin, rtol=0, atol=1e-2 * np.abs(u_lin).max())
    assert co.n_newton == 0


CHAIR = {}


def chair(stiffness):
    """The built-in chair at resolution 16 on its default supports (kept per stiffness mode)."""
    if stiffness not in CHAIR:
        CHAIR[stiffness] = Scene.from_mesh("builtin:chair", resolution=16, fix="default", stiffness=stiffness)
    return CHAIR[stiffness]


@pytest.mark.parametrize("stiffness, element", [("moments", "q1i"), ("fraction", "q1i"), ("full", "q1i"),
                                                ("moments", "q1"), ("moments", "q1sri")])
def test_chair_under_gravity_keeps_its_energy(stiffness, element):
    """``sc-fem simulate builtin:chair --fix default --gravity --method corotational --dt 1e-3`` blew up
    at step 1 with the default ``moments`` stiffness: it now runs 0.1 s and its total energy (kinetic +
    elastic + gravity) never rises above its start by more than 1e-3 of the largest T + U."""
    sc = chair(stiffness)
    integ = Corotational(sc.model, 1e-3, fixed_nodes=sc.fixed_nodes, loads=LoadSet(sc.model, [Gravity()]),
                         element=element)
    rise, mech = energy_rise(integ, 100)
    assert mech > 0
    assert rise <= 1e-3 * mech


@pytest.mark.parametrize("stiffness", ["moments", "fraction", "full"])
def test_chair_struck_at_its_top_keeps_its_energy(stiffness):
    """A 0.01 N s impulse on the chair's top vertex (plus gravity) gives light nodes 3-30 m/s: every
    stiffness mode blew up within 6 steps (the start carried the sign-flipping accelerations of those
    nodes, and the convergence was judged in the max-norm those nodes rule). Linear Newmark is stable
    there; so is the corotational run now."""
    sc = chair(stiffness)
    integ = Corotational(sc.model, 1e-3, fixed_nodes=sc.fixed_nodes, loads=LoadSet(sc.model, [Gravity()]))
    J = np.zeros((len(sc.rest_vertices), 3))
    J[int(np.argmax(sc.rest_vertices[:, 2]))] = (0.01, 0.0, 0.0)
    integ.set_velocity_from_impulse(sc.forces_to_nodes(J))
    rise, mech = energy_rise(integ, 100)
    assert rise <= 1e-3 * mech


def test_large_rotation_steps_fall_back_to_newton():
    """A slender bar spinning by 0.2 rad per step (dt 9x the explicit limit): with the tangent of
    ``u_n`` the passes do not contract (residual 311, 174, 269, 319 N at step 1) and the old step
    blew up. The stalled passes fall back to Newton's method with the warped stiffness of every
    iterate: the half turn completes with the energy kept within 4 % and the length within 1 %."""
    m = CubeModel.box((8, 1, 1), 0.05, youngs=1e6, poisson=0.3, density=1000.0)
    c = m.nodes_m.mean(axis=0)
    omega, dt = 20.0, 1e-2
    integ = Corotational(m, dt, v0=np.cross([0.0, 0.0, omega], m.nodes_m - c))
    ends = [np.flatnonzero(m.node_index[:, 0] == 0), np.flatnonzero(m.node_index[:, 0] == 8)]
    e0 = integ.energy().total
    es = []
    for _ in range(int(np.pi / omega / dt)):              # loop over time steps
        integ.step()
        es.append(integ.energy().total)
    assert max(es) <= 1.001 * e0 and min(es) >= 0.96 * e0
    x = m.nodes_m + integ.state.u
    assert abs(np.linalg.norm(x[ends[1]].mean(0) - x[ends[0]].mean(0)) / 0.4 - 1) < 0.01
    assert integ.n_newton > 0
