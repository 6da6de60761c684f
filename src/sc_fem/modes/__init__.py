"""Modal analysis: the eigen basis of a Scene baked onto its source mesh (:func:`modal`), the
coarsest converged grid (:func:`modal_converged`), and playback (:class:`ModalPlayer`)."""

from .._lazy import lazy_getattr
from .modal import modal  # bound eagerly: it shares its module's name

_NAMES = {"ModalBasis": ".basis", "ModalPlayer": ".player",
          "Damping": ".options", "AutoResolution": ".options",
          "ModalRequest": ".options", "modal_converged": ".auto"}
__all__ = sorted([*_NAMES, "modal"])
__getattr__ = lazy_getattr(__name__, _NAMES)
