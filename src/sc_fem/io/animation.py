"""Vertex-animation files (``.npz``): what ``sc-fem simulate`` writes and ``sc-fem reconstruct`` reads.

Schema (``format_version`` 2; version 1 files, which stored absolute ``positions`` in float32,
are still read):

=================  ===============  =====================================================
key                shape / dtype    meaning
=================  ===============  =====================================================
format_version     () int           2
kind               () str           ``"sc_fem.animation"``
faces              (m, 3) int64     source-mesh triangles (may be (0, 3) for point sets)
rest_vertices      (n, 3) float64   rest positions, model units
times              (T,) float64     seconds, strictly increasing
displacements      (T, n, 3) f32    vertex positions minus rest positions, model units
                                    (float32 relative to the motion, not to the model's
                                    size or its offset from the origin)
energy             (T,) float64     kinetic + elastic + gravity potential, J (NaN if unknown)
meta_json          () str           JSON dict: method, dt, fps (the frame rate stored),
                                    material, source, ...
curves (optional)  (T, C, P, 3) f8  curves on the surface (e.g. the XPBD rope's 24 x 832), model units
lattice_*          (optional)       the cube lattice of the run, written by ``sc-fem simulate``:
                                    ``lattice_node_index`` (q, 3) int (grid indices of the nodes),
                                    ``lattice_rest`` (q, 3) f8 node rest positions and
                                    ``lattice_displacements`` (T, q, 3) f4 their motion, model
                                    units; ``lattice_W_data`` / ``_indices`` / ``_indptr``: the
                                    embedding W (n, q) in CSR form, so vertex displacements are
                                    ``W @ lattice_displacements[t]`` (``sc-fem reconstruct`` fits
                                    the lattice's node lines and maps them back exactly)
=================  ===============  =====================================================

Further optional arrays may be stored with ``save_animation(..., extra={...})``; readers ignore
keys they do not know.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from .._atomic import save_npz_atomic
from ._npz import read_versioned_npz
from .._validate import as_float_array, positive_scalar
from ..dynamics.contact import obstacles_from
from ..errors import InputError, FileFormatError
from ..units import up_axis
from .paraview import write_xdmf_series
from .render import render_animation

ANIMATION_FORMAT_VERSION = 2
ANIMATION_READS = (1, 2)
ANIMATION_KIND = "sc_fem.animation"


def frame_rate(times: np.ndarray, default: float = 30.0) -> float:
    """The frame rate of an animation's frame times, as written to the stage.

    Parameters
    ----------
    times : ndarray, shape (T,)
        Frame times, s, increasing.
    default : float
        Frames per second of a single-frame animation.

    Returns
    -------
    float
        ``(T - 1) / (t_{T-1} - t_0)``, rounded to 9 significant digits (so the 100.00000000000007
        of times summed in floating point is 100).
    """
    t = np.asarray(times, dtype=float)
    rate = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 else float(default)
    return float(f"{rate:.9g}")


@dataclass(frozen=True, eq=False)
class Animation:
    """A vertex animation of a source mesh.

    Attributes
    ----------
    faces : ndarray of int, shape (m, 3)
    rest_vertices : ndarray, shape (n, 3)
        Model units.
    times : ndarray, shape (T,)
        Seconds.
    positions : ndarray, shape (T, n, 3)
        Model units.
    energy : ndarray, shape (T,)
        Joules (NaN where not computed).
    meta : dict
        Free-form provenance (JSON-serialisable).
    curves : ndarray, shape (T, C, P, 3), or None
        Optional curves on the surface (model units), None if the file has none.
    lattice : LatticeTrack or None
        The cube lattice's node motion behind the animation, None if the file has none.
    """

    faces: np.ndarray
    rest_vertices: np.ndarray
    times: np.ndarray
    positions: np.ndarray
    energy: np.ndarray
    meta: dict = field(default_factory=dict)
    curves: np.ndarray | None = None
    lattice: "LatticeTrack | None" = None

    @property
    def n_frames(self) -> int:
        """Number of frames ``T``."""
        return len(self.times)

    @property
    def frame_rate(self) -> float | None:
        """Frames per second stored: ``meta["fps"]`` (what ``sc-fem simulate`` records) when it agrees
        with the frame times, else ``(T - 1) / (t_{T-1} - t_0)`` to 9 significant digits; None for
        a single frame."""
        if self.n_frames < 2:
            return None
        rate = frame_rate(self.times)
        said = self.meta.get("fps") if isinstance(self.meta, dict) else None
        ok = isinstance(said, (int, float)) and not isinstance(said, bool) and abs(said - rate) <= 1e-6 * rate
        return float(said) if ok else rate


@dataclass(frozen=True, eq=False)
class LatticeTrack:
    """The cube lattice behind a vertex animation (see the module's schema).

    Attributes
    ----------
    node_index : ndarray of int, shape (q, 3)
        Grid indices of the lattice nodes.
    rest : ndarray, shape (q, 3)
        Node rest positions, model units.
    displacements : ndarray, shape (T, q, 3)
        Node displacements per frame, model units.
    W : scipy.sparse.csr_matrix, shape (n, q)
        Embedding of the source vertices: vertex displacement = ``W @`` node displacement.
    """

    node_index: np.ndarray
    rest: np.ndarray
    displacements: np.ndarray
    W: Any

    @property
    def dims(self) -> np.ndarray:
        """Cubes along each grid axis spanned by the nodes, shape (3,)."""
        return np.ptp(self.node_index, axis=0)


_LATTICE_KEYS = ("lattice_node_index", "lattice_rest", "lattice_displacements", "lattice_W_data",
                 "lattice_W_indices", "lattice_W_indptr")


def lattice_arrays(scene, node_displacements_m: np.ndarray) -> dict:
    """The ``lattice_*`` arrays of a run of ``scene`` whose node displacements (T, q, 3) are in metres."""
    W = scene.W.tocsr()
    return {"lattice_node_index": np.asarray(scene.model.node_index, dtype=np.int32),
            "lattice_rest": np.asarray(scene.model.nodes, dtype=np.float64),
            "lattice_displacements": (np.asarray(node_displacements_m) / scene.model.scale).astype(np.float32),
            "lattice_W_data": W.data, "lattice_W_indices": W.indices.astype(np.int64),
            "lattice_W_indptr": W.indptr.astype(np.int64)}


def _read_lattice(path, data, n_vertices: int, n_frames: int) -> LatticeTrack | None:
    present = [k for k in _LATTICE_KEYS if k in data]
    if not present:
        return None
    if len(present) != len(_LATTICE_KEYS):
        raise FileFormatError(f"{path}: incomplete lattice arrays (missing "
                              f"{sorted(set(_LATTICE_KEYS) - set(present))})")

    ni, rest, disp = data["lattice_node_index"], data["lattice_rest"], data["lattice_displacements"]
    q = len(rest)
    if ni.shape != (q, 3) or rest.shape != (q, 3) or disp.shape != (n_frames, q, 3):
        raise FileFormatError(f"{path}: lattice arrays disagree in shape: node_index {ni.shape}, rest "
                              f"{rest.shape}, displacements {disp.shape} for {n_frames} frames")
    try:
        W = sp.csr_matrix((data["lattice_W_data"], data["lattice_W_indices"], data["lattice_W_indptr"]),
                          shape=(n_vertices, q))
        W.check_format(full_check=True)
    except ValueError as exc:
        raise FileFormatError(f"{path}: the stored embedding is not a valid ({n_vertices}, {q}) matrix: {exc}") from None
    disp = disp.astype(np.float64)
    if not (np.all(np.isfinite(rest)) and np.all(np.isfinite(disp)) and np.all(np.isfinite(W.data))):
        raise FileFormatError(f"{path}: non-finite lattice values")
    return LatticeTrack(node_index=ni.astype(np.int64), rest=rest.astype(np.float64), displacements=disp, W=W)


def _check(faces, rest, times, positions, energy) -> None:
    n = len(rest)
    if positions.ndim != 3 or positions.shape[1:] != (n, 3):
        raise InputError(f"positions must have shape (T, {n}, 3), got {positions.shape}")
    if times.shape != (positions.shape[0],):
        raise InputError(f"times must have shape ({positions.shape[0]},), got {times.shape}")
    if len(times) > 1 and np.any(np.diff(times) <= 0):
        raise InputError("times must be strictly increasing")
    if energy.shape != times.shape:
        raise InputError(f"energy must have shape {times.shape}, got {energy.shape}")
    if faces.size and (faces.min() < 0 or faces.max() >= n):
        raise InputError("faces index vertices that do not exist")


_RESERVED = {"format_version", "kind", "faces", "rest_vertices", "times", "positions", "displacements", "energy",
             "meta_json"}


def save_animation(path: str | Path, *, faces: ArrayLike, rest_vertices: ArrayLike, times: ArrayLike,
                   positions: ArrayLike, energy: ArrayLike | None = None, meta: dict | None = None,
                   extra: dict | None = None) -> Path:
    """Write an animation ``.npz`` atomically (temp file + rename).

    Parameters
    ----------
    path : str or Path
        Output file (``.npz``).
    faces : array_like of int, shape (m, 3)
        Triangles of the animated mesh.
    rest_vertices : array_like, shape (n, 3)
        Vertices at rest, model units.
    times : array_like, shape (T,)
        Frame times, s (increasing).
    positions : array_like, shape (T, n, 3)
        Vertex positions per frame, model units.
    energy : array_like, shape (T,), optional
        Total energy per frame, J (NaN where not computed).
    meta : dict, optional
        Provenance, JSON-serialisable.
    extra : dict, optional
        Further named arrays (e.g. ``curves`` of shape (T, C, P, 3)).

    Returns
    -------
    Path
        The file written.
    """
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    rest = as_float_array(rest_vertices, "rest_vertices", (-1, 3))
    times = as_float_array(times, "times", (-1,))
    positions = as_float_array(positions, "positions", (-1, -1, 3))
    energy = np.full(times.shape, np.nan) if energy is None else np.asarray(energy, dtype=float)
    _check(faces, rest, times, positions, energy)
    extra = dict(extra or {})
    clash = _RESERVED & set(extra)
    if clash:
        raise InputError(f"extra arrays may not use the reserved keys {sorted(clash)}")
    try:                                  # never write a lattice track that load_animation would refuse
        _read_lattice("lattice arrays", {k: np.asarray(v) for k, v in extra.items()}, len(rest), len(times))
    except FileFormatError as exc:
        raise InputError(str(exc)) from None
    return save_npz_atomic(
        path, format_version=np.int64(ANIMATION_FORMAT_VERSION), kind=np.str_(ANIMATION_KIND),
        faces=faces, rest_vertices=rest, times=times, displacements=(positions - rest[None]).astype(np.float32),
        energy=energy, meta_json=np.str_(json.dumps(meta or {}, default=str)),
        **{k: np.asarray(v) for k, v in extra.items()},
    )


def load_animation(path: str | Path) -> Animation:
    """Read and validate an animation ``.npz``.

    Parameters
    ----------
    path : str or Path
        A file written by :func:`save_animation` (or ``sc-fem simulate``).

    Returns
    -------
    Animation

    Raises
    ------
    FileFormatError
        Missing, truncated, corrupted, foreign (not an sc_fem animation) or wrong-version file,
        or an optional ``curves`` array of the wrong shape or with non-finite values.
    """
    path = Path(path)
    data = read_versioned_npz(path, kind=ANIMATION_KIND, version=ANIMATION_READS, what="animation file")
    motion = "positions" if int(data["format_version"]) == 1 else "displacements"
    missing = {"faces", "rest_vertices", "times", motion, "energy"} - set(data)
    if missing:
        raise FileFormatError(f"{path}: missing keys {sorted(missing)}")
    faces, rest, times = data["faces"], data["rest_vertices"], data["times"]
    energy = data["energy"]
    positions = data[motion].astype(np.float64)
    if motion == "displacements":
        if positions.ndim != 3 or positions.shape[1:] != rest.shape:
            raise FileFormatError(f"{path}: displacements must have shape (T, {len(rest)}, 3), got {positions.shape}")
        positions = rest[None] + positions
    try:
        _check(faces, rest, times, positions, energy)
    except InputError as exc:
        raise FileFormatError(f"{path}: {exc}") from None
    if not (np.all(np.isfinite(positions)) and np.all(np.isfinite(rest)) and np.all(np.isfinite(times))):
        raise FileFormatError(f"{path}: non-finite positions, rest vertices or times")
    curves = None
    if "curves" in data:
        curves = data["curves"]
        if (curves.ndim != 4 or curves.shape[0] != len(times) or curves.shape[-1] != 3
                or not np.issubdtype(curves.dtype, np.number)):
            raise FileFormatError(f"{path}: curves must have shape ({len(times)}, C, P, 3), got "
                                f"{curves.dtype} {curves.shape}")
        curves = curves.astype(np.float64, copy=False)
        if not np.all(np.isfinite(curves)):
            raise FileFormatError(f"{path}: curves contain {int(np.count_nonzero(~np.isfinite(curves)))} "
                                "non-finite value(s)")
    meta = json.loads(str(data.get("meta_json", "{}")))
    lattice = _read_lattice(path, data, len(rest), len(times))
    return Animation(faces=faces, rest_vertices=rest, times=times, positions=positions,
                     energy=energy, meta=meta, curves=curves, lattice=lattice)


def _lerp(frames: np.ndarray, i0: np.ndarray, i1: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``frames[i0] + a (frames[i1] - frames[i0])`` for frames (T, ...) and indices/weights (S,):
    (S, ...); exactly ``frames[i0]`` where ``a == 0``."""
    lo = frames[i0]
    return lo + a.reshape((-1,) + (1,) * (frames.ndim - 1)) * (frames[i1] - lo)


def resample_animation(anim: Animation, fps: float, *, duration: float | None = None) -> Animation:
    """The animation at ``fps`` frames per second: vertex positions (and curves, lattice motion)
    interpolated linearly in time between the stored frames.

    Parameters
    ----------
    anim : Animation
        T stored frames at times ``t_0 < ... < t_{T-1}`` (s), not necessarily uniform.
    fps : float
        Frames per second of the result.
    duration : float, optional
        Seconds from ``t_0`` (default the whole animation, ``t_{T-1} - t_0``); at most that.

    Returns
    -------
    Animation
        ``S = floor(duration fps) + 1`` frames at ``t_0 + arange(S) / fps`` (s): positions (S, n, 3)
        in model units, energy (S,) in J (interpolated, a record only), curves (S, C, P, 3) and the
        lattice track when ``anim`` has them. A time that falls on a stored frame (within 1e-6 of
        a frame step) gives that frame exactly: when ``fps`` divides the stored rate, every k-th
        frame. ``meta`` adds ``fps``, ``resampled_from_fps`` and ``resampling``.

    Raises
    ------
    InputError
        ``fps`` or ``duration`` not positive and finite, or ``duration`` beyond the animation's.
    """
    fps = positive_scalar(fps, "fps")
    t = np.asarray(anim.times, dtype=float)
    whole = float(t[-1] - t[0])
    duration = whole if duration is None else positive_scalar(duration, "duration")
    if duration > whole * (1 + 1e-9) + 1e-12:
        raise InputError(f"duration {duration:g} s is longer than the animation ({whole:g} s, {anim.n_frames} frames)")
    times = t[0] + np.arange(int(np.floor(duration * fps * (1 + 1e-9))) + 1) / fps
    u = np.interp(times, t, np.arange(len(t), dtype=float))      # fractional stored-frame index, (S,)
    near = np.rint(u)
    u = np.where(np.abs(u - near) < 1e-6, near, u)               # on a stored frame: that frame, exactly
    i0 = np.minimum(np.floor(u).astype(np.int64), len(t) - 1)
    i1, a = np.minimum(i0 + 1, len(t) - 1), u - i0
    lattice = anim.lattice
    if lattice is not None:
        lattice = replace(lattice, displacements=_lerp(lattice.displacements, i0, i1, a))
    meta = {**(anim.meta if isinstance(anim.meta, dict) else {}), "fps": fps, "resampled_from_fps": anim.frame_rate,
            "resampling": "stored frames, exact" if np.all(a == 0) else "linear interpolation in time"}
    return Animation(faces=anim.faces, rest_vertices=anim.rest_vertices, times=times,
                     positions=_lerp(np.asarray(anim.positions, dtype=float), i0, i1, a),
                     energy=np.interp(times, t, np.asarray(anim.energy, dtype=float)), meta=meta,
                     curves=None if anim.curves is None else _lerp(anim.curves, i0, i1, a), lattice=lattice)


ANIMATION_OUTPUTS = (".npz", ".xdmf", ".mp4", ".gif")
"""Extensions :func:`write_animation` writes."""


def write_xdmf(path: str | Path, rest: np.ndarray, faces: np.ndarray, times: ArrayLike, positions: ArrayLike, *,
               model: Any = None, node_displacements: ArrayLike | None = None, element: str | None = None) -> Path:
    """XDMF time series for ParaView: the rest mesh and point data ``displacement`` (model units)
    per time, the arrays in an HDF5 file beside it (``NAME.h5``; inline XML of a large run is more
    than VTK's XML reader takes); with ``model`` and ``node_displacements`` (T, m, 3) in metres,
    the cube lattice too, in ``NAME_lattice.xdmf`` (:func:`sc_fem.io.paraview.write_xdmf_series`).
    All files appear together or not at all. Returns the surface series' path."""
    return write_xdmf_series(path, rest, faces, times, positions, model=model,
                             node_displacements=node_displacements, element=element)[0]


def keeps_lattice(rec: Any) -> bool:
    """Whether a recording kept the node displacements of every frame (its lattice is written)."""
    return len(rec.u) == len(rec.times)


def write_animation(path, scene, rec, *, exaggerate: float = 1.0, fps: float = 50.0, title: str = "",
                    progress: bool = False) -> Path:
    """Write a recorded run of ``scene`` by the extension of ``path``: ``.npz`` (:func:`save_animation`,
    with ``rec.info`` as its record), ``.xdmf`` (ParaView time series, and the lattice's in
    ``NAME_lattice.xdmf`` when ``rec`` kept the node displacements), ``.mp4`` / ``.gif`` (rendered,
    displacements times ``exaggerate``)."""
    path = Path(path)
    kind = path.suffix.lower()
    if kind not in ANIMATION_OUTPUTS:
        raise InputError(f"unsupported output {path.name!r}: use {', '.join(ANIMATION_OUTPUTS)}")
    rest, faces = scene.rest_vertices, scene.faces
    if kind == ".npz":
        meta = {k: v for k, v in rec.info.items() if k != "warnings"}
        return save_animation(path, faces=faces, rest_vertices=rest, times=rec.times, positions=rec.points,
                              energy=rec.energy, meta=meta,
                              extra=lattice_arrays(scene, rec.u) if keeps_lattice(rec) else None)
    if kind == ".xdmf":                    # the lattice beside it: NAME_lattice.xdmf (sc_fem.io.paraview)
        lattice = {"model": scene.model, "node_displacements": rec.u,
                   "element": rec.info.get("element")} if keeps_lattice(rec) else {}
        return write_xdmf(path, rest, faces, rec.times, rec.points, **lattice)
    exaggerate = positive_scalar(exaggerate, "exaggerate")
    info = rec.info
    up = str(info.get("up", "z"))
    obstacles = obstacles_from(info.get("ground"), info.get("sphere"), info.get("box"), up=up_axis(up))
    frames = rest[None] + exaggerate * (rec.points - rest[None])
    title = title or f"{scene.source} {rec.method}" + (f" (x{exaggerate:g})" if exaggerate != 1 else "")
    return render_animation(frames, faces, path, fps=min(fps, 30.0), title=title, progress=progress,
                            times=rec.times, up=up, obstacles=obstacles)
