"""The automatic eigensolver choice predicts shift-invert from the fill of the actual matrix.

A power law in the DOF count cannot tell a compact solid (whose factorization fills ~n^(4/3) and
costs ~n^2) from a thin plate of the same size (far less): :func:`sc_fem.fem.fill.analyze_fill`
reads the fill from CHOLMOD's ordering of the matrix itself, and the factorization reuses it.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg  # noqa: F401 - sp.linalg.norm

from sc_fem.fem import fill, options
from sc_fem.fem.assemble import Assembler
from sc_fem.fem.eigen import EigenSolver, SHIFT_FRACTION, lambda_scale, shifted
from sc_fem.fem.linsolve import available_backends, factorize
from sc_fem.lattice.cubes import CubeModel

needs_fill = pytest.mark.skipif("cholmod" not in available_backends() or fill._column_counts_jit is None,
                                reason="the fill analysis needs CHOLMOD (scikit-sparse) and numba")


def _shifted(shape) -> sp.csr_matrix:
    """``K - sigma M`` of a free box of ``shape`` cubes."""
    asm = Assembler(CubeModel.box(shape, 0.01, youngs=1e7, poisson=0.3, density=1000.0), "q1i")
    K, M = asm.stiffness(), asm.mass()
    return shifted(K, M, -SHIFT_FRACTION * lambda_scale(K, M))


def test_column_counts_match_a_dense_cholesky():
    """nnz of each column of L, counted from the elimination tree, equals that of a dense Cholesky
    factor of the permuted matrix (random pattern, random order)."""
    if fill._column_counts_jit is None:
        pytest.skip("needs numba")
    rng = np.random.default_rng(3)
    n = 60
    B = sp.random(n, n, density=0.04, random_state=4, data_rvs=lambda m: rng.uniform(0.1, 1.0, m))
    A = (B + B.T + sp.eye(n) * n).tocsc()
    perm = rng.permutation(n)
    L = np.linalg.cholesky(A[perm][:, perm].toarray())
    counts = fill.column_counts(A, perm)
    np.testing.assert_array_equal(counts, np.count_nonzero(np.abs(L) > 1e-300, axis=0))
    np.testing.assert_array_equal(fill.column_counts(sp.eye(5), np.arange(5)), np.ones(5))


@needs_fill
def test_a_compact_solid_predicts_more_shift_invert_time_per_dof_than_a_plate():
    """At (nearly) equal DOFs, the compact cube fills and costs far more than the plate; the power
    law cannot see it (same prediction), the fill analysis does, and ``auto`` chooses accordingly."""
    cube, plate = _shifted((16, 16, 16)), _shifted((49, 49, 1))
    n_c, n_p = cube.shape[0], plate.shape[0]
    assert abs(n_c / n_p - 1) < 0.05
    a_c, a_p = fill.analyze_fill(cube), fill.analyze_fill(plate)
    assert a_c.nnz_l > 2 * a_p.nnz_l and a_c.flops > 5 * a_p.flops
    t_c = options.predicted_seconds("shift-invert", n_c, 16, a_c)
    t_p = options.predicted_seconds("shift-invert", n_p, 16, a_p)
    assert t_c / n_c > 2 * t_p / n_p
    big = 10 * 2**30
    assert options.choose_method(n_p, plate.nnz, 16, big, a_p)[0] == "shift-invert"
    method, reason = options.choose_method(n_c, cube.nnz, 16, big, a_c)
    assert "fill nnz(L)" in reason and "predicted" in reason
    # the memory estimate follows the fill too
    assert options.factor_memory_estimate(n_c, cube.nnz, a_c) > 2 * options.factor_memory_estimate(n_p, plate.nnz, a_p)


@needs_fill
def test_the_fill_agrees_with_the_real_factor_and_is_reused():
    """nnz(L) from the analysis is within 10 % of CHOLMOD's factor in the analysis's order (which
    pads supernodes with zeros), and the factorization reuses the order: the same solution as
    CHOLMOD's own ordering, no second ordering."""
    A = _shifted((12, 10, 8)).tocsc()
    a = fill.analyze_fill(A)
    fac = factorize(A, "cholmod")
    real = factorize(A, "cholmod", analysis=a)._f.L().nnz
    assert 0.9 * real <= a.nnz_l <= real
    assert a.nnz_l <= 1.05 * fac._f.L().nnz                   # the node order fills no more than CHOLMOD's
    est = options.factor_memory_estimate(A.shape[0], A.nnz, a)
    assert 0.9 * 8 * real <= est <= 1.5 * 8 * real
    import sksparse.cholmod as cholmod

    b = np.random.default_rng(0).standard_normal(A.shape[0])
    calls = []
    real_cholesky = cholmod.cholesky
    try:
        cholmod.cholesky = lambda *x, **y: calls.append(y) or real_cholesky(*x, **y)
        reused = factorize(A, "cholmod", analysis=a)
    finally:
        cholmod.cholesky = real_cholesky
    assert calls == [{"ordering_method": "natural"}]          # factorized in the analysis's order
    x = reused.solve(b)                        # another order rounds differently (cond(A) ~ 1e8)
    scale = sp.linalg.norm(A) * np.linalg.norm(x)
    assert np.linalg.norm(A @ x - b) <= 1e-13 * scale
    np.testing.assert_allclose(x, fac.solve(b), rtol=1e-7, atol=0)
    np.testing.assert_allclose(reused.solve(np.column_stack([b, 2 * b])), np.column_stack([x, 2 * x]), rtol=1e-12)


def _partly_fixed(shape=(6, 4, 3)) -> sp.csr_matrix:
    """``K - sigma M`` of a box with some nodes fixed in x alone (supervariables of 2 and 3 rows)
    and one entry of a block dropped (a row that no longer matches its node's others)."""
    model = CubeModel.box(shape, 0.01, youngs=1e7, poisson=0.3, density=1000.0)
    fixed = np.flatnonzero(model.nodes_m[:, 0] < 1e-9) * 3           # x only
    asm = Assembler(model, "q1i", fixed_dofs=fixed)
    K, M = asm.stiffness(), asm.mass()
    A = shifted(K, M, -SHIFT_FRACTION * lambda_scale(K, M)).tocsr().astype(np.float64)
    A = A.tolil()
    A[10, 40] = A[40, 10] = 0.0                                    # one coupling gone, both ways
    A = A.tocsr()
    A.eliminate_zeros()
    return A


def test_supervariables_compiled_equal_the_numpy_oracle_and_group_identical_rows():
    A = _partly_fixed()
    A.sort_indices()
    ip, ix = A.indptr.astype(np.int64), A.indices.astype(np.int64)
    want = fill._compress_numpy(ip, ix)
    if fill._compress_jit is not None:
        for got, w in zip(fill._compress_jit(ip, ix), want):
            np.testing.assert_array_equal(got, w)
    start, G = fill.supervariables(A)
    size = np.diff(start)
    assert set(size) >= {1, 2, 3} and start[-1] == A.shape[0]
    dense = A.toarray() != 0                                       # loop oracle: rows equal within a group
    for j in range(len(size)):
        rows = dense[start[j]:start[j + 1]]
        assert (rows == rows[0]).all()
        if start[j + 1] < A.shape[0]:
            assert not (dense[start[j + 1]] == rows[0]).all()
        blocks = [any(dense[start[j], start[i]:start[i + 1]]) for i in range(len(size))]
        np.testing.assert_array_equal(G[:, j].toarray().ravel() != 0, blocks)


@needs_fill
def test_compressed_counts_are_exact_for_the_expanded_order():
    """The analysis orders the compressed matrix; its weighted column counts give exactly the
    ``nnz(L)`` and flops that the DOF-level counts give in the same (expanded) order."""
    A = _partly_fixed()
    a = fill.analyze_fill(A)
    assert sorted(a.perm) == list(range(A.shape[0]))
    c = fill.column_counts(A, a.perm).astype(float)
    assert a.nnz_l == int(c.sum())
    assert a.flops == pytest.approx(float(c @ c), rel=1e-12)


@needs_fill
def test_auto_records_what_it_predicted_and_what_it_took():
    A = _shifted((8, 3, 3))
    asm = Assembler(CubeModel.box((8, 3, 3), 0.01, youngs=1e7, poisson=0.3, density=1000.0), "q1i")
    res = EigenSolver(asm.stiffness(), asm.mass(), method="auto").solve(8)
    pred = res.info["predicted_seconds"]
    assert set(pred) == {"shift-invert", "lobpcg"} and all(v > 0 for v in pred.values())
    assert res.method == "shift-invert" and "fill nnz(L)" in res.reason
    from sksparse import cholmod

    real = cholmod.cholesky(sp.csc_matrix(A)).L().nnz         # the factor auto predicted, computed
    assert res.seconds["setup"] > 0 and 8 * real <= res.info["factor_memory_estimate"] <= 1.5 * 11 * real + 16 * A.shape[0]


def test_without_cholmod_or_numba_the_power_law_predicts(monkeypatch):
    """Another backend (or no numba): no analysis, the power law in n, and ``auto`` still works."""
    A = _shifted((8, 3, 3))
    assert fill.analyze_fill(A, "splu") is None
    monkeypatch.setattr(fill, "_column_counts_jit", None)
    assert fill.analyze_fill(A, "auto") is None and fill.column_counts(A, np.arange(A.shape[0])) is None
    n = A.shape[0]
    assert options.predicted_seconds("shift-invert", n, 6, None) == pytest.approx(
        options.SPEED_MODEL["shift-invert"][0] * (n / 7776.0) ** options.SPEED_MODEL["shift-invert"][1])
    assert options.fill_analysis(sp.eye(options.FILL_ANALYSIS_MAX_DOFS + 1, format="csr")) is None
    asm = Assembler(CubeModel.box((8, 3, 3), 0.01, youngs=1e7, poisson=0.3, density=1000.0), "q1i")
    res = EigenSolver(asm.stiffness(), asm.mass(), method="auto", backend="splu").solve(6)
    assert "power law in n" in res.reason and res.backend in ("splu", "pyamg")
    assert res.info["predicted_seconds"]["shift-invert"] == pytest.approx(options.predicted_seconds("shift-invert", n, 6))


def test_the_summary_says_what_auto_predicted_and_what_it_took(tmp_path, capsys):
    import re

    from sc_fem._cli.main import main

    assert main(["precompute-modes", "builtin:beam", "-r", "8", "-k", "4", "-o", str(tmp_path / "b.npz")]) == 0
    line = next(s for s in capsys.readouterr().out.splitlines() if s.strip().startswith("eigensolver"))
    assert re.search(r"predicted [\d.]+ s shift-invert", line) and re.search(r"took [\d.]+ s", line), line


def test_compression_with_empty_rows_and_no_ordering():
    """Empty rows (a middle one and the last) compress alike in the compiled kernel and its numpy
    oracle; when no ordering can run, the analysis gives None (the power law predicts)."""
    D = sp.csr_matrix(np.array([[1, 0, 1, 0], [0, 0, 0, 0], [1, 0, 1, 0], [0, 0, 0, 0]], float))
    ip, ix = D.indptr.astype(np.int64), D.indices.astype(np.int64)
    want = fill._compress_numpy(ip, ix)
    np.testing.assert_array_equal(want[1], [0, 2, 2, 4, 4])         # the compressed rows' pointers
    if fill._compress_jit is not None:
        for got, w in zip(fill._compress_jit(ip, ix), want):
            np.testing.assert_array_equal(got, w)


@needs_fill
def test_no_ordering_means_no_analysis(monkeypatch):
    import sksparse.cholmod as cholmod

    def fails(*args, **kwargs):
        raise cholmod.CholmodError("no ordering")

    monkeypatch.setattr(cholmod, "analyze", fails)
    assert fill.analyze_fill(_shifted((4, 3, 3))) is None


def test_the_power_law_scales_lobpcg_by_k_and_the_fill_model_by_its_block():
    n = 40_000
    six = options.predicted_seconds("lobpcg", n, 6, None)
    assert options.predicted_seconds("lobpcg", n, 16, None) == pytest.approx(six * 16 / 6)
    assert options.lobpcg_block(6) == 10 and options.lobpcg_block(16) == 20 and options.lobpcg_block(40) == 50
    # the fill's model: set-up + iterations (independent of k) x one iteration's cost (of the block's entries)
    m = fill.LOBPCG_FILL_MODEL
    a = fill.FillAnalysis(n=n, nnz_l=int(8.0 * n ** (4 / 3)), flops=1e9, seconds=0.1)
    setup = m["setup"] + m["setup_per_dof"] * n
    for k in (6, 16, 40):
        e = n * options.lobpcg_block(k)
        want = setup + fill.lobpcg_iterations(a) * m["c"] * e * (e / 1e6) ** m["gamma"]
        assert options.predicted_seconds("lobpcg", n, k, a) == pytest.approx(want, rel=1e-12)
    ratio = fill.lobpcg_iteration_seconds(n, 16) / fill.lobpcg_iteration_seconds(n, 6)
    assert ratio == pytest.approx(2.0 ** (1 + m["gamma"]))


# LOBPCG + AMG on the shapes of ``python benchmarks/auto_choice.py --quick`` that LOBPCG_FILL_MODEL was
# fitted to (one run of 2 repeats of our LOBPCG, 2026-11-28, benchmarks/out/auto_choice_fitdata3.json):
# (shape, free DOFs, nnz(L), pairs, iterations taken, median seconds taken)
LOBPCG_FIT_TABLE = [
    ("beam", 5292, 797823, 16, 17, 0.34),
    ("bunny", 31161, 15725535, 16, 21, 1.56),
    ("spot", 23283, 9714411, 16, 20, 1.13),
    ("armchair", 24921, 6688251, 16, 36, 2.36),
    ("chair", 7803, 975825, 16, 31, 0.70),
    ("plate", 75465, 18919017, 16, 35, 7.83),
    ("I-beam", 30186, 5442939, 16, 46, 2.91),
    ("truss (mm)", 10992, 1031640, 16, 94, 2.21),
    ("toy truck", 76035, 35660139, 16, 36, 5.11),
    ("cantilever", 139656, 119457186, 6, 13, 4.08),
]


def test_the_lobpcg_model_reproduces_the_runs_it_was_fitted_to():
    """Iterations within the fit's stated rms (0.31 in log, each within 1.85x: the beam's 17 against
    31; compact solids, q >= q0, exactly the compact count), and the seconds of the fitted table
    without a bias (geometric mean of taken / predicted within 15 %) and each within 1.5x, the
    issue's target (0.75-1.31x when fitted)."""
    its, secs = [], []
    for _, n, nnz_l, k, taken_its, taken_s in LOBPCG_FIT_TABLE:
        a = fill.FillAnalysis(n=n, nnz_l=nnz_l, flops=0.0, seconds=0.0)
        its.append(np.log(taken_its / fill.lobpcg_iterations(a)))
        secs.append(np.log(taken_s / options.predicted_seconds("lobpcg", n, k, a)))
        if nnz_l / n ** (4 / 3) >= fill.LOBPCG_FILL_MODEL["q0"]:
            assert fill.lobpcg_iterations(a) == fill.LOBPCG_FILL_MODEL["iterations"]
    its, secs = np.array(its), np.array(secs)
    assert np.sqrt(np.mean(its ** 2)) <= 0.32 and np.abs(its).max() <= np.log(1.85), its
    assert abs(np.mean(secs)) <= np.log(1.15) and np.abs(secs).max() <= np.log(1.5), np.exp(secs)


@needs_fill
def test_a_small_problem_is_not_over_predicted_by_the_set_up():
    """A 2,499-DOF box: LOBPCG is predicted at most 2x what it takes (measured here; the load only
    makes it take longer), and the set-up term is below half the prediction."""
    import time

    from sc_fem.fem.eigen import solve_eigen
    from sc_fem.fem.rigid import rigid_body_modes

    model = CubeModel.box((16, 6, 6), 0.01, youngs=1e7, poisson=0.3, density=1000.0)
    asm = Assembler(model, "q1i")
    K, M = asm.stiffness(), asm.mass()
    a = fill.analyze_fill(shifted(K, M, -SHIFT_FRACTION * lambda_scale(K, M)))
    n, near_null = K.shape[0], rigid_body_modes(model.nodes_m)
    solve_eigen(K, M, 16, method="lobpcg", near_null=near_null)              # compiled kernels warm
    t0 = time.perf_counter()
    solve_eigen(K, M, 16, method="lobpcg", near_null=near_null)
    taken = time.perf_counter() - t0
    predicted = options.predicted_seconds("lobpcg", n, 16, a)
    m = fill.LOBPCG_FILL_MODEL
    assert predicted <= 2.0 * taken, (predicted, taken)          # 1.5x on this machine; 2x for a faster one
    assert m["setup"] + m["setup_per_dof"] * n < 0.5 * predicted
