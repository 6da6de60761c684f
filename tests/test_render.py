"""Off-screen rendering works headless, and a missing OpenGL stack is a clear error."""

from __future__ import annotations

import numpy as np
import pytest

import sc_fem
from sc_fem.io import render
from sc_fem.errors import InputError, RenderError


def test_picture_and_animation(tmp_path):
    mesh = sc_fem.load_mesh("builtin:chair")
    model = sc_fem.voxelize(mesh, resolution=10)
    png = render.plot_cubes_over_mesh(model, mesh, tmp_path / "c.png")
    import imageio.v2 as imageio

    img = imageio.imread(png)
    assert img.shape[2] in (3, 4) and img.std() > 5          # not a blank image
    frames = mesh.vertices[None] + np.linspace(0, 0.05, 4)[:, None, None]
    gif = render.render_animation(frames, mesh.faces, tmp_path / "a.gif", fps=8, window_size=(160, 120))
    assert len(imageio.mimread(gif)) == 4
    folder = render.render_animation(frames, mesh.faces, tmp_path / "frames", window_size=(160, 120))
    assert len(list(folder.glob("frame_*.png"))) == 4
    mp4 = render.render_animation(frames, mesh.faces, tmp_path / "a.mp4", fps=8, window_size=(160, 120))
    assert mp4.stat().st_size > 0
    assert not list(tmp_path.glob(".*tmp*"))                  # no temporary files left behind


def test_missing_opengl_is_a_clear_error(monkeypatch):
    monkeypatch.setattr(render, "_PROBE", "raise SystemExit('no EGL device')")
    render.ensure_rendering.cache_clear()
    try:
        with pytest.raises(RenderError, match="apt-get install"):
            render.ensure_rendering()
    finally:
        render.ensure_rendering.cache_clear()


def test_bad_animation_input(tmp_path):
    with pytest.raises(InputError):
        render.render_animation(np.zeros((0, 3, 3)), np.zeros((1, 3), int), tmp_path / "a.gif")
    with pytest.raises(InputError, match="unsupported"):
        render.render_animation(np.zeros((1, 3, 3)), np.array([[0, 1, 2]]), tmp_path / "a.avi")
