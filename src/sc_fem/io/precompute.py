"""Precompute vibration modes into mode files: one mesh, or many on Dask (``sc-fem precompute-modes``).

:func:`precompute_modes` runs :func:`sc_fem.io.batch.mesh_modes` (the modes at a grid, or the coarsest
converged one) and writes the mode file, or hands several meshes to :func:`sc_fem.io.batch.run_batch`;
:func:`precompute_summary` describes the result.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Any, Iterable

from ..errors import InputError, ScFemWarning
from ..modes.auto import format_resolution_table
from .batch import BatchResult, expand_inputs, mesh_modes, run_batch
from .modes import save_modes
from .report import JobResult, stage, table


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
    import numpy as np

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
