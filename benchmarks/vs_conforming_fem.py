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

``--thin``: thin-walled steel members instead (the shapes of ``tests/shapes.py``: an I-section and a
channel cantilever, a portal frame of I-sections, a plate, a table; E = 200 GPa, nu = 0.3,
rho = 7850 kg/m^3, ``fill="solid"``, the default element). Their P2 reference is meshed from the
boxes the shapes are united from: a tensor grid through every box face, graded geometrically
towards every face (the re-entrant web-flange corners are stress singularities that an
isotropic TetGen mesh resolves only at great cost), split into conforming tetrahedra (Kuhn),
refined until two levels agree to < 0.5 % in the 10 lowest free-free frequencies. Per case and
resolution: mass, the 10 frequencies (mean / max relative error), MAC pairing of the mode
shapes (sampled at the reference's vertices through sc_fem's trilinear embedding), a static
case (cantilevers and plate clamped at x = 0 under gravity, the table standing on its feet
under gravity, the portal frame's feet clamped and a side load on its beam) and wall time; and
the "two plates a third of a cube apart" study (rigid-body modes found, lowest elastic
frequency against one plate alone). The members are voxelized with the voxelizer's default
``topology`` (recorded per row); when :class:`sc_fem.VoxelOptions` has a ``topology`` field
(looked up at run time) the two-plates study runs both ``topology="grid"`` (one grid: parts in
one cell move together) and the default, otherwise only the one grid. Writes
``benchmarks/out/vs_conforming_fem_thin.{md,png,json}`` and ``docs/vs_conforming_fem_thin.png``.

    python benchmarks/vs_conforming_fem.py --thin     # resolutions 16, 24, 32, 48, 64
    python benchmarks/vs_conforming_fem.py --thin --cases i_beam two_plates --resolutions 16 32
    python benchmarks/vs_conforming_fem.py --thin --reuse-reference --elements q1i q2 q3 --resolutions 16 32 \
        --cases i_beam channel portal_frame plate table --tag higher_order      # the higher-order cubes
"""

from __future__ import annotations

import argparse
import gc
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from _common import SHARED_MESHES, out_path, print_table, save_figure

import sc_fem
from sc_fem.fem.choice import choose_element
from sc_fem.fem.highorder import DEGREES
from sc_fem.fem.reference import solve_reference, uniform_field

ELEMENTS = ("q1", "q1sri", "q1i")
"""Default elements of the compact-solid comparison (``--elements`` also takes ``q2``, ``q3``)."""
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
    chair = sc_fem.geometry.models.material("builtin:chair")
    beam = sc_fem.geometry.models.material("builtin:beam")
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
        scene = sc_fem.Scene.from_mesh(mesh, resolution=r, **mat)     # the mesh too: q2 / q3 are made from it
    model = scene.model
    t_vox = time.perf_counter() - t0
    t0 = time.perf_counter()
    basis = sc_fem.modal(scene, n_modes=10, element=element)
    t_modal = time.perf_counter() - t0
    t0 = time.perf_counter()
    st = sc_fem.solve_static(sc_fem.Scene.from_model(model, mesh, fix=spec), element=element, gravity=g)
    t_static = time.perf_counter() - t0
    umax = float(np.linalg.norm(st.vertex_displacements, axis=1).max())
    return dict(cubes=model.n_cubes, mass=model.total_mass, freqs=basis.frequencies[:10], umax=umax,
                seconds=t_vox + t_modal, static_seconds=t_static)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="resolutions 16, 24, 32 and a coarser reference")
    ap.add_argument("--cases", nargs="*", default=None,
                    help="subset of: spot bunny chair beam (with --thin: i_beam channel portal_frame plate table "
                         "two_plates)")
    ap.add_argument("--tag", default="", help="suffix of the output names (runs of different cases side by side)")
    ap.add_argument("--resolutions", type=int, nargs="*", default=None, help="override the resolutions")
    ap.add_argument("--elements", nargs="*", default=None,
                    help=f"subset of {ELEMENTS} (default: all three; with --thin: today's default element)")
    ap.add_argument("--thin", action="store_true", help="the thin-walled cases instead (see the module docstring)")
    ap.add_argument("--reuse-reference", action="store_true",
                    help="--thin: reuse the reference solutions cached in benchmarks/out/thin_ref/")
    ap.add_argument("--ref-max-dofs", type=int, default=450_000,
                    help="--thin: skip reference levels above this many DOFs (default 450,000)")
    ap.add_argument("--higher-max-res", type=int, default=32,
                    help="--thin: q2 / q3 / auto only up to this resolution (default 32: they reach 2 %% there)")
    args = ap.parse_args(argv)
    if args.thin:
        return thin_main(args)
    if args.elements is None:
        args.elements = list(ELEMENTS)
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


# ------------------------------------------------------------------------------ thin walls ---

STEEL = dict(youngs=200e9, poisson=0.3, density=7850.0)
THIN_CASES = ("i_beam", "channel", "portal_frame", "plate", "table")
THIN_REF_LEVELS = ((1, 2.0, 20), (2, 1.7, 28), (3, 1.5, 36))
"""Reference mesh levels ``(d, g, n)``, tried in order until two in a row agree to
:data:`REF_TOL`: the cells next to every box face are (thinnest wall interval) / ``d``; away from
the faces they grow by the ratio ``g`` up to (longest extent) / ``n``. Each level refines all
three: on the I-section, refining only ``d`` (2 -> 4) moved the 10 frequencies by 0.18 %, only
``g``, ``n`` (2 -> 1.6, 25 -> 33) by 0.5 % (the 9th mode), so neither alone shows the error."""
THIN_REF_LEVELS_BY_CASE = {"portal_frame": ((1, 3.0, 15), (1, 2.0, 20), (2, 1.7, 28))}
"""The portal frame is 2.8 m of I-section in one tensor grid: d = 2 means 600k-800k DOFs (above
``--ref-max-dofs``), so it is refined in ``g`` and ``n`` at d = 1 only."""
THIN_QUICK_REF_LEVELS = ((1, 3.0, 12), (1, 3.0, 15))
REF_TOL = 0.005
ASM_CHUNK = 20_000          # P2 tets assembled at a time
TWO_PLATES_RES = (8, 16, 32)
SIDE_LOAD = 1000.0          # N along +x, spread uniformly over the portal frame's beam
THIN_STATIC = {"i_beam": "clamped at x = 0, gravity -z", "channel": "clamped at x = 0, gravity -z",
               "portal_frame": f"feet clamped, {SIDE_LOAD:g} N along +x spread over the beam",
               "plate": "clamped at x = min (short edge), gravity -z",
               "table": "feet clamped, gravity -z"}


def voxel_topology() -> dict:
    """What this sc_fem's voxelizer does with separate parts, looked up at run time: ``topology``
    (``None`` when :class:`sc_fem.VoxelOptions` has no such field yet: today's one-grid behaviour),
    its default and ``weld``'s default."""
    fields = sc_fem.VoxelOptions.__dataclass_fields__
    if "topology" not in fields:
        return dict(has_topology=False, default=None, weld_default=None, keep_default=fields["keep"].default)
    return dict(has_topology=True, default=fields["topology"].default,
                weld_default=fields["weld"].default if "weld" in fields else None,
                keep_default=fields["keep"].default)


def _topology_of(model, topo: dict) -> str:
    """The topology a voxelized model was built with (from its ``info`` when recorded)."""
    if not topo["has_topology"]:
        return "grid (no topology option)"
    return str(model.info.get("topology", topo["default"]))


def _git_state() -> dict:
    """HEAD and the uncommitted changes under src/ when the run started (sc_fem is being edited)."""
    import hashlib
    import subprocess

    root = Path(__file__).resolve().parents[1]
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True).stdout.strip()
        diff = subprocess.run(["git", "diff", "HEAD", "--", "src"], cwd=root, capture_output=True, text=True).stdout
        dirty = subprocess.run(["git", "status", "--short", "--", "src"], cwd=root, capture_output=True,
                               text=True).stdout.split("\n")
    except OSError:
        return {}
    return dict(head=head, src_diff_sha1=hashlib.sha1(diff.encode()).hexdigest() if diff else None,
                src_changed=[x.strip() for x in dirty if x.strip()])


def _shapes():
    tests = Path(__file__).resolve().parents[1] / "tests"
    if str(tests) not in sys.path:
        sys.path.insert(0, str(tests))
    import shapes

    return shapes


def box_union(builder, **kw):
    """``(mesh, lo (n, 3), hi (n, 3))``: a shape of ``tests/shapes.py`` and the boxes it is the union
    of (recorded from its call of ``shapes._union``; a shape that is one box: its bounds)."""
    shapes = _shapes()
    rec = []
    real = shapes._union

    def spy(lo, hi):
        rec.append((np.atleast_2d(lo).astype(float).copy(), np.atleast_2d(hi).astype(float).copy()))
        return real(lo, hi)

    shapes._union = spy
    try:
        mesh = builder(**kw)
    finally:
        shapes._union = real
    if rec:
        return mesh, rec[0][0], rec[0][1]
    b = np.asarray(mesh.bounds, dtype=float)
    return mesh, b[:1], b[1:]


def thin_geometry(name: str) -> dict:
    """The mesh, its boxes and the static case of one thin-walled case."""
    shapes = _shapes()
    mesh, lo, hi = box_union(getattr(shapes, name))
    geo = dict(name=name, mesh=mesh, lo=lo, hi=hi, fix_axis=0, gravity=np.array([0.0, 0.0, -9.81]),
               load_boxes=None)
    if name in ("portal_frame", "table"):
        geo["fix_axis"] = 2
    if name == "portal_frame":                  # boxes 6..8 are the beam (columns 0..5)
        geo["gravity"], geo["load_boxes"] = None, (lo[6:9], hi[6:9])
    return geo


def _graded(a: float, b: float, s0: float, h: float, g: float) -> np.ndarray:
    """Grid points in ``(a, b]``: cells of ``s0`` at both ends growing by ``g`` up to ``h``."""
    length = b - a
    sizes, tot, s = [], 0.0, s0
    while tot + s <= 0.5 * length * (1 + 1e-9):
        sizes.append(s)
        tot += s
        s = min(h, s * g)
    rest = length - 2 * tot
    mid = []
    if rest > 0.5 * (sizes[-1] if sizes else length):
        k = max(1, int(np.ceil(rest / s - 1e-9)))
        mid = [rest / k] * k
    cells = np.r_[sizes, mid, sizes[::-1]]
    pts = a + np.cumsum(cells) * (length / cells.sum())
    pts[-1] = b
    return pts


def box_grid_mesh(lo, hi, d: int, g: float, n: int):
    """Conforming tetrahedra (skfem ``MeshTet.init_tensor``, 6 per grid cell) filling the union of
    axis-aligned boxes ``lo``, ``hi`` (k, 3) exactly: a tensor grid through every box face, graded
    towards each (see :data:`THIN_REF_LEVELS`), keeping the cells inside a box."""
    from skfem import MeshTet

    coords = [np.unique(np.round(np.r_[lo[:, a], hi[:, a]], 12)) for a in range(3)]
    tmin = min(float(np.diff(c).min()) for c in coords if len(c) > 1)
    h = float(np.max(np.max(hi, axis=0) - np.min(lo, axis=0))) / n
    axes = [np.concatenate([c[:1]] + [_graded(a, b, tmin / d, h, g) for a, b in zip(c[:-1], c[1:])])
            for c in coords]
    m = MeshTet.init_tensor(*axes)
    cen = m.p[:, m.t].mean(axis=1).T
    inside = np.zeros(len(cen), dtype=bool)
    for l, u in zip(lo, hi):                    # a handful of boxes
        inside |= np.all((cen > l) & (cen < u), axis=1)
    return m if inside.all() else m.restrict(np.flatnonzero(inside))


def _in_boxes(x: np.ndarray, boxes) -> np.ndarray:
    """Points ``x`` (3, ...) strictly inside any of the boxes ``(lo (k, 3), hi (k, 3))``."""
    out = np.zeros(x.shape[1:], dtype=bool)
    for l, u in zip(*boxes):
        out |= np.all([(x[a] > l[a]) & (x[a] < u[a]) for a in range(3)], axis=0)
    return out


def thin_reference(geo: dict, level, static: bool = True) -> dict:
    """P2 tetrahedra (scikit-fem) on :func:`box_grid_mesh`: mass, the 10 lowest free-free
    frequencies and their mode shapes at the mesh vertices, and the static case of ``geo``."""
    from skfem import Basis, BilinearForm, ElementTetP2, ElementVector, LinearForm, asm
    from skfem.helpers import dot
    from skfem.models.elasticity import lame_parameters, linear_elasticity

    from sc_fem.fem.eigen import EigenSolver
    from sc_fem.fem.linsolve import factorize

    rho = STEEL["density"]
    t = {}
    t0 = time.perf_counter()
    m = box_grid_mesh(geo["lo"], geo["hi"], *level)
    t["mesh"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    elem = ElementVector(ElementTetP2())
    basis = Basis(m, elem, intorder=2)                       # grad P2 . grad P2: degree 2, exact
    lam, mu = lame_parameters(STEEL["youngs"], STEEL["poisson"])

    @BilinearForm
    def mass_form(u, v, w):
        return rho * dot(u, v)

    K = M = None
    for s in range(0, m.t.shape[1], ASM_CHUNK):              # in chunks: skfem's COO arrays of 900
        cells = np.arange(s, min(m.t.shape[1], s + ASM_CHUNK))  # entries per P2 tet would need GBs
        k = asm(linear_elasticity(lam, mu), Basis(m, elem, intorder=2, elements=cells)).tocsr()
        mm = asm(mass_form, Basis(m, elem, intorder=4, elements=cells)).tocsr()   # P2 . P2: degree 4, exact
        K, M = (k, mm) if K is None else (K + k, M + mm)

    ez = uniform_field(basis, np.array([0.0, 0.0, 1.0]))
    mass = float(ez @ (M @ ez))
    t["assemble"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    solver = EigenSolver(K, M, method="shift-invert")
    eig = solver.solve(16)
    t["eigen"] = time.perf_counter() - t0
    lam_, vectors, lambda_scale = eig.eigenvalues, eig.vectors, solver.lambda_scale
    del solver, eig                                          # the factorization: before the static one
    gc.collect()
    # rigid modes come out at ~1e-16 lambda_scale; the portal frame's first elastic mode (the columns
    # swinging out of plane against the beam's torsion, 9 Hz) is at ~1e-10 lambda_scale
    n_rigid = int((lam_ < 1e-13 * lambda_scale).sum())
    if n_rigid != 6:
        print(f"[{geo['name']}] WARNING: the reference has {n_rigid} near-zero modes, not 6: "
              f"lambda / lambda_scale = {lam_[:8] / lambda_scale}", file=sys.stderr)
    freqs = np.sqrt(np.maximum(lam_[6:], 0.0)) / (2 * np.pi)
    nd = basis.nodal_dofs                                    # (3, vertices)
    modes = np.ascontiguousarray(vectors[nd][:, :, 6:].transpose(2, 1, 0))       # (10, vertices, 3)
    del vectors
    out = dict(level=tuple(level), n_tets=int(m.t.shape[1]), n_dofs=int(basis.N), mass=mass, freqs=freqs,
               verts=np.ascontiguousarray(m.p.T), modes=modes, timings=t, n_rigid=n_rigid,
               seconds=t["mesh"] + t["assemble"] + t["eigen"])
    if static:
        t0 = time.perf_counter()
        a = geo["fix_axis"]
        ext = float(np.ptp(m.p[a]))
        held = basis.doflocs[a] <= m.p[a].min() + 1e-9 * ext
        if geo["gravity"] is not None:
            f = M @ uniform_field(basis, geo["gravity"])
        else:
            boxes = geo["load_boxes"]
            p = m.p[:, m.t]                                  # (3, 4, tets)
            vol = np.abs(np.einsum("ij,ij->j", p[:, 1] - p[:, 0], np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0], axis=0))) / 6
            v_region = float(vol[_in_boxes(p.mean(axis=1), boxes)].sum())
            q = SIDE_LOAD / v_region                         # N/m^3 along +x, in the beam region

            @LinearForm
            def side(v, w):
                return q * _in_boxes(np.asarray(w.x), boxes) * v.value[0]

            f = asm(side, basis)
            out["load_volume"] = v_region
        free = np.flatnonzero(~held)
        u = np.zeros(basis.N)
        u[free] = factorize(K[free][:, free].tocsc()).solve(f[free])
        uv = np.ascontiguousarray(u[nd].T)                   # (vertices, 3)
        out.update(u=uv, umax=float(np.linalg.norm(uv, axis=1).max()), static_seconds=time.perf_counter() - t0)
    return out


def estimate_dofs(geo: dict, level) -> int:
    """P2 vector DOFs of a reference level (3 per vertex and per edge), without assembling."""
    m = box_grid_mesh(geo["lo"], geo["hi"], *level)
    return 3 * (m.p.shape[1] + m.edges.shape[1])


def _ref_cache(name: str, level) -> Path:
    d, g, n = level
    return out_path("thin_ref").joinpath(f"{name}_d{d}_g{g:g}_n{n}.npz")


def cached_reference(geo: dict, level, reuse: bool, static: bool = True) -> dict:
    path = _ref_cache(geo["name"], level)
    path.parent.mkdir(parents=True, exist_ok=True)
    if reuse and path.exists():
        z = np.load(path, allow_pickle=True)
        ref = z["meta"].item()
        ref.update({k: z[k] for k in z.files if k != "meta"})
        ref["cached"] = True
        return ref
    ref = thin_reference(geo, level, static=static)
    arrays = {k: v for k, v in ref.items() if isinstance(v, np.ndarray)}
    meta = {k: v for k, v in ref.items() if not isinstance(v, np.ndarray)}
    np.savez(path, meta=np.array(meta, dtype=object), **arrays)
    return ref


def mac_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Modal assurance criterion between mode sets ``a`` (p, n, 3) and ``b`` (q, n, 3): (p, q)."""
    a, b = a.reshape(len(a), -1), b.reshape(len(b), -1)
    return (a @ b.T) ** 2 / np.outer((a * a).sum(1), (b * b).sum(1))


def side_load_points(boxes, spacing=(4e-3, 1e-3, 1e-3)) -> np.ndarray:
    """Cell centres of a regular grid (``spacing`` along the longest axis of the boxes' union,
    then the others) inside the union of ``boxes``: equal point forces on them are a uniform body
    force on the region (the grid fits the 1 mm box coordinates exactly)."""
    lo, hi = np.min(boxes[0], axis=0), np.max(boxes[1], axis=0)
    order = np.argsort(-(hi - lo))
    s = np.empty(3)
    s[order] = spacing
    axes = [np.arange(lo[a] + s[a] / 2, hi[a], s[a]) for a in range(3)]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), axis=0).reshape(3, -1)
    return np.ascontiguousarray(g[:, _in_boxes(g, boxes)].T)


def run_thin_sc_fem(geo: dict, r: int, element: str, ref: dict, topo: dict) -> dict:
    """sc_fem on one thin case at resolution ``r`` (the voxelizer's default topology): cubes,
    mass, 10 free-free frequencies, the best MAC of each reference mode among its 10 modes, the
    static case; seconds. Trilinear cubes are sampled at the reference's vertices through the
    trilinear embedding, higher-order cubes (``"q2"``, ``"q3"``) through their own field."""
    if element == "auto":                         # what the default picks for this model (same grid)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            element = choose_element(sc_fem.Scene.from_mesh(geo["mesh"], resolution=r, fill="solid", **STEEL))[0]
    if element in DEGREES:
        return run_thin_higher_order(geo, r, element, ref, topo)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = sc_fem.voxelize(geo["mesh"], resolution=r, fill="solid", **STEEL)
    t_vox = time.perf_counter() - t0
    t0 = time.perf_counter()
    basis = sc_fem.modal(model, n_modes=10, element=element, keep_lattice=True)
    t_modal = time.perf_counter() - t0
    W = sc_fem.embed(model, ref["verts"])
    phi = np.stack([np.asarray(W @ basis.node_modes[k]) for k in range(basis.n_modes)])
    mac = mac_matrix(ref["modes"], phi)                           # (10 reference, k model)
    t0 = time.perf_counter()
    spec = f"{AXES[geo['fix_axis']]}<min+0"
    if geo["gravity"] is not None:
        st = sc_fem.solve_static(model, element=element, fix=spec, gravity=geo["gravity"])
    else:
        pts = side_load_points(geo["load_boxes"])
        fp = np.zeros((len(pts), 3))
        fp[:, 0] = SIDE_LOAD / len(pts)
        forces = np.asarray(sc_fem.embed(model, pts).T @ fp)
        st = sc_fem.solve_static(model, element=element, fix=spec, forces=forces)
    t_static = time.perf_counter() - t0
    u = np.asarray(W @ st.displacements)
    return _thin_result(model, basis.frequencies[:10], mac, u, ref, t_vox + t_modal, t_static, topo)


def _thin_result(model, freqs, mac, u, ref, seconds, static_seconds, topo) -> dict:
    umax = float(np.linalg.norm(u, axis=1).max())
    return dict(cubes=model.n_cubes, mass=model.total_mass, freqs=freqs, mac=mac,
                umax=umax, u_field_err=float(np.linalg.norm(u - ref["u"]) / np.linalg.norm(ref["u"])),
                seconds=seconds, static_seconds=static_seconds, pitch=float(model.pitch),
                topology=_topology_of(model, topo), weld=model.info.get("weld"), bodies=model.info.get("bodies"))


def run_thin_higher_order(geo: dict, r: int, element: str, ref: dict, topo: dict) -> dict:
    """:func:`run_thin_sc_fem` for degree-2/3 cubes: modes and static solution sampled at the
    reference's vertices through the degree-p field; gravity through the consistent mass, the side
    load through the field's transpose (the same loads :func:`sc_fem.solve_static` applies)."""
    from sc_fem.fem.highorder import HighOrderAssembler, HighOrderCubes
    from sc_fem.fem.linsolve import factorize
    from sc_fem.modes.options import ModalRequest
    from sc_fem.modes.solve import solve_scene

    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        scene = sc_fem.Scene.from_mesh(geo["mesh"], resolution=r, fill="solid", **STEEL)
    t_vox = time.perf_counter() - t0
    t0 = time.perf_counter()
    solved = solve_scene(scene, ModalRequest(n_modes=10, element=element))
    t_modal = time.perf_counter() - t0
    asm = solved.asm
    Wr = asm.cubes.map_points(ref["verts"])
    phi = asm.vertex_field(solved.X[:, ~solved.rigid][:, :10], Wr).transpose(2, 0, 1)
    mac = mac_matrix(ref["modes"], phi)
    model = scene.model
    t0 = time.perf_counter()
    spec = f"{AXES[geo['fix_axis']]}<min+0"
    held = sc_fem.Scene.from_model(model, geo["mesh"], fix=spec)
    sa = HighOrderAssembler(HighOrderCubes(held, element))      # condensed with the clamped face's material held
    K = sa.stiffness()
    if geo["gravity"] is not None:
        b = sa.mass() @ np.tile(geo["gravity"], sa.cubes.n_nodes)[sa.free_dofs]
    else:
        pts = side_load_points(geo["load_boxes"])
        fp = np.zeros((len(pts), 3))
        fp[:, 0] = SIDE_LOAD / len(pts)
        b = (sa.cubes.map_points(pts).T @ fp.reshape(-1))[sa.free_dofs]
    x = factorize(K).solve(b)
    u = sa.vertex_field(x, sa.cubes.map_points(ref["verts"]))
    t_static = time.perf_counter() - t0
    freqs = np.sqrt(np.maximum(solved.lam[~solved.rigid][:10], 0.0)) / (2 * np.pi)
    return _thin_result(model, freqs, mac, u, ref, t_vox + t_modal, t_static, topo)


def two_plates_study(element: str, levels, reuse: bool, topo: dict) -> tuple[list, dict]:
    """Two parallel plates (0.5 x 0.5 x 0.005 m) a third of a cube apart, at resolutions
    :data:`TWO_PLATES_RES`: lattice parts, rigid-body modes sc_fem finds (12 for two separate
    plates), the lowest elastic frequency against one plate alone (sc_fem at the same pitch,
    and the P2 reference). With a ``topology`` option (looked up at run time) both
    ``topology="grid"`` (one grid: what sc_fem did before) and the default are run."""
    from sc_fem.fem.static import node_parts

    shapes = _shapes()
    lx = ly = 0.5
    t = 0.005
    one = shapes.plate(lx=lx, ly=ly, t=t)
    b = np.asarray(one.bounds, float)
    geo = dict(name="one_plate", mesh=one, lo=b[:1], hi=b[1:], fix_axis=0, gravity=None, load_boxes=None)
    refs = []
    for level in levels[:2]:
        ref = cached_reference(geo, level, reuse, static=False)
        refs.append(ref)
        print(f"[two_plates] one plate alone, P2 reference {level}: {ref['n_tets']} tets, {ref['n_dofs']} DOFs, "
              f"f1 = {ref['freqs'][0]:.3f} Hz ({ref['seconds']:.1f} s){' (cached)' if ref.get('cached') else ''}",
              file=sys.stderr, flush=True)
    f_ref = float(refs[-1]["freqs"][0])
    if not topo["has_topology"]:
        variants = [("grid (no topology option)", {})]
    elif topo["default"] == "grid":
        variants = [("grid (the default)", {})]
    else:
        variants = [("grid", dict(topology="grid")), (f"{topo['default']} (default)", {})]
    rows, data = [], []
    for label, kw in variants:
        for r in TWO_PLATES_RES:
            pitch = max(lx, ly) / r
            gap = pitch / 3
            mesh = shapes.two_plates(gap=gap, lx=lx, ly=ly, t=t)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                model = sc_fem.voxelize(mesh, resolution=r, fill="solid", keep="all", **kw, **STEEL)
                single = sc_fem.voxelize(one, resolution=r, fill="solid", **kw, **STEEL)
            assert abs(model.pitch - pitch) < 1e-12 * pitch, (model.pitch, pitch)
            used = _topology_of(model, topo)
            n_parts = int(node_parts(model).max()) + 1
            bm = sc_fem.modal(sc_fem.Scene.from_model(model, mesh), n_modes=10, element=element, keep_rigid=True)
            n_rigid = int(bm.rigid.sum())
            f_two = float(bm.frequencies[~bm.rigid][0])
            b1 = sc_fem.modal(sc_fem.Scene.from_model(single, one), n_modes=10, element=element)
            f_one = float(b1.frequencies[0])
            layers = int(model.dims[2])
            weld = model.info.get("weld")
            rows.append([label, r, f"{1e3 * pitch:.2f}", f"{1e3 * gap:.2f}",
                         "-" if weld is None else f"{1e3 * weld:.2f}", model.n_cubes, model.n_nodes, layers, n_parts,
                         n_rigid, f"{f_two:.2f}", f"{f_one:.2f}", f"{f_ref:.2f}", f"{f_two / f_one:.2f}"])
            data.append(dict(topology=used, topology_label=label, weld=weld, bodies=model.info.get("bodies"),
                             resolution=r, pitch=pitch, gap=gap, cubes=model.n_cubes, nodes=model.n_nodes,
                             z_layers=layers, parts=n_parts, rigid_modes=n_rigid, f1_two_plates=f_two,
                             f1_one_plate=f_one, f1_one_plate_p2=f_ref,
                             freqs_two_plates=bm.frequencies[~bm.rigid][:10].tolist()))
            print(f"[two_plates] topology {label}, r={r}: pitch {1e3 * pitch:.2f} mm, gap {1e3 * gap:.2f} mm, "
                  f"{model.n_cubes} cubes, {model.n_nodes} nodes in {layers} layer(s), {n_parts} lattice part(s), "
                  f"{n_rigid} rigid modes; f1 {f_two:.2f} Hz (one plate alone: sc_fem {f_one:.2f} Hz, "
                  f"P2 {f_ref:.2f} Hz)", file=sys.stderr, flush=True)
    conv = float(abs(refs[0]["freqs"][0] - refs[-1]["freqs"][0]) / refs[-1]["freqs"][0])
    return rows, dict(rows=data, p2_one_plate_f1=[float(x["freqs"][0]) for x in refs],
                      p2_one_plate_levels=[list(x["level"]) for x in refs], p2_change=conv)


def _fmt_freqs(f) -> str:
    return ", ".join(f"{x:.1f}" for x in f)


def thin_main(args) -> int:
    """The ``--thin`` case set (see the module docstring)."""
    import os
    import shutil

    t_start = time.perf_counter()
    resolutions = args.resolutions or ((16, 24, 32) if args.quick else (16, 24, 32, 48, 64))
    all_levels = THIN_QUICK_REF_LEVELS if args.quick else THIN_REF_LEVELS
    elements = args.elements or [sc_fem.DEFAULT_ELEMENT]
    names = args.cases or [*THIN_CASES, "two_plates"]
    unknown = set(names) - {*THIN_CASES, "two_plates"}
    if unknown:
        raise SystemExit(f"unknown thin case(s) {sorted(unknown)}; choose from {[*THIN_CASES, 'two_plates']}")
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", file=sys.stderr, flush=True)
    topo = voxel_topology()
    git = _git_state()
    print(f"sc_fem at {git.get('head', '?')[:10]}, uncommitted under src/: {git.get('src_changed') or 'none'}; "
          f"VoxelOptions topology: " + (f"default {topo['default']!r}, weld default {topo['weld_default']!r}"
                                        if topo["has_topology"] else "no such field (one grid)")
          + f", keep default {topo['keep_default']!r}", file=sys.stderr, flush=True)
    with warnings.catch_warnings():              # imports and JIT compilation outside the timings
        warnings.simplefilter("ignore")
        warm = sc_fem.Scene.from_mesh(_shapes().plate(), resolution=8, fill="solid", fix="x<min+0", **STEEL)
        for element in elements:
            sc_fem.modal(warm, n_modes=10, element=element)
            sc_fem.solve_static(warm, element=element, gravity=(0, 0, -9.81))
    texts, record, series = [], {"cases": {}, "voxel_topology": topo, "git": git}, {}
    for name in names:
        if name == "two_plates":
            continue
        geo = thin_geometry(name)
        refs, conv = [], None
        levels = all_levels if args.quick else THIN_REF_LEVELS_BY_CASE.get(name, all_levels)
        for level in levels:
            n_est = estimate_dofs(geo, level)
            if n_est > args.ref_max_dofs:
                print(f"[{name}] reference level {level}: {n_est} DOFs > --ref-max-dofs {args.ref_max_dofs}: "
                      f"not run", file=sys.stderr, flush=True)
                break
            ref = cached_reference(geo, level, args.reuse_reference)
            refs.append(ref)
            rel = None if len(refs) < 2 else np.abs(refs[-2]["freqs"] - ref["freqs"]) / ref["freqs"]
            change = None if rel is None else float(rel.max())
            ref["change"], ref["mean_change"] = change, None if rel is None else float(rel.mean())
            print(f"[{name}] reference {level}: {ref['n_tets']} P2 tets, {ref['n_dofs']} DOFs, "
                  f"{ref['seconds']:.1f} s (+{ref['static_seconds']:.1f} s static){' (cached)' if ref.get('cached') else ''}; "
                  f"f = {np.round(ref['freqs'], 2)} Hz"
                  + ("" if change is None else f"; max change {100 * change:.3f} %"), file=sys.stderr, flush=True)
            if change is not None and change < REF_TOL:
                conv = change
                break
        ref = refs[-1]
        if conv is None:
            last = "-" if ref["change"] is None else f"{100 * ref['change']:.2f} %"
            print(f"[{name}] WARNING: reference NOT converged to {100 * REF_TOL:g} % (last change {last})",
                  file=sys.stderr, flush=True)
        ref_rows = []
        for k, x in enumerate(refs):
            ref_rows.append([f"d={x['level'][0]}, g={x['level'][1]:g}, n={x['level'][2]}", x["n_tets"], x["n_dofs"],
                             f"{x['mass']:.5g}", _fmt_freqs(x["freqs"]),
                             "-" if x["change"] is None else f"{100 * x['mean_change']:.3f} / {100 * x['change']:.3f}",
                             f"{x['umax']:.4g}", f"{x['seconds']:.1f} (+{x['static_seconds']:.1f})"])
        title = f"### {name}: P2 reference ({THIN_STATIC[name]})"
        print("\n" + title)
        t1 = print_table(["P2 level", "tets", "DOFs", "mass kg", "10 free-free f, Hz", "mean / max change %",
                          "static max |u| m", "time s (+static)"], ref_rows)
        rows, errs, used = [], {}, set()
        for element in elements:
            errs[element] = []
            for r in resolutions:
                if (element in DEGREES or element == "auto") and r > args.higher_max_res:
                    continue
                res = run_thin_sc_fem(geo, r, element, ref, topo)
                used.add(res["topology"])
                fe = np.abs(res["freqs"] - ref["freqs"]) / ref["freqs"]
                best = res["mac"].max(axis=1)
                n_good = int((best >= 0.9).sum())
                errs[element].append((r, float(fe.mean()), float(fe.max()), res["seconds"]))
                rows.append([element, r, res["cubes"], f"{100 * (res['mass'] / ref['mass'] - 1):+.2f}",
                             f"{100 * fe.mean():.2f}", f"{100 * fe.max():.2f}", f"{n_good}/10", f"{best.min():.2f}",
                             f"{100 * (res['umax'] / ref['umax'] - 1):+.1f}", f"{100 * res['u_field_err']:.1f}",
                             f"{res['seconds']:.2f} (+{res['static_seconds']:.2f})",
                             f"{ref['seconds'] / res['seconds']:.0f}x"])
                record["cases"].setdefault(name, {}).setdefault("sc_fem", []).append(dict(
                    element=element, resolution=r, cubes=res["cubes"], mass=res["mass"],
                    freqs=res["freqs"].tolist(), freq_rel_err=fe.tolist(), best_mac=best.tolist(),
                    best_mac_partner=res["mac"].argmax(axis=1).tolist(), umax=res["umax"],
                    u_field_rel_err=res["u_field_err"], seconds=res["seconds"], static_seconds=res["static_seconds"],
                    pitch=res["pitch"], topology=res["topology"], weld=res["weld"], bodies=res["bodies"]))
                print(f"[{name}] {element} r={r} ({res['topology']}): {res['cubes']} cubes, "
                      f"mass {100 * (res['mass'] / ref['mass'] - 1):+.2f} %, "
                      f"f mean {100 * fe.mean():.2f} % max {100 * fe.max():.2f} %, MAC>=0.9 {n_good}/10, "
                      f"max|u| {100 * (res['umax'] / ref['umax'] - 1):+.1f} %, {res['seconds']:.2f} s",
                      file=sys.stderr, flush=True)
        series[name] = (errs, ref["seconds"], ref["mean_change"])
        print()
        t2 = print_table(["element", "res", "cubes", "mass err %", "mean f err %", "max f err %",
                          "ref modes with MAC>=0.9", "worst best-MAC", "static max|u| err %",
                          "static field err % (L2)", "time s (+static)", "ref time / time"], rows)
        texts.append("\n".join([title, "", t1, "", f"sc_fem, {', '.join(elements)}, fill=\"solid\", "
                                f"topology {', '.join(sorted(used))} (reference time {ref['seconds']:.1f} s):", "", t2]))
        record["cases"].setdefault(name, {})["reference"] = [
            dict(level=list(x["level"]), n_tets=x["n_tets"], n_dofs=x["n_dofs"], mass=x["mass"], freqs=x["freqs"].tolist(),
                 max_change=x["change"], mean_change=x["mean_change"], umax=x["umax"], seconds=x["seconds"], static_seconds=x["static_seconds"],
                 timings=x["timings"]) for x in refs]
        record["cases"][name]["static"] = THIN_STATIC[name]
        record["cases"][name]["topology"] = sorted(used)
        record["cases"][name]["reference_converged"] = conv is not None
    if "two_plates" in names:
        rows, rec = two_plates_study(elements[0], all_levels, args.reuse_reference, topo)
        title = "### two_plates: two 0.5 x 0.5 x 0.005 m plates a third of a cube apart (keep=\"all\")"
        print("\n" + title)
        t3 = print_table(["topology", "res", "pitch mm", "gap mm", "weld mm", "cubes", "nodes", "cube layers",
                          "lattice parts",
                          "rigid modes (12 expected)", "f1 two plates Hz", "f1 one plate (sc_fem) Hz",
                          "f1 one plate (P2) Hz", "two / one"], rows)
        texts.append(title + "\n\n" + t3)
        record["two_plates"] = rec
    wall = time.perf_counter() - t_start
    record["wall_seconds"] = wall
    record["resolutions"] = list(resolutions)
    record["elements"] = list(elements)
    print(f"\ntotal wall time {wall / 60:.1f} min", file=sys.stderr, flush=True)
    tag = f"_{args.tag}" if args.tag else ""
    with open(out_path(f"vs_conforming_fem_thin{tag}.md"), "w") as fh:
        fh.write("\n\n".join(texts) + f"\n\nTotal wall time {wall / 60:.1f} min.\n")
    with open(out_path(f"vs_conforming_fem_thin{tag}.json"), "w") as fh:
        json.dump(record, fh, indent=1, default=float)
    if series:
        png = thin_chart(series, elements, f"vs_conforming_fem_thin{tag}.png")
        if not tag:                                # the docs keep the chart of the full set only
            docs = Path(__file__).resolve().parents[1] / "docs" / png.name
            shutil.copyfile(png, docs)
            print(f"wrote {docs}")
    return 0


def thin_chart(series: dict, elements, name: str):
    """Mean frequency error against wall time, one line per case, log-log."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.2))
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    styles = ["o-", "s--", "^:"]
    for i, (case, (errs, ref_seconds, ref_change)) in enumerate(series.items()):
        c = colors[i % len(colors)]
        for j, element in enumerate(elements):
            e = np.array(errs[element])
            label = case if len(elements) == 1 else f"{case} ({element})"
            ax.loglog(e[:, 3], 100 * e[:, 1], styles[j % len(styles)], color=c, label=label, lw=1.6, ms=5)
            for r, err, _, t in errs[element]:
                ax.annotate(str(int(r)), (t, 100 * err), fontsize=7, color=c, textcoords="offset points",
                            xytext=(4, 3))
        if ref_change:
            ax.loglog([ref_seconds], [100 * ref_change], "*", color=c, ms=13, mec="k", mew=0.6)
    ax.plot([], [], "*", color="0.5", ms=12, mec="k", mew=0.6,
            label="P2 reference: its time, its mean level-to-level change")
    ax.axhline(5, color="0.6", lw=0.8, ls="--")
    ax.annotate("5 %", (0, 5), xycoords=("axes fraction", "data"), xytext=(4, 3), textcoords="offset points",
                ha="left", fontsize=7, color="0.4")      # left: the legend sits top right
    ax.set_xlabel("wall time, s (sc_fem: voxelize + assemble + 10 modes; reference: mesh + assemble + eigen)")
    ax.set_ylabel("mean error of the 10 lowest free-free frequencies, %")
    ax.set_title("Thin-walled steel members: sc_fem cubes (labels: resolution) vs conforming P2", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    return save_figure(fig, name)


if __name__ == "__main__":
    sys.exit(main())
