"""Implicit time integration: the sparse Cholesky factorization against CG + AMG.

Usage: python benchmarks/newmark_speed.py [--quick]

For every case: the integrator built and stepped with ``solver="direct"`` and with
``solver="cg-amg"`` (:class:`sc_fem.fem.options.DynamicOptions`, default tolerance); wall time
of the whole run (construction, i.e. assembly and the initial acceleration, included), its
solver set-up (factorization or AMG hierarchy), the mean time of a step after the first (the
first one sets up the effective matrix's solver), the CG iterations per step, and the largest
displacement difference of the two trajectories over the run relative to the largest
displacement.

Cases: the Stanford bunny (``bunny.obj`` of the shared meshes; y up, E = 10 MPa, the nodes of the
lowest 2 % held) under gravity with linear Newmark, dt = 2 ms, at resolution 32 and 48; and the
bunny at r24 dropped on a floor with barrier contact (``ipc``: Newton steps with contact), dt =
10 ms, 0.3 s. ``--quick``: r24 and r32 and 20 steps; the default run takes ~5-8 minutes (most of
it the r48 factorization).

This 2-core machine is shared: read the ratios, not the seconds. Writes
benchmarks/out/newmark_speed.png (time against DOFs; CG iterations per step).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import SHARED_MESHES, bunny_scene, print_table, save_figure  # noqa: E402

from sc_fem.dynamics import make_integrator
from sc_fem.dynamics.contact import Ground
from sc_fem.dynamics.ipc import IPC
from sc_fem.dynamics.loads import Gravity, LoadSet

G = (0.0, -9.81, 0.0)


def run(make, n: int) -> dict:
    """Build (timed) and step ``n`` times: total s, per-step s after the first, history, info."""
    t0 = time.perf_counter()
    integ = make()
    steps, us = [], [integ.state.u]
    for _ in range(n):
        ts = time.perf_counter()
        us.append(integ.step().u)
        steps.append(time.perf_counter() - ts)
    total = time.perf_counter() - t0
    return {"total": total, "step": float(np.mean(steps[1:])), "first": steps[0], "u": np.array(us),
            "info": integ.info, "dofs": int(integ.K.shape[0])}


def case(label: str, make_kw, n: int) -> dict:
    out = {"label": label, "dofs": None}
    for how in ("cg-amg", "direct"):
        o = run(lambda: make_kw(how), n)
        out[how] = o
        print(f"  {label} {how}: {o['total']:.1f} s, {o['step'] * 1e3:.1f} ms/step, {o['info']}", file=sys.stderr)
    d, c = out["direct"], out["cg-amg"]
    out["dofs"] = d["dofs"]
    out["diff"] = float(np.abs(c["u"] - d["u"]).max() / np.abs(d["u"]).max())
    return out


def newmark_case(r: int, n: int) -> dict:
    scene = bunny_scene(r, True)
    m = scene.model
    ld = LoadSet(m, [Gravity(G)])
    return case(f"bunny r{r} clamped, Newmark {n} steps",
                lambda how: make_integrator("newmark", m, 2e-3, fixed_nodes=scene.fixed_nodes, loads=ld, solver=how), n)


def drop_case(r: int, n: int) -> dict:
    scene = bunny_scene(r, False)
    m, V = scene.model, scene.rest_vertices
    y0 = float(V[:, 1].min()) - 0.02 * float(np.ptp(V[:, 1]))

    def make(how):
        contact = IPC.contact_for(m, V, scene.faces, [Ground(y0, axis=1)], W=scene.W, friction=0.3)
        return make_integrator("ipc", m, 1e-2, loads=LoadSet(m, [Gravity(G)]), contact=contact, solver=how)

    return case(f"bunny r{r} dropped, IPC {n} steps", make, n)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="bunny r24 and r32, 20 steps")
    args = ap.parse_args(argv)
    if not (SHARED_MESHES / "bunny.obj").exists():
        print(f"no {SHARED_MESHES / 'bunny.obj'}: nothing to run", file=sys.stderr)
        return 1
    n = 20 if args.quick else 60
    rows_in = [newmark_case(r, n) for r in ((24, 32) if args.quick else (32, 48))]
    rows_in.append(drop_case(16 if args.quick else 24, 10 if args.quick else 30))
    rows = []
    for o in rows_in:
        d, c = o["direct"], o["cg-amg"]
        solves = max(c["info"].get("linear_solves", c["info"].get("newton_iterations", 1)), 1)
        rows.append([o["label"], f"{o['dofs']:,}", d["total"], c["total"], f"{d['total'] / c['total']:.2f}x",
                     f"{d['info'].get('solver_setup_seconds', float('nan')):.2f}",
                     f"{c['info'].get('solver_setup_seconds', float('nan')):.2f}",
                     f"{d['step'] * 1e3:.1f}", f"{c['step'] * 1e3:.1f}", f"{d['step'] / c['step']:.2f}",
                     f"{c['info']['cg_iterations'] / solves:.1f}", f"{o['diff']:.1e}"])
    print("\nImplicit integration, direct (CHOLMOD) vs CG + AMG (DynamicOptions defaults); times in s, one run "
          "each on a shared 2-core machine: read the ratios\n")
    print_table(["case", "free DOFs", "direct total", "CG-AMG total", "direct / CG-AMG", "direct setup",
                 "AMG setup", "direct ms/step", "CG-AMG ms/step", "step ratio", "CG its / solve",
                 "max rel. diff"], rows)
    _chart(rows_in)
    return 0


def _chart(rows_in: list) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    nm = [o for o in rows_in if "Newmark" in o["label"]]
    n = [o["dofs"] for o in nm]
    axes[0].loglog(n, [o["direct"]["total"] for o in nm], "o-", color="C3", label="Newmark: direct, total")
    axes[0].loglog(n, [o["cg-amg"]["total"] for o in nm], "o-", color="C0", label="Newmark: CG + AMG, total")
    for o in rows_in:
        if "IPC" in o["label"]:
            axes[0].loglog([o["dofs"]], [o["direct"]["total"]], "s", color="C3", label="IPC drop: direct")
            axes[0].loglog([o["dofs"]], [o["cg-amg"]["total"]], "s", color="C0", label="IPC drop: CG + AMG")
    axes[0].set(xlabel="free DOFs", ylabel="wall time of the run [s]", title="implicit run, end to end")
    axes[0].legend(fontsize=7)
    labels = [o["label"].split(",")[0] for o in rows_in]
    axes[1].bar(labels, [o["direct"]["step"] * 1e3 for o in rows_in], width=0.4, align="edge", color="C3",
                label="direct")
    axes[1].bar(labels, [o["cg-amg"]["step"] * 1e3 for o in rows_in], width=-0.4, align="edge", color="C0",
                label="CG + AMG")
    axes[1].set(ylabel="ms per step (after the first)", title="per step")
    axes[1].legend(fontsize=7)
    for a in axes:
        a.grid(True, which="both", alpha=0.3)
    save_figure(fig, "newmark_speed.png", dpi=120)


if __name__ == "__main__":
    raise SystemExit(main())
