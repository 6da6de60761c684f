"""The ``(r, alpha)`` search of the PDE fit (:func:`sc_fem.reconstruct.pde.fit`).

The constants of Eq. 17 are linear, so the rates are found by variable projection: the
objective (:data:`CRITERIA`: the residual at the fitted frames, or the
leave-one-interior-frame-out error) on the whole log-spaced grid at once, then alpha refined
by batched zoom levels at the best grid r and its neighbours (:func:`_best_alpha`) and
successive parabolic steps in ``log r`` (:func:`_search`). The space side of every rate tried
is kept (:class:`_Sides`): it is the expensive half of an evaluation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .varpro import FitData, SpaceSide, leave_one_out, residual, space_side, time_side

CRITERIA = ("residual", "loo")


@dataclass(frozen=True, eq=False)
class SearchResult:
    """The (r, alpha) search: grid (nr,), (na,), objective (nr, na) and the refined optimum.

    The objective is evaluated on the curve points ``points`` (indices into each curve's
    points: all of them, or an evenly spaced subset when the curves have more than
    ``search_points``; see :func:`~sc_fem.reconstruct.pde.fit`)."""

    r_grid: np.ndarray
    alpha_grid: np.ndarray
    objective: np.ndarray
    criterion: str
    best_objective: float
    points: np.ndarray | None = None


class _Sides:
    """Space sides of the rates ``r`` already evaluated (the grid's, then those of the
    refinement): the space side (basis, SVD, projection of the data) is the expensive half of an
    objective evaluation and is reused whenever only ``alpha`` changes."""

    def __init__(self, data: FitData) -> None:
        self.data = data
        self._store: dict[float, SpaceSide] = {}

    def add(self, space: SpaceSide) -> SpaceSide:
        for k, rk in enumerate(space.r):
            self._store[float(rk)] = space.take(k)
        return space

    def __call__(self, r: float) -> SpaceSide:
        key = float(r)
        if key not in self._store:
            self._store[key] = space_side(self.data, [key])
        return self._store[key]


def _objective(space: SpaceSide, s: np.ndarray, alpha, rcond: float, criterion: str) -> np.ndarray:
    """Search objective (R, A) for every rate of ``space`` and of ``alpha``: the residual at the
    fitted frames (``"residual"``) or the leave-one-interior-frame-out error (``"loo"``)."""
    if criterion == "residual":
        return residual(space, time_side(s, alpha), rcond)
    return leave_one_out(space, s, alpha, rcond)


ZOOM_POINTS = 17
"""Points of every zoom level of the alpha refinement (each level shrinks the step 8-fold)."""
ALPHA_STEP = 3e-2
"""The alpha refinement zooms until its ``log alpha`` step is below this, then takes one
parabolic step through the best three points (on the rope, a step of 4e-3 instead gives the
same objective to 7 digits)."""
R_TOL = 3e-2
"""The r refinement stops when a parabolic step in ``log r`` is shorter than this (r is weakly
identified: on the rope, r = 2.45 and 2.52 give the same E_A to 1e-6)."""
R_STEPS = 8
"""At most this many parabolic steps in ``log r`` (each one a new space side)."""
R_GAIN = 1e-3
"""... and none that the parabola predicts to lower the objective by less than this fraction of it:
the objective is flat in r near its minimum (on the rope in two pieces it differs by 4e-7 of
itself between r = 2.0 and 3.0; one piece: three steps from the grid's best r found nothing lower)."""


def _parabola(x, f, at: float) -> float:
    """Value at ``at`` of the parabola through the three points ``(x, f)``."""
    return float(np.polyval(np.polyfit(x, f, 2), at))


def _vertex(x0, x1, x2, f0, f1, f2):
    """Abscissa of the vertex of the parabola through three points (nan if they are collinear)."""
    den = (x1 - x0) * (f1 - f2) - (x1 - x2) * (f1 - f0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return x1 - 0.5 * ((x1 - x0) ** 2 * (f1 - f2) - (x1 - x2) ** 2 * (f1 - f0)) / den


def _best_alpha(space: SpaceSide, s, ag, lims, rcond: float, criterion: str, near=None, first=None):
    """``(alpha, objective)``, both (R,): alpha minimising the objective at every rate of ``space``.

    Batched levels for all rates at once: the grid ``ag`` (whose objective ``first`` (R, len(ag))
    may be given; with ``2 ZOOM_POINTS - 1`` more points spanning one grid step either side of
    ``near`` (R,), the best ``log alpha`` at a nearby r, if given), then levels of
    :data:`ZOOM_POINTS` around each best point until the step is below :data:`ALPHA_STEP`, then one
    parabolic step through the best three points. Every level is one batched evaluation of
    each rate with its own points (cheap: the time side and small matrix products).""" 
    n_r, rows = len(space.r), np.arange(len(space.r))

    def pairs(alpha_rows):           # objective of rate k with the alphas of row k: (R, n)
        if criterion == "residual":
            return residual(space, time_side(s, alpha_rows.ravel()), rcond, paired=True)
        full = _objective(space, s, alpha_rows.ravel(), rcond, criterion)
        return full.reshape(n_r, n_r, -1)[rows, rows]

    if len(ag) == 1:
        return np.full(n_r, float(ag[0])), (_objective(space, s, ag, rcond, criterion) if first is None else first)[:, 0]
    step = float(np.log(ag[-1] / ag[0])) / (len(ag) - 1)
    pts = np.broadcast_to(np.log(ag), (n_r, len(ag)))
    if near is not None:
        fine = np.asarray(near)[:, None] + step * np.linspace(-1.0, 1.0, 2 * ZOOM_POINTS - 1)
        pts = np.sort(np.clip(np.concatenate([pts, fine], axis=1), *lims), axis=1)
        vals = pairs(np.exp(pts))
    else:
        vals = _objective(space, s, ag, rcond, criterion) if first is None else first
    best, f_best = np.empty(n_r), np.full(n_r, np.inf)
    while True:                      # a handful of levels, each one batched evaluation
        k = np.argmin(vals, axis=1)
        better = vals[rows, k] < f_best
        best[better], f_best[better] = pts[rows, k][better], vals[rows, k][better]
        gaps = np.diff(pts, axis=1)
        step = float(np.max(np.maximum(gaps[rows, np.maximum(k - 1, 0)], gaps[rows, np.minimum(k, gaps.shape[1] - 1)])))
        if step <= ALPHA_STEP:
            break
        pts = np.clip(best[:, None] + step * np.linspace(-1.0, 1.0, ZOOM_POINTS), *lims)
        vals = pairs(np.exp(pts))
    inner = np.clip(k, 1, pts.shape[1] - 2)
    xv = _vertex(*(pts[rows, inner + d] for d in (-1, 0, 1)), *(vals[rows, inner + d] for d in (-1, 0, 1)))
    ok = (inner == k) & (pts[rows, k] == best) & (pts[rows, k - 1] < xv) & (xv < pts[rows, np.minimum(k + 1, pts.shape[1] - 1)])
    if np.any(ok):                   # vertex of the parabola through the best three
        fv = pairs(np.exp(np.where(ok, xv, best))[:, None])[:, 0]
        better = ok & (fv < f_best)
        best[better], f_best[better] = xv[better], fv[better]
    return np.exp(best), f_best


def _search(sides: _Sides, s, r, alpha, bounds_r, bounds_a, grid, rcond, criterion):
    """(r, alpha) minimising the objective: the whole log-spaced grid at once, alpha refined at
    every grid r (:func:`_best_alpha`, batched), then successive parabolic steps in ``log r``
    through the best point and its neighbours, alpha refined at each new r (each new r needs a
    space side, each alpha only the cheap time side)."""
    rg = np.array([r]) if r is not None else np.geomspace(*bounds_r, grid[0])
    ag = np.array([alpha]) if alpha is not None else np.geomspace(*bounds_a, grid[1])
    grid_space = sides.add(space_side(sides.data, rg))
    obj = _objective(grid_space, s, ag, rcond, criterion)           # the whole grid at once
    lims_a = tuple(np.log(bounds_a))
    # alpha refined at the best grid r and its two neighbours (three grid r's: the first parabola in log r)
    i = int(np.argmin(obj.min(axis=1)))
    near = np.arange(len(rg))[max(0, min(i - 1, len(rg) - 3)):][:3]
    sub = SpaceSide(*(getattr(grid_space, k)[near] for k in ("r", "su", "vtu", "un", "xu", "gram", "outf")), grid_space.xx)
    a_best, f_best = _best_alpha(sub, s, ag, lims_a, rcond, criterion, first=obj[near])
    tried = dict(zip(np.log(rg[near]).tolist(), zip(a_best.tolist(), f_best.tolist())))   # log r -> (alpha, objective)
    lo, hi = np.log(bounds_r)
    for _ in range(R_STEPS if r is None and len(rg) >= 3 else 0):   # a handful of steps
        xs = np.array(sorted(tried))
        fs = np.array([tried[v][1] for v in xs])
        i = int(np.clip(np.argmin(fs), 1, len(xs) - 2))
        xv = float(np.clip(_vertex(*xs[i - 1:i + 2], *fs[i - 1:i + 2]), xs[i - 1], xs[i + 1]))
        if not np.isfinite(xv) or np.min(np.abs(xs - xv)) < R_TOL or not lo <= xv <= hi:
            break
        if fs.min() - _parabola(xs[i - 1:i + 2], fs[i - 1:i + 2], xv) <= R_GAIN * fs.min():
            break            # the step would gain (as the parabola predicts) too little to pay for itself
        near = np.log([tried[xs[int(np.argmin(fs))]][0]])
        a_v, f_v = _best_alpha(sides(np.exp(xv)), s, ag, lims_a, rcond, criterion, near=near)
        tried[xv] = (float(a_v[0]), float(f_v[0]))
    x_opt = min(tried, key=lambda v: tried[v][1])
    a_opt, f_opt = tried[x_opt]
    return float(np.exp(x_opt)), a_opt, SearchResult(rg, ag, obj, criterion, f_opt)
