"""Modal analysis: the eigen basis baked onto the source mesh (:func:`modal`), its playback and
pictures (:class:`ModalPlayer`), and batches of meshes."""

from .._lazy import lazy_getattr
from .modal import modal  # bound eagerly: it shares its module's name

_NAMES = {"ModalBasis": ".modal", "ModalPlayer": ".player", "modes_sheet": ".player",
          "run_batch": ".batch", "BatchResult": ".batch", "Damping": ".options", "AutoResolution": ".options",
          "ModalRequest": ".options"}
__all__ = sorted([*_NAMES, "modal"])
__getattr__ = lazy_getattr(__name__, _NAMES)
