"""Modal analysis benchmark: eigensolvers side by side, stage times and peak memory, playback speed.

Run:  .venv/bin/python benchmarks/modal.py [--quick]

1. Cantilever refinements (n x n section, 10 n cubes long, fixed root), 6 modes, each eigensolver:
   shift-invert through ``splu`` (SuperLU, symmetric mode), ``cholespy``, ``cholmod``
   (scikit-sparse) and ``pardiso`` (pypardiso, benchmark only), and LOBPCG + pyamg smoothed
   aggregation. Time (setup + solve) and peak memory.
2. Built-in chair (feet fixed) and bridge at several resolutions: time and peak memory per stage
   (voxelize, assemble, eigensolve, bake) with the automatic solver choice.
3. Playback frames per second of :class:`sc_fem.modes.player.ModalPlayer` for 100k vertices and 32 modes.

Peak memory is the peak resident set size (VmRSS from /proc/self/status, sampled every 5 ms by a
thread) above the value at the start of the stage, so C allocations (CHOLMOD, SuperLU, PARDISO,
pyamg) are included -- tracemalloc would not see them.
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import print_table, save_figure  # noqa: E402


class PeakRSS:
    """Context manager: peak VmRSS (bytes) above the entry value, sampled by a thread."""

    def __enter__(self):
        self.base = self.peak = _rss()
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()
        self.t0 = time.perf_counter()
        return self

    def _run(self):
        while not self._stop.wait(0.005):
            self.peak = max(self.peak, _rss())

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self.t0
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, _rss())
        self.delta = self.peak - self.base
        return False


def _rss() -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    return 0


def _pardiso_eigsh(K, M, k, sigma):
    import pypardiso
    from scipy.sparse.linalg import LinearOperator, eigsh

    A = (K - sigma * M).tocsr()
    solver = pypardiso.PyPardisoSolver(mtype=2)         # real symmetric positive definite
    import scipy.sparse as sp

    Au = sp.triu(A, format="csr")
    solver.factorize(Au)

    def solve(b):
        return solver.solve(Au, np.asarray(b, dtype=float))

    op = LinearOperator(A.shape, matvec=solve, matmat=solve, dtype=float)
    lam, X = eigsh(K, k=k, M=M, sigma=sigma, OPinv=op, v0=np.random.default_rng(0).standard_normal(A.shape[0]))
    solver.free_memory(everything=True)
    return np.sort(lam)


def solvers_available() -> list[str]:
    import importlib.util

    from sc_fem.fem.linsolve import available_backends

    names = [f"si-{b}" for b in reversed(available_backends())]
    if importlib.util.find_spec("pypardiso") is not None:
        names.append("si-pardiso")
    names.append("lobpcg-amg")
    return names


def run_solver(name, K, M, k, near_null):
    from sc_fem.fem.eigen import SHIFT_FRACTION, lambda_scale, solve_eigen

    if name == "si-pardiso":
        sigma = -SHIFT_FRACTION * lambda_scale(K, M)
        return _pardiso_eigsh(K, M, k, sigma)
    if name == "lobpcg-amg":
        return solve_eigen(K, M, k, method="lobpcg", near_null=near_null).eigenvalues
    return solve_eigen(K, M, k, method="shift-invert", backend=name[3:]).eigenvalues


def bench_cantilevers(sizes, k, limits):
    from sc_fem.fem.assemble import Assembler
    from sc_fem.lattice.boundary import fixed_dofs, fixed_nodes
    from sc_fem.fem.rigid import rigid_body_modes
    from sc_fem.lattice.cubes import CubeModel

    rows, results = [], {}
    names = solvers_available()
    for n in sizes:                                             # loop over refinements
        m = CubeModel.box((10 * n, n, n), 0.1 / n, youngs=200e9, poisson=0.3, density=7850.0)
        asm = Assembler(m, "q1i", fixed_dofs=fixed_dofs(fixed_nodes(m, "x<min+0")))
        K, M = asm.stiffness(), asm.mass()
        nn = rigid_body_modes(m.nodes_m, asm.free_dofs)
        ref = None
        for name in names:                                      # loop over solvers
            if K.shape[0] > limits.get(name, np.inf):
                rows.append([n, K.shape[0], name, "skipped", "", ""])
                continue
            with PeakRSS() as pk:
                lam = run_solver(name, K, M, k, nn)
            f = np.sqrt(np.maximum(lam[:k], 0)) / 2 / np.pi
            ref = f if ref is None else ref
            err = float(np.max(np.abs(f - ref) / ref))
            results.setdefault(name, []).append((K.shape[0], pk.seconds, pk.delta))
            rows.append([n, K.shape[0], name, pk.seconds, pk.delta / 2**20, err])
            print(f"  n={n} dofs={K.shape[0]} {name}: {pk.seconds:.2f} s, {pk.delta / 2**20:.0f} MiB", file=sys.stderr)
    return rows, results


def bench_models(cases, k):
    from sc_fem import modal
    from sc_fem.geometry.mesh import load_mesh
    from sc_fem.lattice.voxelize import voxelize

    rows = []
    for name, fix, res in cases:                                # loop over models and resolutions
        mesh = load_mesh(f"builtin:{name}")
        with PeakRSS() as pv:
            model = voxelize(mesh, resolution=res)
        with PeakRSS() as pm:
            b = modal(model, mesh=mesh, n_modes=k, fix=fix)
        t = b.timings
        rows.append([name, res, model.n_cubes, model.n_dofs, pv.seconds, t.get("assemble", 0), t.get("eigensolve", 0),
                     t.get("bake", 0), pv.delta / 2**20, pm.delta / 2**20, f"{b.eigen['method']}/{b.eigen['backend']}",
                     float(b.frequencies[0])])
        print(f"  {name} r={res}: {model.n_cubes} cubes, {pm.seconds:.2f} s", file=sys.stderr)
    return rows


def bench_playback(n_vertices=100_000, k=32, seconds=2.0):
    from sc_fem.modes.basis import ModalBasis
    from sc_fem.modes.player import ModalPlayer

    rng = np.random.default_rng(0)
    b = ModalBasis(frequencies=np.sort(rng.uniform(1, 100, k)), modes=rng.standard_normal((k, n_vertices, 3)).astype(np.float32),
                   vertices=rng.standard_normal((n_vertices, 3)), faces=np.zeros((0, 3), int), damping=np.full(k, 0.01),
                   damping_spec={"kind": "ratio", "zeta": 0.01}, rigid=np.zeros(k, bool), residuals=np.zeros(k),
                   n_rigid_removed=0, scale=1.0, pitch=0.01, resolution=64, element="q1i")
    p = ModalPlayer(b)
    p.impulse(0, [1.0, 0.0, 0.0])
    p.frames(0.1, 30)                                           # warm-up
    t0 = time.perf_counter()
    fr = p.frames(seconds, 60.0)
    dt = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(60):                                         # the interactive path: step() per frame
        p.step(1 / 60)
    dt_step = time.perf_counter() - t0
    return len(fr) / dt, 60 / dt_step


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes only (~30 s)")
    args = ap.parse_args(argv)
    k = 6
    if args.quick:
        sizes, cases = [2, 4, 6], [("chair", ["z<min+0.01"], 24), ("bridge", ["z<min+0.05"], 32)]
        limits = {}
    else:
        sizes = [2, 4, 6, 8, 10, 12]          # n = 16 (the 139k-DOF case) is left out to stay under ~5 min
        cases = [("chair", ["z<min+0.01"], r) for r in (24, 48, 64)] + \
                [("bridge", ["z<min+0.05"], r) for r in (32, 64)]
        limits = {"si-splu": 40_000, "si-cholespy": 140_000}
    print("== eigensolvers on cantilevers (6 modes)", file=sys.stderr)
    rows, res = bench_cantilevers(sizes, k, limits)
    print("\nEigensolvers, cantilever 10n x n x n, root fixed, 6 modes (time = setup + solve; memory = peak RSS rise)")
    print_table(["n", "DOFs", "solver", "time [s]", "peak MiB", "max rel f diff"], rows)
    # ratios to the fastest Cholesky backend at each size
    base = "si-cholmod" if "si-cholmod" in res else "si-cholespy"
    ratio_rows = []
    for name, pts in res.items():
        for dofs, t, _ in pts:
            b = {d: tt for d, tt, _ in res[base]}.get(dofs)
            if b:
                ratio_rows.append([dofs, name, t / b])
    print(f"\nTime relative to {base}")
    print_table(["DOFs", "solver", f"time / {base}"], ratio_rows)

    print("\n== built-in models", file=sys.stderr)
    mrows = bench_models(cases, 8)
    print("\nBuilt-in models, 8 modes, automatic solver (seconds per stage; peak RSS rise in MiB)")
    print_table(["model", "res", "cubes", "DOFs", "voxelize", "assemble", "eigensolve", "bake", "MiB vox",
                 "MiB modal", "solver", "f1 [Hz]"], mrows)

    fps, fps_step = bench_playback(n_vertices=100_000 if not args.quick else 20_000)
    print(f"\nPlayback, {'100k' if not args.quick else '20k'} vertices, 32 modes: frames() {fps:,.0f} frames/s, "
          f"step() {fps_step:,.0f} frames/s (one float32 mat-vec per frame)")

    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(16, 4.8))
    for name, pts in res.items():
        d, t, mem = (np.array(x) for x in zip(*pts))
        ax[0].loglog(d, t, "o-", label=name)
        ax[1].loglog(d, np.maximum(mem, 1) / 2**20, "o-", label=name)
        bmap = {dd: tt for dd, tt, _ in res[base]}
        r = [(dd, tt / bmap[dd]) for dd, tt in zip(d, t) if dd in bmap]
        if r:
            ax[2].semilogx(*zip(*r), "o-", label=name)
    ax[0].set(xlabel="DOFs", ylabel="seconds", title="6 modes of a cantilever")
    ax[1].set(xlabel="DOFs", ylabel="peak RSS rise [MiB]", title="memory")
    ax[2].set(xlabel="DOFs", ylabel=f"time / {base}", title="ratio to the Cholesky backend")
    ax[2].set_yscale("log")
    for a in ax:
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    save_figure(fig, "modal.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
