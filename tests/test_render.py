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


def _orange(img):
    """Mask of the model's colour (#d9822b, shaded) in an RGB image."""
    r, g, b = (img[..., k].astype(int) for k in range(3))
    return (r > g + 25) & (g > b + 15) & (r > 60)


def test_the_camera_frames_every_frame_and_draws_time_and_ground(tmp_path):
    """A bar that travels 3 lengths sideways and falls onto a ground stays inside every frame; the
    time stamp changes the corner; the ground is drawn (grey) under the model."""
    import imageio.v2 as imageio

    from sc_fem.dynamics.contact import Ground

    mesh = sc_fem.load_mesh("builtin:beam")
    T = 5
    shift = np.zeros((T, 1, 3))
    shift[:, 0, 1] = np.linspace(0.0, 3.0, T)                   # 3 m sideways
    frames = np.asarray(mesh.vertices)[None] + shift
    folder = render.render_animation(frames, mesh.faces, tmp_path / "f", window_size=(240, 180),
                                     times=np.arange(T) * 0.1, obstacles=[Ground(-0.5)])
    imgs = [imageio.imread(p)[..., :3] for p in sorted(folder.glob("frame_*.png"))]
    for img in imgs:
        m = _orange(img)
        assert m.sum() > 50                                     # the bar is in the picture ...
        assert not (m[0].any() or m[-1].any() or m[:, 0].any() or m[:, -1].any())   # ... entirely
        grey = (np.abs(img.astype(int) - 160).max(axis=2) < 30)
        assert grey.sum() > 0.05 * grey.size                    # the ground
    corner = [img[-30:, -120:].astype(int) for img in imgs]
    assert np.abs(corner[1] - corner[0]).sum() > 0              # "t = 0.100 s" replaced "t = 0.000 s"


def test_up_axis_draws_a_y_up_model_upright():
    d, up = render.view_vectors("y")
    assert up.tolist() == [0.0, 1.0, 0.0] and d[1] > 0          # looking down on it from above
    d, up = render.view_vectors("z")
    assert up.tolist() == [0.0, 0.0, 1.0] and d[2] > 0
    with pytest.raises(InputError, match="up must be"):
        render.view_vectors("w")


def test_mode_sheet_marks_fixed_nodes_and_has_colour_bars(tmp_path):
    import imageio.v2 as imageio

    basis = sc_fem.modal("builtin:beam", resolution=8, fix="x<min+1e-6", n_modes=2)
    assert basis.fixed_points is not None and np.all(basis.fixed_points[:, 0] < 1e-6)
    from sc_fem.io.render import modes_sheet

    img = imageio.imread(modes_sheet(basis, tmp_path / "s.png", n_modes=2, window_size=(640, 300)))[..., :3]
    r, g, b = (img[..., k].astype(int) for k in range(3))
    assert ((r > 180) & (g < 60) & (b < 60)).sum() > 10        # red fixed nodes
    bars = img[:, int(0.8 * 320):int(0.88 * 320)]               # left panel's colour bar (viridis yellow)
    assert ((bars[..., 0] > 200) & (bars[..., 1] > 200) & (bars[..., 2] < 80)).sum() > 10
    # the positions survive the mode file
    back = sc_fem.load_modes(sc_fem.save_modes(basis, tmp_path / "m.npz"))
    np.testing.assert_array_equal(back.fixed_points, basis.fixed_points)
