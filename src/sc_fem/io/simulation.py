"""Simulating a mesh and writing its vertex animation (``sc-fem simulate``): :func:`simulate_to_file`.

The job is :func:`sc_fem.dynamics.job.run_simulation` on a :class:`~sc_fem.Scene`, written by
:func:`sc_fem.io.animation.write_animation` (``.npz``, ``.xdmf``, ``.mp4``, ``.gif``);
:func:`run_summary` describes a run.
"""

from __future__ import annotations

import warnings
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np

from .._progress import stage_bar
from ..dynamics.job import run_simulation
from ..errors import ScFemWarning
from ..scene import Scene
from .animation import keeps_lattice, write_animation
from .paraview import lattice_xdmf_path
from .report import JobResult, stage, table
from .voxelize import model_summary


def energy_line(rec: Any) -> str:
    """The energy of a run's last frame by kind, J.

    Parameters
    ----------
    rec : sc_fem.dynamics.Recording

    Returns
    -------
    str
    """
    p = rec.parts
    keys = ("kinetic", "elastic", "gravity", "contact", "work", "dissipated")
    return ", ".join(f"{k} {p[k][-1]:.4g}" for k in keys if k in p and len(p[k])) + " J"


def run_summary(rec: Any) -> str:
    """A run described for a person: method, steps, time per step, energy, displacement, contact.

    Parameters
    ----------
    rec : sc_fem.dynamics.Recording
        A run of :func:`sc_fem.dynamics.job.run_simulation`.

    Returns
    -------
    str
        Aligned ``key  value`` lines.
    """
    info = rec.info
    disp = np.linalg.norm(rec.points - rec.points[0], axis=2).max() if len(rec.points) else 0.0
    kind = (f"{info['substeps']} substeps x {info['iterations']} iterations, {info['constraints']}"
            if info["method"] == "xpbd" else ("implicit" if info["implicit"] else "explicit"))
    n, dt = info["n_steps"], info["dt"]
    rows = [("method", f"{info['method']} ({kind})"),
            ("steps", f"{n:,} x {dt:g} s = {n * dt:g} s ({len(rec.times)} frames)"),
            ("time per step", f"{1e3 * rec.seconds_per_step:.3g} ms (setup {rec.setup_seconds:.3g} s)"),
            ("energy at the end", energy_line(rec)),
            ("energy created", f"{rec.energy_gain:.3e} of the energy scale {rec.energy_scale:.4g} J at most "
                               "(beyond the loads' work; 0 for a stable run)"),
            ("max vertex displacement", f"{disp:.4g} model units")]
    if info["dt_crit"] is not None:
        rows.append(("dt / dt_crit", f"{dt / info['dt_crit']:.3g} (dt_crit = {info['dt_crit']:.4g} s)"))
    if info.get("newton_iterations") is not None and info["method"] == "ipc":
        rows.append(("contact", f"{info['contact_steps']} steps in contact, {info['newton_iterations']} Newton "
                                f"iterations, friction {info['friction']}, dhat {info['dhat']:.3g} model units, "
                                "no vertex ever through an obstacle"))
    if info["contact_tol"] is not None:
        rows.append(("max contact depth", f"{max(rec.max_contact_depth, 0.0):.3g} model units "
                                          f"(tolerance {info['contact_tol']:.3g})"))
    return table(rows)


def simulate_to_file(mesh: Any, output: str | Path, *, duration: float, fps: float = 50.0, voxel: Any = None,
                     fix: Any = None, fix_vertices: Any = None, exaggerate: float = 1.0, verbose: bool = False,
                     progress: bool = False, **options: Any) -> JobResult:
    """Voxelize ``mesh``, simulate it and write the source mesh's vertex animation.

    Parameters
    ----------
    mesh : path, ``"builtin:NAME"`` or anything :func:`sc_fem.load_mesh` takes
    output : str or Path
        ``.npz`` (:func:`sc_fem.io.animation.save_animation`), ``.xdmf`` (ParaView; with the cube
        lattice and its strain energy density in ``NAME_lattice.xdmf`` beside it,
        :mod:`sc_fem.io.paraview`) or a rendered ``.mp4`` / ``.gif``.
    duration : float
        Simulated time, s.
    fps : float
        Frames per second recorded (and of a video, at most 30).
    voxel : VoxelOptions or dict, optional
        How to voxelize (:class:`sc_fem.VoxelOptions`).
    fix, fix_vertices : optional
        Fixed nodes and source vertices (:meth:`sc_fem.Scene.from_mesh`).
    exaggerate : float
        Factor on the displacements of a rendered video only.
    verbose : bool
        Print every stage (voxelize, simulate, write) and its time on stderr.
    progress : bool
        Progress bars of the stages (voxelize, assembly, the run, the rendering) on stderr; False: none.
    **options
        Keyword arguments of :func:`sc_fem.dynamics.job.run_simulation` (``dt``, ``method``,
        ``gravity``, ``ground``, ``impulses``, ``newmark``, ``xpbd``, ``up``, ...).

    Returns
    -------
    JobResult
        ``result`` the :class:`~sc_fem.dynamics.Recording`; the summary is the model's
        (:func:`sc_fem.io.voxelize.model_summary`), the run's (:func:`run_summary`) and the files
        written (``written``: the output, then the lattice series of an ``.xdmf`` when written).

    Warns
    -----
    ScFemWarning
        What the run reports in ``info["warnings"]`` (e.g. energy created with nothing feeding it).
    """
    timings: dict = {}
    with nullcontext() if progress else stage_bar("simulate", enabled=False):     # False: no bar in any stage
        with stage("voxelize", timings, verbose):
            scene = Scene.from_mesh(mesh, voxel, fix=fix, fix_vertices=fix_vertices)
        with stage("simulate", timings, verbose):
            rec = run_simulation(scene, duration=duration, fps=fps, progress=progress, **options)
        with stage("write", timings, verbose):
            path = write_animation(output, scene, rec, exaggerate=exaggerate, fps=fps, progress=progress)
    for w in rec.info["warnings"]:
        warnings.warn(w, ScFemWarning, stacklevel=2)
    written, wrote = [path], f"wrote {Path(output)}"
    if Path(path).suffix.lower() == ".xdmf" and keeps_lattice(rec):
        written.append(lattice_xdmf_path(path))
        wrote += f" and {written[1]} (the cube lattice: displacement, strain_energy_density per cube, J/m^3)"
    return JobResult(written=written, result=rec,
                     text=f"{model_summary(scene.model)}\n{run_summary(rec)}\n{wrote}")
