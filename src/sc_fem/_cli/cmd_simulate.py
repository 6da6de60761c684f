"""``sc-fem simulate MESH --duration S --dt DT -o OUT``: dynamics of the cube lattice, written as the
source mesh's vertex animation (``.npz``, ``.xdmf`` for ParaView, or a rendered ``.mp4``/``.gif``).

Impulses (``--impulse VERTEX JX JY JZ``, N s) act at t = 0 as an initial velocity
``v0 = M^-1 W^T J`` (the momentum they carry, spread to the cube nodes with ``W^T``).
``--gust FX FY FZ SECONDS`` is a total force (N) spread equally over all source vertices with a
half-sine time profile of SECONDS (a gust of wind).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from .._validate import positive_scalar
from ..errors import InputError, RenderError
from .common import (add_element_arg, add_fix_args, add_grid_args, add_material_args, add_mesh_arg,
                     add_up_arg, model_summary, scene_from_args, stage)


def register(sub) -> None:
    p = sub.add_parser(
        "simulate", help="time integration (Newmark, corotational, central differences) with loads and contact",
        description="Simulate MESH as elastic cubes for DURATION seconds with step DT and write the source "
                    "mesh's vertex animation: .npz (sc_fem.io.animation), .xdmf (ParaView time series with its arrays "
                    "in NAME.h5 beside it, point data 'displacement' in model units: apply Warp By Vector), or a "
                    "rendered .mp4/.gif. "
                    "A run that blows up stops with the time step and dt_crit and writes nothing.")
    add_mesh_arg(p)
    add_grid_args(p)
    add_material_args(p)
    add_fix_args(p)
    p.add_argument("--duration", type=float, required=True, help="simulated time, s")
    p.add_argument("--dt", type=float, default=None,
                   help="time step, s; it must divide the frame step 1/--fps (default: half a frame for the implicit "
                        "methods, 0.9 x the stability limit for central, a frame for xpbd)")
    p.add_argument("--method", choices=("auto", "ipc", "newmark", "corotational", "central", "xpbd"), default="auto",
                   help="auto (default): ipc when there is an obstacle (--ground/--sphere/--box), else newmark. "
                        "ipc: backward Euler with barrier contact and friction inside the step (never "
                        "interpenetrates, stable at any dt); newmark: implicit Newmark; corotational: Newmark for "
                        "large rotations; central: explicit; xpbd: gravity and --fix only, --dt is the frame step "
                        "(see --substeps). newmark/corotational/central push vertices out of obstacles after each "
                        "step instead, which can add energy")
    p.add_argument("--friction", type=float, default=0.3,
                   help="Coulomb friction coefficient of the ipc contacts (default 0.3; 0: frictionless)")
    p.add_argument("--no-self-contact", dest="self_contact", action="store_false",
                   help="ipc: let a body pass through itself (by default the outer surface of its cube lattice "
                        "keeps it from doing so; separate bodies always collide)")
    p.add_argument("--substeps", type=int, default=20, help="XPBD substeps per --dt step (default 20)")
    p.add_argument("--iterations", type=int, default=1, help="XPBD solver iterations per substep (default 1)")
    p.add_argument("--constraints", choices=("neohookean", "corotational", "distance"), default="neohookean",
                   help="XPBD constraints (default neohookean; see sc_fem.dynamics.xpbd)")
    p.add_argument("--xpbd-damping", type=float, default=0.0, help="XPBD mass-proportional damping, 1/s")
    add_element_arg(p)
    p.add_argument("--beta", type=float, default=None, help="Newmark beta (default 1/4, or the HHT value)")
    p.add_argument("--gamma", type=float, default=None, help="Newmark gamma (default 1/2, or the HHT value)")
    p.add_argument("--hht-alpha", type=float, default=0.0, help="HHT alpha in [-1/3, 0] (numerical damping)")
    p.add_argument("--rayleigh", type=float, nargs=2, default=(0.0, 0.0), metavar=("A0", "A1"),
                   help="Rayleigh damping C = A0 M + A1 K (A0 in 1/s, A1 in s)")
    p.add_argument("--gravity", action="store_true", help="gravity 9.81 m/s^2 down the --up axis (default -z)")
    p.add_argument("--ground", type=float, default=None, metavar="Z",
                   help="ground plane at height Z along the --up axis (model units): source vertices stay above it")
    add_up_arg(p, uses="pictures draw it upward, --gravity pulls down it and --ground is a height along it")
    p.add_argument("--sphere", type=float, nargs=4, default=None, metavar=("X", "Y", "Z", "R"),
                   help="static sphere obstacle (model units)")
    p.add_argument("--box", type=float, nargs=6, default=None, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                   help="static axis-aligned box obstacle (model units)")
    p.add_argument("--impulse", type=float, nargs=4, action="append", default=[],
                   metavar=("VERTEX", "JX", "JY", "JZ"),
                   help="impulse in N s on a source vertex at t = 0 (repeatable)")
    p.add_argument("--velocity", type=float, nargs=3, default=None, metavar=("VX", "VY", "VZ"),
                   help="initial velocity of the whole model, m/s (a thrown model)")
    p.add_argument("--gust", type=float, nargs=4, default=None, metavar=("FX", "FY", "FZ", "SECONDS"),
                   help="total force in N over all vertices, half-sine pulse lasting SECONDS")
    p.add_argument("--fps", type=float, default=50.0, help="frames per second stored (default 50)")
    p.add_argument("--exaggerate", dest="magnify", type=float, default=1.0,
                   help="multiply displacements in a rendered video only (default 1; the same option as play's)")
    p.add_argument("-o", "--output", required=True, help="output: .npz, .xdmf, .mp4 or .gif")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..dynamics.job import NewmarkOptions, XPBDOptions, run_simulation
    from ..io.animation import write_animation

    out = Path(args.output)                             # its extension was checked by main before any work
    for name, flag in (("duration", "--duration"), ("dt", "--dt"), ("fps", "--fps"), ("magnify", "--exaggerate")):
        if getattr(args, name) is not None:
            positive_scalar(getattr(args, name), flag)      # checked before any work, named as typed
    if args.dt is not None and int(round(args.duration / args.dt)) < 1:
        raise InputError(f"--duration {args.duration:g} s is shorter than one step of --dt {args.dt:g} s")
    if args.dt is not None and args.method != "xpbd":
        ratio = 1.0 / (args.fps * args.dt)
        if abs(ratio - max(1, round(ratio))) > 1e-6 * ratio:
            raise InputError(f"--dt {args.dt:g} s does not divide the frame step 1/--fps = {1 / args.fps:.6g} s "
                             f"(the frames would not be stored at {args.fps:g} fps): give a --dt that divides it")
    timings: dict = {}
    q = args.quiet
    progress = not (q or args.no_progress)
    with stage("voxelize", timings, q):
        scene = scene_from_args(args)
    with stage("simulate", timings, q):
        rec = run_simulation(
            scene, dt=args.dt, duration=args.duration, method=args.method, fps=args.fps, gravity=args.gravity,
            gust=args.gust, ground=args.ground, sphere=args.sphere, box=args.box, impulses=args.impulse,
            velocity=args.velocity, friction=args.friction, self_contact=args.self_contact, rayleigh=args.rayleigh, newmark=NewmarkOptions(beta=args.beta, gamma=args.gamma, alpha=args.hht_alpha),
            xpbd=XPBDOptions(substeps=args.substeps, iterations=args.iterations, constraints=args.constraints,
                             damping=args.xpbd_damping), element=args.element, up=args.up, progress=progress)
    with stage("write", timings, q):
        write_animation(out, scene, rec, exaggerate=args.magnify, fps=args.fps, progress=progress)
    for w in rec.info["warnings"]:
        print(f"sc-fem simulate: warning: {w}", file=sys.stderr)
    if not q:
        print(model_summary(scene.model))
        print(run_summary(rec))
        print(f"wrote {out}")
    return 0


def energy_line(rec) -> str:
    """The energy of a run's last frame by kind, J."""
    p = rec.parts
    keys = ("kinetic", "elastic", "gravity", "contact", "work", "dissipated")
    return ", ".join(f"{k} {p[k][-1]:.4g}" for k in keys if k in p and len(p[k])) + " J"


def run_summary(rec) -> str:
    """The lines ``sc-fem simulate`` prints about a run."""
    info = rec.info
    disp = np.linalg.norm(rec.points - rec.points[0], axis=2).max() if len(rec.points) else 0.0
    kind = (f"{info['substeps']} substeps x {info['iterations']} iterations, {info['constraints']}"
            if info["method"] == "xpbd" else ("implicit" if info["implicit"] else "explicit"))
    n, dt = info["n_steps"], info["dt"]
    rows = [("method", f"{info['method']} ({kind})"),
            ("steps", f"{n:,} x {dt:g} s = {n * dt:g} s ({len(rec.times)} frames)"),
            ("time per step", f"{1e3 * rec.seconds_per_step:.3g} ms (setup {rec.setup_seconds:.3g} s)"),
            ("energy at the end", energy_line(rec)),
            ("energy created", f"{rec.energy_gain:.3e} of the energy scale {rec.energy_scale:.4g} J at most "
                               "(beyond the loads' work; 0 for a stable run)"),
            ("max vertex displacement", f"{disp:.4g} model units")]
    if info["dt_crit"] is not None:
        rows.append(("dt / dt_crit", f"{dt / info['dt_crit']:.3g} (dt_crit = {info['dt_crit']:.4g} s)"))
    if info.get("newton_iterations") is not None and info["method"] == "ipc":
        rows.append(("contact", f"{info['contact_steps']} steps in contact, {info['newton_iterations']} Newton "
                                f"iterations, friction {info['friction']}, dhat {info['dhat']:.3g} model units, "
                                "no vertex ever through an obstacle"))
    if info["contact_tol"] is not None:
        rows.append(("max contact depth", f"{max(rec.max_contact_depth, 0.0):.3g} model units "
                                          f"(tolerance {info['contact_tol']:.3g})"))
    w = max(len(k) for k, _ in rows)
    return "\n".join(f"  {k:<{w}}  {v}" for k, v in rows)


def demo_dynamics(out_dir, *, resolution: int = 16, quiet: bool = True) -> list[Path]:
    """Demo step: the built-in bridge under a lateral gust and gravity, settling on its supports.

    Writes ``bridge_gust.npz`` (true displacements) and ``bridge_gust.gif`` (displacements x2000, 10x slow motion)
    under ``out_dir`` and returns their paths (about 10--20 s)."""
    from ..dynamics.job import run_simulation
    from ..io.animation import write_animation
    from ..scene import Scene

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    scene = Scene.from_mesh("builtin:bridge", resolution=resolution, fix="default")
    rec = run_simulation(scene, dt=0.001, duration=0.5, gravity=True, gust=(0.0, 2e7, 0.0, 0.02),
                         rayleigh=(1.0, 2e-4), fps=250)
    written = [write_animation(out_dir / "bridge_gust.npz", scene, rec)]
    try:
        written.append(write_animation(out_dir / "bridge_gust.gif", scene, rec, exaggerate=2000.0, fps=25,
                                       title="bridge: gust + gravity, Newmark (x2000, 10x slow motion)"))
    except RenderError as exc:
        print(f"demo_dynamics: no video ({exc})", file=sys.stderr)
    if not quiet:
        print(run_summary(rec))
    return written
