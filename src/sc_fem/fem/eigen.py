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
    :func:`scipy.sparse.linalg.lobpcg` preconditioned by a pyamg smoothed-aggregation solver of
    ``K - sigma M`` whose near-null space is the 6 rigid-body modes of the free DOFs. Needs only
    ``O(nnz(K))`` memory: the method for models whose factorization would not fit.

``method="auto"`` (:func:`choose_method`) predicts both solvers' times from
:data:`SPEED_MODEL` (calibrated by ``benchmarks/scale.py``) and their memory
(:func:`factor_memory_estimate`, :func:`lobpcg_memory_estimate`), and takes the faster one that
fits ``max_memory`` (default: half the available memory); the choice and the reason are returned
in :attr:`EigenResult.reason`. LOBPCG's pairs are checked after the solve: a wanted pair whose
relative residual exceeds :data:`LOBPCG_ACCEPT` (AMG can precondition thin members badly) makes
``"auto"`` fall back to shift-invert, and an explicitly requested ``"lobpcg"`` raise
:class:`~sc_fem.errors.SolverError` -- never unconverged modes returned as if they were eigenpairs.

All eigenvalues are refined and the vectors made exactly ``M``-orthonormal by a final
Rayleigh--Ritz step on the computed subspace, whose products ``K V``, ``M V`` also give the
residuals. :class:`EigenSolver` keeps the factorization (or AMG hierarchy) between solves, so
asking again for more eigenpairs costs no second setup; :func:`solve_eigen` is the one-shot form.
"""

from __future__ import annotations

import time
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator, eigsh

from .._validate import positive_int
from ..errors import InputError, SolverError

METHODS: tuple[str, ...] = ("auto", "shift-invert", "lobpcg")
"""Names accepted by ``method=``."""

SHIFT_FRACTION = 1e-7
"""The shift is ``-SHIFT_FRACTION * mean(diag K) / mean(diag M)``: far below every elastic
eigenvalue of a voxel model (so convergence is not slowed) yet large enough that
``K - sigma M`` stays well conditioned (condition number about ``1 / SHIFT_FRACTION``)."""

FILL_CONSTANT = 12.0
"""Calibration of :func:`factor_memory_estimate`: ``nnz(L) ~ FILL_CONSTANT * n^(4/3)`` (``n`` DOFs).
Measured with CHOLMOD on ``K + 1e-3 M``: root-fixed cantilevers 7.9 (3k DOFs), 11.1 (19k), 11.7 (61k);
chair r=48 7.6, r=96 5.5; bridge r=96 4.7; solid bunny r=64 5.1. 12 bounds all of them, so the
automatic choice never starts a factorization that would not fit (it may pick LOBPCG a little early
for shells)."""


@dataclass(frozen=True)
class EigenOptions:
    """Which eigensolver, and within what memory: the options :func:`sc_fem.modal` passes on to
    :class:`EigenSolver`.

    Parameters
    ----------
    solver : {"auto", "shift-invert", "lobpcg"}
        ``"auto"`` takes the one predicted faster on this machine whose memory fits
        ``max_memory`` (the reason is recorded in the result).
    backend : {"auto", "cholmod", "cholespy", "splu"}
        Factorization backend of shift-invert (:func:`sc_fem.fem.linsolve.factorize`).
    max_memory : float, optional
        Memory budget in bytes for the automatic choice; default half the available memory.
    """

    solver: str = "auto"
    backend: str = "auto"
    max_memory: float | None = None

    def __post_init__(self) -> None:
        from .linsolve import BACKENDS

        if self.solver not in METHODS:
            raise InputError(f"eigensolver must be one of {list(METHODS)}, got {self.solver!r}")
        if self.backend not in ("auto", *BACKENDS):
            raise InputError(f"backend must be one of {['auto', *BACKENDS]}, got {self.backend!r}")
        if self.max_memory is not None:
            from .._validate import positive_scalar

            object.__setattr__(self, "max_memory", positive_scalar(self.max_memory, "max_memory"))

    @classmethod
    def coerce(cls, value: "EigenOptions | str | None") -> "EigenOptions":
        """``None`` (defaults), an EigenOptions, or a solver name (``"lobpcg"``)."""
        if value is None:
            return cls()
        if isinstance(value, cls):
            return value
        if isinstance(value, str):
            return cls(solver=value)
        raise InputError(f"eigen must be an EigenOptions or a solver name, got {type(value).__name__}")


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
        ``||K phi - lambda M phi|| / ||K phi||`` of each pair (:func:`relative_residuals`).
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


def lambda_scale(K: sp.spmatrix, M: sp.spmatrix) -> float:
    """``mean(diag K) / mean(diag M)`` in 1/s^2: the order of the largest eigenvalues."""
    dk, dm = np.asarray(K.diagonal()), np.asarray(M.diagonal())
    s = float(dk.mean() / dm.mean()) if len(dk) else 0.0
    if not np.isfinite(s) or s <= 0:
        raise SolverError("K and M must have positive diagonals (is the mass zero somewhere?)")
    return s


def factor_memory_estimate(n: int, nnz: int) -> int:
    """Estimated bytes of a sparse Cholesky factorization of an ``n x n`` lattice matrix.

    ``nnz(L) ~ FILL_CONSTANT * n^(4/3)`` (nested dissection on a 3-D grid), 12 bytes per entry
    (value + index) plus workspace, and never below the matrix itself.
    """
    nnz_l = max(FILL_CONSTANT * float(n) ** (4.0 / 3.0), 0.5 * nnz)
    return int(12.0 * nnz_l * 1.3 + 16.0 * n)


def lobpcg_memory_estimate(n: int, nnz: int, k: int) -> int:
    """Estimated bytes of LOBPCG + AMG: the hierarchy (~2.5x the matrix) and ~12 blocks of k vectors."""
    return int(2.5 * 12.0 * nnz + 12.0 * 8.0 * n * (k + 8))


SPEED_MODEL = {"shift-invert": (0.23, 1.98), "lobpcg": (0.72, 0.98), "lobpcg-numba": (0.52, 0.98)}
"""Predicted seconds for 6 modes of a lattice with ``n`` free DOFs: ``c * (n / 7776) ** p`` per
solver, fitted (least squares in log-log) to cantilevers measured on this machine class (2 cores,
the default OpenBLAS, nothing else running; ``benchmarks/scale.py`` and its ``--compare``):
shift-invert with CHOLMOD 2.55 s / 4.95 s / 9.57 s / ~100 s at 24,336 / 37,800 / 55,488 / 158,976
DOFs; LOBPCG + smoothed-aggregation AMG with scipy's products 2.54 s / 4.57 s / 11.5 s / 85.7 s at
24,336 / 55,488 / 158,976 / 931,896 DOFs (2026-11-23), and with the compiled row-parallel products
(``"lobpcg-numba"``, used when numba is installed) 2.42 s / 9.4-10.2 s at 37,800 / 158,976 DOFs
(2026-11-24). The factorization's cost grows with ~n^2, LOBPCG's with ~n; they cross near 24,000
DOFs (~18,000 with numba). LOBPCG's cost also grows with ``k``."""


def predicted_seconds(method: str, n: int, k: int) -> float:
    """Seconds :data:`SPEED_MODEL` predicts for ``k`` modes of ``n`` free DOFs (LOBPCG: with the
    compiled products when numba is installed)."""
    from .._jit import available

    c, p = SPEED_MODEL["lobpcg-numba" if method == "lobpcg" and available() else method]
    t = c * (max(n, 1) / 7776.0) ** p
    return t * (max(k, 6) / 6.0 if method == "lobpcg" else 1.0)


def memory_budget(max_memory: float | None = None) -> float:
    """Bytes the eigensolver may use: ``max_memory``, or half the available memory."""
    from ..lattice.voxelize import available_memory

    return 0.5 * available_memory() if max_memory is None else float(max_memory)


def choose_method(n: int, nnz: int, k: int, max_memory: float | None = None) -> tuple[str, str]:
    """``("shift-invert" | "lobpcg", reason)``: the one :func:`predicted_seconds` says is faster,
    among those whose memory estimate fits the budget (bytes; default half the available memory)."""
    budget = memory_budget(max_memory)
    need = factor_memory_estimate(n, nnz)
    need_l = lobpcg_memory_estimate(n, nnz, k)
    t_si, t_l = predicted_seconds("shift-invert", n, k), predicted_seconds("lobpcg", n, k)
    fits_si, fits_l = need <= budget, need_l <= budget
    if not (fits_si or fits_l):
        raise SolverError(f"the eigenproblem with {n:,} DOFs does not fit in memory: a factorization needs "
                          f"~{need / 2**30:.1f} GiB and LOBPCG ~{need_l / 2**30:.1f} GiB, budget "
                          f"{budget / 2**30:.1f} GiB (half the available memory unless max_memory is given: "
                          f"EigenOptions(max_memory=...)); use a coarser resolution or a larger budget")
    times = f"predicted {t_si:.3g} s shift-invert vs {t_l:.3g} s LOBPCG + AMG"
    if fits_si and (t_si <= t_l or not fits_l):
        return "shift-invert", (f"{times}; factorization ~{need / 2**20:,.0f} MiB <= budget "
                                f"{budget / 2**20:,.0f} MiB")
    why = "faster" if fits_si else (f"the factorization would need ~{need / 2**20:,.0f} MiB > budget "
                                    f"{budget / 2**20:,.0f} MiB")
    return "lobpcg", f"{times} ({why}); LOBPCG needs ~{need_l / 2**20:,.0f} MiB"


LOBPCG_ACCEPT = 1e-3
"""Largest relative residual ``||K phi - lambda M phi|| / ||K phi||`` of a wanted LOBPCG pair that
is accepted (after the Rayleigh--Ritz step) when LOBPCG stops short of its tolerance; it stalls at
~1e-5 on large cantilevers with the frequencies converged to 1e-10. Beyond it the pairs are not
eigenpairs: on the bridge at resolution 96 (31,656 DOFs) the AMG V-cycle preconditions the
one-cube-thick cables so poorly (PCG needs 300-500 iterations) that LOBPCG stalled at relative
residuals ~0.98 with frequencies 15 % off, and ``modal`` returned them. The solver then falls back
to shift-invert (``method="auto"`` when the factorization fits the budget) or raises
:class:`SolverError` (``method="lobpcg"``)."""

LOBPCG_ROUNDS = (20, 8)
"""LOBPCG iterations of the first round and of every later one, between checks of the wanted
eigenpairs' residuals (see ``EigenSolver._lobpcg``): small models converge within the first
round (rounds of 12 took 29 iterations instead of 23 on a 3,000-DOF bar); on the 158,976-DOF
cantilever rounds of 20 stopped at 46 iterations, 20 then 8 at 34 (each restart costs a few)."""

JACOBI = ("jacobi", {"omega": 2.0 / 3.0, "iterations": 2})
"""Smoother of the AMG V-cycle: damped Jacobi on ``D^-1 A`` scaled to spectral radius 1 (a block of
vectors is smoothed by sparse matrix-matrix products, unlike Gauss-Seidel)."""


@contextmanager
def _seeded_global_random(seed: int):
    """numpy's global random state seeded for the block, and restored after it.

    pyamg starts its spectral-radius estimates (the Jacobi weights of the prolongation smoother
    and of the smoothers) from ``np.random.rand``: unseeded, the preconditioner, and so LOBPCG's
    iterations, differed from run to run (a 3,600-DOF plate converged in 45 iterations on most
    runs and stalled on one in six). pyamg's documentation asks for ``np.random.seed`` for
    reproducible hierarchies; the caller's own random stream is left as it was."""
    state = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(state)


class BlockVCycle:
    """The V-cycle of a pyamg hierarchy applied to a block of vectors at once.

    scipy's LOBPCG hands its preconditioner a block (n, k); pyamg's own V-cycle takes one vector
    at a time, so each LOBPCG iteration cost k V-cycles of sparse matrix-vector products. Here
    every level does its Jacobi sweeps, restriction and prolongation as sparse matrix-matrix
    products on the whole block; the coarsest level is a dense Cholesky solve. Column by column
    the result agrees with pyamg's ``solve(b, x0=0, maxiter=1, cycle="V")`` with the same
    smoothers (tested to 1e-10); it is symmetric positive definite. Its cost is the sparse block
    products (~6 per LOBPCG iteration), done by :class:`sc_fem.fem.spmm.BlockProduct` (rows split
    over the cores when numba is installed: 26 ms instead of scipy's 41 ms for 10 vectors at
    158,976 DOFs; a Jacobi sweep's product and update are then one pass, 124 instead of 128 ms a
    cycle at 139,656 DOFs); float32 values did not make them faster.

    Parameters
    ----------
    ml : pyamg.MultilevelSolver
        The hierarchy (its levels' ``A``, ``R``, ``P``; Jacobi smoothers set up by pyamg).
    kernel : {"auto", "numba", "numpy"}
        The block products' kernel (:class:`sc_fem.fem.spmm.BlockProduct`).
    """

    def __init__(self, ml, kernel: str = "auto") -> None:
        from pyamg.relaxation.smoothing import rho_D_inv_A

        from .spmm import BlockProduct

        self.levels = ml.levels
        # every level's A, R and P as row-parallel block products (pyamg keeps R and P as BSR)
        self.A = [BlockProduct(lvl.A, kernel) for lvl in self.levels[:-1]]
        self.R = [BlockProduct(lvl.R, kernel) for lvl in self.levels[:-1]]
        self.P = [BlockProduct(lvl.P, kernel) for lvl in self.levels[:-1]]
        self.wd = []                                       # per level: the Jacobi weights omega / (rho d_ii)
        for lvl in self.levels[:-1]:
            d = lvl.A.diagonal()
            dinv = np.where(d != 0, 1.0 / np.where(d != 0, d, 1.0), 0.0)
            # pyamg's estimate of the spectral radius of D^-1 A, cached on the matrix when pyamg set
            # up its own Jacobi smoothers: the same number, not a second Krylov run per level
            self.wd.append(JACOBI[1]["omega"] / rho_D_inv_A(lvl.A) * dinv)
        self.coarse = _coarse_solver(self.levels[-1].A.toarray())
        self.nu = JACOBI[1]["iterations"]

    def _cycle(self, i: int, b: np.ndarray) -> np.ndarray:
        if i == len(self.levels) - 1:
            return self.coarse(b)
        A, wd = self.A[i], self.wd[i]
        x = wd[:, None] * b                                # first sweep from x = 0
        for _ in range(self.nu - 1):                       # pre-smoothing (a couple of sweeps)
            x = A.jacobi(x, b, wd)
        x += self.P[i](self._cycle(i + 1, self.R[i](b - A(x))))
        for _ in range(self.nu):                           # post-smoothing
            x = A.jacobi(x, b, wd)
        return x

    def __call__(self, b: np.ndarray) -> np.ndarray:
        """V-cycle applied to ``b`` (n,) or (n, k)."""
        b = np.asarray(b, dtype=np.float64)
        return self._cycle(0, b.reshape(b.shape[0], -1)).reshape(b.shape)

    def operator(self) -> LinearOperator:
        n = self.levels[0].A.shape[0]
        return LinearOperator((n, n), matvec=self, matmat=self, dtype=np.float64)


def _coarse_solver(a: np.ndarray):
    """``b -> A^-1 b`` for the dense coarsest matrix of the hierarchy: a Cholesky factor when
    ``A`` is positive definite (the shifted ``K - sigma M`` always is), else the pseudo-inverse
    (pyamg's default, an SVD: 3 s for a 1,900-DOF coarsest level against 0.05 s for Cholesky)."""
    from scipy.linalg import LinAlgError, cho_factor, cho_solve

    try:
        factor = cho_factor(a, lower=True, check_finite=False)
    except LinAlgError:
        pinv = np.linalg.pinv(a)
        return lambda b: pinv @ b
    return lambda b: cho_solve(factor, b, check_finite=False)


def shifted(K: sp.spmatrix, M: sp.spmatrix, sigma: float) -> sp.csr_matrix:
    """``K - sigma M`` as CSR; when both share one sparsity pattern (the assembler's consistent
    ``M`` shares ``K``'s), one operation on the values instead of a sparse merge (4.7 s at
    931,896 DOFs)."""
    K, M = sp.csr_matrix(K), sp.csr_matrix(M)
    same = (K.nnz == M.nnz and K.has_sorted_indices and M.has_sorted_indices
            and (K.indptr is M.indptr or np.array_equal(K.indptr, M.indptr))
            and (K.indices is M.indices or np.array_equal(K.indices, M.indices)))
    if not same:
        return (K - sigma * M).tocsr()
    return sp.csr_matrix((K.data - sigma * M.data, K.indices, K.indptr), shape=K.shape)


def rigid_body_modes(points: np.ndarray, free_dofs: np.ndarray | None = None) -> np.ndarray:
    """The 6 rigid-body displacement fields of ``points`` (m, 3): shape (3m or n_free, 6).

    Columns: translations x, y, z, then rotations about x, y, z (about the centroid, scaled
    by the extent so all columns have similar norms). Rows are interleaved DOFs ``3i + c``,
    restricted to ``free_dofs`` when given.
    """
    p = np.asarray(points, dtype=float)
    q = p - p.mean(axis=0)
    B = rigid_block(q / max(float(np.abs(q).max()), 1e-300)).reshape(3 * len(p), 6)
    return B if free_dofs is None else B[free_dofs]


def rigid_block(q: np.ndarray) -> np.ndarray:
    """Rigid-body displacement of points at offsets ``q`` (n, 3) from a centre: shape (n, 3, 6),
    ``[I, -[q]x]`` (translations x, y, z, then rotations about x, y, z)."""
    B = np.zeros((len(q), 3, 6))
    B[:, [0, 1, 2], [0, 1, 2]] = 1.0
    x, y, z = np.asarray(q, dtype=float).T
    B[:, 1, 3], B[:, 2, 3] = -z, y
    B[:, 0, 4], B[:, 2, 4] = z, -x
    B[:, 0, 5], B[:, 1, 5] = -y, x
    return B


def rayleigh_ritz(K, M, X: np.ndarray, k: int | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Refine a subspace ``X`` (n, m): eigenpairs of ``(X^T K X, X^T M X)``, vectors ``M``-orthonormal.

    Returns the ``k`` smallest (default all ``m``) eigenvalues ``lam`` (k,), vectors ``V`` (n, k),
    and ``K V``, ``M V`` (n, k) -- obtained from ``K X``, ``M X`` at no extra sparse product, for
    :func:`relative_residuals`.
    """
    from scipy.linalg import eigh

    KX, MX = K @ X, M @ X
    A = X.T @ KX
    G = X.T @ MX
    A, G = 0.5 * (A + A.T), 0.5 * (G + G.T)
    lam, C = eigh(A, G)
    C = C[:, :k]
    return lam[:k], X @ C, KX @ C, MX @ C


def relative_residuals(eigenvalues: np.ndarray, KV: np.ndarray, MV: np.ndarray, scale: float) -> np.ndarray:
    """``||K phi - lambda M phi|| / ||K phi||`` per column from the products ``K V``, ``M V`` (n, k).

    For (near-)rigid modes, where ``K phi ~ 0``, the denominator is floored at
    ``SHIFT_FRACTION * scale * ||M phi||`` (the size of the shift term; ``scale`` =
    :func:`lambda_scale`), which is below ``||K phi||`` for every elastic mode.
    """
    r = np.linalg.norm(KV - MV * eigenvalues[None, :], axis=0)
    den = np.maximum(np.linalg.norm(KV, axis=0), SHIFT_FRACTION * scale * np.linalg.norm(MV, axis=0))
    return r / den


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
        Rigid-body modes for the AMG near-null space (LOBPCG); default: constant vectors.
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

    def __init__(self, K, M, *, method: str = "auto", backend: str = "auto", sigma: float | None = None,
                 near_null: np.ndarray | None = None, tol: float = 0.0, lobpcg_tol: float = 1e-3,
                 maxiter: int = 400, max_memory: float | None = None, seed: int = 0) -> None:
        if method not in METHODS:
            raise InputError(f"method must be one of {list(METHODS)}, got {method!r}")
        if not (sp.issparse(K) and sp.issparse(M)) or K.shape != M.shape or K.shape[0] != K.shape[1]:
            raise InputError("K and M must be square scipy.sparse matrices of the same shape")
        self.K, self.M = sp.csr_matrix(K, dtype=float), sp.csr_matrix(M, dtype=float)
        self.n = self.K.shape[0]
        self.lambda_scale = lambda_scale(self.K, self.M)
        if sigma is None:
            sigma = -SHIFT_FRACTION * self.lambda_scale
        elif not (np.isfinite(sigma) and sigma < 0):
            raise InputError(f"sigma must be a negative shift (below every eigenvalue), got {sigma!r}")
        self.sigma = float(sigma)
        self.method, self.backend, self.reason = method, backend, ""
        self._auto, self._requested_backend = False, backend
        self.near_null, self.tol, self.lobpcg_tol, self.maxiter = near_null, tol, lobpcg_tol, maxiter
        self.max_memory, self.seed = max_memory, seed
        self.n_setups = 0
        self._op = None                       # OPinv (shift-invert) or the V-cycle (LOBPCG)
        self._setup_seconds = 0.0
        self._info: dict = {}

    def _setup(self, k: int) -> None:
        if self.method == "auto":
            self.method, self.reason = choose_method(self.n, self.K.nnz, k, self.max_memory)
            self._auto = True
        else:
            self.reason = "requested"
        self._build()

    def _build(self) -> None:
        """The factorization of ``K - sigma M`` (shift-invert) or the AMG hierarchy (LOBPCG)."""
        t0 = time.perf_counter()
        A = shifted(self.K, self.M, self.sigma)
        if self.method == "shift-invert":
            from .linsolve import factorize

            fac = factorize(A, self.backend)
            self.backend = fac.backend
            self._op = LinearOperator(A.shape, matvec=fac.solve, matmat=fac.solve, dtype=np.float64)
        else:
            import pyamg

            from .spmm import BlockProduct

            self._products = BlockProduct(A), BlockProduct(self.M)     # K - sigma M and M; row-parallel with numba
            # the rigid-body modes are the exact near-null space of K: pyamg's default smoothing of
            # the candidates (4 block Gauss-Seidel sweeps) adds nothing but time (5 s at 931,896 DOFs)
            kw = {"improve_candidates": None} if self.near_null is not None else {}
            with _seeded_global_random(self.seed):
                ml = pyamg.smoothed_aggregation_solver(A, B=self.near_null, max_coarse=500, keep=False,
                                                       presmoother=JACOBI, postsmoother=JACOBI, **kw)
                self._op = BlockVCycle(ml).operator()
            self.backend = "pyamg"
            self._info["levels"] = len(ml.levels)
        self._info["factor_memory_estimate"] = factor_memory_estimate(self.n, self.K.nnz)
        self.n_setups += 1
        self._setup_seconds += time.perf_counter() - t0

    def _lobpcg_failed(self, worst: float, info: dict) -> None:
        """LOBPCG stopped with a wanted pair's relative residual above :data:`LOBPCG_ACCEPT`: switch
        to shift-invert when the method was chosen automatically and the factorization fits the
        memory budget (the reason says so), else raise :class:`SolverError`."""
        msg = (f"LOBPCG did not converge: relative residual {worst:.2g} > {LOBPCG_ACCEPT:g} after "
               f"{info['iterations']} iterations (stopped: {info['stop']}; "
               f"the AMG preconditioner works poorly on this model)")
        if not self._auto:
            raise SolverError(f"{msg}; use the shift-invert solver (eigen='shift-invert', or 'auto' to "
                              f"fall back automatically)")
        need, budget = factor_memory_estimate(self.n, self.K.nnz), memory_budget(self.max_memory)
        if need > budget:
            raise SolverError(f"{msg}; shift-invert would need ~{need / 2**30:.1f} GiB > budget "
                              f"{budget / 2**30:.1f} GiB: use a coarser resolution or raise max_memory "
                              f"(EigenOptions(max_memory=...))")
        self._info["lobpcg_failed"] = {"relative_residual": worst, **info}
        self.reason = f"{self.reason}; {msg}: fell back to shift-invert"
        self.method, self.backend = "shift-invert", self._requested_backend
        self._build()

    def _eigsh(self, k: int) -> tuple[np.ndarray, dict]:
        v0 = np.random.default_rng(self.seed).standard_normal(self.n)
        ncv = min(self.n, max(2 * k + 1, k + 20))
        try:
            _, X = eigsh(self.K, k=k, M=self.M, sigma=self.sigma, which="LM", OPinv=self._op, tol=self.tol,
                         v0=v0, ncv=ncv, mode="normal")
        except Exception as exc:  # ARPACK errors carry partial results; report them as solver errors
            raise SolverError(f"eigsh (shift-invert, {self.backend}) failed: {exc}") from None
        return X, {}

    def _lobpcg(self, k: int) -> tuple[np.ndarray, dict]:
        import warnings

        from scipy.sparse.linalg import lobpcg

        B = self.near_null
        m = min(self.n - 1, k + max(4, k // 4))   # a few extra vectors speed convergence
        X = np.random.default_rng(self.seed).standard_normal((self.n, m))
        if B is not None:                          # start in the rigid space: those modes converge at once
            X[:, :min(B.shape[1], m)] = B[:, :min(B.shape[1], m)]
        from .._jit import blas_single_threaded

        Ap, Mp = self._products
        parallel = "numba" in (Ap.kernel, Mp.kernel)
        with warnings.catch_warnings(), (blas_single_threaded() if parallel else nullcontext()):
            warnings.simplefilter("ignore")        # lobpcg warns when it stops at maxiter; we report residuals
            # lobpcg's tol is absolute on ||A x - mu M x|| (x M-normalized): scale it by the shift, the
            # smallest eigenvalue scale we know, times the typical ||M x|| ~ sqrt(mean diag M)
            tol_abs = self.lobpcg_tol * abs(self.sigma) * float(np.sqrt(np.mean(self.M.diagonal())))
            # scipy's LOBPCG stops only when every vector of the block has converged, the extra
            # ones too, which converge last (on the 24,336-DOF cantilever the 6 wanted modes
            # converged at iteration 19 and the block at 53); so it runs in rounds of
            # LOBPCG_ROUNDS iterations, each restarted from the last, until the k wanted pass
            # A round that LOBPCG ends early on its own (its Gram matrices too ill-conditioned to
            # go on) is restarted from where it got to: a fresh, orthonormal block often goes on
            # (a 3,600-DOF plate stalled in 5 of 60 random starts, at relative residuals down to
            # 0.003, and converged after one to three restarts). A stalled round is judged as any
            # other, by the rule below, and ends the solve when it made too little progress:
            # restarting then gains nothing (at 931,896 DOFs every later round ran 2-3 iterations
            # and left the residuals where they were, the frequencies already converged to 1e-10);
            # the residuals reached are reported.
            # A round whose residual reduction, kept up, would not reach the tolerance within
            # maxiter ends the solve too ("slow"): on the bridge at resolution 128 the second round
            # cut the residual by 1 % (the cantilevers' rounds cut it 3x or more).
            its = rounds = stalls = 0
            stop, prev = "converged", None
            while True:
                asked = min(LOBPCG_ROUNDS[rounds > 0], self.maxiter - its)
                lam, V, hist = lobpcg(Ap.operator(), X, B=Mp.operator(), M=self._op, tol=tol_abs, maxiter=asked,
                                      largest=False, retResidualNormsHistory=True)
                its, rounds = its + len(hist), rounds + 1
                stalled = len(hist) < asked            # it ended the round before maxiter on its own
                stalls += stalled
                order = np.argsort(lam)
                lam, V = lam[order], V[:, order]
                R = Ap(V[:, :k]) - Mp(V[:, :k]) * lam[None, :k]
                worst = float(np.linalg.norm(R, axis=0).max()) / tol_abs
                if worst <= 1.0:
                    break
                if its >= self.maxiter:
                    stop = "maxiter"
                elif prev is not None and (prev <= worst or its + LOBPCG_ROUNDS[1] * np.log(worst)
                                           / np.log(prev / worst) > self.maxiter):
                    stop = "stalled" if stalled else "slow"
                if stop != "converged":
                    break
                X, prev = V, worst
        return V, {"iterations": its, "rounds": rounds, "stop": stop, "stalled_rounds": stalls,
                   "residual_over_tol": worst}

    def solve(self, k: int) -> EigenResult:
        """The ``k`` smallest eigenpairs (``1 <= k < n``), refined by Rayleigh--Ritz, with residuals."""
        k = positive_int(k, "k")
        if k >= self.n:
            raise InputError(f"k = {k} eigenpairs requested but the problem has only {self.n} DOFs (need k < n)")
        reused = self._op is not None
        if not reused:
            self._setup(k)
        t0 = time.perf_counter()
        secs = {}
        while True:                            # at most twice: LOBPCG, then shift-invert if it failed
            X, info = self._eigsh(k) if self.method == "shift-invert" else self._lobpcg(k)
            secs["solve"] = secs.get("solve", 0.0) + time.perf_counter() - t0
            t0 = time.perf_counter()
            lam, X, KX, MX = rayleigh_ritz(self.K, self.M, np.asarray(X), k)
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


def solve_eigen(K, M, k: int, *, method: str = "auto", backend: str = "auto", sigma: float | None = None,
                near_null: np.ndarray | None = None, tol: float = 0.0, lobpcg_tol: float = 1e-3,
                maxiter: int = 400, max_memory: float | None = None, seed: int = 0) -> EigenResult:
    """Smallest ``k`` eigenpairs of ``K phi = lambda M phi``: ``EigenSolver(K, M, ...).solve(k)``.

    The parameters are those of :class:`EigenSolver`; ``k`` is the number of eigenpairs
    (``1 <= k < n``). Use :class:`EigenSolver` directly to solve again (e.g. for more pairs)
    without a second factorization.

    Returns
    -------
    EigenResult
    """
    return EigenSolver(K, M, method=method, backend=backend, sigma=sigma, near_null=near_null, tol=tol,
                       lobpcg_tol=lobpcg_tol, maxiter=maxiter, max_memory=max_memory, seed=seed).solve(k)
