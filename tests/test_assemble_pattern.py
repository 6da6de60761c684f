"""The fast assembler's CSR pattern and values against a plain COO oracle.

The oracle scatters every element entry with ``scipy.sparse.coo_matrix(...).tocsr()`` (which sums
duplicates and sorts columns) and drops the fixed rows and columns by slicing; it shares nothing
with :class:`~sc_fem.fem.assemble.Assembler`'s stencil-based pattern and on-the-fly slots, so a
single wrong slot, a missing or extra column, or a wrong fixed-DOF removal fails these tests.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest
import scipy.sparse as sp

from sc_fem.fem.assemble import Assembler, assemble
from sc_fem.lattice.boundary import fixed_dofs
from sc_fem.fem.elements import cube_stiffness, reference_mass
from sc_fem.lattice.cubes import CubeModel


def lattice(shape, seed, fill=0.6):
    """Random cubes of a box (holes, several components) with per-cube materials and masses."""
    rng = np.random.default_rng(seed)
    occ = rng.random(shape) < fill
    occ.flat[0] = True
    cells = np.argwhere(occ)
    n = len(cells)
    return CubeModel.from_cells(cells, origin=(0.1, 0.2, -0.3), pitch=0.02, scale=1.0,
                                mass=rng.uniform(0.5, 2.0, n), youngs=rng.uniform(1e8, 3e11, n),
                                poisson=rng.uniform(0.0, 0.45, n), density=1000.0)


def coo_oracle(model, values, free):
    """CSR from all element entries ``values`` (n, 24, 24) by COO summation, restricted to ``free``."""
    dofs = (3 * model.hexes[:, :, None] + np.arange(3)).reshape(-1, 24)
    rows = np.repeat(dofs, 24, axis=1).ravel()
    cols = np.tile(dofs, (1, 24)).ravel()
    A = sp.coo_matrix((values.ravel(), (rows, cols)), shape=(model.n_dofs,) * 2).tocsr()
    idx = np.flatnonzero(free)
    A = A[idx][:, idx].tocsr()
    A.sort_indices()
    return A


def assert_same(A, B):
    """Same shape, same pattern (indptr and column indices) and same values up to rounding."""
    A.check_format(full_check=True)
    assert isinstance(A, sp.csr_matrix) and A.dtype == np.float64
    assert A.shape == B.shape and A.has_sorted_indices
    assert np.array_equal(A.indptr, B.indptr)
    assert np.array_equal(A.indices, B.indices)
    np.testing.assert_allclose(A.data, B.data, rtol=1e-12, atol=1e-13 * np.abs(B.data).max())


def free_mask(model, fixed):
    free = np.ones(model.n_dofs, dtype=bool)
    free[fixed] = False
    return free


FIXINGS = {
    "none": lambda model, rng: np.zeros(0, dtype=np.int64),
    "nodes": lambda model, rng: fixed_dofs(rng.choice(model.n_nodes, model.n_nodes // 4, replace=False)),
    "single dofs": lambda model, rng: rng.choice(model.n_dofs, model.n_dofs // 5, replace=False),
    "mixed": lambda model, rng: np.union1d(fixed_dofs(rng.choice(model.n_nodes, 3, replace=False)),
                                           rng.choice(model.n_dofs, 7, replace=False)),
}


@pytest.mark.parametrize("fixing", list(FIXINGS))
@pytest.mark.parametrize("element", ["q1i", "q1"])
@pytest.mark.parametrize("shape,seed,fill", [((1, 1, 1), 0, 0.6), ((2, 3, 1), 1, 0.6), ((7, 5, 6), 2, 0.6),
                                             ((3, 9, 4), 3, 0.6), ((8, 7, 6), 4, 0.97)])
def test_pattern_and_values_match_coo_oracle(shape, seed, fill, element, fixing):
    """Sparse random lattices (every cube on a boundary) and a nearly solid one with a few holes
    (interior cubes, whose slots follow a template, next to boundary cubes)."""
    model = lattice(shape, seed, fill)
    fixed = FIXINGS[fixing](model, np.random.default_rng(seed + 10))
    free = free_mask(model, fixed)
    A = Assembler(model, element, fixed_dofs=fixed)
    assert A.shape == (int(free.sum()),) * 2
    if fill > 0.9 and fixing == "none":
        assert 0 < A._interior.sum() < model.n_cubes             # both slot paths are exercised
    K, M = A.stiffness(), A.mass()
    assert_same(K, coo_oracle(model, cube_stiffness(model, element), free))
    assert_same(M, coo_oracle(model, model.mass[:, None, None] * reference_mass(), free))
    assert K.indices.dtype == K.indptr.dtype == np.int32
    assert np.shares_memory(M.indices, K.indices) and np.shares_memory(M.indptr, K.indptr)   # one pattern
    Kf, Mf = assemble(model, element, fixed_dofs=fixed)
    assert_same(Kf, K) and assert_same(Mf, M)


@pytest.mark.parametrize("cache_slots", [False, True, None])
@pytest.mark.parametrize("fixing", ["none", "mixed"])
def test_refill_with_arbitrary_element_matrices_matches_coo_oracle(fixing, cache_slots):
    """Non-symmetric random element matrices: every (a, c, b, d) entry must land in its own slot,
    on the first fill and on re-fills (from cached slots when ``cache_slots``)."""
    model = lattice((6, 4, 5), 4)
    rng = np.random.default_rng(5)
    fixed = FIXINGS[fixing](model, rng)
    free = free_mask(model, fixed)
    A = Assembler(model, "q1i", fixed_dofs=fixed, cache_slots=cache_slots)
    assert_same(A.mass(), coo_oracle(model, model.mass[:, None, None] * reference_mass(), free))
    assert (A._cache is None) == (cache_slots is False) and bool(A._cache) == bool(cache_slots)
    for _ in range(3):                                            # re-fill on one pattern
        Ke = rng.normal(size=(model.n_cubes, 24, 24))
        assert_same(A.stiffness(element_matrices=Ke), coo_oracle(model, Ke, free))
    assert bool(A._cache) == (cache_slots is not False)           # None: a small model's re-fills keep them
    assert_same(A.mass(), coo_oracle(model, model.mass[:, None, None] * reference_mass(), free))


def test_default_slot_cache_is_bounded(monkeypatch):
    asm_mod = importlib.import_module("sc_fem.fem.assemble")
    monkeypatch.setattr(asm_mod, "_AUTO_CACHE_BYTES", 2304 * 10)
    model = lattice((4, 4, 4), 5, fill=0.9)
    assert model.n_cubes > 10
    A = Assembler(model, "q1")
    Ke = np.random.default_rng(0).normal(size=(model.n_cubes, 24, 24))
    assert_same(A.stiffness(element_matrices=Ke), coo_oracle(model, Ke, free_mask(model, [])))
    assert A._cache is None


def test_chunk_boundaries_and_many_cubes(monkeypatch):
    """Chunks smaller than the lattice (cubes and node rows split across chunks) change nothing."""
    asm_mod = importlib.import_module("sc_fem.fem.assemble")   # the module, not the function

    model = lattice((12, 10, 9), 6, fill=0.95)
    fixed = FIXINGS["mixed"](model, np.random.default_rng(7))
    free = free_mask(model, fixed)
    Ke = np.random.default_rng(8).normal(size=(model.n_cubes, 24, 24))
    ref = coo_oracle(model, Ke, free)
    for chunk, node_chunk in [(1, 1), (7, 13), (100, 1000)]:
        monkeypatch.setattr(asm_mod, "_CHUNK", chunk)
        monkeypatch.setattr(asm_mod, "_NODE_CHUNK", node_chunk)
        assert_same(Assembler(model, "q1", fixed_dofs=fixed).stiffness(element_matrices=Ke), ref)


def test_all_dofs_fixed_gives_empty_matrices():
    model = lattice((2, 2, 2), 9)
    A = Assembler(model, "q1", fixed_dofs=np.arange(model.n_dofs))
    K, M = A.stiffness(), A.mass()
    assert K.shape == M.shape == (0, 0) and K.nnz == M.nnz == 0
