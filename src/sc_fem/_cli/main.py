"""``sc-fem`` entry point: ``main(argv=None) -> int``, testable in-process. :data:`COMMANDS` lists the command
modules; each ``register(subparsers)`` adds its command(s) with :func:`.common.command`: a ``run(args) -> int``
(parse, call one library function, print its summary) and its outputs, checked here before any work."""

from __future__ import annotations

import argparse
import sys
import warnings

from .. import __version__
from .._log import stderr_messages
from .._atomic import check_output
from ..errors import ScFemError, ScFemWarning
from . import cmd_demo, cmd_export, cmd_modes, cmd_reconstruct, cmd_simulate, cmd_voxelize

COMMANDS = (cmd_demo, cmd_export, cmd_modes, cmd_reconstruct, cmd_simulate, cmd_voxelize)
"""The command modules, in the order ``sc-fem --help`` lists their commands."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sc-fem", description=(
        "Squashing Cubes: turn any graphics mesh into a deformable object (voxelize, FEM, modes, dynamics, XPBD, "
        "PDE reconstruction). A MESH is a file path (OBJ, STL, PLY, OFF, glTF, VTK/VTU, ...) or builtin:NAME "
        "(chair, bridge, rope, beam). Units are SI; geometry options are in model units."))
    parser.add_argument("--version", action="version", version=f"sc-fem {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for module in COMMANDS:
        module.register(sub)
    return parser


def _check_outputs(args) -> None:
    """Before any work: the output's extension (or a folder) and ``--report``, and that they can be written."""
    suffixes, folder = getattr(args, "outputs", ((), True))
    if getattr(args, "output", None):
        check_output(args.output, suffixes=suffixes, folder=folder)
    if getattr(args, "report", None):
        check_output(args.report, suffixes=(".md", ".txt"))


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the process exit code (0 ok, 2 bad input, 130 interrupted)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        _check_outputs(args)
        with warnings.catch_warnings(), stderr_messages("WARNING" if getattr(args, "quiet", False) else "INFO"):
            warnings.simplefilter("always", ScFemWarning)              # each as one line, no source excerpt
            warnings.showwarning = lambda m, *a, **k: print(f"sc-fem {args.command}: warning: {m}", file=sys.stderr)
            return int(args.func(args) or 0)
    except ScFemError as exc:
        print(f"sc-fem {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as stop:              # a batch says which of its mode files were completed
        said = getattr(stop, "outcome", "no output was written")
        print(f"sc-fem {args.command}: interrupted; {said}", file=sys.stderr)
        return 130

