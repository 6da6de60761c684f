"""Modal commands: ``precompute-modes`` (one mesh, or many on Dask), ``play`` and ``modes-sheet``.

``demo_modal(out_dir)`` is the modal part of ``sc-fem demo`` (chair with fixed feet: mode file,
mode sheet, a short playback GIF).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np

from .common import (add_element_arg, add_fix_args, add_grid_args, add_material_args, add_mesh_arg, add_up_arg, stage,
                     voxel_options)


def register(sub) -> None:
    p = sub.add_parser(
        "precompute-modes", help="compute vibration modes and bake them onto the mesh (.npz)",
        description="Voxelize MESH, compute its vibration modes, interpolate them onto the source mesh and "
                    "write a mode file (.npz, see the README). Several meshes (or a glob such as "
                    "'assets/*.obj') with -o FOLDER run as one Dask task per mesh (a local cluster, or "
                    "--scheduler ADDRESS) and write FOLDER/NAME.modes.npz plus FOLDER/summary.csv.")
    add_mesh_arg(p, many=True)
    p.add_argument("-o", "--output", required=True, help="mode file (.npz) for one mesh, or a folder for several")
    add_grid_args(p, auto=True)
    p.add_argument("--tolerance", type=float, default=None,
                   help="relative frequency agreement for --resolution auto (default 0.05)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--modes", "-k", type=int, default=None, help="number of elastic modes (default 10)")
    g.add_argument("--max-frequency", type=float, default=None, metavar="HZ",
                   help="all modes below this frequency (e.g. half the playback frame rate)")
    add_fix_args(p)
    add_element_arg(p)
    add_material_args(p)
    d = p.add_mutually_exclusive_group()
    d.add_argument("--damping", type=float, default=None, metavar="ZETA",
                   help="modal damping ratio of every mode (default 0.01)")
    d.add_argument("--rayleigh", type=float, nargs=2, default=None, metavar=("ALPHA", "BETA"),
                   help="Rayleigh damping C = ALPHA M + BETA K (ALPHA in 1/s, BETA in s)")
    p.add_argument("--lumped", action="store_true", help="lumped instead of consistent mass")
    p.add_argument("--keep-rigid", action="store_true", help="keep rigid-body modes (flagged) instead of removing them")
    p.add_argument("--keep-lattice", action="store_true", help="also store the lattice and the node modes")
    p.add_argument("--eigensolver", dest="eigensolver", choices=("auto", "shift-invert", "lobpcg"),
                   default="auto", help="default auto: the one predicted faster on this machine (shift-invert with "
                                        "a Cholesky factor below ~18k DOFs (~24k without numba), else LOBPCG + AMG) whose memory fits")
    p.add_argument("--backend", choices=("auto", "cholmod", "cholespy", "splu"), default="auto",
                   help="factorization backend for shift-invert (default: the fastest installed)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="batch: address of a running dask.distributed scheduler (default: a local cluster)")
    p.add_argument("--workers", type=int, default=None, help="batch: local workers (default: min(meshes, CPUs))")
    p.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    p.set_defaults(func=run_precompute)

    q = sub.add_parser("play", help="play a mode file back (exact damped modal oscillators)",
                       description="Play back a mode file: an impulse on a source vertex or one mode displaced, "
                                   "advanced by the exact solution of each damped modal oscillator. Writes "
                                   ".mp4, .gif or a folder of PNG frames; without -o opens a window when a "
                                   "display exists.")
    q.add_argument("modes", metavar="MODES", help="mode file (.npz) from precompute-modes")
    q.add_argument("--impulse", nargs=4, default=None, metavar=("VERTEX", "FX", "FY", "FZ"),
                   help="impulse (N s) on source vertex VERTEX")
    q.add_argument("--mode", type=int, default=None, help="displace this mode (default 0 when no --impulse)")
    q.add_argument("--amplitude", type=float, default=None,
                   help="largest vertex displacement of --mode, model units (default 5%% of the diagonal)")
    q.add_argument("--duration", type=float, default=2.0, help="seconds to play (default 2)")
    q.add_argument("--fps", type=float, default=30.0, help="frames per second (default 30)")
    q.add_argument("--exaggerate", type=float, default=1.0, help="multiply displacements for display (default 1)")
    q.add_argument("-o", "--output", default=None, help="out.mp4, out.gif or a folder for PNG frames")
    add_up_arg(q)
    q.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    q.set_defaults(func=run_play)

    s = sub.add_parser("modes-sheet", help="picture of the first mode shapes with their frequencies",
                       description="Write a PNG grid of the first mode shapes of a mode file.")
    s.add_argument("modes", metavar="MODES", help="mode file (.npz)")
    s.add_argument("-o", "--output", required=True, help="output .png")
    s.add_argument("--count", "-n", type=int, default=6, help="number of modes shown (default 6)")
    s.add_argument("--columns", type=int, default=None, help="panels per row (default 3)")
    add_up_arg(s)
    s.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    s.set_defaults(func=run_sheet)


# ---------------------------------------------------------------------------------------- precompute
def _modal_options(args) -> dict:
    """Keyword arguments of :func:`sc_fem.modal` from the command line (option objects built once here)."""
    from ..errors import InputError
    from ..fem.boundary import read_vertex_file
    from ..fem.eigen import EigenOptions
    from ..modes.options import AutoResolution, Damping, parse_resolution

    voxel = voxel_options(args)                        # holds --resolution N; "auto" is resolution=
    resolution = parse_resolution(args.resolution) if voxel.resolution is None else None
    if args.tolerance is not None:
        if not isinstance(resolution, AutoResolution):
            raise InputError("--tolerance applies to --resolution auto only")
        resolution = AutoResolution(tolerance=args.tolerance)
    damping = None
    if args.damping is not None or args.rayleigh is not None:
        damping = Damping(ratio=args.damping, rayleigh=None if args.rayleigh is None else tuple(args.rayleigh))
    return dict(resolution=resolution, voxel=voxel, n_modes=args.modes,
                max_frequency=args.max_frequency, element=args.element, lumped=args.lumped,
                keep_rigid=args.keep_rigid, keep_lattice=args.keep_lattice, damping=damping,
                eigen=EigenOptions(solver=args.eigensolver, backend=args.backend), fix=list(args.fix) or None,
                fix_vertices=read_vertex_file(args.fix_vertices) if args.fix_vertices else None)


def precompute_summary(basis, timings: dict) -> str:
    """Summary table of a precomputation: sizes, solver, time per stage, frequencies."""
    e = basis.eigen
    rows = [
        ("source", f"{basis.source}  (sha256 {basis.source_sha256[:12]})"),
        ("cubes / DOFs", f"{basis.n_cubes:,} / {basis.n_dofs:,}  (resolution {basis.resolution}, "
                         f"pitch {basis.pitch:.4g}, element {basis.element})"),
        ("size / mass", " x ".join(f"{e:.4g}" for e in np.ptp(basis.vertices, axis=0) * basis.scale)
         + f" m, {basis.material.get('mass', float('nan')):.6g} kg"),
        ("fixed", f"{basis.fix_record.get('n_nodes', 0)} nodes ({', '.join(basis.fix_record.get('specs', [])) or 'free'})"),
        ("eigensolver", f"{e.get('method', '')} / {e.get('backend', '')}: {e.get('reason', '')}; "
                        f"{e.get('passes', 1)} solve(s) on {e.get('setups', 1)} factorization/hierarchy"),
        ("rigid modes", f"{e.get('n_rigid_found', 0)} found, {basis.n_rigid_removed} removed"),
        ("modes", f"{basis.n_modes} on {basis.n_vertices:,} vertices, damping {basis.damping_spec}"),
    ]
    rows += [(f"time {k}", f"{v:.3f} s") for k, v in {**basis.timings, **timings}.items()
             if isinstance(v, (int, float))]
    w = max(len(k) for k, _ in rows)
    text = "\n".join(f"  {k:<{w}}  {v}" for k, v in rows)
    return text + "\n" + basis.summary()


def run_precompute(args) -> int:
    from ..modes.batch import expand_inputs

    meshes = expand_inputs(args.mesh)
    out = Path(args.output)
    batch = len(meshes) > 1 or out.is_dir() or args.output.endswith(("/", os.sep)) or args.scheduler
    if batch:
        return _run_batch(args, meshes, out)
    from ..errors import InputError

    if out.suffix.lower() != ".npz":
        raise InputError(f"the mode file must end in .npz, got {out.name!r} (give a folder ending in / for a batch)")
    from ..modes.auto import format_resolution_table
    from ..modes.modal import modal
    from ..io.modes import save_modes

    timings: dict = {}
    opts = _modal_options(args)                        # modal expands --fix default (the built-in's supports)
    with stage("load + voxelize + modes", timings, args.quiet):
        basis = modal(meshes[0], progress=not args.quiet, **opts)   # modal loads the mesh (and times it)
    with stage("write", timings, args.quiet):
        save_modes(basis, out)
    if not args.quiet:
        if basis.resolution_table:
            print("resolution auto:")
            print(format_resolution_table(basis.resolution_table))
        print(precompute_summary(basis, {"write": timings["write"]}))
        if basis.eigen.get("truncated"):
            print(f"warning: {basis.eigen['truncated']}", file=sys.stderr)
        print(f"wrote {out}")
    return 0


def _run_batch(args, meshes: list[str], out: Path) -> int:
    """The batch; Ctrl-C gives one line naming the mode files completed, and exit status 130."""
    from ..modes.batch import BatchInterrupted, run_batch

    opts = _modal_options(args)
    try:
        res = run_batch(meshes, out, options=opts, scheduler=args.scheduler, n_workers=args.workers,
                        progress=not args.quiet, expand=False)
    except BatchInterrupted as stop:
        done = (f"{len(stop.completed)} of {stop.n_meshes} mode files completed (complete and valid): "
                + ", ".join(map(str, stop.completed)) if stop.completed else
                f"none of the {stop.n_meshes} mode files was completed")
        print(f"sc-fem precompute-modes: interrupted; {done}; the others were not written; "
              f"summary {stop.summary}", file=sys.stderr)
        return 130
    if not args.quiet:
        w = max(len(Path(r["mesh"]).name) for r in res.rows)
        for r in res.rows:
            detail = (f"{r['cubes']} cubes, {r['n_modes']} modes, {r['f_min_hz']}..{r['f_max_hz']} Hz"
                      if r["status"] == "ok" else r["error"][:160])
            print(f"  {Path(r['mesh']).name:<{w}}  {r['status']:<5}  {float(r['seconds']):7.2f} s  {detail}")
        print(f"{res.n_ok} ok, {res.n_failed} failed in {res.seconds:.1f} s (scheduler {res.scheduler}); "
              f"summary {res.summary}")
    return 0 if res.n_failed == 0 else 1


# ---------------------------------------------------------------------------------------- play
def _player_from_args(args):
    import numpy as np

    from ..errors import InputError
    from ..modes.player import ModalPlayer

    player = ModalPlayer(args.modes)
    b = player.basis
    if args.impulse is not None:
        try:
            vertex = int(args.impulse[0])
            J = [float(x) for x in args.impulse[1:]]
        except ValueError:
            raise InputError(f"--impulse needs VERTEX FX FY FZ (an integer and three numbers), "
                             f"got {' '.join(args.impulse)}") from None
        player.impulse(vertex, J)
    if args.mode is not None or args.impulse is None:
        diag = float(np.linalg.norm(np.ptp(b.vertices, axis=0)))
        amp = 0.05 * diag if args.amplitude is None else args.amplitude
        player.excite(0 if args.mode is None else args.mode, amp)
    elif args.amplitude is not None:
        raise InputError("--amplitude needs --mode")
    return player


def run_play(args) -> int:
    import numpy as np

    from ..errors import InputError
    from ..io.render import render_animation

    player = _player_from_args(args)
    b = player.basis
    if args.output is None:
        if not os.environ.get("DISPLAY"):
            raise InputError("no display for an interactive window: give -o out.mp4, out.gif or a folder")
        return _interactive(player, args)
    frames = player.frames(args.duration, args.fps)
    if args.exaggerate != 1.0:
        frames = b.vertices[None] + args.exaggerate * (frames - b.vertices[None])
    from ..modes.player import playback_warnings

    for w in playback_warnings(b, frames, args.fps, args.exaggerate):
        print(f"sc-fem play: warning: {w}", file=sys.stderr)
    title = f"{b.source}: {b.n_modes} modes, {b.frequencies[0]:.3g}..{b.frequencies[-1]:.3g} Hz"
    path = render_animation(np.asarray(frames), b.faces, args.output, fps=args.fps, title=title,
                            progress=not args.quiet, times=np.arange(len(frames)) / args.fps, up=args.up)
    if not args.quiet:
        print(f"wrote {path} ({len(frames)} frames at {args.fps:g} fps)")
    return 0


def _interactive(player, args) -> int:  # pragma: no cover - needs a display
    import time

    import pyvista as pv

    from ..io.render import surface_polydata

    b = player.basis
    mesh = surface_polydata(b.vertices, b.faces)
    p = pv.Plotter(title="sc-fem play")
    p.add_mesh(mesh, color="#d9822b")
    p.show(interactive_update=True)
    dt = 1.0 / args.fps
    t_end = time.perf_counter() + args.duration
    while time.perf_counter() < t_end:
        mesh.points = b.vertices + args.exaggerate * (player.step(dt) - b.vertices)
        p.update()
        time.sleep(max(0.0, dt - 0.002))
    p.close()
    return 0


def run_sheet(args) -> int:
    from ..io.modes import load_modes
    from ..modes.player import modes_sheet

    basis = load_modes(args.modes)
    path = modes_sheet(basis, args.output, n_modes=args.count, columns=args.columns, up=args.up)
    if not args.quiet:
        print(f"wrote {path} ({min(args.count, basis.n_modes)} modes)")
    return 0


# ---------------------------------------------------------------------------------------- demo
def demo_modal(out_dir, *, resolution: int = 24, n_modes: int = 8) -> list[Path]:
    """Modal part of ``sc-fem demo``: the built-in chair with its feet fixed.

    Writes ``chair.modes.npz``, ``chair_modes_sheet.png`` and ``chair_play.gif`` (an impulse on
    the top of the backrest, 2 s at 15 fps) under ``out_dir``; returns the paths.
    """
    import numpy as np

    from ..geometry import models
    from ..modes.modal import modal
    from ..io.modes import save_modes
    from ..modes.player import ModalPlayer, modes_sheet
    from ..io.render import render_animation

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    basis = modal("builtin:chair", resolution=resolution, n_modes=n_modes, fix=list(models.fix_specs("chair")))
    print(f"chair modes: {basis.n_cubes} cubes, f = "
          + ", ".join(f"{f:.3g}" for f in basis.frequencies) + " Hz", file=sys.stderr)
    written = [save_modes(basis, out / "chair.modes.npz"),
               modes_sheet(basis, out / "chair_modes_sheet.png", n_modes=6)]
    player = ModalPlayer(basis)
    top = int(np.argmax(basis.vertices[:, 2]))                   # a vertex on the top of the backrest
    player.impulse(top, [2.0, 1.0, 0.0])
    frames = player.frames(2.0, 15.0)
    disp = frames - basis.vertices[None]
    peak = float(np.abs(disp).max())
    exaggerate = max(1.0, 0.04 * float(np.linalg.norm(np.ptp(basis.vertices, axis=0))) / max(peak, 1e-300))
    frames = basis.vertices[None] + exaggerate * disp
    written.append(render_animation(frames, basis.faces, out / "chair_play.gif", fps=15.0,
                                    title=f"chair: impulse on the backrest (x{exaggerate:.3g})",
                                    window_size=(480, 360), times=np.arange(len(frames)) / 15.0))
    return written
