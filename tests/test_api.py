"""The public API: every name in ``sc_fem.__all__`` resolves, and the Python examples of the README
and of the documentation pages (``docs/**/*.md``) run."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import sc_fem

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").rglob("*.md"))]
"""The README and every Markdown page of the docs: each ```python block is an example that runs."""


def _python_blocks() -> list:
    blocks = []
    for page in PAGES:
        found = re.findall(r"```python\n(.*?)```", page.read_text(), flags=re.DOTALL)
        name = page.relative_to(ROOT).as_posix()
        blocks += [pytest.param(page, block, id=f"{name}[{k}]") for k, block in enumerate(found)]
    return blocks


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


def test_the_docs_have_examples_to_run():
    pages = {param.values[0] for param in _python_blocks()}
    assert README in pages and len(pages) >= 8


@pytest.mark.parametrize(("page", "block"), _python_blocks())
def test_readme_python_examples_run(page, block, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(block, str(page), "exec"), {})


def test_the_package_declares_its_type_hints():
    """PEP 561: ``py.typed`` ships with the package (listed in the package data)."""
    from pathlib import Path

    root = Path(sc_fem.__file__).parent
    assert (root / "py.typed").is_file()
    pyproject = (root.parents[1] / "pyproject.toml").read_text()
    assert '"py.typed"' in pyproject
