"""Progress bars of the long stages (voxelize, assemble, eigensolve, simulate, render, batch).

:func:`stage_bar` returns a tqdm bar on stderr for one stage. Whether it is drawn:

* ``enabled=None`` (the library's own stages): when the ``sc_fem`` logger shows INFO messages on
  the console and stderr is a terminal or a notebook -- the command line shows bars, ``--quiet``
  (warnings only) silences them, a run whose stderr goes to a file or a pipe writes only the stage
  lines, and a library call with no logging configured draws nothing;
* ``enabled=True`` / ``False``: the caller's explicit ``progress=`` (a ``False`` stage silences
  the stages run inside it too, e.g. the re-assembly at every step of ``--no-progress``);
* inside a stage whose bar is drawn, no second bar: the outer one is the progress.

A drawn bar appears once the stage has run :data:`DELAY` seconds and is erased when it ends
(``leave=False``); log messages written meanwhile start a clean line above it. The environment
variable :data:`ENV` overrides: ``never`` (no bar), ``always`` (no delay and every update drawn,
for tests and logs) or ``auto`` (the default).
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import weakref
from typing import Any

import numpy as np
from tqdm import tqdm

from ._log import logger

ENV = "SC_FEM_PROGRESS"
"""Environment override: ``auto`` (default), ``always`` or ``never``."""

DELAY = 0.5
"""Seconds a stage runs before its bar appears (``auto``)."""

_NO_RATE = "{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]"

_OPEN: list[weakref.ref] = []     # stages under way whose bar is drawn or that silence the ones inside
# (weak: a bar dropped without close() is closed by tqdm when collected, a silencing stage forgotten)


def _open_stages() -> list[_StageBar | _NoBar]:
    """The stages under way, outermost first."""
    return [b for r in _OPEN if (b := r()) is not None]


def _end(bar: _StageBar | _NoBar) -> None:
    """Remove ``bar`` from the stages under way (by identity: tqdm compares bars by position)."""
    _OPEN[:] = [r for r in _OPEN if (b := r()) is not None and b is not bar]


def progress_mode() -> str:
    """The :data:`ENV` setting: ``"auto"``, ``"always"`` or ``"never"`` (anything else: ``"auto"``)."""
    mode = os.environ.get(ENV, "auto").strip().lower()
    return mode if mode in ("always", "never") else "auto"


def info_shown() -> bool:
    """Whether an INFO record of the ``sc_fem`` logger reaches a console handler (stderr or stdout)
    that lets it through: logging to a file alone draws no bar."""
    if not logger.isEnabledFor(logging.INFO):
        return False
    return any(h.level <= logging.INFO for h in _console_handlers())


class _ClearBars(logging.Filter):
    """On the console handlers while a bar is drawn: erase the drawn bars before a message is
    written, so that it starts a clean line (the bar is drawn again below it at its next update)."""

    def filter(self, record: logging.LogRecord) -> bool:
        with _StageBar.get_lock():
            for bar in _open_stages():
                if not bar.disable and bar.last_print_t >= bar.start_t + bar.delay:   # drawn already
                    bar.clear(nolock=True)
        return True


_CLEAR = _ClearBars()


def _console_handlers() -> list[logging.Handler]:
    """The handlers writing the ``sc_fem`` logger's records to stderr or stdout."""
    out: list[logging.Handler] = []
    lg: logging.Logger | None = logger
    while lg is not None:
        out += [h for h in lg.handlers if isinstance(h, logging.StreamHandler)
                and getattr(h, "stream", None) in (sys.stderr, sys.stdout)]
        lg = lg.parent if lg.propagate else None
    return out


class _NoBar:
    """A bar that is not drawn: the methods of :class:`tqdm.tqdm` that the stages use, doing nothing
    (no tqdm instance, so no tqdm monitor thread in a library call that shows nothing)."""

    disable = True

    def __init__(self, silencing: bool = False) -> None:
        self.silencing, self.n = silencing, 0
        if silencing:
            _OPEN.append(weakref.ref(self))

    def update(self, n: float = 1) -> None:
        """Count ``n`` units (kept in ``n``)."""
        self.n += n

    def set_postfix_str(self, s: str = "", refresh: bool = True) -> None:
        """Nothing to show."""

    def close(self) -> None:
        """End the stage."""
        _end(self)

    def __enter__(self) -> _NoBar:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _StageBar(tqdm):
    """A drawn tqdm bar, registered as a stage under way (see the module docstring)."""

    silencing = False

    def __init__(self, *args: Any, tick: float | None = None, **kwargs: Any) -> None:
        self._stop, self._thread = threading.Event(), None
        self._handlers: list[logging.Handler] = []
        super().__init__(*args, **kwargs)
        self._handlers = _console_handlers()
        for h in self._handlers:
            h.addFilter(_CLEAR)
        if tick:                            # redraw (the elapsed time) during sub-stages without updates
            self._thread = threading.Thread(target=self._tick, args=(tick,), daemon=True)
            self._thread.start()
        _OPEN.append(weakref.ref(self))

    def _tick(self, every: float) -> None:
        while not self._stop.wait(every):
            with self._lock:
                now = self._time()
                if now >= self.start_t + self.delay:      # drawn from now on (tqdm's rule): close erases it
                    self.refresh(nolock=True)
                    self.last_print_t = now

    def close(self) -> None:
        """Erase the bar (``leave=False``) and end the stage."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        for h in self._handlers:
            h.removeFilter(_CLEAR)
        self._handlers = []
        _end(self)
        super().close()


def _interactive() -> bool:
    """Whether stderr is a terminal or a notebook's output (where a redrawn bar reads as one line;
    in a log file or a pipe every redraw would stay)."""
    return bool(getattr(sys.stderr, "isatty", lambda: False)()) or "ipykernel" in sys.modules


def stage_bar(desc: str, total: float | None = None, *, unit: str = "it", enabled: bool | None = None,
              tick: float | None = None, rate: bool = True) -> tqdm | _NoBar:
    """A progress bar on stderr for one stage (use it as a context manager, or ``close()`` it).

    Parameters
    ----------
    desc : str
        The stage (``"voxelize"``, ``"LOBPCG"``, ...): the bar's label.
    total : float, optional
        Units the stage takes (``None``: a counter without a bar).
    unit : str
        What is counted (``"it"``, ``"cube"``, ``"step"``, ...).
    enabled : bool, optional
        ``None``: drawn when the ``sc_fem`` logger shows INFO messages (see the module docstring);
        ``True`` / ``False``: the caller's explicit choice (``False`` also silences the stages inside).
    tick : float, optional
        Redraw every ``tick`` seconds even without updates (the elapsed time of a stage whose
        sub-stages take seconds each).
    rate : bool
        Show the rate and the remaining time (``False``: sub-stages of unequal length).

    Returns
    -------
    tqdm or _NoBar
        A drawn tqdm bar, or an object with the same few methods (``update``, ``set_postfix_str``,
        ``close``, context manager) doing nothing; ``disable`` tells which.
    """
    mode = progress_mode()
    inside = any(not b.disable or b.silencing for b in _open_stages())       # a drawn or a silencing stage
    drawn = mode != "never" and not inside and enabled is not False and (
        enabled or (info_shown() and (mode == "always" or _interactive())))
    if not drawn:
        return _NoBar(silencing=enabled is False)
    now = mode == "always"
    return _StageBar(desc=desc, total=total, unit=unit, file=sys.stderr, leave=False, delay=0.0 if now else DELAY,
                     mininterval=0.0 if now else 0.2, tick=tick, bar_format=None if rate else _NO_RATE)


def step(bar: tqdm | _NoBar, stage: str, done: int = 1) -> None:
    """Count ``done`` sub-stages done and name the next one, ``stage``, in the bar's postfix."""
    if not bar.disable:
        bar.set_postfix_str(stage, refresh=False)
        bar.update(done)


class _Counted:
    """A linear operator that advances a bar at every application (see :func:`counting`)."""

    def __init__(self, op: Any, bar: tqdm, tol: float | None, wanted: tuple[int, int] | None) -> None:
        self.op, self.bar, self.tol, self.wanted = op, bar, tol, wanted
        self.shape, self.dtype = op.shape, getattr(op, "dtype", None)

    def _count(self, x: np.ndarray) -> None:
        if self.tol is not None:                     # the columns are residuals
            r = x.reshape(x.shape[0], -1)
            if self.wanted is not None:              # the unconverged wanted: the first k - (m - active)
                k, m = self.wanted
                r = r[:, :max(0, k - (m - r.shape[1]))]
            text = (f"residual {float(np.linalg.norm(r, axis=0).max()) / self.tol:.1e} x tol" if r.shape[1]
                    else "wanted converged")
            self.bar.set_postfix_str(text, refresh=False)
        if self.bar.total is not None and self.bar.n >= self.bar.total:    # a forecast total passed: one more
            self.bar.total = self.bar.n + 1
        self.bar.update(1)

    def matvec(self, x: np.ndarray) -> np.ndarray:
        self._count(x)
        return self.op.matvec(x)

    def matmat(self, x: np.ndarray) -> np.ndarray:
        self._count(x)
        return self.op @ x

    __call__ = __matmul__ = matmat


def counting(bar: tqdm | _NoBar, op: Any, tol: float | None = None, wanted: tuple[int, int] | None = None) -> Any:
    """``op`` (a linear operator), counting its applications in ``bar``.

    Parameters
    ----------
    bar : tqdm
        From :func:`stage_bar`; a disabled bar gives back ``op`` itself (no cost).
    op : LinearOperator-like
        A preconditioner or a factorization's solve: has ``shape``, ``@`` and ``matvec``.
    tol : float, optional
        ``op`` is applied to residual columns (LOBPCG applies its preconditioner once per
        iteration to the block of unconverged residuals): the postfix shows the largest column
        norm over ``tol``, ``"residual 3.2e+01 x tol"``.
    wanted : (int, int), optional
        ``(k, m)``: only the first ``k`` of the ``m`` columns of the block are wanted. LOBPCG passes
        the unconverged columns in block order, and the wanted (lowest) pairs converge first, so
        the first ``k - (m - active)`` columns passed are the unconverged wanted ones: the postfix
        shows their largest residual (``"wanted converged"`` when none is left), the number the
        solve's stopping rule looks at rather than the extra vectors', which converge last.

    Returns
    -------
    LinearOperator-like
        Callable, with ``matvec``, ``matmat``, ``@``, ``shape`` and ``dtype`` (what the solvers of
        :mod:`scipy.sparse.linalg` take as ``M`` or ``OPinv``).
    """
    return op if bar.disable else _Counted(op, bar, tol, wanted)
