"""The fast inside tests and moment integrals of voxelization against their oracles.

``crossing_number`` (exact ray crossings) against libigl's exact generalized winding number and
an analytic count with the documented tie rule; its compiled kernel against the numpy path; the
compiled surface integrals against the numpy ones and a point-by-point loop.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import sc_fem
from sc_fem._jit import available as numba_available
from sc_fem.geometry.inside import mesh_parts
from sc_fem.geometry import inside_jit
from sc_fem.geometry.rays import _bin_faces, crossing_number
from sc_fem.lattice.moments import EXPONENTS, _triangle_rule, piece_integrals

KERNELS = ["numpy"] + (["numba"] if numba_available() else [])


def _overlapping_solids() -> trimesh.Trimesh:
    """Intersecting closed solids in general position (rotated boxes, a sphere, a cylinder)."""
    rng = np.random.default_rng(3)
    parts = [trimesh.creation.box(extents=[1.0, 0.4, 0.3]), trimesh.creation.icosphere(2, radius=0.35),
             trimesh.creation.cylinder(radius=0.15, height=1.2)]
    for p in parts:
        p.apply_transform(trimesh.transformations.random_rotation_matrix(rng.random(3)))
        p.apply_translation(0.2 * rng.standard_normal(3))
    return trimesh.util.concatenate(parts)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("source", ["overlap", "builtin:chair"])
def test_crossing_number_is_the_exact_winding_number_of_closed_parts(source, kernel, rng):
    igl = pytest.importorskip("igl")
    mesh = _overlapping_solids() if source == "overlap" else sc_fem.load_mesh(source)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    parts = mesh_parts(v, np.asarray(mesh.faces))
    tf = parts.faces[parts.watertight[parts.label]]
    assert len(tf) > 100
    q = v.min(0) + (v.max(0) - v.min(0)) * rng.random((4000, 3))
    w = np.asarray(igl.winding_number(v, tf, q))
    c = crossing_number(v, tf, q, kernel=kernel)
    assert np.all(c == np.rint(c))
    assert np.abs(c - w).max() < 1e-6
    assert np.unique(c).size >= 3          # the solids overlap: 0, 1 and 2 occur


BOXES = [((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5)), ((0.0, 0.0, -0.25), (1.0, 1.0, 0.75)),
         ((-1.0, -0.25, 0.75), (1.0, 0.25, 1.25))]


@pytest.mark.parametrize("kernel", KERNELS)
def test_points_on_projected_edges_and_vertices_follow_the_tie_rule(kernel):
    """Boxes on a grid, queried at every grid point: many points lie exactly over edges and corners
    of the projected faces. The tie rule moves a point by (d, d^2): it belongs to ``[lo, hi)`` in x
    and y, so the count is analytic; a wrong rule counts an edge twice or not at all."""
    mesh = trimesh.util.concatenate([trimesh.creation.box(bounds=np.array(b)) for b in BOXES])
    g = np.arange(-1.5, 1.51, 0.25)
    q = np.stack(np.meshgrid(g, g, g + 0.125, indexing="ij"), -1).reshape(-1, 3)
    ref = np.zeros(len(q))
    for lo, hi in BOXES:                # 3 boxes, not elements
        lo, hi = np.array(lo), np.array(hi)
        ref += np.all((lo[:2] <= q[:, :2]) & (q[:, :2] < hi[:2]), axis=1) & (lo[2] < q[:, 2]) & (q[:, 2] < hi[2])
    c = crossing_number(mesh.vertices, mesh.faces, q, kernel=kernel)
    on_edge = np.isin(q[:, 0], [-1, -0.5, 0, 0.5, 1]) | np.isin(q[:, 1], [-0.5, -0.25, 0, 0.25, 0.5, 1])
    assert on_edge.sum() > len(q) // 2
    np.testing.assert_array_equal(c, ref)


@pytest.mark.skipif(not numba_available(), reason="the compiled kernel needs numba (extra 'fast')")
def test_compiled_and_numpy_crossings_agree_point_for_point(rng):
    mesh = _overlapping_solids()
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    q = v.min(0) + (v.max(0) - v.min(0)) * rng.random((20000, 3))
    q[:5000] = np.round(q[:5000] * 8) / 8
    q[5000:6000] = v[rng.integers(0, len(v), 1000)]        # on vertices
    np.testing.assert_array_equal(crossing_number(v, f, q, kernel="numba"),
                                  crossing_number(v, f, q, kernel="numpy", max_pairs=5000))


def test_surface_grid_samples_compiled_numpy_and_a_loop_agree(rng):
    """The stratified surface samples: compiled kernel, numpy path and a face-by-face loop (the
    oracle) give the same points, weights and faces; the weights sum to the area."""
    from sc_fem.geometry.sampling import _apex_frame, surface_grid_samples

    mesh = _overlapping_solids()
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    f = np.vstack([f, [[0, 0, 1]]])                                   # a face of zero area: no samples
    spacing = 0.37 * float(np.ptp(v, axis=0).max()) / 20
    got = surface_grid_samples(v, f, spacing, kernel="numpy")
    A, B, C = _apex_frame(v, f)
    pts, w, face = [], [], []
    for k in range(len(f)):                                            # loop over faces: the oracle
        area = 0.5 * np.linalg.norm(np.cross(v[f[k, 1]] - v[f[k, 0]], v[f[k, 2]] - v[f[k, 0]]))
        if area == 0:
            continue
        ks = max(1, int(np.ceil(max(np.linalg.norm(B[k] - A[k]), np.linalg.norm(C[k] - A[k])) / spacing)))
        kt = max(1, int(np.ceil(np.linalg.norm(C[k] - B[k]) / spacing)))
        for i in range(ks):
            for j in range(kt):
                s, t = (i + 0.5) / ks, (j + 0.5) / kt
                pts.append(A[k] + s * (B[k] - A[k]) + s * t * (C[k] - B[k]))
                w.append(2 * area * s / (ks * kt))
                face.append(k)
    np.testing.assert_allclose(got.points, pts, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.weight, w, rtol=1e-12)
    np.testing.assert_array_equal(got.face, face)
    assert got.weight.sum() == pytest.approx(mesh.area, rel=1e-12)
    if numba_available():
        fast = surface_grid_samples(v, f, spacing, kernel="numba")
        for a, b in ((fast.points, got.points), (fast.weight, got.weight), (fast.face, got.face)):
            np.testing.assert_array_equal(a, b)


def test_voxel_index_compiled_and_numpy_agree_on_and_off_the_grid(rng):
    """Cells of points: the compiled kernel and the numpy path agree point for point, on cell
    faces, on the grid's upper faces (the last cell) and outside it (clipped)."""
    from sc_fem.lattice.topology import voxel_index

    origin, pitch, dims = np.array([-1.0, 0.5, -2.0]), 0.125, np.array([16, 8, 40])
    p = origin + pitch * dims * rng.uniform(-0.2, 1.2, (50_000, 3))
    p[:2000] = origin + pitch * rng.integers(0, 41, (2000, 3))          # on cell faces, upper ones too
    want = np.clip(np.floor((p - origin) / pitch).astype(np.int64), 0, dims - 1)
    np.testing.assert_array_equal(voxel_index(p, origin, pitch, dims, kernel="numpy"), want)
    if numba_available():
        np.testing.assert_array_equal(voxel_index(p, origin, pitch, dims, kernel="numba"), want)
        np.testing.assert_array_equal(voxel_index(p[:10], origin, pitch, dims, kernel="numba"), want[:10])


def test_piece_integrals_match_a_loop_oracle_and_the_compiled_kernel(rng):
    origin, pitch = np.array([1.0, -2.0, 0.5]), 0.3
    cells = rng.integers(0, 6, (40, 3))
    pieces = origin + pitch * (cells[:, None, :] + rng.random((40, 3, 3)))
    inner, column = piece_integrals(pieces, cells, origin, pitch, kernel="numpy", chunk=7)
    st, w = _triangle_rule()
    for i in range(3):                  # loop oracle on a few pieces, quadrature point by point
        t = (pieces[i] - origin) / pitch - cells[i]
        az = 0.5 * np.cross(t[1] - t[0], t[2] - t[0])[2]
        ref_in, ref_col = np.zeros(27), np.zeros(9)
        for (s, u), wk in zip(st, w):
            x, y, z = t[0] + s * (t[1] - t[0]) + u * (t[2] - t[0])
            for m, (a, b, c) in enumerate(EXPONENTS):
                ref_in[m] += wk * az * x**a * y**b * z ** (c + 1) / (c + 1)
            for m in range(9):
                ref_col[m] += wk * az * x ** (m // 3) * y ** (m % 3)
        np.testing.assert_allclose(inner[i], ref_in, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(column[i], ref_col, rtol=1e-12, atol=1e-15)
    if numba_available():
        inner_j, column_j = piece_integrals(pieces, cells, origin, pitch, kernel="numba")
        np.testing.assert_allclose(inner_j, inner, rtol=1e-13, atol=1e-16)
        np.testing.assert_allclose(column_j, column, rtol=1e-13, atol=1e-16)


def _bins_by_loop(tri, lo, size, nb):
    """The (bin, face) lists face by face (the oracle of both binning paths)."""
    bins = [[] for _ in range(nb * nb)]
    for f, t in enumerate(tri):                # a loop over faces: the oracle
        b0 = np.clip(np.floor((t[:, :2].min(0) - lo) / size).astype(int), 0, nb - 1)
        b1 = np.clip(np.floor((t[:, :2].max(0) - lo) / size).astype(int), 0, nb - 1)
        for ix in range(b0[0], b1[0] + 1):
            for iy in range(b0[1], b1[1] + 1):
                bins[ix * nb + iy].append(f)
    start = np.r_[0, np.cumsum([len(b) for b in bins])]
    return start, np.array([f for b in bins for f in b], dtype=np.int64)


@pytest.mark.parametrize("kernel", KERNELS)
def test_faces_are_binned_as_a_loop_over_faces_bins_them(kernel, rng):
    mesh = _overlapping_solids()
    tri = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
    lo, hi = tri[:, :, :2].reshape(-1, 2).min(0), tri[:, :, :2].reshape(-1, 2).max(0)
    for nb in (1, 7, 40):
        size = np.maximum(hi - lo, 1e-300) / nb
        start, bin_face = (inside_jit.bin_faces(tri, lo, size, nb) if kernel == "numba"
                           else _bin_faces(tri, lo, size, nb))
        want_start, want_face = _bins_by_loop(tri, lo, size, nb)
        np.testing.assert_array_equal(start, want_start)
        np.testing.assert_array_equal(bin_face, want_face)


@pytest.mark.skipif(not numba_available(), reason="the compiled kernel needs numba (extra 'fast')")
def test_columns_of_points_through_vertices_count_alike_in_both_kernels(rng):
    """Columns of points (through vertices, at the vertices' own heights and others', and on a
    grid): the compiled kernel counts as the numpy path does."""
    mesh = _overlapping_solids()
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    lo, hi = v.min(0), v.max(0)
    cols = (np.stack(np.meshgrid(np.linspace(lo[0], hi[0], 23), np.linspace(lo[1], hi[1], 19),
                                 np.linspace(lo[2], hi[2], 31), indexing="ij"), -1).reshape(-1, 3))
    through = v[rng.integers(0, len(v), 300)]
    heights = v[rng.integers(0, len(v), (300, 7)), 2]
    heights[:, 0] = through[:, 2]                                     # the vertex itself
    on_vertices = np.concatenate([np.broadcast_to(through[:, None, :2], (300, 7, 2)), heights[..., None]], -1)
    q = np.vstack([cols, on_vertices.reshape(-1, 3)])
    assert len(q) > 15000
    np.testing.assert_array_equal(crossing_number(v, f, q, kernel="numba"),
                                  crossing_number(v, f, q, kernel="numpy", max_pairs=5000))


def test_position_ids_are_np_uniques_inverse(rng):
    """The weld's ids: duplicated vertices, signed zeros, points sharing one or two coordinates."""
    from sc_fem.geometry.inside import position_ids

    v = np.round(rng.random((3000, 3)) * 4) / 4 - 0.5                       # many repeats, ties in columns
    v = np.vstack([v, v[:500], [[0.0, -0.0, 0.25], [-0.0, 0.0, 0.25]]])
    ids = position_ids(v)
    np.testing.assert_array_equal(ids, np.unique(v, axis=0, return_inverse=True)[1].reshape(-1))
    assert ids[-1] == ids[-2] and ids.max() + 1 < len(v)
    assert position_ids(np.zeros((0, 3))).shape == (0,)
    scan = rng.random((5000, 3))                                                # distinct first values, but
    scan[::7, 0] = scan[::7, 0][0]                                              # one long run of equal ones,
    scan = np.vstack([scan, scan[::3], scan[:50] * [1, 0, 1]])                  # duplicates and new ties
    for pts in (scan, scan[:, :2], scan[:, :1]):
        np.testing.assert_array_equal(position_ids(pts), np.unique(pts, axis=0, return_inverse=True)[1].reshape(-1))


def test_row_norms_are_numpys_norms_bit_for_bit(rng):
    """The column-wise row norms the sampler uses: the same numbers as ``np.linalg.norm(axis=1)``
    over 16 orders of magnitude, zeros, infinities and NaN included."""
    from sc_fem._arrays import row_norms

    d = rng.standard_normal((100_000, 3)) * 10.0 ** rng.uniform(-8, 8, (100_000, 1))
    d[:10] = 0.0
    d[10, 1], d[11, 2] = np.inf, np.nan
    np.testing.assert_array_equal(row_norms(d), np.linalg.norm(d, axis=1))


def test_column_bounds_are_numpys_reductions(rng):
    """The column-wise bounds: the same numbers as ``min`` / ``max`` over the leading axes, on
    (n, 3) and (n, 3, 3) arrays, the first columns only, integers, and NaN where numpy gives NaN."""
    from sc_fem._arrays import column_bounds

    for a in (rng.standard_normal((1000, 3)) * 1e6, rng.standard_normal((500, 3, 3)), rng.integers(-9, 9, (77, 3))):
        for k in (None, 2):
            lo, hi = column_bounds(a, k)
            cols = a.shape[-1] if k is None else k
            flat = a.reshape(-1, a.shape[-1])[:, :cols]
            np.testing.assert_array_equal(lo, flat.min(axis=0))
            np.testing.assert_array_equal(hi, flat.max(axis=0))
            assert lo.dtype == a.dtype and lo.shape == (cols,)
    a = rng.standard_normal((10, 3))
    a[3, 1] = np.nan
    lo, hi = column_bounds(a)
    assert np.isnan(lo[1]) and np.isnan(hi[1]) and np.isfinite(lo[[0, 2]]).all()
