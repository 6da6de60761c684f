"""Embedding of points in the cube lattice: the trilinear interpolation matrix W.

Displacement of any point = ``W @ u_nodes`` (``u_nodes`` shape (m, 3)); forces on points go
to the nodes as ``W.T @ f``. Each row of W holds the 8 trilinear weights of the point's cube
(corner order :data:`sc_fem.lattice.cubes.HEX_CORNERS`), so rows sum to 1 and any linear field is
reproduced exactly. A point whose own voxel is not in the model (a dropped small component, a
gap, a stray polygon) is attached to the nearest kept cube with its local coordinates clamped
to that cube; such points are counted as *detached*.

In a model whose cells hold cubes of several bodies (:attr:`CubeModel.piece`), each point
follows its own body: the body given, or that of the nearest source-surface site
(:meth:`CubeModel.piece_at`); a detached point is attached to the nearest cube of its body (of any
body when its body has no cube, e.g. a loose polygon that was not kept).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from .._validate import as_points
from ..errors import InputError
from .cubes import HEX_CORNERS, CubeModel


@dataclass(frozen=True, eq=False)
class Embedding:
    """Where points sit in the lattice.

    Attributes
    ----------
    W : scipy.sparse.csr_matrix, shape (n_points, n_nodes)
        Trilinear interpolation matrix.
    cube : ndarray of int, shape (n_points,)
        Cube each point is attached to.
    local : ndarray, shape (n_points, 3)
        Local coordinates in [0, 1]^3 inside that cube.
    detached : ndarray of bool, shape (n_points,)
        Points outside every kept cube (attached to the nearest one, clamped).
    distance : ndarray, shape (n_points,)
        Distance (model units) from each point to its cube (0 inside).
    """

    W: sp.csr_matrix
    cube: np.ndarray
    local: np.ndarray
    detached: np.ndarray
    distance: np.ndarray

    @property
    def n_detached(self) -> int:
        """Number of points attached to a cube they are not inside."""
        return int(self.detached.sum())


def _nearest_cube(model: CubeModel, pts: np.ndarray, among: np.ndarray) -> np.ndarray:
    """Index of the cube (of the cubes ``among``) nearest to each point (clamped distance)."""
    k = min(8, len(among))
    _, cand = cKDTree(model.cell_centers[among]).query(pts, k=k)
    cand = among[np.asarray(cand).reshape(len(pts), k)]
    lo = model.origin + model.pitch * model.cells[cand]            # (q, k, 3)
    clamped = np.clip(pts[:, None, :], lo, lo + model.pitch)
    d = np.linalg.norm(clamped - pts[:, None, :], axis=2)
    return cand[np.arange(len(pts)), np.argmin(d, axis=1)]


def embedding(model: CubeModel, points: ArrayLike, piece: ArrayLike | None = None) -> Embedding:
    """Locate ``points`` (n, 3), model units, in ``model``; see :class:`Embedding`.

    ``piece`` (n,) int: the body of each point, when known (default :meth:`CubeModel.piece_at`);
    it matters only where cells hold cubes of several bodies.

    Parameters
    ----------
    model : CubeModel
        The lattice.
    points : array_like, shape (n, 3)
        Positions in model units.
    piece : array_like of int, shape (n,), optional
        Body of each point.

    Returns
    -------
    Embedding
        ``W`` (n, n_nodes), the cube and local coordinates of each point, and the detached points.
    """
    pts = as_points(points, "points")
    dims = model.dims
    n_p = int(model.piece.max()) + 1
    several = n_p > 1
    if several:
        pp = model.piece_at(pts) if piece is None else np.asarray(piece, dtype=np.int64).reshape(-1)
        if pp.shape != (len(pts),):
            raise InputError(f"piece must have shape ({len(pts)},), got {pp.shape}")
        pp = np.where((pp >= 0) & (pp < n_p), pp, -1)
    else:
        pp = np.zeros(len(pts), np.int64)
    key_cells = np.ravel_multi_index(model.cells.T, dims) * n_p + model.piece   # sorted (CubeModel sorts)
    ijk = np.floor((pts - model.origin) / model.pitch).astype(np.int64)
    inside_grid = np.all((ijk >= 0) & (ijk < dims), axis=1)
    ijk_c = np.clip(ijk, 0, dims - 1)
    key = np.ravel_multi_index(ijk_c.T, dims) * n_p + pp
    pos = np.searchsorted(key_cells, key)
    pos_c = np.minimum(pos, len(key_cells) - 1)
    found = (key_cells[pos_c] == key) & (pp >= 0)
    cube = np.where(found, pos_c, -1)
    # points on the upper grid boundary belong to the last cell (ijk == dims after floor)
    upper = ~inside_grid & np.all((ijk >= 0) & (ijk <= dims), axis=1) & found
    direct = found & (inside_grid | upper)
    cube[~direct] = -1
    miss = np.flatnonzero(cube < 0)
    if len(miss):
        everything = np.arange(model.n_cubes)
        if not several:
            cube[miss] = _nearest_cube(model, pts[miss], everything)
        else:
            has = np.bincount(model.piece, minlength=n_p) > 0
            own = np.where(pp[miss] >= 0, pp[miss], 0)
            own_ok = (pp[miss] >= 0) & has[own]
            lost = miss[~own_ok]
            if len(lost):
                cube[lost] = _nearest_cube(model, pts[lost], everything)
            for b in np.unique(own[own_ok]):                  # per body, not per point
                sel = miss[own_ok][own[own_ok] == b]
                cube[sel] = _nearest_cube(model, pts[sel], np.flatnonzero(model.piece == b))
    lo = model.origin + model.pitch * model.cells[cube]
    local_raw = (pts - lo) / model.pitch
    local = np.clip(local_raw, 0.0, 1.0)
    distance = np.linalg.norm((local_raw - local) * model.pitch, axis=1)
    detached = distance > 1e-9 * model.pitch
    # trilinear weights in HEX_CORNERS order: prod_d (xi_d if offset_d else 1 - xi_d)
    w = np.prod(np.where(HEX_CORNERS[None, :, :] == 1, local[:, None, :], 1.0 - local[:, None, :]), axis=2)
    rows = np.repeat(np.arange(len(pts)), 8)
    W = sp.csr_matrix((w.ravel(), (rows, model.hexes[cube].ravel())), shape=(len(pts), model.n_nodes))
    return Embedding(W=W, cube=cube, local=local, detached=detached, distance=distance)


def embed(model: CubeModel, points: ArrayLike, piece: ArrayLike | None = None) -> sp.csr_matrix:
    """Trilinear interpolation matrix W, shape (len(points), model.n_nodes).

    Parameters
    ----------
    model : CubeModel
        The lattice.
    points : array_like, shape (n, 3)
        Positions in model units (e.g. the source mesh's vertices).
    piece : array_like of int, shape (n,), optional
        Body of each point (see :func:`embedding`).

    Returns
    -------
    scipy.sparse.csr_matrix
        ``W @ u_nodes`` interpolates node displacements (m, 3) to the points; rows sum to 1.
        Use :func:`embedding` for the cube, local coordinates and the detached-point count.
    """
    return embedding(model, points, piece).W
