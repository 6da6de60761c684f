"""Cost against size: voxelize -> assemble -> 6 modes -> bake, from ~10k to ~1M cubes.

Each stage of each size runs in a **fresh process** (the bake in the process of the modes it maps), so
its wall time and its peak memory (the resident set size sampled every 5 ms during the stage, minus
what the process held before it) are its own.
The model is a solid bar of 4a x a x a cubes (a 4 m steel cantilever, one end held) voxelized from
a box mesh, so the cube count is exact and the frequencies are checkable; the bake maps the modes
onto a surface mesh of about 10 % as many vertices as cubes. Prints a Markdown table, the measured
log-log slopes (cost ~ cubes^p), the eigensolver each size chose and why, and at one size the
shift-invert and LOBPCG + AMG solvers side by side (and ``sc_fem.modal`` end to end); writes ``benchmarks/out/scale.png`` and
``benchmarks/out/scale.md``.

    python benchmarks/scale.py                      # 10k, 30k, 100k, 300k, 1M cubes (~15 min, ~8 GB)
    python benchmarks/scale.py --quick              # 10k, 30k, 100k
    python benchmarks/scale.py --sizes 10000 50000 --compare 46240
    python benchmarks/scale.py --sizes 1000000 --compare 0 --dask 1000000   # + the same as one Dask task
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import textwrap

import numpy as np
from _common import out_path, print_table, save_figure

STAGE = textwrap.dedent(r"""
    import json, os, sys, threading, time
    import numpy as np, trimesh
    import sc_fem
    from sc_fem.fem.eigen import solve_eigen
    from sc_fem.fem.rigid import rigid_body_modes

    PAGE = os.sysconf("SC_PAGE_SIZE")

    def now():                                   # resident set size now, bytes
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * PAGE

    class Peak:                                  # samples the RSS every 5 ms during a stage
        def __enter__(self):
            self.base = self.top = now(); self.on = True
            def loop():
                while self.on:
                    self.top = max(self.top, now()); time.sleep(0.005)
            self.t = threading.Thread(target=loop, daemon=True); self.t.start(); return self
        def __exit__(self, *exc):
            self.on = False; self.t.join(); self.top = max(self.top, now())
        @property
        def added(self):
            return self.top - self.base

    def run(a, stage, method):   # the pipeline up to stage (voxelize, assemble, modes + bake), each timed
        box = trimesh.creation.box(extents=(4.0, 1.0, 1.0))
        box.apply_translation((2.0, 0.5, 0.5))
        out = {}
        t0 = time.perf_counter()
        with Peak() as pk:
            model = sc_fem.voxelize(box, pitch=1.0 / a, fill="solid", youngs=200e9, poisson=0.3, density=7850.0)
        out["voxelize"], out["voxelize_peak"] = time.perf_counter() - t0, pk.added
        out["cubes"] = model.n_cubes
        if stage == "voxelize":
            return out
        if stage == "modal":     # what a user calls: assembly, the eigensolve and the bake in one call
            t0 = time.perf_counter()
            with Peak() as pk:
                basis = sc_fem.modal(model, n_modes=6, fix="x<min+1e-9", eigen=method)
            out["modal"], out["modal_peak"] = time.perf_counter() - t0, pk.added
            e = basis.eigen
            free = 3 * (model.n_nodes - len(sc_fem.fixed_nodes(model, "x<min+1e-9")))
            out.update(method=e["method"], reason=e["reason"], iterations=e.get("iterations"), dofs=free,
                       f_hz=basis.frequencies.tolist())
            return out
        fixed = sc_fem.fixed_nodes(model, "x<min+1e-9")
        t0 = time.perf_counter()
        with Peak() as pk:
            asm = sc_fem.Assembler(model, "q1i", fixed_dofs=sc_fem.fixed_dofs(fixed))
            K = asm.stiffness(); M = asm.mass()
        out["assemble"], out["assemble_peak"] = time.perf_counter() - t0, pk.added
        out["dofs"] = K.shape[0]
        if stage == "assemble":
            return out
        t0 = time.perf_counter()
        with Peak() as pk:
            eig = solve_eigen(K, M, 6, method=method, near_null=rigid_body_modes(model.nodes_m, asm.free_dofs))
        out["modes"], out["modes_peak"] = time.perf_counter() - t0, pk.added
        out["method"], out["reason"] = eig.method, eig.reason
        out["iterations"] = eig.info.get("iterations")
        out["f_hz"] = (np.sqrt(np.maximum(eig.eigenvalues, 0)) / 2 / np.pi).tolist()
        surf = trimesh.creation.box(extents=(4.0, 1.0, 1.0))
        surf.apply_translation((2.0, 0.5, 0.5))
        while len(surf.vertices) < 0.1 * model.n_cubes:
            surf = surf.subdivide()
        t0 = time.perf_counter()
        with Peak() as pk:       # the modes onto the surface (the same process: bake needs the modes)
            W = sc_fem.embed(model, surf.vertices)
            node = asm.expand(eig.vectors)                     # (m, 3, k)
            vert = np.asarray(W @ node.reshape(model.n_nodes, -1)).reshape(len(surf.vertices), 3, -1)
        out["bake"], out["bake_peak"] = time.perf_counter() - t0, pk.added
        out["vertices"] = len(surf.vertices)
        return out

    def task(a, method):                         # the whole pipeline as one Dask task
        with Peak() as pk:
            got = run(a, "modes", method)
        got["peak"] = pk.added
        return got

    if __name__ == "__main__":
        a, stage, method = int(sys.argv[1]), sys.argv[2], sys.argv[3]
        if stage != "dask":
            out = run(a, stage, method)
            out["peak"] = out[f"{stage}_peak"]
        else:                # one worker process on a local cluster, no memory limit
            from dask.distributed import Client, LocalCluster
            t0 = time.perf_counter()
            with LocalCluster(n_workers=1, threads_per_worker=2, processes=True, memory_limit=0,
                              dashboard_address=None) as cluster, Client(cluster) as client:
                started = time.perf_counter() - t0
                out = client.submit(task, a, method, pure=False).result()
            out["dask"], out["cluster_start"] = time.perf_counter() - t0, started
        print(json.dumps(out))
""")



def run_stage(a: int, stage: str, method: str = "auto") -> dict:
    res = subprocess.run([sys.executable, "-c", STAGE, str(a), stage, method], capture_output=True, text=True)
    if res.returncode != 0:
        tail = (res.stderr or res.stdout).strip().splitlines()[-1:]
        return {"error": " ".join(tail)[:200]}
    return json.loads(res.stdout.strip().splitlines()[-1])


def dask_comparison(a: int, rows: list) -> str:
    """The pipeline at ``4 a^3`` cubes run directly (the table's stages, or one fresh run) and as one
    task on a local Dask cluster: wall time and peak memory, as a Markdown table."""
    direct = next((r for r in rows if r["a"] == a and isinstance(r.get("modes"), float)), None)
    if direct is None:        # LOBPCG asked for: at a million cubes "auto" refuses both (budget: half the memory)
        direct = {**run_stage(a, "modes", "lobpcg"), "a": a}
    got = run_stage(a, "dask", "lobpcg")
    if "error" in got or "error" in direct:
        msg = got.get("error") or direct.get("error")
        print(f"[dask] FAILED: {msg}", file=sys.stderr, flush=True)
        return f"Dask comparison at {4 * a**3:,} cubes failed: {msg}"
    stages = ("voxelize", "assemble", "modes", "bake")
    t_direct = sum(direct[s] for s in stages)
    peak_direct = max(direct[f"{s}_peak"] for s in stages)
    rows_ = [["direct (one process)", f"{t_direct:.1f}", *(f"{direct[s]:.1f}" for s in stages), "-",
              f"{peak_direct / 2**20:,.0f} (largest stage)"],
             ["one task on a local Dask cluster", f"{got['dask']:.1f}", *(f"{got[s]:.1f}" for s in stages),
              f"{got['cluster_start']:.1f}", f"{got['peak'] / 2**20:,.0f} (whole task)"]]
    print()
    table = print_table([f"{got['cubes']:,} cubes, {got['dofs']:,} DOFs", "wall s", *(f"{s} s" for s in stages),
                         "cluster start s", "peak MiB"], rows_)
    line = f"6 modes by {got['method']} ({got.get('iterations')} iterations), f1 {got['f_hz'][0]:.4g} Hz"
    print(line)
    return f"{table}\n\n{line}"


def side(n_cubes: float) -> int:
    """``a`` of a 4a x a x a bar with about ``n_cubes`` cubes."""
    return max(2, int(round((n_cubes / 4.0) ** (1.0 / 3.0))))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="10k, 30k and 100k cubes")
    ap.add_argument("--sizes", type=int, nargs="*", default=None, help="approximate cube counts")
    ap.add_argument("--modes-up-to", type=int, default=2_000_000,
                    help="skip the modes and bake stages above this many cubes (they take longest)")
    ap.add_argument("--dask", type=int, default=0, metavar="CUBES",
                    help="also run the whole pipeline at about this many cubes as one task on a local Dask "
                         "cluster (one worker process) and compare it with the same pipeline run directly")
    ap.add_argument("--compare", type=int, default=46240,
                    help="cubes of the size where shift-invert and LOBPCG run side by side (default: the "
                         "92 x 23 x 23-cube cantilever of 158,976 free DOFs; 0 to skip)")
    args = ap.parse_args(argv)
    sizes = args.sizes or ((10_000, 30_000, 100_000) if args.quick else (10_000, 30_000, 100_000, 300_000, 1_000_000))
    rows, series = [], {s: [] for s in ("voxelize", "assemble", "modes", "bake")}
    for n in sizes:
        a = side(n)
        r = {"a": a}
        for stage in ("voxelize", "assemble", "modes"):       # a fresh process per stage; "modes" also bakes
            if stage == "modes" and 4 * a**3 > args.modes_up_to:
                r["modes"] = r["bake"] = None
                continue
            got = run_stage(a, stage)
            if stage == "modes" and "does not fit in memory" in got.get("error", ""):
                # "auto" refuses when no solver's estimate fits its budget (half the free memory; at a
                # million cubes): LOBPCG asked for by name, as a user would do, and the row says so
                refused = got["error"]
                got = run_stage(a, stage, "lobpcg")
                if "error" not in got:
                    got["method"], got["reason"] = "lobpcg (asked: auto refused)", refused[:120]
            if "error" in got:
                r[stage] = got["error"]
                print(f"[{4 * a**3:,} cubes] {stage} FAILED: {got['error']}", file=sys.stderr, flush=True)
                break
            r.update({k: got[k] for k in ("cubes", "dofs", "method", "reason", "f_hz", "vertices", "iterations")
                      if k in got})
            for done in (stage, "bake") if stage == "modes" else (stage,):
                r[done], r[f"{done}_peak"] = got[done], got[f"{done}_peak"]
                series[done].append((got["cubes"], got[done], got[f"{done}_peak"]))
                print(f"[{got['cubes']:,} cubes] {done}: {got[done]:.2f} s, peak +{got[f'{done}_peak'] / 2**20:,.0f} MiB"
                      + (f" ({got['method']}, {got['iterations']} iterations: {got['reason']})" if done == "modes" else ""),
                      file=sys.stderr, flush=True)
        rows.append(r)

    def cell(r, s):
        v = r.get(s)
        if v is None:
            return "-"
        if isinstance(v, str):
            return "failed"
        return f"{v:.2f} s / {r[f'{s}_peak'] / 2**20:,.0f} MiB"

    table = [[f"{r.get('cubes', 4 * r['a'] ** 3):,}", f"{r.get('dofs', 0):,}", cell(r, "voxelize"), cell(r, "assemble"),
              cell(r, "modes"), r.get("method", "-"), cell(r, "bake"),
              "-" if "f_hz" not in r else f"{r['f_hz'][0]:.4g}"] for r in rows]
    text = print_table(["cubes", "free DOFs", "voxelize", "assemble K, M", "6 modes", "solver (auto)", "bake",
                        "f1 Hz (Euler-Bernoulli: 51.0)"], table)
    slopes = []
    for stage, pts in series.items():
        if len(pts) >= 2:
            e = np.array(pts, dtype=float)
            pt = np.polyfit(np.log(e[:, 0]), np.log(e[:, 1]), 1)[0]
            pm = np.polyfit(np.log(e[:, 0]), np.log(np.maximum(e[:, 2], 2.0**20)), 1)[0]   # floor: 1 MiB
            slopes.append([stage, f"{pt:.2f}", f"{pm:.2f}"])
    print()
    text += "\n\n" + print_table(["stage", "time ~ cubes^p", "peak memory ~ cubes^p"], slopes)
    if args.compare:
        a = side(args.compare)
        cmp_rows = []
        # the eigensolve alone by each method, then sc_fem.modal end to end (assembly + eigensolve + bake)
        for stage, method in (("modes", "shift-invert"), ("modes", "lobpcg"), ("modes", "auto"), ("modal", "auto")):
            got = run_stage(a, stage, method)
            asked = method if stage == "modes" else "sc_fem.modal, auto (end to end)"
            cmp_rows.append([asked, f"{got.get('dofs', 0):,}",
                             "failed" if "error" in got else f"{got[stage]:.2f}",
                             "-" if "error" in got else f"{got['peak'] / 2**20:,.0f}",
                             got.get("method", "-"), got.get("reason", got.get("error", ""))[:90]])
            print(f"[compare] {asked}: {cmp_rows[-1][2]} s", file=sys.stderr, flush=True)
        print()
        text += "\n\n" + print_table(["asked", "free DOFs", "6 modes, s", "peak MiB", "ran", "reason"], cmp_rows)
    if args.dask:
        text += "\n\n" + dask_comparison(side(args.dask), rows)
    with open(out_path("scale.md"), "w") as fh:
        fh.write(text + "\n")

    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    slope = {row[0]: (row[1], row[2]) for row in slopes}
    for stage, pts in series.items():
        if pts:
            e = np.array(pts, dtype=float)
            pt, pm = slope.get(stage, ("-", "-"))
            ax[0].loglog(e[:, 0], e[:, 1], "o-", label=f"{stage} (~cubes^{pt})")
            ax[1].loglog(e[:, 0], np.maximum(e[:, 2], 2.0**20) / 2**20, "o-", label=f"{stage} (~cubes^{pm})")
    ax[0].set(xlabel="cubes", ylabel="wall time, s", title="time per stage (fresh process each)")
    ax[1].set(xlabel="cubes", ylabel="peak memory added, MiB (floored at 1)", title="peak memory per stage")
    for a_ in ax:
        a_.grid(True, which="both", alpha=0.3)
        a_.legend(fontsize=8)
    save_figure(fig, "scale.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
