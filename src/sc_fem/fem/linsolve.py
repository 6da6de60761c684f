"""Repeated solves of sparse symmetric positive-definite systems: :class:`SystemSolver` (a sparse
Cholesky factorization or CG + AMG, set up once and reused, lagging as the matrix changes) and
:class:`MassSolver` (a consistent mass by CG). The factorizations themselves, with a choice of
backend, are :mod:`sc_fem.fem.factorization`'s (re-exported here: :func:`factorize`,
:class:`Factorization`, :data:`BACKENDS`, :func:`available_backends`, :func:`resolve_backend`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .._jit import blas_single_threaded
from ..errors import InputError, SolverError
from .bsr import NodeBlockProduct, node_blocks
from .factorization import (BACKENDS, Factorization, available_backends, factorize,  # noqa: F401 (re-exported)
                            resolve_backend)
from .multigrid import LatticeAMG, pcg


REFRESH_GROWTH = (1.5, 4)
"""A :class:`SystemSolver` whose AMG hierarchy is of an earlier matrix rebuilds it on the current
one once a solve takes more than ``1.5 x`` (+ 4) the iterations of the first solve after a set-up."""


ROUNDOFF_FLOOR = 100.0
"""A CG solve whose recurrence reached ``tol`` but whose recomputed residual stays above it (after
:func:`~sc_fem.fem.multigrid.pcg`'s restarts, within ``maxiter``) is accepted up to this times
``tol``: the round-off floor of ``S x = r`` (e.g. 3.2e-12 on the bunny r16's IPC step matrix)."""


@dataclass(frozen=True)
class Lag:
    """How a direct :class:`SystemSolver` lags: after :meth:`~SystemSolver.update` it solves by CG
    preconditioned with the factorization of an earlier matrix (to ``rtol``), factorizes the current
    matrix at once when CG has not converged within ``maxiter`` iterations, and the next matrix when
    a solve took more than ``refactor``.

    Parameters
    ----------
    refactor : int
        CG iterations of a lagged solve past which the next matrix is factorized.
    maxiter : int
        CG iterations after which a lagged solve factorizes its matrix at once.
    rtol : float
        Relative residual at which the lagged CG stops.
    """

    refactor: int
    maxiter: int
    rtol: float


class SystemSolver:
    """``A x = b`` for an SPD matrix that may change between solves (the stiffness of a static solve,
    the effective matrices and contact Hessians of implicit time steps), set up once and reused: a
    sparse Cholesky factorization (:class:`Factorization`), or conjugate gradients preconditioned by a
    smoothed-aggregation V-cycle (:class:`sc_fem.fem.multigrid.LatticeAMG`); either built at the first
    solve.

    The lag policy after :meth:`update` (a new matrix; here and in :meth:`solve` only):

    * CG + AMG: the hierarchy of an earlier matrix stays the preconditioner (SPD, so CG still
      converges to the new matrix's solution) until a solve takes more iterations than
      :data:`REFRESH_GROWTH` allows, or does not converge: then it is set up again on the current one;
    * direct with a :class:`Lag`: CG preconditioned by an earlier factorization (or another solver,
      :meth:`precondition_with`), the current matrix factorized when ``lag`` says;
    * direct without one: the new matrix is factorized at its first solve.

    A CG solve whose recurrence reached ``tol`` but whose recomputed residual stays above it is
    accepted up to :data:`ROUNDOFF_FLOOR` times ``tol``.

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
    amg_data : callable, optional
        ``() -> (near_null, aggregates)`` instead, called at each AMG set-up only (never by a direct solve).
    lag : Lag, optional
        The direct solve's lag (default none: every new matrix is factorized).
    system : str, optional
        What the error of a CG failure calls the matrix (default ``"the n-DOF system"``; ``""``: nothing).

    Attributes
    ----------
    kind : str
        ``"direct"`` or ``"cg-amg"`` (``"direct"`` after an automatic fallback).
    reason : str
        Why (and, after a fallback, the CG failure).
    amg_data, lag : callable, Lag or None
        As given (may be set before the first solve).
    last : dict
        The last CG solve's :func:`~sc_fem.fem.multigrid.pcg` info (``iterations``, ``residual``,
        ``residuals``, ...), with ``levels`` (DOFs per level) and ``kernel`` for CG + AMG.
    stats : dict
        ``solves``, ``iterations`` (CG, all solves), ``setups`` (AMG), ``factorizations``,
        ``setup_seconds`` (AMG set-ups and factorizations), ``solve_seconds`` (CG and back-solves),
        ``fallback`` (the failed CG: ``residual``, ``iterations``, its ``setup`` and ``solve`` seconds;
        or None), ``floor`` (solves accepted at the round-off floor, :data:`ROUNDOFF_FLOOR`).
    """

    def __init__(self, A: sp.spmatrix, kind: str = "direct", *, reason: str = "", tol: float = 1e-8,
                 maxiter: int = 500, backend: str = "auto", fallback: str | None = None, hint: str = "",
                 near_null: np.ndarray | None = None, aggregates: np.ndarray | None = None,
                 amg_data: Callable[[], tuple] | None = None, lag: Lag | None = None, system: str | None = None) -> None:
        if kind not in ("direct", "cg-amg"):
            raise InputError(f"kind must be 'direct' or 'cg-amg', got {kind!r}")
        self.A = sp.csr_matrix(A, dtype=np.float64)
        self.kind, self.reason, self.tol, self.maxiter, self.backend = kind, reason, tol, maxiter, backend
        self.fallback, self.hint, self.lag = fallback, hint, lag
        self.amg_data = amg_data if amg_data is not None else (lambda: (near_null, aggregates))
        self._system = f"the {self.A.shape[0]:,}-DOF system" if system is None else system
        self._fac = self._pre = self._amg = self._product = None     # factor of A, an older one (lag), hierarchy
        self._due, self._lagged, self._fresh, self._last = False, False, None, 0
        self.last: dict = {}
        self.stats = {"solves": 0, "iterations": 0, "setups": 0, "factorizations": 0, "setup_seconds": 0.0,
                      "solve_seconds": 0.0, "fallback": None, "floor": 0}

    @property
    def backend_used(self) -> str:
        """``"pyamg"`` (CG + AMG) or the factorization's backend (:func:`resolve_backend` before one)."""
        if self.kind == "cg-amg":
            return "pyamg"
        return self._fac.backend if self._fac is not None else resolve_backend(self.backend)

    def update(self, A: sp.spmatrix) -> None:
        """Solve with ``A`` from now on, the preconditioner of the earlier matrix lagging (see the class).

        Parameters
        ----------
        A : scipy.sparse matrix, shape (n, n)
            The new SPD matrix, same shape (e.g. this step's effective matrix, kg).
        """
        self.A = sp.csr_matrix(A, dtype=np.float64)
        if self.lag is None or self._due:        # no lag, or the last lagged solves were slow: factorize A
            self._pre = None
        elif self._fac is not None:              # the factor of the earlier matrix preconditions this one
            self._pre = self._fac
        self._fac, self._product, self._due, self._lagged = None, None, False, self._amg is not None

    def precondition_with(self, other: "SystemSolver") -> None:
        """Precondition the lagged solves of the current matrix with ``other`` (e.g. the factorization of its
        part without contact) until one is factorized; nothing unless both are direct and this one lags.

        Parameters
        ----------
        other : SystemSolver
            A solver of a matrix near ``A``, same shape.
        """
        if self.kind == other.kind == "direct" and self.lag is not None and self._fac is None:
            self._pre, self._due = other, False

    def _setup(self) -> None:
        bs = 3 if self.A.shape[0] % 3 == 0 else 1
        near_null, aggregates = self.amg_data()
        self._amg = LatticeAMG(self.A, near_null, aggregates=aggregates if bs == 3 else None, blocksize=bs)
        self._product, self._lagged, self._fresh = self._amg.levels[0], False, None
        self.stats["setups"] += 1
        self.stats["setup_seconds"] += self._amg.seconds

    def _direct(self, b: np.ndarray) -> np.ndarray:
        if self._fac is None:
            self._fac, self._pre, self._due = factorize(self.A, self.backend), None, False
            self.stats["factorizations"] += 1
            self.stats["setup_seconds"] += self._fac.seconds
        t0 = time.perf_counter()
        x = self._fac.solve(b)
        self.stats["solve_seconds"] += time.perf_counter() - t0
        return x

    def _pcg(self, A: Callable, M: Callable, b: np.ndarray, x0: np.ndarray | None, tol: float,
             maxiter: int) -> tuple[np.ndarray, dict]:
        t0 = time.perf_counter()
        x, info = pcg(A, M, b, tol=tol, maxiter=maxiter, x0=x0)
        self.stats["iterations"] += info["iterations"]
        self.stats["solve_seconds"] += time.perf_counter() - t0
        return x, info

    def _cg(self, b: np.ndarray, x0: np.ndarray | None) -> tuple[np.ndarray, dict]:
        if self._product is None:
            self._product = (NodeBlockProduct(node_blocks(self.A), self._amg.kernel) if self.A.shape[0] % 3 == 0
                             else self.A.__matmul__)
        with blas_single_threaded():
            x, info = self._pcg(self._product, self._amg.vcycle, b, x0, self.tol, self.maxiter)
        self._last = info["iterations"]
        if self._fresh is None and not self._lagged:
            self._fresh = info["iterations"]
        info.update(levels=[lvl.A.shape[0] for lvl in self._amg.levels], kernel=self._amg.kernel)
        return x, info

    def _accepted(self, info: dict, tol: float, maxiter: int) -> bool:
        """Converged, or stopped at the round-off floor: the recurrence reached ``tol`` (3 times), the
        recomputed residual cannot (:data:`ROUNDOFF_FLOOR`)."""
        floor = (not info["converged"] and info["iterations"] < maxiter and not info["breakdown"]
                 and info["residual"] <= ROUNDOFF_FLOOR * tol)
        self.stats["floor"] += floor
        return info["converged"] or floor

    def solve(self, b: np.ndarray, x0: np.ndarray | None = None) -> np.ndarray:
        """``A^-1 b``.

        Parameters
        ----------
        b : ndarray, shape (n,)
            Right-hand side (e.g. a residual force, N).
        x0 : ndarray, shape (n,), optional
            CG + AMG's start (e.g. the previous step's solution); ignored by the direct solve.

        Returns
        -------
        ndarray, shape (n,)
            The solution (e.g. an acceleration increment, m/s^2), to ``tol`` relative residual for
            CG + AMG (to ``lag.rtol`` for a lagged direct solve).

        Raises
        ------
        SolverError
            ``"cg-amg"`` did not reach ``tol`` within ``maxiter`` (naming the residual), or
            the factorization failed.
        """
        b = np.asarray(b, dtype=np.float64)
        self.stats["solves"] += 1
        if self.kind == "direct":
            lag = self.lag
            if self._fac is None and lag is not None and self._pre is not None:    # CG on an older factor
                x, self.last = self._pcg(self.A.__matmul__, self._pre.solve, b, None, lag.rtol, lag.maxiter)
                if self._accepted(self.last, lag.rtol, lag.maxiter):
                    self._due |= self.last["iterations"] > lag.refactor
                    return x
            return self._direct(b)                       # (a lagged CG that failed: factorize at once)
        grow, extra = REFRESH_GROWTH
        if self._amg is None or (self._lagged and self._fresh is not None and self._last > grow * self._fresh + extra):
            self._setup()
        x, info = self._cg(b, x0)
        if not info["converged"] and self._lagged:            # the old hierarchy no longer does: a new one
            self._setup()
            x, more = self._cg(b, x)
            info = {**more, "iterations": info["iterations"] + more["iterations"],
                    "residuals": info["residuals"] + more["residuals"]}
        self.last = info
        if self._accepted(info, self.tol, self.maxiter):
            return x
        why = (" (a non-positive curvature: the matrix is not positive definite)" if info["breakdown"] else
               " (too slow: members one or two cubes thick?)" if self.fallback and info["iterations"] >= self.maxiter
               else "")
        on = f" on {self._system}" if self._system else ""
        msg = (f"CG + AMG did not converge{on}: relative residual {info['residual']:.3g} > tol {self.tol:g} "
               f"after {info['iterations']} iterations{why}")
        if self.fallback is None:
            raise SolverError(f"{msg}; {self.hint}" if self.hint else msg)
        st = self.stats
        st["fallback"] = {"residual": info["residual"], "iterations": info["iterations"],
                          "setup": st["setup_seconds"], "solve": st["solve_seconds"]}
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
        b = np.asarray(b, dtype=np.float64)
        self.stats["solves"] += 1
        if self._direct is None:
            x, info = pcg(self.M.__matmul__, self._dinv.__mul__, b, **MASS_CG)
            self.stats["iterations"] += info["iterations"]
            if info["converged"]:
                return x
            self._direct, self.stats["fallback"] = self._fallback(), True
        return self._direct.solve(b)
