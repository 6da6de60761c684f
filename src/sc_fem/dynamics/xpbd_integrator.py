"""XPBD behind the common integrator interface, so the one driver (:func:`sc_fem.dynamics.simulate`,
:func:`sc_fem.dynamics.record`) runs it like Newmark or central differences: the same
:class:`~sc_fem.dynamics.State`, energy split, load work and blow-up check."""

from __future__ import annotations

import math
import time as _time

import numpy as np

from ..lattice.cubes import CubeModel
from .base import Energy
from .driver import State
from .loads import Gravity, LoadSet
from .xpbd import XPBDSolver


class XPBDIntegrator:
    """One ``dt`` step = ``substeps`` XPBD substeps of :class:`~sc_fem.dynamics.xpbd.XPBDSolver`.

    Parameters
    ----------
    model : CubeModel
    dt : float
        Frame step, s.
    fixed_nodes : array_like of int, optional
        Nodes held in place.
    gravity : array_like, shape (3,)
        m/s^2 (the only load XPBD takes).
    substeps, iterations, constraints, damping
        See :class:`~sc_fem.dynamics.xpbd.XPBDSolver`.
    """

    name = "xpbd"
    implicit = False
    contact = None

    def __init__(self, model: CubeModel, dt: float, *, fixed_nodes=None, gravity=(0.0, 0.0, 0.0),
                 substeps: int = 20, iterations: int = 1, constraints: str = "neohookean",
                 damping: float = 0.0) -> None:
        t0 = _time.perf_counter()
        self.solver = XPBDSolver(model, dt, substeps=substeps, iterations=iterations, constraints=constraints,
                                 gravity=gravity, fixed_nodes=fixed_nodes, damping=damping)
        self.model, self.dt = model, self.solver.dt
        g = tuple(float(x) for x in self.solver.gravity)
        self.loads = LoadSet(model, [Gravity(g)] if any(g) else [])
        self.max_contact_depth = -math.inf
        self.setup_seconds = _time.perf_counter() - t0

    @property
    def info(self) -> dict:
        s = self.solver
        return {"substeps": s.substeps, "iterations": s.iterations, "constraints": s.constraints}

    @property
    def state(self) -> State:
        return self._as_state(self.solver.state)

    def _as_state(self, s) -> State:
        return State(time=s.time, u=s.positions - self.solver.rest, v=s.velocities,
                     a=np.zeros_like(s.velocities), step=s.step)

    def energy(self) -> Energy:
        return self.solver.energy()

    def step(self) -> State:
        return self._as_state(self.solver.step())   # raises InstabilityError naming the too-long substep

    @property
    def dt_crit(self) -> float:
        """The frame step at which the substeps reach their rule-of-thumb limit, s."""
        return self.solver.substep_hint * self.solver.substeps
