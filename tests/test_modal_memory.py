"""The lean paths of the modal pipeline: the compact mass, the released assembler, ``K - sigma M``
with a compact ``M``, the float32 V-cycle's finest matrix split in two, the chunked AMG set-up, and
the frequencies of ``sc_fem.modal`` through all of them."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
import scipy.sparse as sp

import sc_fem
from sc_fem import _jit
from sc_fem.fem import bsr, multigrid, nodemass
from sc_fem.fem.assemble import _CHUNK, _PAIR_OFFSET, Assembler
from sc_fem.fem.eigen import EigenSolver, solve_eigen
from sc_fem.fem.options import lobpcg_memory_estimate
from sc_fem.fem.rigid import rigid_body_modes
from sc_fem.fem.shift import ComponentMass, shift_in_place, shifted, without_zeros
from sc_fem.lattice.cubes import CubeModel

needs_numba = pytest.mark.skipif(not _jit.available(), reason="numba not installed")
BOX = CubeModel.box((7, 4, 3), 0.1, youngs=1e7, poisson=0.3, density=1000.0)
WHOLE = np.arange(3 * 6)                     # the first 6 nodes, all 3 components


def _same(A: sp.csr_matrix, B: sp.csr_matrix) -> None:
    assert A.shape == B.shape
    np.testing.assert_array_equal(A.indptr, B.indptr)
    np.testing.assert_array_equal(A.indices, B.indices)
    np.testing.assert_array_equal(A.data, B.data)


@pytest.mark.parametrize("kernel", [pytest.param("numba", marks=needs_numba), "numpy"])
@pytest.mark.parametrize("fixed", [None, WHOLE, [0, 4, 5]])
def test_compact_mass_is_the_full_mass_without_its_zeros(kernel, fixed):
    """``mass(compact=True)``: bit for bit the shared-pattern ``M`` without its structural zeros, whole
    nodes fixed or not (a node fixed in some components goes through the full ``M``)."""
    asm = Assembler(BOX, "q1i", fixed_dofs=fixed, kernel=kernel)
    full, compact = asm.mass(), asm.mass(compact=True)
    _same(compact, without_zeros(full))
    assert compact.nnz * 3 == full.nnz and compact.has_sorted_indices


def test_compact_mass_of_partly_filled_cubes():
    """A voxelized mesh's partly filled cubes (their mass distributed like the filled region): the
    same compact ``M``, held or free."""
    model = sc_fem.voxelize("builtin:chair", resolution=12)
    assert model.stiffness == "moments"
    for fix in (None, "z<min+0.01"):
        fd = None if fix is None else sc_fem.fixed_dofs(sc_fem.fixed_nodes(model, fix))
        asm = Assembler(model, "q1i", fixed_dofs=fd)
        _same(asm.mass(compact=True), without_zeros(asm.mass()))


@needs_numba
def test_node_mass_kernel_matches_its_loop_oracle_and_numpy():
    """The compiled scatter of the cubes' scalar mass blocks equals the same loop run by Python and
    numpy's ``add.at`` of the same positions."""
    from sc_fem.fem import assemble_jit
    from sc_fem.fem.assemble_jit import fill_nodes
    from sc_fem.fem.elements import cube_mass_chunks

    asm = Assembler(BOX, "q1i", fixed_dofs=WHOLE)
    vals = np.ascontiguousarray(cube_mass_chunks(BOX, BOX.mass)(0, BOX.n_cubes)).reshape(-1, 576)
    free, mstart, hexes = asm._free3[:, 0], asm._rowstart[0] // 9, np.ascontiguousarray(BOX.hexes)
    want = np.zeros(asm.nnz // 9)
    assemble_jit._fill_nodes_py(want, vals, hexes, 0, mstart, asm._coloff, free, _PAIR_OFFSET)   # loop oracle
    got = np.zeros_like(want)
    fill_nodes(got, vals, hexes, 0, mstart, asm._coloff, free, _PAIR_OFFSET)
    np.testing.assert_array_equal(got, want)
    by_numpy = nodemass.node_values(Assembler(BOX, "q1i", fixed_dofs=WHOLE, kernel="numpy"),
                                    cube_mass_chunks(BOX, BOX.mass), _CHUNK, _PAIR_OFFSET)
    np.testing.assert_array_equal(by_numpy, want)


def test_released_assembler_builds_its_pattern_again():
    """After ``release()`` the pattern's arrays are gone; ``expand`` needs none of them, and the next
    fill builds them again: the same matrices."""
    asm = Assembler(BOX, "q1i", fixed_dofs=WHOLE)
    K, M = asm.stiffness(), asm.mass()
    asm.release()
    assert "indices" not in vars(asm) and "_coloff" not in vars(asm)
    u = asm.expand(np.ones(len(asm.free_dofs)))
    assert u.shape == (BOX.n_nodes, 3) and "indices" not in vars(asm)
    _same(asm.stiffness(), K)
    _same(asm.mass(), M)
    assert asm.nnz == K.nnz


def test_shift_with_a_compact_mass_is_in_place_and_the_same():
    """``K - sigma M`` with ``M`` on a pattern inside ``K``'s: written over ``K``, equal to the shift on
    the shared pattern; ``shifted`` keeps ``K``'s pattern; an ``M`` entry outside ``K``'s pattern
    leaves ``K`` untouched."""
    asm = Assembler(BOX, "q1i", fixed_dofs=WHOLE)
    K, M, Mc = asm.stiffness(), asm.mass(), asm.mass(compact=True)
    sigma = -1e3
    ref = (K - sigma * M).toarray()
    scale = np.abs(ref).max()
    new = shifted(K, Mc, sigma)
    assert np.shares_memory(new.indices, K.indices) and new.nnz == K.nnz
    np.testing.assert_allclose(new.toarray(), ref, rtol=0, atol=1e-15 * scale)
    K1 = K.copy()
    assert shift_in_place(K1, Mc, sigma) is K1
    np.testing.assert_allclose(K1.toarray(), ref, rtol=0, atol=1e-15 * scale)
    outside = Mc.tolil()
    outside[0, K.shape[1] - 1] = 1.0                                   # no such entry in K
    K2 = K.copy()
    got = shift_in_place(K2, outside.tocsr(), sigma)
    assert got is not K2
    _same(K2, K)
    np.testing.assert_allclose(got.toarray(), (K - sigma * outside).toarray(), rtol=0, atol=1e-15 * scale)


def test_component_mass_of_the_compact_mass_is_that_of_the_full_one():
    """The node matrix recognized in the compact ``M`` is the one of the shared-pattern ``M``; row
    chunks of any size find it."""
    asm = Assembler(BOX, "q1i", fixed_dofs=WHOLE)
    a, b = ComponentMass.of(asm.mass()), ComponentMass.of(asm.mass(compact=True))
    _same(a.m, b.m)
    from sc_fem.fem import shift
    old = shift._ROW_CHUNK
    try:
        shift._ROW_CHUNK = 5
        _same(ComponentMass.of(asm.mass(compact=True)).m, a.m)
    finally:
        shift._ROW_CHUNK = old


@needs_numba
@pytest.mark.parametrize("parallel", [False, True])
def test_split_node_blocks_are_the_matrix_bit_for_bit(parallel, monkeypatch):
    """``SplitNodeBlocks``: ``hi`` the float32 rounding (shared by :meth:`high`), ``hi + lo`` every
    float64 entry exactly (also through numpy's split), and its compiled product (a vector, a block;
    serial, parallel) the float64 kernel's, bit for bit."""
    monkeypatch.setattr(bsr, "PARALLEL_NNZ", 0 if parallel else 10**12)
    Kb = bsr.node_blocks(Assembler(BOX, "q1i", fixed_dofs=WHOLE).stiffness())
    Kb.data[0, 0, 1] = 3e-39                                          # a subnormal float32
    Kb.data[1, 2, 2] = -1e-300                                        # below float32's range: 2^-181
    S = bsr.SplitNodeBlocks(Kb)
    np.testing.assert_array_equal(S.hi, Kb.data.astype(np.float32))
    rebuilt = S.tobsr().data
    assert abs(rebuilt[1, 2, 2] - Kb.data[1, 2, 2]) <= 2.0**-181
    rebuilt[1, 2, 2] = Kb.data[1, 2, 2]
    np.testing.assert_array_equal(rebuilt, Kb.data)
    assert np.shares_memory(S.high().data, S.hi) and S.high().dtype == np.float32
    np.testing.assert_array_equal(S.tocsr().toarray(), S.tobsr().toarray())
    monkeypatch.setattr(bsr, "_split_values", None)
    monkeypatch.setattr(bsr, "SPLIT_CHUNK", 5)
    by_numpy = bsr.SplitNodeBlocks(Kb)
    np.testing.assert_array_equal(by_numpy.hi, S.hi)
    np.testing.assert_array_equal(by_numpy.lo, S.lo)
    Kb.data[1, 2, 2] = 0.0
    S = bsr.SplitNodeBlocks(Kb)
    X = np.random.default_rng(3).standard_normal((Kb.shape[0], 4))
    prod, f64 = bsr.NodeBlockProduct(S, "numba"), bsr.NodeBlockProduct(Kb, "numba")
    assert prod.parallel == parallel
    np.testing.assert_array_equal(prod(X), f64(X))
    np.testing.assert_array_equal(prod(X[:, 1]), f64(X[:, 1:2]).ravel())
    np.testing.assert_array_equal(S @ X, f64(X))
    with pytest.raises(ValueError):
        bsr.NodeBlockProduct(S, "numpy")
    Kb.data[2, 0, 0] = 1e39                                           # beyond float32: not split
    with pytest.raises(ValueError, match="float32"):
        bsr.SplitNodeBlocks(Kb)


@needs_numba
def test_float32_v_cycle_keeps_its_finest_matrix_once():
    """``LatticeAMG(dtype=float32)`` compiled: the finest ``A`` split in two, the smoother reading its
    float32 part (no second copy), the float64 products those of ``A`` itself, bit for bit."""
    m = CubeModel.box((24, 4, 4), 0.05, youngs=1e7, poisson=0.3, density=1000.0)
    asm = Assembler(m, "q1i", fixed_dofs=np.arange(3 * 25))
    K = asm.stiffness()
    amg = multigrid.LatticeAMG(K, rigid_body_modes(m.nodes_m, asm.free_dofs), max_coarse=50, dtype=np.float32)
    fine = amg.levels[0]
    assert isinstance(fine.A, bsr.SplitNodeBlocks)
    assert np.shares_memory(fine.smoothing.A.data, fine.A.hi)
    X = np.random.default_rng(1).standard_normal((K.shape[0], 3))
    np.testing.assert_array_equal(fine(X), bsr.NodeBlockProduct(bsr.node_blocks(K), "numba")(X))


def test_chunked_set_up_builds_the_same_hierarchy(monkeypatch):
    """The prolongator and the coarse matrix formed over chunks of rows: the finest ``P`` bit for bit,
    the coarse matrices to round-off."""
    m = CubeModel.box((24, 6, 5), 0.05, youngs=1e7, poisson=0.3, density=1000.0)
    asm = Assembler(m, "q1i", fixed_dofs=np.arange(3 * 42))
    K, B = asm.stiffness(), rigid_body_modes(m.nodes_m, asm.free_dofs)
    one = multigrid.LatticeAMG(K, B, max_coarse=50)
    monkeypatch.setattr(multigrid, "SETUP_ROWS", 7)
    assert len(multigrid._row_chunks(K.shape[0] // 3)) == multigrid.SETUP_CHUNKS
    many = multigrid.LatticeAMG(K, B, max_coarse=50)
    assert len(one.levels) == len(many.levels) > 2
    np.testing.assert_array_equal(one.levels[0].P.toarray(), many.levels[0].P.toarray())
    for a, b in zip(one.levels[1:], many.levels[1:]):
        ref = a.A.toarray()
        np.testing.assert_allclose(b.A.toarray(), ref, rtol=0, atol=1e-13 * np.abs(ref).max())


@pytest.mark.parametrize("name, fix", [("beam", "x<min+0.01"), ("chair", "z<min+0.01")])
def test_modal_frequencies_are_shift_inverts_of_the_full_matrices(name, fix):
    """``sc_fem.modal`` with LOBPCG (compact mass, released assembler, split finest matrix) against
    shift-invert on the matrices assembled the plain way: the same frequencies to 1e-8."""
    model = sc_fem.voxelize(f"builtin:{name}", resolution=16)
    got = sc_fem.modal(model, n_modes=4, fix=fix, eigen="lobpcg")
    asm = Assembler(model, "q1i", fixed_dofs=sc_fem.fixed_dofs(sc_fem.fixed_nodes(model, fix)))
    ref = solve_eigen(asm.stiffness(), asm.mass(), 4, method="shift-invert", backend="splu")
    np.testing.assert_allclose(got.frequencies, np.sqrt(ref.eigenvalues) / (2 * np.pi), rtol=1e-8)


@needs_numba
def test_node_blocks_in_place_are_the_copied_blocks():
    """``node_blocks(A, overwrite=True)``: the blocks of the copy, their values in ``A``'s own array
    (reordered); a matrix whose rows do not share node columns is left as it was and copied."""
    K = Assembler(BOX, "q1i", fixed_dofs=WHOLE).stiffness()
    ref = bsr.node_blocks(K)
    A = K.copy()
    got = bsr.node_blocks(A, overwrite=True)
    assert np.shares_memory(got.data, A.data)
    np.testing.assert_array_equal(got.data, ref.data)
    np.testing.assert_array_equal(got.indices, ref.indices)
    np.testing.assert_array_equal(got.indptr, ref.indptr)
    partial = Assembler(BOX, "q1i", fixed_dofs=[0, 4, 5]).stiffness()       # a node fixed in x alone
    before = partial.copy()
    got = bsr.node_blocks(partial, overwrite=True)
    _same(partial, before)
    np.testing.assert_array_equal(got.toarray(), before.toarray())


@needs_numba
def test_compiled_subset_shift_is_the_numpy_one(monkeypatch):
    """``K - sigma M`` for ``M``'s entries among ``K``'s: the compiled row merge and numpy's chunked
    search give the same values, and both refuse (untouched) an ``M`` entry that ``K`` lacks."""
    from sc_fem.fem import shift

    asm = Assembler(BOX, "q1i", fixed_dofs=WHOLE)
    K, Mc = asm.stiffness(), asm.mass(compact=True)
    outside = Mc.tolil()
    outside[3, K.shape[1] - 1] = 1.0
    outside = outside.tocsr()
    got = {}
    for compiled in (True, False):
        if not compiled:
            monkeypatch.setattr(shift, "_subset_rows", None)
            monkeypatch.setattr(shift, "_ROW_CHUNK", 7)
        data = K.data.copy()
        assert shift._subtract_subset(K, Mc, -2.5e3, data)
        got[compiled] = data
        again = K.data.copy()
        assert not shift._subtract_subset(K, outside, -2.5e3, again)
        np.testing.assert_array_equal(again, K.data)
    np.testing.assert_array_equal(got[True], got[False])


@pytest.mark.parametrize("kernel", [pytest.param("numba", marks=needs_numba), "numpy"])
def test_a_mass_not_m_times_identity_goes_the_full_way(kernel):
    """Element matrices whose 3 x 3 blocks are not ``m_ab I``: no node matrix (either kernel), and the
    compact ``M`` is then the full one without its zeros."""
    asm = Assembler(BOX, "q1i", fixed_dofs=WHOLE, kernel=kernel)
    rng = np.random.default_rng(0)

    def coupled(s, e):
        v = rng.random((e - s, 24, 24))
        return (v + v.transpose(0, 2, 1)).reshape(e - s, 576)

    assert nodemass.node_values(asm, coupled, _CHUNK, _PAIR_OFFSET) is None
    assert nodemass.compact_mass(asm, coupled, _CHUNK, _PAIR_OFFSET) is None


def test_expand_components_by_numpy_is_the_compiled_one():
    """The node matrix written out per component: numpy's index arithmetic (any chunk of node rows)
    and the compiled loop give the same arrays."""
    asm = Assembler(BOX, "q1i", fixed_dofs=WHOLE)
    mdata = np.arange(1.0, asm.nnz // 9 + 1)
    ref = nodemass.expand_components(asm.indptr, asm.indices, mdata, asm.shape, "numba")
    old = nodemass._ROW_CHUNK
    try:
        nodemass._ROW_CHUNK = 5
        _same(nodemass.expand_components(asm.indptr, asm.indices, mdata, asm.shape, "numpy"), ref)
    finally:
        nodemass._ROW_CHUNK = old
    K = asm.stiffness()
    assert all(set(ref.indices[ref.indptr[r]:ref.indptr[r + 1]]) <= set(K.indices[K.indptr[r]:K.indptr[r + 1]])
               for r in range(K.shape[0]))


@pytest.mark.parametrize("shape", [(40, 10, 10), (60, 15, 15)])
def test_lobpcgs_memory_estimate_covers_what_the_solve_allocates(shape):
    """``auto`` refuses LOBPCG when its estimate exceeds the budget: the estimate must cover what the
    eigensolve allocates (tracemalloc's peak; K and M handed over as modal does) without being
    several times too large (a million cubes was refused at 11.7 GB where 4.5 GiB were needed)."""
    model = CubeModel.box(shape, 0.1, youngs=2e11, poisson=0.3, density=7850.0)
    asm = Assembler(model, "q1i", fixed_dofs=sc_fem.fixed_dofs(sc_fem.fixed_nodes(model, "x<min+1e-9")))
    K, M = asm.stiffness(), asm.mass()
    n, nnz = K.shape[0], K.nnz
    solver = EigenSolver(K, M, method="lobpcg", near_null=rigid_body_modes(model.nodes_m, asm.free_dofs),
                         overwrite=True)
    del K, M
    tracemalloc.start()
    try:
        solver.solve(6)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    estimate = lobpcg_memory_estimate(n, nnz, 6)
    assert peak <= estimate <= 1.6 * peak, (peak / n, estimate / n)
