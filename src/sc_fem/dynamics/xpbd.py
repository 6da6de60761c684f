"""XPBD (Macklin, Mueller & Chentanez 2016) on the Squashing Cubes lattice: :class:`XPBDSolver`.

Per substep: predict, one or more vectorized Gauss-Seidel sweeps (8 cube colours) over the
constraints of every cube, update velocities. Constraints: ``"neohookean"`` (default; the stable
Neo-Hookean pair linearising to the lattice's own Lame parameters), ``"corotational"`` (an ARAP
block, stable at long substeps but soft) and ``"distance"`` (a central-force lattice). A step that
blows up raises :class:`~sc_fem.errors.InstabilityError` naming the substep that is too long.
The constraints and their projection are in :mod:`.xpbd_constraints` (batched kernels in
:mod:`.xpbd_kernels`), the stability sweep in :mod:`.xpbd_stability`;
the algorithm, the quadrature and the measurements behind the defaults are in ``docs/xpbd.md``.
Through :class:`~sc_fem.dynamics.xpbd_integrator.XPBDIntegrator` it runs on the common driver.

Units: positions in metres, velocities m/s, times s, energies J.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np
from numpy.typing import ArrayLike

from .._progress import stage_bar
from .._validate import as_float_array, as_points, positive_int, positive_scalar
from ..errors import InputError, InstabilityError
from ..lattice.cubes import CubeModel
from .loads import DOWN
from .state import Energy
from .xpbd_constraints import CONSTRAINTS, ConstraintSet
from .xpbd_jit import choose_kernel
from .xpbd_kernels import _as_fixed

XPBDEnergy = Energy
"""Energy split of an XPBD state (alias of :class:`sc_fem.dynamics.state.Energy`): kinetic,
gravity potential (relative to the rest positions), elastic (of the constraints, zero at rest), J."""


@dataclass(frozen=True)
class XPBDOptions:
    """Options of the XPBD method, and their defaults wherever XPBD runs (:class:`XPBDSolver`,
    :func:`simulate_xpbd`, :class:`~sc_fem.dynamics.xpbd_integrator.XPBDIntegrator`,
    :func:`~sc_fem.dynamics.job.run_simulation`): substeps per step, solver iterations per substep,
    the constraint family and the mass-proportional damping rate (1/s)."""

    substeps: int = 20
    iterations: int = 1
    constraints: str = "neohookean"
    damping: float = 0.0


@dataclass(frozen=True, eq=False)
class XPBDState:
    """State of an XPBD simulation after a step.

    Attributes
    ----------
    time : float
        Seconds since the start.
    step : int
        Number of (frame) steps taken.
    positions : ndarray, shape (m, 3)
        Node positions, metres.
    velocities : ndarray, shape (m, 3)
        Node velocities, m/s.
    """

    time: float
    step: int
    positions: np.ndarray
    velocities: np.ndarray


class XPBDSolver:
    """XPBD time integrator of a :class:`~sc_fem.lattice.cubes.CubeModel`.

    Parameters
    ----------
    model : CubeModel
        The lattice (material per cube: ``youngs``, ``poisson``; masses ``model.mass``).
    dt : float
        Frame step in seconds (one :meth:`step`); split into ``substeps`` substeps.
    substeps, iterations : int
        Substeps per step (default 20) and solver iterations per substep (J of Algorithm 1; default 1).
    constraints : {"neohookean", "corotational", "distance"}
        Constraint family (see the module docstring).
    gravity : array_like, shape (3,)
        m/s^2 (default 9.81 down z, :data:`~sc_fem.dynamics.loads.DOWN`).
    fixed_nodes : array_like of int or bool mask (m,), optional
        Nodes held at their initial positions.
    damping : float
        Mass-proportional damping rate in 1/s (0 = none besides XPBD's numerical damping).
    gauss_seidel : bool
        8-colour Gauss-Seidel sweeps (default) or under-relaxed Jacobi.
    relaxation : float
        Jacobi relaxation factor ``omega`` (per-constraint step scaled by ``omega / valence``).
    warm_start : bool
        Re-use the previous substep's multipliers (see module docstring). False = Algorithm 1.
    max_energy_growth : float
        Blow-up threshold: :meth:`step` raises :class:`~sc_fem.errors.InstabilityError` when the
        total energy exceeds its start by more than this many :attr:`energy_scale` (default 10).
    positions, velocities : array_like, shape (m, 3), optional
        Initial state in metres and m/s (default: rest positions ``model.nodes_m``, zero).
    kernel : {"auto", "numba", "numpy"}
        Sweep of the Neo-Hookean Gauss-Seidel iteration: compiled (:mod:`sc_fem.dynamics.xpbd_jit`,
        needs numba) or vectorized numpy per colour; ``"auto"``: compiled when numba is installed.
        Both give the same result up to round-off. The chosen one is :attr:`kernel`.
    """

    def __init__(self, model: CubeModel, dt: float, *, substeps: int = XPBDOptions.substeps,
                 iterations: int = XPBDOptions.iterations, constraints: str = XPBDOptions.constraints,
                 gravity: ArrayLike = DOWN, fixed_nodes: ArrayLike | None = None, damping: float = XPBDOptions.damping,
                 gauss_seidel: bool = True, relaxation: float = 1.0, warm_start: bool = False,
                 max_energy_growth: float = 10.0, positions: ArrayLike | None = None,
                 velocities: ArrayLike | None = None, kernel: str = "auto") -> None:
        if not isinstance(model, CubeModel):
            raise InputError(f"model must be a CubeModel, got {type(model).__name__}")
        if constraints not in CONSTRAINTS:
            raise InputError(f"constraints must be one of {CONSTRAINTS}, got {constraints!r}")
        self.model = model
        self.dt = positive_scalar(dt, "dt")
        self.substeps = positive_int(substeps, "substeps")
        self.iterations = positive_int(iterations, "iterations")
        self.constraints = constraints
        self.gravity = as_float_array(gravity, "gravity", (3,)).copy()
        self.damping = positive_scalar(damping, "damping", allow_zero=True)
        self.relaxation = positive_scalar(relaxation, "relaxation")
        if self.relaxation >= 2.0:
            raise InputError(f"relaxation must be in (0, 2), got {self.relaxation}")
        self.gauss_seidel = bool(gauss_seidel)
        self.warm_start = bool(warm_start)
        self.max_energy_growth = positive_scalar(max_energy_growth, "max_energy_growth")
        m = model.n_nodes
        self.rest = model.nodes_m.copy()
        x = self.rest.copy() if positions is None else as_float_array(positions, "positions", (m, 3)).copy()
        v = np.zeros((m, 3)) if velocities is None else as_float_array(velocities, "velocities", (m, 3)).copy()
        self.fixed_mask = _as_fixed(fixed_nodes, m)
        self.mass = model.node_masses()
        self.w = np.where(self.fixed_mask, 0.0, 1.0 / self.mass)
        v[self.fixed_mask] = 0.0
        self._x, self._v = x, v
        self.time, self.n_steps = 0.0, 0
        self._energy_cache = (None, None)          # (positions array, its energy)
        self.last_energy_growth = 0.0
        """Energy growth (see :meth:`energy_growth`) after the last :meth:`step`."""
        self.kernel = choose_kernel(kernel, constraints == "neohookean" and self.gauss_seidel)
        """The sweep that runs: ``"numba"`` or ``"numpy"``."""
        self.constraint_set = ConstraintSet(model, constraints, self.w, self.rest, relaxation=self.relaxation)
        """The constraints, their multipliers and their projection."""
        e0 = self.energy()
        self._energy0 = e0.total
        lo, hi = self.rest.min(0), self.rest.max(0)
        self.energy_scale = max(abs(e0.kinetic) + abs(e0.elastic),
                                float(self.mass.sum() * np.linalg.norm(self.gravity) * np.linalg.norm(hi - lo)),
                                1e-300)
        """Energy scale (J) of the runaway test: ``max(initial kinetic + elastic, M |g| diameter)``."""

    # ------------------------------------------------------------------ time stepping
    def substep(self, ds: float) -> None:
        """Advance by one substep (Algorithm 1).

        Parameters
        ----------
        ds : float
            Substep length, s.
        """
        x_prev = self._x
        free = ~self.fixed_mask
        x = x_prev + ds * self._v
        x[free] += ds * ds * self.gravity
        cs = self.constraint_set
        a_t = cs.compliance(ds)
        if self.warm_start:
            cs.apply_multipliers(x, x_prev)
        else:
            cs.reset_multipliers()
        for _ in range(self.iterations):
            cs.iterate(x, a_t, gauss_seidel=self.gauss_seidel, kernel=self.kernel)
        v = (x - x_prev) / ds
        if self.damping > 0.0:
            v /= 1.0 + self.damping * ds
        self._x, self._v = x, v

    def step(self) -> XPBDState:
        """Advance one frame step ``dt`` (``substeps`` substeps).

        Returns
        -------
        XPBDState
            The new state (copies).

        Raises
        ------
        InstabilityError
            If the positions or velocities become non-finite, or the total energy exceeds its
            start by more than ``max_energy_growth`` x :attr:`energy_scale` (the growth is kept
            in :attr:`last_energy_growth`).
        """
        ds = self.dt / self.substeps
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):   # checked just below
            for _ in range(self.substeps):
                self.substep(ds)
            self.time += self.dt
            self.n_steps += 1
            finite = bool(np.all(np.isfinite(self._x)) and np.all(np.isfinite(self._v)))
            growth = self.energy_growth() if finite else np.inf
        self.last_energy_growth = growth
        if not finite or not growth <= self.max_energy_growth:
            what = ("non-finite positions" if not finite else
                    f"energy grew by {growth:.3g} x its scale {self.energy_scale:.3g} J")
            hint = self.substep_hint
            need = int(np.ceil(self.dt / hint))
            raise InstabilityError(
                f"XPBD ({self.constraints}) blew up at step {self.n_steps} (t = {self.time:g} s): {what}; "
                f"substep {ds * 1e3:.4g} ms ({self.substeps} substeps of the {self.dt:g} s step) is too "
                f"long: with one Gauss-Seidel sweep the shear stiffness is integrated explicitly, so "
                f"substeps must stay below roughly 0.4 h / c_s = {hint * 1e3:.3g} ms here (c_s the shear "
                f"wave speed) -- use substeps >= {need}" + (" or constraints='corotational' (stable, but soft "
                "at long substeps)" if self.constraints == "neohookean" else ""))
        return self.state

    @property
    def substep_hint(self) -> float:
        """Rule-of-thumb longest stable substep, s: ``0.4 h / c_s`` with the shear wave speed
        ``c_s = sqrt(mu / rho)`` of the median cube (``rho`` = cube mass / h^3). Measured limits: 4 m
        bar (h = 8.3 cm, 50 MPa) ~0.5 ms vs hint 0.24 ms; 5 cm, 5 MPa lattice 0.66 ms vs 0.46 ms."""
        _, mu = self.model.lame()
        rho = self.model.mass / self.model.h ** 3
        return 0.4 * self.model.h / float(np.median(np.sqrt(mu / rho)))

    def energy_growth(self) -> float:
        """Energy created since the start, relative to :attr:`energy_scale`.

        Returns
        -------
        float
            ``(E_total - E_total(t=0)) / energy_scale``, dimensionless (XPBD should keep it <= ~0 up
            to the work of gravity, which is bounded by one ``energy_scale``).
        """
        return (self.energy().total - self._energy0) / self.energy_scale

    @property
    def state(self) -> XPBDState:
        """The current state (copies)."""
        return XPBDState(time=self.time, step=self.n_steps, positions=self._x.copy(),
                         velocities=self._v.copy())

    def run(self, n_steps: int, *, progress: bool = False) -> Iterator[XPBDState]:
        """Yield the current state, then the state after each of ``n_steps`` steps.

        Parameters
        ----------
        n_steps : int
            Frame steps to take (>= 0).
        progress : bool
            Show a progress bar on stderr (:func:`sc_fem._progress.stage_bar`).

        Yields
        ------
        XPBDState
            ``n_steps + 1`` states (copies).
        """
        n_steps = positive_int(n_steps, "n_steps", minimum=0)
        yield self.state
        with stage_bar("xpbd", n_steps, unit="step", enabled=progress) as bar:
            for _ in range(n_steps):
                st = self.step()
                bar.update(1)
                yield st

    def __iter__(self) -> Iterator[XPBDState]:
        while True:
            yield self.step()

    # ------------------------------------------------------------------ diagnostics
    def constraint_values(self, positions: ArrayLike | None = None) -> dict:
        """Constraint values at ``positions``.

        Parameters
        ----------
        positions : array_like, shape (m, 3), optional
            Node positions, m (default: current).

        Returns
        -------
        dict
            By constraint kind: :meth:`~sc_fem.dynamics.xpbd_constraints.ConstraintSet.values`.
        """
        return self.constraint_set.values(self._x if positions is None else as_points(positions, "positions"))

    def elastic_energy(self, positions: ArrayLike | None = None) -> float:
        """Elastic energy of the constraints at ``positions``, zero at rest
        (:meth:`~sc_fem.dynamics.xpbd_constraints.ConstraintSet.elastic_energy`).

        Parameters
        ----------
        positions : array_like, shape (m, 3), optional
            Node positions, m (default: current).

        Returns
        -------
        float
            Elastic energy, J.
        """
        return self.constraint_set.elastic_energy(self._x if positions is None else as_points(positions, "positions"))

    def energy(self, state: XPBDState | None = None) -> XPBDEnergy:
        """Kinetic + gravity potential (relative to rest) + elastic energy.

        Parameters
        ----------
        state : XPBDState, optional
            Default: the current state (computed once per state; :meth:`step` evaluates it).

        Returns
        -------
        XPBDEnergy
            By kind, J.
        """
        if state is None and self._energy_cache[0] is self._x:
            return self._energy_cache[1]
        e = self._energy_of(state)
        if state is None:
            self._energy_cache = (self._x, e)
        return e

    def _energy_of(self, state: XPBDState | None) -> XPBDEnergy:
        x = self._x if state is None else state.positions
        v = self._v if state is None else state.velocities
        kin = 0.5 * float(np.sum(self.mass[:, None] * v * v))
        grav = -float(np.sum(self.mass * ((x - self.rest) @ self.gravity)))
        return XPBDEnergy(kinetic=kin, gravity=grav, elastic=self.elastic_energy(x))


def simulate_xpbd(model: CubeModel, dt: float, n_steps: int, *, substeps: int = XPBDOptions.substeps,
                  iterations: int = XPBDOptions.iterations, constraints: str = XPBDOptions.constraints,
                  gravity: ArrayLike = DOWN, fixed_nodes: ArrayLike | None = None, damping: float = XPBDOptions.damping,
                  gauss_seidel: bool = True, warm_start: bool = False, progress: bool = False,
                  **kw: Any) -> Iterator[XPBDState]:
    """Generator of XPBD states: the initial state (t = 0) then ``n_steps`` steps of ``dt`` s.

    The common driver runs XPBD like the other methods instead
    (:func:`~sc_fem.dynamics.driver.make_integrator` ``("xpbd", ...)``,
    :func:`~sc_fem.dynamics.driver.simulate`), with its states and energy accounting.

    Parameters
    ----------
    model : CubeModel
    dt : float
        Frame step, s.
    n_steps : int
        Frame steps after the initial state.
    substeps, iterations, constraints, gravity, fixed_nodes, damping, gauss_seidel, warm_start
        As :class:`XPBDSolver` (``gravity`` m/s^2, shape (3,); ``damping`` 1/s).
    progress : bool
        Show a progress bar on stderr.
    **kw
        Further :class:`XPBDSolver` options (``relaxation``, ``max_energy_growth``, ``positions``,
        ``velocities``, ``kernel``).

    Yields
    ------
    XPBDState
        ``n_steps + 1`` states.
    """
    solver = XPBDSolver(model, dt, substeps=substeps, iterations=iterations, constraints=constraints,
                        gravity=gravity, fixed_nodes=fixed_nodes, damping=damping, gauss_seidel=gauss_seidel,
                        warm_start=warm_start, **kw)
    yield from solver.run(n_steps, progress=progress)
