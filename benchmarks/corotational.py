"""Corotational Newmark step against the linear one, and the two ways to solve its matrix.

Per model (gravity from rest, one end or the base held): ms per step of linear Newmark (one
factorization, one back-solve per step), corotational with a factorization every step
(``max_cg=0``), and corotational with the factorization of an earlier step preconditioning
conjugate gradients (default); the ratios to linear, how many factorizations and CG iterations
the default needed, and how far its trajectory is from the factorize-every-step one. Prints a
Markdown table, writes ``benchmarks/out/corotational.png``.

    python benchmarks/corotational.py            # ~1 min
    python benchmarks/corotational.py --settings # + cheaper settings: fewer iterations, looser CG (~3 min)
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _common import print_table, save_figure

import sc_fem
from sc_fem.dynamics import make_integrator
from sc_fem.dynamics.loads import Gravity, LoadSet
from sc_fem.lattice.boundary import fixed_nodes
from sc_fem.lattice.cubes import CubeModel


CHEAPER = (dict(iterations=1), dict(iterations=1, cg_rtol=1e-4), dict(iterations=2, cg_rtol=1e-6))
"""Settings cheaper than the default (3 frozen-tangent iterations, CG to 1e-10) for ``--settings``."""


def cases(quick: bool):
    out = [("bridge r12", sc_fem.voxelize("builtin:bridge", resolution=12), "z<min+0.05", 1e-4),
           ("bar 10x2x2 (E 10 MPa)", CubeModel.box((10, 2, 2), 0.05, youngs=1e7, poisson=0.3, density=1e3),
            "x<min+0", 1e-3),
           ("bar 40x4x4 (E 1 MPa, large sag)", CubeModel.box((40, 4, 4), 0.025, youngs=1e6, poisson=0.3, density=1e3),
            "x<min+0", 2e-3)]
    if not quick:
        out.append(("chair r24", sc_fem.voxelize("builtin:chair", resolution=24), "z<min+0.01", 2e-4))
    return out


def run(model, fix, dt, kind, n_steps, **kw):
    integ = make_integrator(kind, model, dt, fixed_nodes=fixed_nodes(model, fix),
                            loads=LoadSet(model, [Gravity()]), **kw)
    t0 = time.perf_counter()
    for _ in range(n_steps):                          # loop over time steps
        state = integ.step()
    ms = 1e3 * (time.perf_counter() - t0) / n_steps
    return ms, state.u.copy(), getattr(integ, "n_factorizations", 0), getattr(integ, "cg_iterations", 0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer steps, no chair")
    ap.add_argument("--steps", type=int, default=None, help="time steps per run (default 200, quick 50)")
    ap.add_argument("--settings", action="store_true",
                    help="also time cheaper settings (1-2 frozen-tangent iterations, looser CG) and their distance "
                         "from the factorize-every-step trajectory")
    args = ap.parse_args(argv)
    n = args.steps or (50 if args.quick else 200)
    rows, names, ratios, cheap = [], [], [], []
    for name, model, fix, dt in cases(args.quick):
        lin = run(model, fix, dt, "newmark", n)
        each = run(model, fix, dt, "corotational", n, max_cg=0)
        for kw in (CHEAPER if args.settings else ()):
            got = run(model, fix, dt, "corotational", n, **kw)
            diff = float(np.abs(got[1] - each[1]).max() / max(np.abs(each[1]).max(), 1e-300))
            cheap.append([name, ", ".join(f"{k}={v:g}" for k, v in kw.items()), f"{got[0] / lin[0]:.1f}x",
                          f"{got[3] / n:.1f}", f"{diff:.1e}"])
        lag = run(model, fix, dt, "corotational", n)
        diff = float(np.abs(lag[1] - each[1]).max() / max(np.abs(each[1]).max(), 1e-300))
        rows.append([name, model.n_cubes, n, f"{lin[0]:.3f}", f"{each[0]:.2f} ({each[0] / lin[0]:.0f}x)",
                     f"{lag[0]:.2f} ({lag[0] / lin[0]:.0f}x)", f"{each[0] / lag[0]:.2f}x", lag[2],
                     f"{lag[3] / n:.1f}", f"{diff:.1e}"])
        names.append(name)
        ratios.append((each[0] / lin[0], lag[0] / lin[0]))
    print_table(["model", "cubes", "steps", "linear ms/step", "corot, factor every step",
                 "corot, lagged factor + CG (default)", "speed-up", "factorizations",
                 "CG its per step", "rel. difference"], rows)
    if cheap:
        print()
        print_table(["model", "setting", "step / linear step", "CG its per step",
                     "rel. difference from factorize-every-step"], cheap)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.6))
    y = np.arange(len(names))
    r = np.array(ratios)
    ax.barh(y + 0.2, r[:, 0], 0.4, label="factorize every step")
    ax.barh(y - 0.2, r[:, 1], 0.4, label="lagged factor + CG (default)")
    ax.axvline(5.0, color="k", ls="--", lw=1, label="goal: 5x a linear step")
    ax.set_yticks(y, names)
    ax.set_xlabel("corotational step / linear Newmark step")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    save_figure(fig, "corotational.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
