"""The reconstruction job on a vertex animation: extract (or read) curves, fit the PDE model at
some frames, fit the B-spline baseline at the same frames, compare both at every frame in
between. (The ``.npz`` file that holds the result: :mod:`sc_fem.io.reconstruction`.)

Every result is judged (:attr:`Reconstruction.failures`): the PDE fit *fails* when an error is
not finite, when its mean E_A over the evaluated frames exceeds :data:`MAX_MEAN_E_A` or its max
E_M exceeds :data:`MAX_E_M`, or when at the fitted frames its mean E_A is worse than the B-spline
baseline's (errors below :data:`MATCH_FLOOR` count as matching, so a baseline that interpolates
its points does not fail a fit that is good in absolute terms). ``summary()`` and the report say
so; ``sc-fem reconstruct`` then exits 1.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .._validate import positive_int
from ..errors import InputError
from .bspline import bspline_baseline
from .meshmap import curve_mesh_map, curves_to_vertices, extract_curves, lattice_lines
from .metrics import errors
from .pde import check_frame_indices
from .segments import MIN_POINTS, fit_segmented, max_segments

MAX_MEAN_E_A = 0.02
"""A PDE fit whose mean E_A over the evaluated frames is above this (2 % of the curves' diameter;
good fits of simulated animations measure 1e-4 to 2e-3) has failed."""
MAX_E_M = 0.2
"""... or whose largest point error E_M is above this (20 % of a curve's diameter)."""
MATCH_FLOOR = 1e-3
"""At the fitted frames the PDE must do as well as the B-spline baseline (mean E_A) or better than
this: the baseline interpolates short curves (lattice node lines, E_A ~1e-11) where the PDE's
1e-4 is a good fit."""

BUDGET = 2.0
"""``segments="auto"`` stops refining once the PDE model has more than this many times the
B-spline baseline's scalars: past that it is no longer the compact model the paper is about."""


@dataclass(frozen=True, eq=False)
class Reconstruction:
    """PDE and B-spline reconstructions of an animation's curves.

    Attributes
    ----------
    frames : ndarray of int, shape (F,)
        Frames evaluated (every frame from the first to the last fitted one).
    times : ndarray, shape (F,)
        Their times, s.
    fit_frames : ndarray of int, shape (K,)
        Frames the models were fitted to.
    curves_reference, curves_pde, curves_bspline : ndarray, shape (F, C, P, 3)
        Simulated, PDE and B-spline curves, model units.
    E_A_pde, E_M_pde, E_A_bspline, E_M_bspline : ndarray, shape (F, C)
        The paper's errors (Eqs. 26-27) per frame and curve, relative to the curve's diameter.
    r, alpha : float
        Spatial and temporal rates of the PDE model.
    coefficients : ndarray
        The PDE model's fitted coefficients.
    u : ndarray
        Curve parameter values.
    faces : ndarray of int, shape (f, 3)
        Triangles of the animated mesh.
    vertices_pde : ndarray, shape (F, n, 3) or None
        Mesh rebuilt from the PDE curves (when the curves were the lattice's node lines or mesh
        vertices, not stored curves).
    mesh_error_pde : ndarray, shape (F,) or None
        Mean vertex error of that mesh / bounding-box diagonal.
    meta : dict
        Source, timings (s), design-variable counts and options.
    """

    frames: np.ndarray
    times: np.ndarray
    fit_frames: np.ndarray
    curves_reference: np.ndarray
    curves_pde: np.ndarray
    curves_bspline: np.ndarray
    E_A_pde: np.ndarray
    E_M_pde: np.ndarray
    E_A_bspline: np.ndarray
    E_M_bspline: np.ndarray
    r: float
    alpha: float
    coefficients: np.ndarray
    u: np.ndarray
    faces: np.ndarray
    vertices_pde: np.ndarray | None = None
    mesh_error_pde: np.ndarray | None = None
    curve_vertex_index: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    @property
    def fitted(self) -> np.ndarray:
        """Which of :attr:`frames` were fitted, bool (F,)."""
        return np.isin(self.frames, self.fit_frames)

    @property
    def failures(self) -> list[str]:
        """Why the PDE fit failed (see the module docstring), one sentence each; empty if it did not."""
        ea, em = float(np.mean(self.E_A_pde)), float(np.max(self.E_M_pde))
        out = []
        if not (np.all(np.isfinite(self.E_A_pde)) and np.all(np.isfinite(self.E_M_pde))):
            out.append("the PDE curves are not finite at some frames")
        if not ea <= MAX_MEAN_E_A:
            out.append(f"PDE mean E_A {ea:.3g} is above the threshold {MAX_MEAN_E_A:g}")
        if not em <= MAX_E_M:
            out.append(f"PDE max E_M {em:.3g} is above the threshold {MAX_E_M:g}")
        f = self.fitted
        pde, bsp = float(np.mean(self.E_A_pde[f])), float(np.mean(self.E_A_bspline[f]))
        if not pde <= max(bsp, MATCH_FLOOR):
            out.append(f"at the fitted frames the PDE's mean E_A {pde:.3g} is worse than the B-spline "
                       f"baseline's {bsp:.3g}")
        return out

    @property
    def ok(self) -> bool:
        """True when the PDE fit did not fail (:attr:`failures` is empty)."""
        return not self.failures

    def summary(self) -> str:
        """One line: mean E_A and max E_M of both methods, the PDE's rates, and ``fit FAILED`` when
        it failed (:attr:`failures`)."""
        pieces = self.meta.get("segments", 1)
        return (f"PDE: mean E_A {self.E_A_pde.mean():.6f}, max E_M {self.E_M_pde.max():.6f} (r={self.r:.4g}, "
                f"alpha={self.alpha:.4g}, {pieces} piece{'s' if pieces != 1 else ''} per curve); B-spline: mean E_A {self.E_A_bspline.mean():.6f}, "
                f"max E_M {self.E_M_bspline.max():.6f}" + ("" if self.ok else "; fit FAILED"))


ARRAYS = ("frames", "times", "fit_frames", "curves_reference", "curves_pde", "curves_bspline", "E_A_pde",
          "E_M_pde", "E_A_bspline", "E_M_bspline", "coefficients", "u", "faces")
"""The arrays every :class:`Reconstruction` has (and its file stores)."""
OPTIONAL = ("vertices_pde", "mesh_error_pde", "curve_vertex_index")
"""Arrays a :class:`Reconstruction` may lack (``None``; a file stores them when present)."""


def reconstruct_animation(animation, fit_frames, *, n_curves: int = 8, n_points: int = 64, r=None, alpha=None,
                          parametrization: str = "paper", criterion: str = "residual",
                          rigid_interpolation: str = "cubic", remove_rigid: bool = True,
                          n_control: int = 50, offset: str = "auto", segments="auto",
                          curves_from: str = "auto") -> Reconstruction:
    """Reconstruct ``animation`` from ``fit_frames`` with the PDE model and the B-spline baseline.

    Parameters
    ----------
    animation : sc_fem.Animation
        A vertex animation (:func:`sc_fem.io.animation.load_animation` reads the file that
        ``sc-fem simulate`` writes); its ``curves`` (T, C, P, 3) are used
        when it has them, otherwise ``n_curves`` curves of ``n_points`` vertices are extracted along
        the rest principal axis and the mesh is rebuilt from them.
    fit_frames : array_like of int
        At least two increasing frame indices.
    r, alpha : float, optional
        PDE rates (searched when omitted).
    parametrization, criterion, rigid_interpolation, remove_rigid
        See :func:`sc_fem.reconstruct.fit`.
    offset : {"auto", "none", "first"}
        See :func:`sc_fem.reconstruct.fit`; ``"auto"`` tries ``"none"`` (the paper) then ``"first"``
        at every number of pieces.
    n_control : int
        B-spline control points per curve (capped at the points per curve).
    curves_from : {"auto", "stored", "lattice", "mesh"}
        Which curves are fitted: the file's stored ``curves``; the node lines of the cube lattice
        stored by ``sc-fem simulate`` (every node on one line, mapped back to the mesh exactly
        through the stored embedding W -- needs a bar-like lattice whose node lines are all
        complete); or curves of mesh vertices (mapped back to the mesh by inverse distance).
        ``"auto"``: the stored curves, else mesh curves. The lattice's lines rebuild the mesh far
        more accurately (beam r24: 0.05 % of the diagonal against 0.37 %) but are short (one node
        per cube), so the B-spline baseline with ``min(n_control, points)`` control points
        interpolates them and the PDE cannot match it at the fitted frames; ask for them.
    segments : int or "auto"
        Cut every curve into this many pieces, each with its own Eq. 17 model
        (:mod:`.segments`). ``"auto"``: 1, 2, 4, ... pieces (and both offsets) until the PDE fits the fitted frames
        at least as well as the B-spline baseline (mean E_A and max E_M), as finely as the points
        allow, or until the PDE has :data:`BUDGET` times the B-spline's scalars (then the best
        fit tried is kept); ``meta["segments"]`` and ``meta["pde_matches_bspline_at_fitted_frames"]`` say
        what happened.
    """
    anim = animation
    fit_idx = check_frame_indices(np.asarray(fit_frames), anim.n_frames, name="fit_frames")
    frames = np.arange(fit_idx[0], fit_idx[-1] + 1)
    if segments != "auto":
        segments = positive_int(segments, "segments")
    n_control = positive_int(n_control, "n_control")
    source, lines = _curve_source(anim, curves_from)
    curves, idx, on_surface = (anim.curves if source == "stored" else None), None, False
    if source == "lattice":
        L = anim.lattice
        nodes = L.rest[None] + L.displacements                              # (T, q, 3)
        curves = nodes[:, lines]                                            # (T, L, P, 3)
    elif source == "mesh":
        rest, moving = anim.rest_vertices, anim.positions
        if len(rest) < n_curves * n_points and len(anim.faces):
            # too few vertices for the curves (a box of 8): curves through points on the surface,
            # each moving with the vertices of its triangle (barycentric, fixed per point)
            rest, moving = _surface_points(anim, n_curves * n_points)
            on_surface = True
        idx = extract_curves(rest, n_curves, n_points)
        curves = moving[:, idx].astype(np.float64)                          # (T, C, P, 3)
    times = np.asarray(anim.times, dtype=float)
    t0 = time.perf_counter()
    bs = bspline_baseline(curves, times, fit_idx, n_control=min(n_control, curves.shape[2]))
    bs_curves = bs.evaluate(times[frames])
    t_bs = time.perf_counter() - t0
    ref = curves[frames]
    e_bs = errors(ref, bs_curves)
    fitted = np.isin(frames, fit_idx)
    n_p = curves.shape[2]
    if segments == "auto":
        top = max_segments(n_p)
        tries = sorted({*(2 ** k for k in range(8) if 2 ** k < top), top})
    else:
        tries = [segments]
    offsets = ("none", "first") if offset == "auto" else (offset,)
    t0 = time.perf_counter()
    budget = BUDGET * bs.n_parameters
    best = None
    for n_seg, off in ((n, o) for n in tries for o in offsets):   # a handful of refinements
        model = fit_segmented(curves[fit_idx], times[fit_idx], n_seg, r=r, alpha=alpha, remove_rigid=remove_rigid,
                              parametrization=parametrization, rigid_interpolation=rigid_interpolation,
                              criterion=criterion, offset=off)
        pde_curves = model.evaluate(times[frames])
        e_pde = errors(ref, pde_curves)
        matches = bool(e_pde.E_A[fitted].mean() <= e_bs.E_A[fitted].mean()
                       and e_pde.E_M[fitted].max() <= e_bs.E_M[fitted].max())
        if best is None or matches or e_pde.E_A[fitted].mean() < best[2].E_A[fitted].mean():
            best = (model, pde_curves, e_pde, off, matches)
        if matches or (segments == "auto" and model.n_parameters > budget):
            break                       # as good as the baseline, or no longer a compact model
    model, pde_curves, e_pde, off, matches = best
    t_pde = time.perf_counter() - t0
    extra = {}
    if source != "stored":
        if source == "lattice":         # exact: every node is on one line, W maps nodes to vertices
            W, rest_curves, rest_verts = anim.lattice.W[:, lines.ravel()], anim.lattice.rest[lines], anim.rest_vertices
        else:                           # vertices follow the curve points near them at the first fitted frame
            f0 = fit_idx[0]
            W = curve_mesh_map(curves[f0], anim.positions[f0], k=4)
            rest_curves, rest_verts = curves[f0], anim.positions[f0]
        verts = curves_to_vertices(pde_curves, W, rest_curves, rest_verts)
        diag = float(np.linalg.norm(np.ptp(anim.rest_vertices, axis=0)))
        extra = dict(vertices_pde=verts.astype(np.float32),
                     mesh_error_pde=np.linalg.norm(verts - anim.positions[frames], axis=-1).mean(axis=1) / diag)
        if source == "mesh" and not on_surface:       # the curves' points are mesh vertices
            extra["curve_vertex_index"] = idx
    counts = {"PDE scalars (coefficients + r, alpha + rigid)": int(model.n_parameters),
              "PDE constants, paper's count (32 per curve piece)": 32 * int(model.model.n_curves),
              "B-spline scalars": int(bs.n_parameters), "B-spline control points (paper's count)": int(bs.n_control_points),
              "reference scalars (curve points x 3 x frames)": int(ref.size)}
    meta = {"source": str(anim.meta.get("source", "")),
            "timings_s": {"pde": t_pde, "bspline": t_bs}, "counts": counts, "criterion": criterion,
            "rigid_interpolation": rigid_interpolation, "remove_rigid": bool(remove_rigid),
            "parametrization": model.parametrization, "curves_extracted": idx is not None, "offset": off,
            "curves_from": source,
            "segments": int(model.n_segments), "pde_matches_bspline_at_fitted_frames": matches}
    return Reconstruction(frames=frames, times=times[frames], fit_frames=fit_idx, curves_reference=ref,
                          curves_pde=pde_curves, curves_bspline=bs_curves, E_A_pde=e_pde.E_A, E_M_pde=e_pde.E_M,
                          E_A_bspline=e_bs.E_A, E_M_bspline=e_bs.E_M, r=float(model.r), alpha=float(model.alpha),
                          coefficients=model.coefficients, u=model.u, faces=np.asarray(anim.faces), meta=meta,
                          **extra)


CURVE_SOURCES = ("auto", "stored", "lattice", "mesh")


def _curve_source(anim, curves_from: str):
    """``(source, lattice lines or None)`` for :func:`reconstruct_animation`'s ``curves_from``."""
    if curves_from not in CURVE_SOURCES:
        raise InputError(f"curves_from must be one of {list(CURVE_SOURCES)}, got {curves_from!r}")
    if curves_from in ("auto", "stored") and anim.curves is not None:
        return "stored", None
    if curves_from == "stored":
        raise InputError("the animation stores no curves (curves_from='stored')")
    if curves_from == "lattice":
        if anim.lattice is None:
            raise InputError("the animation stores no lattice (write it with sc-fem simulate)")
        lines = lattice_lines(anim.lattice)          # InputError for lattices with holes or branches
        if lines.shape[1] < MIN_POINTS:
            raise InputError(f"the lattice's node lines have only {lines.shape[1]} nodes; a fit needs at least "
                             f"{MIN_POINTS} (a finer resolution)")
        return "lattice", lines
    return "mesh", None


def _surface_points(anim, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points spread over the animated surface by area: rest (n, 3) and per frame (T, n, 3)."""
    faces = np.asarray(anim.faces, dtype=np.int64)
    tri = anim.rest_vertices[faces]                                       # (f, 3, 3)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if not area.sum() > 0:
        raise InputError("the animated mesh has no surface area to put curves on")
    rng = np.random.default_rng(seed)
    face = rng.choice(len(faces), size=n, p=area / area.sum())
    a, b = rng.random(n), rng.random(n)
    flip = a + b > 1.0
    a, b = np.where(flip, 1.0 - a, a), np.where(flip, 1.0 - b, b)
    bary = np.stack([1.0 - a - b, a, b], axis=1)                          # (n, 3)
    rest = np.einsum("nk,nkd->nd", bary, tri[face])
    moving = np.einsum("nk,tnkd->tnd", bary, np.asarray(anim.positions, dtype=float)[:, faces[face]])
    return rest, moving


def markdown_report(result: Reconstruction) -> str:
    """Markdown: per-frame E_A / E_M (mean / max over curves) for PDE and B-spline, then a summary."""
    res = result
    failures = res.failures
    verdict = ("**The PDE fit FAILED**: " + "; ".join(failures) + "." if failures else
               f"The PDE fit is acceptable (mean E_A <= {MAX_MEAN_E_A:g}, max E_M <= {MAX_E_M:g}, at the fitted "
               f"frames no worse than the B-spline or below {MATCH_FLOOR:g}).")
    lines = [verdict, "", "| frame | fitted | PDE E_A | PDE E_M | B-spline E_A | B-spline E_M |",
             "|---:|:---:|---:|---:|---:|---:|"]
    fitted = res.fitted
    for k, f in enumerate(res.frames):
        lines.append(f"| {f} | {'yes' if fitted[k] else ''} | {res.E_A_pde[k].mean():.6f} | "
                     f"{res.E_M_pde[k].max():.6f} | {res.E_A_bspline[k].mean():.6f} | {res.E_M_bspline[k].max():.6f} |")
    lines += ["", f"mean E_A: PDE {res.E_A_pde.mean():.6f}, B-spline {res.E_A_bspline.mean():.6f}; "
              f"max E_M: PDE {res.E_M_pde.max():.6f}, B-spline {res.E_M_bspline.max():.6f}",
              "(E_A, E_M: paper Eqs. 26-27, per curve, normalised by the curve's diameter D; "
              "table: mean of E_A and max of E_M over the curves)", "",
              "| quantity | value |", "|---|---:|"]
    c = res.curves_reference.shape
    origin = {"lattice": " (lattice node lines, exact map to the mesh)", "mesh": " (mesh vertices)",
              "stored": " (stored)"}.get(res.meta.get("curves_from"),
                                         " (extracted)" if res.meta.get("curves_extracted") else " (stored)")
    rows = {"curves x points": f"{c[1]} x {c[2]}" + origin,
            "r": f"{res.r:.4g}", "alpha": f"{res.alpha:.4g}", "parametrization": res.meta.get("parametrization", ""),
            "PDE pieces per curve": res.meta.get("segments", 1), "PDE offset": res.meta.get("offset", "none"),
            "PDE fits the fitted frames at least as well as the B-spline":
                res.meta.get("pde_matches_bspline_at_fitted_frames", "")}
    if res.mesh_error_pde is not None:
        rows["mesh mean vertex error / bbox diagonal (PDE, max over frames)"] = f"{np.max(res.mesh_error_pde):.6f}"
    t = res.meta.get("timings_s", {})
    rows["PDE fit + evaluation (s)"] = f"{t.get('pde', float('nan')):.3f}"
    rows["B-spline fit + evaluation (s)"] = f"{t.get('bspline', float('nan')):.3f}"
    rows.update(res.meta.get("counts", {}))
    lines += [f"| {k} | {v} |" for k, v in rows.items()]
    return "\n".join(lines) + "\n"
