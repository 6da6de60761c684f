"""Precompute vibration modes into mode files: one mesh, or many on Dask (``sc-fem precompute-modes``).

:func:`precompute_modes` builds the :class:`~sc_fem.Scene` of the mesh and runs :func:`sc_fem.modal`
on it (or :func:`~sc_fem.modes.auto.modal_converged` for the coarsest converged grid:
:func:`mesh_modes`) and writes the mode file, or hands several meshes to :func:`run_batch` (one
:func:`precompute_one` a mesh, on :func:`sc_fem.io.batch.run_tasks`); :func:`precompute_summary`
describes the result.
"""

from __future__ import annotations

import os
import time
import traceback
import warnings
from pathlib import Path
from typing import Any, Iterable

import numpy as np

from ..errors import InputError, ScFemError, ScFemWarning
from ..modes.auto import format_resolution_table, modal_converged
from ..modes.modal import modal
from ..scene import Scene
from .batch import BatchResult, expand_inputs, run_tasks
from .modes import save_modes
from .report import JobResult, stage, table

SUMMARY_FIELDS = ("mesh", "status", "output", "seconds", "cubes", "dofs", "n_modes", "f_min_hz", "f_max_hz", "solver", "error")
"""Columns of a batch's ``summary.csv``."""


def mesh_modes(mesh: Any, *, voxel: Any = None, auto: Any = None, fix: Any = None, fix_vertices: Any = None,
               **request: Any) -> Any:
    """The modes of one mesh, as a job's ``options`` describe them (these keywords).

    Parameters
    ----------
    mesh : path, ``"builtin:NAME"`` or mesh-like
        The source mesh.
    voxel : VoxelOptions or dict, optional
        How it is voxelized (:class:`~sc_fem.lattice.options.VoxelOptions`, the grid included).
    auto : AutoResolution, optional
        Choose the grid instead: :func:`sc_fem.modes.auto.modal_converged` over these resolutions.
    fix : str, FixSpec, callable or list, optional
        Fixed nodes; ``"default"`` = a built-in model's supports.
    fix_vertices : array_like of int, optional
        Source vertices whose cubes are fixed.
    **request
        The keywords of :func:`sc_fem.modes.modal.modal` (``n_modes``, ``damping``, ...).

    Returns
    -------
    ModalBasis
        The modes (Hz, m kg^-1/2) baked onto the mesh.
    """
    if auto is not None:
        return modal_converged(mesh, auto, voxel=voxel, fix=fix, fix_vertices=fix_vertices, **request)
    return modal(Scene.from_mesh(mesh, voxel, fix=fix, fix_vertices=fix_vertices), **request)


def output_name(mesh: str) -> str:
    """Mode-file name of a mesh: ``chair.obj`` -> ``chair.modes.npz``, ``builtin:bridge`` -> ``bridge.modes.npz``."""
    stem = mesh.split(":", 1)[1] if mesh.startswith("builtin:") else Path(mesh).stem
    return f"{stem}.modes.npz"


def precompute_one(mesh: str, output: str, options: dict) -> dict:
    """Compute and save the modes of one mesh; never raises (errors go in the returned row).

    Parameters
    ----------
    mesh : str
        Path or ``builtin:NAME``.
    output : str
        Mode file to write.
    options : dict
        Keyword arguments of :func:`mesh_modes` (``voxel``, ``auto``, ``fix``, ``n_modes``, ...).

    Returns
    -------
    dict
        The mesh's row of the summary (keys :data:`SUMMARY_FIELDS`).
    """
    t0 = time.perf_counter()
    row: dict[str, Any] = {k: "" for k in SUMMARY_FIELDS}
    row.update(mesh=mesh, output=output)
    try:
        basis = mesh_modes(mesh, **dict(options))
        save_modes(basis, output)
        f = basis.frequencies[~basis.rigid]
        row.update(status="ok", cubes=basis.n_cubes, dofs=basis.n_dofs, n_modes=basis.n_modes,
                   f_min_hz=f"{f.min():.6g}" if len(f) else "", f_max_hz=f"{f.max():.6g}" if len(f) else "",
                   solver=f"{basis.eigen.get('method', '')}/{basis.eigen.get('backend', '')}")
    except Exception as exc:  # noqa: BLE001 - one bad mesh must fail alone, with its message
        msg = f"{type(exc).__name__}: {exc}"
        if not isinstance(exc, ScFemError):
            msg += " | " + traceback.format_exc(limit=-2).strip().replace("\n", " / ")[-400:]
        row.update(status="error", error=msg, output="")
    row["seconds"] = f"{time.perf_counter() - t0:.3f}"
    return row


def run_batch(meshes: Iterable[str], out_dir: str | Path, *, options: dict | None = None,
              scheduler: str | None = None, n_workers: int | None = None, processes: bool = True, progress: bool = True,
              expand: bool = True) -> BatchResult:
    """Precompute modes for many meshes, one Dask task per mesh (:func:`precompute_one`).

    Parameters
    ----------
    meshes : iterable of str
        Paths, glob patterns or ``builtin:NAME``.
    out_dir : str or Path
        Folder for ``NAME.modes.npz`` files and ``summary.csv`` (created).
    options : dict, optional
        Keyword arguments of :func:`mesh_modes` (``voxel``, ``auto``, ``fix``, ``n_modes``, ...).
    scheduler, n_workers, processes, progress
        The cluster and the progress bar, as :func:`~sc_fem.io.batch.run_tasks` takes them (default:
        a local cluster of ``min(len(meshes), cpu count)`` worker processes, a bar on stderr).
    expand : bool
        Expand ``meshes`` with :func:`~sc_fem.io.batch.expand_inputs` (``False``: they are already
        expanded paths).

    Returns
    -------
    BatchResult
        One row per mesh (:data:`SUMMARY_FIELDS`), the summary written, the time and the scheduler.

    Raises
    ------
    InputError
        No meshes, ``out_dir`` an existing file, or ``scheduler`` without dask installed.
    BatchInterrupted
        Ctrl-C (a KeyboardInterrupt): the cluster is shut down and the summary written first; it
        lists the mode files completed.
    """
    meshes = expand_inputs(meshes) if expand else [str(m) for m in meshes]
    if not meshes:
        raise InputError("no meshes given")
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"output for several meshes must be a folder, got the file {out}")
    out.mkdir(parents=True, exist_ok=True)
    names = [output_name(m) for m in meshes]
    dup = {n for n in names if names.count(n) > 1}
    if dup:   # chair.obj and chair.stl would overwrite each other
        names = [f"{Path(m).stem}.{Path(m).suffix.lstrip('.') or 'mesh'}.modes.npz" if n in dup else n
                 for m, n in zip(meshes, names)]
    return run_tasks(precompute_one, meshes, [str(out / n) for n in names], out / "summary.csv", options=options,
                     fields=SUMMARY_FIELDS, what="mode files", scheduler=scheduler, n_workers=n_workers,
                     processes=processes, progress=progress)


def precompute_summary(basis: Any, timings: dict) -> str:
    """A precomputation described for a person: sizes, supports, solver, time per stage, frequencies.

    Parameters
    ----------
    basis : ModalBasis
        The modes computed (:func:`sc_fem.modes.modal.modal`).
    timings : dict
        Further stages (name: seconds) to list after the basis's own ``timings``.

    Returns
    -------
    str
        Aligned ``key  value`` lines, then :meth:`ModalBasis.summary` (the frequency table).
    """
    e = basis.eigen
    rows = [
        ("source", f"{basis.source}  (sha256 {basis.source_sha256[:12]})"),
        ("cubes / DOFs", f"{basis.n_cubes:,} / {basis.n_dofs:,}  (resolution {basis.resolution}, "
                         f"pitch {basis.pitch:.4g}, element {basis.element})"),
        ("size / mass", " x ".join(f"{e:.4g}" for e in np.ptp(basis.vertices, axis=0) * basis.scale)
         + f" m, {basis.material.get('mass', float('nan')):.6g} kg"),
        ("fixed", f"{basis.fix_record.get('n_nodes', 0)} nodes "
                  f"({', '.join(basis.fix_record.get('specs', [])) or 'free'})"),
        ("eigensolver", f"{e.get('method', '')} / {e.get('backend', '')}: {e.get('reason', '')}; "
                        + (f"took {basis.timings['eigensolve']:.3g} s, " if "eigensolve" in basis.timings else "")
                        + f"{e.get('passes', 1)} solve(s) on {e.get('setups', 1)} factorization/hierarchy"),
        ("rigid modes", f"{e.get('n_rigid_found', 0)} found, {basis.n_rigid_removed} removed"),
        ("modes", f"{basis.n_modes} on {basis.n_vertices:,} vertices, damping {basis.damping_spec}"),
    ]
    rows += [(f"time {k}", f"{v:.3f} s") for k, v in {**basis.timings, **timings}.items()
             if isinstance(v, (int, float))]
    return table(rows) + "\n" + basis.summary()


def _batch_lines(res: BatchResult) -> str:
    """One line per mesh (status, time, cubes, modes and frequencies or the error) and the total."""
    w = max(len(Path(r["mesh"]).name) for r in res.rows)
    lines = [f"  {Path(r['mesh']).name:<{w}}  {r['status']:<5}  {float(r['seconds']):7.2f} s  "
             + (f"{r['cubes']} cubes, {r['n_modes']} modes, {r['f_min_hz']}..{r['f_max_hz']} Hz"
                if r["status"] == "ok" else r["error"][:160]) for r in res.rows]
    return "\n".join(lines + [f"{res.n_ok} ok, {res.n_failed} failed in {res.seconds:.1f} s "
                              f"(scheduler {res.scheduler}); summary {res.summary}"])


def precompute_modes(meshes: Iterable[str], output: str | Path, options: dict | None = None, *,
                     scheduler: str | None = None, n_workers: int | None = None,
                     verbose: bool = False) -> JobResult:
    """Compute the vibration modes of one mesh, or of many on Dask, and write the mode files.

    One mesh and a file ``output``: :func:`sc_fem.io.batch.mesh_modes`, then the mode file
    (``.npz``, :func:`sc_fem.io.modes.save_modes`). Several meshes, or a folder ``output``
    (existing, or ending in ``/``), or a ``scheduler``: :func:`run_batch` (``FOLDER/NAME.modes.npz``
    and ``FOLDER/summary.csv``).

    Parameters
    ----------
    meshes : iterable of str
        Paths, glob patterns (``assets/*.obj``) or ``builtin:NAME``.
    output : str or Path
        The mode file (``.npz``) of one mesh, or a folder.
    options : dict, optional
        Keyword arguments of :func:`sc_fem.io.batch.mesh_modes` (``voxel``, ``auto``, ``fix``,
        ``n_modes``, ``damping``, ``eigen``, ...).
    scheduler : str, optional
        Address of a running ``dask.distributed`` scheduler (a batch).
    n_workers : int, optional
        Local Dask workers of a batch (default ``min(meshes, CPUs)``).
    verbose : bool
        Print the stages and their times (a batch: a progress bar) and the solver's progress on
        stderr, and a ``warning:`` line when the modes were cut at ``max_modes``.

    Returns
    -------
    JobResult
        One mesh: ``result`` the :class:`~sc_fem.ModalBasis`, the summary the resolution search
        (``auto``), :func:`precompute_summary` and the file written. A batch:
        ``result`` the :class:`BatchResult`, a line per mesh and a total; not ``ok`` when a mesh
        failed.

    Raises
    ------
    BatchInterrupted
        Ctrl-C during a batch (see :func:`run_batch`).
    """
    meshes = expand_inputs(meshes)
    out = Path(output)
    if len(meshes) > 1 or out.is_dir() or str(output).endswith(("/", os.sep)) or scheduler:
        res = run_batch(meshes, out, options=options, scheduler=scheduler, n_workers=n_workers,
                        progress=verbose, expand=False)
        done = [Path(r["output"]) for r in res.rows if r["status"] == "ok"]
        return JobResult(written=[*done, res.summary], result=res, text=_batch_lines(res), ok=res.n_failed == 0)
    if out.suffix.lower() != ".npz":
        raise InputError(f"the mode file must end in .npz, got {out.name!r} (give a folder ending in / for a batch)")
    timings: dict = {}
    with stage("load + voxelize + modes", timings, verbose):
        basis = mesh_modes(meshes[0], progress=verbose, **dict(options or {}))
    with stage("write", timings, verbose):
        save_modes(basis, out)
    if basis.eigen.get("truncated"):
        warnings.warn(basis.eigen["truncated"], ScFemWarning, stacklevel=2)
    auto = f"resolution auto:\n{format_resolution_table(basis.resolution_table)}\n" if basis.resolution_table else ""
    return JobResult(written=[out], result=basis,
                     text=f"{auto}{precompute_summary(basis, {'write': timings['write']})}\nwrote {out}")
