"""Centralised input validation (pyvista style): every message names the bad argument,
its shape or its value."""

from __future__ import annotations

from typing import Any

import numpy as np

from .errors import InputError, MaterialError


def as_float_array(value: Any, name: str, shape: tuple | None = None, *,
                   finite: bool = True, dtype=np.float64) -> np.ndarray:
    """Convert ``value`` to a float array, checking shape (``-1`` = any) and finiteness."""
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be numeric, could not convert ({exc})") from None
    if shape is not None:
        ok = arr.ndim == len(shape) and all(s == -1 or s == a for s, a in zip(shape, arr.shape))
        if not ok:
            want = "(" + ", ".join("n" if s == -1 else str(s) for s in shape) + ")"
            raise InputError(f"{name} must have shape {want}, got {arr.shape}")
    if finite and arr.size and not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise InputError(f"{name} contains {bad} non-finite value(s) (NaN or inf)")
    return arr


def as_points(value: Any, name: str = "points") -> np.ndarray:
    """An ``(n, 3)`` float64 array of finite coordinates (a single ``(3,)`` point is promoted)."""
    arr = as_float_array(value, name)
    if arr.ndim == 1 and arr.shape[0] == 3:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name} must have shape (n, 3), got {arr.shape}")
    return arr


def positive_scalar(value: Any, name: str, *, allow_zero: bool = False) -> float:
    """A finite float > 0 (or >= 0)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(v) or v < 0 or (v == 0 and not allow_zero):
        raise InputError(f"{name} must be {'>= 0' if allow_zero else '> 0'} and finite, got {v!r}")
    return v


def positive_int(value: Any, name: str, *, minimum: int = 1) -> int:
    """An integer >= ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        else:
            raise InputError(f"{name} must be an integer, got {value!r}")
    if value < minimum:
        raise InputError(f"{name} must be >= {minimum}, got {value}")
    return int(value)


def check_material(youngs: np.ndarray, poisson: np.ndarray, density: np.ndarray | None = None,
                   where: str = "") -> None:
    """Raise :class:`MaterialError` naming the first offending value."""
    where = f" ({where})" if where else ""
    # from each array's range alone (a NaN makes both ends NaN): two passes, not a mask per test
    if (r := _range(youngs)) is not None:
        if not np.all(np.isfinite(r)):
            raise MaterialError(f"Young's modulus E must be finite{where}")
        if r[0] <= 0:
            raise MaterialError(f"Young's modulus E must be > 0 Pa{where}, got min {r[0]:g}")
    if (r := _range(poisson)) is not None:
        if not np.all(np.isfinite(r)):
            raise MaterialError(f"Poisson's ratio nu must be finite{where}")
        if r[0] <= -1.0 or r[1] >= 0.5:
            raise MaterialError(f"Poisson's ratio nu must lie in (-1, 0.5){where}, got range [{r[0]:g}, {r[1]:g}]")
    if density is not None and (r := _range(density)) is not None and (not np.all(np.isfinite(r)) or r[0] <= 0):
        raise MaterialError(f"density must be > 0 kg/m^3 and finite{where}, "
                            f"got min {np.nanmin(np.asarray(density, dtype=float)):g}")


def _range(values: Any) -> tuple[float, float] | None:
    """Smallest and largest of ``values`` (both NaN when any is NaN), None when there are none."""
    a = np.asarray(values, dtype=float)
    return (float(a.min()), float(a.max())) if a.size else None


def as_indices(value: Any, n: int, name: str, *, allow_mask: bool = False, allow_empty: bool = True,
               error: type = InputError) -> np.ndarray:
    """int64 indices (in the order given) into ``range(n)`` from a 1-D integer array (or, with
    ``allow_mask``, a bool mask of shape (n,)); ``error`` names the bad dtype, shape or range."""
    arr = np.atleast_1d(np.asarray(value))
    if allow_mask and arr.dtype == bool:
        if arr.shape != (n,):
            raise error(f"{name} as a mask must have shape ({n},), got {arr.shape}")
        return np.flatnonzero(arr)
    if arr.size == 0:
        if not allow_empty:
            raise error(f"{name} must not be empty")
        return np.zeros(0, dtype=np.int64)
    if arr.ndim != 1 or not np.issubdtype(arr.dtype, np.integer):
        kind = "a 1-D integer array" + (" or a bool mask" if allow_mask else "")
        raise error(f"{name} must be {kind}, got dtype {arr.dtype} shape {arr.shape}")
    if arr.min() < 0 or arr.max() >= n:
        raise error(f"{name} must lie in [0, {n}), got range [{arr.min()}, {arr.max()}]")
    return arr.astype(np.int64)
