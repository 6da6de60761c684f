"""glTF export (modes as morph targets, animations) checked by two independent readers and the
Khronos validator, and the web viewer driven in a real (headless) browser."""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

import sc_fem
from sc_fem._cli.main import main
from sc_fem.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
VALIDATOR = ROOT / "build" / "npm" / "node_modules" / "gltf-validator"


@pytest.fixture(scope="module")
def chair_modes(tmp_path_factory):
    d = tmp_path_factory.mktemp("chair")
    basis = sc_fem.modal("builtin:chair", resolution=12, n_modes=5, fix="default")
    return basis, sc_fem.save_modes(basis, d / "chair.npz")


def _validate(path: Path) -> dict:
    if shutil.which("node") is None or not VALIDATOR.is_dir():
        pytest.skip("the Khronos glTF validator is not installed (make viewer installs it from the npm registry)")
    script = ("const v=require(process.argv[1]);const d=new Uint8Array(require('fs').readFileSync(process.argv[2]));"
              "v.validateBytes(d).then(r=>console.log(JSON.stringify(r.issues)))")
    out = subprocess.run(["node", "-e", script, str(VALIDATOR), str(path)], capture_output=True, text=True, timeout=120)
    return json.loads(out.stdout)


def test_modes_become_morph_targets_that_two_readers_agree_on(chair_modes, tmp_path):
    import pygltflib
    import trimesh

    from sc_fem.io.gltf import mode_scales

    basis, npz = chair_modes
    assert main(["export", str(npz), "-o", str(tmp_path / "c.glb"), "--quiet"]) == 0
    glb = tmp_path / "c.glb"
    doc = pygltflib.GLTF2().load(str(glb))
    prim = doc.meshes[0].primitives[0]
    assert len(prim.targets) == 2 * basis.n_modes              # +mode k, -mode k
    extras = doc.meshes[0].extras["sc_fem"]
    R = np.asarray(extras["axes"]["model_to_gltf"])             # model z-up -> glTF +Y up, metres
    np.testing.assert_allclose(extras["frequencies_hz"], basis.frequencies)
    np.testing.assert_allclose(extras["damping_ratios"], basis.damping)
    s = np.asarray(extras["mode_scales"])
    np.testing.assert_allclose(s, mode_scales(basis, 0.05))
    blob = doc.binary_blob()

    def read(acc_index):
        acc = doc.accessors[acc_index]
        view = doc.bufferViews[acc.bufferView]
        n = {"SCALAR": 1, "VEC3": 3}[acc.type]
        return np.frombuffer(blob, np.float32, acc.count * n, view.byteOffset).reshape(acc.count, n)

    for j, tgt in enumerate(prim.targets):                  # displacement = +-baked mode x recorded scale
        k, sign = divmod(j, 2)
        want = (1 - 2 * sign) * np.asarray(basis.modes[k], dtype=np.float64) * s[k] @ R.T      # metres
        np.testing.assert_allclose(read(tgt["POSITION"]), want, rtol=2e-6, atol=2e-7 * np.abs(want).max())
    np.testing.assert_allclose(read(prim.attributes.POSITION), basis.vertices @ R.T * basis.scale, rtol=1e-6,
                               atol=1e-6)
    # the promise behind the scale: at weight 1 every mode's largest vertex displacement is 5 % of
    # the bounding-box diagonal
    diag = np.linalg.norm(np.ptp(basis.vertices, axis=0)) * basis.scale
    peaks = [np.linalg.norm(read(t["POSITION"]), axis=1).max() for t in prim.targets]
    np.testing.assert_allclose(peaks, 0.05 * diag, rtol=1e-5)
    # an independent reader: trimesh sees the same surface
    mesh = trimesh.load(glb, force="mesh")
    assert len(mesh.faces) == len(basis.faces)
    np.testing.assert_allclose(np.sort(mesh.vertices, axis=0), np.sort(basis.vertices @ R.T * basis.scale, axis=0),
                               atol=1e-5)
    issues = _validate(glb)
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]


def test_baked_playback_is_the_exact_modal_response(chair_modes, tmp_path):
    import pygltflib

    basis, npz = chair_modes
    top = int(np.argmax(basis.vertices[:, 2]))
    out = tmp_path / "p.glb"
    assert main(["export", str(npz), "-o", str(out), "--impulse", str(top), "1", "0", "0",
                 "--duration", "0.5", "--fps", "40", "--quiet"]) == 0
    doc = pygltflib.GLTF2().load(str(out))
    ch = doc.animations[0].channels[0]
    assert ch.target.path == "weights"
    sam = doc.animations[0].samplers[ch.sampler]
    blob = doc.binary_blob()
    t = np.frombuffer(blob, np.float32, doc.accessors[sam.input].count, doc.bufferViews[doc.accessors[sam.input].bufferView].byteOffset)
    w_acc = doc.accessors[sam.output]
    w = np.frombuffer(blob, np.float32, w_acc.count, doc.bufferViews[w_acc.bufferView].byteOffset).reshape(len(t), -1)
    w = w[:, 0::2] - w[:, 1::2]                             # signed mode weights (two targets per mode)
    player = sc_fem.ModalPlayer(basis)
    player.impulse(top, [1.0, 0.0, 0.0])
    q = player.coordinates(t.astype(float))
    s = np.asarray(doc.meshes[0].extras["sc_fem"]["mode_scales"])
    np.testing.assert_allclose(w * s, q, rtol=1e-5, atol=1e-6 * np.abs(q).max())
    assert len(t) == 21 and abs(t[-1] - 0.5) < 1e-6
    issues = _validate(out)
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]


def test_baked_mode_release_starts_at_weight_one(chair_modes, tmp_path):
    """``--mode K``: mode K released from weight 1 (a visible amplitude) rings down alone at its own
    frequency; the other weights stay 0. impulse and mode together are refused."""
    import pygltflib

    from sc_fem.errors import InputError
    from sc_fem.io.gltf import gltf_document

    basis, npz = chair_modes
    out = tmp_path / "m.glb"
    assert main(["export", str(npz), "-o", str(out), "--mode", "1", "--duration", "0.5", "--fps", "40",
                 "--quiet"]) == 0
    doc = pygltflib.GLTF2().load(str(out))
    sam = doc.animations[0].samplers[doc.animations[0].channels[0].sampler]
    blob = doc.binary_blob()
    t_acc, w_acc = doc.accessors[sam.input], doc.accessors[sam.output]
    t = np.frombuffer(blob, np.float32, t_acc.count, doc.bufferViews[t_acc.bufferView].byteOffset).astype(float)
    w = np.frombuffer(blob, np.float32, w_acc.count, doc.bufferViews[w_acc.bufferView].byteOffset).reshape(len(t), -1)
    w = w[:, 0::2] - w[:, 1::2]                             # signed mode weights (two targets per mode)
    assert w[0, 1] == pytest.approx(1.0, rel=1e-6)
    assert np.abs(np.delete(w, 1, axis=1)).max() < 1e-6
    om, z = 2 * np.pi * basis.frequencies[1], basis.damping[1]
    wd = om * np.sqrt(1 - z * z)
    free = np.exp(-z * om * t) * (np.cos(wd * t) + z * om / wd * np.sin(wd * t))   # released from rest
    np.testing.assert_allclose(w[:, 1], free, atol=1e-5)
    with pytest.raises(InputError, match="not both"):
        gltf_document(npz, impulse=(0, [1.0, 0, 0]), mode=1)


def test_animation_export_and_its_limit(tmp_path):
    from sc_fem.io.gltf import MAX_ANIMATION_TARGETS, export_gltf

    anim = tmp_path / "a.npz"
    assert main(["simulate", "builtin:beam", "-r", "6", "--fix", "default", "--gravity", "--dt", "1e-3",
                 "--duration", "0.01", "-o", str(anim), "--quiet"]) == 0
    out = export_gltf(anim, tmp_path / "a.gltf")
    doc = json.loads(out.read_text())
    a = sc_fem.load_animation(anim)
    assert len(doc["meshes"][0]["primitives"][0]["targets"]) == a.n_frames
    assert doc["animations"][0]["samplers"][0]["interpolation"] == "LINEAR"
    issues = _validate(out)
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"][:5]
    long = sc_fem.io.animation.Animation(faces=a.faces, rest_vertices=a.rest_vertices,
                                         times=np.arange(MAX_ANIMATION_TARGETS + 1) * 1e-3,
                                         positions=np.repeat(a.positions[:1], MAX_ANIMATION_TARGETS + 1, axis=0),
                                         energy=np.zeros(MAX_ANIMATION_TARGETS + 1))
    with pytest.raises(InputError, match="at most 256"):
        export_gltf(long, tmp_path / "b.glb")
    with pytest.raises(InputError, match=".glb or .gltf"):
        export_gltf(anim, tmp_path / "b.obj")


def _browser(size: str = "1100,700"):
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.options import Options
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        pytest.skip("selenium is not installed (pip install -e .[test])")
    chromium, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if not (chromium and driver):
        pytest.skip("headless Chromium is not installed (Debian: apt-get install chromium chromium-driver; "
                    "make test does it where it can)")
    opts = Options()
    for a in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", f"--window-size={size}",
              "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"):
        opts.add_argument(a)
    opts.binary_location = chromium
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(driver), options=opts)


def test_viewer_page_plays_a_strike_in_a_real_browser(chair_modes, tmp_path):
    """The page loads, its JavaScript unpacks the quantized .glb byte for byte as
    :func:`~sc_fem.io.viewer.read_viewer_glb` does (length and Adler-32), a click strikes, the chair
    moves between two screenshots and the console stays free of errors."""
    import zlib

    import imageio.v2 as imageio
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.support.ui import Select

    from sc_fem.io.quantize import EXTENSION
    from sc_fem.io.viewer import BUNDLE, read_viewer_glb

    if not BUNDLE.is_file():
        pytest.skip("the viewer bundle is not built (make viewer; needs npm)")
    _, npz = chair_modes
    page = tmp_path / "chair.html"
    assert main(["view", str(npz), "-o", str(page), "--quiet"]) == 0
    text = page.read_text()
    assert "http://" not in text.split("<script>")[0] and "https://" not in text.split("<script>")[0]
    d = _browser()
    try:
        d.get(page.as_uri())
        t0 = time.time()
        while not d.execute_script("return !!(window.scViewer && window.scViewer.ready)"):
            assert time.time() - t0 < 60, "the viewer did not load"
            time.sleep(0.2)
        Select(d.find_element("id", "slow")).select_by_value("0.1")
        time.sleep(0.3)
        d.save_screenshot(str(tmp_path / "before.png"))
        ActionChains(d).move_to_element(d.find_element("tag name", "canvas")).click().perform()
        time.sleep(0.25)
        d.save_screenshot(str(tmp_path / "moment1.png"))
        time.sleep(0.35)
        d.save_screenshot(str(tmp_path / "moment2.png"))
        state = d.execute_script("return window.scViewer")
        logs = [e for e in d.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]
    finally:
        d.quit()
    assert state["strikes"] == 1 and state["errors"] == [] and state["lastImpulse"]["J"] > 0
    assert logs == [], logs
    glb = read_viewer_glb(page)
    assert json.loads(glb[20:20 + int.from_bytes(glb[12:16], "little")])["extensionsRequired"] == [EXTENSION]
    assert state["glb"] == {"bytes": len(glb), "adler32": zlib.adler32(glb)}     # the browser's unpack is exact

    def model(p):                                   # the 3-D view without the clock in its corner
        return imageio.imread(p)[:-40, :700, :3].astype(int)

    moved = (np.abs(model(tmp_path / "moment2.png") - model(tmp_path / "moment1.png")).max(axis=2) > 30).sum()
    assert moved > 100                             # the struck chair moves between the two moments
