"""Exporting a mode file or an animation for other programs (``sc-fem export``): glTF 2.0 for engines,
Blender and the browser (:func:`sc_fem.io.gltf.export_gltf`), OpenUSD for VFX tools
(:func:`sc_fem.io.usd.export_usd`), or the mode shapes as ``.vtu`` for ParaView
(:func:`sc_fem.io.modes.save_modes_vtu`). :data:`EXPORT_FORMATS` is the one list of what is written."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, Sequence

from ..errors import InputError, ScFemWarning
from .report import JobResult

EXPORT_FORMATS = {".glb": "gltf", ".gltf": "gltf", ".usd": "usd", ".usda": "usd", ".usdc": "usd", ".vtu": "vtu"}
"""Output suffix -> writer (``sc-fem export -o``): ``gltf`` (:func:`sc_fem.io.gltf.export_gltf`),
``usd`` (:func:`sc_fem.io.usd.export_usd`, needs ``usd-core``: ``pip install 'sc_fem[usd]'``),
``vtu`` (:func:`sc_fem.io.modes.save_modes_vtu`, mode files only)."""


def export_to_file(source: Any, output: str | Path, *, amplitude: float = 0.05,
                   impulse: tuple[int, Sequence[float]] | None = None, mode: int | None = None,
                   duration: float = 2.0, fps: float = 30.0, up: str = "z", mesh: Any = None) -> JobResult:
    """Write a mode file or a vertex animation as glTF 2.0 (``.glb``/``.gltf``), OpenUSD
    (``.usd``/``.usda``/``.usdc``), or a mode file's shapes as ``.vtu`` (one point array per mode).

    Parameters
    ----------
    source : ModalBasis, Animation or path
        A mode file (glTF: two morph targets per mode; USD: one blend shape per mode) or an
        animation (glTF: one morph target per frame; USD: time-sampled points).
    output : str or Path
        ``.glb``, ``.gltf``, ``.usd``, ``.usda``, ``.usdc`` or ``.vtu`` (a mode file only, without
        a baked playback); see :data:`EXPORT_FORMATS`.
    amplitude : float
        Largest displacement of a mode at weight 1, fraction of the bounding-box diagonal.
    impulse : (int, (float, float, float)), optional
        Bake the exact response to an impulse (N s) on a source vertex.
    mode : int, optional
        Bake this mode released from weight 1.
    duration : float
        Seconds of baked playback.
    fps : float
        Samples per second of the baked playback.
    up : {"x", "y", "z"}
        The model's up axis (turned onto glTF's +Y; USD's ``upAxis``).
    mesh : path or mesh, optional
        The source mesh (same vertices): its UVs and file normals are kept.

    Returns
    -------
    JobResult
        ``result`` the mode basis or animation exported; the summary names the file and its size.

    Raises
    ------
    InputError
        An output suffix not in :data:`EXPORT_FORMATS`, or options the format does not take.
    ScFemError
        USD output without ``usd-core`` installed (the message says what to install).

    Warns
    -----
    ScFemWarning
        A baked playback moves modes above ``fps / 2`` (they alias).
    """
    from .gltf import _load, alias_warning, moving_modes

    writer = EXPORT_FORMATS.get(Path(output).suffix.lower())
    if writer is None:
        raise InputError(f"cannot export to {Path(output).name!r}: use {', '.join(EXPORT_FORMATS)}")
    if writer == "usd":
        from .usd import _pxr

        _pxr()                                     # a missing usd-core is said before any work
    data = _load(source)
    if writer == "vtu":
        from ..modes.basis import ModalBasis
        from .modes import save_modes_vtu

        if not isinstance(data, ModalBasis):
            raise InputError(f"{source}: only a mode file can be written as .vtu (an animation: "
                             "sc-fem simulate -o run.xdmf)")
        if impulse is not None or mode is not None:
            raise InputError(".vtu holds the mode shapes; --impulse/--mode bake a playback (glTF or USD)")
        path = save_modes_vtu(data, output)
        text = (f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB): point arrays mode_K, field data "
                "frequency_Hz, damping_ratio")
        return JobResult(written=[path], result=data, text=text)
    if writer == "usd":
        from .usd import export_usd as write
    else:
        from .gltf import export_gltf as write
    path = write(data, output, amplitude=amplitude, impulse=impulse, mode=mode, duration=duration, fps=fps,
                 up=up, mesh=mesh)
    baked = impulse is not None or mode is not None
    if baked:                                          # the rule and words of sc-fem play
        warning = alias_warning(data.frequencies, fps, moving_modes(data, impulse=impulse, mode=mode))
        if warning:
            warnings.warn(warning, ScFemWarning, stacklevel=2)
    text = f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB)"
    if writer == "usd":                                # what a Blender user has to set: the frame rate
        from .usd import frame_rate

        if hasattr(data, "n_modes"):
            text += f": {data.n_modes} blend shapes" + (f", weights at {fps:g} fps" if baked else "")
        else:
            text += f": {data.n_frames} frames of points at {frame_rate(data.times, fps):g} fps"
    return JobResult(written=[path], result=data, text=text)
