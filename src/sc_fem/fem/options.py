"""Which solver, and within what memory: the options of :func:`sc_fem.modal`'s eigensolve
(:class:`EigenOptions`) and the automatic choice of method (:func:`choose_method`), and the options
of :func:`sc_fem.solve_static`'s linear solve (:class:`StaticOptions`, :func:`choose_static_solver`).

``method="auto"`` predicts both solvers' times (:func:`predicted_seconds`) and memory
(:func:`factor_memory_estimate`, :func:`lobpcg_memory_estimate`), and takes the faster one that
fits the budget (:func:`memory_budget`: ``max_memory``, default half the available memory).
Shift-invert's time and memory follow from the fill of the matrix itself
(:func:`~sc_fem.fem.fill.fill_analysis`:
CHOLMOD's ordering, whose factorization then reuses it), LOBPCG's as a set-up plus iterations
(more on thin members, which fill less) times their cost (:func:`~sc_fem.fem.fill.lobpcg_seconds`);
without CHOLMOD or numba both from :data:`SPEED_MODEL`. The solvers themselves are in
:mod:`sc_fem.fem.eigen`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from .._jit import available
from .._memory import available_memory
from .._validate import positive_int, positive_scalar
from ..errors import InputError, SolverError

# fill_analysis and its size limit are re-exported: the automatic choice's names stay importable from here
from .fill import (FILL_ANALYSIS_MAX_DOFS, LOBPCG_FILL_MODEL, fill_analysis, lobpcg_block,  # noqa: F401
                   lobpcg_seconds, shift_invert_seconds)
from .linsolve import BACKENDS, SystemSolver

if TYPE_CHECKING:
    from .fill import FillAnalysis

METHODS: tuple[str, ...] = ("auto", "shift-invert", "lobpcg")
"""Names accepted by ``method=``."""

FILL_CONSTANT = 12.0
"""Calibration of :func:`factor_memory_estimate`: ``nnz(L) ~ FILL_CONSTANT * n^(4/3)`` (``n`` DOFs).
Measured with CHOLMOD on ``K + 1e-3 M``: root-fixed cantilevers 7.9 (3k DOFs), 11.1 (19k), 11.7 (61k);
chair r=48 7.6, r=96 5.5; bridge r=96 4.7; solid bunny r=64 5.1. 12 bounds all of them, so the
automatic choice never starts a factorization that would not fit (it may pick LOBPCG a little early
for shells)."""


def _coerce(cls, value, what: str):
    """Options of type ``cls``: ``None`` (defaults), an instance, or a solver name (the ``solver``
    field); anything else is an InputError naming the argument ``what``."""
    if value is None:
        return cls()
    if isinstance(value, cls):
        return value
    if isinstance(value, str):
        return cls(solver=value)
    raise InputError(f"{what} must be a {cls.__name__} or a solver name, got {type(value).__name__}")


@dataclass(frozen=True)
class EigenOptions:
    """Which eigensolver, and within what memory: the options :func:`sc_fem.modal` passes on to
    :class:`~sc_fem.fem.eigen.EigenSolver`.

    Parameters
    ----------
    solver : {"auto", "shift-invert", "lobpcg"}
        ``"auto"`` takes the one predicted faster on this machine whose memory fits
        ``max_memory`` (the reason is recorded in the result).
    backend : {"auto", "cholmod", "cholespy", "splu"}
        Factorization backend of shift-invert (:func:`sc_fem.fem.linsolve.factorize`).
    max_memory : float, optional
        Memory budget in bytes for the automatic choice; default half the available memory.
    """

    solver: str = "auto"
    backend: str = "auto"
    max_memory: float | None = None

    def __post_init__(self) -> None:
        if self.solver not in METHODS:
            raise InputError(f"eigensolver must be one of {list(METHODS)}, got {self.solver!r}")
        if self.backend not in ("auto", *BACKENDS):
            raise InputError(f"backend must be one of {['auto', *BACKENDS]}, got {self.backend!r}")
        if self.max_memory is not None:
            object.__setattr__(self, "max_memory", positive_scalar(self.max_memory, "max_memory"))

    @classmethod
    def coerce(cls, value: "EigenOptions | str | None") -> "EigenOptions":
        """``None`` (defaults), an EigenOptions, or a solver name (``"lobpcg"``).

        Parameters
        ----------
        value : EigenOptions, str or None
            The options, a solver name (the ``solver`` field) or ``None`` for the defaults.

        Returns
        -------
        EigenOptions
            ``value`` itself when it is one, else new options.
        """
        return _coerce(cls, value, "eigen")


def factor_memory_estimate(n: int, nnz: int, analysis: FillAnalysis | None = None) -> int:
    """Estimated bytes of a sparse Cholesky factorization of an ``n x n`` lattice matrix.

    With a :class:`~sc_fem.fem.fill.FillAnalysis` of the matrix, from its ``nnz(L)``: 11 bytes per
    entry (8 per value, CHOLMOD's supernodal padding and the symbolic factor: 1,246 MiB measured for
    121.3M entries at 192k DOFs), plus workspace. Without one,
    ``nnz(L) ~ FILL_CONSTANT * n^(4/3)`` (nested dissection on a 3-D grid), 12 bytes per entry
    (value + index) plus workspace, and never below the matrix itself.
    """
    if analysis is not None:
        return int(11.0 * analysis.nnz_l + 16.0 * n)
    nnz_l = max(FILL_CONSTANT * float(n) ** (4.0 / 3.0), 0.5 * nnz)
    return int(12.0 * nnz_l * 1.3 + 16.0 * n)


LOBPCG_MEMORY = {"per_nonzero": 12.0, "blocks": 9.0, "fixed": 8 * 2**20}
"""Bytes of LOBPCG + AMG (:func:`lobpcg_memory_estimate`): ``per_nonzero`` bytes per nonzero of ``K``
for what stays alive through the solve (``K - sigma M`` once, as node blocks split for the float32
V-cycle; ``M``'s node matrix; the prolongators, coarse levels and rigid modes: 937 B/DOF measured at
3,096,576 DOFs, ~81 nonzeros a DOF), and ``blocks`` blocks of ``n x lobpcg_block(k)`` doubles
(:func:`sc_fem.fem.lobpcg.lobpcg` keeps at most 6, the V-cycle's work about 3), plus ``fixed`` bytes
(the coarsest level's dense factor, small arrays: ~3 MB beyond the rest at 14,520 DOFs). Measured 2026-11-28:
``sc_fem.modal`` with 6 modes at 3,096,576 DOFs peaked at 4.54 GiB (1,574 B/DOF), this estimate 1,692."""


def lobpcg_memory_estimate(n: int, nnz: int, k: int) -> int:
    """Estimated bytes of LOBPCG + AMG for ``k`` pairs of ``n`` DOFs and ``nnz`` nonzeros of ``K``
    (:data:`LOBPCG_MEMORY`: the matrices and hierarchy, and the solver's blocks)."""
    m = LOBPCG_MEMORY
    return int(m["fixed"] + m["per_nonzero"] * nnz + m["blocks"] * 8.0 * n * lobpcg_block(k))


SPEED_MODEL = {"shift-invert": (0.23, 1.98), "lobpcg": (0.72, 0.98), "lobpcg-numba": (0.52, 0.98)}
"""Predicted seconds for 6 modes of a lattice with ``n`` free DOFs: ``c * (n / 7776) ** p`` per
solver, fitted (least squares in log-log) to cantilevers measured on this machine class (2 cores,
the default OpenBLAS, nothing else running; ``benchmarks/scale.py`` and its ``--compare``):
shift-invert with CHOLMOD 2.55 s / 4.95 s / 9.57 s / ~100 s at 24,336 / 37,800 / 55,488 / 158,976
DOFs; LOBPCG + smoothed-aggregation AMG with scipy's products 2.54 s / 4.57 s / 11.5 s / 85.7 s at
24,336 / 55,488 / 158,976 / 931,896 DOFs (2026-11-23), and with the compiled row-parallel products
(``"lobpcg-numba"``, used when numba is installed) 2.42 s / 9.4-10.2 s at 37,800 / 158,976 DOFs
(2026-11-24). The factorization's cost grows with ~n^2, LOBPCG's with ~n; they cross near 24,000
DOFs (~18,000 with numba). LOBPCG's cost also grows with its block (:func:`~sc_fem.fem.fill.lobpcg_block`)."""


LOBPCG_OVERHEAD = 0.15
"""Seconds LOBPCG + AMG takes for 6 pairs beyond :data:`SPEED_MODEL`'s power law (the hierarchy's
set-up and each iteration's Python work), without a fill analysis: 0.17 s for 8 pairs of a 432-DOF
box, 0.33 s for 16."""

def predicted_seconds(method: str, n: int, k: int, analysis: FillAnalysis | None = None) -> float:
    """Seconds predicted for ``k`` modes of ``n`` free DOFs.

    Parameters
    ----------
    method : {"shift-invert", "lobpcg"}
        The solver (LOBPCG: with the compiled products when numba is installed).
    n, k : int
        Free DOFs and eigenpairs.
    analysis : FillAnalysis, optional
        The fill of the shifted matrix (:func:`~sc_fem.fem.fill.analyze_fill`): both are then
        predicted from it (:data:`~sc_fem.fem.fill.FILL_SPEED_MODEL`,
        :data:`~sc_fem.fem.fill.LOBPCG_FILL_MODEL`), else from :data:`SPEED_MODEL`'s power law in ``n``.

    Returns
    -------
    float
        Seconds, set-up included.
    """
    if method == "shift-invert" and analysis is not None:
        return shift_invert_seconds(analysis, k)
    c, p = SPEED_MODEL["lobpcg-numba" if method == "lobpcg" and available() else method]
    if method != "lobpcg":
        return c * (max(n, 1) / 7776.0) ** p
    if analysis is None:                      # the power law: fitted to 6 pairs, scaled by k
        return (c * (max(n, 1) / 7776.0) ** p + LOBPCG_OVERHEAD) * max(k, 6) / 6.0
    return lobpcg_seconds(analysis, k)        # set-up + iterations (from the fill) x their cost


def memory_budget(max_memory: float | None = None) -> float:
    """Bytes the eigensolver may use: ``max_memory``, or half the available memory."""
    return 0.5 * available_memory() if max_memory is None else float(max_memory)


def choose_method(n: int, nnz: int, k: int, max_memory: float | None = None,
                  analysis: FillAnalysis | None = None, lattice: bool = True) -> tuple[str, str]:
    """``("shift-invert" | "lobpcg", reason)``: the one :func:`predicted_seconds` says is faster,
    among those whose memory estimate fits the budget.

    Parameters
    ----------
    n, nnz, k : int
        Free DOFs, nonzeros of ``K`` and eigenpairs.
    max_memory : float, optional
        Budget in bytes; default half the available memory.
    analysis : FillAnalysis, optional
        The fill of ``K - sigma M`` (:func:`~sc_fem.fem.fill.fill_analysis`): shift-invert's time and memory are
        then predicted from it.
    lattice : bool
        The matrices are a trilinear lattice's, which the lattice multigrid preconditions (LOBPCG's
        prediction is calibrated on those); otherwise (higher-order cubes) shift-invert is taken
        whenever it fits (measured: LOBPCG + AMG 3.6x slower on the chair's q3 cubes at 32, and it
        did not converge).

    Returns
    -------
    method : str
    reason : str
        Both predicted times (and what shift-invert's came from) and the memory against the budget.
    """
    budget = memory_budget(max_memory)
    need = factor_memory_estimate(n, nnz, analysis)
    need_l = lobpcg_memory_estimate(n, nnz, k)
    t_si, t_l = predicted_seconds("shift-invert", n, k, analysis), predicted_seconds("lobpcg", n, k, analysis)
    fits_si, fits_l = need <= budget, need_l <= budget
    if not (fits_si or fits_l):
        raise SolverError(f"the eigenproblem with {n:,} DOFs does not fit in memory: a factorization needs "
                          f"~{need / 2**30:.1f} GiB and LOBPCG ~{need_l / 2**30:.1f} GiB, budget "
                          f"{budget / 2**30:.1f} GiB (half the available memory unless max_memory is given: "
                          f"EigenOptions(max_memory=...)); use a coarser resolution or a larger budget")
    fill = (f" (fill nnz(L) {analysis.nnz_l:,}, {analysis.flops / 1e9:.3g} Gflop)" if analysis is not None
            else " (power law in n)")
    times = f"predicted {t_si:.3g} s shift-invert{fill} vs {t_l:.3g} s LOBPCG + AMG"
    if fits_si and (t_si <= t_l or not fits_l or not lattice):
        return "shift-invert", (f"{times}{'' if lattice else '; not a trilinear lattice: no lattice multigrid'}; "
                                f"factorization ~{need / 2**20:,.0f} MiB <= budget {budget / 2**20:,.0f} MiB")
    why = "faster" if fits_si else (f"the factorization would need ~{need / 2**20:,.0f} MiB > budget "
                                    f"{budget / 2**20:,.0f} MiB")
    return "lobpcg", f"{times} ({why}); LOBPCG needs ~{need_l / 2**20:,.0f} MiB"


STATIC_SOLVERS: tuple[str, ...] = ("auto", "direct", "cg-amg")
"""Names accepted by :class:`StaticOptions` ``solver``."""

CG_AMG_MIN_DOFS = 5_000
"""``solver="auto"`` solves ``K u = f`` by CG + AMG from this many free DOFs on, by a sparse
Cholesky factorization below. Measured end to end on this 2-core machine
(``benchmarks/static_speed.py``, CHOLMOD on the system's reference BLAS, 2026-11-25): the
cantilever 0.044 s direct vs 0.064 s CG + AMG at 3,000 DOFs, 0.14 vs 0.09 s at 5,184, 0.34 vs
0.12 s at 8,820; the bunny 0.085 vs 0.073 s at 2,619, 0.28 vs 0.17 s at 5,217, 1.5 vs 0.33 s at
14,325. Below the threshold both take well under a second, and the direct solve has no tolerance."""

AUTO_CG_ITERATIONS = 80
"""``solver="auto"`` gives CG this many iterations; a model that needs more (members one or two
cubes thick, which the AMG preconditions poorly and a factorization fills little) is solved
directly instead, when the factorization fits in memory. Measured at tol 1e-8: compact shapes
(bunny, cantilever) 16-28 iterations, the chair 43-53 (CG + AMG 1.3 s vs direct 2.4 s at 35,661
DOFs), the cable-stayed bridge 135 at 8,172 DOFs and 315 at 28,968 (4.2 s vs direct 1.0 s)."""


@dataclass(frozen=True)
class StaticOptions:
    """How :func:`sc_fem.solve_static` solves ``K u = f``.

    Parameters
    ----------
    solver : {"auto", "direct", "cg-amg"}
        ``"direct"``: sparse Cholesky (:func:`sc_fem.fem.linsolve.factorize`); ``"cg-amg"``:
        conjugate gradients preconditioned by a smoothed-aggregation AMG V-cycle
        (:class:`sc_fem.fem.multigrid.LatticeAMG`); ``"auto"`` (:func:`choose_static_solver`): CG +
        AMG from :data:`CG_AMG_MIN_DOFS` free DOFs on for trilinear cubes, else direct, and direct
        after all if CG has not converged within :data:`AUTO_CG_ITERATIONS` iterations and the
        factorization fits in memory.
    backend : {"auto", "cholmod", "cholespy", "splu"}
        Factorization backend of the direct solve.
    tol : float
        CG stops at ``||K u - f|| <= tol ||f||``. The default 1e-8 gave displacements within
        1e-9 (relative 2-norm) of the direct solve on the bunny, chair and cantilever, 5e-9 on the
        bridge's one-cube cables (``benchmarks/static_speed.py``).
    maxiter : int
        Largest number of CG iterations; beyond it the solve fails (:class:`~sc_fem.SolverError`,
        naming the residual reached), or with ``"auto"`` falls back to the direct solve.
    max_memory : float, optional
        Bytes a fallback factorization may use; default half the available memory.
    """

    solver: str = "auto"
    backend: str = "auto"
    tol: float = 1e-8
    maxiter: int = 500
    max_memory: float | None = None

    def __post_init__(self) -> None:
        if self.solver not in STATIC_SOLVERS:
            raise InputError(f"static solver must be one of {list(STATIC_SOLVERS)}, got {self.solver!r}")
        if self.backend not in ("auto", *BACKENDS):
            raise InputError(f"backend must be one of {['auto', *BACKENDS]}, got {self.backend!r}")
        tol = positive_scalar(self.tol, "tol")
        if not tol < 1.0:
            raise InputError(f"tol must be a relative residual below 1, got {tol!r}")
        object.__setattr__(self, "tol", tol)
        object.__setattr__(self, "maxiter", positive_int(self.maxiter, "maxiter"))
        if self.max_memory is not None:
            object.__setattr__(self, "max_memory", positive_scalar(self.max_memory, "max_memory"))

    @classmethod
    def coerce(cls, value: StaticOptions | str | None) -> StaticOptions:
        """``None`` (defaults), a StaticOptions, or a solver name (``"cg-amg"``); on
        :class:`DynamicOptions` (which inherits it) the same, giving DynamicOptions.

        Parameters
        ----------
        value : StaticOptions, str or None
            The options, a solver name (the ``solver`` field) or ``None`` for the defaults.

        Returns
        -------
        StaticOptions
            ``value`` itself when it is one, else new options.
        """
        return _coerce(cls, value, "solver")


def choose_static_solver(n: int, nnz: int, solver: str = "auto", *, lattice: bool = True,
                         max_memory: float | None = None, min_dofs: int | None = None) -> tuple[str, str]:
    """``("direct" | "cg-amg", reason)`` for ``K u = f`` with ``n`` free DOFs and ``nnz`` nonzeros.

    Parameters
    ----------
    n, nnz : int
        Size and nonzeros of the reduced stiffness.
    solver : {"auto", "direct", "cg-amg"}
        A requested solver is returned as it is.
    lattice : bool
        Trilinear cubes (the AMG's lattice aggregates apply); ``"auto"`` keeps higher-order cubes
        on the direct solve.
    max_memory : float, optional
        Budget in bytes (default half the available memory): a factorization estimated above it
        is not chosen below :data:`CG_AMG_MIN_DOFS` either.
    min_dofs : int, optional
        CG + AMG from this many DOFs on (default :data:`CG_AMG_MIN_DOFS`).

    Returns
    -------
    solver : str
    reason : str
    """
    if solver != "auto":
        return solver, "requested"
    if not lattice:
        return "direct", "higher-order cubes: direct (the AMG is tuned for trilinear cubes)"
    min_dofs = CG_AMG_MIN_DOFS if min_dofs is None else min_dofs
    need, budget = factor_memory_estimate(n, nnz), memory_budget(max_memory)
    if n >= min_dofs:
        return "cg-amg", f"{n:,} DOFs >= {min_dofs:,}: CG + AMG"
    if need > budget:
        return "cg-amg", (f"the factorization would need ~{need / 2**20:,.0f} MiB > budget "
                          f"{budget / 2**20:,.0f} MiB: CG + AMG")
    return "direct", f"{n:,} DOFs < {min_dofs:,}: direct"


DYNAMIC_CG_MIN_DOFS = 100_000
"""The implicit integrators' ``solver="auto"`` (:class:`DynamicOptions`) solves their effective
matrices by CG + AMG from this many free DOFs on, by a sparse Cholesky factorization below. Far
higher than :data:`CG_AMG_MIN_DOFS`: one factorization serves every step of a linear run, and a
back-solve costs a tenth of a step's CG (~20 iterations to the default tol). Measured
(``benchmarks/newmark_speed.py``, 60 steps of the clamped bunny, CHOLMOD on the reference BLAS,
2 shared cores, 2026-11-25): 30,171 DOFs direct 16.9 s (45 ms/step) vs CG + AMG 34.2 s
(518 ms/step); 90,036 DOFs (r48) direct 167 s (102 s factorizing, 283 ms/step) vs 143 s
(2.3 s/step): CG wins there for runs below ~70 steps, and by more as the factorization grows
(~n^2) faster than the steps (~n); its memory is the other reason (a factorization over budget is
never chosen)."""

DYNAMIC_CG_ITERATIONS = 100
"""``solver="auto"``: a step's CG that has not converged in this many iterations (after one
re-setup of the AMG on the current matrix) is replaced by the direct solve for the rest of the run,
when the factorization fits in memory."""


@dataclass(frozen=True)
class DynamicOptions(StaticOptions):
    """How the implicit integrators (:class:`~sc_fem.dynamics.newmark.Newmark`, its corotational and
    IPC variants) solve their effective matrices ``S x = r`` every step
    (:class:`sc_fem.fem.linsolve.SystemSolver`): the fields of :class:`StaticOptions`.

    Parameters
    ----------
    solver : {"auto", "direct", "cg-amg"}
        ``"auto"`` (:func:`choose_dynamic_solver`): CG + AMG from :data:`DYNAMIC_CG_MIN_DOFS` free
        DOFs on, else direct; and direct for the rest of the run when a CG solve has not converged
        within :data:`DYNAMIC_CG_ITERATIONS` iterations and the factorization fits in memory.
    backend : {"auto", "cholmod", "cholespy", "splu"}
        Factorization backend of the direct solve.
    tol : float
        CG stops at ``||S x - r|| <= tol ||r||`` (``r`` a step's residual force). Default 1e-12,
        tighter than the static solve's: on the chair at r16 (thin members, near-static steps)
        Newmark ended 100 steps of 5 ms 2.6e-4 / 3.9e-6 / 2.4e-7 / 1.4e-8 (relative) off the direct
        trajectory with 1e-8 / 1e-10 / 1e-11 / 1e-12, at 44 / 58 / 66 / 71 CG iterations per step
        (``tests/test_dynamics_iterative.py`` holds every model it runs to 1e-6 over 1 s).
    maxiter : int
        Largest number of CG iterations of ``"cg-amg"``; beyond it :class:`~sc_fem.SolverError`.
    max_memory : float, optional
        Bytes a (fallback) factorization may use; default half the available memory.
    """

    tol: float = 1e-12

    def solver_for(self, A, *, near_null=None, aggregates=None):
        """The :class:`~sc_fem.fem.linsolve.SystemSolver` of ``A`` these options choose
        (:func:`choose_dynamic_solver`; ``"auto"``: CG limited to :data:`DYNAMIC_CG_ITERATIONS`, then
        direct for good, when the factorization fits in memory; when it does not, CG has no way out
        and may take ``maxiter`` iterations).

        Parameters
        ----------
        A : scipy.sparse matrix, shape (n, n)
            Symmetric positive definite (e.g. an effective matrix, kg).
        near_null, aggregates : ndarray, optional
            The AMG's near-null space (n, k) and finest aggregates (n // 3,).

        Returns
        -------
        SystemSolver
        """
        n, nnz = A.shape[0], A.nnz
        kind, reason = choose_dynamic_solver(n, nnz, self.solver, max_memory=self.max_memory)
        need, budget = factor_memory_estimate(n, nnz), memory_budget(self.max_memory)
        auto = self.solver == "auto"
        fallback = "solved directly from then on" if auto and need <= budget else None
        hint = ("use solver='direct' (or 'auto' to fall back to it), or raise maxiter / tol (DynamicOptions)"
                if not auto else f"the direct solve would need ~{need / 2**30:.1f} GiB > budget "
                f"{budget / 2**30:.1f} GiB")
        return SystemSolver(A, kind, reason=reason, tol=self.tol, backend=self.backend, fallback=fallback,
                            hint=hint, maxiter=min(self.maxiter, DYNAMIC_CG_ITERATIONS) if fallback else self.maxiter,
                            near_null=near_null, aggregates=aggregates)


def choose_dynamic_solver(n: int, nnz: int, solver: str = "auto", *, max_memory: float | None = None
                          ) -> tuple[str, str]:
    """``("direct" | "cg-amg", reason)`` for the effective matrix (``n`` free DOFs, ``nnz`` nonzeros)
    of an implicit time integration: :func:`choose_static_solver` with the threshold
    :data:`DYNAMIC_CG_MIN_DOFS`.

    Parameters
    ----------
    n, nnz : int
        Size and nonzeros of the effective matrix.
    solver : {"auto", "direct", "cg-amg"}
        A requested solver is returned as it is.
    max_memory : float, optional
        Budget in bytes (default half the available memory).

    Returns
    -------
    solver : str
    reason : str
    """
    return choose_static_solver(n, nnz, solver, max_memory=max_memory, min_dofs=DYNAMIC_CG_MIN_DOFS)
