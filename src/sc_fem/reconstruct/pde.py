"""PDE-based dynamic reconstruction (paper Section 4): fit Eq. 17 to curves at key frames.

Model, per curve ``c`` and coordinate ``w in {x, y, z}`` of the rigid-aligned curve::

    w_c(u, t) = sum_{i<4, j<8} C[c, w, i, j] T_i(t) U_j(u)        (Eq. 17, 32 constants)

Times are normalised internally: ``s = (t - t_first) / (t_last - t_first)`` over the fitted
frames, so the paper's frames 0..10 map to ``s = 0.0 .. 1.0``. ``u`` is a fixed material
coordinate per point (see :mod:`.param`).

Because ``u`` is fixed per point, the data of every curve and coordinate is a frames x points
grid ``X`` and the 32-column design matrix of Eq. 25 is the Kronecker product ``T (x) U``; the
least-squares solution is therefore exactly ``C = pinv(T) X pinv(U)^T`` (column-scaled, SVD
truncation at ``rcond``), done for all curves and coordinates in one batched computation.

``r`` and ``alpha`` are not given by the paper. The constants are linear, so ``(r, alpha)`` are
found by variable projection: for each pair solve the linear problem, minimise the residual on a
log-spaced grid, then refine with bounded L-BFGS-B in log space. ``alpha`` is bounded by the
Nyquist rate ``pi / max(ds)`` of the fitted frames (beyond it ``sin(alpha t)`` aliases: it fits
the frames and oscillates in between). ``criterion="loo"`` minimises instead the
leave-one-interior-frame-out prediction error, which targets the skipped frames directly.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize

from .._validate import as_float_array, positive_scalar
from ..errors import InputError
from .basis import paper_scale, space_basis, time_basis
from .param import PARAMETRIZATIONS, check_u, parametrize
from .rigid import RIGID_INTERPOLATIONS, RigidMotion
from .rigid import remove_rigid as _remove_rigid

CRITERIA = ("residual", "loo")


@dataclass(frozen=True, eq=False)
class SearchResult:
    """The (r, alpha) search: grid (nr,), (na,), objective (nr, na) and the refined optimum."""

    r_grid: np.ndarray
    alpha_grid: np.ndarray
    objective: np.ndarray
    criterion: str
    best_objective: float


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
        ub = space_basis(self.u, self.r)                           # (C, P, 8)
        out = np.einsum("ti,cwij,cpj->tcpw", tb, self.coefficients, ub, optimize=True)
        if self.reference is not None:
            out = out + self.reference[None]
        return out[0] if t_arr.ndim == 0 else out

    def evaluate(self, t, normalized: bool = False) -> np.ndarray:
        """Curves at time(s) ``t`` (caller's units, or normalised if ``normalized``), world frame.

        Returns
        -------
        ndarray, shape (C, P, 3) for scalar ``t``, (len(t), C, P, 3) for an array.
        """
        t_arr = np.asarray(t, dtype=float)
        s = np.atleast_1d(t_arr if normalized else self.normalize(t_arr)).ravel()
        aligned = self.evaluate_aligned(s, normalized=True)
        out = aligned if self.rigid is None else self.rigid.to_world(aligned, s)
        return out[0] if t_arr.ndim == 0 else out


# ----------------------------------------------------------------------------- linear algebra
def _svd(a: np.ndarray):
    """Column-normalised thin SVD of (batched) ``a``: ``a / n = q diag(sv) vt``."""
    n = np.linalg.norm(a, axis=-2)
    n = np.where(n > 0, n, 1.0)
    q, sv, vt = np.linalg.svd(a / n[..., None, :], full_matrices=False)
    return q, sv, vt, n


def _space_side(x: np.ndarray, u: np.ndarray, r: float, xx: np.ndarray | None = None):
    """SVD of the space basis and the data in its orthonormal coordinates (reused across alpha).

    Returns ``(qu, su, vtu, un)``, ``xu`` (C, 3, F, 8) and ``out_u`` (F,): the squared data norm
    per frame outside span(U), which no coefficient can fit.
    """
    qu, su, vtu, un = _svd(space_basis(u, r))
    xu = x @ qu[:, None]                                                 # (C, 3, F, 8)
    # qu has orthonormal columns: |x - qu qu^T x|^2 = |x|^2 - |qu^T x|^2 per frame (no (C, 3, F, P) temporary)
    if xx is None:
        xx = np.einsum("cwfp,cwfp->f", x, x)
    out = xx - np.einsum("cwfj,cwfj->f", xu, xu)
    return (qu, su, vtu, un), xu, np.maximum(out, 0.0)


def _time_side(s: np.ndarray, alpha: float, criterion: str):
    """Time basis and its column-normalised SVD(s) for one ``alpha`` (reused across r).

    Returns ``(tb, svd)`` with ``svd`` the SVD of ``tb`` (``"residual"``) or a list of
    ``(j, keep, svd of tb[keep])`` per held-out interior frame ``j`` (``"loo"``).
    """
    tb = time_basis(s, alpha)
    if criterion == "residual":
        return tb, _svd(tb)
    keeps = [np.arange(len(s)) != j for j in range(1, len(s) - 1)]   # held-out frames (a handful)
    return tb, [(j + 1, keep, _svd(tb[keep])) for j, keep in enumerate(keeps)]


def _project(xu: np.ndarray, su: np.ndarray, tsvd, rcond: float):
    """Truncated projection onto span(T (x) U) of data already in U's orthonormal coordinates.

    ``tsvd = _svd(T)``. The Kronecker design matrix has singular values ``st_a * su_b``; pairs
    below ``rcond`` times the largest are dropped *jointly* (truncating T and U separately would
    leave a product condition number up to cond(T) * cond(U) and lose all precision in the
    coefficients). Returns ``z`` (C, 3, 4, 8) coordinates in the orthonormal bases and the mask.
    """
    qt, st, vtt, tn = tsvd
    prod = st[None, :, None] * su[:, None, :]                           # (C, 4, 8)
    mask = prod > rcond * prod.max(axis=(1, 2), keepdims=True)
    z = (qt.T @ xu) * mask[:, None]
    return z, mask


def _solve(x: np.ndarray, s: np.ndarray, u: np.ndarray, r: float, alpha: float, rcond: float,
           space=None) -> np.ndarray:
    """Coefficients (C, 3, 4, 8) of the separable least squares for data ``x`` (C, 3, F, P);
    ``space`` is ``_space_side(x, u, r)`` if already computed."""
    (qu, su, vtu, un), xu, _ = _space_side(x, u, r) if space is None else space
    tsvd = _svd(time_basis(s, alpha))
    qt, st, vtt, tn = tsvd
    z, mask = _project(xu, su, tsvd, rcond)
    inv = np.where(mask, 1.0 / np.where(mask, st[None, :, None] * su[:, None, :], 1.0), 0.0)
    coef = vtt.T @ (z * inv[:, None]) @ vtu[:, None]
    return coef / (tn[None, None, :, None] * un[:, None, None, :])


def _objective(space, tside, rcond: float, criterion: str) -> float:
    """Sum of squared residuals (``"residual"``) or of leave-one-interior-frame-out errors,
    given the space side ``space = _space_side(x, u, r)`` and ``tside = _time_side(s, alpha,
    criterion)``."""
    (qu, su, *_), xu, out_u = space
    tb, tsvd = tside
    if criterion == "residual":
        z, _ = _project(xu, su, tsvd, rcond)
        return float(out_u.sum() + np.sum((xu - tsvd[0] @ z) ** 2))
    total = 0.0
    for j, keep, (qt, st, vtt, tn) in tsvd:     # loop over held-out frames (a handful)
        z, _ = _project(xu[:, :, keep], su, (qt, st, vtt, tn), rcond)
        g = (vtt @ (tb[j] / tn)) / st                                   # row j in the SVD basis
        total += float(np.sum((xu[:, :, j] - np.einsum("a,cwab->cwb", g, z)) ** 2) + out_u[j])
    return total


class _SpaceCache:
    """The last few ``_space_side(x, u, r)`` by ``r``: the space side (basis, SVD, projection of
    the data) is the expensive half of an objective evaluation and is reused whenever only
    ``alpha`` changes (``r`` given, or the alpha-steps of the refinement)."""

    def __init__(self, x: np.ndarray, u: np.ndarray, size: int = 4) -> None:
        self.x, self.u, self.size = x, u, size
        self.xx = np.einsum("cwfp,cwfp->f", x, x)                   # |x|^2 per frame, for every r
        self._store: dict[float, tuple] = {}

    def __call__(self, r: float):
        key = float(r)
        if key not in self._store:
            if len(self._store) >= self.size:
                self._store.pop(next(iter(self._store)))
            self._store[key] = _space_side(self.x, self.u, key, self.xx)
        return self._store[key]


def _search(x, s, space_of: _SpaceCache, r, alpha, bounds_r, bounds_a, grid, rcond, criterion):
    rg = np.array([r]) if r is not None else np.geomspace(*bounds_r, grid[0])
    ag = np.array([alpha]) if alpha is not None else np.geomspace(*bounds_a, grid[1])
    tsides = [_time_side(s, ai, criterion) for ai in ag]               # time side once per alpha
    obj = np.empty((len(rg), len(ag)))
    for i, ri in enumerate(rg):                     # grid loops (small); space side once per r
        space = space_of(ri)
        obj[i] = [_objective(space, ts, rcond, criterion) for ts in tsides]
    i, j = np.unravel_index(np.argmin(obj), obj.shape)
    free = [k for k, v in enumerate((r, alpha)) if v is None]
    start = np.log([rg[i], ag[j]])
    lims = np.log([bounds_r, bounds_a])

    floor = 1e-30 * (float(np.sum(x * x)) + 1e-300)

    def f(z):   # log of the objective: the optimum may be an exact fit (objective -> 0)
        p = start.copy()
        p[free] = z
        r_, a_ = np.exp(p)
        return np.log(_objective(space_of(r_), _time_side(s, a_, criterion), rcond, criterion) + floor)

    f0 = f(start[free])
    res = minimize(f, start[free], method="L-BFGS-B", bounds=[tuple(lims[k]) for k in free],
                   options={"ftol": 1e-8, "gtol": 1e-6, "maxiter": 40})
    best = start.copy()
    if res.fun < f0:
        best[free] = res.x
    r_opt, a_opt = np.exp(best)
    return float(r_opt), float(a_opt), SearchResult(rg, ag, obj, criterion, float(np.exp(min(res.fun, f0)) - floor))


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


def fit(curves, times, r: float | None = None, alpha: float | None = None, remove_rigid: bool = True,
        parametrization: str = "paper", u=None, *, rigid_interpolation: str = "cubic",
        criterion: str = "residual", r_bounds: tuple[float, float] = (0.2, 30.0),
        alpha_bounds: tuple[float, float] | None = None, grid: tuple[int, int] = (14, 14),
        rcond: float = 1e-11, offset: str = "none") -> PDEModel:
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
    data = np.ascontiguousarray(aligned.transpose(1, 3, 0, 2))    # (C, 3, F, P)
    search = None
    space_of = _SpaceCache(data, uu)
    if r is None or alpha is None:
        ds = float(np.max(np.diff(s)))
        ab = alpha_bounds if alpha_bounds is not None else (ALPHA_LOW, np.pi / ds)
        if not (0 < r_bounds[0] < r_bounds[1] and 0 < ab[0] < ab[1]):
            raise InputError(f"bounds must be 0 < low < high, got r_bounds={r_bounds}, alpha_bounds={ab}")
        r, alpha, search = _search(data, s, space_of, r, alpha, r_bounds, ab, grid, rcond, criterion)
    coef = _solve(data, s, uu, r, alpha, rcond, space=space_of(r))
    fitted = np.einsum("fi,cwij,cpj->cwfp", time_basis(s, alpha), coef, space_basis(uu, r))
    rms = float(np.sqrt(np.mean((fitted - data) ** 2)))
    return PDEModel(coefficients=coef, r=float(r), alpha=float(alpha), u=uu, t0=float(t[0]),
                    t1=float(t[-1]), fit_times=t, rigid=rigid, parametrization=pname,
                    residual_rms=rms, search=search, reference=reference)

