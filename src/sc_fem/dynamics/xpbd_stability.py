"""Stability of XPBD against the substep length: energy growth, blow-up and error per substep
(used by ``benchmarks/xpbd.py`` and the tests)."""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import numpy as np

from .._validate import as_float_array, positive_scalar
from ..errors import InputError, InstabilityError
from ..lattice.cubes import CubeModel
from .loads import DOWN
from .xpbd import XPBDSolver


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
                    fixed_nodes=None, reference=None, constraints: str = "neohookean", iterations: int = 1,
                    gravity=DOWN, **kw) -> list[StabilityRow]:
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
    fixed_nodes : array_like, optional
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
    duration = positive_scalar(duration, "duration")
    if frame_dt is not None:
        frame_dt = positive_scalar(frame_dt, "frame_dt")
    ref = None
    if reference is not None:
        ref = as_float_array(reference, "reference", (model.n_nodes, 3))
        if not np.linalg.norm(ref) > 0:
            raise InputError("reference is zero everywhere: no displacement to measure an error against")
    rows = []
    for ds in np.atleast_1d(np.asarray(substep_sizes, dtype=float)):
        ds = positive_scalar(float(ds), "substep_sizes")
        n_sub = max(1, int(round((1 / 60 if frame_dt is None else frame_dt) / ds)))
        solver = XPBDSolver(model, ds * n_sub, substeps=n_sub, iterations=iterations, constraints=constraints,
                            fixed_nodes=fixed_nodes, gravity=gravity, **kw)
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
