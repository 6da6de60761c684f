"""Separable least squares of Eq. 25 and its (r, alpha) objective, batched over curves and rates.

The data of curve ``c`` and coordinate ``w`` at the ``F`` fitted frames is a frames x points grid
``X_cw``; the design matrix of Eq. 25 is the Kronecker product ``T (x) U_c`` of the time basis
``T`` (F x 4, the same for every curve) and the space basis ``U_c`` (P x 8, from the curve's
parameter values). With column-normalised thin SVDs ``T / tn = Qt St Vt`` and ``U_c / un = Qu
Su Vu``, the least-squares constants are ``Vt^T (Z / (st su^T)) Vu`` (divided by ``tn un^T``) with
``Z = Qt^T X_cw Qu``, where singular-value pairs ``st_a su_b`` below ``rcond`` times the largest
are dropped *jointly* (truncating T and U separately would leave a product condition number up to
cond(T) cond(U)), and the residual is ``|X_cw|^2 - |Z masked|^2``.

Cost. The space side (basis, SVD, projection ``X Qu`` of the data) depends on ``r`` only and the
time side on ``alpha`` only:

* curves whose parameter values are identical (all curves of the rope, whose points sit at the
  same stations along its axis; every piece of a cut curve) share ``U``: one SVD and one matrix
  product ``X Qu`` for all of them instead of one per curve;
* both sides are batched over R values of ``r`` and A values of ``alpha``, and the objective of
  all R x A pairs is one matrix product ``Qt^T (X Qu)``, so the coarse grid of the search is a
  single computation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .basis import space_basis_rates, time_basis_bound, time_basis_rates


SHARED_U_TOL = 1e-12
"""Parameter rows that differ by at most this (the rounding of :func:`.param.parametrize` on
curves cut into pieces) are one row: the space functions then change by at most ``r`` times it."""


def space_rows(u: np.ndarray) -> np.ndarray:
    """Distinct parameter rows of ``u`` (C, P): ``u[:1]`` (G = 1) when every curve has the same
    parameter values to :data:`SHARED_U_TOL`, else ``u`` itself (G = C)."""
    u = np.asarray(u, dtype=float)
    return u[:1].copy() if float(np.max(np.abs(u - u[:1]), initial=0.0)) <= SHARED_U_TOL else u


@dataclass(frozen=True, eq=False)
class FitData:
    """Data of a fit, arranged once.

    Attributes
    ----------
    x : ndarray, shape (C, F, 3, P)
        Aligned curves per curve, fitted frame, coordinate and point (the memory layout of
        :func:`.rigid.remove_rigid`'s result, so that building it copies nothing).
    u_rows : ndarray, shape (G, P)
        Distinct parameter rows: ``G = 1`` when every curve has the same ``u`` (then one space
        basis serves all curves), else ``G = C`` (one per curve).
    xxf : ndarray, shape (F,)
        ``|x|^2`` per frame.
    """

    x: np.ndarray
    u_rows: np.ndarray
    xxf: np.ndarray

    @classmethod
    def build(cls, curves: np.ndarray, u: np.ndarray) -> FitData:
        """From curves (F, C, P, 3) at the fitted frames and parameter values ``u`` (C, P)."""
        x = np.ascontiguousarray(np.asarray(curves, dtype=float).transpose(1, 0, 3, 2))
        xxf = np.einsum("cfwp,cfwp->f", x, x)
        return cls(x=x, u_rows=space_rows(u), xxf=xxf)

    def subset(self, points: np.ndarray) -> FitData:
        """The data at the curve points ``points`` (indices) only."""
        x = np.ascontiguousarray(self.x[..., points])
        return FitData(x=x, u_rows=self.u_rows[:, points], xxf=np.einsum("cfwp,cfwp->f", x, x))

    @property
    def shared(self) -> bool:
        return self.u_rows.shape[0] == 1


@dataclass(frozen=True, eq=False)
class SpaceSide:
    """Space basis of R rates ``r``.

    Attributes
    ----------
    r : ndarray, shape (R,)
    su, vtu, un : ndarray, shapes (R, G, 8), (R, G, 8, 8), (R, G, 8)
        Column-normalised SVD factors of the space basis of every distinct parameter row.
    xu : ndarray, shape (R, C, 3, F, 8)
        The data in the orthonormal coordinates ``Qu`` of the space basis.
    gram : ndarray, shape (R, G, 8, F, F)
        ``sum_{c, w} xu[..., f, j] xu[..., f', j]`` over the curves of each parameter row: all an
        objective needs, so the (r, alpha) grid costs no per-curve work.
    outf : ndarray, shape (R, F)
        Squared data norm per frame outside span(U), which no coefficient can fit.
    xx : float
        Squared norm of all the data.
    """

    r: np.ndarray
    su: np.ndarray
    vtu: np.ndarray
    un: np.ndarray
    xu: np.ndarray
    gram: np.ndarray
    outf: np.ndarray
    xx: float

    def take(self, k: int) -> SpaceSide:
        """The space side of the ``k``-th rate alone (R = 1)."""
        sl = slice(k, k + 1)
        return SpaceSide(self.r[sl], self.su[sl], self.vtu[sl], self.un[sl], self.xu[sl], self.gram[sl],
                         self.outf[sl], self.xx)


@dataclass(frozen=True, eq=False)
class TimeSide:
    """Time basis ``tb`` (A, F, 4) of A rates ``alpha`` and its column-normalised SVD."""

    alpha: np.ndarray
    tb: np.ndarray
    qt: np.ndarray
    st: np.ndarray
    vtt: np.ndarray
    tn: np.ndarray


UNSEEN = 1e-3
"""A time function whose values at the fitted frames have a norm below this fraction of its
largest value on the fitted interval (:func:`.basis.time_basis_bound`) is not fitted (constant
0): fitting it would multiply what it fits by more than ``1 / UNSEEN`` between the frames.
``sin(alpha s)`` at the Nyquist rate ``alpha = pi / ds`` of evenly spaced frames -- the upper
end of the alpha search -- is rounding noise (~1e-14) at every frame and +-1 between them;
column-normalised, it was a unit column whose constant (~1e17) made the curves explode there."""


def svd_normalized(a: np.ndarray, peak: np.ndarray | None = None):
    """Column-normalised thin SVD of (batched) ``a``: ``a / n = q diag(sv) vt``.

    With ``peak`` (..., columns), the largest value of each column's function over the whole
    interval its rows sample, a column whose norm is below :data:`UNSEEN` times it is zeroed
    (singular value 0: dropped by every ``rcond`` mask) instead of being scaled up to unit norm."""
    n = np.linalg.norm(a, axis=-2)
    if peak is not None:
        seen = n > UNSEEN * peak
        a = np.where(seen[..., None, :], a, 0.0)
        n = np.where(seen, n, 0.0)
    n = np.where(n > 0, n, 1.0)
    q, sv, vt = np.linalg.svd(a / n[..., None, :], full_matrices=False)
    return q, sv, vt, n


def space_side(data: FitData, r) -> SpaceSide:
    """Space side for the rates ``r`` (R,): one SVD per rate and distinct parameter row."""
    r = np.atleast_1d(np.asarray(r, dtype=float))
    n_r, (c, f, _, p) = len(r), data.x.shape
    qu, su, vtu, un = svd_normalized(space_basis_rates(data.u_rows, r))       # (R, G, P, 8) ...
    if data.shared:          # one matrix product (C 3 F, P) @ (P, R 8) for every curve and rate
        flat = data.x.reshape(-1, p) @ qu[:, 0].transpose(1, 0, 2).reshape(p, n_r * 8)
        xu = flat.reshape(c, f, 3, n_r, 8).transpose(3, 0, 2, 1, 4)            # (R, C, 3, F, 8) view
        per_rate = flat.reshape(c, f, 3, n_r * 8).transpose(3, 1, 0, 2).reshape(n_r * 8, f, c * 3)
        gram = (per_rate @ per_rate.transpose(0, 2, 1)).reshape(n_r, 1, 8, f, f)
    else:
        xu = np.matmul(data.x[None], qu[:, :, None]).transpose(0, 1, 3, 2, 4)   # (R, C, 3, F, 8)
        gram = np.einsum("rcwfj,rcwgj->rcjfg", xu, xu)
    # qu has orthonormal columns: |x - qu qu^T x|^2 = |x|^2 - |qu^T x|^2 per frame
    outf = np.maximum(data.xxf - np.einsum("rgjff->rf", gram), 0.0)
    return SpaceSide(r, su, vtu, un, xu, gram, outf, float(data.xxf.sum()))


def time_side(s: np.ndarray, alpha) -> TimeSide:
    """Time side for the rates ``alpha`` (A,) at the normalised fitted times ``s`` (F,); a time
    function the frames do not see is dropped (:data:`UNSEEN`)."""
    alpha = np.atleast_1d(np.asarray(alpha, dtype=float))
    tb = time_basis_rates(s, alpha)                                            # (A, F, 4)
    return TimeSide(alpha, tb, *svd_normalized(tb, time_basis_bound(alpha)))


def _mask(st: np.ndarray, su: np.ndarray, rcond: float) -> np.ndarray:
    """Kept singular-value pairs, (A, K, R, G, 8) (K = min(F, 4) time singular values):
    ``st su > rcond * max`` per (alpha, r, curve)."""
    prod = st[:, :, None, None, None] * su[None, None]
    return prod > rcond * prod.max(axis=(1, 4), keepdims=True)


def _coords(xu: np.ndarray, qt: np.ndarray) -> np.ndarray:
    """``Z = Qt^T xu`` for every alpha and r as one matrix product: (A, K, R, C, 3, 8).

    ``xu`` (R, C, 3, F', 8), ``qt`` (A, F', K) with K = min(F', 4)."""
    n_r, n_c, _, n_f, _ = xu.shape
    n_a = qt.shape[0]
    n_k = qt.shape[2]                                  # min(F', 4) time singular vectors
    lhs = qt.transpose(0, 2, 1).reshape(n_a * n_k, n_f)
    rhs = np.moveaxis(xu, 3, 0).reshape(n_f, -1)
    return (lhs @ rhs).reshape(n_a, n_k, n_r, n_c, 3, 8)


def _fitted_norms(gram: np.ndarray, qt: np.ndarray) -> np.ndarray:
    """``|Z[i, j]|^2`` summed over the curves of each parameter row, (A, K, R, G, 8), from the Gram
    matrices: ``sum_{f, f'} qt[f, i] qt[f', i] gram[j, f, f']`` as one matrix product."""
    n_a, n_f, n_k = qt.shape
    n_r, n_g = gram.shape[:2]
    q2 = np.einsum("afi,agi->aifg", qt, qt).reshape(n_a * n_k, n_f * n_f)
    return (q2 @ gram.reshape(-1, n_f * n_f).T).reshape(n_a, n_k, n_r, n_g, 8)


def residual(space: SpaceSide, tside: TimeSide, rcond: float, paired: bool = False) -> np.ndarray:
    """Sum of squared residuals at the fitted frames for every (r, alpha) pair, (R, A); with
    ``paired``, ``tside`` holds ``n`` alphas per rate (rate-major, A = R n) and the result is the
    objective of each rate with its own alphas only, (R, n).

    The fit is the orthogonal projection ``Qt (Z masked) Qu^T``, so the residual is
    ``|X|^2 - |Z masked|^2``."""
    if not paired:
        kept = _fitted_norms(space.gram, tside.qt) * _mask(tside.st, space.su, rcond)
        return np.maximum(space.xx - kept.sum(axis=(1, 3, 4)).T, 0.0)
    n_r, (n_g, n_f) = len(space.r), space.gram.shape[1:4:2]
    n_k = tside.qt.shape[2]
    qt = tside.qt.reshape(n_r, -1, n_f, n_k)
    q2 = np.einsum("rafi,ragi->raifg", qt, qt).reshape(n_r, -1, n_f * n_f)
    e = (q2 @ space.gram.reshape(n_r, n_g * 8, n_f * n_f).transpose(0, 2, 1)).reshape(n_r, -1, n_k, n_g, 8)
    prod = tside.st.reshape(n_r, -1, n_k)[:, :, :, None, None] * space.su[:, None, None]     # (R, n, 4, G, 8)
    kept = e * (prod > rcond * prod.max(axis=(2, 4), keepdims=True))
    return np.maximum(space.xx - kept.sum(axis=(2, 3, 4)), 0.0)


def leave_one_out(space: SpaceSide, s: np.ndarray, alpha, rcond: float) -> np.ndarray:
    """Sum over interior fitted frames ``j`` of the squared error at ``j`` of the fit to the other
    frames, for every (r, alpha) pair, (R, A).

    The prediction at ``j`` of the truncated fit to the kept frames is a combination ``h`` of the
    data's frames (``-1`` at ``j``), so its squared error is ``h^T gram h``, plus the part of
    frame ``j`` outside span(U)."""
    alpha = np.atleast_1d(np.asarray(alpha, dtype=float))
    tb = time_basis_rates(s, alpha)                                            # (A, F, 4)
    n_f = len(s)
    total = np.zeros((len(space.r), len(alpha)))
    for j in range(1, n_f - 1):               # held-out frames (a handful)
        keep = np.arange(n_f) != j
        qk, st, vtt, tn = svd_normalized(tb[:, keep], time_basis_bound(alpha))
        qt = np.zeros((len(alpha), n_f, qk.shape[2]))
        qt[:, keep] = qk
        safe = np.where(st > 0, st, 1.0)
        g = np.where(st > 0, np.einsum("aik,ak->ai", vtt, tb[:, j] / tn) / safe, 0.0)   # row j, SVD basis
        m = _mask(st, space.su, rcond)                                         # (A, 4, R, G, 8)
        h = np.einsum("ai,afi,airgj->argjf", g, qt, m)
        h[..., j] -= 1.0
        err = np.einsum("argjf,rgjfe,argje->ra", h, space.gram, h)
        total += err + space.outf[:, j][:, None]
    return total


def solve(space: SpaceSide, tside: TimeSide, rcond: float) -> np.ndarray:
    """Constants (C, 3, 4, 8) of one (r, alpha) pair (``space`` and ``tside`` of one rate each)."""
    z = _coords(space.xu, tside.qt)[0, :, 0]                                   # (K, C, 3, 8)
    st, su = tside.st[0], space.su[0]                                          # (K,), (G, 8)
    prod = st[:, None, None] * su[None]                                        # (K, G, 8)
    keep = _mask(tside.st, space.su, rcond)[0, :, 0]
    inv = np.where(keep, 1.0 / np.where(keep, prod, 1.0), 0.0)
    zc = (z * inv[:, :, None]).transpose(1, 2, 0, 3)                           # (C, 3, K, 8)
    coef = tside.vtt[0].T @ zc @ space.vtu[0][:, None]
    return coef / (tside.tn[0][:, None] * space.un[0][:, None, None, :])
