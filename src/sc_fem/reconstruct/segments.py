"""Curves cut into overlapping pieces, each fitted with its own Eq. 17 model.

Eight space functions per coordinate follow a gently bent rope; a curve extracted from an
arbitrary mesh (a tunnel sheet, a chair) bends more than that, and one 32-term model per curve
then fits even its key frames worse than a B-spline. Cutting every curve into ``S`` equal,
one-point-overlapping pieces gives each piece its own rigid motion and 32 constants per
coordinate (the parameter count grows accordingly and is reported); points shared by two pieces
take the mean of both, so the reassembled curve is continuous at the joints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .pde import PDEModel, fit

MIN_POINTS = 8
"""Points a piece needs (one per space function)."""


def segment_index(n_points: int, n_segments: int) -> np.ndarray:
    """Point indices of ``n_segments`` equal pieces covering ``range(n_points)``, consecutive
    pieces sharing at least one point, shape (S, L)."""
    if n_segments < 1:
        raise InputError(f"segments must be >= 1, got {n_segments}")
    length = int(np.ceil((n_points - 1) / n_segments)) + 1 if n_segments > 1 else n_points
    if length < MIN_POINTS or length > n_points:
        raise InputError(f"{n_segments} pieces of a {n_points}-point curve have {length} points each; "
                         f"at least {MIN_POINTS} are needed")
    starts = np.round(np.linspace(0, n_points - length, n_segments)).astype(np.int64)
    return starts[:, None] + np.arange(length)[None, :]


def max_segments(n_points: int) -> int:
    """Most pieces a curve of ``n_points`` points can be cut into."""
    return max(1, (n_points - 1) // (MIN_POINTS - 1))


@dataclass(frozen=True, eq=False)
class SegmentedModel:
    """An Eq. 17 model per piece of every curve (see module docstring).

    Attributes
    ----------
    model : PDEModel
        The fit of all ``C * S`` pieces.
    index : ndarray of int, shape (S, L)
        Point indices of each piece.
    n_points : int
        Points per whole curve.
    """

    model: PDEModel
    index: np.ndarray
    n_points: int

    @property
    def n_segments(self) -> int:
        return int(self.index.shape[0])

    @property
    def n_curves(self) -> int:
        return self.model.n_curves // self.n_segments

    @property
    def n_parameters(self) -> int:
        return self.model.n_parameters

    def __getattr__(self, name):          # r, alpha, coefficients, u, search, ... of the fit
        if name in ("model", "index", "n_points"):
            raise AttributeError(name)
        return getattr(self.model, name)

    def evaluate(self, t, normalized: bool = False) -> np.ndarray:
        """Whole curves at time(s) ``t``, shape (C, P, 3) or (len(t), C, P, 3)."""
        m = self.model
        t_arr = np.asarray(t, dtype=float)
        s = np.atleast_1d(t_arr if normalized else m.normalize(t_arr)).ravel()
        return self._assemble(m.evaluate(s, normalized=True), t_arr.ndim == 0)

    def _joints(self):
        """Points in several pieces and how many: (J,), (J,)."""
        count = np.bincount(self.index.ravel(), minlength=self.n_points)
        joint = np.flatnonzero(count > 1)
        return joint, count[joint]

    def _assemble(self, pieces: np.ndarray, scalar: bool) -> np.ndarray:
        """Whole curves from the pieces' curves (nt, C S, L, 3)."""
        nt, S, L = len(pieces), self.n_segments, self.index.shape[1]
        pieces = pieces.reshape(nt, self.n_curves, S, L, 3)
        starts = self.index[:, 0]           # every piece is a run of consecutive points
        out = np.empty((nt, self.n_curves, self.n_points, 3))
        for k, s0 in enumerate(starts):     # a handful of pieces
            out[:, :, s0:s0 + L] = pieces[:, :, k]
        joint, count = self._joints()
        acc = np.zeros((nt, self.n_curves, len(joint), 3))
        for k, s0 in enumerate(starts):     # a handful of pieces
            inside = (joint >= s0) & (joint < s0 + L)
            acc[:, :, inside] += pieces[:, :, k, joint[inside] - s0]
        out[:, :, joint] = acc / count[:, None]
        return out[0] if scalar else out


def fit_segmented(curves, times, n_segments: int, **fit_options) -> SegmentedModel:
    """:func:`~sc_fem.reconstruct.fit` on every curve cut into ``n_segments`` pieces.

    ``curves`` (F, C, P, 3) at the fitted frames; ``fit_options`` go to :func:`fit`."""
    x = np.asarray(curves, dtype=float)
    if x.ndim != 4 or x.shape[-1] != 3:
        raise InputError(f"curves must have shape (F, C, P, 3), got {x.shape}")
    n_f, n_c, n_p, _ = x.shape
    idx = segment_index(n_p, int(n_segments))
    length = idx.shape[1]
    pieces = np.stack([x[:, :, s0:s0 + length] for s0 in idx[:, 0]], axis=2)   # a handful of pieces
    pieces = pieces.reshape(n_f, n_c * idx.shape[0], length, 3)
    return SegmentedModel(model=fit(pieces, times, **fit_options), index=idx, n_points=n_p)
