"""XPBD (Macklin, Mueller & Chentanez 2016) on the Squashing Cubes lattice: :class:`XPBDSolver`.

Per substep: predict, one or more vectorized Gauss-Seidel sweeps (8 cube colours) over the
constraints of every cube, update velocities. Constraints: ``"neohookean"`` (default; the stable
Neo-Hookean pair linearising to the lattice's own Lame parameters), ``"corotational"`` (an ARAP
block, stable at long substeps but soft) and ``"distance"`` (a central-force lattice). A step that
blows up raises :class:`~sc_fem.errors.InstabilityError` naming the substep that is too long.
The constraint kernels are in :mod:`.xpbd_kernels`, the stability sweep in :mod:`.xpbd_stability`;
the algorithm, the quadrature and the measurements behind the defaults are in ``docs/xpbd.md``.
Through :class:`~sc_fem.dynamics.xpbd_integrator.XPBDIntegrator` it runs on the common driver.

Units: positions in metres, velocities m/s, times s, energies J.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .._validate import as_float_array, as_points, positive_int, positive_scalar
from ..errors import InputError, InstabilityError
from ..lattice.cubes import CubeModel
from .base import Energy
from .corotational import DN_CENTRE, centre_F, polar_rotation
from .xpbd_jit import choose_kernel
from .xpbd_kernels import (L_REF, MATCHING_KIND, MATCHINGS, S_REF, _as_fixed, _scatter_add, _volume_terms, corotational_terms, cube_colors,
                           neohookean_terms)

CONSTRAINTS = ("corotational", "neohookean", "distance")

XPBDEnergy = Energy
"""Energy split of an XPBD state (alias of :class:`sc_fem.dynamics.base.Energy`): kinetic,
gravity potential (relative to the rest positions), elastic (of the constraints, zero at rest), J."""


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
        Substeps per step and solver iterations per substep (J of Algorithm 1).
    constraints : {"neohookean", "corotational", "distance"}
        Constraint family (see the module docstring).
    gravity : array_like, shape (3,)
        m/s^2.
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

    def __init__(self, model: CubeModel, dt: float, *, substeps: int = 10, iterations: int = 1,
                 constraints: str = "neohookean", gravity=(0.0, 0.0, -9.81), fixed_nodes=None,
                 damping: float = 0.0, gauss_seidel: bool = True, relaxation: float = 1.0,
                 warm_start: bool = False, max_energy_growth: float = 10.0,
                 positions=None, velocities=None, kernel: str = "auto") -> None:
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
        self.h = model.h
        self.kernel = choose_kernel(kernel, constraints == "neohookean" and self.gauss_seidel)
        """The sweep that runs: ``"numba"`` or ``"numpy"``."""
        self._build()
        e0 = self.energy()
        self._energy0 = e0.total
        lo, hi = self.rest.min(0), self.rest.max(0)
        self.energy_scale = max(abs(e0.kinetic) + abs(e0.elastic),
                                float(self.mass.sum() * np.linalg.norm(self.gravity) * np.linalg.norm(hi - lo)),
                                1e-300)
        """Energy scale (J) of the runaway test: max(initial kinetic + elastic, M |g| diameter)."""

    # ------------------------------------------------------------------ setup
    def _build(self) -> None:
        md = self.model
        V = self.h ** 3
        lam, mu = md.lame()
        colors = cube_colors(md)
        self._hexes64 = np.ascontiguousarray(md.hexes, dtype=np.int64)
        if self.constraints == "neohookean":
            lam_nh = lam + mu
            self._gamma = 1.0 + mu / lam_nh
            self._alphaD = 1.0 / (mu * V)
            self._alphaH = 1.0 / (lam_nh * V)
        if self.constraints == "corotational":
            self._alphaD = 1.0 / (2.0 * mu * V)
            self._alphaH = 1.0 / (lam * V)
            self._Ainv_ds = None
        if self.constraints != "distance":
            self._lamD = np.zeros((md.n_cubes, 8, 3) if self.constraints == "corotational" else md.n_cubes)
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
        self._R = polar_rotation(centre_F(x[self.model.hexes], self.h))

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

    def _iteration(self, x: np.ndarray, a_t) -> None:
        """One solver iteration over all constraints (in place on ``x``)."""
        project = {"distance": self._project_dist, "neohookean": self._project_nh,
                   "corotational": self._project_corot}[self.constraints]
        if self.constraints == "corotational":
            self._update_rotations(x)
        if self.kernel == "numba":
            from .xpbd_jit import nh_sweep

            nh_sweep(x, self._hexes64, self._order, self.w, self._lamD, self._lamH, a_t[0], a_t[1],
                     self._gamma, L_REF, DN_CENTRE, self.h)
            return
        if self.gauss_seidel:
            for g in range(len(self._gidx) - 1):
                project(x, g, *a_t)
            return
        nodes, dX = project(x, len(self._gidx) - 1, *a_t, scale=self._jac, accumulate=True)
        _scatter_add(x, nodes, dX)

    def _scaled_compliance(self, ds: float):
        if self.constraints != "distance":
            return (self._alphaD / ds**2, self._alphaH / ds**2)
        return (self._alpha / ds**2,)

    def _apply_multipliers(self, x: np.ndarray, at: np.ndarray) -> None:
        """Warm start: add ``M^-1 grad C^T lam`` of the stored multipliers, gradients at ``at``."""
        if self.constraints == "corotational":
            hexes = self.model.hexes
            _, gH = _volume_terms(at[hexes], self.h)
            dX = self.w[hexes][..., None] * (np.matmul(S_REF, self._lamD) * (1.0 / self.h)
                                             + gH * self._lamH[:, None, None])
            nodes = hexes
        elif self.constraints != "distance":
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

    def _reset_multipliers(self) -> None:
        for name in ("_lamD", "_lamH", "_lamC"):
            if hasattr(self, name):
                getattr(self, name)[:] = 0.0

    # ------------------------------------------------------------------ time stepping
    def substep(self, ds: float) -> None:
        """Advance by one substep of ``ds`` seconds (Algorithm 1)."""
        x_prev = self._x
        free = ~self.fixed_mask
        x = x_prev + ds * self._v
        x[free] += ds * ds * self.gravity
        a_t = self._scaled_compliance(ds)
        if self.constraints == "corotational":
            self._block_inverse(ds)
        if self.warm_start:
            self._apply_multipliers(x, x_prev)
        else:
            self._reset_multipliers()
        for _ in range(self.iterations):
            self._iteration(x, a_t)
        v = (x - x_prev) / ds
        if self.damping > 0.0:
            v /= 1.0 + self.damping * ds
        self._x, self._v = x, v

    def step(self) -> XPBDState:
        """Advance one frame step ``dt`` (``substeps`` substeps) and return the new state.

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
        """``(E_total - E_total(t=0)) / energy_scale`` now (dimensionless; XPBD should keep it
        <= ~0 up to the work of gravity, which is bounded by one ``energy_scale``)."""
        return (self.energy().total - self._energy0) / self.energy_scale

    @property
    def state(self) -> XPBDState:
        """The current state (copies)."""
        return XPBDState(time=self.time, step=self.n_steps, positions=self._x.copy(),
                         velocities=self._v.copy())

    def run(self, n_steps: int, *, progress: bool = False) -> Iterator[XPBDState]:
        """Yield the current state, then the state after each of ``n_steps`` steps."""
        n_steps = positive_int(n_steps, "n_steps", minimum=0)
        yield self.state
        bar = None
        if progress:
            from tqdm import tqdm
            bar = tqdm(total=n_steps, desc="XPBD", unit="step", file=sys.stderr)
        try:
            for _ in range(n_steps):
                st = self.step()
                if bar is not None:
                    bar.update()
                yield st
        finally:
            if bar is not None:
                bar.close()

    def __iter__(self) -> Iterator[XPBDState]:
        while True:
            yield self.step()

    # ------------------------------------------------------------------ diagnostics
    def constraint_values(self, positions=None) -> dict:
        """Constraint values at ``positions`` (m, 3) metres (default: current).

        Returns ``{"C_D": (n,), "C_H": (n,)}`` (neohookean: ``C_D = sqrt(mean |F|^2)``,
        ``C_H = det F - gamma``; corotational: ``C_D = |S (X - R X_ref)| / h``, ``C_H = det F - 1``)
        or ``{"C": (k,)}`` (distance; ``|x_j - x_i| - L``)."""
        x = self._x if positions is None else as_points(positions, "positions")
        if self.constraints == "corotational":
            X = x[self.model.hexes]
            F = centre_F(X, self.h)
            CD = corotational_terms(X, self.h, polar_rotation(F))
            return {"C_D": np.sqrt(np.einsum("nij,nij->n", CD, CD)), "C_H": np.linalg.det(F) - 1.0}
        if self.constraints != "distance":
            CD, _, J, _ = neohookean_terms(x[self.model.hexes], self.h)
            return {"C_D": CD, "C_H": J - self._gamma}
        p = self._pairs
        return {"C": np.linalg.norm(x[p[:, 1]] - x[p[:, 0]], axis=1) - self._rest_len}

    def elastic_energy(self, positions=None) -> float:
        """Elastic energy of the constraints in J, zero at rest:
        neohookean ``sum V [mu/2 (C_D^2 - 3) + lam_nh/2 (C_H^2 - (mu/lam_nh)^2)]``;
        corotational ``sum V [mu C_D^2 + lambda/2 C_H^2]``; distance ``sum k/2 C^2``."""
        c = self.constraint_values(positions)
        if self.constraints == "corotational":
            return float(np.sum(c["C_D"] ** 2 / (2 * self._alphaD) + c["C_H"] ** 2 / (2 * self._alphaH)))
        if self.constraints != "distance":
            rest_H = (1.0 - self._gamma) ** 2
            return float(np.sum((c["C_D"] ** 2 - 3.0) / (2 * self._alphaD)
                                + (c["C_H"] ** 2 - rest_H) / (2 * self._alphaH)))
        return float(np.sum(c["C"] ** 2 / (2 * self._alpha)))

    def energy(self, state: XPBDState | None = None) -> XPBDEnergy:
        """Kinetic + gravity potential (relative to rest) + elastic energy, J (of the current state,
        computed once per state: :meth:`step` evaluates it for its blow-up check)."""
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


def simulate_xpbd(model: CubeModel, dt: float, n_steps: int, *, substeps: int = 10, iterations: int = 1,
                  constraints: str = "neohookean", gravity=(0.0, 0.0, -9.81), fixed_nodes=None,
                  damping: float = 0.0, gauss_seidel: bool = True, warm_start: bool = False,
                  progress: bool = False, **kw) -> Iterator[XPBDState]:
    """Generator of XPBD states: the initial state (t = 0) then ``n_steps`` steps of ``dt`` s.

    See :class:`XPBDSolver` for the parameters."""
    solver = XPBDSolver(model, dt, substeps=substeps, iterations=iterations, constraints=constraints,
                        gravity=gravity, fixed_nodes=fixed_nodes, damping=damping, gauss_seidel=gauss_seidel,
                        warm_start=warm_start, **kw)
    yield from solver.run(n_steps, progress=progress)
