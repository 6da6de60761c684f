"""Bodies from geometry (``topology="pieces"``) against the seed's grid topology.

Two questions, side by side in one run:

1. **Does the number of free bodies depend on the resolution?** Lattice components kept
   (``keep="bodies"`` for pieces; ``keep="all"`` for the grid, which keeps everything the cubes
   join) at resolutions 8, 16, 32, 64 for the built-ins and the test shapes of ``tests/shapes.py``.
2. **What does it cost?** voxelize + assemble (K and M, default element) at resolution 32, best of
   3, pieces / grid as a ratio from the same run (the issue's budget: within 2x).

Writes ``benchmarks/out/bodies.{md,json}`` and ``docs/bodies.png`` (bodies against resolution).

    python benchmarks/bodies.py            # ~5 min (18 min when the machine is busy)
    python benchmarks/bodies.py --chart    # redraw the chart from benchmarks/out/bodies.json
"""

from __future__ import annotations

import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from _common import best_time, out_path, print_table, save_figure

import sc_fem
from sc_fem.fem.assemble import assemble

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import shapes  # noqa: E402

RESOLUTIONS = (8, 16, 32, 64)
CASES = {
    "chair": lambda: "builtin:chair",
    "bridge": lambda: "builtin:bridge",
    "rope": lambda: "builtin:rope",
    "beam": lambda: "builtin:beam",
    "two plates 5 mm apart": lambda: shapes.two_plates(),
    "boxes 10 mm apart": lambda: shapes.near_touching_boxes(gap=0.01),
    "slatted chair (soup)": lambda: shapes.slatted_chair(),
    "toy truck": lambda: shapes.toy_truck(),
    "truss bridge (mm)": lambda: shapes.truss_bridge_mm(),
}


def scale_of(name: str) -> float:
    return 0.001 if "(mm)" in name else 1.0


def main() -> int:
    warnings.simplefilter("ignore")
    rows_b, rows_t, record = [], [], {}
    for name, make in CASES.items():
        mesh = make()
        s = scale_of(name)
        counts = {}
        for topo, keep in (("grid", "all"), ("pieces", "bodies")):
            counts[topo] = [sc_fem.voxelize(mesh, resolution=r, topology=topo, keep=keep, scale=s).n_components
                            for r in RESOLUTIONS]
        times = {}
        for topo, keep in (("grid", "all"), ("pieces", "bodies")):
            def job():
                m = sc_fem.voxelize(mesh, resolution=32, topology=topo, keep=keep, scale=s)
                assemble(m)
                return m
            times[topo], m = best_time(job, 3)
        info = m.info
        rows_b.append([name, " ".join(map(str, counts["grid"])), " ".join(map(str, counts["pieces"])),
                       info.get("bodies", 1), info.get("loose_bodies", 0)])
        rows_t.append([name, m.n_cubes, times["grid"], times["pieces"], times["pieces"] / times["grid"]])
        record[name] = dict(counts=counts, seconds=times, bodies=info.get("bodies"), loose=info.get("loose_bodies"),
                            weld=info.get("weld"), welds_by_distance=info.get("welds_by_distance"),
                            welds_by_containment=info.get("welds_by_containment"))
        print(f"{name}: bodies {counts}, voxelize+assemble r32 grid {times['grid']:.2f} s, pieces "
              f"{times['pieces']:.2f} s", flush=True)
    t1 = print_table(["case", "components, grid (r8 r16 r32 r64)", "bodies kept, pieces (r8 r16 r32 r64)",
                      "bodies found", "loose"], rows_b)
    t2 = print_table(["case", "cubes r32", "grid s", "pieces s", "pieces / grid"], rows_t, floatfmt=".3g")
    print(t1)
    print()
    print(t2)
    out_path("bodies.md").write_text(f"{t1}\n\n{t2}\n")
    out_path("bodies.json").write_text(json.dumps(record, indent=1))
    chart(record)
    return 0


def chart(record: dict):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    for ax, topo, title in ((axes[0], "grid", "grid topology (the seed's cubes)"),
                            (axes[1], "pieces", "pieces topology (bodies from geometry, default)")):
        for i, (name, rec) in enumerate(record.items()):
            ax.plot(RESOLUTIONS, np.array(rec["counts"][topo]) + 0.04 * (i - len(record) / 2), "o-", label=name,
                    lw=1.4, ms=4)
        ax.set_xscale("log", base=2)
        ax.set_xticks(RESOLUTIONS, [str(r) for r in RESOLUTIONS])
        ax.set_xlabel("resolution (cubes along the longest side)")
        ax.set_title(title, fontsize=10)
        ax.set_yticks([1, 2])
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("free bodies in the lattice (connected components)")
    axes[1].legend(fontsize=7, loc="upper left")
    fig.suptitle("Does the number of free bodies change with the resolution? (lines offset slightly to separate)",
                 fontsize=10)
    fig.tight_layout()
    import shutil

    path = save_figure(fig, "bodies.png")
    shutil.copyfile(path, Path(__file__).resolve().parents[1] / "docs" / "bodies.png")
    return path


if __name__ == "__main__":
    if "--chart" in sys.argv[1:]:
        chart(json.loads(out_path("bodies.json").read_text()))
        sys.exit(0)
    t0 = time.perf_counter()
    rc = main()
    print(f"total {time.perf_counter() - t0:.0f} s")
    sys.exit(rc)
