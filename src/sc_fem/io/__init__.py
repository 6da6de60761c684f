"""Files and pictures: mode, model and animation files (versioned ``.npz``), and rendering."""

from .._lazy import lazy_getattr

_NAMES = {
    "save_modes": ".modes", "load_modes": ".modes",
    "save_model": ".model", "load_model": ".model",
    "Animation": ".animation", "save_animation": ".animation", "load_animation": ".animation",
    "render": "",
}
__all__ = sorted(_NAMES)
__getattr__ = lazy_getattr(__name__, _NAMES)
