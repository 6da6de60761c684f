"""Contact inside the implicit step (method "ipc"): cost against linear Newmark and explicit
central differences, and the energy of a drop with and without friction.

Usage: python benchmarks/contact.py [--quick]     (--quick: resolutions 16 and 24 only)

1. Cost.  The built-in chair and bridge (no fixed nodes) at resolutions 16, 24, 32, 48, each
   through :func:`sc_fem.dynamics.job.run_simulation` with gravity:

   * ``ipc``: 0.5 s dropped onto a ground 5 % of the model height below its lowest vertex,
     ``fps=50`` -> ``dt`` = 0.01 s (half a frame);
   * ``newmark`` (linear, average acceleration): the same ``dt`` and duration, no ground.  It
     factorizes its matrices in its first step (the mass for the initial acceleration and the
     effective stiffness), inside the stepping time, where ipc factorizes in its set-up: the
     table gives both the run's ms/step and that after the first step (a 1-step run's time
     subtracted), and the ratio ipc/newmark uses the latter;
   * ``central``: its own step (``dt=None`` -> 0.9 dt_crit, a whole number of steps per frame),
     run for 0.02 s only; the cost of 0.5 s is ms/step x the steps 0.5 s takes.

   ms/step is the stepping wall time of the run (``Recording.seconds``: the driver's energy
   bookkeeping included, the integrator's assembly not) over its steps.  "ccd s" is the part of
   the ipc stepping spent in the IPC Toolkit's ``compute_collision_free_stepsize`` (timed by
   wrapping :meth:`BarrierContact.stepsize`; nothing else is changed).  The issue's goal: a 0.5 s
   drop of the chair at resolution 32 in under 10 s.

2. Energy.  The chair at resolution 16 thrown sideways at 1 m/s from 10 cm above the ground,
   1.0 s, friction 0 and 0.5 (dt = 10 ms, every step recorded): total, kinetic, gravity and
   dissipated energy against time -- without friction it keeps sliding, with it it stops.

Charts: ``benchmarks/out/contact_energy.png`` and ``benchmarks/out/contact_cost.png``
(copied to ``docs/``).  Results also in ``benchmarks/out/contact.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
import traceback
from contextlib import contextmanager
from pathlib import Path

# One BLAS thread (unless set by the caller), before numpy loads: on the shared 2-core machine
# OpenBLAS's threaded dot products (vectors > 10,000 entries, the driver's energy of every step)
# made the r48 steps 3-6x slower (central 25 ms/step -> 4.3 ms/step with one thread).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import OUT, print_table, save_figure  # noqa: E402

import sc_fem  # noqa: E402
from sc_fem.dynamics.job import run_simulation  # noqa: E402
from sc_fem.units import gravity_down  # noqa: E402

DOCS = Path(__file__).resolve().parents[1] / "docs"
MODELS = ("chair", "bridge")
DURATION = 0.5          # s, the simulated drop
FPS = 50.0              # -> dt = 0.5 / fps = 0.01 s for ipc and newmark
CENTRAL_RUN = 0.02      # s of central differences actually run
GOAL = ("chair", 32, 10.0)      # the goal: a 0.5 s drop of the chair at r32 in < 10 s


@contextmanager
def ccd_timer():
    """Time the CCD calls of :class:`~sc_fem.dynamics.ipc.BarrierContact` (a wrapper, restored after)."""
    from sc_fem.dynamics import ipc

    calls: list[tuple[float, float]] = []
    orig = ipc.BarrierContact.stepsize

    def timed(self, V0, V1):
        t0 = time.perf_counter()
        a = orig(self, V0, V1)
        calls.append((time.perf_counter() - t0, a))
        return a

    ipc.BarrierContact.stepsize = timed
    try:
        yield calls
    finally:
        ipc.BarrierContact.stepsize = orig


def lowest(scene) -> tuple[float, float]:
    z = scene.rest_vertices[:, 2]
    return float(z.min()), float(np.ptp(z))


def attempt(label: str, fn, failures: list):
    """``fn()``, or None with the traceback kept for the report."""
    try:
        return fn()
    except Exception:  # noqa: BLE001 - a failing library run is a result to report
        tb = traceback.format_exc()
        failures.append((label, tb))
        print(f"FAILED: {label}\n{tb}", flush=True)
        return None


def cost_case(name: str, r: int, failures: list) -> dict:
    t0 = time.perf_counter()
    scene = sc_fem.Scene.from_mesh(f"builtin:{name}", resolution=r)
    scene_s = time.perf_counter() - t0
    m = scene.model
    zmin, h = lowest(scene)
    ground = zmin - 0.05 * h
    row = {"model": name, "r": r, "cubes": int(m.n_cubes), "nodes": int(m.n_nodes),
           "dofs": 3 * (int(m.n_nodes) - len(scene.fixed_nodes)), "vertices": int(len(scene.rest_vertices)),
           "scene_s": scene_s, "ground": ground, "height": h}
    nan = float("nan")

    # (a) ipc drop onto the ground
    with ccd_timer() as calls:
        t0, c0 = time.perf_counter(), time.process_time()
        rec = attempt(f"ipc {name} r{r}", lambda: run_simulation(scene, duration=DURATION, gravity=gravity_down(),
                                                                 ground=ground, fps=FPS), failures)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    if rec is not None:
        info = rec.info
        c = np.array(calls).reshape(-1, 2)
        row.update(ipc_dt=rec.dt, ipc_steps=rec.n_steps, ipc_step_s=rec.seconds, ipc_wall_s=wall, ipc_cpu_s=cpu,
                   load=os.getloadavg()[0],
                   ipc_setup_s=wall - rec.seconds, ipc_ms=1e3 * rec.seconds_per_step,
                   newton=info["newton_iterations"] / rec.n_steps, contact_steps=info["contact_steps"],
                   factorizations=info["factorizations"], cg=info["cg_iterations"],
                   cuts=info["line_search_cuts"], ccd_s=float(c[:, 0].sum()), ccd_calls=len(c),
                   ccd_max_s=float(c[:, 0].max(initial=0.0)), ipc_warnings=info.get("warnings", []),
                   ipc_drift=rec.energy_drift,
                   ipc_gap_mm=1e3 * m.scale * (float(rec.points[:, :, 2].min()) - ground))
    else:
        row.update(ipc_ms=nan, newton=nan, ipc_step_s=nan, ipc_wall_s=nan, ipc_dt=0.5 / FPS)
    print(f"  {name} r{r}: ipc done ({row.get('ipc_step_s', nan):.2f} s stepping)", flush=True)

    # (b) linear newmark, same dt, no contact
    rec = attempt(f"newmark {name} r{r}", lambda: run_simulation(scene, duration=DURATION, dt=row["ipc_dt"],
                                                                 method="newmark", gravity=gravity_down(), fps=FPS), failures)
    row["newmark_ms"] = 1e3 * rec.seconds_per_step if rec is not None else nan
    row["newmark_run_s"] = rec.seconds if rec is not None else nan
    row["newmark_setup_s"] = rec.setup_seconds if rec is not None else nan
    rec1 = attempt(f"newmark 1 step {name} r{r}", lambda: run_simulation(
        scene, duration=row["ipc_dt"], dt=row["ipc_dt"], method="newmark", gravity=gravity_down(), fps=FPS), failures)
    if rec is not None and rec1 is not None:
        row["newmark_first_s"] = rec1.seconds
        row["newmark_steady_ms"] = 1e3 * (rec.seconds - rec1.seconds) / (rec.n_steps - rec1.n_steps)
    else:
        row["newmark_first_s"] = row["newmark_steady_ms"] = nan

    # (c) explicit central differences at 0.9 dt_crit, 0.02 s of it
    rec = attempt(f"central {name} r{r}", lambda: run_simulation(scene, duration=CENTRAL_RUN, method="central",
                                                                 gravity=gravity_down(), fps=FPS), failures)
    if rec is not None:
        row.update(central_ms=1e3 * rec.seconds_per_step, central_dt=rec.dt, dt_crit=rec.info["dt_crit"],
                   central_steps_05=int(round(DURATION / rec.dt)))
        row["central_cost_s"] = row["central_ms"] * 1e-3 * row["central_steps_05"]
    else:
        row.update(central_ms=nan, central_dt=nan, central_steps_05=0, central_cost_s=nan)
    print(f"  {name} r{r}: newmark {row['newmark_ms']:.3g} ms/step ({row['newmark_steady_ms']:.3g} after its "
          f"1st step), central {row['central_ms']:.3g} ms/step "
          f"(dt {row['central_dt']:.3g} s)", flush=True)
    return row


THROW = 1.0
"""Sideways speed of the chair in the energy runs, m/s."""


def energy_runs(failures: list) -> dict:
    scene = sc_fem.Scene.from_mesh("builtin:chair", resolution=16)
    zmin, _ = lowest(scene)
    out = {"ground": zmin - 0.1, "scale": scene.model.scale}
    for mu in (0.0, 0.5):
        t0 = time.perf_counter()
        rec = attempt(f"energy drop mu={mu}", lambda: run_simulation(scene, duration=1.0, gravity=gravity_down(),
                                                                     ground=zmin - 0.1, friction=mu, dt=0.5 / FPS,
                                                                     velocity=(THROW, 0.0, 0.0),
                                                                     fps=2 * FPS),   # every step recorded
                      failures)
        if rec is not None:
            out[mu] = (rec, time.perf_counter() - t0)
    return out


def plot_energy(runs: dict) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.8), sharey=True)
    kinds = [("total", "k", "-", 2.0), ("kinetic", "tab:blue", "-", 1.5), ("gravity", "tab:green", "-", 1.5),
             ("dissipated", "tab:red", "--", 1.8)]
    for ax, mu in zip(axes, (0.0, 0.5)):
        if mu not in runs:
            ax.set_title(f"friction mu = {mu:g}: run failed")
            continue
        rec, _ = runs[mu]
        series = {"total": rec.energy, **rec.parts}
        for k, col, ls, lw in kinds:
            ax.plot(rec.times, series[k], color=col, ls=ls, lw=lw, label=k)
        ax.plot(rec.times, rec.parts["elastic"] + rec.parts["contact"], color="tab:purple", lw=1.0, ls=":",
                label="elastic + contact barrier")
        ax.axhline(0.0, color="0.6", lw=0.6)
        ax.set_title(f"chair r16 thrown at {THROW:g} m/s from 10 cm, friction mu = {mu:g} (ipc, dt = {rec.dt * 1e3:g} ms)",
                     fontsize=10)
        ax.set_xlabel("time t [s]")
        ax.grid(True, alpha=0.3)
    fig.suptitle("backward Euler: the free fall loses m g^2 dt^2 / 2 per step to numerical damping; the impact is "
                 "inelastic; friction then takes the sliding energy; dissipated = E(0) + work - E(t)", fontsize=9)
    axes[0].set_ylabel("energy [J]  (gravity potential 0 at the start)")
    axes[0].legend(fontsize=9, loc="center right")
    path = save_figure(fig, "contact_energy.png")
    shutil.copyfile(path, DOCS / "contact_energy.png")
    print(f"copied to {DOCS / 'contact_energy.png'}")
    plt.close(fig)


def plot_cost(rows: list[dict]) -> None:
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(14, 4.8))
    methods = [("ipc", "ipc (contact, dt 10 ms)", "tab:red"),
               ("newmark_steady", "newmark (no contact, dt 10 ms; after its 1st step)", "tab:blue"),
               ("central", "central (0.9 dt_crit)", "tab:green")]
    markers = {"chair": ("o", "-"), "bridge": ("s", "--")}
    for name in MODELS:
        rs = sorted((r for r in rows if r["model"] == name), key=lambda r: r["dofs"])
        if not rs:
            continue
        x = [r["dofs"] for r in rs]
        mk, ls = markers[name]
        for key, label, col in methods:
            axes[0].loglog(x, [r[f"{key}_ms"] for r in rs], marker=mk, ls=ls, color=col, label=f"{label}, {name}")
        axes[1].loglog(x, [r["ipc_ms"] * 1e-3 * r.get("ipc_steps", 0) if "ipc_steps" in r else np.nan for r in rs],
                       marker=mk, ls=ls, color="tab:red", label=f"ipc, {name}")
        axes[1].loglog(x, [r["newmark_run_s"] for r in rs], marker=mk, ls=ls,
                       color="tab:blue", label=f"newmark, {name}")
        axes[1].loglog(x, [r["central_cost_s"] for r in rs], marker=mk, ls=ls, color="tab:green",
                       label=f"central, {name}")
    axes[0].set_ylabel("wall time per step [ms]")
    axes[0].set_title("cost of one step", fontsize=10)
    axes[1].set_ylabel("wall time for 0.5 s simulated [s]")
    axes[1].axhline(GOAL[2], color="0.4", lw=0.8, ls=":")
    axes[1].annotate("goal: chair r32 drop < 10 s", (0.02, GOAL[2]), xycoords=("axes fraction", "data"),
                     fontsize=8, va="bottom", color="0.3")
    axes[1].annotate("central: ms/step x steps needed", (0.02, 0.97), xycoords="axes fraction", fontsize=8,
                     va="top", color="0.3")
    axes[1].set_title("stepping time of 0.5 s simulated", fontsize=10)
    for ax in axes:
        ax.set_xlabel("degrees of freedom (3 x lattice nodes)")
        ax.grid(True, which="both", alpha=0.3)
    # one legend for both panels, at the right: colour = method, marker and line style = model
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=col, lw=2, label=label) for _, label, col in methods]
    handles += [Line2D([], [], color="k", marker=mk, ls=ls, label=name) for name, (mk, ls) in markers.items()]
    axes[1].legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8)
    path = save_figure(fig, "contact_cost.png")
    shutil.copyfile(path, DOCS / "contact_cost.png")
    print(f"copied to {DOCS / 'contact_cost.png'}")
    plt.close(fig)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="resolutions 16 and 24 only")
    args = ap.parse_args(argv)
    resolutions = (16, 24) if args.quick else (16, 24, 32, 48)
    failures: list = []
    t_start = time.perf_counter()
    print(f"load average at start: {os.getloadavg()[0]:.2f} (cpus: {os.cpu_count()}); BLAS threads: "
          f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS')}, "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS')}")

    # warm-up: imports, compiled kernels' caches and ipctk, so that the first timed case does not pay them
    t0 = time.perf_counter()
    warm = sc_fem.Scene.from_mesh("builtin:chair", resolution=8)
    zmin, h = lowest(warm)
    run_simulation(warm, duration=0.02, gravity=gravity_down(), ground=zmin - 0.05 * h, fps=FPS)
    run_simulation(warm, duration=0.02, method="newmark", gravity=gravity_down(), fps=FPS)
    run_simulation(warm, duration=0.02, method="central", gravity=gravity_down(), fps=FPS)
    print(f"warm-up {time.perf_counter() - t0:.1f} s")

    rows = []
    for name in MODELS:
        for r in resolutions:
            rows.append(cost_case(name, r, failures))

    print("\n## Cost: ipc drop onto the ground vs newmark and central without contact "
          f"({DURATION:g} s simulated, gravity, no fixed nodes)\n")
    headers = ["model", "r", "cubes", "DOFs", "ipc ms/step", "Newton it/step", "newmark ms/step",
               "newmark ms/step after 1st", "ipc/newmark",
               "central ms/step", "central dt [s]", "central cost 0.5 s [s]", "ipc cost 0.5 s [s]", "ipc/central"]
    table = []
    for r in rows:
        ipc_cost = r["ipc_step_s"]
        table.append([r["model"], r["r"], r["cubes"], r["dofs"], r["ipc_ms"], r["newton"], r["newmark_ms"],
                      r["newmark_steady_ms"], r["ipc_ms"] / r["newmark_steady_ms"], r["central_ms"], r["central_dt"],
                      r["central_cost_s"],
                      ipc_cost, ipc_cost / r["central_cost_s"]])
    print_table(headers, table, floatfmt=".3g")

    print("\n## ipc details (per run of 50 steps of 10 ms)\n")
    headers = ["model", "r", "src verts", "contact steps", "Newton total", "factorizations", "CG it",
               "LS cuts", "ccd calls", "ccd s", "slowest ccd s", "stepping s", "set-up s", "run CPU s", "load avg",
               "scene s", "min gap [mm]", "energy drift"]
    table = []
    for r in rows:
        if "ipc_steps" not in r:
            table.append([r["model"], r["r"], r["vertices"]] + ["failed"] * 15)
            continue
        table.append([r["model"], r["r"], r["vertices"], r["contact_steps"], int(round(r["newton"] * r["ipc_steps"])),
                      r["factorizations"], r["cg"], r["cuts"], r["ccd_calls"], r["ccd_s"], r["ccd_max_s"],
                      r["ipc_step_s"], r["ipc_setup_s"], r["ipc_cpu_s"], r["load"], r["scene_s"], r["ipc_gap_mm"],
                      r["ipc_drift"]])
    print_table(headers, table, floatfmt=".3g")
    warned = [(r["model"], r["r"], w) for r in rows for w in r.get("ipc_warnings", [])]
    for m, res, w in warned:
        print(f"warning (ipc {m} r{res}): {w}")

    goal = [r for r in rows if (r["model"], r["r"]) == GOAL[:2]]
    print(f"\n## Goal: a {DURATION:g} s drop of the chair at resolution {GOAL[1]} in under {GOAL[2]:g} s\n")
    if goal and "ipc_steps" in goal[0]:
        g = goal[0]
        ok = "MET" if g["ipc_wall_s"] < GOAL[2] else "NOT MET"
        print(f"chair r{GOAL[1]} ({g['cubes']} cubes, {g['dofs']} DOFs): stepping {g['ipc_step_s']:.2f} s; "
              f"run_simulation with its set-up (contact mesh, assembly, factorization) {g['ipc_wall_s']:.2f} s; "
              f"plus the scene (voxelize + embedding) {g['ipc_wall_s'] + g['scene_s']:.2f} s  -> goal {ok} "
              f"(CCD {g['ccd_s']:.2f} s of the stepping)")
    else:
        print("chair r32 not run (--quick) or failed")

    print("\n## Energy: chair r16 dropped 10 cm onto the ground, 1.0 s, ipc dt = 10 ms\n")
    runs = energy_runs(failures)
    table = []
    for mu, (rec, wall) in ((k, v) for k, v in runs.items() if k not in ("ground", "scale")):
        p = rec.parts
        table.append([mu, rec.n_steps, rec.info["newton_iterations"] / rec.n_steps, rec.seconds, wall,
                      float(-p["gravity"][-1]), float(p["kinetic"].max()), float(p["kinetic"][-1]),
                      float(p["dissipated"][-1]), float(p["dissipated"].min()), rec.energy_gain,
                      1e3 * runs["scale"] * (float(rec.points[:, :, 2].min()) - runs["ground"]),
                      len(rec.info.get("warnings", []))])
    print_table(["friction", "steps", "Newton it/step", "stepping s", "wall s", "gravity work [J]", "max kinetic [J]",
                 "final kinetic [J]", "dissipated at 1 s [J]", "min dissipated [J]", "energy gain",
                 "min gap [mm]", "warnings"], table, floatfmt=".4g")
    print(f"(ground at z = {runs['ground']:.4g} model units; model scale {runs['scale']:g} m per unit)")

    plot_energy(runs)
    plot_cost(rows)
    with open(OUT / "contact.json", "w") as fh:
        json.dump({"rows": rows, "failures": failures}, fh, indent=1, default=str)
    print(f"wrote {OUT / 'contact.json'}")
    if failures:
        print(f"\n{len(failures)} run(s) failed: " + ", ".join(lbl for lbl, _ in failures))
    print(f"total wall time {time.perf_counter() - t_start:.0f} s; load average at end: {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
