"""What a time integrator hands out: a :class:`State` of the lattice and its :class:`Energy` by kind.

The bottom of :mod:`sc_fem.dynamics`: plain records, imported by the integrators and the driver alike.
Units: SI (m, m/s, m/s^2, s, J).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Energy:
    """Energy of a state by kind, J; :attr:`total` is their sum.

    Attributes
    ----------
    kinetic : float
        Kinetic energy, J.
    elastic : float
        Strain energy, J (0 at rest).
    gravity : float
        Gravity potential ``-f_g . u``, J (0 at rest).
    contact : float
        Barrier potential of :class:`~sc_fem.dynamics.ipc.IPC`, J (0 without contact).
    """

    kinetic: float
    elastic: float
    gravity: float
    contact: float = 0.0

    @property
    def total(self) -> float:
        """Kinetic + elastic + gravity + contact, J."""
        return self.kinetic + self.elastic + self.gravity + self.contact

    @property
    def mechanical(self) -> float:
        """Kinetic + elastic (>= 0)."""
        return self.kinetic + self.elastic


@dataclass(frozen=True, eq=False)
class State:
    """A dynamic state of the lattice.

    Attributes
    ----------
    time : float
        Seconds.
    u : ndarray, shape (m, 3)
        Node displacements, m (zero on fixed nodes).
    v : ndarray, shape (m, 3)
        Node velocities, m/s.
    a : ndarray, shape (m, 3)
        Node accelerations, m/s^2.
    step : int
        Steps taken.
    energy : float
        Kinetic + elastic + gravity + contact energy, J (NaN until :func:`~sc_fem.dynamics.driver.simulate` fills it).
    mechanical : float
        Kinetic + elastic energy, J (>= 0; NaN until :func:`~sc_fem.dynamics.driver.simulate` fills it).
    parts : Energy or None
        The energy by kind (:class:`Energy`), filled by :func:`~sc_fem.dynamics.driver.simulate`.
    work : float
        Work done by the loads since the start, J (trapezoidal rule; NaN until filled).
    """

    time: float
    u: np.ndarray
    v: np.ndarray
    a: np.ndarray
    step: int = 0
    energy: float = float("nan")
    mechanical: float = float("nan")
    parts: object = None
    work: float = float("nan")
