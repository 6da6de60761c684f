"""Modes end to end against a hand-written peer: ``sc_fem.modal`` beside LOBPCG + pyamg written as a
scipy user would, in one run.

Usage: python benchmarks/modes_speed.py [--sizes A ...] [--baseline-src DIR] [--repeat N] [--peer-maxiter N]

The model is the 4 m steel cantilever of ``benchmarks/scale.py`` (4a x a x a cubes from a box mesh,
one end held), 6 modes. Each size is timed, in a fresh process per row:

* ``sc_fem.modal(model, n_modes=6, fix=..., eigen="lobpcg")``: assembly, eigensolve and bake (the
  voxelizing is timed apart and not included);
* the same with another source tree (``--baseline-src``, e.g. a ``git worktree`` of an older commit);
* the peer: the same ``K`` and ``M`` (sc_fem's assembly, timed apart), then
  ``pyamg.smoothed_aggregation_solver(K - sigma M, B=rigid-body modes)`` and
  ``scipy.sparse.linalg.lobpcg(K, X, B=M, M=ml.aspreconditioner(), largest=False)`` with a block of
  10 random vectors and sc_fem's absolute tolerance, until its 6 smallest pairs pass it
  (``--peer-maxiter`` iterations at most).

Prints a Markdown table (seconds, the ratio to the peer, iterations, the first frequency) and
writes ``benchmarks/out/modes_speed.png``. The machine is shared: the rows' runs are interleaved
(peer, ours, baseline, then again), and the ratios of one run are what to compare.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from _common import print_table, save_figure

ROW = textwrap.dedent(r"""
    import json, sys, time, warnings
    import numpy as np, trimesh
    import sc_fem
    a, what, maxiter = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
    box = trimesh.creation.box(extents=(4.0, 1.0, 1.0))
    box.apply_translation((2.0, 0.5, 0.5))
    model = sc_fem.voxelize(box, pitch=1.0 / a, fill="solid", youngs=200e9, poisson=0.3, density=7850.0)
    out = {"cubes": model.n_cubes}
    if what == "modal":
        t0 = time.perf_counter()
        basis = sc_fem.modal(model, n_modes=6, fix="x<min+1e-9", eigen="lobpcg")
        out.update(seconds=time.perf_counter() - t0, iterations=basis.eigen.get("iterations"),
                   f1=float(basis.frequencies[0]), dofs=None)
    else:
        import pyamg
        from scipy.sparse.linalg import lobpcg
        from sc_fem.fem.eigen import SHIFT_FRACTION, lambda_scale
        from sc_fem.fem.rigid import rigid_body_modes
        fixed = sc_fem.fixed_nodes(model, "x<min+1e-9")
        asm = sc_fem.Assembler(model, "q1i", fixed_dofs=sc_fem.fixed_dofs(fixed))
        K, M = asm.stiffness(), asm.mass()
        t0 = time.perf_counter()
        sigma = -SHIFT_FRACTION * lambda_scale(K, M)
        B = rigid_body_modes(model.nodes_m, asm.free_dofs)
        ml = pyamg.smoothed_aggregation_solver((K - sigma * M).tocsr(), B=B)
        X = np.random.default_rng(0).standard_normal((K.shape[0], 10))
        tol = 1e-3 * abs(sigma) * float(np.sqrt(np.mean(M.diagonal())))
        its, lam = 0, None
        while its < maxiter:                     # until the 6 wanted pairs pass (not the whole block)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                lam, X, hist = lobpcg(K, X, B=M, M=ml.aspreconditioner(), tol=tol, maxiter=10, largest=False,
                                      retResidualNormsHistory=True)
            its += len(hist)
            order = np.argsort(lam)
            lam, X = lam[order], X[:, order]
            R = K @ X[:, :6] - (M @ X[:, :6]) * lam[None, :6]
            if np.linalg.norm(R, axis=0).max() <= tol:
                break
        out.update(seconds=time.perf_counter() - t0, iterations=its, dofs=K.shape[0],
                   f1=float(np.sqrt(max(lam[0], 0.0)) / 2 / np.pi))
    print(json.dumps(out))
""")


def run(a: int, what: str, src: Path | None, maxiter: int) -> dict:
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = str(src.resolve())
    proc = subprocess.run([sys.executable, "-c", ROW, str(a), what, str(maxiter)], capture_output=True, text=True,
                          env=env, timeout=3600)
    if proc.returncode != 0:
        raise SystemExit(f"row a={a} {what} failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="*", default=[12, 22], help="a: cubes across (4a x a x a cubes)")
    ap.add_argument("--baseline-src", type=Path, help="another sc_fem source tree, timed the same way")
    ap.add_argument("--repeat", type=int, default=2, help="runs per row (the best is kept)")
    ap.add_argument("--peer-maxiter", type=int, default=200, help="LOBPCG iterations the peer may take")
    args = ap.parse_args(argv)
    rows, plot = [], []
    for a in args.sizes:
        kinds = [("peer", None), ("modal", None)] + ([("modal", args.baseline_src)] if args.baseline_src else [])
        got = {kind: [] for kind in kinds}
        for _ in range(args.repeat):              # interleaved: a shared machine's load hits all alike
            for kind in kinds:
                got[kind].append(run(a, kind[0], kind[1], args.peer_maxiter))
        peer, ours = (min(got[kind], key=lambda g: g["seconds"]) for kind in kinds[:2])
        base = min(got[kinds[2]], key=lambda g: g["seconds"]) if args.baseline_src else None
        rows.append([a, ours["cubes"], peer["dofs"], f"{ours['seconds']:.2f}", ours["iterations"],
                     f"{base['seconds']:.2f}" if base else "-", base["iterations"] if base else "-",
                     f"{peer['seconds']:.2f}", peer["iterations"], f"{ours['seconds'] / peer['seconds']:.2f}",
                     f"{ours['f1']:.3f} / {peer['f1']:.3f}"])
        plot.append((peer["dofs"], ours["seconds"], base["seconds"] if base else np.nan, peer["seconds"]))
    print_table(["a", "cubes", "free DOFs", "sc_fem.modal [s]", "its", "baseline [s]", "its",
                 "LOBPCG + pyamg peer [s]", "its", "ratio to peer", "f1 Hz (ours / peer)"], rows)
    fig, ax = plt.subplots(figsize=(6, 4))
    d = np.array(plot, dtype=float)
    ax.loglog(d[:, 0], d[:, 1], "o-", label="sc_fem.modal (end to end)")
    if args.baseline_src:
        ax.loglog(d[:, 0], d[:, 2], "s--", label="baseline source tree")
    ax.loglog(d[:, 0], d[:, 3], "^:", label="hand-written LOBPCG + pyamg (eigensolve only)")
    ax.set_xlabel("free DOFs")
    ax.set_ylabel("wall time [s]")
    ax.set_title("6 modes of a steel cantilever")
    ax.legend()
    save_figure(fig, "modes_speed.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
