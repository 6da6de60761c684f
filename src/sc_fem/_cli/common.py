"""Options shared by several commands (mesh, grid, material), so every command spells them alike."""

from __future__ import annotations

import argparse
import sys
import time
from contextlib import contextmanager

import numpy as np


def add_mesh_arg(p: argparse.ArgumentParser, *, many: bool = False) -> None:
    """The positional MESH (``many``: one or more, glob patterns allowed)."""
    if many:
        p.add_argument("mesh", metavar="MESH", nargs="+",
                       help="mesh file(s) (OBJ, STL, PLY, OFF, glTF, VTK/VTU, ...), glob patterns or "
                            "builtin:NAME (chair, bridge, rope, beam)")
    else:
        p.add_argument("mesh", metavar="MESH",
                       help="mesh file (OBJ, STL, PLY, OFF, glTF, VTK/VTU, ...) or builtin:NAME "
                            "(chair, bridge, rope, beam)")


def add_grid_args(p: argparse.ArgumentParser, *, auto: bool = False) -> None:
    """Grid, fill, stiffness, occupancy, bodies and ``--keep`` options (``auto``: ``--resolution``
    also takes ``auto``)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resolution", "-r", default=None,
                   type=(str if auto else int),
                   help="cubes along the longest bounding-box axis (default 32)"
                        + ("; 'auto' picks the coarsest grid whose frequencies have converged" if auto else ""))
    g.add_argument("--pitch", type=float, default=None, help="cube edge in model units")
    p.add_argument("--scale", type=float, default=1.0,
                   help="metres per model unit (a model in millimetres: 0.001); default 1")
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


def voxel_options(args):
    """The :class:`sc_fem.VoxelOptions` of the grid/material options of ``args`` (``--resolution``
    only when it is a number: ``auto`` is the modal command's business)."""
    from ..lattice.options import VoxelOptions
    from ..modes.options import AutoResolution, parse_resolution

    res = parse_resolution(getattr(args, "resolution", None))      # a bad value is an error here
    return VoxelOptions(resolution=None if isinstance(res, AutoResolution) else res, pitch=args.pitch, scale=args.scale, fill=args.fill, occupancy=args.occupancy,
                        keep=args.keep, topology=args.topology, weld=args.weld,
                        shell_thickness=args.shell_thickness, stiffness=args.stiffness,
                        youngs=args.youngs, poisson=args.poisson, density=args.density, mass=args.mass)


def voxelize_from_args(args, mesh=None):
    """Run :func:`sc_fem.voxelize` with the grid/material options of ``args``."""
    from ..lattice.voxelize import voxelize

    return voxelize(mesh if mesh is not None else args.mesh, voxel_options(args))


def scene_from_args(args, mesh=None):
    """A :class:`sc_fem.Scene` from the mesh, grid, material and fix options of ``args``."""
    from ..fem.boundary import read_vertex_file
    from ..scene import Scene

    fix_vertices = read_vertex_file(args.fix_vertices) if getattr(args, "fix_vertices", None) else None
    return Scene.from_mesh(mesh if mesh is not None else args.mesh, voxel_options(args),
                           fix=list(getattr(args, "fix", []) or []) or None, fix_vertices=fix_vertices)


def _bodies_line(model) -> str:
    info = model.info
    if info.get("topology") != "pieces":
        return f"{model.n_components} (topology {info.get('topology', 'grid')}: cubes glue what they share)"
    shared = int(np.sum(np.diff(np.ravel_multi_index(model.cells.T, model.dims)) == 0))
    return (f"{model.n_components} kept of {info.get('bodies', 1)} (weld {info.get('weld', 0):.4g} model units: "
            f"{info.get('welds_by_distance', 0)} part pairs welded by distance, "
            f"{info.get('welds_by_containment', 0)} by nesting; {info.get('loose_bodies', 0)} loose; "
            f"{shared} cells hold cubes of two bodies)")


def model_summary(model) -> str:
    info = model.info
    rows = [
        ("source", info.get("source", "")),
        ("grid", " x ".join(str(int(d)) for d in model.dims) + f"  (pitch {model.pitch:.4g} model units, h {model.h:.4g} m)"),
        ("cubes / nodes / DOFs", f"{model.n_cubes:,} / {model.n_nodes:,} / {model.n_dofs:,}"),
        ("samples", f"{info.get('n_samples', 0):,} ({info.get('sampler', '')}, {info.get('occupancy', '')}, fill {info.get('fill', '')})"),
        ("bodies", _bodies_line(model)),
        ("components", f"{info.get('components_found', model.n_components)} found, "
                       f"{info.get('dropped_cubes', 0)} cubes dropped"),
        ("size", " x ".join(f"{e:.4g}" for e in model.dims * model.h) + " m (bounding box of the cubes)"),
        ("mass", f"{model.total_mass:.6g} kg"),
        ("E", f"{model.youngs.min():.4g} .. {model.youngs.max():.4g} Pa ({info.get('material', '')})"),
    ]
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{w}}  {v}" for k, v in rows)


@contextmanager
def stage(name: str, timings: dict, quiet: bool = False):
    """Time a stage and print it to stderr."""
    t0 = time.perf_counter()
    if not quiet:
        print(f"[{name}] ...", file=sys.stderr, flush=True)
    yield
    timings[name] = time.perf_counter() - t0
    if not quiet:
        print(f"[{name}] {timings[name]:.2f} s", file=sys.stderr, flush=True)


def add_fix_args(p: argparse.ArgumentParser) -> None:
    """``--fix SPEC`` (repeatable) and ``--fix-vertices FILE``: the same on every command."""
    p.add_argument("--fix", action="append", default=[], metavar="SPEC",
                   help='fix lattice nodes: "x<0.01", "z<min+0.02", "y>max-0.1", "x>0.2 & x<0.4" '
                        '(axis, < or >, a value in model units, optionally relative to the bounding box; '
                        'repeatable, the union is fixed); "default" = the built-in model\'s natural supports')
    p.add_argument("--fix-vertices", metavar="FILE", default=None,
                   help="text file of source-mesh vertex indices (one a line); their cubes' nodes are fixed")


def add_up_arg(p: argparse.ArgumentParser, *, uses: str = "pictures draw it upward") -> None:
    """``--up x|y|z``: the model's up axis, one option and default on every command; ``uses`` says
    what this command does with it (help text)."""
    p.add_argument("--up", choices=("x", "y", "z"), default="z",
                   help=f"the model's up axis (default z; many OBJ/glTF models are y-up): {uses}")


def add_element_arg(p: argparse.ArgumentParser) -> None:
    """``--element`` with the element types of :data:`sc_fem.fem.elements.ELEMENTS`."""
    from ..fem.elements import DEFAULT_ELEMENT, ELEMENTS

    p.add_argument("--element", choices=ELEMENTS, default=DEFAULT_ELEMENT,
                   help=f"element type: {', '.join(ELEMENTS)} (default {DEFAULT_ELEMENT})")
