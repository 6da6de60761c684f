"""The automatic eigensolver choice against what each solver takes, on shapes users bring, in one run.

Usage: python benchmarks/auto_choice.py [--quick | --larger] [--repeat R] [--only NAME ...]

Per shape and resolution (free-free, 16 pairs: 10 elastic modes and the 6 rigid ones): the fill
analysis of ``K - sigma M`` (:func:`sc_fem.fem.options.fill_analysis`, CHOLMOD's ordering and the
column counts of ``L``), the times :func:`sc_fem.fem.options.predicted_seconds` predicts from it
(shift-invert; also the power law in ``n`` alone, the prediction before the fill analysis) and for
LOBPCG, then both solvers timed ``R`` times each, interleaved (``solve_eigen(method="shift-invert")``
with CHOLMOD, ``"lobpcg"`` with the lattice multigrid as ``sc_fem.modal`` sets it up): the median,
the spread (min-max), taken / predicted, which one ``"auto"`` picks and whether it was the faster.
The shapes: compact solids (a cantilever, the bunny, spot), thin-walled ones (the chair, the
armchair, a plate, an I-beam, a truss bridge in millimetres, the cable-stayed bridge) and many parts
(the toy truck). Prints a Markdown table and the machine's load, writes
``benchmarks/out/auto_choice.json`` and ``auto_choice.png`` (copied to ``docs/``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from _common import SHARED_MESHES, out_path, print_table, save_figure

K_PAIRS = 16
DOCS = Path(__file__).resolve().parents[1] / "docs"


def shapes(quick: bool, larger: bool = False):
    """``(label, kind, mesh, resolutions, scale)``: each shape at two resolutions, the first with
    ``quick``, the second with ``larger``."""
    import sc_fem

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    import shapes as sh

    out = [("beam", "compact", sc_fem.load_mesh("builtin:beam"), (48, 96), 1.0)]
    for name, label, kind, res in (("bunny.obj", "bunny", "compact", (32, 40)), ("spot.obj", "spot", "compact", (32, 40)),
                                   ("chair_armchair.off", "armchair", "thin", (32, 64))):
        if (SHARED_MESHES / name).is_file():
            out.append((label, kind, sc_fem.load_mesh(str(SHARED_MESHES / name)), res, 1.0))
    out += [("chair", "thin", sc_fem.load_mesh("builtin:chair"), (32, 64), 1.0),
            ("plate", "thin", sh.plate(), (128, 192), 1.0), ("I-beam", "thin", sh.i_beam(), (128, 192), 1.0),
            ("truss (mm)", "thin", sh.truss_bridge_mm(), (64, 128), 1e-3),
            ("bridge", "thin, many parts", sc_fem.load_mesh("builtin:bridge"), (96, 128), 1.0),
            ("toy truck", "many parts", sh.toy_truck(), (64, 96), 1.0)]
    return [(a, b, c, d[:1] if quick else d[1:] if larger else d, e) for a, b, c, d, e in out]


def _timed(fn, info: dict) -> float | None:
    """Seconds ``fn()`` takes (None when it fails); its result's ``info`` goes into ``info``."""
    import sc_fem

    t0 = time.perf_counter()
    try:
        info.update(fn().info)
    except sc_fem.SolverError as exc:
        print(f"    failed: {str(exc)[:100]}", file=sys.stderr)
        info["error"] = str(exc)[:200]
        return None
    return time.perf_counter() - t0


def measure(label: str, kind: str, mesh, r: int, scale: float, repeat: int) -> dict:
    """One shape at one resolution: the predictions, and both solvers timed ``repeat`` times."""
    import sc_fem
    from sc_fem.fem.eigen import SHIFT_FRACTION, lambda_scale, shifted, solve_eigen
    from sc_fem.fem.multigrid import lattice_aggregates
    from sc_fem.fem.options import choose_method, fill_analysis, predicted_seconds
    from sc_fem.fem.rigid import rigid_body_modes
    from sc_fem.fem.static import node_parts

    model = sc_fem.voxelize(mesh, resolution=r, scale=scale)
    K, M = sc_fem.assemble(model)[:2]
    n = K.shape[0]
    analysis = fill_analysis(shifted(K, M, -SHIFT_FRACTION * lambda_scale(K, M)))
    rec = {"shape": label, "kind": kind, "res": r, "dofs": n, "nnz": int(K.nnz), "load": os.getloadavg()[0],
           "nnz_l": analysis.nnz_l if analysis else None, "gflop": analysis.flops / 1e9 if analysis else None,
           "analysis_s": analysis.seconds if analysis else None,
           "shift-invert_predicted": predicted_seconds("shift-invert", n, K_PAIRS, analysis),
           "shift-invert_power_law": predicted_seconds("shift-invert", n, K_PAIRS),
           "lobpcg_predicted": predicted_seconds("lobpcg", n, K_PAIRS, analysis),
           "lobpcg_power_law": predicted_seconds("lobpcg", n, K_PAIRS),
           "auto": choose_method(n, K.nnz, K_PAIRS, None, analysis)[0],
           "auto_power_law": choose_method(n, K.nnz, K_PAIRS)[0]}
    del analysis
    runs = {"shift-invert": [], "lobpcg": []}
    near_null, agg = rigid_body_modes(model.nodes_m), lattice_aggregates(model, node_parts(model), np.arange(n))
    info = {}
    for _ in range(repeat):                                   # interleaved: both see the same load
        runs["shift-invert"].append(_timed(lambda: solve_eigen(K, M, K_PAIRS, method="shift-invert"), {}))
        runs["lobpcg"].append(_timed(lambda: solve_eigen(K, M, K_PAIRS, method="lobpcg", near_null=near_null,
                                                         aggregates=agg), info))
    rec["lobpcg_iterations"], rec["lobpcg_error"] = info.get("iterations"), info.get("error")
    for m, ts in runs.items():
        ok = [t for t in ts if t is not None]
        rec[m] = float(np.median(ok)) if ok else None
        rec[m + "_runs"] = ts
    rec["load_after"] = os.getloadavg()[0]
    print(f"  {label} r={r} {n:,} DOFs: SI {rec['shift-invert']} (pred {rec['shift-invert_predicted']:.3g}), "
          f"LOBPCG {rec['lobpcg']} (pred {rec['lobpcg_predicted']:.3g}), load {rec['load']:.1f}",
          file=sys.stderr, flush=True)
    return rec


def repredict(rec: dict) -> dict:
    """An earlier run's record with the predictions and choice of the current model (from its stored fill)."""
    from sc_fem.fem.fill import FillAnalysis
    from sc_fem.fem.options import choose_method, predicted_seconds

    n = rec["dofs"]
    a = (FillAnalysis(n=n, nnz_l=rec["nnz_l"], flops=rec["gflop"] * 1e9, seconds=rec["analysis_s"])
         if rec["nnz_l"] else None)
    return {**rec, "shift-invert_predicted": predicted_seconds("shift-invert", n, K_PAIRS, a),
            "lobpcg_predicted": predicted_seconds("lobpcg", n, K_PAIRS, a),
            "auto": choose_method(n, rec["nnz"], K_PAIRS, None, a)[0]}


def _cell(rec: dict, m: str) -> str:
    ok = [t for t in rec[m + "_runs"] if t is not None]
    if not ok:
        return "failed"
    spread = f" ({min(ok):.2f}-{max(ok):.2f})" if len(ok) > 1 else ""
    return f"{rec[m]:.2f}{spread} / {rec[m + '_predicted']:.2f} s ({rec[m] / rec[m + '_predicted']:.2f}x)"


def table(records: list[dict]) -> None:
    """The Markdown table: per shape both solvers taken (median, spread) / predicted, and the choice."""
    rows = []
    for rec in records:
        t_si, t_l = rec["shift-invert"], rec["lobpcg"]
        best = "shift-invert" if t_l is None or (t_si is not None and t_si <= t_l) else "lobpcg"
        old = rec["shift-invert"] / rec["shift-invert_power_law"] if t_si is not None else float("nan")
        rows.append([rec["shape"], rec["kind"], rec["res"], f"{rec['dofs']:,}", _cell(rec, "shift-invert"),
                     f"{old:.2f}x", _cell(rec, "lobpcg"), rec["lobpcg_iterations"] or "-", rec["auto"], best, "yes" if rec["auto"] == best else "**no**",
                     "yes" if rec["auto_power_law"] == best else "no", f"{rec['load']:.1f}-{rec['load_after']:.1f}"])
    print_table(["shape", "kind", "res", "DOFs", "shift-invert taken / predicted", "power law: taken/pred",
                 "LOBPCG taken / predicted", "LOBPCG its", "auto picks", "faster", "right?", "power law right?", "load"], rows)


def chart(records: list[dict]) -> None:
    """Taken against predicted, both methods (and shift-invert by the power law, hollow)."""
    fig, ax = plt.subplots(figsize=(6.5, 5))
    for key, m, marker, fc, lab in (("shift-invert_predicted", "shift-invert", "o", None, "shift-invert (fill)"),
                                    ("shift-invert_power_law", "shift-invert", "o", "none", "shift-invert (power law, before)"),
                                    ("lobpcg_predicted", "lobpcg", "s", None, "LOBPCG")):
        pts = np.array([(r[key], r[m]) for r in records if r[m] is not None])
        if len(pts):
            ax.loglog(pts[:, 0], pts[:, 1], marker, mfc=fc, color="C1" if m == "lobpcg" else "C0", label=lab)
    lim = [0.1, 300]
    ax.loglog(lim, lim, "k-", lw=0.8, label="taken = predicted")
    ax.fill_between(lim, [v / 1.5 for v in lim], [v * 1.5 for v in lim], color="0.88", label="within 1.5x")
    ax.set(xlabel="predicted [s]", ylabel="taken [s] (median)", title=f"eigensolver time, {K_PAIRS} pairs, free-free")
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    path = save_figure(fig, "auto_choice.png")
    if DOCS.is_dir():
        shutil.copyfile(path, DOCS / "auto_choice.png")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="the first (coarser) resolution of each shape only")
    ap.add_argument("--larger", action="store_true", help="the second (finer) resolution of each shape only")
    ap.add_argument("--out", default="auto_choice.json", help="JSON file written into benchmarks/out/")
    ap.add_argument("--repeat", type=int, default=2, help="timed runs of each solver (median and spread)")
    ap.add_argument("--only", nargs="*", help="shape labels to run (default all)")
    ap.add_argument("--from-json", nargs="+", help="print the table and chart of earlier runs' JSON files "
                    "with the current model's predictions (from their stored fill), measure nothing")
    args = ap.parse_args(argv)
    print(f"uptime: {os.popen('uptime').read().strip()}")
    if args.from_json:
        records = [repredict(rec) for f in args.from_json for rec in json.loads(Path(f).read_text())]
    else:
        records = [measure(label, kind, mesh, r, scale, args.repeat)
                   for label, kind, mesh, resolutions, scale in shapes(args.quick, args.larger)
                   if not args.only or label in args.only for r in resolutions]
        out_path(args.out).write_text(json.dumps(records, indent=1))
    table(records)
    print(f"uptime: {os.popen('uptime').read().strip()}")
    chart(records)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
