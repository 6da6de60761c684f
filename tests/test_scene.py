"""Scene: one object carries mesh + lattice + embedding + fixed nodes through every solver."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import sc_fem
from sc_fem import Scene
from sc_fem.errors import InputError


def _mm_box():
    """An off-origin box in millimetres (scale 1e-3), as users bring CAD parts."""
    m = trimesh.creation.box(extents=(400.0, 100.0, 100.0))
    m.apply_translation((1000.0, -250.0, 3000.0))
    return m


def test_maps_are_the_trilinear_map_and_its_transpose():
    scene = Scene.from_mesh(_mm_box(), resolution=8, scale=1e-3, fix="x<min+1")
    m, n = scene.model.n_nodes, len(scene.rest_vertices)
    rng = np.random.default_rng(0)
    u = rng.normal(size=(m, 3)) * 1e-3                       # metres
    W = sc_fem.embed(scene.model, scene.rest_vertices).toarray()
    np.testing.assert_allclose(scene.vertex_positions(u), scene.rest_vertices + W @ u / 1e-3, rtol=1e-12)
    stack = rng.normal(size=(4, m, 3))
    np.testing.assert_allclose(scene.vertex_displacements(stack)[2], W @ stack[2] / 1e-3, rtol=1e-12)
    # forces go to the nodes by the transpose: the work f . du equals F . u for any u
    f = rng.normal(size=(n, 3))
    F = scene.forces_to_nodes(f)
    assert np.sum(F * u) == pytest.approx(np.sum(f * (W @ u)), rel=1e-12)
    # a rigid translation of the nodes moves every vertex by the same amount (rows of W sum to 1)
    np.testing.assert_allclose(scene.vertex_displacements(np.tile([1e-3, 0, 0], (m, 1))),
                               np.tile([1.0, 0, 0], (n, 1)), atol=1e-12)
    assert len(scene.fixed_nodes) and np.all(scene.model.nodes[scene.fixed_nodes, 0] < scene.rest_vertices[:, 0].min() + 1)
    with pytest.raises(InputError, match=r"u must have shape"):
        scene.vertex_positions(np.zeros((m + 1, 3)))
    with pytest.raises(InputError, match=r"f must have shape"):
        scene.forces_to_nodes(np.zeros((n, 2)))


def test_solvers_give_the_same_answers_from_a_scene():
    scene = Scene.from_mesh("builtin:beam", resolution=10, fix="x<min+1e-6")
    a = sc_fem.modal(scene, n_modes=3)
    b = sc_fem.modal("builtin:beam", resolution=10, fix="x<min+1e-6", n_modes=3)
    np.testing.assert_allclose(a.frequencies, b.frequencies, rtol=1e-9)
    assert a.fix_record == b.fix_record and a.source == "builtin:beam" and a.modes.shape == b.modes.shape
    s1 = sc_fem.solve_static(scene, gravity=(0, 0, -9.81))
    s2 = sc_fem.solve_static(scene.model, fix="x<min+1e-6", gravity=(0, 0, -9.81), mesh="builtin:beam")
    np.testing.assert_allclose(s1.vertex_displacements, s2.vertex_displacements, rtol=1e-9, atol=1e-15)
    with pytest.raises(InputError, match="do not pass fix"):
        sc_fem.modal(scene, fix="x<0")
    with pytest.raises(InputError, match="do not pass mesh"):
        sc_fem.solve_static(scene, mesh="builtin:beam")


def test_default_supports_of_a_builtin_and_the_records():
    scene = Scene.from_mesh("builtin:bridge", resolution=8, fix="default")
    assert len(scene.fixed_nodes) > 0 and scene.fix_record()["n_nodes"] == len(scene.fixed_nodes)
    assert scene.material_record()["mass"] == pytest.approx(scene.model.total_mass)
    assert "builtin:bridge" in repr(scene)
    with pytest.raises(sc_fem.BoundaryConditionError, match="builtin"):
        Scene.from_mesh(_mm_box(), resolution=6, scale=1e-3, fix="default")
    with pytest.raises(InputError, match="needs the source mesh"):
        Scene.from_model(scene.model, fix_vertices=[0])


def test_a_millimetre_part_off_the_origin_behaves_like_the_same_part_in_metres_at_the_origin():
    """Modes and static sag of the off-origin millimetre box equal those of the 0.4 x 0.1 x 0.1 m box
    at the origin: units and placement change nothing physical (y-up gravity, one end held)."""
    mm = Scene.from_mesh(_mm_box(), resolution=8, scale=1e-3, fix="x<min+1", youngs=1e7, poisson=0.3,
                         density=1000)
    box_m = trimesh.creation.box(extents=(0.4, 0.1, 0.1))
    m = Scene.from_mesh(box_m, resolution=8, fix="x<min+0.001", youngs=1e7, poisson=0.3, density=1000)
    assert mm.model.n_cubes == m.model.n_cubes and len(mm.fixed_nodes) == len(m.fixed_nodes)
    fa, fb = sc_fem.modal(mm, n_modes=4), sc_fem.modal(m, n_modes=4)
    np.testing.assert_allclose(fa.frequencies, fb.frequencies, rtol=1e-9)
    # the first pair is degenerate: compare the spanned subspaces, modes in metres per unit coordinate
    A, B = fa.modes[:2].reshape(2, -1).T, fb.modes[:2].reshape(2, -1).T
    cosines = np.linalg.svd(np.linalg.qr(A)[0].T @ np.linalg.qr(B)[0], compute_uv=False)   # principal angles
    np.testing.assert_allclose(cosines, 1.0, atol=1e-6)
    sa = sc_fem.solve_static(mm, gravity=(0, -9.81, 0))
    sb = sc_fem.solve_static(m, gravity=(0, -9.81, 0))
    np.testing.assert_allclose(sa.vertex_displacements, sb.vertex_displacements, atol=1e-9 * np.abs(sb.vertex_displacements).max())
    assert sb.vertex_displacements[:, 1].min() < 0


def test_fix_vertices_locate_the_vertices_once(monkeypatch):
    """fix_vertices needs the embedding of the source vertices; the scene keeps that one instead of
    embedding them a second time (and a single query point, as a list, is a valid source)."""
    import sys

    embed_mod = sys.modules["sc_fem.lattice.embed"]          # the module (sc_fem.lattice.embed is the function)

    calls = []
    real = embed_mod.embedding
    for name in ("sc_fem.lattice.embed", "sc_fem.lattice.boundary", "sc_fem.scene"):   # every module that calls it
        monkeypatch.setattr(sys.modules[name], "embedding", lambda *a, **k: calls.append(1) or real(*a, **k))
    model = sc_fem.voxelize("builtin:beam", resolution=8)
    scene = sc_fem.Scene.from_model(model, "builtin:beam", fix_vertices=[0, 1, 2, 3])
    assert len(scene.fixed_nodes) > 0 and scene.W.shape[0] == scene.rest_vertices.shape[0]
    u = np.zeros((model.n_nodes, 3))
    scene.vertex_positions(u)
    assert len(calls) == 1
    one = sc_fem.Scene.from_model(model, [[float(x) for x in model.nodes[5]]])
    assert one.W.shape == (1, model.n_nodes)
