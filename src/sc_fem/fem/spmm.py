"""A sparse matrix times a block of vectors, on every core: the product LOBPCG and its AMG V-cycle
spend most of their time in.

scipy's CSR product runs on one thread: 41 ms for 10 vectors at 158,976 DOFs (12M nonzeros), about
six of them per LOBPCG iteration. With numba installed (the optional extra ``sc_fem[fast]``) a
compiled kernel splits the rows over the cores (26 ms on this 2-core machine; the product is
memory-bound, so it does not scale with the cores). Without numba, or for small matrices where
threads cost more than they save, scipy's product runs; both give the same numbers (each row is
summed in the same order).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import LinearOperator

from .._jit import choose_kernel, compiled_parallel, prange

MIN_NNZ = 500_000
"""Below this many nonzeros ``kernel="auto"`` keeps scipy's product (a matrix this small is a few
milliseconds' work, where starting the threads is not repaid)."""


def _csr_block_py(indptr, indices, data, X, Y, B, wd, sweep):  # pragma: no cover - compiled
    n, k = Y.shape
    for i in prange(n):                       # rows split over the cores
        for c in range(k):
            Y[i, c] = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j, a = indices[p], data[p]
            for c in range(k):
                Y[i, c] += a * X[j, c]
        if sweep:                             # a Jacobi sweep: Y = X + wd (B - A X), in the same pass
            for c in range(k):
                Y[i, c] = X[i, c] + wd[i] * (B[i, c] - Y[i, c])


_csr_block = compiled_parallel(_csr_block_py)


class BlockProduct:
    """``X -> A @ X`` for a sparse ``A`` (n, m) and ``X`` (m,) or (m, k), compiled and parallel
    when numba is installed.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, m)
        Converted to CSR once (float64).
    kernel : {"auto", "numba", "numpy"}
        ``"numba"``: the compiled row-parallel kernel (needs numba); ``"numpy"``: scipy's product;
        ``"auto"``: compiled when numba is installed and ``A`` has at least :data:`MIN_NNZ`
        nonzeros.

    Attributes
    ----------
    kernel : str
        ``"numba"`` or ``"numpy"``: which product runs.
    """

    def __init__(self, A, kernel: str = "auto") -> None:
        self.A = sp.csr_matrix(A, dtype=np.float64)
        big = self.A.nnz >= MIN_NNZ
        self.kernel = choose_kernel(kernel, applicable=big or kernel == "numba")
        self.shape = self.A.shape

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """``A @ X`` as a C-ordered array, shape (n,) or (n, k)."""
        X = np.asarray(X, dtype=np.float64)
        if self.kernel != "numba" or X.ndim != 2:
            return np.asarray(self.A @ X)
        Y = np.empty((self.shape[0], X.shape[1]))
        _csr_block(self.A.indptr, self.A.indices, self.A.data, np.ascontiguousarray(X), Y,
                   np.empty((0, 0)), np.empty(0), False)
        return Y

    def jacobi(self, X: np.ndarray, B: np.ndarray, wd: np.ndarray) -> np.ndarray:
        """One damped Jacobi sweep ``X + wd (B - A X)`` for a square ``A``, with ``X`` and ``B`` of
        shape (n, k) and the row weights ``wd`` (n,) (the damping over the diagonal); compiled, the
        product and the update are one pass over the rows (no temporaries)."""
        if self.kernel != "numba":
            return X + wd[:, None] * (B - self.A @ X)
        Y = np.empty((self.shape[0], X.shape[1]))
        _csr_block(self.A.indptr, self.A.indices, self.A.data, np.ascontiguousarray(X, dtype=np.float64), Y,
                   np.ascontiguousarray(B, dtype=np.float64), np.ascontiguousarray(wd, dtype=np.float64), True)
        return Y

    def operator(self) -> LinearOperator:
        """The product as a :class:`scipy.sparse.linalg.LinearOperator` (``matvec`` and ``matmat``)."""
        return LinearOperator(self.shape, matvec=self, matmat=self, dtype=np.float64)
