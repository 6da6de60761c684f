"""A batch on Dask: one task per mesh, each writing one file, a CSV summary, failures isolated.

:func:`run_tasks` submits a task ``task(mesh, output, options) -> row`` for each mesh to a
``dask.distributed`` cluster -- a :class:`~distributed.LocalCluster` started for the run (default)
or an existing scheduler (``scheduler="tcp://host:8786"``) -- or runs them one after the other
when dask is not installed. The task never raises: a mesh that fails (unreadable file, bad
boundary condition, solver error) returns ``status="error"`` and its message, and a crashed
worker is recorded the same way; the others finish. Progress is shown with tqdm on stderr as
tasks complete; the summary is written atomically as ``summary.csv`` in the output folder. What a
task computes is the caller's (:func:`sc_fem.io.precompute.run_batch`: mode files); nothing here
knows it.

Ctrl-C (SIGINT) is handled by this process alone: the local cluster's worker processes are
started with SIGINT ignored (so they print no tracebacks; a Ctrl-C while the cluster starts, a
few seconds, is ignored too), the cluster is shut down, the summary is written (unfinished meshes
``status="interrupted"``) and :class:`BatchInterrupted` lists the files that were completed. Tasks
write their files atomically, so each listed file is complete and no other file is left
half-written.
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
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

from .._atomic import atomic_path
from .._progress import stage_bar
from ..errors import InputError

BASE_FIELDS = ("mesh", "status", "output", "seconds", "error")
"""Columns every summary has (a task adds its own, :func:`run_tasks`' ``fields``)."""


@dataclass(frozen=True)
class BatchResult:
    """Outcome of :func:`run_tasks`.

    Attributes
    ----------
    rows : list of dict
        One row per mesh (keys: the summary's columns), in input order.
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
    """Ctrl-C during :func:`run_tasks`, after the cluster was shut down and the summary written.

    Attributes
    ----------
    completed : list of Path
        Files this batch completed (written atomically: complete and valid), in input order.
    n_meshes : int
        Meshes in the batch.
    summary : Path
        The CSV written (unfinished meshes have ``status="interrupted"``).
    what : str
        What the files are, plural (``"mode files"``).
    """

    def __init__(self, completed, n_meshes: int, summary: Path, what: str = "files") -> None:
        super().__init__(f"interrupted: {len(completed)} of {n_meshes} {what} completed")
        self.completed, self.n_meshes, self.summary = [Path(p) for p in completed], n_meshes, Path(summary)
        self.what = what

    @property
    def outcome(self) -> str:
        """What the stopped batch left, as one sentence: the files completed, and the summary."""
        done = (f"{len(self.completed)} of {self.n_meshes} {self.what} completed (complete and valid): "
                + ", ".join(map(str, self.completed)) if self.completed else
                f"none of the {self.n_meshes} {self.what} was completed")
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


def _interrupted(rows: list, meshes: list[str], outputs: list[str], before: dict, summary: Path,
                 fields: Sequence[str], what: str) -> BatchInterrupted:
    """The :class:`BatchInterrupted` of a batch stopped with ``rows`` (None: no result received):
    completed are the outputs reported ok and those replaced on disk since ``before`` (a task that
    finished while the cluster was stopped); the summary is written with the rest interrupted."""
    done = [o for o, r in zip(outputs, rows)
            if (r is not None and r["status"] == "ok") or _stamp(o) not in (None, before[o])]
    late = {"status": "ok", "error": "finished as the batch was interrupted (details not collected)"}
    cut = {"status": "interrupted", "error": "interrupted (Ctrl-C)"}
    for i, (m, o) in enumerate(zip(meshes, outputs)):     # loop over meshes: rows of unfinished ones
        if rows[i] is None:
            rows[i] = {**{k: "" for k in fields}, "mesh": m, **({**late, "output": o} if o in done else cut)}
    return BatchInterrupted(done, len(meshes), write_summary(rows, summary, fields), what)


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


def write_summary(rows: list[dict], path, fields: Sequence[str] = BASE_FIELDS) -> Path:
    """Write the summary rows as CSV atomically (the columns ``fields``; other keys are left out)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(fields), extrasaction="ignore")
    w.writeheader()
    w.writerows(rows)
    path = Path(path)
    with atomic_path(path, suffix=".csv") as tmp:
        tmp.write_text(buf.getvalue())
    return path


Task = Callable[[str, str, dict], dict]
"""A batch task: ``task(mesh, output, options) -> row`` writes ``output`` and never raises (its
failure is the row's ``status="error"`` and ``error``); a module-level function, so that dask
can send it to worker processes by reference."""


def run_tasks(task: Task, meshes: Sequence[str], outputs: Sequence[str], summary: str | Path, *,
              options: dict | None = None, fields: Sequence[str] = BASE_FIELDS, what: str = "files",
              scheduler: str | None = None, n_workers: int | None = None, processes: bool = True,
              progress: bool = True) -> BatchResult:
    """Run ``task(mesh, output, options)`` for every mesh, one Dask task each, and write the summary.

    Parameters
    ----------
    task : callable
        ``task(mesh, output, options) -> dict`` (:data:`Task`): the row of one mesh, with at least
        :data:`BASE_FIELDS`.
    meshes : sequence of str
        The inputs, one task each.
    outputs : sequence of str
        The file each task writes (same length).
    summary : str or Path
        The CSV summary to write (one row per mesh).
    options : dict, optional
        Handed to every task unchanged.
    fields : sequence of str
        The summary's columns.
    what : str
        What the outputs are, plural, for the interruption's message (``"mode files"``).
    scheduler : str, optional
        Address of a running ``dask.distributed`` scheduler; default: start a LocalCluster.
    n_workers : int, optional
        Local workers (default ``min(len(meshes), cpu count)``), one thread each.
    processes : bool
        Local workers as processes (default) or threads.
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    BatchResult

    Raises
    ------
    InputError
        ``scheduler`` given without ``dask.distributed`` installed.
    BatchInterrupted
        Ctrl-C (a KeyboardInterrupt): the cluster is shut down and the summary written first; it
        lists the files completed.
    """
    try:
        from dask.distributed import Client, LocalCluster, as_completed
    except ImportError:
        if scheduler:
            raise InputError("--scheduler needs dask.distributed, which is not installed: "
                             "pip install 'sc_fem[batch]'") from None
        Client = None                                     # serial fallback, same rows and summary
    meshes, outputs, summary = list(meshes), list(outputs), Path(summary)
    opts = dict(options or {})
    t0 = time.perf_counter()
    before = {o: _stamp(o) for o in outputs}
    rows: list[dict | None] = [None] * len(meshes)
    if Client is None:
        bar = stage_bar("meshes (serial: dask not installed)", len(meshes), unit="mesh", enabled=progress, tick=1.0)
        try:
            for i, (m, o) in enumerate(zip(meshes, outputs)):     # loop over input meshes
                rows[i] = task(m, o, opts)
                bar.update(1)
        except KeyboardInterrupt:
            with _sigint_ignored():
                raise _interrupted(rows, meshes, outputs, before, summary, fields, what) from None
        finally:
            bar.close()
        return BatchResult(rows=rows, summary=write_summary(rows, summary, fields),
                           seconds=time.perf_counter() - t0, scheduler="serial (dask not installed)")
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
        futures = [client.submit(task, m, o, opts, key=f"task-{i}-{Path(o).stem}", pure=False)
                   for i, (m, o) in enumerate(zip(meshes, outputs))]
        index = {f.key: i for i, f in enumerate(futures)}
        for fut in as_completed(futures):                 # loop over completed tasks
            i = index[fut.key]
            try:
                rows[i] = fut.result()
            except Exception as exc:  # noqa: BLE001 - e.g. a worker killed by the OS
                rows[i] = {**{k: "" for k in fields}, "mesh": meshes[i], "status": "error",
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
                raise _interrupted(rows, meshes, outputs, before, summary, fields, what) from None
    return BatchResult(rows=rows, summary=write_summary(rows, summary, fields),
                       seconds=time.perf_counter() - t0, scheduler=address)
