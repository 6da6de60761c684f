"""``KHR_mesh_quantization`` for the glTF documents of :mod:`sc_fem.io.gltf` (``quantize=True``).

:func:`quantize_document` rewrites a float32 document (as :func:`sc_fem.io.gltf.gltf_document`
builds it) in place; every number below is in the document's own units (metres for the engine
layout, model units for the viewer's):

* ``POSITION``: SHORT normalized (``c = round(f * 32767)``, the extension's rule), stride 8. The
  dequantization is the node's ``translation`` (the box centre ``o``) and uniform ``scale``
  ``S`` (so normals keep their direction): a point is ``o + S * c / 32767``, off by at most
  ``S / 65534`` per component. ``S`` is the largest half extent of the box, raised to the
  largest target displacement when that is larger (so every target fits the ``[-1, 1]`` range).
* Target ``POSITION`` (displacements): SHORT normalized with a per-target scale ``a_t``:
  ``c = round(d / a_t * 32767)``, off by at most ``a_t / 65534``. A morph target is added in
  the node's frame (before ``S``), so the morph weight that gives the original target at weight
  ``w`` is ``w * a_t / S``: the *weight factor* ``a_t / S``, applied to ``meshes[0].weights`` and
  to the weights animation here. ``per_target=True`` (the web viewer): ``a_t`` is the target's
  own largest component (16 bits of its own range; weight factors below 1). ``per_target=False``
  (engine files): ``a_t = S`` for every target, weight factor 1, so a weight keeps its meaning
  (weight 1 = the target, every weight in [0, 1]) in every importer; the step is ``S / 32767``.
* ``NORMAL`` (unit vectors): BYTE normalized, stride 4. Target ``NORMAL`` deltas (up to 2 per
  component) divided by the weight factor: SHORT normalized when they fit ``[-1, 1]``, float32
  otherwise (as the extension says of large normal displacements).
* Indices, UVs and the animation stay as they were (uint32, float32).

``extensionsUsed`` and ``extensionsRequired`` list ``KHR_mesh_quantization`` (files that use it
cannot be read without it), and ``meshes[0].extras.sc_fem.quantization`` records ``o``, ``S``,
every ``a_t`` and weight factor.
"""

from __future__ import annotations

import numpy as np

EXTENSION = "KHR_mesh_quantization"
"""The glTF extension a quantized document requires."""

_BYTE, _SHORT, _UINT, _FLOAT = 5120, 5122, 5125, 5126          # glTF componentType codes
_LIMIT = {_BYTE: 127, _SHORT: 32767}
_DTYPE = {_BYTE: np.int8, _SHORT: np.int16, _UINT: np.uint32, _FLOAT: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def _encode(values: np.ndarray, scale: float, comp: int) -> np.ndarray:
    """Normalized signed integers ``round(values / scale * limit)`` of ``values`` (n, 3), padded
    to a 4-byte element with a zero column: shape (n, 4) int16 or (n, 4) int8."""
    limit = _LIMIT[comp]
    q = np.clip(np.rint(np.asarray(values, dtype=float) / scale * limit), -limit, limit)
    return np.column_stack([q, np.zeros(len(q))]).astype(_DTYPE[comp])


def decode(values: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """The float values of normalized signed integers (the extension's ``max(c / limit, -1)``)
    times ``scale``: shape as ``values``, float64."""
    limit = _LIMIT[_BYTE if np.asarray(values).dtype == np.int8 else _SHORT]
    return np.maximum(np.asarray(values, dtype=float) / limit, -1.0) * scale


def _read(gltf, blob: bytes, index: int) -> np.ndarray:
    """Accessor ``index`` of ``gltf`` (tightly packed float32 / uint32, as :mod:`asset` writes
    them) as an array of shape (count, width)."""
    acc = gltf.accessors[index]
    view = gltf.bufferViews[acc.bufferView]
    width = _WIDTH[acc.type]
    data = np.frombuffer(blob, _DTYPE[acc.componentType], acc.count * width, view.byteOffset + (acc.byteOffset or 0))
    return data.reshape(acc.count, width)


def quantize_document(gltf, *, per_target: bool) -> dict:
    """Quantize a float32 document of :mod:`sc_fem.io.gltf` in place (see the module docstring).

    Parameters
    ----------
    gltf : pygltflib.GLTF2
        One mesh of one primitive on node 0, float32 attributes, one accessor per buffer view
        (as :func:`sc_fem.io.asset._document` builds it), optionally a weights animation.
    per_target : bool
        Each target's displacement gets its own 16-bit scale (the weight factors fold it into the
        morph weights: the web viewer) instead of the node's scale (weights unchanged: engines).

    Returns
    -------
    dict
        The record also stored as ``meshes[0].extras["sc_fem"]["quantization"]``: ``offset``
        (3,) and ``scale`` (the node's translation and uniform scale), ``target_scales`` (t,)
        (``a_t``: a target's displacement is ``a_t * c / 32767``, document units),
        ``weight_factors`` (t,) (morph weight = original weight times it) and the encodings.
    """
    import pygltflib as g

    blob = gltf.binary_blob()
    mesh = gltf.meshes[0]
    prim = mesh.primitives[0]
    targets = prim.targets or []
    p = _read(gltf, blob, prim.attributes.POSITION).astype(float)
    d = [_read(gltf, blob, t["POSITION"]).astype(float) for t in targets]
    peak = np.array([np.abs(x).max() if x.size else 0.0 for x in d])
    offset = 0.5 * (p.min(axis=0) + p.max(axis=0)) if len(p) else np.zeros(3)
    scale = max(float(np.abs(p - offset).max()) if len(p) else 0.0, float(peak.max(initial=0.0)))
    scale = scale if scale > 0 else 1.0
    a = np.where(peak > 0, peak, scale) if per_target else np.full(len(d), scale)
    factor = a / scale
    new: dict[int, tuple[np.ndarray, int, bool]] = {}           # accessor -> (data, componentType, min/max)
    new[prim.attributes.POSITION] = (_encode(p - offset, scale, _SHORT), _SHORT, True)
    if prim.attributes.NORMAL is not None:
        new[prim.attributes.NORMAL] = (_encode(_read(gltf, blob, prim.attributes.NORMAL), 1.0, _BYTE), _BYTE, False)
    normals: set[str] = set()
    for t, tgt in enumerate(targets):
        new[tgt["POSITION"]] = (_encode(d[t], a[t], _SHORT), _SHORT, True)
        if "NORMAL" in tgt:
            dn = _read(gltf, blob, tgt["NORMAL"]).astype(float) / factor[t]
            fits = not dn.size or np.abs(dn).max() <= 1.0
            new[tgt["NORMAL"]] = (_encode(dn, 1.0, _SHORT), _SHORT, False) if fits else (dn.astype(np.float32), _FLOAT, False)
            normals.add("SHORT normalized" if fits else "float32")
    weights_out = None
    if gltf.animations:
        sampler = gltf.animations[0].samplers[gltf.animations[0].channels[0].sampler]
        weights_out = sampler.output
        w = _read(gltf, blob, weights_out).reshape(-1, len(targets)) * factor.astype(np.float32)
        new[weights_out] = (w.astype(np.float32).reshape(-1, 1), _FLOAT, False)
    if mesh.weights:
        mesh.weights = [float(w) for w in np.asarray(mesh.weights, dtype=float) * factor]

    parts, offset_bytes, views = [], 0, []
    for i, acc in enumerate(gltf.accessors):                  # one buffer view per accessor, rebuilt in order
        old = gltf.bufferViews[acc.bufferView]
        stride = None
        if i in new:
            data, comp, minmax = new[i]
            raw = np.ascontiguousarray(data).tobytes()
            acc.componentType = comp
            acc.normalized = True if comp in _LIMIT else None
            stride = data.itemsize * data.shape[1] if comp in _LIMIT and acc.type == "VEC3" else None
            if minmax:
                acc.min = [int(x) for x in data[:, :3].min(axis=0)] if len(data) else [0, 0, 0]
                acc.max = [int(x) for x in data[:, :3].max(axis=0)] if len(data) else [0, 0, 0]
        else:
            start = old.byteOffset + (acc.byteOffset or 0)
            raw = blob[start:start + old.byteLength]
        views.append(g.BufferView(buffer=0, byteOffset=offset_bytes, byteLength=len(raw), byteStride=stride,
                                  target=old.target))
        acc.bufferView, acc.byteOffset = len(views) - 1, None
        pad = (-len(raw)) % 4
        parts.append(raw + b"\x00" * pad)
        offset_bytes += len(raw) + pad
    gltf.bufferViews = views
    data = b"".join(parts)
    gltf.buffers = [g.Buffer(byteLength=len(data))]
    gltf.set_binary_blob(data)
    gltf.nodes[0].translation = [float(x) for x in offset]
    gltf.nodes[0].scale = [scale] * 3
    gltf.extensionsUsed = sorted(set(gltf.extensionsUsed or []) | {EXTENSION})
    gltf.extensionsRequired = sorted(set(gltf.extensionsRequired or []) | {EXTENSION})
    record = {"extension": EXTENSION, "offset": [float(x) for x in offset], "scale": scale,
              "position": "SHORT normalized: point = offset + scale * c / 32767 (the node's translation and scale)",
              "target_scales": [float(x) for x in a], "weight_factors": [float(x) for x in factor],
              "targets": ("SHORT normalized: displacement = target_scales[t] * c / 32767; morph weight = "
                          "weight * weight_factors[t]" + (" (the per-target scale folded into the weight)"
                                                          if per_target else " (1: the node's scale)")),
              "normal": "BYTE normalized" if prim.attributes.NORMAL is not None else "none",
              "target_normals": (" or ".join(sorted(normals)) + " (delta divided by weight_factors[t])") if normals else "none"}
    mesh.extras["sc_fem"]["quantization"] = record
    return record
