"""Static solves: the sparse Cholesky factorization against CG + AMG, and a hand-written pyamg CG.

Usage: python benchmarks/static_speed.py [--quick]

For every case (clamped under gravity): ``sc_fem.solve_static`` end to end (assembly included) with
``solver="direct"`` and with ``solver="cg-amg"``; CG + AMG's set-up + solve; its iterations; the
relative 2-norm difference of its displacements from the direct ones; and, on the same assembled
``K`` and load, a hand-written peer: pyamg's ``smoothed_aggregation_solver(K, B=rigid modes)``
with default options and ``ml.solve(b, tol=TOL, accel="cg")``. A second table sweeps small models
for the crossover that ``solver="auto"`` uses (:data:`sc_fem.fem.options.CG_AMG_MIN_DOFS`).

Cases: the Stanford bunny (``bunny.obj`` of the shared meshes, ``_common.SHARED_MESHES``; y up, E = 10 MPa, the nodes of the
lowest 2 % held) at resolution 32 and 64, and the built-in steel cantilever ``builtin:beam``
(root face held) at resolution 160 (139k DOFs). ``--quick``: the bunny at 32, the beam at 80. The
crossover sweep adds thin-membered built-ins (chair r64, cable-stayed bridge r48 and r96, held
at their default supports), where the AMG needs many more iterations.
The default run spends most of its time in the bunny r64 direct solve (~5 min on 2 quiet cores);
``--quick`` takes about a minute.

Writes benchmarks/out/static_speed.png (time against DOFs; CG residual histories).
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SHARED_MESHES, best_time, bunny_scene, print_table, save_figure  # noqa: E402

import sc_fem
from sc_fem.fem.assemble import Assembler
from sc_fem.fem.options import StaticOptions
from sc_fem.fem.rigid import rigid_body_modes
from sc_fem.lattice.boundary import fixed_dofs

TOL = StaticOptions().tol


def scene_of(name: str, r: int):
    """(label, scene, gravity m/s^2) of a case, voxelized (not timed)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if name == "bunny":
            return f"bunny r{r}", bunny_scene(r), np.array([0.0, -9.81, 0.0])
        if name in ("chair", "bridge"):                # thin members, held at their built-in supports
            return f"{name} r{r}", sc_fem.Scene.from_mesh(f"builtin:{name}", resolution=r, fix="default"), \
                np.array([0.0, 0.0, -9.81])
        scene = sc_fem.Scene.from_mesh("builtin:beam", resolution=r, fix="x<min+1e-9")
        return f"beam r{r}", scene, np.array([0.0, 0.0, -9.81])


def peer(scene, g: np.ndarray, u_ref: np.ndarray) -> tuple[float, int, float, list]:
    """Hand-written pyamg CG (defaults) on the same K and load: (set-up + solve s, iterations,
    relative difference from ``u_ref``, residual history)."""
    import pyamg

    model = scene.model
    asm = Assembler(model, "q1i", fixed_dofs=fixed_dofs(scene.fixed_nodes))
    K = asm.stiffness()
    b = asm.restrict(model.node_masses()[:, None] * g[None, :])
    B = rigid_body_modes(model.nodes_m, asm.free_dofs)
    t0 = time.perf_counter()
    ml = pyamg.smoothed_aggregation_solver(K, B=B)
    res: list = []
    x = ml.solve(b, tol=TOL, accel="cg", maxiter=2000, residuals=res)
    t = time.perf_counter() - t0
    x_ref = u_ref.reshape(-1)[asm.free_dofs]
    return t, len(res) - 1, float(np.linalg.norm(x - x_ref) / np.linalg.norm(x_ref)), \
        list(np.asarray(res) / max(res[0], 1e-300))


def run_case(name: str, r: int, with_peer: bool = True, repeat: int = 2, with_auto: bool = False) -> dict:
    label, scene, g = scene_of(name, r)

    def solve(how: str):
        return sc_fem.solve_static(scene, gravity=g, solver=how)

    t0 = time.perf_counter()
    solve("cg-amg")                              # the first call: loads compiled kernels, fills caches
    first = time.perf_counter() - t0
    tc, c = best_time(lambda: solve("cg-amg"), repeat=repeat)
    tc = min(tc, first)
    td, d = best_time(lambda: solve("direct"), repeat=1 if scene.model.n_nodes > 20_000 else repeat)
    diff = float(np.linalg.norm(c.displacements - d.displacements) / np.linalg.norm(d.displacements))
    out = {"label": label, "dofs": int(c.info["levels"][0]), "direct": td, "hist": c.info["residuals"], "first": first,
           "factorize": d.timings["factorize"], "cg": tc, "setup": c.timings["setup"],
           "solve": c.timings["solve"], "assemble": c.timings["assemble"], "its": c.info["iterations"],
           "diff": diff, "levels": c.info["levels"]}
    if with_auto:
        out["auto"], a = best_time(lambda: solve("auto"), repeat=repeat)
        out["auto_solver"] = a.solver + (" (after CG)" if "cg_failed" in a.info else "")
    if with_peer:
        out["peer"], out["peer_its"], out["peer_diff"], out["peer_hist"] = peer(scene, g, d.displacements)
    print(f"  {label}: {out['dofs']:,} DOFs, direct {td:.2f} s, CG-AMG {tc:.2f} s "
          f"({c.info['iterations']} it), diff {diff:.1e}" + (f", peer {out['peer']:.2f} s" if with_peer else ""),
          file=sys.stderr)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="the bunny at r32 and the beam at r80 only")
    args = ap.parse_args(argv)
    have_bunny = (SHARED_MESHES / "bunny.obj").exists()
    if not have_bunny:
        print(f"(no {SHARED_MESHES / 'bunny.obj'}: beam only)", file=sys.stderr)
    cases = [("bunny", 32)] + ([] if args.quick else [("bunny", 64)]) if have_bunny else []
    cases += [("beam", 80 if args.quick else 160)]
    rows, main_rows = [], []
    for name, r in cases:
        o = run_case(name, r)
        main_rows.append(o)
        rows.append([o["label"], f"{o['dofs']:,}", o["direct"], o["factorize"], o["cg"], o["first"], o["assemble"],
                     f"{o['setup']:.2f} + {o['solve']:.2f}", o["its"], f"{o['diff']:.1e}",
                     f"{o['direct'] / o['cg']:.1f}x", f"{o['peer']:.2f}", o["peer_its"],
                     f"{o['peer_diff']:.1e}", f"{o['peer'] / (o['setup'] + o['solve']):.1f}x"])
    print(f"\nStatic solve, clamped under gravity, CG tolerance {TOL:g} (relative residual); times in s, "
          "end to end of solve_static unless noted (CG-AMG: best of the calls in this process, the first "
          "call loads the compiled kernels; direct: one call, after CG-AMG)\n")
    print_table(["case", "DOFs", "direct", "(factorize)", "CG-AMG", "(first call)", "(assemble)",
                 "CG-AMG setup + solve",
                 "iterations", "rel. diff", "direct / CG-AMG", "pyamg CG peer (setup + solve)", "peer its",
                 "peer rel. diff", "peer / ours (setup + solve)"], rows)

    sweep = [("bunny", r) for r in (12, 14, 16, 20, 24)] if have_bunny else []
    sweep += [("beam", r) for r in (40, 48, 60)] + [("chair", 64), ("bridge", 48), ("bridge", 96)]
    cross = [run_case(n, r, with_peer=False, repeat=5 if r < 64 else 2, with_auto=True) for n, r in sweep]
    print("\nCrossover (solver='auto': CG + AMG from sc_fem.fem.options.CG_AMG_MIN_DOFS on, direct after "
          "AUTO_CG_ITERATIONS without convergence); end to end, s\n")
    print_table(["case", "DOFs", "direct", "CG-AMG", "iterations", "rel. diff", "direct / CG-AMG", "auto",
                 "auto took"],
                [[o["label"], f"{o['dofs']:,}", o["direct"], o["cg"], o["its"], f"{o['diff']:.1e}",
                  f"{o['direct'] / o['cg']:.2f}", o["auto"], o["auto_solver"]] for o in cross])
    _chart(main_rows, cross)
    return 0


def _chart(main_rows: list, cross: list) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for kind, marker in (("bunny", "o"), ("beam", "s"), ("chair", "^"), ("bridge", "v")):
        pts = sorted([o for o in main_rows + cross if o["label"].startswith(kind)], key=lambda o: o["dofs"])
        if not pts:
            continue
        n = [o["dofs"] for o in pts]
        axes[0].loglog(n, [o["direct"] for o in pts], marker + "-", color="C3", label=f"{kind}: direct (CHOLMOD)")
        axes[0].loglog(n, [o["cg"] for o in pts], marker + "-", color="C0", label=f"{kind}: CG + AMG")
        pe = [o for o in pts if "peer" in o]
        axes[0].loglog([o["dofs"] for o in pe], [o["peer"] for o in pe], marker, color="C2", mfc="none",
                       label=f"{kind}: pyamg CG peer (setup + solve)")
    axes[0].set(xlabel="free DOFs", ylabel="wall time [s]", title="static solve, end to end")
    axes[0].legend(fontsize=7)
    for i, o in enumerate(main_rows):
        axes[1].semilogy([1.0, *o["hist"]], "-", color=f"C{i}", label=f"{o['label']}: CG + AMG")
        axes[1].semilogy(o["peer_hist"], "--", color=f"C{i}", label=f"{o['label']}: pyamg peer")
    axes[1].axhline(TOL, color="k", lw=0.8)
    axes[1].set(xlabel="CG iteration", ylabel="relative residual", title=f"CG residual histories to tol {TOL:g}")
    axes[1].legend(fontsize=7)
    for a in axes:
        a.grid(True, which="both", alpha=0.3)
    save_figure(fig, "static_speed.png", dpi=120)


if __name__ == "__main__":
    raise SystemExit(main())
