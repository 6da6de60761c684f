"""Batch mode precomputation on Dask: one task per mesh, a CSV summary, failures isolated.

:func:`run_batch` submits :func:`precompute_one` for each mesh to a ``dask.distributed`` cluster --
a :class:`~distributed.LocalCluster` started for the run (default) or an existing scheduler
(``scheduler="tcp://host:8786"``). A mesh that fails (unreadable file, bad boundary condition,
solver error, even a crashed worker) gets ``status="error"`` and its message in the summary; the
others finish. Progress is shown with tqdm on stderr as tasks complete; the summary is written
atomically as ``summary.csv`` in the output folder.

Ctrl-C (SIGINT) is handled by this process alone: the local cluster's worker processes are
started with SIGINT ignored (so they print no tracebacks; a Ctrl-C while the cluster starts, a
few seconds, is ignored too), the cluster is shut down, the summary is written (unfinished meshes
``status="interrupted"``) and :class:`BatchInterrupted` lists the mode files that were completed.
Mode files are written atomically and validated before writing, so each listed file is complete
and readable and no other file is left half-written.
"""

from __future__ import annotations

import contextlib
import csv
import glob
import io
import logging
import os
import signal
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

from .._atomic import atomic_path
from .._progress import stage_bar
from ..errors import InputError, ScFemError
from ..modes.auto import modal_converged
from ..modes.modal import modal
from ..scene import Scene
from .modes import save_modes

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
        """Meshes whose mode file was written."""
        return sum(r["status"] == "ok" for r in self.rows)

    @property
    def n_failed(self) -> int:
        """Meshes that failed (their message is in the summary)."""
        return sum(r["status"] != "ok" for r in self.rows)


class BatchInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`run_batch`, after the cluster was shut down and the summary written.

    Attributes
    ----------
    completed : list of Path
        Mode files this batch completed (written atomically: complete and valid), in input order.
    n_meshes : int
        Meshes in the batch.
    summary : Path
        The CSV written (unfinished meshes have ``status="interrupted"``).
    """

    def __init__(self, completed, n_meshes: int, summary: Path) -> None:
        super().__init__(f"interrupted: {len(completed)} of {n_meshes} mode files completed")
        self.completed, self.n_meshes, self.summary = [Path(p) for p in completed], n_meshes, Path(summary)

    @property
    def outcome(self) -> str:
        """What the stopped batch left, as one sentence: the mode files completed, and the summary."""
        done = (f"{len(self.completed)} of {self.n_meshes} mode files completed (complete and valid): "
                + ", ".join(map(str, self.completed)) if self.completed else
                f"none of the {self.n_meshes} mode files was completed")
        return f"{done}; the others were not written; summary {self.summary}"


@contextlib.contextmanager
def _sigint_ignored():
    """Ignore SIGINT meanwhile (in the main thread; elsewhere signals cannot be set): processes
    started inside inherit it across ``exec`` and Python then installs no KeyboardInterrupt handler
    in them; around a shutdown, a second Ctrl-C cannot interrupt it."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


WORKER_LOGGING = "critical"
"""Level of the ``distributed`` loggers in the local cluster's worker processes: what they report
(a failed task, and on Ctrl-C the cancelled tasks and lost heartbeats of workers being stopped,
with tracebacks) is in the summary or is not news."""


@contextlib.contextmanager
def _quiet_workers():
    """Worker processes started meanwhile ignore SIGINT (:func:`_sigint_ignored`) and log at
    :data:`WORKER_LOGGING` (dask reads ``DASK_LOGGING__DISTRIBUTED`` as it starts in them)."""
    key = "DASK_LOGGING__DISTRIBUTED"
    old = os.environ.get(key)
    os.environ[key] = WORKER_LOGGING
    try:
        with _sigint_ignored():
            yield
    finally:
        if old is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = old


def _stamp(path) -> tuple[int, int] | None:
    """``(inode, mtime_ns)`` of a file, None if it does not exist: an atomic write (a rename of a
    new file) always changes it."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns


def _interrupted(rows: list, meshes: list[str], outputs: list[str], before: dict, out: Path) -> BatchInterrupted:
    """The :class:`BatchInterrupted` of a batch stopped with ``rows`` (None: no result received):
    completed are the outputs reported ok and those replaced on disk since ``before`` (a task that
    finished while the cluster was stopped); the summary is written with the rest interrupted."""
    done = [o for o, r in zip(outputs, rows)
            if (r is not None and r["status"] == "ok") or _stamp(o) not in (None, before[o])]
    late = {"status": "ok", "error": "finished as the batch was interrupted (details not collected)"}
    cut = {"status": "interrupted", "error": "interrupted (Ctrl-C)"}
    for i, (m, o) in enumerate(zip(meshes, outputs)):     # loop over meshes: rows of unfinished ones
        if rows[i] is None:
            rows[i] = {**{k: "" for k in SUMMARY_FIELDS}, "mesh": m, **({**late, "output": o} if o in done else cut)}
    return BatchInterrupted(done, len(meshes), write_summary(rows, out / "summary.csv"))


@contextlib.contextmanager
def _no_logging(quiet: bool):
    """Meanwhile (if ``quiet``), no logging in this process: the shutdown of an interrupted batch
    logs cancelled tasks and killed workers."""
    previous = logging.root.manager.disable
    if quiet:
        logging.disable(logging.CRITICAL)
    try:
        yield
    finally:
        logging.disable(previous)


def expand_inputs(patterns) -> list[str]:
    """Meshes from paths, glob patterns (``assets/*.obj``) and ``builtin:NAME``; order kept, no duplicates
    (one path or pattern on its own is one argument, not a sequence of characters)."""
    if isinstance(patterns, (str, os.PathLike)):
        patterns = [patterns]
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


def mesh_modes(mesh: Any, *, voxel: Any = None, auto: Any = None, fix: Any = None, fix_vertices: Any = None,
               **request: Any) -> Any:
    """The modes of one mesh, as a job's ``options`` describe them (these keywords).

    Parameters
    ----------
    mesh : path, ``"builtin:NAME"`` or mesh-like
        The source mesh.
    voxel : VoxelOptions or dict, optional
        How it is voxelized; its ``resolution`` is the grid (cubes along the longest axis).
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


def run_batch(meshes: Iterable[str], out_dir: str | Path, *, options: dict | None = None,
              scheduler: str | None = None, n_workers: int | None = None, processes: bool = True, progress: bool = True,
              expand: bool = True) -> BatchResult:
    """Precompute modes for many meshes, one Dask task per mesh.

    Parameters
    ----------
    meshes : iterable of str
        Paths, glob patterns or ``builtin:NAME``.
    out_dir : str or Path
        Folder for ``NAME.modes.npz`` files and ``summary.csv`` (created).
    options : dict, optional
        Keyword arguments of :func:`mesh_modes` (``voxel``, ``auto``, ``fix``, ``n_modes``, ...).
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

    Raises
    ------
    BatchInterrupted
        Ctrl-C (a KeyboardInterrupt): the cluster is shut down and the summary written first; it
        lists the mode files completed.
    """
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
    before = {o: _stamp(o) for o in outputs}
    rows: list[dict | None] = [None] * len(meshes)
    if Client is None:
        bar = stage_bar("meshes (serial: dask not installed)", len(meshes), unit="mesh", enabled=progress, tick=1.0)
        try:
            for i, (m, o) in enumerate(zip(meshes, outputs)):     # loop over input meshes
                rows[i] = precompute_one(m, o, opts)
                bar.update(1)
        except KeyboardInterrupt:
            with _sigint_ignored():
                raise _interrupted(rows, meshes, outputs, before, out) from None
        finally:
            bar.close()
        summary = write_summary(rows, out / "summary.csv")
        return BatchResult(rows=rows, summary=summary, seconds=time.perf_counter() - t0,
                           scheduler="serial (dask not installed)")
    cluster = None
    if scheduler:
        client = Client(scheduler, timeout="20s")
    else:
        nw = n_workers or max(1, min(len(meshes), os.cpu_count() or 1))
        with _quiet_workers():         # Ctrl-C is this process's alone
            cluster = LocalCluster(n_workers=nw, threads_per_worker=1, processes=processes, dashboard_address=None)
            client = Client(cluster)
    interrupted = False
    bar = stage_bar("meshes", len(meshes), unit="mesh", enabled=progress, tick=1.0)
    try:
        futures = [client.submit(precompute_one, m, o, opts, key=f"precompute-{i}-{Path(o).stem}", pure=False)
                   for i, (m, o) in enumerate(zip(meshes, outputs))]
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in as_completed(futures):                 # loop over completed tasks
            i = index[fut.key]
            try:
                rows[i] = fut.result()
            except Exception as exc:  # noqa: BLE001 - e.g. a worker killed by the OS
                rows[i] = {**{k: "" for k in SUMMARY_FIELDS}, "mesh": meshes[i], "status": "error",
                           "seconds": 0.0, "error": f"task failed: {type(exc).__name__}: {exc}"}
            bar.update(1)
            bar.set_postfix_str(f"{Path(meshes[i]).name}: {rows[i]['status']}")
        address = client.scheduler.address if client.scheduler else str(scheduler)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        bar.close()
        with _sigint_ignored(), _no_logging(interrupted):   # a stopped batch's shutdown is not news
            client.close()
            if cluster is not None:
                cluster.close()
            if interrupted:
                raise _interrupted(rows, meshes, outputs, before, out) from None
    summary = write_summary(rows, out / "summary.csv")
    return BatchResult(rows=rows, summary=summary, seconds=time.perf_counter() - t0, scheduler=address)
