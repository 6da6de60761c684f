"""How thick the material in the cubes is: the walls' thickness around each partly filled cube
(:func:`wall_thickness`), from the filled volume and the source surface's area there."""

from __future__ import annotations

import numpy as np

from .cubes import CubeModel
from .gridcut import cut_by_grid
from .topology import NEIGHBOURS, voxel_index


def wall_thickness(model: CubeModel, vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How thick the material around each partly filled cube is: ``2 V / A`` (model units) over the
    cube and its 26 neighbours, ``V`` the filled volume and ``A`` the area of the source surface
    there (a wall of thickness ``t`` through a block of cubes has ``V = t a`` and ``A = 2 a``; the
    surface of a compact solid has ``V / A`` of about a cube or more).

    Parameters
    ----------
    model : CubeModel
        The lattice.
    vertices : ndarray, shape (v, 3)
        The source surface's vertices, model units.
    faces : ndarray of int, shape (f, 3)
        Its triangles.

    Returns
    -------
    thickness : ndarray, shape (k,)
        ``2 V / A`` around the partly filled cubes whose block holds surface.
    area : ndarray, shape (k,)
        The surface area in each such cube itself, model units^2 (weights: where the walls are).
    """
    pieces, _ = cut_by_grid(np.asarray(vertices, dtype=float)[np.asarray(faces, dtype=np.int64)], model.origin,
                            model.pitch)
    a = 0.5 * np.linalg.norm(np.cross(pieces[:, 1] - pieces[:, 0], pieces[:, 2] - pieces[:, 0]), axis=1)
    lin_a = np.ravel_multi_index(voxel_index(pieces.mean(axis=1), model.origin, model.pitch, model.dims).T, model.dims)
    lin_c = np.ravel_multi_index(model.cells.T, model.dims)
    key = np.unique(np.r_[lin_a, lin_c])                                    # every cell with surface or cubes
    area = np.bincount(np.searchsorted(key, lin_a), weights=a, minlength=len(key))
    vol = np.bincount(np.searchsorted(key, lin_c), weights=np.asarray(model.fraction, float) * model.pitch**3,
                      minlength=len(key))
    cells = np.stack(np.unravel_index(key, model.dims), axis=1)
    partial = np.flatnonzero(np.isin(key, lin_c[np.asarray(model.fraction, float) < 1.0 - 1e-12]))
    v_blk, a_blk = np.zeros(len(partial)), np.zeros(len(partial))
    for o in np.vstack([np.zeros((1, 3), np.int64), NEIGHBOURS]):              # the cube and its 26 neighbours
        nb = cells[partial] + o
        ok = np.all((nb >= 0) & (nb < model.dims), axis=1)
        k = np.ravel_multi_index(np.clip(nb, 0, model.dims - 1).T, model.dims)
        at = np.minimum(np.searchsorted(key, k), len(key) - 1)
        hit = ok & (key[at] == k)
        v_blk += np.where(hit, vol[at], 0.0)
        a_blk += np.where(hit, area[at], 0.0)
    own = area[partial]
    sel = (own > 0) & (a_blk > 0)
    return 2.0 * v_blk[sel] / a_blk[sel], own[sel]


def shell_thickness(model: CubeModel) -> float | None:
    """The shells' thickness (model units) of a model made of shells alone (open sheets: the
    voxelizer's ``info`` has shells and no solid part), None for any other model.

    Parameters
    ----------
    model : CubeModel
        The lattice.

    Returns
    -------
    float or None
    """
    shell = float(model.info.get("shell_thickness", 0.0) or 0.0)
    return shell if shell > 0 and model.info.get("solid_parts", 1) == 0 else None


THIN_PERCENTILE = 10.0
"""The walls' thickness is this percentile (weighted by surface area) of the cubes' ``2 V / A``."""


def thinnest_walls(model: CubeModel, vertices: np.ndarray, faces: np.ndarray) -> float:
    """The thickness of a model's thin walls: the area-weighted :data:`THIN_PERCENTILE` percentile of
    :func:`wall_thickness` (model units; ``inf`` without partly filled cubes). A model of shells
    alone has walls of exactly its shells' thickness (:func:`shell_thickness`): ``2 V / A`` counts one
    side of a sheet and would give twice it.

    Parameters
    ----------
    model : CubeModel
        The lattice.
    vertices : ndarray, shape (v, 3)
        The source surface's vertices, model units.
    faces : ndarray of int, shape (f, 3)
        Its triangles.

    Returns
    -------
    float
    """
    if (shell := shell_thickness(model)) is not None:
        return shell
    t, a = wall_thickness(model, vertices, faces)
    if not len(t):
        return float("inf")
    order = np.argsort(t)
    cum = np.cumsum(a[order]) / a.sum()
    return float(t[order][min(np.searchsorted(cum, THIN_PERCENTILE / 100.0), len(t) - 1)])

