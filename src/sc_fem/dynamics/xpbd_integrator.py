"""XPBD as a :class:`~sc_fem.dynamics.base.TimeIntegrator`, so the one driver
(:func:`sc_fem.dynamics.simulate`, :func:`sc_fem.dynamics.record`) runs it like Newmark or central
differences: the same :class:`~sc_fem.dynamics.State`, energy split, load work and blow-up check."""

from __future__ import annotations

import time as _time

import numpy as np

from ..errors import InputError
from ..lattice.cubes import CubeModel
from .base import TimeIntegrator
from .loads import LoadSet
from .state import Energy, State
from .xpbd import XPBDOptions, XPBDSolver


class XPBDIntegrator(TimeIntegrator):
    """One ``dt`` step = ``substeps`` XPBD substeps of :class:`~sc_fem.dynamics.xpbd.XPBDSolver`.

    Parameters
    ----------
    model : CubeModel
    dt : float
        Frame step, s.
    fixed_nodes : array_like of int, optional
        Nodes held in place.
    loads : LoadSet, optional
        Gravity only (the one load XPBD takes; default none).
    substeps, iterations, constraints, damping
        See :class:`~sc_fem.dynamics.xpbd.XPBDSolver` (defaults :class:`~sc_fem.dynamics.xpbd.XPBDOptions`).
    **solver_kw
        Further options of :class:`~sc_fem.dynamics.xpbd.XPBDSolver` (``kernel``, ``warm_start``, ...).
    """

    name = "xpbd"
    implicit = False
    supports = frozenset({"substeps"})
    steps_per_frame = 1
    convergence_hint = "use more substeps"

    def __init__(self, model: CubeModel, dt: float, *, fixed_nodes=None, loads: LoadSet | None = None,
                 substeps: int = XPBDOptions.substeps, iterations: int = XPBDOptions.iterations,
                 constraints: str = XPBDOptions.constraints, damping: float = XPBDOptions.damping,
                 **solver_kw) -> None:
        t0 = _time.perf_counter()
        super().__init__(model, dt, fixed_nodes=fixed_nodes, loads=loads)
        if self.loads.n_forces:
            raise InputError("method 'xpbd' takes gravity only: no forces or pressures in its loads")
        self.solver = XPBDSolver(model, self.dt, substeps=substeps, iterations=iterations, constraints=constraints,
                                 gravity=self.loads.gravity, fixed_nodes=self.fixed_nodes, damping=damping,
                                 **solver_kw)
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
        st = self._as_state(self.solver.step())     # raises InstabilityError naming the too-long substep
        self.time, self.n_steps = st.time, st.step
        return st

    @property
    def dt_crit(self) -> float:
        """The frame step at which the substeps reach their rule-of-thumb limit, s."""
        return self.solver.substep_hint * self.solver.substeps

    def blowup_hint(self) -> str:
        return "use more substeps (or constraints='corotational')"
