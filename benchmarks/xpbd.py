"""XPBD on the 4 m bar (E = 50 MPa, nu = 0.3, 0.5 m square section, 48 x 6 x 6 cubes = 2,401 nodes,
rho = 950 kg/m^3 so that the lattice's linear FEM (q1i) gives the -0.287 m static tip sag used for the
peers), 200 frames at 60 fps, released from rest: mean tip sag and ms/frame vs substeps x iterations,
beside the peers' figures measured while planning.  Usage: python benchmarks/xpbd.py [--quick]"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from sc_fem.errors import InstabilityError
from sc_fem.lattice import CubeModel
from sc_fem.xpbd import XPBDSolver

PEERS = [("pypbd FEM-XPBD 5x1", -2.1, 5.5), ("pypbd 400 substeps", -0.287 * 2.7, 830.0),
         ("pbatoolkit SNH 50 substeps", -0.287 * 1.2, 249.0), ("NVIDIA Newton XPBD default", np.nan, np.nan)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="60 frames and fewer settings")
    args = ap.parse_args(argv)
    frames = 60 if args.quick else 200
    m = CubeModel.box((48, 6, 6), 4 / 48, youngs=50e6, poisson=0.3, density=950.0)
    fixed = np.flatnonzero(m.node_index[:, 0] == 0)
    tip = m.node_index[:, 0] == 48
    ref = None
    try:
        from sc_fem.static import solve_static
        ref = float(solve_static(m, fix="x<0.01", gravity=(0, 0, -9.81)).displacements[tip, 2].mean())
    except ImportError:
        pass
    settings = [(20, 1, "neohookean", False), (50, 1, "neohookean", False), (100, 1, "neohookean", False),
                (50, 1, "neohookean", True), (10, 5, "neohookean", False), (50, 1, "distance", False)]
    if args.quick:
        settings = settings[:2] + settings[3:4]
    rows = []
    for ss, it, kind, ws in settings:
        s = XPBDSolver(m, 1 / 60, substeps=ss, iterations=it, constraints=kind, fixed=fixed, warm_start=ws)
        z, t = [], time.perf_counter()
        try:
            for _ in range(frames):
                z.append(s.step().positions[tip, 2].mean() - m.nodes_m[tip, 2].mean())
        except InstabilityError:
            z.append(np.nan)
        ms = (time.perf_counter() - t) / len(z) * 1e3
        z = np.array(z)
        rows.append((f"sc_fem {kind} {ss}x{it}{' warm' if ws else ''}", float(np.mean(z)), float(z.min()), ms))
    print(f"linear FEM static tip sag: {ref}  (peers' reference -0.287 m)")
    print(f"{'method':38s} {'mean sag m':>10s} {'ratio':>6s} {'min m':>8s} {'ms/frame':>9s}")
    for name, mean, lo, ms in rows:
        print(f"{name:38s} {mean:10.3f} {mean / -0.287:6.2f} {lo:8.3f} {ms:9.1f}")
    for name, mean, ms in PEERS:
        print(f"{name:38s} {mean:10.3f} {mean / -0.287:6.2f} {'':8s} {ms:9.1f}")
    out = Path(__file__).parent / "out"
    out.mkdir(exist_ok=True)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 4))
    for name, mean, _, ms in rows + [(n, a, None, b) for n, a, b in PEERS]:
        ax.scatter(ms, mean / -0.287, label=name)
    ax.axhline(1.0, color="k", lw=0.5)
    ax.set_xscale("log")
    ax.set_xlabel("ms / frame")
    ax.set_ylabel("mean sag / linear FEM")
    ax.legend(fontsize=6)
    from sc_fem._atomic import atomic_path
    with atomic_path(out / "xpbd_bar.png") as p:
        fig.savefig(p, dpi=120, format="png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
