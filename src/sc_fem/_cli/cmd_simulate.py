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

from .common import (add_element_arg, add_fix_args, add_grid_args, add_material_args, add_mesh_arg,
                     model_summary, stage, voxelize_from_args)

ENERGY_GAIN_WARN = 0.05
"""Energy gained (fraction of the largest kinetic + elastic energy) past which simulate warns."""

OUTPUTS = (".npz", ".xdmf", ".mp4", ".gif")


def register(sub) -> None:
    p = sub.add_parser(
        "simulate", help="time integration (Newmark, corotational, central differences) with loads and contact",
        description="Simulate MESH as elastic cubes for DURATION seconds with step DT and write the source "
                    "mesh's vertex animation: .npz (sc_fem.animfile), .xdmf (ParaView time series, point data "
                    "'displacement' in model units: apply Warp By Vector), or a rendered .mp4/.gif. "
                    "A run that blows up stops with the time step and dt_crit and writes nothing.")
    add_mesh_arg(p)
    add_grid_args(p, method_flags=("--voxel-method",))
    add_material_args(p)
    add_fix_args(p)
    p.add_argument("--duration", type=float, required=True, help="simulated time, s")
    p.add_argument("--dt", type=float, required=True, help="time step, s")
    p.add_argument("--method", choices=("newmark", "corotational", "central", "xpbd"), default="newmark",
                   help="implicit Newmark (default), corotational Newmark (large rotations), explicit central, "
                        "or XPBD (gravity and --fix only; --dt is then the frame step, see --substeps)")
    p.add_argument("--substeps", type=int, default=20, help="XPBD substeps per --dt step (default 20)")
    p.add_argument("--iterations", type=int, default=1, help="XPBD solver iterations per substep (default 1)")
    p.add_argument("--constraints", choices=("neohookean", "corotational", "distance"), default="neohookean",
                   help="XPBD constraints (default neohookean; see sc_fem.xpbd)")
    p.add_argument("--xpbd-damping", type=float, default=0.0, help="XPBD mass-proportional damping, 1/s")
    add_element_arg(p)
    p.add_argument("--beta", type=float, default=None, help="Newmark beta (default 1/4, or the HHT value)")
    p.add_argument("--gamma", type=float, default=None, help="Newmark gamma (default 1/2, or the HHT value)")
    p.add_argument("--hht-alpha", type=float, default=0.0, help="HHT alpha in [-1/3, 0] (numerical damping)")
    p.add_argument("--rayleigh", type=float, nargs=2, default=(0.0, 0.0), metavar=("A0", "A1"),
                   help="Rayleigh damping C = A0 M + A1 K (A0 in 1/s, A1 in s)")
    p.add_argument("--gravity", action="store_true", help="gravity 9.81 m/s^2 along -z")
    p.add_argument("--ground", type=float, default=None, metavar="Z",
                   help="ground plane z = Z (model units): source vertices stay above it")
    p.add_argument("--sphere", type=float, nargs=4, default=None, metavar=("X", "Y", "Z", "R"),
                   help="static sphere obstacle (model units)")
    p.add_argument("--box", type=float, nargs=6, default=None, metavar=("X0", "Y0", "Z0", "X1", "Y1", "Z1"),
                   help="static axis-aligned box obstacle (model units)")
    p.add_argument("--impulse", type=float, nargs=4, action="append", default=[],
                   metavar=("VERTEX", "JX", "JY", "JZ"),
                   help="impulse in N s on a source vertex at t = 0 (repeatable)")
    p.add_argument("--gust", type=float, nargs=4, default=None, metavar=("FX", "FY", "FZ", "SECONDS"),
                   help="total force in N over all vertices, half-sine pulse lasting SECONDS")
    p.add_argument("--fps", type=float, default=50.0, help="frames per second stored (default 50)")
    p.add_argument("--exaggerate", "--magnify", dest="magnify", type=float, default=1.0,
                   help="multiply displacements in a rendered video only (default 1; the same option as "
                        "play's; --magnify is its old name)")
    p.add_argument("-o", "--output", required=True, help="output: .npz, .xdmf, .mp4 or .gif")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    p.set_defaults(func=run)


def _impulse_nodes(args, model, W, n_vertices: int) -> np.ndarray | None:
    from ..errors import InputError

    if not args.impulse:
        return None
    J = np.zeros((n_vertices, 3))
    for vert, jx, jy, jz in args.impulse:          # loop over a few user impulses
        if not float(vert).is_integer() or not 0 <= int(vert) < n_vertices:
            raise InputError(f"--impulse VERTEX must be a vertex index in [0, {n_vertices}), got {vert:g}")
        J[int(vert)] += (jx, jy, jz)
    return np.asarray(W.T @ J)


def build(args, mesh, model, W):
    """Integrator for the parsed ``args`` (used by :func:`run` and :func:`demo_dynamics`)."""
    from ..errors import InputError
    from ..integrators import make_integrator
    from ..integrators.contact import Contact, obstacles_from
    from ..integrators.loads import Gravity, LoadSet, VertexForce, half_sine
    from .common import fixed_nodes_from_args

    verts = np.asarray(mesh.vertices, dtype=float)
    fixed = fixed_nodes_from_args(args, model, mesh)
    loads = []
    if args.gravity:
        loads.append(Gravity((0.0, 0.0, -9.81)))
    if args.gust is not None:
        fx, fy, fz, secs = args.gust
        if not secs > 0:
            raise InputError(f"--gust SECONDS must be > 0, got {secs:g}")
        loads.append(VertexForce(np.arange(len(verts)), np.array([fx, fy, fz]) / len(verts), half_sine(secs)))
    loadset = LoadSet(model, loads, points=verts, faces=mesh.faces, W=W)
    obs = obstacles_from(args.ground, args.sphere, args.box)
    contact = Contact(model, verts, obs, W=W) if obs else None      # the integrator binds it to `fixed`
    kw = {"fixed_nodes": fixed, "loads": loadset, "contact": contact, "rayleigh": tuple(args.rayleigh),
          "element": args.element}
    if args.method != "central":
        kw.update(beta=args.beta, gamma=args.gamma, alpha=args.hht_alpha)
    elif args.beta is not None or args.gamma is not None or args.hht_alpha:
        raise InputError("--beta, --gamma and --hht-alpha apply to the implicit methods, not to 'central'")
    integ = make_integrator(args.method, model, args.dt, **kw)
    J = _impulse_nodes(args, model, W, len(verts))
    if J is not None:
        integ.set_velocity_from_impulse(J)
    return integ


def record_xpbd(args, mesh, model, W, n_steps: int, every: int, progress: bool):
    """Run XPBD (:class:`sc_fem.xpbd.XPBDSolver`) and record the source-mesh vertices every
    ``every`` steps, as an :class:`sc_fem.integrators.Recording`."""
    import time

    from ..errors import InputError
    from ..integrators import Recording
    from ..xpbd import XPBDSolver
    from .common import fixed_nodes_from_args

    unsupported = [flag for flag, on in (
        ("--gust", args.gust is not None), ("--impulse", bool(args.impulse)), ("--ground", args.ground is not None),
        ("--sphere", args.sphere is not None), ("--box", args.box is not None), ("--rayleigh", any(args.rayleigh)),
        ("--hht-alpha", bool(args.hht_alpha)), ("--beta", args.beta is not None),
        ("--gamma", args.gamma is not None)) if on]
    if unsupported:
        raise InputError(f"--method xpbd supports gravity and --fix only, not {', '.join(unsupported)}")
    t0 = time.perf_counter()
    solver = XPBDSolver(model, args.dt, substeps=args.substeps, iterations=args.iterations,
                        constraints=args.constraints, gravity=(0.0, 0.0, -9.81) if args.gravity else (0.0, 0.0, 0.0),
                        fixed=fixed_nodes_from_args(args, model, mesh), damping=args.xpbd_damping)
    setup = time.perf_counter() - t0
    rest, X0 = np.asarray(mesh.vertices, dtype=float), model.nodes_m
    times, points, energy, mechanical = [], [], [], []
    t1 = time.perf_counter()
    for st in solver.run(n_steps, progress=progress):          # loop over time steps
        if st.step % every == 0 or st.step == n_steps:
            e = solver.energy(st)
            times.append(st.time)
            points.append(rest + (W @ (st.positions - X0)) / model.scale)
            energy.append(e.total)
            mechanical.append(e.mechanical)
    return Recording(times=np.array(times), u=np.zeros((0, model.n_nodes, 3)), energy=np.array(energy),
                     mechanical=np.array(mechanical), points=np.array(points), n_steps=n_steps,
                     seconds=time.perf_counter() - t1, setup_seconds=setup, method="xpbd", dt=args.dt,
                     info={"substeps": args.substeps, "iterations": args.iterations,
                           "constraints": args.constraints})


def write_xdmf(path: Path, rest: np.ndarray, faces: np.ndarray, times, positions) -> Path:
    """XDMF time series (XML data, no HDF5 needed): the rest mesh and point data ``displacement``
    (model units) per time; written atomically."""
    import meshio

    from .._atomic import atomic_path

    cells = [("triangle", np.asarray(faces, dtype=np.int64))] if len(faces) else \
        [("vertex", np.arange(len(rest), dtype=np.int64)[:, None])]
    with atomic_path(path, suffix=".xdmf") as tmp:
        with meshio.xdmf.TimeSeriesWriter(str(tmp), data_format="XML") as w:
            w.write_points_cells(np.asarray(rest, dtype=float), cells)
            for t, p in zip(times, positions):         # loop over frames
                w.write_data(float(t), point_data={"displacement": np.asarray(p, dtype=float) - rest})
    return path


def _write(out: Path, mesh, rec, meta: dict, magnify: float, fps: float, progress: bool) -> Path:
    from ..animfile import save_animation

    rest = np.asarray(mesh.vertices, dtype=float)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    kind = out.suffix.lower()
    if kind == ".npz":
        return save_animation(out, faces=faces, rest_vertices=rest, times=rec.times, positions=rec.points,
                              energy=rec.energy, meta=meta)
    if kind == ".xdmf":
        return write_xdmf(out, rest, faces, rec.times, rec.points)
    from ..render import render_animation

    frames = rest[None] + magnify * (rec.points - rest[None])
    title = f"{meta.get('source', '')} {meta['method']}" + (f" (x{magnify:g})" if magnify != 1 else "")
    return render_animation(frames, faces, out, fps=min(fps, 30.0), title=title, progress=progress)


def run(args) -> int:
    from .._validate import positive_scalar
    from ..embed import embed
    from ..errors import InputError
    from ..integrators import record
    from ..mesh import load_mesh
    out = Path(args.output)
    if out.suffix.lower() not in OUTPUTS:
        raise InputError(f"unsupported output {out.name!r}: use {', '.join(OUTPUTS)}")
    for name in ("duration", "dt", "fps", "magnify"):
        positive_scalar(getattr(args, name), f"--{name}")
    n_steps = int(round(args.duration / args.dt))
    if n_steps < 1:
        raise InputError(f"--duration {args.duration:g} s is shorter than one step of --dt {args.dt:g} s")
    every = max(1, int(round(1.0 / (args.fps * args.dt))))
    timings: dict = {}
    q = args.quiet
    with stage("load", timings, q):
        mesh = load_mesh(args.mesh)
    with stage("voxelize", timings, q):
        model = voxelize_from_args(args, mesh=mesh)
        W = embed(model, np.asarray(mesh.vertices, dtype=float))
    integ = None
    if args.method == "xpbd":
        with stage("simulate", timings, q):
            rec = record_xpbd(args, mesh, model, W, n_steps, every, progress=not (q or args.no_progress))
    else:
        with stage("setup", timings, q):
            integ = build(args, mesh, model, W)
        with stage("simulate", timings, q):
            rec = record(integ, n_steps, W=W, rest_points=np.asarray(mesh.vertices, float), scale=model.scale,
                         every=every, progress=not (q or args.no_progress), keep_u=False)
    dtc = integ.dt_crit if args.method == "central" else None
    meta = {"method": args.method, "dt": args.dt, "duration": args.duration, "n_steps": n_steps,
            "source": model.info.get("source", str(args.mesh)), "element": args.element,
            "material": model.info.get("material", ""), "gravity": bool(args.gravity), "ground": args.ground,
            "rayleigh": list(args.rayleigh), "hht_alpha": args.hht_alpha, "dt_crit": dtc,
            "scale": model.scale, "cubes": model.n_cubes, **rec.info}
    with stage("write", timings, q):
        _write(out, mesh, rec, meta, args.magnify, args.fps, progress=not (q or args.no_progress))
    if rec.energy_drift > ENERGY_GAIN_WARN and args.gust is None:
        # only a gust does work after t = 0 (impulses act at t = 0, damping and contact take energy out)
        print(f"sc-fem simulate: warning: the total energy grew by {100 * rec.energy_drift:.3g} % of the largest "
              f"kinetic + elastic energy with nothing feeding it: the run is not converged"
              + (" (use more --substeps)" if args.method == "xpbd" else " (reduce --dt)"), file=sys.stderr)
    if not q:
        print(model_summary(model))
        disp = np.linalg.norm(rec.points - rec.points[0], axis=2).max() if len(rec.points) else 0.0
        kind = (f"{args.substeps} substeps x {args.iterations} iterations, {args.constraints}" if integ is None
                else ("implicit" if integ.implicit else "explicit"))
        rows = [("method", f"{args.method} ({kind})"),
                ("steps", f"{n_steps:,} x {args.dt:g} s = {n_steps * args.dt:g} s ({len(rec.times)} frames)"),
                ("time per step", f"{1e3 * rec.seconds_per_step:.3g} ms (setup {rec.setup_seconds:.3g} s)"),
                ("energy drift", f"{rec.energy_drift:+.3e} of max(T + U) = {rec.mechanical.max():.4g} J"),
                ("max vertex displacement", f"{disp:.4g} model units")]
        if dtc is not None:
            rows.append(("dt / dt_crit", f"{args.dt / dtc:.3g} (dt_crit = {dtc:.4g} s)"))
        if integ is not None and integ.contact is not None:
            rows.append(("max contact depth", f"{max(rec.max_contact_depth, 0.0):.3g} model units "
                                              f"(tolerance {integ.contact.tol:.3g})"))
        w = max(len(k) for k, _ in rows)
        print("\n".join(f"  {k:<{w}}  {v}" for k, v in rows))
        print(f"wrote {out}")
    return 0


def demo_dynamics(out_dir, *, resolution: int = 16, quiet: bool = True) -> list[Path]:
    """Demo step: the built-in bridge under a lateral gust and gravity, settling on its supports.

    Writes ``bridge_gust.npz`` (true displacements) and ``bridge_gust.gif`` (displacements x2000, 10x slow motion)
    under ``out_dir`` and returns their paths (about 10--20 s)."""
    from .main import main

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    common = ["builtin:bridge", "--resolution", str(resolution), "--fix", "default", "--gravity",
              "--gust", "0", "2e7", "0", "0.02", "--duration", "0.5", "--dt", "0.001", "--rayleigh", "1.0", "2e-4",
              "--fps", "250", "--no-progress"] + (["--quiet"] if quiet else [])
    npz = out_dir / "bridge_gust.npz"
    rc = main(["simulate", *common, "-o", str(npz)])
    if rc != 0:
        print(f"demo_dynamics: sc-fem simulate failed (exit {rc})", file=sys.stderr)
        return []
    written = [npz]
    from ..animfile import load_animation
    from ..errors import RenderError
    from ..render import render_animation

    anim = load_animation(npz)
    frames = anim.rest_vertices[None] + 2000.0 * (anim.positions - anim.rest_vertices[None])
    try:
        written.append(render_animation(frames, anim.faces, out_dir / "bridge_gust.gif", fps=25,
                                        title="bridge: gust + gravity, Newmark (x2000, 10x slow motion)",
                                        window_size=(640, 400)))
    except RenderError as exc:
        print(f"demo_dynamics: no video ({exc})", file=sys.stderr)
    return written
