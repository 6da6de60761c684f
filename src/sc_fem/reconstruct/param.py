"""Curve parametrization ``u in [0, 1]`` (paper Eq. 24 and an arc-length variant).

Eq. 24 normalises a *coordinate* of the aligned curve: ``u_k = (w_k - w_min) / (w_max - w_min)``
for ``w = x, y, z``. Read literally this gives three different ``u`` per point (one per
coordinate) and, because the paper recomputes it at every frame ``n`` from that frame's own
coordinates, it needs the data of the very frames that are being reconstructed. We interpret it
for a 3-D curve as follows (``"paper"``): per curve, take the coordinate with the largest range
on the reference (first fitted, aligned) frame and min-max normalise it. ``u`` is then a
*material* (Lagrangian) coordinate, fixed per point for all frames, so skipped frames can be
evaluated without their data. It is a valid parameter only where that coordinate is monotone along
the curve (true for a rope hanging or lying along an axis).

``"arclength"``: normalised cumulative chord length of the reference curve (monotone by
construction, invariant to rigid motion and uniform scaling).
"""

from __future__ import annotations

import numpy as np

from .._validate import as_float_array
from ..errors import InputError

PARAMETRIZATIONS = ("paper", "arclength")


def check_u(u, n_curves: int, n_points: int) -> np.ndarray:
    """Validate explicit parameter values: shape (P,) (shared by every curve) or (C, P), finite,
    in [0, 1]. Returns a new (C, P) float64 array."""
    uu = as_float_array(u, "u")
    if uu.shape not in ((n_points,), (n_curves, n_points)):
        raise InputError(f"u must have shape ({n_points},) or ({n_curves}, {n_points}), got {uu.shape}")
    if uu.min() < 0 or uu.max() > 1:
        raise InputError(f"u must have values in [0, 1], got range [{uu.min():g}, {uu.max():g}]")
    return np.broadcast_to(uu, (n_curves, n_points)).copy()


def parametrize(curves, method: str = "paper") -> np.ndarray:
    """Parameter values of reference curves.

    Parameters
    ----------
    curves : array_like, shape (C, P, 3) or (P, 3)
        Reference (aligned, first fitted frame) curves, model units.
    method : {"paper", "arclength"}

    Returns
    -------
    ndarray, shape (C, P) or (P,), values in [0, 1] with min 0 and max 1.
    """
    x = np.asarray(curves, dtype=float)
    single = x.ndim == 2
    if single:
        x = x[None]
    if x.ndim != 3 or x.shape[-1] != 3 or x.shape[1] < 2:
        raise InputError(f"curves must have shape (n_curves, n_points >= 2, 3), got {np.shape(curves)}")
    if method == "paper":
        rng = np.ptp(x, axis=1)                                 # (C, 3)
        axis = np.argmax(rng, axis=1)                           # (C,)
        w = np.take_along_axis(x, axis[:, None, None], axis=2)[..., 0]
        lo, span = w.min(axis=1, keepdims=True), np.ptp(w, axis=1, keepdims=True)
    elif method == "arclength":
        seg = np.linalg.norm(np.diff(x, axis=1), axis=-1)
        w = np.concatenate([np.zeros((len(x), 1)), np.cumsum(seg, axis=1)], axis=1)
        lo, span = 0.0, w[:, -1:]
    else:
        raise InputError(f"parametrization must be one of {PARAMETRIZATIONS}, got {method!r}")
    if np.any(span <= 0):
        raise InputError("a reference curve is degenerate (all points coincide); cannot parametrize it")
    u = (w - lo) / span
    return u[0] if single else u
