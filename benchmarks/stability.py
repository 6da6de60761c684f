"""Stability study: where time integrators fail.  Usage: python benchmarks/stability.py [--quick]

Models: a cantilever (10 x 2 x 2 cubes, E = 10 MPa) and the built-in bridge (steel, resolution 12),
gravity switched on at t = 0 from rest. Methods: explicit central differences (lumped mass),
average-acceleration Newmark, Newmark gamma = 0.6, HHT alpha = -0.3, corotational Newmark, and
XPBD (1 substep, 10 iterations). Time steps from 0.1x to 100x the explicit limit dt_crit.

Per run: the largest total-energy change ``max |E(t) - E(0)|`` over the static strain energy
``E_s = f.u_s / 2`` (energy growth), and the displacement error against the exact semi-discrete
response (modal superposition with the method's own mass matrix), ``max_t |u - u_ref| / max |u_ref|``.

Charts: ``benchmarks/out/stability.png`` (energy growth and error vs dt / dt_crit) and
``benchmarks/out/stability_cost.png`` (error vs wall time at a fixed simulated duration).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _common import print_table, save_figure
from scipy.linalg import eigh

from sc_fem.lattice.boundary import fixed_nodes
from sc_fem.errors import InstabilityError
from sc_fem.dynamics import make_integrator, record
from sc_fem.dynamics.loads import Gravity, LoadSet
from sc_fem.lattice.cubes import CubeModel

METHODS = {
    "central": ("central", {}),
    "newmark avg": ("newmark", {}),
    "newmark g=0.6": ("newmark", {"gamma": 0.6, "beta": 0.3025}),
    "HHT a=-0.3": ("newmark", {"alpha": -0.3}),
    "corotational": ("corotational", {}),
    "xpbd 1x10": ("xpbd", {}),
}


def models(quick: bool):
    cant = CubeModel.box((10, 2, 2), 0.05, youngs=1e7, poisson=0.3, density=1000.0)
    out = [("cantilever", cant, fixed_nodes(cant, "x<min+0"))]
    if not quick:
        from sc_fem.geometry.mesh import load_mesh
        from sc_fem.lattice.voxelize import voxelize

        br = voxelize(load_mesh("builtin:bridge"), resolution=12)
        out.append(("bridge", br, fixed_nodes(br, "z<min+0.05")))
    return out


class Reference:
    """Exact response to a step load from rest: u(t) = u_s - Phi (q cos(omega t))."""

    def __init__(self, integ):
        K, M = integ.K.toarray(), integ.M.toarray()
        f = integ.external_force(0.0)
        w2, self.phi = eigh(K, M)
        self.w = np.sqrt(np.maximum(w2, 0))
        self.us = np.linalg.solve(K, f)
        self.q = self.phi.T @ (M @ self.us)
        self.asm = integ.asm
        self.Es = 0.5 * float(f @ self.us)

    def __call__(self, t):
        return self.asm.expand(self.us - self.phi @ (self.q * np.cos(self.w * t)))


def run_xpbd(model, fixed, dt, n):
    from sc_fem.dynamics.xpbd import XPBDSolver

    s = XPBDSolver(model, dt, substeps=1, iterations=10, fixed_nodes=fixed, gravity=(0, 0, -9.81))
    us, es, t0 = [np.zeros((model.n_nodes, 3))], [0.0], time.perf_counter()
    for _ in range(n):
        st = s.step()
        if not np.all(np.isfinite(st.positions)):
            raise InstabilityError("xpbd non-finite")
        us.append(st.positions - model.nodes_m)
        es.append(s.energy().total)
        if abs(es[-1]) > 1e12:
            raise InstabilityError("xpbd energy")
    return np.arange(n + 1) * dt, np.array(us), np.array(es), time.perf_counter() - t0


def one(model, fixed, label, dt, n, refs):
    kind, kw = METHODS[label]
    ld = LoadSet(model, [Gravity()])
    if kind == "xpbd":
        times, us, es, secs = run_xpbd(model, fixed, dt, n)
        ref = refs["consistent"]
    else:
        integ = make_integrator(kind, model, dt, fixed_nodes=fixed, loads=ld, **kw)
        rec = record(integ, n, growth=1e3)
        times, us, es, secs = rec.times, rec.u, rec.energy, rec.seconds
        ref = refs["lumped" if kind == "central" else "consistent"]
    uref = np.array([ref(t) for t in times])
    err = float(np.abs(us - uref).max() / np.abs(uref).max())
    growth = float(np.max(np.abs(es - es[0])) / ref.Es)
    return growth, err, secs, times, es / ref.Es


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="cantilever only, fewer steps")
    args = ap.parse_args(argv)
    factors = [0.1, 0.5, 0.9, 0.99, 1.01, 1.1, 3.0, 10.0, 30.0, 100.0]
    if args.quick:
        factors = [0.1, 0.9, 1.1, 10.0, 100.0]
    import matplotlib.pyplot as plt

    ms = models(args.quick)
    fig, axes = plt.subplots(len(ms), 3, figsize=(16, 4.6 * len(ms)), squeeze=False)
    rows, cost = [], {}
    for mi, (name, model, fixed) in enumerate(ms):
        lumped = make_integrator("central", model, 1.0, fixed_nodes=fixed, loads=LoadSet(model, [Gravity()]))
        cons = make_integrator("newmark", model, 1.0, fixed_nodes=fixed, loads=LoadSet(model, [Gravity()]))
        dtc = lumped.dt_crit
        refs = {"lumped": Reference(lumped), "consistent": Reference(cons)}
        T1 = 2 * np.pi / refs["consistent"].w[0]
        duration = max(2.0 * T1, 20 * 100 * dtc) if not args.quick else max(2.0 * T1, 10 * 100 * dtc)
        print(f"{name}: {model.n_cubes} cubes, dt_crit = {dtc:.3g} s, T1 = {T1:.3g} s, duration {duration:.3g} s")
        for label in METHODS:
            g_list, e_list = [], []
            for fac in factors:
                if label in ("corotational", "xpbd 1x10") and fac < 0.5:
                    continue        # 10^4 steps of the slow methods: too long for a benchmark run
                dt = fac * dtc
                n = int(np.ceil(duration / dt))
                try:
                    growth, err, secs, times, en = one(model, fixed, label, dt, n, refs)
                    if fac == 100.0 or (label == "central" and fac in (0.9, 1.1)):
                        axes[mi, 2].plot(times / T1, en, label=f"{label} {fac:g}x")
                except InstabilityError:
                    growth, err, secs = np.inf, np.inf, np.nan
                g_list.append(growth)
                e_list.append(err)
                rows.append([name, label, fac, n, growth, err, secs / n * 1e3 if np.isfinite(secs) else np.nan])
                if name == "cantilever":
                    cost.setdefault(label, []).append((secs, err))
            gp = np.where(np.isfinite(g_list), g_list, 1e6)
            ep = np.where(np.isfinite(e_list), e_list, 1e3)
            fs = [f for f in factors if not (label in ("corotational", "xpbd 1x10") and f < 0.5)]
            axes[mi, 0].loglog(fs, np.maximum(gp, 1e-16), "o-", label=label)
            axes[mi, 1].loglog(fs, np.maximum(ep, 1e-16), "o-", label=label)
        for ax, title in zip(axes[mi], ("max |E - E0| / E_static (1e6 = blew up)",
                                        "displacement error vs exact (1e3 = blew up)",
                                        "energy / E_static over time (selected runs)")):
            ax.set_title(f"{name}: {title}", fontsize=9)
            ax.grid(True, which="both", alpha=0.3)
        for ax in axes[mi, :2]:
            ax.axvline(1.0, color="k", ls="--", lw=0.8)
            ax.set_xlabel("dt / dt_crit")
        axes[mi, 2].set_xlabel("t / T1")
        axes[mi, 2].set_ylim(-3, 3)
        axes[mi, 0].legend(fontsize=7)
        axes[mi, 2].legend(fontsize=6)
    save_figure(fig, "stability.png")
    print_table(["model", "method", "dt/dt_crit", "steps", "energy growth", "error", "ms/step"], rows)

    fig2, ax = plt.subplots(figsize=(7, 5))
    for label, pts in cost.items():
        pts = [(s, e) for s, e in pts if np.isfinite(e) and np.isfinite(s)]
        if pts:
            s, e = zip(*sorted(pts))
            ax.loglog(s, e, "o-", label=label)
    ax.set_xlabel("wall time for the fixed simulated duration, s")
    ax.set_ylabel("displacement error vs exact")
    ax.set_title("cantilever: accuracy vs cost (each point one dt)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig2, "stability_cost.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
