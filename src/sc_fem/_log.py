"""The ``sc_fem`` logger: stage lines, solver progress and notes go through :mod:`logging`.

The package logs at INFO on the ``"sc_fem"`` logger (children ``"sc_fem.<module>"``) and never
prints to stderr itself. The command line attaches a handler (``--quiet``: warnings only); in a
notebook call :func:`log_to_stderr`, or configure :mod:`logging` as usual. Asking a library call
for progress (``progress=True`` / ``verbose=True``) attaches the same handler when nothing is
configured yet, so the request is not silently dropped.
"""

from __future__ import annotations

import logging
import sys
from contextlib import contextmanager
from typing import Iterator

logger = logging.getLogger("sc_fem")
logger.addHandler(logging.NullHandler())

_HANDLER_NAME = "sc_fem-stderr"


def _configured() -> bool:
    """Whether a record of the ``sc_fem`` logger reaches a real handler (ours, the user's, the root's)."""
    lg: logging.Logger | None = logger
    while lg is not None:
        if any(not isinstance(h, logging.NullHandler) for h in lg.handlers):
            return True
        lg = lg.parent if lg.propagate else None
    return False


def log_to_stderr(level: int | str = "INFO") -> logging.Handler:
    """Show the package's messages on stderr (one line each, no prefix) from ``level`` up.

    Parameters
    ----------
    level : int or str
        A :mod:`logging` level (``"INFO"`` shows stage lines and solver progress, ``"WARNING"``
        only warnings and errors).

    Returns
    -------
    logging.Handler
        The handler (attached once; calling again changes its level).
    """
    handler = next((h for h in logger.handlers if h.get_name() == _HANDLER_NAME), None)
    if handler is None:
        handler = logging.StreamHandler(sys.stderr)
        handler.set_name(_HANDLER_NAME)
        handler.setFormatter(logging.Formatter("%(message)s"))
        logger.addHandler(handler)
    level = logging.getLevelName(level.upper()) if isinstance(level, str) else int(level)
    handler.setLevel(level)
    logger.setLevel(level)
    return handler


@contextmanager
def stderr_messages(level: int | str = "INFO") -> Iterator[logging.Handler]:
    """:func:`log_to_stderr` for the duration of a block (the command line's), then as before.

    Parameters
    ----------
    level : int or str
        The :mod:`logging` level shown.

    Yields
    ------
    logging.Handler
    """
    had = next((h for h in logger.handlers if h.get_name() == _HANDLER_NAME), None)
    old_level, old_handler_level = logger.level, (had.level if had else None)
    handler = log_to_stderr(level)
    try:
        yield handler
    finally:
        logger.setLevel(old_level)
        if had is None:
            logger.removeHandler(handler)
        else:
            had.setLevel(old_handler_level)


def say(message: str, enabled: bool = True, name: str | None = None) -> None:
    """Log ``message`` at INFO when ``enabled`` (a caller's ``progress`` / ``verbose``), attaching the
    stderr handler first when no handler would show it.

    Parameters
    ----------
    message : str
    enabled : bool
        The caller's request to report (nothing is logged when False).
    name : str, optional
        Child logger (``"sc_fem.<name>"``).
    """
    if not enabled:
        return
    if not _configured():
        log_to_stderr("INFO")
    (logger.getChild(name) if name else logger).info(message)
