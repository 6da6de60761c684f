"""The generalized winding number of broken meshes: ray crossings of the surface closed by a cone
over its holes, less the cone's own share, against libigl's exact (brute-force) winding number."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import sc_fem
from conftest import SHARED_MESHES
from sc_fem.geometry.inside import _closed, boundary_cone, weld, winding_number

igl = pytest.importorskip("igl")


def _holed_sphere() -> trimesh.Trimesh:
    """A sphere with three holes and two flipped faces."""
    s = trimesh.creation.icosphere(3)
    keep = np.ones(len(s.faces), bool)
    keep[[0, 1, 2, 50, 300, 301]] = False
    f = s.faces[keep].copy()
    f[[10, 200]] = f[[10, 200]][:, ::-1]
    return trimesh.Trimesh(s.vertices, f, process=False)


def _soup() -> trimesh.Trimesh:
    """Self-intersecting open boxes (top removed), an open sheet and loose triangles."""
    rng = np.random.default_rng(5)
    parts = []
    for c in ([0, 0, 0], [0.3, 0.2, 0.1]):
        b = trimesh.creation.box(extents=[1, 0.8, 0.6])
        b.apply_translation(c)
        top = b.triangles_center[:, 2] > 0.29 + c[2]
        parts.append(trimesh.Trimesh(b.vertices, b.faces[~top], process=False))
    sheet = trimesh.Trimesh([[-1, -1, 0.05], [1, -1, 0.05], [1, 1, 0.1], [-1, 1, 0.1]], [[0, 1, 2], [0, 2, 3]])
    loose = trimesh.Trimesh(rng.random((30, 3)) - 0.5, np.arange(30).reshape(10, 3), process=False)
    return trimesh.util.concatenate(parts + [sheet, loose])


def _bunny() -> trimesh.Trimesh:
    """The Stanford bunny: a scan with five holes in its base."""
    path = SHARED_MESHES / "bunny.obj"
    if not path.exists():
        pytest.skip(f"shared test mesh {path} not present")
    return sc_fem.load_mesh(path)


CASES = {"bunny": _bunny, "holed_sphere": _holed_sphere, "soup": _soup, "chair": lambda: sc_fem.load_mesh("builtin:chair")}


@pytest.mark.parametrize("case", sorted(CASES))
def test_winding_number_matches_the_exact_solid_angle_sum(case, rng):
    mesh = CASES[case]()
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    lo, hi = v.min(0), v.max(0)
    far = lo - 0.2 * (hi - lo) + 1.4 * (hi - lo) * rng.random((1500, 3))
    fi = rng.integers(0, len(f), 1500)
    bary = rng.dirichlet([1, 1, 1], 1500)
    near = np.einsum("ij,ijk->ik", bary, v[f[fi]]) + 0.01 * np.linalg.norm(hi - lo) * rng.standard_normal((1500, 3))
    q = np.vstack([far, near])
    exact = np.asarray(igl.winding_number(v, f, q))
    w = winding_number(v, f, q)
    assert np.abs(w - exact).max() < 2e-3
    clear = np.abs(exact - 0.5) > 2e-3
    assert np.array_equal(w[clear] > 0.5, exact[clear] > 0.5)
    assert (exact > 0.25).any() and (exact < 0.25).any()      # the points see both sides


@pytest.mark.parametrize("case", ["bunny", "holed_sphere", "soup"])
def test_the_cone_closes_any_soup(case):
    """Faces plus cone use every edge equally often in both directions (the loop over edges
    in :func:`sc_fem.geometry.inside._closed` is the oracle), so the crossing count is exact."""
    mesh = CASES[case]()
    v, f = np.asarray(mesh.vertices, float), np.asarray(mesh.faces, np.int64)
    apex, cone = boundary_cone(v, f)
    assert len(cone) > 0
    allv = np.vstack([v, apex])
    allf = np.vstack([f, cone])
    wf = weld(allv, allf)
    assert _closed(wf, np.zeros(len(allf), np.int64), 1)[0]
    assert not _closed(weld(v, f), np.zeros(len(f), np.int64), 1)[0]
    # a loop oracle for the number of cone triangles: the open edges, counted one by one
    net: dict = {}
    for a, b in wf[: len(f)][:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2).tolist():
        key = (min(a, b), max(a, b))
        net[key] = net.get(key, 0) + (1 if a < b else -1)
    assert sum(abs(n) for n in net.values()) == len(cone)


def test_a_closed_surface_needs_no_cone_and_gets_integers(rng):
    box = trimesh.creation.box(extents=[1, 2, 3])
    apex, cone = boundary_cone(box.vertices, box.faces)
    assert len(cone) == 0 and len(apex) == 0
    q = rng.random((500, 3)) * 4 - 2
    w = winding_number(box.vertices, box.faces, q)
    assert np.array_equal(w, np.rint(w))
    assert np.array_equal(w > 0.5, box.contains(q))
