"""The block LOBPCG of :mod:`sc_fem.fem.lobpcg`: against dense eigensolves, shift-invert, its own
variants, an ill-conditioned start, and the memory it allocates."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
import scipy.linalg as sl
import scipy.sparse as sp

from sc_fem import modal
from sc_fem.fem.assemble import Assembler
from sc_fem.fem.lobpcg import lobpcg
from sc_fem.fem.shift import SHIFT_FRACTION, lambda_scale
from sc_fem.lattice.cubes import CubeModel


def _jacobi(A):
    d = 1.0 / A.diagonal()
    return lambda R: R * d[:, None]


def _lattice(dims, fixed_nodes=0, pitch=0.05):
    m = CubeModel.box(dims, pitch, youngs=1e7, poisson=0.3, density=1000.0)
    asm = Assembler(m, "q1i", fixed_dofs=np.arange(3 * fixed_nodes))
    K, M = asm.stiffness().tocsr(), asm.mass().tocsr()
    sigma = -SHIFT_FRACTION * lambda_scale(K, M)
    return K, M, sigma, (K - sigma * M).tocsr()


def _residuals(A, B, theta, X):
    return np.linalg.norm(A @ X - (B @ X) * theta, axis=0)


def test_a_free_body_has_its_six_rigid_modes_and_the_dense_spectrum():
    """A free 4 x 3 x 2 box (180 DOFs): 6 rigid modes (eigenvalue ~0 of K) and the elastic ones
    after them, as a dense generalized eigensolve gives them."""
    K, M, sigma, A = _lattice((4, 3, 2))
    lam = sl.eigh(K.toarray(), M.toarray(), eigvals_only=True)
    k, m = 10, 14
    tol = 1e-7 * abs(sigma)                  # rounding: ~1e-8 |sigma| (dense: 2.5e-9)
    theta, X, info = lobpcg(A, M, np.random.default_rng(0).standard_normal((A.shape[0], m)), k, tol,
                            T=_jacobi(A), maxiter=500)
    assert info["stop"] == "converged"
    got = theta[:k] + sigma
    assert np.all(np.abs(got[:6]) < 1e-7 * lam[6]) and np.all(np.abs(lam[:6]) < 1e-7 * lam[6])
    np.testing.assert_allclose(got[6:], lam[6:k], rtol=1e-9)
    assert np.all(_residuals(A, M, theta[:k], X[:, :k]) <= tol)
    np.testing.assert_allclose(X.T @ (M @ X), np.eye(m), atol=1e-10)
    assert info["history"].shape == (info["iterations"] + 1, k)


def test_a_clustered_and_repeated_spectrum():
    """Eigenvalues 1 (four times), 1 + 1e-9, 2, 2, 3, ...: the repeated ones and the near-repeated
    one are all found, with the dense solve's values and B-orthonormal vectors."""
    rng = np.random.default_rng(3)
    n = 300
    d = np.concatenate([[1, 1, 1, 1, 1 + 1e-9, 2, 2], 3 + np.arange(n - 7)])
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    L = np.tril(rng.standard_normal((n, n)) * 0.05, -1) + np.eye(n)
    Bm = L @ L.T                                   # B SPD, not diagonal
    Lc = np.linalg.cholesky(Bm)
    A = Lc @ Q @ np.diag(d) @ Q.T @ Lc.T           # A x = lambda B x has eigenvalues d
    lam = sl.eigh(A, Bm, eigvals_only=True)
    np.testing.assert_allclose(lam[:7], d[:7], rtol=1e-10)
    k = 7
    T = np.linalg.inv(A + np.diag(0.5 * np.diag(A)))   # an approximate inverse: a preconditioner
    theta, X, info = lobpcg(A, Bm, rng.standard_normal((n, 10)), k, 1e-10, T=T, maxiter=500)
    assert info["stop"] == "converged"
    np.testing.assert_allclose(theta[:k], d[:k], rtol=1e-12)
    assert np.all(_residuals(A, Bm, theta[:k], X[:, :k]) <= 1e-10)
    np.testing.assert_allclose(X.T @ Bm @ X, np.eye(10), atol=1e-10)


def test_soft_locking_changes_nothing_but_the_work():
    """Converged columns without new directions give the same pairs as every column expanded, in
    no more iterations, with fewer preconditioned columns."""
    K, M, sigma, A = _lattice((20, 4, 3), fixed_nodes=20)
    X0 = np.random.default_rng(1).standard_normal((A.shape[0], 10))
    cols = {True: 0, False: 0}
    out = {}
    for lock in (True, False):
        Tj = _jacobi(A)

        def T(R, lock=lock):
            cols[lock] += R.shape[1]
            return Tj(R)

        out[lock] = lobpcg(A, M, X0, 6, 1e-4 * abs(sigma), T=T, maxiter=800, soft_locking=lock)
    (t1, X1, i1), (t0, X0_, i0) = out[True], out[False]
    assert i1["stop"] == i0["stop"] == "converged"
    np.testing.assert_allclose(t1[:6], t0[:6], rtol=1e-9)
    assert i1["iterations"] <= i0["iterations"] + 2
    assert cols[True] < cols[False]


def test_a_start_block_with_duplicate_columns_is_handled():
    """Three copies of one column (a Gram matrix of rank m - 2): the copies are replaced by random
    vectors and the solve converges to the dense eigenvalues."""
    K, M, sigma, A = _lattice((6, 3, 2), fixed_nodes=4)
    lam = sl.eigh(K.toarray(), M.toarray(), eigvals_only=True)
    X0 = np.random.default_rng(2).standard_normal((A.shape[0], 8))
    X0[:, 3] = X0[:, 1]
    X0[:, 5] = 2 * X0[:, 1]
    tol = 1e-7 * abs(sigma)
    theta, X, info = lobpcg(A, M, X0, 5, tol, T=_jacobi(A), maxiter=500)
    assert info["stop"] == "converged"
    np.testing.assert_allclose(theta[:5] + sigma, lam[:5], rtol=1e-9)
    np.testing.assert_allclose(X.T @ (M @ X), np.eye(8), atol=1e-10)
    with pytest.raises(ValueError):
        lobpcg(A, M, X0[:, :3], 5, tol)            # fewer columns than wanted pairs


@pytest.mark.parametrize("name, kwargs", [
    ("builtin:beam", dict(resolution=24, fix="x<min+0.01")),
    ("plate", dict(fix="x<min+0")),
])
def test_lattice_models_have_shift_inverts_frequencies(name, kwargs):
    """The built-in beam held at one end and a thin plate (one cube thick): LOBPCG (by name, so no
    fallback can hide a failure) gives shift-invert's frequencies to 1e-8."""
    model = (CubeModel.box((30, 20, 1), 0.01, youngs=1e7, poisson=0.3, density=1000.0) if name == "plate"
             else name)
    lo = modal(model, n_modes=8, eigen="lobpcg", **kwargs)
    si = modal(model, n_modes=8, eigen="shift-invert", **kwargs)
    assert lo.eigen["method"] == "lobpcg" and lo.eigen["stop"] == "converged"
    np.testing.assert_allclose(lo.frequencies, si.frequencies, rtol=1e-8)


BLOCKS = 6
"""``n x m`` blocks the solver may allocate: ``X, AX, P, AP, W`` kept, and one product at a time
(``B X`` for the residual, ``B W``, ``A W``, or the preconditioner's output)."""


def test_the_solver_allocates_at_most_six_blocks():
    """tracemalloc's peak during a solve of 29,835 DOFs with a block of 10: at most :data:`BLOCKS`
    blocks of ``n x m`` doubles, beside the row chunks' small temporaries (scipy's LOBPCG: ~19)."""
    from sc_fem.fem.lobpcg import CHUNK_BYTES

    K, M, sigma, A = _lattice((50, 14, 12), fixed_nodes=15 * 13)
    n, m = A.shape[0], 10
    assert n == 29_250
    X0 = np.random.default_rng(0).standard_normal((n, m))
    T = _jacobi(A)
    lobpcg(A, M, X0, 6, 1e-3 * abs(sigma), T=T, maxiter=3)       # any lazy set-up done
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        _, X, info = lobpcg(A, M, X0, 6, 1e-3 * abs(sigma), T=T, maxiter=12)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    assert info["iterations"] == 12 and info["stop"] == "maxiter"
    block = 8 * n * m
    assert peak <= BLOCKS * block + 2 * CHUNK_BYTES, peak / block
    assert peak > (BLOCKS - 1) * block                             # the count is tight: it measures


def test_each_parts_rigid_fields_are_its_own_rigid_body_modes():
    """part_rigid_modes against rigid_body_modes of each part alone, part by part (the oracle),
    zero off the part, the columns in the order asked."""
    from sc_fem.fem.rigid import part_rigid_modes, rigid_body_modes

    rng = np.random.default_rng(4)
    points = rng.random((40, 3)) * [2.0, 1.0, 0.5] + 3.0
    labels = rng.integers(0, 4, 40)
    parts = np.array([2, 0, 3])
    B = part_rigid_modes(points, labels, parts).reshape(40, 3, 3, 6)
    for i, p in enumerate(parts):                # a loop over 3 parts: the oracle
        on = labels == p
        np.testing.assert_allclose(B[on, :, i].reshape(-1, 6), rigid_body_modes(points[on]), atol=1e-15)
        assert not B[~on, :, i].any()
    free = np.sort(rng.choice(120, 90, replace=False))
    np.testing.assert_array_equal(part_rigid_modes(points, labels, parts, free), B.reshape(120, 18)[free])


@pytest.mark.parametrize("origin", [(0.0, 0.0, 0.0), (5.0, -3.0, 2.0)])
def test_two_loose_parts_converge_faster_from_each_parts_rigid_motions(origin):
    """Two separate bars, free: 12 zero modes. From the global 6 rigid fields LOBPCG must find the
    other 6 by iteration; from each part's 6 it has them at once. Both give shift-invert's
    frequencies; the per-part start takes fewer iterations (the toy truck of two bodies: 36, not 52)."""
    from sc_fem.fem.eigen import EigenSolver
    from sc_fem.fem.rigid import part_rigid_modes, rigid_body_modes
    from sc_fem.fem.static import node_parts

    cells = np.vstack([np.argwhere(np.ones((12, 3, 3), bool)), np.argwhere(np.ones((9, 4, 2), bool)) + [0, 6, 0]])
    m = CubeModel.from_cells(cells, origin=np.array(origin), pitch=0.05, mass=np.full(len(cells), 1000.0 * 0.05**3),
                             youngs=1e7, poisson=0.3, density=1000.0)
    assert m.n_components == 2
    K, M = Assembler(m, "q1i").stiffness(), Assembler(m, "q1i").mass()
    labels = node_parts(m)
    near_null = rigid_body_modes(m.nodes_m)
    ref = EigenSolver(K, M, method="shift-invert").solve(18).eigenvalues
    got = {}
    for name, start in (("global", None), ("parts", part_rigid_modes(m.nodes_m, labels, np.array([0, 1])))):
        r = EigenSolver(K, M, method="lobpcg", near_null=near_null, start=start).solve(18)
        np.testing.assert_allclose(np.sqrt(np.abs(r.eigenvalues[12:])), np.sqrt(ref[12:]), rtol=1e-7)
        assert np.all(np.abs(r.eigenvalues[:12]) < 1e-6 * ref[12])
        got[name] = r.info["iterations"]
    assert got["parts"] < got["global"], got


def test_the_loose_start_takes_the_largest_loose_parts_the_block_holds():
    """One loose part: no start of its own (the global rigid fields serve). Three: the largest
    first, as many whole parts as the columns hold, each its own rigid fields."""
    from sc_fem.fem.rigid import loose_start, part_rigid_modes

    rng = np.random.default_rng(2)
    labels = np.repeat([0, 1, 2, 3], [5, 30, 12, 20])            # sizes: 1 > 3 > 2 > 0
    points = rng.random((len(labels), 3)) + 10.0
    assert loose_start(points, labels, np.array([2]), 20) is None
    got = loose_start(points, labels, np.array([0, 2, 3, 1]), 20)   # room for 3 parts of 6 columns
    np.testing.assert_array_equal(got, part_rigid_modes(points, labels, np.array([1, 3, 2])))


def test_the_projection_is_exact_on_a_geometric_decay_and_unbounded_on_a_stall():
    """:func:`projected_iterations` extrapolates the logarithm of the largest wanted residual: on
    residuals falling 10x an iteration from 1e6 x tol it names the iteration where they reach tol;
    on a flat or rising window, no end."""
    from sc_fem.fem.lobpcg import projected_iterations

    tol = 1e-3
    hist = [np.array([tol * 10.0 ** (6 - i), tol]) for i in range(4)]       # at iteration 3: 1e3 x tol
    assert projected_iterations(hist, tol, 2) == pytest.approx(6.0)
    assert projected_iterations(hist, tol, 8) == pytest.approx(6.0)           # a window past the start: what there is
    flat = [np.array([5.0 * tol])] * 10
    assert projected_iterations(flat, tol, 8) == float("inf")
    assert projected_iterations(flat[:1], tol, 8) == float("inf")


def test_a_monitor_sees_every_check_and_can_stop_the_solve():
    """The monitor is called at each progress check (iteration 20, then every 8) with the
    iteration and the projection; returning True ends the solve there, ``"over budget"``."""
    rng = np.random.default_rng(3)
    n = 400
    d = np.linspace(1.0, 1e4, n)
    A, B = sp.diags(d).tocsr(), sp.identity(n, format="csr")
    X0 = rng.standard_normal((n, 8))
    seen = []
    _, _, info = lobpcg(A, B, X0, 4, 1e-12, maxiter=60, monitor=lambda it, p: seen.append((it, p)) or False)
    assert [it for it, _ in seen] == [20, 28, 36, 44, 52, 60][:len(seen)] and len(seen) >= 2
    assert all(p > it for it, p in seen)                              # not yet converged at a check
    _, _, info = lobpcg(A, B, X0, 4, 1e-12, maxiter=60, monitor=lambda it, p: it >= 28)
    assert info["stop"] == "over budget" and info["iterations"] == 28
