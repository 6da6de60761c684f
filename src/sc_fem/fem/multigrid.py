"""The algebraic multigrid preconditioner of the LOBPCG eigensolver (:mod:`sc_fem.fem.eigen`):
pyamg's smoothed-aggregation hierarchy of ``K - sigma M``, seeded for reproducibility, and its
V-cycle applied to a block of vectors at once (:class:`BlockVCycle`)."""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
from scipy.sparse.linalg import LinearOperator

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
