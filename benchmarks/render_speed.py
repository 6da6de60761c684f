"""Video rendering speed: ``sc_fem.io.render.render_animation`` against a rebuild-every-frame loop, in one run.

Run:  .venv/bin/python benchmarks/render_speed.py [--quick] [--frames 60] [--size 960x720]

The animation is the built-in chair's modal strike (8 modes at resolution 16, the feet fixed, an
impulse on the top of the backrest, played at 30 frames/s, exaggerated to 4 % of the diagonal: the
demo's ``chair_play``), rendered off-screen to ``.mp4`` with the title and the clock of ``sc-fem play``.
Each row is the wall time of one whole call (plotter, every frame, H.264 encoding, the file):

* ``render_animation``: one plotter and one surface actor, each frame overwrites its points,
  renders once and streams the image to ffmpeg (the default: no multisampling);
* ``render_animation(antialias=True)``: the same with 4x multisample anti-aliasing (the pictures
  of the previous implementation, pixel for pixel);
* ``rebuild every frame``: the peer, a plain pyvista loop that clears the plotter, adds a new mesh
  and the texts and writes the frame (``Plotter.clear_actors`` / ``add_mesh`` / ``write_frame``), with
  pyvista's default multisampling (timed on the first 20 frames: it is the slow one) and without.

The last column is the mean absolute difference (0-255) of the video's first frame from the first
row's, so the rows are seen to draw the same picture. Writes benchmarks/out/render_speed.png.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, print_table, save_figure  # noqa: E402


def chair_strike(n_frames: int, fps: float = 30.0):
    """Frames (T, n, 3), faces, times (T,) and title of the chair struck on its backrest."""
    import sc_fem
    from sc_fem.geometry import models
    from sc_fem.modes.player import ModalPlayer

    basis = sc_fem.modal("builtin:chair", resolution=16, n_modes=8, fix=list(models.fix_specs("chair")))
    player = ModalPlayer(basis)
    player.impulse(int(np.argmax(basis.vertices[:, 2])), [2.0, 1.0, 0.0])
    frames = np.asarray(player.frames(n_frames / fps, fps), dtype=float)[:n_frames]
    disp = frames - basis.vertices[None]
    scale = 0.04 * float(np.linalg.norm(np.ptp(basis.vertices, axis=0))) / max(float(np.abs(disp).max()), 1e-300)
    title = f"{basis.source}: {basis.n_modes} modes, {basis.frequencies[0]:.3g}..{basis.frequencies[-1]:.3g} Hz"
    return basis.vertices[None] + scale * disp, np.asarray(basis.faces), np.arange(len(frames)) / fps, title


def rebuild_every_frame(frames, faces, times, title, path, size, fps, antialias: bool) -> Path:
    """The peer: a plain pyvista loop that rebuilds the scene for every frame."""
    from sc_fem.io.render import frame_camera, pv

    pvm = pv()
    cells = np.hstack([np.full((len(faces), 1), 3), faces]).ravel()
    lo, hi = frames.min(axis=(0, 1)), frames.max(axis=(0, 1))
    box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    p = pvm.Plotter(off_screen=True, window_size=size)
    if not antialias:
        p.disable_anti_aliasing()
    p.set_background("white")
    frame_camera(p, box)
    cpos = p.camera_position
    p.open_movie(str(path), framerate=fps, codec="libx264", macro_block_size=1, pixelformat="yuv420p")
    for k in range(len(frames)):                                     # loop over frames
        p.clear_actors()                                             # (clear() would drop the lights too)
        p.add_mesh(pvm.PolyData(frames[k], cells), color="#d9822b", smooth_shading=False)
        p.add_text(title, font_size=10, color="black")
        p.add_text(f"t = {times[k]:.3f} s", position="lower_right", font_size=10, color="black")
        p.camera_position = cpos
        p.write_frame()
    p.close()
    return path


def first_frame(path: Path) -> np.ndarray:
    import imageio.v2 as imageio

    with imageio.get_reader(str(path)) as r:
        return np.asarray(r.get_data(0), dtype=float)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="skip the multisampled rows (the slow ones)")
    ap.add_argument("--frames", type=int, default=60, help="frames of the animation (default 60: 2 s)")
    ap.add_argument("--size", default="960x720", help="frame size WxH (default 960x720)")
    args = ap.parse_args(argv)
    size = tuple(int(s) for s in args.size.lower().split("x"))
    fps = 30.0

    from sc_fem.io.render import ensure_rendering, render_animation

    t0 = time.perf_counter()
    frames, faces, times, title = chair_strike(args.frames, fps)
    print(f"chair strike: {len(frames)} frames of {frames.shape[1]} vertices, {len(faces)} triangles "
          f"({time.perf_counter() - t0:.1f} s); OpenGL: {ensure_rendering()}", file=sys.stderr)

    def ours(antialias, n):
        return lambda out: render_animation(frames[:n], faces, out, fps=fps, window_size=size, title=title,
                                            times=times[:n], antialias=antialias)

    def peer(antialias, n):
        return lambda out: rebuild_every_frame(frames[:n], faces, times[:n], title, out, size, fps, antialias)

    T, short = len(frames), min(len(frames), 20)          # the slowest peer (~0.5 s a frame) on 20 frames
    cases = [("render_animation", "off", ours(False, T), 3, T), ("rebuild every frame", "off", peer(False, T), 1, T)]
    if not args.quick:
        cases.insert(1, ("render_animation(antialias=True)", "4x MSAA", ours(True, T), 1, T))
        cases.append(("rebuild every frame", "4x MSAA", peer(True, short), 1, short))
    rows, ref, fps_of = [], None, {}
    with tempfile.TemporaryDirectory() as tmp:
        render_animation(frames[:2], faces, Path(tmp) / "warm.mp4", window_size=size, title=title,
                         times=times[:2])                            # imports and shaders, not timed
        for i, (name, aa, fn, repeat, n) in enumerate(cases):
            out = Path(tmp) / f"case{i}.mp4"
            t, _ = best_time(lambda fn=fn, out=out: fn(out), repeat=repeat)
            img = first_frame(out)
            ref = img if ref is None else ref
            fps_of[(name, aa)] = n / t
            rows.append([name, aa, n, t, 1000 * t / n, n / t, float(np.abs(img - ref).mean())])
            print(f"  {name} ({aa}): {n / t:.1f} frames/s", file=sys.stderr)
    base = fps_of[("render_animation", "off")]
    for r in rows:
        r.insert(6, base / r[5])
    print(f"\nchair modal strike, {len(frames)} frames at {size[0]}x{size[1]}, off-screen, to .mp4 "
          f"(wall time of the whole call, best of the repeats)\n")
    print_table(["path", "anti-aliasing", "frames", "time [s]", "ms/frame", "frames/s",
                 "render_animation is x faster", "frame 0 mean |diff|"], rows, floatfmt=".3g")
    for ours_name, aa in (("render_animation", "off"), ("render_animation(antialias=True)", "4x MSAA")):
        if (ours_name, aa) in fps_of and ("rebuild every frame", aa) in fps_of:
            print(f"\n{ours_name} vs rebuild every frame (anti-aliasing {aa}): "
                  f"{fps_of[(ours_name, aa)] / fps_of[('rebuild every frame', aa)]:.2f}x the frames/s")
    print(f"target >= 20 frames/s: {'met' if base >= 20 else 'NOT met'} ({base:.1f})")

    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.2))
    labels = [f"{r[0]}\n({r[1]})" for r in rows]
    ax.barh(labels[::-1], [r[5] for r in rows][::-1], color=["#3a7bd5" if "render_anim" in r[0] else "#999999"
                                                            for r in rows][::-1])
    ax.axvline(20, color="#d9822b", ls="--", label="target 20 frames/s")
    ax.set_xlabel(f"frames/s (chair, {size[0]}x{size[1]}, to .mp4)")
    ax.legend(loc="lower right")
    save_figure(fig, "render_speed.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
