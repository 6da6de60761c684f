"""``sc-fem export`` of long animations: resampled in time to ``--fps`` (and cut to ``--duration``)
instead of refused; exact (the stored frames) when ``--fps`` divides the stored rate, linear
interpolation of the vertex positions otherwise; the glTF frame limit says which ``--fps`` /
``--duration`` fit; USD gets the same frames as time samples at ``--fps``. A baked modal playback
is sampled exactly at ``--fps`` and warns when it aliases (the rule of ``sc-fem play``)."""

from __future__ import annotations

import re

import numpy as np
import pytest

import sc_fem
from sc_fem._cli.main import main
from sc_fem.errors import InputError
from sc_fem.io.animation import Animation, resample_animation
from sc_fem.io.gltf import MAX_ANIMATION_TARGETS, UP_TO_GLTF


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A 400-frame ``simulate`` run at 50 fps (a struck, sagging cantilever: 7.98 s)."""
    path = tmp_path_factory.mktemp("sim") / "beam.npz"
    assert main(["simulate", "builtin:beam", "-r", "4", "--fix", "default", "--gravity", "--impulse", "6", "0", "0",
                 "0.5", "--rayleigh", "2", "0", "--duration", "7.98", "-o", str(path), "--quiet"]) == 0
    return sc_fem.load_animation(path), path


def _doc(path):
    import pygltflib

    return pygltflib.GLTF2().load(str(path))


def _read(doc, index: int) -> np.ndarray:
    acc = doc.accessors[index]
    view = doc.bufferViews[acc.bufferView]
    n = {"SCALAR": 1, "VEC3": 3}[acc.type]
    data = np.frombuffer(doc.binary_blob(), np.float32, acc.count * n, view.byteOffset + (acc.byteOffset or 0))
    return data.reshape(acc.count, n)


def _targets(doc) -> np.ndarray:
    """The morph targets' POSITION displacements, (targets, n, 3) float32 (glTF axes, metres)."""
    return np.stack([_read(doc, t["POSITION"]) for t in doc.meshes[0].primitives[0].targets])


def _times(doc) -> np.ndarray:
    sampler = doc.animations[0].samplers[doc.animations[0].channels[0].sampler]
    return _read(doc, sampler.input).ravel()


def _lerp_oracle(times: np.ndarray, positions: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Independent reference: each coordinate of each vertex interpolated by np.interp, (S, n, 3)."""
    flat = positions.reshape(len(times), -1)
    return np.stack([np.interp(t, times, flat[:, j]) for j in range(flat.shape[1])], axis=1).reshape(len(t), -1, 3)


def _gltf_disp(a: Animation, positions: np.ndarray) -> np.ndarray:
    """What the glTF writer stores for frames ``positions``: their displacement, scaled, turned onto +Y."""
    R = np.asarray(UP_TO_GLTF["z"], dtype=float)
    return ((positions - a.rest_vertices[None]) * a.meta["scale"] @ R.T).astype(np.float32)


def test_simulate_records_its_frame_rate(run):
    a, _ = run
    assert a.n_frames == 400 > MAX_ANIMATION_TARGETS
    assert a.meta["fps"] == 50.0 and a.frame_rate == 50.0
    assert np.ptp(a.positions[:, :, 2]) > 1e-3                    # it moves: interpolation is not trivial


def test_too_long_for_gltf_says_which_fps_and_duration_fit(run, tmp_path, capsys):
    _, path = run
    out = tmp_path / "a.glb"
    assert main(["export", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert "400 frames" in err and f"at most {MAX_ANIMATION_TARGETS}" in err and not out.exists()
    fps = re.search(r"--fps ([0-9.]+) or lower", err).group(1)
    secs = re.search(r"--duration ([0-9.]+) or shorter", err).group(1)
    assert float(fps) > 0.9 * (MAX_ANIMATION_TARGETS - 1) / 7.98         # the largest rate that fits, nearly
    for extra in (["--fps", fps], ["--duration", secs]):             # what it says works
        assert main(["export", str(path), "-o", str(out), "--quiet", *extra]) == 0, extra
        assert len(_doc(out).meshes[0].primitives[0].targets) <= MAX_ANIMATION_TARGETS
    assert main(["export", str(path), "-o", str(out), "--duration", "9"]) == 2
    assert "longer than the animation (7.98 s" in capsys.readouterr().err


def test_export_at_a_lower_fps_interpolates_linearly_in_time(run, tmp_path, capsys):
    a, path = run
    out = tmp_path / "a30.glb"
    assert main(["export", str(path), "-o", str(out), "--fps", "30"]) == 0
    assert "240 frames of morph targets at 30 fps, resampled from the 400 at 50 fps" in capsys.readouterr().out
    doc = _doc(out)
    t = np.arange(240) / 30.0                                         # 7.98 s at 30 fps: frames 0..239
    np.testing.assert_allclose(_times(doc), t, rtol=0, atol=1e-6)
    want = _gltf_disp(a, _lerp_oracle(a.times, a.positions, a.times[0] + t))
    got = _targets(doc)
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6 * np.abs(want).max())
    nearest = _gltf_disp(a, a.positions[np.rint(t * 50).astype(int)])
    assert np.abs(got - nearest).max() > 100 * np.abs(got - want).max()    # not the nearest frame
    extras = doc.meshes[0].extras["sc_fem"]
    assert extras["meta"]["fps"] == 30.0 and extras["meta"]["resampled_from_fps"] == 50.0


def test_an_integer_ratio_gives_the_stored_frames_exactly(run, tmp_path):
    a, path = run
    out = tmp_path / "a25.glb"
    assert main(["export", str(path), "-o", str(out), "--fps", "25", "--duration", "2", "--quiet"]) == 0
    got = _targets(_doc(out))
    assert len(got) == 51
    np.testing.assert_array_equal(got, _gltf_disp(a, a.positions[0:101:2]))
    b = resample_animation(a, 10.0)
    np.testing.assert_array_equal(b.positions, a.positions[::5])
    np.testing.assert_array_equal(b.times, np.arange(80) / 10.0)
    assert b.meta["resampling"] == "stored frames, exact" and b.lattice.displacements.shape[0] == 80
    same = resample_animation(a, 50.0)                                   # its own rate: every frame
    np.testing.assert_array_equal(same.positions, a.positions)


def test_resample_animation_library(run):
    a, _ = run
    b = resample_animation(a, 7.0, duration=3.0)
    t = np.arange(22) / 7.0
    np.testing.assert_allclose(b.times, t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(b.positions, _lerp_oracle(a.times, a.positions, t), rtol=0, atol=1e-12)
    assert b.frame_rate == 7.0 and b.positions.shape == (22, len(a.rest_vertices), 3)
    uneven = Animation(faces=a.faces, rest_vertices=a.rest_vertices, times=np.array([0.0, 0.1, 0.4]),
                       positions=a.positions[:3], energy=np.zeros(3))
    c = resample_animation(uneven, 10.0)                                  # not uniformly stored
    np.testing.assert_allclose(c.positions, _lerp_oracle(uneven.times, uneven.positions, np.arange(5) / 10.0),
                               rtol=0, atol=1e-12)
    for bad in ({"fps": 0.0}, {"fps": float("nan")}, {"fps": 10.0, "duration": -1.0}, {"fps": 10.0, "duration": 1.0}):
        with pytest.raises(InputError):
            resample_animation(uneven, **bad)


def test_usd_gets_the_same_frames_at_the_fps(run, tmp_path):
    pytest.importorskip("pxr")
    from pxr import Usd, UsdGeom

    a, path = run
    out = tmp_path / "a.usdc"
    assert main(["export", str(path), "-o", str(out), "--fps", "30", "--quiet"]) == 0
    stage = Usd.Stage.Open(str(out))
    assert stage.GetTimeCodesPerSecond() == 30 and stage.GetFramesPerSecond() == 30
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (0, 239)
    points = UsdGeom.Mesh(stage.GetPrimAtPath("/Model/Mesh")).GetPointsAttr()
    assert points.GetNumTimeSamples() == 240
    want = _lerp_oracle(a.times, a.positions, np.arange(240) / 30.0) * a.meta["scale"]
    for k in (0, 1, 7, 120, 239):
        np.testing.assert_allclose(np.array(points.Get(float(k))), want[k], rtol=0, atol=1e-6)


@pytest.fixture(scope="module")
def modes(tmp_path_factory):
    path = tmp_path_factory.mktemp("modes") / "beam.modes.npz"
    assert main(["precompute-modes", "builtin:beam", "-r", "6", "--fix", "default", "-k", "3", "-o", str(path),
                 "-q"]) == 0
    return sc_fem.load_modes(path), path


def test_baked_playback_is_exact_at_the_fps_and_warns_when_it_aliases(modes, tmp_path, capsys):
    """A strike of the 82 Hz and 526 Hz beam modes sampled at 250 fps: the 526 Hz mode aliases and
    ``export`` says so in the words of ``play``; at 1200 fps nothing does. The weights are the exact
    modal response at ``k / fps``."""
    from sc_fem.modes.player import playback_warnings

    basis, path = modes
    tip = int(np.argmax(basis.vertices[:, 0]))
    strike = ["--impulse", str(tip), "0", "0.3", "0.3", "--duration", "0.1"]
    assert main(["export", str(path), "-o", str(tmp_path / "a.glb"), *strike, "--fps", "250"]) == 0
    err = capsys.readouterr().err
    player = sc_fem.ModalPlayer(basis)
    player.impulse(tip, [0.0, 0.3, 0.3])
    said_by_play = playback_warnings(basis, player.frames(0.1, 250.0), 250.0)[0]
    assert f"sc-fem export: warning: {said_by_play}" in err and "(526 Hz)" in err
    doc = _doc(tmp_path / "a.glb")
    np.testing.assert_allclose(_times(doc), np.arange(26) / 250.0, rtol=0, atol=1e-7)
    assert main(["export", str(path), "-o", str(tmp_path / "b.glb"), *strike, "--fps", "1200", "--quiet"]) == 0
    assert "warning" not in capsys.readouterr().err
