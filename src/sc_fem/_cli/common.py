"""Options shared by several commands (mesh, grid, material, fix, up, element), so every command
spells them alike; :func:`command` declares a command and :func:`finish` prints what its job says."""

from __future__ import annotations

import argparse
import math
import sys

from ..errors import InputError
from ..fem.elements import DEFAULT_ELEMENT, ELEMENTS
from ..fem.choice import AUTO, THIN_WALLS
from ..fem.highorder import DEGREES
from ..lattice.boundary import read_vertex_file
from ..lattice.options import VoxelOptions
from ..modes.options import AutoResolution


def command(sub, name: str, run, *, outputs: tuple = (), folder: bool = False, **kw) -> argparse.ArgumentParser:
    """Add the command ``name`` running ``run(args) -> int``; ``outputs``: the extensions its ``-o``
    takes, ``folder``: whether it takes a folder (main checks both, probing the location, first)."""
    p = sub.add_parser(name, **kw)
    p.set_defaults(func=run, outputs=(tuple(outputs), folder))
    return p


def add_quiet(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quiet", "-q", action="store_true", help="print only errors")


def finish(args, res) -> int:
    """Print a job's summary (unless ``--quiet``) and its error line; the exit status (1: not ok)."""
    if res.summary() and not getattr(args, "quiet", False):
        print(res.summary())
    if res.error:
        print(f"sc-fem {args.command}: error: {res.error}", file=sys.stderr)
    return 0 if res.ok else 1


def add_mesh_arg(p: argparse.ArgumentParser, *, many: bool = False) -> None:
    """The positional MESH (``many``: one or more, glob patterns allowed)."""
    files = "mesh file(s) (OBJ, STL, PLY, OFF, glTF, VTK/VTU, ...), glob patterns" if many else \
        "mesh file (OBJ, STL, PLY, OFF, glTF, VTK/VTU, ...)"
    p.add_argument("mesh", metavar="MESH", nargs="+" if many else None,
                   help=f"{files} or builtin:NAME (chair, bridge, rope, beam)")


def add_grid_args(p: argparse.ArgumentParser, *, auto: bool = False) -> None:
    """Grid, fill, stiffness, occupancy, bodies and ``--keep`` options (``auto``: ``--resolution``
    also takes ``auto``)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resolution", "-r", default=None, type=(str if auto else int),
                   help="cubes along the longest bounding-box axis (default 32)"
                        + ("; 'auto' picks the coarsest grid whose frequencies have converged" if auto else ""))
    g.add_argument("--pitch", type=float, default=None, help="cube edge in model units")
    p.add_argument("--scale", type=float, default=1.0, help="metres per model unit (a model in mm: 0.001); default 1")
    p.add_argument("--fill", choices=("auto", "solid", "surface"), default="auto",
                   help="auto (default): solid where the surface encloses volume, a shell of "
                        "--shell-thickness where it does not; solid: every part solid; surface: every part a shell")
    p.add_argument("--shell-thickness", type=float, default=None,
                   help="physical thickness of shell parts in model units (default 1%% of the longest extent)")
    p.add_argument("--stiffness", choices=("moments", "fraction", "full"), default="moments",
                   help="moments (default): a partly filled cube's element matrices are integrated over its "
                        "filled region; fraction: its stiffness is scaled by its filled volume; "
                        "full: every cube at full stiffness (the original Squashing Cubes)")
    p.add_argument("--occupancy", dest="occupancy", choices=("sample", "exact"), default="sample",
                   help="which cubes the surface occupies: point sampling (default) or exact triangle-cube overlap")
    p.add_argument("--keep", choices=("bodies", "largest", "all"), default="bodies",
                   help="bodies (default): the largest connected part of every body, except loose ones "
                        "(< 1%% of the heaviest body's mass, e.g. stray polygons); largest: only the largest "
                        "connected part; all: everything")
    p.add_argument("--topology", choices=("pieces", "grid"), default="pieces",
                   help="pieces (default): parts of the mesh closer than --weld, crossing or nested are one "
                        "body, and bodies never share cube nodes even inside one cube; grid: everything in a "
                        "cube moves together (the original Squashing Cubes)")
    p.add_argument("--weld", type=float, default=None,
                   help="weld distance in model units: parts closer than this are joined (default 0.5%% of "
                        "the longest extent, the same at every resolution)")


def add_material_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--youngs", type=float, default=None, help="Young's modulus E in Pa")
    p.add_argument("--poisson", type=float, default=None, help="Poisson's ratio nu in (-1, 0.5)")
    p.add_argument("--density", type=float, default=None, help="density in kg/m^3")
    p.add_argument("--mass", type=float, default=None, help="total mass in kg (overrides density)")


def grid_options(args: argparse.Namespace) -> dict:
    """``{"voxel": VoxelOptions, "auto": AutoResolution or None}`` of the grid/material options of ``args``
    (keywords of :func:`sc_fem.io.precompute.mesh_modes`): the one place ``--resolution`` is read (a number, or
    ``auto`` with ``--tolerance`` for the modal command); past here the options carry it unopened."""
    res, tol = getattr(args, "resolution", None), getattr(args, "tolerance", None)
    auto = isinstance(res, str) and res.strip().lower() == "auto"
    if isinstance(res, str) and not auto and not res.strip().lstrip("-").isdigit():
        raise InputError(f"resolution must be an integer or 'auto', got {res!r}")
    res = int(res) if isinstance(res, str) and not auto else res
    if tol is not None and not auto:
        raise InputError("--tolerance applies to --resolution auto only")
    same = ("pitch", "scale", "fill", "occupancy", "keep", "topology", "weld", "shell_thickness", "stiffness",
            "youngs", "poisson", "density", "mass")              # VoxelOptions' fields spelled as the options
    voxel = VoxelOptions(resolution=None if auto else res, **{k: getattr(args, k) for k in same})
    return {"voxel": voxel, "auto": AutoResolution(**({} if tol is None else {"tolerance": tol})) if auto else None}


def voxel_options(args: argparse.Namespace):
    """The :class:`sc_fem.VoxelOptions` of the grid/material options of ``args`` (:func:`grid_options`)."""
    return grid_options(args)["voxel"]


def add_fix_args(p: argparse.ArgumentParser) -> None:
    """``--fix SPEC`` (repeatable) and ``--fix-vertices FILE``: the same on every command."""
    p.add_argument("--fix", action="append", default=[], metavar="SPEC",
                   help='fix lattice nodes: "x<0.01", "z<min+0.02", "y>max-0.1", "x>0.2 & x<0.4" '
                        '(axis, < or >, a value in model units, optionally relative to the bounding box; '
                        'repeatable, the union is fixed); "default" = the built-in model\'s natural supports')
    p.add_argument("--fix-vertices", metavar="FILE", default=None,
                   help="text file of source-mesh vertex indices (one a line); their cubes' nodes are fixed")


def fix_options(args) -> dict:
    """``fix`` and ``fix_vertices`` (:meth:`sc_fem.Scene.from_mesh`, :func:`sc_fem.modal`) of
    ``--fix`` and ``--fix-vertices``."""
    return dict(fix=list(args.fix or []) or None,
                fix_vertices=read_vertex_file(args.fix_vertices) if args.fix_vertices else None)


def add_up_arg(p: argparse.ArgumentParser, *, uses: str = "pictures draw it upward") -> None:
    """``--up x|y|z``: the model's up axis, one option and default on every command; ``uses`` says
    what this command does with it (help text)."""
    p.add_argument("--up", choices=("x", "y", "z"), default="z",
                   help=f"the model's up axis (default z; many OBJ/glTF models are y-up): {uses}")


def add_amplitude_arg(p: argparse.ArgumentParser, what: str) -> None:
    """``--amplitude``: one meaning on play, export and view (``what``: of which motion)."""
    p.add_argument("--amplitude", type=float, default=None, metavar="FRACTION",
                   help=f"largest vertex displacement {what}, fraction of the bounding-box diagonal (default 0.05)")


def add_impulse_arg(p, help: str, *, many: bool = False) -> None:
    """``--impulse VERTEX JX JY JZ`` (N s), parsed alike on every command (``many``: repeatable)."""
    p.add_argument("--impulse", type=float, nargs=4, metavar=("VERTEX", "JX", "JY", "JZ"), help=help,
                   action="append" if many else "store", default=[] if many else None)


def impulse_arg(values) -> tuple[int, tuple] | None:
    """``(vertex, (Jx, Jy, Jz))`` of one ``--impulse`` (None: None): VERTEX a whole number >= 0, J finite."""
    if values is not None and not (float(values[0]).is_integer() and values[0] >= 0
                                   and all(map(math.isfinite, values))):
        raise InputError("--impulse needs VERTEX JX JY JZ: a vertex index (an integer >= 0) and an impulse in N s, "
                         f"got {' '.join(f'{x:g}' for x in values)}")
    return None if values is None else (int(values[0]), tuple(values[1:]))


def add_element_arg(p: argparse.ArgumentParser, *, higher_order: bool = False) -> None:
    """``--element``: the cube elements of :data:`sc_fem.fem.elements.ELEMENTS`, and with
    ``higher_order`` the degree-2 and 3 cubes of :mod:`sc_fem.fem.highorder` (linear analyses)."""
    if not higher_order:
        p.add_argument("--element", choices=ELEMENTS, default=DEFAULT_ELEMENT,
                       help=f"element type: {', '.join(ELEMENTS)} (default {DEFAULT_ELEMENT})")
        return
    choices = (AUTO, *ELEMENTS, *DEGREES)
    p.add_argument("--element", choices=choices, default=DEFAULT_ELEMENT,
                   help=f"element type: {', '.join(choices)} (default {DEFAULT_ELEMENT}: trilinear, fast; q3: degree-3 "
                        "cubes, partly filled ones condensed from a finer model of their walls -- thin-walled members "
                        "to a few %%, 10-50x slower; q2: degree 2; auto: q3 for a thin-walled model, walls thinner "
                        f"than 1/{1 / THIN_WALLS:.0f} of its size and than a cube, {DEFAULT_ELEMENT} otherwise)")
