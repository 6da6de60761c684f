"""load_mesh: formats, built-ins, arrays, point clouds, scenes, and clear errors on bad input."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import sc_fem
from sc_fem.errors import MeshError, MeshFileError, ScFemError


@pytest.fixture(scope="module")
def chair():
    return sc_fem.load_mesh("builtin:chair")


@pytest.mark.parametrize("ext", ["obj", "stl", "ply", "off", "glb"])
def test_round_trip_trimesh_formats(tmp_path, chair, ext):
    path = tmp_path / f"chair.{ext}"
    chair.export(path)
    m = sc_fem.load_mesh(path)
    assert m.faces.shape[1] == 3 and len(m.faces) == len(chair.faces)
    np.testing.assert_allclose(m.bounds, chair.bounds, atol=1e-6)
    assert len(m.metadata["sha256"]) == 64 and m.metadata["source"] == path.name


def test_vtu_through_meshio_with_quads(tmp_path):
    import meshio

    pts = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1]], float)
    meshio.write(tmp_path / "q.vtu", meshio.Mesh(pts, [("quad", np.array([[0, 1, 2, 3]])),
                                                        ("triangle", np.array([[0, 1, 4]]))]))
    m = sc_fem.load_mesh(tmp_path / "q.vtu")
    assert m.faces.shape == (3, 3)          # the quad became two triangles


def test_arrays_polygons_and_point_cloud():
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.5]], float)
    m = sc_fem.load_mesh((v, np.array([[0, 1, 2, 3]])))
    assert m.faces.shape == (2, 3)
    pc = sc_fem.load_mesh(v)
    assert pc.faces.shape == (0, 3) and len(pc.vertices) == 4
    pc2 = sc_fem.load_mesh(trimesh.PointCloud(v))
    assert pc2.faces.shape == (0, 3)


def test_scene_is_flattened_with_transforms():
    a = trimesh.creation.box(extents=[1, 1, 1])
    scene = trimesh.Scene()
    scene.add_geometry(a, transform=trimesh.transformations.translation_matrix([10, 0, 0]))
    scene.add_geometry(a, transform=trimesh.transformations.translation_matrix([-10, 0, 0]))
    m = sc_fem.load_mesh(scene)
    np.testing.assert_allclose(m.bounds, [[-10.5, -0.5, -0.5], [10.5, 0.5, 0.5]])


def test_builtin_names_and_unknown():
    for name in sc_fem.geometry.models.names():
        assert len(sc_fem.load_mesh(f"builtin:{name}").faces) > 0
    with pytest.raises(ScFemError, match="unknown built-in model 'nope'"):
        sc_fem.load_mesh("builtin:nope")


def test_missing_directory_empty_unknown_corrupted(tmp_path):
    with pytest.raises(MeshFileError, match="not found"):
        sc_fem.load_mesh(tmp_path / "missing.obj")
    with pytest.raises(MeshFileError, match="directory"):
        sc_fem.load_mesh(tmp_path)
    (tmp_path / "empty.obj").write_text("")
    with pytest.raises(MeshError, match="empty"):
        sc_fem.load_mesh(tmp_path / "empty.obj")
    (tmp_path / "x.foo").write_text("hello")
    with pytest.raises(MeshFileError, match="unknown or unsupported format"):
        sc_fem.load_mesh(tmp_path / "x.foo")
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n" + bytes(range(256)))
    with pytest.raises(ScFemError):
        sc_fem.load_mesh(tmp_path / "bad.ply")
    (tmp_path / "junk.obj").write_bytes(b"\x00\x01garbage\nnot an obj\n")
    with pytest.raises(ScFemError):
        sc_fem.load_mesh(tmp_path / "junk.obj")


def test_truncated_binary_stl(tmp_path, chair):
    path = tmp_path / "c.stl"
    chair.export(path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2 + 7])
    with pytest.raises(ScFemError):
        sc_fem.load_mesh(path)


@pytest.mark.parametrize("vertices, faces, match", [
    (np.zeros((0, 3)), np.zeros((0, 3), int), "empty"),
    (np.array([[0, 0, 0], [np.nan, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]), "NaN/inf"),
    (np.array([[0, 0, 0], [np.inf, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]]), "NaN/inf"),
    (np.ones((3, 3)), np.array([[0, 1, 2]]), "zero-extent"),
    (np.eye(3), np.array([[0, 1, 3]]), "do not exist"),
    (np.eye(3), np.array([[0, -1, 2]]), "do not exist"),
    (np.eye(3)[:, :2], np.array([[0, 1, 2]]), r"shape \(n, 3\)"),
])
def test_bad_arrays(vertices, faces, match):
    with pytest.raises(MeshError, match=match):
        sc_fem.load_mesh((vertices, faces))


def test_obj_with_faces_indexing_missing_vertices(tmp_path):
    (tmp_path / "bad.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n")
    with pytest.raises(ScFemError):
        sc_fem.load_mesh(tmp_path / "bad.obj")
