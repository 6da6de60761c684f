"""Cantilever accuracy vs wall time per element type, and fast vs scikit-fem assembly, in one run.

Steel cantilever L = 1 m, 0.1 x 0.1 m section, clamped at x = 0, with t = 1, 2, 4, 8 (16) cubes
through the thickness. For every element (q1, q1sri, q1i with the fast assembly; q1 with
scikit-fem's generic assembly as the reference column): first bending frequency and tip
deflection under a 1 kN tip load against the converged 3-D values (f1 = 81.26 Hz,
2.002e-4 m), and the wall time of assembly (pattern + K + M) + factorization + static solve +
first eigenpair. Then the assembly time of K, fast vs scikit-fem, against the number of cubes.

Usage: python benchmarks/accuracy_vs_speed.py [--quick | --full]
(default: solves up to 8 cubes thick, assembly comparison up to 16 cubes thick = 40960 cubes)
Writes benchmarks/out/accuracy_vs_speed.png and prints Markdown tables.
"""

from __future__ import annotations

import argparse
import sys
import time

import matplotlib.pyplot as plt
import numpy as np
import scipy.sparse.linalg as sla

from _common import best_time, print_table, save_figure
from sc_fem.fem.assemble import Assembler, assemble
from sc_fem.lattice.boundary import fixed_dofs, fixed_nodes
from sc_fem.lattice.cubes import CubeModel
from sc_fem.fem.linsolve import factorize

F1_REF, TIP_REF, LOAD = 81.26, 2.002e-4, 1000.0
VARIANTS = [("q1", "skfem"), ("q1", "fast"), ("q1sri", "fast"), ("q1i", "fast")]


def cantilever(t: int) -> CubeModel:
    return CubeModel.box((10 * t, t, t), 0.1 / t, youngs=200e9, poisson=0.3, density=7850.0)


def tip_load(model: CubeModel, t: int) -> tuple[np.ndarray, np.ndarray]:
    j, k = model.node_index[:, 1], model.node_index[:, 2]
    w = np.where((j == 0) | (j == t), 0.5, 1.0) * np.where((k == 0) | (k == t), 0.5, 1.0)
    w = w * (model.node_index[:, 0] == 10 * t)
    w /= w.sum()
    F = np.zeros((model.n_nodes, 3))
    F[:, 2] = -LOAD * w
    return w, F


def run_case(t: int, element: str, method: str) -> dict:
    model = cantilever(t)
    w, F = tip_load(model, t)
    fixed = fixed_dofs(fixed_nodes(model, "x<min+0"))
    t0 = time.perf_counter()
    if method == "fast":
        A = Assembler(model, element, fixed_dofs=fixed)
        K, M = A.stiffness(), A.mass()
        free = A.free_dofs
    else:
        K, M = assemble(model, element, fixed_dofs=fixed, method="skfem")
        free = np.setdiff1d(np.arange(model.n_dofs), fixed)
    t_asm = time.perf_counter() - t0
    t0 = time.perf_counter()
    fac = factorize(K)
    u = np.zeros(model.n_dofs)
    u[free] = fac.solve(F.ravel()[free])
    t_static = time.perf_counter() - t0
    t0 = time.perf_counter()
    op = sla.LinearOperator(K.shape, matvec=fac.solve, dtype=float)
    lam = sla.eigsh(K, k=2, M=M, sigma=0.0, OPinv=op, return_eigenvectors=False).min()
    t_eig = time.perf_counter() - t0
    tip = -np.sum(w * u.reshape(-1, 3)[:, 2])
    f1 = np.sqrt(lam) / (2 * np.pi)
    return dict(t=t, element=element, method=method, cubes=model.n_cubes, dofs=K.shape[0],
                t_asm=t_asm, t_static=t_static, t_eig=t_eig, total=t_asm + t_static + t_eig,
                e_tip=tip / TIP_REF - 1.0, e_f1=f1 / F1_REF - 1.0, backend=fac.backend)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="assembly comparison up to 8 cubes thick only")
    ap.add_argument("--full", action="store_true", help="also solve 16 cubes thick (139k DOFs; minutes per element)")
    args = ap.parse_args(argv)
    ts = [1, 2, 4, 8, 16] if args.full else [1, 2, 4, 8]
    ts_asm = [1, 2, 4, 8] if args.quick else [1, 2, 4, 8, 16]
    # warm up the cached unit-cube reference matrices so they are not timed
    from sc_fem.fem.elements import q1i_unit_stiffness, reference_mass, reference_stiffness

    reference_stiffness("q1"), reference_stiffness("q1sri"), reference_mass(), q1i_unit_stiffness(0.5)

    results = []
    for t in ts:
        for element, method in VARIANTS:
            r = run_case(t, element, method)
            results.append(r)
            print(f"  t={t} {element}/{method}: {r['total']:.2f} s, f1 err {100 * r['e_f1']:+.2f}%",
                  file=sys.stderr)
    print("\nCantilever (E = 200 GPa, nu = 0.3, L = 1 m, 0.1 x 0.1 m), errors vs converged 3-D values; "
          f"solver backend {results[0]['backend']}\n")
    print_table(["cubes thick", "element", "assembly", "cubes", "DOFs", "asm [s]", "static [s]", "eig [s]",
                 "total [s]", "tip err [%]", "f1 err [%]"],
                [[r["t"], r["element"], r["method"], r["cubes"], r["dofs"], r["t_asm"], r["t_static"], r["t_eig"],
                  r["total"], f"{100 * r['e_tip']:+.2f}", f"{100 * r['e_f1']:+.2f}"] for r in results])

    # fast vs scikit-fem assembly of K (same physics), one run
    rows, ratio_series = [], []
    for t in ts_asm:
        model = cantilever(t)
        t_sk, K_sk = best_time(lambda: assemble(model, "q1", method="skfem")[0], repeat=1 if t >= 8 else 3)
        t_fast, A = best_time(lambda: Assembler(model, "q1"), repeat=3)
        t_fill, K = best_time(lambda: A.stiffness(), repeat=3)
        A_i = Assembler(model, "q1i")
        t_q1i, _ = best_time(lambda: A_i.stiffness(), repeat=3)
        err = abs(K - K_sk).max() / abs(K_sk).max()
        rows.append([model.n_cubes, model.n_dofs, t_sk, t_fast + t_fill, t_fill, t_q1i, t_sk / (t_fast + t_fill),
                     t_sk / t_fill, 1e6 * (t_fast + t_fill) / model.n_cubes, f"{err:.1e}"])
        ratio_series.append((model.n_cubes, t_sk / (t_fast + t_fill), t_sk / t_fill))
    print("\nAssembly of K (q1): scikit-fem generic vs fast scatter (pattern + fill) vs re-fill into the pattern\n")
    print_table(["cubes", "DOFs", "skfem [s]", "fast [s]", "refill [s]", "refill q1i [s]", "skfem/fast",
                 "skfem/refill", "fast [us/cube]", "max rel diff"], rows)

    fig, ax = plt.subplots(1, 3, figsize=(16, 4.8))
    styles = {("q1", "skfem"): "k--s", ("q1", "fast"): "C0-o", ("q1sri", "fast"): "C1-^", ("q1i", "fast"): "C2-D"}
    for key, st in styles.items():
        rs = [r for r in results if (r["element"], r["method"]) == key]
        lab = f"{key[0]} ({key[1]})"
        for a, name in ((ax[0], "e_f1"), (ax[1], "e_tip")):
            a.loglog([r["total"] for r in rs], [max(abs(r[name]), 1e-5) for r in rs], st, label=lab)
            for r in rs:
                a.annotate(str(r["t"]), (r["total"], max(abs(r[name]), 1e-5)), fontsize=7,
                           textcoords="offset points", xytext=(3, 3))
    ax[0].set(xlabel="wall time: assembly + factorization + solves [s]", ylabel="|first-frequency error|",
              title="First bending frequency (labels: cubes through thickness)")
    ax[1].set(xlabel="wall time: assembly + factorization + solves [s]", ylabel="|tip-deflection error|",
              title="Tip deflection, 1 kN")
    for a in ax[:2]:
        a.axhline(0.02, color="gray", lw=0.8, ls=":")
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    n, r1, r2 = np.array(ratio_series).T
    ax[2].semilogx(n, r1, "C0-o", label="skfem / fast (pattern + fill)")
    ax[2].semilogx(n, r2, "C3-s", label="skfem / re-fill into stored pattern")
    ax[2].set(xlabel="cubes", ylabel="speed-up over scikit-fem", title="Assembly of K, speed-up")
    ax[2].grid(True, which="both", alpha=0.3)
    ax[2].legend(fontsize=8)
    save_figure(fig, "accuracy_vs_speed.png", dpi=120)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
