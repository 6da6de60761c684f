"""Newmark-beta / HHT on the cube lattice: energy, convergence, static limit, gravity sag."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import eigh

from sc_fem.lattice.boundary import fixed_nodes
from sc_fem.errors import InputError
from sc_fem.dynamics import make_integrator, record, simulate
from sc_fem.dynamics.loads import Gravity, LoadSet
from sc_fem.dynamics.newmark import Newmark
from sc_fem.lattice.cubes import CubeModel
from sc_fem import solve_static

G = (0.0, 0.0, -9.81)


def cantilever(n=6, k=1, pitch=0.05, E=1e7):
    m = CubeModel.box((n, k, k), pitch, youngs=E, poisson=0.3, density=1000.0)
    return m, fixed_nodes(m, "x<min+0")


def exact_step_response(integ, t):
    """Exact semi-discrete response to a load switched on at t = 0 from rest (modal superposition)."""
    K, M = integ.K.toarray(), integ.M.toarray()
    f = integ.external_force(0.0)
    w2, phi = eigh(K, M)
    us = np.linalg.solve(K, f)
    q = phi.T @ (M @ us)
    return integ.asm.expand(us - phi @ (q * np.cos(np.sqrt(w2) * t)))


def test_undamped_energy_conserved_over_1000_steps():
    m, fx = cantilever(6, 2)
    integ = Newmark(m, 2e-3, fixed_nodes=fx)
    tip = np.flatnonzero(m.node_index[:, 0] == 6)
    J = np.zeros((m.n_nodes, 3))
    J[tip, 2] = 1e-3                                    # N s
    integ.set_velocity_from_impulse(J)
    e = np.array([s.energy for s in simulate(integ, 1000)])
    assert e[0] > 0
    assert np.max(np.abs(e - e[0])) / e[0] < 1e-8
    # and the motion is not trivial: elastic energy was exchanged
    assert integ.energy().elastic > 1e-3 * e[0]


def test_energy_with_gravity_conserved_and_damped_variants_dissipate():
    m, fx = cantilever(6, 1)
    ld = LoadSet(m, [Gravity(G)])
    plain = record(Newmark(m, 2e-3, fixed_nodes=fx, loads=ld), 400)
    scale = plain.mechanical.max()
    assert scale > 0 and np.max(np.abs(plain.energy - plain.energy[0])) < 1e-9 * scale
    for kw in ({"gamma": 0.6, "beta": 0.3025}, {"alpha": -0.3}):
        damped = record(Newmark(m, 1e-2, fixed_nodes=fx, loads=ld, **kw), 400)
        assert damped.energy[-1] < -0.1 * scale             # lost energy (total starts at 0)
        # gamma > 1/2 never gains energy; HHT's plain energy may wiggle by < 0.1 % of the scale
        assert np.all(np.diff(damped.energy) < 1e-3 * scale)


def first_mode(integ):
    w2, phi = eigh(integ.K.toarray(), integ.M.toarray(), subset_by_index=[0, 0])
    return np.sqrt(w2[0]), integ.asm.expand(phi[:, 0] * 1e-3 / np.abs(phi[:, 0]).max())


@pytest.mark.parametrize("kw", [{}, {"alpha": -0.1}])
def test_second_order_convergence(kw):
    """Released from its first mode shape, the exact motion is u0 cos(omega t): error O(dt^2)."""
    m, fx = cantilever(4, 1)
    w, u0 = first_mode(Newmark(m, 1.0, fixed_nodes=fx))
    T = 2 * np.pi / w
    errs = []
    for n in (20, 40, 80):
        integ = Newmark(m, T / n, fixed_nodes=fx, u0=u0, **kw)
        rec = record(integ, n)
        exact = u0[None] * np.cos(w * rec.times)[:, None, None]
        errs.append(np.abs(rec.u - exact).max() / np.abs(u0).max())
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert np.all(rates > 1.9) and np.all(rates < 2.2), (errs, rates)
    assert errs[-1] < 1e-2


def test_step_load_matches_modal_reference():
    """Gravity switched on from rest: with a small step the whole history matches modal superposition."""
    m, fx = cantilever(4, 1)
    ld = LoadSet(m, [Gravity(G)])
    integ = Newmark(m, 2e-5, fixed_nodes=fx, loads=ld)
    rec = record(integ, 500)
    ref = np.array([exact_step_response(integ, t) for t in rec.times])
    assert np.abs(rec.u - ref).max() < 2e-3 * np.abs(ref).max()


def test_hht_tends_to_newmark_as_alpha_tends_to_zero():
    """alpha = 0 is the default, so compare a tiny non-zero alpha (the HHT branch runs, with the HHT
    beta = (1 - alpha)^2 / 4, gamma = 1/2 - alpha) against plain average-acceleration Newmark."""
    m, fx = cantilever(4, 1)
    ld = LoadSet(m, [Gravity(G)])
    hht = Newmark(m, 1e-3, fixed_nodes=fx, loads=ld, alpha=-1e-9)
    assert hht.beta != 0.25 and hht.gamma != 0.5
    a = record(hht, 50).u[-1]
    b = record(Newmark(m, 1e-3, fixed_nodes=fx, loads=ld), 50).u[-1]
    assert not np.array_equal(a, b)                       # the HHT terms did change the result ...
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6 * np.abs(b).max())   # ... by O(alpha)


def test_load_patterns_match_the_dense_scatter(rng):
    """Vertex forces and face pressures (sparse rows of W, repeated vertices and faces included)
    equal W^T applied to the dense per-vertex force array built with np.add.at."""
    import trimesh

    from sc_fem.lattice.embed import embed
    from sc_fem.dynamics.loads import FacePressure, VertexForce
    from sc_fem.lattice.voxelize import voxelize

    mesh = trimesh.creation.box(extents=[0.4, 0.2, 0.1])
    model = voxelize(mesh, resolution=6, youngs=1e6, poisson=0.3, density=500.0, fill="solid")
    pts, tri = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    W = embed(model, pts)
    idx = np.array([0, 3, 3, 5, 0])                       # repeated vertices add up
    f = rng.standard_normal((len(idx), 3))
    fidx = np.array([1, 4, 4, 7])                         # repeated faces add up
    pr = rng.uniform(1.0, 2.0, len(fidx))
    ld = LoadSet(model, [VertexForce(idx, f, spread="embedding"), FacePressure(fidx, pr)], points=pts, faces=tri, W=W)
    vf = np.zeros((len(pts), 3))
    np.add.at(vf, idx, f)
    vp = np.zeros((len(pts), 3))
    for p_k, face in zip(pr, fidx):                       # slow oracle: one face at a time
        a, b, c = pts[tri[face]]
        an = 0.5 * np.cross(b - a, c - a) * model.scale**2
        for vert in tri[face]:
            vp[vert] += -p_k * an / 3.0
    expected = np.asarray(W.T @ vf) + np.asarray(W.T @ vp)
    np.testing.assert_allclose(ld.force(0.0), expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
    # the total force is kept (the rows of W sum to 1): sum of the vertex forces + pressures
    np.testing.assert_allclose(ld.force(0.0).sum(axis=0), vf.sum(axis=0) + vp.sum(axis=0), rtol=1e-12, atol=1e-12)


def test_long_time_limit_is_static_solution():
    m, fx = cantilever(6, 2)
    ld = LoadSet(m, [Gravity(G)])
    ref = solve_static(m, fix="x<min+0", gravity=G).displacements
    # Rayleigh damping (the stiffness part reaches the high modes that average acceleration
    # never damps at large omega dt), or HHT numerical damping
    for kw in ({"rayleigh": (100.0, 1e-4)}, {"alpha": -0.3, "rayleigh": (100.0, 0.0)}):
        *_, st = simulate(Newmark(m, 5e-3, fixed_nodes=fx, loads=ld, **kw), 600)
        assert np.linalg.norm(st.u - ref) < 1e-9 * np.linalg.norm(ref)


def test_cantilever_gravity_sag_dynamic_and_beam_theory():
    n, k, pitch, E = 20, 2, 0.05, 1e7
    m, fx = cantilever(n, k, pitch, E)
    ld = LoadSet(m, [Gravity(G)])
    L, b = n * pitch, k * pitch
    q = 1000.0 * b * b * 9.81
    eb = q * L**4 / (8 * E * b**4 / 12)                   # Euler-Bernoulli tip sag, m
    tip = m.node_index[:, 0] == n
    # a suddenly applied load: the undamped tip swings between 0 and twice the static sag
    integ = Newmark(m, 1e-3, fixed_nodes=fx, loads=ld)
    rec = record(integ, 400)
    z = rec.u[:, tip, 2].mean(axis=1)
    static = solve_static(m, fix="x<min+0", gravity=G).displacements[tip, 2].mean()
    assert abs(z.min() / static - 2.0) < 0.05
    assert z.max() <= 1e-9 * abs(static)
    # damped: it settles at the static sag, within 10 % of beam theory
    damped = Newmark(m, 5e-3, fixed_nodes=fx, loads=ld, rayleigh=(20.0, 1e-4))
    *_, st = simulate(damped, 400)
    sag = st.u[tip, 2].mean()
    assert abs(sag / static - 1.0) < 1e-3
    assert abs(-sag / eb - 1.0) < 0.10


def test_energy_is_evaluated_only_when_checked_or_yielded(monkeypatch):
    m, fx = cantilever(4, 1)
    integ = Newmark(m, 1e-3, fixed_nodes=fx, loads=LoadSet(m, [Gravity(G)]))
    calls = []
    energy = integ.energy
    monkeypatch.setattr(integ, "energy", lambda: calls.append(1) or energy())
    states = list(simulate(integ, 20, every=5, check=False))
    assert [s.step for s in states] == [0, 5, 10, 15, 20] and len(calls) == 5
    assert np.all(np.isfinite([s.energy for s in states]))
    list(simulate(integ, 20, every=5, check=True))
    assert len(calls) == 5 + 21                            # the check needs it at every step


def test_invalid_parameters():
    m, fx = cantilever(3, 1)
    with pytest.raises(InputError, match="alpha"):
        Newmark(m, 1e-3, fixed_nodes=fx, alpha=-0.5)
    with pytest.raises(InputError, match="gamma"):
        Newmark(m, 1e-3, fixed_nodes=fx, gamma=0.4)
    with pytest.raises(InputError, match="dt"):
        Newmark(m, 0.0, fixed_nodes=fx)
    with pytest.raises(InputError, match="method"):
        make_integrator("rk4", m, 1e-3)
