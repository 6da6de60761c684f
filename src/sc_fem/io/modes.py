"""Mode files (``.npz``): what ``sc-fem precompute-modes`` writes and ``sc-fem play`` reads.

Schema (``format_version`` 1); every file is written atomically (temporary file + rename):

===================  ================  ==========================================================
key                  shape / dtype     meaning
===================  ================  ==========================================================
format_version       () int64          1
kind                 () str            ``"sc_fem.modes"``
vertices             (n, 3) float64    rest positions of the source mesh, model units
faces                (m, 3) int64      source-mesh triangles ((0, 3) for a point set)
frequencies          (k,) float64      natural frequencies, Hz, ascending (0 = rigid mode)
modes                (k, n, 3) f32     mass-normalized mode shapes at the vertices, metres per
                                       unit modal coordinate (m kg^-1/2)
damping              (k,) float64      damping ratio zeta of each mode
damping_json         () str            how damping was given: ratio or Rayleigh (alpha, beta)
rigid                (k,) bool         rigid-body modes (frequency 0); all False unless kept
residuals            (k,) float64      ||K phi - omega^2 M phi|| / ||K phi|| per mode
rigid_removed        () int64          rigid-body modes found and removed
scale                () float64        metres per model unit
pitch                () float64        cube edge, model units
resolution           () int64          cubes along the longest axis
element              () str            ``"q1i"``, ``"q1"`` or ``"q1sri"``
material_json        () str            material name, E / nu / rho ranges, total mass
fixed_json           () str            fixed-node description: ``--fix`` specs, vertex count, nodes
source               () str            source file name or ``builtin:NAME``
source_sha256        () str            SHA-256 of the source file (or of its arrays)
meta_json            () str            solver report, timings, resolution table, cube/DOF counts
fixed_points         optional (q, 3)   positions of the fixed lattice nodes, model units
lattice_*            optional          the lattice (``keep_lattice``): cells, origin, pitch, scale,
                                       dims, mass, youngs, poisson, density, node_modes (k, m, 3) f32
===================  ================  ==========================================================

:func:`load_modes` checks the kind, version, keys, shapes, dtypes and finiteness and raises
:class:`~sc_fem.errors.FileFormatError` naming the problem for a missing, truncated, corrupted,
foreign or wrong-version file.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._atomic import atomic_path, save_npz_atomic
from ._npz import read_versioned_npz
from ..errors import InputError, FileFormatError
from ..lattice.cubes import CubeModel
from ..modes.basis import ModalBasis
from .paraview import modes_content

MODES_FORMAT_VERSION = 1
MODES_KIND = "sc_fem.modes"

_REQUIRED = ("format_version", "kind", "vertices", "faces", "frequencies", "modes", "damping", "damping_json",
             "rigid", "residuals", "rigid_removed", "scale", "pitch", "resolution", "element", "material_json",
             "fixed_json", "source", "source_sha256", "meta_json")
_LATTICE = ("cells", "origin", "pitch", "scale", "dims", "mass", "youngs", "poisson", "density", "node_modes")


def save_modes(basis: ModalBasis, path: str | Path) -> Path:
    """Write ``basis`` to ``path`` (``.npz``, see the module docstring) atomically.

    Parameters
    ----------
    basis : ModalBasis
        The modes.
    path : str or Path
        Output file (``.npz``).

    Returns
    -------
    Path
        The file written.
    """
    if not isinstance(basis, ModalBasis):
        raise InputError(f"basis must be a ModalBasis, got {type(basis).__name__}")
    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise InputError(f"mode files are .npz, got {path.name!r}")
    meta = {"n_cubes": basis.n_cubes, "n_dofs": basis.n_dofs, "eigen": basis.eigen, "timings": basis.timings,
            "resolution_table": basis.resolution_table,
            "units": {"vertices": "model units", "frequencies": "Hz", "modes": "m kg^-1/2 (per unit modal coordinate)",
                      "scale": "m per model unit"}}
    arrays = dict(
        format_version=np.int64(MODES_FORMAT_VERSION), kind=np.str_(MODES_KIND),
        vertices=np.asarray(basis.vertices, dtype=np.float64),
        faces=np.asarray(basis.faces, dtype=np.int64).reshape(-1, 3),
        frequencies=np.asarray(basis.frequencies, dtype=np.float64),
        modes=np.asarray(basis.modes, dtype=np.float32),
        damping=np.asarray(basis.damping, dtype=np.float64),
        damping_json=np.str_(json.dumps(basis.damping_spec)),
        rigid=np.asarray(basis.rigid, dtype=bool), residuals=np.asarray(basis.residuals, dtype=np.float64),
        rigid_removed=np.int64(basis.n_rigid_removed), scale=np.float64(basis.scale),
        pitch=np.float64(basis.pitch), resolution=np.int64(basis.resolution), element=np.str_(basis.element),
        material_json=np.str_(json.dumps(basis.material)), fixed_json=np.str_(json.dumps(basis.fix_record)),
        source=np.str_(basis.source), source_sha256=np.str_(basis.source_sha256),
        meta_json=np.str_(json.dumps(meta, default=_json_default)),
    )
    if basis.fixed_points is not None and len(basis.fixed_points):
        arrays["fixed_points"] = np.asarray(basis.fixed_points, dtype=np.float64).reshape(-1, 3)
    if basis.lattice is not None and basis.node_modes is not None:
        lat = basis.lattice
        arrays.update(lattice_cells=lat.cells, lattice_origin=lat.origin, lattice_pitch=np.float64(lat.pitch),
                      lattice_scale=np.float64(lat.scale), lattice_dims=lat.dims, lattice_mass=lat.mass,
                      lattice_youngs=lat.youngs, lattice_poisson=lat.poisson, lattice_density=lat.density,
                      lattice_fraction=lat.fraction, lattice_stiffness=np.str_(lat.stiffness),
                      **({} if lat.moments is None else {"lattice_moments": lat.moments}),
                      lattice_piece=lat.piece,
                      **({} if lat.sites is None else {"lattice_sites": lat.sites, "lattice_site_piece": lat.site_piece}),
                      lattice_node_modes=np.asarray(basis.node_modes, dtype=np.float32))
    _check_arrays(arrays, path)        # never write a file we would refuse to read
    return save_npz_atomic(path, **arrays)


def save_modes_vtu(basis: ModalBasis, path: str | Path) -> Path:
    """Write ``basis`` for ParaView as a ``.vtu`` (atomically): the mesh (points in model units,
    its triangles, or vertex cells for a point set) with one point array per mode, ``mode_K``
    (n, 3) in m kg^-1/2 (mass-normalized; in ParaView: Warp By Vector with a scale factor), and the
    field data ``frequency_Hz`` (k,), ``damping_ratio`` (k,), ``rigid`` (k,) and ``scale`` (metres
    per model unit); :func:`sc_fem.io.paraview.save_modes_vtkhdf` writes the same as VTKHDF.
    Returns the path."""
    import pyvista as pv

    path = Path(path)
    if path.suffix.lower() != ".vtu":
        raise InputError(f"{path.name}: a ParaView mode file must end in .vtu")
    points, cells, cell_type, point_data, field_data = modes_content(basis)   # as the .vtkhdf
    grid = pv.UnstructuredGrid({pv.CellType(cell_type): cells}, points)
    for name, arr in point_data.items():
        grid.point_data[name] = arr
    for name, arr in field_data.items():
        grid.field_data[name] = arr
    with atomic_path(path, suffix=".vtu") as tmp:
        grid.save(str(tmp))
    return path


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def _fail(path, msg: str):
    raise FileFormatError(f"{path}: {msg}")


def _check_arrays(d: dict, path) -> None:
    """Validate the arrays of a mode file (raises FileFormatError)."""
    missing = [k for k in _REQUIRED if k not in d]
    if missing:
        _fail(path, f"not a complete sc_fem mode file: missing keys {missing}")
    v, f, fr, modes = d["vertices"], d["faces"], d["frequencies"], d["modes"]
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0 or v.dtype.kind != "f":
        _fail(path, f"vertices must be a float array of shape (n, 3), got {v.dtype} {v.shape}")
    n = len(v)
    if f.ndim != 2 or f.shape[1] != 3 or f.dtype.kind not in "iu":
        _fail(path, f"faces must be an integer array of shape (m, 3), got {f.dtype} {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= n):
        _fail(path, f"faces index vertices outside [0, {n})")
    if fr.ndim != 1 or len(fr) == 0 or fr.dtype.kind != "f":
        _fail(path, f"frequencies must be a non-empty float array of shape (k,), got {fr.dtype} {fr.shape}")
    k = len(fr)
    if modes.shape != (k, n, 3) or modes.dtype.kind != "f":
        _fail(path, f"modes must be a float array of shape ({k}, {n}, 3), got {modes.dtype} {modes.shape}")
    for key in ("damping", "residuals", "rigid"):
        if d[key].shape != (k,):
            _fail(path, f"{key} must have shape ({k},), got {d[key].shape}")
    for key, arr in (("vertices", v), ("frequencies", fr), ("modes", modes), ("damping", d["damping"])):
        if not np.all(np.isfinite(arr)):
            _fail(path, f"{key} contains {int(np.count_nonzero(~np.isfinite(arr)))} non-finite value(s) (NaN/inf)")
    if np.any(fr < 0) or np.any(np.diff(fr) < -1e-9 * max(float(fr.max()), 1.0)):
        _fail(path, "frequencies must be >= 0 and ascending")
    if np.any(d["damping"] < 0):
        _fail(path, "damping ratios must be >= 0")
    for key in ("scale", "pitch"):
        if d[key].shape != () or not (np.isfinite(d[key]) and d[key] > 0):
            _fail(path, f"{key} must be a positive scalar, got {d[key]!r}")
    if "lattice_node_modes" in d:
        lmissing = [f"lattice_{k}" for k in _LATTICE if f"lattice_{k}" not in d]
        if lmissing:
            _fail(path, f"incomplete lattice: missing {lmissing}")
        nm = d["lattice_node_modes"]
        if nm.ndim != 3 or nm.shape[0] != k or nm.shape[2] != 3 or not np.all(np.isfinite(nm)):
            _fail(path, f"lattice_node_modes must be finite with shape ({k}, m, 3), got {nm.shape}")


def load_modes(path: str | Path) -> ModalBasis:
    """Read and validate a mode file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    ModalBasis
        With ``modes`` as float32 (as stored); ``lattice`` / ``node_modes`` when the file has them.

    Raises
    ------
    FileFormatError
        Missing, truncated, corrupted, foreign or wrong-version file, missing keys, wrong shapes,
        NaN/inf values.
    """
    path = Path(path)
    data = read_versioned_npz(path, kind=MODES_KIND, version=MODES_FORMAT_VERSION, what="mode file")
    _check_arrays(data, path)
    try:
        damping_spec = json.loads(str(data["damping_json"]))
        material = json.loads(str(data["material_json"]))
        fixed = json.loads(str(data["fixed_json"]))
        meta = json.loads(str(data["meta_json"]))
    except json.JSONDecodeError as exc:
        raise FileFormatError(f"{path}: corrupted metadata ({exc})") from None
    lattice = node_modes = None
    if "lattice_node_modes" in data:
        try:
            lattice = CubeModel.from_cells(
                data["lattice_cells"], origin=data["lattice_origin"], pitch=float(data["lattice_pitch"]),
                scale=float(data["lattice_scale"]), dims=data["lattice_dims"], mass=data["lattice_mass"],
                youngs=data["lattice_youngs"], poisson=data["lattice_poisson"], density=data["lattice_density"],
                fraction=data["lattice_fraction"] if "lattice_fraction" in data else 1.0,
                stiffness=str(data["lattice_stiffness"]) if "lattice_stiffness" in data else "full",
                moments=data["lattice_moments"] if "lattice_moments" in data else None,
                piece=data["lattice_piece"] if "lattice_piece" in data else None,
                sites=data["lattice_sites"] if "lattice_sites" in data else None,
                site_piece=data["lattice_site_piece"] if "lattice_site_piece" in data else None)
        except InputError as exc:
            raise FileFormatError(f"{path}: invalid lattice: {exc}") from None
        node_modes = data["lattice_node_modes"]
        if node_modes.shape[1] != lattice.n_nodes:
            raise FileFormatError(f"{path}: lattice_node_modes has {node_modes.shape[1]} nodes, the lattice "
                                f"{lattice.n_nodes}")
    return ModalBasis(
        frequencies=data["frequencies"], modes=data["modes"], vertices=data["vertices"], faces=data["faces"],
        damping=data["damping"], damping_spec=damping_spec, rigid=data["rigid"].astype(bool),
        residuals=data["residuals"], n_rigid_removed=int(data["rigid_removed"]), scale=float(data["scale"]),
        pitch=float(data["pitch"]), resolution=int(data["resolution"]), element=str(data["element"]),
        material=material, fix_record=fixed, source=str(data["source"]), source_sha256=str(data["source_sha256"]),
        n_cubes=int(meta.get("n_cubes", 0)), n_dofs=int(meta.get("n_dofs", 0)), eigen=meta.get("eigen", {}),
        timings=meta.get("timings", {}), resolution_table=meta.get("resolution_table"),
        lattice=lattice, node_modes=node_modes,
        fixed_points=_fixed_points(data, path))


def _fixed_points(data: dict, path) -> np.ndarray | None:
    if "fixed_points" not in data:
        return None
    fp = data["fixed_points"]
    if fp.ndim != 2 or fp.shape[1] != 3 or not np.all(np.isfinite(fp)):
        raise FileFormatError(f"{path}: fixed_points must be finite with shape (q, 3), got {fp.shape}")
    return fp.astype(np.float64)
