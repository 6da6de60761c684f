"""sc_fem's cubes against a conforming reference from outside the project (TetGen + scikit-fem P2).

For closed solids (the shared meshes spot and bunny, the built-in chair and beam): the conforming
quadratic-tetrahedron reference at two densities (to show it converged), and sc_fem at several
resolutions for each element: total mass, the 10 lowest free-free frequencies (mean and max
relative error), the largest displacement of a clamped case under gravity (the lowest 2 % of the
height held), cubes and wall time (voxelize + assemble + eigensolve; the static solve is timed
apart). Prints a Markdown table and the measured convergence rates, writes
``benchmarks/out/vs_conforming_fem.png`` (error against wall time, the reference's time marked)
and ``benchmarks/out/vs_conforming_fem.md``.

    python benchmarks/vs_conforming_fem.py            # resolutions 16, 24, 32, 48, 64 (~25 min)
    python benchmarks/vs_conforming_fem.py --quick    # resolutions 16, 24, 32, fewer tets
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import numpy as np
from _common import SHARED_MESHES, out_path, print_table, save_figure

import sc_fem
from sc_fem.fem.reference import solve_reference

ELEMENTS = ("q1", "q1sri", "q1i")
AXES = "xyz"


def cases():
    soft = dict(youngs=1e7, poisson=0.3, density=1000.0)
    out = []
    for name, up in (("spot.obj", "y"), ("bunny.obj", "y")):
        path = SHARED_MESHES / name
        if path.exists():
            out.append((name.split(".")[0], str(path), soft, up))
        else:
            print(f"(skipping {name}: {path} not found)", file=sys.stderr)
    chair = sc_fem.models.material("builtin:chair")
    beam = sc_fem.models.material("builtin:beam")
    out.append(("chair", "builtin:chair", dict(youngs=chair.youngs, poisson=chair.poisson, density=chair.density), "z"))
    out.append(("beam", "builtin:beam", dict(youngs=beam.youngs, poisson=beam.poisson, density=beam.density), "x"))
    return out


def clamp_spec(mesh, up: str) -> tuple[str, float, np.ndarray]:
    """'AXIS<min+d' holding the lowest 2 % along ``up``, and gravity along ``-up``. The beam is a
    cantilever: held at its root face x = min (both sides), loaded along -z."""
    a = AXES.index(up)
    ext = float(np.ptp(np.asarray(mesh.vertices)[:, a]))
    g = np.zeros(3)
    g[2 if up == "x" else a] = -9.81
    d = (1e-6 if up == "x" else 0.02) * ext
    return f"{up}<min+{d:.6g}", d, g


def run_sc_fem(path, mat, up, r, element):
    mesh = sc_fem.load_mesh(path)
    spec, _, g = clamp_spec(mesh, up)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = sc_fem.voxelize(mesh, resolution=r, **mat)
    t_vox = time.perf_counter() - t0
    t0 = time.perf_counter()
    basis = sc_fem.modal(model, n_modes=10, element=element)
    t_modal = time.perf_counter() - t0
    t0 = time.perf_counter()
    st = sc_fem.solve_static(model, element=element, fix=spec, gravity=g, mesh=mesh)
    t_static = time.perf_counter() - t0
    umax = float(np.linalg.norm(st.vertex_displacements, axis=1).max())
    return dict(cubes=model.n_cubes, mass=model.total_mass, freqs=basis.frequencies[:10], umax=umax,
                seconds=t_vox + t_modal, static_seconds=t_static)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="resolutions 16, 24, 32 and a coarser reference")
    ap.add_argument("--cases", nargs="*", default=None, help="subset of: spot bunny chair beam")
    ap.add_argument("--tag", default="", help="suffix of the output names (runs of different cases side by side)")
    ap.add_argument("--resolutions", type=int, nargs="*", default=None, help="override the resolutions")
    ap.add_argument("--elements", nargs="*", default=list(ELEMENTS), help=f"subset of {ELEMENTS}")
    args = ap.parse_args(argv)
    resolutions = args.resolutions or ((16, 24, 32) if args.quick else (16, 24, 32, 48, 64))
    tets = (1500, 4000) if args.quick else (3000, 8000)     # TetGen makes about 2.5x as many
    rows, series, rates = [], {}, []
    for name, path, mat, up in cases():
        if args.cases and name not in args.cases:
            continue
        mesh = sc_fem.load_mesh(path)
        _, d, g = clamp_spec(mesh, up)
        a = AXES.index(up)
        lo = float(np.asarray(mesh.vertices)[:, a].min())
        refs = []
        for n in tets:
            ref = solve_reference(mesh, n_tets=n, n_modes=10, clamp=lambda p, a=a, lo=lo, d=d: p[:, a] < lo + d,
                                  gravity=g, **mat)
            refs.append(ref)
            print(f"[{name}] reference {ref.n_tets} P2 tets, {ref.n_dofs} DOFs: {ref.seconds:.1f} s, "
                  f"f = {np.round(ref.frequencies[:4], 3)} Hz; surface: {ref.repair}", file=sys.stderr, flush=True)
        coarse, ref = refs
        conv = float(np.max(np.abs(coarse.frequencies - ref.frequencies) / ref.frequencies))
        print(f"[{name}] reference: mass {ref.mass:.6g} kg, max |u| {ref.max_displacement:.4g} m, "
              f"change coarse -> fine {100 * conv:.2f} %", file=sys.stderr, flush=True)
        rows.append([name, "P2 ref (coarse)", "-", coarse.n_tets, f"{coarse.mass:.5g}", "-", "-",
                     f"{coarse.max_displacement:.4g}", f"{coarse.seconds:.1f}"])
        rows.append([name, "P2 ref", "-", ref.n_tets, f"{ref.mass:.5g}",
                     f"{100 * conv:.2f} (vs coarse)", "", f"{ref.max_displacement:.4g}", f"{ref.seconds:.1f}"])
        for element in args.elements:
            errs = []
            for r in resolutions:
                res = run_sc_fem(path, mat, up, r, element)
                fe = np.abs(res["freqs"] - ref.frequencies) / ref.frequencies
                errs.append((r, float(fe.mean()), float(fe.max()), res["seconds"]))
                rows.append([name, element, r, res["cubes"], f"{100 * (res['mass'] / ref.mass - 1):+.2f} %",
                             f"{100 * fe.mean():.2f}", f"{100 * fe.max():.2f}",
                             f"{100 * (res['umax'] / ref.max_displacement - 1):+.1f} %",
                             f"{res['seconds']:.2f} (+{res['static_seconds']:.2f})"])
                print(f"[{name}] {element} r={r}: {res['cubes']} cubes, mass {100 * (res['mass'] / ref.mass - 1):+.2f} %, "
                      f"f mean {100 * fe.mean():.2f} %, max {100 * fe.max():.2f} %, "
                      f"|u| {100 * (res['umax'] / ref.max_displacement - 1):+.1f} %, {res['seconds']:.1f} s",
                      file=sys.stderr, flush=True)
            series[name, element] = errs
            e = np.array(errs)
            slope = float(np.polyfit(np.log(1.0 / e[:, 0]), np.log(np.maximum(e[:, 1], 1e-12)), 1)[0])
            hit = [x for x in errs if x[1] <= 0.05]
            speed = f"{ref.seconds / hit[0][3]:.0f}x" if hit else "not reached"
            rates.append([name, element, f"{slope:.2f}", hit[0][0] if hit else "-", speed])
        series[name, "ref"] = ref.seconds
    text = print_table(["case", "model", "res", "cubes / tets", "mass", "mean f err %", "max f err %",
                        "max |u| (clamped, gravity)", "time s (+static)"], rows)
    print()
    text2 = print_table(["case", "element", "rate (mean f err ~ h^p)", "res reaching 5 %",
                         "speed-up vs reference there"], rates)
    tag = f"_{args.tag}" if args.tag else ""
    with open(out_path(f"vs_conforming_fem{tag}.md"), "w") as fh:
        fh.write(text + "\n\n" + text2 + "\n")

    import matplotlib.pyplot as plt

    names = sorted({k[0] for k in series})
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 3.8), squeeze=False)
    for ax, name in zip(axes[0], names):
        for element in args.elements:
            e = np.array(series[name, element])
            ax.loglog(e[:, 3], 100 * e[:, 1], "o-", label=f"sc_fem {element}")
            for r, _, _, t in series[name, element]:
                if element == "q1i":
                    ax.annotate(str(int(r)), (t, 100 * e[e[:, 0] == r][0, 1]), fontsize=7,
                                textcoords="offset points", xytext=(3, 3))
        ax.axvline(series[name, "ref"], color="k", ls="--", lw=1, label="P2 reference time")
        ax.axhline(5, color="0.6", lw=0.8)
        ax.set_title(name)
        ax.set_xlabel("wall time, s (voxelize + assemble + 10 modes)")
        ax.set_ylabel("mean error of 10 free-free frequencies, %")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=7)
    save_figure(fig, f"vs_conforming_fem{tag}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
