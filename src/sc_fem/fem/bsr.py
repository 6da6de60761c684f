"""Lattice matrices as 3 x 3 node blocks, and their products with a vector or a block of vectors.

A lattice's stiffness and mass (node-major interleaved DOFs, nodes fixed whole) have the same
columns in the 3 rows of a node: as block sparse rows (BSR) they keep one column index per 3 x 3
block instead of one per entry. :func:`node_blocks` converts; :class:`NodeBlockProduct` multiplies,
compiled and split over the cores when numba is installed (the ``fast`` extra), else by scipy's
BSR product (same numbers up to the order of a row's sums). The kernels take any block size (the
multigrid's prolongators have 3 x 6 blocks, its coarse levels 6 x 6), the transpose of a matrix
from its own blocks (the restriction ``P.T``, no second matrix), and float32 as well as float64
(a float32 V-cycle reads half the bytes). The multigrid of :mod:`sc_fem.fem.multigrid` spends most
of its time here.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._jit import choose_kernel, compiled, compiled_parallel, prange
from .nodeblocks import node_blocks  # noqa: F401 - the conversion, importable from here

PARALLEL_NNZ = 4_000_000
"""From this many nonzeros a product runs on every core; below, on one. A parallel product waits
for both threads: on this shared 2-core machine, with another process on the other core, that cost
~8 ms a call whatever the size (0.3 ms for the 578k nonzeros of an 8,820-DOF cantilever on one
core); at 14.6M nonzeros it took 7 ms on 2 quiet cores, 12 ms on one."""

PARALLEL_WORK = 16_000_000
"""A product with a block of vectors runs on every core also below :data:`PARALLEL_NNZ` when its
nonzeros times its columns reach this: a float32 V-cycle's prolongation and restriction at
139,656 DOFs (2.6M nonzeros, 10 columns) took 9.5 ms each on one core, 5 ms on two."""

CHUNKS = 64
"""Row chunks of a parallel product (more than cores, so that a slow core does not hold the rest)."""


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
    for c in prange(CHUNKS):                    # row chunks split over the cores
        _bsr3_rows(indptr, indices, data, x, y, c * n // CHUNKS, (c + 1) * n // CHUNKS)


def _bsr3_block_rows_py(indptr, indices, data, X, Y, lo, hi):  # pragma: no cover - compiled
    k = X.shape[1]
    for i in range(lo, hi):                     # Y = A X on the node rows lo:hi, X (n, k)
        r = 3 * i
        for a in range(3):
            for c in range(k):
                Y[r + a, c] = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = 3 * indices[p]
            for a in range(3):
                d0, d1, d2 = data[p, a, 0], data[p, a, 1], data[p, a, 2]
                for c in range(k):
                    Y[r + a, c] += d0 * X[j, c] + d1 * X[j + 1, c] + d2 * X[j + 2, c]


def _bsr3_block_py(indptr, indices, data, X, Y):  # pragma: no cover - compiled
    n = len(indptr) - 1
    for c in prange(CHUNKS):
        _bsr3_block_rows(indptr, indices, data, X, Y, c * n // CHUNKS, (c + 1) * n // CHUNKS)


def _bsr3_dres_rows_py(indptr, indices, data, dinv, X, B, Y, add, lo, hi):  # pragma: no cover - compiled
    k = X.shape[1]
    have_b = B.shape[0] > 0
    t = np.empty((3, k), dtype=Y.dtype)         # in the vectors' precision (float32 in a float32 V-cycle)
    for i in range(lo, hi):                     # Y = D^-1 (B - A X) on the node rows lo:hi (add: Y +=)
        r = 3 * i
        for a in range(3):
            for c in range(k):
                t[a, c] = B[r + a, c] if have_b else 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = 3 * indices[p]
            for a in range(3):
                d0, d1, d2 = data[p, a, 0], data[p, a, 1], data[p, a, 2]
                for c in range(k):
                    t[a, c] -= d0 * X[j, c] + d1 * X[j + 1, c] + d2 * X[j + 2, c]
        for a in range(3):
            for c in range(k):
                v = dinv[i, a, 0] * t[0, c] + dinv[i, a, 1] * t[1, c] + dinv[i, a, 2] * t[2, c]
                Y[r + a, c] = Y[r + a, c] + v if add else v


def _bsr3_dres_py(indptr, indices, data, dinv, X, B, Y, add):  # pragma: no cover - compiled
    n = len(indptr) - 1
    for c in prange(CHUNKS):
        _bsr3_dres_rows(indptr, indices, data, dinv, X, B, Y, add, c * n // CHUNKS, (c + 1) * n // CHUNKS)


def _bsr_rows_py(indptr, indices, data, X, Y, lo, hi):  # pragma: no cover - compiled
    R, C = data.shape[1], data.shape[2]
    k = X.shape[1]
    for i in range(lo, hi):                     # Y = A X on the block rows lo:hi, any R x C blocks
        r = R * i
        for a in range(R):
            for c in range(k):
                Y[r + a, c] = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = C * indices[p]
            for a in range(R):
                for b in range(C):
                    d = data[p, a, b]
                    for c in range(k):
                        Y[r + a, c] += d * X[j + b, c]


def _bsr_block_py(indptr, indices, data, X, Y):  # pragma: no cover - compiled
    n = len(indptr) - 1
    for c in prange(CHUNKS):
        _bsr_rows(indptr, indices, data, X, Y, c * n // CHUNKS, (c + 1) * n // CHUNKS)


def _bsr_t_rows_py(indptr, indices, data, X, Y, lo, hi):  # pragma: no cover - compiled
    R, C = data.shape[1], data.shape[2]
    k = X.shape[1]
    for i in range(lo, hi):                     # Y += A^T X from the block rows lo:hi of A
        r = R * i
        for p in range(indptr[i], indptr[i + 1]):
            j = C * indices[p]
            for a in range(R):
                for b in range(C):
                    d = data[p, a, b]
                    for c in range(k):
                        Y[j + b, c] += d * X[r + a, c]


def _bsr_t_block_py(indptr, indices, data, X, Ys):  # pragma: no cover - compiled
    n, parts = len(indptr) - 1, Ys.shape[0]
    for t in prange(parts):                     # each part of A's rows adds into its own Ys[t]
        _bsr_t_rows(indptr, indices, data, X, Ys[t], t * n // parts, (t + 1) * n // parts)


def _bsr3_split_rows_py(indptr, indices, hi, hbits, lo, scale, X, Y, lo_row, hi_row):  # pragma: no cover - compiled
    k = X.shape[1]
    for i in range(lo_row, hi_row):             # Y = A X in float64 on the node rows, X (n, k), A = hi + lo
        r = 3 * i
        for a in range(3):
            for c in range(k):
                Y[r + a, c] = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            j = 3 * indices[p]
            for a in range(3):               # each entry rebuilt exactly: hi + lo 2^-31 ulp(hi)
                d0 = np.float64(hi[p, a, 0]) + lo[p, a, 0] * scale[(hbits[p, a, 0] >> 23) & 255]
                d1 = np.float64(hi[p, a, 1]) + lo[p, a, 1] * scale[(hbits[p, a, 1] >> 23) & 255]
                d2 = np.float64(hi[p, a, 2]) + lo[p, a, 2] * scale[(hbits[p, a, 2] >> 23) & 255]
                for c in range(k):
                    Y[r + a, c] += d0 * X[j, c] + d1 * X[j + 1, c] + d2 * X[j + 2, c]


def _bsr3_split_py(indptr, indices, hi, hbits, lo, scale, X, Y):  # pragma: no cover - compiled
    n = len(indptr) - 1
    for c in prange(CHUNKS):
        _bsr3_split_rows(indptr, indices, hi, hbits, lo, scale, X, Y, c * n // CHUNKS, (c + 1) * n // CHUNKS)


# separate functions, not one compiled twice: numba's disk cache keys a function by name and line, and a
# serial and a parallel build of one function overwrote each other
_bsr3_rows = compiled(_bsr3_rows_py)
_bsr3_mv = compiled_parallel(_bsr3_mv_py)
_bsr3_block_rows = compiled(_bsr3_block_rows_py)
_bsr3_block = compiled_parallel(_bsr3_block_py)
_bsr3_dres_rows = compiled(_bsr3_dres_rows_py)
_bsr3_dres = compiled_parallel(_bsr3_dres_py)
_bsr_rows = compiled(_bsr_rows_py)
_bsr_block = compiled_parallel(_bsr_block_py)
_bsr_t_rows = compiled(_bsr_t_rows_py)
_bsr_t_block = compiled_parallel(_bsr_t_block_py)
_bsr3_split_rows = compiled(_bsr3_split_rows_py)
_bsr3_split = compiled_parallel(_bsr3_split_py)


def _split_values_py(data, hi, hbits, lo, scale):  # pragma: no cover - compiled
    for i in prange(len(data)):              # hi: data rounded to float32; lo: the rest in 2^-31 ulp(hi)
        h = np.float32(data[i])
        hi[i] = h
        lo[i] = np.int32(round((data[i] - np.float64(h)) / scale[(hbits[i] >> 23) & 255]))


_split_values = compiled_parallel(_split_values_py)

T_PARTS = 4
"""Row parts of a parallel transposed product, each adding into its own copy of the (short) result."""


SPLIT_CHUNK = 1 << 20
"""Blocks per chunk while :class:`SplitNodeBlocks` splits a matrix without numba (bounded temporaries)."""

LO_SCALE = np.ldexp(1.0, np.maximum(np.arange(256), 1) - 181)
"""Unit of :class:`SplitNodeBlocks`' ``lo`` by the float32 exponent field ``E`` of ``hi``: ``2^-31`` of
``hi``'s last place, ``2^(E - 150 - 31)`` (subnormal ``hi``: ``E = 1``)."""


class SplitNodeBlocks:
    """A float64 matrix of 3 x 3 node blocks stored in two 4-byte parts, exactly: ``hi``, ``A`` rounded
    to float32 (the float32 V-cycle's smoother reads it alone, :meth:`high`), and ``lo``, the rounding
    error as an int32 count of ``2^-31`` of ``hi``'s last place (:data:`LO_SCALE`). The error is at
    most half a last place and a multiple of ``A``'s own last place, so ``lo`` holds it exactly and
    ``hi + lo * LO_SCALE[E]`` is ``A``'s entry bit for bit (for ``|A| >= 2^-126``; smaller entries to
    ``2^-181``). Both take the bytes of one float64 copy: a float32 V-cycle keeps its finest matrix
    once instead of in float64 and float32 both (:meth:`sc_fem.fem.multigrid._Level.lower`), and its
    products (:class:`NodeBlockProduct`, compiled) are the float64 ones, bit for bit.

    Parameters
    ----------
    A : scipy.sparse.bsr_matrix, shape (n, n)
        Float64, 3 x 3 blocks, entries below float32's overflow; its index arrays are shared.

    Attributes
    ----------
    hi : ndarray of float32, shape (nnzb, 3, 3)
        ``A`` rounded, in ``A``'s units.
    lo : ndarray of int32, shape (nnzb, 3, 3)
        The rest, in units of ``LO_SCALE[E]`` (``E`` the exponent field of ``hi``).
    indptr, indices : ndarray of int
        ``A``'s block pattern.
    shape : tuple
        ``(n, n)``.

    Raises
    ------
    ValueError
        An entry is not finite or beyond float32's range.
    """

    dtype = np.dtype(np.float64)
    blocksize = (3, 3)
    format = "split"

    def __init__(self, A: sp.bsr_matrix) -> None:
        data = A.data
        self.indptr, self.indices, self.shape = A.indptr, A.indices, A.shape
        self.hi, self.lo = np.empty(data.shape, np.float32), np.empty(data.shape, np.int32)
        if _split_values is not None and data.flags.c_contiguous:      # one pass on every core
            _split_values(data.reshape(-1), self.hi.reshape(-1), self.hi.view(np.int32).reshape(-1),
                          self.lo.reshape(-1), LO_SCALE)
        else:
            with np.errstate(over="ignore", invalid="ignore"):     # an overflow is refused below
                for s in range(0, len(data), SPLIT_CHUNK):  # loop over chunks of blocks: bounded temporaries
                    e = s + SPLIT_CHUNK
                    self.hi[s:e] = data[s:e]
                    self.lo[s:e] = np.rint((data[s:e] - self.hi[s:e]) / self._unit(s, e))
        if len(data) and not (np.isfinite(self.hi.max()) and np.isfinite(self.hi.min())):
            raise ValueError("a matrix entry is not finite or beyond float32's range: not split")

    def _unit(self, s: int, e: int) -> np.ndarray:
        """``lo``'s unit for blocks ``s:e`` (float64, their shape)."""
        return LO_SCALE[(self.hi[s:e].view(np.int32) >> 23) & 255]

    @property
    def nnz(self) -> int:
        """Stored entries (9 per block)."""
        return self.hi.size

    def high(self) -> sp.bsr_matrix:
        """``hi`` as a float32 BSR matrix (the arrays shared, no copy)."""
        return sp.bsr_matrix((self.hi, self.indices, self.indptr), shape=self.shape)

    def tobsr(self) -> sp.bsr_matrix:
        """``A`` as a new float64 BSR matrix."""
        data = self.hi.astype(np.float64)
        for s in range(0, len(data), SPLIT_CHUNK):        # loop over chunks of blocks
            e = s + SPLIT_CHUNK
            data[s:e] += self.lo[s:e] * self._unit(s, e)
        return sp.bsr_matrix((data, self.indices.copy(), self.indptr.copy()), shape=self.shape)

    def tocsr(self) -> sp.csr_matrix:
        """``A`` as a new float64 CSR matrix."""
        return self.tobsr().tocsr()

    def __matmul__(self, x: np.ndarray) -> np.ndarray:
        return NodeBlockProduct(self, "numba")(x)


class NodeBlockProduct:
    """``x -> A @ x`` (or ``A.T @ x``) for a BSR matrix ``A`` and ``x`` of shape (m,) or (m, k), in
    ``A``'s precision.

    Parameters
    ----------
    A : scipy.sparse.bsr_matrix, shape (n, m)
        The matrix, float64 or float32 (a float32 V-cycle's), any block size: the 3 x 3 node blocks
        of a lattice matrix, a prolongator's 3 x 6 or a coarse level's 6 x 6.
    kernel : {"numba", "numpy"}
        ``"numba"``: compiled (on every core from :data:`PARALLEL_NNZ` nonzeros, or
        :data:`PARALLEL_WORK` nonzeros times columns); ``"numpy"``: scipy's product (one thread).
    transpose : bool
        The product with ``A.T`` (shape (m, n); a restriction from its prolongator, no second
        matrix); compiled only: ``"numpy"`` takes scipy's product with ``A.T`` stored once.
    """

    def __init__(self, A: sp.bsr_matrix, kernel: str, transpose: bool = False) -> None:
        self.fast = choose_kernel(kernel) == "numba"
        self.split = isinstance(A, SplitNodeBlocks)
        if self.split and (transpose or not self.fast):
            raise ValueError("a SplitNodeBlocks product is compiled and not transposed")
        self.transpose = bool(transpose) and self.fast
        self.A = sp.bsr_matrix(A.T) if transpose and not self.fast else A
        self.dtype = A.dtype
        self.shape = A.shape[::-1] if transpose else A.shape
        self.node = A.blocksize == (3, 3) and A.shape[0] == A.shape[1] and not self.transpose and not self.split
        self.parallel = A.nnz >= PARALLEL_NNZ

    def _parallel(self, x: np.ndarray) -> bool:
        """Whether a product with ``x`` (n,) or (n, k) runs on every core: :data:`PARALLEL_NNZ`
        nonzeros, or :data:`PARALLEL_WORK` nonzeros times columns."""
        return self.parallel or (x.ndim == 2 and self.A.nnz * x.shape[1] >= PARALLEL_WORK)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        A = self.A
        if not self.fast:
            return A @ np.asarray(x, dtype=self.dtype)
        x = np.ascontiguousarray(x, dtype=self.dtype)
        n = len(A.indptr) - 1
        parallel = self._parallel(x)
        if self.split:                         # A X in float64 from hi and lo, a vector as a one-column block
            y = np.empty((A.shape[0],) + x.shape[1:])
            X, Y = x.reshape(x.shape[0], -1), y.reshape(y.shape[0], -1)
            args = (A.indptr, A.indices, A.hi, A.hi.view(np.int32), A.lo, LO_SCALE, X, Y)
            if parallel:
                _bsr3_split(*args)
            else:
                _bsr3_split_rows(*args, 0, n)
            return y
        if self.transpose:                     # Y = A^T X: each part of the rows adds into its own Y
            X = x.reshape(x.shape[0], -1)
            Ys = np.zeros((T_PARTS if parallel else 1, self.shape[0], X.shape[1]), dtype=self.dtype)
            if parallel:
                _bsr_t_block(A.indptr, A.indices, A.data, X, Ys)
            else:
                _bsr_t_rows(A.indptr, A.indices, A.data, X, Ys[0], 0, n)
            return Ys.sum(axis=0).reshape((self.shape[0],) + x.shape[1:])
        y = np.empty((A.shape[0],) + x.shape[1:], dtype=self.dtype)
        if not self.node:                      # any blocks, a vector as a one-column block
            X, Y = x.reshape(x.shape[0], -1), y.reshape(y.shape[0], -1)
            if parallel:
                _bsr_block(A.indptr, A.indices, A.data, X, Y)
            else:
                _bsr_rows(A.indptr, A.indices, A.data, X, Y, 0, n)
        elif x.ndim == 1:
            if self.parallel:
                _bsr3_mv(A.indptr, A.indices, A.data, x, y)
            else:
                _bsr3_rows(A.indptr, A.indices, A.data, x, y, 0, n)
        elif parallel:
            _bsr3_block(A.indptr, A.indices, A.data, x, y)
        else:
            _bsr3_block_rows(A.indptr, A.indices, A.data, x, y, 0, n)
        return y

    def scaled_residual(self, dinv: np.ndarray, x: np.ndarray, b: np.ndarray | None,
                        add_to: np.ndarray | None = None) -> np.ndarray:
        """``D^-1 (b - A x)`` in one pass over ``A`` (``b`` None: ``-D^-1 A x``).

        Parameters
        ----------
        dinv : ndarray, shape (n // bs, bs, bs)
            The inverse diagonal blocks.
        x, b : ndarray, shape (n,) or (n, k)
            In ``A``'s precision (compiled for 3 x 3 blocks).
        add_to : ndarray, shape of ``x``, optional
            C-ordered, ``A``'s precision: the result is added to it (no new array; a V-cycle's
            Chebyshev residual update) and it is returned.

        Returns
        -------
        ndarray, shape of ``x``
        """
        A = self.A
        if not (self.fast and self.node) or (add_to is not None and not add_to.flags.c_contiguous):
            ax = self(x)
            y = block_diagonal_product(dinv, np.negative(ax, out=ax) if b is None else b - ax)
            return y if add_to is None else np.add(add_to, y, out=add_to)
        shape, dt = x.shape, self.dtype
        X = np.ascontiguousarray(x, dtype=dt).reshape(shape[0], -1)
        Bm = np.empty((0, X.shape[1]), dt) if b is None else np.ascontiguousarray(b, dtype=dt).reshape(X.shape)
        Y = np.empty_like(X) if add_to is None else add_to.reshape(X.shape)
        if self._parallel(X):
            _bsr3_dres(A.indptr, A.indices, A.data, dinv, X, Bm, Y, add_to is not None)
        else:
            _bsr3_dres_rows(A.indptr, A.indices, A.data, dinv, X, Bm, Y, add_to is not None, 0, len(A.indptr) - 1)
        return Y.reshape(shape) if add_to is None else add_to


def _chebyshev_step_py(d, r, x, a, c):  # pragma: no cover - compiled
    for i in prange(d.shape[0]):             # d <- a d + c r, then x <- x + d: one pass over the rows
        for j in range(d.shape[1]):
            v = d[i, j] * a + c * r[i, j]
            d[i, j] = v
            x[i, j] += v


_chebyshev_step = compiled_parallel(_chebyshev_step_py)

CHEBYSHEV_STEP_MIN = 1 << 13
"""Fewest entries of ``d`` for which :func:`chebyshev_step` runs compiled. Measured on float32
blocks of 8 columns (median of 200 calls): 1,024 entries 3.1 us compiled against 2.4 us for numpy's
passes, 8,192 entries 3.7 us against 4.9 us, 32,768 6.6 us against 16.4 us."""


def chebyshev_step(d: np.ndarray, r: np.ndarray, x: np.ndarray, a: float, c: float) -> None:
    """The Chebyshev smoother's update in place: ``d <- a d + c r``, then ``x <- x + d``, in ``d``'s
    precision (``a`` and ``c`` rounded to it first, as numpy rounds a Python scalar).

    Parameters
    ----------
    d, r, x : ndarray, shape (n, k) or (n,)
        The step (updated), the scaled residual and the iterate (updated), one dtype.
    a, c : float
        The step's coefficients.

    Notes
    -----
    Compiled (numba): one pass over the rows for 2-D C-ordered arrays of at least
    :data:`CHEBYSHEV_STEP_MIN` entries; otherwise numpy's three passes and a temporary. The same
    values bit for bit (no fused multiply-add).
    """
    a, c = d.dtype.type(a), d.dtype.type(c)
    if (_chebyshev_step is not None and d.ndim == 2 and d.size >= CHEBYSHEV_STEP_MIN
            and d.shape == r.shape == x.shape and d.dtype == r.dtype == x.dtype
            and d.flags.c_contiguous and r.flags.c_contiguous and x.flags.c_contiguous):
        _chebyshev_step(d, r, x, a, c)
        return
    d *= a
    d += c * r
    x += d


def block_diagonal_product(blocks: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``diag(blocks) @ x`` for ``blocks`` (m, b, b) and ``x`` (m b,) or (m b, k)."""
    m, bs = blocks.shape[:2]
    return np.matmul(blocks, x.reshape(m, bs, -1)).reshape(x.shape)
