"""OpenUSD export (``sc-fem export -o .usd/.usda/.usdc``): read back with ``pxr`` -- mesh, one
blend shape per mode with its frequency, damping and scale, a baked strike that USD's own skinning
turns into the exact modal motion, a ``simulate`` run as time-sampled points at its frame rate,
metres and the up axis in the stage metadata -- and imported into Blender (``bpy``) with the
documented snippet where a Python with ``bpy`` is available."""

from __future__ import annotations

import dataclasses
import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import sc_fem
from sc_fem._cli.main import main
from sc_fem.errors import InputError, ScFemError
from sc_fem.io.gltf import mode_scales

pxr = pytest.importorskip("pxr", reason="usd-core (module pxr) is not installed: pip install 'sc_fem[usd]'")
from pxr import Gf, Usd, UsdGeom, UsdSkel  # noqa: E402

from sc_fem.io import usd  # noqa: E402  (not a lazy name of sc_fem.io: imported here)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def chair(tmp_path_factory):
    """The built-in chair (z-up, metres, 198 vertices, 360 triangles) with 5 modes, 8.7..90 Hz."""
    d = tmp_path_factory.mktemp("chair")
    path = sc_fem.save_modes(sc_fem.modal("builtin:chair", resolution=12, n_modes=5, fix="default"), d / "chair.npz")
    return sc_fem.load_modes(path), path                     # float32 modes, exactly what export reads


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A ``sc-fem simulate`` animation: the beam sagging under gravity, 11 frames at 100 fps."""
    anim = tmp_path_factory.mktemp("run") / "a.npz"
    assert main(["simulate", "builtin:beam", "-r", "6", "--fix", "default", "--gravity", "--dt", "1e-3",
                 "--duration", "0.1", "--fps", "100", "-o", str(anim), "--quiet"]) == 0
    return sc_fem.load_animation(anim), anim


def _mesh(stage) -> UsdGeom.Mesh:
    return UsdGeom.Mesh(stage.GetPrimAtPath("/Model/Mesh"))


def _shapes(stage) -> list:
    binding = UsdSkel.BindingAPI(stage.GetPrimAtPath("/Model/Mesh"))
    return [UsdSkel.BlendShape(stage.GetPrimAtPath(p)) for p in binding.GetBlendShapeTargetsRel().GetTargets()]


def _strike(basis, vertex: int, J, duration: float, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """(times, modal coordinates (T, k)) of the exact playback, as gltf.py bakes it."""
    player = sc_fem.ModalPlayer(basis)
    player.impulse(vertex, J)
    t = player.times(duration, fps)
    return t, player.coordinates(t)


# ------------------------------------------------------------------------------------ mode file
def test_mode_file_reads_back_as_mesh_and_blend_shapes(chair, tmp_path):
    """The mesh (points in metres, triangles, normals, no subdivision), one blend shape per mode
    whose offsets are the mode at the chosen amplitude, the per-mode attributes, the metadata."""
    basis, npz = chair
    out = tmp_path / "chair.usda"
    assert main(["export", str(npz), "-o", str(out), "--amplitude", "0.08", "--quiet"]) == 0
    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetDefaultPrim().GetPath() == "/Model" and stage.GetDefaultPrim().IsA(UsdSkel.Root)
    mesh = _mesh(stage)
    points = np.array(mesh.GetPointsAttr().Get())
    counts = np.array(mesh.GetFaceVertexCountsAttr().Get())
    assert len(points) == len(basis.vertices) == 198 and len(counts) == len(basis.faces) == 360
    assert np.all(counts == 3)
    np.testing.assert_array_equal(np.array(mesh.GetFaceVertexIndicesAttr().Get()).reshape(-1, 3), basis.faces)
    np.testing.assert_array_equal(points, (basis.vertices * basis.scale).astype(np.float32))
    assert mesh.GetSubdivisionSchemeAttr().Get() == UsdGeom.Tokens.none
    assert len(mesh.GetNormalsAttr().Get()) == len(points) and mesh.GetNormalsInterpolation() == "vertex"
    shapes = _shapes(stage)
    assert len(shapes) == basis.n_modes
    s = mode_scales(basis, 0.08)
    top = int(np.argmax(basis.vertices[:, 2]))
    for k, shape in enumerate(shapes):
        offsets = np.array(shape.GetOffsetsAttr().Get())
        assert offsets.shape == (len(points), 3) and offsets.dtype == np.float32
        np.testing.assert_array_equal(offsets[top], (basis.modes[k][top] * s[k]).astype(np.float32))
        np.testing.assert_allclose(offsets, basis.modes[k] * s[k], rtol=1e-6, atol=1e-9)
        prim = shape.GetPrim()
        assert prim.GetAttribute("scfem:frequencyHz").Get() == basis.frequencies[k]
        assert prim.GetAttribute("scfem:dampingRatio").Get() == basis.damping[k]
        assert prim.GetAttribute("scfem:modeScale").Get() == s[k]
        assert prim.GetAttribute("scfem:mode").Get() == k
    # the largest offset of every mode is the amplitude (8 %) of the bounding-box diagonal
    diag = np.linalg.norm(np.ptp(basis.vertices, axis=0))
    peaks = [np.linalg.norm(np.array(sh.GetOffsetsAttr().Get()), axis=1).max() for sh in shapes]
    np.testing.assert_allclose(peaks, 0.08 * diag, rtol=1e-6)
    root = stage.GetDefaultPrim()
    np.testing.assert_array_equal(root.GetAttribute("scfem:frequenciesHz").Get(), basis.frequencies)
    anim = UsdSkel.Animation(stage.GetPrimAtPath("/Model/Skel/Anim"))
    assert list(anim.GetBlendShapesAttr().Get()) == list(UsdSkel.BindingAPI(mesh.GetPrim()).GetBlendShapesAttr().Get())
    assert anim.GetBlendShapeWeightsAttr().GetNumTimeSamples() == 0          # nothing baked: the rest shape
    assert np.all(np.array(anim.GetBlendShapeWeightsAttr().Get()) == 0)


def test_baked_strike_is_the_exact_modal_motion_through_usdskel(chair, tmp_path):
    """``--impulse``: time-sampled blend-shape weights at ``--fps`` (time codes 0..T-1), signed
    (both halves of every swing), ``weight * modeScale`` the exact modal coordinate; USD's own
    skinning (UsdSkel.BakeSkinning) gives the exact vertex motion."""
    basis, npz = chair
    out = tmp_path / "strike.usdc"
    top = int(np.argmax(basis.vertices[:, 2]))
    J = (300.0, 0.0, 100.0)
    assert main(["export", str(npz), "-o", str(out), "--impulse", str(top), *map(str, J), "--duration", "0.5",
                 "--fps", "200", "--quiet"]) == 0
    t, q = _strike(basis, top, J, 0.5, 200)
    stage = Usd.Stage.Open(str(out))
    assert stage.GetTimeCodesPerSecond() == 200 and stage.GetFramesPerSecond() == 200
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, len(t) - 1)
    attr = UsdSkel.Animation(stage.GetPrimAtPath("/Model/Skel/Anim")).GetBlendShapeWeightsAttr()
    assert attr.GetTimeSamples() == list(range(len(t)))
    w = np.array([attr.Get(float(i)) for i in range(len(t))])
    s = np.array([sh.GetPrim().GetAttribute("scfem:modeScale").Get() for sh in _shapes(stage)])
    np.testing.assert_allclose(w * s, q, rtol=1e-5, atol=1e-6 * np.abs(q).max())
    assert w[:, 0].min() < -0.5 * np.abs(w[:, 0]).max() and w[:, 0].max() > 0.5 * np.abs(w[:, 0]).max()
    assert np.abs(w).max() > 10                                            # a hard strike: not clamped to [-1, 1]
    # USD applies the blend shapes itself: baked points = rest + sum_k q_k phi_k
    assert UsdSkel.BakeSkinning(UsdSkel.Root(stage.GetDefaultPrim()), Gf.Interval(0, len(t) - 1))
    points = _mesh(stage).GetPointsAttr()
    for i in (0, 17, len(t) - 1):
        exact = basis.vertices + np.einsum("k,knc->nc", q[i], basis.modes)
        assert np.abs(exact - basis.vertices).max() > 1e-4 or i == 0
        np.testing.assert_allclose(np.array(points.Get(float(i))), exact, atol=1e-6)


def test_mode_release_and_alias_warning(chair, tmp_path, capsys):
    """``--mode K`` releases mode K from weight 1 (the first sample); at 30 fps the strike of the
    90 Hz mode warns in the words of ``sc-fem play``, as the glTF export does."""
    basis, npz = chair
    out = tmp_path / "m.usda"
    assert main(["export", str(npz), "-o", str(out), "--mode", "4", "--duration", "0.2"]) == 0
    captured = capsys.readouterr()
    assert "lie above half the frame rate" in captured.err and "5 blend shapes, weights at 30 fps" in captured.out
    stage = Usd.Stage.Open(str(out))                                       # held: its prims live as long as it
    attr = UsdSkel.Animation(stage.GetPrimAtPath("/Model/Skel/Anim")).GetBlendShapeWeightsAttr()
    np.testing.assert_allclose(attr.Get(0.0), [0, 0, 0, 0, 1], atol=1e-6)


@pytest.mark.parametrize("up", ["y", "x"])
def test_up_axis_and_units(chair, tmp_path, up):
    """A y-up model keeps its coordinates with ``upAxis`` Y; x-up (which USD lacks) is turned onto
    +Y; either way the chair's height lies along the stage's up axis. Points are metres: a model in
    centimetres (scale 0.01) is 100 times smaller, ``metersPerUnit`` stays 1."""
    from sc_fem.io.usd import export_usd

    basis, _ = chair
    turn = {"y": np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]], float),
            "x": np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float)}[up]
    turned = dataclasses.replace(basis, vertices=basis.vertices @ turn.T, modes=np.asarray(basis.modes) @ turn.T,
                                 scale=0.01)
    out = export_usd(turned, tmp_path / f"{up}.usda", up=up)
    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    p = np.array(_mesh(stage).GetPointsAttr().Get(), dtype=float)
    lo, hi = basis.vertices[:, 2].min(), basis.vertices[:, 2].max()
    np.testing.assert_allclose([p[:, 1].min(), p[:, 1].max()], [0.01 * lo, 0.01 * hi], atol=1e-8)
    R = np.array(stage.GetDefaultPrim().GetAttribute("scfem:modelToStage").Get())
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(p, 0.01 * turned.vertices @ R.T, atol=1e-8)
    with pytest.raises(InputError, match="up must be"):
        export_usd(basis, tmp_path / "bad.usda", up="-z")


def test_source_uvs_with_mesh_and_smooth_seams(tmp_path, shared_meshes):
    """``--mesh`` keeps the source's UVs as ``primvars:st`` (USD's bottom-left origin, as in the
    OBJ); spot's 3,225 vertices (split at UV seams) stay as they are, and twins at a seam get the
    same normal (no shading seam), as in the glTF export."""
    import trimesh

    obj = shared_meshes / "spot.obj"
    npz = sc_fem.save_modes(sc_fem.modal(str(obj), resolution=8, n_modes=2), tmp_path / "spot.npz")
    basis = sc_fem.load_modes(npz)
    out = tmp_path / "spot.usdc"
    assert main(["export", str(npz), "-o", str(out), "--mesh", str(obj), "--up", "y", "--quiet"]) == 0
    src = trimesh.load(str(obj), process=False, force="mesh")
    stage = Usd.Stage.Open(str(out))
    mesh = _mesh(stage)
    st = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("st")
    assert st.GetInterpolation() == "vertex" and len(st.Get()) == len(basis.vertices) == 3225
    np.testing.assert_allclose(np.array(st.Get()), src.visual.uv, atol=1e-6)
    n = np.array(mesh.GetNormalsAttr().Get())
    _, group = np.unique(basis.vertices, axis=0, return_inverse=True)
    group = group.ravel()
    first = np.zeros((group.max() + 1, 3))
    first[group] = n
    twins = np.bincount(group)[group] > 1
    assert twins.sum() > 500 and (np.abs(n - first[group]).max(axis=1) < 1e-6)[twins].mean() > 0.97
    bare = usd.usd_stage(npz)                                    # without --mesh: no UVs
    assert bare.GetPrimAtPath("/Model/Mesh").IsValid()
    assert not bare.GetPrimAtPath("/Model/Mesh").GetAttribute("primvars:st").IsValid()


def test_file_normals_are_kept(tmp_path):
    """An OBJ with ``vn`` lines: those are the rest ``normals`` (not recomputed ones)."""
    import shapes

    obj, vn = shapes.box_obj_with_normals(tmp_path)                            # corner normals, not face normals
    basis = sc_fem.modal(str(obj), resolution=4, n_modes=2)
    stage = usd.usd_stage(basis, mesh=obj)
    np.testing.assert_allclose(np.array(_mesh(stage).GetNormalsAttr().Get()), vn, atol=1e-6)


# ------------------------------------------------------------------------------------ animation
def test_animation_is_time_sampled_points_at_its_frame_rate(run, tmp_path):
    """A ``simulate`` run: one ``points`` sample per frame at time codes 0..T-1 with
    timeCodesPerSecond the run's 100 fps, every sample the frame's positions (metres, float32)."""
    a, anim = run
    out = tmp_path / "run.usdc"
    assert main(["export", str(anim), "-o", str(out), "--quiet"]) == 0
    stage = Usd.Stage.Open(str(out))
    assert stage.GetTimeCodesPerSecond() == 100 and stage.GetFramesPerSecond() == 100
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, a.n_frames - 1)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    mesh = _mesh(stage)
    points = mesh.GetPointsAttr()
    assert points.GetNumTimeSamples() == a.n_frames == 11
    assert mesh.GetNormalsAttr().GetNumTimeSamples() == a.n_frames
    scale = a.meta["scale"]
    for i in range(a.n_frames):
        np.testing.assert_array_equal(np.array(points.Get(float(i))), (a.positions[i] * scale).astype(np.float32))
    assert min(np.array(points.Get(float(i)))[:, 2].min() for i in range(a.n_frames)) < -5e-5   # it sags along -Z
    assert len(mesh.GetFaceVertexCountsAttr().Get()) == len(a.faces)
    with pytest.raises(InputError, match="mode files"):
        usd.export_usd(a, tmp_path / "x.usda", mode=0)


# ------------------------------------------------------------------------------------ errors
def test_bad_suffix_and_a_failed_write_leave_nothing(chair, tmp_path, monkeypatch, capsys):
    """An unknown suffix is refused with the list of formats; a write that fails half-way leaves
    no file (atomic, as every writer)."""
    import sc_fem.io.usd as usd
    from sc_fem.io.export import export_to_file

    basis, npz = chair
    with pytest.raises(InputError, match=r"\.usd, \.usda, \.usdc"):
        usd.export_usd(basis, tmp_path / "c.fbx")
    with pytest.raises(InputError, match=r"\.usda"):
        export_to_file(basis, tmp_path / "c.abc")
    assert main(["export", str(npz), "-o", str(tmp_path / "c.abc")]) == 2
    assert ".usd, .usda, .usdc" in capsys.readouterr().err

    class Broken:
        def GetRootLayer(self):
            return self

        def Export(self, path):
            Path(path).write_text("#usda 1.0\n(")                            # half a file, then failure
            raise RuntimeError("disk full")

    monkeypatch.setattr(usd, "usd_stage", lambda *a, **k: Broken())
    with pytest.raises(RuntimeError, match="disk full"):
        usd.export_usd(basis, tmp_path / "half.usda")
    assert list(tmp_path.iterdir()) == [], list(tmp_path.iterdir())


def test_missing_pxr_says_what_to_install(chair, tmp_path, monkeypatch, capsys):
    """Without usd-core one line names ``pip install 'sc_fem[usd]'`` (library and command line), and
    nothing is written."""
    from sc_fem.io.export import export_to_file

    basis, npz = chair
    monkeypatch.setitem(sys.modules, "pxr", None)                           # import pxr -> ImportError
    with pytest.raises(ScFemError, match=re.escape("pip install 'sc_fem[usd]'")):
        export_to_file(basis, tmp_path / "c.usda")
    assert main(["export", str(npz), "-o", str(tmp_path / "c.usdc")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "usd-core" in err and "pip install 'sc_fem[usd]'" in err
    assert list(tmp_path.iterdir()) == []
    assert main(["export", str(npz), "-o", str(tmp_path / "c.glb"), "--quiet"]) == 0   # glTF needs no pxr


# ------------------------------------------------------------------------------------ Blender
def _bpy_python() -> str | None:
    """A Python with Blender's module ``bpy``: ``SC_FEM_BPY_PYTHON`` or this one."""
    env = os.environ.get("SC_FEM_BPY_PYTHON")
    if env:
        return env
    return sys.executable if importlib.util.find_spec("bpy") is not None else None


def _blender_snippet() -> str:
    """The Blender import snippet of docs/guide/export.md (the one the page tells users to paste; a
    ``{code-block} python``, not a ``python`` block, which tests/test_api.py runs without Blender)."""
    text = (ROOT / "docs" / "guide" / "export.md").read_text(encoding="utf-8")
    blocks = [b for b in re.findall(r"```\{code-block\} python\n(.*?)```", text, flags=re.S) if "usd_import" in b]
    assert len(blocks) == 1, "docs/guide/export.md has one Blender USD snippet"
    return blocks[0]


_BLENDER_RUN = r"""
import json, sys
import numpy as np
import bpy

snippet, jobs = sys.argv[1], json.loads(sys.argv[2])
report = []
for job in jobs:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    code = open(snippet).read()
    line = next(l for l in code.splitlines() if l.startswith("path, fps = "))
    exec(code.replace(line, f"path, fps = {job['path']!r}, {job['fps']!r}"), {})
    scene = bpy.context.scene
    ob = next(o for o in scene.objects if o.type == "MESH")
    keys = ob.data.shape_keys
    out = {"fps": scene.render.fps, "frames": [scene.frame_start, scene.frame_end],
           "keys": [k.name for k in keys.key_blocks[1:]] if keys else []}
    for f in job["frames"]:
        scene.frame_set(f)
        ev = ob.evaluated_get(bpy.context.evaluated_depsgraph_get())
        m = ev.to_mesh()
        co = np.empty(3 * len(m.vertices))
        m.vertices.foreach_get("co", co)
        mw = np.array(ob.matrix_world)
        np.save(f"{job['path']}.{f}.npy", co.reshape(-1, 3) @ mw[:3, :3].T + mw[:3, 3])
        ev.to_mesh_clear()
    report.append(out)
print("REPORT" + json.dumps(report))
"""


def test_blender_imports_the_full_swing_and_the_animation(chair, run, tmp_path):
    """Blender (``bpy``) with the snippet of docs/guide/export.md: the chair upright in metres, one
    shape key per mode, and at every checked frame the exact modal motion -- its negative half
    included (Blender's default [0, 1] shape-key range would clamp it); a ``simulate`` run frame
    by frame."""
    python = _bpy_python()
    if python is None:
        pytest.skip("Blender's Python module bpy is not importable here (pip install bpy for a Python it "
                    "supports, or set SC_FEM_BPY_PYTHON to a Python that has it)")
    basis, npz = chair
    a, anim = run
    top = int(np.argmax(basis.vertices[:, 2]))
    J = (30.0, 0.0, 10.0)                                  # mode 0 swings from -1.44 to +1.46: past [0, 1] both ways
    strike, sim = tmp_path / "strike.usdc", tmp_path / "run.usdc"
    assert main(["export", str(npz), "-o", str(strike), "--impulse", str(top), *map(str, J), "--duration", "0.5",
                 "--fps", "60", "--quiet"]) == 0
    assert main(["export", str(anim), "-o", str(sim), "--quiet"]) == 0
    snippet = tmp_path / "snippet.py"
    snippet.write_text(_blender_snippet())
    frames = [0, 1, 3, 5, 9]
    jobs = [{"path": str(strike), "fps": 60, "frames": frames}, {"path": str(sim), "fps": 100, "frames": [0, 5, 10]}]
    proc = subprocess.run([python, "-c", _BLENDER_RUN, str(snippet), json.dumps(jobs)], capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    report = json.loads(proc.stdout.split("REPORT", 1)[1])
    assert report[0]["keys"] == [f"mode_{k}" for k in range(basis.n_modes)]
    assert report[0]["fps"] == 60 and report[0]["frames"] == [0, 30]
    _, q = _strike(basis, top, J, 0.5, 60)
    w = q / mode_scales(basis)
    assert w[frames].min() < -1.0 and w[frames].max() > 1.0                 # both halves, beyond [0, 1]
    for f in frames:
        got = np.load(f"{strike}.{f}.npy")
        exact = basis.vertices + np.einsum("k,knc->nc", q[f], basis.modes)
        np.testing.assert_allclose(got, exact, atol=2e-6)
    assert np.ptp(np.load(f"{strike}.0.npy")[:, 2]) == pytest.approx(0.8598, abs=1e-3)   # upright along Z
    assert report[1]["fps"] == 100 and report[1]["frames"] == [0, 10]
    for f in (0, 5, 10):
        np.testing.assert_allclose(np.load(f"{sim}.{f}.npy"), a.positions[f] * a.meta["scale"], atol=1e-6)
