"""Off-screen rendering with pyvista/VTK (EGL on headless machines).

:func:`~sc_fem.io.opengl.ensure_rendering` checks, in a child process, that an OpenGL context can
be made, so a broken graphics stack raises :class:`~sc_fem.errors.RenderError` with what to
install instead of crashing this process. Images and videos are written atomically.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import re
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np

from .._atomic import atomic_path
from .._progress import stage_bar
from .._validate import as_float_array, positive_int
from ..errors import InputError
from ..units import up_axis
from ..dynamics.contact import Box, Ground, Sphere
from ..lattice.cubes import CubeModel
from ..modes.basis import ModalBasis
from .opengl import ensure_rendering

# VTK_HEXAHEDRON corner order expressed in sc_fem's HEX_CORNERS indices
_VTK_HEX_ORDER = np.array([0, 3, 6, 2, 1, 5, 7, 4])

def pv():
    """The ``pyvista`` module, ready for off-screen rendering (checked by :func:`ensure_rendering`).

    Raises
    ------
    RenderError
        No OpenGL context could be made.
    """
    ensure_rendering()
    with warnings.catch_warnings():
        # importing pyvista imports pooch, which imports tqdm.auto: in a Jupyter kernel without
        # ipywidgets that prints a TqdmWarning (with this machine's site-packages path) although
        # no progress bar is ever shown
        warnings.filterwarnings("ignore", message="IProgress not found")
        import pyvista

    pyvista.OFF_SCREEN = True
    return pyvista


def surface_polydata(vertices: np.ndarray, faces: np.ndarray):
    """A pyvista PolyData of a triangle mesh (or point cloud when there are no faces)."""
    pvm = pv()
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:
        return pvm.PolyData(vertices)
    cells = np.hstack([np.full((len(faces), 1), 3), faces]).ravel()
    return pvm.PolyData(vertices, cells)


def cubes_grid(model: CubeModel, node_positions: np.ndarray | None = None):
    """The cubes as a pyvista UnstructuredGrid of VTK hexahedra (model units)."""
    pvm = pv()
    import vtk

    pts = model.nodes if node_positions is None else np.asarray(node_positions, float)
    conn = model.hexes[:, _VTK_HEX_ORDER]
    cells = np.hstack([np.full((model.n_cubes, 1), 8), conn]).ravel()
    grid = pvm.UnstructuredGrid(cells, np.full(model.n_cubes, vtk.VTK_HEXAHEDRON, dtype=np.uint8), pts)
    grid.cell_data["youngs_Pa"] = model.youngs
    grid.cell_data["mass_kg"] = model.mass
    return grid


def view_vectors(up: str = "z") -> tuple[np.ndarray, np.ndarray]:
    """Camera direction (from the focal point to the camera) and view-up for a model whose up
    axis is ``up``: a three-quarter view from above, the up axis drawn upward."""
    a = up_axis(up)
    e = np.eye(3)
    h1, h2 = e[(a + 1) % 3], e[(a + 2) % 3]
    return 1.0 * h1 - 1.3 * h2 + 0.9 * e[a], e[a]


def frame_camera(plotter, points: np.ndarray, up: str = "z", margin: float = 0.08) -> None:
    """Point the camera so that every point of ``points`` (k, 3) -- e.g. all frames of an animation
    together, obstacles included -- is in the picture, with ``margin`` of the view to spare."""
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    direction, view_up = view_vectors(up)
    plotter.camera_position = [tuple((lo + hi) / 2 + direction), tuple((lo + hi) / 2), tuple(view_up)]
    plotter.reset_camera(bounds=(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]))
    plotter.camera.zoom(1.0 - margin)


def obstacle_meshes(obstacles, around: np.ndarray) -> list:
    """pyvista meshes of contact obstacles (:mod:`sc_fem.dynamics.contact`) to draw; the ground is a
    square 1.5x the horizontal size of ``around`` (k, 3) points."""
    pvm = pv()
    lo, hi = np.min(around, axis=0), np.max(around, axis=0)
    out = []
    for ob in obstacles:                                # a few obstacles
        if isinstance(ob, Ground):
            c = (lo + hi) / 2
            c[ob.axis] = ob.z
            size = 1.5 * float(np.max(np.delete(hi - lo, ob.axis)))
            out.append(pvm.Plane(center=c, direction=np.eye(3)[ob.axis], i_size=size, j_size=size))
        elif isinstance(ob, Sphere):
            out.append(pvm.Sphere(radius=ob.radius, center=ob.center))
        elif isinstance(ob, Box):
            out.append(pvm.Box(bounds=(ob.lo[0], ob.hi[0], ob.lo[1], ob.hi[1], ob.lo[2], ob.hi[2])))
    return out


def write_png(plotter, path) -> Path:
    """Screenshot of a pyvista ``plotter`` written atomically to ``path`` (PNG); returns the path."""
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        plotter.screenshot(str(tmp))
    return path


def plot_cubes_over_mesh(model: CubeModel, mesh, path, *, title: str | None = None,
                         window_size=(1200, 900), up: str = "z") -> Path:
    """Write a PNG of the cube lattice (translucent, with edges) over the source mesh, the whole
    of both in the picture, ``up`` drawn upward."""
    pvm = pv()
    path = Path(path)
    p = pvm.Plotter(off_screen=True, window_size=tuple(window_size))
    try:
        p.set_background("white")
        p.add_mesh(surface_polydata(mesh.vertices, mesh.faces), color="#d9822b", smooth_shading=False)
        p.add_mesh(cubes_grid(model), color="#3a7bd5", opacity=0.35, show_edges=True, edge_color="#1b3a66")
        text = title or (f"{model.info.get('source', '')}: {model.n_cubes:,} cubes, pitch {model.pitch:.3g} "
                         f"model units (h = {model.h:.3g} m)")
        p.add_text(text, font_size=10, color="black")
        p.add_legend([["source mesh", "#d9822b"], ["cubes", "#3a7bd5"]], bcolor="white", size=(0.16, 0.08),
                     loc="lower left")
        frame_camera(p, np.vstack([model.nodes, np.asarray(mesh.vertices, dtype=float)]), up)
        return write_png(p, path)
    finally:
        p.close()


class _CornerClock:
    """Text in the lower right corner, drawn exactly as ``plotter.add_text(text, position="lower_right")``
    draws it, whose text changes every frame without re-adding an actor.

    pyvista draws a named corner with a ``vtkCornerAnnotation``, which fits its font to the window
    whenever its text changes (~90 text measurements, ~30 ms a frame). This draws the annotation's
    lower-right text actor itself (same text mapper, property, justification and position) at the
    size the annotation's fit gives, fitted once per text shape (digits have one advance width).

    Parameters
    ----------
    plotter : pyvista.Plotter
        The plotter to draw in (its active renderer).
    text : str
        The first text.
    font_size : int
        ``font_size`` of ``add_text`` (the annotation's linear font scale is half of it).
    color : str
        Colour of the text.
    """

    def __init__(self, plotter, text: str, font_size: int = 10, color: str = "black"):
        from vtkmodules.vtkRenderingCore import vtkActor2D, vtkTextMapper

        ann = plotter.add_text(text, position="lower_right", font_size=font_size, color=color, render=False)
        plotter.remove_actor(ann, render=False)         # only its text property and fitting constants
        self._fit = (ann.GetLinearFontScaleFactor(), ann.GetNonlinearFontScaleFactor(),
                     ann.GetMaximumLineHeight(), ann.GetMinimumFontSize(), ann.GetMaximumFontSize())
        self._renderer = plotter.renderer
        self.mapper = vtkTextMapper()
        prop = self.mapper.GetTextProperty()
        prop.ShallowCopy(ann.GetTextProperty())
        prop.SetJustificationToRight()
        prop.SetVerticalJustificationToBottom()
        self.actor = vtkActor2D(mapper=self.mapper, property=ann.GetProperty())
        self._sizes: dict[str, int] = {}
        plotter.add_actor(self.actor, reset_camera=False, name="clock", pickable=False, render=False)
        self.set(text)

    def _fitted_size(self, text: str) -> int:
        """The font size ``vtkCornerAnnotation::RenderOpaqueGeometry`` gives ``text`` alone in a corner."""
        linear, nonlinear, line_height, _, largest = self._fit
        w, h = self._renderer.GetSize()
        limit = (int(0.9 * w), int(0.9 * h), int(h * line_height) * (text.count("\n") + 1))
        prop, size, fs = self.mapper.GetTextProperty(), [0, 0], 12

        def excess() -> tuple[int, int, int]:           # text size minus the three limits, pixels
            prop.SetFontSize(fs)
            self.mapper.GetSize(self._renderer, size)
            return size[0] - limit[0], size[1] - limit[1], size[1] - limit[2]

        while max(excess()) < 0 and fs < 100:           # a few dozen sizes, once per text shape
            fs += 1
        while max(excess()) > 0 and fs > 0:
            fs -= 1
        return min(int(fs ** nonlinear * linear), int(largest))

    def set(self, text: str) -> None:
        """Show ``text`` (at the annotation's fitted size); the actor stays the same."""
        w, _ = self._renderer.GetSize()
        self.actor.SetPosition(w - 5, 5)
        key = re.sub(r"[0-9]", "0", text)
        self.mapper.SetInput(text)
        if key not in self._sizes:
            self._sizes[key] = self._fitted_size(text)
        self.mapper.GetTextProperty().SetFontSize(self._sizes[key])
        self.actor.SetVisibility(self._sizes[key] >= self._fit[3])


@contextlib.contextmanager
def _frame_sink(path: Path, kind: str, fps: float):
    """Write frames to ``path`` one at a time; the output appears atomically when the block ends
    without an error.

    Parameters
    ----------
    path : Path
        The output: ``.mp4`` (streamed to ffmpeg, which encodes while the next frames render),
        ``.gif`` or a folder of PNGs.
    kind : {".mp4", ".gif", ""}
        ``path``'s suffix, lower case.
    fps : float
        Frames per second of a video.

    Yields
    ------
    callable
        ``write(image)`` for an RGB image of shape (H, W, 3), uint8.
    """
    import imageio.v2 as imageio

    if kind == ".mp4":
        # macro_block_size=1 keeps odd window sizes; yuv420p plays everywhere
        with atomic_path(path) as tmp, imageio.get_writer(str(tmp), fps=fps, codec="libx264", macro_block_size=1,
                                                          pixelformat="yuv420p", format="FFMPEG") as w:
            yield w.append_data
    elif kind == ".gif":
        images: list[np.ndarray] = []
        yield images.append
        with atomic_path(path) as tmp:
            imageio.mimsave(str(tmp), images, duration=1.0 / fps, loop=0, format="GIF")
    else:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmpdir = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
        count = itertools.count()
        try:
            yield lambda img: imageio.imwrite(tmpdir / f"frame_{next(count):05d}.png", img)
            if path.exists():
                shutil.rmtree(path)
            os.replace(tmpdir, path)
        except BaseException:
            shutil.rmtree(tmpdir, ignore_errors=True)
            raise


def render_animation(frames: np.ndarray, faces: np.ndarray, path, *, fps: float = 30.0,
                     window_size=(960, 720), color: str = "#d9822b", scalars: np.ndarray | None = None,
                     title: str | None = None, progress: bool = False, times=None, up: str = "z",
                     obstacles=(), antialias: bool = False) -> Path:
    """Render a vertex animation to ``.mp4``, ``.gif`` or a folder of PNG frames.

    One plotter, one surface actor, the obstacles, the title, the clock and the camera are made once;
    each frame only overwrites the surface's points (and the clock's text), renders once and hands
    the image to the writer (an ``.mp4`` is encoded by ffmpeg while the next frames render). The
    camera is fixed and frames every position of every frame (and the obstacles near the model),
    so nothing leaves the picture.

    Parameters
    ----------
    frames : ndarray, shape (T, n, 3)
        Vertex positions per frame, model units.
    faces : ndarray of int, shape (m, 3)
        Triangles, indices into the ``n`` vertices.
    path : str or Path
        ``*.mp4``, ``*.gif`` or a directory (created; frames ``frame_00000.png``, ...).
    fps : float
        Frames per second of the video.
    window_size : (int, int)
        Width and height of every frame, pixels.
    color : str
        Colour of the surface.
    scalars : ndarray, optional
        Unused (kept for compatibility).
    title : str, optional
        Text in the upper left corner of every frame.
    progress : bool
        Show a progress bar on stderr.
    times : array_like, shape (T,), optional
        Simulated time of each frame, s: stamped in the lower right corner of every frame.
    up : {"x", "y", "z"}
        The model's up axis (drawn upward).
    obstacles : sequence
        Contact obstacles (:mod:`sc_fem.dynamics.contact`) to draw.
    antialias : bool
        pyvista's multisample anti-aliasing (4 samples on EGL). Off by default: on software OpenGL
        (llvmpipe, the headless default) it costs ~100 ms a frame at 960x720, three times the rest
        of the frame; off, edges are one-pixel stairs and every other pixel is the same.

    Returns
    -------
    Path
        ``path``.
    """
    frames = np.asarray(frames, dtype=float)
    if frames.ndim != 3 or frames.shape[2] != 3 or len(frames) == 0:
        raise InputError(f"frames must have shape (T, n, 3) with T >= 1, got {frames.shape}")
    path = Path(path)
    kind = path.suffix.lower()
    if kind not in (".mp4", ".gif", ""):
        raise InputError(f"unsupported animation output {path.name!r}: use .mp4, .gif or a folder")
    pvm = pv()
    mesh = surface_polydata(frames[0].copy(), faces)   # its points are overwritten in place
    stamps = None if times is None else as_float_array(times, "times", (len(frames),))
    lo, hi = frames.min(axis=(0, 1)), frames.max(axis=(0, 1))
    p = pvm.Plotter(off_screen=True, window_size=tuple(window_size))
    try:
        if not antialias:
            p.disable_anti_aliasing()
        p.set_background("white")
        p.add_mesh(mesh, color=color, smooth_shading=False)
        for ob in obstacle_meshes(obstacles, np.vstack([lo, hi])):
            p.add_mesh(ob, color="#9aa5b1", opacity=0.6)
        if title:
            p.add_text(title, font_size=10, color="black")
        box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        ground = [ob for ob in obstacles if type(ob).__name__ == "Ground"]
        if ground:                                    # keep the ground line in view under the model
            g = box.copy()
            g[:, ground[0].axis] = ground[0].z
            box = np.vstack([box, g])
        frame_camera(p, box, up)
        clock = None if stamps is None else _CornerClock(p, f"t = {stamps[0]:.3f} s")
        points = mesh.points                          # a view of the VTK points: written in place
        with (_frame_sink(path, kind, fps) as write,
              stage_bar("render", len(frames), unit="frame", enabled=progress) as bar):
            for k in range(len(frames)):                  # loop over frames
                points[:] = frames[k]
                mesh.Modified()
                if clock is not None:
                    clock.set(f"t = {stamps[k]:.3f} s")
                p.render()                            # no-op before the first screenshot, which renders
                write(p.screenshot(return_img=True))
                bar.update()
    finally:
        p.close()
    return path


def modes_sheet(basis: ModalBasis, path, *, n_modes: int = 6, columns: int | None = None,
                amplitude: float = 0.08, window_size: tuple[int, int] | None = None, up: str = "z") -> Path:
    """Write a PNG grid of the first mode shapes with their frequencies (pyvista off-screen).

    Each panel shows the rest shape (grey, translucent) and the mode displaced so that its largest
    vertex displacement is ``amplitude`` times the bounding-box diagonal, coloured by the mode's
    displacement magnitude ``|phi|`` in m kg^-1/2 (per unit modal coordinate; colour bar per
    panel), the fixed lattice nodes as red points, ``up`` drawn upward.
    """
    k = min(positive_int(n_modes, "n_modes"), basis.n_modes)
    cols = columns or min(k, 3)
    rows = int(np.ceil(k / cols))
    size = window_size or (420 * cols, 380 * rows)
    pvm = pv()
    rest = np.asarray(basis.vertices, dtype=float)
    diag = float(np.linalg.norm(np.ptp(rest, axis=0)))
    p = pvm.Plotter(off_screen=True, shape=(rows, cols), window_size=tuple(size), border=False)
    try:
        for i in range(k):                                   # loop over modes (panels)
            p.subplot(i // cols, i % cols)
            p.set_background("white")
            shape = np.asarray(basis.modes[i], dtype=float)
            mag = np.linalg.norm(shape, axis=1)
            s = amplitude * diag / max(float(mag.max()), 1e-300)
            p.add_mesh(surface_polydata(rest, basis.faces), color="#bbbbbb", opacity=0.25)
            moved = rest + s * shape
            surf = surface_polydata(moved, basis.faces)
            label = f"|phi{i}| m/kg^.5"                      # one bar per panel (bars are keyed by title)
            surf[label] = mag
            p.add_mesh(surf, scalars=label, cmap="viridis", point_size=4, render_points_as_spheres=True,
                       clim=(0.0, max(float(mag.max()), 1e-300)),
                       scalar_bar_args={"title": label, "vertical": True, "color": "black",
                                        "position_x": 0.8, "position_y": 0.08, "height": 0.6, "width": 0.08,
                                        "fmt": "%.2g", "n_labels": 3, "title_font_size": 11, "label_font_size": 10})
            drawn = [rest, moved]
            if basis.fixed_points is not None and len(basis.fixed_points):
                p.add_points(np.asarray(basis.fixed_points), color="red", point_size=6,
                             render_points_as_spheres=True)
                drawn.append(basis.fixed_points)
            tag = " (rigid)" if basis.rigid[i] else ""
            held = "" if basis.fixed_points is None or not len(basis.fixed_points) else "; red: fixed nodes"
            p.add_text(f"mode {i}: {basis.frequencies[i]:.4g} Hz{tag}{held}", font_size=9, color="black")
            frame_camera(p, np.vstack(drawn), up, margin=0.15)
        return write_png(p, path)
    finally:
        p.close()
