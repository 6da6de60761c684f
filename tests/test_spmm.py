"""The row-parallel block product (``sc_fem.fem.spmm``) against a loop oracle and scipy, and the
eigensolver's use of it (same V-cycle, same eigenpairs, BLAS on one thread meanwhile)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from sc_fem import _jit
from sc_fem.errors import InputError
from sc_fem.fem import spmm
from sc_fem.fem.assemble import Assembler
from sc_fem.fem.eigen import solve_eigen
from sc_fem.fem.multigrid import LatticeAMG
from sc_fem.fem.rigid import rigid_body_modes
from sc_fem.fem.spmm import BlockProduct
from sc_fem.lattice.cubes import CubeModel

needs_numba = pytest.mark.skipif(not _jit.available(), reason="numba not installed (the optional 'fast' extra)")


def loop_oracle(A: sp.csr_matrix, X: np.ndarray) -> np.ndarray:
    """``A @ X`` entry by entry from the CSR arrays (rows, then stored entries, then columns)."""
    Y = np.zeros((A.shape[0], X.shape[1]))
    for i in range(A.shape[0]):
        for p in range(A.indptr[i], A.indptr[i + 1]):
            for c in range(X.shape[1]):
                Y[i, c] += A.data[p] * X[A.indices[p], c]
    return Y


def _matrices():
    rng = np.random.default_rng(7)
    square = sp.random(60, 60, density=0.15, random_state=rng, format="csr")
    wide = sp.random(25, 70, density=0.2, random_state=rng, format="csr")     # a restriction's shape
    empty_rows = sp.csr_matrix((np.array([2.0, -1.0]), np.array([3, 0]), np.array([0, 0, 1, 1, 2, 2])),
                               shape=(5, 4))                                   # rows with no entry
    unsorted = square.copy()
    for i in range(unsorted.shape[0]):                                           # column order reversed
        s = slice(unsorted.indptr[i], unsorted.indptr[i + 1])
        unsorted.indices[s], unsorted.data[s] = unsorted.indices[s][::-1].copy(), unsorted.data[s][::-1].copy()
    unsorted.has_sorted_indices = False
    return {"square": square, "wide": wide, "empty rows": empty_rows, "unsorted": unsorted}


@needs_numba
@pytest.mark.parametrize("name", list(_matrices()))
@pytest.mark.parametrize("k", [1, 3, 10])
def test_compiled_block_product_matches_the_loop_oracle_and_scipy(name, k):
    A = _matrices()[name]
    rng = np.random.default_rng(k)
    X = rng.standard_normal((A.shape[1], k))
    P = BlockProduct(A, kernel="numba")
    assert P.kernel == "numba"
    ref = loop_oracle(A, X)
    for Xin in (X, np.asfortranarray(X), np.repeat(X, 2, axis=1)[:, ::2]):      # C, F, strided view
        got = P(Xin)
        assert got.shape == (A.shape[0], k) and got.flags.c_contiguous
        np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-13 * max(1.0, np.abs(ref).max()))
        np.testing.assert_array_equal(got, np.asarray(A @ Xin))    # the same sums in the same order
    x = X[:, 0]
    np.testing.assert_array_equal(P(x), A @ x)                    # a vector: scipy's product
    np.testing.assert_array_equal(P.operator().matmat(X), P(X))


@pytest.mark.parametrize("kernel", [pytest.param("numba", marks=needs_numba), "numpy"])
@pytest.mark.parametrize("name", ["square", "unsorted"])
def test_jacobi_sweep_matches_the_loop_oracle(kernel, name):
    """``X + wd (B - A X)`` in one pass (compiled) or by scipy: a loop oracle, and the very bits
    of the numpy expression the V-cycle used before."""
    A = _matrices()[name]
    rng = np.random.default_rng(3)
    X, Bv, wd = rng.standard_normal((60, 4)), rng.standard_normal((60, 4)), rng.uniform(0.1, 1.0, 60)
    P = BlockProduct(A, kernel=kernel)
    ref = X + wd[:, None] * (Bv - loop_oracle(A, X))
    for Xin in (X, np.asfortranarray(X)):
        got = P.jacobi(Xin, Bv, wd)
        assert got.shape == X.shape
        np.testing.assert_allclose(got, ref, rtol=1e-13, atol=1e-13 * np.abs(ref).max())
        np.testing.assert_array_equal(got, X + wd[:, None] * (Bv - np.asarray(A @ X)))


def test_kernel_choice():
    small = sp.identity(10, format="csr")
    assert BlockProduct(small).kernel == "numpy"                    # below MIN_NNZ: scipy
    assert BlockProduct(small, kernel="numpy").kernel == "numpy"
    with pytest.raises(InputError, match="kernel must be"):
        BlockProduct(small, kernel="fortran")
    big = sp.random(2000, 2000, density=spmm.MIN_NNZ / 2000**2 * 1.01, random_state=0, format="csr")
    assert big.nnz >= spmm.MIN_NNZ
    assert BlockProduct(big).kernel == ("numba" if _jit.available() else "numpy")


def test_numba_asked_for_without_numba_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(_jit, "numba", None)
    with pytest.raises(InputError, match="needs numba"):
        BlockProduct(sp.identity(4, format="csr"), kernel="numba")


def bsr_loop_oracle(A: sp.bsr_matrix, X: np.ndarray) -> np.ndarray:
    """``A @ X`` block by block from the BSR arrays (block rows, stored blocks, block entries, columns)."""
    r, c = A.blocksize
    Y = np.zeros((A.shape[0], X.shape[1]))
    for i in range(A.shape[0] // r):
        for p in range(A.indptr[i], A.indptr[i + 1]):
            j = A.indices[p]
            for a in range(r):
                for b in range(c):
                    Y[r * i + a] += A.data[p, a, b] * X[c * j + b]
    return Y


@needs_numba
@pytest.mark.parametrize("parallel", [False, True])
def test_node_block_products_match_a_loop_oracle(parallel, monkeypatch):
    """The compiled 3 x 3 block products (a vector and a block of vectors, serial and parallel)
    equal a loop over the BSR arrays and scipy's product."""
    from sc_fem.fem import bsr

    m = CubeModel.box((7, 3, 2), 0.1, youngs=1e7, poisson=0.3, density=1000.0)
    K = Assembler(m, "q1i", fixed_dofs=np.arange(3 * 4)).stiffness()
    Kb = bsr.node_blocks(K)
    assert Kb.blocksize == (3, 3)
    monkeypatch.setattr(bsr, "PARALLEL_NNZ", 0 if parallel else 10**12)
    prod = bsr.NodeBlockProduct(Kb, "numba")
    assert prod.fast and prod.parallel == parallel
    X = np.random.default_rng(2).standard_normal((K.shape[0], 5))
    ref = bsr_loop_oracle(Kb, X)
    scale = np.abs(ref).max()
    np.testing.assert_allclose(prod(X), ref, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(prod(X[:, 1]), ref[:, 1], rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(bsr.NodeBlockProduct(Kb, "numpy")(X), ref, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(prod(X), K @ X, rtol=0, atol=1e-12 * scale)


@needs_numba
def test_v_cycle_and_eigenpairs_are_the_same_with_either_product(monkeypatch):
    """The block V-cycle with compiled products equals the one with scipy's; LOBPCG with compiled
    products finds shift-invert's eigenpairs, with the BLAS limited to one thread while it runs."""
    from sc_fem.fem import eigen

    m = CubeModel.box((24, 4, 4), 0.05, youngs=1e7, poisson=0.3, density=1000.0)
    asm = Assembler(m, "q1i", fixed_dofs=np.arange(3 * 25))
    K, M = asm.stiffness(), asm.mass()
    B = rigid_body_modes(m.nodes_m, asm.free_dofs)
    X = np.random.default_rng(1).standard_normal((K.shape[0], 6))
    a = LatticeAMG(K, B, max_coarse=50, kernel="numba").vcycle(X)
    b = LatticeAMG(K, B, max_coarse=50, kernel="numpy").vcycle(X)
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10 * np.abs(b).max())

    seen = []
    real = _jit.blas_single_threaded

    def spy():
        seen.append(True)
        return real()

    monkeypatch.setattr(eigen, "blas_single_threaded", spy)                 # where LOBPCG looks it up
    solver = eigen.EigenSolver(K, M, method="lobpcg", near_null=B)
    got = solver.solve(4)
    assert solver._products[0]._product.fast and seen
    ref = solve_eigen(K, M, 4, method="shift-invert", backend="splu")
    np.testing.assert_allclose(got.eigenvalues, ref.eigenvalues, rtol=1e-8)


def test_blas_single_threaded_limits_the_blas():
    threadpoolctl = pytest.importorskip("threadpoolctl")
    with _jit.blas_single_threaded():
        blas = [p for p in threadpoolctl.threadpool_info() if p["user_api"] == "blas"]
        assert blas and all(p["num_threads"] == 1 for p in blas)     # numpy's BLAS is loaded and limited


def _random_bsr(rows: int, cols: int, blocksize: tuple[int, int], dtype, seed: int) -> sp.bsr_matrix:
    """A random BSR matrix of ``rows x cols`` blocks, some block rows empty."""
    r, c = blocksize
    dense = sp.random(rows, cols, density=0.3, random_state=seed, format="csr")
    dense = sp.kron(dense, np.ones(blocksize)).toarray() * np.random.default_rng(seed).standard_normal((rows * r, cols * c))
    dense[:r] = 0.0                                                  # an empty block row
    return sp.bsr_matrix(dense.astype(dtype), blocksize=blocksize)


@needs_numba
@pytest.mark.parametrize("blocksize", [(3, 6), (6, 3), (6, 6), (3, 3)])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("parallel", [False, True])
def test_any_block_product_and_its_transpose_match_a_loop_oracle(blocksize, dtype, parallel, monkeypatch):
    """The compiled products with a prolongator's (3 x 6), a restriction's (6 x 3) and a coarse
    level's (6 x 6) blocks, and with the transpose of a matrix from its own blocks (the restriction
    ``P.T``, no second matrix), serial and parallel, float64 and float32: a loop over the BSR
    arrays (float64) to the precision of the type, and the result in the matrix's type."""
    from sc_fem.fem import bsr

    monkeypatch.setattr(bsr, "PARALLEL_NNZ", 0 if parallel else 10**12)
    A = _random_bsr(9, 7, blocksize, dtype, seed=sum(blocksize))
    A64 = sp.bsr_matrix((A.data.astype(np.float64), A.indices, A.indptr), shape=A.shape)
    At64 = sp.bsr_matrix(A64.T)
    rng = np.random.default_rng(4)
    tol = 1e-13 if dtype == np.float64 else 1e-5
    for transpose, oracle_of in ((False, A64), (True, At64)):
        prod = bsr.NodeBlockProduct(A, "numba", transpose=transpose)
        assert prod.fast and prod.parallel == parallel and prod.shape == oracle_of.shape
        X = rng.standard_normal((oracle_of.shape[1], 5)).astype(dtype)
        ref = bsr_loop_oracle(oracle_of, X.astype(np.float64))
        for x, want in ((X, ref), (X[:, 2], ref[:, 2])):        # a block of vectors and one vector
            got = prod(x)
            assert got.dtype == dtype and got.shape == want.shape
            np.testing.assert_allclose(got, want, rtol=0, atol=tol * np.abs(ref).max())
        slow = bsr.NodeBlockProduct(A, "numpy", transpose=transpose)      # scipy's, R stored once
        np.testing.assert_allclose(slow(X), ref, rtol=0, atol=tol * np.abs(ref).max())


@needs_numba
@pytest.mark.parametrize("parallel", [False, True])
def test_float32_node_block_products_and_scaled_residual(parallel, monkeypatch):
    """The 3 x 3 node-block kernels in float32 (a float32 V-cycle's): the product and ``D^-1 (b - A x)``
    against the float64 loop oracle to single precision, in float32."""
    from sc_fem.fem import bsr

    monkeypatch.setattr(bsr, "PARALLEL_NNZ", 0 if parallel else 10**12)
    m = CubeModel.box((7, 3, 2), 0.1, youngs=1e7, poisson=0.3, density=1000.0)
    Kb = bsr.node_blocks(Assembler(m, "q1i", fixed_dofs=np.arange(3 * 4)).stiffness())
    K32 = sp.bsr_matrix((Kb.data.astype(np.float32), Kb.indices, Kb.indptr), shape=Kb.shape)
    rng = np.random.default_rng(5)
    X, Bv = rng.standard_normal((Kb.shape[0], 4)), rng.standard_normal((Kb.shape[0], 4))
    dinv = np.linalg.inv(Kb.data[Kb.indices == np.repeat(np.arange(Kb.shape[0] // 3), np.diff(Kb.indptr))])
    ref = bsr_loop_oracle(Kb, X)
    prod = bsr.NodeBlockProduct(K32, "numba")
    got = prod(X.astype(np.float32))
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-5 * np.abs(ref).max())
    want = bsr.block_diagonal_product(dinv, Bv - ref)
    for b, w in ((Bv, want), (None, bsr.block_diagonal_product(dinv, -ref))):
        got = prod.scaled_residual(dinv.astype(np.float32), X.astype(np.float32),
                                   None if b is None else b.astype(np.float32))
        assert got.dtype == np.float32
        np.testing.assert_allclose(got, w, rtol=0, atol=1e-5 * np.abs(w).max())
        acc = np.ones_like(got)                                          # added in place
        out = prod.scaled_residual(dinv.astype(np.float32), X.astype(np.float32),
                                   None if b is None else b.astype(np.float32), add_to=acc)
        assert out is acc
        np.testing.assert_allclose(acc, 1.0 + w, rtol=0, atol=1e-5 * np.abs(w).max())


@pytest.mark.parametrize("kernel", [pytest.param("numba", marks=needs_numba), "numpy"])
def test_float32_v_cycle_is_the_float64_one_to_single_precision(kernel):
    """``LatticeAMG(dtype=float32)``: the V-cycle's matrices in float32 (``R`` not kept when compiled),
    the finest level's products (LOBPCG's and CG's) still float64 and exact, the V-cycle taking and
    giving float64 and equal to the float64 one to single precision."""
    m = CubeModel.box((24, 4, 4), 0.05, youngs=1e7, poisson=0.3, density=1000.0)
    asm = Assembler(m, "q1i", fixed_dofs=np.arange(3 * 25))
    K = asm.stiffness()
    B = rigid_body_modes(m.nodes_m, asm.free_dofs)
    X = np.random.default_rng(1).standard_normal((K.shape[0], 6))
    a64 = LatticeAMG(K, B, max_coarse=50, kernel=kernel)
    a32 = LatticeAMG(K, B, max_coarse=50, kernel=kernel, dtype=np.float32)
    assert len(a32.levels) == len(a64.levels) > 1
    for lvl in a32.levels:
        assert lvl.smoothing.A.dtype == np.float32 and lvl.Dinv.dtype == np.float32
        assert lvl.P is None or (lvl.P.dtype == np.float32 and not hasattr(lvl, "R"))     # no restriction kept
    fine = a32.levels[0]
    assert fine.A.dtype == np.float64
    np.testing.assert_allclose(fine(X), K @ X, rtol=0, atol=1e-12 * np.abs(K @ X).max())
    for x in (X, X[:, 0]):
        got, ref = a32.vcycle(x), a64.vcycle(x)
        assert got.dtype == np.float64 and got.shape == x.shape
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-4 * np.abs(ref).max())
    with pytest.raises(InputError, match="float64 or float32"):
        LatticeAMG(K, B, max_coarse=50, dtype=np.float16)


@needs_numba
def test_float32_preconditioner_finds_the_same_eigenpairs_in_as_many_iterations(monkeypatch):
    """LOBPCG (float64) with the float32 V-cycle: shift-invert's eigenvalues and the float64
    V-cycle's iterations."""
    from sc_fem.fem import eigen

    m = CubeModel.box((24, 4, 4), 0.05, youngs=1e7, poisson=0.3, density=1000.0)
    asm = Assembler(m, "q1i", fixed_dofs=np.arange(3 * 25))
    K, M = asm.stiffness(), asm.mass()
    B = rigid_body_modes(m.nodes_m, asm.free_dofs)
    got = {}
    for dt in (np.float32, np.float64):
        monkeypatch.setattr(eigen, "VCYCLE_DTYPE", dt)
        got[dt] = solve_eigen(K, M, 6, method="lobpcg", near_null=B)
    ref = solve_eigen(K, M, 6, method="shift-invert", backend="splu")
    np.testing.assert_allclose(got[np.float32].eigenvalues, ref.eigenvalues, rtol=1e-8)
    np.testing.assert_allclose(got[np.float32].eigenvalues, got[np.float64].eigenvalues, rtol=1e-10)
    assert abs(got[np.float32].info["iterations"] - got[np.float64].info["iterations"]) <= 1
    assert got[np.float32].residuals.max() <= eigen.LOBPCG_ACCEPT


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_chebyshev_step_matches_a_loop_oracle_bit_for_bit(dtype, monkeypatch):
    """The smoother's update ``d <- a d + c r; x <- x + d`` in ``d``'s precision: the compiled pass,
    numpy's (small, 1-D or strided arrays, or no numba) and a loop over the entries agree bit for
    bit (no fused multiply-add, the coefficients rounded to ``d``'s precision first)."""
    from sc_fem.fem import bsr

    rng = np.random.default_rng(7)
    a, c = 0.7312345678901, -1.2345678901e-3
    n = bsr.CHEBYSHEV_STEP_MIN // 4 + 3                              # 4 columns: the compiled pass
    d0, r, x0 = (rng.standard_normal((n, 4)).astype(dtype) for _ in range(3))
    A, C = dtype(a), dtype(c)
    want_d, want_x = d0.copy(), x0.copy()
    for i in range(0, n, 997):                                     # loop oracle on every 997th row
        for j in range(4):
            v = dtype(want_d[i, j] * A) + dtype(C * r[i, j])
            want_d[i, j], want_x[i, j] = v, dtype(x0[i, j] + v)
    rows = np.arange(0, n, 997)
    compiled, calls = bsr._chebyshev_step, []
    for kernel in ("compiled", "numpy"):
        if kernel == "numpy":
            monkeypatch.setattr(bsr, "_chebyshev_step", None)
        elif compiled is None:
            continue                                               # numba absent: numpy's pass below
        else:                                                      # the compiled pass is the one that ran
            monkeypatch.setattr(bsr, "_chebyshev_step", lambda *args: calls.append(1) or compiled(*args))
        d, x = d0.copy(), x0.copy()
        bsr.chebyshev_step(d, r, x, a, c)
        np.testing.assert_array_equal(d[rows], want_d[rows])
        np.testing.assert_array_equal(x[rows], want_x[rows])
        assert d.dtype == dtype and x.dtype == dtype
    assert len(calls) == (compiled is not None)
    monkeypatch.undo()
    d, x = d0[:, 1].copy(), x0[:, 1].copy()                         # 1-D: numpy's passes
    bsr.chebyshev_step(d, r[:, 1], x, a, c)
    np.testing.assert_array_equal(d[rows], want_d[rows, 1])
    np.testing.assert_array_equal(x[rows], want_x[rows, 1])
    wide = np.zeros((n, 8), dtype=dtype)                            # a strided view: numpy's passes
    d, x = wide[:, ::2], x0.copy()
    d[...] = d0
    bsr.chebyshev_step(d, r, x, a, c)
    np.testing.assert_array_equal(d[rows], want_d[rows])
    np.testing.assert_array_equal(x[rows], want_x[rows])
