"""Eigensolver back-ends for the generalized problem ``K phi = lambda M phi`` (``lambda = omega^2``).

Two methods, both returning the smallest eigenvalues:

``"shift-invert"``
    :func:`scipy.sparse.linalg.eigsh` in shift-invert mode around a small **negative** shift
    ``sigma = -SHIFT_FRACTION * lambda_scale`` (``lambda_scale = mean(diag K) / mean(diag M)``).
    ``K - sigma M`` is then positive definite even for a free body (a shift of exactly 0 makes
    it singular, and a positive one indefinite), and every eigenvalue ``lambda >= 0`` lies above
    ``sigma``, so the eigenvalues nearest the shift are exactly the smallest ones, rigid modes
    included. The factorization of ``K - sigma M`` is done once by
    :func:`sc_fem.fem.linsolve.factorize` (CHOLMOD, cholespy or SuperLU -- the same backend as
    static solves) and passed to ``eigsh`` as ``OPinv`` (a ``LinearOperator``), so scipy never
    factorizes anything itself.
``"lobpcg"``
    The block LOBPCG of :mod:`sc_fem.fem.lobpcg` (soft locking, an orthonormalized basis, the
    implicit ``P`` update, five blocks of vectors updated in place) on ``K - sigma M``,
    preconditioned by a V-cycle of the smoothed-aggregation multigrid of ``K - sigma M``
    (:class:`sc_fem.fem.multigrid.LatticeAMG`, on the block of active residuals at once) whose
    near-null space is the 6 rigid-body modes of the free DOFs (:mod:`sc_fem.fem.rigid`). It stops
    when the ``k`` wanted pairs converge, at ``maxiter``, or when their residuals stop falling fast
    enough (``"stalled"``, ``"slow"``). Needs only ``O(nnz(K))`` memory: the method for models whose
    factorization would not fit.

``method="auto"`` (:func:`~sc_fem.fem.options.choose_method`) predicts both solvers' times from
:data:`~sc_fem.fem.options.SPEED_MODEL` (calibrated by ``benchmarks/scale.py``) and their memory
(:func:`~sc_fem.fem.options.factor_memory_estimate`, :func:`~sc_fem.fem.options.lobpcg_memory_estimate`),
and takes the faster one that fits ``max_memory`` (default: half the available memory); the choice
and the reason are returned in :attr:`EigenResult.reason`. LOBPCG's pairs are checked after the
solve: a wanted pair whose relative residual exceeds :data:`LOBPCG_ACCEPT` (AMG can precondition
thin members badly) makes ``"auto"`` fall back to shift-invert, and an explicitly requested ``"lobpcg"`` raise
:class:`~sc_fem.errors.SolverError` -- never unconverged modes returned as if they were eigenpairs.
While LOBPCG runs, it forecasts the rest of its solve at each progress check (``info["forecasts"]``);
``"auto"`` switches to shift-invert when that rest would take more than :data:`LOBPCG_SWITCH` times
shift-invert's predicted time.

All eigenvalues are refined and the vectors made exactly ``M``-orthonormal by a final
Rayleigh--Ritz step on the computed subspace, whose products ``K V``, ``M V`` also give the
residuals. :class:`EigenSolver` keeps the factorization (or AMG hierarchy) between solves, so
asking again for more eigenpairs costs no second setup; :func:`solve_eigen` is the one-shot form.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, eigsh

from .._jit import blas_single_threaded
from .._log import logger
from .._progress import counting, stage_bar
from .._validate import positive_int
from ..errors import InputError, SolverError
from .bsr import node_blocks
from .linsolve import factorize
from .lobpcg import lobpcg
from .multigrid import LatticeAMG
# re-exported (noqa: F401): the eigensolver's names stay importable from here
from .ritz import rayleigh_ritz, relative_residuals  # noqa: F401
from .shift import (SHIFT_FRACTION, ComponentMass, ShiftedStiffness, lambda_scale, shift_in_place,  # noqa: F401
                    shifted, without_zeros)
from .spmm import BlockProduct
from .options import (METHODS, EigenOptions, choose_method, factor_memory_estimate, fill_analysis,  # noqa: F401
                      lobpcg_block, lobpcg_memory_estimate, memory_budget, predicted_seconds)

_LOG = logger.getChild("eigen")

@dataclass(frozen=True, eq=False)
class EigenResult:
    """Smallest eigenpairs of ``K phi = lambda M phi``.

    Attributes
    ----------
    eigenvalues : ndarray, shape (k,)
        ``lambda = omega^2`` in 1/s^2, ascending (tiny negative values are possible for rigid modes).
    vectors : ndarray, shape (n, k)
        ``M``-orthonormal eigenvectors (``vectors.T @ M @ vectors = I``).
    method : str
        ``"shift-invert"`` or ``"lobpcg"``.
    backend : str
        Factorization backend (``"cholmod"``, ``"cholespy"``, ``"splu"``) or ``"pyamg"``.
    sigma : float
        The (negative) shift used, 1/s^2.
    reason : str
        Why ``method`` was chosen (memory estimate vs budget).
    seconds : dict
        Wall time of ``"setup"`` (factorization or AMG hierarchy, done once per :class:`EigenSolver`),
        ``"solve"`` and ``"rayleigh_ritz"``.
    info : dict
        Iterations, memory estimate (bytes), ``setup_reused`` (the factorization / hierarchy of an
        earlier :meth:`EigenSolver.solve` was used), etc.
    residuals : ndarray, shape (k,)
        ``||K phi - lambda M phi|| / ||K phi||`` of each pair (:func:`~sc_fem.fem.ritz.relative_residuals`).
    """

    eigenvalues: np.ndarray
    vectors: np.ndarray
    method: str
    backend: str
    sigma: float
    reason: str
    seconds: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))


LOBPCG_ACCEPT = 1e-3
"""Largest relative residual ``||K phi - lambda M phi|| / ||K phi||`` of a wanted LOBPCG pair that
is accepted (after the Rayleigh--Ritz step) when LOBPCG stops short of its tolerance; it stalls at
~1e-5 on large cantilevers with the frequencies converged to 1e-10. Beyond it the pairs are not
eigenpairs: on the bridge at resolution 96 (31,656 DOFs) the AMG V-cycle preconditions the
one-cube-thick cables so poorly (PCG needs 300-500 iterations) that LOBPCG stalled at relative
residuals ~0.98 with frequencies 15 % off, and ``modal`` returned them. The solver then falls back
to shift-invert (``method="auto"`` when the factorization fits the budget) or raises
:class:`SolverError` (``method="lobpcg"``)."""

LOBPCG_SWITCH = 1.5
"""``method="auto"``: at each of LOBPCG's progress checks (iteration 20, then every 8) it forecasts
the rest (:meth:`EigenSolver._monitor`) and switches to shift-invert when that rest would take more
than this many times shift-invert's predicted time. At iteration 20 the projection was 0.74-1.25x the
iterations taken on 31 runs of 18 shapes, the seconds 0.81-1.13x on 13; the armchair at 64, where
LOBPCG stalls, then took 0.60x the time, the toy truck at 96 0.75x (``docs/performance.md``)."""

VCYCLE_DTYPE = np.float32
"""Precision of LOBPCG's preconditioner, the AMG V-cycle (:class:`~sc_fem.fem.multigrid.LatticeAMG`
``dtype``; LOBPCG, its products with ``K`` and ``M`` and the residuals stay float64). On the
139,656-DOF cantilever a V-cycle on 10 vectors took 0.68x the float64 one's time (122 ms / 179 ms in
one run), ``sc_fem.modal`` 0.81x end to end, with the same 23 LOBPCG iterations and frequencies equal
to 1e-12 (the beam, the chair: the same; the bridge at 64 stalls at 28 iterations either way)."""


class EigenSolver:
    """Smallest eigenpairs of ``K phi = lambda M phi`` with the shifted operator set up once.

    The first :meth:`solve` chooses the method (``"auto"``: from the memory estimates for its
    ``k``) and builds the factorization of ``K - sigma M`` (shift-invert) or the AMG hierarchy
    (LOBPCG); every later :meth:`solve` -- e.g. with more eigenpairs -- reuses it.

    Parameters
    ----------
    K, M : scipy.sparse matrix, shape (n, n)
        Symmetric stiffness (N/m, positive semi-definite) and mass (kg, positive definite).
    method : {"auto", "shift-invert", "lobpcg"}
        See the module docstring.
    backend : {"auto", "cholmod", "cholespy", "splu"}
        Factorization backend for shift-invert (:func:`sc_fem.fem.linsolve.factorize`).
    sigma : float, optional
        Shift in 1/s^2; must be negative. Default ``-SHIFT_FRACTION * lambda_scale(K, M)``.
    near_null : ndarray, shape (n, 6), optional
        Rigid-body modes for the AMG near-null space (LOBPCG); default: the translations.
    start : ndarray, shape (n, s), optional
        Vectors LOBPCG's block starts from (the first ``min(s, block)`` columns, the rest random),
        e.g. the rigid-body modes of every loose part (:func:`sc_fem.fem.rigid.part_rigid_modes`);
        default ``near_null``.
    aggregates : ndarray of int, shape (n // 3,), optional
        The AMG's finest aggregates, one per DOF node (LOBPCG; e.g.
        :func:`sc_fem.fem.multigrid.lattice_aggregates`); default: pyamg's standard aggregation.
    tol : float
        ARPACK tolerance (0 = machine precision).
    lobpcg_tol, maxiter : float, int
        LOBPCG tolerance, relative to ``|sigma| * sqrt(mean(diag M))`` (the residual of a mode with
        eigenvalue ``|sigma|``, far below every elastic one), and iteration limit. The final
        Rayleigh--Ritz step makes the eigenvalues much more accurate than the vectors.
    max_memory : float, optional
        Bytes the factorization may use (``method="auto"``); default half the available memory.
    seed : int
        Seed of the random start vectors.
    lattice : bool
        ``K`` and ``M`` are a trilinear lattice's (``"auto"`` may take LOBPCG + the lattice
        multigrid); False (higher-order cubes): ``"auto"`` takes shift-invert whenever it fits.
    overwrite : bool
        ``K`` and ``M`` are the solver's (the caller keeps no reference): ``K`` is overwritten by
        ``K - sigma M`` and, for LOBPCG, both give way to leaner forms (:mod:`sc_fem.fem.shift`;
        a million cubes: ~3.3 GiB less). Only where ``M`` shares ``K``'s pattern (the consistent
        mass): a lumped ``M`` leaves ``K`` as it is and ``K - sigma M`` is a new matrix. Default
        False: ``K`` and ``M`` are left as they are (LOBPCG's products with them are the same lean
        ones: ``M`` as its node matrix, :class:`~sc_fem.fem.shift.ComponentMass`, when it is one).

    Attributes
    ----------
    lambda_scale : float
        :func:`lambda_scale` ``(K, M)``, 1/s^2 (computed once).
    sigma : float
        The shift, 1/s^2.
    n_setups : int
        Factorizations / AMG hierarchies built (0 before the first solve, then 1; 2 when LOBPCG
        failed and the solver fell back to shift-invert).
    """

    def __init__(self, K: sp.spmatrix, M: sp.spmatrix, *, method: str = "auto", backend: str = "auto",
                 sigma: float | None = None, near_null: np.ndarray | None = None, start: np.ndarray | None = None,
                 aggregates: np.ndarray | None = None, tol: float = 0.0, lobpcg_tol: float = 1e-3,
                 maxiter: int = 400, max_memory: float | None = None, seed: int = 0, lattice: bool = True,
                 overwrite: bool = False) -> None:
        if method not in METHODS:
            raise InputError(f"method must be one of {list(METHODS)}, got {method!r}")
        if not (sp.issparse(K) and sp.issparse(M)) or K.shape != M.shape or K.shape[0] != K.shape[1]:
            raise InputError("K and M must be square scipy.sparse matrices of the same shape")
        self.K, self.M = sp.csr_matrix(K, dtype=float), sp.csr_matrix(M, dtype=float)
        self.n, self.nnz, self.overwrite = self.K.shape[0], self.K.nnz, bool(overwrite)
        self.lambda_scale = lambda_scale(self.K, self.M)
        if sigma is None:
            sigma = -SHIFT_FRACTION * self.lambda_scale
        elif not (np.isfinite(sigma) and sigma < 0):
            raise InputError(f"sigma must be a negative shift (below every eigenvalue), got {sigma!r}")
        self.sigma = float(sigma)
        self.method, self.backend, self.reason, self._auto, self._requested_backend = method, backend, "", False, backend
        self.near_null, self.aggregates, self.start = near_null, aggregates, near_null if start is None else start
        self.tol, self.lobpcg_tol, self.maxiter, self.max_memory, self.seed = tol, lobpcg_tol, maxiter, max_memory, seed
        self.n_setups, self._setup_seconds, self._info, self.lattice = 0, 0.0, {}, bool(lattice)
        self._op = None                       # OPinv (shift-invert) or the V-cycle (LOBPCG)
        self._shifted = self._analysis = None  # K - sigma M and its fill (FillAnalysis), from _setup to _build

    def _setup(self, k: int) -> None:
        self._shifted, self.reason = self._shift(), "requested"
        if self.method == "auto":     # shift-invert predicted from the fill of K - sigma M (CHOLMOD + numba)
            self._analysis = a = fill_analysis(self._shifted, self.backend)
            self.method, self.reason = choose_method(self.n, self.nnz, k, self.max_memory, a, self.lattice)
            self._auto, self._setup_seconds = True, a.seconds if a is not None else 0.0
            self._info["predicted_seconds"] = {m: predicted_seconds(m, self.n, k, a) for m in METHODS[1:]}
        self._build()

    def _shift(self) -> sp.csr_matrix:
        """``K - sigma M``: over ``K`` (then ``K`` products from it) with ``overwrite``, from the node
        blocks after a LOBPCG set-up, else a new matrix."""
        if isinstance(self.K, ShiftedStiffness):
            return self.K.shifted_matrix()
        if not self.overwrite:
            return shifted(self.K, self.M, self.sigma)
        A = shift_in_place(self.K, self.M, self.sigma)
        if A is self.K:
            self.K = ShiftedStiffness(A.__matmul__, self.M.__matmul__, self.sigma, A)
        return A

    def _build(self) -> None:
        """The factorization of ``K - sigma M`` (shift-invert) or the AMG hierarchy (LOBPCG)."""
        t0 = time.perf_counter()
        A, self._shifted = (self._shifted if self._shifted is not None else self._shift()), None
        if self.method == "shift-invert":
            fac = factorize(A, self.backend, self._analysis)     # CHOLMOD reuses the ordering of _setup
            self._analysis = self._analysis and replace(self._analysis, perm=None)   # the numbers stay
            self.backend = fac.backend
            self._op = LinearOperator(A.shape, matvec=fac.solve, matmat=fac.solve, dtype=np.float64)
        else:
            bs = 3 if self.n % 3 == 0 else 1
            Mp = self.M if isinstance(self.M, ComponentMass) else None       # (a set-up that failed)
            if Mp is None and sp.issparse(self.M):   # M's nonzeros, as m (x) I_3 when it is (a ninth of M)
                Mp = ComponentMass.of(self.M)
            if self.overwrite:                       # M's lean form kept; K's products from the blocks
                self.M = Mp if Mp is not None else without_zeros(self.M)
                self.K = None
            # node blocks, the values reordered in place (A is the solver's own): no second copy, 648 B/DOF
            A = node_blocks(A, overwrite=True) if bs == 3 else A
            try:
                amg = LatticeAMG(A, self.near_null, aggregates=self.aggregates, blocksize=bs, seed=self.seed,
                                 dtype=VCYCLE_DTYPE)
            except BaseException:                    # K as the blocks' products, so that a retry can start over
                if self.K is None:
                    self.K = ShiftedStiffness(A.__matmul__, self.M.__matmul__, self.sigma, A)
                raise
            del A
            self._products = amg.levels[0], Mp if Mp is not None else BlockProduct(self.M)   # K - sigma M, M
            self.K = self._ritz_operators()[0] if self.K is None else self.K
            self._op, self.backend = amg.operator(), "pyamg"      # pyamg aggregation and tentative prolongator
            self._info["levels"] = len(amg.levels)
        self._info["factor_memory_estimate"] = factor_memory_estimate(self.n, self.nnz, self._analysis)
        self.n_setups += 1
        self._setup_seconds += time.perf_counter() - t0
        what = f"{self.backend} factorization" if self.method == "shift-invert" else f"AMG hierarchy ({self._info['levels']} levels)"
        _LOG.info(f"    {what} of {self.n:,} DOFs: {time.perf_counter() - t0:.2f} s")

    def _ritz_operators(self) -> tuple:
        """``K``, ``M`` for Rayleigh--Ritz: LOBPCG's own products (the node blocks, ``M``'s node matrix),
        also where the caller kept ``K`` and ``M``; the matrices after shift-invert's set-up."""
        if self.method != "lobpcg":
            return self.K, self.M
        A, Mp = self._products
        return (self.K if isinstance(self.K, ShiftedStiffness) else ShiftedStiffness(A, Mp, self.sigma, A.A)), Mp

    def _lobpcg_failed(self, worst: float, info: dict) -> None:
        """LOBPCG stopped with a wanted pair's relative residual above :data:`LOBPCG_ACCEPT`: switch
        to shift-invert when the method was chosen automatically and the factorization fits the
        memory budget (the reason says so), else raise :class:`SolverError`."""
        msg = (f"LOBPCG did not converge: relative residual {worst:.2g} > {LOBPCG_ACCEPT:g} after "
               f"{info['iterations']} iterations (stopped: {info['stop']}; "
               f"the AMG preconditioner works poorly on this model)")
        if info["stop"] == "over budget":                  # only "auto" stops it so
            f = info["forecasts"][-1]
            rest = (f"~{f['iterations']} iterations in all, ~{f['seconds_more']:.3g} s more" if f["iterations"]
                    else "its residual stopped falling")
            msg = (f"LOBPCG's forecast at iteration {f['at_iteration']}: {rest}, over {LOBPCG_SWITCH:g}x the "
                   f"{f['shift_invert_seconds']:.3g} s predicted for shift-invert")
        if not self._auto:
            raise SolverError(f"{msg}; use the shift-invert solver (eigen='shift-invert', or 'auto' to "
                              f"fall back automatically)")
        need, budget = factor_memory_estimate(self.n, self.nnz, self._analysis), memory_budget(self.max_memory)
        if need > budget:
            raise SolverError(f"{msg}; shift-invert would need ~{need / 2**30:.1f} GiB > budget "
                              f"{budget / 2**30:.1f} GiB: use a coarser resolution or raise max_memory "
                              f"(EigenOptions(max_memory=...))")
        self._info["lobpcg_failed"] = {"relative_residual": worst, **info}
        self.reason = f"{self.reason}; {msg}: {'switched' if info['stop'] == 'over budget' else 'fell back'} to shift-invert"
        self.method, self.backend = "shift-invert", self._requested_backend
        self._build()

    def _eigsh(self, k: int) -> tuple[np.ndarray, dict]:
        v0, ncv = np.random.default_rng(self.seed).standard_normal(self.n), min(self.n, max(2 * k + 1, k + 20))
        with stage_bar("eigensolve (shift-invert)", unit="solve") as bar:     # counts the solves with K - sigma M
            try:
                _, X = eigsh(self.K, k=k, M=self.M, sigma=self.sigma, which="LM", OPinv=counting(bar, self._op),
                             tol=self.tol, v0=v0, ncv=ncv, mode="normal")
            except Exception as exc:  # ARPACK errors carry partial results; report them as solver errors
                raise SolverError(f"eigsh (shift-invert, {self.backend}) failed: {exc}") from None
        return X, {}

    def _lobpcg(self, k: int) -> tuple[np.ndarray, dict]:
        m = min(self.n - 1, lobpcg_block(k))      # a few extra vectors speed convergence
        X = np.random.default_rng(self.seed).standard_normal((self.n, m))
        if (B := self.start) is not None:          # start in the rigid space: those modes converge at once
            X[:, :min(B.shape[1], m)] = B[:, :min(B.shape[1], m)]
        Ap, Mp = self._products
        # the tolerance is absolute on ||A x - mu M x|| (x M-normalized): the shift, the smallest
        # eigenvalue scale we know, times the typical ||M x|| ~ sqrt(mean diag M)
        tol_abs = self.lobpcg_tol * abs(self.sigma) * float(np.sqrt(np.mean(self.M.diagonal())))
        with blas_single_threaded(), stage_bar("eigensolve (LOBPCG)") as bar:   # counts the V-cycles
            forecasts, monitor = self._monitor(bar, k)
            _, V, info = lobpcg(Ap, Mp, X, k, tol_abs, T=counting(bar, self._op, tol_abs, (k, m)),
                                maxiter=self.maxiter, seed=self.seed, copy=False, monitor=monitor)
        out = {key: info[key] for key in ("iterations", "stop", "restarts", "residual_over_tol")}
        return V, {**out, "forecasts": forecasts} if forecasts else out

    def _monitor(self, bar, k: int) -> tuple[list[dict], Callable[[int, float], bool]]:
        """LOBPCG's forecasts for ``k`` pairs, one per progress check (filled in as it runs:
        ``at_iteration``, ``iterations`` in all or None when unbounded, ``seconds`` in all with the
        set-up, ``seconds_more``; with ``"auto"``, ``shift_invert_seconds``), and the monitor that
        makes them, gives the progress ``bar`` its total (so that it shows the time left), and stops
        LOBPCG when ``"auto"`` chose it and shift-invert, which fits the budget, would now finish
        sooner (:data:`LOBPCG_SWITCH`): its time predicted for these ``k`` pairs, less the fill
        analysis already made."""
        switch = self._auto and (factor_memory_estimate(self.n, self.nnz, self._analysis)
                                 <= memory_budget(self.max_memory))
        t_si = max(predicted_seconds("shift-invert", self.n, k, self._analysis)
                   - (self._analysis.seconds if self._analysis is not None else 0.0), 0.0) if self._auto else None
        forecasts, t0 = [], time.perf_counter()

        def monitor(it: int, projected: float) -> bool:
            spent = time.perf_counter() - t0
            more = float(max(projected - it, 0.0) * spent / max(it, 1))
            end = bool(np.isfinite(projected))              # None where the residual stopped falling
            forecasts.append({"at_iteration": it, "iterations": round(projected) if end else None,
                              "seconds": self._setup_seconds + spent + more if end else None,
                              "seconds_more": more if end else None,
                              **({"shift_invert_seconds": t_si} if t_si is not None else {})})
            _LOG.info(f"    LOBPCG forecast at iteration {it}: ~{forecasts[-1]['iterations'] or 'unbounded'} "
                      f"iterations, ~{more:.3g} s more")
            if end and not bar.disable:                     # the bar counts one V-cycle an iteration
                bar.total = max(round(projected), bar.n + 1)
                bar.refresh()
            return switch and more > LOBPCG_SWITCH * t_si

        return forecasts, monitor

    def solve(self, k: int) -> EigenResult:
        """The ``k`` smallest eigenpairs (``1 <= k < n``), refined by Rayleigh--Ritz, with residuals.

        Parameters
        ----------
        k : int
            Number of eigenpairs, ``1 <= k < n``.

        Returns
        -------
        EigenResult
            Eigenvalues (1/s^2, shape (k,)), ``M``-orthonormal vectors (shape (n, k)), residuals
            and timings.
        """
        k = positive_int(k, "k")
        if k >= self.n:
            raise InputError(f"k = {k} eigenpairs requested but the problem has only {self.n} DOFs (need k < n)")
        reused = self._op is not None
        if not reused:
            with stage_bar("eigensolver set-up", tick=1.0, rate=False):   # the fill analysis, the AMG
                self._setup(k)
        t0, secs = time.perf_counter(), {}
        while True:                            # at most twice: LOBPCG, then shift-invert if it failed
            X, info = self._eigsh(k) if self.method == "shift-invert" else self._lobpcg(k)
            secs["solve"] = secs.get("solve", 0.0) + time.perf_counter() - t0
            t0 = time.perf_counter()
            lam, X, KX, MX = rayleigh_ritz(*self._ritz_operators(), np.asarray(X), k)
            secs["rayleigh_ritz"] = secs.get("rayleigh_ritz", 0.0) + time.perf_counter() - t0
            if not (np.all(np.isfinite(lam)) and np.all(np.isfinite(X))):
                raise SolverError(f"the eigensolver ({self.method}) returned non-finite values")
            res = relative_residuals(lam, KX, MX, self.lambda_scale)
            worst = float(res.max())
            if self.method == "shift-invert" or worst <= LOBPCG_ACCEPT:
                break
            self._lobpcg_failed(worst, info)
            reused, t0 = False, time.perf_counter()
        secs["setup"] = self._setup_seconds
        return EigenResult(eigenvalues=lam, vectors=X, method=self.method, backend=self.backend,
                           sigma=self.sigma, reason=self.reason, seconds=secs,
                           info={**self._info, **info, "setup_reused": reused}, residuals=res)


def solve_eigen(K: sp.spmatrix, M: sp.spmatrix, k: int, *, method: str = "auto", backend: str = "auto",
                sigma: float | None = None, near_null: np.ndarray | None = None,
                aggregates: np.ndarray | None = None, tol: float = 0.0, lobpcg_tol: float = 1e-3,
                maxiter: int = 400, max_memory: float | None = None, seed: int = 0) -> EigenResult:
    """Smallest ``k`` eigenpairs of ``K phi = lambda M phi``: ``EigenSolver(K, M, ...).solve(k)``.

    Use :class:`EigenSolver` directly to solve again (e.g. for more pairs) without a second setup.

    Parameters
    ----------
    K, M : scipy.sparse matrix, shape (n, n)
        Symmetric stiffness (N/m, positive semi-definite) and mass (kg, positive definite).
    k : int
        Number of eigenpairs, ``1 <= k < n``.
    method : {"auto", "shift-invert", "lobpcg"}
        See the module docstring.
    backend : {"auto", "cholmod", "cholespy", "splu"}
        Factorization backend for shift-invert (:func:`sc_fem.fem.linsolve.factorize`).
    sigma : float, optional
        Shift in 1/s^2; must be negative. Default ``-SHIFT_FRACTION * lambda_scale(K, M)``.
    near_null : ndarray, shape (n, 6), optional
        Rigid-body modes for the AMG near-null space (LOBPCG); default: the translations.
    aggregates : ndarray of int, shape (n // 3,), optional
        The AMG's finest aggregates, one per DOF node (LOBPCG; e.g.
        :func:`sc_fem.fem.multigrid.lattice_aggregates`); default: pyamg's standard aggregation.
    tol : float
        ARPACK tolerance (0 = machine precision).
    lobpcg_tol, maxiter : float, int
        LOBPCG tolerance (relative, see :class:`EigenSolver`) and iteration limit.
    max_memory : float, optional
        Bytes the factorization may use (``method="auto"``); default half the available memory.
    seed : int
        Seed of the random start vectors.

    Returns
    -------
    EigenResult
        Eigenvalues (1/s^2, shape (k,)), ``M``-orthonormal vectors (shape (n, k)), residuals,
        the method chosen and why.
    """
    return EigenSolver(K, M, method=method, backend=backend, sigma=sigma, near_null=near_null, aggregates=aggregates, tol=tol,
                       lobpcg_tol=lobpcg_tol, maxiter=maxiter, max_memory=max_memory, seed=seed).solve(k)
