"""Algebraic multigrid on the lattice: the preconditioner of the LOBPCG eigensolver
(:mod:`sc_fem.fem.eigen`: pyamg's smoothed-aggregation hierarchy of ``K - sigma M``, seeded for
reproducibility, its V-cycle applied to a block of vectors at once, :class:`BlockVCycle`) and the
conjugate-gradient solver of static equilibrium (:class:`StaticAMG`: a smoothed-aggregation
hierarchy of ``K`` with node-block Jacobi and Chebyshev smoothing, :func:`pcg`)."""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator

from .._jit import choose_kernel, compiled, compiled_parallel, prange

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


# ---------------------------------------------------------------- conjugate gradients + AMG (statics)

CHEBYSHEV = {"degree": 3, "ratio": 30.0, "safety": 1.1}
"""The smoother of :class:`StaticAMG`: a Chebyshev polynomial of the given degree in ``D^-1 A``
(``D`` the node blocks of the diagonal), damping the part of the spectrum from
``safety * rho / ratio`` to ``safety * rho`` (``rho`` a Lanczos estimate of its spectral radius).
On the clamped bunny at r64 (195,759 DOFs) degree 3 took 20 CG iterations to 1e-8 and degree 4
19 (one more product per sweep); with the point diagonal instead of the node blocks, and pyamg's
aggregation, 38; pyamg's default solver (symmetric Gauss-Seidel) 53. It needs only products with
``A`` (compiled, :data:`PARALLEL_NNZ`)."""

PROLONGATION_OMEGA = 4.0 / 3.0
"""Weight of the tentative prolongator's Jacobi smoothing, ``P = (I - omega / rho D^-1 A) T``."""

LANCZOS_STEPS = 12
"""Lanczos steps of the spectral-radius estimate of ``D^-1 A`` on every level (pyamg's own estimate
took 1-5 s at 195,759 DOFs; these take ~0.2 s and are within a few per cent)."""


def _bsr3_rows_py(indptr, indices, data, x, y, lo, hi):  # pragma: no cover - compiled
    for i in range(lo, hi):                     # y = A x on the node rows lo:hi
        s0 = s1 = s2 = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = 3 * indices[p]
            x0, x1, x2 = x[j], x[j + 1], x[j + 2]
            s0 += data[p, 0, 0] * x0 + data[p, 0, 1] * x1 + data[p, 0, 2] * x2
            s1 += data[p, 1, 0] * x0 + data[p, 1, 1] * x1 + data[p, 1, 2] * x2
            s2 += data[p, 2, 0] * x0 + data[p, 2, 1] * x1 + data[p, 2, 2] * x2
        y[3 * i], y[3 * i + 1], y[3 * i + 2] = s0, s1, s2


def _bsr3_mv_py(indptr, indices, data, x, y):  # pragma: no cover - compiled
    n = len(indptr) - 1
    for c in prange(64):                        # row chunks split over the cores
        _bsr3_rows(indptr, indices, data, x, y, c * n // 64, (c + 1) * n // 64)


# two functions, not one compiled twice: numba's disk cache keys a function by name and line, and a
# serial and a parallel build of one function overwrote each other
_bsr3_rows = compiled(_bsr3_rows_py)
_bsr3_mv = compiled_parallel(_bsr3_mv_py)

PARALLEL_NNZ = 4_000_000
"""From this many nonzeros the finest level's product runs on every core; below, on one. A
parallel product waits for both threads: on this shared 2-core machine, with another process on
the other core, that cost ~8 ms a call whatever the size (0.3 ms for the 578k nonzeros of an
8,820-DOF cantilever on one core); at 14.6M nonzeros it took 7 ms on 2 quiet cores, 12 ms on one."""


def _node_blocks_py(ptr, indices, data, bptr, bidx, bdata, bad):  # pragma: no cover - compiled
    for i in prange(len(bptr) - 1):          # node rows split over the cores
        for j in range(bptr[i + 1] - bptr[i]):
            c = indices[ptr[3 * i] + 3 * j]
            bidx[bptr[i] + j] = c // 3
            for a in range(3):
                s = ptr[3 * i + a] + 3 * j
                for b in range(3):
                    bdata[bptr[i] + j, a, b] = data[s + b]
                    if indices[s + b] != c - c % 3 + b:
                        bad[i] = True


_node_blocks = compiled_parallel(_node_blocks_py)


def node_blocks(A: sp.spmatrix) -> sp.bsr_matrix:
    """``A`` (n, n) as a BSR matrix of 3 x 3 node blocks.

    The lattice's CSR matrices (node-major interleaved DOFs, nodes fixed whole, sorted indices)
    have the same columns in the 3 rows of a node; with numba the blocks are copied straight out
    of them on every core (0.05 s instead of scipy's 0.6 s at 195,759 DOFs). Any other matrix, or
    no numba, goes through scipy.
    """
    A = sp.csr_matrix(A, dtype=np.float64)
    n = A.shape[0]
    if _node_blocks is None or n % 3 or not A.has_sorted_indices:
        return sp.bsr_matrix(A, blocksize=(3, 3))
    cnt = np.diff(A.indptr)
    per = cnt[0::3]
    if np.any(per % 3) or np.any(cnt[1::3] != per) or np.any(cnt[2::3] != per):
        return sp.bsr_matrix(A, blocksize=(3, 3))
    bptr = np.concatenate([[0], np.cumsum(per // 3)]).astype(A.indptr.dtype)
    bidx = np.empty(bptr[-1], dtype=A.indices.dtype)
    bdata = np.empty((bptr[-1], 3, 3))
    bad = np.zeros(n // 3, dtype=np.bool_)
    _node_blocks(A.indptr, A.indices, A.data, bptr, bidx, bdata, bad)
    if bad.any():                                # a node's rows do not share whole node columns
        return sp.bsr_matrix(A, blocksize=(3, 3))
    return sp.bsr_matrix((bdata, bidx, bptr), shape=A.shape)


class _Level:
    """One level of :class:`StaticAMG`: ``A`` as node blocks, the inverse (square root) of its
    block diagonal, the spectral-radius estimate, and (but on the coarsest) ``P`` and ``R``."""

    def __init__(self, A: sp.bsr_matrix, kernel: str, seed: int) -> None:
        self.A = A
        self.bs = A.blocksize[0]
        self.fast = kernel == "numba" and self.bs == 3
        nb = A.shape[0] // self.bs
        rows = np.repeat(np.arange(nb), np.diff(A.indptr))
        D = np.zeros((nb, self.bs, self.bs))
        diag = A.indices == rows
        D[rows[diag]] = A.data[diag]
        # D^-1/2 and D^-1 by eigen-decomposition: a block of zero rows (an aggregate too small for all
        # six rigid modes leaves coarse DOFs with no entries) gets a pseudo-inverse, not a division by 0
        w, V = np.linalg.eigh(D)
        big = w > 1e-12 * np.maximum(w.max(axis=1, keepdims=True), 1e-300)
        s = np.where(big, 1.0 / np.sqrt(np.where(big, w, 1.0)), 0.0)
        self.Dinv = np.einsum("nij,nj,nkj->nik", V, s * s, V)
        eye = (np.arange(nb), np.arange(nb + 1))
        self._Dhalf = sp.bsr_matrix((np.einsum("nij,nj,nkj->nik", V, s, V), *eye), shape=A.shape)
        self._Dinv = sp.bsr_matrix((self.Dinv, *eye), shape=A.shape)
        self.rho = _lanczos_max(lambda v: self.dscale(self(self.dscale(v, half=True)), half=True), A.shape[0], seed)
        self.P = self.R = None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """``A @ x``."""
        if not self.fast:
            return self.A @ x
        y = np.empty(self.A.shape[0])
        if self.A.nnz >= PARALLEL_NNZ:
            _bsr3_mv(self.A.indptr, self.A.indices, self.A.data, x, y)
        else:
            _bsr3_rows(self.A.indptr, self.A.indices, self.A.data, x, y, 0, len(self.A.indptr) - 1)
        return y

    def dscale(self, x: np.ndarray, half: bool = False) -> np.ndarray:
        """``D^-1 x`` (or ``D^-1/2 x``) with ``D`` the block diagonal of ``A``."""
        return (self._Dhalf if half else self._Dinv) @ x

    def chebyshev(self, x: np.ndarray | None, b: np.ndarray) -> np.ndarray:
        """:data:`CHEBYSHEV` smoothing of ``A x = b`` from ``x`` (``None``: from 0)."""
        hi = CHEBYSHEV["safety"] * self.rho
        lo = hi / CHEBYSHEV["ratio"]
        theta, delta = 0.5 * (hi + lo), 0.5 * (hi - lo)
        sigma = theta / delta
        rho = 1.0 / sigma
        r = self.dscale(b if x is None else b - self(x))
        d = r / theta
        x = d.copy() if x is None else x + d
        for _ in range(CHEBYSHEV["degree"] - 1):
            r -= self.dscale(self(d))
            rho_new = 1.0 / (2.0 * sigma - rho)
            d *= rho_new * rho
            d += (2.0 * rho_new / delta) * r
            rho = rho_new
            x += d
        return x


def _lanczos_max(mv, n: int, seed: int, steps: int = LANCZOS_STEPS) -> float:
    """Largest eigenvalue of the symmetric operator ``mv`` (n x n) by Lanczos with full
    reorthogonalization (a slight underestimate, covered by :data:`CHEBYSHEV`'s safety factor)."""
    steps = max(1, min(steps, n))
    V, alpha, beta, k = np.zeros((steps + 1, n)), np.zeros(steps), np.zeros(steps), steps
    V[0] = np.random.default_rng(seed).standard_normal(n)
    V[0] /= np.linalg.norm(V[0])
    for j in range(steps):
        w = mv(V[j])
        alpha[j] = w @ V[j]
        w -= V[: j + 1].T @ (V[: j + 1] @ w)
        beta[j] = np.linalg.norm(w)
        if not beta[j] > 1e-10 * max(abs(alpha[j]), 1e-300):
            k = j + 1
            break
        V[j + 1] = w / beta[j]
    T = np.diag(alpha[:k]) + np.diag(beta[: k - 1], 1) + np.diag(beta[: k - 1], -1)
    return max(float(np.linalg.eigvalsh(T)[-1]), 1e-300)


class StaticAMG:
    """CG preconditioned by a smoothed-aggregation V-cycle for ``A x = b``, ``A`` SPD (the stiffness
    of a held model): set up once, then :meth:`solve` any number of right-hand sides.

    pyamg's smoothed aggregation (its aggregation, ``fit_candidates``, products; the rigid-body
    modes as near-null space), built level by level here so that the finest aggregates can be given
    (lattice blocks, :mod:`sc_fem.fem.static`), the prolongator is smoothed with the node blocks of
    the diagonal and a Lanczos spectral radius, and the V-cycle smooths with :data:`CHEBYSHEV`.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        Symmetric positive definite, e.g. the reduced stiffness (N/m), DOFs node-major.
    near_null : ndarray, shape (n, k)
        Near-null space: the 6 rigid-body modes (:func:`sc_fem.fem.rigid.rigid_body_modes`).
    aggregates : ndarray of int, shape (n // 3,), optional
        Aggregate of every node of the finest level; default pyamg's standard aggregation.
    blocksize : int
        DOFs per node (3; 1 for a matrix without node structure).
    max_coarse : int
        Largest coarsest level, solved densely.
    kernel : {"auto", "numba", "numpy"}
        The finest level's products: compiled (numba; on every core from :data:`PARALLEL_NNZ`
        nonzeros) or scipy's; ``"auto"``: compiled when numba is installed.
    seed : int
        Seed of the Lanczos start vectors.

    Attributes
    ----------
    levels : list
        The levels, finest first (their ``A`` in N/m at the finest).
    seconds : float
        Wall time of the setup, s.
    """

    def __init__(self, A: sp.spmatrix, near_null: np.ndarray, *, aggregates: np.ndarray | None = None,
                 blocksize: int = 3, max_coarse: int = 600, kernel: str = "auto", seed: int = 0) -> None:
        import time

        from .._jit import blas_single_threaded

        t0 = time.perf_counter()
        with blas_single_threaded():            # OpenBLAS's spinning threads starve numba's
            self._build(A, near_null, aggregates, blocksize, max_coarse, kernel, seed)
        self.seconds = time.perf_counter() - t0

    def _build(self, A, near_null, aggregates, blocksize, max_coarse, kernel, seed) -> None:
        from pyamg.aggregation.aggregate import standard_aggregation
        from pyamg.aggregation.tentative import fit_candidates
        from pyamg.strength import symmetric_strength_of_connection

        Ab = node_blocks(A) if blocksize == 3 else sp.bsr_matrix(A, blocksize=(blocksize,) * 2)
        kernel = choose_kernel(kernel)
        B = np.asarray(near_null, dtype=np.float64)
        self.levels: list[_Level] = []
        while True:
            lvl = _Level(Ab, kernel if not self.levels else "numpy", seed + len(self.levels))
            self.levels.append(lvl)
            nb = Ab.shape[0] // lvl.bs
            if Ab.shape[0] <= max_coarse or len(self.levels) == 10:
                break
            if aggregates is not None and len(self.levels) == 1:
                agg = np.asarray(aggregates)
                AggOp = sp.csr_matrix((np.ones(nb), (np.arange(nb), agg)), shape=(nb, int(agg.max()) + 1))
            else:
                AggOp = standard_aggregation(symmetric_strength_of_connection(Ab, theta=0.0))[0]
            if AggOp.shape[1] * B.shape[1] >= Ab.shape[0]:
                break                                   # aggregation no longer coarsens
            T, B = fit_candidates(AggOp.tocsr(), B)
            AT = sp.bsr_matrix(Ab @ T, blocksize=T.blocksize)
            rows = np.repeat(np.arange(AT.shape[0] // lvl.bs), np.diff(AT.indptr))
            U = np.einsum("pij,pjk->pik", ((PROLONGATION_OMEGA / lvl.rho) * lvl.Dinv)[rows], AT.data)
            P = sp.bsr_matrix(T - sp.bsr_matrix((U, AT.indices, AT.indptr), shape=AT.shape),
                              blocksize=T.blocksize)
            lvl.P, lvl.R = P, sp.bsr_matrix(P.T)
            Ab = sp.bsr_matrix(lvl.R @ (Ab @ P), blocksize=(P.blocksize[1],) * 2)
            Ab.sort_indices()
        c = self.levels[-1].A.toarray()
        self._coarse = _coarse_solver(0.5 * (c + c.T))
        self.kernel = kernel
        self.shape = A.shape

    def vcycle(self, b: np.ndarray, i: int = 0) -> np.ndarray:
        """One V-cycle for ``A x = b`` (n,) from ``x = 0``: the preconditioner (symmetric positive
        definite: the same Chebyshev polynomial before and after the coarse correction)."""
        if i == len(self.levels) - 1:
            return self._coarse(b)
        lvl = self.levels[i]
        x = lvl.chebyshev(None, b)
        x += lvl.P @ self.vcycle(lvl.R @ (b - lvl(x)), i + 1)
        return lvl.chebyshev(x, b)

    def solve(self, b: np.ndarray, *, tol: float = 1e-8, maxiter: int = 500,
              x0: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
        """Preconditioned CG from ``x0`` (default 0) until ``||b - A x|| <= tol ||b||``.

        Parameters
        ----------
        b : ndarray, shape (n,)
            Right-hand side (e.g. forces, N).
        x0 : ndarray, shape (n,), optional
            Start (e.g. the previous solution when only ``b`` changed).
        tol : float
            Relative residual to reach.
        maxiter : int
            Largest number of iterations.

        Returns
        -------
        x : ndarray, shape (n,)
            The last iterate (e.g. displacements, m), converged or not.
        info : dict
            ``iterations``, ``residual`` (``||b - A x|| / ||b||`` recomputed from ``x``),
            ``converged``, ``breakdown`` (a non-positive curvature: ``A`` is not positive
            definite) and ``residuals`` (the recurrence's relative residual per iteration).
        """
        from .._jit import blas_single_threaded

        with blas_single_threaded():
            return pcg(self.levels[0], self.vcycle, np.asarray(b, dtype=np.float64), tol=tol, maxiter=maxiter,
                       x0=x0)


def pcg(A, M, b: np.ndarray, *, tol: float, maxiter: int, x0: np.ndarray | None = None) -> tuple[np.ndarray, dict]:
    """Preconditioned conjugate gradients from ``x0`` (default 0); ``A``, ``M``: callables
    ``v -> A v``, ``v -> M^-1 v`` on (n,) vectors, both SPD (see :meth:`StaticAMG.solve`). When the
    recurrence's residual reaches ``tol``, the true residual is recomputed, and CG restarts from
    ``x`` if the two drifted apart (at most twice)."""
    bn = float(np.linalg.norm(b))
    x = np.zeros_like(b) if x0 is None else np.array(x0, dtype=np.float64)
    hist: list[float] = []
    info = {"iterations": 0, "residual": 0.0, "converged": True, "breakdown": False, "residuals": hist}
    if bn == 0.0:
        return np.zeros_like(b), info
    r, it, restarts, broke = (b.copy() if x0 is None else b - A(x)), 0, 0, False
    while float(np.linalg.norm(r)) > tol * bn:
        z = M(r)
        p, rz = z.copy(), float(r @ z)
        while it < maxiter:
            q = A(p)
            pq = float(p @ q)
            broke = not (np.isfinite(pq) and pq > 0.0 and np.isfinite(rz) and rz > 0.0)
            if broke:
                break
            alpha = rz / pq
            x += alpha * p
            r -= alpha * q
            it += 1
            hist.append(float(np.linalg.norm(r)) / bn)
            if hist[-1] <= tol:
                break
            z = M(r)
            rz_new = float(r @ z)
            p *= rz_new / rz
            p += z
            rz = rz_new
        r = b - A(x)
        if it >= maxiter or restarts >= 2 or broke or not np.all(np.isfinite(r)):
            break
        restarts += 1
    res = float(np.linalg.norm(r)) / bn
    info.update(iterations=it, residual=res, converged=bool(res <= tol), breakdown=broke)
    return x, info
