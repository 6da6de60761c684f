"""The cube-rope scene (coarse and short so it stays fast)."""

import numpy as np

from sc_fem.geometry import models
from sc_fem.dynamics.rope_scene import rope_scene


def test_rope_scene_swings_down_and_curves_follow_surface():
    sc = rope_scene(n_frames=6, fps=60, resolution=16, substeps=20, n_curves=24, n_points=832)
    assert sc.curves.shape == (6, 24, 832, 3)
    assert sc.times.shape == (6,) and sc.times[1] == 1 / 60
    assert sc.vertex_positions.shape[0] == 6 and sc.vertex_positions.shape[2] == 3
    assert np.all(np.isfinite(sc.curves))
    h = sc.model.h
    # frame 0 is the rest pose; curve points lie on the rope's square surface: the larger of the
    # y and z offsets from the axis is the half-width (points on edges: both are)
    c0 = sc.curves[0]
    lo, hi = models.load("rope").bounds
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    assert half[1] == half[2]
    off = np.maximum(np.abs(c0[..., 1] - centre[1]), np.abs(c0[..., 2] - centre[2]))
    np.testing.assert_allclose(off, half[1], rtol=0, atol=1e-9 * half[1])
    # gravity pulls the free end down, the fixed end stays
    dz = sc.curves[-1, :, :, 2] - c0[:, :, 2]
    assert dz[:, -1].mean() < -0.05 * h
    assert abs(dz[:, 0].mean()) < abs(dz[:, -1].mean())
    np.testing.assert_allclose(sc.timings["per_frame"], sc.timings["simulate"] / (6 - 1), rtol=1e-12)
