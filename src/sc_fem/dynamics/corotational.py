r"""Corotational (warped-stiffness) linear elasticity on the cube lattice, integrated with Newmark.

Linear elasticity measures strain with the linearised ``sym(grad u)``, so a rigid rotation by a
large angle looks like a huge strain: a swinging rope or a tipping chair grows ("inflates")
instead of turning. The corotational model (Mueller et al. 2002/2004, Felippa 2000) removes each
cube's rotation before measuring the strain:

* per cube, the deformation gradient at the cube centre ``F = sum_a x_a (x) grad N_a`` (current
  corner positions ``x_a`` in metres) and its rotation ``R = polar(F)``
  (:func:`~sc_fem.dynamics.kinematics.polar_rotation`:
  Newton's iteration, SVD fallback, ``det R = +1``), vectorized over cubes;
* elastic force ``f_e = R K_e (R^T x_e - X_e)`` (``X_e`` rest corners), zero for any rigid motion;
* warped stiffness ``K_e' = R K_e R^T`` (the rotation held fixed), assembled with
  :meth:`sc_fem.fem.assemble.Assembler.stiffness` ``(element_matrices=...)`` -- the fast re-assembly
  that only refills the CSR ``data`` of the pattern built once;
* strain energy ``1/2 (R^T x_e - X_e) . K_e (R^T x_e - X_e)``.

Each Newmark step forms ``S = M + (1+alpha)(gamma dt C + beta dt^2 K')`` with the warped
stiffness of ``u_n`` and iterates the non-linear residual with this frozen tangent, the force
always evaluated with the rotations of the current iterate (``iterations`` passes, default 3).
Where the passes start, and what happens when they do not converge (:meth:`Corotational._advance`):

* **start**: the first iterate is ``u_n + dt v_n + dt^2 (a_{n-1} + a_n) / 4`` (second order for
  smooth motion). It is *not* the Newmark predictor ``u_n + dt v_n + dt^2/2 a_n``: average
  acceleration keeps, in modes with ``omega dt >> 1``, an acceleration that flips sign every step
  (``a_{n+1} ~ -a_n``), harmless to linear Newmark (whose one solve is exact from anywhere) but
  carried whole by that predictor. On the built-in chair (``stiffness="moments"``) gravity is
  lumped 1/8 per corner while the consistent mass follows the filled region, so nodes that only
  slivers reach start at ``|a_0| = M^-1 f_g`` up to 12,238 m/s^2 (median 64; 12.8 with
  ``"fraction"``); the predictor put them 6.1 mm = 0.23 h off at ``dt = 1e-3`` s, where the
  frozen tangent of ``u_n`` no longer contracts (residual 1.1e5, 7.7e3, 2.2e5, 3.7e8 N) and
  step 1 ended at 9.8e8 J. The first step, and any state set from outside (contact, impulses),
  starts instead with one pass **linearised at** ``u_n`` (``f(u) ~ f(u_n) + K'(u_n)(u - u_n)``:
  linear Newmark with the warped stiffness, independent of ``a_n``).
* **convergence check**, in the mass norm ``|x|_M = sqrt(x.Mx)`` (the max-norm is ruled by
  light nodes ringing at 1e4-1e6 m/s^2 and hides the rest): a pass whose correction exceeds
  :data:`CONTRACTION` of the previous one has stalled, and so have passes whose estimated
  remaining error ``theta/(1-theta)|da|_M`` is above :data:`ACCEPT` ``|a|_M`` once spent. A
  stalled extrapolated start restarts from the linearised pass (``n_relinearised``); a stalled
  linearised one continues with **Newton's method**, the warped stiffness re-assembled at every
  iterate (``n_newton``, :data:`HARD_PASSES` at most) -- what large rotations per step of a
  slender part need (its stiffness anisotropy turns a rotated tangent into a divergent one).

``S`` is solved by conjugate gradients preconditioned with the factorization of an earlier step's
``S`` -- the rotations change little between steps -- and refactorized only when CG needs more
than ``max_cg`` iterations; with CG + AMG (``solver``, :class:`~sc_fem.fem.options.DynamicOptions`)
by CG preconditioned with the AMG hierarchy of an earlier step's ``S``, set up again when CG slows: one
:class:`~sc_fem.fem.linsolve.SystemSolver` for the run, updated every step. No step loops over cubes or materials. Cost against linear Newmark and
how to reproduce it: ``docs/corotational.md``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from ..fem.elements import DEFAULT_ELEMENT, cube_stiffness
from ..fem.linsolve import Lag, SystemSolver
from ..errors import InputError
from ..lattice.cubes import CubeModel
from .kinematics import cube_rotations
from .newmark import Newmark

CONTRACTION = 0.5
"""A frozen-tangent pass whose correction (mass norm) exceeds this fraction of the previous pass's
has stalled (:meth:`Corotational._advance`)."""

ACCEPT = 1e-3
"""Frozen-tangent passes, once spent, are accepted when their estimated remaining error
``theta / (1 - theta) |da|_M`` (``theta`` the last pass's contraction) is below this times ``|a|_M``."""

STALL_FLOOR = 1e-8
"""Corrections below this times ``|a|_M`` are at round-off level: never judged as stalled."""

HARD_PASSES = 12
"""Newton passes (the warped stiffness re-assembled at every iterate) allowed to a step whose
frozen-tangent passes stalled from the linearised start."""

NEWTON_RTOL = 1e-8
"""Newton's passes stop once a correction is below this times ``|a|_M``."""

_EXTRAPOLATED, _LINEARISED, _NEWTON = 0, 1, 2          # how a step's iteration started / continues


class Corotational(Newmark):
    """Newmark/HHT integration of the corotational cube lattice.

    The unrotated element matrices ``K_e`` (N/m) of all cubes are computed once and kept,
    shape (n_cubes, 24, 24): ``576 * 8`` bytes per cube (190 MB for 41 000 cubes).

    Parameters
    ----------
    model : CubeModel
    dt : float
        Time step, s.
    iterations : int
        Frozen-tangent passes per step (default 3); the linearised pass that starts the first step
        (or a state set from outside) is one of them, and a step that stalls gets more (see the
        module docstring). ``n_relinearised`` and ``n_newton`` count the steps that fell back.
    max_cg : int
        The factorization of an earlier step's effective matrix preconditions conjugate gradients
        on this step's; when a solve needs more than ``max_cg`` iterations the next step
        refactorizes (``0``: factorize every step). ``n_factorizations`` and ``cg_iterations``
        count what was done.
    cg_rtol : float
        Relative residual at which CG stops.
    **kw
        As :class:`~sc_fem.dynamics.newmark.Newmark`.
    """

    name = "corotational"

    def __init__(self, model: CubeModel, dt: float, *, iterations: int = 3, max_cg: int = 8, cg_rtol: float = 1e-10,
                 **kw: Any) -> None:
        if not isinstance(model, CubeModel):
            raise InputError(f"model must be a CubeModel, got {type(model).__name__}")
        self.iterations = max(1, int(iterations))
        self.max_cg = int(max_cg)
        if self.max_cg < 0:
            raise InputError(f"max_cg must be >= 0, got {max_cg!r}")
        self.cg_rtol = float(cg_rtol)
        if not 0.0 < self.cg_rtol < 1.0:
            raise InputError(f"cg_rtol must lie in (0, 1), got {cg_rtol!r}")
        self.n_relinearised = 0                                 # steps restarted from the linearised pass
        self.n_newton = 0                                       # steps finished by Newton's method
        # per-cube element matrices, N/m, (n, 24, 24); needed by the base class's __init__
        # (initial acceleration), hence built before it
        self._Ke = cube_stiffness(model, kw.get("element", DEFAULT_ELEMENT))
        self._X = model.nodes_m[model.hexes]                    # rest corners (n, 8, 3), m
        self._cache_u = None                                    # (u, K'(u)): last tangent
        self._cache_R = None                                    # (u, x_e, R): last rotations
        self._last_a = None                                     # (a_n, a_{n+1}) of the last step
        super().__init__(model, dt, **kw)

    # ------------------------------------------------------------------ kinematics
    def _corners(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Current corners (n, 8, 3) m and rotations (n, 3, 3) for free-DOF ``u``.

        The result for the last ``u`` (the same array object) is kept: a step's tangent, the
        HHT force at ``u_n`` and the energy of the new state share one polar decomposition.
        The integrator never modifies a state array in place."""
        c = self._cache_R
        if c is not None and c[0] is u:
            return c[1], c[2]
        x = self.model.nodes_m + self.asm.expand(u)
        xe = x[self.model.hexes]
        R = cube_rotations(xe, self.model.h)
        self._cache_R = (u, xe, R)
        return xe, R

    def _local(self, u):
        xe, R = self._corners(u)
        loc = np.einsum("nji,naj->nai", R, xe) - self._X          # R^T x_a - X_a, (n, 8, 3)
        return loc.reshape(-1, 24), R

    def _Kl(self, loc: np.ndarray) -> np.ndarray:
        """``K_e loc_e`` per cube: (n, 24) -> (n, 24)."""
        return np.einsum("nij,nj->ni", self._Ke, loc)

    def internal_force(self, u: np.ndarray) -> np.ndarray:
        """Corotational elastic force ``sum_e R K_e (R^T x_e - X_e)`` on the free DOFs.

        Parameters
        ----------
        u : ndarray, shape (n_free,)
            Displacement, m.

        Returns
        -------
        ndarray, shape (n_free,)
            Elastic force, N.
        """
        loc, R = self._local(u)
        fl = self._Kl(loc).reshape(-1, 8, 3)
        fe = np.einsum("nij,naj->nai", R, fl)                     # (n, 8, 3)
        m = self.model.n_nodes
        hx = self.model.hexes.ravel()
        f = np.stack([np.bincount(hx, weights=fe[..., c].ravel(), minlength=m) for c in range(3)], axis=1)
        return self.asm.restrict(f)

    def elastic_energy(self, u: np.ndarray) -> float:
        """Strain energy ``sum_e 1/2 (R^T x_e - X_e) . K_e (R^T x_e - X_e)`` (zero for rigid motion).

        Parameters
        ----------
        u : ndarray, shape (n_free,)
            Displacement, m.

        Returns
        -------
        float
            Strain energy, J.
        """
        loc, _ = self._local(u)
        return 0.5 * float(np.einsum("ni,ni->", loc, self._Kl(loc)))

    def warped_matrices(self, R: np.ndarray) -> np.ndarray:
        """Warped element matrices ``R K_e R^T`` of all cubes.

        ``R`` acts block-diagonally on the 8 corners: with ``K_e`` viewed as (8, 3, 8, 3),
        ``out[a, i, b, j] = R_ik K[a, k, b, l] R_jl`` -- two batched 3x3 products.

        Parameters
        ----------
        R : ndarray, shape (n_cubes, 3, 3)
            Rotation of each cube.

        Returns
        -------
        ndarray, shape (n_cubes, 24, 24)
            Element matrices, N/m.
        """
        n = len(R)
        left = np.matmul(R[:, None], self._Ke.reshape(n, 8, 3, 24))          # R K, (n, 8, 3, 24)
        out = np.matmul(left.reshape(n, 24, 8, 3), np.swapaxes(R, 1, 2)[:, None])   # (R K) R^T
        return out.reshape(n, 24, 24)

    def tangent(self, u: np.ndarray) -> sp.spmatrix:
        """Warped stiffness ``K'(u) = sum_e R K_e R^T`` (the rotations of ``u`` held fixed); the last
        one is kept.

        Parameters
        ----------
        u : ndarray, shape (n_free,)
            Displacement, m.

        Returns
        -------
        scipy.sparse matrix, shape (n_free, n_free)
            Tangent stiffness, N/m.
        """
        if self._cache_u is not None and self._cache_u[0] is u:
            return self._cache_u[1]
        _, R = self._corners(u)
        Kt = self.asm.stiffness(element_matrices=self.warped_matrices(R))
        self._cache_u = (u, Kt)
        return Kt

    @property
    def n_factorizations(self) -> int:
        """Factorizations of the effective matrix so far."""
        return 0 if self._S is None else self._S.stats["factorizations"]

    @property
    def cg_iterations(self) -> int:
        """CG iterations of the effective matrix's solves so far (lagged direct, or CG + AMG)."""
        return 0 if self._S is None else self._S.stats["iterations"]

    def effective_solver(self, u: np.ndarray) -> SystemSolver:
        """Solver of this step's ``S(u)``: one :class:`~sc_fem.fem.linsolve.SystemSolver` for the run, updated
        with every ``S`` and lagging. Direct (``solver_options``, below the automatic choice's threshold):
        conjugate gradients preconditioned by the factorization of an earlier step's ``S`` (the rotations
        change little from step to step), refactorized when CG needs more than ``max_cg`` iterations
        (:class:`~sc_fem.fem.linsolve.Lag`; ``max_cg=0`` factorizes every step). CG + AMG: the AMG hierarchy
        of an earlier step's ``S`` preconditions this one's, set up again when CG slows.

        Parameters
        ----------
        u : ndarray, shape (n_free,)
            Displacement whose warped stiffness ``S`` uses, m.

        Returns
        -------
        SystemSolver
            ``solve(r)``: ``S^-1 r``, residual force (N) to acceleration (m/s^2).
        """
        S = self._effective(self.tangent(u))
        if self._S is None:
            lag = Lag(refactor=self.max_cg, maxiter=4 * self.max_cg, rtol=self.cg_rtol) if self.max_cg else None
            self._S = self._linear_solver(S, lag)
        else:
            self._S.update(S)
        return self._S

    # ------------------------------------------------------------------ step
    def _advance(self, u, v, a, t0, t1):
        """One HHT/Newmark step of the corotational model (see the module docstring).

        Parameters
        ----------
        u, v, a : ndarray, shape (n_free,)
            State at ``t0`` on the free DOFs: m, m/s, m/s^2.
        t0, t1 : float
            Start and end of the step, s.

        Returns
        -------
        tuple of ndarray
            ``(u, v, a)`` at ``t1``, each shape (n_free,).
        """
        dt, b, g, al = self.dt, self.beta, self.gamma, self.alpha
        c = b * dt * dt
        M = self.M
        ut = u + dt * v + dt * dt * (0.5 - b) * a
        vt = v + dt * (1.0 - g) * a
        solver = self.effective_solver(u)
        Kt = self.tangent(u)
        F = (1.0 + al) * self.external_force(t1)
        fu = self.internal_force(u) if al else None
        if al:
            F += -al * self.external_force(t0) + al * (self.damping(v, Kt) + fu)

        def linearised():
            # the step with f(u) ~ f(u_n) + K'(u_n) (u - u_n): linear Newmark with the warped stiffness at
            # u_n, the same whatever a_n holds
            f0 = self.internal_force(u) if fu is None else fu
            r0 = F - M @ a - (1.0 + al) * (self.damping(vt + g * dt * a, Kt) + f0 + Kt @ (dt * v + 0.5 * dt * dt * a))
            return a + solver.solve(r0)

        last = self._last_a
        if last is not None and last[1] is a:
            # a_n came from the previous step: first iterate u_n + dt v_n + dt^2 (a_{n-1} + a_n) / 4 --
            # second order for smooth motion, and free of the acceleration that flips sign every step in
            # modes with omega dt >> 1 (the Newmark predictor u_n + dt v_n + dt^2/2 a_n carries it whole)
            a1, k, stage = ((last[0] + a) / 4.0 - (0.5 - b) * a) / b, 0, _EXTRAPOLATED
        else:                                            # first step, or a state set from outside
            a1, k, stage = linearised(), 1, _LINEARISED
        Ma = M @ a1
        scale = max(_mnorm(a1, Ma), 1e-300)              # the corrections are judged in the mass norm
        budget, prev, theta, size = self.iterations, None, None, 0.0
        while True:
            if k < budget:                               # a pass on the non-linear residual
                u1, v1 = ut + c * a1, vt + g * dt * a1
                fi = self.internal_force(u1)
                if stage == _NEWTON:                     # the tangent of this iterate
                    solver, Kt = self.effective_solver(u1), self.tangent(u1)
                r = F - Ma - (1.0 + al) * (self.damping(v1, Kt) + fi)
                da = solver.solve(r)
                Mda = M @ da
                size = _mnorm(da, Mda)
                theta = None if prev is None else size / prev          # this pass's contraction
                if stage == _NEWTON or theta is None or theta <= CONTRACTION or size <= STALL_FLOOR * scale:
                    a1, Ma, k = a1 + da, Ma + Mda, k + 1
                    scale = max(scale, _mnorm(a1, Ma))
                    if size <= (NEWTON_RTOL if stage == _NEWTON else 1e-10) * scale:
                        break
                    prev = size
                    continue
                # the frozen-tangent passes stopped contracting: escalate (below), this correction dropped
            elif stage == _NEWTON or theta is None or theta / (1.0 - theta) * size <= ACCEPT * scale:
                break                                    # passes spent and converged enough (or nothing to judge)
            # the frozen-tangent passes do not reach the solution: they stalled, or their estimated
            # remaining error theta / (1 - theta) |da|_M is above ACCEPT |a|_M once their passes are spent
            if stage == _EXTRAPOLATED:
                # the extrapolated start lies outside their reach: restart from the linearised step
                self.n_relinearised += 1
                a1 = linearised()
                Ma, stage, budget, prev, theta = M @ a1, _LINEARISED, k + self.iterations, None, None
                scale = max(scale, _mnorm(a1, Ma))
                k += 1
            else:
                # the tangent of u_n is too far from the iterate's: Newton's method from here on, the
                # warped stiffness re-assembled at every iterate, HARD_PASSES passes at most
                self.n_newton += 1
                stage, budget, prev, theta = _NEWTON, k + HARD_PASSES, None, None
        self._last_a = (a, a1)
        return ut + c * a1, vt + g * dt * a1, a1


def _mnorm(x: np.ndarray, Mx: np.ndarray) -> float:
    """Mass norm ``sqrt(x . M x)`` of a free-DOF field ``x`` given ``M x``."""
    return float(np.sqrt(max(float(x @ Mx), 0.0)))
