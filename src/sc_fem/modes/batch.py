"""Batch mode precomputation on Dask: one task per mesh, a CSV summary, failures isolated.

:func:`run_batch` submits :func:`precompute_one` for each mesh to a ``dask.distributed`` cluster --
a :class:`~distributed.LocalCluster` started for the run (default) or an existing scheduler
(``scheduler="tcp://host:8786"``). A mesh that fails (unreadable file, bad boundary condition,
solver error, even a crashed worker) gets ``status="error"`` and its message in the summary; the
others finish. Progress is shown with tqdm on stderr as tasks complete; the summary is written
atomically as ``summary.csv`` in the output folder.
"""

from __future__ import annotations

import csv
import glob
import io
import os
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .._atomic import atomic_path
from ..errors import InputError

SUMMARY_FIELDS = ("mesh", "status", "output", "seconds", "cubes", "dofs", "n_modes", "f_min_hz", "f_max_hz",
                  "solver", "error")
"""Columns of ``summary.csv``."""


@dataclass(frozen=True)
class BatchResult:
    """Outcome of :func:`run_batch`.

    Attributes
    ----------
    rows : list of dict
        One row per mesh (keys :data:`SUMMARY_FIELDS`), in input order.
    summary : Path
        The CSV written.
    seconds : float
        Wall time of the batch.
    scheduler : str
        Address of the scheduler used.
    """

    rows: list = field(default_factory=list)
    summary: Path = Path("summary.csv")
    seconds: float = 0.0
    scheduler: str = ""

    @property
    def n_ok(self) -> int:
        return sum(r["status"] == "ok" for r in self.rows)

    @property
    def n_failed(self) -> int:
        return sum(r["status"] != "ok" for r in self.rows)


def expand_inputs(patterns) -> list[str]:
    """Meshes from paths, glob patterns (``assets/*.obj``) and ``builtin:NAME``; order kept, no duplicates."""
    out: list[str] = []
    for p in patterns:                                     # loop over command-line arguments
        s = str(p)
        hits = sorted(glob.glob(s)) if any(c in s for c in "*?[") and not s.startswith("builtin:") else [s]
        if not hits:
            raise InputError(f"no file matches {s!r}")
        out += [h for h in hits if h not in out]
    return out


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
        Keyword arguments of :func:`sc_fem.modes.modal.modal`; a ``"default"`` entry of ``fix`` is
        replaced by the built-in model's supports (:func:`sc_fem.models.expand_fix`).
    """
    t0 = time.perf_counter()
    row: dict[str, Any] = {k: "" for k in SUMMARY_FIELDS}
    row.update(mesh=mesh, output=output)
    try:
        from .modal import modal
        from ..io.modes import save_modes

        basis = modal(mesh, **dict(options))             # modal loads the mesh (once) and expands "default"
        save_modes(basis, output)
        f = basis.frequencies[~basis.rigid]
        row.update(status="ok", cubes=basis.n_cubes, dofs=basis.n_dofs, n_modes=basis.n_modes,
                   f_min_hz=f"{f.min():.6g}" if len(f) else "", f_max_hz=f"{f.max():.6g}" if len(f) else "",
                   solver=f"{basis.eigen.get('method', '')}/{basis.eigen.get('backend', '')}")
    except Exception as exc:  # noqa: BLE001 - one bad mesh must fail alone, with its message
        from ..errors import ScFemError

        msg = f"{type(exc).__name__}: {exc}"
        if not isinstance(exc, ScFemError):
            msg += " | " + traceback.format_exc(limit=-2).strip().replace("\n", " / ")[-400:]
        row.update(status="error", error=msg, output="")
    row["seconds"] = f"{time.perf_counter() - t0:.3f}"
    return row


def write_summary(rows: list[dict], path) -> Path:
    """Write the summary rows as CSV atomically."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(SUMMARY_FIELDS), extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    path = Path(path)
    with atomic_path(path, suffix=".csv") as tmp:
        tmp.write_text(buf.getvalue())
    return path


def run_batch(meshes, out_dir, *, options: dict | None = None, scheduler: str | None = None,
              n_workers: int | None = None, processes: bool = True, progress: bool = True,
              expand: bool = True) -> BatchResult:
    """Precompute modes for many meshes, one Dask task per mesh.

    Parameters
    ----------
    meshes : iterable of str
        Paths, glob patterns or ``builtin:NAME``.
    out_dir : str or Path
        Folder for ``NAME.modes.npz`` files and ``summary.csv`` (created).
    options : dict, optional
        Keyword arguments for :func:`sc_fem.modes.modal.modal` (``resolution``, ``n_modes``, ``fix``, ...).
    scheduler : str, optional
        Address of a running ``dask.distributed`` scheduler; default: start a LocalCluster.
    n_workers : int, optional
        Local workers (default ``min(len(meshes), cpu count)``), one thread each.
    processes : bool
        Local workers as processes (default) or threads.
    progress : bool
        tqdm progress bar on stderr.
    expand : bool
        Expand ``meshes`` with :func:`expand_inputs` (``False``: they are already expanded paths).

    Returns
    -------
    BatchResult
    """
    from tqdm import tqdm

    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        if scheduler:
            raise InputError("--scheduler needs dask.distributed, which is not installed: "
                             "pip install 'sc_fem[batch]'") from None
        Client = None                                     # serial fallback, same rows and summary
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
    outputs = [str(out / n) for n in names]
    opts = dict(options or {})
    t0 = time.perf_counter()
    if Client is None:
        bar = tqdm(total=len(meshes), desc="meshes (serial: dask not installed)", unit="mesh",
                   disable=not progress, file=sys.stderr)
        rows = []
        for m, o in zip(meshes, outputs):                 # loop over input meshes
            rows.append(precompute_one(m, o, opts))
            bar.update(1)
        bar.close()
        summary = write_summary(rows, out / "summary.csv")
        return BatchResult(rows=rows, summary=summary, seconds=time.perf_counter() - t0,
                           scheduler="serial (dask not installed)")
    cluster = None
    if scheduler:
        client = Client(scheduler, timeout="20s")
    else:
        nw = n_workers or max(1, min(len(meshes), os.cpu_count() or 1))
        cluster = LocalCluster(n_workers=nw, threads_per_worker=1, processes=processes, dashboard_address=None)
        client = Client(cluster)
    rows: list[dict | None] = [None] * len(meshes)
    try:
        futures = [client.submit(precompute_one, m, o, opts, key=f"precompute-{i}-{Path(o).stem}", pure=False)
                   for i, (m, o) in enumerate(zip(meshes, outputs))]
        index = {f.key: i for i, f in enumerate(futures)}
        bar = tqdm(total=len(futures), desc="meshes", unit="mesh", disable=not progress, file=sys.stderr)
        for fut in as_completed(futures):                 # loop over completed tasks
            i = index[fut.key]
            try:
                rows[i] = fut.result()
            except Exception as exc:  # noqa: BLE001 - e.g. a worker killed by the OS
                rows[i] = {**{k: "" for k in SUMMARY_FIELDS}, "mesh": meshes[i], "status": "error",
                           "error": f"task failed: {type(exc).__name__}: {exc}"}
            bar.update(1)
            bar.set_postfix_str(f"{Path(meshes[i]).name}: {rows[i]['status']}")
        bar.close()
        address = client.scheduler.address if client.scheduler else str(scheduler)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    summary = write_summary(rows, out / "summary.csv")
    return BatchResult(rows=rows, summary=summary, seconds=time.perf_counter() - t0, scheduler=address)
