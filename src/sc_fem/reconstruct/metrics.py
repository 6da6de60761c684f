"""Reconstruction errors of the paper's Eqs. 26-27.

``E_A[n] = mean_k |w_nk - w^_nk| / D`` and ``E_M[n] = max_k |w_nk - w^_nk| / D`` where ``D`` is
the distance between the two furthest points of the *reference* curve at frame ``n`` (the paper
writes ``1/832 sum_{k=0}^{832}``, an off-by-one; we use the mean over the points).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import as_float_array
from ..errors import InputError


def curve_diameter(points, chunk_bytes: float = 64e6) -> np.ndarray:
    """Exact largest pairwise distance of point sets, vectorised (Gram matrix, chunked).

    Parameters
    ----------
    points : array_like, shape (..., P, 3)

    Returns
    -------
    ndarray, shape (...)
    """
    x = np.asarray(points, dtype=float)
    lead, n = x.shape[:-2], x.shape[-2]
    x = x.reshape(-1, n, 3)
    x = x - x.mean(axis=1, keepdims=True)
    sq = np.einsum("bpi,bpi->bp", x, x)
    out = np.empty(len(x))
    step = max(1, int(chunk_bytes // (8 * n * n)))
    for s in range(0, len(x), step):   # loop over memory-sized chunks of curves, not points
        xs, qs = x[s:s + step], sq[s:s + step]
        d2 = qs[:, :, None] + qs[:, None, :] - 2.0 * np.einsum("bpi,bqi->bpq", xs, xs)
        out[s:s + step] = np.sqrt(np.maximum(d2.max(axis=(1, 2)), 0.0))
    return out.reshape(lead)


@dataclass(frozen=True, eq=False)
class ReconstructionErrors:
    """Per-frame errors (Eqs. 26-27), dimensionless (fractions of ``D``).

    Attributes
    ----------
    E_A, E_M : ndarray, shape (F, C) or (F,)
        Average and maximum point error over ``D`` per frame (and curve).
    D : ndarray, same shape
        Diameter of the reference curve, model units.
    """

    E_A: np.ndarray
    E_M: np.ndarray
    D: np.ndarray

    @property
    def frame_E_A(self) -> np.ndarray:
        """(F,) mean of ``E_A`` over curves."""
        return self.E_A if self.E_A.ndim == 1 else self.E_A.mean(axis=1)

    @property
    def frame_E_M(self) -> np.ndarray:
        """(F,) max of ``E_M`` over curves."""
        return self.E_M if self.E_M.ndim == 1 else self.E_M.max(axis=1)

    @property
    def mean_E_A(self) -> float:
        """Mean of the average errors (the paper's summary figure 0.006986)."""
        return float(np.mean(self.E_A))

    @property
    def max_E_M(self) -> float:
        """Max of the maximum errors (the paper's summary figure 0.019478)."""
        return float(np.max(self.E_M))


def errors(reference, reconstructed) -> ReconstructionErrors:
    """E_A and E_M per frame (and curve) of ``reconstructed`` against ``reference``.

    Parameters
    ----------
    reference, reconstructed : array_like, shape (F, C, P, 3) or (F, P, 3)
        Same shape, model units.
    """
    ref = as_float_array(reference, "reference")
    rec = as_float_array(reconstructed, "reconstructed")
    if ref.ndim not in (3, 4) or ref.shape[-1] != 3:
        raise InputError(f"reference must have shape (F, C, P, 3) or (F, P, 3), got {ref.shape}")
    if rec.shape != ref.shape:
        raise InputError(f"reconstructed must have the reference's shape {ref.shape}, got {rec.shape}")
    d = curve_diameter(ref)
    if np.any(d <= 0):
        raise InputError("a reference curve has all its points at one location (D = 0)")
    dist = np.linalg.norm(ref - rec, axis=-1)
    return ReconstructionErrors(E_A=dist.mean(axis=-1) / d, E_M=dist.max(axis=-1) / d, D=d)
