"""Physical constants in SI units, shared by every layer.

sc_fem works in SI units throughout: metres, kilograms, seconds, newtons, pascals. A model read
in other units is scaled to metres by its ``scale`` (see :mod:`sc_fem.lattice.cubes`).
"""

from __future__ import annotations

GRAVITY: float = 9.81
"""Standard gravity (m/s^2), the magnitude used wherever "gravity on" is asked for by name."""
