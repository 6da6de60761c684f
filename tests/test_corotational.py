"""Corotational (warped-stiffness) model: oracle, rigid-rotation invariance, large rotations."""

from __future__ import annotations

import numpy as np
from scipy.linalg import polar

from sc_fem.elements import element_stiffness
from sc_fem.integrators import record
from sc_fem.integrators.corotational import Corotational, cube_rotations, polar_rotation
from sc_fem.integrators.newmark import Newmark
from sc_fem.lattice import HEX_CORNERS, CubeModel


def bar():
    return CubeModel.box((6, 2, 2), 0.05, youngs=1e6, poisson=0.3, density=1000.0)


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


def test_internal_force_matches_loop_oracle(rng):
    m = bar()
    integ = Corotational(m, 1e-3)
    u = 0.01 * rng.standard_normal((m.n_nodes, 3)) + ((rot([1, 2, 3], 0.7) - np.eye(3)) @ m.nodes_m.T).T
    got = integ.asm.expand(integ.internal_force(integ.asm.restrict(u)))
    want = oracle_force(m, u)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * np.abs(want).max())


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
