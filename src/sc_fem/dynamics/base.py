"""What every time integrator of the cube lattice shares: matrices, loads, contact, energy, and the
stability limit of explicit stepping (:func:`critical_time_step`).

The semi-discrete equations of motion on the free DOFs (fixed nodes condensed out) are

    M a + C v + f_int(u) = f(t),       C = a0 M + a1 K  (Rayleigh damping)

with ``u`` node displacements (m), ``M`` the consistent or lumped mass (kg), ``f_int = K u`` or the
corotational force, ``f(t)`` the loads (N). :class:`TimeIntegrator` is what every method shares (XPBD
too); :class:`AssembledIntegrator` builds ``K``, ``M``, ``C``; its subclasses implement ``_advance``.
"""

from __future__ import annotations

import time as _time
from collections.abc import Sequence
from dataclasses import replace
from functools import cache, partial

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.linalg import ArpackNoConvergence, eigsh

from .._validate import as_float_array, as_indices, positive_scalar
from ..fem.assemble import Assembler
from ..lattice.boundary import fixed_dofs as _fixed_dofs
from ..fem.elements import DEFAULT_ELEMENT
from ..errors import BoundaryConditionError, InputError, SolverError
from ..lattice.cubes import CubeModel
from ..fem.options import DynamicOptions
from ..fem.linsolve import Lag, MassSolver, SystemSolver, factorize
from ..fem.static import lattice_amg_data
from .contact import Contact
from .loads import LoadSet
from .state import Energy, State


def max_frequency(K: sp.spmatrix, M_lumped: sp.spmatrix | np.ndarray, *, tol: float = 1e-8, seed: int = 0) -> float:
    """Largest circular frequency ``omega_max`` (rad/s) of ``K x = omega^2 M x`` with diagonal ``M``.

    Uses ARPACK (``eigsh``, largest algebraic eigenvalue of ``D^-1/2 K D^-1/2``), falling back
    to a power iteration if ARPACK does not converge.
    """
    d = np.asarray(M_lumped.diagonal() if sp.issparse(M_lumped) else M_lumped, dtype=float)
    if np.any(d <= 0):
        raise SolverError("the lumped mass has non-positive entries; cannot compute omega_max")
    s = sp.diags(1.0 / np.sqrt(d))
    A = (s @ K @ s).tocsr()
    n = A.shape[0]
    if n <= 3:
        lam = float(np.linalg.eigvalsh(A.toarray()).max())
    else:
        v0 = np.random.default_rng(seed).standard_normal(n)
        try:
            lam = float(eigsh(A, k=1, which="LA", tol=tol, v0=v0, maxiter=max(1000, 20 * n),
                              return_eigenvectors=False)[0])
        except ArpackNoConvergence:
            x = v0 / np.linalg.norm(v0)
            lam = 0.0
            for _ in range(5000):                          # power iteration (A is PSD)
                y = A @ x
                lam_new, x = float(x @ y), y / np.linalg.norm(y)
                done, lam = abs(lam_new - lam) <= tol * abs(lam_new), lam_new
                if done:
                    break
    return float(np.sqrt(max(lam, 0.0)))


def critical_time_step(K: sp.spmatrix, M_lumped: sp.spmatrix | np.ndarray) -> float:
    """``dt_crit = 2 / omega_max`` (s) of undamped central differences with lumped mass ``M_lumped``.

    Parameters
    ----------
    K : scipy.sparse matrix, shape (n, n)
        Stiffness on the free DOFs, N/m.
    M_lumped : scipy.sparse matrix (n, n) or ndarray (n,)
        Lumped (diagonal) mass or its diagonal, kg; all entries > 0.

    Returns
    -------
    float
        Stability limit, s (``inf`` when ``K`` has no positive eigenvalue).
    """
    w = max_frequency(K, M_lumped)
    return float("inf") if w == 0 else 2.0 / w


class TimeIntegrator:
    """Base class of every method: steps a :class:`State` of ``model`` by ``dt`` under ``loads``, the
    ``fixed_nodes`` held in place. :func:`~sc_fem.dynamics.driver.simulate` runs any subclass.

    A subclass names itself (``name``, the key of :data:`~sc_fem.dynamics.driver.METHODS`), says
    whether it is ``implicit``, declares what it :attr:`supports` and how long its default step is
    (:attr:`steps_per_frame`), and implements :attr:`state`, :meth:`energy`, :meth:`step` and
    :attr:`dt_crit`.

    Parameters
    ----------
    model : CubeModel
    dt : float
        Time step, s.
    fixed_nodes : array_like of int or bool mask (m,), optional
        Lattice nodes held at zero displacement.
    loads : LoadSet, optional
        External loads (default none).
    """

    name = "base"
    implicit = True
    supports: frozenset = frozenset()
    """What the method takes besides gravity and fixed nodes: ``"loads"`` (forces and pressures),
    ``"contact"`` (obstacles), ``"impulses"``, ``"velocity"`` (an initial velocity), ``"rayleigh"``
    (damping), ``"element"`` (the element type), ``"newmark"`` (``beta``, ``gamma``, HHT ``alpha``),
    ``"friction"`` (of the contacts) and ``"substeps"`` (XPBD's substeps, iterations, constraints
    and damping). :func:`~sc_fem.dynamics.job.run_simulation` refuses options a method does not
    support."""
    steps_per_frame: int | None = 2
    """Time steps per recorded frame when a run gives no ``dt``; None: the longest step below
    ``0.9 dt_crit`` that divides the frame (a conditionally stable method)."""
    convergence_hint = "use --method ipc, or a smaller dt"
    """What to change when a run creates energy (the warning of :func:`~sc_fem.dynamics.job.run_simulation`)."""
    contact = None

    def __init__(self, model: CubeModel, dt: float, *, fixed_nodes: ArrayLike | None = None,
                 loads: LoadSet | None = None) -> None:
        if not isinstance(model, CubeModel):
            raise InputError(f"model must be a CubeModel, got {type(model).__name__}")
        self.model = model
        self.dt = positive_scalar(dt, "dt")
        self.fixed_nodes = (np.zeros(0, dtype=np.int64) if fixed_nodes is None else
                            np.unique(as_indices(fixed_nodes, model.n_nodes, "fixed_nodes", allow_mask=True,
                                                 error=BoundaryConditionError)))
        self.loads = loads if loads is not None else LoadSet(model)
        self.time, self.n_steps = 0.0, 0
        self.max_contact_depth = -np.inf
        self.setup_seconds = 0.0

    @property
    def info(self) -> dict:
        """Counters and settings of the run for its record (none by default)."""
        return {}

    @property
    def state(self) -> State:   # pragma: no cover - abstract
        """The current state (full node fields, fixed nodes at zero)."""
        raise NotImplementedError

    def energy(self) -> Energy:   # pragma: no cover - abstract
        """The energy of the current state by kind, J."""
        raise NotImplementedError

    def step(self) -> State:   # pragma: no cover - abstract
        """Advance one step ``dt`` and return the new state."""
        raise NotImplementedError

    @property
    def dt_crit(self) -> float:   # pragma: no cover - abstract
        """The step (s) beyond which the method is expected to blow up."""
        raise NotImplementedError

    def set_velocity_from_impulse(self, impulse_nodes: ArrayLike) -> None:
        """Add the velocity of node impulses ``J`` (methods that support ``"impulses"``).

        Parameters
        ----------
        impulse_nodes : array_like, shape (m, 3)
            Node impulses ``J``, N s.
        """
        raise InputError(f"method {self.name!r} takes no impulses")

    def blowup_hint(self) -> str:
        """What to change when a run of this method blows up.

        Returns
        -------
        str
            The advice, one clause of the driver's message.
        """
        if self.contact is not None:
            return ("this method pushes vertices out of the obstacles after each step, which feeds energy into "
                    "the model: use --method ipc (method='ipc'), which keeps contact inside the step and is stable "
                    "at any dt")
        if not self.implicit:
            return "use dt < dt_crit or an implicit method (--method newmark)"
        return "reduce dt or add damping"


class AssembledIntegrator(TimeIntegrator):
    """Base class of the methods on the assembled equations of motion: builds ``K``, ``M``, ``C`` on
    the free DOFs and steps a :class:`State` (subclasses implement :meth:`_advance`).

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
    solver : DynamicOptions or {"auto", "direct", "cg-amg"}, optional
        How the linear systems (effective matrices, consistent mass) are solved
        (:class:`~sc_fem.fem.options.DynamicOptions`, :class:`~sc_fem.fem.linsolve.SystemSolver`).
    """

    supports = frozenset({"loads", "contact", "impulses", "velocity", "rayleigh", "element"})

    @classmethod
    def contact_for(cls, model: CubeModel, points: ArrayLike, faces: ArrayLike, obstacles: Sequence, *,
                    W: sp.spmatrix | None = None, friction: float = 0.0, self_contact: bool = True) -> Contact | None:
        """The ``contact`` argument of a run: vertices projected out of the obstacles after each step.

        Parameters
        ----------
        model : CubeModel
        points : array_like, shape (n, 3)
            Source-mesh vertices at rest, model units.
        faces : array_like of int, shape (f, 3)
            Source-mesh triangles (used by :class:`~sc_fem.dynamics.ipc.IPC` only).
        obstacles : sequence of Ground / Sphere / Box
            Static obstacles, model units.
        W : scipy.sparse matrix, shape (n, m), optional
            Embedding of ``points`` (computed if omitted).
        friction, self_contact : float, bool
            Used by IPC only (contact inside the step).

        Returns
        -------
        Contact or None
            Vertex-obstacle :class:`~sc_fem.dynamics.contact.Contact`; None without obstacles.
        """
        return Contact(model, points, obstacles, W=W) if obstacles else None

    def __init__(self, model: CubeModel, dt: float, *, element: str = DEFAULT_ELEMENT,
                 fixed_nodes: ArrayLike | None = None, loads: LoadSet | None = None, contact: Contact | None = None,
                 rayleigh: tuple[float, float] = (0.0, 0.0), lumped: bool = False, u0: ArrayLike | None = None,
                 v0: ArrayLike | None = None, backend: str = "auto", solver: DynamicOptions | str | None = None) -> None:
        super().__init__(model, dt, fixed_nodes=fixed_nodes, loads=loads)
        opts = DynamicOptions.coerce(solver)
        self.solver_options = opts if backend == "auto" else replace(opts, backend=backend)
        self.element, self.backend = element, self.solver_options.backend      # one backend for every solve
        fn, t0 = self.fixed_nodes, _time.perf_counter()
        self.asm = Assembler(model, element, fixed_dofs=_fixed_dofs(fn))
        if self.asm.shape[0] == 0:
            raise InputError("every node is fixed: nothing moves")
        self.K = self.asm.stiffness()
        self.lumped = bool(lumped)
        self.M = self.asm.mass(lumped=self.lumped)
        # inverse of the lumped (diagonal) mass, 1/kg; None for the consistent mass
        self._minv = 1.0 / self.M.diagonal() if self.lumped else None
        self._dt_crit, self.setup_seconds = None, _time.perf_counter() - t0
        r = as_float_array(rayleigh, "rayleigh", (2,))
        if np.any(r < 0):
            raise InputError(f"rayleigh coefficients must be >= 0, got {r.tolist()}")
        self.rayleigh = (float(r[0]), float(r[1]))
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
        # the AMG's near-null space and finest aggregates: built at its first set-up, if any, and kept
        self._mass_solver, self._amg_data = None, cache(partial(lattice_amg_data, model, self.asm.free_dofs))
        self._a = self._initial_acceleration()

    # ------------------------------------------------------------------ helpers
    def _linear_solver(self, A: sp.spmatrix, lag: Lag | None = None) -> SystemSolver:
        """Solver of ``A x = b`` (``A`` SPD, free DOFs) by :attr:`solver_options`: direct (lagging by ``lag``)
        or CG + AMG (:func:`~sc_fem.fem.static.lattice_amg_data` built at its first set-up)."""
        solver = self.solver_options.solver_for(A)
        solver.amg_data, solver.lag = self._amg_data, lag
        return solver

    def damping(self, v: np.ndarray, K: sp.spmatrix | None = None) -> np.ndarray:
        """Damping force ``C v = a0 M v + a1 K v`` on the free DOFs.

        Parameters
        ----------
        v : ndarray, shape (n_free,)
            Velocity, m/s.
        K : scipy.sparse matrix, shape (n_free, n_free), optional
            Stiffness of the ``a1`` term, N/m (default :attr:`K`; a tangent for non-linear models).

        Returns
        -------
        ndarray, shape (n_free,)
            Damping force, N.
        """
        a0, a1 = self.rayleigh
        out = np.zeros_like(v)
        if a0:
            out += a0 * (self.M @ v)
        if a1:
            out += a1 * ((self.K if K is None else K) @ v)
        return out

    def internal_force(self, u: np.ndarray) -> np.ndarray:
        """Elastic force ``f_int(u)`` on the free DOFs (linear: ``K u``).

        Parameters
        ----------
        u : ndarray, shape (n_free,)
            Displacement, m.

        Returns
        -------
        ndarray, shape (n_free,)
            Elastic force, N.
        """
        return self.K @ u

    def elastic_energy(self, u: np.ndarray) -> float:
        """Strain energy of free-DOF displacements ``u`` (linear: ``1/2 u.Ku``).

        Parameters
        ----------
        u : ndarray, shape (n_free,)
            Displacement, m.

        Returns
        -------
        float
            Strain energy, J.
        """
        return 0.5 * float(u @ (self.K @ u))

    def external_force(self, t: float) -> np.ndarray:
        """Load vector on the free DOFs at time ``t``.

        Parameters
        ----------
        t : float
            Time, s.

        Returns
        -------
        ndarray, shape (n_free,)
            Loads, N.
        """
        return self.asm.restrict(self.loads.force(t))

    def solve_mass(self, r: np.ndarray) -> np.ndarray:
        """``M^-1 r`` on the free DOFs (consistent mass: :class:`~sc_fem.fem.linsolve.MassSolver`).

        Parameters
        ----------
        r : ndarray, shape (n_free,)
            Force, N.

        Returns
        -------
        ndarray, shape (n_free,)
            Acceleration, m/s^2.
        """
        if self._minv is not None:
            return self._minv * r
        if self._mass_solver is None:            # CG on the diagonal-scaled mass; a factorization if it fails
            self._mass_solver = MassSolver(self.M, lambda: factorize(self.M, self.backend))
        return self._mass_solver.solve(r)

    def _initial_acceleration(self) -> np.ndarray:
        r = self.external_force(0.0) - self.internal_force(self._u) - self.damping(self._v)
        return self.solve_mass(r)

    def set_velocity_from_impulse(self, impulse_nodes: ArrayLike) -> None:
        """Add ``M^-1 J`` to the velocity; the initial acceleration is recomputed (call before the
        first step).

        Parameters
        ----------
        impulse_nodes : array_like, shape (m, 3)
            Node impulses ``J``, N s (e.g. ``W^T`` of vertex impulses).
        """
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
        """Kinetic, elastic and gravity energy of the current state.

        Returns
        -------
        Energy
            By kind, J.
        """
        u, v = self._u, self._v
        return Energy(kinetic=0.5 * float(v @ (self.M @ v)), elastic=self.elastic_energy(u),
                      gravity=self.loads.gravity_potential(self.asm.expand(u)))

    def step(self) -> State:
        """Advance one step ``dt`` (contact, if any, projected after it).

        Returns
        -------
        State
            The new state (energy fields not filled: :func:`~sc_fem.dynamics.driver.simulate` does).
        """
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
        on this model (:func:`critical_time_step`); computed on first access (an eigenvalue solve)
        and kept."""
        if self._dt_crit is None:
            self._dt_crit = critical_time_step(self.K, self.M if self.lumped else self.asm.mass(lumped=True))
        return self._dt_crit
