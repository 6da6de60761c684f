"""Rigid-motion removal of the paper's Eqs. 18-23 and its interpolation at frames that were not fitted.

Per curve and frame: (Eq. 19) translate so the curve's first point coincides with the first point
at frame 0, then (Eqs. 20-23) rotate about that point onto the frame-0 curve. The least squares
of Eq. 23 has the closed form of Kabsch (SVD of the 3x3 cross-covariance, with a reflection guard
so that ``det R = +1``). The paper multiplies row vectors by ``A``; here ``aligned = pivot +
R (x - anchor)`` with column vectors, i.e. ``R = A^T``.

The rigid motion is only known at the fitted frames. At other times it is interpolated:
rotations by SLERP between neighbouring fitted frames (``"linear"``) or by a cubic spline of the
rotation vectors relative to frame 0 (``"cubic"``, valid for rotations below pi, which holds for a
swinging rope), and the anchor (first point) linearly or by a cubic spline. The error this adds
is reported by ``benchmarks/reconstruction.py`` (oracle rigid motion vs interpolated).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline, make_interp_spline
from scipy.spatial.transform import Rotation

from ..errors import InputError

RIGID_INTERPOLATIONS = ("linear", "cubic")


@dataclass(frozen=True, eq=False)
class RigidAlignment:
    """Result of :func:`remove_rigid`.

    Attributes
    ----------
    aligned : ndarray, shape (F, C, P, 3)
        Curves with the rigid motion removed (frame 0 unchanged); a transposed view of a
        (F, C, 3, P) array.
    rotations : ndarray, shape (F, C, 3, 3)
        ``R`` per frame and curve (``rotations[0]`` is the identity).
    anchors : ndarray, shape (F, C, 3)
        First point of every curve at every frame (model units).
    """

    aligned: np.ndarray
    rotations: np.ndarray
    anchors: np.ndarray


def _norm3(v: np.ndarray) -> np.ndarray:
    """Euclidean norm over a last axis of length 3 (faster than ``np.linalg.norm`` there)."""
    return np.sqrt(v[..., 0] ** 2 + v[..., 1] ** 2 + v[..., 2] ** 2)


def kabsch(q: np.ndarray, p: np.ndarray, reg: float = 1e-6) -> np.ndarray:
    """Batched best rotation ``R`` minimising ``sum_k |R q_k - p_k|^2`` (closed form of Eq. 23).

    Parameters
    ----------
    q, p : ndarray, shape (..., P, 3)
        Broadcast against each other.
    reg : float
        Tie-break towards the identity: maximises ``tr(R H) + lam tr(R)`` with
        ``lam = reg * sum_k |q_k| |p_k|``. For (nearly) straight curves the spin about the curve's
        own axis is undetermined (a rope at rest is straight); without this the SVD returns an
        arbitrary spin that differs from frame to frame and ruins the interpolation between
        frames. The bias on well-determined rotations is of order ``reg``.

    Returns
    -------
    ndarray, shape (..., 3, 3), proper rotations (``det = +1``).
    """
    return _kabsch_t(np.swapaxes(q, -1, -2), p, reg)


def _kabsch_t(qt: np.ndarray, p: np.ndarray, reg: float, n_stack: int = 1) -> np.ndarray:
    """:func:`kabsch` with ``q`` given transposed, ``qt`` (..., 3, P) (points along the last axis,
    where the elementwise work is fastest), or (..., n_stack 3, P): ``n_stack`` q's against the
    same ``p``, returned as (..., n_stack, 3, 3)."""
    h = qt @ p                                                      # (..., n_stack 3, 3), q and p broadcast
    if n_stack > 1:
        qt = qt.reshape(qt.shape[:-2] + (n_stack, 3, qt.shape[-1]))
        h = h.reshape(h.shape[:-2] + (n_stack, 3, 3))
        p = p[..., None, :, :]
    norm_q = np.sqrt(qt[..., 0, :] ** 2 + qt[..., 1, :] ** 2 + qt[..., 2, :] ** 2)
    return _kabsch_h(h, reg * (norm_q * _norm3(p)).sum(axis=-1))


def _kabsch_h(h: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Rotations (..., 3, 3) maximising ``tr(R H) + lam tr(R)`` for cross-covariances ``h``
    (..., 3, 3) and tie-breaks ``lam`` (...): one batched SVD, reflection guard."""
    h = h + lam[..., None, None] * np.eye(3)
    uu, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.swapaxes(vt, -1, -2) @ np.swapaxes(uu, -1, -2)))
    d = np.where(d == 0, 1.0, d)
    fix = np.ones(h.shape[:-2] + (3,))
    fix[..., 2] = d
    return np.swapaxes(vt, -1, -2) @ (fix[..., :, None] * np.swapaxes(uu, -1, -2))


def remove_rigid(curves, reg: float = 1e-6) -> RigidAlignment:
    """Remove per-curve rigid motion relative to frame 0 (paper Eqs. 18-23).

    Parameters
    ----------
    curves : array_like, shape (F, C, P, 3)
        Model units.
    reg : float
        Tie-break towards the identity for straight curves (see :func:`kabsch`); 0 = plain Kabsch.
    """
    x = np.asarray(curves, dtype=float)
    if x.ndim != 4 or x.shape[-1] != 3:
        raise InputError(f"curves must have shape (n_frames, n_curves, n_points, 3), got {x.shape}")
    anchors = x[:, :, 0, :]
    n_f, n_c, n_p, _ = x.shape
    # work on (C, F, 4, P): every elementwise step runs along the points, the 3 x 3 products of a
    # curve's frames with its frame 0 are one matrix product per curve, and with a 4-th row of
    # ones the alignment R q + pivot of a frame is one (3, 4) @ (4, P) product
    q = np.empty((n_c, n_f, 4, n_p))
    q[:, :, :3] = x.transpose(1, 0, 3, 2)
    q[:, :, :3] -= anchors.transpose(1, 0, 2)[..., None]             # relative to the first point
    q[:, :, 3] = 1.0
    p = np.swapaxes(q[:, 0, :3], -1, -2)                              # (C, P, 3), frame 0
    rot = np.empty((n_c, n_f, 3, 4))
    rot[:, 0, :, :3] = np.eye(3)                                      # frame 0: the identity
    if n_f > 1:
        moving = q[:, 1:]
        h = (moving.reshape(n_c, -1, n_p) @ p).reshape(n_c, n_f - 1, 4, 3)[:, :, :3]
        norm_q = np.sqrt(np.einsum("cfwp,cfwp->cfp", moving[:, :, :3], moving[:, :, :3]))
        lam = reg * (norm_q @ _norm3(p)[:, :, None])[..., 0]           # (C, F - 1)
        rot[:, 1:, :, :3] = _kabsch_h(h, lam)
    rot[:, :, :, 3] = anchors[0][:, None, :]                          # + pivot, via the row of ones
    aligned = rot @ q                                                 # (C, F, 3, P)
    return RigidAlignment(aligned=aligned.transpose(1, 0, 3, 2), rotations=rot[..., :3].transpose(1, 0, 2, 3),
                          anchors=anchors)


def rotvec_from_matrix(rot: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) (axis times angle in [0, pi]) of proper rotations (..., 3, 3).

    Through the unit quaternion of Markley's method (of the four candidate formulas, the one
    built on the largest of ``R_00, R_11, R_22, tr R``, so it is accurate at every angle, pi
    included); the same result as :meth:`scipy.spatial.transform.Rotation.as_rotvec` without its
    per-call overhead (the fit converts a few hundred rotations per evaluation)."""
    m = np.asarray(rot, dtype=float)
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    cand = np.empty(m.shape[:-2] + (4, 4))                # candidate quaternions (x, y, z, w), one per row
    for i in range(3):                                    # built on R_ii: the three axes
        j, k = (i + 1) % 3, (i + 2) % 3
        cand[..., i, i] = 1.0 - tr + 2.0 * m[..., i, i]
        cand[..., i, j] = m[..., j, i] + m[..., i, j]
        cand[..., i, k] = m[..., k, i] + m[..., i, k]
        cand[..., i, 3] = m[..., k, j] - m[..., j, k]
    cand[..., 3, 0] = m[..., 2, 1] - m[..., 1, 2]
    cand[..., 3, 1] = m[..., 0, 2] - m[..., 2, 0]
    cand[..., 3, 2] = m[..., 1, 0] - m[..., 0, 1]
    cand[..., 3, 3] = 1.0 + tr
    pick = np.argmax(np.stack([m[..., 0, 0], m[..., 1, 1], m[..., 2, 2], tr], axis=-1), axis=-1)
    q = np.take_along_axis(cand, pick[..., None, None], axis=-2)[..., 0, :]
    q *= np.where(q[..., 3:] < 0, -1.0, 1.0) / np.linalg.norm(q, axis=-1, keepdims=True)   # w >= 0
    vn = np.linalg.norm(q[..., :3], axis=-1)
    angle = 2.0 * np.arctan2(vn, q[..., 3])
    small = angle < 1e-3                                  # angle / sin(angle / 2) by its series there
    a2 = np.where(small, angle, 0.0) ** 2
    scale = np.where(small, 2.0 + a2 / 12.0 + 7.0 * a2 * a2 / 2880.0,
                     angle / np.where(small, 1.0, np.sin(0.5 * angle)))
    return scale[..., None] * q[..., :3]


def spline_weights(knots: np.ndarray, s: np.ndarray) -> np.ndarray:
    """``W`` (len(s), len(knots)) with ``CubicSpline(knots, y)(s) = W @ y`` for any knot values
    ``y`` (not-a-knot end conditions, the default): the spline of the identity."""
    return CubicSpline(knots, np.eye(len(knots)), axis=0)(s)


@dataclass(frozen=True, eq=False)
class RigidMotion:
    """Rigid motion known at key times, interpolated in between (see module docstring).

    Attributes
    ----------
    key_times : ndarray, shape (F,)
        Normalised times of the fitted frames.
    rotations : ndarray, shape (F, C, 3, 3)
    anchors : ndarray, shape (F, C, 3)
    interpolation : str
        ``"linear"`` (SLERP + linear anchor) or ``"cubic"`` (cubic splines of rotation vectors
        and anchors; needs >= 3 key frames, otherwise falls back to linear).
    """

    key_times: np.ndarray
    rotations: np.ndarray
    anchors: np.ndarray
    interpolation: str = "cubic"

    @property
    def pivot(self) -> np.ndarray:
        return self.anchors[0]

    def at(self, s) -> tuple[np.ndarray, np.ndarray]:
        """Rotations (nt, C, 3, 3) and anchors (nt, C, 3) at normalised times ``s`` (nt,)."""
        s = np.atleast_1d(np.asarray(s, dtype=float))
        kt, n_c = self.key_times, self.rotations.shape[1]
        cubic = self.interpolation == "cubic" and len(kt) >= 3
        if cubic:       # the spline is linear in the knot values: one weight matrix (nt, F) for both
            w = spline_weights(kt, s)
            anchors = (w @ self.anchors.reshape(len(kt), -1)).reshape(len(s), n_c, 3)
            rv = rotvec_from_matrix(self.rotations).reshape(len(kt), -1)
            rot = Rotation.from_rotvec((w @ rv).reshape(-1, 3)).as_matrix()
            return rot.reshape(len(s), n_c, 3, 3), anchors
        anchors = make_interp_spline(kt, self.anchors, k=1, axis=0)(s)
        i = np.clip(np.searchsorted(kt, s, side="right") - 1, 0, len(kt) - 2)
        frac = (s - kt[i]) / (kt[i + 1] - kt[i])
        r0 = Rotation.from_matrix(self.rotations[i].reshape(-1, 3, 3))
        r1 = Rotation.from_matrix(self.rotations[i + 1].reshape(-1, 3, 3))
        step = (r0.inv() * r1).as_rotvec() * np.repeat(frac, n_c)[:, None]
        rot = (r0 * Rotation.from_rotvec(step)).as_matrix()
        return rot.reshape(len(s), n_c, 3, 3), anchors

    def to_world(self, aligned: np.ndarray, s) -> np.ndarray:
        """Inverse of the alignment: ``x = anchor(s) + R(s)^T (aligned - pivot)``.

        Parameters
        ----------
        aligned : ndarray, shape (nt, C, P, 3)
        s : array_like, shape (nt,)
        """
        rot, anchors = self.at(s)
        rel = aligned - self.pivot[None, :, None, :]
        return anchors[:, :, None, :] + rel @ rot                     # R^T rel per point
