"""From curves back to a mesh, and from a generic vertex animation to curves.

* :func:`curve_mesh_map` builds a sparse ``W`` (n_vertices x C*P) of inverse-distance weights over
  the ``k`` nearest rest curve points (rows sum to 1). :func:`mesh_vertices` moves every vertex by
  ``W @`` (curve-point displacement), which is exact for translations and first-order accurate for
  rotations and bending (a vertex off the curves does not rotate with them). It is a simple and
  honest map; its error against the true mesh is measured by ``benchmarks/reconstruction.py``.
* :func:`lattice_lines` gives the cube lattice's node lines along its longest axis as curves.
  Fitted like any curves, they map back to the mesh *exactly* through the trilinear embedding:
  ``mesh_vertices(fit, t, embed(model, vertices)[:, lines.ravel()], rest_nodes[lines], vertices)``
  (the columns of W reordered to the lines), because every vertex moves as W times the nodes.
* :func:`extract_curves` picks curves in a mesh for animations that have none: vertices are split
  into ``n_points`` slabs of equal count along the rest principal axis (PCA) and, in every slab,
  the vertex whose angle about the axis is closest to each of ``n_curves`` equally spaced angles
  is taken. The result is an index array (C, P) into the vertices (vertices may repeat when a slab
  has fewer distinct directions than curves); point 0 of every curve is at the low end of the axis.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from .._validate import as_points, positive_int
from ..errors import InputError


def curve_mesh_map(rest_curves, rest_vertices, k: int = 4) -> sp.csr_matrix:
    """Sparse inverse-distance map from curve points to mesh vertices.

    Parameters
    ----------
    rest_curves : array_like, shape (C, P, 3)
        Curve points in the rest (or reference) pose, model units.
    rest_vertices : array_like, shape (n, 3)
        Mesh vertices in the same pose.
    k : int
        Curve points per vertex.

    Returns
    -------
    scipy.sparse.csr_matrix, shape (n, C*P), rows summing to 1.
    """
    pts = as_points(np.reshape(rest_curves, (-1, 3)), "rest_curves")
    verts = as_points(rest_vertices, "rest_vertices")
    k = min(positive_int(k, "k"), len(pts))
    dist, idx = cKDTree(pts).query(verts, k=k)
    dist, idx = dist.reshape(len(verts), k), idx.reshape(len(verts), k)
    scale = max(float(np.ptp(pts, axis=0).max()), 1.0) * 1e-9
    w = 1.0 / np.maximum(dist, scale) ** 2
    w /= w.sum(axis=1, keepdims=True)
    rows = np.repeat(np.arange(len(verts)), k)
    return sp.csr_matrix((w.ravel(), (rows, idx.ravel())), shape=(len(verts), len(pts)))


def mesh_vertices(model, t, W, rest_curves, rest_vertices) -> np.ndarray:
    """Mesh vertices at time(s) ``t``: ``rest_vertices + W @ (curves(t) - rest_curves)``.

    Parameters
    ----------
    model : object with ``evaluate(t)`` -> (C, P, 3) or (nt, C, P, 3)
        A fitted :class:`PDEModel` or :class:`BSplineModel`.
    t : float or array_like (nt,)
    W : sparse matrix, shape (n, C*P)
        From :func:`curve_mesh_map` (or any linear map of curve points to vertices).
    rest_curves : array_like, shape (C, P, 3)
    rest_vertices : array_like, shape (n, 3)

    Returns
    -------
    ndarray, shape (n, 3) or (nt, n, 3)
    """
    moved = curves_to_vertices(np.asarray(model.evaluate(t)), W, rest_curves, rest_vertices)
    return moved[0] if np.ndim(t) == 0 else moved


def curves_to_vertices(curves, W, rest_curves, rest_vertices) -> np.ndarray:
    """``rest_vertices + W @ (curves - rest_curves)`` for curves (C, P, 3) or (nt, C, P, 3): shape
    (nt, n, 3), one sparse product for all frames (``W`` (n, C*P) as in :func:`mesh_vertices`)."""
    rc = np.asarray(rest_curves, dtype=float).reshape(-1, 3)
    rv = as_points(rest_vertices, "rest_vertices")
    if W.shape != (len(rv), len(rc)):
        raise InputError(f"W must have shape ({len(rv)}, {len(rc)}), got {W.shape}")
    disp = np.asarray(curves, dtype=float).reshape(-1, len(rc), 3) - rc          # (nt, C*P, 3)
    nt = len(disp)
    return rv + (W @ disp.transpose(1, 0, 2).reshape(len(rc), nt * 3)).reshape(len(rv), nt, 3).transpose(1, 0, 2)


def lattice_lines(model, axis: int | None = None) -> np.ndarray:
    """Node indices of the lattice lines along ``axis`` (default: the longest grid axis).

    Parameters
    ----------
    model : CubeModel
    axis : {0, 1, 2}, optional

    Returns
    -------
    ndarray of int, shape (L, P)
        One row per line (nodes sharing the other two lattice indices), ordered along ``axis``;
        together the rows hold every node exactly once.

    Raises
    ------
    InputError
        The lines do not all have the same nodes along ``axis`` (a lattice with holes or
        branches); use curves on the surface instead.
    """
    ni = np.asarray(model.node_index)
    ax = int(np.argmax(model.dims)) if axis is None else int(axis)
    if ax not in (0, 1, 2):
        raise InputError(f"axis must be 0, 1 or 2, got {axis!r}")
    others = [a for a in range(3) if a != ax]
    order = np.lexsort((ni[:, ax], ni[:, others[1]], ni[:, others[0]]))
    key = ni[order][:, others]
    starts = np.flatnonzero(np.r_[True, np.any(np.diff(key, axis=0) != 0, axis=1)])
    counts = np.diff(np.r_[starts, len(order)])
    along = ni[order, ax]
    if np.any(counts != counts[0]) or np.any(along.reshape(len(starts), -1) != along[: counts[0]][None]):
        raise InputError("the lattice's node lines are not all complete along the axis (holes or branches); "
                         "lattice_lines needs a bar-like lattice")
    return order.reshape(len(starts), counts[0])


def extract_curves(rest_vertices, n_curves: int = 8, n_points: int = 64) -> np.ndarray:
    """Indices (C, P) of mesh vertices forming curves along the principal axis (see module doc)."""
    v = as_points(rest_vertices, "rest_vertices")
    n_curves = positive_int(n_curves, "n_curves")
    n_points = positive_int(n_points, "n_points", minimum=8)
    if len(v) < n_points:
        raise InputError(f"the mesh has {len(v)} vertices, fewer than n_points={n_points}")
    c = v - v.mean(axis=0)
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    axis, e1, e2 = vt[0], vt[1], vt[2]
    proj = c @ axis
    order = np.argsort(proj, kind="stable")
    slab = np.empty(len(v), dtype=int)
    slab[order] = (np.arange(len(v)) * n_points) // len(v)          # equal-count slabs
    centre = np.zeros((n_points, 3))
    np.add.at(centre, slab, c)
    centre /= np.bincount(slab, minlength=n_points)[:, None]
    rel = c - centre[slab]
    ang = np.arctan2(rel @ e2, rel @ e1)
    out = np.empty((n_curves, n_points), dtype=np.int64)
    for ci, target in enumerate(2 * np.pi * np.arange(n_curves) / n_curves - np.pi):  # few curves
        d = np.abs(np.angle(np.exp(1j * (ang - target))))
        o = np.lexsort((d, slab))
        first = np.unique(slab[o], return_index=True)[1]
        out[ci] = o[first]
    return out
