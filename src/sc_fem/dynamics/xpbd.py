"""XPBD (Macklin, Mueller & Chentanez 2016) on the Squashing Cubes lattice.

Algorithm 1 of the paper, per substep of length ``dt_s = dt / substeps``:

1. prediction ``x0 = x + dt_s v + dt_s^2 g`` (fixed nodes have inverse mass 0 and do not move);
2. ``iterations`` solver passes; each constraint ``C`` with compliance ``alpha`` (scaled
   ``alpha~ = alpha / dt_s^2``) updates its Lagrange multiplier
   ``dlam = (-C - alpha~ lam) / (sum_i w_i |grad_i C|^2 + alpha~)``, ``lam += dlam``,
   ``x_i += w_i grad_i C dlam`` -- the multipliers accumulate across iterations;
3. velocity update ``v = (x - x_prev) / dt_s``, then optional mass-proportional damping.

Constraints (``constraints=``):

``"neohookean"`` (default) -- Macklin & Mueller 2021 ("A constraint-based formulation of stable
    Neo-Hookean materials") from the *same* material as the FEM: per cube a hydrostatic
    constraint ``C_H = det F - gamma`` (``gamma = 1 + mu / lam_nh``, compliance ``1 / (lam_nh V)``)
    and a deviatoric one ``C_D = sqrt(mean_cube |F|^2)`` (compliance ``1 / (mu V)``), with
    ``lam_nh = lambda + mu`` so that the linearisation at rest is exactly linear elasticity with the
    model's Lame parameters (``CubeModel.lame()``). Both are solved together as a 2x2 block per
    cube, so the rest state is an exact fixed point of every iteration.

    Hexahedral quadrature: ``C_H`` uses ``F`` at the cube centre (1-point); alone, 1-point ``F`` has
    12 zero-energy hourglass modes per cube (including the element bending modes, which makes
    beams too soft / unstable). ``C_D`` therefore integrates ``|F|^2`` *exactly* over the trilinear
    cube (``mean |F|^2 = x^T L x / h^2`` with the cube's reference Laplacian ``L``), which is the
    hourglass-stabilised, selectively-reduced-integrated hex: the ``mu`` term is fully integrated
    (no hourglass modes), the volumetric term is 1-point (no volumetric locking). Still two
    scalar constraints per cube, so one vectorized sweep per colour.

``"corotational"`` -- per cube an ARAP block ``C_D = S (X - R X_ref) / h`` (``S = sqrt(L)``, so
    ``|C_D|^2 h^3 = int |grad x - R|^2`` exactly; ``R`` = polar rotation of the centre ``F``,
    refreshed once per iteration; compliance ``1 / (2 mu V)``) solved exactly as a 24-dof block at
    fixed ``R``, then the volume constraint ``det F - 1`` (compliance ``1 / (lambda V)``). Zero
    rest values, no cancelling multipliers. Eigen-analysis of one substep's linearised map at rest
    (tests): spectral radius <= 1 + 5e-4 at 1-16 ms substeps (0.9990 / 1.00006 / 1.0005 / 0.99997
    at 1 / 2 / 4 / 16 ms), whereas the Neo-Hookean pair reaches ~3.8 at
    1 ms and ~2.5e5 at 4 ms on a 5 MPa 5 cm lattice (its C_D and C_H gradients are parallel at
    rest, so the 2x2 solve produces large cancelling multipliers ~1/alpha~ and the one-sweep
    Gauss-Seidel overshoots). Limits (measured): with one iteration at long substeps it is far
    too soft (8x2x2 cantilever: 4.1x the FEM sag at 5 ms) and, with gravity, it pumps spurious
    elastic energy (growth > 10 M|g|D at >= 8 ms on that beam -> InstabilityError); converged it is
    ~11 % stiffer than q1i on a 2-cube-thick beam (fully integrated rotation term), and it costs
    ~2-3x the Neo-Hookean sweep. Use it when the Neo-Hookean pair blows up; not the default.

    Why the Neo-Hookean pair is unstable at long substeps (derived, and measured with the tests'
    spectral-radius helper, 6x2x2 cubes, h = 5 cm, E = 5 MPa): at rest its Gauss-Newton block
    ``grad C^T grad C`` only holds volumetric stiffness (the gradients of ``C_D = sqrt(3)`` and
    ``C_H`` are both ``~ I``); the whole shear stiffness comes from the curvature terms ``mu C_D
    grad^2 C_D + lam_nh C_H grad^2 C_H`` of the non-zero rest values, which XPBD applies only via
    re-evaluated gradients times the prestress multipliers -- explicitly, hence a CFL-type limit
    ``~ h / c_s``. Spectral radius at 0.25 / 0.5 / 1 / 2 / 4 ms substeps: coupled 2x2 (kept) 0.9998 /
    0.9993 / 3.77 / 104 / 2.5e5; sequential C_D then C_H (2021 paper) 0.9997 / 0.9994 / 1.04 / 2.83 /
    14.5 (and rest is no longer a fixed point of one iteration); 2x2 with a proximal term ``A_ii (1 +
    eps)`` (fixed point unchanged) eps = 0.01: 3.63 / 88.9 / 376 at 1 / 2 / 4 ms, eps = 0.1: 2.62 /
    23.2 / 67.5; corotational 0.9998 / 0.9994 / 0.9990 / 1.00006 / 1.0005. ``C_D = |F| - sqrt(3)``
    (zero rest value) has no shear stiffness at rest; any scalar deviatoric constraint has a rank-1
    Gauss-Newton block, so a stable small-strain-exact form needs a block constraint like ARAP. A
    corotational quadrature with exactly the Neo-Hookean linearisation (``S = sqrt((L + DN DN^T)/2)``:
    half fully integrated, half 1-point; energies agree to 1e-4, converged 8x2x2 sag 1.052 x q1sri
    for both) was tried and not kept: equally stable, but at 50 x 1 per 60-fps frame it is softer
    (quick bar 24x3x3: sag / FEM 1.085, period / FEM 1.047 vs 1.001 / 1.006 for this quadrature,
    whose full-integration stiffening happens to cancel the one-iteration softening; full bar
    48x6x6, first peak / (2 FEM sag): 1.51 vs 1.49, Neo-Hookean 1.10). Warm start makes the
    corotational pair unstable at >= 0.67 ms substeps on the quick bar.

Blow-up detection: after every step, non-finite positions/velocities or a total energy above its
start by more than ``max_energy_growth`` (default 10) x ``energy_scale`` (max of initial kinetic +
elastic energy and ``M |g| diameter``) raise :class:`~sc_fem.errors.InstabilityError` naming the step
and the substep length. :func:`stability_sweep` returns (dt, max energy growth, blown up, error)
rows for a model (used by ``benchmarks/xpbd.py``); its error compares the *final* displacement
with a static reference.

``"distance"`` -- classic per-cube distance constraints along the 12 edges, 12 face diagonals and
    4 body diagonals (a central-force lattice). Stiffnesses ``k_edge = k_face = M h / 12``,
    ``k_body = M h / 4`` with the P-wave modulus ``M = lambda + 2 mu`` reproduce the uniaxial-strain
    modulus; a central-force lattice has Poisson's ratio 1/4 (Cauchy relation), so this is only an
    approximation of the material (the simple variant).

Vectorization: cubes whose (i, j, k) have equal parities share no node, so the lattice splits
into 8 colours and Gauss-Seidel runs as 8 vectorized sweeps per iteration (distance constraints:
each cube's 28 constraints form 7 perfect matchings of its 8 corners, so 8 x 7 sweeps). The Jacobi
variant (``gauss_seidel=False``) updates all constraints at once with under-relaxation
``relaxation / (max node valence of the constraint)``.

``warm_start=True`` (an extension, off by default = Algorithm 1): the multipliers of the previous
substep are re-used and their correction applied after the prediction (an explicit force
predictor). Then a static equilibrium is an exact fixed point for any iteration count, which
removes the "effective stiffness depends on iterations" bias of XPBD at rest.

Numerical damping: XPBD with few iterations is implicit-Euler-like and dissipates energy; the
dissipation falls with more substeps. Measured (``python benchmarks/xpbd.py --quick``: 4 m bar,
24 x 3 x 3 cubes, first bending mode T = 0.866 s, 2.6 periods of free vibration, log decrement of
successive downward tip peaks): neohookean 25 substeps/frame (0.67 ms) delta = 0.021 (zeta =
0.34 %), 50 substeps delta = 0.016 (zeta = 0.26 %), 50 substeps warm start delta = 0.010 (0.17 %),
corotational 50 substeps delta = 0.020 (0.31 %); i.e. 1.4x (0.67 ms) to 2.2x (0.33 ms) implicit
Euler's zeta = omega dt_s / 2 (omega = 7.25 rad/s): halving the substep removes only ~1/4 of the
damping, because the unconverged single iteration adds its own dissipation. The full-size figures
are printed by the default run. ``damping`` adds explicit mass-proportional damping
``v <- v / (1 + damping * dt_s)`` (1/s).

Units: positions in metres, velocities m/s, times s, energies J.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .._validate import as_float_array, as_points, positive_int, positive_scalar
from ..errors import BoundaryConditionError, InputError, InstabilityError
from .base import Energy
from .corotational import DN_CENTRE, centre_F, cofactor, polar_rotation
from ..lattice.cubes import HEX_CORNERS, CubeModel

CONSTRAINTS = ("corotational", "neohookean", "distance")

XPBDEnergy = Energy
"""Energy split of an XPBD state (alias of :class:`sc_fem.dynamics.base.Energy`): kinetic,
gravity potential (relative to the rest positions), elastic (of the constraints, zero at rest), J."""


def _reference_laplacian() -> np.ndarray:
    """``L_ab = int_unit cube grad N_a . grad N_b`` (8, 8), exact by 2x2x2 Gauss."""
    g = 0.5 + np.array([-0.5, 0.5]) / np.sqrt(3.0)
    q = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)          # (8, 3)
    o = HEX_CORNERS[None, :, :]                                                     # (1, 8, 3)
    f = np.where(o == 1, q[:, None, :], 1.0 - q[:, None, :])                       # (8q, 8a, 3)
    df = np.where(o == 1, 1.0, -1.0) * np.ones_like(f)
    grad = np.stack([df[..., 0] * f[..., 1] * f[..., 2], f[..., 0] * df[..., 1] * f[..., 2],
                     f[..., 0] * f[..., 1] * df[..., 2]], -1)                       # (8q, 8a, 3)
    return np.einsum("qai,qbi->ab", grad, grad) / 8.0


L_REF = _reference_laplacian()
"""Reference Laplacian of the unit cube, shape (8, 8), in :data:`HEX_CORNERS` order."""

# 7 perfect matchings of the 8 corners (3 edge sets, 3 face-diagonal sets, 1 body-diagonal set)
def _matchings() -> tuple[np.ndarray, np.ndarray]:
    pairs, kinds = [], []
    for a in range(8):
        for b in range(a + 1, 8):
            d = np.abs(HEX_CORNERS[a] - HEX_CORNERS[b])
            pairs.append((a, b, int(d.sum()), tuple(d)))
    groups = []
    for kind in (1, 2):   # edges / face diagonals grouped by the axis (edge) or face normal
        for ax in range(3):
            sel = [(a, b) for a, b, n, d in pairs if n == kind and
                   ((kind == 1 and d[ax] == 1) or (kind == 2 and d[ax] == 0))]
            groups.append(sel)
            kinds.append(kind)
    groups.append([(a, b) for a, b, n, _ in pairs if n == 3])
    kinds.append(3)
    return np.array(groups, dtype=np.int64), np.array(kinds)


MATCHINGS, MATCHING_KIND = _matchings()               # (7, 4, 2), (7,) 1=edge 2=face 3=body


def _sqrt_laplacian() -> np.ndarray:
    e, V = np.linalg.eigh(L_REF)
    return (V * np.sqrt(np.maximum(e, 0.0))) @ V.T


S_REF = _sqrt_laplacian()
"""Symmetric square root of :data:`L_REF` (8, 8): ``S S = L_REF``, ``S 1 = 0``."""


def _volume_terms(X: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """``J = det F`` at the cube centre and its gradient ``grad_a J = cof(F) grad N_a``.

    Parameters
    ----------
    X : ndarray, shape (n, 8, 3)
        Corner positions, metres, :data:`HEX_CORNERS` order.
    h : float
        Rest edge, metres.

    Returns
    -------
    J : ndarray, shape (n,)
        Dimensionless.
    gJ : ndarray, shape (n, 8, 3)
        1/m.
    """
    F = centre_F(X, h)                                               # (n, 3, 3), F_jk
    cof = cofactor(F)
    J = np.einsum("ij,ij->i", F[:, 0, :], cof[:, 0, :])
    return J, np.matmul(DN_CENTRE, cof.transpose(0, 2, 1)) * (1.0 / h)


def _scatter_add(x: np.ndarray, nodes: np.ndarray, dX: np.ndarray) -> None:
    """``x[nodes] += dX`` with repeated nodes summed; ``x`` (m, 3), ``nodes`` (k, c), ``dX`` (k, c, 3)."""
    flat = nodes.ravel()
    for j in range(3):
        x[:, j] += np.bincount(flat, weights=dX[..., j].ravel(), minlength=len(x))


def corotational_terms(X: np.ndarray, h: float, R: np.ndarray):
    """Deviatoric (ARAP) constraint vectors of a batch of cubes.

    ``C_D = S (X - X_ref R^T) / h`` with ``S = sqrt(L_REF)``, so that ``|C_D|^2 h^3 =
    int_cube |grad x - R|^2`` exactly for the trilinear cube (``R`` constant in the cube).

    Parameters
    ----------
    X : ndarray, shape (n, 8, 3)
        Corner positions, metres, :data:`HEX_CORNERS` order.
    h : float
        Rest edge, metres.
    R : ndarray, shape (n, 3, 3)
        Rotation per cube (normally :func:`polar_rotation` of the centre ``F``).

    Returns
    -------
    ndarray, shape (n, 8, 3)
        ``C_D`` (dimensionless); its gradient w.r.t. corner ``a`` component ``j`` at fixed
        ``R`` is ``S[:, a] / h`` for component ``j``.
    """
    Xr = np.matmul((h * HEX_CORNERS)[None], R.transpose(0, 2, 1))        # (n, 8, 3) = R X_ref
    return np.matmul(S_REF, X - Xr) * (1.0 / h)


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


def cube_colors(model: CubeModel) -> np.ndarray:
    """Colour 0..7 of each cube from the parities of its lattice index, shape (n,).

    Two cubes of the same colour share no node."""
    p = np.asarray(model.cells) % 2
    return p[:, 0] * 4 + p[:, 1] * 2 + p[:, 2]


def neohookean_terms(X: np.ndarray, h: float):
    """Constraint values and gradients of the stable Neo-Hookean pair for a batch of cubes.

    Parameters
    ----------
    X : ndarray, shape (n, 8, 3)
        Corner positions (metres) in :data:`HEX_CORNERS` order.
    h : float
        Rest edge length, metres.

    Returns
    -------
    CD : (n,) ``sqrt(mean |F|^2)``;  gD : (n, 8, 3) its gradient;
    J : (n,) ``det F`` at the centre;  gH : (n, 8, 3) its gradient (``cof(F) grad N_a``).
    """
    n = X.shape[0]
    LX = np.matmul(L_REF, X)                                       # (n, 8, 3)
    CD = np.sqrt(np.maximum(np.einsum("ij,ij->i", X.reshape(n, 24), LX.reshape(n, 24)), 1e-300)) / h
    gD = LX * (1.0 / (h * h * CD))[:, None, None]
    J, gH = _volume_terms(X, h)
    return CD, gD, J, gH


def _as_fixed(fixed, n_nodes: int) -> np.ndarray:
    """Boolean mask (m,) of fixed nodes from indices or a mask."""
    if fixed is None:
        return np.zeros(n_nodes, dtype=bool)
    arr = np.asarray(fixed)
    if arr.dtype == bool:
        if arr.shape != (n_nodes,):
            raise BoundaryConditionError(f"fixed mask must have shape ({n_nodes},), got {arr.shape}")
        return arr.copy()
    if arr.size == 0:
        return np.zeros(n_nodes, dtype=bool)
    if not np.issubdtype(arr.dtype, np.integer) or arr.ndim != 1:
        raise BoundaryConditionError(f"fixed must be a 1-D array of node indices or a bool mask, "
                                     f"got dtype {arr.dtype} shape {arr.shape}")
    if arr.min() < 0 or arr.max() >= n_nodes:
        raise BoundaryConditionError(f"fixed node indices must lie in [0, {n_nodes}), got range "
                                     f"[{arr.min()}, {arr.max()}]")
    mask = np.zeros(n_nodes, dtype=bool)
    mask[arr] = True
    return mask


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
    fixed : array_like of int or bool mask (m,), optional
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
    """

    def __init__(self, model: CubeModel, dt: float, *, substeps: int = 10, iterations: int = 1,
                 constraints: str = "neohookean", gravity=(0.0, 0.0, -9.81), fixed=None,
                 damping: float = 0.0, gauss_seidel: bool = True, relaxation: float = 1.0,
                 warm_start: bool = False, max_energy_growth: float = 10.0,
                 positions=None, velocities=None) -> None:
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
        self.fixed = _as_fixed(fixed, m)
        self.mass = model.node_masses()
        self.w = np.where(self.fixed, 0.0, 1.0 / self.mass)
        v[self.fixed] = 0.0
        self._x, self._v = x, v
        self.time, self.n_steps = 0.0, 0
        self.last_energy_growth = 0.0
        """Energy growth (see :meth:`energy_growth`) after the last :meth:`step`."""
        self.h = model.h
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
        free = ~self.fixed
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
        """Kinetic + gravity potential (relative to rest) + elastic energy, J."""
        x = self._x if state is None else state.positions
        v = self._v if state is None else state.velocities
        kin = 0.5 * float(np.sum(self.mass[:, None] * v * v))
        grav = -float(np.sum(self.mass * ((x - self.rest) @ self.gravity)))
        return XPBDEnergy(kinetic=kin, gravity=grav, elastic=self.elastic_energy(x))


def simulate_xpbd(model: CubeModel, dt: float, n_steps: int, *, substeps: int = 10, iterations: int = 1,
                  constraints: str = "neohookean", gravity=(0.0, 0.0, -9.81), fixed=None,
                  damping: float = 0.0, gauss_seidel: bool = True, warm_start: bool = False,
                  progress: bool = False, **kw) -> Iterator[XPBDState]:
    """Generator of XPBD states: the initial state (t = 0) then ``n_steps`` steps of ``dt`` s.

    See :class:`XPBDSolver` for the parameters."""
    solver = XPBDSolver(model, dt, substeps=substeps, iterations=iterations, constraints=constraints,
                        gravity=gravity, fixed=fixed, damping=damping, gauss_seidel=gauss_seidel,
                        warm_start=warm_start, **kw)
    yield from solver.run(n_steps, progress=progress)


@dataclass(frozen=True)
class StabilityRow:
    """One row of :func:`stability_sweep`.

    Attributes
    ----------
    dt : float
        Substep length, s.
    max_energy_growth : float
        ``max_t (E(t) - E(0)) / energy_scale`` (see :meth:`XPBDSolver.energy_growth`); ``inf``
        when the run blew up.
    blew_up : bool
        :class:`~sc_fem.errors.InstabilityError` was raised.
    error : float
        ``|| u(end) - u_ref || / || u_ref ||`` over all nodes (``nan`` without a reference or
        after a blow-up): the final displacement against a static reference (pass ``damping`` so
        that the run settles, e.g. twice the first angular frequency).
    ms_per_second : float
        Wall milliseconds per simulated second.
    """

    dt: float
    max_energy_growth: float
    blew_up: bool
    error: float
    ms_per_second: float


def stability_sweep(model: CubeModel, substep_sizes, *, duration: float = 0.5, frame_dt: float | None = None,
                    fixed=None, reference=None, constraints: str = "neohookean", iterations: int = 1,
                    gravity=(0.0, 0.0, -9.81), **kw) -> list[StabilityRow]:
    """XPBD released from rest under gravity for each substep length: energy growth, blow-up, error.

    Parameters
    ----------
    model : CubeModel
    substep_sizes : sequence of float
        Substep lengths, s (e.g. ``[1e-4, 4e-4, 1e-3, 4e-3, 16e-3]``).
    duration : float
        Simulated seconds per run.
    frame_dt : float, optional
        Frame step, s (default 1/60 s), rounded to a whole number of substeps; at least one
        substep (so the frame step is the substep itself when the substep is longer).
    fixed : array_like, optional
        Fixed nodes (see :class:`XPBDSolver`).
    reference : array_like, shape (m, 3), optional
        Static displacement (m) to compare the final displacement with (see
        :attr:`StabilityRow.error`).
    constraints, iterations, gravity, **kw
        Passed to :class:`XPBDSolver`.

    Returns
    -------
    list of StabilityRow
    """
    import time as _time

    duration = positive_scalar(duration, "duration")
    if frame_dt is not None:
        frame_dt = positive_scalar(frame_dt, "frame_dt")
    ref = None if reference is None else as_points(reference, "reference")
    rows = []
    for ds in np.atleast_1d(np.asarray(substep_sizes, dtype=float)):
        ds = positive_scalar(float(ds), "substep_sizes")
        n_sub = max(1, int(round((1 / 60 if frame_dt is None else frame_dt) / ds)))
        solver = XPBDSolver(model, ds * n_sub, substeps=n_sub, iterations=iterations, constraints=constraints,
                            fixed=fixed, gravity=gravity, **kw)
        n_steps = max(1, int(round(duration / solver.dt)))
        growth, blew = -np.inf, False
        t0 = _time.perf_counter()
        try:
            for _ in range(n_steps):
                st = solver.step()
                growth = max(growth, solver.last_energy_growth)
        except InstabilityError:
            blew, growth = True, np.inf
        wall = _time.perf_counter() - t0
        err = np.nan
        if ref is not None and not blew:
            err = float(np.linalg.norm(st.positions - solver.rest - ref) / np.linalg.norm(ref))
        rows.append(StabilityRow(dt=float(ds), max_energy_growth=float(growth), blew_up=blew, error=err,
                                 ms_per_second=1e3 * wall / (solver.time or 1.0)))
    return rows
