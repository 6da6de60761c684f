"""``sc-fem`` entry point: ``main(argv=None) -> int``, testable in-process.

Each module ``sc_fem/_cli/cmd_*.py`` defines ``register(subparsers)``, which adds its
sub-command(s) and sets ``func=run`` (a callable ``run(args) -> int``) as the parser default.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from .. import __version__
from ..errors import ScFemError, ScFemWarning


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sc-fem",
        description="Squashing Cubes: turn any graphics mesh into a deformable object "
                    "(voxelize, FEM, modes, dynamics, XPBD, PDE reconstruction). "
                    "A MESH is a file path (OBJ, STL, PLY, OFF, glTF, VTK/VTU, ...) or builtin:NAME "
                    "(chair, bridge, rope, beam). Units are SI; geometry options are in model units.",
    )
    parser.add_argument("--version", action="version", version=f"sc-fem {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    from . import __path__ as cli_path

    for info in sorted(pkgutil.iter_modules(cli_path), key=lambda m: m.name):
        if info.name.startswith("cmd_"):
            importlib.import_module(f"{__package__}.{info.name}").register(sub)
    return parser


OUTPUTS: dict[str, tuple[tuple[str, ...], bool]] = {
    "voxelize": ((".png", ".npz", ".vtu"), False),
    "precompute-modes": ((".npz",), True),
    "play": ((".mp4", ".gif"), True),
    "modes-sheet": ((".png",), False),
    "simulate": ((".npz", ".xdmf", ".mp4", ".gif"), False),
    "reconstruct": ((".npz",), False),
    "demo": ((), True),
    "export": ((".glb", ".gltf", ".vtu"), False),
    "view": ((".html", ".htm"), False),
}
"""Per command: the output extensions it writes and whether a folder is accepted; checked (and the
output location probed for writing) before any work starts."""


def _check_outputs(args) -> None:
    from .._atomic import check_output

    suffixes, folder = OUTPUTS.get(args.command, ((), True))
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
    import warnings

    def show(message, category, *rest, **kw):      # one line, no source excerpt
        print(f"sc-fem {args.command}: warning: {message}", file=sys.stderr)

    try:
        _check_outputs(args)
        with warnings.catch_warnings():
            warnings.simplefilter("always", ScFemWarning)
            warnings.showwarning = show
            return int(args.func(args) or 0)
    except ScFemError as exc:
        print(f"sc-fem {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"sc-fem {args.command}: interrupted; no output was written", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
