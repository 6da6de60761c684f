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


def test_old_module_names_still_work():
    """Names users already import from keep working after the move into subpackages."""
    assert sc_fem.models.material("builtin:chair").density > 0
    assert sc_fem.integrators.make_integrator is sc_fem.dynamics.make_integrator
    assert sc_fem.xpbd.XPBDSolver is sc_fem.XPBDSolver
    assert callable(sc_fem.render.render_animation)


def test_errors_share_one_base():
    for name in sc_fem.__all__:
        obj = getattr(sc_fem, name)
        if isinstance(obj, type) and issubclass(obj, Exception):
            assert issubclass(obj, sc_fem.ScFemError)


@pytest.mark.parametrize("block", re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S))
def test_readme_python_examples_run(block, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(block, str(README), "exec"), {})
