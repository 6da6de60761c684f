"""``sc-fem simulate MESH --duration S --dt DT -o OUT``: dynamics of the cube lattice, written as the
source mesh's vertex animation (:func:`sc_fem.io.simulation.simulate_to_file`)."""

from __future__ import annotations

from .._validate import positive_scalar
from ..dynamics.job import NewmarkOptions, XPBDOptions, frame_steps
from ..io.simulation import simulate_to_file
from ..units import gravity_down
from .common import (add_element_arg, add_fix_args, add_grid_args, add_impulse_arg, add_material_args, add_mesh_arg,
                     add_quiet, add_up_arg, command, finish, fix_options, impulse_arg, voxel_options)


def register(sub) -> None:
    p = command(
        sub, "simulate", run, outputs=(".npz", ".xdmf", ".mp4", ".gif"),
        help="time integration (Newmark, corotational, central differences) with loads and contact",
        description="Simulate MESH as elastic cubes for DURATION s (step DT) and write the source mesh's vertex "
                    "animation: .npz, .xdmf (ParaView: 'displacement' in model units, Warp By Vector; the cubes in "
                    "NAME_lattice.xdmf) or a rendered .mp4/.gif. A run that blows up writes nothing.")
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
    p.add_argument("--linear-solver", dest="solver", choices=("auto", "direct", "cg-amg"), default="auto",
                   help="linear systems of newmark/corotational/ipc: direct (sparse Cholesky), cg-amg (conjugate "
                        "gradients + lattice multigrid) or auto (default: direct below 100,000 free DOFs)")
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
    add_impulse_arg(p, "an impulse (N s) on a source vertex at t = 0 (repeatable)", many=True)
    p.add_argument("--velocity", type=float, nargs=3, default=None, metavar=("VX", "VY", "VZ"),
                   help="initial velocity of the whole model, m/s (a thrown model)")
    p.add_argument("--gust", type=float, nargs=4, default=None, metavar=("FX", "FY", "FZ", "SECONDS"),
                   help="total force in N over all vertices, half-sine pulse lasting SECONDS")
    p.add_argument("--fps", type=float, default=50.0, help="frames per second stored (default 50)")
    p.add_argument("--exaggerate", dest="magnify", type=float, default=1.0,
                   help="multiply displacements in a rendered video only (default 1; the same option as play's)")
    p.add_argument("-o", "--output", required=True, help="output: .npz, .xdmf, .mp4 or .gif")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_quiet(p)


def run(args) -> int:
    for name, flag in (("duration", "--duration"), ("dt", "--dt"), ("fps", "--fps"), ("magnify", "--exaggerate")):
        if getattr(args, name) is not None:
            positive_scalar(getattr(args, name), flag)      # checked before any work, named as typed
    if args.dt is not None:
        frame_steps(args.duration, args.dt, args.fps)       # before any work
    same = ("dt", "method", "gust", "ground", "sphere", "box", "velocity", "friction", "self_contact", "rayleigh",
            "element", "up", "solver")                     # run_simulation's keywords spelled as the options
    return finish(args, simulate_to_file(
        args.mesh, args.output, duration=args.duration, fps=args.fps, voxel=voxel_options(args), **fix_options(args),
        exaggerate=args.magnify, verbose=not args.quiet, progress=not (args.quiet or args.no_progress),
        impulses=[(v, *j) for v, j in map(impulse_arg, args.impulse)], gravity=gravity_down(args.up) if args.gravity else None,
        newmark=NewmarkOptions(beta=args.beta, gamma=args.gamma, alpha=args.hht_alpha),
        xpbd=XPBDOptions(substeps=args.substeps, iterations=args.iterations, constraints=args.constraints,
                         damping=args.xpbd_damping), **{k: getattr(args, k) for k in same}))
