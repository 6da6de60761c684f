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
