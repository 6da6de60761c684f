"""Execute the notebooks and store their outputs in place (so the plots show on a code host).

    .venv/bin/python notebooks/execute.py            # all notebooks
    .venv/bin/python notebooks/execute.py 03*.ipynb  # some

``make test`` executes them again (nbmake) without writing; run this after changing one.
"""

from __future__ import annotations

import os
import re
import sys
import tempfile
from pathlib import Path

import nbformat
from nbclient import NotebookClient

HERE = Path(__file__).resolve().parent

MACHINE_PATH = re.compile(r"(?:/(?:home|Users|root|work|tmp|opt|usr)/[^\s\"']*|[A-Za-z]:\\Users\\)")
"""Absolute paths of a checkout, a home directory or a Python installation."""


def machine_paths(nb) -> list[str]:
    """Paths of the executing machine in a notebook's outputs (a dict as read from the JSON)."""
    found = []
    for cell in nb["cells"]:
        for out in cell.get("outputs", []):
            texts = [out.get("text", "")] + [v for k, v in out.get("data", {}).items() if k.startswith("text/")]
            for t in texts:
                found += MACHINE_PATH.findall("".join(t) if isinstance(t, list) else t)
    return found


def execute(path: Path) -> None:
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=1200, kernel_name="python3", resources={"metadata": {"path": str(HERE)}}).execute()
    for cell in nb.cells:                                     # stable files: no execution timing noise
        cell.metadata.pop("execution", None)
    leaked = machine_paths(nb)
    if leaked:                                                # stored outputs go to a code host
        raise SystemExit(f"{path.name}: an output names a path of this machine ({', '.join(leaked[:3])}); "
                         "silence or reword it before storing the outputs")
    fd, tmp = tempfile.mkstemp(suffix=".ipynb", dir=path.parent)
    os.close(fd)
    try:
        nbformat.write(nb, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    print(f"executed {path.name} ({path.stat().st_size // 1024} KiB)")


if __name__ == "__main__":
    os.environ.pop("MPLBACKEND", None)             # the inline backend, so the plots are stored
    names = sys.argv[1:] or sorted(p.name for p in HERE.glob("*.ipynb"))
    for name in names:
        for p in sorted(HERE.glob(name)):
            execute(p)
