"""The automatic eigensolver choice against what each solver takes, on shapes users bring, in one run.

Usage: python benchmarks/auto_choice.py [--quick]

Per shape and resolution (free-free, 16 pairs: 10 elastic modes and the 6 rigid ones): both solvers
timed (``solve_eigen(method="shift-invert")`` with CHOLMOD, ``"lobpcg"`` with AMG), the time
:func:`sc_fem.fem.options.predicted_seconds` predicts for each, their ratio, and whether ``"auto"``
picked the faster one. The shapes: a cantilever (the calibration's own), the chair, the solid bunny
and spot, the armchair, a truss bridge in millimetres. A solver that fails is shown as such.
Prints a Markdown table and writes ``benchmarks/out/auto_choice.json`` and ``auto_choice.png``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from _common import SHARED_MESHES, out_path, print_table, save_figure

K_PAIRS = 16


def shapes(quick: bool):
    import sc_fem

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    import shapes as sh

    out = [("beam", sc_fem.load_mesh("builtin:beam"), (48, 96), 1.0), ("chair", sc_fem.load_mesh("builtin:chair"), (32, 64), 1.0)]
    for name, label, res in (("bunny.obj", "bunny", (32, 48)), ("spot.obj", "spot", (32, 48)),
                             ("chair_armchair.off", "armchair", (32, 64))):
        if (SHARED_MESHES / name).is_file():
            out.append((label, sc_fem.load_mesh(str(SHARED_MESHES / name)), res, 1.0))
    out.append(("truss (mm)", sh.truss_bridge_mm(), (64, 128), 1e-3))
    return [(a, b, c[:1] if quick else c, d) for a, b, c, d in out]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="one resolution per shape")
    args = ap.parse_args(argv)
    import sc_fem
    from sc_fem.fem.eigen import solve_eigen
    from sc_fem.fem.options import choose_method, predicted_seconds
    from sc_fem.fem.rigid import rigid_body_modes
    from sc_fem.fem.multigrid import lattice_aggregates
    from sc_fem.fem.static import node_parts

    rows, records = [], []
    for label, mesh, resolutions, scale in shapes(args.quick):
        for r in resolutions:
            model = sc_fem.voxelize(mesh, resolution=r, scale=scale)
            K, M = sc_fem.assemble(model)[:2]
            n = K.shape[0]
            rec = {"shape": label, "res": r, "dofs": n, "nnz": int(K.nnz)}
            for method in ("shift-invert", "lobpcg"):
                t0 = time.perf_counter()
                try:
                    lob = method == "lobpcg"           # the multigrid as sc_fem.modal sets it up
                    solve_eigen(K, M, K_PAIRS, method=method, near_null=rigid_body_modes(model.nodes_m) if lob else None,
                                aggregates=lattice_aggregates(model, node_parts(model), np.arange(n)) if lob else None)
                    rec[method] = time.perf_counter() - t0
                except sc_fem.SolverError as exc:
                    rec[method] = None
                    rec[method + "_error"] = str(exc)[:80]
                rec[method + "_predicted"] = predicted_seconds(method, n, K_PAIRS)
                print(f"  {label} r={r} {n} DOFs {method}: {rec[method]} s (predicted {rec[method + '_predicted']:.3g})",
                      file=sys.stderr, flush=True)
            rec["auto"] = choose_method(n, K.nnz, K_PAIRS)[0]
            records.append(rec)
            t_si, t_l = rec["shift-invert"], rec["lobpcg"]
            best = "shift-invert" if t_l is None or (t_si is not None and t_si <= t_l) else "lobpcg"
            ratio = lambda t, m: "failed" if t is None else f"{t / rec[m + '_predicted']:.2f}"  # noqa: E731
            rows.append([label, r, n, "failed" if t_si is None else f"{t_si:.2f}", f"{rec['shift-invert_predicted']:.2f}",
                         ratio(t_si, "shift-invert"), "failed" if t_l is None else f"{t_l:.2f}",
                         f"{rec['lobpcg_predicted']:.2f}", ratio(t_l, "lobpcg"), rec["auto"], best])
    print_table(["shape", "res", "DOFs", "SI [s]", "SI predicted", "SI taken/predicted", "LOBPCG [s]",
                 "LOBPCG predicted", "LOBPCG taken/predicted", "auto picks", "faster"], rows)
    out_path("auto_choice.json").write_text(json.dumps(records, indent=1))
    fig, ax = plt.subplots(figsize=(6.5, 5))
    for method, marker in (("shift-invert", "o"), ("lobpcg", "s")):
        pts = [(r[method + "_predicted"], r[method]) for r in records if r[method] is not None]
        if pts:
            ax.loglog(*np.array(pts).T, marker, label=method)
    lim = [0.05, 300]
    ax.loglog(lim, lim, "k-", lw=0.8, label="taken = predicted")
    ax.fill_between(lim, [v / 1.5 for v in lim], [v * 1.5 for v in lim], color="0.85", label="within 1.5x")
    ax.set(xlabel="predicted [s]", ylabel="taken [s]", title=f"eigensolver time, {K_PAIRS} pairs, free-free")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    save_figure(fig, "auto_choice.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
