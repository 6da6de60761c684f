"""How cubes hang together: corner order, cells of points, shared nodes and connected components.

Corner order is scikit-fem's ``MeshHex`` order (:data:`HEX_CORNERS`). A node is a (grid corner,
body) pair, so cubes of different bodies in one cell share no node (virtual nodes); components
are found among neighbouring cubes of the same body.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .._jit import choose_kernel
from . import topology_jit

HEX_CORNERS = np.array(
    [[0, 0, 0], [0, 0, 1], [0, 1, 0], [1, 0, 0], [0, 1, 1], [1, 0, 1], [1, 1, 0], [1, 1, 1]],
    dtype=np.int64,
)
"""Offsets (dx, dy, dz) of the 8 corners of a cube, in scikit-fem ``MeshHex`` order."""

CONNECTIVITY = {"face": 1, "edge": 2, "vertex": 3}

NEIGHBOURS = np.array([(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)
                       if (a, b, c) != (0, 0, 0)], dtype=np.int64)
"""The offsets (26, 3) of a cell's face, edge and corner neighbours."""
"""Neighbourhoods for connected components: cubes sharing a face (6-connected, default),
an edge (18-connected) or a corner (26-connected)."""


VOXEL_INDEX_COMPILED_FROM = 4096
"""Points from which :func:`voxel_index` takes the compiled kernel (fewer: numpy, no call overhead)."""


def voxel_index(points: np.ndarray, origin: np.ndarray, pitch: float, dims: np.ndarray,
                kernel: str = "auto") -> np.ndarray:
    """Lattice cell (i, j, k) of each point, shape (n, 3) int64, clipped into the grid.

    Cells are half-open ``[lo, lo + pitch)``, except that points on the upper faces of the grid
    belong to the last cell. ``kernel``: the compiled one (:mod:`sc_fem.lattice.topology_jit`,
    with numba, from :data:`VOXEL_INDEX_COMPILED_FROM` points) or numpy; both give the same cells.
    """
    hi = np.asarray(dims, dtype=np.int64) - 1
    p = np.asarray(points)
    compiled = choose_kernel(kernel) == "numba" and (kernel == "numba" or len(p) >= VOXEL_INDEX_COMPILED_FROM)
    if compiled and p.ndim == 2 and p.shape[1] == 3:
        out = np.empty((len(p), 3), np.int64)
        topology_jit.cells(np.ascontiguousarray(p, dtype=np.float64), np.asarray(origin, dtype=np.float64).reshape(3),
                           float(pitch), np.broadcast_to(hi, 3).copy(), out)
        return out
    return np.clip(np.floor((p - origin) / pitch).astype(np.int64), 0, hi)


def voxel_keys(points: np.ndarray, origin: np.ndarray, pitch: float, dims: np.ndarray,
               kernel: str = "auto") -> np.ndarray:
    """The C-order linear index of each point's cell, shape (n,) int64:
    ``np.ravel_multi_index(voxel_index(points, origin, pitch, dims).T, dims)`` without the (n, 3)
    cells, compiled (:mod:`sc_fem.lattice.topology_jit`, with numba, from
    :data:`VOXEL_INDEX_COMPILED_FROM` points) or that numpy line; the same keys."""
    dims = np.asarray(dims, dtype=np.int64)
    p = np.asarray(points)
    compiled = choose_kernel(kernel) == "numba" and (kernel == "numba" or len(p) >= VOXEL_INDEX_COMPILED_FROM)
    if compiled and p.ndim == 2 and p.shape[1] == 3:
        out = np.empty(len(p), np.int64)
        topology_jit.keys(np.ascontiguousarray(p, dtype=np.float64), np.asarray(origin, dtype=np.float64).reshape(3),
                          float(pitch), dims - 1, out)
        return out
    return np.ravel_multi_index(voxel_index(p, origin, pitch, dims, kernel="numpy").T, dims)


def mark_cells(grid: np.ndarray, points: np.ndarray, origin: np.ndarray, pitch: float,
               select: np.ndarray | None = None, kernel: str = "auto") -> np.ndarray:
    """Set ``grid[cell] = True`` for the cell of every point (as :func:`voxel_index` finds it), in place.

    ``grid[tuple(voxel_index(points[select], origin, pitch, grid.shape).T)] = True`` without the
    cells array or the selected copy: one compiled pass (:mod:`sc_fem.lattice.topology_jit`, with
    numba, from :data:`VOXEL_INDEX_COMPILED_FROM` points) or that numpy line.

    Parameters
    ----------
    grid : ndarray of bool, shape dims
        The grid to mark (C-contiguous).
    points : ndarray, shape (n, 3)
        Model units.
    origin : ndarray, shape (3,)
        The grid's corner, model units.
    pitch : float
        The cells' side, model units.
    select : ndarray of bool, shape (n,), optional
        The points to mark (default all).
    kernel : {"auto", "numba", "numpy"}

    Returns
    -------
    ndarray of bool
        ``grid``.
    """
    p = np.asarray(points)
    dims = np.array(grid.shape, dtype=np.int64)
    compiled = choose_kernel(kernel) == "numba" and (kernel == "numba" or len(p) >= VOXEL_INDEX_COMPILED_FROM)
    if compiled and p.ndim == 2 and p.shape[1] == 3 and grid.flags.c_contiguous:
        sel = np.zeros(0, dtype=bool) if select is None else np.asarray(select, dtype=bool)
        topology_jit.mark(np.ascontiguousarray(p, dtype=np.float64), np.asarray(origin, dtype=np.float64).reshape(3),
                          float(pitch), dims - 1, sel, grid.reshape(-1))
        return grid
    grid[tuple(voxel_index(p if select is None else p[select], origin, pitch, dims, kernel="numpy").T)] = True
    return grid


DENSE_KEYS_PER_ITEM = 8
""":func:`unique_keys` marks the keys in a table when it has at most this many entries per key
(plus :data:`DENSE_KEYS_MIN`); larger, sparser key ranges are sorted."""

DENSE_KEYS_MIN = 1 << 22
"""Table entries :func:`unique_keys` allows whatever the number of keys (4 Mi: 32 MiB of indices)."""

DENSE_KEYS_MAX = 1 << 24
"""Table entries :func:`unique_keys` never exceeds (16 Mi: 128 MiB of indices; a 256^3 grid)."""


def unique_keys(keys: np.ndarray, size: int, return_inverse: bool = False):
    """``np.unique(keys, return_inverse=...)`` for integer keys in ``[0, size)``, by marking a table
    of ``size`` entries (O(n + size), no sort) when it is small enough (:data:`DENSE_KEYS_PER_ITEM`,
    :data:`DENSE_KEYS_MAX`): the same sorted keys and the same inverse.

    Parameters
    ----------
    keys : ndarray of int, shape (n,)
        Keys in ``[0, size)`` (linear cell or node indices).
    size : int
        The key range.
    return_inverse : bool
        Also return the index of each key in the result.

    Returns
    -------
    uniq : ndarray of int64, shape (u,)
        The distinct keys, ascending.
    inverse : ndarray of int64, shape (n,)
        With ``return_inverse``: ``uniq[inverse] == keys``.
    """
    keys = np.asarray(keys, dtype=np.int64).ravel()
    if size > min(DENSE_KEYS_PER_ITEM * len(keys) + DENSE_KEYS_MIN, DENSE_KEYS_MAX):
        out = np.unique(keys, return_inverse=return_inverse)
        return (out[0], out[1].reshape(-1).astype(np.int64)) if return_inverse else out
    mark = np.zeros(size, dtype=bool)
    mark[keys] = True
    uniq = np.flatnonzero(mark)
    if not return_inverse:
        return uniq
    rank = np.empty(size, dtype=np.int64)
    rank[uniq] = np.arange(len(uniq))
    return uniq, rank[keys]


def unique_cells(cells: np.ndarray, dims: np.ndarray) -> np.ndarray:
    """The distinct cells of ``cells`` (n, 3) int in a grid of ``dims``, shape (m, 3), sorted in
    C order (as ``np.unique(cells, axis=0)``, by their linear index: a 1-D sort, not a row sort)."""
    dims = np.asarray(dims, dtype=np.int64)
    lin = unique_keys(np.ravel_multi_index(np.asarray(cells, dtype=np.int64).T, dims), int(np.prod(dims)))
    return np.stack(np.unravel_index(lin, dims), axis=1).astype(np.int64)


def keyed_nodes(points: np.ndarray, ndims: np.ndarray, piece: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Number the lattice points that cubes carry, a node per (lattice point, body), vectorized.

    Parameters
    ----------
    points : ndarray of int, shape (n, k, 3)
        The lattice points of each of the n cubes (its corners, or the points of a finer lattice).
    ndims : ndarray of int, shape (3,)
        Extent of that lattice (points per axis).
    piece : ndarray of int, shape (n,)
        Body of each cube: cubes of different bodies share no node.

    Returns
    -------
    node_index : ndarray of int, shape (m, 3)
        Lattice point of each node.
    nodes : ndarray of int, shape (n, k)
        Node of each cube's points.
    """
    ndims = np.asarray(ndims, dtype=np.int64)
    return _keyed(np.ravel_multi_index(points.reshape(-1, 3).T, ndims).reshape(points.shape[:2]), ndims, piece)


def _keyed(lin: np.ndarray, ndims: np.ndarray, piece: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`keyed_nodes` from the points' linear indices ``lin`` (n, k) in a lattice of ``ndims``."""
    n, k = lin.shape
    n_p = int(piece.max()) + 1 if len(piece) else 1
    keys = lin.reshape(-1) if n_p == 1 else lin.reshape(-1) * n_p + np.repeat(piece, k)   # one body: the points
    uniq, inverse = unique_keys(keys, int(np.prod(ndims)) * n_p, return_inverse=True)
    node_index = np.stack(np.unravel_index(uniq // n_p, ndims), axis=1).astype(np.int64)
    return node_index, inverse.reshape(n, k).astype(np.int64, copy=False)


def nodes_and_hexes(cells: np.ndarray, dims: np.ndarray, piece: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique corner nodes of the cubes and the (n, 8) connectivity (:func:`keyed_nodes` on the
    corners): a node is a (grid corner, body) pair, so cubes of different bodies in one cell share
    no node. The corners' linear indices are the cell's plus each corner's offset (no (n, 8, 3)
    array of corner points)."""
    ndims = np.asarray(dims, dtype=np.int64) + 1
    cells = np.asarray(cells, dtype=np.int64)
    step = np.array([ndims[1] * ndims[2], ndims[2], 1], dtype=np.int64)
    lin = np.ravel_multi_index(cells.T, ndims)[:, None] + HEX_CORNERS @ step
    return _keyed(lin, ndims, piece)


def piece_labels(cells: np.ndarray, dims: np.ndarray, connectivity: str, piece: np.ndarray) -> tuple[np.ndarray, int]:
    """Connected components of cubes of the same body that are neighbours (graph on the sorted
    (cell, body) keys; labels in order of each component's first cube, as ``ndimage.label``)."""
    n_p = int(piece.max()) + 1
    dims = np.asarray(dims, dtype=np.int64)
    key = np.ravel_multi_index(cells.T, dims) * n_p + piece            # sorted (from_cells sorts)
    offs = np.argwhere(ndimage.generate_binary_structure(3, CONNECTIVITY[connectivity])) - 1
    offs = offs[[tuple(o) > (0, 0, 0) for o in offs]]                  # each neighbour pair once
    rows, cols = [], []
    for o in offs:                                                     # 3, 9 or 13 offsets
        nb = cells + o
        ok = np.all((nb >= 0) & (nb < dims), axis=1)
        k = np.ravel_multi_index(nb[ok].T, dims) * n_p + piece[ok]
        at = np.minimum(np.searchsorted(key, k), len(key) - 1)
        hit = key[at] == k
        rows.append(np.flatnonzero(ok)[hit])
        cols.append(at[hit])
    r, c = np.concatenate(rows), np.concatenate(cols)
    n_c, lab = connected_components(coo_matrix((np.ones(len(r)), (r, c)), shape=(len(cells),) * 2), directed=False)
    first = np.full(n_c, len(cells))
    np.minimum.at(first, lab, np.arange(len(cells)))
    rank = np.empty(n_c, np.int64)
    rank[np.argsort(first)] = np.arange(n_c)
    return rank[lab], n_c


def components(cells: np.ndarray, dims: np.ndarray, connectivity: str, piece: np.ndarray) -> np.ndarray:
    """Component label per cube, 0 = largest, by ``scipy.ndimage.label`` on the occupancy grid
    (one body) or by neighbours of the same body (:func:`piece_labels`)."""
    if len(piece) and piece.max() > 0:
        lab, n = piece_labels(cells, dims, connectivity, piece)
    else:
        grid = np.zeros(tuple(int(d) for d in dims), dtype=bool)
        grid[tuple(cells.T)] = True
        structure = ndimage.generate_binary_structure(3, CONNECTIVITY[connectivity])
        labels, n = ndimage.label(grid, structure=structure)
        lab = labels[tuple(cells.T)] - 1
    sizes = np.bincount(lab, minlength=n)
    rank = np.empty(n, dtype=np.int64)
    rank[np.argsort(-sizes, kind="stable")] = np.arange(n)
    return rank[lab]


def fine_to_coarse(coarse, fine, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which cubes of ``fine`` (the same mesh voxelized with ``pitch / n`` from the same origin)
    lie in which cube of ``coarse``, matched by cell and body.

    Parameters
    ----------
    coarse, fine : CubeModel
        The two lattices.
    n : int
        Fine cubes per coarse cube edge.

    Returns
    -------
    fine_index, coarse_index : ndarray of int, shape (k,)
        Matched pairs (fine cubes in no coarse cube of their body are left out).
    local : ndarray of int, shape (k, 3)
        Position of each fine cube inside its coarse cube, in ``[0, n)^3``.
    """
    parent = fine.cells // n
    n_p = int(max(coarse.piece.max(), fine.piece.max())) + 1
    key_c = np.ravel_multi_index(coarse.cells.T, coarse.dims) * n_p + coarse.piece      # sorted
    ok = np.all(parent < coarse.dims, axis=1)
    key_f = np.full(len(parent), -1, dtype=np.int64)
    key_f[ok] = np.ravel_multi_index(parent[ok].T, coarse.dims) * n_p + fine.piece[ok]
    at = np.minimum(np.searchsorted(key_c, key_f), len(key_c) - 1)
    hit = np.flatnonzero(ok & (key_c[at] == key_f))
    return hit, at[hit], fine.cells[hit] - n * parent[hit]
