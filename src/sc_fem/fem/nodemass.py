"""The consistent mass of a lattice as its nonzeros alone (:func:`compact_mass`).

A cube's consistent mass couples the same component of two nodes only (every 3 x 3 node block is
``m_ab I``), so on the assembler's pattern (:class:`~sc_fem.fem.assemble.Assembler`, 81 columns per
row of a solid lattice, shared with ``K``) two entries in three are zeros. :func:`compact_mass`
sums the scalar ``m_ab`` of every cube into one value per pair of free nodes that share a cube (a
ninth of the entries), cube after cube in the order of the assembler's scatter (so every sum is the
same, bit for bit), and writes ``M`` with its 27 nonzeros per row and its own index arrays: 12
bytes per nonzero, ~320 bytes per DOF instead of the 648 of its values on ``K``'s pattern, and
assembled in a ninth of the work. The eigensolvers take ``K - sigma M`` on ``K``'s pattern in place
(:func:`sc_fem.fem.shift.shift_in_place`) and ``M`` as :class:`~sc_fem.fem.shift.ComponentMass`.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._progress import stage_bar
from .assemble_jit import expand_components as compiled_expand, fill_nodes

_ROW_CHUNK = 1 << 13
"""Node rows per chunk while ``M``'s arrays are written (bounded temporaries)."""

_EYE3 = np.eye(3)[None, None, :, None, :]


def node_values(asm, values_of_chunk, chunk: int, pair: np.ndarray) -> np.ndarray | None:
    """The scalar node matrix's values (one per stored 3 x 3 block of ``asm``'s pattern), or None
    when a cube's matrix is not ``m_ab I`` per block.

    Parameters
    ----------
    asm, values_of_chunk, chunk, pair
        As :func:`compact_mass` (``asm`` with whole nodes free or fixed).

    Returns
    -------
    ndarray of float64, shape (asm.nnz // 9,) or None
    """
    model = asm.model
    free = asm._free3[:, 0]
    mstart = asm._rowstart[0] // 9                        # 9 entries per block before a node's rows
    data = np.zeros(asm.nnz // 9)
    hexes = np.ascontiguousarray(model.hexes)
    for s in range(0, model.n_cubes, chunk):              # loop over chunks of cubes
        e = min(s + chunk, model.n_cubes)
        vals = np.ascontiguousarray(values_of_chunk(s, e), dtype=np.float64).reshape(e - s, 576)
        if fill_nodes is not None and asm.kernel == "numba":
            if not fill_nodes(data, vals, hexes, s, mstart, asm._coloff, free, pair):
                return None
            continue
        v = vals.reshape(e - s, 8, 3, 8, 3)
        scalar = v[:, :, 0, :, 0]
        if not np.array_equal(v, scalar[:, :, None, :, None] * _EYE3):
            return None
        hx = hexes[s:e]
        pos = mstart[hx][:, :, None] + asm._coloff[(27 * hx)[:, :, None] + pair] // 3
        keep = free[hx][:, :, None] & free[hx][:, None, :]
        np.add.at(data, pos[keep], scalar[keep])
    return data


def expand_components(indptr: np.ndarray, indices: np.ndarray, mdata: np.ndarray, shape: tuple[int, int],
                      kernel: str = "numba") -> sp.csr_matrix:
    """``M = m (x) I3`` on whole free nodes from the node matrix's values and the pattern of ``K``.

    Parameters
    ----------
    indptr, indices : ndarray of int
        ``K``'s CSR pattern (node-major DOFs, whole nodes, 3 columns per node block).
    mdata : ndarray, shape (nnz(K) // 9,)
        ``m`` per stored node block, in the blocks' order, kg.
    shape : tuple
        ``(n, n)``, ``n = 3 x`` free nodes.
    kernel : {"numba", "numpy"}
        Compiled (on every core, when numba is installed) or numpy's index arithmetic, chunk of node
        rows by chunk; the same arrays.

    Returns
    -------
    scipy.sparse.csr_matrix, shape ``shape``
        Row ``3 r + c`` holds ``m[r, j]`` at column ``3 j + c`` for every block ``j`` of node ``r``'s
        rows (sorted; stored zeros only where ``m`` has them), kg.
    """
    n = shape[0]
    bptr = indptr[0::3] // 9                              # node r's blocks: bptr[r] .. bptr[r + 1]
    length = np.diff(bptr)
    mptr = np.empty(n + 1, dtype=indptr.dtype)
    mptr[:-1] = (3 * bptr[:-1, None] + np.arange(3) * length[:, None]).ravel()
    mptr[-1] = 3 * bptr[-1]
    data = np.empty(3 * len(mdata))
    idx = np.empty(3 * len(mdata), dtype=indices.dtype)
    if compiled_expand is not None and kernel == "numba":
        compiled_expand(bptr, indices, mdata, data, idx)
    else:
        _expand_numpy(bptr, indices, mdata, data, idx)
    M = sp.csr_matrix((data, idx, mptr), shape=shape)
    M.has_sorted_indices = True
    return M


def _expand_numpy(bptr, indices, mdata, data, idx) -> None:
    """:func:`sc_fem.fem.assemble_jit._expand_components_py` by index arithmetic, chunk of node rows by chunk."""
    length = np.diff(bptr)
    for r0 in range(0, len(length), _ROW_CHUNK):           # loop over chunks of node rows
        r1 = min(r0 + _ROW_CHUNK, len(length))
        q0, q1 = 3 * int(bptr[r0]), 3 * int(bptr[r1])
        L = np.repeat(length[r0:r1], 3 * length[r0:r1])   # the row's blocks, per entry of M
        u = np.arange(q1 - q0) - np.repeat(3 * (bptr[r0:r1] - bptr[r0]), 3 * length[r0:r1])
        c, t = u // np.maximum(L, 1), u % np.maximum(L, 1)    # component, block within the row
        first = np.repeat(bptr[r0:r1], 3 * length[r0:r1])
        data[q0:q1] = mdata[first + t]
        idx[q0:q1] = indices[9 * first + 3 * c * L + 3 * t + c]


def compact_mass(asm, values_of_chunk, chunk: int, pair: np.ndarray) -> sp.csr_matrix | None:
    """``M`` without its structural zeros, from the node matrix of the scalar blocks; None when a node
    is fixed in some components only or a cube's blocks are not ``m_ab I`` (the caller then drops
    the zeros of the full ``M``).

    Parameters
    ----------
    asm : Assembler
        Its pattern (``indptr``, ``indices``, the per-node tables).
    values_of_chunk : callable
        ``(s, e) -> (e - s, 576)`` flattened element mass matrices, kg.
    chunk : int
        Cubes per chunk.
    pair : ndarray of int, shape (8, 8)
        Stencil offset (0..26) of corner ``b`` seen from corner ``a``.

    Returns
    -------
    scipy.sparse.csr_matrix, shape ``asm.shape``, or None
        Mass, kg.
    """
    free3 = asm._free3
    if not np.all(free3.all(axis=1) | ~free3.any(axis=1)):
        return None
    with stage_bar("assemble M", asm.model.n_cubes, unit="cube") as bar:
        mdata = node_values(asm, values_of_chunk, chunk, pair)
        bar.update(asm.model.n_cubes)
    return None if mdata is None else expand_components(asm.indptr, asm.indices, mdata, asm.shape, asm.kernel)
