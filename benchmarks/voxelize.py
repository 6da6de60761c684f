"""Voxelization time and cube count per mesh and resolution, sampling vs exact, in one run.

Usage: python benchmarks/voxelize.py [--quick]
Writes benchmarks/out/voxelize.png and prints a Markdown table (ratios exact / sample).
"""

from __future__ import annotations

import argparse
import sys

import matplotlib.pyplot as plt

import sc_fem
from _common import SHARED_MESHES, best_time, print_table, save_figure


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer resolutions and meshes")
    args = ap.parse_args(argv)
    resolutions = [16, 32, 64] if args.quick else [16, 32, 64, 128]
    sources = [f"builtin:{n}" for n in ("chair", "bridge", "rope", "beam")]
    if SHARED_MESHES.is_dir():
        sources += [str(p) for p in sorted(SHARED_MESHES.glob("*")) if p.suffix in (".obj", ".off", ".stl")]
    if args.quick:
        sources = sources[:6]
    rows, series = [], {}
    for src in sources:
        mesh = sc_fem.load_mesh(src)
        label = mesh.metadata["source"]
        for res in resolutions:
            ts, ms = best_time(lambda: sc_fem.voxelize(mesh, resolution=res, keep="all"), repeat=2)
            te, me = best_time(lambda: sc_fem.voxelize(mesh, resolution=res, keep="all", occupancy="exact"), repeat=2)
            rows.append([label, len(mesh.faces), res, ms.n_cubes, me.n_cubes, ms.info["n_samples"],
                         ts, te, te / ts])
            series.setdefault(label, []).append((res, ts, te, ms.n_cubes))
            print(f"  {label} r={res}: sample {ts:.3f} s, exact {te:.3f} s", file=sys.stderr)
    print_table(["mesh", "faces", "res", "cubes (sample)", "cubes (exact)", "samples", "t sample [s]",
                 "t exact [s]", "exact/sample"], rows)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    for label, pts in series.items():
        r = [p[0] for p in pts]
        line, = axes[0].loglog(r, [p[1] for p in pts], "o-", label=label)
        axes[0].loglog(r, [p[2] for p in pts], "s--", color=line.get_color())
        axes[1].loglog([p[3] for p in pts], [p[1] for p in pts], "o-", color=line.get_color())
    axes[0].set(xlabel="resolution (cubes along longest axis)", ylabel="wall time [s]",
                title="voxelize: sampling (solid) vs exact overlap (dashed)")
    axes[1].set(xlabel="cubes", ylabel="wall time [s] (sampling)", title="time vs model size")
    axes[0].legend(fontsize=7)
    for a in axes:
        a.grid(True, which="both", alpha=0.3)
    save_figure(fig, "voxelize.png", dpi=120)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
