"""Explicit central differences (leapfrog / Verlet) with lumped mass, and its stability limit.

Step (``M`` diagonal, so no linear solve)::

    v_{n+1/2} = v_n + dt/2 a_n
    u_{n+1}   = u_n + dt v_{n+1/2}
    a_{n+1}   = M^-1 (f(t_{n+1}) - K u_{n+1} - C v_{n+1/2})
    v_{n+1}   = v_{n+1/2} + dt/2 a_{n+1}

which is Newmark with ``beta = 0``, ``gamma = 1/2`` (the damping force uses the half-step
velocity, which keeps the step explicit). Second-order accurate, conditionally stable: for the
undamped system the step must satisfy ``dt <= dt_crit = 2 / omega_max`` with ``omega_max^2`` the
largest eigenvalue of ``M^-1 K`` (:func:`critical_time_step`; a lattice of edge ``h`` has
``dt_crit ~ h / c`` with ``c`` the P-wave speed). Stiffness-proportional damping lowers the limit.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import SolverError
from .base import TimeIntegrator


def max_frequency(K, M_lumped, *, tol: float = 1e-8, seed: int = 0) -> float:
    """Largest circular frequency ``omega_max`` (rad/s) of ``K x = omega^2 M x`` with diagonal ``M``.

    Uses ARPACK (``eigsh``, largest algebraic eigenvalue of ``D^-1/2 K D^-1/2``), falling back
    to a power iteration if ARPACK does not converge.
    """
    from scipy.sparse.linalg import ArpackNoConvergence, eigsh

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
                lam_new = float(x @ y)
                x = y / np.linalg.norm(y)
                if abs(lam_new - lam) <= tol * abs(lam_new):
                    lam = lam_new
                    break
                lam = lam_new
    return float(np.sqrt(max(lam, 0.0)))


def critical_time_step(K, M_lumped) -> float:
    """``dt_crit = 2 / omega_max`` (s) of undamped central differences with lumped mass ``M_lumped``."""
    w = max_frequency(K, M_lumped)
    return float("inf") if w == 0 else 2.0 / w


class CentralDifference(TimeIntegrator):
    """Explicit central differences with lumped mass (see the module docstring).

    Parameters are those of :class:`~sc_fem.dynamics.base.TimeIntegrator` (``lumped`` is
    forced to True). :attr:`~sc_fem.dynamics.base.TimeIntegrator.dt_crit` is the stability
    limit (computed on first access).
    """

    name = "central"
    implicit = False

    def __init__(self, model, dt, **kw) -> None:
        kw["lumped"] = True
        super().__init__(model, dt, **kw)

    def _advance(self, u, v, a, t0, t1):
        dt = self.dt
        vh = v + 0.5 * dt * a
        u1 = u + dt * vh
        a1 = self._minv * (self.external_force(t1) - self.internal_force(u1) - self.damping(vh))
        return u1, vh + 0.5 * dt * a1, a1
