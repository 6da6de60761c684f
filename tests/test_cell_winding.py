"""Winding numbers on the voxel grid: :func:`sc_fem.geometry.inside.cell_winding` against
:func:`sc_fem.geometry.inside.winding_number` point for point, the cone bound it skips libigl with
against libigl, the compiled ray crossings that reuse a ray against the numpy path, and
:func:`sc_fem.lattice.topology.unique_keys` against ``np.unique``."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import sc_fem
import shapes
from sc_fem._jit import available as numba_available
from sc_fem.geometry import inside_jit
from sc_fem.geometry.cellwinding import CONE_CERTAIN, _cone_certain, _rim_bounds, cell_winding
from sc_fem.geometry.sampling import sub_offsets
from sc_fem.geometry.inside import _fast_winding_number, boundary_cone, winding_number
from sc_fem.geometry.rays import crossing_number
from sc_fem.lattice.grid import grid_for
from sc_fem.lattice.topology import unique_keys, voxel_index

pytest.importorskip("igl")


def _leaky_sphere(y_up: bool = False) -> trimesh.Trimesh:
    """An icosphere with its top cap cut away (one large round hole), 3 m off the origin."""
    s = trimesh.creation.icosphere(3, radius=0.8)
    keep = s.face_normals[:, 2] < 0.7
    m = trimesh.Trimesh(s.vertices + [3.0, -1.0, 2.0], s.faces[keep], process=False)
    if y_up:
        m.vertices = m.vertices[:, [0, 2, 1]] * [1, 1, -1]
    return m


def _holey_box() -> trimesh.Trimesh:
    """A box with two opposite faces' triangles removed at random spots (several small holes) and a
    separate closed sphere: parts of both kinds in one call."""
    b = trimesh.creation.box(extents=[1.0, 0.6, 0.4]).subdivide().subdivide()
    keep = np.ones(len(b.faces), bool)
    keep[np.random.default_rng(5).choice(len(b.faces), 6, replace=False)] = False
    box = trimesh.Trimesh(b.vertices, b.faces[keep], process=False)
    ball = trimesh.creation.icosphere(2, radius=0.2).apply_translation([0.9, 0.0, 0.0])
    return trimesh.util.concatenate([box, ball])


def _grid(v: np.ndarray, res: int):
    b = np.array([v.min(0), v.max(0)])
    return grid_for(b, pitch=float((b[1] - b[0]).max()) / res)


def _in_mm(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    return trimesh.Trimesh(np.asarray(mesh.vertices) * 1000.0 + [2.0e5, 0.0, -7.0e4], mesh.faces, process=False)


def _leaky_soup() -> trimesh.Trimesh:
    """Two leaky spheres that intersect (a self-intersecting soup with two holes)."""
    a = _leaky_sphere()
    b = trimesh.Trimesh(np.asarray(a.vertices) + [0.5, 0.3, 0.1], a.faces, process=False)
    return trimesh.util.concatenate([a, b])


CASES = {"leaky sphere": (_leaky_sphere, 16), "y-up leaky sphere": (lambda: _leaky_sphere(True), 16),
         "leaky sphere in mm": (lambda: _in_mm(_leaky_sphere()), 16), "leaky soup": (_leaky_soup, 16),
         "holey box and ball": (_holey_box, 20), "closed sphere": (lambda: trimesh.creation.icosphere(2), 8),
         "I-beam": (lambda: shapes.i_beam(), 48), "open sheet": (lambda: shapes.open_sheet(), 16)}


KERNELS = ["numpy"] + (["numba"] if numba_available() else [])


@pytest.mark.parametrize("name", sorted(CASES))
@pytest.mark.parametrize("n_sub", [1, 3])
@pytest.mark.parametrize("kernel", KERNELS)
def test_cell_winding_is_the_rounded_winding_number_point_for_point(name, n_sub, kernel, rng):
    """Both ways of counting (compiled column by column, numpy point by point) on every case."""
    make, res = CASES[name]
    mesh = make()
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    origin, pitch, dims = _grid(v, res)
    cells = np.argwhere(np.ones(tuple(dims), bool))
    cells = cells[rng.permutation(len(cells))[: max(len(cells) // 2, 1)]]      # any cells, any order
    pts = origin + pitch * (cells[:, None, :] + sub_offsets(n_sub)[None])
    ref = np.rint(winding_number(v, f, pts.reshape(-1, 3))).reshape(len(cells), -1)
    got = cell_winding(v, f, cells, origin, pitch, n_sub, kernel=kernel)
    np.testing.assert_array_equal(got, ref)
    assert set(np.unique(got)) >= {0.0, 1.0}


@pytest.mark.parametrize("n_sub", [1, 2])
@pytest.mark.parametrize("kernel", KERNELS)
def test_cell_winding_far_from_every_hole_needs_no_cone(n_sub, kernel):
    """Cells far below a leaky sphere's hole, where the bound rules the cone out in every cell: the
    crossings alone, equal to the winding number (0 below the sphere, 1 inside it)."""
    mesh = _leaky_sphere()
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    origin, pitch, dims = _grid(v, 16)
    cells = np.argwhere(np.ones((16, 16, 3), bool))                  # the bottom three layers
    pts = origin + pitch * (cells[:, None, :] + sub_offsets(n_sub)[None])
    ref = np.rint(winding_number(v, f, pts.reshape(-1, 3))).reshape(len(cells), -1)
    got = cell_winding(v, f, cells, origin, pitch, n_sub, kernel=kernel)
    np.testing.assert_array_equal(got, ref)
    assert set(np.unique(got)) == {0.0, 1.0}


@pytest.mark.parametrize("kernel", KERNELS)
def test_cell_winding_set_up_once_gives_what_each_call_alone_gives(kernel, rng):
    """One :class:`CellWinding` called on sets of cells with 1, 3 and 2 points a side (bins of other
    sizes: 20,000 cells and then 8) and again on the first: each result is the fresh call's."""
    from sc_fem.geometry.cellwinding import CellWinding

    mesh = _leaky_soup()
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    origin, pitch, dims = _grid(v, 32)
    every = np.argwhere(np.ones(tuple(dims), bool))
    sets = [(every[rng.permutation(len(every))[:20000]], 1), (every[:3000], 3), (every[-8:], 2)]
    winding = CellWinding(v, f, origin, pitch, kernel=kernel)
    for cells, n_sub in sets + sets[:1]:
        np.testing.assert_array_equal(winding(cells, n_sub), cell_winding(v, f, cells, origin, pitch, n_sub, kernel=kernel))


def test_cell_winding_on_the_bunny_surface_cells_as_the_voxelizer_calls_it():
    """The bunny (5 holes) at 32: the surface cells' 4^3 sub-cube centres, the cone passed in."""
    from conftest import SHARED_MESHES
    path = SHARED_MESHES / "bunny.obj"
    if not path.is_file():
        pytest.skip(f"{path} absent")
    mesh = sc_fem.load_mesh(str(path))
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    origin, pitch, dims = _grid(v, 32)
    cells = np.unique(voxel_index(v, origin, pitch, dims), axis=0)
    cone = boundary_cone(v, f)
    assert len(cone[0]) >= 5
    pts = origin + pitch * (cells[:, None, :] + sub_offsets(4)[None])
    ref = np.rint(winding_number(v, f, pts.reshape(-1, 3), cone)).reshape(len(cells), -1)
    np.testing.assert_array_equal(cell_winding(v, f, cells, origin, pitch, 4, cone), ref)


@pytest.mark.parametrize("name", ["leaky sphere", "holey box and ball"])
def test_cone_bound_holds_at_every_point_of_a_certified_cell(name):
    """Where :func:`_cone_certain` skips libigl, libigl's cone winding number (at 5^3 points of each
    cell, corners included) is below the threshold; and the bound is not vacuous."""
    mesh = CASES[name][0]()
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    origin, pitch, dims = _grid(v, 24)
    apex, cone = boundary_cone(v, f)
    cells = np.argwhere(np.ones(tuple(dims), bool))
    sure = _cone_certain(np.vstack([v, apex]), apex, cone, origin + pitch * (cells + 0.5), 0.5 * np.sqrt(3) * pitch)
    assert 0.2 < sure.mean() < 1.0
    t = np.linspace(0.0, 1.0, 5)
    offs = np.stack(np.meshgrid(t, t, t, indexing="ij"), -1).reshape(-1, 3)
    pts = (origin + pitch * (cells[sure][:, None, :] + offs[None])).reshape(-1, 3)
    cv = np.vstack([v, apex])
    used, local = np.unique(cone, return_inverse=True)
    w = _fast_winding_number(cv[used], local.reshape(-1, 3), pts)
    assert np.abs(w).max() < CONE_CERTAIN


@pytest.mark.skipif(not numba_available(), reason="the compiled kernel needs numba (extra 'fast')")
@pytest.mark.parametrize("n_sub", [1, 2, 4])
def test_column_crossings_agree_with_numpy_also_past_the_ray_cache_and_outside_the_faces(n_sub, rng):
    """Cells in columns through a stack of more thin boxes than :data:`inside_jit.RAY_CACHE` holds
    crossings, columns beside the stack (no face over them) and cells given in any order: the
    compiled column kernel counts what the numpy path counts, and is 1 inside a box and 0 between."""
    n_box = inside_jit.RAY_CACHE // 2 + 10
    boxes = [trimesh.creation.box(bounds=[[0, 0, 2 * i], [1, 1, 2 * i + 1]]) for i in range(n_box)]
    stack = trimesh.util.concatenate(boxes)
    v, f = np.asarray(stack.vertices), np.asarray(stack.faces)
    origin, pitch = np.array([-0.2, -0.2, -0.45]), 0.5      # cells of half a box, no point on a face
    cells = np.argwhere(np.ones((4, 3, 4 * n_box + 2), bool))          # x = 3: beside the stack
    cells = cells[rng.permutation(len(cells))]
    got = cell_winding(v, f, cells, origin, pitch, n_sub, kernel="numba")
    np.testing.assert_array_equal(got, cell_winding(v, f, cells, origin, pitch, n_sub, kernel="numpy"))
    pts = origin + pitch * (cells[:, None, :] + sub_offsets(n_sub)[None])
    in_box = np.all((pts[..., :2] > 0) & (pts[..., :2] < 1), axis=-1) & (pts[..., 2] > 0) \
        & (np.floor(pts[..., 2]) % 2 == 0) & (pts[..., 2] < 2 * n_box)
    np.testing.assert_array_equal(got, in_box.astype(float))


@pytest.mark.skipif(not numba_available(), reason="the compiled kernel needs numba (extra 'fast')")
@pytest.mark.parametrize("name", ["leaky sphere", "holey box and ball", "leaky soup"])
def test_cone_bound_compiled_and_numpy_certify_the_same_cells(name):
    """The first step of :func:`_cone_certain` compiled and in numpy, for cells (half diagonal) and
    for points (0): the same cells, and a loop over cells and pieces for the sums."""
    mesh = CASES[name][0]()
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    origin, pitch, dims = _grid(v, 20)
    apex, cone = boundary_cone(v, f)
    cv = np.vstack([v, apex])
    centres = origin + pitch * (np.argwhere(np.ones(tuple(dims), bool)) + 0.5)
    for h in (0.0, 0.5 * np.sqrt(3) * pitch):
        a = _cone_certain(cv, apex, cone, centres, h, kernel="numba")
        np.testing.assert_array_equal(a, _cone_certain(cv, apex, cone, centres, h, kernel="numpy"))
        assert 0.1 < a.mean() < 1.0
    tri = cv[cone]
    piece = cone[:, 2] - len(v)
    area = np.bincount(piece, weights=0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1))
    radius = np.array([np.linalg.norm(tri[piece == p][:, :2] - apex[p], axis=2).max() for p in range(len(apex))])
    got = np.empty(50)
    inside_jit.area_bounds(centres[:50].copy(), apex, radius, area, 0.1, got)
    ref = [sum(area[p] / (np.linalg.norm(c - apex[p]) - radius[p] - 0.1) ** 2
               if np.linalg.norm(c - apex[p]) - radius[p] - 0.1 > 0 else np.inf for p in range(len(apex))) / (4 * np.pi)
           for c in centres[:50]]                                     # 50 cells, a few pieces: the oracle loop
    np.testing.assert_allclose(got, ref, rtol=1e-12)


@pytest.mark.skipif(not numba_available(), reason="the compiled kernel needs numba (extra 'fast')")
def test_compiled_crossings_reusing_rays_agree_with_numpy_also_past_the_ray_cache(rng):
    """Points in runs along rays (the voxelizer's order) and a ray through more faces than
    :data:`inside_jit.RAY_CACHE` (a stack of thin boxes) count what the numpy path counts."""
    n_box = inside_jit.RAY_CACHE // 2 + 10
    boxes = [trimesh.creation.box(bounds=[[0, 0, 2 * i], [1, 1, 2 * i + 1]]) for i in range(n_box)]
    stack = trimesh.util.concatenate(boxes)
    v, f = np.asarray(stack.vertices), np.asarray(stack.faces)
    xy = rng.random((40, 2)) * 1.2 - 0.1
    z = np.linspace(-1.0, 2.0 * n_box + 1.0, 25)
    q = np.column_stack([np.repeat(xy, len(z), axis=0), np.tile(z, len(xy))])    # 25 points a ray
    q = np.vstack([q, rng.random((300, 3)) * [1, 1, 2 * n_box]])                  # and lone points
    got = crossing_number(v, f, q, kernel="numba")
    np.testing.assert_array_equal(got, crossing_number(v, f, q, kernel="numpy"))
    on = np.all((q[:, :2] > 0) & (q[:, :2] < 1), axis=1)
    assert got[on].max() == 1 and got[on].min() == 0 and got[on].sum() > 100


@pytest.mark.parametrize("size", [50, 10**9])            # the table, and the sort for a sparse range
def test_unique_keys_is_np_unique(size, rng):
    keys = rng.integers(0, size, 3000)
    u, inv = unique_keys(keys, size, return_inverse=True)
    ref_u, ref_inv = np.unique(keys, return_inverse=True)
    np.testing.assert_array_equal(u, ref_u)
    np.testing.assert_array_equal(inv, ref_inv)
    np.testing.assert_array_equal(unique_keys(keys, size), ref_u)
    assert u.dtype == np.int64 and inv.dtype == np.int64


@pytest.mark.parametrize("kernel", ["numpy"] + (["numba"] if numba_available() else []))
def test_voxel_keys_are_the_linear_index_of_the_cells_a_loop_finds(kernel, rng):
    """Points inside, on the faces of and outside a grid (clipped into it), in mm off the origin."""
    from sc_fem.lattice.topology import voxel_keys

    origin, pitch, dims = np.array([5.0e5, -3.0e4, 12.0]), 2.5, np.array([7, 5, 9])
    p = origin + pitch * (rng.random((6000, 3)) * (dims + 2) - 1)
    p[:40] = origin + pitch * rng.integers(0, 6, (40, 3))                   # on grid planes
    got = voxel_keys(p, origin, pitch, dims, kernel=kernel)
    ref = [int(np.ravel_multi_index(voxel_index(p[i:i + 1], origin, pitch, dims, kernel="numpy")[0], dims))
           for i in range(len(p))]                                              # the loop oracle
    np.testing.assert_array_equal(got, ref)


@pytest.mark.parametrize("kernel", ["numpy"] + (["numba"] if numba_available() else []))
def test_mark_cells_marks_each_selected_points_cell_as_a_loop_does(kernel, rng):
    """Points on and off the grid (clipped into it), on cell faces, with a selection: the same grid
    as marking point by point with :func:`voxel_index` (the oracle)."""
    from sc_fem.lattice.topology import mark_cells

    origin, pitch, dims = np.array([-1.0, 2.0, 0.5]), 0.25, np.array([7, 5, 9])
    p = origin + pitch * (rng.random((400, 3)) * (dims + 2) - 1)
    p[:100] = origin + pitch * np.round(rng.random((100, 3)) * dims)        # on cell faces and the grid's
    select = rng.random(len(p)) < 0.6
    ref = np.zeros(tuple(dims), bool)
    for i in np.flatnonzero(select):                                         # point by point: the oracle
        ref[tuple(voxel_index(p[i:i + 1], origin, pitch, dims, kernel="numpy")[0])] = True
    got = mark_cells(np.zeros(tuple(dims), bool), p, origin, pitch, select, kernel=kernel)
    np.testing.assert_array_equal(got, ref)
    assert 0 < ref.sum() < ref.size
    all_ = mark_cells(np.zeros(tuple(dims), bool), p, origin, pitch, kernel=kernel)
    assert all_.sum() > ref.sum() - 1 and np.all(all_ >= ref)
    ref_all = np.zeros(tuple(dims), bool)
    for i in range(len(p)):                                                  # every point: the oracle
        ref_all[tuple(voxel_index(p[i:i + 1], origin, pitch, dims, kernel="numpy")[0])] = True
    np.testing.assert_array_equal(all_, ref_all)


@pytest.mark.skipif(not numba_available(), reason="the compiled kernel needs numba (extra 'fast')")
def test_rim_bounds_compiled_numpy_and_a_loop_agree(rng):
    """The distance to the cone triangles' boxes and the rims' gradient bound: compiled kernel,
    numpy path and a loop over (centre, triangle) pairs (the oracle)."""
    mesh = _holey_box()
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    apex, cone = boundary_cone(v, f)
    tri = np.vstack([v, apex])[cone]
    c = v.min(0) + np.ptp(v, axis=0) * rng.random((300, 3))
    h = 0.02
    box_f, grad_f = _rim_bounds(c, tri, h, kernel="numba")
    box_n, grad_n = _rim_bounds(c, tri, h, kernel="numpy")
    box_o, grad_o = np.empty(len(c)), np.empty(len(c))
    for i in range(len(c)):                                  # the oracle: centre by centre, triangle by triangle
        near, g = np.inf, 0.0
        for t in tri:
            near = min(near, np.linalg.norm(np.clip(c[i], t.min(0), t.max(0)) - c[i]))
            e = t[1] - t[0]
            s = np.clip(np.dot(c[i] - t[0], e) / np.dot(e, e), 0.0, 1.0)
            d = np.linalg.norm(c[i] - t[0] - s * e) - h
            g += np.linalg.norm(e) / d**2 if d > 0 else np.inf
        box_o[i], grad_o[i] = near, g / (4 * np.pi)
    for box, grad in ((box_f, grad_f), (box_n, grad_n)):
        np.testing.assert_allclose(box, box_o, rtol=1e-12, atol=1e-15)
        np.testing.assert_array_equal(np.isinf(grad), np.isinf(grad_o))
        np.testing.assert_allclose(grad[np.isfinite(grad)], grad_o[np.isfinite(grad_o)], rtol=1e-10)
    assert np.isfinite(grad_o).sum() > 100


@pytest.mark.parametrize("inside_out", [False, True])
def test_parts_keep_the_cone_of_their_faces_unless_they_flipped_a_part(inside_out):
    """:func:`mesh_parts` hands its cone on (the solid fill reuses it): it is the cone of the faces
    it returns; a leaky part turned outward afterwards (an inside-out scan) leaves none."""
    from sc_fem.geometry.inside import mesh_parts

    mesh = _leaky_sphere()
    f = np.asarray(mesh.faces)[:, ::-1] if inside_out else np.asarray(mesh.faces)
    parts = mesh_parts(mesh.vertices, f)
    assert parts.closed.all() and not parts.watertight.any()
    if inside_out:
        assert parts.cone is None
        return
    apex, cone = boundary_cone(np.asarray(mesh.vertices, float), parts.faces)
    np.testing.assert_array_equal(parts.cone[0], apex)
    np.testing.assert_array_equal(parts.cone[1], cone)
    assert len(cone) > 0


def test_parts_cone_after_turning_inside_out_closed_parts_is_that_of_the_faces_returned():
    """Closed parts given inside out are turned outward before the cone is taken: with a leaky
    sphere, two inside-out closed boxes (one touching the sphere, unwelded duplicate vertices) and
    a vertex no face uses, the parts' cone is :func:`boundary_cone` of the faces returned."""
    from sc_fem.geometry.inside import mesh_parts

    sphere = _leaky_sphere()
    boxes = [trimesh.creation.box(bounds=b) for b in ([[3.5, -1.2, 1.5], [4.5, -0.5, 2.5]], [[0, 0, 0], [1, 1, 1]])]
    parts_in = [sphere] + [trimesh.Trimesh(b.vertices, b.faces[:, ::-1], process=False) for b in boxes]
    mesh = trimesh.util.concatenate(parts_in)
    v = np.vstack([mesh.vertices, [[9.0, 9.0, 9.0]]])
    parts = mesh_parts(v, np.asarray(mesh.faces))
    assert parts.watertight.sum() == 2 and not np.array_equal(parts.faces, mesh.faces)
    apex, cone = boundary_cone(v, parts.faces)
    assert len(cone) > 0
    np.testing.assert_array_equal(parts.cone[0], apex)
    np.testing.assert_array_equal(parts.cone[1], cone)


def test_cell_winding_when_the_cone_would_crowd_every_axis_is_libigls_alone(monkeypatch, rng):
    """With no axis along which the cone's faces stay few (forced here), both winding numbers are
    libigl's of the faces alone, and agree."""
    from sc_fem.geometry import inside

    monkeypatch.setattr(inside, "CONE_PAIRS", 0.0)
    mesh = _leaky_sphere()
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    origin, pitch, dims = _grid(v, 12)
    apex, cone = boundary_cone(v, f)
    assert inside._ray_axis(np.vstack([v, apex]), f, cone, 100) is None
    cells = np.argwhere(np.ones(tuple(dims), bool))
    pts = origin + pitch * (cells[:, None, :] + sub_offsets(2)[None])
    ref = np.rint(winding_number(v, f, pts.reshape(-1, 3))).reshape(len(cells), -1)
    np.testing.assert_array_equal(cell_winding(v, f, cells, origin, pitch, 2), ref)
    assert ref.max() == 1 and ref.min() == 0
