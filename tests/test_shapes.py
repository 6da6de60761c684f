"""Quick checks of the test-mesh library in ``tests/shapes.py``."""

from __future__ import annotations

import itertools

import manifold3d
import numpy as np
import pytest
import shapes
import trimesh

# Stated bounding boxes of the defaults (see the docstrings); metres unless the name says mm.
BOUNDS = {
    "i_beam": [[0, -0.03, 0], [1, 0.03, 0.1]],
    "channel": [[0, -0.025, 0], [1, 0.025, 0.1]],
    "portal_frame": [[-0.5, -0.03, 0], [0.5, 0.03, 1.0]],
    "plate": [[-0.5, -0.25, 0], [0.5, 0.25, 0.01]],
    "two_plates": [[-0.25, -0.25, 0], [0.25, 0.25, 0.015]],
    "table": [[-0.5, -0.3, 0], [0.5, 0.3, 0.75]],
    "slatted_chair": [[-0.25, -0.25, 0], [0.25, 0.25, 0.9]],
    "truss_bridge_mm": [[0, -200, 0], [2000, 200, 300]],
    "toy_truck": [[-0.2, -0.0925, 0], [0.2, 0.0925, 0.17]],
    "open_sheet": [[-0.25, -0.15, 0], [0.25, 0.15, 0.02]],
    "near_touching_boxes": [[-0.1005, -0.05, 0], [0.1005, 0.05, 0.1]],
}


def _manifold(m: trimesh.Trimesh) -> manifold3d.Manifold:
    return manifold3d.Manifold(manifold3d.Mesh(vert_properties=np.asarray(m.vertices, np.float32),
                                               tri_verts=np.asarray(m.faces, np.uint32)))


def _overlap_volumes(mesh: trimesh.Trimesh) -> np.ndarray:
    """Intersection volume of every pair of closed parts (manifold3d)."""
    parts = [_manifold(p) for p in shapes.parts(mesh) if p.is_watertight]
    return np.array([(a ^ b).volume() for a, b in itertools.combinations(parts, 2)])


def test_registry_is_importable_and_complete():
    assert set(shapes.REGISTRY) == set(BOUNDS)
    assert set(shapes.WATERTIGHT) | set(shapes.SOUPS) | set(shapes.OPEN) <= set(shapes.REGISTRY)


@pytest.mark.parametrize("name", sorted(BOUNDS))
def test_builds_small_deterministic_with_stated_bounds(name):
    mesh = shapes.REGISTRY[name]()
    assert isinstance(mesh, trimesh.Trimesh) and 0 < len(mesh.faces) < 5000
    np.testing.assert_allclose(mesh.bounds, BOUNDS[name], atol=1e-6 * np.ptp(BOUNDS[name]))
    assert np.array_equal(mesh.vertices, shapes.REGISTRY[name]().vertices)
    assert mesh.metadata["units"] == ("mm" if name.endswith("_mm") else "m")
    assert len(shapes.parts(mesh)) == mesh.metadata["parts"]


@pytest.mark.parametrize("name", shapes.WATERTIGHT)
def test_watertight_shapes_enclose_volume(name):
    mesh = shapes.REGISTRY[name]()
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert all(p.volume > 0 for p in shapes.parts(mesh))


@pytest.mark.parametrize("name, volume", [
    ("i_beam", 2 * 0.06 * 0.008 + 0.005 * (0.1 - 0.016)),       # flanges + web between them
    ("channel", 2 * 0.05 * 0.008 + 0.005 * (0.1 - 0.016)),
    ("table", 1.0 * 0.6 * 0.02 + 4 * 0.04**2 * 0.73),
    ("plate", 0.005),
])
def test_unions_have_exact_volume(name, volume):
    assert shapes.REGISTRY[name]().volume == pytest.approx(volume, rel=1e-9)


def test_portal_frame_is_one_thin_walled_body():
    mesh = shapes.portal_frame()
    assert mesh.body_count == 1 and mesh.euler_number == 2          # one closed body, no handles
    assert mesh.volume < 0.05 * np.prod(mesh.extents[[0, 2]]) * 0.1  # thin walls, mostly air


def test_separate_bodies_keep_their_gap():
    two = shapes.two_plates(gap=0.004)
    lower, upper = sorted(shapes.parts(two), key=lambda p: p.bounds[0, 2])
    assert upper.bounds[0, 2] - lower.bounds[1, 2] == pytest.approx(0.004)
    for gap in (0.002, 0.0, -0.001):
        a, b = sorted(shapes.parts(shapes.near_touching_boxes(gap)), key=lambda p: p.bounds[0, 0])
        assert b.bounds[0, 0] - a.bounds[1, 0] == pytest.approx(gap)


@pytest.mark.parametrize("name, min_parts", [("slatted_chair", 15), ("truss_bridge_mm", 21), ("toy_truck", 8)])
def test_soups_self_intersect(name, min_parts):
    mesh = shapes.REGISTRY[name]()
    assert mesh.metadata["parts"] >= min_parts
    assert (_overlap_volumes(mesh) > 1e-6 * mesh.volume).sum() >= 3   # several parts pass through others


def test_chair_boxes_overlap_by_bounds():
    b = np.array([p.bounds for p in shapes.parts(shapes.slatted_chair())])   # (n, 2, 3)
    depth = np.minimum(b[:, None, 1], b[None, :, 1]) - np.maximum(b[:, None, 0], b[None, :, 0])
    overlapping = np.all(depth > 1e-4, axis=-1) & ~np.eye(len(b), dtype=bool)
    assert overlapping.sum() // 2 >= 10                                 # axis-aligned boxes: exact test
    legs = np.argsort(-np.ptp(b[:, :, 2], axis=1))[:4]
    assert overlapping[legs].any(axis=1).all()                          # every leg cuts through something


def test_truss_bridge_members():
    mesh = shapes.truss_bridge_mm()
    assert 20 <= mesh.metadata["parts"] - 1 <= 50                       # members, plus the deck
    widths = np.sort(np.array([p.extents for p in shapes.parts(mesh)]), axis=1)
    assert np.sum(np.isclose(widths[:, 0], 20.0)) >= 20                 # thin square members, 20 mm


def test_toy_truck_and_sheet_are_open():
    truck = shapes.toy_truck()
    assert not truck.is_watertight
    parts = shapes.parts(truck)
    assert sum(not p.is_watertight for p in parts) == 3                 # cab, bed, cover
    sheet = shapes.open_sheet()
    assert not sheet.is_watertight and len(sheet.outline().entities) == 1   # one boundary loop
    assert np.all(sheet.face_normals[:, 2] > 0.9)


def test_y_up_is_a_proper_rotation():
    mesh = shapes.i_beam()
    up = shapes.y_up(mesh)
    assert np.linalg.det(shapes.Y_UP[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_allclose(up.bounds[:, 1], mesh.bounds[:, 2])      # old +z extent -> +y
    np.testing.assert_allclose(up.bounds[:, 2], -mesh.bounds[::-1, 1])  # old +y -> -z
    assert up.volume == pytest.approx(mesh.volume) and up.is_watertight
    np.testing.assert_array_equal(mesh.bounds, shapes.i_beam().bounds)  # input untouched


@pytest.mark.parametrize("name", ["table", "slatted_chair", "open_sheet"])
def test_to_millimetres_scales_by_1000(name):
    mesh = shapes.REGISTRY[name]()
    mm = shapes.to_millimetres(mesh)
    np.testing.assert_allclose(mm.extents, 1000 * mesh.extents)
    np.testing.assert_allclose(mm.bounds, 1000 * mesh.bounds)
    assert mm.metadata["units"] == "mm" and mesh.metadata["units"] == "m"


def test_off_origin_and_stacked_on():
    mesh = shapes.table()
    moved = shapes.off_origin(mesh)
    np.testing.assert_allclose(moved.bounds - mesh.bounds, [[1000.0, -500.0, 250.0]] * 2)
    floor = shapes.plate(lx=2.0, ly=2.0, t=0.05)
    scene = shapes.stacked_on(shapes.slatted_chair(), floor, gap=0.01)
    assert scene.metadata["parts"] == 20 and len(shapes.parts(scene)) == 20
    np.testing.assert_allclose(scene.bounds[:, 2], [0.0, 0.05 + 0.01 + 0.9])
    np.testing.assert_allclose(scene.bounds[:, :2], floor.bounds[:, :2])
