"""Blender (``bpy``) imports the glTF export of a baked strike with the snippet of
docs/guide/export.md: the chair upright along Blender's +Z (glTF +Y), in metres, both halves of
every swing over the animation (the ``+``/``-`` shape keys: nothing is clamped at 0), the exact
modal motion at the checked frames, and a small Eevee still of the chair lit by a sun. Runs when
``SC_FEM_BPY_PYTHON`` names a Python with Blender's module ``bpy`` (it renders through Blender's
own GPU module: on a machine without a GPU, EGL's software renderer); with ``SC_FEM_WRITE_DOCS=1``
the still becomes docs/gltf_blender.png."""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path

import numpy as np
import pytest

import sc_fem
from sc_fem._cli.main import main
from sc_fem.io.gltf import signed_weights

ROOT = Path(__file__).resolve().parents[1]
BPY_PYTHON = os.environ.get("SC_FEM_BPY_PYTHON")

pytestmark = pytest.mark.skipif(not BPY_PYTHON, reason="SC_FEM_BPY_PYTHON is not set (a Python with Blender's "
                                                       "module bpy, e.g. a venv with pip install bpy)")

FPS, SECONDS, STILL = 100, 0.3, 3          # 31 frames; the still shows frame 3 (the backrest 3 cm aside)


def _snippet() -> str:
    """The glTF import snippet of docs/guide/export.md (a ``{code-block} python``: tests/test_api.py
    runs the ``python`` blocks without Blender)."""
    text = (ROOT / "docs" / "guide" / "export.md").read_text(encoding="utf-8")
    blocks = [b for b in re.findall(r"```\{code-block\} python\n(.*?)```", text, flags=re.S)
              if "import_scene.gltf" in b]
    assert len(blocks) == 1, "docs/guide/export.md has one Blender glTF snippet"
    return blocks[0]


_BLENDER_RUN = r"""
import json, math, sys
import numpy as np
import bpy
from mathutils import Vector

snippet, job = sys.argv[1], json.loads(sys.argv[2])
bpy.ops.wm.read_factory_settings(use_empty=True)
code = open(snippet).read()
line = next(l for l in code.splitlines() if l.startswith("path, fps, seconds = "))
exec(code.replace(line, f"path, fps, seconds = {job['path']!r}, {job['fps']!r}, {job['seconds']!r}"), {})
scene = bpy.context.scene
ob = next(o for o in scene.objects if o.type == "MESH")
keys = ob.data.shape_keys.key_blocks[1:]
report = {"fps": scene.render.fps, "frames": [scene.frame_start, scene.frame_end],
          "keys": [k.name for k in keys], "values": []}
for f in range(scene.frame_start, scene.frame_end + 1):
    scene.frame_set(f)
    report["values"].append([k.value for k in keys])              # what the animation drives
    if f in job["frames"]:                                       # the evaluated mesh, world coordinates
        ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
        m = ev.to_mesh()
        co = np.empty(3 * len(m.vertices))
        m.vertices.foreach_get("co", co)
        mw = np.array(ob.matrix_world)
        np.save(f"{job['path']}.{f}.npy", co.reshape(-1, 3) @ mw[:3, :3].T + mw[:3, 3])
        ev.to_mesh_clear()

# the still: Eevee, the file's own material, a sun and a dim grey sky, transparent film
scene.frame_set(job["still"])
try:
    scene.render.engine = "BLENDER_EEVEE"                          # Blender 5
except TypeError:
    scene.render.engine = "BLENDER_EEVEE_NEXT"                     # Blender 4.2 - 4.5
scene.eevee.taa_render_samples = 8
r = scene.render
r.resolution_x, r.resolution_y, r.resolution_percentage = 640, 480, 100
r.film_transparent = True
r.image_settings.file_format, r.image_settings.color_mode = "PNG", "RGBA"
scene.view_settings.view_transform = "Standard"                   # plain sRGB, as three.js writes it
world = bpy.data.worlds.new("sky")
scene.world = world
if world.node_tree is None:
    world.use_nodes = True
world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.12, 0.12, 0.12, 1.0)
sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
sun.data.energy = 2.5
sun.rotation_euler = Vector((-1.0, -0.4, 1.2)).to_track_quat("Z", "Y").to_euler()  # from the left, above
scene.collection.objects.link(sun)
cam = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
cam.data.sensor_fit = "VERTICAL"
scene.collection.objects.link(cam)
scene.camera = cam
box = [ob.matrix_world @ Vector(c) for c in ob.bound_box]
centre = sum(box, Vector()) / 8
radius = max((c - centre).length for c in box)
view = Vector((0.55, -1.0, 0.45)).normalized()                    # in front, to the right, a little above
cam.location = centre + view * (1.05 * radius / math.sin(cam.data.angle_y / 2))
cam.rotation_euler = (-view).to_track_quat("-Z", "Y").to_euler()
r.filepath = job["png"]
bpy.ops.render.render(write_still=True)
report["engine"] = r.engine
print("REPORT" + json.dumps(report))
"""


def test_blender_imports_the_glb_upright_with_both_halves_of_every_swing(tmp_path):
    """``sc-fem precompute-modes builtin:chair`` then ``sc-fem export ... --impulse`` to a .glb,
    imported with the documented snippet: one keyframe per frame at the export's rate; the chair
    stands along +Z (0.86 m) with its feet down, exactly where the model is (Blender's importer
    turns glTF's +Y back onto +Z); the shape keys replay the file's weights, whose signed mode
    weights (``mode k +`` minus ``mode k -``) swing to both sides; the evaluated mesh is the exact
    modal motion (the side below rest included); the still shows the chair tall, not lying down,
    lit (not the dark of a metal or an unlit material) and distinct from the background."""
    import imageio.v2 as imageio
    import pygltflib

    modes, glb, png = tmp_path / "chair.modes.npz", tmp_path / "strike.glb", tmp_path / "chair_blender.png"
    assert main(["precompute-modes", "builtin:chair", "--fix", "default", "--modes", "4", "-r", "16",
                 "-o", str(modes), "--quiet"]) == 0
    basis = sc_fem.load_modes(modes)
    top = int(np.argmax(basis.vertices[:, 2]))                   # the backrest's top corner
    J = (10.0, 0.0, 0.0)                                          # N s sideways: up to 3 cm of motion
    assert main(["export", str(modes), "-o", str(glb), "--impulse", str(top), *map(str, J),
                 "--fps", str(FPS), "--duration", str(SECONDS), "--quiet"]) == 0
    snippet = tmp_path / "snippet.py"
    snippet.write_text(_snippet())
    frames = [0, 1, STILL, 7, 12, 30]
    job = {"path": str(glb), "fps": FPS, "seconds": SECONDS, "frames": frames, "still": STILL, "png": str(png)}
    proc = subprocess.run([BPY_PYTHON, "-c", _BLENDER_RUN, str(snippet), json.dumps(job)], capture_output=True,
                          text=True, timeout=900)
    assert proc.returncode == 0 and "REPORT" in proc.stdout, proc.stderr[-3000:]
    report = json.loads(proc.stdout.split("REPORT", 1)[1])

    # the animation: one keyframe per frame, the file's weights, both halves of the swing
    doc = pygltflib.GLTF2().load(str(glb))
    names = doc.meshes[0].extras["targetNames"]
    assert report["keys"] == names and len(names) == 2 * basis.n_modes
    assert report["fps"] == FPS and report["frames"] == [0, round(FPS * SECONDS)]
    player = sc_fem.ModalPlayer(basis)
    player.impulse(top, J)
    t = player.times(SECONDS, FPS)
    q = player.coordinates(t)                                     # exact modal coordinates, (31, 4)
    values = np.asarray(report["values"])
    assert values.shape == (len(t), 2 * basis.n_modes)
    assert values.min() >= 0.0 and values.max() <= 1.0           # Blender's shape-key range: nothing to clamp
    signed = signed_weights(values)
    np.testing.assert_allclose(signed * np.asarray(doc.meshes[0].extras["sc_fem"]["mode_scales"]), q,
                               rtol=1e-5, atol=1e-6 * np.abs(q).max())
    for k in range(3):                                           # the modes the strike moves much: both ways
        peak = np.abs(signed[:, k]).max()
        assert signed[:, k].min() < -0.5 * peak and signed[:, k].max() > 0.5 * peak, (k, signed[:, k])

    # upright, in metres, the exact motion (below rest as well as above)
    rest = np.load(f"{glb}.0.npy")
    np.testing.assert_allclose(rest, basis.vertices * basis.scale, atol=1e-6)
    assert np.ptp(rest[:, 2]) == pytest.approx(0.8598, abs=1e-3)                     # height along +Z
    assert np.ptp(rest[:, 2]) > 1.6 * max(np.ptp(rest[:, 0]), np.ptp(rest[:, 1]))
    for f in frames[1:]:
        exact = basis.vertices + np.einsum("k,knc->nc", q[f], basis.modes)
        np.testing.assert_allclose(np.load(f"{glb}.{f}.npy"), exact, atol=2e-6)
    below = [f for f in frames if q[f, 0] < 0]                    # mode 0 on its negative side ...
    assert below and max(np.abs(np.load(f"{glb}.{f}.npy") - rest).max() for f in below) > 0.01   # ... cm away

    # the still: tall (upright), lit, distinct from the background
    rgba = imageio.imread(png).astype(float)
    assert rgba.shape == (480, 640, 4), rgba.shape
    alpha = rgba[..., 3:] / 255.0
    img = rgba[..., :3] * alpha + 255.0 * (1.0 - alpha)          # on white, as the three.js picture
    chair = alpha[..., 0] > 0.5
    rows, cols = np.flatnonzero(chair.any(axis=1)), np.flatnonzero(chair.any(axis=0))
    assert chair.sum() > 10000, chair.sum()
    assert np.ptp(rows) > 1.3 * np.ptp(cols), (np.ptp(rows), np.ptp(cols))         # upright, not on its back
    assert 0.35 * 480 < np.ptp(rows) < 480 and rows.min() > 0 and rows.max() < 479  # framed, whole
    luminance = img[chair] @ np.array([0.2126, 0.7152, 0.0722])
    # lit: the file's dielectric grey under the sun, mean 150 here; the same file with metallic 1
    # renders 120 (it mirrors the dim sky), an unlit one black
    assert luminance.mean() > 135 and (luminance < 40).mean() < 0.05, (luminance.mean(), (luminance < 40).mean())
    assert (np.abs(img[chair] - 255.0).max(axis=1) > 8).mean() > 0.95                # not white on white
    out = tmp_path / "chair_blender_on_white.png"
    imageio.imwrite(out, np.clip(np.rint(img), 0, 255).astype(np.uint8))
    if os.environ.get("SC_FEM_WRITE_DOCS"):      # the README and docs/guide/export.md show this still
        (ROOT / "docs" / "gltf_blender.png").write_bytes(out.read_bytes())
