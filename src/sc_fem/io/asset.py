"""The glTF asset that :mod:`sc_fem.io.gltf` writes: one binary buffer with its views and
accessors (:class:`_Blob`), and a document (:func:`_document`) with one mesh of one primitive,
the default material (:data:`MATERIAL`), its morph targets and an optional LINEAR weights
animation. What goes into it (axes, units, targets, weights) is decided by :mod:`sc_fem.io.gltf`.
"""

from __future__ import annotations

import numpy as np

MATERIAL = {"name": "sc_fem default (dielectric)", "baseColorFactor": [0.7, 0.7, 0.7, 1.0],
            "metallicFactor": 0.0, "roughnessFactor": 0.6, "doubleSided": True}
"""The default PBR metallic-roughness material of every exported primitive."""

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


def _document(vertices, faces, extras, *, targets=(), normal_fn=None, normals=None, uv=None, weights=(),
              times=None, anim_weights=None, target_normals: bool = True, name: str = "sc_fem"):
    """A pygltflib GLTF2 with one mesh (and optionally one LINEAR weights animation).

    ``vertices`` / ``targets`` are already in glTF axes and units; ``normal_fn(positions)`` gives
    unit vertex normals (the rest ``NORMAL`` unless ``normals`` is given, and the targets' deltas).
    """
    import pygltflib as g

    gltf = g.GLTF2(asset=g.Asset(version="2.0", generator="sc_fem"))
    blob = _Blob(gltf)
    vertices = np.asarray(vertices, dtype=float)
    attrs = g.Attributes(POSITION=blob.add(vertices.astype(np.float32), "VEC3", target=_ARRAY_BUFFER, minmax=True))
    rest_n = None
    if len(faces):
        rest_n = normal_fn(vertices)
        written = rest_n if normals is None else normals
        attrs.NORMAL = blob.add(written.astype(np.float32), "VEC3", target=_ARRAY_BUFFER)
    if uv is not None:
        attrs.TEXCOORD_0 = blob.add(np.asarray(uv, dtype=np.float32), "VEC2", target=_ARRAY_BUFFER)
    gltf.materials.append(g.Material(
        name=MATERIAL["name"], doubleSided=MATERIAL["doubleSided"],
        pbrMetallicRoughness=g.PbrMetallicRoughness(baseColorFactor=list(MATERIAL["baseColorFactor"]),
                                                    metallicFactor=MATERIAL["metallicFactor"],
                                                    roughnessFactor=MATERIAL["roughnessFactor"])))
    prim = g.Primitive(attributes=attrs, mode=4 if len(faces) else 0, material=0)
    if len(faces):
        prim.indices = blob.add(np.asarray(faces, dtype=np.uint32).ravel(), "SCALAR", target=_ELEMENT_ARRAY_BUFFER)
    prim.targets = []
    for d in targets:
        d = np.asarray(d, dtype=float)
        tgt = {"POSITION": blob.add(d.astype(np.float32), "VEC3", target=_ARRAY_BUFFER, minmax=True)}
        if rest_n is not None and target_normals:
            tgt["NORMAL"] = blob.add((normal_fn(vertices + d) - rest_n).astype(np.float32), "VEC3",
                                     target=_ARRAY_BUFFER)
        prim.targets.append(tgt)
    if not prim.targets:
        prim.targets = None
    mesh = g.Mesh(name=name, primitives=[prim], extras={"targetNames": list(extras.get("target_names", [])),
                                                        "sc_fem": extras})
    if len(targets):
        mesh.weights = [float(w) for w in weights]
    gltf.meshes.append(mesh)
    gltf.nodes.append(g.Node(name=name, mesh=0))
    gltf.scenes.append(g.Scene(nodes=[0]))
    gltf.scene = 0
    if times is not None:
        t_acc = blob.add(np.asarray(times, dtype=np.float32), "SCALAR", minmax=True)
        w_acc = blob.add(np.asarray(anim_weights, dtype=np.float32).ravel(), "SCALAR")
        gltf.animations.append(g.Animation(
            name=f"{name} playback",
            samplers=[g.AnimationSampler(input=t_acc, output=w_acc, interpolation="LINEAR")],
            channels=[g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(node=0, path="weights"))]))
    data = blob.bytes()
    gltf.buffers.append(g.Buffer(byteLength=len(data)))
    gltf.set_binary_blob(data)
    return gltf
