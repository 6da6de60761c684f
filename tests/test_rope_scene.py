"""The cube-rope scene (coarse and short so it stays fast)."""

import numpy as np

from sc_fem.rope_scene import rope_scene


def test_rope_scene_swings_down_and_curves_follow_surface():
    sc = rope_scene(n_frames=6, fps=60, resolution=16, substeps=20, n_curves=24, n_points=832)
    assert sc.curves.shape == (6, 24, 832, 3)
    assert sc.times.shape == (6,) and sc.times[1] == 1 / 60
    assert sc.vertex_positions.shape[0] == 6 and sc.vertex_positions.shape[2] == 3
    assert np.all(np.isfinite(sc.curves))
    h = sc.model.h
    # frame 0 is the rest pose; curve points lie on the rope's surface (|y| or |z| at half-width)
    c0 = sc.curves[0]
    half = 0.0525 / 2
    assert np.all(np.maximum(np.abs(c0[..., 1]), np.abs(c0[..., 2] - half)) > half - 1e-6)
    # gravity pulls the free end down, the fixed end stays
    dz = sc.curves[-1, :, :, 2] - c0[:, :, 2]
    assert dz[:, -1].mean() < -0.05 * h
    assert abs(dz[:, 0].mean()) < abs(dz[:, -1].mean())
    assert sc.timings["per_frame"] > 0
