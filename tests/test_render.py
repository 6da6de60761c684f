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


def test_missing_opengl_is_a_clear_error(monkeypatch, tmp_path):
    from sc_fem.io import opengl

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setattr(opengl, "_PROBE", "raise SystemExit('no EGL device')")
    opengl.ensure_rendering.cache_clear()
    try:
        with pytest.raises(RenderError, match="apt-get install"):
            opengl.ensure_rendering()
        assert not list(tmp_path.rglob("render-ok-*"))          # a failure is not remembered
    finally:
        opengl.ensure_rendering.cache_clear()


def test_a_successful_check_is_remembered_on_disk(monkeypatch, tmp_path):
    """The second process (here: after clearing the in-process cache) starts no child Python."""
    from sc_fem.io import opengl

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delenv("SC_FEM_NO_RENDER_CACHE", raising=False)
    opengl.ensure_rendering.cache_clear()
    try:
        opengl.ensure_rendering()
        assert len(list(tmp_path.rglob("render-ok-*"))) == 1
        opengl.ensure_rendering.cache_clear()
        monkeypatch.setattr(opengl.subprocess, "run", lambda *a, **k: pytest.fail("probed again"))
        opengl.ensure_rendering()
        monkeypatch.setenv("SC_FEM_NO_RENDER_CACHE", "1")             # the opt-out probes every time
        opengl.ensure_rendering.cache_clear()
        with pytest.raises(pytest.fail.Exception):
            opengl.ensure_rendering()
    finally:
        opengl.ensure_rendering.cache_clear()


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


def _chair_sway(T: int) -> tuple[np.ndarray, np.ndarray]:
    """``T`` frames (T, n, 3) of the chair swaying sideways (more at the top), and its faces."""
    mesh = sc_fem.load_mesh("builtin:chair")
    v = np.asarray(mesh.vertices, dtype=float)
    h = (v[:, 2] - v[:, 2].min()) / np.ptp(v[:, 2])
    sway = 0.1 * np.sin(np.linspace(0.0, np.pi, T))                  # m at the top; 0 at both ends
    frames = v[None] + sway[:, None, None] * (h[:, None] * np.array([1.0, 0.0, 0.0]))[None]
    return frames, np.asarray(mesh.faces)


def _still(frames, faces, k, size, *, title=None, time=None, antialias=False):
    """Frame ``k`` drawn from scratch by a fresh plain-pyvista plotter, with the camera framing all frames."""
    pvm = render.pv()
    lo, hi = frames.min(axis=(0, 1)), frames.max(axis=(0, 1))
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    p = pvm.Plotter(off_screen=True, window_size=size)
    try:
        if not antialias:
            p.disable_anti_aliasing()
        p.set_background("white")
        p.add_mesh(render.surface_polydata(frames[k], faces), color="#d9822b", smooth_shading=False)
        if title:
            p.add_text(title, font_size=10, color="black")
        if time is not None:
            p.add_text(f"t = {time:.3f} s", position="lower_right", font_size=10, color="black")
        render.frame_camera(p, box)
        return p.screenshot(return_img=True)[..., :3].astype(int)
    finally:
        p.close()


def test_video_frames_follow_the_mesh_and_match_still_renders(tmp_path):
    """Every frame is the picture a fresh plotter draws of that frame (title, clock and camera
    included); in the video the frames differ where the mesh moves and agree where it is back."""
    import imageio.v2 as imageio

    T, size = 5, (240, 180)
    frames, faces = _chair_sway(T)                                  # frames 0 and 4 are the rest shape
    before = frames.copy()
    times = np.arange(T) / 30.0
    folder = render.render_animation(frames, faces, tmp_path / "f", window_size=size, title="chair", times=times)
    np.testing.assert_array_equal(frames, before)                   # the caller's frames are left alone
    pngs = [imageio.imread(p)[..., :3].astype(int) for p in sorted(folder.glob("frame_*.png"))]
    for k in (0, 2, 3):
        still = _still(frames, faces, k, size, title="chair", time=times[k])
        assert np.abs(pngs[k] - still).max() == 0, k                 # pixel for pixel
    aa = render.render_animation(frames[:3], faces, tmp_path / "aa", window_size=size, title="chair",
                                 times=times[:3], antialias=True)
    img = imageio.imread(aa / "frame_00002.png")[..., :3].astype(int)
    assert np.abs(img - _still(frames[:3], faces, 2, size, title="chair", time=times[2], antialias=True)).max() == 0

    mp4 = render.render_animation(frames, faces, tmp_path / "a.mp4", fps=10, window_size=size)
    with imageio.get_reader(str(mp4)) as r:
        video = [np.asarray(im, dtype=int) for im in r]
    assert len(video) == T and video[0].shape == (size[1], size[0], 3)
    assert np.abs(video[0] - _still(frames, faces, 0, size)).mean() < 1.5   # H.264 noise only
    assert np.abs(video[2] - video[0]).mean() > 5 * np.abs(video[4] - video[0]).mean()
    assert np.abs(video[2] - video[0]).mean() > 2.0                  # the swayed chair is elsewhere
    assert np.abs(video[1] - video[2]).mean() > 0.5


def test_the_animation_is_one_plotter_one_mesh_updated_in_place(tmp_path, monkeypatch):
    """Meshes, texts and actors are added once whatever the number of frames; the window renders
    once per frame, always with the same actors and camera."""
    pvm = render.pv()
    calls: dict[str, int] = {}
    scenes: list[tuple] = []

    def counted(name):
        original = getattr(pvm.Plotter, name)

        def wrapper(self, *args, **kwargs):
            calls[name] = calls.get(name, 0) + 1
            if name == "add_mesh" and calls[name] == 1:              # count the window's real renders
                self.render_window.AddObserver("StartEvent", lambda *_: calls.__setitem__(
                    "window renders", calls.get("window renders", 0) + 1))
            if name == "screenshot":
                r = self.renderer
                scenes.append((tuple(sorted(r.actors)), r.GetActors().GetNumberOfItems(),
                               r.GetViewProps().GetNumberOfItems(), tuple(r.camera_position)))
            return original(self, *args, **kwargs)

        monkeypatch.setattr(pvm.Plotter, name, wrapper)

    for name in ("add_mesh", "add_actor", "add_text", "screenshot", "clear", "clear_actors", "remove_actor"):
        counted(name)
    from sc_fem.dynamics.contact import Ground

    seen = []
    for T in (3, 9):
        calls.clear()
        scenes.clear()
        frames, faces = _chair_sway(T)
        render.render_animation(frames, faces, tmp_path / f"f{T}", window_size=(96, 72), title="chair",
                                times=np.arange(T) * 0.1, obstacles=[Ground(float(frames[..., 2].min()) - 0.01)])
        assert calls["window renders"] == T and len(scenes) == T     # one render per frame
        assert len(set(scenes)) == 1                                  # same actors, same camera
        assert calls["add_mesh"] == 2                                 # the chair and the ground
        assert not calls.get("clear") and not calls.get("clear_actors")
        seen.append({k: v for k, v in calls.items() if k not in ("window renders", "screenshot")})
    assert seen[0] == seen[1]                                         # nothing added per frame


def test_the_clock_draws_like_a_corner_annotation():
    """The clock's text actor draws what ``add_text(position="lower_right")`` draws, pixel for pixel,
    as its text changes (including the font fitted to a longer text)."""
    pvm = render.pv()
    for size in ((160, 120), (480, 360)):
        for text in ("t = 0.000 s", "t = 1.234 s", "t = 12.345 s"):
            imgs = []
            for own in (False, True):
                p = pvm.Plotter(off_screen=True, window_size=size)
                p.disable_anti_aliasing()
                p.set_background("white")
                if own:
                    render._CornerClock(p, "t = 0.000 s").set(text)
                else:
                    p.add_text(text, position="lower_right", font_size=10, color="black")
                imgs.append(p.screenshot(return_img=True).astype(int))
                p.close()
            assert (imgs[0] < 128).any()                              # some text is drawn
            assert np.abs(imgs[0] - imgs[1]).max() == 0, (size, text)


def test_play_title_says_what_excited_the_model_and_the_magnification(tmp_path, monkeypatch):
    """A video states its excitation and its magnification (or true scale) in its title."""
    import sc_fem.io.playback as playback
    from sc_fem.io.playback import play_modes

    titles = []
    monkeypatch.setattr(playback, "render_animation", lambda frames, faces, out, **kw: titles.append(kw["title"]) or out)
    basis = sc_fem.modal("builtin:beam", resolution=6, n_modes=3)
    play_modes(basis, tmp_path / "a.gif", impulse=(0, (1.0, 0.0, 0.0)), duration=0.1, fps=10, exaggerate=50.0)
    play_modes(basis, tmp_path / "b.gif", mode=1, duration=0.1, fps=10)
    assert "impulse (1, 0, 0) N s at vertex 0" in titles[0] and "x50" in titles[0]
    assert "mode 1" in titles[1] and "true scale" in titles[1]
