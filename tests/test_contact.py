"""Contact of source-mesh vertices with the ground, a sphere and a box: no vertex ends a step deeper
than the stated tolerance."""

from __future__ import annotations

import numpy as np
import pytest

from sc_fem import Scene
import trimesh

from sc_fem.errors import InputError
from sc_fem.dynamics import record
from sc_fem.dynamics.contact import TOL_FRACTION, Box, Contact, Ground, Sphere, obstacles_from
from sc_fem.dynamics.loads import Gravity, LoadSet
from sc_fem.dynamics.newmark import Newmark
from sc_fem.lattice.voxelize import voxelize


def block(z0=0.05):
    mesh = trimesh.creation.box(extents=[0.4, 0.2, 0.1]).subdivide()
    mesh.apply_translation([0.0, 0.0, 0.05 + z0])
    model = voxelize(mesh, resolution=8, youngs=1e6, poisson=0.3, density=500.0, fill="solid")
    return mesh, model


def test_obstacle_depths():
    p = np.array([[0.0, 0.0, -0.1], [0.0, 0.0, 0.3]])
    d, n = Ground(0.0).depth(p)
    np.testing.assert_allclose(d, [0.1, -0.3])
    np.testing.assert_allclose(n, [[0, 0, 1], [0, 0, 1]])
    d, n = Sphere((0, 0, 0), 0.2).depth(p)
    np.testing.assert_allclose(d, [0.1, -0.1])
    np.testing.assert_allclose(n, [[0, 0, -1], [0, 0, 1]])
    d, n = Box((-1, -1, -1), (1, 1, 0.0)).depth(p)
    assert d[0] == pytest.approx(0.1) and d[1] < 0
    np.testing.assert_allclose(n[0], [0, 0, 1])
    with pytest.raises(InputError):
        obstacles_from(box=[0, 0, 0, -1, 1, 1])


def test_single_projection_removes_ground_penetration(rng):
    mesh, model = block()
    c = Contact(model, mesh.vertices, [Ground(0.08)])
    u = 1e-3 * rng.standard_normal((model.n_nodes, 3))
    d0, _ = c.depths(u)
    assert d0.max() > 10 * c.tol
    u2, v2, info = c.project(u, np.zeros_like(u))
    assert info.passes == 1 and info.n_active == int((d0 > 0).sum())
    d1, _ = c.depths(u2)
    assert d1.max() <= c.tol
    assert c.tol == pytest.approx(TOL_FRACTION * model.pitch)
    # only nodes of cubes carrying penetrating vertices moved, and only upward
    du = u2 - u
    assert np.all(du[:, 2] >= 0) and np.allclose(du[:, :2], 0)


@pytest.mark.parametrize("obstacle", [Ground(0.0), Sphere((0.0, 0.0, -0.5), 0.5), Box((-0.1, -0.5, -1), (0.1, 0.5, 0.0))])
def test_dropped_block_never_ends_a_step_below_the_tolerance(obstacle):
    mesh, model = block(z0=0.05)
    c = Contact(model, mesh.vertices, [obstacle])
    ld = LoadSet(model, [Gravity()])
    # dt below the explicit limit of the block (~0.9 ms): with larger steps the position
    # projection can feed energy into the stiff modes of an implicit scheme (see contact.py)
    integ = Newmark(model, 5e-4, loads=ld, contact=c, rayleigh=(0.0, 1e-3))
    rec = record(integ, 400, scene=Scene.from_model(model, mesh), every=2)
    d = np.array([obstacle.depth(p)[0].max() for p in rec.points])    # deepest vertex per frame
    # it started 5 cm above the obstacle (top at z = 0), fell and touched it after the free-fall
    # time sqrt(2 h / g) = 0.101 s (frames every 1 ms), then bounced off (elastic rebound)
    assert d[0] == pytest.approx(-0.05, abs=1e-9)
    assert d.max() > -1e-3 and rec.points[:, :, 2].min() < 1e-3
    t_touch = rec.times[np.argmax(d > -1e-5)]
    assert t_touch == pytest.approx(np.sqrt(2 * 0.05 / 9.81), abs=2e-3)
    # ... without any vertex ending a step deeper than the tolerance
    assert rec.max_contact_depth <= c.tol
    assert d.max() <= c.tol
    # inelastic contact does not create energy: the total (0 at the start) never rises above 0
    mgh = model.total_mass * 9.81 * 0.05
    assert rec.energy.max() <= 1e-3 * mgh
    assert rec.energy[-1] < -0.005 * mgh               # the impact dissipated some energy


def test_block_rests_on_ground_without_sinking():
    mesh, model = block(z0=0.0)
    c = Contact(model, mesh.vertices, [Ground(0.0)])
    integ = Newmark(model, 5e-4, loads=LoadSet(model, [Gravity()]), contact=c, rayleigh=(0.0, 1e-3))
    rec = record(integ, 200, scene=Scene.from_model(model, mesh))
    assert rec.points[:, :, 2].min() >= -c.tol
    assert rec.points[-1, :, 2].min() < 1e-3         # still touching the ground (not bounced off)


def test_fixed_nodes_of_the_integrator_bind_the_contact():
    """The integrator binds the contact to its own fixed nodes: the projection never moves them,
    and vertices embedded only in fixed cubes are not pushed (their depth is reported). The block
    rests on the ground and is thrown down into it (a ground cutting it at t = 0 is refused)."""
    from sc_fem.lattice.boundary import fixed_nodes
    from sc_fem.errors import InputError

    mesh, model = block(z0=0.0)
    fx = fixed_nodes(model, "x<min+0.06")                # the cubes at the -x end (model units)
    with pytest.raises(InputError, match="already cuts the model"):
        Newmark(model, 5e-4, fixed_nodes=fx, contact=Contact(model, mesh.vertices, [Ground(0.01)]))
    c = Contact(model, mesh.vertices, [Ground(0.0)])    # touching the bottom face
    assert c.free.all()                                  # on its own it may move every node
    v0 = np.zeros((model.n_nodes, 3))
    v0[:, 2] = -20.0                                     # m/s downwards: 1 cm into the ground in one step
    integ = Newmark(model, 5e-4, fixed_nodes=fx, contact=c, v0=v0)
    assert integ.contact is not c and c.free.all()       # the user's object is left unchanged
    assert not integ.contact.free[fx].any() and integ.contact.free.sum() == model.n_nodes - len(fx)
    st = integ.step()
    assert np.all(st.u[fx] == 0.0)
    d, _ = integ.contact.depths(st.u)
    mov = integ.contact.movable
    pinned = ~mov & (mesh.vertices[:, 2] < 1e-9)         # bottom vertices in fully fixed cubes
    assert pinned.any() and (mov & (mesh.vertices[:, 2] < 1e-9)).any()
    assert d[mov].max() <= c.tol                         # every vertex that can move was pushed out
    np.testing.assert_allclose(d[pinned], 0.0, atol=1e-12)    # the pinned ones did not move
    assert integ.max_contact_depth == pytest.approx(d.max())
