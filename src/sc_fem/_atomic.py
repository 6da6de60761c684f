"""Atomic file writes: write to a temporary file in the target folder, then rename.

A failed or interrupted run (exception, Ctrl-C) never leaves a half-written output.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

import numpy as np

from .errors import OutputError


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; on success it is renamed onto ``path``.

    The temporary name keeps the final suffix (writers that dispatch on the
    extension, e.g. ``np.savez`` or image writers, still see the right one).
    On any exception (including ``KeyboardInterrupt``) the temporary file is removed.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix if suffix is None else suffix
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{suffix}", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp_path, 0o666 & ~umask)   # mkstemp makes 0600; give the file normal permissions
        os.replace(tmp_path, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            tmp_path.unlink()
        raise


def save_npz_atomic(path: str | os.PathLike, **arrays) -> Path:
    """``np.savez_compressed`` to ``path`` atomically; returns the final path."""
    path = Path(path)
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)
    return path


def check_output(path: str | os.PathLike, *, suffixes: tuple[str, ...] = (), folder: bool = False) -> Path:
    """Check, before any work, that ``path`` can be written and names a format that is written.

    Parameters
    ----------
    path : path-like
        The output file (or folder).
    suffixes : tuple of str
        Accepted extensions (lower case, with the dot); empty accepts any.
    folder : bool
        A path without an extension is a folder to create (files are written inside it).

    Raises
    ------
    OutputError
        Unsupported extension, an existing non-directory in the way, or a folder where no file can
        be created (checked by creating and removing a temporary file there).
    """
    path = Path(path)
    ext = path.suffix.lower()
    is_folder = folder and (ext == "" or path.is_dir())
    if not is_folder and suffixes and ext not in suffixes:
        extra = " or a folder" if folder else ""
        raise OutputError(f"unsupported output {path.name!r}: use {', '.join(suffixes)}{extra} "
                          f"({ext or 'no extension'} is not a format this command writes)")
    if path.is_dir() and not is_folder:
        raise OutputError(f"{path} is a folder; give a file name")
    target = path if is_folder else path.parent
    probe = target
    while not probe.exists():                       # the nearest existing ancestor must be a writable folder
        if probe.parent == probe:
            break
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"cannot write {path}: {probe} is a file, not a folder")
    try:
        fd, tmp = tempfile.mkstemp(prefix=".sc_fem-probe.", dir=probe)
        os.close(fd)
        os.unlink(tmp)
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {probe} is not writable ({exc.strerror or exc})") from None
    return path
