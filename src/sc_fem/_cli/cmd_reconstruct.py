"""``sc-fem reconstruct``: PDE-based dynamic reconstruction of a vertex animation (Fang et al. 2024).

Fits the paper's Eq. 17 model and the static B-spline baseline at ``--fit-frames``, evaluates
both at every frame between the first and the last fitted frame, and writes the reconstructed
curves (and mesh vertices) to an ``.npz`` plus an optional Markdown report (E_A / E_M per frame,
timings, design-variable counts).

Curves: if the animation ``.npz`` holds a ``curves`` array (T, C, P, 3) it is used; otherwise
curves are extracted from the mesh (:func:`sc_fem.reconstruct.extract_curves`: ``--curves``
lines of ``--points`` vertices along the rest principal axis), and the mesh is rebuilt from the
reconstructed curves with an inverse-distance map (:func:`sc_fem.reconstruct.curve_mesh_map`).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from ..errors import InputError

RECON_KIND = "sc_fem.reconstruction"


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "reconstruct", help="PDE-based dynamic reconstruction of an animation from a few frames",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
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
    p.set_defaults(func=run)


def parse_frames(text: str, n_frames: int) -> np.ndarray:
    """``"0,2,4"`` -> array of >= 2 strictly increasing frame indices inside the animation."""
    from ..reconstruct.pde import check_frame_indices

    try:
        idx = np.array([int(v) for v in str(text).split(",") if v.strip() != ""], dtype=int)
    except ValueError:
        raise InputError(f"--fit-frames must be comma-separated integers, got {text!r}") from None
    return check_frame_indices(idx, n_frames, name="--fit-frames")


def markdown_report(frames, e_pde, e_bs, timings: dict, counts: dict, info: dict) -> str:
    """Markdown: per-frame E_A / E_M (mean / max over curves) for PDE and B-spline, then summary."""
    lines = ["| frame | fitted | PDE E_A | PDE E_M | B-spline E_A | B-spline E_M |",
             "|---:|:---:|---:|---:|---:|---:|"]
    for k, f in enumerate(frames):
        lines.append(f"| {f} | {'yes' if info['fitted'][k] else ''} | {e_pde.frame_E_A[k]:.6f} | "
                     f"{e_pde.frame_E_M[k]:.6f} | {e_bs.frame_E_A[k]:.6f} | {e_bs.frame_E_M[k]:.6f} |")
    lines += ["", f"mean E_A: PDE {e_pde.mean_E_A:.6f}, B-spline {e_bs.mean_E_A:.6f}; "
              f"max E_M: PDE {e_pde.max_E_M:.6f}, B-spline {e_bs.max_E_M:.6f}",
              "(E_A, E_M: paper Eqs. 26-27, per curve, normalised by the curve's diameter D; "
              "table: mean of E_A and max of E_M over the curves)", "",
              "| quantity | value |", "|---|---:|"]
    lines += [f"| {k} | {v} |" for k, v in {**info["fit"], **timings, **counts}.items()]
    return "\n".join(lines) + "\n"


def run(args) -> int:
    from .. import reconstruct as rec
    from .._atomic import atomic_path, save_npz_atomic
    from ..io.animation import load_animation

    path = Path(args.animation)
    anim = load_animation(path)
    fit_idx = parse_frames(args.fit_frames, anim.n_frames)
    frames = np.arange(fit_idx[0], fit_idx[-1] + 1)
    curves = anim.curves
    idx = None
    if curves is None:
        idx = rec.extract_curves(anim.rest_vertices, args.curves, args.points)
        curves = anim.positions[:, idx].astype(np.float64)                # (T, C, P, 3)
    times = np.asarray(anim.times, dtype=float)

    t0 = time.perf_counter()
    model = rec.fit(curves[fit_idx], times[fit_idx], r=args.r, alpha=args.alpha,
                    remove_rigid=not args.no_rigid, parametrization=args.parametrization,
                    rigid_interpolation=args.rigid_interpolation, criterion=args.criterion)
    pde_curves = model.evaluate(times[frames])
    t_pde = time.perf_counter() - t0
    t0 = time.perf_counter()
    bs = rec.bspline_baseline(curves, times, fit_idx, n_control=min(args.n_control, curves.shape[2]))
    bs_curves = bs.evaluate(times[frames])
    t_bs = time.perf_counter() - t0
    ref = curves[frames]
    e_pde, e_bs = rec.errors(ref, pde_curves), rec.errors(ref, bs_curves)

    out = dict(format_version=np.int64(1), kind=np.str_(RECON_KIND), frames=frames, times=times[frames],
               fit_frames=fit_idx, curves_reference=ref, curves_pde=pde_curves, curves_bspline=bs_curves,
               E_A_pde=e_pde.E_A, E_M_pde=e_pde.E_M, E_A_bspline=e_bs.E_A, E_M_bspline=e_bs.E_M,
               r=np.float64(model.r), alpha=np.float64(model.alpha), coefficients=model.coefficients,
               u=model.u, faces=anim.faces)
    info = {"fitted": np.isin(frames, fit_idx),
            "fit": {"curves x points": f"{curves.shape[1]} x {curves.shape[2]}"
                                       + (" (extracted)" if idx is not None else " (stored)"),
                    "r": f"{model.r:.4g}", "alpha": f"{model.alpha:.4g}",
                    "parametrization": model.parametrization}}
    if idx is not None:
        f0 = fit_idx[0]
        w = rec.curve_mesh_map(curves[f0], anim.positions[f0], k=4)
        verts = rec.mesh_vertices(model, times[frames], w, curves[f0], anim.positions[f0])
        diag = float(np.linalg.norm(np.ptp(anim.rest_vertices, axis=0)))
        mesh_err = np.linalg.norm(verts - anim.positions[frames], axis=-1).mean(axis=1) / diag
        out.update(curve_vertex_index=idx, vertices_pde=verts.astype(np.float32), mesh_error_pde=mesh_err)
        info["fit"]["mesh mean vertex error / bbox diagonal (PDE, max over frames)"] = f"{mesh_err.max():.6f}"
    timings = {"PDE fit + evaluation (s)": f"{t_pde:.3f}", "B-spline fit + evaluation (s)": f"{t_bs:.3f}"}
    counts = {"PDE scalars (coefficients + r, alpha + rigid)": model.n_parameters,
              "PDE constants, paper's count (32 per curve)": 32 * model.n_curves,
              "B-spline scalars": bs.n_parameters, "B-spline control points (paper's count)": bs.n_control_points,
              "reference scalars (curve points x 3 x frames)": int(ref.size)}
    out["meta_json"] = np.str_(json.dumps({"source": str(path), "timings_s": {"pde": t_pde, "bspline": t_bs},
                                           "counts": counts, "criterion": args.criterion,
                                           "rigid_interpolation": args.rigid_interpolation,
                                           "remove_rigid": not args.no_rigid}))
    save_npz_atomic(args.output, **out)
    if args.report:
        report = markdown_report(frames, e_pde, e_bs, timings, counts, info)
        with atomic_path(args.report) as tmp:
            tmp.write_text(report)
    print(f"PDE: mean E_A {e_pde.mean_E_A:.6f}, max E_M {e_pde.max_E_M:.6f} (r={model.r:.4g}, "
          f"alpha={model.alpha:.4g}); B-spline: mean E_A {e_bs.mean_E_A:.6f}, max E_M {e_bs.max_E_M:.6f}; "
          f"wrote {args.output}")
    return 0
