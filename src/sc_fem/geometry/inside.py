"""Inside and outside of a broken triangle mesh: generalized winding numbers and closed parts.

The generalized winding number ``w(p)`` (Jacobson et al. 2013) is 1 inside a closed, outward
oriented surface, 0 outside, and degrades gracefully on holes, overlaps and self-intersections,
so ``w > 1/2`` is a robust inside test for the meshes users bring. We evaluate it with libigl's
fast (Barnes--Hut) winding number, exact near the surface.

A *part* is a set of faces connected through shared vertex positions. A part *encloses volume*
when the winding number just inside and just outside its faces sums to about 1 (an open sheet
gives about 0: its winding number jumps from +1/2 to -1/2 across it). The test uses the whole
mesh, so a box made of six separate quads encloses volume as well as a watertight one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

CLOSED_THRESHOLD = 0.75
"""A part encloses volume when the median of ``|w(c - d n) + w(c + d n)|`` over probe points on
its faces exceeds this (closed surfaces give 1, open flat sheets 0, a half-pipe about 0.5)."""

PROBES_PER_PART = 24
"""Largest faces of each part probed by :func:`mesh_parts`."""

_CHUNK = 1 << 20   # query points per winding-number call (bounds temporary memory)


def winding_number(vertices: np.ndarray, faces: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Generalized winding number of ``points`` (q, 3) w.r.t. the triangles ``faces`` (m, 3).

    Returns shape (q,). 1 inside a closed outward-oriented surface, 0 outside, fractional near
    holes and open sheets.
    """
    import igl

    v = np.ascontiguousarray(vertices, dtype=np.float64)
    f = np.ascontiguousarray(faces, dtype=np.int64)
    q = np.ascontiguousarray(points, dtype=np.float64).reshape(-1, 3)
    if len(f) == 0 or len(q) == 0:
        return np.zeros(len(q))
    return np.concatenate([np.asarray(igl.fast_winding_number(v, f, q[s:s + _CHUNK]))
                           for s in range(0, len(q), _CHUNK)])


def group_boxes(vertices: np.ndarray, faces: np.ndarray, group: np.ndarray,
                n_groups: int) -> tuple[np.ndarray, np.ndarray]:
    """Bounding box of every group of faces (parts, bodies), vectorized.

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
        Model units.
    faces : ndarray of int, shape (m, 3)
    group : ndarray of int, shape (m,)
        Group of each face, in ``[0, n_groups)``.
    n_groups : int

    Returns
    -------
    lo, hi : ndarray, shape (n_groups, 3)
        Lowest and highest corner (inf / -inf for a group without faces).
    """
    fg = np.repeat(group, 3)
    lo = np.full((n_groups, 3), np.inf)
    hi = np.full((n_groups, 3), -np.inf)
    np.minimum.at(lo, fg, vertices[faces.reshape(-1)])
    np.maximum.at(hi, fg, vertices[faces.reshape(-1)])
    return lo, hi


@dataclass(frozen=True, eq=False)
class MeshParts:
    """Parts of a mesh and which of them enclose volume.

    Attributes
    ----------
    label : ndarray of int, shape (m,)
        Part of each face.
    closed : ndarray of bool, shape (k,)
        Whether each part encloses volume.
    closure : ndarray, shape (k,)
        The measured closure (median ``|w_in + w_out|``; 1 closed, 0 open sheet).
    faces : ndarray of int, shape (m, 3)
        The faces, reoriented so that every closed part faces outward (use these for inside tests).
    watertight : ndarray of bool, shape (k,)
        Parts whose consistently oriented faces close up (every edge used equally often in both
        directions): the divergence theorem holds on them.
    """

    label: np.ndarray
    closed: np.ndarray
    closure: np.ndarray
    faces: np.ndarray
    watertight: np.ndarray

    @property
    def n_parts(self) -> int:
        """Number of parts."""
        return len(self.closed)

    def boxes(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box of every part: lowest and highest corner, each (k, 3), model units."""
        return group_boxes(vertices, self.faces, self.label, self.n_parts)

    def closed_faces(self) -> np.ndarray:
        """Boolean mask (m,) of the faces that belong to closed parts."""
        return self.closed[self.label]


def weld(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces (m, 3) re-indexed so that vertices at the same position share one index."""
    _, inv = np.unique(np.asarray(vertices), axis=0, return_inverse=True)
    return inv.reshape(-1)[faces]


def _part_labels(wfaces: np.ndarray, n_vertices: int) -> np.ndarray:
    m = len(wfaces)
    rows = np.repeat(np.arange(m), 3)
    inc = sparse.csr_matrix((np.ones(3 * m), (rows, wfaces.ravel())), shape=(m, n_vertices))
    graph = sparse.bmat([[None, inc], [inc.T, None]]).tocsr()
    _, lab = csgraph.connected_components(graph, directed=False)
    _, label = np.unique(lab[:m], return_inverse=True)
    return label.reshape(-1)


def _closed(wfaces: np.ndarray, label: np.ndarray, n_parts: int) -> np.ndarray:
    """Parts whose consistently oriented faces close up: every edge (between welded vertices) is
    used as often in one direction as in the other (the boundary of the 2-chain is zero, which is
    what the divergence theorem needs; edges shared by four faces of touching boxes are fine)."""
    a = wfaces.ravel()
    b = wfaces[:, [1, 2, 0]].ravel()
    edges = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)
    _, inv = np.unique(edges, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    balance = np.bincount(inv, weights=np.where(a < b, 1.0, -1.0))
    open_edge = balance[inv] != 0
    return np.bincount(label[np.repeat(np.arange(len(wfaces)), 3)[open_edge]], minlength=n_parts) == 0


def mesh_parts(vertices: np.ndarray, faces: np.ndarray) -> MeshParts:
    """Split a mesh into parts and decide which enclose volume.

    Watertight parts are oriented outward by the sign of their enclosed volume; every part is
    then probed with the winding number of the whole mesh just inside and outside its
    :data:`PROBES_PER_PART` largest faces (offset 1e-4 of the bounding-box diagonal). Parts
    whose closure exceeds :data:`CLOSED_THRESHOLD` enclose volume; inward-facing open-but-closing
    parts (e.g. a scan with holes, inside out) are flipped too.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    m = len(faces)
    if m == 0:
        return MeshParts(np.zeros(0, np.int64), np.zeros(0, bool), np.zeros(0), faces, np.zeros(0, bool))
    wfaces = weld(vertices, faces)
    label = _part_labels(wfaces, len(vertices))
    k = int(label.max()) + 1
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    # orient watertight parts outward (signed volume > 0)
    signed = np.bincount(label, weights=np.einsum("ij,ij->i", tri[:, 0], cross), minlength=k)
    tight = _closed(wfaces, label, k)
    flip = tight & (signed < 0)
    out = faces.copy()
    out[flip[label]] = out[flip[label]][:, ::-1]
    normal = np.where(flip[label][:, None], -1.0, 1.0) * cross / np.maximum(area2, 1e-300)[:, None]

    # probes: the largest faces of each part (rank within part by area)
    order = np.lexsort((-area2, label))
    start = np.searchsorted(label[order], np.arange(k))
    rank = np.arange(m) - start[label[order]]
    pick = order[(rank < PROBES_PER_PART) & (area2[order] > 0)]
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    d = 1e-4 * diag
    centre = tri[pick].mean(axis=1)
    w = winding_number(vertices, out, np.vstack([centre - d * normal[pick], centre + d * normal[pick]]))
    s = w[:len(pick)] + w[len(pick):]
    plab = label[pick]
    signed_closure = np.zeros(k)
    if len(pick):   # median per part, vectorized: sort by (part, value), take each part's middle
        key = np.lexsort((s, plab))
        bounds = np.searchsorted(plab[key], np.arange(k + 1))
        has = bounds[1:] > bounds[:-1]
        mid = (bounds[:-1] + bounds[1:] - 1) // 2
        signed_closure[has] = s[key][mid[has]]
    closure = np.abs(signed_closure)
    closed = tight | (closure > CLOSED_THRESHOLD)
    inward = ~tight & closed & (signed_closure < 0)
    if inward.any():
        out[inward[label]] = out[inward[label]][:, ::-1]
    closure = np.where(tight, 1.0, closure)
    return MeshParts(label=label, closed=closed, closure=closure, faces=out, watertight=tight)
