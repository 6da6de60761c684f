"""Lazy attribute access for packages: ``import sc_fem`` stays cheap and the CLI starts fast."""

from __future__ import annotations

import importlib
import sys
from typing import Any, Callable


def lazy_getattr(package: str, names: dict[str, str]) -> Callable[[str], Any]:
    """A module ``__getattr__`` that imports ``names[attr]`` (a module relative to ``package``) on
    first access and returns its attribute ``attr``; ``names[attr] == ""`` means the submodule."""

    def __getattr__(attr: str) -> Any:
        if attr not in names:
            raise AttributeError(f"module {package!r} has no attribute {attr!r}")
        where = names[attr]
        module = importlib.import_module(where or f".{attr}", package)
        value = module if not where else getattr(module, attr)
        # cache it on the package: also undoes the import system binding a submodule that shares
        # the attribute's name (``rope_scene`` the function vs ``rope_scene`` the module)
        setattr(sys.modules[package], attr, value)
        return value

    return __getattr__
