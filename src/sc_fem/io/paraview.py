"""Files for ParaView: mode shapes as VTKHDF (``.vtkhdf``) and the XDMF time series of a run with
its cube lattice.

Mode shapes (:func:`save_modes_vtkhdf`, ``sc-fem export modes.npz -o modes.vtkhdf``)
    The content of the ``.vtu`` of :func:`sc_fem.io.modes.save_modes_vtu`, written with h5py in
    the VTKHDF 1.0 ``UnstructuredGrid`` layout (one partition): ``/VTKHDF`` with the attributes
    ``Version`` = (1, 0) and ``Type`` = ``"UnstructuredGrid"``; ``NumberOfPoints``,
    ``NumberOfCells``, ``NumberOfConnectivityIds`` (1,) int64; ``Points`` (n, 3) float64 (model
    units); ``Types`` (c,) uint8, ``Offsets`` (c + 1,) and ``Connectivity`` int64 (the triangles, or
    one vertex cell per point for a point set); ``PointData/mode_K`` (n, 3) float32 in m kg^-1/2;
    ``FieldData/frequency_Hz``, ``damping_ratio`` (k,) float64, ``rigid`` (k,) int8 and ``scale``
    (1,) float64 (metres per model unit). Version 1.0 is the layout every VTKHDF reader takes
    (ParaView 5.10 onwards; VTK's own ``vtkHDFWriter`` writes 2.x, which the first readers refuse).

The lattice of a run (:func:`write_xdmf_series`, ``sc-fem simulate ... -o run.xdmf``)
    Beside the surface series ``run.xdmf`` + ``run.h5``, a second series ``run_lattice.xdmf`` +
    ``run_lattice.h5`` (:func:`lattice_xdmf_path`; meshio's XDMF time series hold one mesh per file,
    so ParaView opens the two files side by side, on the same times): the cubes as hexahedra, node
    positions in model units, point data ``displacement`` (model units) and cell data
    ``strain_energy_density`` (J/m^3, :func:`strain_energy_density`) per frame. All four files
    appear together or not at all.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._atomic import atomic_path
from ..errors import InputError, OutputError
from ..fem.elements import DEFAULT_ELEMENT, cube_stiffness_chunks
from ..modes.basis import ModalBasis
from .render import _VTK_HEX_ORDER

VTKHDF_VERSION = (1, 0)
"""The VTKHDF version written by :func:`save_modes_vtkhdf`."""

_VTK_VERTEX, _VTK_TRIANGLE = 1, 5
_CHUNK_BYTES = 32 * 2**20
"""Working memory per chunk of cubes in :func:`strain_energy_density` (about 3 arrays of this size)."""


def _surface_cells(faces: np.ndarray, n_points: int) -> tuple[np.ndarray, str]:
    """The cells a surface is written with: its triangles (m, 3), or for a point set (no faces) one
    vertex cell per point (n, 1); and their kind, ``"triangle"`` or ``"vertex"`` (meshio's names)."""
    if len(faces):
        return faces, "triangle"
    return np.arange(n_points, dtype=np.int64)[:, None], "vertex"


def modes_content(basis: Any) -> tuple[np.ndarray, np.ndarray, int, dict, dict]:
    """What a ParaView mode file holds (the ``.vtu`` and the ``.vtkhdf`` alike).

    Parameters
    ----------
    basis : ModalBasis

    Returns
    -------
    points : ndarray, shape (n, 3)
        Source-mesh vertices, model units, float64.
    cells : ndarray of int64, shape (c, p)
        Triangles (p = 3), or one vertex cell per point (p = 1) for a point set.
    cell_type : int
        The VTK cell type of ``cells`` (5 triangle, 1 vertex).
    point_data : dict of str to ndarray (n, 3) float32
        ``mode_K`` (K zero-padded to the width of the largest index), m kg^-1/2.
    field_data : dict of str to ndarray
        ``frequency_Hz`` (k,) Hz, ``damping_ratio`` (k,), ``rigid`` (k,) int8, ``scale`` (1,) m per
        model unit.
    """
    if not isinstance(basis, ModalBasis):
        raise InputError(f"basis must be a ModalBasis, got {type(basis).__name__}")
    faces = np.asarray(basis.faces, dtype=np.int64).reshape(-1, 3)
    points = np.asarray(basis.vertices, dtype=np.float64)
    cells, kind = _surface_cells(faces, len(points))
    cell_type = _VTK_TRIANGLE if kind == "triangle" else _VTK_VERTEX
    width = len(str(max(basis.n_modes - 1, 0)))
    point_data = {f"mode_{k:0{width}d}": np.asarray(basis.modes[k], dtype=np.float32) for k in range(basis.n_modes)}
    field_data = {"frequency_Hz": np.asarray(basis.frequencies, dtype=np.float64),
                  "damping_ratio": np.asarray(basis.damping, dtype=np.float64),
                  "rigid": np.asarray(basis.rigid, dtype=np.int8),
                  "scale": np.array([basis.scale], dtype=np.float64)}
    return points, cells, cell_type, point_data, field_data


def save_modes_vtkhdf(basis: Any, path: str | Path) -> Path:
    """Write ``basis`` for ParaView as VTKHDF (``.vtkhdf``, atomically; layout in the module docstring).

    Parameters
    ----------
    basis : ModalBasis
        The modes.
    path : str or Path
        Output file, ``.vtkhdf``.

    Returns
    -------
    Path
        The file written: the mesh (points in model units), one point array ``mode_K`` (n, 3) per
        mode in m kg^-1/2, field data ``frequency_Hz``, ``damping_ratio``, ``rigid``, ``scale``;
        ``pyvista.read`` and ParaView read it.

    Raises
    ------
    InputError
        ``path`` not ending in ``.vtkhdf``, or ``basis`` not a ModalBasis.
    """
    import h5py

    path = Path(path)
    if path.suffix.lower() != ".vtkhdf":
        raise InputError(f"{path.name}: a VTKHDF mode file must end in .vtkhdf")
    points, cells, cell_type, point_data, field_data = modes_content(basis)
    with atomic_path(path, suffix=".vtkhdf") as tmp, h5py.File(tmp, "w") as f:
        g = f.create_group("VTKHDF")
        g.attrs["Version"] = np.array(VTKHDF_VERSION, dtype=np.int64)
        g.attrs["Type"] = np.bytes_("UnstructuredGrid")          # fixed-length ASCII, as the spec's files
        g["NumberOfPoints"] = np.array([len(points)], dtype=np.int64)
        g["NumberOfCells"] = np.array([len(cells)], dtype=np.int64)
        g["NumberOfConnectivityIds"] = np.array([cells.size], dtype=np.int64)
        g["Points"] = points
        g["Types"] = np.full(len(cells), cell_type, dtype=np.uint8)
        g["Offsets"] = np.arange(len(cells) + 1, dtype=np.int64) * cells.shape[1]
        g["Connectivity"] = cells.ravel()
        for name, data in (("PointData", point_data), ("CellData", {}), ("FieldData", field_data)):
            group = g.create_group(name)
            for key, arr in data.items():
                group[key] = arr
    return path


def strain_energy_density(model: Any, u: ArrayLike, element: str | None = None) -> np.ndarray:
    """Linear small-strain energy density of every cube in every frame.

    ``w_e = 0.5 u_e^T K_e u_e / h^3`` with ``K_e`` the cube's element matrix (the package's,
    :func:`sc_fem.fem.elements.cube_stiffness_chunks`, honouring partly filled cubes) and ``h^3``
    its volume: ``sum_e w_e h^3`` is the lattice's linear elastic energy ``0.5 u^T K u``.
    Vectorized over cubes and frames (batched matrix products over chunks of cubes).

    Parameters
    ----------
    model : CubeModel
        The lattice.
    u : array_like, shape (T, m, 3) or (m, 3)
        Node displacements, m.
    element : str, optional
        ``"q1"``, ``"q1i"`` or ``"q1sri"`` (default :data:`sc_fem.DEFAULT_ELEMENT`).

    Returns
    -------
    ndarray, shape (T, n) or (n,)
        J/m^3 per cube (n cubes), float64. Small strain: a large rotation of a cube counts as strain.

    Raises
    ------
    InputError
        ``u`` not of shape (T, m, 3) / (m, 3) for the model's m nodes, or not finite; an unknown element.
    """
    arr = np.asarray(u, dtype=np.float64)
    single = arr.ndim == 2
    arr = arr[None] if single else arr
    if arr.ndim != 3 or arr.shape[1:] != (model.n_nodes, 3):
        raise InputError(f"node displacements must have shape (T, {model.n_nodes}, 3), got {np.shape(u)}")
    if not np.all(np.isfinite(arr)):
        raise InputError("node displacements contain non-finite values")
    values = cube_stiffness_chunks(model, DEFAULT_ELEMENT if element is None else element)
    n, T = model.n_cubes, arr.shape[0]
    out = np.empty((n, T))
    step = max(1, _CHUNK_BYTES // (24 * 8 * max(T, 24)))
    for s in range(0, n, step):                   # chunks of cubes, each one batched product
        e = min(s + step, n)
        ue = arr[:, model.hexes[s:e]].transpose(1, 2, 3, 0).reshape(e - s, 24, T)   # (c, 24, T), DOF 3a + c
        Ke = values(s, e).reshape(e - s, 24, 24)
        out[s:e] = 0.5 * np.einsum("cit,cit->ct", ue, Ke @ ue)
    out /= model.h ** 3
    return out[:, 0] if single else out.T


def lattice_xdmf_path(path: str | Path) -> Path:
    """The lattice series beside an XDMF run: ``run.xdmf`` -> ``run_lattice.xdmf`` (its arrays in
    ``run_lattice.h5``).

    Parameters
    ----------
    path : str or Path
        The surface series.

    Returns
    -------
    Path
    """
    path = Path(path)
    return path.with_name(f"{path.stem}_lattice{path.suffix}")


def _series(name: str, points: np.ndarray, cells: list, times: np.ndarray, point_frames, cell_frames=None) -> None:
    """One meshio XDMF time series ``name`` (+ ``.h5``) in the current directory; the frames are
    given by generators so one frame's arrays exist at a time."""
    import meshio

    with meshio.xdmf.TimeSeriesWriter(name, data_format="HDF") as w:
        w.write_points_cells(points, cells)
        frames = zip(times, point_frames, cell_frames if cell_frames is not None else [None] * len(times))
        for t, pd, cd in frames:                          # loop over frames
            w.write_data(float(t), point_data=pd, cell_data=cd)


def write_xdmf_series(path: str | Path, rest: ArrayLike, faces: ArrayLike, times: Sequence[float] | np.ndarray,
                      positions: ArrayLike, *, model: Any = None, node_displacements: ArrayLike | None = None,
                      element: str | None = None) -> list[Path]:
    """XDMF time series for ParaView (heavy data in HDF5 beside it), with the cube lattice when given.

    Parameters
    ----------
    path : str or Path
        The surface series, ``NAME.xdmf`` (arrays in ``NAME.h5``).
    rest : array_like, shape (n, 3)
        Source-mesh vertices at rest, model units.
    faces : array_like of int, shape (f, 3)
        Triangles ((0, 3): one vertex cell per point).
    times : sequence of float, shape (T,)
        Frame times, s.
    positions : array_like, shape (T, n, 3)
        Vertex positions, model units; written as point data ``displacement`` (minus ``rest``).
    model : CubeModel, optional
        The lattice of the run: with ``node_displacements``, also writes :func:`lattice_xdmf_path`.
    node_displacements : array_like, shape (T, m, 3), optional
        Node displacements, m; written in model units as point data ``displacement`` with cell
        data ``strain_energy_density`` (J/m^3, :func:`strain_energy_density`).
    element : str, optional
        Element of the energy (default :data:`sc_fem.DEFAULT_ELEMENT`).

    Returns
    -------
    list of Path
        The ``.xdmf`` files written: the surface series, then the lattice series if any. All files
        (with their ``.h5``) are written in a temporary folder beside ``path`` and moved in place
        at the end: a failure leaves none of them.

    Raises
    ------
    InputError
        ``positions`` / ``node_displacements`` of the wrong shape, or only one of ``model`` and
        ``node_displacements`` given.
    OutputError
        The folder cannot be written.
    """
    path = Path(path)
    rest = np.asarray(rest, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    positions = np.asarray(positions, dtype=np.float64)
    if positions.shape != (len(times), *rest.shape):
        raise InputError(f"positions must have shape ({len(times)}, {len(rest)}, 3), got {positions.shape}")
    if (model is None) != (node_displacements is None):
        raise InputError("the lattice needs both the model and its node displacements")
    cells, kind = _surface_cells(faces, len(rest))
    jobs = [(path.name, rest, [(kind, cells)], times,
             ({"displacement": p - rest} for p in positions), None)]
    if model is not None:
        u = np.asarray(node_displacements, dtype=np.float64)
        if u.shape != (len(times), model.n_nodes, 3):
            raise InputError(f"node displacements must have shape ({len(times)}, {model.n_nodes}, 3), got {u.shape}")
        sed = strain_energy_density(model, u, element)                    # (T, n) J/m^3, before any file
        jobs.append((lattice_xdmf_path(path).name, np.asarray(model.nodes, dtype=np.float64),
                     [("hexahedron", np.asarray(model.hexes, dtype=np.int64)[:, _VTK_HEX_ORDER])], times,
                     ({"displacement": ui / model.scale} for ui in u),
                     ({"strain_energy_density": [w]} for w in sed)))
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmpdir = Path(tempfile.mkdtemp(prefix=f".{path.stem}.", dir=path.parent))
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc}") from None
    try:
        cwd = os.getcwd()
        os.chdir(tmpdir)                      # meshio names the .h5 after the .xdmf, relative to it
        try:
            for job in jobs:
                _series(*job)
        finally:
            os.chdir(cwd)
        written = [path.with_name(job[0]) for job in jobs]
        for xdmf in written[::-1]:            # the surface series last: it names the run
            for f in (xdmf.with_suffix(".h5"), xdmf):
                os.replace(tmpdir / f.name, f)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc}") from None
    finally:
        shutil.rmtree(tmpdir, ignore_errors=True)
    return written
