"""The automatic eigensolver choice against what each solver takes, on shapes users bring, in one run.

Usage: python benchmarks/auto_choice.py [--quick | --larger | --unseen | --fresh] [--repeat R] [--only NAME ...]
       python benchmarks/auto_choice.py --from-json out/FILE.json ... [--loo] [--fit]

Per shape and resolution (free-free, 16 pairs: 10 elastic modes and the 6 rigid ones; the held
cantilever 6 pairs): the fill analysis of ``K - sigma M`` (:func:`sc_fem.fem.options.fill_analysis`,
CHOLMOD's ordering and the column counts of ``L``), the times
:func:`sc_fem.fem.options.predicted_seconds` predicts from it for shift-invert (also the power law
in ``n`` alone, the prediction before the fill analysis) and LOBPCG (and LOBPCG's iterations), then
both solvers timed ``R`` times each, interleaved (``solve_eigen(method="shift-invert")`` with
CHOLMOD, ``"lobpcg"`` with the lattice multigrid as ``sc_fem.modal`` sets it up): the median, the
spread (min-max), taken / predicted, which one ``"auto"`` picks and whether it was the faster, each
run's stages (set-up, solve, Rayleigh--Ritz) and iterations. The shapes: compact solids (the
beam, the bunny, spot, the held cantilever of ``modes_speed.py``), thin-walled ones (the chair,
the armchair, a plate, an I-beam, a truss bridge in millimetres, the cable-stayed bridge) and many
parts (the toy truck). Prints a Markdown table, the counts within 1.5x, the repeats' spread and the
machine's load, writes ``benchmarks/out/auto_choice.json`` (``--out``) and ``auto_choice.png``
(copied to ``docs/``). ``--from-json`` re-predicts stored runs with the current model, and
``--fit`` fits LOBPCG's model (:data:`sc_fem.fem.fill.LOBPCG_FILL_MODEL`) to them (:func:`fit`),
``--loo`` predicts each shape with the iteration constants fitted without it (:func:`leave_one_out`);
LOBPCG's own forecast at its first progress check (iteration 20) is printed against the iterations it
took. ``--unseen`` times seven shapes no fit has used (:func:`unseen_shapes`), ``--fresh`` fifteen more
(:func:`fresh_shapes`).
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

from _common import OUT, SHARED_MESHES, out_path, print_table, save_figure

K_PAIRS = 16
CANTILEVER = "cantilever"
"""The 4 m x 1 m x 1 m bar of ``benchmarks/modes_speed.py``, one end held, 6 elastic pairs (the
speed target's model: 139,656 free DOFs at resolution 88), the other shapes free-free, 16 pairs."""
DOCS = Path(__file__).resolve().parents[1] / "docs"


def shapes(quick: bool, larger: bool = False):
    """``(label, kind, mesh, resolutions, scale)``: each shape at two resolutions, the first with
    ``quick``, the second with ``larger``. The held cantilever (:data:`CANTILEVER`) is solved for its
    own pairs."""
    import sc_fem
    import trimesh

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
    bar = trimesh.creation.box(extents=(4.0, 1.0, 1.0))
    bar.apply_translation((2.0, 0.5, 0.5))
    out.append((CANTILEVER, "compact, held", bar, (88, 48), 1.0))       # 139,656 and 24,336 free DOFs
    return [(a, b, c, d[:1] if quick else d[1:] if larger else d, e) for a, b, c, d, e in out]


def unseen_shapes():
    """Shapes no fit of :data:`sc_fem.fem.fill.LOBPCG_FILL_MODEL` has used (``--unseen``), one resolution
    each: three compact scans (the dragon, a knot, the teapot of 2 parts) and four of slender or
    thin members (a table, a portal frame, a slatted chair, a channel section)."""
    import sc_fem

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    import shapes as sh

    out = [(label, "compact", sc_fem.load_mesh(str(SHARED_MESHES / name)), (r,), 1.0)
           for name, label, r in (("dragon_lowres.obj", "dragon", 48), ("knot.obj", "knot", 64),
                                  ("teapot.obj", "teapot", 48)) if (SHARED_MESHES / name).is_file()]
    return out + [("table", "thin", sh.table(), (64,), 1.0), ("portal frame", "thin", sh.portal_frame(), (96,), 1.0),
                  ("slatted chair", "thin", sh.slatted_chair(), (64,), 1.0), ("channel", "thin", sh.channel(), (128,), 1.0)]


def fresh_shapes():
    """A second set of shapes no fit has used (``--fresh``), chosen after every fit and the
    :func:`unseen_shapes` runs: a rope and a toy bridge (the public meshes no other set takes), two
    plates 5 mm apart, two boxes 1 mm apart (two parts each), an open sheet, the bunny in millimetres
    with y up, and shapes of the other sets at resolutions no run has used."""
    import sc_fem

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
    import shapes as sh

    def scan(name):
        return sc_fem.load_mesh(str(SHARED_MESHES / name)) if (SHARED_MESHES / name).is_file() else None

    out = [(label, kind, scan(name), (r,), 1.0) for name, label, kind, r in (
        ("rope.obj", "rope", "thin", 64), ("bridge_toy_openscad.stl", "toy bridge", "thin, many parts", 64),
        ("dragon_lowres.obj", "dragon", "compact", 64), ("knot.obj", "knot", "compact", 48),
        ("teapot.obj", "teapot", "compact", 64), ("bunny.obj", "bunny", "compact", 48))]
    bunny = scan("bunny.obj")
    if bunny is not None:
        out.append(("bunny (mm, y up)", "compact", sh.to_millimetres(sh.y_up(bunny)), (36,), 1e-3))
    return [s for s in out if s[2] is not None] + [
        ("two plates", "thin, many parts", sh.two_plates(), (96,), 1.0), ("table", "thin", sh.table(), (96,), 1.0),
        ("portal frame", "thin", sh.portal_frame(), (64,), 1.0), ("slatted chair", "thin", sh.slatted_chair(), (48,), 1.0),
        ("open sheet", "thin", sh.open_sheet(), (96,), 1.0), ("boxes 1 mm apart", "many parts", sh.near_touching_boxes(), (48,), 1.0),
        ("channel", "thin", sh.channel(), (96,), 1.0), ("chair", "thin", sc_fem.load_mesh("builtin:chair"), (48,), 1.0)]


def _timed(fn, info: dict, parts: list) -> float | None:
    """Seconds ``fn()`` takes (None when it fails); its result's ``info`` goes into ``info``, and its
    stages (set-up, solve, Rayleigh--Ritz, s) with LOBPCG's iterations and rounds are appended to ``parts``."""
    import sc_fem

    t0 = time.perf_counter()
    try:
        res = fn()
    except sc_fem.SolverError as exc:
        print(f"    failed: {str(exc)[:100]}", file=sys.stderr)
        info["error"] = str(exc)[:200]
        parts.append(None)
        return None
    took = time.perf_counter() - t0
    info.update(res.info)
    parts.append({**{s: float(v) for s, v in res.seconds.items()}, "total": took,
                  **{f: res.info[f] for f in ("iterations", "rounds", "levels") if f in res.info}})
    return took


def measure(label: str, kind: str, mesh, r: int, scale: float, repeat: int) -> dict:
    """One shape at one resolution: the predictions, and both solvers timed ``repeat`` times."""
    import sc_fem
    from sc_fem.fem.assemble import Assembler
    from sc_fem.fem.eigen import SHIFT_FRACTION, EigenSolver, lambda_scale, shifted, solve_eigen
    from sc_fem.fem.fill import lobpcg_block, lobpcg_iterations
    from sc_fem.fem.multigrid import lattice_aggregates
    from sc_fem.fem.options import choose_method, fill_analysis, predicted_seconds
    from sc_fem.fem.rigid import loose_start, rigid_body_modes
    from sc_fem.fem.static import node_parts

    model = sc_fem.voxelize(mesh, resolution=r, scale=scale)
    k, free = (6, None) if label == CANTILEVER else (K_PAIRS, np.arange(3 * model.n_nodes))
    if free is None:                                          # one end held
        from sc_fem.lattice.boundary import fixed_dofs, fixed_nodes

        asm = Assembler(model, "q1i", fixed_dofs=fixed_dofs(fixed_nodes(model, "x<min+1e-9")))
        K, M, free = asm.stiffness(), asm.mass(), asm.free_dofs
    else:
        K, M = sc_fem.assemble(model)[:2]
    n = K.shape[0]
    analysis = fill_analysis(shifted(K, M, -SHIFT_FRACTION * lambda_scale(K, M)))
    rec = {"shape": label, "kind": kind, "res": r, "dofs": n, "nnz": int(K.nnz), "k": k, "block": lobpcg_block(k),
           "load": os.getloadavg()[0], "nnz_l": analysis.nnz_l if analysis else None,
           "gflop": analysis.flops / 1e9 if analysis else None, "analysis_s": analysis.seconds if analysis else None,
           "shift-invert_predicted": predicted_seconds("shift-invert", n, k, analysis),
           "shift-invert_power_law": predicted_seconds("shift-invert", n, k),
           "lobpcg_predicted": predicted_seconds("lobpcg", n, k, analysis),
           "lobpcg_power_law": predicted_seconds("lobpcg", n, k),
           "lobpcg_iterations_predicted": lobpcg_iterations(analysis) if analysis else None,
           "auto": choose_method(n, K.nnz, k, None, analysis)[0],
           "auto_power_law": choose_method(n, K.nnz, k)[0]}
    del analysis
    runs = {"shift-invert": [], "lobpcg": []}
    parts = {"shift-invert": [], "lobpcg": []}
    near_null = rigid_body_modes(model.nodes_m, free)
    labels = node_parts(model)
    agg = lattice_aggregates(model, labels, free)
    # loose parts start from their own rigid motions, as sc_fem.modal starts them
    start = loose_start(model.nodes_m, labels, np.arange(labels.max() + 1), lobpcg_block(k), free)
    info = {}
    for _ in range(repeat):                                   # interleaved: both see the same load
        runs["shift-invert"].append(_timed(lambda: solve_eigen(K, M, k, method="shift-invert"), {},
                                           parts["shift-invert"]))
        runs["lobpcg"].append(_timed(lambda: EigenSolver(K, M, method="lobpcg", near_null=near_null, start=start,
                                                         aggregates=agg).solve(k), info, parts["lobpcg"]))
    rec["shift-invert_parts"], rec["lobpcg_parts"] = parts["shift-invert"], parts["lobpcg"]
    rec["lobpcg_iterations"], rec["lobpcg_error"] = info.get("iterations"), info.get("error")
    rec["lobpcg_forecasts"] = info.get("forecasts")           # LOBPCG's own, at its progress checks
    for m, ts in runs.items():
        ok = [t for t in ts if t is not None]
        rec[m] = float(np.median(ok)) if ok else None
        rec[m + "_runs"] = ts
    rec["load_after"] = os.getloadavg()[0]
    print(f"  {label} r={r} {n:,} DOFs: SI {rec['shift-invert']} (pred {rec['shift-invert_predicted']:.3g}), "
          f"LOBPCG {rec['lobpcg']} (pred {rec['lobpcg_predicted']:.3g}), load {rec['load']:.1f}",
          file=sys.stderr, flush=True)
    return rec


def _analysis(rec: dict):
    """The stored fill of a record as a :class:`~sc_fem.fem.fill.FillAnalysis` (None without one)."""
    from sc_fem.fem.fill import FillAnalysis

    return (FillAnalysis(n=rec["dofs"], nnz_l=rec["nnz_l"], flops=rec["gflop"] * 1e9, seconds=rec["analysis_s"])
            if rec["nnz_l"] else None)


def repredict(rec: dict) -> dict:
    """An earlier run's record with the predictions and choice of the current model (from its stored fill)."""
    from sc_fem.fem.fill import lobpcg_iterations
    from sc_fem.fem.options import choose_method, predicted_seconds

    n, k, a = rec["dofs"], rec.get("k", K_PAIRS), _analysis(rec)
    return {**rec, "shift-invert_predicted": predicted_seconds("shift-invert", n, k, a),
            "lobpcg_predicted": predicted_seconds("lobpcg", n, k, a),
            "lobpcg_iterations_predicted": lobpcg_iterations(a) if a else None,
            "auto": choose_method(n, rec["nnz"], k, None, a)[0]}


def fit(records: list[dict]) -> dict:
    """Fit :data:`sc_fem.fem.fill.LOBPCG_FILL_MODEL` to the LOBPCG runs of ``records`` (every converged
    run, each record's fill) in three steps, each on what it predicts:

    1. set-up: the runs' set-up + Rayleigh--Ritz seconds against ``n``, least squares (non-negative);
    2. one iteration: the solve's seconds / iterations against the block's entries ``e = n * block``,
       ``c * e * (e / 1e6) ** gamma``, least squares in log-log;
    3. iterations (which the load does not change): a compact solid's ``iterations``, ``q0`` and
       ``beta`` by least squares of log(iterations taken / predicted) over the shapes (``cap`` kept).

    Prints each step and returns the fitted constants (also set in the model for the table)."""
    from scipy.optimize import nnls

    from sc_fem.fem import fill

    runs = [(r, p) for r in records for p in r.get("lobpcg_parts") or [] if p]
    n = np.array([r["dofs"] for r, _ in runs], float)
    setup = np.array([p["setup"] + p["rayleigh_ritz"] for _, p in runs])
    (a, b), _ = nnls(np.column_stack([np.ones_like(n), n]), setup)
    e = n * np.array([r.get("block", 20) for r, _ in runs], float)
    per_it = np.array([p["solve"] / p["iterations"] for _, p in runs])
    g, lc = np.polyfit(np.log(e / 1e6), np.log(per_it / e), 1)
    model = fill.LOBPCG_FILL_MODEL
    model.update(setup=float(a), setup_per_dof=float(b), c=float(np.exp(lc)), gamma=float(g))
    print(f"1. set-up {a:.3g} s + {b:.3g} s/DOF; residual {np.ptp(np.log(setup / (a + b * n))):.2f} (log range)")
    print(f"2. one iteration: {np.exp(lc):.3g} s x e x (e / 1e6)^{g:.3f}; per-run ratios "
          f"{np.round(per_it / (np.exp(lc) * e * (e / 1e6) ** g), 2).tolist()}")
    done = _converged(records)
    x, rms = _fit_iterations(done)
    print(f"3. iterations: a compact solid's {x[0]:.3g}, q0 {x[1]:.3g}, beta {x[2]:.3g}; "
          f"rms log(iterations taken / predicted) {rms:.3f} over {len(done)} shapes")
    return dict(model)


def _converged(records: list[dict]) -> list[dict]:
    """One record per (shape, resolution) whose LOBPCG converged and whose fill is known."""
    return list({(r["shape"], r["res"]): r for r in records if r["lobpcg_iterations"] and r["nnz_l"]}.values())


def _fit_iterations(done: list[dict]) -> tuple[np.ndarray, float]:
    """Fit the model's three iteration constants (``iterations``, ``q0``, ``beta``; set in the model)
    to ``done`` by least squares of log(iterations taken / predicted); returns them and the rms."""
    from scipy.optimize import minimize

    from sc_fem.fem import fill

    model = fill.LOBPCG_FILL_MODEL
    taken = np.array([r["lobpcg_iterations"] for r in done], float)

    def err(x):
        model.update(iterations=x[0], q0=x[1], beta=x[2])
        pred = np.array([fill.lobpcg_iterations(_analysis(r)) for r in done])
        return float(np.sum(np.log(taken / pred) ** 2))

    x = minimize(err, [model["iterations"], model["q0"], model["beta"]], method="Nelder-Mead",
                 options={"xatol": 1e-3, "fatol": 1e-6}).x
    return x, float(np.sqrt(err(x) / len(done)))


def leave_one_out(records: list[dict]) -> None:
    """Leave-one-shape-out: LOBPCG's iteration constants refitted without each shape, then that
    shape's iterations and seconds predicted (the set-up and per-iteration law as stored); prints
    each run and how many are within 1.5x. The model's constants are restored afterwards."""
    from sc_fem.fem import fill
    from sc_fem.fem.options import predicted_seconds

    saved = dict(fill.LOBPCG_FILL_MODEL)
    done = _converged(records)
    rows, within = [], 0
    try:
        for shape in dict.fromkeys(r["shape"] for r in done):
            _fit_iterations([r for r in done if r["shape"] != shape])
            for r in (r for r in done if r["shape"] == shape):
                its = fill.lobpcg_iterations(_analysis(r))
                sec = predicted_seconds("lobpcg", r["dofs"], r.get("k", K_PAIRS), _analysis(r))
                ratio = r["lobpcg"] / sec
                within += 1 / 1.5 <= ratio <= 1.5
                rows.append([shape, r["res"], f"{r['lobpcg_iterations']} / {its:.1f}",
                             f"{r['lobpcg']:.2f} / {sec:.2f} s", f"{ratio:.2f}x"])
    finally:
        fill.LOBPCG_FILL_MODEL.update(saved)
    print_table(["shape", "res", "iterations taken / predicted", "seconds taken / predicted", "ratio"], rows)
    print(f"leave-one-shape-out: LOBPCG's seconds within 1.5x on {within} of {len(rows)} runs")


def _cell(rec: dict, m: str) -> str:
    ok = [t for t in rec[m + "_runs"] if t is not None]
    if not ok:
        return "failed"
    spread = f" ({min(ok):.2f}-{max(ok):.2f})" if len(ok) > 1 else ""
    return f"{rec[m]:.2f}{spread} / {rec[m + '_predicted']:.2f} s ({rec[m] / rec[m + '_predicted']:.2f}x)"


def table(records: list[dict]) -> None:
    """The Markdown table: per shape both solvers taken (median, spread) / predicted, LOBPCG's
    iterations taken (predicted), and the choice; then the counts within 1.5x and the repeats' spread."""
    rows, within, right, spread = [], {"shift-invert": [], "lobpcg": []}, 0, []
    for rec in records:
        t_si, t_l = rec["shift-invert"], rec["lobpcg"]
        best = "shift-invert" if t_l is None or (t_si is not None and t_si <= t_l) else "lobpcg"
        old = rec["shift-invert"] / rec["shift-invert_power_law"] if t_si is not None else float("nan")
        right += rec["auto"] == best
        for m in within:
            ok = [t for t in rec[m + "_runs"] if t is not None]
            if ok:
                within[m].append(rec[m] / rec[m + "_predicted"])
                spread.append(np.ptp(ok) / rec[m])
        its = rec["lobpcg_iterations"] or "-"
        if rec.get("lobpcg_iterations_predicted"):
            its = f"{its} ({rec['lobpcg_iterations_predicted']:.0f})"
        rows.append([rec["shape"], rec["kind"], rec["res"], f"{rec['dofs']:,}", rec.get("k", K_PAIRS),
                     _cell(rec, "shift-invert"), f"{old:.2f}x", _cell(rec, "lobpcg"), its, rec["auto"], best,
                     "yes" if rec["auto"] == best else "**no**", "yes" if rec["auto_power_law"] == best else "no",
                     f"{rec['load']:.1f}-{rec['load_after']:.1f}"])
    print_table(["shape", "kind", "res", "DOFs", "pairs", "shift-invert taken / predicted", "power law: taken/pred",
                 "LOBPCG taken / predicted", "LOBPCG its (pred)", "auto picks", "faster", "right?",
                 "power law right?", "load"], rows)
    for m, r in within.items():
        r = np.array(r)
        if len(r):
            print(f"{m}: within 1.5x on {int(np.sum((r <= 1.5) & (r >= 1 / 1.5)))} of {len(r)} "
                  f"(taken / predicted {r.min():.2f}-{r.max():.2f})")
    print(f"auto picks the faster on {right} of {len(records)}; spread (max - min) / median of the repeats: "
          f"median {np.median(spread) if spread else 0:.0%}, largest {max(spread, default=0):.0%}")
    first = [(rec["shape"], rec["res"], rec["lobpcg_forecasts"][0], rec["lobpcg_iterations"], rec["lobpcg"])
             for rec in records if rec.get("lobpcg_forecasts") and rec.get("lobpcg_iterations")]
    first = [(a, b, f, t, sec) for a, b, f, t, sec in first if f["iterations"]]
    if first:                                  # LOBPCG's forecast at its first check, against what it took
        its = np.array([f["iterations"] / t for _, _, f, t, _ in first])
        secs = np.array([f["seconds"] / sec for _, _, f, _, sec in first])
        print(f"LOBPCG's forecast at its first check (iteration 20), on the {len(first)} converged runs that went "
              f"past it: iterations {its.min():.2f}-{its.max():.2f}x of those taken, seconds (set-up included) "
              f"{secs.min():.2f}-{secs.max():.2f}x of the median run's: "
              + ", ".join(f"{a} r{b} {f['iterations']}/{t} its" for a, b, f, t, _ in first))


def _name_points(ax, points: list[tuple[float, float, str, str]]) -> None:
    """Label each ``(x, y, text, colour)`` below and right of its point, on a white ground, each
    label moved down as far as needed to clear the ones above it that it would overlap, with a thin
    line to its point."""
    to_pt = 72.0 / ax.figure.dpi
    placed = []                                               # (left, right, top) of labels, points
    for x, y, text, colour in sorted(points, key=lambda t: -t[1]):
        px, py = (ax.transData.transform((x, y)) * to_pt)
        left, right, top = px + 6, px + 6 + 4.2 * len(text), py - 4
        for l2, r2, t2 in placed:
            if left < r2 and l2 < right and top > t2 - 10:
                top = t2 - 10
        placed.append((left, right, top))
        ax.annotate(text, (x, y), fontsize=7, color=colour, xytext=(6, top - py - 6), textcoords="offset points",
                    bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85},
                    arrowprops={"arrowstyle": "-", "color": colour, "lw": 0.6, "alpha": 0.7, "shrinkA": 0, "shrinkB": 3})


def chart(records: list[dict]) -> None:
    """Taken against predicted, both methods (and shift-invert by the power law, hollow)."""
    fig, ax = plt.subplots(figsize=(6.5, 5))
    outside = []
    for key, m, marker, fc, lab in (("shift-invert_predicted", "shift-invert", "o", None, "shift-invert (fill)"),
                                    ("shift-invert_power_law", "shift-invert", "o", "none", "shift-invert (power law, before)"),
                                    ("lobpcg_predicted", "lobpcg", "s", None, "LOBPCG")):
        pts = np.array([(r[key], r[m]) for r in records if r[m] is not None])
        if len(pts):
            ax.loglog(pts[:, 0], pts[:, 1], marker, mfc=fc, color="C1" if m == "lobpcg" else "C0", label=lab)
        if fc is None:                                        # the points outside 1.5x are named
            outside += [(r[key], r[m], f"{r['shape']} r{r['res']}", "C1" if m == "lobpcg" else "C0")
                        for r in records if r[m] is not None and not 1 / 1.5 <= r[m] / r[key] <= 1.5]
    lim = [0.1, 300]
    ax.set(xlim=(0.04, 700), ylim=(0.04, 700))
    _name_points(ax, outside)
    ax.loglog(lim, lim, "k-", lw=0.8, label="taken = predicted")
    ax.fill_between(lim, [v / 1.5 for v in lim], [v * 1.5 for v in lim], color="0.88", label="within 1.5x")
    ax.set(xlabel="predicted [s]", ylabel="taken [s] (median)",
           title=f"eigensolver time, {K_PAIRS} pairs free-free (cantilever: 6, held)")
    ax.legend(fontsize=8, loc="lower right")
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
                    "(paths, or names in benchmarks/out/) "
                    "with the current model's predictions (from their stored fill), measure nothing")
    ap.add_argument("--unseen", action="store_true", help="the shapes no fit has used (unseen_shapes) instead")
    ap.add_argument("--fresh", action="store_true", help="a second set no fit has used (fresh_shapes) instead")
    ap.add_argument("--loo", action="store_true", help="with --from-json: leave-one-shape-out predictions of "
                    "LOBPCG (the iteration constants refitted without each shape)")
    ap.add_argument("--fit", action="store_true", help="with --from-json: fit LOBPCG's model to those runs "
                    "(print the constants) and show the table with them")
    args = ap.parse_args(argv)
    print(f"uptime: {os.popen('uptime').read().strip()}")
    if args.from_json:
        paths = [Path(f) if Path(f).is_file() else OUT / Path(f).name for f in args.from_json]
        if missing := [f for f, p in zip(args.from_json, paths) if not p.is_file()]:
            ap.error(f"no such JSON file (here or in {OUT}): {', '.join(missing)}")
        records = [rec for f in paths for rec in json.loads(f.read_text())]
        if args.loo:
            leave_one_out(records)
        if args.fit:
            print("LOBPCG_FILL_MODEL =", {k: float(f"{v:.3g}") for k, v in fit(records).items()})
        records = [repredict(rec) for rec in records]
    else:
        records = [measure(label, kind, mesh, r, scale, args.repeat)
                   for label, kind, mesh, resolutions, scale in (
                       unseen_shapes() if args.unseen else fresh_shapes() if args.fresh else shapes(args.quick, args.larger))
                   if not args.only or label in args.only for r in resolutions]
        out_path(args.out).write_text(json.dumps(records, indent=1))
    table(records)
    print(f"uptime: {os.popen('uptime').read().strip()}")
    chart(records)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
