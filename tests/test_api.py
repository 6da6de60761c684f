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

    for name in ("voxelize", "embed", "assemble", "modal"):
        importlib.import_module(f"sc_fem.{name}")
        assert callable(getattr(sc_fem, name)), name


def test_errors_share_one_base():
    for name in sc_fem.__all__:
        obj = getattr(sc_fem, name)
        if isinstance(obj, type) and issubclass(obj, Exception):
            assert issubclass(obj, sc_fem.ScFemError)


@pytest.mark.parametrize("block", re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S))
def test_readme_python_examples_run(block, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    exec(compile(block, str(README), "exec"), {})
