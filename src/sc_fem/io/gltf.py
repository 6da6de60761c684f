"""glTF 2.0 export: the source mesh with its baked modes as morph targets (what game engines,
Blender and the browser read), or a vertex animation as morph targets with a weights channel.

**Axes and units.** glTF is +Y up, metres, and so is every file :func:`export_gltf` writes. The
model's up axis (``up=``, ``sc-fem export --up``, default ``"z"`` as for ``sc-fem view`` / ``play``)
is turned onto +Y *in the data* (no node transform: the single node has none, so every importer
sees the same coordinates): a glTF point is ``R @ (scale * p)`` for a model point ``p`` (model
units), ``scale`` the mode file's metres per model unit, and ``R`` a proper rotation (handedness
and winding are kept):

=====  ============================  ==================================================
up     model (x, y, z) -> glTF       note
=====  ============================  ==================================================
z      (x, z, -y)                    Blender's convention: its importer gives the model's
                                     own z-up coordinates back
y      (x, y, z)                     unchanged
x      (-y, x, z)                    a quarter turn about z
=====  ============================  ==================================================

``R``, ``up`` and the scale are in ``meshes[0].extras.sc_fem.axes``. Mode shapes and normals are
turned by the same ``R``. A vertex animation (``sc-fem simulate``) is scaled by the ``scale`` its
metadata records (1 when it records none: then the units are the model's, and ``axes.units`` says
so).

**Surface.** One primitive with a default PBR material: dielectric (``metallicFactor`` 0,
``roughnessFactor`` 0.6, neutral grey base colour) and ``doubleSided`` (meshes people bring have
inconsistent winding). ``NORMAL`` are area-weighted vertex normals; a vertex that shares its
position with others (a mesh split at UV seams) also takes their faces that lie within 60 degrees
of its own normal, so a UV seam is smooth and a crease is kept. ``TEXCOORD_0`` comes from the source mesh: a mode file stores no UVs,
so pass the mesh the modes were computed from (``mesh=``, ``sc-fem export --mesh``; its vertices
must be the mode file's, as :func:`sc_fem.geometry.mesh.load_mesh` gives them); its UVs are
written (``v`` flipped to glTF's top-left origin) and, when the file gave vertex normals, those
are the rest ``NORMAL`` (the targets' normal deltas are always those of the computed normals).
Without ``mesh=`` there is no ``TEXCOORD_0``; the source's own material and textures are not
carried over (every file gets the default material).

**Modes.** Mode ``k``'s displacement is ``d_k = s_k phi_k`` (metres, turned by ``R``), with
``s_k`` (m kg^1/2, a modal coordinate) chosen so that its largest vertex displacement is
``amplitude`` times the bounding-box diagonal: weight 1 is a visible but small motion. Morph
weights are clamped to [0, 1] by some importers (Blender gives shape keys ``slider_min = 0``), so
each mode is **two morph targets**: target ``2k`` is ``+d_k`` and target ``2k + 1`` is ``-d_k``;
a signed mode weight ``w_k`` is written as the pair ``(max(w_k, 0), max(-w_k, 0))``, every weight
lies in [0, 1], and ``w_k = weights[2k] - weights[2k + 1]`` exactly; the modal coordinate is
``q_k = w_k s_k``. Every target also carries ``NORMAL``: the vertex normals of the displaced mesh
(rest ``+ d_k``, resp. ``- d_k``, at weight 1) minus the rest normals, so shading follows the
motion. ``meshes[0].extras.sc_fem`` holds ``targets`` (which mode and sign each target is), the
frequencies (Hz), damping ratios and ``mode_scales`` (``s_k``); ``extras.targetNames`` names them.

A baked playback (an impulse, or one mode released from weight 1, solved exactly as by
:class:`~sc_fem.ModalPlayer`) is a LINEAR animation of the weights sampled at ``fps``. Where a
mode's ``|w_k(t)|`` would exceed 1, its ``s_k`` is widened for that file so that its largest
weight is exactly 1 (the recorded ``mode_scales`` are the ones used). Modes that move and lie
above ``fps / 2`` alias; they are listed in ``extras.sc_fem.playback.aliased_modes``, and
:func:`alias_warning` says so in the words of ``sc-fem play`` (``sc-fem export`` prints it).

**Vertex animation** (``sc-fem simulate`` output): one morph target per frame (its displacement
from the rest mesh, with its normal deltas) and a LINEAR weights channel that blends frame ``i``
into ``i + 1`` -- weights in [0, 1], linear interpolation of the vertex positions between frames.
Limit: :data:`MAX_ANIMATION_TARGETS` frames (engines upload every target; subsample longer clips).

**The web viewer's layout** (``layout="viewer"``, the default of :func:`glb_bytes` only, which
``sc-fem view`` inlines): model axes and units and one signed morph target per mode, without
normal deltas -- the page drives signed weights itself, orients its camera by the up axis and
converts to metres with ``scale_m_per_unit``.

Positions, normals, UVs and morph targets are float32; indices uint32. ``quantize=True`` (by default in
the web viewer's page) stores positions and target displacements as 16-bit and normals as 8-bit
integers (``KHR_mesh_quantization``, required by the file; :mod:`sc_fem.io.quantize`): the node
then carries the dequantizing translation and uniform scale, and the viewer layout gives each
target its own 16-bit range, folded into its morph weight (``extras.sc_fem.quantization``); an
engine file keeps its weights. The document's buffer, material and morph targets are assembled by
:mod:`sc_fem.io.asset`, the vertex normals computed by :mod:`sc_fem.io.normals`.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._atomic import atomic_path
from .._validate import positive_scalar
from ..errors import InputError, MeshFileError
from ..geometry.mesh import load_mesh
from ..modes.basis import ModalBasis
from ..modes.player import ModalPlayer
from ..units import up_axis
from ._npz import npz_kind
from .animation import ANIMATION_KIND, Animation, load_animation
from .asset import _document
from .modes import load_modes
from .normals import _Normals, _unit
from .quantize import quantize_document

MAX_ANIMATION_TARGETS = 256
"""Frames of a vertex animation exported as morph targets (one target per frame)."""

DEFAULT_AMPLITUDE = 0.05
"""Largest displacement of a mode at weight 1, as a fraction of the bounding-box diagonal."""

LAYOUTS = ("engine", "viewer")
"""``engine``: +Y up, metres, two targets per mode with normal deltas (files); ``viewer``: the web
viewer's model-axes, model-units, one-signed-target-per-mode document (see the module docstring)."""

UP_TO_GLTF = {"z": ((1, 0, 0), (0, 0, 1), (0, -1, 0)),
              "y": ((1, 0, 0), (0, 1, 0), (0, 0, 1)),
              "x": ((0, -1, 0), (1, 0, 0), (0, 0, 1))}
"""Rotation ``R`` (rows: glTF X, Y, Z in model coordinates) turning the model's up axis onto +Y."""


def _load(source, what: str = "mode or animation file"):
    """A ModalBasis or an Animation from an object or a path (by the file's kind).

    Raises
    ------
    FileFormatError
        A missing, truncated, non-zip or corrupted file (named ``what``), or a foreign one.
    """
    if isinstance(source, (ModalBasis, Animation)):
        return source
    path = Path(source)
    return load_animation(path) if npz_kind(path, what=what) == ANIMATION_KIND else load_modes(path)


def _surface(mesh, rest: np.ndarray):
    """``(uv or None, normals or None)`` of the source mesh ``mesh`` (path or trimesh), checked to
    have the vertices ``rest`` (model units) in the same order."""
    import trimesh

    if mesh is None:
        return None, None
    if not isinstance(mesh, trimesh.Trimesh):
        path = Path(mesh)
        if str(mesh).startswith("builtin:"):
            load_mesh(str(mesh))                  # a valid name; built-ins carry no UVs
            return None, None
        if not path.is_file():
            raise MeshFileError(f"mesh file not found: {path}")
        try:
            loaded = trimesh.load(str(path), process=False, force=None)
        except Exception as exc:  # noqa: BLE001 - third-party readers raise anything
            raise MeshFileError(f"cannot read {path} for its UVs: {type(exc).__name__}: {exc}") from None
        if isinstance(loaded, trimesh.Scene):
            geoms = [g for g in loaded.geometry.values() if isinstance(g, trimesh.Trimesh)]
            loaded = geoms[0] if len(geoms) == 1 else None
        if not isinstance(loaded, trimesh.Trimesh):
            return None, None                     # point clouds, multi-part scenes: no per-vertex UVs here
        mesh = loaded
    v = np.asarray(mesh.vertices, dtype=float)
    diag = float(np.linalg.norm(np.ptp(rest, axis=0)))
    if v.shape != rest.shape or not np.allclose(v, rest, rtol=0, atol=1e-9 * max(diag, 1e-300)):
        raise InputError(f"the mesh has {len(v)} vertices that are not the {len(rest)} of the mode/animation "
                         "file: give the mesh the modes were computed from (as sc-fem precompute-modes read it)")
    uv = getattr(mesh.visual, "uv", None)
    uv = None if uv is None or np.shape(uv) != (len(v), 2) else np.asarray(uv, dtype=float)
    if uv is not None:
        uv = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]])          # glTF's UV origin is the top left
    normals = None
    if "vertex_normals" in getattr(mesh, "_cache", ()):              # given by the file (e.g. OBJ vn)
        normals = _unit(np.asarray(mesh.vertex_normals, dtype=float), fallback=(0.0, 0.0, 1.0))
    return uv, normals


def mode_scales(basis, amplitude: float = DEFAULT_AMPLITUDE) -> np.ndarray:
    """``s_k`` (m kg^1/2): the modal coordinate at which mode ``k``'s largest vertex displacement
    is ``amplitude`` times the bounding-box diagonal, shape (k,)."""
    diag = float(np.linalg.norm(np.ptp(np.asarray(basis.vertices, dtype=float), axis=0)))
    peak = np.linalg.norm(np.asarray(basis.modes, dtype=float), axis=2).max(axis=1) / basis.scale
    return np.where(peak > 0, amplitude * diag / np.where(peak > 0, peak, 1.0), 0.0)


def split_weights(w) -> np.ndarray:
    """Signed mode weights ``(..., k)`` as the two-targets-per-mode weights ``(..., 2k)``:
    ``[max(w_0, 0), max(-w_0, 0), max(w_1, 0), ...]``, all in [0, 1] when ``|w| <= 1``."""
    w = np.asarray(w, dtype=float)
    out = np.empty(w.shape[:-1] + (2 * w.shape[-1],))
    out[..., 0::2], out[..., 1::2] = np.maximum(w, 0.0), np.maximum(-w, 0.0)
    return out


def signed_weights(weights) -> np.ndarray:
    """The inverse of :func:`split_weights`: ``weights[..., 0::2] - weights[..., 1::2]``."""
    weights = np.asarray(weights, dtype=float)
    return weights[..., 0::2] - weights[..., 1::2]


def moving_modes(basis, *, impulse=None, mode: int | None = None) -> np.ndarray:
    """Indices of the modes a baked playback moves: ``mode``, or those with ``phi_k(vertex) . J != 0``
    for ``impulse = (vertex, J)`` (the others stay at rest)."""
    if mode is not None:
        return np.array([int(mode)])
    if impulse is None:
        return np.zeros(0, dtype=int)
    vertex, J = impulse
    dv = np.asarray(basis.modes[:, int(vertex), :], dtype=float) @ np.asarray(J, dtype=float)
    return np.flatnonzero(dv)


def aliased_modes(frequencies, fps: float, moving=None) -> list[int]:
    """Indices of the modes above ``fps / 2`` (among ``moving``, default all): a playback sampled at
    ``fps`` shows them as a slow sway that is not there (the rule of ``sc-fem play``)."""
    f = np.asarray(frequencies, dtype=float)
    idx = np.arange(len(f)) if moving is None else np.asarray(moving, dtype=int)
    return [int(i) for i in idx if f[i] > 0.5 * float(fps)]


def alias_warning(frequencies, fps: float, moving=None) -> str | None:
    """The sentence ``sc-fem play`` prints for modes above half the frame rate, or None."""
    high = aliased_modes(frequencies, fps, moving)
    if not high:
        return None
    nyquist = 0.5 * float(fps)
    fs = ", ".join(f"{frequencies[i]:.3g}" for i in high[:6]) + (", ..." if len(high) > 6 else "")
    return (f"{len(high)} mode(s) ({fs} Hz) lie above half the frame rate ({nyquist:g} Hz): they alias "
            f"into a slow sway that is not there; raise --fps or precompute with --max-frequency {nyquist:g}")


def _axes(up: str, scale: float, units: str, engine: bool) -> tuple[np.ndarray, float, dict]:
    up_axis(up)                                          # one clear error for a bad axis
    if not engine:
        return np.eye(3), 1.0, {"up": up, "gltf_up": "the model's own (the viewer turns it)",
                                "model_to_gltf": np.eye(3).tolist(), "units": "model units",
                                "scale_m_per_unit": float(scale)}
    R = np.asarray(UP_TO_GLTF[up], dtype=float)
    return R, float(scale), {"up": up, "gltf_up": "+Y", "model_to_gltf": R.tolist(), "units": units,
                             "scale_m_per_unit": float(scale),
                             "note": "glTF point = model_to_gltf @ (scale_m_per_unit * model point)"}


def gltf_document(source, *, amplitude: float = DEFAULT_AMPLITUDE, impulse=None, mode: int | None = None,
                  duration: float = 2.0, fps: float = 30.0, up: str = "z", mesh=None, layout: str = "engine",
                  quantize: bool = False):
    """The pygltflib document of :func:`export_gltf` (see there), not written.

    ``layout="viewer"`` gives the web viewer's document (model axes and units, one signed morph
    target per mode, no normal deltas; see the module docstring) instead of the engine one.
    ``quantize=True``: ``KHR_mesh_quantization`` (:func:`sc_fem.io.quantize.quantize_document`;
    per-target scales folded into the weights for the viewer layout, the node's scale for engines).
    """
    doc = _gltf_document(source, amplitude=amplitude, impulse=impulse, mode=mode, duration=duration, fps=fps,
                         up=up, mesh=mesh, layout=layout)
    if quantize:
        quantize_document(doc, per_target=layout == "viewer")
    return doc


def _gltf_document(source, *, amplitude: float, impulse, mode: int | None, duration: float, fps: float, up: str,
                   mesh, layout: str):
    """The float32 document of :func:`gltf_document`."""
    if layout not in LAYOUTS:
        raise InputError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    engine = layout == "engine"
    obj = _load(source)
    if isinstance(obj, Animation):
        if impulse is not None or mode is not None:
            raise InputError("impulse / mode apply to mode files; an animation is exported as it is")
        T = obj.n_frames
        if T > MAX_ANIMATION_TARGETS:
            raise InputError(f"the animation has {T} frames; at most {MAX_ANIMATION_TARGETS} are exported as morph "
                             "targets: write fewer frames (sc-fem simulate --fps) or subsample")
        recorded = obj.meta.get("scale") if isinstance(obj.meta, dict) else None
        known = isinstance(recorded, (int, float)) and bool(np.isfinite(recorded)) and recorded > 0
        scale, units = (float(recorded), "m") if known else (1.0, "model units (the file records no scale)")
        R, k, axes = _axes(up, scale, units, engine)
        rest = np.asarray(obj.rest_vertices, dtype=float)
        uv, normals = _surface(mesh, rest)
        disp = (np.asarray(obj.positions, dtype=float) - rest[None]) * k @ R.T
        extras = {"kind": "vertex_animation", "layout": layout, "frames": T,
                  "times_s": [float(t) for t in obj.times], "units": axes["units"], "axes": axes,
                  "encoding": "one morph target per frame (its displacement from the rest mesh); a LINEAR "
                              "weights channel blends frame i into i + 1, every weight in [0, 1]",
                  "targets": [{"frame": i, "time_s": float(t)} for i, t in enumerate(obj.times)],
                  "meta": obj.meta, "target_names": [f"frame {i}" for i in range(T)]}
        verts = rest * k @ R.T
        return _document(verts, obj.faces, extras, targets=disp, normal_fn=_Normals(verts, obj.faces),
                         normals=None if normals is None else normals @ R.T, uv=uv, weights=np.eye(T)[0],
                         times=obj.times - obj.times[0], anim_weights=np.eye(T), target_normals=engine)
    basis = obj
    amplitude = positive_scalar(amplitude, "amplitude")
    if impulse is not None and mode is not None:
        raise InputError("give impulse or mode for the baked playback, not both")
    R, k, axes = _axes(up, basis.scale, "m", engine)
    rest = np.asarray(basis.vertices, dtype=float)
    uv, normals = _surface(mesh, rest)
    s = mode_scales(basis, amplitude)
    extras = {"kind": "modes", "layout": layout, "frequencies_hz": [float(f) for f in basis.frequencies],
              "damping_ratios": [float(z) for z in basis.damping], "amplitude": amplitude,
              "scale_m_per_unit": float(basis.scale), "units": axes["units"], "axes": axes,
              "source": basis.source, "material": basis.material, "fixed": basis.fix_record}
    playback = None
    if impulse is not None or mode is not None:
        player = ModalPlayer(basis)
        if impulse is not None:
            vertex, J = impulse
            player.impulse(int(vertex), J)
            what = f"impulse {list(map(float, J))} N s on vertex {int(vertex)}"
        else:
            player.excite(int(mode), amplitude * float(np.linalg.norm(np.ptp(basis.vertices, axis=0))))
            what = f"mode {int(mode)} released from weight 1"
        times = player.times(duration, fps)
        q = player.coordinates(times)                                    # (T, k), exact
        if engine:                                 # no weight beyond 1: widen s_k where the motion needs it
            peak = np.abs(np.where(s > 0, q / np.where(s > 0, s, 1.0), 0.0)).max(axis=0)
            s = s * np.maximum(peak, 1.0)
        w = np.where(s > 0, q / np.where(s > 0, s, 1.0), 0.0)
        moving = moving_modes(basis, impulse=impulse, mode=mode)
        playback = {"what": what, "fps": float(fps), "duration_s": float(times[-1]),
                    "aliased_modes": aliased_modes(basis.frequencies, fps, moving),
                    "nyquist_hz": 0.5 * float(fps)}
    extras["mode_scales"] = [float(x) for x in s]
    d = np.asarray(basis.modes, dtype=float) * s[:, None, None]          # metres
    if engine:
        d = d @ R.T
        targets = np.stack([d, -d], axis=1).reshape(-1, *d.shape[1:])
        extras["mode_scales_units"] = ("m kg^0.5 (modal coordinate q_k = w_k * mode_scales[k], w_k = "
                                       "weights[2k] - weights[2k+1])")
        extras["encoding"] = ("two morph targets per mode: target 2k = +mode k, target 2k+1 = -mode k; the signed "
                              "mode weight w_k = weights[2k] - weights[2k+1], both weights in [0, 1]")
        extras["targets"] = [{"mode": j, "sign": sg} for j in range(basis.n_modes) for sg in (1, -1)]
        extras["target_names"] = [f"mode {j} {'+' if sg > 0 else '-'} ({f:.4g} Hz)"
                                  for j, f in enumerate(basis.frequencies) for sg in (1, -1)]
        split = split_weights
    else:
        targets = d / basis.scale                                        # model units
        extras["mode_scales_units"] = "m kg^0.5 (modal coordinate q_k = weight_k * mode_scales[k])"
        extras["encoding"] = "one morph target per mode, signed weights"
        extras["targets"] = [{"mode": j, "sign": 1} for j in range(basis.n_modes)]
        extras["target_names"] = [f"mode {j}: {f:.4g} Hz" for j, f in enumerate(basis.frequencies)]
        split = np.asarray
    verts = rest * k @ R.T
    common = dict(targets=targets, normal_fn=_Normals(verts, basis.faces), uv=uv, target_normals=engine,
                  normals=None if normals is None else normals @ R.T)
    if playback is None:
        return _document(verts, basis.faces, extras, weights=np.zeros(len(targets)), **common)
    extras["playback"] = playback
    ws = split(w)
    if engine:
        ws = np.clip(ws, 0.0, 1.0)                 # rounding only: |w| <= 1 by the widened scales
    return _document(verts, basis.faces, extras, weights=ws[0], times=times, anim_weights=ws, **common)


def export_gltf(source, path, *, amplitude: float = DEFAULT_AMPLITUDE, impulse=None, mode: int | None = None,
                duration: float = 2.0, fps: float = 30.0, up: str = "z", mesh=None, quantize: bool = False) -> Path:
    """Write a mode file (or :class:`~sc_fem.ModalBasis`) or a vertex animation as glTF 2.0.

    The file is +Y up and in metres, with a dielectric double-sided material, normals, and two
    morph targets (``+`` and ``-``) with normal deltas per mode so every weight is in [0, 1]; see
    the module docstring for the exact encoding.

    Parameters
    ----------
    source : ModalBasis, Animation or path
        Modes (two morph targets per mode) or a vertex animation (one morph target per frame).
    path : str or Path
        ``.glb`` (binary, one file) or ``.gltf`` (JSON with the buffer embedded as a data URI).
    amplitude : float
        Largest displacement of a mode at weight 1, as a fraction of the bounding-box diagonal.
    impulse : (vertex, (Jx, Jy, Jz)), optional
        Bake the exact damped response to this impulse (N s) as a weights animation.
    mode : int, optional
        Bake mode ``mode`` released from weight 1 as a weights animation.
    duration, fps : float
        Length (s) and sampling rate of a baked playback. Moving modes above ``fps / 2`` alias:
        they are listed in ``extras.sc_fem.playback.aliased_modes`` (see :func:`alias_warning`).
    up : {"z", "y", "x"}
        The model's up axis, turned onto glTF's +Y (default ``"z"``, as ``sc-fem view``).
    mesh : str, Path or trimesh.Trimesh, optional
        The source mesh, with the mode file's vertices in the same order: its UVs become
        ``TEXCOORD_0`` and its file normals (if any) ``NORMAL``. A mode file stores no UVs; without
        ``mesh`` the glTF has none.
    quantize : bool
        16-bit positions and displacements, 8-bit normals (``KHR_mesh_quantization``, listed in
        ``extensionsRequired``; the node's translation and scale dequantize, weights unchanged):
        about two thirds of the size, positions and displacements within ``S / 65534`` of the
        float ones (``S`` the node's scale, about half the model's size).

    Returns
    -------
    Path
    """
    path = Path(path)
    kind = path.suffix.lower()
    if kind not in (".glb", ".gltf"):
        raise InputError(f"glTF is written as .glb or .gltf, got {path.name!r}")
    doc = gltf_document(source, amplitude=amplitude, impulse=impulse, mode=mode, duration=duration, fps=fps,
                        up=up, mesh=mesh, quantize=quantize)
    with atomic_path(path, suffix=kind) as tmp:
        if kind == ".glb":
            doc.save_binary(str(tmp))
        else:
            import pygltflib as g

            doc.convert_buffers(g.BufferFormat.DATAURI)
            Path(tmp).write_text(json.dumps(json.loads(doc.to_json()), separators=(",", ":")))
    return path


def glb_bytes(source, *, layout: str = "viewer", quantize: bool = False, **options) -> bytes:
    """A ``.glb`` as bytes: by default the web viewer's document (``layout="viewer"``: model axes
    and units, one signed morph target per mode), with ``layout="engine"`` the bytes
    :func:`export_gltf` writes to a ``.glb``. ``quantize=True``: ``KHR_mesh_quantization`` (what
    ``sc-fem view`` inlines, packed). ``options`` as for :func:`gltf_document`."""
    return b"".join(gltf_document(source, layout=layout, quantize=quantize, **options).save_to_bytes())
