"""PDE-based dynamic reconstruction (paper Section 4): fit Eq. 17 to curves at key frames.

Model, per curve ``c`` and coordinate ``w in {x, y, z}`` of the rigid-aligned curve::

    w_c(u, t) = sum_{i<4, j<8} C[c, w, i, j] T_i(t) U_j(u)        (Eq. 17, 32 constants)

Times are normalised internally: ``s = (t - t_first) / (t_last - t_first)`` over the fitted
frames, so the paper's frames 0..10 map to ``s = 0.0 .. 1.0``. ``u`` is a fixed material
coordinate per point (see :mod:`.param`).

Because ``u`` is fixed per point, the data of every curve and coordinate is a frames x points
grid ``X`` and the 32-column design matrix of Eq. 25 is the Kronecker product ``T (x) U``; the
least-squares solution is therefore exactly ``C = pinv(T) X pinv(U)^T`` (column-scaled, SVD
truncation at ``rcond``), done for all curves and coordinates in one batched computation
(:mod:`.varpro`; curves with the same parameter values share one space basis and its SVD).

``r`` and ``alpha`` are not given by the paper. The constants are linear, so ``(r, alpha)`` are
found by variable projection: the residual of the linear problem on the whole log-spaced grid at
once, then alpha refined by batched zoom levels at the best grid r and its neighbours and
successive parabolic steps in ``log r`` (:mod:`.search`). ``alpha`` is bounded by the
Nyquist rate ``pi / max(ds)`` of the fitted frames (beyond it ``sin(alpha t)`` aliases: it fits
the frames and oscillates in between; at it, with evenly spaced frames, ``sin(alpha t)`` vanishes
at every frame and is left out of the fit: :data:`.varpro.UNSEEN`). ``criterion="loo"`` minimises instead the
leave-one-interior-frame-out prediction error, which targets the skipped frames directly. The
search evaluates its objective on at most :data:`SEARCH_POINTS` evenly spaced points per curve;
the constants at the ``(r, alpha)`` found are the least squares of all points.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .._validate import as_float_array, positive_scalar
from ..errors import InputError
from .basis import paper_scale, space_basis, time_basis
from .param import PARAMETRIZATIONS, check_u, parametrize
from .rigid import RIGID_INTERPOLATIONS, RigidMotion
from .rigid import remove_rigid as _remove_rigid
from .search import CRITERIA, SearchResult, _search, _Sides
from .varpro import FitData, SpaceSide, residual, solve, space_rows, time_side


@dataclass(frozen=True, eq=False)
class PDEModel:
    """A fitted Eq. 17 model for ``C`` curves (see module docstring).

    Attributes
    ----------
    coefficients : ndarray, shape (C, 3, 4, 8)
        Constants in the shifted (bounded) basis of :mod:`.basis`; paper ``n = 8 i + j + 1``.
    r, alpha : float
        Spatial (1 / unit u) and temporal (1 / unit normalised time) rates; ``r_bar = r / sqrt 2``.
    u : ndarray, shape (C, P)
        Parameter of every curve point.
    t0, t1 : float
        Times of the first and last fitted frames (caller's units, e.g. seconds).
    fit_times : ndarray, shape (F,)
    rigid : RigidMotion or None
        Rigid motion at the fitted frames (interpolated in between), None if not removed.
    parametrization : str
    residual_rms : float
        RMS point-coordinate residual over the fitted frames (aligned frame, model units).
    search : SearchResult or None
    reference : ndarray, shape (C, P, 3) or None
        With ``offset="first"``: the aligned curves at the first fitted frame; the PDE then
        models the motion away from them (``w = reference + sum C T U``).
    """

    coefficients: np.ndarray
    r: float
    alpha: float
    u: np.ndarray
    t0: float
    t1: float
    fit_times: np.ndarray
    rigid: RigidMotion | None
    parametrization: str
    residual_rms: float
    search: SearchResult | None = None
    reference: np.ndarray | None = None

    @property
    def n_curves(self) -> int:
        return self.coefficients.shape[0]

    @property
    def n_coefficients(self) -> int:
        """Linear constants: 32 per coordinate per curve = 96 per curve (the paper counts 32)."""
        return int(self.coefficients.size)

    @property
    def n_rigid(self) -> int:
        """Rigid-motion numbers needed to go back to world coordinates: 6 per curve per fitted frame."""
        return 0 if self.rigid is None else 6 * self.rigid.rotations.shape[0] * self.n_curves

    @property
    def n_parameters(self) -> int:
        """True scalar count: coefficients + (r, alpha) + rigid motion (u values not counted, see
        :attr:`n_parameter_values`)."""
        return self.n_coefficients + 2 + self.n_rigid + (0 if self.reference is None else int(self.reference.size))

    @property
    def n_parameter_values(self) -> int:
        """Number of stored parameter values ``u`` (one per curve point)."""
        return int(self.u.size)

    @property
    def paper_coefficients(self) -> np.ndarray:
        """(C, 3, 32) constants ``c_wn`` of the paper's unshifted basis (may overflow to 0 / inf)."""
        return self.coefficients.reshape(self.n_curves, 3, 32) * paper_scale(self.r, self.alpha)

    def normalize(self, t) -> np.ndarray:
        """Caller's times -> normalised time ``s`` (0 at the first fitted frame, 1 at the last)."""
        return (np.asarray(t, dtype=float) - self.t0) / (self.t1 - self.t0)

    def evaluate_aligned(self, t, normalized: bool = False) -> np.ndarray:
        """Curves in the rigid-aligned frame, shape (C, P, 3) or (len(t), C, P, 3)."""
        t_arr = np.asarray(t, dtype=float)
        s = np.atleast_1d(t_arr if normalized else self.normalize(t_arr))
        if not np.all(np.isfinite(s)):
            raise InputError("t must be finite")
        tb = time_basis(s.ravel(), self.alpha)                     # (nt, 4)
        out = _synthesize(tb, self.coefficients, space_basis(space_rows(self.u), self.r))
        if self.reference is not None:
            out = out + self.reference[None]
        return out[0] if t_arr.ndim == 0 else out

    def _world_terms(self, s: np.ndarray):
        """``(lhs, ub, rot)`` of the world-frame curves at normalised times ``s`` (nt,): the curves are
        ``sum_j lhs[t, c, j] ub[j](u_cp)`` (:func:`_kron_space`) with ``lhs`` (nt, C, 9, 3) the
        time-combined constants rotated by ``R(s)`` (row vectors: ``aligned @ R``) plus, as a 9-th
        "space function" equal to 1, the translation ``anchor - pivot @ R``; ``ub`` (G, P, 8); ``rot``
        (nt, C, 3, 3). Without ``reference`` (a per-point offset, added by the caller)."""
        rot, anchors = self.rigid.at(s)                                         # (nt, C, 3, 3), (nt, C, 3)
        lhs = np.empty(rot.shape[:2] + (9, 3))
        np.matmul(np.einsum("ti,cwij->tcjw", time_basis(s, self.alpha), self.coefficients), rot, out=lhs[:, :, :8])
        lhs[:, :, 8] = anchors - np.einsum("cv,tcvw->tcw", self.rigid.pivot, rot)
        return lhs, space_basis(space_rows(self.u), self.r), rot

    def evaluate(self, t, normalized: bool = False) -> np.ndarray:
        """Curves at time(s) ``t`` (caller's units, or normalised if ``normalized``), world frame.

        Returns
        -------
        ndarray, shape (C, P, 3) for scalar ``t``, (len(t), C, P, 3) for an array.
        """
        t_arr = np.asarray(t, dtype=float)
        s = np.atleast_1d(t_arr if normalized else self.normalize(t_arr)).ravel()
        if self.rigid is None:
            out = self.evaluate_aligned(s, normalized=True)
            return out[0] if t_arr.ndim == 0 else out
        if not np.all(np.isfinite(s)):
            raise InputError("t must be finite")
        # RigidMotion.to_world of the aligned curves, x = anchor + R^T (aligned - pivot) per point
        # (row vectors: aligned @ R), with R applied to the time-combined constants, not to every point
        lhs, ub, rot = self._world_terms(s)
        if ub.shape[0] == 1:      # one matrix product (nt C, 27) @ (27, P 3) straight into (nt, C, P, 3)
            out = (lhs.reshape(-1, 27) @ _kron_space(ub[0])).reshape(lhs.shape[:2] + (ub.shape[1], 3))
        else:
            out = ub @ lhs[:, :, :8]
            out += lhs[:, :, 8, None, :]
        if self.reference is not None:
            out += self.reference[None] @ rot
        return out[0] if t_arr.ndim == 0 else out


def _kron_space(ub: np.ndarray) -> np.ndarray:
    """``K`` (27, P 3) with ``K[3 j + v, 3 p + w] = ub1[p, j] delta_vw`` for the space basis ``ub``
    (P, 8) and ``ub1 = [ub, 1]``: ``(lhs (n, 9, 3) as (n, 27)) @ K`` is ``ub1 @ lhs`` laid out as
    (n, P, 3), one matrix product writing the points in their final order."""
    n_p = ub.shape[0]
    k = np.zeros((9, 3, n_p, 3))
    for w in range(3):                                     # the three coordinates
        k[:8, w, :, w] = ub.T
        k[8, w, :, w] = 1.0
    return k.reshape(27, 3 * n_p)


# ----------------------------------------------------------------------------- linear algebra
def _synthesize(tb: np.ndarray, coef: np.ndarray, ub: np.ndarray, rot: np.ndarray | None = None) -> np.ndarray:
    """``sum_ij C[c, w, i, j] T_i(t) U_j(u_cp)`` as (nt, C, P, 3) from the time basis ``tb``
    (nt, 4), the constants (C, 3, 4, 8) and the space basis ``ub`` (G, P, 8) of
    :func:`.varpro.space_rows` (G = 1: shared by every curve); with ``rot`` (nt, C, 3, 3), the
    result multiplied by ``rot`` per point, applied to the (nt, C, 8, 3) time-combined constants
    instead of to every point."""
    tc = np.einsum("ti,cwij->tcjw", tb, coef)                      # (nt, C, 8, 3)
    if rot is not None:
        tc = tc @ rot
    return (ub[0] if ub.shape[0] == 1 else ub) @ tc                # (P, 8) or (C, P, 8) @ (nt, C, 8, 3)


# ----------------------------------------------------------------------------- public fit
def _check_curves(curves, name: str = "curves", min_frames: int = 2) -> np.ndarray:
    x = as_float_array(curves, name)
    if x.ndim != 4 or x.shape[-1] != 3:
        raise InputError(f"{name} must have shape (n_frames, n_curves, n_points, 3), got {x.shape}")
    if x.shape[0] < min_frames:
        raise InputError(f"{name} has {x.shape[0]} frame(s); at least {min_frames} are needed to fit motion")
    if x.shape[1] < 1 or x.shape[2] < 8:
        raise InputError(f"{name} needs >= 1 curve of >= 8 points (8 space functions), got {x.shape[1:3]}")
    return x


def check_frame_indices(frames, n_frames: int, name: str = "fit_frames") -> np.ndarray:
    """>= 2 strictly increasing integer frame indices in ``[0, n_frames)``, as an int array."""
    idx = np.asarray(frames)
    if idx.ndim != 1 or (idx.size and not np.issubdtype(idx.dtype, np.integer)):
        raise InputError(f"{name} must be a 1-D sequence of integer frame indices, got {frames!r}")
    if idx.size < 2:
        raise InputError(f"{name} needs at least 2 frames, got {idx.tolist()}")
    if idx.min() < 0 or idx.max() >= n_frames or np.any(np.diff(idx) <= 0):
        raise InputError(f"{name} must be strictly increasing indices in [0, {n_frames - 1}], got {idx.tolist()}")
    return idx.astype(np.int64)


def _check_times(times, n_frames: int) -> np.ndarray:
    t = as_float_array(times, "times", (-1,))
    if len(t) != n_frames:
        raise InputError(f"times must have one entry per frame ({n_frames}), got {len(t)}")
    if np.any(np.diff(t) <= 0):
        raise InputError("times must be strictly increasing")
    return t


OFFSETS = ("none", "first")

ALPHA_LOW = 0.05
"""Lower bound of the alpha search (1 / unit normalised time)."""

SEARCH_POINTS = 64
"""Default most points per curve at which the (r, alpha) search evaluates its objective. The
space functions of the largest default rate (``r = 30``: ``sin(30 u)``, under 5 periods on
[0, 1]) are sampled 13 times a period by 64 evenly spaced points."""


def search_point_index(n_points: int, search_points: int | None) -> np.ndarray:
    """Indices of the points the search uses: all ``n_points``, or ``search_points`` evenly
    spaced ones including both ends."""
    if search_points is None or n_points <= search_points:
        return np.arange(n_points)
    return np.unique(np.round(np.linspace(0, n_points - 1, search_points)).astype(np.int64))


def fit(curves, times, r: float | None = None, alpha: float | None = None, remove_rigid: bool = True,
        parametrization: str = "paper", u=None, *, rigid_interpolation: str = "cubic",
        criterion: str = "residual", r_bounds: tuple[float, float] = (0.2, 30.0),
        alpha_bounds: tuple[float, float] | None = None, grid: tuple[int, int] = (14, 14),
        rcond: float = 1e-11, offset: str = "none", search_points: int | None = SEARCH_POINTS) -> PDEModel:
    """Fit the PDE model of Eq. 17 to curves at the fitted (key) frames.

    Parameters
    ----------
    curves : array_like, shape (F, C, P, 3)
        Curve points at the fitted frames, model units; point ``k`` is the same material point
        in every frame and point 0 is the curve's first point (Eq. 19).
    times : array_like, shape (F,)
        Strictly increasing times of these frames (any unit; normalised internally to [0, 1]).
    r, alpha : float, optional
        Spatial and temporal rates (``alpha = r^2 sqrt(K/m)``); searched if None.
    remove_rigid : bool
        Remove per-curve rigid motion first (Eqs. 18-23) and restore it when evaluating.
    parametrization : {"paper", "arclength"}
        How ``u`` is computed from the first (aligned) frame; see :mod:`.param`.
    u : array_like, shape (P,) or (C, P), optional
        Explicit parameter values in [0, 1] (override ``parametrization``).
    rigid_interpolation : {"cubic", "linear"}
        Interpolation of the rigid motion between fitted frames (see :mod:`.rigid`).
    criterion : {"residual", "loo"}
        Search objective: residual at the fitted frames (variable projection, default) or
        leave-one-interior-frame-out prediction error.
    r_bounds, alpha_bounds : (float, float)
        Search bounds; ``alpha_bounds`` defaults to ``(0.05, pi / max(ds))`` (Nyquist).
    grid : (int, int)
        Coarse grid size (log-spaced) before the bounded refinement.
    rcond : float
        Relative cut-off on the singular values of the column-scaled Kronecker design matrix.
    offset : {"none", "first"}
        ``"none"`` (the paper): Eq. 17 models the aligned curves themselves. ``"first"``: it
        models their motion away from the first fitted frame, which is stored (``3 P`` more
        numbers per curve, counted in :attr:`PDEModel.n_parameters`) -- for curves whose rest
        shape 8 smooth space functions cannot follow (curves extracted from an arbitrary mesh).
    search_points : int or None
        The search evaluates its objective on at most this many evenly spaced points per curve
        (None: all points); the constants are then fitted to all points. The search's cost is
        proportional to the points it uses (the rope's 832-point curves: 13 times fewer).

    Returns
    -------
    PDEModel
    """
    x = _check_curves(curves)
    n_f, n_c, n_p, _ = x.shape
    t = _check_times(times, n_f)
    if parametrization not in PARAMETRIZATIONS:
        raise InputError(f"parametrization must be one of {PARAMETRIZATIONS}, got {parametrization!r}")
    if rigid_interpolation not in RIGID_INTERPOLATIONS:
        raise InputError(f"rigid_interpolation must be one of {RIGID_INTERPOLATIONS}, got {rigid_interpolation!r}")
    if criterion not in CRITERIA:
        raise InputError(f"criterion must be one of {CRITERIA}, got {criterion!r}")
    if offset not in OFFSETS:
        raise InputError(f"offset must be one of {OFFSETS}, got {offset!r}")
    if criterion == "loo" and n_f < 3:
        raise InputError("criterion='loo' needs at least 3 fitted frames")
    r = None if r is None else positive_scalar(r, "r")
    alpha = None if alpha is None else positive_scalar(alpha, "alpha")
    s = (t - t[0]) / (t[-1] - t[0])
    if remove_rigid:
        al = _remove_rigid(x)
        aligned = al.aligned
        rigid = RigidMotion(s, al.rotations, al.anchors, rigid_interpolation)
    else:
        aligned, rigid = x, None
    if u is None:
        uu = parametrize(aligned[0], parametrization)
        pname = parametrization
    else:
        uu = check_u(u, n_c, n_p)
        pname = "explicit"
    reference = aligned[0].copy() if offset == "first" else None
    if reference is not None:
        aligned = aligned - reference[None]
    data = FitData.build(aligned, uu)
    search = None
    sides = _Sides(data)
    if search_points is not None and (isinstance(search_points, bool) or not isinstance(search_points, (int, np.integer))
                                      or search_points < 8):
        raise InputError(f"search_points must be an integer >= 8 (one per space function) or None, got {search_points!r}")
    if r is None or alpha is None:
        ds = float(np.max(np.diff(s)))
        ab = alpha_bounds if alpha_bounds is not None else (ALPHA_LOW, np.pi / ds)
        if not (0 < r_bounds[0] < r_bounds[1] and 0 < ab[0] < ab[1]):
            raise InputError(f"bounds must be 0 < low < high, got r_bounds={r_bounds}, alpha_bounds={ab}")
        pts = search_point_index(n_p, search_points)
        searched = sides if len(pts) == n_p else _Sides(data.subset(pts))
        r, alpha, search = _search(searched, s, r, alpha, r_bounds, ab, grid, rcond, criterion)
        search = dataclasses.replace(search, points=pts)
    tside = time_side(s, alpha)
    space = sides(r)
    coef = solve(space, tside, rcond)
    return PDEModel(coefficients=coef, r=float(r), alpha=float(alpha), u=uu, t0=float(t[0]),
                    t1=float(t[-1]), fit_times=t, rigid=rigid, parametrization=pname,
                    residual_rms=_residual_rms(data, space, tside, coef, rcond), search=search, reference=reference)


RESIDUAL_BY_NORMS = 1e-6
""":func:`_residual_rms` takes the residual as ``|X|^2 - |fit|^2`` when it is at least this
fraction of ``|X|^2`` (rounding then changes the RMS by under 1e-9 of itself) and sums the
squared differences point by point below it."""


def _residual_rms(data: FitData, space: SpaceSide, tside, coef: np.ndarray, rcond: float) -> float:
    """RMS residual of the fit at the fitted frames (model units). The fit is an orthogonal
    projection, so the squared residual is ``|X|^2 - |Z kept|^2`` (:func:`.varpro.residual`),
    free from the data's size; only a fit so close that this difference is lost to rounding
    recomputes the fitted curves and subtracts them."""
    size = data.x.size
    res = float(residual(space, tside, rcond)[0, 0])
    if res >= RESIDUAL_BY_NORMS * space.xx:
        return float(np.sqrt(res / size))
    ub = space_basis(data.u_rows, space.r[0])                       # (G, P, 8)
    tc = np.einsum("fi,cwij->cfwj", tside.tb[0], coef)               # (C, F, 3, 8)
    if data.shared:      # one product (C F 3, 8) @ (8, P)
        resid = (tc.reshape(-1, 8) @ ub[0].T).reshape(data.x.shape)
    else:
        resid = tc @ np.swapaxes(ub, -1, -2)[:, None]                 # (C, F, 3, P)
    resid -= data.x          # in place: a second large temporary costs more than the arithmetic
    return float(np.sqrt(np.vdot(resid, resid) / size))
