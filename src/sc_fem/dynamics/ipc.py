r"""Contact inside the implicit step: the incremental potential with barriers (IPC).

The seed's workflow detects contact on the *source* geometry. Here the source mesh is the
collision mesh, a linear map of the lattice DOFs: its vertices move by ``W u`` (``W`` the
trilinear embedding). A time step of backward (implicit) Euler is the minimiser of the
incremental potential (Li et al. 2020, "Incremental Potential Contact")

.. math::

   E(x) = \tfrac{1}{2 h^2} \|x - x_n - h v_n\|_M^2 + \Psi(x) - f \cdot x
          + \tfrac{1}{2h} \|x - x_n\|_C^2 + \kappa B(V(x)) + h D\big((V(x) - V(x_n)) / h\big)

over the free node displacements ``x`` (m): inertia, elastic energy ``Psi`` (``1/2 x.Kx``),
loads, Rayleigh damping ``C``, the log barrier ``B`` of every vertex-triangle and edge-edge
pair of the collision mesh closer than ``dhat``, and the lagged smooth Coulomb friction ``D``
(coefficient ``friction``). The barrier, its derivatives, the friction potential and the
continuous collision detection (CCD) are the IPC Toolkit's (``ipctk``); gradients and Hessians
come back to the DOFs through ``Phi = W (x) I_3`` (``Phi^T g``, ``Phi^T H Phi``).

Newton's method with the Hessian's contact blocks projected to PSD, a line search that starts
at the CCD's collision-free step and halves until ``E`` decreases: every state is
intersection-free by construction and the step is stable at any ``dt``. When no pair is within
``dhat`` and there is no friction, ``E`` is the quadratic of linear implicit Euler: one
back-solve with a factorization kept for the run (the fast path), or for large models
(``solver``) a CG solve preconditioned by algebraic multigrid set up once. The Hessians with contact
are solved by one :class:`~sc_fem.fem.linsolve.SystemSolver` that lags (:data:`CONTACT_LAG`).

The collision meshes -- the source mesh, the static obstacles (:class:`~sc_fem.dynamics.contact.Ground`,
``Sphere``, ``Box``) and the lattice's outer surface for self-contact -- are built in :mod:`.collision`;
their barrier, friction and CCD in free DOFs are :class:`~sc_fem.dynamics.barrier.BarrierContact`'s.

Units: the collision mesh is in metres (``rest * scale``); ``dhat`` is given in model units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._validate import positive_scalar
from ..errors import InputError, InstabilityError
from ..fem.linsolve import Lag
from .barrier import BarrierContact
from .base import AssembledIntegrator
from .collision import ContactState, require_ipctk
from .state import Energy

MAX_HALVINGS = 3
"""A step whose Newton solve does not converge is cut in two, at most this many times nested."""

CONTACT_LAG = Lag(refactor=8, maxiter=40, rtol=1e-8)
"""The direct solves of the Hessians with contact: CG to a relative residual of 1e-8, preconditioned
with the latest factorization (first that of the step's ``S`` without contact, then that of an
earlier Newton iteration's Hessian); a solve past 8 CG iterations makes the next one factorize its
Hessian (and keep the factor as the preconditioner of the ones after it), one not converged in 40
factorizes at once."""


class _NotConverged(Exception):
    """A Newton solve of :class:`IPC` that did not converge (the step is then cut in two)."""


@dataclass
class _Step:
    """Counters of the Newton iterations of a run (``IPC.info``)."""

    newton: int = 0
    contact_steps: int = 0
    line_search_cuts: int = 0
    halvings: int = 0


class IPC(AssembledIntegrator):
    """Backward Euler as the minimisation of the incremental potential with barrier contact.

    Parameters
    ----------
    model, dt, element, fixed_nodes, loads, rayleigh, lumped, u0, v0, backend
        See :class:`~sc_fem.dynamics.base.AssembledIntegrator`.
    contact : BarrierContact, optional
        The collision mesh (none: linear backward Euler, one back-solve per step).
    tol : float
        Newton stops when the largest step of a vertex-free DOF is below ``tol`` times the
        model size (default 1e-5).
    max_newton : int
        Newton iterations per solve at most (default 100). A step whose solve does not converge
        is cut into two half steps, up to ``MAX_HALVINGS`` times nested (counted in
        ``info["halvings"]``); past that :class:`~sc_fem.errors.InstabilityError` says why.
    """

    name = "ipc"
    implicit = True
    supports = AssembledIntegrator.supports | {"friction", "solver"}
    convergence_hint = "use a smaller dt"

    @classmethod
    def contact_for(cls, model, points, faces, obstacles, *, W=None, friction: float = 0.0, self_contact: bool = True):
        """The collision meshes of a run (:class:`~sc_fem.dynamics.barrier.BarrierContact`), also
        without obstacles: bodies collide with each other and, with ``self_contact``, with themselves."""
        return BarrierContact(model, points, faces, obstacles, W=W, friction=friction, self_contact=self_contact)

    def __init__(self, model, dt, *, contact: BarrierContact | None = None, tol: float = 1e-5,
                 max_newton: int = 100, **kw) -> None:
        if contact is not None and not isinstance(contact, BarrierContact):
            raise InputError(f"contact must be a BarrierContact for method 'ipc', got {type(contact).__name__}")
        if contact is not None and contact.model.n_nodes != model.n_nodes:
            raise InputError(f"contact was built for a model with {contact.model.n_nodes} nodes, "
                             f"this one has {model.n_nodes}")
        self.barrier = contact
        self.tol = positive_scalar(tol, "tol")
        self.max_newton = int(max_newton)
        self.stats = _Step()
        self._kappa = None            # barrier stiffness in IPC's h^2-scaled units, and its maximum
        self._kappa_max = None
        self._last = None             # the ContactState of the last state _advance returned
        super().__init__(model, dt, **kw)
        a0, a1 = self.rayleigh
        self._C = None if not (a0 or a1) else (a0 * self.M + a1 * self.K).tocsr()
        self._levels: dict = {}       # step length -> (S, its SystemSolver)
        self._hsys = None             # the SystemSolver of the contact Hessians
        self._hsys_h = None           # the step length whose S last preconditioned it
        self._h = self.dt             # the length of the (sub)step being solved
        self._S, self._Sfac = self._level(self.dt)
        self._mass_avg = float(self.M.diagonal().mean()) if self.M.shape[0] else 1.0
        if contact is not None:
            contact.bind(self.asm.free_dofs)
            self._scale_x = contact.diag_m
        else:
            self._scale_x = float(np.linalg.norm(np.ptp(model.nodes_m, axis=0))) or 1.0

    # ------------------------------------------------------------------ energy of a state
    def _state_at(self, x: np.ndarray) -> ContactState:
        last = self._last
        return last if last is not None and last.x is x else self.barrier.state(x)

    def contact_energy(self, x: np.ndarray) -> float:
        """Barrier energy ``kappa B`` (J) at free-DOF displacements ``x``."""
        if self.barrier is None or self._kappa is None:
            return 0.0
        return float(self.barrier.barrier(self._state_at(x), self._kphys(), "e"))

    def energy(self):
        e = super().energy()
        return Energy(kinetic=e.kinetic, elastic=e.elastic, gravity=e.gravity, contact=self.contact_energy(self._u))

    @property
    def info(self) -> dict:
        s, c = self.stats, self.barrier
        sys_ = [lv[1] for lv in self._levels.values()] + ([self._hsys] if self._hsys is not None else [])
        return {"newton_iterations": s.newton, "contact_steps": s.contact_steps, "linear_solver": self._Sfac.kind,
                "factorizations": sum(x.stats["factorizations"] for x in sys_),
                "amg_setups": sum(x.stats["setups"] for x in sys_), "line_search_cuts": s.line_search_cuts,
                "cg_iterations": 0 if self._hsys is None else self._hsys.stats["iterations"],
                "halvings": s.halvings,
                "dhat": None if c is None else c.dhat, "friction": None if c is None else c.friction,
                "ground_shift": None if c is None else c.ground_shift,
                "self_contact": None if c is None else c.self_contact,
                "bodies": None if c is None else c.n_bodies}

    # ------------------------------------------------------------------ the potential
    def _level(self, h: float):
        """``S = (1/h^2 + a0/h) M + (1 + a1/h) K`` for a (sub)step ``h`` and its solver (kept;
        :meth:`~sc_fem.dynamics.base.AssembledIntegrator._linear_solver`: factorized, or CG + AMG)."""
        if h not in self._levels:
            a0, a1 = self.rayleigh
            S = ((1.0 / h**2 + a0 / h) * self.M + (1.0 + a1 / h) * self.K).tocsr()
            self._levels[h] = (S, self._linear_solver(S))
        return self._levels[h]

    def _kphys(self) -> float:
        """The physical barrier stiffness: IPC's (for the ``h^2``-scaled potential) over ``h^2``."""
        return self._kappa / self.dt**2

    def _smooth(self, x, u, ut, f) -> tuple[float, np.ndarray]:
        """Energy and gradient of the terms without contact (step length ``self._h``)."""
        dt = self._h
        dx = x - ut
        Mdx = self.M @ dx
        Kx = self.K @ x
        e = 0.5 / dt**2 * float(dx @ Mdx) + 0.5 * float(x @ Kx) - float(f @ x)
        g = Mdx / dt**2 + Kx - f
        if self._C is not None:
            Cd = self._C @ (x - u)
            e += 0.5 / dt * float((x - u) @ Cd)
            g = g + Cd / dt
        return e, g

    def _contact(self, st: ContactState, fric, st0: ContactState, need: str):
        """Barrier + friction at ``st``: energy, gradient or Hessian (``need``) in free DOFs."""
        c = self.barrier
        out = c.barrier(st, self._kphys(), need)
        if fric is not None:
            f = c.friction_terms(fric, st, st0, self._h, need)
            out = f if out is None else (out if f is None else out + f)
        return out

    def _update_kappa(self, x, u, ut, f, st: ContactState) -> None:
        """IPC's adaptive barrier stiffness: set from the gradients at the step's start, never lowered."""
        ipctk = require_ipctk()
        c = self.barrier
        _, gE = self._smooth(x, u, ut, f)
        gB = c.barrier(st, 1.0, "g") if st.n_pairs else 0 * x
        gB = gB if np.ndim(gB) else 0 * x
        B = ipctk.BarrierPotential(c.dhat_m, 1.0)       # alive through the call: .barrier is B's own, not a copy
        k, kmax = ipctk.initial_barrier_stiffness(c.diag_m, B.barrier, c.dhat_m, self._mass_avg, self.dt**2 * gE, gB)
        self._kappa = max(k, self._kappa or 0.0)
        self._kappa_max = max(kmax, self._kappa_max or 0.0)

    def _solve_contact(self, H, g: np.ndarray) -> np.ndarray:
        """``H^-1 g`` for ``H = S + (contact Hessian)`` by the contact Hessians' one
        :class:`~sc_fem.fem.linsolve.SystemSolver`, updated with every ``H``: direct, CG preconditioned
        with the latest factorization (:data:`CONTACT_LAG`; first ``S``'s, again whenever the step length
        changes); CG + AMG, the AMG hierarchy of an earlier Hessian, set up again on the current one when
        CG slows."""
        if self._hsys is None:
            self._hsys = self._linear_solver(H, CONTACT_LAG)
        else:
            self._hsys.update(H)
        if self._hsys_h != self._h:           # a new step length: its S's factorization preconditions
            self._hsys.precondition_with(self._level(self._h)[1])
            self._hsys_h = self._h
        return self._hsys.solve(g)

    # ------------------------------------------------------------------ one step
    def _advance(self, u, v, a, t0, t1):
        dt = self.dt
        if self.barrier is None:                        # linear backward Euler: one back-solve
            self._h = dt
            _, g = self._smooth(u, u, u + dt * v, self.external_force(t1))
            x = u - self._Sfac.solve(g)
            self.stats.newton += 1
        else:
            x = self._substeps(u, v, t0, t1, 0)[0]
        v1 = (x - u) / dt
        return x, v1, (v1 - v) / dt

    def _substeps(self, u, v, t0, t1, depth: int):
        """``(x, v)`` at ``t1`` from ``(u, v)`` at ``t0``: one Newton solve, or, when it does not
        converge, two half steps (at most ``MAX_HALVINGS`` times nested)."""
        try:
            x = self._newton(u, v, t1, t1 - t0)
        except _NotConverged as exc:
            if depth >= MAX_HALVINGS:
                m = self.model
                raise InstabilityError(
                    f"ipc: {exc} at step {self.n_steps + 1} (t = {t1:.6g} s), not even with the step cut to "
                    f"dt / {2 ** MAX_HALVINGS} = {(t1 - t0):.3g} s: raise max_newton (now {self.max_newton}), or "
                    f"check that the model is not far softer than meant for its size (E = "
                    f"{float(np.median(m.youngs)):.3g} Pa over {float(np.linalg.norm(np.ptp(m.nodes_m, axis=0))):.3g} "
                    f"m; a model in millimetres read as metres is 1000 times too large)") from None
            self.stats.halvings += 1
            tm = 0.5 * (t0 + t1)
            xm, vm = self._substeps(u, v, t0, tm, depth + 1)
            return self._substeps(xm, vm, tm, t1, depth + 1)
        return x, (x - u) / (t1 - t0)

    def _newton(self, u, v, t1, h):
        """Minimise the incremental potential of a step of length ``h`` from ``(u, v)``; returns ``x``.
        Raises ``_NotConverged``."""
        c = self.barrier
        self._h = h
        S, Sfac = self._level(h)
        f = self.external_force(t1)
        ut = u + h * v
        x = u.copy()
        st0 = self._state_at(u)
        st = ContactState(x=x, V=st0.V, col=st0.col)
        if self._kappa is None or st.n_pairs:
            self._update_kappa(x, u, ut, f, st)
        fric = c.lagged_friction(st0, self._kphys())    # contacts and normal forces of x_n
        tol_x = self.tol * self._scale_x
        contact_seen = False
        prev_d = c.min_distance_sq(st)
        for it in range(self.max_newton):
            self.stats.newton += 1
            e_s, g = self._smooth(x, u, ut, f)
            quadratic = not st.n_pairs and fric is None
            if quadratic:
                p = -Sfac.solve(g)
            else:
                contact_seen = True
                g = g + self._contact(st, fric, st0, "g")
                p = -self._solve_contact((S + self._contact(st, fric, st0, "h")).tocsr(), g)
            if float(np.abs(p).max(initial=0.0)) <= tol_x:
                break
            alpha = min(1.0, c.stepsize(st, x + p))
            e0 = e_s + (self._contact(st, fric, st0, "e") if not quadratic else 0.0)
            gp = float(g @ p)
            while True:
                xt = x + alpha * p
                stt = c.state(xt)
                et = self._smooth(xt, u, ut, f)[0]
                if stt.n_pairs or fric is not None:
                    et += self._contact(stt, fric, st0, "e")
                if et <= e0 + 1e-4 * alpha * gp + 1e-12 * abs(e0) or alpha < 1e-12:
                    break
                alpha *= 0.5
                self.stats.line_search_cuts += 1
            if alpha < 1e-12:
                raise _NotConverged("the line search stalled")
            x, st = xt, stt
            if quadratic and alpha == 1.0 and not st.n_pairs:
                break                                   # the exact minimiser of the quadratic, still free
            if st.n_pairs:
                d = c.min_distance_sq(st)
                if np.isfinite(prev_d):
                    self._kappa = require_ipctk().update_barrier_stiffness(prev_d, d, self._kappa_max, self._kappa,
                                                                    c.diag_m)
                prev_d = d
        else:
            raise _NotConverged(f"Newton did not converge in {self.max_newton} iterations")
        self.stats.contact_steps += int(contact_seen)
        self._last = st
        return x

    @property
    def max_contact_depth(self) -> float:
        """Barrier contact never lets a vertex through: always ``-inf`` (no penetration)."""
        return -np.inf

    @max_contact_depth.setter
    def max_contact_depth(self, value) -> None:       # the base class initialises it
        pass
