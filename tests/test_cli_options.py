"""One meaning per option across commands: ``--amplitude`` is a fraction of the model's bounding-box
diagonal in ``play``, ``export`` and ``view``; ``--impulse VERTEX JX JY JZ`` (N s) is parsed and
checked alike in ``play``, ``export`` and ``simulate``; help texts carry no reST markup."""

from __future__ import annotations

import argparse

import numpy as np
import pytest
import trimesh

import sc_fem
from sc_fem._cli.main import build_parser, main
from sc_fem.io.gltf import UP_TO_GLTF


def _subcommands() -> dict:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


@pytest.fixture(scope="module")
def part(tmp_path_factory):
    """Modes of a part modelled in millimetres (diagonal ~314 model units, far from 1)."""
    folder = tmp_path_factory.mktemp("part")
    box = trimesh.creation.box(extents=(300.0, 80.0, 40.0))
    box.export(folder / "part.obj")
    modes = folder / "part.modes.npz"
    assert main(["precompute-modes", str(folder / "part.obj"), "-r", "8", "--scale", "0.001", "--fix", "x<min+1",
                 "-k", "3", "-o", str(modes), "-q"]) == 0
    return sc_fem.load_modes(modes), modes


@pytest.fixture
def played(monkeypatch):
    """The frames ``sc-fem play`` would render (no rendering needed)."""
    from sc_fem.io import playback

    seen = {}

    def fake(frames, faces, path, **kw):
        seen["frames"], seen["title"] = np.asarray(frames), kw.get("title", "")
        return path

    monkeypatch.setattr(playback, "render_animation", fake)   # where play_modes looks it up
    return seen


def _glb(path):
    import pygltflib

    doc = pygltflib.GLTF2().load(str(path))

    def read(index):
        acc = doc.accessors[index]
        view = doc.bufferViews[acc.bufferView]
        n = {"SCALAR": 1, "VEC3": 3}[acc.type]
        return np.frombuffer(doc.binary_blob(), np.float32, acc.count * n,
                             view.byteOffset + (acc.byteOffset or 0)).reshape(acc.count, n)

    return doc, read


@pytest.mark.parametrize("amplitude", [None, "0.1"])
def test_the_same_amplitude_is_the_same_displacement_in_play_and_export(part, played, tmp_path, amplitude):
    basis, modes = part
    diag = float(np.linalg.norm(np.ptp(basis.vertices, axis=0)))
    extra = [] if amplitude is None else ["--amplitude", amplitude]
    fraction = 0.05 if amplitude is None else float(amplitude)
    assert main(["play", str(modes), "--mode", "1", *extra, "--duration", "0.1", "-o", str(tmp_path / "p.gif"),
                 "-q"]) == 0
    d_play = played["frames"][0] - basis.vertices                                    # model units, t = 0
    assert np.linalg.norm(d_play, axis=1).max() == pytest.approx(fraction * diag, rel=1e-5)
    out = tmp_path / "e.glb"
    assert main(["export", str(modes), "--mode", "1", *extra, "--duration", "0.1", "-o", str(out), "-q"]) == 0
    doc, read = _glb(out)
    prim = doc.meshes[0].primitives[0]
    sampler = doc.animations[0].samplers[doc.animations[0].channels[0].sampler]
    w0 = read(sampler.output).reshape(-1, len(prim.targets))[0]                      # weights at t = 0
    d_export = sum(w * read(t["POSITION"]) for w, t in zip(w0, prim.targets))       # metres, glTF axes
    R = np.asarray(UP_TO_GLTF["z"])
    np.testing.assert_allclose(d_export, d_play * basis.scale @ R.T, rtol=1e-4, atol=1e-6 * fraction * diag)
    assert doc.meshes[0].extras["sc_fem"]["amplitude"] == fraction


def test_amplitude_help_is_one_meaning(capsys):
    cmds = _subcommands()
    helps = {}
    for name in ("play", "export", "view"):
        opt = next(a for a in cmds[name]._actions if "--amplitude" in a.option_strings)
        assert opt.default is None and opt.type is float and opt.metavar == "FRACTION"
        assert "fraction of the bounding-box diagonal (default 0.05)" in opt.help, name
        helps[name] = opt.help
    assert "model units" not in " ".join(helps.values())


def test_play_impulse_is_vertex_and_impulse_in_newton_seconds(part, played, tmp_path, capsys):
    basis, modes = part
    tip = int(np.argmax(basis.vertices[:, 0] + basis.vertices[:, 2]))       # at the free end
    assert main(["play", str(modes), "--impulse", str(tip), "0", "0", "2.5", "--duration", "0.1",
                 "-o", str(tmp_path / "p.gif"), "-q"]) == 0
    assert f"impulse (0, 0, 2.5) N s at vertex {tip}" in played["title"]
    player = sc_fem.ModalPlayer(basis)
    player.impulse(tip, [0.0, 0.0, 2.5])
    want = player.frames(0.1, 30.0)
    assert np.abs(want - basis.vertices).max() > 1e-3
    np.testing.assert_allclose(played["frames"], want, rtol=1e-6, atol=1e-9 * np.abs(want).max())
    opt = next(a for a in _subcommands()["play"]._actions if "--impulse" in a.option_strings)
    assert opt.metavar == ("VERTEX", "JX", "JY", "JZ") and opt.type is float and "N s" in opt.help


@pytest.mark.parametrize("command", ["play", "export", "simulate"])
def test_impulse_errors_are_one_clear_line_everywhere(part, played, tmp_path, capsys, command):
    _, modes = part
    head = {"play": ["play", str(modes), "-o", str(tmp_path / "p.gif")],
            "export": ["export", str(modes), "-o", str(tmp_path / "e.glb")],
            "simulate": ["simulate", "builtin:beam", "-r", "4", "--duration", "0.02", "-o", str(tmp_path / "s.npz")]}
    for bad in (["2.5", "0", "0", "1"], ["-1", "0", "0", "1"], ["3", "0", "nan", "1"]):
        assert main([*head[command], "--impulse", *bad]) == 2, bad
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err
        assert f"sc-fem {command}: error: --impulse needs VERTEX JX JY JZ" in err, err
    with pytest.raises(SystemExit) as exc:                             # not a number: argparse says which
        main([*head[command], "--impulse", "tip", "0", "0", "1"])
    assert exc.value.code == 2 and "invalid float value: 'tip'" in capsys.readouterr().err
    assert not list(tmp_path.glob("[pes].*"))


def test_an_impulse_on_a_vertex_that_does_not_exist(part, played, tmp_path, capsys):
    _, modes = part
    assert main(["play", str(modes), "--impulse", "99999", "0", "0", "1", "-o", str(tmp_path / "p.gif")]) == 2
    assert "vertex must be an integer in [0, 8)" in capsys.readouterr().err


def test_help_texts_carry_no_rest_markup(capsys):
    for name, cmd in _subcommands().items():
        text = cmd.format_help()
        for markup in ("``", ":func:", ":class:", ":mod:", ":data:", ":meth:"):
            assert markup not in text, (name, markup)
