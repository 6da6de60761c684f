"""Modal analysis: the eigen basis baked onto the source mesh (:func:`modal`), its playback and
playback (:class:`ModalPlayer`)."""

from .._lazy import lazy_getattr
from .modal import modal  # bound eagerly: it shares its module's name

_NAMES = {"ModalBasis": ".basis", "ModalPlayer": ".player",
          "Damping": ".options", "AutoResolution": ".options",
          "ModalRequest": ".options"}
__all__ = sorted([*_NAMES, "modal"])
__getattr__ = lazy_getattr(__name__, _NAMES)
