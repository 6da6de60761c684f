"""Block LOBPCG for the smallest eigenpairs of ``A x = lambda B x`` with a preconditioner.

:func:`lobpcg` is the robust form of Knyazev's LOBPCG (Knyazev 2001; Duersch, Shao, Yang & Gu,
"A robust and efficient implementation of LOBPCG", SIAM J. Sci. Comput. 40, 2018), written for
blocks of a few vectors on millions of DOFs, where the ``n``-sized arrays are what costs:

* **Soft locking**: a block column whose residual ``||A x - theta B x||`` is below ``tol`` gets no
  new search direction; only the active columns' residuals are preconditioned (``W = T R``) and
  multiplied by ``A`` and ``B``. It stays in the block and in every Rayleigh--Ritz step.
* **An orthonormal basis**: ``W`` is ``B``-orthogonalized against ``[X, P]`` (block Gram--Schmidt,
  a second pass when it cancelled more than :data:`REORTHOGONALIZE`) and ``B``-orthonormalized by
  SVQB (the eigen-decomposition of its scaled Gram matrix; directions below :data:`DROP` are
  dropped, so an ill-conditioned block loses columns instead of stalling). The Rayleigh--Ritz
  step on ``[X, P, W]`` (at most ``3m`` columns) then has ``B``-Gram ``~ I``: its ``X`` and ``P``
  blocks are known (``I``, ``diag(theta)`` and ``P^T A P``); the ``W`` rows are computed.
* **The implicit ``P`` update**: ``P`` is the ``W, P`` part of the active Ritz vectors,
  orthogonalized against the new ``X`` within the Ritz coefficients, so ``[X, P]`` stays
  ``B``-orthonormal; ``X, P, AX, AP`` are updated from ``[X, P, W]`` and ``[AX, AP, AW]`` by one
  ``(3m) x (2m)`` coefficient matrix: no product with ``A`` or ``B`` of ``X`` or ``P``.
* **In place**: ``X, AX, P, AP, W`` are the only ``n``-sized arrays kept; the products ``B X``
  (for the residual), ``B W``, ``A W`` and the preconditioner's output are their callers'
  allocations, dropped as soon as used. Updates run over row chunks of :data:`CHUNK_BYTES`, each
  a small GEMM whose result is written back over its input (columns of ``W`` and ``P`` are
  packed at the front of their buffers, so a block of ``c <= m`` columns is a C-ordered array).
  Peak: 6 blocks of ``n x m`` doubles (5 kept, one product) beside the preconditioner's own.
* **Stopping**: when the ``k`` wanted (lowest) pairs' residuals are ``<= tol`` (re-checked with a
  fresh ``A X``: ``AX`` is updated implicitly), at ``maxiter``, or when they stop decreasing: at
  the checks of :data:`CHECKS`, a window whose best residual is no better than the previous
  window's is ``"stalled"``; one whose reduction, kept up, would not reach ``tol`` within
  ``maxiter`` is ``"slow"``. A Rayleigh--Ritz step that breaks down (its Gram matrix not positive
  definite) is restarted without ``P``; a second in a row, or no search direction left, is
  ``"stalled"``. At each check a ``monitor`` may also stop it (``"over budget"``), given the
  iterations the decay of the last window, kept up, would take in all
  (:func:`projected_iterations`).
"""

from __future__ import annotations

from typing import Callable

import numpy as np
from scipy.linalg import LinAlgError, eigh

from .._log import logger

_LOG = logger.getChild("lobpcg")

CHUNK_BYTES = 1 << 20
"""Bytes of one row chunk's input in the in-place updates (the chunk stays in the L2 cache)."""

DROP = 1e-14
"""SVQB: a direction whose eigenvalue of the scaled ``B``-Gram matrix is below ``DROP`` times the
largest is dropped (its norm ratio below 1e-7: it is rounding, not a direction)."""

NOISE = 1e-24
"""A ``W`` column whose squared ``B``-norm fell below ``NOISE`` times its own before the
orthogonalization against ``[X, P]`` lies in their span: dropped."""

REORTHOGONALIZE = 1e-8
"""A second Gram--Schmidt pass when a ``W`` column kept less than this of its squared ``B``-norm
(its rounding, relative to what is left, would exceed ~1e-12)."""

CHECKS = (20, 8)
"""Iterations of the first window, and of every later one, between the progress checks (see the
module docstring): small models converge within the first; the bridge at resolution 128 cut its
residual by 1 % in a window of 8, the cantilevers 3x or more."""

Product = Callable[[np.ndarray], np.ndarray]


def projected_iterations(history: list[np.ndarray], tol: float, window: int) -> float:
    """Iterations in all that LOBPCG would take if the largest wanted residual kept falling as it
    fell over the last ``window`` iterations (its logarithm, linearly), ``inf`` when it did not fall.

    Parameters
    ----------
    history : list of ndarray
        The wanted pairs' residual norms at iterations ``0 .. it``.
    tol : float
        The residual tolerance.
    window : int
        Iterations the decay is measured over.

    Returns
    -------
    float
        ``it + log(r_it / tol) / rate``, ``rate = log(r_(it-window) / r_it) / window``.
    """
    it = len(history) - 1
    window = min(window, it)                               # a check before the window: what there is
    if window < 1:
        return float("inf")
    return _extrapolated(it, float(np.max(history[-1 - window])) / tol, float(np.max(history[-1])) / tol, window)


def _extrapolated(it: int, before: float, now: float, window: int) -> float:
    """The iteration at which a residual that fell from ``before`` to ``now`` (over the tolerance)
    in ``window`` iterations, up to ``it``, would reach the tolerance falling on at that rate (its
    logarithm, linearly); ``inf`` when it did not fall."""
    rate = np.log(before / now) / window if now > 0 and before > 0 else 0.0
    return it + max(np.log(now), 0.0) / rate if rate > 0 else float("inf")


def _product(A) -> Product:
    """``X -> A @ X`` for a callable (returned as it is) or a matrix/operator with ``@``."""
    return A if callable(A) else A.__matmul__


def _view(buf: np.ndarray, n: int, c: int) -> np.ndarray:
    """The first ``n * c`` entries of the flat buffer as a C-ordered (n, c) array."""
    return buf[:n * c].reshape(n, c)


def _rows(n: int, width: int) -> list[slice]:
    """Row chunks of about :data:`CHUNK_BYTES` for ``width`` doubles a row."""
    step = max(64, CHUNK_BYTES // (8 * max(width, 1)))
    return [slice(i, min(i + step, n)) for i in range(0, n, step)]


def _transform(buf: np.ndarray, n: int, c_in: int, Q: np.ndarray) -> np.ndarray:
    """In place: the (n, c_in) view of the flat ``buf`` becomes the (n, c_out) view ``V Q``.
    Chunks run forward when the rows shrink, backward when they grow, so that no chunk is
    overwritten before it is read."""
    c_out = Q.shape[1]
    src, dst = _view(buf, n, c_in), _view(buf, n, c_out)
    rows = _rows(n, c_in + c_out)
    for s in rows if c_out <= c_in else rows[::-1]:
        dst[s] = src[s] @ Q
    return dst


def _compact(buf: np.ndarray, n: int, width: int, cols: np.ndarray) -> np.ndarray:
    """In place: the (n, width) view of ``buf`` becomes its columns ``cols`` as an (n, len(cols)) view."""
    src, dst = _view(buf, n, width), _view(buf, n, len(cols))
    for s in _rows(n, width):
        dst[s] = src[s][:, cols]
    return dst


def _subtract(W: np.ndarray, blocks: list[tuple[np.ndarray, np.ndarray]]) -> None:
    """In place: ``W -= sum(V @ c for V, c in blocks)`` over row chunks."""
    for s in _rows(W.shape[0], W.shape[1] + sum(V.shape[1] for V, _ in blocks)):
        acc = None
        for V, c in blocks:
            acc = V[s] @ c if acc is None else np.add(acc, V[s] @ c, out=acc)
        W[s] -= acc


def _svqb(G: np.ndarray, before: np.ndarray | None = None) -> np.ndarray:
    """``Q`` (c, c') with ``Q^T G Q = I`` on the well-conditioned directions of a Gram matrix ``G``
    (c, c): SVQB (Stathopoulos & Wu 2002), dropping the directions below :data:`DROP` and the
    columns whose diagonal fell below :data:`NOISE` times ``before`` (their squared norms earlier)."""
    g = np.diag(G).copy()
    ok = g > (0.0 if before is None else NOISE * before)
    d = np.where(ok, 1.0 / np.sqrt(np.where(ok, g, 1.0)), 0.0)
    Gs = G * d[:, None] * d[None, :]
    w, U = np.linalg.eigh(0.5 * (Gs + Gs.T))
    keep = w > DROP * max(float(w[-1]), 1e-300)
    return (U[:, keep] / np.sqrt(w[keep])) * d[:, None]


def _ritz(GA: np.ndarray, GB: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The Rayleigh--Ritz step: all eigenpairs of ``GA c = theta GB c``, ascending (raises
    ``LinAlgError`` when ``GB`` is not positive definite)."""
    theta, C = eigh(0.5 * (GA + GA.T), 0.5 * (GB + GB.T))
    if not (np.all(np.isfinite(theta)) and np.all(np.isfinite(C))):
        raise LinAlgError("non-finite Ritz pairs")
    return theta, C


def _start(A: Product, B: Product, X0: np.ndarray, seed: int, copy: bool
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The first block: ``X0`` ``B``-orthonormalized (dependent columns replaced by random ones)
    and rotated to its Ritz vectors; returns ``theta, X, AX, BX``."""
    n, m = X0.shape
    X = (np.array if copy else np.asarray)(X0, dtype=np.float64, order="C")
    buf = X.reshape(-1)
    rng = np.random.default_rng(seed)
    for _ in range(4):
        BX = np.ascontiguousarray(B(X), dtype=np.float64)
        Q = _svqb(X.T @ BX)
        if Q.shape[1] == m:
            break
        Xk = _transform(buf, n, m, Q)           # the independent columns, then random ones
        X = np.empty((n, m))
        X[:, :Q.shape[1]] = Xk
        X[:, Q.shape[1]:] = rng.standard_normal((n, m - Q.shape[1]))
        buf = X.reshape(-1)
        del Xk, BX
    else:
        raise LinAlgError("could not B-orthonormalize the start block")
    X = _transform(buf, n, m, Q)
    _transform(BX.reshape(-1), n, m, Q)
    AX = np.ascontiguousarray(A(X), dtype=np.float64)
    theta, C = _ritz(X.T @ AX, X.T @ BX)
    for V in (X, AX, BX):
        _transform(V.reshape(-1), n, m, C)
    return theta, X, AX, BX


def lobpcg(A, B, X0: np.ndarray, k: int, tol: float, *, T=None, maxiter: int = 400,
           checks: tuple[int, int] = CHECKS, seed: int = 0, soft_locking: bool = True,
           copy: bool = True, monitor: Callable[[int, float], bool] | None = None
           ) -> tuple[np.ndarray, np.ndarray, dict]:
    """The ``k`` smallest eigenpairs of ``A x = lambda B x`` by block LOBPCG (module docstring).

    Parameters
    ----------
    A, B : callable or matrix
        ``X -> A X`` and ``X -> B X`` on blocks of shape (n, c), or objects with ``@`` (sparse
        matrices, operators); both symmetric, ``B`` positive definite, and ``A`` positive definite
        for a preconditioner to make sense (e.g. ``K - sigma M``).
    X0 : ndarray, shape (n, m)
        The start block, ``k <= m < n`` (dependent columns are replaced by random ones).
    k : int
        Wanted pairs: the ``k`` lowest of the block's ``m``. The others only speed convergence.
    tol : float
        Absolute tolerance on ``||A x - theta B x||`` of each wanted ``B``-normalized ``x``.
    T : callable or operator, optional
        The preconditioner ``R -> T R`` (~``A^-1``) on blocks of shape (n, c); default none.
    maxiter : int
        Iteration limit.
    checks : (int, int)
        The progress check windows (:data:`CHECKS`).
    seed : int
        Seed of random columns replacing dependent ones.
    soft_locking : bool
        Converged columns get no new direction (default); False: every column does (for tests).
    copy : bool
        False: a C-ordered float64 ``X0`` becomes the block's buffer (overwritten; one block less).
    monitor : callable, optional
        ``monitor(it, projected) -> bool``, called at each progress check with the iteration and
        :func:`projected_iterations` (over the later windows' length): True stops the solve
        (``"over budget"``; e.g. when another solver would now finish sooner).

    Returns
    -------
    theta : ndarray, shape (m,)
        The Ritz values, ascending.
    X : ndarray, shape (n, m)
        The ``B``-orthonormal Ritz vectors (the block's own buffer).
    info : dict
        ``iterations``; ``stop`` (``"converged"``, ``"maxiter"``, ``"stalled"``, ``"slow"`` or
        ``"over budget"``);
        ``restarts`` (Rayleigh--Ritz steps redone without ``P``); ``residual_over_tol`` (the
        largest wanted residual over ``tol`` at the end); ``history``, shape (iterations + 1, k):
        the wanted pairs' residual norms at each iteration.
    """
    A, B = _product(A), _product(B)
    T = (lambda R: R.copy()) if T is None else _product(T)
    n, m = X0.shape
    if not 1 <= k <= m < n:
        raise ValueError(f"need 1 <= k <= m < n, got k={k}, m={m}, n={n}")
    theta, X, AX, BX = _start(A, B, X0, seed, copy)
    wbuf, pbuf, apbuf = np.empty(n * m), np.empty(n * m), np.empty(n * m)
    p, PAP, fresh = 0, np.zeros((0, 0)), True
    hist: list[np.ndarray] = []
    it, restarts, failed, stop = 0, 0, False, "converged"
    window_best, prev, next_check = np.inf, None, checks[0]
    while True:
        if BX is None:
            BX = np.ascontiguousarray(B(X), dtype=np.float64)
        R = _view(wbuf, n, m)
        np.subtract(AX, np.multiply(BX, theta, out=R), out=R)
        del BX
        rn = np.sqrt(np.einsum("ij,ij->j", R, R))
        worst = float(rn[:k].max()) / tol
        if worst <= 1.0 and not fresh:          # AX came from updates: confirm with the product
            AX[...] = A(X)
            fresh, BX = True, None
            continue
        hist.append(rn[:k].copy())
        window_best = min(window_best, worst)
        if worst <= 1.0:
            break
        if it >= maxiter:
            stop = "maxiter"
            break
        if it >= next_check:
            _LOG.info(f"    LOBPCG iteration {it}: largest wanted residual {worst:.3g} x the tolerance")
            if monitor is not None and monitor(it, projected_iterations(hist, tol, checks[1])):
                stop = "over budget"
                break
            if prev is not None and (window_best >= prev or
                                     _extrapolated(it, prev, window_best, checks[1]) > maxiter):
                stop = "stalled" if window_best >= prev else "slow"
                break
            prev, window_best, next_check = window_best, np.inf, next_check + checks[1]
        # the active columns' residuals, preconditioned
        act = np.flatnonzero(rn > tol) if soft_locking else np.arange(m)
        W = _compact(wbuf, n, m, act)
        W[...] = T(W)
        # B-orthogonal to [X, P], then B-orthonormal (SVQB): W's B-Gram rows known from before it
        P, AP = _view(pbuf, n, p), _view(apbuf, n, p)
        BW = np.ascontiguousarray(B(W), dtype=np.float64)
        for sweep in range(3):
            cx, cp, G = X.T @ BW, P.T @ BW, W.T @ BW
            if not sweep:
                before = norms = np.diag(G).copy()     # the squared B-norms before
            else:                                  # orthogonal enough, or the second pass done
                left = np.diag(G) / np.maximum(norms, 1e-300)
                if sweep == 2 or not np.any((left < REORTHOGONALIZE) & (np.diag(G) > NOISE * before)):
                    break
                norms = np.diag(G).copy()
            del BW
            _subtract(W, [(X, cx), (P, cp)] if p else [(X, cx)])
            BW = np.ascontiguousarray(B(W), dtype=np.float64)
        del BW
        Q = _svqb(G, before)
        a = Q.shape[1]
        if a == 0:
            stop = "stalled"
            break
        W = _transform(wbuf, n, W.shape[1], Q)
        # Rayleigh--Ritz on [X, P, W]: the X and P blocks known, the W rows computed
        s = m + p + a
        GA, GB = np.zeros((s, s)), np.eye(s)
        GA[:m, :m], GA[m:m + p, m:m + p] = np.diag(theta), PAP
        GB[:m, m + p:], GB[m:m + p, m + p:], GB[m + p:, m + p:] = cx @ Q, cp @ Q, Q.T @ G @ Q
        AW = np.ascontiguousarray(A(W), dtype=np.float64)
        GA[:m, m + p:], GA[m:m + p, m + p:], GA[m + p:, m + p:] = X.T @ AW, P.T @ AW, W.T @ AW
        GA, GB = np.triu(GA) + np.triu(GA, 1).T, np.triu(GB) + np.triu(GB, 1).T
        try:
            lam, C = _ritz(GA, GB)
            failed = False
        except LinAlgError:
            if failed or p == 0:                 # already restarted, or nothing to drop
                stop = "stalled"
                break
            keep = np.r_[0:m, m + p:s]           # restart: the same step without P
            GA, GB, p, PAP, failed = GA[np.ix_(keep, keep)], GB[np.ix_(keep, keep)], 0, PAP[:0, :0], True
            restarts += 1
            try:
                lam, C = _ritz(GA, GB)
            except LinAlgError:
                stop = "stalled"
                break
            P, AP = _view(pbuf, n, 0), _view(apbuf, n, 0)
        theta, Cx = lam[:m], C[:, :m]
        # P: the W, P part of the active Ritz vectors, GB-orthonormal to Cx (Duersch et al.)
        Z = Cx[:, act].copy()
        Z[:m] = 0.0
        for _ in range(2):
            Z -= Cx @ (Cx.T @ (GB @ Z))
        Z = Z @ _svqb(Z.T @ GB @ Z)
        PAP = Z.T @ GA @ Z
        PAP = 0.5 * (PAP + PAP.T)
        _update(X, P, W, Cx, Z, pbuf)
        _update(AX, AP, AW, Cx, Z, apbuf)
        del AW
        p, fresh, BX, it = Z.shape[1], False, None, it + 1
    _LOG.info(f"    LOBPCG: {stop} after {it} iterations, largest wanted residual {worst:.3g} x the tolerance")
    return theta, X, {"iterations": it, "stop": stop, "restarts": restarts, "residual_over_tol": worst,
                      "history": np.array(hist)}


def _update(X: np.ndarray, P: np.ndarray, W: np.ndarray, Cx: np.ndarray, Cp: np.ndarray, pbuf: np.ndarray) -> None:
    """In place, over row chunks: ``X <- [X, P, W] Cx`` and ``P <- [X, P, W] Cp`` (the (n, p') view of
    ``pbuf``; ``P`` is the (n, p) one). Growing ``P`` runs backward so that no row is overwritten
    before it is read."""
    n, m = X.shape
    p, p_new = P.shape[1], Cp.shape[1]
    C = np.hstack([Cx, Cp])
    cx, cp, cw = (np.ascontiguousarray(c) for c in (C[:m], C[m:m + p], C[m + p:]))
    Pn = _view(pbuf, n, p_new)
    rows = _rows(n, 2 * m + p + W.shape[1])
    for s in rows if p_new <= p else rows[::-1]:
        Y = X[s] @ cx
        if p:
            Y += P[s] @ cp
        Y += W[s] @ cw
        X[s] = Y[:, :m]
        Pn[s] = Y[:, m:]
