"""Voxelize against a voxelizer: sc_fem.voxelize beside trimesh's ``voxelized(pitch).fill()`` in one run.

Usage: python benchmarks/voxelize_speed.py [--baseline-src DIR] [--repeat N]

Cases: the built-in chair at 32, the bunny at 64, the armchair at 32, a 57-member truss bridge in
millimetres (``tests/shapes.truss_bridge_mm(panels=10)``, subdivided to ~44k triangles) at 32 and
spot at 64 (the shared meshes are skipped with a note when absent). trimesh's voxels are
surface-crossing cubes plus flood fill: no mass, moments, material, bodies or overlaps, so the
ratio is what our extra work costs. ``--baseline-src`` times the same cases with another source
tree of sc_fem (e.g. a ``git worktree`` of an older commit) in a subprocess, in the same run.
Prints a Markdown table and writes ``benchmarks/out/voxelize_speed.png``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import trimesh

from _common import SHARED_MESHES, best_time, print_table, save_figure

HERE = Path(__file__).resolve().parent
TARGETS = {"chair": 0.2, "truss (mm)": 3.0}


def cases() -> list[tuple[str, object, int, float]]:
    """(label, mesh, resolution, scale) of every case whose mesh is present."""
    import sc_fem

    sys.path.insert(0, str(HERE.parent / "tests"))
    import shapes

    truss = shapes.truss_bridge_mm(panels=10)
    for _ in range(3):
        truss = truss.subdivide()
    out = [("chair", sc_fem.load_mesh("builtin:chair"), 32, 1.0)]
    for name, label, res in (("bunny.obj", "bunny", 64), ("chair_armchair.off", "armchair", 32)):
        if (SHARED_MESHES / name).is_file():
            out.append((label, sc_fem.load_mesh(str(SHARED_MESHES / name)), res, 1.0))
        else:
            print(f"note: {SHARED_MESHES / name} absent, case skipped", file=sys.stderr)
    out.append(("truss (mm)", truss, 32, 1e-3))
    if (SHARED_MESHES / "spot.obj").is_file():
        out.append(("spot", sc_fem.load_mesh(str(SHARED_MESHES / "spot.obj")), 64, 1.0))
    return out


def time_sc_fem(repeat: int) -> dict[str, dict]:
    """Best-of-``repeat`` voxelize time per case (after one warm-up call that compiles kernels)."""
    import sc_fem

    res = {}
    for label, mesh, r, scale in cases():
        sc_fem.voxelize(mesh, resolution=r, scale=scale)
        t, m = best_time(lambda: sc_fem.voxelize(mesh, resolution=r, scale=scale), repeat=repeat)
        res[label] = {"t": t, "cubes": int(m.n_cubes), "faces": int(len(mesh.faces)), "res": r,
                      "mass": float(m.total_mass)}
        print(f"  {label} r={r}: {t:.3f} s, {m.n_cubes} cubes", file=sys.stderr)
    return res


def time_trimesh(repeat: int) -> dict[str, float]:
    out = {}
    for label, mesh, r, _ in cases():
        tm = trimesh.Trimesh(np.asarray(mesh.vertices), np.asarray(mesh.faces), process=False)
        pitch = float(np.ptp(tm.vertices, axis=0).max()) / r
        out[label], _ = best_time(lambda: tm.voxelized(pitch).fill(), repeat=repeat)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--baseline-src", type=Path, help="another sc_fem source tree to time in a subprocess")
    ap.add_argument("--repeat", type=int, default=2, help="best of N calls (default 2)")
    ap.add_argument("--json", action="store_true", help=argparse.SUPPRESS)     # the subprocess's output
    args = ap.parse_args(argv)
    ours = time_sc_fem(args.repeat)
    if args.json:
        print(json.dumps(ours))
        return 0
    base = {}
    if args.baseline_src:
        env = dict(os.environ, PYTHONPATH=str(args.baseline_src.resolve()))
        run = subprocess.run([sys.executable, __file__, "--json", "--repeat", str(args.repeat)], env=env,
                             capture_output=True, text=True, check=True)
        base = json.loads(run.stdout.strip().splitlines()[-1])
    peer = time_trimesh(args.repeat)
    rows = []
    for label, o in ours.items():
        b = base.get(label, {}).get("t", float("nan"))
        rows.append([label, o["faces"], o["res"], o["cubes"], o["t"], peer[label], o["t"] / peer[label],
                     b, b / o["t"], TARGETS.get(label, float("nan"))])
    print_table(["case", "faces", "res", "cubes", "sc_fem [s]", "trimesh fill [s]", "sc_fem/trimesh",
                 "baseline [s]", "speed-up", "target [s]"], rows)
    fig, ax = plt.subplots(figsize=(8, 4))
    x = np.arange(len(rows))
    ax.bar(x - 0.27, [r[4] for r in rows], 0.27, label="sc_fem.voxelize")
    if base:
        ax.bar(x, [r[7] for r in rows], 0.27, label="sc_fem baseline")
    ax.bar(x + 0.27, [r[5] for r in rows], 0.27, label="trimesh voxelized().fill()")
    ax.set_xticks(x, [f"{r[0]}\nr{r[2]}" for r in rows])
    ax.set(yscale="log", ylabel="wall time [s]", title="voxelize, one run (best of %d)" % args.repeat)
    ax.legend()
    ax.grid(True, axis="y", which="both", alpha=0.3)
    save_figure(fig, "voxelize_speed.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
