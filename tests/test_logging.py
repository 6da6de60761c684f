"""Messages go through the ``sc_fem`` logger: the library never prints to stderr itself, the command
line shows stage lines and solver progress unless ``--quiet``, and a library call asked for
progress is heard even when nothing is configured."""

from __future__ import annotations

import ast
import logging
from pathlib import Path

import sc_fem
from sc_fem import _log
from sc_fem._cli.main import main

SRC = Path(sc_fem.__file__).parent


def test_the_library_does_not_print_to_stderr():
    """Outside the command line, no ``print(..., file=sys.stderr)`` (progress bars are tqdm's)."""
    found = []
    for path in SRC.rglob("*.py"):
        if "_cli" in path.parts:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "print":
                if any(k.arg == "file" and "stderr" in ast.unparse(k.value) for k in node.keywords):
                    found.append(f"{path.relative_to(SRC)}:{node.lineno}")
    assert not found, found


def test_cli_shows_stages_and_eigen_progress_unless_quiet(tmp_path, capsys):
    out = tmp_path / "beam.modes.npz"
    assert main(["precompute-modes", "builtin:beam", "-r", "6", "-k", "4", "-o", str(out)]) == 0
    err = capsys.readouterr().err
    assert "eigensolve" in err and "DOFs" in err
    assert main(["precompute-modes", "builtin:beam", "-r", "6", "-k", "4", "-o", str(out), "-q"]) == 0
    assert capsys.readouterr().err == ""
    assert not any(h.get_name() == "sc_fem-stderr" for h in _log.logger.handlers)     # main() cleaned up


def test_library_progress_reaches_the_logger(caplog):
    with caplog.at_level(logging.INFO, logger="sc_fem"):
        sc_fem.modal("builtin:beam", resolution=6, n_modes=4, progress=True)
    text = caplog.text
    assert "voxelized" in text and "eigensolve" in text
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="sc_fem"):
        sc_fem.modal("builtin:beam", resolution=6, n_modes=4)
    assert "voxelized" not in caplog.text         # no progress asked, no stage lines


def test_progress_without_configured_logging_attaches_one_handler(monkeypatch, capsys):
    monkeypatch.setattr(_log.logger, "handlers", [logging.NullHandler()])
    monkeypatch.setattr(_log.logger, "propagate", False)
    monkeypatch.setattr(_log.logger, "level", logging.NOTSET)
    _log.say("hello from a stage", True)
    _log.say("not asked", False)
    err = capsys.readouterr().err
    assert "hello from a stage" in err and "not asked" not in err
    h = sc_fem.log_to_stderr("WARNING")
    _log.say("quiet now", True)
    assert "quiet now" not in capsys.readouterr().err and h.level == logging.WARNING
