"""Modal commands: ``precompute-modes`` (one mesh, or many on Dask), ``play`` and ``modes-sheet``."""

from __future__ import annotations

from ..fem.options import EigenOptions
from ..io.playback import modes_sheet_to_file, play_modes
from ..io.precompute import precompute_modes
from ..modes.options import Damping
from .common import (add_amplitude_arg, add_element_arg, add_fix_args, add_grid_args, add_impulse_arg,
                     add_material_args, add_mesh_arg, add_quiet, add_up_arg, command, finish, fix_options,
                     grid_options, impulse_arg)


def register(sub) -> None:
    p = command(
        sub, "precompute-modes", run_precompute, outputs=(".npz",), folder=True,
        help="compute vibration modes and bake them onto the mesh (.npz)",
        description="Voxelize MESH, compute its vibration modes, interpolate them onto the source mesh and "
                    "write a mode file (.npz, see docs/formats.md). Several meshes (or a glob such as "
                    "'assets/*.obj') with -o FOLDER run as one Dask task per mesh (a local cluster, or "
                    "--scheduler ADDRESS) and write FOLDER/NAME.modes.npz plus FOLDER/summary.csv.")
    add_mesh_arg(p, many=True)
    p.add_argument("-o", "--output", required=True, help="mode file (.npz) for one mesh, or a folder for several")
    add_grid_args(p, auto=True)
    p.add_argument("--tolerance", type=float, default=None, help="relative frequency agreement of -r auto (0.05)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--modes", "-k", type=int, default=None, help="number of elastic modes (default 10)")
    g.add_argument("--max-frequency", type=float, default=None, metavar="HZ",
                   help="all modes below this frequency (e.g. half the playback frame rate)")
    add_fix_args(p)
    add_element_arg(p, higher_order=True)
    add_material_args(p)
    d = p.add_mutually_exclusive_group()
    d.add_argument("--damping", type=float, default=None, metavar="ZETA",
                   help="modal damping ratio of every mode (default 0.01)")
    d.add_argument("--rayleigh", type=float, nargs=2, default=None, metavar=("ALPHA", "BETA"),
                   help="Rayleigh damping C = ALPHA M + BETA K (ALPHA in 1/s, BETA in s)")
    p.add_argument("--lumped", action="store_true", help="lumped instead of consistent mass")
    p.add_argument("--keep-rigid", action="store_true", help="keep rigid-body modes (flagged) instead of removing them")
    p.add_argument("--keep-lattice", action="store_true", help="also store the lattice and the node modes")
    p.add_argument("--eigensolver", choices=("auto", "shift-invert", "lobpcg"), default="auto",
                   help="default auto: the one predicted faster on this machine (shift-invert with a Cholesky "
                        "factor below ~18k DOFs (~24k without numba), else LOBPCG + AMG) whose memory fits")
    p.add_argument("--backend", choices=("auto", "cholmod", "cholespy", "splu"), default="auto",
                   help="factorization backend for shift-invert (default: the fastest installed)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="batch: address of a running dask.distributed scheduler (default: a local cluster)")
    p.add_argument("--workers", type=int, default=None, help="batch: local workers (default: min(meshes, CPUs))")
    add_quiet(p)

    q = command(sub, "play", run_play, outputs=(".mp4", ".gif"), folder=True,
                help="play a mode file back (exact damped modal oscillators)",
                description="Play back a mode file: an impulse on a source vertex or one mode displaced, "
                            "advanced by the exact solution of each damped modal oscillator. Writes "
                            ".mp4, .gif or a folder of PNG frames; without -o opens a window when a display exists.")
    q.add_argument("modes", metavar="MODES", help="mode file (.npz) from precompute-modes")
    add_impulse_arg(q, "an impulse (N s) on a source vertex at t = 0")
    q.add_argument("--mode", type=int, default=None, help="displace this mode (default 0 when no --impulse)")
    add_amplitude_arg(q, "of --mode at t = 0 (as export --mode releases it)")
    q.add_argument("--duration", type=float, default=2.0, help="seconds to play (default 2)")
    q.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30); modes above fps/2 alias")
    q.add_argument("--exaggerate", type=float, default=1.0, help="multiply displacements for display (default 1)")
    q.add_argument("-o", "--output", default=None, help="out.mp4, out.gif or a folder for PNG frames")
    add_up_arg(q)
    add_quiet(q)

    s = command(sub, "modes-sheet", run_sheet, outputs=(".png",),
                help="picture of the first mode shapes with their frequencies",
                description="Write a PNG grid of the first mode shapes of a mode file.")
    s.add_argument("modes", metavar="MODES", help="mode file (.npz)")
    s.add_argument("-o", "--output", required=True, help="output .png")
    s.add_argument("--count", "-n", type=int, default=6, help="number of modes shown (default 6)")
    s.add_argument("--columns", type=int, default=None, help="panels per row (default 3)")
    add_up_arg(s)
    add_quiet(s)


def run_precompute(args) -> int:
    options = dict(**grid_options(args), **fix_options(args), n_modes=args.modes, max_frequency=args.max_frequency,
                   element=args.element, lumped=args.lumped, keep_rigid=args.keep_rigid, keep_lattice=args.keep_lattice,
                   damping=Damping(ratio=args.damping, rayleigh=args.rayleigh),     # neither: the default ratio
                   eigen=EigenOptions(solver=args.eigensolver, backend=args.backend))
    return finish(args, precompute_modes(args.mesh, args.output, options, scheduler=args.scheduler,
                                         n_workers=args.workers, verbose=not args.quiet))


def run_play(args) -> int:
    return finish(args, play_modes(args.modes, args.output, impulse=impulse_arg(args.impulse), mode=args.mode,
                                   amplitude=args.amplitude, duration=args.duration, fps=args.fps,
                                   exaggerate=args.exaggerate, up=args.up, progress=not args.quiet))


def run_sheet(args) -> int:
    return finish(args, modes_sheet_to_file(args.modes, args.output, n_modes=args.count, columns=args.columns,
                                            up=args.up))
