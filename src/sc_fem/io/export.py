"""Exporting a mode file or an animation for other programs (``sc-fem export``): glTF 2.0 for engines,
Blender and the browser (:func:`sc_fem.io.gltf.export_gltf`), OpenUSD for VFX tools
(:func:`sc_fem.io.usd.export_usd`), or the mode shapes as ``.vtu`` or ``.vtkhdf`` for ParaView
(:func:`sc_fem.io.modes.save_modes_vtu`, :func:`sc_fem.io.paraview.save_modes_vtkhdf`).
:data:`EXPORT_FORMATS` is the one list of what is written."""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any, Sequence

from ..errors import InputError, ScFemWarning
from ..modes.basis import ModalBasis
from .animation import Animation, resample_animation
from .gltf import DEFAULT_AMPLITUDE, MAX_ANIMATION_TARGETS, _load, alias_warning, export_gltf, moving_modes
from .modes import save_modes_vtu
from .paraview import save_modes_vtkhdf
from .report import JobResult
from .usd import _pxr, export_usd

EXPORT_FORMATS = {".glb": "gltf", ".gltf": "gltf", ".usd": "usd", ".usda": "usd", ".usdc": "usd", ".vtu": "vtu",
                  ".vtkhdf": "vtkhdf"}
"""Output suffix -> writer (``sc-fem export -o``): ``gltf`` (:func:`sc_fem.io.gltf.export_gltf`),
``usd`` (:func:`sc_fem.io.usd.export_usd`, needs ``usd-core``: ``pip install 'sc_fem[usd]'``),
``vtu`` (:func:`sc_fem.io.modes.save_modes_vtu`, mode files only), ``vtkhdf`` (the same content as
VTKHDF, :func:`sc_fem.io.paraview.save_modes_vtkhdf`, mode files only)."""


def _sig_floor(x: float, digits: int = 3) -> float:
    """``x`` > 0 rounded down to ``digits`` significant digits (a value people can type)."""
    step = 10.0 ** (math.floor(math.log10(x)) - digits + 1)
    return float(f"{math.floor(x / step * (1 + 1e-12)) * step:.{digits}g}")


def _animation_at(anim: Any, fps: float | None, duration: float | None, max_frames: int | None) -> Any:
    """``anim`` at ``fps`` (default its stored rate) over ``duration`` seconds (default all of it),
    :func:`sc_fem.io.animation.resample_animation` when that differs from what is stored; at most
    ``max_frames`` frames, or an InputError saying which ``--fps`` / ``--duration`` fit."""
    stored = anim.frame_rate
    same = fps is None or stored is None or abs(float(fps) - stored) <= 1e-9 * stored
    if not (same and duration is None):
        anim = resample_animation(anim, stored if fps is None else fps, duration=duration)
    if max_frames is not None and anim.n_frames > max_frames:
        rate, secs = anim.frame_rate, float(anim.times[-1] - anim.times[0])
        raise InputError(f"the animation would be {anim.n_frames} frames ({secs:g} s at {rate:g} fps); glTF takes at "
                         f"most {max_frames} (one morph target per frame; USD takes any number): export it with --fps "
                         f"{_sig_floor((max_frames - 1) / secs)} or lower, or --duration "
                         f"{_sig_floor((max_frames - 1) / rate)} or shorter")
    return anim


def export_to_file(source: Any, output: str | Path, *, amplitude: float | None = None,
                   impulse: tuple[int, Sequence[float]] | None = None, mode: int | None = None,
                   duration: float | None = None, fps: float | None = None, up: str = "z",
                   mesh: Any = None, quantize: bool = False) -> JobResult:
    """Write a mode file or a vertex animation as glTF 2.0 (``.glb``/``.gltf``), OpenUSD
    (``.usd``/``.usda``/``.usdc``), or a mode file's shapes as ``.vtu`` / ``.vtkhdf`` (one point
    array per mode).

    Parameters
    ----------
    source : ModalBasis, Animation or path
        A mode file (glTF: two morph targets per mode; USD: one blend shape per mode) or an
        animation (glTF: one morph target per frame; USD: time-sampled points).
    output : str or Path
        ``.glb``, ``.gltf``, ``.usd``, ``.usda``, ``.usdc``, or ``.vtu`` / ``.vtkhdf`` (a mode file
        only, without a baked playback); see :data:`EXPORT_FORMATS`.
    amplitude : float, optional
        Largest vertex displacement of a mode at weight 1 (and of ``mode`` when released), as a
        fraction of the bounding-box diagonal (default 0.05, as ``sc-fem play`` and ``view``).
    impulse : (int, (float, float, float)), optional
        Bake the exact response to an impulse (N s) on a source vertex.
    mode : int, optional
        Bake this mode released from weight 1.
    duration : float, optional
        Seconds: of baked playback (default 2), or of an animation from its first frame (default
        all of it).
    fps : float, optional
        Frames per second: of a baked playback (default 30; sampled exactly), or of an animation
        (default its stored rate; another rate resamples it with
        :func:`~sc_fem.io.animation.resample_animation`: linear interpolation in time, the stored
        frames themselves when ``fps`` divides the stored rate). glTF takes at most
        :data:`sc_fem.io.gltf.MAX_ANIMATION_TARGETS` frames.
    up : {"x", "y", "z"}
        The model's up axis (turned onto glTF's +Y; USD's ``upAxis``).
    mesh : path or mesh, optional
        The source mesh (same vertices): its UVs and file normals are kept.
    quantize : bool
        glTF only: 16-bit positions and displacements, 8-bit normals (``KHR_mesh_quantization``;
        see :func:`sc_fem.io.gltf.export_gltf`), the weights unchanged.

    Returns
    -------
    JobResult
        ``result`` the mode basis or the animation exported (resampled when it was); the summary
        names the file, its size and, for an animation, its frames and rate.

    Raises
    ------
    InputError
        An output suffix not in :data:`EXPORT_FORMATS`, options the format does not take
        (``quantize`` outside glTF, a baked playback as ``.vtu`` / ``.vtkhdf``), or an animation longer than glTF
        takes (the message names the ``--fps`` / ``--duration`` that fit).
    ScFemError
        USD output without ``usd-core`` installed (the message says what to install).

    Warns
    -----
    ScFemWarning
        A baked playback moves modes above ``fps / 2`` (they alias; the rule and words of ``sc-fem play``).
    """
    writer = EXPORT_FORMATS.get(Path(output).suffix.lower())
    if writer is None:
        raise InputError(f"cannot export to {Path(output).name!r}: use {', '.join(EXPORT_FORMATS)}")
    if quantize and writer != "gltf":
        raise InputError(f"--quantize applies to glTF only (.glb, .gltf: KHR_mesh_quantization), not to "
                         f"{Path(output).suffix.lower()}")
    if writer == "usd":
        _pxr()                                     # a missing usd-core is said before any work
    data = _load(source)
    amplitude = DEFAULT_AMPLITUDE if amplitude is None else amplitude
    if writer in ("vtu", "vtkhdf"):
        if not isinstance(data, ModalBasis):
            raise InputError(f"{source}: only a mode file can be written as .{writer} (an animation: "
                             "sc-fem simulate -o run.xdmf)")
        if impulse is not None or mode is not None:
            raise InputError(f".{writer} holds the mode shapes; --impulse/--mode bake a playback (glTF or USD)")
        path = (save_modes_vtu if writer == "vtu" else save_modes_vtkhdf)(data, output)
        text = (f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB): point arrays mode_K, field data "
                "frequency_Hz, damping_ratio")
        return JobResult(written=[path], result=data, text=text)
    write = export_usd if writer == "usd" else export_gltf
    if isinstance(data, Animation):
        if impulse is not None or mode is not None:
            raise InputError("--impulse / --mode bake a playback of a mode file; an animation is exported with "
                             "its own frames (--fps / --duration resample it)")
        stored = data
        data = _animation_at(data, fps, duration, MAX_ANIMATION_TARGETS if writer == "gltf" else None)
        fps = data.frame_rate or 30.0
    else:
        fps, duration = 30.0 if fps is None else fps, 2.0 if duration is None else duration
    path = write(data, output, amplitude=amplitude, impulse=impulse, mode=mode, duration=duration, fps=fps,
                 up=up, mesh=mesh, **({"quantize": True} if quantize else {}))
    baked = impulse is not None or mode is not None
    if baked:                                          # the rule and words of sc-fem play
        warning = alias_warning(data.frequencies, fps, moving_modes(data, impulse=impulse, mode=mode))
        if warning:
            warnings.warn(warning, ScFemWarning, stacklevel=2)
    text = f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB)"
    if isinstance(data, Animation):                    # what a Blender user has to set: the frame rate
        what = "points" if writer == "usd" else "morph targets"
        text += f": {data.n_frames} frames of {what} at {fps:g} fps"
        if data is not stored:
            text += (f", resampled from the {stored.n_frames} at {stored.frame_rate:g} fps stored "
                     f"({data.meta['resampling']})")
    elif writer == "usd":
        text += f": {data.n_modes} blend shapes" + (f", weights at {fps:g} fps" if baked else "")
    return JobResult(written=[path], result=data, text=text)
