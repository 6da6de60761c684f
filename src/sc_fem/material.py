"""Material parameters: Young's modulus E (Pa), Poisson's ratio nu, density rho (kg/m^3).

A :class:`Material` is what a built-in model documents and what the CLI accepts;
:func:`lame` converts (E, nu) to the Lame parameters used by the elements, and
:func:`resolve_field` turns the user's ``youngs=`` / ``poisson=`` / ``density=`` keyword
(scalar, per-face array or callable of position) into one value per sample point.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ._validate import check_material
from .errors import InputError


@dataclass(frozen=True)
class Material:
    """An isotropic linear-elastic material.

    Parameters
    ----------
    youngs : float
        Young's modulus E in Pa (> 0).
    poisson : float
        Poisson's ratio nu in (-1, 0.5).
    density : float
        Mass density rho in kg/m^3 (> 0).
    name : str
        A label for reports.
    """

    youngs: float
    poisson: float
    density: float
    name: str = ""

    def __post_init__(self) -> None:
        check_material(np.array([self.youngs]), np.array([self.poisson]), np.array([self.density]),
                       where=self.name or "Material")


def lame(youngs: np.ndarray | float, poisson: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """Lame parameters (lambda, mu) in Pa from E (Pa) and nu.

    Parameters
    ----------
    youngs : float or ndarray
        Young's modulus E, Pa (> 0).
    poisson : float or ndarray
        Poisson's ratio nu, in (-1, 0.5); broadcast against ``youngs``.

    Returns
    -------
    lam, mu : ndarray
        First Lame parameter and shear modulus, Pa; same shape as the broadcast inputs.
    """
    E = np.asarray(youngs, dtype=float)
    nu = np.asarray(poisson, dtype=float)
    check_material(E, nu)
    lam = E * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))
    mu = E / (2.0 * (1.0 + nu))
    return lam, mu


def resolve_field(value: Any, name: str, points: np.ndarray, face_index: np.ndarray | None,
                  n_faces: int) -> np.ndarray:
    """Evaluate a material keyword at sample points.

    Parameters
    ----------
    value : float, array_like (n_faces,) or callable
        A scalar for everything; one value per source-mesh face; or a callable
        ``f(points (n, 3)) -> (n,)`` of model-space position.
    name : str
        Keyword name for error messages.
    points : ndarray, shape (n, 3)
        Sample positions in model units.
    face_index : ndarray of int, shape (n,) or None
        Source face of each sample (``None`` when samples do not come from faces).
    n_faces : int
        Number of faces of the source mesh.

    Returns
    -------
    ndarray, shape (n,)
    """
    n = len(points)
    if callable(value):
        try:
            out = np.asarray(value(points), dtype=float)
        except Exception as exc:  # user code: report which keyword failed
            raise InputError(f"{name}= callable failed on sample points: {exc}") from exc
        if out.shape == ():
            out = np.full(n, float(out))
        if out.shape != (n,):
            raise InputError(f"{name}= callable must return shape ({n},) for {n} points, got {out.shape}")
        return out
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.ndim == 1 and arr.shape[0] == n_faces and n_faces > 0:
        if face_index is None:
            raise InputError(f"{name}= per-face values need samples that come from faces")
        return arr[face_index]
    raise InputError(f"{name}= must be a scalar, a per-face array of shape ({n_faces},) or a callable; "
                     f"got shape {arr.shape}")
