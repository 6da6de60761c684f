"""Sparse symmetric positive-definite factorization with a choice of backend.

``backend="auto"`` takes the first importable of

1. ``"cholmod"`` -- CHOLMOD through scikit-sparse (``sksparse.cholmod``; needs the system
   SuiteSparse),
2. ``"cholespy"`` -- CHOLMOD bundled in the ``cholespy`` binary wheels,
3. ``"splu"`` -- SciPy's SuperLU (always available; symmetric mode, no pivoting).

A matrix that is singular or indefinite (e.g. a floating, unsupported model) raises
:class:`~sc_fem.errors.SolverError` instead of returning garbage.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import time

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from ..errors import InputError, SolverError

BACKENDS: tuple[str, ...] = ("cholmod", "cholespy", "splu")
"""Backends in the order ``"auto"`` tries them."""

_PIVOT_RTOL = 1e-13
"""A pivot below this times the largest one means a numerically singular matrix (splu)."""


def available_backends() -> list[str]:
    """The importable backends, in preference order (looked up once per process)."""
    return list(_available_backends())


@functools.lru_cache(maxsize=1)
def _available_backends() -> tuple[str, ...]:
    out = []
    if importlib.util.find_spec("sksparse") is not None:
        out.append("cholmod")
    if importlib.util.find_spec("cholespy") is not None:
        out.append("cholespy")
    out.append("splu")
    return tuple(out)


def _singular_message(n: int, what: str) -> str:
    return (f"the {n}x{n} system matrix is {what}: the model is probably not held in place "
            "(no or too few fixed nodes: a floating part can move as a rigid body). "
            "Fix nodes with fix=[...] / --fix 'x<...' or --fix-vertices FILE.")


class Factorization:
    """A factorization of a sparse SPD matrix ``A`` (n x n).

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        Symmetric positive definite (e.g. a stiffness matrix in N/m); only symmetry is assumed.
    backend : {"auto", "cholmod", "cholespy", "splu"}
        ``"auto"``: the first installed of :data:`BACKENDS`.
    analysis : FillAnalysis, optional
        CHOLMOD's symbolic analysis of ``A``'s pattern (:func:`sc_fem.fem.fill.analyze_fill`):
        reused by the ``"cholmod"`` backend instead of ordering ``A`` again.

    Raises
    ------
    SolverError
        The matrix is singular, not positive definite or has non-finite entries.

    Attributes
    ----------
    backend : str
        ``"cholmod"``, ``"cholespy"`` or ``"splu"``.
    shape : tuple
        ``(n, n)``.
    seconds : float
        Wall time of the factorization.
    """

    def __init__(self, A: sp.spmatrix, backend: str = "auto", analysis: object | None = None) -> None:
        if not sp.issparse(A):
            raise InputError(f"A must be a scipy.sparse matrix, got {type(A).__name__}")
        if A.ndim != 2 or A.shape[0] != A.shape[1] or A.shape[0] == 0:
            raise InputError(f"A must be a non-empty square matrix, got shape {A.shape}")
        if backend == "auto":
            backend = _available_backends()[0]
        if backend not in BACKENDS:
            raise InputError(f"backend must be 'auto' or one of {list(BACKENDS)}, got {backend!r}")
        if backend not in _available_backends():
            raise InputError(f"backend {backend!r} is not installed (available: {available_backends()})")
        self.backend = backend
        self.shape = A.shape
        n = A.shape[0]
        A = sp.csr_matrix(A, dtype=np.float64)
        if not np.all(np.isfinite(A.data)):
            raise SolverError("the system matrix contains non-finite entries")
        t0 = time.perf_counter()
        if backend == "cholmod":
            from sksparse.cholmod import CholmodNotPositiveDefiniteError, cholesky

            try:
                symbolic = getattr(analysis, "factor", None)
                self._f = cholesky(A.tocsc()) if symbolic is None else symbolic.cholesky(A.tocsc())
            except CholmodNotPositiveDefiniteError:
                raise SolverError(_singular_message(n, "singular or not positive definite")) from None
            d = self._f.D()
            if np.any(d <= _PIVOT_RTOL * d.max()):
                raise SolverError(_singular_message(n, "numerically singular"))
        elif backend == "cholespy":
            from cholespy import CholeskySolverD, MatrixType

            # A symmetric: its CSR arrays are its CSC arrays
            try:
                self._f = CholeskySolverD(n, A.indptr.astype(np.int32), A.indices.astype(np.int32),
                                          np.ascontiguousarray(A.data), MatrixType.CSC)
            except ValueError as exc:
                raise SolverError(_singular_message(n, f"singular or not positive definite ({exc})")) from None
        else:
            from scipy.sparse.linalg import splu

            try:
                self._f = splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                               options={"SymmetricMode": True})
            except RuntimeError as exc:
                raise SolverError(_singular_message(n, f"singular ({exc})")) from None
            d = np.abs(self._f.U.diagonal())
            if not np.all(np.isfinite(d)) or d.min() <= _PIVOT_RTOL * d.max():
                raise SolverError(_singular_message(n, "numerically singular"))
            # symmetric without pivoting: A = L D L^T, so a negative pivot means indefinite
            if np.any(self._f.U.diagonal() < 0):
                raise SolverError(_singular_message(n, "not positive definite"))
        self.seconds = time.perf_counter() - t0

    def solve(self, b: ArrayLike) -> np.ndarray:
        """Solve ``A x = b``.

        Parameters
        ----------
        b : array_like, shape (n,) or (n, k)
            Right-hand side(s) (e.g. forces in N).

        Returns
        -------
        ndarray, same shape as ``b``
            The solution ``x`` (e.g. displacements in m).
        """
        b = np.asarray(b, dtype=np.float64)
        n = self.shape[0]
        if b.ndim not in (1, 2) or b.shape[0] != n:
            raise InputError(f"b must have shape ({n},) or ({n}, k), got {b.shape}")
        if self.backend == "cholespy":
            b = np.ascontiguousarray(b)
            x = np.zeros_like(b)
            self._f.solve(b, x)
        elif self.backend == "cholmod":
            x = self._f(b)
        else:
            x = self._f.solve(b)
        x = np.asarray(x).reshape(b.shape)
        if not np.all(np.isfinite(x)):
            raise SolverError(_singular_message(n, "singular (the solution is not finite)"))
        return x

    def __repr__(self) -> str:
        return f"Factorization({self.shape[0]}x{self.shape[1]}, backend={self.backend!r})"


def factorize(A: sp.spmatrix, backend: str | None = "auto", analysis: object | None = None) -> Factorization:
    """Factorize a sparse symmetric positive-definite matrix.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        Symmetric positive definite (only symmetry is assumed, not checked).
    backend : {"auto", "cholmod", "cholespy", "splu"}
        ``"auto"`` (default; overridable with the environment variable ``SC_FEM_SOLVER``) picks
        the first installed of CHOLMOD (scikit-sparse), cholespy, SciPy ``splu``.
    analysis : FillAnalysis, optional
        The symbolic analysis of ``A`` (:func:`sc_fem.fem.fill.analyze_fill`), reused by CHOLMOD.

    Returns
    -------
    Factorization
        With ``.solve(b)`` and ``.backend``.

    Raises
    ------
    SolverError
        The matrix is singular or not positive definite.
    """
    return Factorization(A, resolve_backend(backend, keep_auto=True), analysis)


def resolve_backend(backend: str | None = "auto", *, keep_auto: bool = False) -> str:
    """The factorization backend that ``backend`` means: ``"auto"`` (or None) is the environment
    variable ``SC_FEM_SOLVER`` if set, else the first installed of :data:`BACKENDS`.

    Parameters
    ----------
    backend : str or None
        ``"auto"``, None or a name of :data:`BACKENDS`.
    keep_auto : bool
        Return ``"auto"`` rather than the first installed backend when nothing names one.

    Returns
    -------
    str
    """
    if backend in (None, "auto"):
        backend = os.environ.get("SC_FEM_SOLVER", "auto") or "auto"
    return backend if backend != "auto" or keep_auto else _available_backends()[0]


REFRESH_GROWTH = (1.5, 4)
"""A :class:`SystemSolver` whose AMG hierarchy is of an earlier matrix rebuilds it on the current
one once a solve takes more than ``1.5 x`` (+ 4) the iterations of the first solve after a set-up."""


ROUNDOFF_FLOOR = 100.0
"""A CG solve whose recurrence reached ``tol`` but whose recomputed residual stays above it (after
:func:`~sc_fem.fem.multigrid.pcg`'s restarts, within ``maxiter``) is accepted up to this times
``tol``: the round-off floor of ``S x = r`` (e.g. 3.2e-12 on the bunny r16's IPC step matrix)."""


class SystemSolver:
    """``A x = b`` for an SPD matrix that may change between solves (the effective matrices of implicit
    time steps): a sparse Cholesky factorization (:class:`Factorization`), or conjugate gradients
    preconditioned by a smoothed-aggregation V-cycle (:class:`sc_fem.fem.multigrid.LatticeAMG`).

    After :meth:`update` the AMG hierarchy of the earlier matrix stays the preconditioner (SPD, so
    CG still converges to the new matrix's solution) until a solve takes more iterations than
    :data:`REFRESH_GROWTH` allows, or does not converge: then it is set up again on the current one.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        Symmetric positive definite (e.g. ``M + beta dt^2 K``, kg).
    kind : {"direct", "cg-amg"}
        The solver (chosen by :meth:`sc_fem.fem.options.DynamicOptions.solver_for`).
    reason : str
        Why this one (kept for the record).
    tol, maxiter : float, int
        CG stops at ``||A x - b|| <= tol ||b||``; more than ``maxiter`` iterations fail.
    backend : str
        Factorization backend (:func:`factorize`).
    fallback : str or None
        None: a CG failure raises :class:`~sc_fem.errors.SolverError` (with this as its hint:
        ``hint``); else the direct solve takes over for good (the automatic choice).
    hint : str
        What to do, appended to the error of a CG that failed.
    near_null, aggregates : ndarray, optional
        The AMG's near-null space (n, k) and finest aggregates (n // 3,) (the rigid modes and
        :func:`sc_fem.fem.multigrid.lattice_aggregates`); default the 3 translations and pyamg's aggregation.

    Attributes
    ----------
    kind : str
        ``"direct"`` or ``"cg-amg"`` (``"direct"`` after an automatic fallback).
    reason : str
        Why (and, after a fallback, the CG failure).
    stats : dict
        ``solves``, ``iterations`` (CG, all solves), ``setups`` (AMG), ``factorizations``,
        ``setup_seconds``, ``fallback`` (the failed CG: residual, iterations; or None), ``floor``
        (solves accepted at the round-off floor, :data:`ROUNDOFF_FLOOR`).
    """

    def __init__(self, A: sp.spmatrix, kind: str = "direct", *, reason: str = "", tol: float = 1e-8,
                 maxiter: int = 500, backend: str = "auto", fallback: str | None = None, hint: str = "",
                 near_null: np.ndarray | None = None, aggregates: np.ndarray | None = None) -> None:
        if kind not in ("direct", "cg-amg"):
            raise InputError(f"kind must be 'direct' or 'cg-amg', got {kind!r}")
        self.A = sp.csr_matrix(A, dtype=np.float64)
        n = self.A.shape[0]
        self.kind, self.reason, self.tol, self.maxiter, self.backend = kind, reason, tol, maxiter, backend
        self.fallback, self.hint = fallback, hint
        if near_null is None:
            near_null = np.kron(np.ones((n // 3, 1)), np.eye(3)) if n % 3 == 0 else np.ones((n, 1))
        self._null, self._agg = near_null, aggregates
        self._fac = self._amg = self._product = None
        self._lagged, self._fresh, self._last = False, None, 0
        self.stats = {"solves": 0, "iterations": 0, "setups": 0, "factorizations": 0, "setup_seconds": 0.0,
                      "fallback": None, "floor": 0}

    def update(self, A: sp.spmatrix) -> None:
        """Solve with ``A`` (same shape) from now on; the direct solve refactorizes at the next solve, CG
        keeps the current hierarchy as its preconditioner while it works."""
        self.A = sp.csr_matrix(A, dtype=np.float64)
        self._fac, self._product, self._lagged = None, None, self._amg is not None

    def _setup(self) -> None:
        from .multigrid import LatticeAMG

        bs = 3 if self.A.shape[0] % 3 == 0 else 1
        self._amg = LatticeAMG(self.A, self._null, aggregates=self._agg if bs == 3 else None, blocksize=bs)
        self._product, self._lagged, self._fresh = self._amg.levels[0], False, None
        self.stats["setups"] += 1
        self.stats["setup_seconds"] += self._amg.seconds

    def _direct(self, b: np.ndarray) -> np.ndarray:
        if self._fac is None:
            self._fac = factorize(self.A, self.backend)
            self.stats["factorizations"] += 1
            self.stats["setup_seconds"] += self._fac.seconds
        return self._fac.solve(b)

    def _cg(self, b: np.ndarray, x0: np.ndarray | None, maxiter: int) -> tuple[np.ndarray, dict]:
        from .._jit import blas_single_threaded
        from .bsr import NodeBlockProduct, node_blocks
        from .multigrid import pcg

        if self._product is None:
            self._product = (NodeBlockProduct(node_blocks(self.A), self._amg.kernel) if self.A.shape[0] % 3 == 0
                             else self.A.__matmul__)
        with blas_single_threaded():
            x, info = pcg(self._product, self._amg.vcycle, b, tol=self.tol, maxiter=maxiter, x0=x0)
        self.stats["iterations"] += info["iterations"]
        self._last = info["iterations"]
        if self._fresh is None and not self._lagged:
            self._fresh = info["iterations"]
        return x, info

    def solve(self, b: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """``A^-1 b``.

        Parameters
        ----------
        b : ndarray, shape (n,)
            Right-hand side (e.g. a residual force, N).
        x0 : ndarray, shape (n,), optional
            CG's start (e.g. the previous step's solution); ignored by the direct solve.

        Returns
        -------
        ndarray, shape (n,)
            The solution (e.g. an acceleration increment, m/s^2), to ``options.tol`` relative
            residual for CG.

        Raises
        ------
        SolverError
            ``"cg-amg"`` did not reach ``tol`` within ``maxiter`` (naming the residual), or
            the factorization failed.
        """
        b = np.asarray(b, dtype=np.float64)
        self.stats["solves"] += 1
        if self.kind == "direct":
            return self._direct(b)
        grow, extra = REFRESH_GROWTH
        if self._amg is None or (self._lagged and self._fresh is not None and self._last > grow * self._fresh + extra):
            self._setup()
        x, info = self._cg(b, x0, self.maxiter)
        if not info["converged"] and self._lagged:            # the old hierarchy no longer does: a new one
            self._setup()
            x, more = self._cg(b, x, self.maxiter)
            info = {**more, "iterations": info["iterations"] + more["iterations"]}
        if info["converged"]:
            return x
        if info["iterations"] < self.maxiter and not info["breakdown"] and info["residual"] <= ROUNDOFF_FLOOR * self.tol:
            self.stats["floor"] += 1     # the recurrence reached tol (3 times), the true residual cannot: round-off
            return x
        why = " (a non-positive curvature: the matrix is not positive definite)" if info["breakdown"] else ""
        msg = (f"CG + AMG did not converge on the {self.A.shape[0]:,}-DOF system: relative residual "
               f"{info['residual']:.3g} > tol {self.tol:g} after {info['iterations']} iterations{why}")
        if self.fallback is None:
            raise SolverError(f"{msg}; {self.hint}" if self.hint else msg)
        self.stats["fallback"] = {"residual": info["residual"], "iterations": info["iterations"]}
        self.kind, self.reason = "direct", f"{self.reason}; {msg}: {self.fallback}"
        self._amg = self._product = None
        return self._direct(b)


MASS_CG = {"tol": 1e-12, "maxiter": 1000}
"""Conjugate gradients of :class:`MassSolver`: relative residual reached (that of the dynamic CG
solves, :class:`~sc_fem.fem.options.DynamicOptions`), and the iterations after which it gives way
to a factorization. The chair at r16, whose many partial cubes make its diagonal-scaled mass the
worst conditioned of the built-ins (condition number ~1,000; ~170 at r32), needs ~400."""


class MassSolver:
    """``M^-1 b`` for a consistent mass matrix by conjugate gradients preconditioned by its diagonal.

    A mass matrix is well conditioned once scaled by its diagonal, whatever the model's size: the
    consistent mass of the bunny at r32 (31,161 DOFs) took 107 iterations to 1e-13, 0.66 s, where
    its sparse Cholesky factorization took 5.0 s (the chair at r32, with many partial cubes: 190
    iterations, 0.17 s against 0.12 s; at r16, 400). Should CG not reach :data:`MASS_CG` (e.g. a badly scaled partial cube), ``fallback()``
    -- a solver with ``.solve(b)``, e.g. a factorization -- takes over for good.

    Parameters
    ----------
    M : scipy.sparse matrix, shape (n, n)
        Symmetric positive definite mass, kg.
    fallback : callable
        ``() -> solver`` with ``.solve(b)``, built only when CG fails.

    Attributes
    ----------
    stats : dict
        ``solves``, ``iterations`` (all CG solves) and ``fallback`` (True once the fallback took over).
    """

    def __init__(self, M: sp.spmatrix, fallback) -> None:
        self.M = sp.csr_matrix(M, dtype=np.float64)
        d = self.M.diagonal()
        if not np.all(d > 0):
            raise SolverError("the mass matrix has non-positive diagonal entries: no mass on some DOFs")
        self._dinv, self._fallback, self._direct = 1.0 / d, fallback, None
        self.stats = {"solves": 0, "iterations": 0, "fallback": False}

    def solve(self, b: np.ndarray) -> np.ndarray:
        """``M^-1 b``.

        Parameters
        ----------
        b : ndarray, shape (n,)
            Force, N.

        Returns
        -------
        ndarray, shape (n,)
            Acceleration, m/s^2 (to :data:`MASS_CG` ``tol`` relative residual, or exact by the fallback).
        """
        from .multigrid import pcg

        b = np.asarray(b, dtype=np.float64)
        self.stats["solves"] += 1
        if self._direct is None:
            x, info = pcg(self.M.__matmul__, self._dinv.__mul__, b, **MASS_CG)
            self.stats["iterations"] += info["iterations"]
            if info["converged"]:
                return x
            self._direct, self.stats["fallback"] = self._fallback(), True
        return self._direct.solve(b)
