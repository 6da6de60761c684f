"""Off-screen rendering with pyvista/VTK (EGL on headless machines).

:func:`ensure_rendering` checks once per process, in a child process, that an OpenGL context
can be made, so a broken graphics stack raises :class:`~sc_fem.errors.RenderError` with what to
install instead of crashing this process. Images and videos are written atomically.
"""

from __future__ import annotations

import functools
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from .._atomic import atomic_path
from ..errors import InputError, RenderError
from ..lattice.cubes import CubeModel

# VTK_HEXAHEDRON corner order expressed in sc_fem's HEX_CORNERS indices
_VTK_HEX_ORDER = np.array([0, 3, 6, 2, 1, 5, 7, 4])

_PROBE = (
    "import pyvista as pv\n"
    "p = pv.Plotter(off_screen=True, window_size=(32, 32))\n"
    "p.add_mesh(pv.Cube())\n"
    "img = p.screenshot(return_img=True)\n"
    "p.close()\n"
    "assert img.shape[0] == 32\n"
)


def _configure_env() -> None:
    if not os.environ.get("DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


@functools.lru_cache(maxsize=1)
def ensure_rendering() -> str:
    """Make sure off-screen rendering works; returns the render window class name used.

    Raises
    ------
    RenderError
        No OpenGL context could be made (says what to install).
    """
    _configure_env()
    try:
        res = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120,
                             env=dict(os.environ))
    except (OSError, subprocess.TimeoutExpired) as exc:
        raise RenderError(f"could not start the rendering check: {exc}") from None
    if res.returncode != 0:
        tail = (res.stderr or res.stdout).strip().splitlines()[-3:]
        raise RenderError(
            "off-screen rendering is not available: no OpenGL context could be made "
            f"({' | '.join(tail)}). Install an EGL/OSMesa driver (Debian: apt-get install libegl1 "
            "libgl1-mesa-dri, or libosmesa6 with VTK_DEFAULT_OPENGL_WINDOW=vtkOSOpenGLRenderWindow), "
            "or run under a virtual display (xvfb-run).")
    return os.environ.get("VTK_DEFAULT_OPENGL_WINDOW", "default")


def pv():
    """The ``pyvista`` module, ready for off-screen rendering (checked by :func:`ensure_rendering`).

    Raises
    ------
    RenderError
        No OpenGL context could be made.
    """
    ensure_rendering()
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


def write_png(plotter, path) -> Path:
    """Screenshot of a pyvista ``plotter`` written atomically to ``path`` (PNG); returns the path."""
    path = Path(path)
    with atomic_path(path, suffix=".png") as tmp:
        plotter.screenshot(str(tmp))
    return path


def plot_cubes_over_mesh(model: CubeModel, mesh, path, *, title: str | None = None,
                         window_size=(1200, 900)) -> Path:
    """Write a PNG of the cube lattice (translucent, with edges) over the source mesh."""
    pvm = pv()
    path = Path(path)
    p = pvm.Plotter(off_screen=True, window_size=tuple(window_size))
    try:
        p.set_background("white")
        p.add_mesh(surface_polydata(mesh.vertices, mesh.faces), color="#d9822b", smooth_shading=False)
        p.add_mesh(cubes_grid(model), color="#3a7bd5", opacity=0.35, show_edges=True, edge_color="#1b3a66")
        text = title or f"{model.info.get('source', '')}: {model.n_cubes} cubes, pitch {model.pitch:.3g}"
        p.add_text(text, font_size=10, color="black")
        p.view_vector((1.0, -1.3, 0.9))
        p.reset_camera()
        p.camera.zoom(1.25)
        return write_png(p, path)
    finally:
        p.close()


def render_animation(frames: np.ndarray, faces: np.ndarray, path, *, fps: float = 30.0,
                     window_size=(960, 720), color: str = "#d9822b", scalars: np.ndarray | None = None,
                     title: str | None = None, progress: bool = False) -> Path:
    """Render a vertex animation to ``.mp4``, ``.gif`` or a folder of PNG frames.

    Parameters
    ----------
    frames : ndarray, shape (T, n, 3)
        Vertex positions per frame, model units.
    faces : ndarray of int, shape (m, 3)
    path : str or Path
        ``*.mp4``, ``*.gif`` or a directory (created; frames ``frame_00000.png``, ...).
    fps : float
        Frames per second of the video.
    """
    frames = np.asarray(frames, dtype=float)
    if frames.ndim != 3 or frames.shape[2] != 3 or len(frames) == 0:
        raise InputError(f"frames must have shape (T, n, 3) with T >= 1, got {frames.shape}")
    path = Path(path)
    kind = path.suffix.lower()
    if kind not in (".mp4", ".gif", ""):
        raise InputError(f"unsupported animation output {path.name!r}: use .mp4, .gif or a folder")
    pvm = pv()
    import imageio.v2 as imageio

    mesh = surface_polydata(frames[0], faces)
    p = pvm.Plotter(off_screen=True, window_size=tuple(window_size))
    lo, hi = frames.min(axis=(0, 1)), frames.max(axis=(0, 1))
    try:
        p.set_background("white")
        p.add_mesh(mesh, color=color, smooth_shading=False)
        if title:
            p.add_text(title, font_size=10, color="black")
        p.view_isometric()
        p.reset_camera(bounds=(lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]))
        from tqdm import tqdm

        images = []
        for k in tqdm(range(len(frames)), desc="render", disable=not progress, file=sys.stderr):
            mesh.points = frames[k]
            p.render()
            images.append(p.screenshot(return_img=True))
    finally:
        p.close()
    if kind == "":
        import shutil
        import tempfile

        path.parent.mkdir(parents=True, exist_ok=True)
        tmpdir = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
        try:
            for k, img in enumerate(images):
                imageio.imwrite(tmpdir / f"frame_{k:05d}.png", img)
            if path.exists():
                shutil.rmtree(path)
            os.replace(tmpdir, path)
        except BaseException:
            shutil.rmtree(tmpdir, ignore_errors=True)
            raise
        return path
    with atomic_path(path) as tmp:
        if kind == ".mp4":
            # macro_block_size=1 keeps odd window sizes; yuv420p plays everywhere
            with imageio.get_writer(str(tmp), fps=fps, codec="libx264", macro_block_size=1,
                                    pixelformat="yuv420p", format="FFMPEG") as w:
                for img in images:
                    w.append_data(img)
        else:
            imageio.mimsave(str(tmp), images, duration=1.0 / fps, loop=0, format="GIF")
    return path
