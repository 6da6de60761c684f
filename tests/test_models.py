"""Built-in models: real-world size, documented material, and the defects they are meant to have."""

from __future__ import annotations

import numpy as np
import pytest

import sc_fem
from sc_fem.geometry import models


@pytest.mark.parametrize("name, extents", [("chair", (0.47, 0.49, 0.86)), ("bridge", (24.0, 4.2, 9.0)),
                                           ("rope", (1.0, 0.0525, 0.0525)), ("beam", (1.0, 0.1, 0.1))])
def test_sizes_in_metres(name, extents):
    m = models.load(name)
    np.testing.assert_allclose(m.extents, extents, atol=0.01)
    mat = models.material(name)
    assert mat.youngs > 0 and -1 < mat.poisson < 0.5 and mat.density > 0
    assert models.fix_specs(name)


def test_chair_parts_intersect():
    m = models.load("chair")
    parts = m.split(only_watertight=False)
    assert len(parts) >= 7
    seat = max(parts, key=lambda p: p.area)
    # some other part's vertices lie inside the seat box: the parts overlap
    inside = [np.any(seat.bounding_box.contains(p.vertices)) for p in parts if p is not seat]
    assert sum(inside) >= 4


def test_bridge_has_gaps_isolated_polygons_and_skinny_triangles():
    m = models.load("bridge")
    parts = m.split(only_watertight=False)
    assert sum(len(p.faces) == 1 for p in parts) >= 2                      # isolated polygons
    tri = m.vertices[m.faces]
    edges = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2)
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    aspect = edges.max(axis=1) ** 2 / np.maximum(area, 1e-30)
    assert np.sum(aspect > 500) >= 2                                        # skinny triangles
    cables = [p for p in parts if len(p.faces) == 32]                      # 8-sided cylinders
    assert len(cables) == 16
    lowest = np.array([c.vertices[:, 2].min() for c in cables])
    assert np.all(lowest > 3.2 + 0.01)                                      # they stop short of the deck top
    # the cables are welded to the deck (5 cm < the default weld, 0.5 % of 24 m); the isolated
    # polygons float 0.35-0.4 m above it: bodies of their own, loose (< 1 % of the mass), not kept
    vox = sc_fem.voxelize(m, resolution=32)
    assert vox.n_components == 1 and vox.info["bodies"] == 3 and vox.info["loose_bodies"] == 2
    # joins by distance (groups left by nesting, less the bodies); that each cable is welded to the
    # deck by the default weld is tested pair by pair in test_bodies
    assert vox.info["welds_by_distance"] >= 1
    # the seed's grid topology: at a coarse pitch the gaps close and it is one connected structure
    assert sc_fem.voxelize(m, resolution=32, keep="all", topology="grid").n_components == 1


def test_rope_is_a_chain_of_overlapping_cubes():
    m = models.load("rope")
    parts = m.split(only_watertight=False)
    assert len(parts) == 20
    xs = sorted(p.bounds[0, 0] for p in parts)
    assert np.all(np.diff(xs) < parts[0].extents[0] - 1e-3)   # spacing below the cube size: they overlap
    assert m.extents[0] / m.extents[1] == pytest.approx(19.0, rel=0.01)


def test_unknown_model():
    with pytest.raises(sc_fem.InputError, match="choose one of"):
        models.load("teapot")


def test_expand_default_fix():
    assert models.expand_fix(["default", "x<0.1"], "builtin:chair") == ["z<min+0.01", "x<0.1"]
    with pytest.raises(sc_fem.BoundaryConditionError, match="builtin"):
        models.expand_fix(["default"], "my.obj")
