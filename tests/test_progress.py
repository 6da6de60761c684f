"""Progress bars of the long stages (:mod:`sc_fem._progress`): drawn on stderr when the ``sc_fem``
logger shows INFO messages (the command line, not ``--quiet``), never by a library call with no
logging configured; the eigensolvers count their iterations (LOBPCG with the residual reached)."""

from __future__ import annotations

import io
import logging
import re
import time

import numpy as np
import pytest

import sc_fem
from sc_fem import _log, _progress
from sc_fem._cli.main import main
from sc_fem.fem.assemble import Assembler
from sc_fem.fem.eigen import EigenSolver
from sc_fem.fem.rigid import rigid_body_modes
from sc_fem.lattice.cubes import CubeModel
from sc_fem.lattice.voxelize import STAGES, voxelize


@pytest.fixture
def unconfigured(monkeypatch):
    """The ``sc_fem`` logger as in a fresh interpreter: no handler but the null one, no level."""
    monkeypatch.setattr(_log.logger, "handlers", [logging.NullHandler()])
    monkeypatch.setattr(_log.logger, "propagate", False)
    monkeypatch.setattr(_log.logger, "level", logging.NOTSET)
    monkeypatch.delenv(_progress.ENV, raising=False)


@pytest.fixture
def always(unconfigured, monkeypatch):
    """Every bar drawn at once (no delay) whenever the logging would show INFO messages."""
    monkeypatch.setenv(_progress.ENV, "always")


def _visible(err: str) -> list[str]:
    """What a terminal shows of each line: the text after its last carriage return."""
    return [line.split("\r")[-1] for line in err.split("\n")]


def _cantilever():
    m = CubeModel.box((24, 4, 4), 0.05, youngs=1e7, poisson=0.3, density=1000.0)
    asm = Assembler(m, "q1i", fixed_dofs=np.arange(3 * 25))
    return asm.stiffness(), asm.mass(), rigid_body_modes(m.nodes_m, asm.free_dofs)


def test_lobpcg_bar_counts_iterations_and_shows_the_residual(always, capsys):
    K, M, B = _cantilever()
    with _log.stderr_messages("INFO"):
        res = EigenSolver(K, M, method="lobpcg", near_null=B).solve(4)
    err = capsys.readouterr().err
    assert "eigensolve (LOBPCG)" in err
    counts = [int(c) for c in re.findall(r"eigensolve \(LOBPCG\): (\d+)it", err)]
    assert counts and max(counts) >= 3 and max(counts) <= res.info["iterations"]
    assert "x tol" in err and "residual " in err
    lines = [v for v in _visible(err) if "LOBPCG" in v and "eigensolve (" not in v]
    assert lines and all(v.startswith("    LOBPCG: converged after") for v in lines)   # the bar erased first
    assert not any(v.startswith("eigensolve (") for v in _visible(err))          # leave=False


def test_shift_invert_bar_counts_the_solves(always, capsys):
    K, M, _ = _cantilever()
    with _log.stderr_messages("INFO"):
        EigenSolver(K, M, method="shift-invert").solve(4)
    err = capsys.readouterr().err
    assert "eigensolve (shift-invert)" in err and "solve" in err.split("eigensolve (shift-invert)")[-1]


def test_cli_draws_stage_bars_and_quiet_draws_none(always, tmp_path, capsys):
    out = tmp_path / "beam.modes.npz"
    assert main(["precompute-modes", "builtin:beam", "-r", "6", "-k", "4", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    for stage in ("voxelize:", "assemble K:", "assemble M:", "eigensolve ("):
        assert stage in err, stage
    assert "fill" in err and "cube/s" in err
    assert not any(v.startswith(("voxelize:", "assemble", "eigensolve (")) for v in _visible(err))
    assert main(["precompute-modes", "builtin:beam", "-r", "6", "-k", "4", "-o", str(out), "--quiet"]) == 0
    assert capsys.readouterr().err == ""


def test_simulate_no_progress_draws_no_bar_in_any_stage(always, tmp_path, capsys):
    out = tmp_path / "beam.npz"
    args = ["simulate", "builtin:beam", "-r", "6", "--fix", "default", "--duration", "0.04", "--gravity", "-o", str(out)]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "voxelize:" in err and "assemble K:" in err and "newmark:" in err
    assert main([*args, "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "[voxelize]" in err or "voxelize" in err                 # the stage lines stay
    assert not any(b in err for b in ("voxelize:", "assemble K:", "newmark:"))


@pytest.mark.parametrize("mode", ["auto", "always"])
def test_a_library_call_without_logging_draws_nothing(unconfigured, monkeypatch, capsys, mode):
    monkeypatch.setenv(_progress.ENV, mode)
    sc_fem.modal("builtin:beam", resolution=6, n_modes=4)
    assert capsys.readouterr().err == ""


def test_voxelize_bar_names_its_stages(always, capsys):
    with _log.stderr_messages("INFO"):
        voxelize("builtin:beam", resolution=6)
    err = capsys.readouterr().err
    for stage in STAGES:
        assert f"{stage}]" in err, stage


def test_auto_bar_appears_after_the_delay_and_is_erased(unconfigured, monkeypatch, capsys):
    monkeypatch.setattr(_progress, "DELAY", 0.05)
    monkeypatch.setattr(_progress, "_interactive", lambda: True)        # a terminal
    with _log.stderr_messages("INFO"):
        with _progress.stage_bar("quick", 3) as bar:          # done within the delay: never drawn
            bar.update(3)
        assert capsys.readouterr().err == ""
        with _progress.stage_bar("slow", 3) as bar:
            time.sleep(0.25)                                 # past the delay and tqdm's mininterval
            bar.update(1)
        err = capsys.readouterr().err
    assert "slow:" in err and "1/3" in err and _visible(err)[-1].strip() == ""
    with _log.stderr_messages("WARNING"):                     # --quiet
        assert _progress.stage_bar("x").disable


def test_one_bar_at_a_time_and_explicit_choices(unconfigured, monkeypatch):
    monkeypatch.setattr(_progress, "_interactive", lambda: True)        # a terminal
    with _log.stderr_messages("INFO"):
        with _progress.stage_bar("outer", enabled=True) as outer:
            assert not outer.disable
            assert _progress.stage_bar("inner").disable           # the outer bar is the progress
        with _progress.stage_bar("steps", enabled=False):           # --no-progress
            assert _progress.stage_bar("re-assembly").disable
        assert not _progress.stage_bar("alone").disable
        monkeypatch.setenv(_progress.ENV, "never")
        assert _progress.stage_bar("asked", enabled=True).disable
    assert _progress._open_stages() == []              # "alone", never closed, was collected


def test_counting_passes_the_operator_through():
    x = np.arange(6.0).reshape(3, 2)
    with _progress.stage_bar("off", enabled=False) as bar:
        op = np.eye(3)
        assert _progress.counting(bar, op) is op                   # not drawn: no wrapper at all
    bar = _progress._StageBar(desc="on", file=io.StringIO(), leave=False)
    try:
        wrapped = _progress.counting(bar, np.eye(3) * 2, tol=0.5, wanted=(1, 2))
        assert np.array_equal(wrapped(x), 2 * x) and np.array_equal(wrapped @ x, 2 * x)
        assert bar.n == 2 and "residual 8.9e+00 x tol" in bar.postfix     # ||(0, 2, 4)|| / 0.5
    finally:
        bar.close()


def test_logging_to_a_file_draws_no_bar(unconfigured, tmp_path, capsys):
    handler = logging.FileHandler(tmp_path / "run.log")
    _log.logger.addHandler(handler)
    _log.logger.setLevel(logging.INFO)
    try:
        assert not _progress.info_shown()
        with _progress.stage_bar("file only", 3) as bar:
            assert bar.disable
    finally:
        _log.logger.removeHandler(handler)
        handler.close()


def test_a_log_file_or_pipe_gets_stage_lines_not_bars(unconfigured, monkeypatch, capsys):
    """stderr redirected (not a terminal): ``auto`` draws no bar for the library's stages, an
    explicit ``progress=True`` and ``SC_FEM_PROGRESS=always`` still do."""
    monkeypatch.setattr(_progress, "_interactive", lambda: False)
    with _log.stderr_messages("INFO"):
        assert _progress.stage_bar("voxelize").disable
        with _progress.stage_bar("asked", enabled=True) as bar:
            assert not bar.disable
        monkeypatch.setenv(_progress.ENV, "always")
        with _progress.stage_bar("forced") as bar:
            assert not bar.disable


def test_lobpcg_bar_gets_its_forecast_as_total(always, capsys):
    """Past its first progress check (iteration 20) LOBPCG's bar shows ``n/total`` with the total
    its forecast names (and so the time left); the free chair at 32 takes ~30 iterations."""
    from sc_fem.scene import Scene

    scene = Scene.from_mesh("builtin:chair", resolution=32)
    with _log.stderr_messages("INFO"):
        out = sc_fem.modal(scene, n_modes=10, eigen="lobpcg")
    err = capsys.readouterr().err
    totals = {int(t) for t in re.findall(r"eigensolve \(LOBPCG\):[^\r\n]*?\| *\d+/(\d+) \[", err)}
    assert out.eigen["forecasts"][0]["iterations"] in totals, err[-2000:]
    # once it has a total it keeps one: never past it (tqdm would fall back to a bare count, "31it")
    after = err[re.search(r"eigensolve \(LOBPCG\):[^\r\n]*?\| *\d+/\d+ \[", err).start():]
    assert not re.search(r"eigensolve \(LOBPCG\): \d+it \[", after), after[-500:]
    assert re.search(r"LOBPCG forecast at iteration 20: ~\d+ iterations, ~[\d.e+-]+ s more", err)
