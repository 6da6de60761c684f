"""Static B-spline baseline of the paper (Section 5): a cubic least-squares B-spline with
``n_control`` control points per curve fitted independently at every fitted frame, and linear
interpolation (point by point) between neighbouring fitted frames.

Each frame's spline is parametrised by that frame's own normalised chord length (a static
fit uses only its own frame); clamped uniform knots on [0, 1]. The least squares is the same as
``scipy.interpolate.make_lsq_spline`` (checked in the tests) but batched over frames, curves and
coordinates with one sparse design matrix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline

from .._validate import positive_int
from ..errors import InputError
from .param import check_u, parametrize
from .pde import _check_curves, _check_times, check_frame_indices

DEGREE = 3
PENALTY = 1e-6
"""Weight of the second-difference penalty relative to the mean diagonal of ``B^T B``."""


def clamped_knots(n_control: int, k: int = DEGREE) -> np.ndarray:
    """Clamped uniform knot vector on [0, 1] for ``n_control`` coefficients of degree ``k``."""
    inner = np.linspace(0.0, 1.0, n_control - k + 1)
    return np.concatenate([np.zeros(k), inner, np.ones(k)])


@dataclass(frozen=True, eq=False)
class BSplineModel:
    """Per-frame B-splines at the fitted frames, linear interpolation in between.

    Attributes
    ----------
    control_points : ndarray, shape (F, C, n_control, 3)
    knots : ndarray, shape (n_control + 4,)
    u : ndarray, shape (F, C, P)
        Parameter of every point at every fitted frame.
    fit_times : ndarray, shape (F,)
        Times of the fitted frames (caller's units).
    """

    control_points: np.ndarray
    knots: np.ndarray
    u: np.ndarray
    fit_times: np.ndarray

    @property
    def n_parameters(self) -> int:
        """Scalars: F x C x n_control x 3 (the paper counts points: F x C x n_control)."""
        return int(self.control_points.size)

    @property
    def n_control_points(self) -> int:
        """Control points (the paper's count, e.g. 6 x 24 x 50 = 7200)."""
        return int(np.prod(self.control_points.shape[:3]))

    def frame_points(self) -> np.ndarray:
        """Spline points at the fitted frames, shape (F, C, P, 3)."""
        f, c, p = self.u.shape
        cols, vals = _local_basis(self.u, self.knots)                  # (F, C, P, 4) each
        ctrl = self.control_points[np.arange(f)[:, None, None, None], np.arange(c)[None, :, None, None], cols]
        return np.einsum("fcpk,fcpkw->fcpw", vals, ctrl)

    def evaluate(self, t) -> np.ndarray:
        """Points at time(s) ``t`` (caller's units), clamped to the fitted time range.

        Returns
        -------
        ndarray, shape (C, P, 3) for scalar ``t``, (len(t), C, P, 3) for an array.
        """
        t_arr = np.asarray(t, dtype=float)
        tt = np.clip(np.atleast_1d(t_arr).ravel(), self.fit_times[0], self.fit_times[-1])
        pts = self.frame_points()
        i = np.clip(np.searchsorted(self.fit_times, tt, side="right") - 1, 0, len(self.fit_times) - 2)
        lam = ((tt - self.fit_times[i]) / (self.fit_times[i + 1] - self.fit_times[i]))[:, None, None, None]
        out = (1.0 - lam) * pts[i] + lam * pts[i + 1]
        return out[0] if t_arr.ndim == 0 else out


def _local_basis(u: np.ndarray, knots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Column indices and values of the 4 non-zero cubic B-splines at every ``u``: (..., 4) each."""
    m = BSpline.design_matrix(u.ravel(), knots, DEGREE)                # CSR, 4 non-zeros per row
    m.sort_indices()
    shape = u.shape + (DEGREE + 1,)
    return m.indices.reshape(shape), m.data.reshape(shape)


def bspline_baseline(curves, times, fit_frames, n_control: int = 50, u=None) -> BSplineModel:
    """Fit the static B-spline baseline at ``fit_frames``.

    Parameters
    ----------
    curves : array_like, shape (F_all, C, P, 3)
        All frames (only ``fit_frames`` are used), model units.
    times : array_like, shape (F_all,)
    fit_frames : sequence of int
        Indices of the fitted frames (>= 2, increasing).
    n_control : int
        Control points per curve (>= 4, <= P).
    u : array_like, shape (P,) or (C, P), optional
        Explicit parameter values in [0, 1] (same for every frame); default: each frame's own
        normalised chord length.
    """
    x = _check_curves(curves, min_frames=1)
    t = _check_times(times, x.shape[0])
    n_control = positive_int(n_control, "n_control", minimum=DEGREE + 1)
    idx = check_frame_indices(fit_frames, x.shape[0])
    if n_control > x.shape[2]:
        raise InputError(f"n_control ({n_control}) must not exceed the points per curve ({x.shape[2]})")
    xf = x[idx]                                                    # (F, C, P, 3)
    f, c, p, _ = xf.shape
    if u is None:
        u = parametrize(xf.reshape(f * c, p, 3), "arclength").reshape(f, c, p)
    else:
        u = np.broadcast_to(check_u(u, c, p), (f, c, p)).copy()
    knots = clamped_knots(n_control)
    cols, vals = _local_basis(u, knots)
    # normal equations B^T B c = B^T x, assembled from the 4 non-zeros per row (B-spline
    # collocation with dense, ordered data is well conditioned; checked against make_lsq_spline)
    ata = np.zeros((f, c, n_control, n_control))
    atb = np.zeros((f, c, n_control, 3))
    fi, ci = np.arange(f)[:, None, None], np.arange(c)[None, :, None]
    for a in range(DEGREE + 1):                                  # 4 x 4 local pairs
        np.add.at(atb, (fi, ci, cols[..., a]), vals[..., a, None] * xf)
        for b_ in range(DEGREE + 1):
            np.add.at(ata, (fi, ci, cols[..., a], cols[..., b_]), vals[..., a] * vals[..., b_])
    # a knot span without data (points bunched up along the curve, as on a vertex animation's
    # curves) leaves B^T B singular: a tiny second-difference penalty (P-spline) fills such spans
    # smoothly and changes nothing measurable where the data determine the fit
    d2 = np.diff(np.eye(n_control), 2, axis=0)
    diag = np.einsum("fcii->fci", ata)
    mean = np.maximum(diag.mean(axis=-1), 1e-300)
    starved = diag.min(axis=-1) < 1e-6 * mean              # only systems with a basis function (nearly) without data
    scale = np.where(starved, PENALTY * mean, 0.0)[..., None, None]
    # and a ridge far below round-off of the data keeps every system invertible (a curve whose
    # points bunch into fewer spans than control points, as in bridge cables at resolution 10)
    ridge = 1e-12 * mean[..., None, None] * np.eye(n_control)
    ctrl = np.linalg.solve(ata + scale * (d2.T @ d2) + ridge, atb)
    return BSplineModel(control_points=ctrl, knots=knots, u=u, fit_times=t[idx])
