"""The generalized winding number of broken meshes: ray crossings of the surface closed by a cone
over its holes, less the cone's own share, against libigl's exact (brute-force) winding number."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import sc_fem
from conftest import SHARED_MESHES
from sc_fem.geometry.inside import _closed, _edge_balance, boundary_cone, position_ids, winding_number

igl = pytest.importorskip("igl")


def _holed_sphere() -> trimesh.Trimesh:
    """A sphere with three holes and two flipped faces."""
    s = trimesh.creation.icosphere(3)
    keep = np.ones(len(s.faces), bool)
    keep[[0, 1, 2, 50, 300, 301]] = False
    f = s.faces[keep].copy()
    f[[10, 200]] = f[[10, 200]][:, ::-1]
    return trimesh.Trimesh(s.vertices, f, process=False)


def _soup() -> trimesh.Trimesh:
    """Self-intersecting open boxes (top removed), an open sheet and loose triangles."""
    rng = np.random.default_rng(5)
    parts = []
    for c in ([0, 0, 0], [0.3, 0.2, 0.1]):
        b = trimesh.creation.box(extents=[1, 0.8, 0.6])
        b.apply_translation(c)
        top = b.triangles_center[:, 2] > 0.29 + c[2]
        parts.append(trimesh.Trimesh(b.vertices, b.faces[~top], process=False))
    sheet = trimesh.Trimesh([[-1, -1, 0.05], [1, -1, 0.05], [1, 1, 0.1], [-1, 1, 0.1]], [[0, 1, 2], [0, 2, 3]])
    loose = trimesh.Trimesh(rng.random((30, 3)) - 0.5, np.arange(30).reshape(10, 3), process=False)
    return trimesh.util.concatenate(parts + [sheet, loose])


def _bunny() -> trimesh.Trimesh:
    """The Stanford bunny: a scan with five holes in its base."""
    path = SHARED_MESHES / "bunny.obj"
    if not path.exists():
        pytest.skip(f"shared test mesh {path} not present")
    return sc_fem.load_mesh(path)


CASES = {"bunny": _bunny, "holed_sphere": _holed_sphere, "soup": _soup, "chair": lambda: sc_fem.load_mesh("builtin:chair")}


@pytest.mark.parametrize("case", sorted(CASES))
def test_winding_number_matches_the_exact_solid_angle_sum(case, rng):
    mesh = CASES[case]()
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    lo, hi = v.min(0), v.max(0)
    far = lo - 0.2 * (hi - lo) + 1.4 * (hi - lo) * rng.random((1500, 3))
    fi = rng.integers(0, len(f), 1500)
    bary = rng.dirichlet([1, 1, 1], 1500)
    near = np.einsum("ij,ijk->ik", bary, v[f[fi]]) + 0.01 * np.linalg.norm(hi - lo) * rng.standard_normal((1500, 3))
    q = np.vstack([far, near])
    exact = np.asarray(igl.winding_number(v, f, q))
    w = winding_number(v, f, q)
    assert np.abs(w - exact).max() < 2e-3
    clear = np.abs(exact - 0.5) > 2e-3
    assert np.array_equal(w[clear] > 0.5, exact[clear] > 0.5)
    assert (exact > 0.25).any() and (exact < 0.25).any()      # the points see both sides


@pytest.mark.parametrize("case", ["bunny", "holed_sphere", "soup"])
def test_the_cone_closes_any_soup(case):
    """Faces plus cone use every edge equally often in both directions (the loop over edges
    in :func:`sc_fem.geometry.inside._closed` is the oracle), so the crossing count is exact."""
    mesh = CASES[case]()
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    apex, cone = boundary_cone(v, f)
    assert len(cone) > 0
    allv = np.vstack([v, apex])
    allf = np.vstack([f, cone])
    wf = position_ids(allv)[allf]
    assert _closed(*_edge_balance(wf)[1:], np.zeros(len(allf), np.int64), 1)[0]
    assert not _closed(*_edge_balance(position_ids(v)[f])[1:], np.zeros(len(f), np.int64), 1)[0]
    # a loop oracle for the number of cone triangles: the open edges, counted one by one
    net: dict = {}
    for a, b in wf[: len(f)][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2).tolist():
        key = (min(a, b), max(a, b))
        net[key] = net.get(key, 0) + (1 if a < b else -1)
    assert sum(abs(n) for n in net.values()) == len(cone)


def test_a_closed_surface_needs_no_cone_and_gets_integers(rng):
    box = trimesh.creation.box(extents=[1, 2, 3])
    apex, cone = boundary_cone(box.vertices, box.faces)
    assert len(cone) == 0 and len(apex) == 0
    q = rng.random((500, 3)) * 4 - 2
    w = winding_number(box.vertices, box.faces, q)
    assert np.array_equal(w, np.rint(w))
    assert np.array_equal(w > 0.5, box.contains(q))


def _heightfield(n: int) -> tuple[np.ndarray, np.ndarray]:
    """An open, gently curved n x n sheet: its one boundary loop is nearly flat, so its cone is a
    fan that covers most of the xy bins."""
    xs, ys = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n), indexing="ij")
    v = np.stack([xs.ravel(), ys.ravel(), 0.05 * np.sin(6 * xs.ravel()) * np.cos(5 * ys.ravel())], axis=1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    return v, np.vstack([np.stack([a, a + n, a + n + 1], 1), np.stack([a, a + n + 1, a + 1], 1)])


def test_a_large_flat_hole_does_not_crowd_the_crossing_bins(rng):
    """The cone over a terrain's rim would put most cone triangles into most xy bins (14 s and 4 GB
    for 318k faces); the rays go along the axis the cone crowds least, or libigl alone takes over."""
    import time

    from sc_fem.geometry.inside import _fast_winding_number, _ray_axis

    v, f = _heightfield(200)
    apex, cone = boundary_cone(v, f)
    assert _ray_axis(np.vstack([v, apex]), f, cone, 1000) is None
    q = rng.random((1000, 3)) - [0, 0, 0.5]
    t0 = time.perf_counter()
    w = winding_number(v, f, q)
    took = time.perf_counter() - t0
    t0 = time.perf_counter()
    ref = _fast_winding_number(v, f, q)
    assert took < 10 * (time.perf_counter() - t0) + 1.0
    # the fallback carries libigl's own far-field error (3e-3 here), not the cone's exactness
    assert np.abs(w - np.asarray(igl.winding_number(v, f, q))).max() < 5e-3 and np.abs(w - ref).max() < 5e-3
    # a vertical flat hole (an open-ended tube along z): crowded seen along z, not along x or y
    tube = trimesh.creation.cylinder(radius=0.3, height=2.0, sections=64)
    side = np.abs(tube.face_normals[:, 2]) < 0.5
    tv, tf = np.asarray(tube.vertices), np.asarray(tube.faces)[side]
    apex, cone = boundary_cone(tv, tf)
    assert _ray_axis(np.vstack([tv, apex]), tf, cone, 1000) in (0, 1)
    qq = rng.random((800, 3)) * [0.8, 0.8, 2.4] - [0.4, 0.4, 1.2]
    assert np.abs(winding_number(tv, tf, qq) - np.asarray(igl.winding_number(tv, tf, qq))).max() < 2e-3


def test_a_point_one_rounding_step_inside_the_last_bin_is_inside():
    from sc_fem._jit import available

    from sc_fem.geometry.rays import crossing_number

    lo, hi = 0.23643249400513433, 19.24620178356058
    box = trimesh.creation.box(bounds=[[lo, 0, 0], [hi, 1, 1]])
    q = np.vstack([[[np.nextafter(hi, -np.inf), 0.5, 0.5]], np.tile([[1.0, 0.5, 0.5]], (36 * 36 * 16 - 1, 1))])
    for kernel in ["numpy"] + (["numba"] if available() else []):
        assert crossing_number(box.vertices, box.faces, q, kernel=kernel)[0] == 1.0, kernel


@pytest.mark.parametrize("case", ["holed_sphere", "soup"])
def test_millimetres_off_origin_and_y_up_change_nothing(case, rng):
    """The same broken mesh in millimetres, 10 m off the origin and turned y-up: the same winding
    numbers at the same (moved) points, against the exact sum; in millimetres off the origin, the
    same cubes and mass."""
    mesh = CASES[case]()
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    turn = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])    # z-up -> y-up
    move = lambda x: 1000.0 * x @ turn.T + [1.0e4, -3.0e3, 5.0e2]          # noqa: E731
    q = v.min(0) + (v.max(0) - v.min(0)) * rng.random((1500, 3))
    w, w_mm = winding_number(v, f, q), winding_number(move(v), f, move(q))
    assert np.abs(w_mm - np.asarray(igl.winding_number(move(v), f, move(q)))).max() < 2e-3
    clear = np.abs(w - 0.5) > 5e-3
    assert np.array_equal(w[clear] > 0.5, w_mm[clear] > 0.5)
    # the grid is fitted to the bounding box, so a turned model gets other cubes: the voxelized
    # comparison is in millimetres and off the origin only
    m = sc_fem.voxelize(trimesh.Trimesh(v, f, process=False), resolution=16)
    m_mm = sc_fem.voxelize(trimesh.Trimesh(1000.0 * v + [1.0e4, -3.0e3, 5.0e2], f, process=False),
                           resolution=16, scale=1e-3)
    assert m_mm.n_cubes == m.n_cubes
    np.testing.assert_allclose(m_mm.mass.sum(), m.mass.sum(), rtol=1e-6)


def test_part_labels_match_a_union_find_loop_numbered_by_first_face(rng):
    """Parts through shared (welded) vertices, numbered in the order of their first face: a
    union-find over the faces one by one is the oracle (shuffled faces of three boxes, two of them
    sharing a corner position through duplicate vertices, a loose triangle and an unused vertex)."""
    from sc_fem.geometry.inside import _part_labels, _weld_used

    boxes = [trimesh.creation.box(bounds=b) for b in ([[0, 0, 0], [1, 1, 1]], [[1, 1, 1], [2, 2, 2]],
                                                       [[5, 0, 0], [6, 1, 1]])]
    tri = trimesh.Trimesh([[9, 9, 9], [9, 10, 9], [10, 9, 9]], [[0, 1, 2]])
    mesh = trimesh.util.concatenate(boxes + [tri])
    v = np.vstack([mesh.vertices, [[-3.0, -3.0, -3.0]]])
    f = np.asarray(mesh.faces)[rng.permutation(len(mesh.faces))]
    wf, rep = _weld_used(v, f)
    got = _part_labels(wf, len(rep))
    parent = list(range(len(rep)))

    def root(i):
        while parent[i] != i:
            i = parent[i]
        return i

    for a, b, c in wf.tolist():
        for x, y in ((a, b), (b, c)):
            parent[root(x)] = root(y)
    first: dict = {}
    ref = [first.setdefault(root(a), len(first)) for a in wf[:, 0].tolist()]
    np.testing.assert_array_equal(got, ref)
    assert got.max() == 2          # the two corner-sharing boxes are one part
