"""What every time integrator of the cube lattice shares: matrices, loads, contact, energy.

The semi-discrete equations of motion on the free DOFs (fixed nodes condensed out) are

    M a + C v + f_int(u) = f(t),       C = a0 M + a1 K  (Rayleigh damping)

with ``u`` node displacements in metres, ``M`` (kg) the consistent or lumped mass,
``f_int = K u`` (linear) or the corotational force, ``f(t)`` the loads of a
:class:`~sc_fem.dynamics.loads.LoadSet` (N). Subclasses implement :meth:`TimeIntegrator._advance`.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import numpy as np

from .._validate import as_float_array, as_indices, positive_scalar
from ..fem.assemble import Assembler
from ..fem.boundary import fixed_dofs as _fixed_dofs
from ..fem.elements import DEFAULT_ELEMENT
from ..errors import BoundaryConditionError, InputError
from ..lattice.cubes import CubeModel
from ..fem.linsolve import factorize
from .driver import State
from .loads import LoadSet


@dataclass(frozen=True)
class Energy:
    """Energy of a state, J: ``kinetic``, ``elastic`` (0 at rest), ``gravity`` potential
    (``-f_g . u``, 0 at rest) and ``contact`` (the barrier potential of
    :class:`~sc_fem.dynamics.ipc.IPC`, 0 without contact); ``total`` is their sum."""

    kinetic: float
    elastic: float
    gravity: float
    contact: float = 0.0

    @property
    def total(self) -> float:
        return self.kinetic + self.elastic + self.gravity + self.contact

    @property
    def mechanical(self) -> float:
        """Kinetic + elastic (>= 0)."""
        return self.kinetic + self.elastic


class TimeIntegrator:
    """Base class: builds ``K``, ``M``, ``C`` on the free DOFs and steps a :class:`State`.

    Parameters
    ----------
    model : CubeModel
    dt : float
        Time step, s.
    element : {"q1i", "q1", "q1sri"}
        Element type.
    fixed_nodes : array_like of int, optional
        Lattice nodes held at zero displacement.
    loads : LoadSet, optional
        External loads (default none).
    contact : Contact, optional
        Obstacles; projected after every step. The integrator keeps a copy bound to its
        ``fixed_nodes`` (:meth:`~sc_fem.dynamics.contact.Contact.with_fixed_nodes`), so the
        projection never moves a fixed node.
    rayleigh : (float, float)
        Rayleigh coefficients ``(a0 [1/s], a1 [s])``: ``C = a0 M + a1 K``.
    lumped : bool
        Lumped (diagonal) instead of consistent mass.
    u0, v0 : array_like, shape (m, 3), optional
        Initial displacement (m) and velocity (m/s); default zero.
    backend : str
        Sparse factorization backend (:func:`sc_fem.fem.linsolve.factorize`).
    """

    name = "base"
    implicit = True

    def __init__(self, model: CubeModel, dt: float, *, element: str = DEFAULT_ELEMENT, fixed_nodes=None,
                 loads: LoadSet | None = None, contact=None, rayleigh=(0.0, 0.0), lumped: bool = False,
                 u0=None, v0=None, backend: str = "auto") -> None:
        if not isinstance(model, CubeModel):
            raise InputError(f"model must be a CubeModel, got {type(model).__name__}")
        self.model = model
        self.dt = positive_scalar(dt, "dt")
        self.element = element
        self.backend = backend
        fn = (np.zeros(0, dtype=np.int64) if fixed_nodes is None else
              np.unique(as_indices(fixed_nodes, model.n_nodes, "fixed_nodes", allow_mask=True,
                                   error=BoundaryConditionError)))
        self.fixed_nodes = fn
        t0 = _time.perf_counter()
        self.asm = Assembler(model, element, fixed_dofs=_fixed_dofs(fn))
        if self.asm.shape[0] == 0:
            raise InputError("every node is fixed: nothing moves")
        self.K = self.asm.stiffness()
        self.lumped = bool(lumped)
        self.M = self.asm.mass(lumped=self.lumped)
        # inverse of the lumped (diagonal) mass, 1/kg; None for the consistent mass
        self._minv = 1.0 / self.M.diagonal() if self.lumped else None
        self._dt_crit = None
        self.setup_seconds = _time.perf_counter() - t0
        r = as_float_array(rayleigh, "rayleigh", (2,))
        if np.any(r < 0):
            raise InputError(f"rayleigh coefficients must be >= 0, got {r.tolist()}")
        self.rayleigh = (float(r[0]), float(r[1]))
        self.loads = loads if loads is not None else LoadSet(model)
        if contact is not None and contact.model.n_nodes != model.n_nodes:
            raise InputError(f"contact was built for a model with {contact.model.n_nodes} nodes, "
                             f"this one has {model.n_nodes}")
        self.contact = None if contact is None else contact.with_fixed_nodes(fn)
        m = model.n_nodes
        u = np.zeros((m, 3)) if u0 is None else as_float_array(u0, "u0", (m, 3)).copy()
        v = np.zeros((m, 3)) if v0 is None else as_float_array(v0, "v0", (m, 3)).copy()
        u[fn], v[fn] = 0.0, 0.0
        if self.contact is not None:
            self.contact.check_initial(u)
        self._u, self._v = self.asm.restrict(u), self.asm.restrict(v)
        self._mass_solver = None
        self._a = self._initial_acceleration()
        self.time, self.n_steps = 0.0, 0
        self.max_contact_depth = -np.inf

    # ------------------------------------------------------------------ helpers
    def damping(self, v: np.ndarray, K=None) -> np.ndarray:
        """Damping force ``C v`` on the free DOFs."""
        a0, a1 = self.rayleigh
        out = np.zeros_like(v)
        if a0:
            out += a0 * (self.M @ v)
        if a1:
            out += a1 * ((self.K if K is None else K) @ v)
        return out

    def internal_force(self, u: np.ndarray) -> np.ndarray:
        """Elastic force ``f_int(u)`` on the free DOFs (linear: ``K u``), N."""
        return self.K @ u

    def elastic_energy(self, u: np.ndarray) -> float:
        """Strain energy (J) of free-DOF displacements ``u``."""
        return 0.5 * float(u @ (self.K @ u))

    def external_force(self, t: float) -> np.ndarray:
        """Load vector on the free DOFs at time ``t``, N."""
        return self.asm.restrict(self.loads.force(t))

    def solve_mass(self, r: np.ndarray) -> np.ndarray:
        """``M^-1 r`` on the free DOFs."""
        if self._minv is not None:
            return self._minv * r
        if self._mass_solver is None:
            self._mass_solver = factorize(self.M, self.backend)
        return self._mass_solver.solve(r)

    def _initial_acceleration(self) -> np.ndarray:
        r = self.external_force(0.0) - self.internal_force(self._u) - self.damping(self._v)
        return self.solve_mass(r)

    def set_velocity_from_impulse(self, impulse_nodes: np.ndarray) -> None:
        """Add ``M^-1 J`` to the velocity: ``J`` (m, 3) node impulses in N s (e.g. ``W^T`` of vertex
        impulses). The initial acceleration is recomputed (call before the first step)."""
        J = self.asm.restrict(as_float_array(impulse_nodes, "impulse", (self.model.n_nodes, 3)))
        self._v = self._v + self.solve_mass(J)
        self._a = self._initial_acceleration()

    # ------------------------------------------------------------------ public
    @property
    def state(self) -> State:
        """The current state (full node fields, fixed nodes at zero)."""
        return State(time=self.time, u=self.asm.expand(self._u), v=self.asm.expand(self._v),
                     a=self.asm.expand(self._a), step=self.n_steps)

    def energy(self) -> Energy:
        """Kinetic, elastic and gravity energy of the current state, J."""
        u, v = self._u, self._v
        return Energy(kinetic=0.5 * float(v @ (self.M @ v)), elastic=self.elastic_energy(u),
                      gravity=self.loads.gravity_potential(self.asm.expand(u)))

    def step(self) -> State:
        """Advance one step ``dt`` and return the new state."""
        t1 = self.time + self.dt
        self._u, self._v, self._a = self._advance(self._u, self._v, self._a, self.time, t1)
        if self.contact is not None:
            uf, vf, info = self.contact.project(self.asm.expand(self._u), self.asm.expand(self._v))
            if info.n_active:
                # the projection moved nodes: restart from the projected (u, v) with the
                # acceleration of the free equations of motion there
                self._u, self._v = self.asm.restrict(uf), self.asm.restrict(vf)
                self._a = self.solve_mass(self.external_force(t1) - self.internal_force(self._u)
                                          - self.damping(self._v))
            self.max_contact_depth = max(self.max_contact_depth, info.max_depth)
        self.time, self.n_steps = t1, self.n_steps + 1
        return self.state

    def _advance(self, u, v, a, t0, t1):   # pragma: no cover - abstract
        raise NotImplementedError

    @property
    def dt_crit(self) -> float:
        """Stability limit ``2 / omega_max`` (s) of explicit central differences with lumped mass
        on this model (:func:`sc_fem.dynamics.central.critical_time_step`); computed on first
        access (an eigenvalue solve) and kept."""
        if self._dt_crit is None:
            from .central import critical_time_step

            self._dt_crit = critical_time_step(self.K, self.M if self.lumped else self.asm.mass(lumped=True))
        return self._dt_crit
