"""The full drop-test suite of issue 22: every model we have, dropped on the ground with the
default method and settings, in four placements and at two resolutions.

Usage:
    python benchmarks/drop_suite.py [--quick] [--max-seconds 300]
                                    [--model NAME ...] [--placement KEY ...] [--resolutions 16 32]
                                    [--out STEM]

Models: every built-in (``sc_fem.geometry.models.names()``), every mesh in ``../shared/meshes``
(beside the repository; skipped with a note if absent) and every shape of ``tests/shapes.py``
``REGISTRY``, named ``builtin:NAME``, ``shared:FILE`` and ``shape:NAME``.

Placements (the mesh as built is taken as z-up metres):

* ``z-m``: z-up, metres (``scale=1``, ``up="z"``);
* ``y-m``: y-up, metres (``shapes.y_up``, ``up="y"``);
* ``z-mm``: z-up, millimetres (``shapes.to_millimetres``, ``scale=1e-3``);
* ``y-mm-off``: y-up, millimetres, off the origin (``shapes.off_origin(to_millimetres(y_up(.)))``,
  ``up="y"``, ``scale=1e-3``).

Resolutions 16 and 32 (``--quick``: 16 only, and only ``z-m``).

Each case, as ``drop``/``check_drop`` of ``tests/test_drop.py``: gravity, a ground 5 % of the
model's height (along up) below its lowest vertex, 0.5 s, the default method (``auto`` ->
``ipc``) and step. Checked:

* the run completes (an exception is a FAIL with its last line; the traceback is in the JSON);
* the method was ``ipc``;
* the lowest vertex never goes below the ground by more than 1e-3 of the model size (bounding-box
  diagonal);
* the energy never rises above its start plus the loads' work by more than 1 % of the drop's
  potential ``m g 0.05 h`` (J; ``h`` in metres = height x scale);
* at rest at the end: kinetic <= 1e-3 of the drop's potential -- reported ("not at rest"), not a
  failure, as toppling models may still roll at 0.5 s;
* it fell: gravity did at least 0.9 of the drop's potential in work (``check_drop`` asserts it) --
  reported ("fell 0.64"), not a failure: a model taller than ~25 m (shared meshes in unknown units
  taken as metres) has not reached its ground after 0.5 s, a body that bounced is above it, and a
  very flat one (the rope) stops ``dhat`` above it, a large part of a gap of 5 % of its height.

Shapes built in millimetres (``metadata["units"] == "mm"``: ``truss_bridge_mm``) are first scaled
to metres, so every placement is the same physical object (``z-mm`` is then the mesh as built with
``scale=1e-3``, as in ``tests/test_drop.py``). Shared meshes carry no units: taken as metres.

Each case runs in its own process (multiprocessing, spawn) with a wall-time limit
(``--max-seconds``, default 300; the process is terminated past it and the case reported as
TIMEOUT). The Markdown table and JSON go to ``benchmarks/out/STEM.md`` / ``.json`` (STEM:
``drop_suite``, or ``drop_suite_subset`` when ``--model``/``--placement`` pick cases), rewritten
after every case. Exit status 1 if any case FAILED (not for TIMEOUT or not at rest).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import shlex
import sys
import time
import traceback
from pathlib import Path

# One BLAS thread per case unless the caller says otherwise (the machine is shared; see contact.py).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MPLBACKEND", "Agg")

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
TESTS = REPO / "tests"
OUT = HERE / "out"
SHARED_MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes"
MESH_SUFFIXES = {".obj", ".stl", ".off", ".ply", ".glb", ".gltf", ".vtk", ".vtu"}

GAP = 0.05            # ground below the lowest vertex, fraction of the model height
DURATION = 0.5        # s
G = 9.81
PENETRATION_TOL = 1e-3   # of the model size
ENERGY_TOL = 0.01        # of the drop potential
REST_TOL = 1e-3          # of the drop potential
FELL_MIN = 0.9           # gravity work, of the drop potential

PLACEMENTS = {
    "z-m": dict(label="z-up m", up="z", scale=1.0),
    "y-m": dict(label="y-up m", up="y", scale=1.0),
    "z-mm": dict(label="z-up mm", up="z", scale=1e-3),
    "y-mm-off": dict(label="y-up mm off-origin", up="y", scale=1e-3),
}


# ------------------------------------------------------------------------------- the cases ---

def model_names() -> tuple[list[str], list[str]]:
    """All model names (``builtin:``, ``shared:``, ``shape:``) and notes on what was skipped."""
    sys.path.insert(0, str(TESTS))
    import shapes
    from sc_fem.geometry import models

    notes = []
    names = [f"builtin:{n}" for n in models.names()]
    if SHARED_MESHES.is_dir():
        names += [f"shared:{p.name}" for p in sorted(SHARED_MESHES.iterdir()) if p.suffix.lower() in MESH_SUFFIXES]
    else:
        notes.append(f"shared meshes skipped: {SHARED_MESHES} not present")
    names += [f"shape:{n}" for n in shapes.REGISTRY]
    return names, notes


def base_mesh(name: str):
    """The model as a trimesh, as built (taken as z-up metres)."""
    sys.path.insert(0, str(TESTS))
    import shapes
    from sc_fem.geometry.mesh import load_mesh

    kind, _, key = name.partition(":")
    if kind == "builtin":
        return load_mesh(f"builtin:{key}")
    if kind == "shared":
        return load_mesh(SHARED_MESHES / key)
    if kind == "shape":
        mesh = shapes.REGISTRY[key]()
        if mesh.metadata.get("units", "m") == "mm":        # to metres: the placements scale it back
            mesh = mesh.copy()
            mesh.apply_scale(1e-3)
            mesh.metadata["units"] = "m"
        return mesh
    raise ValueError(f"unknown model {name!r}")


def placed(mesh, placement: str):
    sys.path.insert(0, str(TESTS))
    import shapes

    if placement == "z-m":
        return mesh
    if placement == "y-m":
        return shapes.y_up(mesh)
    if placement == "z-mm":
        return shapes.to_millimetres(mesh)
    if placement == "y-mm-off":
        return shapes.off_origin(shapes.to_millimetres(shapes.y_up(mesh)))
    raise ValueError(f"unknown placement {placement!r}")


def code_version() -> dict:
    """The library the case ran with: git HEAD, the files modified in the work tree, and a hash of
    the dynamics sources (other people edit the repository while the suite runs)."""
    import hashlib
    import subprocess

    def git(*args):
        try:
            return subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True,
                                  timeout=20).stdout.strip()
        except Exception:  # noqa: BLE001
            return None

    src = REPO / "src" / "sc_fem"
    h = hashlib.sha256()
    for f in sorted((src / "dynamics").glob("*.py")) + sorted((src / "lattice").glob("*.py")):
        h.update(f.read_bytes())
    return {"head": git("rev-parse", "--short", "HEAD"),
            "modified": [ln.split(maxsplit=1)[-1] for ln in (git("status", "--short", "--", "src") or "").splitlines()],
            "sources_sha256": h.hexdigest()[:12]}


def run_case(name: str, placement: str, resolution: int) -> dict:
    """One drop (in the worker process): the numbers and the verdict."""
    import numpy as np

    from sc_fem import Scene
    from sc_fem.dynamics.job import run_simulation, up_axis
    from sc_fem.units import gravity_down

    t0 = time.perf_counter()
    p = PLACEMENTS[placement]
    up, scale = p["up"], p["scale"]
    mesh = placed(base_mesh(name), placement)
    scene = Scene.from_mesh(mesh, resolution=resolution, scale=scale)
    a = up_axis(up)
    V = scene.rest_vertices
    h = float(np.ptp(V[:, a]))
    ground = float(V[:, a].min()) - GAP * h
    size = float(np.linalg.norm(np.ptp(V, axis=0)))
    mass = float(scene.model.total_mass)
    potential = mass * G * GAP * h * scale
    t_setup = time.perf_counter() - t0
    rec = run_simulation(scene, duration=DURATION, gravity=gravity_down(up), ground=ground, up=up)
    wall = time.perf_counter() - t0

    info = rec.info
    n_steps = int(info.get("n_steps") or 1)
    lowest = float(rec.points[:, :, a].min())
    penetration = max(0.0, ground - lowest) / size
    created = rec.energy - rec.energy[0] - rec.parts["work"]
    created_max = float(created.max())
    fell = float(-rec.parts["gravity"][-1])
    kinetic_end = float(rec.parts["kinetic"][-1])

    reasons = []
    if info.get("method") != "ipc":
        reasons.append(f"method {info.get('method')!r}, not 'ipc'")
    if penetration > PENETRATION_TOL:
        reasons.append(f"penetration {penetration:.3g} of size > {PENETRATION_TOL:g}")
    if created_max > ENERGY_TOL * potential:
        reasons.append(f"energy created {created_max / potential:.3g} of drop potential > {ENERGY_TOL:g}")
    at_rest = kinetic_end <= REST_TOL * potential
    return {
        "status": "FAIL" if reasons else "PASS", "reasons": reasons, "at_rest": bool(at_rest),
        "fell": bool(fell >= FELL_MIN * potential),
        "cubes": int(scene.model.n_cubes), "vertices": int(V.shape[0]), "faces": int(len(scene.faces)),
        "bodies": info.get("bodies"), "mass_kg": mass, "height_model": h, "size_model": size, "ground": ground,
        "drop_potential_J": potential, "seconds": float(rec.seconds), "setup_seconds": float(rec.setup_seconds),
        "voxelize_seconds": t_setup, "wall_seconds": wall, "n_steps": n_steps, "dt": info.get("dt"),
        "newton_iterations": info.get("newton_iterations"),
        "newton_per_step": (info.get("newton_iterations") or 0) / n_steps,
        "contact_steps": info.get("contact_steps"), "factorizations": info.get("factorizations"),
        "line_search_cuts": info.get("line_search_cuts"), "cg_iterations": info.get("cg_iterations"),
        "dhat": info.get("dhat"), "ground_shift": info.get("ground_shift"),
        "lowest": lowest, "penetration_over_size": penetration,
        "max_created_J": created_max, "created_over_potential": created_max / potential,
        "gravity_work_over_potential": fell / potential,
        "final_kinetic_J": kinetic_end, "final_kinetic_over_potential": kinetic_end / potential,
        "energy_gain": float(rec.energy_gain), "warnings": list(info.get("warnings", [])),
        "halvings": info.get("halvings"), "code": code_version(), "finished": time.strftime("%H:%M:%S"),
    }


def _worker(conn, name, placement, resolution):
    import faulthandler

    faulthandler.enable()          # a crash in native code (ipctk, numba) prints its Python stack
    try:
        out = run_case(name, placement, resolution)
    except BaseException as exc:  # noqa: BLE001 -- report whatever stopped the case
        tb = traceback.format_exc()
        last = f"{type(exc).__name__}: {exc}".strip().splitlines()
        out = {"status": "FAIL", "reasons": [f"did not complete: {last[0] if last else type(exc).__name__}"],
               "traceback": tb, "finished": time.strftime("%H:%M:%S")}
        try:
            out["code"] = code_version()
        except Exception:  # noqa: BLE001
            pass
    try:
        conn.send(out)
    finally:
        conn.close()


def run_limited(name: str, placement: str, resolution: int, max_seconds: float) -> dict:
    """``run_case`` in a fresh process, terminated after ``max_seconds`` of wall time."""
    ctx = mp.get_context("spawn")
    recv, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_worker, args=(send, name, placement, resolution), daemon=True)
    t0 = time.perf_counter()
    proc.start()
    send.close()
    out, answered = None, False
    try:
        answered = recv.poll(max_seconds)       # True on a result, or on EOF: the worker died
        if answered:
            try:
                out = recv.recv()
            except EOFError:
                out = None
    except BaseException:              # Ctrl-C or SIGTERM of the suite: take the case down with it
        proc.terminate()
        proc.join(5)
        if proc.is_alive():
            proc.kill()
        raise
    elapsed = time.perf_counter() - t0
    if not answered:
        proc.terminate()
        proc.join(5)
        if proc.is_alive():
            proc.kill()
        proc.join()
        out = {"status": "TIMEOUT", "reasons": [f"no result within --max-seconds {max_seconds:g} "
                                                f"(stopped at {elapsed:.0f} s)"]}
    else:
        proc.join(60)
        if out is None:
            code = proc.exitcode
            what = {-11: "SIGSEGV", -9: "SIGKILL", -6: "SIGABRT", -7: "SIGBUS"}.get(code, "")
            out = {"status": "FAIL", "reasons": [f"did not complete: the worker process (pid {proc.pid}) died after {elapsed:.0f} s "
                                                 f"(exit code {code}{' ' + what if what else ''}; "
                                                 "its stderr is in the log)"], "exitcode": code}
    out["process_seconds"] = elapsed
    return out


# ------------------------------------------------------------------------------ reporting ---

HEADERS = ["model", "placement", "r", "cubes", "vertices", "seconds", "Newton it./step", "contact steps",
           "max penetration / size", "max energy created / drop potential", "final kinetic / drop potential",
           "result"]


def _g(x, fmt=".3g"):
    return "-" if x is None else format(x, fmt)


def row(res: dict) -> list[str]:
    st = res["status"]
    if st == "TIMEOUT":
        verdict = f"TIMEOUT ({res['process_seconds']:.0f} s)"
    elif st == "FAIL":
        verdict = "FAIL: " + "; ".join(res["reasons"])
    else:
        verdict = "PASS"
    notes = []
    if st != "TIMEOUT" and res.get("at_rest") is False:
        notes.append("not at rest")
    if st != "TIMEOUT" and res.get("fell") is False:
        notes.append(f"fell {res['gravity_work_over_potential']:.2g}")
    if notes:
        verdict += f" ({'; '.join(notes)})"
    secs = res.get("seconds")
    sec = "-" if secs is None else f"{secs:.1f}"
    if secs is not None and res.get("wall_seconds") is not None:
        sec += f" ({res['wall_seconds']:.1f})"
    return [res["model"], PLACEMENTS[res["placement"]]["label"], str(res["r"]), _g(res.get("cubes"), "d"),
            _g(res.get("vertices"), "d"), sec, _g(res.get("newton_per_step"), ".2f"),
            _g(res.get("contact_steps"), "d"), _g(res.get("penetration_over_size")),
            _g(res.get("created_over_potential")), _g(res.get("final_kinetic_over_potential")), verdict]


def table(results: list[dict]) -> str:
    cells = [row(r) for r in results]
    widths = [max(len(h), *(len(c[i]) for c in cells)) if cells else len(h) for i, h in enumerate(HEADERS)]
    lines = ["| " + " | ".join(h.ljust(w) for h, w in zip(HEADERS, widths)) + " |",
             "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    lines += ["| " + " | ".join(c.ljust(w) for c, w in zip(r, widths)) + " |" for r in cells]
    return "\n".join(lines)


def summary(results: list[dict], planned: int) -> str:
    n = {k: sum(r["status"] == k for r in results) for k in ("PASS", "FAIL", "TIMEOUT")}
    moving = sum(1 for r in results if r["status"] != "TIMEOUT" and r.get("at_rest") is False)
    short = sum(1 for r in results if r["status"] != "TIMEOUT" and r.get("fell") is False)
    s = (f"{n['PASS']} passed, {n['FAIL']} failed, {n['TIMEOUT']} timed out ({moving} not at rest at 0.5 s, "
         f"{short} fell less than 0.9 of the drop)")
    if len(results) < planned:
        s += f"; {len(results)} of {planned} cases run"
    return s


def repro(res: dict) -> str:
    return ("python benchmarks/drop_suite.py " + f"--model {shlex.quote(res['model'])} "
            f"--placement {res['placement']} --resolutions {res['r']}")


def write(stem: str, meta: dict, results: list[dict], planned: int) -> str:
    OUT.mkdir(parents=True, exist_ok=True)
    order = {k: i for i, k in enumerate(PLACEMENTS)}
    ordered = sorted(results, key=lambda r: (meta["models"].index(r["model"]), order[r["placement"]], r["r"]))
    tab = table(ordered)
    summ = summary(results, planned)
    la0, la1 = meta["loadavg_start"], meta.get("loadavg_now", meta["loadavg_start"])
    md = ["# Drop-test suite (issue 22)", "",
          f"Command: `{meta['command']}`  ",
          f"Started {meta['started']}; {meta['cpus']} CPUs; load average (1/5/15 min) at start "
          f"{la0[0]:.2f}/{la0[1]:.2f}/{la0[2]:.2f}, at the last case {la1[0]:.2f}/{la1[1]:.2f}/{la1[2]:.2f}; "
          f"per-case limit {meta['max_seconds']:g} s; elapsed {meta.get('elapsed', 0):.0f} s.  ",
          "Each case: gravity, ground 5 % of the height below the lowest vertex, 0.5 s, default method/dt. "
          "seconds = stepping wall time (in brackets: the whole case, voxelization and set-up included). "
          "'not at rest' = final kinetic > 1e-3 of the drop potential; 'fell x' = gravity's work only x of the "
          "drop potential (both reported, not failures).", ""]
    md += [f"Note: {n}" for n in meta["notes"]] + ([""] if meta["notes"] else [])
    md += [tab, "", summ, ""]
    bad = [r for r in ordered if r["status"] in ("FAIL", "TIMEOUT")]
    if bad:
        md += ["Reproduce a case alone:", ""]
        md += [f"- {r['model']} {PLACEMENTS[r['placement']]['label']} r{r['r']} ({r['status']}): `{repro(r)}`" for r in bad]
        md.append("")
    (OUT / f"{stem}.md").write_text("\n".join(md))
    (OUT / f"{stem}.json").write_text(json.dumps({"meta": meta, "summary": summ, "results": ordered}, indent=1,
                                                 default=float))
    return tab + "\n\n" + summ


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="resolution 16 and z-up metres only")
    ap.add_argument("--max-seconds", type=float, default=300.0, help="wall-time limit per case (default 300)")
    ap.add_argument("--model", action="append", help="run only these models (builtin:chair, shared:FILE, "
                                                     "shape:NAME, or the bare name); repeatable")
    ap.add_argument("--placement", action="append", choices=list(PLACEMENTS), help="only these placements")
    ap.add_argument("--resolutions", type=int, nargs="+", help="resolutions (default 16 32; --quick: 16)")
    ap.add_argument("--out", help="output stem under benchmarks/out (default drop_suite, or drop_suite_subset "
                                  "when --model/--placement select cases)")
    args = ap.parse_args(argv)

    t_start = time.perf_counter()
    names, notes = model_names()
    for n in notes:
        print(f"note: {n}", flush=True)
    if args.model:
        want = set(args.model)

        def hit(m, n):
            key = n.partition(":")[2]
            return m in (n, key, Path(key).stem)

        picked = [n for n in names if any(hit(m, n) for m in want)]
        missing = [m for m in want if not any(hit(m, n) for n in names)]
        if missing:
            ap.error(f"unknown model(s) {missing}; known: {names}")
        names = picked
    placements = args.placement or (["z-m"] if args.quick else list(PLACEMENTS))
    resolutions = args.resolutions or ([16] if args.quick else [16, 32])
    stem = args.out or ("drop_suite_subset" if (args.model or args.placement) else "drop_suite")
    cases = [(n, p, r) for r in resolutions for n in names for p in placements]   # all r16 first

    meta = {"command": "python " + " ".join(shlex.quote(a) for a in [f"benchmarks/{Path(__file__).name}",
                                                                      *(sys.argv[1:] if argv is None else argv)]),
            "started": time.strftime("%Y-%m-%d %H:%M:%S"), "cpus": os.cpu_count(), "python": platform.python_version(),
            "loadavg_start": list(os.getloadavg()), "max_seconds": args.max_seconds, "notes": notes,
            "models": names, "placements": placements, "resolutions": resolutions,
            "blas_threads": os.environ.get("OPENBLAS_NUM_THREADS"), "code_at_start": code_version()}
    print(f"{len(cases)} cases ({len(names)} models x {len(placements)} placements x resolutions {resolutions}); "
          f"load average {os.getloadavg()[0]:.2f}", flush=True)
    results = []
    for i, (name, placement, r) in enumerate(cases, 1):
        res = run_limited(name, placement, r, args.max_seconds)
        res.update(model=name, placement=placement, r=r, loadavg=list(os.getloadavg()), repro=repro(
            {"model": name, "placement": placement, "r": r}))
        results.append(res)
        print(f"[{i}/{len(cases)}] " + " | ".join(row(res)) + f"  [load {os.getloadavg()[0]:.2f}]", flush=True)
        if res.get("traceback"):
            print(res["traceback"], flush=True)
        meta.update(loadavg_now=list(os.getloadavg()), elapsed=time.perf_counter() - t_start)
        write(stem, meta, results, len(cases))
    meta.update(loadavg_now=list(os.getloadavg()), elapsed=time.perf_counter() - t_start)
    text = write(stem, meta, results, len(cases))
    print()
    print(text)
    la = meta["loadavg_now"]
    print(f"\nelapsed {meta['elapsed']:.0f} s; load average now {la[0]:.2f}/{la[1]:.2f}/{la[2]:.2f}; "
          f"wrote {OUT / (stem + '.md')} and .json", flush=True)
    return 1 if any(r["status"] == "FAIL" for r in results) else 0


def _on_sigterm(signum, frame):
    raise SystemExit(128 + signum)


if __name__ == "__main__":
    import signal

    signal.signal(signal.SIGTERM, _on_sigterm)   # a killed suite stops its running case too
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        print("interrupted: the results so far are in benchmarks/out", file=sys.stderr)
        sys.exit(130)
