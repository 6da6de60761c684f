"""The web viewer's quantized model (``KHR_mesh_quantization``, :mod:`sc_fem.io.quantize`) and its
packed payload (:func:`sc_fem.io.viewer.pack_glb`): a 139k-vertex, 16-mode page stays at most
15 MB (it was 44 MB as float32), and what the page carries decodes to the float32 positions and
mode shapes within half a quantization step. The engine export's ``quantize=True`` passes the
Khronos validator with its weights unchanged."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_gltf_viewer import _validate

import sc_fem
from sc_fem.io.gltf import export_gltf, glb_bytes, gltf_document, mode_scales
from sc_fem.io.quantize import EXTENSION, decode
from sc_fem.io.viewer import BUNDLE, pack_glb, read_viewer_glb, unpack_glb, write_viewer

N_VERTICES, N_MODES = 139_000, 16
HALF_STEP = 1.0 / 65534                      # half of the 16-bit normalized step 1/32767
FLOAT32 = 2.0 ** -23                         # relative spacing of float32 (the originals' own rounding)


def _refined(v: np.ndarray, f: np.ndarray, at_least: int) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint-subdivide ``(v, f)``: whole passes, then the fewest leading faces of one more pass
    whose new edge midpoints bring the vertex count to ``at_least``."""
    import trimesh

    while 4 * len(v) < at_least:
        v, f = trimesh.remesh.subdivide(v, f)
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    _, first = np.unique(e[:, 0] * len(v) + e[:, 1], return_index=True)       # each edge's first face
    lead = np.sort(first % len(f))[at_least - len(v) - 1] + 1
    return trimesh.remesh.subdivide(v, f, face_index=np.arange(lead))


@pytest.fixture(scope="module")
def big(tmp_path_factory):
    """A mode file of the issue's size: the chair's 16 lowest modes (a real modal run) baked, by
    the same trilinear embedding ``sc_fem.modal`` uses, onto the chair refined to 139,000+
    vertices, each moved at random by up to a quarter of the mean edge like a scanned surface
    (its page is as large as that of the Stanford bunny subdivided to 139,122 vertices with its
    own 16 modes: 12.5 against 12.2 MB); and its viewer page."""
    from sc_fem.lattice.embed import embedding

    if not BUNDLE.is_file():
        pytest.skip("the viewer bundle is not built (make viewer; needs npm)")
    d = tmp_path_factory.mktemp("big")
    coarse = sc_fem.modal("builtin:chair", resolution=10, n_modes=N_MODES, fix="default", keep_lattice=True)
    v, f = _refined(coarse.vertices, coarse.faces, N_VERTICES)
    edge = np.linalg.norm(v[f[:, 1]] - v[f[:, 0]], axis=1).mean()
    v = v + np.random.default_rng(0).uniform(-0.25, 0.25, v.shape) * edge
    W = embedding(coarse.lattice, v).W
    modes = np.stack([W @ node for node in np.asarray(coarse.node_modes)]).astype(np.float32)
    basis = dataclasses.replace(coarse, vertices=v, faces=f, modes=modes, lattice=None, node_modes=None)
    npz = sc_fem.save_modes(basis, d / "chair_big.npz")
    return sc_fem.load_modes(npz), npz, write_viewer(npz, d / "chair_big.html")


def test_a_139k_vertex_16_mode_page_is_at_most_15_mb(big):
    """The size of the issue: 139k vertices x 16 modes was a 44 MB page as base64 float32; the
    quantized, packed page is at most 15 MB (here 12.5 MB), and the packing is lossless (the
    page's .glb is exactly :func:`glb_bytes` with ``quantize=True``)."""
    basis, npz, page = big
    assert basis.n_vertices >= N_VERTICES and basis.n_modes == N_MODES
    size = page.stat().st_size
    assert size <= 15_000_000, f"{size / 1e6:.2f} MB"
    assert read_viewer_glb(page) == glb_bytes(npz, quantize=True)


def test_the_page_decodes_to_the_float32_modes_within_half_a_step(big):
    """What the page carries, decoded here independently (pygltflib, numpy, the extension's
    ``max(c / 32767, -1)``): the rest positions within ``S / 65534`` and every mode's
    displacement within ``a_k / 65534`` of the float32 ones (``S`` the node's scale, ``a_k`` the
    mode's own largest component: 16 bits of each mode's range), and the morph weight times the
    weight factor moves the model as the float targets did."""
    import pygltflib

    basis, _, page = big
    doc = pygltflib.GLTF2.load_from_bytes(read_viewer_glb(page))
    assert doc.extensionsUsed == [EXTENSION] and doc.extensionsRequired == [EXTENSION]
    prim = doc.meshes[0].primitives[0]
    blob = doc.binary_blob()

    def ints(index):                         # (count, 3) int16 of a SHORT normalized VEC3 (stride 8)
        acc = doc.accessors[index]
        view = doc.bufferViews[acc.bufferView]
        assert (acc.componentType, acc.normalized, acc.type, view.byteStride) == (5122, True, "VEC3", 8)
        return np.frombuffer(blob, np.int16, 4 * acc.count, view.byteOffset).reshape(-1, 4)[:, :3]

    node = doc.nodes[0]
    S, o = node.scale[0], np.asarray(node.translation)
    assert node.scale == [S, S, S]                                   # uniform: normals keep their direction
    rest = o + decode(ints(prim.attributes.POSITION), S)
    v32 = basis.vertices.astype(np.float32).astype(float)
    err = np.abs(rest - v32).max()
    assert err <= S * HALF_STEP * (1 + 1e-6) + np.abs(v32).max() * FLOAT32, (err, S * HALF_STEP)

    q = doc.meshes[0].extras["sc_fem"]["quantization"]
    a, factor = np.asarray(q["target_scales"]), np.asarray(q["weight_factors"])
    s = mode_scales(basis)
    assert len(prim.targets) == N_MODES
    for k, tgt in enumerate(prim.targets):
        want = (basis.modes[k].astype(float) * s[k] / basis.scale).astype(np.float32).astype(float)   # model units
        assert a[k] == pytest.approx(np.abs(want).max(), rel=1e-6)                  # the mode's own range
        assert factor[k] == pytest.approx(a[k] / S, rel=1e-12)
        got = decode(ints(tgt["POSITION"]), a[k])
        err = np.abs(got - want).max()
        assert err <= a[k] * HALF_STEP * (1 + 1e-6) + a[k] * FLOAT32, (k, err, a[k] * HALF_STEP)
        for w in (1.0, -0.5):                # what three.js draws: o + S (rest + influence * target)
            moved = o + S * (decode(ints(prim.attributes.POSITION)) + w * factor[k] * decode(ints(tgt["POSITION"])))
            bound = (S + abs(w) * a[k]) * HALF_STEP * (1 + 1e-6) + 2 * np.abs(v32).max() * FLOAT32
            assert np.abs(moved - (v32 + w * want)).max() <= bound


def test_packing_is_lossless_at_the_int16_extremes():
    """:func:`pack_glb` / :func:`unpack_glb` on adversarial streams: +-32767 and -32768 next to each
    other (residuals wrap modulo 2^16), a point set (no faces: each vertex predicted by the one
    before), degenerate and repeated triangles, and bytes outside the streams left as they are."""
    rng = np.random.default_rng(7)
    n = 1000
    v = rng.normal(size=(n, 3))
    f = rng.integers(0, n, size=(3000, 3))
    f[:50, 1] = f[:50, 0]                                            # degenerate triangles
    stream = rng.choice(np.array([-32768, -32767, -1, 0, 1, 32767], dtype=np.int16), size=(n, 4))
    other = rng.integers(0, 256, size=37, dtype=np.uint8).tobytes()
    glb = other + stream.astype("<i2").tobytes() + stream[::-1].astype("<i2").tobytes() + other
    streams = [len(other), len(other) + 8 * n]
    for faces in (f, np.zeros((0, 3), dtype=int)):
        payload, spec = pack_glb(glb, streams, v, faces)
        assert unpack_glb(payload, spec) == glb


def test_engine_export_can_be_quantized_and_stays_valid(tmp_path):
    """``export_gltf(..., quantize=True)``: the extension in ``extensionsUsed`` and
    ``extensionsRequired``, 0 errors and 0 warnings from the Khronos validator (also with a baked
    strike), weights unchanged (the targets share the node's scale), positions and displacements
    within ``S / 65534`` of the float file's, and under 75 % of its size (targets: 16 bytes a
    vertex instead of 24; indices stay uint32)."""
    import pygltflib

    basis = sc_fem.modal("builtin:chair", resolution=8, n_modes=4, fix="default")
    top = int(np.argmax(basis.vertices[:, 2]))
    plain = gltf_document(basis, impulse=(top, [1.0, 0.0, 0.0]), duration=0.2, fps=60)
    out = export_gltf(basis, tmp_path / "q.glb", quantize=True, impulse=(top, [1.0, 0.0, 0.0]), duration=0.2, fps=60)
    doc = pygltflib.GLTF2().load(str(out))
    assert doc.extensionsUsed == [EXTENSION] and doc.extensionsRequired == [EXTENSION]
    q = doc.meshes[0].extras["sc_fem"]["quantization"]
    S = q["scale"]
    assert q["weight_factors"] == [1.0] * 2 * basis.n_modes and np.allclose(doc.meshes[0].weights, plain.meshes[0].weights)

    def read(d, index):
        acc = d.accessors[index]
        view = d.bufferViews[acc.bufferView]
        dtype = {5122: np.int16, 5120: np.int8, 5126: np.float32}[acc.componentType]
        width = (view.byteStride or 12) // np.dtype(dtype).itemsize
        x = np.frombuffer(d.binary_blob(), dtype, width * acc.count, view.byteOffset).reshape(acc.count, width)[:, :3]
        return decode(x) if acc.normalized else x.astype(float)

    pp, qp = plain.meshes[0].primitives[0], doc.meshes[0].primitives[0]
    rest = np.asarray(doc.nodes[0].translation) + S * read(doc, qp.attributes.POSITION)
    assert np.abs(rest - read(plain, pp.attributes.POSITION)).max() <= S * HALF_STEP * 1.001
    for tp, tq in zip(pp.targets, qp.targets):
        assert np.abs(S * read(doc, tq["POSITION"]) - read(plain, tp["POSITION"])).max() <= S * HALF_STEP * 1.001
        assert np.abs(read(doc, tq["NORMAL"]) - read(plain, tp["NORMAL"])).max() <= HALF_STEP * 1.001
    assert np.abs(read(doc, qp.attributes.NORMAL) - read(plain, pp.attributes.NORMAL)).max() <= 0.5 / 127 * 1.001
    float_size = len(b"".join(plain.save_to_bytes()))
    assert out.stat().st_size < 0.75 * float_size, (out.stat().st_size, float_size)
    for path in (out, export_gltf(basis, tmp_path / "q.gltf", quantize=True)):
        issues = _validate(path)
        assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]


def test_an_unquantized_page_still_carries_the_float_glb(tmp_path):
    """``write_viewer(..., quantize=False)``: the float32 document, zlib-packed, comes back exactly."""
    if not BUNDLE.is_file():
        pytest.skip("the viewer bundle is not built (make viewer; needs npm)")
    basis = sc_fem.modal("builtin:chair", resolution=8, n_modes=3, fix="default")
    page = write_viewer(basis, tmp_path / "c.html", quantize=False)
    assert read_viewer_glb(page) == glb_bytes(basis)
