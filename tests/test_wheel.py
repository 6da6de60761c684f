"""The built package works where the source tree is absent: a wheel and an sdist built from a copy
of the source tree as a fresh clone has it (no ``viewer.js``: a git-ignored build product) carry the
web viewer's JavaScript bundle and ``py.typed``, and the wheel, installed into a fresh venv that
cannot see the source tree, runs ``sc-fem view``.

The build uses ``--no-build-isolation`` with an interpreter that has the build requirements of
``pyproject.toml``: this one where they are installed (no network), else a scratch venv they are
installed into from the package index, as ``pip install -e .`` (``make venv``) fetches them. The
fresh venv gets the package's dependencies from this interpreter's site-packages through a
``.pth`` file listing that directory, which puts it on ``sys.path`` without running the ``.pth``
files inside it (so the editable install's finder, which maps ``sc_fem`` to ``src/``, stays off).
"""

from __future__ import annotations

import importlib.metadata
import os
import shutil
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from pathlib import Path

import pytest
from packaging.requirements import Requirement

try:
    import tomllib
except ModuleNotFoundError:                                 # Python 3.10 (pytest depends on tomli there)
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
NPM = ROOT / "build" / "npm" / "node_modules"
SOURCE_TREE = ("pyproject.toml", "setup.py", "MANIFEST.in", "README.md", "LICENSE", ".ci", "src")
"""What a clean clone holds that building the package reads (tests, docs, benchmarks are not built)."""
VIEWER_JS = "sc_fem/io/_viewer/viewer.js"
TIMEOUT = 300


def _run(args, **kwargs) -> subprocess.CompletedProcess:
    """Run ``args``; on a non-zero exit fail the test with the command's output."""
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    env["PYTHONNOUSERSITE"] = "1"
    proc = subprocess.run([str(a) for a in args], capture_output=True, text=True, timeout=TIMEOUT, env=env, **kwargs)
    if proc.returncode != 0:
        pytest.fail(f"{' '.join(map(str, args))} exited with {proc.returncode}:\n{proc.stdout[-3000:]}\n"
                    f"{proc.stderr[-3000:]}")
    return proc


def _satisfied(requirement: str) -> bool:
    req = Requirement(requirement)
    try:
        return req.specifier.contains(importlib.metadata.version(req.name), prereleases=True)
    except importlib.metadata.PackageNotFoundError:
        return False


def _venv(path: Path) -> Path:
    """A venv without pip at ``path`` (this interpreter's pip installs into it); its python."""
    _run([sys.executable, "-m", "venv", "--without-pip", path])
    return path / ("Scripts" if os.name == "nt" else "bin") / ("python.exe" if os.name == "nt" else "python")


def _pip(python: Path, *args) -> subprocess.CompletedProcess:
    """This interpreter's pip acting on the environment of ``python``."""
    return _run([sys.executable, "-m", "pip", "--python", python, *args])


def _builder(tmp: Path) -> Path:
    """An interpreter with the build requirements of pyproject.toml (see the module docstring)."""
    requires = tomllib.loads((ROOT / "pyproject.toml").read_text())["build-system"]["requires"]
    if all(_satisfied(r) for r in requires):
        return Path(sys.executable)
    python = _venv(tmp / "buildenv")
    _pip(python, "install", "-q", *requires)
    return python


def _clean_clone(dest: Path) -> bool:
    """Copy the source tree as a fresh clone has it to ``dest``: no bundle, no build products.

    ``build/npm`` (three.js and esbuild, installed by ``make viewer``) is linked in when complete,
    so the wheel build makes the bundle offline; without it, the prebuilt bundle is copied in (and
    True returned)."""
    from sc_fem.io.viewer import BUNDLE

    dest.mkdir(parents=True)
    for name in SOURCE_TREE:
        src = ROOT / name
        if not src.exists():                                # a tree without setup.py fails below, not here
            continue
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=shutil.ignore_patterns(
                "__pycache__", "*.pyc", "*.egg-info", BUNDLE.name))
        else:
            shutil.copy2(src, dest / name)
    if (NPM / ".bin" / "esbuild").is_file() and (NPM / "gltf-validator").is_dir():   # build-viewer.sh's test
        (dest / "build").mkdir()
        (dest / "build" / "npm").symlink_to(NPM.parent, target_is_directory=True)
        return False
    shutil.copy2(BUNDLE, dest / "src" / "sc_fem" / "io" / "_viewer" / BUNDLE.name)
    return True


def test_a_wheel_built_from_a_clean_clone_runs_sc_fem_view(tmp_path):
    from sc_fem.io.viewer import BUNDLE

    if not BUNDLE.is_file():
        pytest.skip("the viewer bundle is not built (make viewer; needs npm)")
    import sc_fem

    tree = tmp_path / "clone"
    prebuilt = _clean_clone(tree)
    assert (tree / "src" / VIEWER_JS).is_file() == prebuilt
    builder = _builder(tmp_path)
    dist = tmp_path / "dist"

    # the wheel, straight from the tree (pip wheel .): setup.py's build_py makes the bundle
    _pip(builder, "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", dist, tree)
    (wheel,) = dist.glob("sc_fem-*.whl")
    with zipfile.ZipFile(wheel) as z:
        names = set(z.namelist())
        assert {VIEWER_JS, "sc_fem/py.typed"} <= names, sorted(n for n in names if not n.endswith(".py"))
        bundle = z.read(VIEWER_JS).decode("utf-8")
    assert "__THREE__" in bundle and len(bundle) > 100_000        # three.js, bundled (not main.js alone)
    assert (tree / "src" / VIEWER_JS).read_text(encoding="utf-8") == bundle     # built in the tree, as make does

    # the sdist: the bundle's sources and build script (and the bundle, built by now), and a wheel
    # built from it alone carries the bundle too
    backend = "import sys; from setuptools import build_meta as b; print(b.build_sdist(sys.argv[1]))"
    sdist = dist / _run([builder, "-c", backend, dist], cwd=tree).stdout.splitlines()[-1]
    with tarfile.open(sdist) as t:
        members = {m.split("/", 1)[1] for m in t.getnames() if "/" in m}
    assert {"setup.py", ".ci/build-viewer.sh", "src/sc_fem/io/_viewer/main.js", "src/" + VIEWER_JS,
            "src/sc_fem/py.typed"} <= members
    from_sdist = tmp_path / "from_sdist"
    _pip(builder, "wheel", "-q", "--no-deps", "--no-build-isolation", "-w", from_sdist, sdist)
    (wheel2,) = from_sdist.glob("sc_fem-*.whl")
    with zipfile.ZipFile(wheel2) as z:
        assert {VIEWER_JS, "sc_fem/py.typed"} <= set(z.namelist())

    # a fresh venv: the wheel, and the dependencies from this interpreter's site-packages
    python = _venv(tmp_path / "fresh")
    _pip(python, "install", "-q", "--no-deps", "--no-index", wheel)
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"]).stdout.strip())
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "_sc_fem_test_dependencies.pth").write_text("".join(f"{d}\n" for d in sorted(deps)))
    where = _run([python, "-c", "import sc_fem, sc_fem.io.viewer as v; print(sc_fem.__file__); print(v.BUNDLE)"],
                 cwd=tmp_path).stdout.splitlines()
    assert Path(where[0]).is_relative_to(site) and Path(where[1]).is_relative_to(site), (where, site)
    assert not Path(where[0]).is_relative_to(ROOT)

    modes = sc_fem.save_modes(sc_fem.modal("builtin:beam", resolution=6, n_modes=2, fix="default"),
                              tmp_path / "beam.modes.npz")
    page = tmp_path / "beam.html"
    script = python.parent / ("sc-fem.exe" if os.name == "nt" else "sc-fem")
    _run([script, "view", modes, "-o", page, "--quiet"], cwd=tmp_path)
    text = page.read_text(encoding="utf-8")
    assert bundle.replace("</script", "<\\/script") in text and 'id="sc-glb"' in text
