"""Files and pictures: mode, model, animation and reconstruction files (versioned ``.npz``), rendering,
exports (glTF, VTU, the web viewer), and the jobs the command line runs (one function per verb)."""

from .._lazy import lazy_getattr

_NAMES = {
    "save_modes": ".modes", "load_modes": ".modes",
    "save_model": ".model", "load_model": ".model",
    "Animation": ".animation", "save_animation": ".animation", "load_animation": ".animation",
    "resample_animation": ".animation",
    "save_reconstruction": ".reconstruction", "load_reconstruction": ".reconstruction",
    "run_batch": ".precompute", "BatchResult": ".batch", "modes_sheet": ".render",
    "voxelize_to_file": ".voxelize", "precompute_modes": ".precompute", "play_modes": ".playback",
    "simulate_to_file": ".simulation", "reconstruct_to_file": ".reconstruction", "export_to_file": ".export",
    "run_demo": ".demo", "JobResult": ".report",
    "render": "",
}
__all__ = sorted(_NAMES)
__getattr__ = lazy_getattr(__name__, _NAMES)
