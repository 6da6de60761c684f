"""``sc-fem export --quantize``: the glTF writer's ``KHR_mesh_quantization`` on the command line.
The file is smaller, valid, keeps its weights, and what a renderer draws from it -- decoded here
with the extension's own rule, not the writer's code -- is the float file's motion within the
16-bit step; other formats refuse the flag in one line and write nothing."""

from __future__ import annotations

import numpy as np
import pytest

import sc_fem
from sc_fem._cli.main import main
from test_gltf_viewer import _validate  # the Khronos validator (skips where it is not installed)

EXTENSION = "KHR_mesh_quantization"
STEP = 1.0 / 32767                              # a SHORT normalized step, of the node's scale S
FLOAT32 = 2.0 ** -23


@pytest.fixture(scope="module")
def chair(tmp_path_factory):
    """``sc-fem precompute-modes builtin:chair``: 5 modes at r12 (198 vertices)."""
    modes = tmp_path_factory.mktemp("chair") / "chair.modes.npz"
    assert main(["precompute-modes", "builtin:chair", "--fix", "default", "--modes", "5", "-r", "12",
                 "-o", str(modes), "--quiet"]) == 0
    return sc_fem.load_modes(modes), modes


def _doc(path):
    """The document of a .glb or a .gltf (its data-URI buffer as the binary blob)."""
    import pygltflib

    doc = pygltflib.GLTF2().load(str(path))
    if doc.binary_blob() is None:
        doc.convert_buffers(pygltflib.BufferFormat.BINARYBLOB)
    return doc


def _values(doc, index: int) -> np.ndarray:
    """Accessor ``index`` as floats, shape (count, width): float32 as it is, normalized BYTE/SHORT
    by the glTF rule ``max(c / (2^(bits-1) - 1), -1)``; any byteStride."""
    acc = doc.accessors[index]
    view = doc.bufferViews[acc.bufferView]
    dtype = np.dtype({5120: np.int8, 5122: np.int16, 5125: np.uint32, 5126: np.float32}[acc.componentType])
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}[acc.type]
    stride = view.byteStride or width * dtype.itemsize
    start = view.byteOffset + (acc.byteOffset or 0)
    raw = np.frombuffer(doc.binary_blob(), dtype, (acc.count - 1) * stride // dtype.itemsize + width, start)
    x = np.lib.stride_tricks.as_strided(raw, (acc.count, width), (stride, dtype.itemsize)).astype(float)
    if acc.normalized:
        assert dtype.kind == "i"
        x = np.maximum(x / np.iinfo(dtype).max, -1.0)
    return x


def _drawn(doc, weights) -> np.ndarray:
    """What a renderer draws for morph ``weights``: the node's translation and scale applied to
    ``POSITION + sum_t weights[t] * target_t`` (glTF coordinates), shape (n, 3)."""
    prim = doc.meshes[0].primitives[0]
    p = _values(doc, prim.attributes.POSITION)
    for w, tgt in zip(weights, prim.targets):
        p = p + w * _values(doc, tgt["POSITION"])
    node = doc.nodes[0]
    return np.asarray(node.translation or [0.0, 0.0, 0.0]) + p * np.asarray(node.scale or [1.0, 1.0, 1.0])


def _animation(doc) -> tuple[np.ndarray, np.ndarray]:
    sampler = doc.animations[0].samplers[doc.animations[0].channels[0].sampler]
    t = _values(doc, sampler.input).ravel()
    return t, _values(doc, sampler.output).reshape(len(t), -1)


def test_quantize_gives_a_smaller_valid_glb_with_the_same_motion(chair, tmp_path):
    """A baked strike with and without ``--quantize``: the quantized file requires the extension,
    stores 16-bit positions and displacements, is under 75 % of the size, has the very same
    weights (animation and default), and at every frame draws the float file's vertices -- and
    the exact modal motion -- within the step ``S / 32767`` per unit of weight (``S`` the node's
    scale); the motion itself is hundreds of steps large."""
    basis, modes = chair
    top = int(np.argmax(basis.vertices[:, 2]))
    strike = ["--impulse", str(top), "30", "0", "10", "--fps", "60", "--duration", "0.25", "--quiet"]
    plain, small = tmp_path / "plain.glb", tmp_path / "small.glb"
    assert main(["export", str(modes), "-o", str(plain), *strike]) == 0
    assert main(["export", str(modes), "-o", str(small), *strike, "--quantize"]) == 0
    p, q = _doc(plain), _doc(small)
    assert not p.extensionsRequired and q.extensionsUsed == [EXTENSION] and q.extensionsRequired == [EXTENSION]
    prim = q.meshes[0].primitives[0]
    for index in [prim.attributes.POSITION] + [t["POSITION"] for t in prim.targets]:
        acc = q.accessors[index]
        assert (acc.componentType, acc.normalized) == (5122, True)          # SHORT normalized
    assert small.stat().st_size < 0.75 * plain.stat().st_size, (small.stat().st_size, plain.stat().st_size)

    tp, wp = _animation(p)
    tq, wq = _animation(q)
    np.testing.assert_array_equal(tq, tp)
    np.testing.assert_array_equal(wq, wp)                                      # weights keep their meaning
    np.testing.assert_array_equal(q.meshes[0].weights, p.meshes[0].weights)
    assert wq.min() >= 0.0 and wq.max() == pytest.approx(1.0, abs=1e-6)

    S = float(q.nodes[0].scale[0])
    assert q.nodes[0].scale == [S, S, S] and 0.3 < S < 0.6                    # about half the chair's size
    R = np.asarray(p.meshes[0].extras["sc_fem"]["axes"]["model_to_gltf"])
    player = sc_fem.ModalPlayer(basis)
    player.impulse(top, [30.0, 0.0, 10.0])
    coords = player.coordinates(tp)
    rest = _drawn(p, wp[0] * 0)
    largest = 0.0
    for i, w in enumerate(wq):
        bound = S * STEP / 2 * (1 + np.abs(w).sum()) * (1 + 1e-6) + 4 * FLOAT32
        got, ref = _drawn(q, w), _drawn(p, w)
        assert np.abs(got - ref).max() <= bound, (i, np.abs(got - ref).max(), bound)
        exact = (basis.vertices + np.einsum("k,knc->nc", coords[i], basis.modes)) * basis.scale @ R.T
        assert np.abs(got - exact).max() <= bound + 1e-6, (i, np.abs(got - exact).max(), bound)
        largest = max(largest, np.abs(ref - rest).max())
    assert largest > 300 * S * STEP, (largest, S * STEP)                      # the check is not vacuous
    issues = _validate(small)
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]


def test_quantized_animation_as_gltf_text(tmp_path):
    """``--quantize`` on a ``sc-fem simulate`` run written as ``.gltf``: every frame's morph target
    (weight 1) draws that frame's positions (metres, glTF +Y up) within half a step of ``S``."""
    anim = tmp_path / "run.npz"
    assert main(["simulate", "builtin:beam", "-r", "6", "--fix", "default", "--gravity", "--dt", "1e-3",
                 "--duration", "0.01", "-o", str(anim), "--quiet"]) == 0
    a = sc_fem.load_animation(anim)
    out = tmp_path / "run.gltf"
    assert main(["export", str(anim), "-o", str(out), "--quantize", "--quiet"]) == 0
    doc = _doc(out)
    assert doc.extensionsRequired == [EXTENSION]
    R = np.asarray(doc.meshes[0].extras["sc_fem"]["axes"]["model_to_gltf"])
    S = float(doc.nodes[0].scale[0])
    T = len(doc.meshes[0].primitives[0].targets)
    assert T == a.n_frames
    for i in range(T):
        got = _drawn(doc, np.eye(T)[i])
        want = a.positions[i] * a.meta["scale"] @ R.T
        assert np.abs(got - want).max() <= S * STEP * (1 + 1e-6) + 4 * FLOAT32 * S, i
    issues = _validate(out)
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]


@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".vtu"])
def test_quantize_is_refused_outside_gltf(chair, tmp_path, capsys, suffix):
    """USD and ``.vtu`` have no such encoding: one error line naming glTF, exit status 2, no file
    (also without ``usd-core``: the flag is checked first)."""
    _, modes = chair
    out = tmp_path / f"chair{suffix}"
    assert main(["export", str(modes), "-o", str(out), "--quantize"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--quantize applies to glTF only (.glb, .gltf" in err and suffix in err, err
    assert list(tmp_path.iterdir()) == []
