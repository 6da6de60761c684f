"""Element matrices scattered into one sparse matrix, the pattern found once for several matrices
(the stiffness and the mass of the same elements): :func:`block_pattern`, then :func:`scatter`.

The pattern is found on the nodes (3 x 3 blocks: 9 times fewer entries to sort than DOF by DOF)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp


@dataclass(frozen=True, eq=False)
class BlockPattern:
    """Where each node block of every element matrix lands in the global block matrix.

    Attributes
    ----------
    indptr, indices : ndarray of int
        The block-CSR structure over nodes (sorted, no duplicates).
    slot : ndarray of int, shape (e m^2,)
        The stored block each element node-pair block adds to.
    n_nodes : int
        Nodes of the global matrix (``3 n_nodes`` rows and columns).
    """

    indptr: np.ndarray
    indices: np.ndarray
    slot: np.ndarray
    n_nodes: int


def block_pattern(nodes: np.ndarray, n_nodes: int) -> BlockPattern:
    """The pattern of ``sum_e A_e`` over element matrices on ``nodes`` (3 DOFs each, ``3 node + c``).

    Parameters
    ----------
    nodes : ndarray of int, shape (e, m)
        Global node of each element's m nodes.
    n_nodes : int
        Global nodes.

    Returns
    -------
    BlockPattern
    """
    nodes = np.asarray(nodes, dtype=np.int64)
    key = (nodes[:, :, None] * n_nodes + nodes[:, None, :]).ravel()
    uniq, slot = np.unique(key, return_inverse=True)
    indptr = np.searchsorted(uniq // n_nodes, np.arange(n_nodes + 1)).astype(np.int64)
    return BlockPattern(indptr=indptr, indices=(uniq % n_nodes).astype(np.int64), slot=slot.ravel(),
                        n_nodes=int(n_nodes))


def scatter(pattern: BlockPattern, values: np.ndarray) -> sp.csr_matrix:
    """``sum_e A_e`` of element matrices ``values`` (e, 3 m, 3 m) (DOF ``3 node + c``) on the pattern.

    Parameters
    ----------
    pattern : BlockPattern
    values : ndarray, shape (e, 3 m, 3 m)

    Returns
    -------
    scipy.sparse.csr_matrix, shape (3 n_nodes, 3 n_nodes)
    """
    v = np.asarray(values, dtype=np.float64)
    e, m3 = v.shape[:2]
    blocks = v.reshape(e, m3 // 3, 3, m3 // 3, 3).transpose(0, 1, 3, 2, 4).reshape(-1, 9)
    nb = len(pattern.indices)
    data = np.stack([np.bincount(pattern.slot, weights=blocks[:, k], minlength=nb) for k in range(9)], axis=1)
    n = 3 * pattern.n_nodes
    A = sp.bsr_matrix((data.reshape(nb, 3, 3), pattern.indices, pattern.indptr), shape=(n, n))
    return A.tocsr()
