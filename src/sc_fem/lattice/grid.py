"""The voxel grid of :func:`sc_fem.voxelize`: fitted to a model's bounding box (:func:`grid_for`),
checked against the memory budget before anything grid-sized is allocated, with samples hashed
to its voxels (:func:`hash_samples`) and a point cloud's default pitch and point spacing."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .._validate import positive_int, positive_scalar
from ..errors import InputError, MaterialError, ResolutionError
from ..geometry.sampling import grid_counts
from .topology import unique_keys, voxel_keys
from .options import DEFAULT_RESOLUTION, MAX_RESOLUTION, check_resolution

SPACING_FRACTION = 0.125   # default sample spacing = pitch / 8
_BYTES_PER_GRID_CELL = 6   # bool occupancy + int32 labels
_BYTES_PER_SAMPLE = 160    # positions, weights, faces, temporaries
SNAP_CELLS = 0.01          # largest round-off (in cubes) absorbed by grid_for


def grid_for(bounds: np.ndarray, *, resolution: int | None = None, pitch: float | None = None):
    """Grid fitted to ``bounds`` (2, 3): returns ``(origin (3,), pitch, dims (3,) int)``.

    ``resolution`` cubes along the longest axis, or the given ``pitch`` (model units). A box
    whose extents are whole multiples of the pitch gets exactly that many cubes, also when its
    coordinates went through single precision (STL): extents within ``8 * eps_float32 * |x|``
    (at most :data:`SNAP_CELLS` cubes) of a whole multiple count as that multiple.
    """
    lo, hi = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    extent = hi - lo
    if resolution is not None and pitch is not None:
        raise InputError("give resolution or pitch, not both")
    if pitch is None:
        res = check_resolution(positive_int(DEFAULT_RESOLUTION if resolution is None else resolution, "resolution"))
        pitch = float(extent.max()) / res
    else:
        pitch = positive_scalar(pitch, "pitch")
    ratio = extent / pitch
    # round-off of single-precision files (STL) must not add a layer: extents within a few float32
    # ulps of the coordinates' magnitude of a whole multiple of the pitch count as that multiple
    mag = np.maximum(np.abs(lo), np.abs(hi))
    tol = np.clip(8.0 * np.finfo(np.float32).eps * mag / pitch, 1e-9 * np.maximum(1.0, ratio), SNAP_CELLS)
    dims = np.maximum(1, np.ceil(ratio - tol)).astype(np.int64)
    if np.any(dims > MAX_RESOLUTION):
        raise ResolutionError(f"pitch {pitch:g} gives a grid of {tuple(dims)} cubes: too fine "
                              f"(at most {MAX_RESOLUTION} along an axis)")
    return lo, float(pitch), dims


def _estimate_bytes(vertices, faces, bounds, res) -> int:
    _, pitch, dims = grid_for(bounds, resolution=res)
    return estimate_bytes(vertices, faces, dims, pitch * SPACING_FRACTION)


def estimate_bytes(vertices: np.ndarray, faces: np.ndarray, dims: np.ndarray, spacing: float,
                   subsamples: int = 0) -> int:
    """Bytes :func:`sc_fem.voxelize` needs on a grid of ``dims`` cubes with surface samples
    ``spacing`` apart (model units) and ``subsamples^3`` inside-test samples per boundary cube (the
    estimate its memory guard refuses a grid by).

    Parameters
    ----------
    vertices : ndarray, shape (v, 3)
        The surface's vertices (model units); a point cloud's points when ``faces`` is empty.
    faces : ndarray of int, shape (f, 3)
        Its triangles.
    dims : ndarray of int, shape (3,)
        Cubes along each axis.
    spacing : float
        Surface sample spacing, model units.
    subsamples : int
        Inside-test samples per boundary cube edge (0: not counted).

    Returns
    -------
    int
    """
    n = len(vertices)
    if len(faces):
        k_s, k_t = grid_counts(vertices, faces, spacing)
        n = int((k_s * k_t).sum())
    n += n * subsamples**3 // 32                 # boundary cubes (~ samples / 40) with subsamples^3 each
    return int(np.prod(np.asarray(dims, dtype=float)) * _BYTES_PER_GRID_CELL + n * _BYTES_PER_SAMPLE)


def _memory_guard(vertices, faces, bounds, dims, n_samples, budget) -> None:
    need = float(np.prod(dims.astype(float))) * _BYTES_PER_GRID_CELL + n_samples * _BYTES_PER_SAMPLE
    if need <= budget:
        return
    longest = int(dims.max())
    lo, hi = 1, longest
    while lo < hi:                      # bisection on resolution (a handful of cheap estimates)
        mid = (lo + hi + 1) // 2
        if _estimate_bytes(vertices, faces, bounds, mid) <= budget:
            lo = mid
        else:
            hi = mid - 1
    raise ResolutionError(
        f"a grid of {tuple(int(d) for d in dims)} cubes with {n_samples:,} samples needs about "
        f"{need / 2**30:.1f} GiB, more than the {budget / 2**30:.1f} GiB allowed; "
        f"try resolution <= {lo} (currently {longest})")


def hash_samples(points: np.ndarray, masses: np.ndarray, values: dict[str, np.ndarray], origin: np.ndarray,
                 pitch: float, dims: np.ndarray, sums: dict[str, np.ndarray] | None = None,
                 piece: np.ndarray | None = None,
                 row_sums: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
                 ) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """Hash samples to voxels; sum their masses and mass-average their values per voxel.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        Sample positions, model units. A sample on an upper grid face belongs to the last cell.
    masses : ndarray, shape (n,)
        Sample masses, kg.
    values : dict of name -> ndarray (n,)
        Per-sample properties to average (E, nu, rho, ...).
    origin, pitch, dims
        The grid (see :func:`grid_for`).
    sums : dict of name -> ndarray (n,), optional
        Per-sample quantities to sum (not average) per voxel; returned in ``averages`` too.
    piece : ndarray of int, shape (n,), optional
        Body of each sample: samples of different bodies in one voxel make separate cubes
        (returned as ``averages["piece"]``, int).
    row_sums : dict of name -> (rows (k,) int, values (k, c)), optional
        Quantities of a few samples ``rows`` to sum per voxel; returned in ``averages`` as (cubes, c)
        arrays (zero where no such sample fell).

    Returns
    -------
    cells : ndarray of int, shape (k, 3)
        Occupied voxels, sorted by linear index.
    mass : ndarray, shape (k,)
        Sum of sample masses per voxel.
    averages : dict of name -> ndarray (k,)
        Mass-weighted average of each value per voxel.
    """
    lin = voxel_keys(points, origin, pitch, dims)
    n_p = 1 if piece is None or not len(piece) else int(piece.max()) + 1
    if n_p > 1:
        lin = lin * n_p + piece
    uniq, inv = unique_keys(lin, int(np.prod(dims)) * n_p, return_inverse=True)
    cube_mass = np.bincount(inv, weights=masses, minlength=len(uniq))
    if np.any(cube_mass <= 0):
        raise MaterialError("a cube received zero mass; check density/mass values")
    averages = {k: np.bincount(inv, weights=masses * v, minlength=len(uniq)) / cube_mass for k, v in values.items()}
    averages.update({k: np.bincount(inv, weights=v, minlength=len(uniq)) for k, v in (sums or {}).items()})
    for k, (rows, vals) in (row_sums or {}).items():       # (cube, column) pairs in one bincount
        c = vals.shape[1]
        slot = (inv[rows][:, None] * c + np.arange(c)).ravel()
        averages[k] = np.bincount(slot, weights=np.ravel(vals), minlength=len(uniq) * c).reshape(len(uniq), c)
    cells = np.stack(np.unravel_index(uniq // n_p, dims), axis=1).astype(np.int64)
    if piece is not None:
        averages["piece"] = (uniq % n_p).astype(np.int64)
    return cells, cube_mass, averages


def _point_spacing(points: np.ndarray) -> float:
    """Typical spacing of a point cloud: the median nearest-neighbour distance (model units)."""
    if len(points) < 2:
        return float(np.ptp(points, axis=0).max() or 1.0)
    d, _ = cKDTree(points).query(points, k=2)
    positive = d[:, 1][d[:, 1] > 0]
    return float(np.median(positive)) if len(positive) else float(np.ptp(points, axis=0).max())


def _point_cloud_pitch(points: np.ndarray, bounds: np.ndarray) -> float:
    """Default pitch of a point cloud: 32 cubes along the longest axis, but never finer than 1.5x
    the 90th percentile of the nearest-neighbour distance (finer grids fall apart into single cubes)."""
    d, _ = cKDTree(points).query(points, k=2)
    gap = float(np.percentile(d[:, 1], 90)) if len(points) > 1 else 0.0
    return max(float((bounds[1] - bounds[0]).max()) / DEFAULT_RESOLUTION, 1.5 * gap)
