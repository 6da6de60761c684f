"""``sc-fem voxelize`` and ``sc-fem demo`` run in-process through ``main(argv)``."""

from __future__ import annotations

import pytest

import sc_fem
from sc_fem._cli.main import build_parser, main
from sc_fem.io.model import load_model


def test_help_lists_every_option(capsys):
    with pytest.raises(SystemExit):
        main(["voxelize", "--help"])
    out = capsys.readouterr().out
    for opt in ("--resolution", "--pitch", "--scale", "--fill", "--occupancy", "--keep", "--youngs",
                "--poisson", "--density", "--mass", "--output"):
        assert opt in out


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "COMMAND" in capsys.readouterr().out


def test_npz_round_trip(tmp_path, capsys):
    out = tmp_path / "chair.npz"
    assert main(["voxelize", "builtin:chair", "-r", "12", "--fill", "solid", "-o", str(out)]) == 0
    m = load_model(out)
    assert m.n_cubes > 0 and m.info["fill"] == "solid"
    assert "cubes / nodes / DOFs" in capsys.readouterr().out


def test_vtu_and_png(tmp_path):
    import meshio

    assert main(["voxelize", "builtin:bridge", "-r", "16", "--occupancy", "exact", "-o", str(tmp_path / "b.vtu"), "-q"]) == 0
    m = meshio.read(tmp_path / "b.vtu")
    assert m.cells[0].type == "hexahedron" and "youngs_Pa" in m.cell_data
    assert main(["voxelize", "builtin:beam", "-r", "8", "-o", str(tmp_path / "b.png"), "-q"]) == 0
    assert (tmp_path / "b.png").stat().st_size > 1000


@pytest.mark.parametrize("argv, msg", [
    (["voxelize", "missing.obj", "-o", "x.npz"], "not found"),
    (["voxelize", "builtin:beam", "-r", "0", "-o", "x.npz"], "resolution"),
    (["voxelize", "builtin:beam", "--youngs", "-5", "-o", "x.npz"], "Young"),
    (["voxelize", "builtin:beam", "-o", "x.txt"], "unsupported output"),
])
def test_errors_are_messages_not_tracebacks(tmp_path, capsys, monkeypatch, argv, msg):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert msg in err and "Traceback" not in err
    assert not list(tmp_path.glob("x.*"))


def test_every_command_has_help():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    for name, p in sub.choices.items():
        assert p.description or p.format_help(), name


@pytest.mark.slow
def test_demo_writes_every_output(tmp_path, capsys):
    """``make demo``'s job, in-process: every promised file, non-empty (about a minute)."""
    from sc_fem.io.viewer import BUNDLE

    out = tmp_path / "out"
    assert main(["demo", "-o", str(out)]) == 0
    names = ["chair_cubes_sample.png", "chair_cubes_exact.png", "chair_cubes.vtu", "bridge_cubes_sample.png",
             "chair.modes.npz", "chair_modes_sheet.png", "chair_play.gif", "chair.glb", "bridge_gust.npz",
             "bridge_gust.gif", "rope_xpbd.npz", "rope_xpbd.gif", "rope_reconstruction.npz", "rope_reconstruction.md"]
    if BUNDLE.is_file():
        names.append("chair.html")
    for name in names:
        assert (out / name).stat().st_size > 0, name
    text = capsys.readouterr().out
    assert "demo finished" in text and ("chair.html" in text) == BUNDLE.is_file()
    rec = sc_fem.io.load_reconstruction(out / "rope_reconstruction.npz")
    assert rec.meta["segments"] == 4 and rec.E_A_pde.mean() < 0.006986 and rec.E_M_pde.max() < 0.019478
    assert rec.ok, rec.failures          # the demo fails (exit 1) when its fit does


def test_occupancy_flag_and_no_old_spellings(tmp_path, capsys):
    """``--occupancy`` works; the pre-release ``--method`` / ``--voxel-method`` are gone (usage error)."""
    out = tmp_path / "m.npz"
    assert main(["voxelize", "builtin:beam", "-r", "8", "--occupancy", "exact", "-o", str(out)]) == 0
    assert load_model(out).info["occupancy"] == "exact"
    for flag in ("--method", "--voxel-method"):
        with pytest.raises(SystemExit) as exc:
            main(["voxelize", "builtin:beam", "-r", "8", flag, "exact", "-o", str(out)])
        assert exc.value.code == 2 and flag in capsys.readouterr().err


def test_up_help_names_only_options_the_command_has():
    """``--up`` is one option with one default everywhere, and its help does not send users to
    ``--gravity`` / ``--ground`` on commands that lack them."""
    import argparse

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    checked = 0
    for name, cmd in sub.choices.items():
        opts = {o: a for a in cmd._actions for o in a.option_strings}
        if "--up" not in opts:
            continue
        checked += 1
        assert opts["--up"].default == "z" and tuple(opts["--up"].choices) == ("x", "y", "z")
        for other in ("--gravity", "--ground"):
            assert (other in opts["--up"].help) <= (other in opts), (name, other)
    assert checked >= 5
