"""Loading source geometry: any format trimesh or meshio reads, built-ins, arrays, point clouds.

:func:`load_mesh` always returns a ``trimesh.Trimesh`` (triangles; a point cloud has
``faces.shape == (0, 3)``) whose ``metadata`` holds ``source`` (a name) and, for files,
``sha256`` of the file bytes. Nothing is welded, repaired or removed: the point of Squashing
Cubes is that broken meshes need no repair.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import MeshError, MeshFileError
from . import models

if TYPE_CHECKING:
    import trimesh

BUILTIN_PREFIX = "builtin:"

# meshio cell types whose faces we triangulate (others -- lines, vertices -- are ignored)
_VOLUME_FACES = {
    "tetra": [[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]],
    "hexahedron": [[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]],
}


def load_mesh(source: Any, *, name: str | None = None) -> trimesh.Trimesh:
    """Load a surface mesh or point cloud from anything reasonable.

    Parameters
    ----------
    source : str, path, trimesh.Trimesh, trimesh.Scene, trimesh.PointCloud, or tuple
        A file path (OBJ, STL, PLY, OFF, GLB/glTF, VTK/VTU and anything else trimesh or meshio
        reads), ``"builtin:NAME"`` (see :mod:`sc_fem.geometry.models`), a trimesh object (scenes are
        flattened with their transforms), ``(vertices (n, 3), faces (m, 3 or 4))`` arrays, or a
        bare ``(n, 3)`` vertex array (a point cloud). Quads and polygons are triangulated.
    name : str, optional
        Label stored in ``metadata["source"]``.

    Returns
    -------
    trimesh.Trimesh
        Vertices ``(n, 3)`` in model units, faces ``(m, 3)`` int (``m`` may be 0).

    Raises
    ------
    MeshFileError
        Missing or unreadable file, unknown format.
    MeshError
        Empty mesh, NaN/inf coordinates, zero-extent bounding box, faces indexing missing vertices.
    """
    import trimesh

    meta: dict[str, Any] = {}
    if isinstance(source, (str, os.PathLike)):
        s = str(source)
        if s.startswith(BUILTIN_PREFIX):
            mesh = models.load(s[len(BUILTIN_PREFIX):])
            vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
            meta = {"source": s, "sha256": _sha256_arrays(vertices, faces)}
        else:
            vertices, faces, meta = _read_file(Path(s))
    elif isinstance(source, trimesh.Scene):
        geom = _flatten_scene(source)
        vertices, faces = np.asarray(geom.vertices), np.asarray(geom.faces)
        meta = {"source": name or "scene"}
    elif isinstance(source, trimesh.Trimesh):
        vertices, faces = np.asarray(source.vertices), np.asarray(source.faces)
        meta = {"source": name or source.metadata.get("source", "trimesh"), **{
            k: v for k, v in source.metadata.items() if k in ("sha256", "file_name")}}
    elif isinstance(source, trimesh.PointCloud):
        vertices, faces = np.asarray(source.vertices), np.zeros((0, 3), dtype=np.int64)
        meta = {"source": name or "point cloud"}
    elif isinstance(source, (tuple, list)) and len(source) == 2 and not np.isscalar(source[0]) \
            and np.asarray(source[0]).ndim == 2:
        vertices, faces = source
        meta = {"source": name or "arrays"}
    else:
        try:
            vertices, faces = np.asarray(source, dtype=float), np.zeros((0, 3), dtype=np.int64)
        except (TypeError, ValueError):
            raise MeshError(f"cannot interpret {type(source).__name__} as a mesh: pass a path, "
                            f"'builtin:NAME', a trimesh object or (vertices, faces) arrays") from None
        meta = {"source": name or "points"}
    if name:
        meta["source"] = name
    vertices, faces = _validate(vertices, faces, meta.get("source", "mesh"))
    if "sha256" not in meta:
        meta["sha256"] = _sha256_arrays(vertices, faces)
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False, metadata=meta)


def _sha256_arrays(vertices: np.ndarray, faces: np.ndarray) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(faces, dtype=np.int64).tobytes())
    return h.hexdigest()


def _flatten_scene(scene):
    import trimesh

    try:
        geom = scene.to_geometry() if hasattr(scene, "to_geometry") else scene.dump(concatenate=True)
    except Exception:  # noqa: BLE001 - trimesh raises various types on odd scenes
        geom = scene.dump(concatenate=True)
    if isinstance(geom, trimesh.PointCloud):
        return trimesh.Trimesh(vertices=geom.vertices, faces=np.zeros((0, 3), int), process=False)
    if isinstance(geom, (list, tuple)):
        geom = trimesh.util.concatenate([g for g in geom if isinstance(g, trimesh.Trimesh)])
    if not isinstance(geom, trimesh.Trimesh):
        raise MeshError("the scene holds no triangle geometry")
    return geom


def _read_file(path: Path) -> tuple[np.ndarray, np.ndarray, dict]:
    import trimesh

    if not path.exists():
        raise MeshFileError(f"mesh file not found: {path}")
    if path.is_dir():
        raise MeshFileError(f"expected a mesh file, got a directory: {path}")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise MeshFileError(f"cannot read {path}: {exc.strerror or exc}") from None
    if not data.strip():
        raise MeshError(f"{path} is empty (0 bytes of geometry)")
    meta = {"source": path.name, "file_name": str(path.name), "sha256": hashlib.sha256(data).hexdigest()}
    ext = path.suffix.lower().lstrip(".")
    errors = []
    if ext in _TRIMESH_NATIVE or (ext in trimesh.available_formats() and not _meshio_knows(ext)):
        try:
            loaded = trimesh.load(str(path), process=False, force=None)
            if isinstance(loaded, trimesh.Scene):
                loaded = _flatten_scene(loaded) if loaded.geometry else None
            if isinstance(loaded, trimesh.PointCloud):
                return np.asarray(loaded.vertices), np.zeros((0, 3), np.int64), meta
            if isinstance(loaded, trimesh.Trimesh):
                return np.asarray(loaded.vertices), np.asarray(loaded.faces), meta
            errors.append("trimesh found no geometry")
        except MeshError:
            raise
        except Exception as exc:  # noqa: BLE001 - third-party readers raise anything
            errors.append(f"trimesh: {type(exc).__name__}: {exc}")
    try:
        import meshio

        # meshio prints to stdout and may call sys.exit() on malformed files: contain both
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            m = meshio.read(str(path))
        return (*_triangulate_meshio(m), meta)
    except MeshError:
        raise
    except (Exception, SystemExit) as exc:  # noqa: BLE001
        errors.append(f"meshio: {type(exc).__name__}: {exc}")
    known = ext in trimesh.available_formats() or _meshio_knows(ext)
    what = "is corrupted or unreadable" if known else f"has an unknown or unsupported format '.{ext}'"
    raise MeshFileError(f"{path} {what} ({'; '.join(e[:200] for e in errors)})")


_TRIMESH_NATIVE = {"obj", "stl", "ply", "off", "glb", "gltf", "3mf", "dae", "zae", "xaml", "json", "dict"}


def _meshio_knows(ext: str) -> bool:
    try:
        import meshio

        return f".{ext}" in meshio.extension_to_filetypes
    except Exception:  # noqa: BLE001
        return False


def _triangulate_meshio(m) -> tuple[np.ndarray, np.ndarray]:
    points = np.asarray(m.points, dtype=float)
    if points.ndim == 2 and points.shape[1] == 2:
        points = np.column_stack([points, np.zeros(len(points))])
    tris = []
    for block in m.cells:
        data = np.asarray(block.data)
        if block.type in ("triangle", "quad") or (block.type == "polygon" and data.ndim == 2):
            polys = data
        elif block.type in _VOLUME_FACES:
            faces = np.asarray(_VOLUME_FACES[block.type])
            polys = data[:, faces].reshape(-1, faces.shape[1])
        else:
            continue
        tris.append(_fan_triangulate(polys))
    faces = np.concatenate(tris) if tris else np.zeros((0, 3), dtype=np.int64)
    return points, faces


def _fan_triangulate(polys: np.ndarray) -> np.ndarray:
    """Triangles (m (k - 2), 3) of convex k-gons (m, k) by fans from each polygon's first vertex."""
    k = polys.shape[1]
    fan = np.stack([np.zeros(k - 2, int), np.arange(1, k - 1), np.arange(2, k)], axis=1)
    return polys[:, fan].reshape(-1, 3)


def _validate(vertices, faces, label: str) -> tuple[np.ndarray, np.ndarray]:
    try:
        v = np.asarray(vertices, dtype=np.float64)
    except (TypeError, ValueError):
        raise MeshError(f"{label}: vertices are not numeric") from None
    if v.ndim != 2 or v.shape[1] != 3:
        raise MeshError(f"{label}: vertices must have shape (n, 3), got {v.shape}")
    if len(v) == 0:
        raise MeshError(f"{label}: the mesh is empty (no vertices)")
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        raise MeshError(f"{label}: {int(bad.sum())} vertices have NaN/inf coordinates "
                        f"(first at index {int(np.flatnonzero(bad)[0])})")
    f = np.asarray(faces)
    if f.size == 0:
        f = np.zeros((0, 3), dtype=np.int64)
    if f.ndim != 2 or f.shape[1] < 3:
        raise MeshError(f"{label}: faces must have shape (m, 3) (or (m, k) polygons), got {f.shape}")
    if not np.issubdtype(f.dtype, np.integer):
        if not np.all(np.equal(np.mod(f, 1), 0)):
            raise MeshError(f"{label}: faces must be integer vertex indices")
        f = f.astype(np.int64)
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise MeshError(f"{label}: faces index vertices that do not exist "
                        f"(indices range [{int(f.min())}, {int(f.max())}], {len(v)} vertices)")
    f = _fan_triangulate(f)
    extent = np.ptp(v, axis=0)
    if extent.max() <= 1e-12 * max(1.0, float(np.abs(v).max())):
        raise MeshError(f"{label}: zero-extent bounding box (all {len(v)} vertices coincide)")
    return v, f.astype(np.int64)
