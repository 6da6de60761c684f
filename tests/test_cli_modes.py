"""CLI: precompute-modes (single and batch), play, modes-sheet, in-process."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from sc_fem._cli.main import main
from sc_fem.errors import RenderError
from sc_fem.io.modes import load_modes


def _render_ok():
    from sc_fem.io.render import ensure_rendering

    try:
        ensure_rendering()
    except RenderError as exc:
        pytest.skip(f"no off-screen rendering here: {exc}")


def _drawn_fraction(img) -> float:
    """Fraction of pixels clearly not the white background (a blank render gives 0)."""
    rgb = np.asarray(img)[..., :3].astype(int)
    return float(np.mean(np.any(rgb < 225, axis=-1)))


def test_chair_precompute_play_and_sheet(tmp_path, capsys):
    out = tmp_path / "chair.npz"
    assert main(["precompute-modes", "builtin:chair", "-o", str(out), "-r", "16", "--fix", "default",
                 "--modes", "4", "--damping", "0.03", "-q"]) == 0
    b = load_modes(out)
    assert b.n_modes == 4 and np.allclose(b.damping, 0.03) and b.fix_record["specs"] == ["z<min+0.01"]
    assert main(["precompute-modes", "builtin:chair", "-o", str(out), "-r", "12", "--fix", "default",
                 "--max-frequency", "60"]) == 0
    text = capsys.readouterr().out
    assert "eigensolver" in text and "cubes / DOFs" in text and "f [Hz]" in text
    assert np.all(load_modes(out).frequencies < 60)
    _render_ok()
    gif = tmp_path / "play.gif"
    assert main(["play", str(out), "--impulse", "5", "1", "0", "0", "--duration", "0.4", "--fps", "10",
                 "-o", str(gif), "-q"]) == 0
    import imageio.v2 as imageio

    gif_frames = imageio.mimread(gif)
    assert len(gif_frames) == 5
    assert all(_drawn_fraction(f) > 0.02 for f in gif_frames)      # the chair is drawn in every frame
    sheet = tmp_path / "sheet.png"
    assert main(["modes-sheet", str(out), "-o", str(sheet), "-n", "2", "-q"]) == 0
    img = imageio.imread(sheet)
    assert img.ndim == 3 and img.shape[1] > img.shape[0]
    half = img.shape[1] // 2                                          # two panels side by side, both drawn
    assert _drawn_fraction(img[:, :half]) > 0.02 and _drawn_fraction(img[:, half:]) > 0.02


def test_bridge_modes_and_playback_frames(tmp_path):
    out = tmp_path / "bridge.npz"
    assert main(["precompute-modes", "builtin:bridge", "-o", str(out), "-r", "24", "--fix", "default",
                 "-k", "3", "-q"]) == 0
    assert load_modes(out).n_modes == 3
    _render_ok()
    frames = tmp_path / "frames"
    assert main(["play", str(out), "--mode", "1", "--duration", "0.2", "--fps", "10", "-o", str(frames), "-q"]) == 0
    pngs = sorted(frames.glob("frame_*.png"))
    assert len(pngs) == 3
    import imageio.v2 as imageio

    assert all(_drawn_fraction(imageio.imread(f)) > 0.02 for f in pngs)   # the bridge is drawn


def test_batch_via_cli(tmp_path):
    bad = tmp_path / "bad.obj"
    bad.write_text("not a mesh at all")
    outdir = tmp_path / "outdir"
    rc = main(["precompute-modes", "builtin:beam", str(bad), "-o", f"{outdir}/", "-r", "10", "-k", "2",
               "--fix", "x<min+0.01", "--workers", "1", "-q"])
    assert rc == 1                                    # one mesh failed
    with open(outdir / "summary.csv", newline="") as fh:
        rows = {r["mesh"]: r for r in csv.DictReader(fh)}
    assert rows["builtin:beam"]["status"] == "ok" and rows[str(bad)]["status"] == "error"
    assert (outdir / "beam.modes.npz").is_file()


def test_bad_input_is_a_clean_error(tmp_path, capsys):
    assert main(["precompute-modes", "builtin:chair", "-o", str(tmp_path / "x.txt")]) == 2
    assert main(["play", str(tmp_path / "missing.npz"), "-o", str(tmp_path / "a.gif")]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["precompute-modes", "builtin:chair", "-o", str(tmp_path / "c.npz"), "-r", "12",
                 "--fix", "z<-5"]) == 2


def test_option_groups_from_the_command_line(tmp_path, capsys):
    """--tolerance, --damping / --rayleigh and --eigensolver reach the mode file through the
    option objects (AutoResolution, Damping, EigenOptions); --tolerance without auto is refused."""
    out = tmp_path / "c.npz"
    assert main(["precompute-modes", "builtin:beam", "-r", "auto", "--tolerance", "1e-9", "--modes", "2",
                 "--fix", "x<min+1e-6", "--rayleigh", "0.5", "1e-4", "--eigensolver", "lobpcg", "-q",
                 "-o", str(out)]) == 0
    b = load_modes(out)
    assert b.damping_spec == {"kind": "rayleigh", "alpha": 0.5, "beta": 1e-4}
    assert b.eigen["method"] == "lobpcg"
    assert b.resolution == 64                       # a 1e-9 tolerance never converges: the finest grid
    assert main(["precompute-modes", "builtin:beam", "-r", "8", "--tolerance", "0.1", "-o", str(out)]) == 2
    assert "--tolerance applies to --resolution auto only" in capsys.readouterr().err
    assert main(["precompute-modes", "builtin:beam", "-r", "many", "-o", str(out)]) == 2
    assert "resolution must be an integer or 'auto'" in capsys.readouterr().err
