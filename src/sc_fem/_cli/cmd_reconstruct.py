"""sc-fem reconstruct: PDE-based dynamic reconstruction of a vertex animation (Fang et al. 2024).

Fits the paper's Eq. 17 model and the static B-spline baseline at --fit-frames, evaluates both at
every frame from the first to the last fitted one, and writes the curves (and mesh vertices) to an
.npz, plus a Markdown --report (E_A / E_M per frame, timings, counts). Exit status: 0 when the PDE
fit is acceptable; 1 when it failed (an error not finite, a mean E_A above 0.02 or a max E_M above
0.2 of the curves' diameter, or a mean E_A at the fitted frames above 0.001 and worse than the
B-spline's: the files are still written, an "error:" line says why); 2 for bad input.
"""

from __future__ import annotations

import argparse

from ..errors import InputError
from ..io.reconstruction import reconstruct_to_file
from .common import command, finish


def register(subparsers) -> None:
    p = command(subparsers, "reconstruct", run, outputs=(".npz",), description=__doc__,
                help="PDE-based dynamic reconstruction of an animation from a few frames",
                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("animation", help="vertex animation .npz (as written by sc-fem simulate)")
    p.add_argument("--fit-frames", default="0,2,4,6,8,10",
                   help="comma-separated frame indices to fit (default 0,2,4,6,8,10)")
    p.add_argument("-o", "--output", required=True, help="output .npz")
    p.add_argument("--report", help="write a Markdown table of errors, timings and counts here")
    p.add_argument("--curves", type=int, default=8, help="curves to extract if the file has none (8)")
    p.add_argument("--points", type=int, default=64, help="points per extracted curve (64)")
    p.add_argument("--r", type=float, default=None, help="spatial rate r (searched if omitted)")
    p.add_argument("--alpha", type=float, default=None, help="temporal rate alpha (searched if omitted)")
    p.add_argument("--parametrization", choices=("paper", "arclength"), default="paper")
    p.add_argument("--criterion", choices=("residual", "loo"), default="residual",
                   help="(r, alpha) search objective (default: residual at fitted frames)")
    p.add_argument("--rigid-interpolation", choices=("cubic", "linear"), default="cubic")
    p.add_argument("--no-rigid", action="store_true", help="do not remove rigid motion (Eqs. 18-23)")
    p.add_argument("--n-control", type=int, default=50, help="B-spline control points per curve (50)")
    p.add_argument("--segments", default="auto",
                   help="PDE pieces per curve, or 'auto' (default): 1, 2, 4, ... until the PDE fits the fitted "
                        "frames at least as well as the B-spline")
    p.add_argument("--offset", choices=("auto", "none", "first"), default="auto",
                   help="none (the paper): the PDE models the curves; first: their motion away from the first "
                        "fitted frame (stored, 3 numbers per point more); auto (default): none, then first")
    p.add_argument("--curves-from", choices=("auto", "stored", "lattice", "mesh"), default="auto",
                   help="stored: the file's curves; lattice: the cube lattice's node lines that sc-fem simulate "
                        "stores (mapped back to the mesh exactly, the most accurate mesh; bar-like lattices); "
                        "mesh: curves of mesh vertices; auto (default): stored if the file has curves, else mesh")


def _segments(text: str):
    try:
        n = "auto" if str(text).strip().lower() == "auto" else int(text)
    except ValueError:
        raise InputError(f"--segments must be a positive integer or 'auto', got {text!r}") from None
    if n != "auto" and n < 1:
        raise InputError(f"--segments must be >= 1, got {n}")
    return n


def run(args) -> int:
    try:
        frames = [int(v) for v in str(args.fit_frames).split(",") if v.strip() != ""]
    except ValueError:
        raise InputError(f"--fit-frames must be comma-separated integers, got {args.fit_frames!r}") from None
    same = ("r", "alpha", "parametrization", "criterion", "rigid_interpolation", "n_control", "offset", "curves_from")
    return finish(args, reconstruct_to_file(
        args.animation, args.output, frames, report=args.report, frames_name="--fit-frames", n_curves=args.curves,
        n_points=args.points, remove_rigid=not args.no_rigid, segments=_segments(args.segments),
        **{k: getattr(args, k) for k in same}))
