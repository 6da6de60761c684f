"""Package build hooks: every wheel and sdist carries the web viewer's JavaScript bundle.

All metadata is in :file:`pyproject.toml`; this file only adds one step to two setuptools
commands. ``sc-fem view`` inlines :file:`src/sc_fem/io/_viewer/viewer.js`, a build product
(three.js and :file:`_viewer/main.js` bundled by esbuild, fetched from the npm registry by
:file:`.ci/build-viewer.sh`, the script behind ``make viewer``) that git does not track. So:

* ``build_py`` (run by ``pip wheel .``, ``pip install .``, ``python -m build``) runs the build
  script when the bundle is missing or older than its sources, and stops with an error naming the
  cause when it still is missing afterwards (no npm, no network): a wheel without the bundle would
  install a ``sc-fem view`` that cannot work. Editable installs (``pip install -e .``, used by
  ``make``) skip the step: they read the bundle from the source tree, where ``make viewer`` puts it.
* ``sdist`` tries the same, so a source distribution installs without npm; where the bundle cannot
  be built it warns and the sdist carries its sources instead (:file:`MANIFEST.in` lists
  :file:`main.js` and the build script), from which the wheel build makes it.
"""

from __future__ import annotations

import logging
import shutil
import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py
from setuptools.command.sdist import sdist
from setuptools.errors import ExecError

ROOT = Path(__file__).resolve().parent
BUNDLE = ROOT / "src" / "sc_fem" / "io" / "_viewer" / "viewer.js"
"""The bundle ``sc-fem view`` inlines (the same path as ``sc_fem.io.viewer.BUNDLE``)."""
BUILD_SCRIPT = ROOT / ".ci" / "build-viewer.sh"
"""The script that writes :data:`BUNDLE` (``make viewer``)."""
BUNDLE_SOURCES = (ROOT / "src" / "sc_fem" / "io" / "_viewer" / "main.js", BUILD_SCRIPT)
"""The files the bundle is made from: a bundle older than any of them is rebuilt (as by make)."""


def bundle_status() -> str | None:
    """Why the viewer bundle needs building, or None when it is present and up to date.

    Returns
    -------
    str or None
        ``"missing"``, ``"older than main.js"`` (or the build script), or None.
    """
    if not BUNDLE.is_file():
        return "missing"
    built = BUNDLE.stat().st_mtime
    newer = [p.name for p in BUNDLE_SOURCES if p.is_file() and p.stat().st_mtime > built]
    return f"older than {' and '.join(newer)}" if newer else None


def run_build_script() -> str | None:
    """Run :data:`BUILD_SCRIPT`; None when it wrote the bundle, else what went wrong.

    Returns
    -------
    str or None
        None on success; otherwise a message naming the cause (no script, no bash, no npm, or
        the script's own notes when npm install or esbuild failed).
    """
    if not BUILD_SCRIPT.is_file():
        return f"the build script {BUILD_SCRIPT} is not in this source tree"
    if shutil.which("bash") is None:
        return "bash is not installed (the build script is a bash script)"
    if shutil.which("npm") is None:
        return "npm is not installed (the bundle's three.js and esbuild come from the npm registry)"
    before = BUNDLE.stat().st_mtime_ns if BUNDLE.is_file() else None
    done = subprocess.run(["bash", str(BUILD_SCRIPT)], cwd=ROOT, capture_output=True, text=True)
    if BUNDLE.is_file() and BUNDLE.stat().st_mtime_ns != before and done.returncode == 0:
        return None
    notes = " ".join((done.stdout + done.stderr).split()) or f"exit status {done.returncode}"
    return f"{BUILD_SCRIPT.name} did not write the bundle: {notes}"


def rebuild_bundle(command) -> tuple[str | None, str | None]:
    """Run the build script when the bundle needs it (saying so through ``command.announce``).

    Returns
    -------
    why, problem : str or None
        :func:`bundle_status` (None: up to date, nothing run) and :func:`run_build_script`'s answer.
    """
    why = bundle_status()
    if why is None:
        return None, None
    command.announce(f"sc_fem web viewer bundle {why}: running {BUILD_SCRIPT}", level=logging.INFO)
    return why, run_build_script()


class BuildPyWithViewer(build_py):
    """``build_py`` that first makes sure the web viewer's bundle exists (see the module docstring)."""

    def run(self) -> None:
        """Build the bundle when it is missing or stale, then copy the package as usual.

        Raises
        ------
        setuptools.errors.ExecError
            The bundle is missing and cannot be built (the message says why and what to install).
        """
        if not self.editable_mode:
            why, problem = rebuild_bundle(self)
            if why is not None:
                if problem is not None and not BUNDLE.is_file():
                    raise ExecError(
                        f"the web viewer's JavaScript bundle {BUNDLE} is missing and could not be built: "
                        f"{problem}. Install node and npm (with access to the npm registry) and build "
                        "again, or run `make viewer` first; a wheel without the bundle would install "
                        "a `sc-fem view` that fails.")
                if problem is not None:
                    self.warn(f"the bundle is {why} but could not be rebuilt ({problem}); packaging the existing one")
                self.__dict__.pop("data_files", None)       # the package-data list may predate the bundle
        super().run()


class SdistWithViewer(sdist):
    """``sdist`` that carries the web viewer's bundle when it can be built (see the module docstring)."""

    def run(self) -> None:
        """Build the bundle when it is missing or stale (a warning where it cannot be), then the sdist."""
        why, problem = rebuild_bundle(self)
        if why is not None:
            if problem is not None:
                self.warn(f"the web viewer's bundle is {why} and could not be built: {problem}. The sdist "
                          "carries main.js and the build script instead, so installing it needs npm")
        super().run()


setup(cmdclass={"build_py": BuildPyWithViewer, "sdist": SdistWithViewer})
