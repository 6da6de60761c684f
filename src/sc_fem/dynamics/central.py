"""Explicit central differences (leapfrog / Verlet) with lumped mass.

Step (``M`` diagonal, so no linear solve)::

    v_{n+1/2} = v_n + dt/2 a_n
    u_{n+1}   = u_n + dt v_{n+1/2}
    a_{n+1}   = M^-1 (f(t_{n+1}) - K u_{n+1} - C v_{n+1/2})
    v_{n+1}   = v_{n+1/2} + dt/2 a_{n+1}

which is Newmark with ``beta = 0``, ``gamma = 1/2`` (the damping force uses the half-step
velocity, which keeps the step explicit). Second-order accurate, conditionally stable: for the
undamped system the step must satisfy ``dt <= dt_crit = 2 / omega_max`` with ``omega_max^2`` the
largest eigenvalue of ``M^-1 K`` (:func:`~sc_fem.dynamics.base.critical_time_step`; a lattice of edge ``h`` has
``dt_crit ~ h / c`` with ``c`` the P-wave speed). Stiffness-proportional damping lowers the limit.
"""

from __future__ import annotations

from typing import Any

from ..errors import InputError
from ..lattice.cubes import CubeModel
from .base import AssembledIntegrator


class CentralDifference(AssembledIntegrator):
    """Explicit central differences with lumped mass (see the module docstring).

    :attr:`~sc_fem.dynamics.base.AssembledIntegrator.dt_crit` is the stability limit (computed on
    first access); a run without a ``dt`` steps at ``0.9 dt_crit``.

    Parameters
    ----------
    model : CubeModel
    dt : float
        Time step, s (stable for ``dt <= dt_crit``).
    **kw
        As :class:`~sc_fem.dynamics.base.AssembledIntegrator` (``lumped`` is forced to True); the
        Newmark parameters ``beta``, ``gamma``, ``alpha`` and ``iterations`` are refused unless None.
    """

    name = "central"
    implicit = False
    steps_per_frame = None

    def __init__(self, model: CubeModel, dt: float, **kw: Any) -> None:
        for k in ("beta", "gamma", "alpha", "iterations"):
            if kw.pop(k, None) is not None:
                raise InputError(f"method 'central' has no parameter {k!r}")
        kw["lumped"] = True
        super().__init__(model, dt, **kw)

    def _advance(self, u, v, a, t0, t1):
        dt = self.dt
        vh = v + 0.5 * dt * a
        u1 = u + dt * vh
        a1 = self._minv * (self.external_force(t1) - self.internal_force(u1) - self.damping(vh))
        return u1, vh + 0.5 * dt * a1, a1
