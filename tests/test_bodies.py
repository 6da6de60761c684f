"""Bodies decided by geometry, not by the grid (seed limitation (a)): the weld distance, cubes of
different bodies sharing a cell (virtual nodes), and everything downstream on such cubes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import sc_fem
import shapes
from sc_fem.fem.assemble import assemble
from sc_fem.geometry.bodies import find_bodies, triangle_distance
from sc_fem.geometry.inside import mesh_parts
from sc_fem.lattice.embed import embedding
from sc_fem.units import gravity_down


# ------------------------------------------------------------------ the distance kernel
def _brute_distance(t1: np.ndarray, t2: np.ndarray, n: int = 60) -> float:
    """Loop oracle: the smallest distance between dense barycentric samples of two triangles."""
    g = np.linspace(0.0, 1.0, n + 1)
    u, v = np.meshgrid(g, g, indexing="ij")
    keep = u + v <= 1 + 1e-12
    bary = np.stack([1 - u[keep] - v[keep], u[keep], v[keep]], axis=1)
    p, q = bary @ t1, bary @ t2
    best = np.inf
    for row in p:                                   # the oracle loops; the kernel is vectorized
        best = min(best, float(np.sqrt(((q - row) ** 2).sum(axis=1)).min()))
    return best


def test_triangle_distance_matches_a_loop_oracle():
    rng = np.random.default_rng(4)
    t1 = rng.normal(size=(40, 3, 3))
    t2 = rng.normal(size=(40, 3, 3)) + rng.normal(scale=1.5, size=(40, 1, 3))
    d = triangle_distance(t1, t2)
    ref = np.array([_brute_distance(a, b) for a, b in zip(t1, t2)])
    # the samples are an upper bound, within about the sample spacing of the true distance
    assert np.all(d <= ref + 1e-12)
    assert np.all(ref - d <= 0.1)
    assert (d == 0).sum() >= 3 and (d > 0.2).sum() >= 10      # both crossing and apart pairs were drawn


def test_triangle_distance_exact_cases():
    base = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    above = base + [0.2, 0.2, 0.3]                                  # parallel, 0.3 above
    crossing = np.array([[0.2, 0.2, -1.0], [0.3, 0.2, 1.0], [0.25, 0.3, 1.0]])
    edge = np.array([[2.0, -1, 0.5], [2.0, 1, 0.5], [3.0, 0, 0.5]])  # nearest: corner (1,0,0) to an edge
    degenerate = np.array([[0.0, 0, 2], [0.0, 0, 2], [1.0, 0, 2]])   # a segment 2 above
    d = triangle_distance(np.array([base] * 4), np.array([above, crossing, edge, degenerate]))
    np.testing.assert_allclose(d, [0.3, 0.0, np.hypot(1.0, 0.5), 2.0], atol=1e-12)


# ------------------------------------------------------------------ bodies from geometry
def _bodies(mesh, weld):
    v = np.asarray(mesh.vertices, dtype=float)
    return find_bodies(v, mesh_parts(v, np.asarray(mesh.faces)), weld)


def test_weld_distance_decides_and_crossing_or_contained_parts_join():
    boxes = shapes.near_touching_boxes(gap=0.004)
    assert _bodies(boxes, 0.003).n_bodies == 2 and _bodies(boxes, 0.005).n_bodies == 1
    assert _bodies(shapes.near_touching_boxes(gap=-0.01), 0.0).n_bodies == 1        # overlapping
    outer = trimesh.creation.box(extents=[1, 1, 1])
    inner = trimesh.creation.icosphere(radius=0.2)                                  # inside, 0.3 from its walls
    nested = trimesh.util.concatenate([outer, inner])
    b = _bodies(nested, 0.01)
    assert b.n_bodies == 1 and b.joined_by_containment == 1
    rod = trimesh.creation.box(extents=[2.0, 0.05, 0.05])                           # through a plate
    plate = trimesh.creation.box(extents=[0.02, 1.0, 1.0])
    assert _bodies(trimesh.util.concatenate([rod, plate]), 0.0).n_bodies == 1


def test_the_builtins_stay_one_body_with_the_default_weld():
    chair = sc_fem.voxelize("builtin:chair", resolution=16)
    assert chair.info["bodies"] == 1 and chair.n_components == 1
    bridge = sc_fem.voxelize("builtin:bridge", resolution=16)
    # the cables that stop 5 cm short of the deck are welded; two stray polygons are loose
    assert bridge.n_components == 1 and bridge.info["loose_bodies"] == 2
    # weld 0: the cables hang from the towers only (still one body through them); the
    # cable-to-deck welds are the default weld's
    no_weld = sc_fem.voxelize("builtin:bridge", resolution=16, weld=0.0)
    assert no_weld.info["bodies"] == 3
    # a cable and the deck alone: 5 cm apart, one body with the default weld, two with weld 0
    mesh = sc_fem.load_mesh("builtin:bridge")
    v = np.asarray(mesh.vertices, dtype=float)
    parts = mesh_parts(v, np.asarray(mesh.faces))
    weld = bridge.info["weld"]
    tri = [v[parts.faces[parts.label == i]] for i in range(parts.n_parts)]

    def gap(a, b):      # smallest distance between two parts, all face pairs
        return triangle_distance(np.repeat(a, len(b), axis=0), np.tile(b, (len(a), 1, 1))).min()

    gaps = [(i, j) for i in range(parts.n_parts) for j in range(i + 1, parts.n_parts)      # 21 parts
            if 0.5 * weld < gap(tri[i], tri[j]) <= weld]
    assert len(gaps) >= 2
    for i, j in gaps:
        pair = trimesh.Trimesh(np.vstack([tri[i], tri[j]]).reshape(-1, 3), np.arange(3 * (len(tri[i]) + len(tri[j]))).reshape(-1, 3))
        assert _bodies(pair, weld).n_bodies == 1 and _bodies(pair, 0.0).n_bodies == 2


@pytest.mark.parametrize("name,kwargs,bodies", [
    ("two_plates", {}, 2),
    ("near_touching_boxes", {"gap": 0.01}, 2),
    ("slatted_chair", {}, 1),
    ("toy_truck", {}, 2),          # the cargo cover floats 2.5 mm above the bed's walls (weld 2 mm)
])
def test_the_number_of_bodies_does_not_change_with_the_resolution(name, kwargs, bodies):
    mesh = getattr(shapes, name)(**kwargs)
    counts = [sc_fem.voxelize(mesh, resolution=r).n_components for r in (8, 16, 32, 64)]
    assert counts == [bodies] * 4
    # the seed's grid glues them where they share cubes: the count changes with the resolution
    if name == "two_plates":
        assert sc_fem.voxelize(mesh, resolution=8, topology="grid", keep="all").n_components == 1
    if name == "near_touching_boxes":
        grid = [sc_fem.voxelize(mesh, resolution=r, topology="grid", keep="all").n_components for r in (8, 64)]
        assert grid == [1, 2]


# ------------------------------------------------------------------ two plates a third of a cube apart
def _plates(r: int):
    """Two 0.5 m plates a third of a cube thick and a third of a cube apart: mirror images of each
    other in one layer of cubes, so each must vibrate exactly like the bottom one alone."""
    third = 0.5 / r / 3
    return shapes.two_plates(gap=third, t=third)


@pytest.mark.parametrize("r", [8, 16, 32])
def test_two_plates_a_third_of_a_cube_apart_are_two_free_plates(r):
    pair = sc_fem.voxelize(_plates(r), resolution=r)
    assert pair.n_components == 2 and pair.shares_cells
    basis = sc_fem.modal(pair, n_modes=8, keep_rigid=True)
    assert int(np.asarray(basis.rigid).sum()) == 12
    alone_mesh = shapes.parts(_plates(r))
    alone_mesh = min(alone_mesh, key=lambda m: m.bounds[0, 2])                       # the bottom plate
    alone = sc_fem.modal(sc_fem.voxelize(alone_mesh, pitch=0.5 / r), n_modes=4)
    f_pair = np.asarray(basis.frequencies)[~np.asarray(basis.rigid)]
    # every plate mode appears twice (once per plate), at the frequency of the plate alone
    np.testing.assert_allclose(f_pair[0:8:2], alone.frequencies, rtol=0.01)
    np.testing.assert_allclose(f_pair[1:8:2], alone.frequencies, rtol=0.01)
    glued = sc_fem.modal(sc_fem.voxelize(_plates(r), resolution=r, topology="grid"), n_modes=4)
    assert glued.frequencies[0] > 2.0 * alone.frequencies[0]                        # the seed's cubes glue them


def test_each_vertex_follows_its_own_plate_and_linear_fields_are_reproduced():
    mesh = _plates(8)
    model = sc_fem.voxelize(mesh, resolution=8)
    v = np.asarray(mesh.vertices)
    emb = embedding(model, v)
    assert emb.n_detached == 0
    np.testing.assert_allclose(emb.W @ model.nodes, v, atol=1e-12)                 # x itself: a linear field
    top = v[:, 2] > 0.5 * v[:, 2].max()
    W = emb.W.tocsr()
    for rows, body in ((np.flatnonzero(top), model.piece_at(v[top][:1])[0]),
                       (np.flatnonzero(~top), model.piece_at(v[~top][:1])[0])):
        used = np.unique(W[rows].indices)
        node_body = np.zeros(model.n_nodes, np.int64)
        node_body[model.hexes.ravel()] = np.repeat(model.piece, 8)
        assert np.all(node_body[used] == body)
    assert model.piece_at(v[top]).min() != model.piece_at(v[~top]).max()


def test_split_cubes_assemble_like_scikit_fem_and_keep_twelve_rigid_modes():
    model = sc_fem.voxelize(_plates(8), resolution=8, stiffness="fraction")
    Kf, Mf = assemble(model, "q1")
    Ks, Ms = assemble(model, "q1", method="skfem")
    assert abs(Kf - Ks).max() <= 1e-12 * abs(Ks).max() and abs(Mf - Ms).max() <= 1e-12 * abs(Ms).max()
    # six rigid motions of each plate separately are in the null space of K
    K, _ = assemble(sc_fem.voxelize(_plates(8), resolution=8), "q1i")
    node_body = np.zeros(model.n_nodes, np.int64)
    node_body[model.hexes.ravel()] = np.repeat(model.piece, 8)
    rng = np.random.default_rng(0)
    X = model.nodes_m
    for body in (0, 1):
        w, c = rng.normal(size=3), rng.normal(size=3)
        u = np.where((node_body == body)[:, None], np.cross(w, X) + c, 0.0)
        assert np.abs(K @ u.ravel()).max() <= 1e-9 * abs(K).max() * np.abs(u).max()


def test_patch_test_holds_on_split_cubes():
    """A linear displacement of both plates (each with its own nodes) is an equilibrium state
    of the interior nodes: K u = 0 away from the boundary for u = G x + c on every node."""
    model = sc_fem.voxelize(_plates(8), resolution=8)
    K, _ = assemble(model, "q1i")
    rng = np.random.default_rng(1)
    G = rng.normal(size=(3, 3)) * 1e-3
    u = model.nodes_m @ G.T
    f = (K @ u.ravel()).reshape(-1, 3)
    # the resultant force and moment on each free body vanish for any linear field
    node_body = np.zeros(model.n_nodes, np.int64)
    node_body[model.hexes.ravel()] = np.repeat(model.piece, 8)
    for body in (0, 1):
        sel = node_body == body
        assert np.abs(f[sel].sum(axis=0)).max() <= 1e-9 * np.abs(f).max()


def test_pieces_round_trip_through_model_files_and_vtu(tmp_path):
    import meshio

    from sc_fem.io.model import load_model, save_model

    model = sc_fem.voxelize(_plates(8), resolution=8)
    back = load_model(save_model(model, tmp_path / "m.npz"))
    assert back.n_nodes == model.n_nodes and np.array_equal(back.piece, model.piece)
    assert np.array_equal(back.hexes, model.hexes) and back.n_components == 2
    vtu = meshio.read(save_model(model, tmp_path / "m.vtu"))
    assert sorted(set(vtu.cell_data["body"][0].tolist())) == [0, 1]


def test_bad_weld_and_topology_get_one_clear_error():
    with pytest.raises(sc_fem.errors.InputError, match="weld"):
        sc_fem.VoxelOptions(weld=-1.0)
    with pytest.raises(sc_fem.errors.InputError, match="topology"):
        sc_fem.VoxelOptions(topology="voxels")


# ------------------------------------------------------------------ everything downstream
def _plates_scene(r=8, **kw):
    return sc_fem.Scene.from_mesh(_plates(r), sc_fem.VoxelOptions(resolution=r, youngs=1e6, density=1000.0), **kw)


@pytest.mark.parametrize("method", ["newmark", "corotational", "central"])
def test_striking_one_plate_leaves_the_other_still(method):
    from sc_fem.dynamics.job import run_simulation

    scene = _plates_scene()
    v = scene.rest_vertices
    top = v[:, 2] > 0.5 * v[:, 2].max()
    rec = run_simulation(scene, duration=0.1, method=method, impulses=[(int(np.flatnonzero(top)[0]), 0, 0, 0.01)])
    d = np.asarray(rec.points) - v[None]
    assert np.abs(d[:, top]).max() > 1e-4
    assert np.abs(d[:, ~top]).max() == 0.0          # no node, no impulse patch, no cube shared
    grid = sc_fem.Scene.from_mesh(_plates(8), sc_fem.VoxelOptions(resolution=8, youngs=1e6, density=1000.0,
                                                                   topology="grid"))
    rec = run_simulation(grid, duration=0.1, method=method, impulses=[(int(np.flatnonzero(top)[0]), 0, 0, 0.01)])
    assert np.abs(np.asarray(rec.points)[:, ~top] - v[None, ~top]).max() > 1e-5     # the seed's cubes glue them


def test_xpbd_sags_the_two_cantilever_plates_alike():
    from sc_fem.dynamics.job import run_simulation

    scene = _plates_scene(fix="x<min+0.01")
    v = scene.rest_vertices
    top = v[:, 2] > 0.5 * v[:, 2].max()
    d = np.asarray(run_simulation(scene, duration=0.1, method="xpbd", gravity=gravity_down()).points)[-1] - v
    # mirror images in one layer of cubes, each clamped at its own edge: the same sag
    assert d[top, 2].min() < -0.01
    assert d[top, 2].min() == pytest.approx(d[~top, 2].min(), rel=0.02)


def test_ipc_drops_one_plate_onto_the_other_without_passing_through():
    from sc_fem.dynamics.job import run_simulation

    scene = _plates_scene()
    v = scene.rest_vertices
    top = v[:, 2] > 0.5 * v[:, 2].max()
    rec = run_simulation(scene, duration=0.3, method="ipc", gravity=gravity_down(), ground=-0.001,
                         impulses=[(int(i), 0, 0, -0.05) for i in np.flatnonzero(top)])
    p = np.asarray(rec.points)
    gap = p[:, top, 2].min(axis=1) - p[:, ~top, 2].max(axis=1)
    assert gap[0] == pytest.approx(0.5 / 8 / 3)
    assert 0.0 < gap.min() and gap[-1] < 0.1 * gap[0]           # it landed on the other plate, not through it
    assert p[:, ~top, 2].min() > -0.001                          # which rests on the ground


def test_mode_files_and_gltf_on_split_cubes(tmp_path):
    from sc_fem.io.gltf import export_gltf
    from sc_fem.io.modes import load_modes, save_modes

    basis = sc_fem.modal(_plates_scene(), n_modes=4, keep_lattice=True)
    back = load_modes(save_modes(basis, tmp_path / "p.modes.npz"))
    assert np.array_equal(back.lattice.piece, basis.lattice.piece)
    np.testing.assert_allclose(back.frequencies, basis.frequencies)
    v = basis.vertices
    top = v[:, 2] > 0.5 * v[:, 2].max()
    # the lowest modes come in degenerate pairs (mirror-image plates), and the pair's span holds a
    # motion of the top plate alone: the two modes restricted to the bottom plate are parallel
    assert basis.frequencies[1] == pytest.approx(basis.frequencies[0], rel=1e-6)
    bottom = np.stack([basis.modes[0][~top].ravel(), basis.modes[1][~top].ravel()], axis=1)
    sv = np.linalg.svd(bottom, compute_uv=False)
    assert sv[1] <= 1e-6 * sv[0]
    assert export_gltf(back, tmp_path / "p.glb").stat().st_size > 0


def test_component_labels_of_bodies_match_ndimage_on_one_body():
    """Loop-free graph labelling of (cell, body) neighbours against scipy.ndimage on one body, and
    against a breadth-first loop oracle with two bodies sharing cells."""
    from scipy import ndimage

    from sc_fem.lattice.topology import CONNECTIVITY, piece_labels

    rng = np.random.default_rng(5)
    dims = np.array([7, 6, 5])
    cells = np.argwhere(rng.random(tuple(dims)) < 0.35)
    for conn in ("face", "edge", "vertex"):
        lab, n = piece_labels(cells, dims, conn, np.zeros(len(cells), np.int64))
        grid = np.zeros(tuple(dims), bool)
        grid[tuple(cells.T)] = True
        ref, n_ref = ndimage.label(grid, ndimage.generate_binary_structure(3, CONNECTIVITY[conn]))
        assert n == n_ref and np.array_equal(lab, ref[tuple(cells.T)] - 1)
    # two bodies: every cell twice; a loop oracle (BFS over cubes) gives the same partition
    both = np.vstack([cells, cells])
    piece = np.r_[np.zeros(len(cells), np.int64), np.ones(len(cells), np.int64)]
    order = np.lexsort((piece, *np.ravel_multi_index(both.T, dims)[None]))
    both, piece = both[order], piece[order]
    lab, n = piece_labels(both, dims, "face", piece)
    seen = -np.ones(len(both), np.int64)
    pos = {(tuple(c), p): i for i, (c, p) in enumerate(zip(both.tolist(), piece.tolist()))}
    k = 0
    for i in range(len(both)):                      # the oracle loops over cubes
        if seen[i] >= 0:
            continue
        stack, seen[i] = [i], k
        while stack:
            j = stack.pop()
            for d in np.vstack([np.eye(3, dtype=int), -np.eye(3, dtype=int)]):
                nb = pos.get((tuple(both[j] + d), int(piece[j])))
                if nb is not None and seen[nb] < 0:
                    seen[nb] = k
                    stack.append(nb)
        k += 1
    assert n == k
    assert len(np.unique(np.stack([lab, seen], 1), axis=0)) == n           # the same partition
