"""Embedding of points in the cube lattice: the trilinear interpolation matrix W.

Displacement of any point = ``W @ u_nodes`` (``u_nodes`` shape (m, 3)); forces on points go
to the nodes as ``W.T @ f``. Each row of W holds the 8 trilinear weights of the point's cube
(corner order :data:`sc_fem.lattice.cubes.HEX_CORNERS`), so rows sum to 1 and any linear field is
reproduced exactly. A point whose own voxel is not in the model (a dropped small component, a
gap, a stray polygon) is attached to the nearest kept cube with its local coordinates clamped
to that cube; such points are counted as *detached*.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from .._validate import as_points
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


def embedding(model: CubeModel, points) -> Embedding:
    """Locate ``points`` (n, 3), model units, in ``model``; see :class:`Embedding`."""
    pts = as_points(points, "points")
    dims = model.dims
    lin_cells = np.ravel_multi_index(model.cells.T, dims)          # sorted (CubeModel sorts cells)
    ijk = np.floor((pts - model.origin) / model.pitch).astype(np.int64)
    inside_grid = np.all((ijk >= 0) & (ijk < dims), axis=1)
    ijk_c = np.clip(ijk, 0, dims - 1)
    lin = np.ravel_multi_index(ijk_c.T, dims)
    pos = np.searchsorted(lin_cells, lin)
    pos_c = np.minimum(pos, len(lin_cells) - 1)
    found = (lin_cells[pos_c] == lin)
    cube = np.where(found, pos_c, -1)
    # points on the upper grid boundary belong to the last cell (ijk == dims after floor)
    upper = ~inside_grid & np.all((ijk >= 0) & (ijk <= dims), axis=1) & found
    direct = found & (inside_grid | upper)
    cube[~direct] = -1
    miss = np.flatnonzero(cube < 0)
    if len(miss):
        k = min(8, model.n_cubes)
        centers = model.cell_centers
        _, cand = cKDTree(centers).query(pts[miss], k=k)
        cand = np.asarray(cand).reshape(len(miss), k)
        lo = model.origin + model.pitch * model.cells[cand]        # (q, k, 3)
        clamped = np.clip(pts[miss][:, None, :], lo, lo + model.pitch)
        d = np.linalg.norm(clamped - pts[miss][:, None, :], axis=2)
        cube[miss] = cand[np.arange(len(miss)), np.argmin(d, axis=1)]
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


def embed(model: CubeModel, points) -> sp.csr_matrix:
    """Trilinear interpolation matrix W, shape (len(points), model.n_nodes).

    Parameters
    ----------
    model : CubeModel
    points : array_like, shape (n, 3)
        Positions in model units (e.g. the source mesh's vertices).

    Returns
    -------
    scipy.sparse.csr_matrix
        ``W @ u_nodes`` interpolates node displacements (m, 3) to the points; rows sum to 1.
        Use :func:`embedding` for the cube, local coordinates and the detached-point count.
    """
    return embedding(model, points).W
