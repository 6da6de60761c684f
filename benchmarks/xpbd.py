"""XPBD on the 4 m cantilever bar against linear FEM, the peers' figures, and a large-step sweep.

Bar: 4 m x 0.5 m x 0.5 m, 48 x 6 x 6 cubes (2,401 nodes), E = 50 MPa, nu = 0.3, rho = 950 kg/m^3
(the lattice's linear FEM gives the -0.287 m static tip sag used for the peers), fixed at x = 0,
released from rest under gravity.  From the tip's free vibration about its sagged position:

* static sag  = mean tip z over whole periods (between the first and last upward crossing);
* period      = from the crossings of the mean;
* log decrement of successive downward peaks (numerical damping of substepping);

compared with linear FEM (``solve_static``, default element; first period from ``eigsh`` of the
same lattice's K, M, shift-invert with a small negative sigma), as ratios, with ms/frame at 60 fps,
side by side with the peers' figures measured while planning (not re-run here).  Then a large
substep sweep (0.1-16 ms) on a coarser bar: energy growth and blow-up per constraint family
(``sc_fem.dynamics.xpbd_stability.stability_sweep``).  Writes benchmarks/out/xpbd.png.

Usage: python benchmarks/xpbd.py [--quick]     (default ~3-4 min, --quick < 1 min on 2 cores)
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import print_table, save_figure  # noqa: E402

from sc_fem.errors import InstabilityError  # noqa: E402
from sc_fem.lattice.cubes import CubeModel  # noqa: E402
from sc_fem.dynamics.xpbd import XPBDSolver  # noqa: E402
from sc_fem.dynamics.xpbd_stability import stability_sweep  # noqa: E402

# peers, measured while planning on the same bar (not re-run here): (name, sag / linear FEM, ms/frame)
PEER_TAG = " (measured while planning)"
PEERS = [("pypbd FEM-XPBD 5x1", 7.3, 5.5), ("pypbd FEM-XPBD 400 substeps", 2.7, 830.0),
         ("pbatoolkit stable NH XPBD 50 substeps", 1.2, 249.0), ("NVIDIA Newton XPBD default", np.inf, np.nan)]


def bar(nx: int) -> CubeModel:
    return CubeModel.box((nx, nx // 8, nx // 8), 4.0 / nx, youngs=50e6, poisson=0.3, density=950.0)


def linear_fem(m: CubeModel):
    """Static tip sag (m, mean over the tip face), static displacements (m, 3), first period (s)."""
    import scipy.sparse.linalg as sla

    from sc_fem.fem.assemble import assemble
    from sc_fem.lattice.boundary import fixed_dofs
    from sc_fem.fem.static import solve_static

    tip = m.node_index[:, 0] == m.dims[0]
    u = solve_static(m, fix="x<0.01", gravity=(0, 0, -9.81)).displacements
    K, M = assemble(m, fixed_dofs=fixed_dofs(np.flatnonzero(m.node_index[:, 0] == 0)))
    w2 = sla.eigsh(K, k=2, M=M, sigma=-1.0, which="LM", return_eigenvectors=False)
    return float(u[tip, 2].mean()), u, float(2 * np.pi / np.sqrt(w2.min()))


def vibration(t: np.ndarray, z: np.ndarray):
    """Mean over whole periods, period and mean log decrement of a decaying oscillation z(t)."""
    mid = 0.5 * (z.max() + z[len(z) // 3:].min()) if len(z) > 6 else z.mean()
    for _ in range(3):                                  # re-centre on the whole-period mean
        s = np.sign(z - mid)
        i = np.flatnonzero((s[:-1] < 0) & (s[1:] >= 0))  # upward crossings
        tc = t[i] - (z[i] - mid) * (t[i + 1] - t[i]) / (z[i + 1] - z[i])
        if len(i) < 2:
            return np.nan, np.nan, np.nan
        sel = slice(i[0] + 1, i[-1] + 1)
        mid = float(np.mean(z[sel]))
    period = float((tc[-1] - tc[0]) / (len(tc) - 1))
    # downward peaks: before the first upward crossing, then one per whole period
    amp = np.abs(np.array([z[: i[0] + 1].min()] + [z[a:b].min() for a, b in zip(i[:-1], i[1:])]) - mid)
    dec = float(np.mean(np.log(amp[:-1] / amp[1:]))) if len(amp) > 1 else np.nan
    return mid, period, dec


def run_setting(m, fixed, tip, kind, ss, it, warm, seconds, kernel="auto"):
    s = XPBDSolver(m, 1 / 60, substeps=ss, iterations=it, constraints=kind, fixed_nodes=fixed, warm_start=warm,
                   kernel=kernel)
    if s.kernel == "numba":
        XPBDSolver(m, 1e-5, substeps=1, fixed_nodes=fixed, kernel="numba").step()   # compile outside the timing
    z0 = m.nodes_m[tip, 2].mean()
    z, t0 = [], time.perf_counter()
    blew = ""
    try:
        for _ in range(int(round(seconds * 60))):
            z.append(s.step().positions[tip, 2].mean() - z0)
    except InstabilityError as e:
        blew = str(e).split(":")[0]
    ms = (time.perf_counter() - t0) / max(len(z), 1) * 1e3
    if blew:
        return dict(sag=np.nan, period=np.nan, dec=np.nan, peak=np.nan, ms=ms, blew=blew)
    z = np.array(z)
    sag, period, dec = vibration(np.arange(1, len(z) + 1) / 60, z)
    return dict(sag=sag, period=period, dec=dec, peak=float(z.min()), ms=ms, blew="")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="24 x 3 x 3 bar, fewer settings (< 1 min)")
    args = ap.parse_args(argv)
    nx = 24 if args.quick else 48
    m = bar(nx)
    fixed = np.flatnonzero(m.node_index[:, 0] == 0)
    tip = m.node_index[:, 0] == nx
    ref_sag, _, ref_T = linear_fem(m)
    print(f"bar {m.dims} cubes, {m.n_nodes} nodes: linear FEM static tip sag {ref_sag:.4f} m, "
          f"first period {ref_T:.4f} s")
    from sc_fem.dynamics import xpbd_jit

    # the Neo-Hookean Gauss-Seidel sweep runs compiled (numba) when installed, else numpy: both measured
    kernels = ["numba", "numpy"] if xpbd_jit.available() else ["numpy"]
    settings = [("neohookean", 25, 1, False, k) for k in kernels] + \
        [("neohookean", 50, 1, False, k) for k in kernels] + [("neohookean", 100, 1, False, kernels[0]),
                                                              ("neohookean", 50, 1, True, kernels[0]),
                                                              ("neohookean", 25, 2, False, kernels[0]),
                                                              ("corotational", 50, 1, False, "numpy"),
                                                              ("distance", 50, 1, True, "numpy")]
    if args.quick:
        settings = [("neohookean", 25, 1, False, k) for k in kernels] + \
            [("neohookean", 50, 1, False, k) for k in kernels] + [("neohookean", 50, 1, True, kernels[0]),
                                                                  ("corotational", 50, 1, False, "numpy")]
    seconds = 2.6 * ref_T
    rows, pts, ms_of = [], [], {}
    for kind, ss, it, warm, kernel in settings:
        r = run_setting(m, fixed, tip, kind, ss, it, warm, seconds, kernel)
        name = f"sc_fem {kind} {ss}x{it}{' warm' if warm else ''} [{kernel}]"
        ms_of[(kind, ss, it, warm, kernel)] = r["ms"]
        rows.append([name, f"{1e3 / 60 / ss:.3g}", r["sag"], r["sag"] / ref_sag, r["period"] / ref_T,
                     r["dec"], r["dec"] / (2 * np.pi), r["peak"] / (2 * ref_sag), r["ms"], r["blew"] or "no"])
        pts.append((name, r["ms"], abs(r["sag"] / ref_sag - 1), abs(r["period"] / ref_T - 1)))
        print(f"  {name}: done", file=sys.stderr, flush=True)
    for name, ratio, ms in PEERS:
        rows.append([name + PEER_TAG, "", ratio * ref_sag, ratio, np.nan, np.nan, np.nan, np.nan, ms, ""])
        pts.append((name + PEER_TAG, ms, abs(ratio - 1), np.nan))
    print_table(["method", "substep ms", "static sag m", "sag/FEM", "period/FEM", "log dec", "zeta",
                 "peak/(2 FEM sag)", "ms/frame", "blew up"], rows)
    for ss in (25, 50):
        a, b = ms_of.get(("neohookean", ss, 1, False, "numpy")), ms_of.get(("neohookean", ss, 1, False, "numba"))
        if a and b:
            print(f"neohookean {ss}x1: numpy sweep / compiled sweep = {a / b:.2f}x ({a:.1f} vs {b:.1f} ms/frame)")

    # large-substep stability sweep on a coarse bar
    mc = bar(16 if args.quick else 24)
    fc = np.flatnonzero(mc.node_index[:, 0] == 0)
    _, uc, Tc = linear_fem(mc)
    damp = 2 * (2 * np.pi / Tc)          # critical for the first mode: settles in ~1 s
    dts = [1e-4, 2.5e-4, 5e-4, 1e-3, 2e-3, 4e-3, 8e-3, 16e-3]
    if args.quick:
        dts = [2.5e-4, 1e-3, 4e-3, 16e-3]
    srows = []
    for kind in ("neohookean", "corotational"):
        for r in stability_sweep(mc, dts, duration=0.6 if args.quick else 1.0, fixed_nodes=fc, reference=uc,
                                 constraints=kind, damping=damp):
            srows.append([kind, r.dt * 1e3, r.max_energy_growth, "yes" if r.blew_up else "no", r.error,
                          r.ms_per_second])
    print(f"\nlarge-substep sweep, bar {mc.dims} cubes, released from rest, 1 iteration, "
          f"damping {damp:.3g}/s (energy growth in units of M |g| diameter; error = |u(end) - u_FEM| / |u_FEM|):")
    print_table(["constraints", "substep ms", "max energy growth", "blew up", "final-u error", "ms per sim s"],
                srows)

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import matplotlib.ticker  # noqa: F401

    fig = plt.figure(figsize=(11, 5.6))
    gs = fig.add_gridspec(2, 2, height_ratios=(4.2, 1.0))
    axs = [fig.add_subplot(gs[0, 0]), fig.add_subplot(gs[0, 1])]
    leg = fig.add_subplot(gs[1, :])
    leg.axis("off")
    for ax, k, lab in ((axs[0], 2, "|static sag / FEM - 1|"), (axs[1], 3, "|period / FEM - 1|")):
        for name, ms, *errs in pts:
            e = errs[k - 2]
            if np.isfinite(ms) and np.isfinite(e):
                ax.scatter(ms, max(e, 1e-4), label=name, marker="o" if name.startswith("sc_fem") else "s")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("ms / frame (60 fps)")
        ax.set_ylabel(lab)
        ax.grid(True, which="both", lw=0.3)
    leg.legend(*axs[0].get_legend_handles_labels(), fontsize=7, loc="center", ncol=3, frameon=False)
    fig.suptitle(f"XPBD on the 4 m bar ({m.n_nodes} nodes) vs linear FEM")
    save_figure(fig, "xpbd.png", dpi=120)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
