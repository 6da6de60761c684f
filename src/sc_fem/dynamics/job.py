"""One simulation job from a :class:`~sc_fem.Scene` and plain options: what ``sc-fem simulate``
runs, callable from Python with the same meaning (loads, obstacles, impulses, method)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from .._validate import as_float_array, positive_scalar
from ..errors import InputError
from ..fem.elements import DEFAULT_ELEMENT
from ..fem.options import DynamicOptions
from ..scene import Scene
from ..units import up_axis
from .contact import obstacles_from
from .driver import METHODS, make_integrator, record
from .loads import Gravity, LoadSet, VertexForce, half_sine, impulse_nodes as spread_impulses
from .newmark import NewmarkOptions
from .xpbd import XPBDOptions

LATTICE_TRACK_BYTES = 256 * 2**20
"""Largest recorded node-displacement history (bytes) that a run keeps for its animation file."""

ENERGY_GAIN_WARN = 0.05
"""Energy created beyond the loads' work (fraction of :attr:`Recording.energy_scale`) past which a
run is flagged."""


OPTIONS = {"gust": "loads", "impulse": "impulses", "velocity": "velocity", "ground": "contact",
           "sphere": "contact", "box": "contact", "rayleigh": "rayleigh", "beta/gamma/hht-alpha": "newmark",
           "substeps/iterations/constraints/xpbd-damping": "substeps", "linear solver": "solver"}
"""The options of :func:`run_simulation` that a method must support, and the feature
(:attr:`~sc_fem.dynamics.base.TimeIntegrator.supports`) each needs; gravity and fixed nodes every
method takes."""

_SCENE_OPTIONS = ("gust", "impulse", "velocity", "ground", "sphere", "box", "rayleigh")


def check_supported(method: str, cls, requested) -> None:
    """Refuse the :data:`OPTIONS` in ``requested`` that the method class ``cls`` does not support."""
    unsupported = [o for o in requested if OPTIONS[o] not in cls.supports]
    if unsupported:
        ok = [o for o in _SCENE_OPTIONS if OPTIONS[o] in cls.supports]
        what = "gravity and fixed nodes only" if not ok else f"gravity, fixed nodes, {', '.join(ok[:-1])} and {ok[-1]}"
        raise InputError(f"method {method!r} supports {what}, not {', '.join(unsupported)}")


def impulse_nodes(scene, impulses) -> np.ndarray | None:
    """Impulses ``[(vertex, Jx, Jy, Jz), ...]`` (N s) on source vertices as node impulses, spread
    over the mass around each vertex (:func:`sc_fem.dynamics.loads.impulse_nodes`)."""
    if impulses is None or not len(impulses):
        return None
    n = scene.rest_vertices.shape[0]
    arr = as_float_array(impulses, "impulses")
    if arr.size % 4:
        raise InputError(f"impulses are (vertex, Jx, Jy, Jz) quadruples, got {arr.size} numbers")
    arr = arr.reshape(-1, 4)
    idx = arr[:, 0]
    bad = ~(np.mod(idx, 1) == 0) | (idx < 0) | (idx >= n)
    if np.any(bad):
        raise InputError(f"impulse VERTEX must be a vertex index in [0, {n}), got {idx[bad][0]:g}")
    return spread_impulses(scene.model, scene.rest_vertices, idx.astype(np.int64), arr[:, 1:])


def default_dt(method: str, fps: float) -> float:
    """The time step (s) a run takes when none is given: ``1 / (fps * steps_per_frame)`` of the method
    (:attr:`~sc_fem.dynamics.base.TimeIntegrator.steps_per_frame`): two steps per recorded frame for
    the implicit methods (stable at any step; the frame rate is what the animation resolves), one
    frame for XPBD (its substeps divide it). Central differences take ``0.9 dt_crit`` instead
    (:func:`run_simulation`; this is the step it starts from)."""
    return 1.0 / (fps * (METHODS[method].steps_per_frame or 2))


def frame_steps(duration: float, dt: float, fps: float) -> tuple[int, int]:
    """The steps of a run and the steps between stored frames: an error unless ``dt`` divides the
    frame step ``1 / fps`` (the frames would be stored at another rate) and the run has a step.

    Parameters
    ----------
    duration, dt : float
        Simulated time and time step, s.
    fps : float
        Frames per second stored.

    Returns
    -------
    n_steps, every : int
    """
    n_steps = int(round(duration / dt))
    if n_steps < 1:
        raise InputError(f"duration {duration:g} s is shorter than one step of dt {dt:g} s")
    ratio = 1.0 / (fps * dt)
    every = max(1, int(round(ratio)))
    if abs(ratio - every) > 1e-6 * ratio:
        raise InputError(f"dt = {dt:.6g} s does not divide the frame step 1/fps = {1 / fps:.6g} s: it is not a whole "
                         f"number of time steps (the frames would be stored at {1 / (every * dt):.6g} fps); give a "
                         f"dt that divides it, e.g. {1 / (fps * every):.6g} s")
    return n_steps, every


def run_simulation(scene, *, duration: float, dt: float | None = None, method: str = "auto", fps: float = 50.0,
                   gravity=None, gust=None, ground=None, sphere=None, box=None, impulses=(),
                   velocity=None, friction: float = 0.3, self_contact: bool = True, rayleigh=(0.0, 0.0), newmark: NewmarkOptions = NewmarkOptions(),
                   xpbd: XPBDOptions = XPBDOptions(), element: str | None = None, up: str = "z",
                   solver: DynamicOptions | str = "auto", progress: bool = False):
    """Simulate ``scene`` for ``duration`` s and record its source vertices.

    Parameters
    ----------
    scene : sc_fem.Scene
    duration : float
        Simulated time, s.
    dt : float, optional
        Time step, s (XPBD: the frame step, split in ``xpbd.substeps``). Default
        (:func:`default_dt`): half a frame for the implicit methods, ``0.9 dt_crit`` for
        ``"central"``, a frame for XPBD.
    method : {"auto", "ipc", "newmark", "corotational", "central", "xpbd"}
        ``"auto"`` (default): ``"ipc"`` (contact inside the implicit step,
        :mod:`sc_fem.dynamics.ipc`) when there is an obstacle, else ``"newmark"``.
        ``"newmark"``/``"corotational"``/``"central"`` with obstacles project the vertices out
        after every step (:mod:`sc_fem.dynamics.contact`), which can feed energy into the model.
    fps : float
        Frames per second recorded (the recorded frames are ``round(1 / (fps dt))`` steps apart;
        a ``dt`` that does not divide the frame step is an error).
    gravity : array_like, shape (3,), optional
        Gravitational acceleration, m/s^2 (the type :func:`~sc_fem.fem.static.solve_static` and
        XPBD take); "gravity on" along the model's ``up`` is :func:`sc_fem.units.gravity_down` ``(up)``.
    gust : (Fx, Fy, Fz, seconds), optional
        Total force (N) spread equally over the source vertices, half-sine pulse.
    ground, sphere, box : optional
        Obstacles in model units: the plane at height ``ground`` along ``up``, ``(x, y, z, r)``,
        ``(x0, y0, z0, x1, y1, z1)``.
    impulses : sequence of (vertex, Jx, Jy, Jz)
        Impulses in N s on source vertices at t = 0, each spread over the lattice mass within
        1.5 cube edges of its vertex (:func:`sc_fem.dynamics.loads.impulse_nodes`).
    velocity : (vx, vy, vz), optional
        Initial velocity of the whole model, m/s (a thrown model); impulses add to it.
    friction : float
        Coulomb friction coefficient of the contacts of ``"ipc"`` (default 0.3; 0: frictionless).
    self_contact : bool
        ``"ipc"``: keep each body from passing through itself, with the lattice's outer surface as
        its collision proxy (default True; :class:`~sc_fem.dynamics.barrier.BarrierContact`). Bodies
        (parts of the lattice that share no node) always collide with each other.
    rayleigh : (a0, a1)
        Rayleigh damping ``C = a0 M + a1 K``.
    newmark, xpbd : NewmarkOptions, XPBDOptions
    solver : DynamicOptions or {"auto", "direct", "cg-amg"}
        The implicit methods' linear systems (``"newmark"``, ``"corotational"``, ``"ipc"``):
        sparse Cholesky, or conjugate gradients preconditioned by the lattice multigrid;
        ``"auto"`` (default, :func:`~sc_fem.fem.options.choose_dynamic_solver`) factorizes below
        :data:`~sc_fem.fem.options.DYNAMIC_CG_MIN_DOFS` free DOFs. ``info["linear_solver"]`` says which ran.
    element : str, optional
        Element type (default :data:`sc_fem.DEFAULT_ELEMENT`).
    up : {"x", "y", "z"}
        The model's up axis: gravity points down it, the ground is across it (y-up meshes: "y").

    Returns
    -------
    sc_fem.dynamics.Recording
        With ``points`` (T, n, 3) model units and ``info``: the run's record for the output file,
        and ``info["warnings"]`` (e.g. energy grown with nothing feeding it).
    """
    Scene.check(scene, "sc_fem.dynamics.job.run_simulation", "sc_fem.io.simulation.simulate_to_file(mesh, ...)")
    dt_given = dt

    if method not in ("auto", *METHODS):
        raise InputError(f"method must be one of {['auto', *METHODS]}, got {method!r}")
    duration, fps = positive_scalar(duration, "duration"), positive_scalar(fps, "fps")
    obstacles = obstacles_from(ground, sphere, box, up=up_axis(up))
    if method == "auto":
        method = "ipc" if obstacles else "newmark"
    cls = METHODS[method]
    check_supported(method, cls, [name for name, on in (
        ("gust", gust is not None), ("impulse", impulses is not None and bool(len(impulses))),
        ("velocity", velocity is not None), ("ground", ground is not None), ("sphere", sphere is not None),
        ("box", box is not None), ("rayleigh", any(rayleigh)), ("beta/gamma/hht-alpha", newmark != NewmarkOptions()),
        ("substeps/iterations/constraints/xpbd-damping", xpbd != XPBDOptions()),
        ("linear solver", DynamicOptions.coerce(solver) != DynamicOptions())) if on])
    element = DEFAULT_ELEMENT if element is None else element
    model, verts = scene.model, scene.rest_vertices
    g = None if gravity is None else tuple(as_float_array(gravity, "gravity (m/s^2)", (3,)).tolist())
    dt = default_dt(method, fps) if dt is None else positive_scalar(dt, "dt")
    loads = [Gravity(g)] if g is not None and any(g) else []
    if gust is not None:
        fx, fy, fz, secs = as_float_array(gust, "gust (Fx, Fy, Fz, seconds)", (4,))
        loads.append(VertexForce(np.arange(len(verts)), np.array([fx, fy, fz]) / len(verts), half_sine(secs),
                                 spread="embedding"))
    kw = {"fixed_nodes": scene.fixed_nodes,
          "loads": LoadSet(model, loads, points=verts, faces=scene.faces, W=scene.W)}
    features = cls.supports
    if "element" in features:
        kw["element"] = element
    if "rayleigh" in features:
        kw["rayleigh"] = tuple(rayleigh)
    if velocity is not None:
        kw["v0"] = np.broadcast_to(as_float_array(velocity, "velocity (vx, vy, vz)", (3,)), (model.n_nodes, 3))
    if "contact" in features:
        kw["contact"] = cls.contact_for(model, verts, scene.faces, obstacles, W=scene.W, friction=friction,
                                        self_contact=self_contact)
    if "newmark" in features:
        kw.update(beta=newmark.beta, gamma=newmark.gamma, alpha=newmark.alpha)
    if "solver" in features:
        kw["solver"] = solver
    if "substeps" in features:
        kw.update(substeps=xpbd.substeps, iterations=xpbd.iterations, constraints=xpbd.constraints,
                  damping=xpbd.damping)
    integ = make_integrator(method, model, dt, **kw)
    dtc = None
    if cls.steps_per_frame is None and dt_given is None:    # 0.9 dt_crit, a whole number of steps per frame
        dtc = integ.dt_crit                                 # one eigensolve: the step does not change it
        dt = 1.0 / fps / math.ceil(1.0 / (fps * 0.9 * dtc))
        integ = make_integrator(method, model, dt, **kw)
    J = impulse_nodes(scene, impulses)
    if J is not None:
        integ.set_velocity_from_impulse(J)
    n_steps, every = frame_steps(duration, dt, fps)
    # node displacements go into the animation file (the exact lattice map of ``sc-fem reconstruct``)
    # unless they would take more than LATTICE_TRACK_BYTES of memory
    keep_u = (n_steps // every + 1) * model.n_nodes * 24 <= LATTICE_TRACK_BYTES
    rec = record(integ, n_steps, scene=scene, every=every, progress=progress, keep_u=keep_u)
    if cls.steps_per_frame is None and dtc is None:
        dtc = integ.dt_crit
    warnings = []
    if rec.energy_gain > ENERGY_GAIN_WARN:
        # the loads' work is accounted; damping, friction and contact only take energy out
        warnings.append(f"the run created energy: up to {100 * rec.energy_gain:.3g} % of its energy scale beyond the "
                        f"work of the loads: it is not converged ({integ.convergence_hint})")
    info = {"method": method, "dt": dt, "fps": fps, "duration": duration, "n_steps": n_steps, "source": scene.source,
            "element": element, "material": model.info.get("material", ""), "gravity": g,
            "ground": ground, "up": up, "sphere": None if sphere is None else [float(x) for x in sphere],
            "box": None if box is None else [float(x) for x in box], "rayleigh": [float(x) for x in rayleigh], "hht_alpha": newmark.alpha,
            "dt_crit": dtc, "scale": model.scale, "cubes": model.n_cubes, **rec.info,
            "implicit": bool(integ.implicit), "warnings": warnings,
            "contact_tol": None if getattr(integ, "contact", None) is None else float(integ.contact.tol),
            "friction": friction if "friction" in cls.supports else None,
            "velocity": None if velocity is None else [float(x) for x in velocity]}
    return replace(rec, info=info)
