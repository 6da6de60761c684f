"""Which parts of a mesh belong together: bodies decided by geometry, not by the voxel grid.

A *part* (:mod:`sc_fem.geometry.inside`) is a set of faces connected through shared vertex
positions. Two parts belong to the same *body* when their surfaces come closer than a *weld
distance* (model units), cross each other, or one lies inside the other's enclosed volume; bodies
are the connected groups of that relation. The answer depends on the geometry and the weld
distance only, never on the resolution of a later voxel grid, so a model has the same number of
free bodies at every resolution (the seed paper's limitation (a): "close geometric components may
be undesirably joined" by shared cubes).

The distance test is exact: a broad phase over face bounding spheres (grouped by size, so one
large face does not widen every query) finds the face pairs of different parts that may come
within the weld distance, and :func:`triangle_distance` (vectorized over pairs) decides them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from .inside import MeshParts, winding_number

DEFAULT_WELD_FRACTION = 0.005
"""Default weld distance: 0.5 % of the model's longest bounding-box extent (independent of the
resolution). It joins the built-in bridge's cables, which stop 5 cm (0.2 %) short of its deck,
and keeps apart two 0.5 m plates 5 mm (1 %) apart."""

MIN_WELD_FRACTION = 1e-4
"""Weld distances below this fraction of the bounding-box diagonal are measured as this much (parts
that touch or cross are joined at round-off distances; finer splitting would cost without use)."""

PAIR_CHUNK = 200_000
"""Face pairs measured at a time (bounded memory)."""


@dataclass(frozen=True, eq=False)
class Bodies:
    """Parts grouped into bodies.

    Attributes
    ----------
    of_part : ndarray of int, shape (k,)
        Body of each part, numbered by the lowest part index they contain.
    n_bodies : int
        Number of bodies.
    weld : float
        Weld distance used, model units.
    face_pairs : int
        Face pairs whose distance was measured exactly.
    joined_by_distance : int
        Joins made because surfaces come within ``weld`` (or cross): the number of groups left by
        containment alone less the number of bodies.
    joined_by_containment : int
        Part pairs joined because one part lies inside another's enclosed volume.
    """

    of_part: np.ndarray
    n_bodies: int
    weld: float
    face_pairs: int
    joined_by_distance: int
    joined_by_containment: int


def _box_pairs(lo: np.ndarray, hi: np.ndarray, pad: float, chunk: int = 2048) -> np.ndarray:
    """Pairs ``(i, j)``, i < j, of boxes that overlap once grown by ``pad`` (shape (p, 2))."""
    out = []
    for s in range(0, len(lo), chunk):       # rows in chunks: bounded memory for many parts
        a_lo, a_hi = lo[s:s + chunk, None] - pad, hi[s:s + chunk, None] + pad
        hit = np.all((a_lo <= hi[None]) & (lo[None] <= a_hi), axis=2)
        i, j = np.nonzero(hit)
        i = i + s
        keep = i < j
        out.append(np.stack([i[keep], j[keep]], axis=1))
    return np.vstack(out) if out else np.zeros((0, 2), np.int64)


def _near_faces(vertices: np.ndarray, parts: MeshParts, lo: np.ndarray, hi: np.ndarray, pairs: np.ndarray,
                pad: float) -> np.ndarray:
    """Faces (mask (m,)) whose box, grown by ``pad``, overlaps the box of another part they may touch."""
    m = len(parts.faces)
    near = np.zeros(m, dtype=bool)
    if not len(pairs):
        return near
    tri = vertices[parts.faces]
    f_lo, f_hi = tri.min(axis=1) - pad, tri.max(axis=1) + pad
    # each candidate pair in both directions: (part, partner)
    both = np.vstack([pairs, pairs[:, ::-1]])
    order = np.argsort(parts.label, kind="stable")
    start = np.searchsorted(parts.label[order], np.arange(parts.n_parts + 1))
    counts = start[both[:, 0] + 1] - start[both[:, 0]]
    rep = np.repeat(np.arange(len(both)), counts)
    offs = np.arange(len(rep)) - np.repeat(np.cumsum(counts) - counts, counts)
    face = order[start[both[rep, 0]] + offs]
    partner = both[rep, 1]
    hit = np.all((f_lo[face] <= hi[partner]) & (lo[partner] <= f_hi[face]), axis=1)
    near[face[hit]] = True
    return near


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,ij->i", a, b)


def _point_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    t = np.clip(_dot(p - a, d) / np.maximum(_dot(d, d), 1e-300), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * d), axis=1)


def _point_triangle(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Distance from points to triangles, all (n, 3) (degenerate triangles: to their edges)."""
    n = np.cross(b - a, c - a)
    nn = _dot(n, n)
    ok = nn > 1e-30 * np.maximum(_dot(b - a, b - a), 1e-300) ** 2
    q = p - a
    # barycentric coordinates of the projection: u (b), v (c)
    u = _dot(np.cross(q, c - a), n) / np.where(ok, nn, 1.0)
    v = _dot(np.cross(b - a, q), n) / np.where(ok, nn, 1.0)
    inside = ok & (u >= 0) & (v >= 0) & (u + v <= 1)
    plane = np.abs(_dot(q, n)) / np.sqrt(np.where(ok, nn, 1.0))
    edge = np.minimum(np.minimum(_point_segment(p, a, b), _point_segment(p, b, c)), _point_segment(p, c, a))
    return np.where(inside, plane, edge)


def _segment_segment(p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Distance between segments ``p1 q1`` and ``p2 q2``, all (n, 3) (Ericson 2005, sec. 5.1.9)."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    c, b = _dot(d1, r), _dot(d1, d2)
    tiny = 1e-300
    denom = a * e - b * b
    s = np.where(denom > 1e-12 * np.maximum(a * e, tiny), np.clip((b * f - c * e) / np.maximum(denom, tiny), 0, 1), 0.0)
    t = (b * s + f) / np.maximum(e, tiny)
    s = np.where(t < 0, np.clip(-c / np.maximum(a, tiny), 0, 1), np.where(t > 1, np.clip((b - c) / np.maximum(a, tiny), 0, 1), s))
    t = np.clip(t, 0, 1)
    s = np.where(a <= tiny, 0.0, s)
    t = np.where(e <= tiny, 0.0, np.where(a <= tiny, np.clip(f / np.maximum(e, tiny), 0, 1), t))
    return np.linalg.norm((p1 + s[:, None] * d1) - (p2 + t[:, None] * d2), axis=1)


def _segment_hits_triangle(p: np.ndarray, q: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Whether segments ``p q`` cross triangles ``a b c`` (Moller--Trumbore; parallel: no)."""
    d = q - p
    e1, e2 = b - a, c - a
    h = np.cross(d, e2)
    det = _dot(e1, h)
    ok = np.abs(det) > 1e-14 * np.linalg.norm(d, axis=1) * np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1)
    inv = 1.0 / np.where(ok, det, 1.0)
    s = p - a
    u = inv * _dot(s, h)
    qv = np.cross(s, e1)
    v = inv * _dot(d, qv)
    t = inv * _dot(e2, qv)
    return ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1)


def triangle_distance(t1: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """Distance between triangles, vectorized over pairs.

    Parameters
    ----------
    t1, t2 : ndarray, shape (n, 3, 3)
        Triangle corners (pair ``i`` is ``t1[i]``, ``t2[i]``), any length unit.

    Returns
    -------
    ndarray, shape (n,)
        The smallest distance between points of the two triangles (0 where they touch or cross),
        same unit.
    """
    t1 = np.asarray(t1, dtype=np.float64)
    t2 = np.asarray(t2, dtype=np.float64)
    d = np.full(len(t1), np.inf)
    cross = np.zeros(len(t1), dtype=bool)
    for s, o in ((t1, t2), (t2, t1)):
        for i in range(3):                      # the 3 corners and edges of each triangle
            d = np.minimum(d, _point_triangle(s[:, i], o[:, 0], o[:, 1], o[:, 2]))
            cross |= _segment_hits_triangle(s[:, i], s[:, (i + 1) % 3], o[:, 0], o[:, 1], o[:, 2])
    for i in range(3):
        for j in range(3):
            d = np.minimum(d, _segment_segment(t1[:, i], t1[:, (i + 1) % 3], t2[:, j], t2[:, (j + 1) % 3]))
    return np.where(cross, 0.0, d)


def _face_spheres(tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    centre = tri.mean(axis=1)
    return centre, np.sqrt(((tri - centre[:, None]) ** 2).sum(axis=2).max(axis=1))


def _groups(edges: list, k: int) -> np.ndarray:
    e = np.vstack(edges)
    return csgraph.connected_components(sparse.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(k, k)),
                                        directed=False)[1]


def _nearest_joins(tri: np.ndarray, centre: np.ndarray, r: np.ndarray, lab: np.ndarray, group: np.ndarray,
                   reach: float, k_nearest: int = 8) -> tuple[np.ndarray, int]:
    """Part pairs (h, 2) joined by a face and one of its ``k_nearest`` faces (by centre) of another
    part and not yet in one group, within ``reach`` (exact triangle distance); and the number of
    face pairs measured. Where parts cross or touch, faces of both lie side by side, so this
    decides most touching part pairs at ``n * k_nearest`` pairs instead of all close pairs."""
    kq = min(k_nearest + 1, len(centre))
    if kq < 2:
        return np.zeros((0, 2), np.int64), 0
    dist, j = cKDTree(centre).query(centre, k=kq)
    i = np.repeat(np.arange(len(centre)), kq)
    j, dist = j.ravel(), dist.ravel()
    ok = (lab[i] != lab[j]) & (group[lab[i]] != group[lab[j]]) & (dist - r[i] - r[j] <= reach)
    q = np.unique(np.sort(np.stack([i[ok], j[ok]], axis=1), axis=1), axis=0)
    hit = q[triangle_distance(tri[q[:, 0]], tri[q[:, 1]]) <= reach] if len(q) else q
    return np.stack([lab[hit[:, 0]], lab[hit[:, 1]]], axis=1).astype(np.int64), len(q)


def _close_pairs(centre: np.ndarray, r: np.ndarray, reach: float) -> np.ndarray:
    """Pairs ``(i, j)`` of faces whose bounding spheres come within ``reach`` (queried per size
    class, so that one large face does not widen every query)."""
    cls = np.maximum(np.floor(np.log2(np.maximum(r, 1e-300) / max(reach, 1e-300))).astype(np.int64), -1)
    classes = np.unique(cls)
    groups = [(np.flatnonzero(cls == c), cKDTree(centre[cls == c])) for c in classes]
    out = []
    for i, (idx_i, tree_i) in enumerate(groups):
        for idx_j, tree_j in groups[i:]:            # size classes (a few dozen at most), not faces
            bound = reach + r[idx_i].max() + r[idx_j].max()
            if idx_i is idx_j:
                p = tree_i.query_pairs(bound, output_type="ndarray")
            else:
                m = tree_i.sparse_distance_matrix(tree_j, bound, output_type="ndarray")
                p = np.stack([m["i"], m["j"]], axis=1)
            if len(p):
                out.append(np.stack([idx_i[p[:, 0]], idx_j[p[:, 1]]], axis=1))
    if not out:
        return np.zeros((0, 2), np.int64)
    p = np.vstack(out)
    d = np.linalg.norm(centre[p[:, 0]] - centre[p[:, 1]], axis=1)
    return p[d <= reach + r[p[:, 0]] + r[p[:, 1]]]


def find_bodies(vertices: np.ndarray, parts: MeshParts, weld: float) -> Bodies:
    """Group the parts of a mesh into bodies (see the module docstring).

    Parameters
    ----------
    vertices : ndarray, shape (n, 3)
        Mesh vertices, model units.
    parts : MeshParts
        The mesh's parts (:func:`sc_fem.geometry.inside.mesh_parts`).
    weld : float
        Weld distance, model units (>= 0; 0 joins the parts that touch, cross or contain one
        another, touching measured to :data:`MIN_WELD_FRACTION` of the bounding-box diagonal).

    Returns
    -------
    Bodies
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    k = parts.n_parts
    if k <= 1:
        return Bodies(np.zeros(k, np.int64), k, float(weld), 0, 0, 0)
    lo, hi = parts.boxes(vertices)
    diag = float(np.linalg.norm(hi.max(0) - lo.min(0)))
    reach = max(float(weld), MIN_WELD_FRACTION * diag)
    edges = [np.zeros((0, 2), np.int64)]
    # containment: a part inside another's enclosed volume (a vertex of it with winding number > 1/2)
    closed = np.flatnonzero(parts.closed)
    n_cont = 0
    if len(closed):
        first = np.zeros(k, np.int64)
        first[parts.label[::-1]] = np.arange(len(parts.label))[::-1]    # a face of each part
        rep = vertices[parts.faces[first, 0]]
        inside_box = np.all((rep[None] >= lo[closed, None]) & (rep[None] <= hi[closed, None]), axis=2)
        inside_box[np.arange(len(closed)), closed] = False
        for qi in np.flatnonzero(inside_box.any(axis=1)):     # one inside test per closed part (not per element)
            cand = np.flatnonzero(inside_box[qi])
            w = winding_number(vertices, parts.faces[parts.label == closed[qi]], rep[cand])
            inner = cand[w > 0.5]
            edges.append(np.stack([np.full(len(inner), closed[qi]), inner], axis=1))
            n_cont += len(inner)
    # joins made by distance are counted as the groups left by containment alone less the bodies
    # (independent of the order in which the search meets the face pairs)
    n_after_cont = int(_groups(edges, k).max()) + 1
    # distance: exact triangle distances of the face pairs the broad phase finds
    n_pairs = 0
    pairs = _box_pairs(lo, hi, reach)
    if len(pairs):
        near = np.flatnonzero(_near_faces(vertices, parts, lo, hi, pairs, reach))
        tri = vertices[parts.faces[near]]
        lab = parts.label[near]
        centre, r = _face_spheres(tri)
        # quick pass: each face against the faces of other parts among its nearest; exact distances,
        # so it only adds true joins, and part pairs it joins need no all-pairs search
        hit, tested = _nearest_joins(tri, centre, r, lab, _groups(edges, k), reach)
        edges.append(hit)
        n_pairs += tested
        group = _groups(edges, k)
        open_pair = group[pairs[:, 0]] != group[pairs[:, 1]]
        keep = np.isin(lab, pairs[open_pair].ravel())
        tri, lab, centre, r = tri[keep], lab[keep], centre[keep], r[keep]
        p = _close_pairs(centre, r, reach) if open_pair.any() else np.zeros((0, 2), np.int64)
        p = p[lab[p[:, 0]] != lab[p[:, 1]]]
        # closest first (by the bound centre distance - radii), and pairs of parts already joined
        # skipped: touching parts are decided by their first few face pairs
        bound = np.linalg.norm(centre[p[:, 0]] - centre[p[:, 1]], axis=1) - r[p[:, 0]] - r[p[:, 1]]
        p = p[np.argsort(bound, kind="stable")]
        s, size = 0, 1024
        while s < len(p):                           # chunks of face pairs, growing
            group = _groups(edges, k)
            q = p[s:s + size]
            q = q[group[lab[q[:, 0]]] != group[lab[q[:, 1]]]]
            n_pairs += len(q)
            hit = q[triangle_distance(tri[q[:, 0]], tri[q[:, 1]]) <= reach]
            edges.append(np.stack([lab[hit[:, 0]], lab[hit[:, 1]]], axis=1))
            s += size
            size = min(2 * size, PAIR_CHUNK)
    e = np.vstack(edges)
    graph = sparse.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(k, k))
    n, lab_b = csgraph.connected_components(graph, directed=False)
    first_part = np.full(n, k)
    np.minimum.at(first_part, lab_b, np.arange(k))
    rank = np.empty(n, np.int64)
    rank[np.argsort(first_part)] = np.arange(n)
    return Bodies(rank[lab_b], int(n), float(weld), int(n_pairs), n_after_cont - int(n), int(n_cont))
