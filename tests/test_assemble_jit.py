"""The compiled scatter (``Assembler(kernel="numba")``) against the numpy scatter and the COO oracle.

Both kernels fill the same CSR pattern; the compiled one computes every entry's position inline
(interior template or general stencil tables, fixed DOFs skipped) instead of materialising the
(chunk, 576) position array, so a wrong position, a fixed DOF that is not skipped or a wrong column
rank on a partly fixed node changes the values here. The oracle and the lattices are those of
``test_assemble_pattern.py``.
"""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from sc_fem import _jit
from sc_fem.errors import InputError
from sc_fem.fem import assemble_jit
from sc_fem.fem.assemble import Assembler
from sc_fem.lattice.boundary import fixed_dofs
from sc_fem.fem.elements import cube_stiffness, element_stiffness, reference_mass
from sc_fem.material import lame
from sc_fem.lattice.cubes import CubeModel
from test_assemble_pattern import FIXINGS, assert_same, coo_oracle, free_mask, lattice

asm_mod = importlib.import_module("sc_fem.fem.assemble")      # the module, not the function


def _box_end_fixed():
    """A solid box held at x = 0: mostly interior cubes, the fixed end and the faces around them."""
    model = CubeModel.box((10, 6, 5), 0.02, youngs=70e9, poisson=0.33, density=2700.0)
    return model, fixed_dofs(np.flatnonzero(model.node_index[:, 0] == 0))


def _box_x_fixed():
    """Partly fixed nodes: only the x DOF of a random quarter of the nodes (and y, z of two more)."""
    model = CubeModel.box((9, 7, 6), 0.01)
    rng = np.random.default_rng(3)
    nodes = rng.choice(model.n_nodes, model.n_nodes // 4, replace=False)
    return model, np.concatenate([3 * nodes, 3 * nodes[:2] + 1, 3 * nodes[:2] + 2])


def _holes(fixing):
    def make():
        model = lattice((8, 7, 6), 4, fill=0.97)                # per-cube E, nu, mass; a few holes
        return model, FIXINGS[fixing](model, np.random.default_rng(11))
    return make


CASES = {
    "box, one end fixed": _box_end_fixed,
    "box, x of some nodes fixed": _box_x_fixed,
    "holes, free": _holes("none"),
    "holes, mixed fixing": _holes("mixed"),
    "holes, single dofs": _holes("single dofs"),
}
INTERIOR = {"box, one end fixed", "holes, free", "holes, mixed fixing"}
"""Cases with interior cubes (template positions) next to general ones; in the others a fixed DOF
is near every cube."""


def _fills(A, model, free, rng):
    """Every fill an assembler offers (default, per-cube materials, re-fills, mass again), each
    with its oracle: a list of (name, matrix, oracle)."""
    n = model.n_cubes
    out = [("K", A.stiffness(), coo_oracle(model, cube_stiffness(model, A.element), free)),
           ("M", A.mass(), coo_oracle(model, model.mass[:, None, None] * reference_mass(), free))]
    E, nu = rng.uniform(1e9, 2e11, n), rng.uniform(0.05, 0.45, n)
    out.append(("K(E, nu)", A.stiffness(E, nu),
                coo_oracle(model, element_stiffness(A.element, *lame(E, nu), model.h), free)))
    for k in range(2):                                          # the second re-fill may use cached slots
        Ke = rng.normal(size=(n, 24, 24))                       # non-symmetric: every entry its own slot
        out.append((f"refill {k}", A.stiffness(element_matrices=Ke), coo_oracle(model, Ke, free)))
    masses = rng.uniform(0.1, 3.0, n)
    out.append(("M(masses)", A.mass(masses=masses), coo_oracle(model, masses[:, None, None] * reference_mass(), free)))
    return out


def _forbid(monkeypatch, obj, *names):
    def boom(*args, **kwargs):
        raise AssertionError("this path must not run")
    for name in names:
        monkeypatch.setattr(obj, name, boom)


@pytest.mark.parametrize("chunk", [2048, 7])
@pytest.mark.parametrize("cache_slots", [False, True, None])
@pytest.mark.parametrize("case", list(CASES))
def test_numba_equals_numpy_and_oracle(case, cache_slots, chunk, monkeypatch):
    pytest.importorskip("numba")
    monkeypatch.setattr(asm_mod, "_CHUNK", chunk)
    model, fixed = CASES[case]()
    free = free_mask(model, fixed)
    nb = Assembler(model, "q1i", fixed_dofs=fixed, cache_slots=cache_slots, kernel="numba")
    npy = Assembler(model, "q1i", fixed_dofs=fixed, cache_slots=cache_slots, kernel="numpy")
    assert nb.kernel == "numba" and npy.kernel == "numpy"
    if case in INTERIOR:
        assert 0 < nb._interior.sum() < model.n_cubes          # template and general cubes both run
    if cache_slots is False:                                    # positions inline, never materialised
        _forbid(monkeypatch, Assembler, "_slots", "_general_slots")
    got = _fills(nb, model, free, np.random.default_rng(1))
    monkeypatch.undo()
    monkeypatch.setattr(asm_mod, "_CHUNK", chunk)
    _forbid(monkeypatch, assemble_jit, "fill", "add_at", "add_at_masked")   # the numpy path is numpy
    ref = _fills(npy, model, free, np.random.default_rng(1))
    for (name, A, oracle), (_, B, _) in zip(got, ref):
        assert_same(A, oracle)
        assert_same(A, B)
        assert np.array_equal(A.data, B.data), name             # same entries summed in the same order
        assert np.shares_memory(A.indices, nb.indices) and np.shares_memory(A.indptr, nb.indptr)
    assert (nb._cache is None) == (cache_slots is False)
    assert bool(nb._cache) == (cache_slots is not False)       # cached after the first (re-)fill
    assert bool(npy._cache) == bool(nb._cache)


@pytest.mark.parametrize("kernel", ["numpy", "numba"])
def test_q1_and_sparse_lattices_match_oracle(kernel):
    """Sparse random lattices (no interior cube: the general path only), q1, node fixings."""
    if kernel == "numba":
        pytest.importorskip("numba")
    for shape, seed, fixing in [((1, 1, 1), 0, "none"), ((7, 5, 6), 2, "nodes"), ((3, 9, 4), 3, "mixed")]:
        model = lattice(shape, seed, 0.6)
        fixed = FIXINGS[fixing](model, np.random.default_rng(seed + 10))
        free = free_mask(model, fixed)
        A = Assembler(model, "q1", fixed_dofs=fixed, kernel=kernel)
        assert A.kernel == kernel
        assert_same(A.stiffness(), coo_oracle(model, cube_stiffness(model, "q1"), free))
        assert_same(A.mass(), coo_oracle(model, model.mass[:, None, None] * reference_mass(), free))


def test_numba_all_dofs_fixed():
    pytest.importorskip("numba")
    model = lattice((3, 3, 3), 9, fill=0.9)
    A = Assembler(model, "q1i", fixed_dofs=np.arange(model.n_dofs), kernel="numba")
    K, M = A.stiffness(), A.mass()
    assert K.shape == M.shape == (0, 0) and K.nnz == M.nnz == 0


def test_kernel_choice_is_checked(monkeypatch):
    model, fixed = _box_end_fixed()
    assert Assembler(model, fixed_dofs=fixed, kernel="numpy").kernel == "numpy"
    for bad in ("cuda", "NUMBA", None):
        with pytest.raises(InputError, match="kernel must be 'auto', 'numba' or 'numpy'"):
            Assembler(model, fixed_dofs=fixed, kernel=bad)
    assert Assembler(model, fixed_dofs=fixed).kernel == ("numba" if assemble_jit.available() else "numpy")
    # without numba: "numba" is refused, "auto" falls back to numpy and still assembles correctly
    monkeypatch.setattr(_jit, "numba", None)
    _forbid(monkeypatch, assemble_jit, "fill", "add_at", "add_at_masked")
    assert not assemble_jit.available()
    with pytest.raises(InputError, match="needs numba"):
        Assembler(model, fixed_dofs=fixed, kernel="numba")
    A = Assembler(model, fixed_dofs=fixed)
    assert A.kernel == "numpy"
    free = free_mask(model, fixed)
    assert_same(A.stiffness(), coo_oracle(model, cube_stiffness(model, A.element), free))
