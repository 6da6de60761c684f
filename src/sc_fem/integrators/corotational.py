"""Corotational (warped-stiffness) linear elasticity on the cube lattice, integrated with Newmark.

Linear elasticity measures strain with the linearised ``sym(grad u)``, so a rigid rotation by a
large angle looks like a huge strain: a swinging rope or a tipping chair grows ("inflates")
instead of turning. The corotational model (Mueller et al. 2002/2004, Felippa 2000) removes each
cube's rotation before measuring the strain:

* per cube, the deformation gradient at the cube centre ``F = sum_a x_a (x) grad N_a`` (current
  corner positions ``x_a`` in metres) and its rotation ``R = polar(F)`` by SVD
  (``F = U S V^T``, ``R = U V^T`` with the sign fix ``det R = +1``), vectorized over cubes;
* elastic force ``f_e = R K_e (R^T x_e - X_e)`` (``X_e`` rest corners), zero for any rigid motion;
* warped stiffness ``K_e' = R K_e R^T`` (the rotation held fixed), assembled with
  :meth:`sc_fem.assemble.Assembler.stiffness` ``(element_matrices=...)`` -- the fast re-assembly
  that only refills the CSR ``data`` of the pattern built once;
* strain energy ``1/2 (R^T x_e - X_e) . K_e (R^T x_e - X_e)``.

Each Newmark step linearises at ``u_n`` (``R`` from ``u_n``), factorizes
``S = M + (1+alpha)(gamma dt C + beta dt^2 K')`` and iterates the residual with this frozen
tangent, the force always evaluated with the rotations of the current iterate (``iterations``
passes, default 3; the neglected ``dR/dx`` terms only slow the convergence).

Cost per step against linear Newmark (which re-uses one factorization: one back-solve and a few
sparse products per step): one batched 3x3 SVD and a rotation of every 24x24 element matrix
(``O(n_cubes)``), one re-assembly (``data`` refill) and one **sparse factorization**, plus
``iterations`` back-solves. The factorization dominates; ``benchmarks/stability.py`` prints the
measured ratio (about 10--30x the linear step on the benchmark models).
"""

from __future__ import annotations

import numpy as np

from ..elements import element_stiffness
from ..lattice import HEX_CORNERS
from ..material import lame
from .newmark import Newmark

_DN = (2.0 * HEX_CORNERS - 1.0) / 4.0        # grad N_a at the centre of the unit cube, (8, 3)


def polar_rotation(F: np.ndarray) -> np.ndarray:
    """Rotation factor of the polar decomposition ``F = R U`` for a batch, shape (n, 3, 3).

    ``det R = +1`` always (for ``det F <= 0`` the closest proper rotation is returned)."""
    U, _, Vt = np.linalg.svd(F)
    d = np.linalg.det(U) * np.linalg.det(Vt)
    U[:, :, 2] *= np.where(d < 0, -1.0, 1.0)[:, None]
    return U @ Vt


def cube_rotations(x_e: np.ndarray, h: float) -> np.ndarray:
    """Per-cube rotations from corner positions ``x_e`` (n, 8, 3) m of cubes of edge ``h`` m: (n, 3, 3)."""
    F = np.einsum("nai,aj->nij", x_e, _DN) / h
    return polar_rotation(F)


class Corotational(Newmark):
    """Newmark/HHT integration of the corotational cube lattice.

    Parameters
    ----------
    iterations : int
        Frozen-tangent iterations per step (default 3).
    **kw
        As :class:`~sc_fem.integrators.newmark.Newmark`.
    """

    name = "corotational"

    def __init__(self, model, dt, *, iterations: int = 3, **kw) -> None:
        self.iterations = max(1, int(iterations))
        lam, mu = lame(model.youngs, model.poisson)
        mats, inv = np.unique(np.stack([lam, mu], axis=1), axis=0, return_inverse=True)
        self._mat_inv = inv.ravel()
        self._groups = [np.flatnonzero(self._mat_inv == k) for k in range(len(mats))]
        self._mats = mats
        self._X = model.nodes_m[model.hexes]                    # rest corners (n, 8, 3), m
        self._cache_u = None
        super().__init__(model, dt, **kw)

    # ------------------------------------------------------------------ kinematics
    def _corners(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Current corners (n, 8, 3) m and rotations (n, 3, 3) for free-DOF ``u``."""
        x = self.model.nodes_m + self.asm.expand(u)
        xe = x[self.model.hexes]
        return xe, cube_rotations(xe, self.model.h)

    def _local(self, u):
        xe, R = self._corners(u)
        loc = np.einsum("nji,naj->nai", R, xe) - self._X          # R^T x_a - X_a, (n, 8, 3)
        return loc.reshape(-1, 24), R

    def _Kl(self, loc: np.ndarray) -> np.ndarray:
        if not hasattr(self, "_Ke"):          # during base-class __init__ (initial acceleration)
            lam, mu = self._mats[:, 0], self._mats[:, 1]
            self._Ke = element_stiffness(self.element, lam, mu, self.model.h)
        out = np.empty_like(loc)
        for k, idx in enumerate(self._groups):                  # loop over distinct materials
            out[idx] = loc[idx] @ self._Ke[k].T
        return out

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
        """Element matrices ``R K_e R^T`` (n, 24, 24), N/m, for per-cube rotations ``R`` (n, 3, 3)."""
        n = len(R)
        out = np.empty((n, 8, 3, 8, 3))
        for k, idx in enumerate(self._groups):                  # loop over distinct materials
            Ke = self._Ke[k].reshape(8, 3, 8, 3)
            Ri = R[idx]
            tmp = np.einsum("nik,akbl->naibl", Ri, Ke, optimize=True)
            out[idx] = np.einsum("naibl,njl->naibj", tmp, Ri, optimize=True)
        return out.reshape(n, 24, 24)

    def tangent(self, u: np.ndarray):
        if self._cache_u is not None and self._cache_u[0] is u:
            return self._cache_u[1]
        _, R = self._corners(u)
        Kt = self.asm.stiffness(element_matrices=self.warped_matrices(R))
        self._cache_u = (u, Kt)
        return Kt

    def effective_solver(self, u: np.ndarray):
        return self._factor(self.tangent(u))
