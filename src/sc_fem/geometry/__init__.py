"""Geometry: reading and validating the source mesh, the built-in models, sampling, inside tests."""

from .._lazy import lazy_getattr

_NAMES = {"load_mesh": ".mesh", "models": ""}
__all__ = sorted(_NAMES)
__getattr__ = lazy_getattr(__name__, _NAMES)
