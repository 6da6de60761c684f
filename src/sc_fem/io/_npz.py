"""Reading sc_fem's versioned ``.npz`` files (models, modes, animations, reconstructions) with one
set of checks: every reader goes through :func:`read_npz`, so a missing, truncated, non-zip or
corrupted file is the same :class:`~sc_fem.errors.FileFormatError` (one ``error:`` line from the
command line) whichever command reads it."""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np

from ..errors import FileFormatError

_READ_ERRORS = (zipfile.BadZipFile, zlib.error, ValueError, OSError, EOFError, KeyError)
"""What numpy and zipfile raise on a damaged archive (bad CRC, cut member, bad header, ...)."""


def read_npz(path, *, what: str, keys: tuple[str, ...] | None = None) -> dict[str, np.ndarray]:
    """The arrays of the ``.npz`` file ``path`` (only those of ``keys`` that it has, if given).

    Parameters
    ----------
    path : str or Path
    what : str
        Human name of the file type for messages (``"mode file"``, ...).
    keys : tuple of str, optional
        Read only these members (e.g. ``("kind",)`` to tell files apart without reading the rest).

    Raises
    ------
    FileFormatError
        Missing file, not a zip archive (a ``.npz`` cut short loses the archive's directory at its
        end), or an unreadable member (truncated or corrupted).
    """
    path = Path(path)
    if not path.is_file():
        raise FileFormatError(f"{what} not found: {path}")
    if not zipfile.is_zipfile(path):
        raise FileFormatError(f"{path} is not a readable .npz {what} (truncated or corrupted?): "
                              "not a zip archive")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files if keys is None or k in keys}
    except _READ_ERRORS as exc:
        raise FileFormatError(f"{path} is not a readable .npz {what} (truncated or corrupted?): "
                              f"{type(exc).__name__}: {exc}") from None


def npz_kind(path, *, what: str) -> str | None:
    """The ``kind`` of an sc_fem ``.npz`` file (None if it has none); :func:`read_npz`'s errors."""
    kind = read_npz(path, what=what, keys=("kind",)).get("kind")
    return str(kind) if kind is not None and kind.shape == () else None


def read_versioned_npz(path, *, kind: str, version: int | tuple[int, ...], what: str) -> dict[str, np.ndarray]:
    """All arrays of ``path`` after checking it exists, unzips, and has the right kind and version.

    Parameters
    ----------
    path : str or Path
    kind : str
        Expected value of the ``kind`` key (e.g. ``"sc_fem.modes"``).
    version : int or tuple of int
        Expected ``format_version`` (or the versions this sc_fem reads).
    what : str
        Human name of the file type for messages (``"mode file"``, ...).

    Raises
    ------
    FileFormatError
        Missing, truncated, corrupted, foreign (other ``kind``) or wrong-version file.
    """
    path = Path(path)
    data = read_npz(path, what=what)
    found = str(data["kind"]) if "kind" in data and data["kind"].shape == () else None
    if found != kind:
        raise FileFormatError(f"{path} is not an sc_fem {what} (kind={found!r}; keys {sorted(data)[:8]})")
    try:
        got = int(data["format_version"])
    except (KeyError, TypeError, ValueError):
        got = -1
    versions = (version,) if isinstance(version, int) else tuple(version)
    if got not in versions:
        raise FileFormatError(f"{path}: unsupported {what} format_version {got} (this sc_fem reads version "
                              f"{' or '.join(map(str, versions))})")
    return data
