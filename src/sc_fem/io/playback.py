"""Playing a mode file back (``sc-fem play``) and picturing its modes (``sc-fem modes-sheet``).

:func:`play_modes` excites the modes (an impulse on a vertex, or one mode displaced), advances them
with the exact damped modal oscillators (:class:`sc_fem.modes.player.ModalPlayer`) and renders the
vertex animation (``.mp4``, ``.gif`` or a folder of PNG frames), or plays it in a window.
"""

from __future__ import annotations

import os
import time
import warnings
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from .._validate import positive_scalar
from ..errors import InputError, ScFemWarning
from ..modes.basis import ModalBasis
from ..modes.player import ModalPlayer, playback_warnings
from .gltf import DEFAULT_AMPLITUDE
from .modes import load_modes
from .render import modes_sheet, render_animation, surface_polydata
from .report import JobResult


def _basis(modes: Any) -> Any:
    """A ModalBasis from a basis or a mode-file path."""
    return modes if isinstance(modes, ModalBasis) else load_modes(modes)


def play_modes(modes: Any, output: str | Path | None = None, *,
               impulse: tuple[int, Sequence[float]] | None = None, mode: int | None = None,
               amplitude: float | None = None, duration: float = 2.0, fps: float = 30.0,
               exaggerate: float = 1.0, up: str = "z", progress: bool = False) -> JobResult:
    """Play a mode file back and write the video (or show it in a window).

    Parameters
    ----------
    modes : ModalBasis or path
        The modes (a mode file from ``sc-fem precompute-modes``).
    output : str or Path, optional
        ``.mp4``, ``.gif`` or a folder for PNG frames; None: an interactive window (needs a display).
    impulse : (int, (float, float, float)), optional
        ``(vertex, J)``: an impulse ``J`` (N s) on a source vertex at t = 0.
    mode : int, optional
        Displace this mode at t = 0 (default 0 when there is no ``impulse``).
    amplitude : float, optional
        Largest vertex displacement of ``mode`` at t = 0, as a fraction of the bounding-box
        diagonal (default 0.05; the meaning of ``amplitude`` in :func:`sc_fem.io.export.export_to_file`
        and :func:`sc_fem.io.viewer.write_viewer`: ``sc-fem export --mode K`` releases the same
        displacement); only with ``mode`` (or neither ``mode`` nor ``impulse``).
    duration : float
        Seconds played.
    fps : float
        Frames per second.
    exaggerate : float
        Factor on the displacements drawn.
    up : {"x", "y", "z"}
        The model's up axis, drawn upward.
    progress : bool
        A progress bar of the rendering on stderr.

    Returns
    -------
    JobResult
        ``result`` the :class:`~sc_fem.ModalBasis`; the summary names the video and its frames
        (empty for a window).

    Warns
    -----
    ScFemWarning
        Modes above half the frame rate (they alias), or motion too small to see
        (:func:`sc_fem.modes.player.playback_warnings`).
    """
    player = ModalPlayer(_basis(modes))
    b = player.basis
    if impulse is not None:
        player.impulse(int(impulse[0]), [float(j) for j in impulse[1]])
    if mode is not None or impulse is None:
        diag = float(np.linalg.norm(np.ptp(b.vertices, axis=0)))
        fraction = DEFAULT_AMPLITUDE if amplitude is None else positive_scalar(amplitude, "amplitude")
        player.excite(0 if mode is None else mode, fraction * diag)
    elif amplitude is not None:
        raise InputError("--amplitude needs --mode")
    if output is None:
        if not os.environ.get("DISPLAY"):
            raise InputError("no display for an interactive window: give -o out.mp4, out.gif or a folder")
        _window(player, duration, fps, exaggerate)
        return JobResult(result=b)
    frames = player.frames(duration, fps)
    if exaggerate != 1.0:
        frames = b.vertices[None] + exaggerate * (frames - b.vertices[None])
    for w in playback_warnings(b, frames, fps, exaggerate):
        warnings.warn(w, ScFemWarning, stacklevel=2)
    if impulse is not None:
        j = ", ".join(f"{float(x):.3g}" for x in impulse[1])
        what = f"impulse ({j}) N s at vertex {int(impulse[0])}" + (f" + mode {mode} displaced" if mode is not None else "")
    else:
        what = f"mode {0 if mode is None else mode} ({b.frequencies[0 if mode is None else mode]:.3g} Hz) displaced"
    title = (f"{b.source}: {b.n_modes} modes, {b.frequencies[0]:.3g}..{b.frequencies[-1]:.3g} Hz; {what}"
             + (f"; motion x{exaggerate:g}" if exaggerate != 1.0 else "; true scale"))
    path = render_animation(np.asarray(frames), b.faces, output, fps=fps, title=title, progress=progress,
                            times=np.arange(len(frames)) / fps, up=up)
    return JobResult(written=[path], result=b, text=f"wrote {path} ({len(frames)} frames at {fps:g} fps)")


def _window(player: Any, duration: float, fps: float, exaggerate: float) -> None:  # pragma: no cover - display
    """Play in an interactive pyvista window for ``duration`` seconds of wall time."""
    import pyvista as pv

    b = player.basis
    mesh = surface_polydata(b.vertices, b.faces)
    p = pv.Plotter(title="sc-fem play")
    p.add_mesh(mesh, color="#d9822b")
    p.show(interactive_update=True)
    dt = 1.0 / fps
    t_end = time.perf_counter() + duration
    while time.perf_counter() < t_end:
        mesh.points = b.vertices + exaggerate * (player.step(dt) - b.vertices)
        p.update()
        time.sleep(max(0.0, dt - 0.002))
    p.close()


def modes_sheet_to_file(modes: Any, output: str | Path, *, n_modes: int = 6, columns: int | None = None,
                        up: str = "z") -> JobResult:
    """Write a PNG grid of the first mode shapes of a mode file (:func:`sc_fem.io.render.modes_sheet`).

    Parameters
    ----------
    modes : ModalBasis or path
        The modes (a mode file).
    output : str or Path
        The ``.png``.
    n_modes : int
        Modes shown (at most the basis's).
    columns : int, optional
        Panels per row (default 3).
    up : {"x", "y", "z"}
        The model's up axis, drawn upward.

    Returns
    -------
    JobResult
        ``result`` the :class:`~sc_fem.ModalBasis`; the summary names the picture.
    """
    basis = _basis(modes)
    path = modes_sheet(basis, output, n_modes=n_modes, columns=columns, up=up)
    return JobResult(written=[path], result=basis, text=f"wrote {path} ({min(n_modes, basis.n_modes)} modes)")
