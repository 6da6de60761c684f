"""The public API: every name in ``sc_fem.__all__`` resolves, and the README's Python examples run."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import sc_fem

README = Path(__file__).resolve().parents[1] / "README.md"


def test_every_public_name_resolves():
    missing = [n for n in sc_fem.__all__ if getattr(sc_fem, n, None) is None]
    assert missing == []
    assert len(sc_fem.__all__) == len(set(sc_fem.__all__))


def test_functions_are_not_shadowed_by_their_modules():
    import importlib

    for name, module in (("voxelize", "lattice.voxelize"), ("embed", "lattice.embed"),
                         ("assemble", "fem.assemble"), ("modal", "modes.modal"), ("rope_scene", "dynamics.rope_scene")):
        importlib.import_module(f"sc_fem.{module}")
        assert callable(getattr(sc_fem, name)), name
        package = importlib.import_module(f"sc_fem.{module.split('.')[0]}")
        assert callable(getattr(package, name)), f"sc_fem.{module.split('.')[0]}.{name}"


def test_subpackages_export_what_they_list():
    for package in ("geometry", "lattice", "fem", "modes", "dynamics", "io"):
        mod = getattr(sc_fem, package)
        missing = [n for n in mod.__all__ if getattr(mod, n, None) is None]
        assert missing == [], package


def test_no_deprecated_aliases():
    """Nothing has been released, so no old name is kept: the module aliases and ModeFileError are
    gone, and importing or using the package raises no DeprecationWarning of its own."""
    for old in ("models", "integrators", "xpbd", "render", "ModeFileError"):
        assert not hasattr(sc_fem, old)
    assert sc_fem.geometry.models.material("builtin:chair").density > 0
    from pathlib import Path

    package = Path(sc_fem.__file__).parent
    assert [p.name for p in package.rglob("*.py") if "DeprecationWarning" in p.read_text()] == []


def test_errors_share_one_base():
    for name in sc_fem.__all__:
        obj = getattr(sc_fem, name)
        if isinstance(obj, type) and issubclass(obj, Exception):
            assert issubclass(obj, sc_fem.ScFemError)


@pytest.mark.parametrize("block", re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S))
def test_readme_python_examples_run(block, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(block, str(README), "exec"), {})


def test_the_package_declares_its_type_hints():
    """PEP 561: ``py.typed`` ships with the package (listed in the package data)."""
    from pathlib import Path

    root = Path(sc_fem.__file__).parent
    assert (root / "py.typed").is_file()
    pyproject = (root.parents[1] / "pyproject.toml").read_text()
    assert '"py.typed"' in pyproject
