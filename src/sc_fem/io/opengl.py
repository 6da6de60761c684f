"""Whether off-screen OpenGL works here, checked without risking this process.

:func:`ensure_rendering` renders a cube in a child process (a broken graphics stack can crash
the process that tries), once per process, and remembers a success on disk for this Python, VTK
and display setting (``$XDG_CACHE_HOME/sc_fem``, default ``~/.cache/sc_fem``), so that a short
``sc-fem play`` does not spend its first ~5 s starting a second Python. A failure is never
remembered; set ``SC_FEM_NO_RENDER_CACHE=1`` to check every time.
"""

from __future__ import annotations

import functools
import hashlib
import os
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

from ..errors import RenderError

_PROBE = (
    "import pyvista as pv\n"
    "p = pv.Plotter(off_screen=True, window_size=(32, 32))\n"
    "p.add_mesh(pv.Cube())\n"
    "img = p.screenshot(return_img=True)\n"
    "p.close()\n"
    "assert img.shape[0] == 32\n"
)


def _configure_env() -> None:
    if not os.environ.get("DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def _cache_file() -> Path | None:
    """The marker of a successful check in this setting, or None when caching is off."""
    if os.environ.get("SC_FEM_NO_RENDER_CACHE"):
        return None
    try:
        vtk = version("vtk")
    except Exception:                       # noqa: BLE001 - no metadata: do not cache
        return None
    key = "\n".join([sys.executable, vtk, _PROBE, os.environ.get("DISPLAY", ""),
                     os.environ.get("VTK_DEFAULT_OPENGL_WINDOW", "")])
    root = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "sc_fem"
    return root / f"render-ok-{hashlib.sha256(key.encode()).hexdigest()[:16]}"


@functools.lru_cache(maxsize=1)
def ensure_rendering() -> str:
    """Make sure off-screen rendering works; returns the render window class name used.

    Returns
    -------
    str
        ``VTK_DEFAULT_OPENGL_WINDOW`` (``"vtkEGLRenderWindow"`` without a display) or ``"default"``.

    Raises
    ------
    RenderError
        No OpenGL context could be made (says what to install).
    """
    _configure_env()
    marker = _cache_file()
    if marker is not None and marker.is_file():
        return os.environ.get("VTK_DEFAULT_OPENGL_WINDOW", "default")
    try:
        res = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120,
                             env=dict(os.environ), check=False)
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise RenderError(f"could not start the rendering check: {exc}") from None
    if res.returncode != 0:
        tail = (res.stderr or res.stdout).strip().splitlines()[-3:]
        raise RenderError(
            "off-screen rendering is not available: no OpenGL context could be made "
            f"({' | '.join(tail)}). Install an EGL/OSMesa driver (Debian: apt-get install libegl1 "
            "libgl1-mesa-dri, or libosmesa6 with VTK_DEFAULT_OPENGL_WINDOW=vtkOSOpenGLRenderWindow), "
            "or run under a virtual display (xvfb-run).")
    if marker is not None:
        try:                                # best effort: an unwritable cache only costs the next check
            marker.parent.mkdir(parents=True, exist_ok=True)
            marker.touch()
        except OSError:
            pass
    return os.environ.get("VTK_DEFAULT_OPENGL_WINDOW", "default")
