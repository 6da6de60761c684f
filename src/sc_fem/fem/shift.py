"""The shifted pair ``K - sigma M`` of the eigensolvers, and the memory it takes.

Both eigensolvers work with ``A = K - sigma M`` for a small negative shift ``sigma``
(:data:`SHIFT_FRACTION`): shift-invert factorizes it, LOBPCG solves ``A phi = (lambda - sigma) M
phi`` preconditioned by a multigrid of ``A``. The assembler's ``K`` and consistent ``M`` share one
sparsity pattern (3 x 3 node blocks, so ``M``, diagonal in the components, stores two zeros of
every three entries), and on a million cubes each takes ~3 GB. So that a solver which owns them
need not hold ``K``, ``M`` and ``A`` at once, :func:`shift_in_place` turns ``K`` into ``A``,
:func:`without_zeros` keeps ``M``'s nonzeros alone (:class:`ComponentMass` its one scalar
matrix of node pairs, when it is the same on the three components), and :class:`ShiftedStiffness`
gives the products with ``K`` back as ``A x + sigma M x``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.linalg.blas import daxpy
from scipy.sparse.linalg import LinearOperator

from .._jit import compiled_parallel, prange
from ..errors import SolverError
from .spmm import BlockProduct

SHIFT_FRACTION = 1e-7
"""The shift is ``-SHIFT_FRACTION * mean(diag K) / mean(diag M)``: far below every elastic
eigenvalue of a voxel model (so convergence is not slowed) yet large enough that
``K - sigma M`` stays well conditioned (condition number about ``1 / SHIFT_FRACTION``)."""


def lambda_scale(K: sp.spmatrix, M: sp.spmatrix) -> float:
    """``mean(diag K) / mean(diag M)`` in 1/s^2: the order of the largest eigenvalues."""
    dk, dm = np.asarray(K.diagonal()), np.asarray(M.diagonal())
    s = float(dk.mean() / dm.mean()) if len(dk) else 0.0
    if not np.isfinite(s) or s <= 0:
        raise SolverError("K and M must have positive diagonals (is the mass zero somewhere?)")
    return s


def _same_pattern(K: sp.csr_matrix, M: sp.csr_matrix) -> bool:
    return (K.nnz == M.nnz and K.has_sorted_indices and M.has_sorted_indices
            and (K.indptr is M.indptr or np.array_equal(K.indptr, M.indptr))
            and (K.indices is M.indices or np.array_equal(K.indices, M.indices)))


_ROW_CHUNK = 1 << 15
"""Rows per chunk while ``M``'s entries are found in ``K``'s pattern (bounded temporaries)."""


def _subset_rows_py(kptr, kidx, mptr, midx, bad):  # pragma: no cover - compiled
    for r in prange(len(kptr) - 1):          # is every column of M's row r among K's (both sorted)?
        p, e = kptr[r], kptr[r + 1]
        for q in range(mptr[r], mptr[r + 1]):
            while p < e and kidx[p] < midx[q]:
                p += 1
            if p == e or kidx[p] != midx[q]:
                bad[r] = True
                break


def _subtract_rows_py(kptr, kidx, data, mptr, midx, mdata, sigma):  # pragma: no cover - compiled
    for r in prange(len(kptr) - 1):          # data -= sigma M on K's pattern (M's columns among K's)
        p = kptr[r]
        for q in range(mptr[r], mptr[r + 1]):
            while kidx[p] < midx[q]:
                p += 1
            data[p] -= sigma * mdata[q]


_subset_rows = compiled_parallel(_subset_rows_py)
_subtract_rows = compiled_parallel(_subtract_rows_py)


def _subtract_subset(K: sp.csr_matrix, M: sp.csr_matrix, sigma: float, data: np.ndarray) -> bool:
    """``data -= sigma M`` on ``K``'s pattern (``data``: values on it, e.g. ``K.data``) when every
    stored entry of ``M`` is one of ``K``'s (both sorted, e.g. a compact mass,
    :mod:`sc_fem.fem.nodemass`); False, ``data`` untouched, otherwise. Compiled: a merge of each row's
    columns (checked first, then subtracted); numpy: row chunk by row chunk, a search on the chunk's
    (row, column) keys."""
    if not (K.has_sorted_indices and M.has_sorted_indices) or K.shape != M.shape:
        return False
    if _subset_rows is not None:                         # compiled: a merge of each row, on every core
        bad = np.zeros(K.shape[0], dtype=np.bool_)
        _subset_rows(K.indptr, K.indices, M.indptr, M.indices, bad)
        if bad.any():
            return False
        _subtract_rows(K.indptr, K.indices, data, M.indptr, M.indices, M.data, float(sigma))
        return True
    n, cols = K.shape[0], max(K.shape[1], 1)
    found = []
    for r0 in range(0, n, _ROW_CHUNK):                  # loop over chunks of rows: find every position first
        r1 = min(r0 + _ROW_CHUNK, n)
        k0, k1, m0, m1 = K.indptr[r0], K.indptr[r1], M.indptr[r0], M.indptr[r1]
        kkey = np.repeat(np.arange(r1 - r0, dtype=np.int64) * cols, np.diff(K.indptr[r0:r1 + 1])) + K.indices[k0:k1]
        mkey = np.repeat(np.arange(r1 - r0, dtype=np.int64) * cols, np.diff(M.indptr[r0:r1 + 1])) + M.indices[m0:m1]
        pos = np.searchsorted(kkey, mkey)
        if np.any(pos >= len(kkey)) or not np.array_equal(kkey[np.minimum(pos, len(kkey) - 1)], mkey):
            return False
        found.append(pos.astype(np.int32 if k1 - k0 < 2**31 else np.int64))
    for r0, pos in zip(range(0, n, _ROW_CHUNK), found):   # then subtract (nothing changed on a failure)
        r1 = min(r0 + _ROW_CHUNK, n)
        seg = data[K.indptr[r0]:K.indptr[r1]]
        seg[pos] -= sigma * M.data[M.indptr[r0]:M.indptr[r1]]
    return True


def shifted(K: sp.spmatrix, M: sp.spmatrix, sigma: float) -> sp.csr_matrix:
    """``K - sigma M`` as CSR; when both share one sparsity pattern (the assembler's consistent
    ``M`` shares ``K``'s), one operation on the values instead of a sparse merge (4.7 s at
    931,896 DOFs).

    Parameters
    ----------
    K, M : scipy.sparse matrix, shape (n, n)
        Stiffness (N/m) and mass (kg).
    sigma : float
        The shift, 1/s^2.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n, n)
        A new matrix (sharing ``K``'s index arrays when the patterns are one).
    """
    K, M = sp.csr_matrix(K), sp.csr_matrix(M)
    data = np.array(K.data, dtype=np.float64)                  # one new array of the values' size
    if _same_pattern(K, M):
        data = daxpy(M.data, data, a=-sigma)                   # in place (float64, contiguous)
        return sp.csr_matrix((data, K.indices, K.indptr), shape=K.shape)
    if _subtract_subset(K, M, sigma, data):                    # M's entries among K's: K's pattern
        return sp.csr_matrix((data, K.indices, K.indptr), shape=K.shape)
    return (K - sigma * M).tocsr()


def shift_in_place(K: sp.csr_matrix, M: sp.csr_matrix, sigma: float) -> sp.csr_matrix:
    """:func:`shifted`, written over ``K``'s values when ``K`` is a float64 CSR matrix with ``M``'s
    pattern or one that holds it (a compact mass, :mod:`sc_fem.fem.nodemass`; no second matrix of
    ``K``'s size); otherwise a new matrix, ``K`` untouched.

    Parameters
    ----------
    K : scipy.sparse.csr_matrix, shape (n, n)
        Stiffness, N/m: overwritten (it is ``K - sigma M`` afterwards).
    M : scipy.sparse.csr_matrix, shape (n, n)
        Mass, kg.
    sigma : float
        The shift, 1/s^2.

    Returns
    -------
    scipy.sparse.csr_matrix
        ``K - sigma M`` (``K`` itself when written in place).
    """
    if not (sp.isspmatrix_csr(K) and sp.isspmatrix_csr(M) and K.dtype == np.float64 and M.dtype == np.float64):
        return shifted(K, M, sigma)
    if _same_pattern(K, M):
        daxpy(M.data, K.data, a=-sigma)      # in place: no temporary of the values' size
        return K
    return K if _subtract_subset(K, M, sigma, K.data) else shifted(K, M, sigma)


def without_zeros(M: sp.csr_matrix) -> sp.csr_matrix:
    """A copy of ``M`` without its stored zeros (temporaries: 5 bytes per stored entry, not a copy of
    ``M``), or ``M`` itself (as CSR) when it stores none.

    Parameters
    ----------
    M : scipy.sparse matrix, shape (n, m)

    Returns
    -------
    scipy.sparse.csr_matrix
        The same matrix; a third of the entries for a consistent lattice mass on ``K``'s pattern.
    """
    M = sp.csr_matrix(M)
    if M.data.all():
        return M
    keep = M.data != 0
    upto = np.cumsum(keep, dtype=np.int32 if M.nnz < 2**31 else np.int64)   # entries kept up to each
    indptr = np.where(M.indptr > 0, upto[np.maximum(M.indptr - 1, 0)] if M.nnz else 0, 0)
    return sp.csr_matrix((M.data[keep], M.indices[keep], indptr.astype(M.indptr.dtype)), shape=M.shape)


class ShiftedStiffness(LinearOperator):
    """``K`` given back as ``x -> A x + sigma M x`` from the products with ``A = K - sigma M`` and ``M``.

    Parameters
    ----------
    A, M : callable
        ``X -> A @ X`` and ``X -> M @ X`` for ``X`` of shape (n,) or (n, k) (e.g.
        :class:`~sc_fem.fem.bsr.NodeBlockProduct`, :class:`~sc_fem.fem.spmm.BlockProduct`).
    sigma : float
        The shift, 1/s^2.
    matrix : scipy.sparse matrix or SplitNodeBlocks, shape (n, n)
        ``A`` itself (CSR, node-block BSR or :class:`~sc_fem.fem.bsr.SplitNodeBlocks`), kept for
        :meth:`shifted_matrix`.

    Attributes
    ----------
    sigma : float
    """

    def __init__(self, A, M, sigma: float, matrix: sp.spmatrix) -> None:
        super().__init__(np.float64, matrix.shape)
        self._A, self._M, self.sigma, self._matrix = A, M, float(sigma), matrix

    def shifted_matrix(self) -> sp.csr_matrix:
        """``A = K - sigma M`` as CSR (the matrix itself when it is CSR)."""
        return sp.csr_matrix(self._matrix if sp.issparse(self._matrix) else self._matrix.tocsr())

    def _matmat(self, X: np.ndarray) -> np.ndarray:
        Y, MX = self._A(X), self._M(X)            # two blocks of X's size, no third
        MX *= self.sigma
        Y += MX
        return Y

    def _matvec(self, x: np.ndarray) -> np.ndarray:
        return self._matmat(np.asarray(x).reshape(-1, 1)).ravel()


def _node_counts_py(indptr, indices, data, cnt, bad):  # pragma: no cover - compiled
    for i in prange(len(cnt)):               # node i: are DOF rows 3i+a row 3i's nonzeros, shifted by a?
        r, c = 3 * i, 0
        for p in range(indptr[r], indptr[r + 1]):
            if data[p] != 0.0:
                bad[i] |= indices[p] % 3 != 0
                c += 1
        cnt[i] = c
        for a in range(1, 3):
            q = indptr[r]
            for p in range(indptr[r + a], indptr[r + a + 1]):
                if data[p] != 0.0:
                    while q < indptr[r + 1] and data[q] == 0.0:
                        q += 1
                    if q == indptr[r + 1] or indices[p] != indices[q] + a or data[p] != data[q]:
                        bad[i] = True
                        q = indptr[r + 1] - 1
                    q += 1
            for p in range(q, indptr[r + 1]):    # none of row 3i's nonzeros left over
                bad[i] |= data[p] != 0.0


def _node_fill_py(indptr, indices, data, mptr, mind, mdat):  # pragma: no cover - compiled
    for i in prange(len(mptr) - 1):          # node row i: row 3i's nonzeros, columns over 3
        o = mptr[i]
        for p in range(indptr[3 * i], indptr[3 * i + 1]):
            if data[p] != 0.0:
                mind[o], mdat[o] = indices[p] // 3, data[p]
                o += 1


_node_counts = compiled_parallel(_node_counts_py)
_node_fill = compiled_parallel(_node_fill_py)


class ComponentMass:
    """``X -> M X`` for a mass matrix ``M = m (x) I_3``: one scalar matrix ``m`` of node pairs on
    each of the 3 components of the node-major DOFs (the lattice's consistent and lumped masses
    with whole nodes fixed); a ninth of ``M``'s stored entries, the same products.

    Parameters
    ----------
    m : scipy.sparse.csr_matrix, shape (n / 3, n / 3)
        The node matrix, kg.

    Attributes
    ----------
    m : scipy.sparse.csr_matrix
        The node matrix.
    shape : tuple
        ``(n, n)``.
    """

    def __init__(self, m: sp.csr_matrix) -> None:
        self.m = m
        self._product = BlockProduct(m)
        self.shape = (3 * m.shape[0], 3 * m.shape[1])

    @classmethod
    def of(cls, M: sp.spmatrix) -> ComponentMass | None:
        """The :class:`ComponentMass` equal to ``M`` (compared entry by entry), or None when ``M`` is not
        ``m (x) I_3`` on node-major DOFs. Compiled: two passes over ``M``'s rows, no copy of ``M``
        (a million cubes: ~1 s); numpy: ``M``'s nonzeros copied, then compared node row by node row."""
        M = sp.csr_matrix(M)
        n = M.shape[0]
        if n % 3 or M.shape[1] != n:
            return None
        if _node_counts is not None:
            M = M if M.has_sorted_indices else M.sorted_indices()
            cnt, bad = np.zeros(n // 3, dtype=np.int64), np.zeros(n // 3, dtype=np.bool_)
            _node_counts(M.indptr, M.indices, M.data, cnt, bad)
            if bad.any():
                return None
            indptr = np.zeros(n // 3 + 1, dtype=M.indptr.dtype)
            np.cumsum(cnt, out=indptr[1:])
            data, indices = np.empty(int(indptr[-1])), np.empty(int(indptr[-1]), dtype=M.indices.dtype)
            _node_fill(M.indptr, M.indices, M.data, indptr, indices, data)
            return cls(sp.csr_matrix((data, indices, indptr), shape=(n // 3, n // 3)))
        M = without_zeros(M)
        M.sort_indices()
        cnt = np.diff(M.indptr)
        if not (np.array_equal(cnt[0::3], cnt[1::3]) and np.array_equal(cnt[0::3], cnt[2::3])):
            return None
        c0 = cnt[0::3]
        indptr = np.zeros(n // 3 + 1, dtype=M.indptr.dtype)
        np.cumsum(c0, out=indptr[1:])
        data, indices = np.empty(int(indptr[-1])), np.empty(int(indptr[-1]), dtype=M.indices.dtype)
        for r0 in range(0, n // 3, _ROW_CHUNK):            # loop over chunks of node rows (bounded temporaries)
            r1 = min(r0 + _ROW_CHUNK, n // 3)
            c = c0[r0:r1]
            within = np.arange(int(indptr[r1] - indptr[r0])) - np.repeat(indptr[r0:r1] - indptr[r0], c)
            p0 = np.repeat(M.indptr[3 * r0:3 * r1:3], c) + within             # row 3i's entries
            col = M.indices[p0]
            if np.any(col % 3):
                return None
            for a in (1, 2):                     # the component's rows are row 3i's, shifted by a
                pa = np.repeat(M.indptr[3 * r0 + a:3 * r1 + a:3], c) + within
                if not (np.array_equal(M.indices[pa], col + a) and np.array_equal(M.data[pa], M.data[p0])):
                    return None
            data[indptr[r0]:indptr[r1]] = M.data[p0]
            indices[indptr[r0]:indptr[r1]] = col // 3
        return cls(sp.csr_matrix((data, indices, indptr), shape=(n // 3, n // 3)))

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """``M @ X`` for ``X`` of shape (n,) or (n, k)."""
        X = np.ascontiguousarray(X, dtype=np.float64)
        k = 1 if X.ndim == 1 else X.shape[1]
        return self._product(X.reshape(self.m.shape[0], 3 * k)).reshape(X.shape)

    def __matmul__(self, X: np.ndarray) -> np.ndarray:
        return self(X)

    matvec = matmat = __call__                   # scipy's aslinearoperator (eigsh's M) reads these
    dtype = np.dtype(np.float64)

    def diagonal(self) -> np.ndarray:
        """``diag(M)``, shape (n,)."""
        return np.repeat(self.m.diagonal(), 3)

    def operator(self) -> LinearOperator:
        """The product as a :class:`scipy.sparse.linalg.LinearOperator`."""
        return LinearOperator(self.shape, matvec=self, matmat=self, dtype=np.float64)
