"""glTF 2.0 export: the source mesh with its baked modes as morph targets (what game engines,
Blender and the browser read), or a vertex animation as morph targets with a weights channel.

A mode becomes a **morph target**: a per-vertex displacement. Mode ``k`` is stored as
``d_k = s_k phi_k / scale`` (model units), with ``s_k`` (m kg^1/2, a modal coordinate) chosen so
that the largest displacement of ``d_k`` is ``amplitude`` times the bounding-box diagonal: weight
1 is a visible but small motion, and a weight ``w_k`` means the modal coordinate ``q_k = w_k s_k``.
The ``s_k``, the frequencies (Hz) and damping ratios go to ``meshes[0].extras.sc_fem``; a baked
playback (an impulse, or one mode released from a displacement, solved exactly as by
:class:`~sc_fem.ModalPlayer`) is an animation of the weights, ``w_k(t) = q_k(t) / s_k``, sampled at
``fps``.

A vertex animation (``sc-fem simulate`` output) stores one morph target per frame (its
displacement from the rest mesh) and a LINEAR weights channel that blends frame ``i`` into ``i+1``,
which is linear interpolation of the vertex positions between frames. Limit:
:data:`MAX_ANIMATION_TARGETS` frames (engines upload every target; subsample longer clips).

Positions, normals and morph targets are float32; indices uint32.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError

MAX_ANIMATION_TARGETS = 256
"""Frames of a vertex animation exported as morph targets (one target per frame)."""

DEFAULT_AMPLITUDE = 0.05
"""Largest displacement of a mode at weight 1, as a fraction of the bounding-box diagonal."""

_FLOAT, _UINT = 5126, 5125                 # glTF componentType codes
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


class _Blob:
    """One binary buffer and its views/accessors, built up as arrays are added."""

    def __init__(self, gltf) -> None:
        self.gltf, self.parts, self.offset = gltf, [], 0

    def add(self, array: np.ndarray, kind: str, *, target: int | None = None, minmax: bool = False) -> int:
        import pygltflib as g

        data = np.ascontiguousarray(array)
        raw = data.tobytes()
        pad = (-len(raw)) % 4
        self.gltf.bufferViews.append(g.BufferView(buffer=0, byteOffset=self.offset, byteLength=len(raw),
                                                  target=target))
        self.parts.append(raw + b"\x00" * pad)
        self.offset += len(raw) + pad
        comp = _UINT if data.dtype == np.uint32 else _FLOAT
        count = data.shape[0]
        acc = g.Accessor(bufferView=len(self.gltf.bufferViews) - 1, componentType=comp, count=int(count), type=kind)
        if minmax:
            flat = data.reshape(count, -1)
            acc.min = [float(x) for x in flat.min(axis=0)]
            acc.max = [float(x) for x in flat.max(axis=0)]
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1

    def bytes(self) -> bytes:
        return b"".join(self.parts)


def _normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray | None:
    if len(faces) == 0:
        return None
    tri = vertices[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])          # area-weighted face normals
    vn = np.zeros_like(vertices)
    np.add.at(vn, faces.ravel(), np.repeat(fn, 3, axis=0))
    length = np.linalg.norm(vn, axis=1, keepdims=True)
    return np.where(length > 0, vn / np.where(length > 0, length, 1.0), np.array([0.0, 0.0, 1.0]))


def _document(vertices, faces, targets, weights, extras, *, times=None, anim_weights=None,
              interpolation: str = "LINEAR", name: str = "sc_fem"):
    """A pygltflib GLTF2 with one mesh (and optionally one weights animation) and its binary blob."""
    import pygltflib as g

    gltf = g.GLTF2(asset=g.Asset(version="2.0", generator="sc_fem"))
    blob = _Blob(gltf)
    v32 = np.asarray(vertices, dtype=np.float32)
    attrs = g.Attributes(POSITION=blob.add(v32, "VEC3", target=_ARRAY_BUFFER, minmax=True))
    nrm = _normals(np.asarray(vertices, dtype=float), faces)
    if nrm is not None:
        attrs.NORMAL = blob.add(nrm.astype(np.float32), "VEC3", target=_ARRAY_BUFFER)
    prim = g.Primitive(attributes=attrs, mode=4 if len(faces) else 0)
    if len(faces):
        prim.indices = blob.add(np.asarray(faces, dtype=np.uint32).ravel(), "SCALAR", target=_ELEMENT_ARRAY_BUFFER)
    prim.targets = [{"POSITION": blob.add(np.asarray(t, dtype=np.float32), "VEC3", target=_ARRAY_BUFFER,
                                          minmax=True)} for t in targets]
    gltf.meshes.append(g.Mesh(name=name, primitives=[prim], weights=[float(w) for w in weights],
                              extras={"targetNames": list(extras.get("target_names", [])), "sc_fem": extras}))
    gltf.nodes.append(g.Node(name=name, mesh=0))
    gltf.scenes.append(g.Scene(nodes=[0]))
    gltf.scene = 0
    if times is not None:
        t_acc = blob.add(np.asarray(times, dtype=np.float32), "SCALAR", minmax=True)
        w_acc = blob.add(np.asarray(anim_weights, dtype=np.float32).ravel(), "SCALAR")
        gltf.animations.append(g.Animation(
            name=f"{name} playback",
            samplers=[g.AnimationSampler(input=t_acc, output=w_acc, interpolation=interpolation)],
            channels=[g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(node=0, path="weights"))]))
    data = blob.bytes()
    gltf.buffers.append(g.Buffer(byteLength=len(data)))
    gltf.set_binary_blob(data)
    return gltf


def _load(source, what: str = "mode or animation file"):
    """A ModalBasis or an Animation from an object or a path (by the file's kind).

    Raises
    ------
    FileFormatError
        A missing, truncated, non-zip or corrupted file (named ``what``), or a foreign one.
    """
    from ..modes.modal import ModalBasis
    from ._npz import npz_kind
    from .animation import ANIMATION_KIND, Animation, load_animation
    from .modes import load_modes

    if isinstance(source, (ModalBasis, Animation)):
        return source
    path = Path(source)
    return load_animation(path) if npz_kind(path, what=what) == ANIMATION_KIND else load_modes(path)


def mode_scales(basis, amplitude: float = DEFAULT_AMPLITUDE) -> np.ndarray:
    """``s_k`` (m kg^1/2): the modal coordinate at which mode ``k``'s largest vertex displacement
    is ``amplitude`` times the bounding-box diagonal, shape (k,)."""
    diag = float(np.linalg.norm(np.ptp(np.asarray(basis.vertices, dtype=float), axis=0)))
    peak = np.linalg.norm(np.asarray(basis.modes, dtype=float), axis=2).max(axis=1) / basis.scale
    return np.where(peak > 0, amplitude * diag / np.where(peak > 0, peak, 1.0), 0.0)


def gltf_document(source, *, amplitude: float = DEFAULT_AMPLITUDE, impulse=None, mode: int | None = None,
                  duration: float = 2.0, fps: float = 30.0):
    """The pygltflib document of :func:`export_gltf` (see there), not written."""
    from .._validate import positive_scalar
    from ..modes.player import ModalPlayer
    from .animation import Animation

    obj = _load(source)
    if isinstance(obj, Animation):
        if impulse is not None or mode is not None:
            raise InputError("impulse / mode apply to mode files; an animation is exported as it is")
        T = obj.n_frames
        if T > MAX_ANIMATION_TARGETS:
            raise InputError(f"the animation has {T} frames; at most {MAX_ANIMATION_TARGETS} are exported as morph "
                             "targets: write fewer frames (sc-fem simulate --fps) or subsample")
        disp = obj.positions - obj.rest_vertices[None]
        extras = {"kind": "vertex_animation", "frames": T, "times_s": [float(t) for t in obj.times],
                  "units": "model units", "meta": obj.meta, "target_names": [f"frame {i}" for i in range(T)]}
        return _document(obj.rest_vertices, obj.faces, disp, np.eye(T)[0], extras,
                         times=obj.times - obj.times[0], anim_weights=np.eye(T), interpolation="LINEAR")
    basis = obj
    amplitude = positive_scalar(amplitude, "amplitude")
    s = mode_scales(basis, amplitude)
    targets = np.asarray(basis.modes, dtype=float) * (s / basis.scale)[:, None, None]
    extras = {"kind": "modes", "frequencies_hz": [float(f) for f in basis.frequencies],
              "damping_ratios": [float(z) for z in basis.damping], "mode_scales": [float(x) for x in s],
              "mode_scales_units": "m kg^0.5 (modal coordinate q_k = weight_k * mode_scales[k])",
              "amplitude": amplitude, "scale_m_per_unit": float(basis.scale), "source": basis.source,
              "material": basis.material, "fixed": basis.fix_record,
              "target_names": [f"mode {k}: {f:.4g} Hz" for k, f in enumerate(basis.frequencies)]}
    if impulse is None and mode is None:
        return _document(basis.vertices, basis.faces, targets, np.zeros(basis.n_modes), extras)
    if impulse is not None and mode is not None:
        raise InputError("give impulse or mode for the baked playback, not both")
    player = ModalPlayer(basis)
    if impulse is not None:
        vertex, J = impulse
        player.impulse(int(vertex), J)
        what = f"impulse {list(map(float, J))} N s on vertex {int(vertex)}"
    if mode is not None:
        player.excite(int(mode), amplitude * float(np.linalg.norm(np.ptp(basis.vertices, axis=0))))
        what = f"mode {int(mode)} released from weight 1"
    times = player.times(duration, fps)
    q = player.coordinates(times)                                        # (T, k), exact
    w = np.where(s > 0, q / np.where(s > 0, s, 1.0), 0.0)
    extras["playback"] = {"what": what, "fps": float(fps), "duration_s": float(times[-1])}
    return _document(basis.vertices, basis.faces, targets, w[0], extras, times=times, anim_weights=w)


def export_gltf(source, path, *, amplitude: float = DEFAULT_AMPLITUDE, impulse=None, mode: int | None = None,
                duration: float = 2.0, fps: float = 30.0) -> Path:
    """Write a mode file (or :class:`~sc_fem.ModalBasis`) or a vertex animation as glTF 2.0.

    Parameters
    ----------
    source : ModalBasis, Animation or path
        Modes (one morph target per mode) or a vertex animation (one morph target per frame).
    path : str or Path
        ``.glb`` (binary, one file) or ``.gltf`` (JSON with the buffer embedded as a data URI).
    amplitude : float
        Largest displacement of a mode at weight 1, as a fraction of the bounding-box diagonal.
    impulse : (vertex, (Jx, Jy, Jz)), optional
        Bake the exact damped response to this impulse (N s) as a weights animation.
    mode : int, optional
        Bake mode ``mode`` released from weight 1 as a weights animation.
    duration, fps : float
        Length (s) and sampling rate of a baked playback.

    Returns
    -------
    Path
    """
    from .._atomic import atomic_path

    path = Path(path)
    kind = path.suffix.lower()
    if kind not in (".glb", ".gltf"):
        raise InputError(f"glTF is written as .glb or .gltf, got {path.name!r}")
    doc = gltf_document(source, amplitude=amplitude, impulse=impulse, mode=mode, duration=duration, fps=fps)
    with atomic_path(path, suffix=kind) as tmp:
        if kind == ".glb":
            doc.save_binary(str(tmp))
        else:
            import pygltflib as g

            doc.convert_buffers(g.BufferFormat.DATAURI)
            Path(tmp).write_text(json.dumps(json.loads(doc.to_json()), separators=(",", ":")))
    return path


def glb_bytes(source, **options) -> bytes:
    """The ``.glb`` of :func:`export_gltf` as bytes (for the web viewer)."""
    return b"".join(gltf_document(source, **options).save_to_bytes())
