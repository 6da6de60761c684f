"""What a run reports must be true: energy accounting with the loads' work, impulses that do not
tear the mesh, the frame rate asked for, and default settings that work."""

from __future__ import annotations

import numpy as np
import pytest

import shapes
from sc_fem import Scene
from sc_fem._cli.main import main
from sc_fem.dynamics.job import run_simulation
from sc_fem.dynamics.loads import PATCH_RADIUS, impulse_nodes
from sc_fem.dynamics.newmark import Newmark
from sc_fem.errors import InputError


def test_gust_work_is_accounted_so_an_undamped_run_has_no_drift():
    """Before, a gust run reported 'energy drift 0.55' although its energy is constant once the
    gust ends: the gust's work was not counted."""
    scene = Scene.from_mesh("builtin:bridge", resolution=12, fix="default")
    rec = run_simulation(scene, dt=0.001, duration=0.1, gust=(0.0, 2e7, 0.0, 0.02), fps=100)
    assert rec.parts["work"][-1] > 0
    assert abs(rec.energy_drift) < 1e-3
    assert rec.energy_gain < 1e-3
    late = rec.times > 0.03                     # the gust is over: the energy stays what it put in
    np.testing.assert_allclose(rec.energy[late], rec.parts["work"][late], rtol=1e-3)


def test_impulse_is_spread_over_the_mass_around_its_vertex():
    """Rigid check on a beam with a lumped mass: the patch of nodes within 1.5 cube edges of the
    vertex starts with one velocity J / m_patch (loop oracle), momentum J, energy J^2 / (2 m_patch)."""
    scene = Scene.from_mesh("builtin:beam", resolution=10)
    model, V = scene.model, scene.rest_vertices
    vertex, J = int(np.argmax(V[:, 0])), np.array([0.0, 3.0, 4.0])
    nm = model.node_masses()
    row = scene.W.tocsr()[vertex]
    patch = set(row.indices[row.data != 0])          # the nodes of its cube that carry it
    for i, p in enumerate(model.nodes):          # oracle: a loop over the nodes
        if np.linalg.norm(p - V[vertex]) <= PATCH_RADIUS * model.pitch:
            patch.add(i)
    m_patch = sum(nm[i] for i in patch)
    integ = Newmark(model, 1e-3, lumped=True)
    integ.set_velocity_from_impulse(impulse_nodes(model, V, [vertex], [J]))
    v = integ.state.v
    for i in patch:
        np.testing.assert_allclose(v[i], J / m_patch, rtol=1e-12)
    assert np.count_nonzero(np.abs(v).sum(axis=1)) == len(patch)
    np.testing.assert_allclose((nm[:, None] * v).sum(axis=0), J, rtol=1e-12)
    assert integ.energy().kinetic == pytest.approx(J @ J / (2 * m_patch), rel=1e-12)


def test_an_impulse_does_not_tear_the_slatted_chair():
    """Before: 20 N s on one vertex gave 3.9e4 - 1.3e5 J and the hit vertex flew 24-44 % further
    than the 4th-farthest vertex; now the mesh moves as a whole."""
    scene = Scene.from_mesh(shapes.slatted_chair(), resolution=16)
    V = scene.rest_vertices
    for vertex in (int(np.argmax(V[:, 2])), int(np.argmax(V[:, 0] + V[:, 2]))):
        rec = run_simulation(scene, duration=0.05, impulses=[(vertex, 20.0, 0.0, 0.0)], fps=200)
        d = np.sort(np.linalg.norm(rec.points[-1] - rec.points[0], axis=1))
        assert d[-1] / d[-4] < 1.1
        assert rec.parts["kinetic"][0] < 1e4


def test_the_stored_frame_rate_is_the_one_asked_for(tmp_path, capsys):
    scene = Scene.from_mesh("builtin:beam", resolution=6)
    with pytest.raises(InputError, match="not a whole number of time steps"):
        run_simulation(scene, dt=1e-3, duration=0.01, fps=300)
    rc = main(["simulate", "builtin:beam", "-r", "6", "--duration", "0.01", "--dt", "1e-3", "--fps", "300",
               "-o", str(tmp_path / "x.npz")])
    assert rc == 2 and "does not divide the frame step" in capsys.readouterr().err
    assert not (tmp_path / "x.npz").exists()
    rec = run_simulation(scene, duration=0.1, fps=40)           # default dt: half a frame
    assert rec.dt == pytest.approx(1 / 80) and np.allclose(np.diff(rec.times), 1 / 40)


def test_the_issues_first_command_completes(tmp_path, capsys):
    """``sc-fem simulate builtin:chair --gravity --ground 0 -r 16 --duration 0.5`` ("newmark blew
    up at step 2" before; no --dt needed now)."""
    out = tmp_path / "x.npz"
    rc = main(["simulate", "builtin:chair", "--gravity", "--ground", "0", "-r", "16", "--duration", "0.5",
               "-o", str(out), "--no-progress"])
    assert rc == 0 and out.exists()
    text = capsys.readouterr().out
    assert "ipc" in text and "no vertex ever through an obstacle" in text


def test_a_projected_contact_run_that_blows_up_names_a_setting_that_works(tmp_path, capsys):
    """The issue's chair on the ground with the old projection contact (``--method newmark``) blows
    up at step 2; the message names --method ipc (not "reduce dt", which did not help), and that
    setting completes the same run."""
    argv = ["simulate", "builtin:chair", "--gravity", "--ground", "0", "-r", "16", "--duration", "0.1",
            "--dt", "1e-3", "-o", str(tmp_path / "x.npz"), "--no-progress", "--quiet"]
    assert main(argv + ["--method", "newmark"]) == 2
    err = capsys.readouterr().err
    assert "blew up" in err and "--method ipc" in err and "Traceback" not in err
    assert not (tmp_path / "x.npz").exists()
    assert main(argv + ["--method", "ipc"]) == 0
    assert (tmp_path / "x.npz").exists()


def test_a_point_force_is_shared_by_the_mass_around_its_vertex():
    """VertexForce's default: the force on one vertex is shared by the nodes of its patch in
    proportion to their mass (the same sharing as an impulse); the total force is kept."""
    from sc_fem.dynamics.loads import LoadSet, VertexForce

    scene = Scene.from_mesh(shapes.slatted_chair(), resolution=16)
    V, model = scene.rest_vertices, scene.model
    vertex, F = int(np.argmax(V[:, 2])), np.array([5.0, 0.0, -2.0])
    f = LoadSet(model, [VertexForce([vertex], F)], points=V, W=scene.W).force(0.0)
    np.testing.assert_allclose(f, impulse_nodes(model, V, [vertex], [F]), rtol=1e-12)
    np.testing.assert_allclose(f.sum(axis=0), F, rtol=1e-12)
    on = np.abs(f).sum(axis=1) > 0
    assert on.sum() >= 8                                      # at least the 8 nodes of its cube
    acc = f[on] / model.node_masses()[on, None]
    np.testing.assert_allclose(acc, np.broadcast_to(acc[0], acc.shape), rtol=1e-12)   # one acceleration


def test_gravity_is_a_vector_and_a_bool_is_refused():
    """run_simulation takes gravity as the acceleration vector (m/s^2), like solve_static: the beam
    falls freely by g t^2 / 2 along it (here along -y, a y-up model), and ``gravity=True`` (the old
    flag) is one clear InputError, not a silent zero."""
    from sc_fem.units import gravity_down

    scene = Scene.from_mesh("builtin:beam", resolution=6)
    rec = run_simulation(scene, duration=0.05, gravity=gravity_down("y"), up="y", fps=100)
    drop = np.asarray(rec.points)[-1] - np.asarray(rec.points)[0]
    np.testing.assert_allclose(drop.mean(axis=0), [0.0, -0.5 * 9.81 * 0.05**2, 0.0], atol=1e-4)
    with pytest.raises(InputError, match="gravity"):
        run_simulation(scene, duration=0.05, gravity=True)
    with pytest.raises(InputError, match="up must be"):
        gravity_down("w")
