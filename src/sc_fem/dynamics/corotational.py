r"""Corotational (warped-stiffness) linear elasticity on the cube lattice, integrated with Newmark.

Linear elasticity measures strain with the linearised ``sym(grad u)``, so a rigid rotation by a
large angle looks like a huge strain: a swinging rope or a tipping chair grows ("inflates")
instead of turning. The corotational model (Mueller et al. 2002/2004, Felippa 2000) removes each
cube's rotation before measuring the strain:

* per cube, the deformation gradient at the cube centre ``F = sum_a x_a (x) grad N_a`` (current
  corner positions ``x_a`` in metres) and its rotation ``R = polar(F)`` (:func:`polar_rotation`:
  Newton's iteration, SVD fallback, ``det R = +1``), vectorized over cubes;
* elastic force ``f_e = R K_e (R^T x_e - X_e)`` (``X_e`` rest corners), zero for any rigid motion;
* warped stiffness ``K_e' = R K_e R^T`` (the rotation held fixed), assembled with
  :meth:`sc_fem.fem.assemble.Assembler.stiffness` ``(element_matrices=...)`` -- the fast re-assembly
  that only refills the CSR ``data`` of the pattern built once;
* strain energy ``1/2 (R^T x_e - X_e) . K_e (R^T x_e - X_e)``.

Each Newmark step linearises at ``u_n`` (``R`` from ``u_n``), forms
``S = M + (1+alpha)(gamma dt C + beta dt^2 K')`` and iterates the residual with this frozen
tangent, the force always evaluated with the rotations of the current iterate (``iterations``
passes, default 3; the neglected ``dR/dx`` terms only slow the convergence). ``S`` is solved by
conjugate gradients preconditioned with the factorization of an earlier step's ``S`` -- the
rotations change little between steps -- and refactorized only when CG needs more than
``max_cg`` iterations. No step loops over cubes or materials. Cost against linear Newmark and
how to reproduce it: ``docs/corotational.md``.
"""

from __future__ import annotations

import numpy as np

from ..fem.elements import DEFAULT_ELEMENT, cube_stiffness
from ..fem.linsolve import factorize
from ..errors import InputError
from ..lattice.cubes import HEX_CORNERS, CubeModel
from .newmark import Newmark

DN_CENTRE = (2.0 * HEX_CORNERS - 1.0) / 4.0   # grad N_a at the centre of the unit cube, (8, 3)
_P1, _P2 = np.array([1, 2, 0]), np.array([2, 0, 1])    # cyclic index shifts for cofactors


def centre_F(X: np.ndarray, h: float) -> np.ndarray:
    """Deformation gradient at the cube centre (= cube mean) ``F = sum_a x_a (x) grad N_a``.

    Parameters
    ----------
    X : ndarray, shape (n, 8, 3)
        Corner positions, metres, in :data:`~sc_fem.lattice.cubes.HEX_CORNERS` order.
    h : float
        Rest edge, metres.

    Returns
    -------
    ndarray, shape (n, 3, 3)
        ``F`` (dimensionless), ``F[n, j, k] = d x_j / d X_k``.
    """
    return np.matmul(X.transpose(0, 2, 1), DN_CENTRE) * (1.0 / h)


def cofactor(F: np.ndarray) -> np.ndarray:
    """Cofactor matrices ``det(F) F^-T`` of a batch (n, 3, 3) (also for singular ``F``)."""
    return (F[:, _P1[:, None], _P1] * F[:, _P2[:, None], _P2]
            - F[:, _P1[:, None], _P2] * F[:, _P2[:, None], _P1])


def polar_rotation(F: np.ndarray, iterations: int = 5) -> np.ndarray:
    """Rotation ``R`` of the polar decomposition ``F = R U`` of a batch, shape (n, 3, 3).

    Newton's iteration ``X <- (X + X^-T) / 2`` from ``X = F`` (quadratic convergence; 5
    iterations reach round-off for strains below ~30 %); matrices with ``det F <= 0`` or that
    did not converge fall back to the SVD ``F = U S V^T``, ``R = U diag(1, 1, det(U V^T)) V^T``
    (the closest proper rotation). ``det R = +1`` always."""
    X = F
    prev = F
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for _ in range(iterations):
            C = cofactor(X)
            d = np.einsum("nj,nj->n", X[:, 0], C[:, 0])
            prev, X = X, 0.5 * (X + C / d[:, None, None])
        bad = ~(np.einsum("nij,nij->n", X - prev, X - prev) < 1e-20)
        bad |= ~(np.linalg.det(F) > 0)
    if np.any(bad):
        Fb = np.where(np.isfinite(F[bad]), F[bad], 0.0)
        U, _, Vt = np.linalg.svd(Fb)
        s = np.sign(np.linalg.det(np.matmul(U, Vt)))
        U[:, :, 2] *= np.where(s == 0, 1.0, s)[:, None]
        X = X.copy()
        X[bad] = np.matmul(U, Vt)
    return X


def cube_rotations(x_e: np.ndarray, h: float) -> np.ndarray:
    """Per-cube rotations from corner positions ``x_e`` (n, 8, 3) m of cubes of edge ``h`` m: (n, 3, 3)."""
    return polar_rotation(centre_F(x_e, h))


class Corotational(Newmark):
    """Newmark/HHT integration of the corotational cube lattice.

    The unrotated element matrices ``K_e`` (N/m) of all cubes are computed once and kept,
    shape (n_cubes, 24, 24): ``576 * 8`` bytes per cube (190 MB for 41 000 cubes).

    Parameters
    ----------
    iterations : int
        Frozen-tangent iterations per step (default 3).
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

    def __init__(self, model, dt, *, iterations: int = 3, max_cg: int = 8, cg_rtol: float = 1e-10, **kw) -> None:
        if not isinstance(model, CubeModel):
            raise InputError(f"model must be a CubeModel, got {type(model).__name__}")
        self.iterations = max(1, int(iterations))
        self.max_cg = int(max_cg)
        if self.max_cg < 0:
            raise InputError(f"max_cg must be >= 0, got {max_cg!r}")
        self.cg_rtol = float(cg_rtol)
        if not 0.0 < self.cg_rtol < 1.0:
            raise InputError(f"cg_rtol must lie in (0, 1), got {cg_rtol!r}")
        self._pre, self._stale = None, False                    # factorization reused as preconditioner
        self.n_factorizations = 0
        self.cg_iterations = 0
        # per-cube element matrices, N/m, (n, 24, 24); needed by the base class's __init__
        # (initial acceleration), hence built before it
        self._Ke = cube_stiffness(model, kw.get("element", DEFAULT_ELEMENT))
        self._X = model.nodes_m[model.hexes]                    # rest corners (n, 8, 3), m
        self._cache_u = None                                    # (u, K'(u)): last tangent
        self._cache_R = None                                    # (u, x_e, R): last rotations
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
        """``sum_e R K_e (R^T x_e - X_e)`` on the free DOFs, N."""
        loc, R = self._local(u)
        fl = self._Kl(loc).reshape(-1, 8, 3)
        fe = np.einsum("nij,naj->nai", R, fl)                     # (n, 8, 3)
        m = self.model.n_nodes
        hx = self.model.hexes.ravel()
        f = np.stack([np.bincount(hx, weights=fe[..., c].ravel(), minlength=m) for c in range(3)], axis=1)
        return self.asm.restrict(f)

    def elastic_energy(self, u: np.ndarray) -> float:
        loc, _ = self._local(u)
        return 0.5 * float(np.einsum("ni,ni->", loc, self._Kl(loc)))

    def warped_matrices(self, R: np.ndarray) -> np.ndarray:
        """Element matrices ``R K_e R^T`` (n, 24, 24), N/m, for per-cube rotations ``R`` (n, 3, 3).

        ``R`` acts block-diagonally on the 8 corners: with ``K_e`` viewed as (8, 3, 8, 3),
        ``out[a, i, b, j] = R_ik K[a, k, b, l] R_jl`` -- two batched 3x3 products."""
        n = len(R)
        left = np.matmul(R[:, None], self._Ke.reshape(n, 8, 3, 24))          # R K, (n, 8, 3, 24)
        out = np.matmul(left.reshape(n, 24, 8, 3), np.swapaxes(R, 1, 2)[:, None])   # (R K) R^T
        return out.reshape(n, 24, 24)

    def tangent(self, u: np.ndarray):
        if self._cache_u is not None and self._cache_u[0] is u:
            return self._cache_u[1]
        _, R = self._corners(u)
        Kt = self.asm.stiffness(element_matrices=self.warped_matrices(R))
        self._cache_u = (u, Kt)
        return Kt

    def effective_solver(self, u: np.ndarray):
        """Solver of this step's ``S(u)``: conjugate gradients preconditioned by the factorization of
        an earlier step's ``S`` (the rotations change little from step to step), refactorized when
        CG needs more than ``max_cg`` iterations; ``max_cg=0`` factorizes every step."""
        S = self._effective(self.tangent(u))
        if self._pre is None or self._stale or self.max_cg == 0:
            self._pre, self._stale = factorize(S, self.backend), False
            self.n_factorizations += 1
            return self._pre
        return _LaggedFactor(S, self)


class _LaggedFactor:
    """``solve(b)``: ``S x = b`` by CG preconditioned with the owner's (older) factorization."""

    def __init__(self, S, owner: "Corotational") -> None:
        self.S, self.owner = S, owner
        self.exact = False                   # the owner's factor is of this S (refactorized mid-step)

    def solve(self, b: np.ndarray) -> np.ndarray:
        from scipy.sparse.linalg import LinearOperator, cg

        o = self.owner
        if self.exact:
            return o._pre.solve(b)
        pre = LinearOperator(self.S.shape, matvec=o._pre.solve, dtype=float)
        count = [0]

        def tick(_):
            count[0] += 1

        x, info = cg(self.S, b, rtol=o.cg_rtol, atol=0.0, maxiter=4 * max(o.max_cg, 1), M=pre, callback=tick)
        o.cg_iterations += count[0]
        if info != 0:                        # the old factor no longer preconditions well: refactorize now
            o._pre = factorize(self.S, o.backend)
            o.n_factorizations += 1
            self.exact = True
            return o._pre.solve(b)
        if count[0] > o.max_cg:
            o._stale = True                  # refactorize at the next step
        return x
