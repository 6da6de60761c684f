"""Newmark-beta time integration (with the HHT-alpha variant) of the cube lattice.

Unknowns on the free DOFs: displacement ``u`` (m), velocity ``v`` (m/s), acceleration ``a``
(m/s^2). With the predictors ``u~ = u_n + dt v_n + dt^2 (1/2 - beta) a_n`` and
``v~ = v_n + dt (1 - gamma) a_n``, the new state is ``u_{n+1} = u~ + beta dt^2 a_{n+1}``,
``v_{n+1} = v~ + gamma dt a_{n+1}``, where ``a_{n+1}`` solves the HHT-alpha balance
(Hilber, Hughes & Taylor 1977; ``alpha = 0`` is plain Newmark)

    M a_{n+1} + (1 + alpha) [C v_{n+1} + f_int(u_{n+1})] - alpha [C v_n + f_int(u_n)]
        = (1 + alpha) f(t_{n+1}) - alpha f(t_n).

It is solved in acceleration form with the effective matrix
``S = M + (1 + alpha) (gamma dt C + beta dt^2 K)``. For linear elasticity (``f_int = K u``) ``S``
is set up **once** and each step costs one solve plus a few sparse products. The residual form
``a += S^-1 r`` is used, so subclasses with a non-linear ``f_int`` (the corotational model)
iterate it with a frozen tangent.

Linear solver (``solver=``, :class:`~sc_fem.fem.options.DynamicOptions`): a sparse Cholesky
factorization and one back-solve per step, or conjugate gradients preconditioned by the lattice's
algebraic multigrid (:class:`~sc_fem.fem.linsolve.SystemSolver`), set up once (``"auto"``: CG +
AMG from :data:`~sc_fem.fem.options.DYNAMIC_CG_MIN_DOFS` free DOFs on). CG solves for the
correction ``da`` from 0, i.e. warm-started from the previous step's acceleration ``a_n``, so its
tolerance is relative to a step's change of acceleration, not to the acceleration. (Starting it
from the previous step's ``da`` as well took more iterations: 1,974 against 1,800 over 200 steps of
a 5,900-DOF cantilever under gravity.)

Defaults: average acceleration (``beta = 1/4``, ``gamma = 1/2``): unconditionally stable, no
numerical damping, exact conservation of ``1/2 v.Mv + 1/2 u.Ku - f.u`` for a constant load, but a
period elongation (phase error) that grows like ``(omega dt)^2 / 12``. ``gamma > 1/2`` damps the
high frequencies (first-order accurate); HHT with ``alpha`` in ``[-1/3, 0]`` and
``beta = (1 - alpha)^2 / 4``, ``gamma = 1/2 - alpha`` damps them while staying second order.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from ..errors import InputError
from ..fem.linsolve import SystemSolver
from ..lattice.cubes import CubeModel
from .base import AssembledIntegrator


@dataclass(frozen=True)
class NewmarkOptions:
    """Options of the Newmark methods (``"newmark"``, ``"corotational"``): ``beta``, ``gamma`` (None:
    the scheme's default) and the HHT ``alpha`` in [-1/3, 0]."""

    beta: float | None = None
    gamma: float | None = None
    alpha: float = 0.0


class Newmark(AssembledIntegrator):
    """Newmark-beta / HHT-alpha integrator (see the module docstring).

    Parameters
    ----------
    model : CubeModel
    dt : float
        Time step, s.
    beta, gamma : float, optional
        Newmark parameters; default 1/4, 1/2 (or the HHT values when ``alpha`` is set).
    alpha : float
        HHT parameter in ``[-1/3, 0]`` (0: plain Newmark).
    **kw
        ``element``, ``fixed_nodes``, ``loads``, ``contact``, ``rayleigh``, ``lumped``, ``u0``, ``v0``,
        ``backend``, ``solver`` (``"auto"`` | ``"direct"`` | ``"cg-amg"`` or a
        :class:`~sc_fem.fem.options.DynamicOptions`): see :class:`~sc_fem.dynamics.base.AssembledIntegrator`.
    """

    name = "newmark"
    implicit = True
    supports = AssembledIntegrator.supports | {"newmark", "solver"}
    iterations = 1

    def __init__(self, model: CubeModel, dt: float, *, beta: float | None = NewmarkOptions.beta,
                 gamma: float | None = NewmarkOptions.gamma, alpha: float = NewmarkOptions.alpha, **kw: Any) -> None:
        alpha = float(alpha)
        if not -1.0 / 3.0 - 1e-12 <= alpha <= 0.0:
            raise InputError(f"HHT alpha must lie in [-1/3, 0], got {alpha!r}")
        self.alpha = alpha
        self.beta = (1.0 - alpha) ** 2 / 4.0 if beta is None else float(beta)
        self.gamma = 0.5 - alpha if gamma is None else float(gamma)
        if self.gamma < 0.5:
            raise InputError(f"gamma must be >= 1/2 (gamma < 1/2 adds negative damping), got {self.gamma!r}")
        if self.beta <= 0:
            raise InputError(f"beta must be > 0 for the implicit Newmark scheme, got {self.beta!r} "
                             "(beta = 0 is explicit: use method='central')")
        self._S = None
        super().__init__(model, dt, **kw)

    # ------------------------------------------------------------------ hooks for non-linear models
    def tangent(self, u: np.ndarray) -> sp.spmatrix:
        """Tangent stiffness at ``u`` (linear: ``K``).

        Parameters
        ----------
        u : ndarray, shape (n_free,)
            Displacement, m.

        Returns
        -------
        scipy.sparse matrix, shape (n_free, n_free)
            Tangent stiffness, N/m.
        """
        return self.K

    def _effective(self, Kt):
        """The effective matrix ``S`` of a step with tangent ``Kt`` (CSR)."""
        a0, a1 = self.rayleigh
        al, g, b, dt = self.alpha, self.gamma, self.beta, self.dt
        S = (1.0 + (1.0 + al) * g * dt * a0) * self.M + (1.0 + al) * (g * dt * a1 + b * dt * dt) * Kt
        return S.tocsr()

    def _factor(self, Kt) -> SystemSolver:
        return self._linear_solver(self._effective(Kt))

    @property
    def info(self) -> dict:
        """The run's linear solves: ``linear_solver`` (``"direct"`` / ``"cg-amg"``), why, and the
        counts of the effective matrix's solver (:attr:`~sc_fem.fem.linsolve.SystemSolver.stats`)."""
        s = self._S
        if s is None:
            return {}
        st = s.stats
        return {"linear_solver": s.kind, "solver_reason": s.reason, "cg_iterations": st["iterations"],
                "linear_solves": st["solves"], "amg_setups": st["setups"], "factorizations": st["factorizations"],
                "solver_setup_seconds": st["setup_seconds"]}

    def effective_solver(self, u: np.ndarray) -> SystemSolver:
        """Solver of the effective matrix ``S`` (linear: set up once and kept).

        Parameters
        ----------
        u : ndarray, shape (n_free,)
            Displacement at the start of the step, m (unused by the linear model).

        Returns
        -------
        SystemSolver
            ``solve(r, x0)``: ``S^-1 r``, residual force (N) to acceleration (m/s^2).
        """
        if self._S is None:
            self._S = self._factor(self.K)
        return self._S

    # ------------------------------------------------------------------ step
    def _advance(self, u, v, a, t0, t1):
        dt, b, g, al = self.dt, self.beta, self.gamma, self.alpha
        ut = u + dt * v + dt * dt * (0.5 - b) * a
        vt = v + dt * (1.0 - g) * a
        solver = self.effective_solver(u)
        Kt = self.tangent(u)
        F = (1.0 + al) * self.external_force(t1)
        if al:
            F += -al * self.external_force(t0) + al * (self.damping(v, Kt) + self.internal_force(u))
        a1 = a.copy()
        scale = None
        for it in range(self.iterations):                   # loop over (frozen-tangent) iterations
            u1 = ut + b * dt * dt * a1
            v1 = vt + g * dt * a1
            r = F - self.M @ a1 - (1.0 + al) * (self.damping(v1, Kt) + self.internal_force(u1))
            da = solver.solve(r)              # from da = 0, i.e. from a_n (see the module docstring)
            a1 += da
            scale = max(float(np.abs(a1).max()), 1e-300) if scale is None else scale
            if it and float(np.abs(da).max()) <= 1e-10 * scale:
                break
        return ut + b * dt * dt * a1, vt + g * dt * a1, a1
