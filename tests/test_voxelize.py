"""voxelize: grid fitting, hashing (vs a loop oracle), mass and material, fill, components,
the coverage guarantee of the default sampler, sample vs exact, memory guard and bad input."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import sc_fem
from sc_fem.errors import InputError, MaterialError, ResolutionError, ScFemError
from sc_fem.lattice.grid import grid_for, hash_samples


def box_mesh(extents, corner=(0.0, 0.0, 0.0)):
    m = trimesh.creation.box(extents=extents)
    m.apply_translation(np.asarray(corner) + np.asarray(extents) / 2)
    return m


# ---------------------------------------------------------------- grid and hashing
def test_box_multiple_of_pitch_gives_exact_cube_count():
    m = sc_fem.voxelize(box_mesh([1.0, 0.5, 0.25]), pitch=0.125, fill="solid")
    assert tuple(m.dims) == (8, 4, 2) and m.n_cubes == 64
    m2 = sc_fem.voxelize(box_mesh([1.0, 0.5, 0.25]), resolution=8, fill="solid")
    assert m2.n_cubes == 64 and m2.pitch == pytest.approx(0.125)
    shell = sc_fem.voxelize(box_mesh([1.0, 0.5, 0.25]), resolution=8, fill="surface")
    assert shell.n_cubes == 64          # 2 cubes thick: every cube touches the surface


def test_grid_for_and_scale():
    origin, pitch, dims = grid_for(np.array([[0, 0, 0], [2.0, 1.0, 0.0]]), resolution=4)
    assert pitch == 0.5 and tuple(dims) == (4, 2, 1)
    m = sc_fem.voxelize(box_mesh([100.0, 10.0, 10.0]), resolution=10, scale=0.001, fill="solid", density=1000.0)
    assert m.h == pytest.approx(0.01)
    assert m.total_mass == pytest.approx(1000.0 * 0.1 * 0.01 * 0.01)   # 100 x 10 x 10 mm of water


def _hash_oracle(points, masses, values, origin, pitch, dims):
    acc = {}
    for p, mm, *vals in zip(points, masses, *values.values()):
        key = tuple(min(max(int(np.floor((p[d] - origin[d]) / pitch)), 0), dims[d] - 1) for d in range(3))
        a = acc.setdefault(key, [0.0] + [0.0] * len(values))
        a[0] += mm
        for i, v in enumerate(vals):
            a[1 + i] += mm * v
    keys = sorted(acc)
    return (np.array(keys), np.array([acc[k][0] for k in keys]),
            {name: np.array([acc[k][1 + i] / acc[k][0] for k in keys]) for i, name in enumerate(values)})


def test_hash_samples_matches_loop_oracle(rng):
    pts = rng.uniform(-1, 1, size=(3000, 3))
    pts[:5] = 1.0                                                   # on the upper faces
    masses = rng.uniform(0.1, 2.0, 3000)
    vals = {"E": rng.uniform(1e6, 1e9, 3000), "nu": rng.uniform(0.0, 0.45, 3000)}
    origin, pitch, dims = grid_for(np.array([[-1.0] * 3, [1.0] * 3]), resolution=7)
    cells, mass, avg = hash_samples(pts, masses, vals, origin, pitch, dims)
    c2, m2, a2 = _hash_oracle(pts, masses, vals, origin, pitch, dims)
    np.testing.assert_array_equal(cells, c2)
    np.testing.assert_allclose(mass, m2, rtol=1e-12)
    for k in vals:
        np.testing.assert_allclose(avg[k], a2[k], rtol=1e-12)
    assert np.all(cells < dims)
    # quantities of a few samples summed per cube (the cut cubes' moments): against a loop
    rows = rng.choice(3000, 400, replace=False)
    extra = rng.normal(size=(400, 27))
    _, _, got = hash_samples(pts, masses, vals, origin, pitch, dims, row_sums={"m": (rows, extra)})
    want = np.zeros((len(cells), 27))
    lin = np.ravel_multi_index(cells.T, dims)
    for r, e in zip(rows, extra):                                    # loop over samples: the oracle
        i = np.clip(np.floor((pts[r] - origin) / pitch).astype(int), 0, dims - 1)
        want[np.searchsorted(lin, np.ravel_multi_index(i, dims))] += e
    np.testing.assert_allclose(got["m"], want, rtol=1e-12, atol=1e-12)


# ---------------------------------------------------------------- mass and material
def test_total_mass_is_conserved_and_split_by_area():
    mesh = sc_fem.load_mesh("builtin:chair")
    m = sc_fem.voxelize(mesh, resolution=24, mass=3.5)
    assert m.total_mass == pytest.approx(3.5, rel=1e-12)
    # shells: rho * area * thickness, plus the floor volume of cubes only a vertex reaches
    m2 = sc_fem.voxelize(mesh, resolution=24, density=900.0, keep="all", fill="surface", shell_thickness=0.004)
    floor = m2.info["floor_cubes"] * m2.pitch**3 / (2 * 4**3)
    assert m2.info["shell_parts"] == 9 and m2.info["floor_cubes"] < 0.05 * m2.n_cubes
    assert m2.total_mass == pytest.approx(900.0 * (mesh.area * 0.004 + floor), rel=1e-9)


def test_solid_mass_is_density_times_volume():
    m = sc_fem.voxelize(box_mesh([1.0, 1.0, 1.0]), resolution=5, fill="solid", density=2.0)
    assert m.n_cubes == 125
    np.testing.assert_allclose(m.mass, 2.0 * 0.2**3)


def test_per_face_and_callable_materials_are_mass_averaged():
    a = box_mesh([1.0, 1.0, 1.0])
    b = box_mesh([1.0, 1.0, 1.0], corner=(1.0, 0.0, 0.0))
    mesh = sc_fem.load_mesh((np.vstack([a.vertices, b.vertices]), np.vstack([a.faces, b.faces + 8])))
    E = np.r_[np.full(12, 1e6), np.full(12, 3e6)]
    # shells: every sample carries its face's material
    m = sc_fem.voxelize(mesh, pitch=0.5, youngs=E, poisson=0.3, density=1000.0, fill="surface")
    left = m.cell_centers[:, 0] < 1.0       # samples on the shared plane x = 1 hash to the upper cell
    right = m.cell_centers[:, 0] > 1.5
    np.testing.assert_allclose(m.youngs[left], 1e6)
    np.testing.assert_allclose(m.youngs[right], 3e6)
    mid = ~left & ~right            # the cubes just above x = 1 hold samples of both boxes
    assert np.all((m.youngs[mid] > 1e6) & (m.youngs[mid] < 3e6))
    # solids: volume samples take the material of the nearest face
    solid = sc_fem.voxelize(mesh, pitch=0.5, youngs=E, poisson=0.3, density=1000.0, fill="solid")
    np.testing.assert_allclose(solid.youngs[solid.cell_centers[:, 0] < 0.5], 1e6)
    np.testing.assert_allclose(solid.youngs[solid.cell_centers[:, 0] > 1.5], 3e6)
    # callable of position, solid fill: interior volume samples see the field too
    m2 = sc_fem.voxelize(a, pitch=0.25, fill="solid", youngs=lambda p: 1e6 * (1 + p[:, 2]))
    np.testing.assert_allclose(m2.youngs, 1e6 * (1 + m2.cell_centers[:, 2]), rtol=1e-12)


@pytest.mark.parametrize("kw, match", [
    ({"youngs": -1.0}, "Young"), ({"youngs": 0.0}, "Young"), ({"poisson": 0.5}, "Poisson"),
    ({"poisson": -1.0}, "Poisson"), ({"poisson": np.nan}, "Poisson"), ({"density": 0.0}, "density"),
    ({"youngs": np.ones(5)}, "per-face"),
])
def test_bad_material(kw, match):
    with pytest.raises(ScFemError, match=match):
        sc_fem.voxelize(box_mesh([1, 1, 1]), resolution=4, **kw)


# ---------------------------------------------------------------- fill and components
def test_solid_fill_names_the_cells_its_samples_lie_in():
    """The cells :func:`sc_fem.lattice.fill.solid_fill` returns are those its samples hash to (the
    voxelizer marks them instead of hashing every sample again): closed boxes that overlap, a
    leaky sphere, in millimetres 3 m off the origin."""
    from sc_fem.geometry.sampling import Samples, surface_grid_samples
    from sc_fem.lattice.fill import solid_fill
    from sc_fem.lattice.mass import _occupied_cells, _solid_parts
    from sc_fem.lattice.topology import unique_cells, voxel_index

    s = trimesh.creation.icosphere(3, radius=0.4)
    leaky = trimesh.Trimesh(s.vertices + [1.5, 0.5, 0.5], s.faces[s.face_normals[:, 2] < 0.7], process=False)
    a = trimesh.creation.box(bounds=[[0, 0, 0], [1, 1, 1]])
    b = trimesh.creation.box(bounds=[[0.5, 0.3, 0.2], [1.2, 0.9, 0.8]])
    mesh = trimesh.util.concatenate([a, b, leaky])
    v, f = np.asarray(mesh.vertices) * 1000.0 + 3000.0, np.asarray(mesh.faces)
    origin, pitch, dims = grid_for(np.array([v.min(0), v.max(0)]), pitch=float(np.ptp(v, axis=0).max()) / 20)
    surf = surface_grid_samples(v, f, 0.25 * pitch)
    parts, solid_part = _solid_parts(v, f, "auto")
    assert solid_part.all() and not parts.watertight.all()
    occupied, _ = _occupied_cells(surf, v, f, (origin, pitch, dims), "sampled")
    pieces, cells = solid_fill(occupied, v, parts, solid_part, surf, origin, pitch, 4)
    samples = Samples.concat(pieces)
    assert len(samples) > len(cells) > 0
    np.testing.assert_array_equal(unique_cells(cells, dims), unique_cells(voxel_index(samples.points, origin, pitch, dims), dims))


def test_solid_fill_of_closed_and_leaky_shells():
    closed = sc_fem.voxelize(box_mesh([1, 1, 1]), resolution=10, fill="solid")
    assert closed.n_cubes == 1000
    assert closed.total_mass == pytest.approx(1000.0, rel=1e-9)      # rho V, default rho = 1000
    shell = sc_fem.voxelize(box_mesh([1, 1, 1]), resolution=10, fill="surface")
    assert shell.n_cubes == 1000 - 8**3
    open_box = box_mesh([1, 1, 1])
    open_box.update_faces(np.abs(open_box.face_normals[:, 2] - 1) > 1e-9)   # remove the lid: a big hole
    # the winding number still sees the inside below the missing lid (no flood-fill leak) ...
    leaky = sc_fem.voxelize(open_box, resolution=10, fill="solid")
    assert leaky.n_cubes == 1000 and leaky.total_mass == pytest.approx(1000.0, rel=0.01)
    # ... and "auto" calls a cup missing one side of six closed (closure 5/6 > 3/4)
    assert sc_fem.voxelize(open_box, resolution=10).info["solid_parts"] == 1


def test_a_leaky_solids_cut_cubes_carry_the_moments_of_their_inside_subcubes():
    """A sphere with holes (a leaky solid, off the grid): every cube's 27 moments are the sum over its
    inside sub-cubes (winding number > 1/2 at the sub-cube centre) of their box moments -- per cube,
    in a loop, as the samples were once summed one by one."""
    from sc_fem.geometry.inside import boundary_cone, winding_number
    from sc_fem.lattice.moments import box_moments

    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    sphere.apply_translation([0.13, -0.07, 0.21])
    sphere.update_faces(np.arange(len(sphere.faces)) % 37 != 0)        # 35 holes: leaky, still a solid
    model = sc_fem.voxelize(sphere, resolution=6, fill="solid")
    n = 4                                                              # the default sub-samples per edge
    offs = (np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) / n
    sub = box_moments(offs - 0.5 / n, 1.0 / n)
    v, f = np.asarray(sphere.vertices), np.asarray(sphere.faces)
    cone = boundary_cone(v, f)
    cut = 0
    for c, got in zip(model.cells, model.moments):                     # loop over cubes: the oracle
        w = winding_number(v, f, model.origin + model.pitch * (c + offs), cone)
        want = sub[w > 0.5].sum(axis=0)
        if 0 < (w > 0.5).sum() < len(offs):
            cut += 1
            np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert cut > 20


def test_components_keep_and_connectivity():
    a = box_mesh([0.9, 0.9, 0.9])                      # cells 0..3 along each axis
    b = box_mesh([0.4, 0.4, 0.4], corner=(3, 0, 0))     # cells 12..13 along x, 0..1 along y, z
    mesh = trimesh.util.concatenate([a, b])
    allm = sc_fem.voxelize(mesh, pitch=0.25, fill="solid", keep="all")
    assert allm.n_components == 2 and list(allm.component_sizes) == [64, 8]
    big = sc_fem.voxelize(mesh, pitch=0.25, fill="solid", keep="largest")
    assert big.n_cubes == 64 and big.info["components_found"] == 2 and big.info["dropped_cubes"] == 8
    # the default keeps every body that is not loose: the small box is 1/8 of the large one's mass
    both = sc_fem.voxelize(mesh, pitch=0.25, fill="solid")
    assert both.n_cubes == 72 and both.info["bodies"] == 2 and both.info["dropped_cubes"] == 0
    # two cubes touching along an edge only: separate with face connectivity, joined with edge
    cells = np.array([[0, 0, 0], [1, 1, 0]])
    m1 = sc_fem.CubeModel.from_cells(cells, origin=[0, 0, 0], pitch=1.0, mass=1, youngs=1, poisson=0.3, density=1)
    m2 = sc_fem.CubeModel.from_cells(cells, origin=[0, 0, 0], pitch=1.0, mass=1, youngs=1, poisson=0.3,
                                     density=1, connectivity="edge")
    assert m1.n_components == 2 and m2.n_components == 1


def test_hexes_follow_skfem_corner_order():
    m = sc_fem.CubeModel.box((3, 2, 2), 0.5)
    corners = m.nodes[m.hexes] - m.nodes[m.hexes[:, :1]]
    np.testing.assert_allclose(corners, 0.5 * sc_fem.lattice.cubes.HEX_CORNERS[None].repeat(m.n_cubes, 0))
    sk = m.to_skfem()
    assert sk.t.shape == (8, 12) and np.allclose(sk.p.T, m.nodes_m)


# ---------------------------------------------------------------- coverage guarantee
def _dense_surface_points(mesh, n, seed):
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return pts


@pytest.mark.parametrize("name, res", [("chair", 24), ("bridge", 40), ("rope", 32), ("beam", 16)])
def test_default_sampling_covers_every_cube_the_surface_enters(name, res):
    mesh = sc_fem.load_mesh(f"builtin:{name}")
    m = sc_fem.voxelize(mesh, resolution=res, keep="all")
    spacing = m.info["spacing"]
    pts = _dense_surface_points(mesh, 200_000, seed=1)
    rel = (pts - m.origin) / m.pitch
    ijk = np.clip(np.floor(rel).astype(int), 0, m.dims - 1)
    depth = np.min(np.minimum(rel - ijk, ijk + 1 - rel), axis=1) * m.pitch
    deep = depth >= spacing
    assert deep.sum() > 1000
    have = set(map(tuple, m.cells))
    missing = [tuple(c) for c in ijk[deep] if tuple(c) not in have]   # loop oracle over test points
    assert missing == []


@pytest.mark.parametrize("name", ["chair", "bridge", "rope"])
def test_sample_cubes_are_a_subset_of_exact_cubes(name):
    s = sc_fem.voxelize(f"builtin:{name}", resolution=32, keep="all")
    e = sc_fem.voxelize(f"builtin:{name}", resolution=32, keep="all", occupancy="exact")
    ss, es = set(map(tuple, s.cells)), set(map(tuple, e.cells))
    assert ss <= es
    # exact adds only cubes the surface grazes (no deeper than the sample spacing)
    assert len(es - ss) == e.info["exact_only_cubes"]
    assert len(es - ss) <= 0.05 * len(es)


def test_random_sampling_option_is_the_papers_scheme():
    m = sc_fem.voxelize("builtin:chair", resolution=16, n_samples=50_000, mass=2.0)
    assert m.info["sampler"] == "random" and m.info["n_samples"] == 50_000
    assert m.total_mass == pytest.approx(2.0)


def test_point_cloud_is_voxelized():
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 1, size=(5000, 3))
    m = sc_fem.voxelize(pts, resolution=4)
    assert m.n_cubes == 64 and m.total_mass > 0


# ---------------------------------------------------------------- guards and bad input
def test_memory_guard_refuses_before_allocating():
    with pytest.raises(ResolutionError, match=r"try resolution <= \d+"):
        sc_fem.voxelize("builtin:beam", resolution=5000, max_memory=200e6)


@pytest.mark.parametrize("kw, exc", [
    ({"resolution": 0}, InputError), ({"resolution": -3}, InputError), ({"resolution": 2.5}, InputError),
    ({"resolution": 10**6}, ResolutionError), ({"pitch": 0.0}, InputError), ({"pitch": -1}, InputError),
    ({"pitch": 1e-9}, ResolutionError), ({"resolution": 4, "pitch": 0.1}, InputError),
    ({"fill": "volume"}, InputError), ({"occupancy": "magic"}, InputError), ({"keep": "some"}, InputError),
    ({"scale": 0}, InputError), ({"mass": -1.0}, InputError), ({"connectivity": "any"}, InputError),
])
def test_bad_arguments(kw, exc):
    with pytest.raises(exc):
        sc_fem.voxelize("builtin:beam", **kw)


def test_all_degenerate_faces_is_a_clear_error():
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]], float)
    with pytest.raises(ScFemError, match="zero area"):
        sc_fem.voxelize((v, np.array([[0, 1, 2]])), resolution=4)
    with pytest.raises(ScFemError, match="needs faces"):
        sc_fem.voxelize(v, resolution=4, occupancy="exact")


def test_zero_mass_material_is_rejected():
    with pytest.raises(MaterialError):
        sc_fem.voxelize("builtin:beam", resolution=4, density=lambda p: np.zeros(len(p)))


def test_method_is_not_an_option_any_more():
    with pytest.raises(sc_fem.errors.InputError, match="unknown voxelize option"):
        sc_fem.voxelize("builtin:beam", resolution=8, method="exact")
    assert sc_fem.voxelize("builtin:beam", resolution=8, occupancy="exact").info["occupancy"] == "exact"

def test_a_face_on_a_grid_plane_occupies_the_cube_of_its_material_only():
    """A box with a post whose joint face lies exactly on a grid plane: the face's samples and
    vertices belong to the solid's cube, not the empty one beyond (which used to become a layer of
    1/128-mass "floor cubes": +0.18 % mass and 60 extra cubes at resolution 8)."""
    import shapes

    m = shapes._union(np.array([[0, 0, 0], [0.4, 0.4, 0.5]]), np.array([[1, 1, 0.5], [0.6, 0.6, 1.0]]))
    for r in (8, 16):
        model = sc_fem.voxelize(m, resolution=r, fill="solid", density=1000.0)
        k = r // 8
        assert model.info["floor_cubes"] == 0
        assert model.n_cubes == (8 * 8 * 4 + 2 * 2 * 4) * k**3            # the base's cells and the post's
        assert model.total_mass == pytest.approx(1000.0 * m.volume, rel=1e-9)
        from sc_fem.lattice.embed import embedding

        emb = embedding(model, m.vertices)
        assert emb.n_detached == 0 and np.abs(emb.W @ model.nodes - m.vertices).max() < 1e-12


def test_a_field_given_twice_with_two_values_is_refused():
    from sc_fem.errors import InputError
    from sc_fem.lattice.options import VoxelOptions

    with pytest.raises(InputError, match="resolution=12 contradicts the voxel options"):
        sc_fem.voxelize("builtin:beam", VoxelOptions(resolution=8), resolution=12)
    same = sc_fem.voxelize("builtin:beam", VoxelOptions(resolution=8), resolution=8, fill="solid")
    assert same.n_cubes == sc_fem.voxelize("builtin:beam", resolution=8, fill="solid").n_cubes


def test_subset_keeping_every_cube_is_the_model_a_rebuild_would_give():
    """``subset`` of every cube returns the model itself; a rebuild from the same cells gives the same
    nodes, hexes and components (two bodies, the toy truck), and dropping one cube still rebuilds."""
    import shapes
    from sc_fem.lattice.cubes import CubeModel

    m = sc_fem.voxelize(shapes.toy_truck(), resolution=24, keep="all")
    assert m.subset(np.ones(m.n_cubes, bool)) is m
    again = CubeModel.from_cells(m.cells, origin=m.origin, pitch=m.pitch, scale=m.scale, dims=m.dims, mass=m.mass,
                                 youngs=m.youngs, poisson=m.poisson, density=m.density, fraction=m.fraction,
                                 stiffness=m.stiffness, moments=m.moments, connectivity=m.connectivity,
                                 info=dict(m.info), piece=m.piece, sites=m.sites, site_piece=m.site_piece)
    for name in ("cells", "nodes", "hexes", "component", "piece", "mass", "moments"):
        np.testing.assert_array_equal(getattr(again, name), getattr(m, name))
    keep = np.ones(m.n_cubes, bool)
    keep[0] = False
    assert m.subset(keep).n_cubes == m.n_cubes - 1
