"""The fine models of the multiscale cubes (:mod:`sc_fem.fem.multiscale`): each partly filled cube's
content voxelized finer, with nodes of its own, the nodes that follow the coarse field, and one
fine model per distinct content."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import InputError
from ..lattice.cubes import CubeModel
from ..lattice.topology import HEX_CORNERS, NEIGHBOURS, fine_to_coarse
from .elements import cube_mass_chunks, cube_stiffness
from .scatter import block_pattern, scatter


def _tied_nodes(coarse: CubeModel, cubes: np.ndarray, node_cube: np.ndarray, node_q: np.ndarray,
                s: int, held: np.ndarray | None = None) -> np.ndarray:
    """Which fine nodes (coarse cube ``node_cube``, local lattice point ``node_q`` in [0, s]^3)
    lie where their coarse cube meets another cube of its body holding material there, or on a
    face, edge or corner of the cube whose corners are all ``held`` (bool per coarse node)."""
    on_lo, on_hi = node_q == 0, node_q == s
    tied = np.zeros(len(node_q), dtype=bool)
    if held is not None and np.any(held):                # the fixed faces: their material is held too
        corner_held = np.asarray(held, dtype=bool)[coarse.hexes[cubes[node_cube]]]          # (m, 8)
        agree = (((HEX_CORNERS[None] == 0) | ~on_lo[:, None, :]) & ((HEX_CORNERS[None] == 1) | ~on_hi[:, None, :])).all(2)
        tied = (on_lo | on_hi).any(axis=1) & np.all(~agree | corner_held, axis=1)
    cell = coarse.cells[cubes[node_cube]]
    body = coarse.piece[cubes[node_cube]]
    n_p = int(coarse.piece.max()) + 1
    g = s * cell + node_q                                                    # the global fine lattice point
    key = np.ravel_multi_index(g.T, s * coarse.dims + 1) * n_p + body
    _, inv, count = np.unique(key, return_inverse=True, return_counts=True)
    tied |= count[inv.ravel()] >= 2                                          # another condensed cube has it
    # ... or a cube that is not condensed (a full cube: its polynomial covers its whole face)
    condensed = np.zeros(coarse.n_cubes, dtype=bool)
    condensed[cubes] = True
    key_cells = np.ravel_multi_index(coarse.cells.T, coarse.dims) * n_p + coarse.piece     # sorted
    bnd = np.flatnonzero((on_lo | on_hi).any(axis=1) & ~tied)
    for o in NEIGHBOURS:                                                       # the 26 neighbouring cells
        ok = np.all((o == 0) | ((o < 0) & on_lo[bnd]) | ((o > 0) & on_hi[bnd]), axis=1)
        sel = bnd[ok]
        nb = cell[sel] + o
        inside = np.all((nb >= 0) & (nb < coarse.dims), axis=1)
        sel, nb = sel[inside], nb[inside]
        k = np.ravel_multi_index(nb.T, coarse.dims) * n_p + body[sel]
        at = np.minimum(np.searchsorted(key_cells, k), len(key_cells) - 1)
        hit = (key_cells[at] == k) & ~condensed[at]
        tied[sel[hit]] = True
    return tied


def _floating_pieces(hexes: np.ndarray, n_nodes: int, tied: np.ndarray) -> np.ndarray:
    """Nodes of the fine pieces (connected through fine cubes) that hold no tied node."""
    k = len(hexes)
    inc = sp.csr_matrix((np.ones(8 * k), (np.repeat(np.arange(k), 8), hexes.ravel())), shape=(k, n_nodes))
    _, label = connected_components(inc.T @ inc, directed=False)
    has = np.zeros(label.max() + 1, dtype=bool)
    has[label[tied]] = True
    return ~has[label]


def _same_content(coarse: CubeModel, cubes: np.ndarray, fine: CubeModel, fidx: np.ndarray, fc: np.ndarray,
                  fl: np.ndarray, node_cube: np.ndarray, node_q: np.ndarray, tied: np.ndarray, s: int) -> np.ndarray:
    """For every cube of ``cubes`` (positions 0..n-1), the first cube of equal content: the same fine
    cubes at the same places with the same moments (to 1e-9 of a fine cube), the same tied nodes and
    the same material. Two 64-bit hashes per cube, summed over its fine cubes and tied nodes."""
    n = len(cubes)
    rng = np.random.default_rng(20261128)
    mom = np.round(np.asarray(fine.moments[fidx], dtype=float) * 1e9).astype(np.int64)
    rows = np.concatenate([fl, mom], axis=1).view(np.uint64)                # (k, 30)
    tq = node_q[tied].astype(np.int64).view(np.uint64)
    mat = np.stack([coarse.youngs[cubes], coarse.poisson[cubes], coarse.density[cubes]], axis=1)
    sig = [np.bincount(fc, minlength=n).astype(np.uint64), np.bincount(node_cube[tied], minlength=n).astype(np.uint64)]
    with np.errstate(over="ignore"):
        for _ in range(2):
            a = rng.integers(1, 2**63, size=rows.shape[1], dtype=np.uint64) | np.uint64(1)
            b = rng.integers(1, 2**63, size=3, dtype=np.uint64) | np.uint64(1)
            hf = (rows * a).sum(axis=1)
            hf ^= hf >> np.uint64(29)
            hf *= np.uint64(0x9E3779B97F4A7C15)
            ht = (tq * b).sum(axis=1)
            ht ^= ht >> np.uint64(31)
            ht *= np.uint64(0xBF58476D1CE4E5B9)
            acc_f = np.zeros(n, np.uint64)
            acc_t = np.zeros(n, np.uint64)
            np.add.at(acc_f, fc, hf)
            np.add.at(acc_t, node_cube[tied], ht)
            sig += [acc_f, acc_t]
    table = np.concatenate([np.stack(sig, axis=1).view(np.int64), mat.view(np.int64)], axis=1)
    _, first, inv = np.unique(table, axis=0, return_index=True, return_inverse=True)
    return first[inv.ravel()]


@dataclass(frozen=True, eq=False)
class FineSystem:
    """The fine models of the cubes to condense, one per distinct content, each with its own nodes.

    Attributes
    ----------
    K, M : scipy.sparse.csr_matrix, shape (3 m, 3 m)
        Stiffness (N/m) and consistent mass (kg) of all fine models together (block diagonal: no
        fine node is shared by two cubes), DOF ``3 node + c``.
    tied : ndarray of bool, shape (m,)
        The fine nodes that follow the coarse field.
    node_cube : ndarray of int, shape (m,)
        The distinct content (0..n-1) each fine node belongs to.
    node_q : ndarray of int, shape (m, 3)
        Its lattice point inside the coarse cube, in [0, s]^3.
    hexes : ndarray of int, shape (k, 8)
        The fine cubes' nodes; ``fine_cube`` (k,) their content, ``fine_local`` (k, 3) their cell in the cube.
    slot : ndarray of int, shape (n_cubes,)
        The content of every cube condensed (cubes of equal content share one fine model).
    """

    K: sp.csr_matrix
    M: sp.csr_matrix
    tied: np.ndarray
    node_cube: np.ndarray
    node_q: np.ndarray
    hexes: np.ndarray
    fine_cube: np.ndarray
    fine_local: np.ndarray
    slot: np.ndarray
    n: int


def fine_system(coarse: CubeModel, cubes: np.ndarray, fine: CubeModel, s: int, element: str = "q1i",
                held: np.ndarray | None = None) -> FineSystem:
    """The fine models of the coarse ``cubes``: their fine cubes, nodes, tied nodes and matrices.

    Parameters
    ----------
    coarse : CubeModel
        The coarse lattice.
    cubes : ndarray of int, shape (n,)
        The coarse cubes to condense, sorted (partly filled ones).
    fine : CubeModel
        The same source voxelized with ``coarse.pitch / s`` from the same origin and topology.
    s : int
        Fine cubes per coarse cube edge.
    element : str
        The fine cubes' element (:data:`sc_fem.fem.elements.ELEMENTS`).
    held : ndarray of bool, shape (m,), optional
        The coarse model's fixed nodes: the fine nodes on a face, edge or corner whose corners are
        all fixed follow the (fixed) coarse field, so the material there is held as well.

    Returns
    -------
    FineSystem
        The fine cubes carry their coarse cube's material (as the moments' integrals do).
    """
    cubes = np.asarray(cubes, dtype=np.int64)
    n_all = len(cubes)
    pos = np.full(coarse.n_cubes, -1, dtype=np.int64)
    pos[cubes] = np.arange(n_all)
    hit, parent, local = fine_to_coarse(coarse, fine, s)
    sel = pos[parent] >= 0
    fidx, fc, fl = hit[sel], pos[parent[sel]], local[sel]
    if len(fidx) == 0:
        raise InputError("no fine cube lies in the cubes to condense: the fine model does not match")
    # per-coarse-cube copies of the fine nodes, and which of them follow the coarse field
    span = (s + 1) ** 3
    key = fc[:, None] * span + np.ravel_multi_index((fl[:, None, :] + HEX_CORNERS[None]).reshape(-1, 3).T,
                                                     (s + 1,) * 3).reshape(-1, 8)
    ukey, hexes = np.unique(key, return_inverse=True)
    hexes = hexes.reshape(-1, 8)
    node_cube, node_q = ukey // span, np.stack(np.unravel_index(ukey % span, (s + 1,) * 3), axis=1)
    tied = _tied_nodes(coarse, cubes, node_cube, node_q, s, held)
    tied |= _floating_pieces(hexes, len(ukey), tied)
    # cubes of equal content (fine cubes, their moments, tied nodes, material) keep one fine model
    reps, slot = np.unique(_same_content(coarse, cubes, fine, fidx, fc, fl, node_cube, node_q, tied, s),
                           return_inverse=True)
    rpos = np.full(n_all, -1, dtype=np.int64)
    rpos[reps] = np.arange(len(reps))
    keep = rpos[fc] >= 0
    fidx, fc, fl, hexes = fidx[keep], rpos[fc[keep]], fl[keep], hexes[keep]
    used, hexes = np.unique(hexes, return_inverse=True)
    hexes = hexes.reshape(-1, 8)
    mask = np.zeros(fine.n_cubes, dtype=bool)
    mask[fidx] = True                                     # fidx is sorted: cube i of the subset is fidx[i]
    own = cubes[reps[fc]]
    hf3 = (fine.pitch * fine.scale) ** 3
    sub = replace(fine.subset(mask), youngs=coarse.youngs[own], poisson=coarse.poisson[own],
                  density=coarse.density[own], mass=coarse.density[own] * np.asarray(fine.fraction[fidx], float) * hf3)
    pattern = block_pattern(hexes, len(used))
    K = scatter(pattern, cube_stiffness(sub, element))
    M = scatter(pattern, cube_mass_chunks(sub, sub.mass)(0, sub.n_cubes).reshape(-1, 24, 24))
    return FineSystem(K=K, M=M, tied=tied[used], node_cube=rpos[node_cube[used]], node_q=node_q[used], hexes=hexes,
                      fine_cube=fc, fine_local=fl, slot=slot.ravel(), n=len(reps))
