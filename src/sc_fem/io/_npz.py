"""Reading sc_fem's versioned ``.npz`` files (models, modes, animations) with one set of checks."""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path

import numpy as np

from ..errors import FileFormatError


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
    if not path.is_file():
        raise FileFormatError(f"{what} not found: {path}")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (zipfile.BadZipFile, zlib.error, ValueError, OSError, EOFError, KeyError) as exc:
        raise FileFormatError(f"{path} is not a readable .npz {what} (truncated or corrupted?): "
                            f"{type(exc).__name__}: {exc}") from None
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
