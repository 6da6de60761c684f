"""Exporting a mode file or an animation for other programs (``sc-fem export``): glTF 2.0 for engines,
Blender and the browser (:func:`sc_fem.io.gltf.export_gltf`), or the mode shapes as ``.vtu`` for
ParaView (:func:`sc_fem.io.modes.save_modes_vtu`)."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any, Sequence

from ..errors import InputError, ScFemWarning
from .report import JobResult


def export_to_file(source: Any, output: str | Path, *, amplitude: float = 0.05,
                   impulse: tuple[int, Sequence[float]] | None = None, mode: int | None = None,
                   duration: float = 2.0, fps: float = 30.0, up: str = "z", mesh: Any = None) -> JobResult:
    """Write a mode file or a vertex animation as glTF 2.0 (``.glb``/``.gltf``), or a mode file's
    shapes as ``.vtu`` (one point array per mode).

    Parameters
    ----------
    source : ModalBasis, Animation or path
        A mode file (two morph targets per mode) or an animation (one morph target per frame).
    output : str or Path
        ``.glb``, ``.gltf`` or ``.vtu`` (a mode file only, without a baked playback).
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
        The model's up axis (turned onto glTF's +Y).
    mesh : path or mesh, optional
        The source mesh (same vertices): its UVs and file normals are kept.

    Returns
    -------
    JobResult
        ``result`` the mode basis or animation exported; the summary names the file and its size.

    Warns
    -----
    ScFemWarning
        A baked playback moves modes above ``fps / 2`` (they alias).
    """
    from .gltf import _load, alias_warning, export_gltf, moving_modes

    data = _load(source)
    if str(output).lower().endswith(".vtu"):
        from ..modes.basis import ModalBasis
        from .modes import save_modes_vtu

        if not isinstance(data, ModalBasis):
            raise InputError(f"{source}: only a mode file can be written as .vtu (an animation: "
                             "sc-fem simulate -o run.xdmf)")
        if impulse is not None or mode is not None:
            raise InputError(".vtu holds the mode shapes; --impulse/--mode bake a playback, which is glTF's")
        path = save_modes_vtu(data, output)
        text = (f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB): point arrays mode_K, field data "
                "frequency_Hz, damping_ratio")
        return JobResult(written=[path], result=data, text=text)
    path = export_gltf(data, output, amplitude=amplitude, impulse=impulse, mode=mode, duration=duration, fps=fps,
                       up=up, mesh=mesh)
    if impulse is not None or mode is not None:        # the rule and words of sc-fem play
        warning = alias_warning(data.frequencies, fps, moving_modes(data, impulse=impulse, mode=mode))
        if warning:
            warnings.warn(warning, ScFemWarning, stacklevel=2)
    return JobResult(written=[path], result=data, text=f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB)")
