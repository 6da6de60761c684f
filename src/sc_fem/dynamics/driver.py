"""Time integration of the cube lattice: a common interface, several methods, one driver.

Methods (one module each; all step a :class:`~sc_fem.dynamics.state.State` and are subclasses of
:class:`~sc_fem.dynamics.base.TimeIntegrator`), registered by name in :data:`METHODS`:

==================  ======================================================================
``"newmark"``       :class:`~sc_fem.dynamics.newmark.Newmark` -- implicit Newmark-beta
                    (average acceleration by default; ``gamma > 1/2`` or HHT ``alpha`` for
                    numerical damping), Rayleigh damping; linear: one factorization and a
                    back-solve per step, or CG + AMG on large models (``solver=``).
``"corotational"``  :class:`~sc_fem.dynamics.corotational.Corotational` -- the same scheme on
                    the corotational (warped-stiffness) model for large rotations.
``"central"``       :class:`~sc_fem.dynamics.central.CentralDifference` -- explicit central
                    differences with lumped mass, stable for ``dt <= dt_crit = 2 / omega_max``.
``"xpbd"``          :class:`~sc_fem.dynamics.xpbd_integrator.XPBDIntegrator` -- XPBD
                    substeps (:class:`~sc_fem.dynamics.xpbd.XPBDSolver`); gravity and fixed
                    nodes only.
``"ipc"``           :class:`~sc_fem.dynamics.ipc.IPC` -- backward Euler as the minimisation of
                    the incremental potential with barrier contact and friction on the source
                    mesh (stable at any ``dt``, never interpenetrating); linear backward Euler
                    (one back-solve) while nothing is within the contact distance.
==================  ======================================================================

Each class declares what it supports (:attr:`~sc_fem.dynamics.base.TimeIntegrator.supports`) and
its default step (:attr:`~sc_fem.dynamics.base.TimeIntegrator.steps_per_frame`). Loads (gravity,
forces and pressures on the source mesh) are in :mod:`.loads`, obstacles (ground, sphere, box) in
:mod:`.contact` (projected after each step) and :mod:`.barrier` (inside the step of :mod:`.ipc`).
:func:`simulate` is the driver: a generator of states that computes the energy of each, and stops
with :class:`~sc_fem.errors.InstabilityError` (naming the step and ``dt_crit``) when the run blows
up. :func:`record` collects a run into a :class:`Recording`.

Units: SI. Displacements ``u`` in metres at the lattice nodes, shape (m, 3).
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field, replace
from typing import Any, Iterator

import numpy as np

from .._progress import stage_bar
from ..errors import InputError, InstabilityError
from ..lattice.cubes import CubeModel
from .base import TimeIntegrator
from .central import CentralDifference
from .corotational import Corotational
from .ipc import IPC
from .newmark import Newmark
from .state import State
from .xpbd_integrator import XPBDIntegrator

METHODS: dict[str, type[TimeIntegrator]] = {cls.name: cls for cls in (Newmark, Corotational, CentralDifference,
                                                                      XPBDIntegrator, IPC)}
"""The methods by name: what :func:`make_integrator` (and ``sc-fem simulate --method``) accepts."""


def make_integrator(method: str, model: CubeModel, dt: float, **kw: Any) -> TimeIntegrator:
    """Build the integrator ``method`` for ``model`` with step ``dt``.

    Parameters
    ----------
    method : str
        A key of :data:`METHODS`: ``"newmark"``, ``"corotational"``, ``"central"``, ``"xpbd"``, ``"ipc"``.
    model : CubeModel
    dt : float
        Time step, s.
    **kw
        Go to the class (``fixed_nodes``, ``loads``, ``contact``, ``rayleigh``, ``beta``, ``gamma``,
        ``alpha``, ``element``, ``substeps``, ...).

    Returns
    -------
    TimeIntegrator
        An instance of ``METHODS[method]``.
    """
    cls = METHODS.get(method) if isinstance(method, str) else None
    if cls is None:
        raise InputError(f"method must be one of {list(METHODS)}, got {method!r}")
    return cls(model, dt, **kw)


def _blowup_message(integ, state_time: float, step: int, why: str) -> str:
    try:
        dtc = float(integ.dt_crit)
        crit = f"dt_crit = {dtc:.4g} s (dt / dt_crit = {integ.dt / dtc:.3g})"
    except Exception as exc:  # noqa: BLE001 - the message must still be raised
        crit = f"dt_crit could not be computed ({exc})"
    hint = integ.blowup_hint() if isinstance(integ, TimeIntegrator) else "reduce dt or add damping"
    return (f"{integ.name} blew up at step {step} (t = {state_time:.6g} s, dt = {integ.dt:.4g} s): {why}; "
            f"explicit stability limit {crit}; {hint}. Nothing was written.")


def simulate(integrator: TimeIntegrator, n_steps: int, *, every: int = 1, check: bool = True,
             growth: float = 10.0, progress: bool = False) -> Iterator[State]:
    """Run ``integrator`` for ``n_steps`` steps, yielding states with their energy filled in.

    Yields the initial state, then every ``every``-th state and always the last one; each with
    its energy by kind (``parts``) and the work the loads other than gravity (whose potential is
    in the energy) have done since the start (``work``, J, trapezoidal rule over every step: ``sum 1/2 (f_k + f_k+1) . (u_k+1 - u_k)``), so that
    ``energy - energy_0 - work`` is the energy the run created (> 0) or dissipated (< 0).

    Blow-up check (``check=True``): the run stops with
    :class:`~sc_fem.errors.InstabilityError` (naming the step, the time and ``dt_crit``) when
    the state becomes non-finite or the mechanical energy ``T + U`` exceeds
    ``growth * (T_0 + U_0 + |W_ext| + |V_g|)``, ``V_g`` the gravity potential. A stable run
    satisfies ``T + U <= T_0 + U_0 + W_ext - V_g`` (energy balance), so this only fires on
    runaway growth. With ``check=False`` the energy is evaluated only for the yielded states.

    Parameters
    ----------
    integrator : TimeIntegrator
        Stepped in place.
    n_steps : int
        Steps of ``integrator.dt`` to take (>= 0).
    every : int
        Yield every ``every``-th state (and the last).
    check : bool
        Check for blow-up after every step.
    growth : float
        Blow-up threshold, a multiple of the initial energy scale (see above).
    progress : bool
        Show a progress bar on stderr (:func:`sc_fem._progress.stage_bar`; ``False`` also keeps
        the stages inside a step, e.g. a long re-assembly, from drawing theirs).

    Yields
    ------
    State
        With ``energy``, ``mechanical`` (J), ``parts`` and ``work`` (J) filled in.

    Raises
    ------
    InstabilityError
        The run blew up (``check=True``).
    """
    n_steps = int(n_steps)
    every = max(1, int(every))
    if n_steps < 0:
        raise InputError(f"n_steps must be >= 0, got {n_steps}")
    st = integrator.state
    e = integrator.energy()
    e0 = e.mechanical
    work = 0.0
    loads = integrator.loads
    f_prev = _nonconservative(loads, st.time)
    u_prev = st.u
    yield replace(st, energy=e.total, mechanical=e.mechanical, parts=e, work=0.0)
    bar = stage_bar(integrator.name, n_steps, unit="step", enabled=progress)
    try:
        for k in range(1, n_steps + 1):
            out = k % every == 0 or k == n_steps
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                st = integrator.step()
                finite = bool(np.all(np.isfinite(st.u)) and np.all(np.isfinite(st.v)))
                if finite:
                    f = _nonconservative(loads, st.time)
                    work += 0.5 * float(np.sum((f + f_prev) * (st.u - u_prev)))
                    f_prev, u_prev = f, st.u
                if check or out:
                    e = integrator.energy()
            if check:
                if not finite or not math.isfinite(e.total):
                    raise InstabilityError(_blowup_message(integrator, st.time, k, "non-finite displacements"))
                bound = growth * (e0 + abs(work) + abs(e.gravity))
                if e.mechanical > bound + 1e-300:
                    raise InstabilityError(_blowup_message(
                        integrator, st.time, k,
                        f"energy {e.mechanical:.4g} J grew beyond {growth:g} x (initial energy + load work + "
                        f"gravity potential) = {bound:.4g} J"))
            bar.update()
            if out:
                yield replace(st, energy=e.total, mechanical=e.mechanical, parts=e, work=work)
    finally:
        bar.close()


def _nonconservative(loads, t: float) -> np.ndarray:
    """The node forces at ``t`` whose work is counted (N): all loads but gravity, whose potential
    is part of the energy."""
    return loads.force(t) - loads.gravity_force


@dataclass(frozen=True, eq=False)
class Recording:
    """A recorded run (see :func:`record`).

    Attributes
    ----------
    times : ndarray, shape (T,)
        Seconds.
    u : ndarray, shape (T, m, 3)
        Node displacements, m.
    energy : ndarray, shape (T,)
        Total energy (kinetic + elastic + gravity + contact), J.
    mechanical : ndarray, shape (T,)
        Kinetic + elastic energy, J.
    parts : dict of str to ndarray (T,)
        The energy by kind, J: ``kinetic``, ``elastic``, ``gravity``, ``contact``, and ``work``
        (done by the loads since the start) and ``dissipated`` (``energy_0 + work - energy``:
        damping, friction, the integrator's numerical damping; < 0 is energy the run created).
    points : ndarray, shape (T, k, 3) or None
        Positions of the embedded points (source-mesh vertices), model units.
    n_steps : int
        Steps taken.
    seconds : float
        Wall time of the stepping, s (excludes the set-up in ``setup_seconds``).
    setup_seconds : float
        Wall time of the integrator's assembly.
    method : str
    dt : float
    max_contact_depth : float
        Largest vertex penetration depth (model units) after any step (-inf without contact).
    """

    times: np.ndarray
    u: np.ndarray
    energy: np.ndarray
    mechanical: np.ndarray
    points: np.ndarray | None
    n_steps: int
    seconds: float
    setup_seconds: float
    method: str
    dt: float
    max_contact_depth: float = -math.inf
    info: dict = field(default_factory=dict)
    parts: dict = field(default_factory=dict)

    @property
    def seconds_per_step(self) -> float:
        return self.seconds / max(self.n_steps, 1)

    @property
    def energy_scale(self) -> float:
        """The energy the run handles, J: the largest of ``T + U``, ``|work|`` and the gravity
        potential's change over the run (0 when nothing moves)."""
        vals = [float(np.max(np.abs(self.mechanical)))] if len(self.mechanical) else [0.0]
        for k in ("work", "gravity"):
            if k in self.parts and len(self.parts[k]):
                vals.append(float(np.max(np.abs(self.parts[k] - self.parts[k][0]))))
        return max(vals)

    def _created(self) -> np.ndarray:
        """Energy created per frame, J: ``E - E_0 - work`` (what was put in not counted)."""
        work = self.parts.get("work", np.zeros_like(self.energy))
        return self.energy - self.energy[0] - work

    @property
    def energy_drift(self) -> float:
        """``(E_end - E_0 - W) / scale`` (:attr:`energy_scale`): the energy created (> 0) or
        dissipated (< 0) by the end, beyond the work ``W`` the loads put in; 0 when nothing moves."""
        scale = self.energy_scale
        return 0.0 if scale == 0 or not len(self.energy) else float(self._created()[-1] / scale)

    @property
    def energy_gain(self) -> float:
        """The most energy the run ever created beyond what was put in, as a fraction of
        :attr:`energy_scale` (>= 0; a stable, dissipative run stays near 0)."""
        scale = self.energy_scale
        return 0.0 if scale == 0 or not len(self.energy) else max(0.0, float(self._created().max() / scale))


def record(integrator, n_steps: int, *, scene=None, every: int = 1, check: bool = True, growth: float = 10.0,
           progress: bool = False, keep_u: bool = True) -> Recording:
    """Run :func:`simulate` and collect the frames.

    Parameters
    ----------
    scene : sc_fem.Scene, optional
        The positions of its source vertices (``Scene.vertex_positions``, model units) are recorded.
    keep_u : bool
        Keep the node displacements of every frame (memory ``T * m * 3`` floats).
    """
    t0 = _time.perf_counter()
    times, us, es, pts, mech, parts = [], [], [], [], [], []
    for st in simulate(integrator, n_steps, every=every, check=check, growth=growth, progress=progress):
        times.append(st.time)
        es.append(st.energy)
        mech.append(st.mechanical)
        p = st.parts
        parts.append((p.kinetic, p.elastic, p.gravity, p.contact, st.work))
        if keep_u:
            us.append(st.u)
        if scene is not None:
            pts.append(scene.vertex_positions(st.u))
    secs = _time.perf_counter() - t0
    m = integrator.model.n_nodes
    return Recording(times=np.asarray(times), u=np.asarray(us) if keep_u else np.zeros((0, m, 3)),
                     energy=np.asarray(es), mechanical=np.asarray(mech), points=np.asarray(pts) if scene is not None else None,
                     n_steps=int(n_steps), seconds=secs, setup_seconds=getattr(integrator, "setup_seconds", 0.0),
                     method=integrator.name, dt=integrator.dt,
                     max_contact_depth=float(getattr(integrator, "max_contact_depth", -math.inf)),
                     info=dict(getattr(integrator, "info", {})), parts=_parts(np.asarray(parts), np.asarray(es)))


def _parts(rows: np.ndarray, energy: np.ndarray) -> dict:
    """The energy-by-kind arrays of a recording from rows (kinetic, elastic, gravity, contact, work)."""
    rows = rows.reshape(-1, 5)
    out = dict(zip(("kinetic", "elastic", "gravity", "contact", "work"), rows.T.copy()))
    out["dissipated"] = (energy[0] + out["work"] - energy) if len(energy) else np.zeros(0)
    return out


__all__ = ["METHODS", "make_integrator", "simulate", "record", "Recording"]
