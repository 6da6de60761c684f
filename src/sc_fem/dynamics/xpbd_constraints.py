"""The constraints of an XPBD lattice (:class:`ConstraintSet`): their compliances, Lagrange multipliers
and projection, for :class:`~sc_fem.dynamics.xpbd.XPBDSolver`.

Three families: ``"neohookean"`` (the stable Neo-Hookean pair per cube, linearising to the lattice's
own Lame parameters), ``"corotational"`` (an ARAP block and the volume ``det F - 1`` per cube) and
``"distance"`` (the 28 corner pairs of every cube as springs: a central-force lattice). The cubes
(or pairs) are split into groups that share no node -- the 8 cube colours -- so one group is
projected at once: Gauss-Seidel over the groups, or all at once under-relaxed (Jacobi). The
batched kernels are in :mod:`.xpbd_kernels`, the compiled Neo-Hookean sweep in :mod:`.xpbd_jit`.

Units: positions in metres; compliances are inverse stiffnesses, scaled by ``1 / ds^2`` per substep ``ds``.
"""

from __future__ import annotations

import numpy as np

from ..lattice.cubes import CubeModel
from .kinematics import DN_CENTRE, centre_F, cube_rotations, polar_rotation
from .xpbd_kernels import (L_REF, MATCHING_KIND, MATCHINGS, S_REF, _scatter_add, _volume_terms, corotational_terms,
                           cube_colors, neohookean_terms)
from .xpbd_jit import nh_sweep

CONSTRAINTS = ("corotational", "neohookean", "distance")
"""The constraint families :class:`ConstraintSet` knows."""


class ConstraintSet:
    """The constraints of one family over a lattice, their multipliers and their projection.

    Parameters
    ----------
    model : CubeModel
        The lattice (Lame parameters per cube from ``model.lame()``).
    kind : {"neohookean", "corotational", "distance"}
        Constraint family (see the module docstring).
    w : ndarray, shape (m,)
        Inverse node masses, 1/kg (0 on fixed nodes).
    rest : ndarray, shape (m, 3)
        Rest node positions, metres.
    relaxation : float
        Jacobi relaxation factor ``omega`` (per-constraint step scaled by ``omega / valence``).
    """

    def __init__(self, model: CubeModel, kind: str, w: np.ndarray, rest: np.ndarray, *,
                 relaxation: float = 1.0) -> None:
        self.model, self.kind, self.w, self.rest = model, kind, w, rest
        self.relaxation = relaxation
        self.h = model.h
        self._build()

    # ------------------------------------------------------------------ setup
    def _build(self) -> None:
        md = self.model
        V = self.h ** 3
        lam, mu = md.lame()
        colors = cube_colors(md)
        self._hexes64 = np.ascontiguousarray(md.hexes, dtype=np.int64)
        if self.kind == "neohookean":
            lam_nh = lam + mu
            self._gamma = 1.0 + mu / lam_nh
            self._alphaD = 1.0 / (mu * V)
            self._alphaH = 1.0 / (lam_nh * V)
        if self.kind == "corotational":
            self._alphaD = 1.0 / (2.0 * mu * V)
            self._alphaH = 1.0 / (lam * V)
            self._Ainv_ds = None
        if self.kind != "distance":
            self._lamD = np.zeros((md.n_cubes, 8, 3) if self.kind == "corotational" else md.n_cubes)
            self._lamH = np.zeros(md.n_cubes)
            groups = [np.flatnonzero(colors == c) for c in range(8) if np.any(colors == c)]
            valence = np.bincount(md.hexes.ravel(), minlength=md.n_nodes)
            self._jac = self.relaxation / valence[md.hexes].max(axis=1)
            nodes_of = md.hexes
        else:
            M = lam + 2.0 * mu
            kfac = np.where(MATCHING_KIND == 3, 0.25, 1.0 / 12.0)                   # (7,)
            pairs, k = [], []
            for c in range(8):
                cubes = np.flatnonzero(colors == c)
                if cubes.size == 0:
                    continue
                for g in range(7):
                    pairs.append(md.hexes[cubes][:, MATCHINGS[g]].reshape(-1, 2))  # (4 n_c, 2)
                    k.append(np.repeat(M[cubes] * self.h * kfac[g], 4))
            self._pairs = np.concatenate(pairs)
            self._alpha = 1.0 / np.concatenate(k)
            self._rest_len = np.linalg.norm(self.rest[self._pairs[:, 1]] - self.rest[self._pairs[:, 0]], axis=1)
            ends = np.cumsum([0] + [len(p) for p in pairs])
            groups = [np.arange(i, j) for i, j in zip(ends[:-1], ends[1:])]
            self._lamC = np.zeros(len(self._pairs))
            nodes_of = self._pairs
            cval = np.bincount(self._pairs.ravel(), minlength=md.n_nodes)
            self._jac = self.relaxation / cval[self._pairs].max(axis=1)

        # per group: constraint indices, their nodes and inverse masses (last group = all, for Jacobi)
        self._gidx = [*groups, np.arange(len(nodes_of))]
        self._order = np.ascontiguousarray(np.concatenate(groups), dtype=np.int64)   # colour by colour
        self._gnodes = [nodes_of[i] for i in self._gidx]
        self._gw = [self.w[nd][..., None] for nd in self._gnodes]

    # ------------------------------------------------------------------ constraint projection
    def _project_nh(self, x: np.ndarray, g: int, aD: np.ndarray, aH: np.ndarray,
                    scale=None, accumulate: bool = False):
        """Project the cube constraints of group ``g`` (2x2 coupled solve per cube)."""
        idx, hexes, W = self._gidx[g], self._gnodes[g], self._gw[g]
        X = x[hexes]
        CD, gD, J, gH = neohookean_terms(X, self.h)
        aD, aH = aD[idx], aH[idx]
        WgD, WgH = W * gD, W * gH
        n = len(idx)
        A11 = np.einsum("ij,ij->i", WgD.reshape(n, 24), gD.reshape(n, 24)) + aD
        A22 = np.einsum("ij,ij->i", WgH.reshape(n, 24), gH.reshape(n, 24)) + aH
        A12 = np.einsum("ij,ij->i", WgD.reshape(n, 24), gH.reshape(n, 24))
        r1 = -CD - aD * self._lamD[idx]
        r2 = self._gamma[idx] - J - aH * self._lamH[idx]
        det = A11 * A22 - A12 * A12
        dD = (A22 * r1 - A12 * r2) / det
        dH = (A11 * r2 - A12 * r1) / det
        if scale is not None:
            dD, dH = dD * scale[idx], dH * scale[idx]
        self._lamD[idx] += dD
        self._lamH[idx] += dH
        dX = WgD * dD[:, None, None] + WgH * dH[:, None, None]
        if accumulate:
            return hexes, dX
        x[hexes] = X + dX
        return None

    def _block_inverse(self, ds: float) -> None:
        """Cache ``(S W_c S / h^2 + alpha~_D I)^-1`` per cube (n, 8, 8), split by group, for the
        substep ``ds``."""
        if self._Ainv_ds != ds:
            Wc = self.w[self.model.hexes]                                               # (n, 8)
            A = np.einsum("ab,nb,bc->nac", S_REF, Wc, S_REF) / self.h ** 2
            A += (self._alphaD / ds ** 2)[:, None, None] * np.eye(8)
            Ainv = np.linalg.inv(A)
            self._Ainv_g = [Ainv[i] for i in self._gidx]
            self._Ainv_ds = ds

    def _update_rotations(self, x: np.ndarray) -> None:
        self._R = cube_rotations(x[self.model.hexes], self.h)

    def _project_corot(self, x: np.ndarray, g: int, aD: np.ndarray, aH: np.ndarray,
                       scale=None, accumulate: bool = False):
        """Project the cubes of group ``g``: deviatoric block (exact 24-dof solve at fixed R),
        then the volume constraint ``det F - 1`` (Gauss-Seidel: at the updated positions; Jacobi
        (``accumulate``): both at ``x``, corrections returned as ``(hexes, dX)``)."""
        if accumulate:
            hexes, dXD = self._project_dev(x, g, aD, scale, accumulate=True)
            _, dXH = self._project_vol(x, g, aH, scale, accumulate=True)
            return hexes, dXD + dXH
        self._project_dev(x, g, aD)
        self._project_vol(x, g, aH)
        return None

    def _project_dev(self, x: np.ndarray, g: int, aD: np.ndarray, scale=None, accumulate: bool = False):
        """Deviatoric (ARAP) block of group ``g``: exact 24-dof solve at fixed ``R``."""
        idx, hexes, W = self._gidx[g], self._gnodes[g], self._gw[g]
        X = x[hexes]
        rhs = -corotational_terms(X, self.h, self._R[idx]) - aD[idx][:, None, None] * self._lamD[idx]
        dl = np.matmul(self._Ainv_g[g], rhs)                                            # (n, 8, 3)
        if scale is not None:
            dl = dl * scale[idx][:, None, None]
        self._lamD[idx] += dl
        dX = W * np.matmul(S_REF, dl) * (1.0 / self.h)
        if accumulate:
            return hexes, dX
        x[hexes] = X + dX
        return None

    def _project_vol(self, x: np.ndarray, g: int, aH: np.ndarray, scale=None, accumulate: bool = False):
        """Volume constraint ``det F_centre - 1`` of the cubes of group ``g``."""
        idx, hexes, W = self._gidx[g], self._gnodes[g], self._gw[g]
        X = x[hexes]
        J, gH = _volume_terms(X, self.h)                                                # (n,), (n, 8, 3)
        WgH = W * gH
        a = aH[idx]
        n = len(idx)
        dH = (1.0 - J - a * self._lamH[idx]) / (np.einsum("ij,ij->i", WgH.reshape(n, 24), gH.reshape(n, 24)) + a)
        if scale is not None:
            dH = dH * scale[idx]
        self._lamH[idx] += dH
        dX = WgH * dH[:, None, None]
        if accumulate:
            return hexes, dX
        x[hexes] = X + dX
        return None

    def _project_dist(self, x: np.ndarray, g: int, alpha: np.ndarray, scale=None,
                      accumulate: bool = False):
        """Project the (node-disjoint) distance constraints of group ``g``."""
        idx, p = self._gidx[g], self._gnodes[g]
        d = x[p[:, 1]] - x[p[:, 0]]
        ln = np.linalg.norm(d, axis=1)
        n = d / np.maximum(ln, 1e-300)[:, None]
        w0, w1 = self.w[p[:, 0]], self.w[p[:, 1]]
        a = alpha[idx]
        dl = (-(ln - self._rest_len[idx]) - a * self._lamC[idx]) / (w0 + w1 + a)
        if scale is not None:
            dl = dl * scale[idx]
        self._lamC[idx] += dl
        corr = n * dl[:, None]
        if accumulate:
            return p, np.stack([-w0[:, None] * corr, w1[:, None] * corr], axis=1)
        x[p[:, 0]] -= w0[:, None] * corr
        x[p[:, 1]] += w1[:, None] * corr
        return None

    # ------------------------------------------------------------------ one substep's work
    def compliance(self, ds: float) -> tuple:
        """The compliances scaled by the substep, ``alpha / ds^2`` (the deviatoric and hydrostatic
        arrays, or the distance one), and the per-substep caches set up for ``ds``."""
        if self.kind == "corotational":
            self._block_inverse(ds)
        if self.kind != "distance":
            return (self._alphaD / ds**2, self._alphaH / ds**2)
        return (self._alpha / ds**2,)

    def iterate(self, x: np.ndarray, a_t, *, gauss_seidel: bool = True, kernel: str = "numpy") -> None:
        """One solver iteration over all constraints (in place on ``x``): Gauss-Seidel group by group
        (``kernel="numba"``: the compiled Neo-Hookean sweep) or one under-relaxed Jacobi pass."""
        project = {"distance": self._project_dist, "neohookean": self._project_nh,
                   "corotational": self._project_corot}[self.kind]
        if self.kind == "corotational":
            self._update_rotations(x)
        if kernel == "numba":
            nh_sweep(x, self._hexes64, self._order, self.w, self._lamD, self._lamH, a_t[0], a_t[1],
                     self._gamma, L_REF, DN_CENTRE, self.h)
            return
        if gauss_seidel:
            for g in range(len(self._gidx) - 1):
                project(x, g, *a_t)
            return
        nodes, dX = project(x, len(self._gidx) - 1, *a_t, scale=self._jac, accumulate=True)
        _scatter_add(x, nodes, dX)

    def apply_multipliers(self, x: np.ndarray, at: np.ndarray) -> None:
        """Warm start: add ``M^-1 grad C^T lam`` of the stored multipliers, gradients at ``at``."""
        if self.kind == "corotational":
            hexes = self.model.hexes
            _, gH = _volume_terms(at[hexes], self.h)
            dX = self.w[hexes][..., None] * (np.matmul(S_REF, self._lamD) * (1.0 / self.h)
                                             + gH * self._lamH[:, None, None])
            nodes = hexes
        elif self.kind != "distance":
            hexes = self.model.hexes
            _, gD, _, gH = neohookean_terms(at[hexes], self.h)
            dX = self.w[hexes][..., None] * (gD * self._lamD[:, None, None] + gH * self._lamH[:, None, None])
            nodes = hexes
        else:
            p = self._pairs
            d = at[p[:, 1]] - at[p[:, 0]]
            n = d / np.linalg.norm(d, axis=1)[:, None]
            corr = n * self._lamC[:, None]
            dX = np.stack([-self.w[p[:, 0]][:, None] * corr, self.w[p[:, 1]][:, None] * corr], axis=1)
            nodes = p
        _scatter_add(x, nodes, dX)

    def reset_multipliers(self) -> None:
        for name in ("_lamD", "_lamH", "_lamC"):
            if hasattr(self, name):
                getattr(self, name)[:] = 0.0

    # ------------------------------------------------------------------ values and energy
    def values(self, x: np.ndarray) -> dict:
        """Constraint values at node positions ``x`` (m, 3), metres: ``{"C_D": (n,), "C_H": (n,)}``
        (neohookean: ``C_D = sqrt(mean |F|^2)``, ``C_H = det F - gamma``; corotational:
        ``C_D = |S (X - R X_ref)| / h``, ``C_H = det F - 1``) or ``{"C": (k,)}`` (distance;
        ``|x_j - x_i| - L``)."""
        if self.kind == "corotational":
            X = x[self.model.hexes]
            F = centre_F(X, self.h)
            CD = corotational_terms(X, self.h, polar_rotation(F))
            return {"C_D": np.sqrt(np.einsum("nij,nij->n", CD, CD)), "C_H": np.linalg.det(F) - 1.0}
        if self.kind != "distance":
            CD, _, J, _ = neohookean_terms(x[self.model.hexes], self.h)
            return {"C_D": CD, "C_H": J - self._gamma}
        p = self._pairs
        return {"C": np.linalg.norm(x[p[:, 1]] - x[p[:, 0]], axis=1) - self._rest_len}

    def elastic_energy(self, x: np.ndarray) -> float:
        """Elastic energy (J) of the constraints at node positions ``x`` (m, 3), zero at rest:
        neohookean ``sum V [mu/2 (C_D^2 - 3) + lam_nh/2 (C_H^2 - (mu/lam_nh)^2)]``;
        corotational ``sum V [mu C_D^2 + lambda/2 C_H^2]``; distance ``sum k/2 C^2``."""
        c = self.values(x)
        if self.kind == "corotational":
            return float(np.sum(c["C_D"] ** 2 / (2 * self._alphaD) + c["C_H"] ** 2 / (2 * self._alphaH)))
        if self.kind != "distance":
            rest_H = (1.0 - self._gamma) ** 2
            return float(np.sum((c["C_D"] ** 2 - 3.0) / (2 * self._alphaD)
                                + (c["C_H"] ** 2 - rest_H) / (2 * self._alphaH)))
        return float(np.sum(c["C"] ** 2 / (2 * self._alpha)))
