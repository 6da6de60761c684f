"""Physical constants in SI units, shared by every layer.

sc_fem works in SI units throughout: metres, kilograms, seconds, newtons, pascals. A model read
in other units is scaled to metres by its ``scale`` (see :mod:`sc_fem.lattice.cubes`).
"""

from __future__ import annotations

from .errors import InputError

GRAVITY: float = 9.81
"""Standard gravity (m/s^2), the magnitude used wherever "gravity on" is asked for by name."""

AXES: tuple[str, ...] = ("x", "y", "z")
"""Names of the axes a model's ``up`` may be."""


def up_axis(up: str) -> int:
    """Index of a model's up axis.

    Parameters
    ----------
    up : {"x", "y", "z"}
        The model's up axis.

    Returns
    -------
    int
        0, 1 or 2.
    """
    if up not in AXES:
        raise InputError(f"up must be one of {list(AXES)}, got {up!r}")
    return AXES.index(up)


def gravity_down(up: str = "z") -> tuple[float, float, float]:
    """Standard gravity pointing down a model's ``up`` axis: the gravity vector of "gravity on".

    Parameters
    ----------
    up : {"x", "y", "z"}
        The model's up axis (many OBJ and glTF models are y-up).

    Returns
    -------
    tuple of 3 float
        Gravitational acceleration, m/s^2, e.g. ``(0, 0, -9.81)`` for ``up="z"``.
    """
    a = up_axis(up)
    return tuple(-GRAVITY if k == a else 0.0 for k in range(3))
