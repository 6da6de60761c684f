"""The option groups of :func:`sc_fem.modes.modal.modal`: how the modes are damped (:class:`Damping`),
the request that travels from :func:`~sc_fem.modes.modal.modal` through the solve to the baked
:class:`~sc_fem.ModalBasis` (:class:`ModalRequest`), and how
:func:`~sc_fem.modes.auto.modal_converged` chooses the grid (:class:`AutoResolution`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .._validate import positive_int, positive_scalar
from ..errors import InputError
from ..fem.eigen import EigenOptions
from ..fem.elements import DEFAULT_ELEMENT, check_element
from ..fem.choice import AUTO
from ..fem.highorder import DEGREES

DEFAULT_DAMPING_RATIO = 0.01
"""Damping ratio of every mode when no damping is given (1 % of critical)."""

AUTO_RESOLUTIONS: tuple[int, ...] = (12, 16, 24, 32, 48, 64)
"""Grids tried by :func:`~sc_fem.modes.auto.modal_converged` (cubes along the longest axis), coarsest first."""

DEFAULT_RESOLUTION_TOLERANCE = 0.05
"""Relative frequency agreement that :func:`~sc_fem.modes.auto.modal_converged` asks for by default."""


@dataclass(frozen=True)
class Damping:
    """Modal damping: a ratio of critical per mode, or Rayleigh damping ``C = alpha M + beta K``.

    Parameters
    ----------
    ratio : float or sequence of float, optional
        ``zeta`` for every mode, or one per mode (>= 0). Default
        :data:`DEFAULT_DAMPING_RATIO` unless ``rayleigh`` is given.
    rayleigh : (alpha, beta), optional
        ``alpha`` in 1/s, ``beta`` in s (both >= 0); mode ``k`` then has
        ``zeta_k = alpha / (2 omega_k) + beta omega_k / 2``.
    """

    ratio: float | tuple[float, ...] | None = None
    rayleigh: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if self.ratio is not None and self.rayleigh is not None:
            raise InputError("give a damping ratio or Rayleigh coefficients, not both")
        if self.rayleigh is not None:
            try:
                alpha, beta = (float(x) for x in self.rayleigh)
            except (TypeError, ValueError):
                raise InputError(f"rayleigh must be a pair (alpha, beta), got {self.rayleigh!r}") from None
            if not (np.isfinite(alpha) and np.isfinite(beta)) or alpha < 0 or beta < 0:
                raise InputError(f"rayleigh coefficients must be finite and >= 0, got alpha={alpha}, beta={beta}")
            object.__setattr__(self, "rayleigh", (alpha, beta))
        if self.ratio is not None:
            try:
                arr = np.asarray(self.ratio, dtype=float)
            except (TypeError, ValueError):
                raise InputError(f"damping ratio must be a number or a sequence of numbers, got {self.ratio!r}") from None
            if arr.ndim > 1 or not np.all(np.isfinite(arr)) or np.any(arr < 0):
                raise InputError("damping ratio must be finite and >= 0, a scalar or one value per mode")
            object.__setattr__(self, "ratio", float(arr) if arr.ndim == 0 else tuple(arr.tolist()))

    @classmethod
    def coerce(cls, value: Any) -> "Damping":
        """``None`` (the default ratio), a Damping, or a ratio (scalar or one per mode).

        Parameters
        ----------
        value : Damping, float, sequence of float or None
            The damping, or the ``ratio`` field (dimensionless), or ``None`` for the default.

        Returns
        -------
        Damping
            ``value`` itself when it is one, else a new ratio damping.
        """
        if value is None:
            return cls()
        if isinstance(value, cls):
            return value
        return cls(ratio=value)

    def ratios(self, omegas: ArrayLike) -> tuple[np.ndarray, dict]:
        """Damping ratio per mode, shape (k,), and the record stored with the modes.

        ``omegas`` (k,) are the angular frequencies, rad/s; rigid modes (0) get ``zeta = 0``.

        Parameters
        ----------
        omegas : array_like, shape (k,)
            Angular frequencies of the modes, rad/s.

        Returns
        -------
        zeta : ndarray, shape (k,)
            Damping ratio of each mode (dimensionless, 0 for rigid modes).
        record : dict
            ``{"kind": "ratio", "zeta": ...}`` or ``{"kind": "rayleigh", "alpha": ..., "beta": ...}``.
        """
        omegas = np.asarray(omegas, dtype=float)
        elastic = omegas > 0
        if self.rayleigh is not None:
            alpha, beta = self.rayleigh
            zeta = np.zeros(len(omegas))
            w = omegas[elastic]
            zeta[elastic] = alpha / (2.0 * w) + beta * w / 2.0
            return zeta, {"kind": "rayleigh", "alpha": alpha, "beta": beta}
        z = DEFAULT_DAMPING_RATIO if self.ratio is None else self.ratio
        arr = np.asarray(z, dtype=float)
        if arr.ndim == 0:
            arr = np.full(len(omegas), float(arr))
        if arr.shape != omegas.shape:
            raise InputError(f"damping ratio must be a scalar or have one value per mode ({len(omegas)}), "
                             f"got {arr.shape[0]}")
        arr = np.where(elastic, arr, 0.0)
        return arr, {"kind": "ratio", "zeta": float(z) if np.ndim(z) == 0 else arr.tolist()}


@dataclass(frozen=True)
class AutoResolution:
    """How :func:`~sc_fem.modes.auto.modal_converged` chooses the grid: the coarsest of
    ``resolutions`` whose frequencies agree with those of the next finer grid within ``tolerance``.

    Parameters
    ----------
    resolutions : sequence of int
        Grids tried (cubes along the longest axis), coarsest first; at least two.
    tolerance : float
        Largest relative change of the compared frequencies.
    """

    resolutions: tuple[int, ...] = AUTO_RESOLUTIONS
    tolerance: float = DEFAULT_RESOLUTION_TOLERANCE

    def __post_init__(self) -> None:
        try:
            grids = tuple(sorted({positive_int(r, "resolutions") for r in self.resolutions}))
        except TypeError:
            raise InputError(f"resolutions must be a sequence of integers, got {self.resolutions!r}") from None
        if len(grids) < 2:
            raise InputError(f"AutoResolution needs at least two positive resolutions, got {list(grids)}")
        object.__setattr__(self, "resolutions", grids)
        object.__setattr__(self, "tolerance", positive_scalar(self.tolerance, "tolerance"))


@dataclass(frozen=True)
class ModalRequest:
    """What :func:`sc_fem.modal` was asked for, checked once; read by the solve and the bake."""

    n_modes: int | None = None
    max_frequency: float | None = None
    max_modes: int = 200
    element: str = DEFAULT_ELEMENT
    lumped: bool = False
    damping: Damping = field(default_factory=Damping)
    eigen: EigenOptions = field(default_factory=EigenOptions)
    keep_rigid: bool = False
    keep_lattice: bool = False
    progress: bool = False

    def __post_init__(self) -> None:
        if not (isinstance(self.element, str) and self.element.lower() in (AUTO, *DEGREES)):
            object.__setattr__(self, "element", check_element(self.element))
        else:
            object.__setattr__(self, "element", self.element.lower())
        if self.n_modes is not None:
            object.__setattr__(self, "n_modes", positive_int(self.n_modes, "n_modes"))
        if self.max_frequency is not None:
            object.__setattr__(self, "max_frequency", positive_scalar(self.max_frequency, "max_frequency"))
        object.__setattr__(self, "max_modes", positive_int(self.max_modes, "max_modes"))
        object.__setattr__(self, "damping", Damping.coerce(self.damping))
        object.__setattr__(self, "eigen", EigenOptions.coerce(self.eigen))
