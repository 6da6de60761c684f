"""``sc-fem reconstruct`` on what ``sc-fem simulate`` writes, for every built-in and shared mesh:
no crash, and the PDE fits the fitted frames at least as well as the B-spline baseline."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from sc_fem import Scene
from sc_fem._cli.main import main
from sc_fem.dynamics.job import run_simulation
from sc_fem.io.animation import load_animation, write_animation
from sc_fem.io.reconstruction import load_reconstruction
from sc_fem.reconstruct import reconstruct_animation
from sc_fem.units import gravity_down

FIT = list(range(0, 21, 2))


def _animation(source, path):
    """21 frames (0.2 s) of a soft copy of ``source`` sagging under gravity, one end held."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                 # size / point-cloud notes of odd meshes
        scene = Scene.from_mesh(source, resolution=10, fix="x<min+1e-9", youngs=1e6, poisson=0.3, density=1000)
    rec = run_simulation(scene, dt=0.01, duration=0.2, gravity=gravity_down(), fps=100)
    return write_animation(path, scene, rec)


def _check(res):
    f = res.fitted
    assert res.meta["pde_matches_bspline_at_fitted_frames"]
    assert res.E_A_pde[f].mean() <= res.E_A_bspline[f].mean()
    assert res.E_M_pde[f].max() <= res.E_M_bspline[f].max()
    assert np.all(np.isfinite(res.curves_pde)) and res.E_M_pde.max() < 0.2


@pytest.mark.parametrize("name", ["chair", "bridge", "rope", "beam"])
def test_every_builtin(tmp_path, name):
    anim = _animation(f"builtin:{name}", tmp_path / "a.npz")
    out = tmp_path / "r.npz"
    assert main(["reconstruct", str(anim), "--fit-frames", ",".join(map(str, FIT)), "-o", str(out)]) == 0
    _check(load_reconstruction(out))


@pytest.mark.slow
def test_every_shared_mesh(tmp_path, shared_meshes):
    files = sorted(p for p in shared_meshes.iterdir() if p.suffix.lower() in (".obj", ".off", ".stl"))
    assert len(files) >= 8
    for path in files:                                # one animation per mesh (a handful)
        res = reconstruct_animation(load_animation(_animation(str(path), tmp_path / f"{path.stem}.npz")), FIT)
        _check(res)


def test_segments_and_offset_are_counted_and_refused_when_impossible(tmp_path):
    anim = load_animation(_animation("builtin:rope", tmp_path / "a.npz"))
    one = reconstruct_animation(anim, FIT, segments=1, offset="none", curves_from="mesh")
    four = reconstruct_animation(anim, FIT, segments=4, offset="first", curves_from="mesh")
    assert one.meta["segments"] == 1 and four.meta["segments"] == 4 and four.meta["offset"] == "first"
    # every piece carries its 96 constants and 6 rigid numbers per fitted frame; offset="first"
    # adds the stored first frame (3 per point of every 17-point piece); r and alpha are shared
    key = "PDE scalars (coefficients + r, alpha + rigid)"
    n_fit, curves = len(FIT), 8
    assert one.meta["counts"][key] == curves * 96 + 2 + 6 * n_fit * curves
    pieces = 4 * curves
    assert four.meta["counts"][key] == pieces * 96 + 2 + 6 * n_fit * pieces + pieces * 17 * 3
    assert four.E_A_pde[four.fitted].mean() < one.E_A_pde[one.fitted].mean()
    from sc_fem.errors import InputError

    with pytest.raises(InputError, match="at least 8"):
        reconstruct_animation(anim, FIT, segments=20, curves_from="mesh")


def test_simulate_stores_the_lattice_and_reconstruct_maps_its_node_lines_back_exactly(tmp_path):
    """simulate writes the lattice (node motion + W); reconstruct fits its node lines and rebuilds
    the mesh through W -- closer to the simulated mesh than curves of mesh vertices. A lattice whose
    node lines are incomplete (the chair) is refused with the reason."""

    scene = Scene.from_mesh("builtin:beam", resolution=24, fix="x<min+1e-9", youngs=1e6, poisson=0.3, density=1000)
    rec = run_simulation(scene, dt=0.01, duration=0.2, gravity=gravity_down(), fps=100)
    anim = load_animation(write_animation(tmp_path / "a.npz", scene, rec))
    L = anim.lattice
    assert L is not None and L.displacements.shape == (anim.n_frames, len(L.rest), 3)
    moved = anim.rest_vertices[None] + np.einsum("vq,tqc->tvc", L.W.toarray(), L.displacements)
    scale = np.abs(anim.positions - anim.rest_vertices).max()
    np.testing.assert_allclose(moved, anim.positions, rtol=0, atol=1e-6 * scale)   # float32 storage

    lat = reconstruct_animation(anim, FIT, curves_from="lattice")
    mesh = reconstruct_animation(anim, FIT)                       # auto: no stored curves -> mesh curves
    assert lat.meta["curves_from"] == "lattice" and mesh.meta["curves_from"] == "mesh"
    assert lat.curves_reference.shape[1:] == (16, 25, 3)         # 4 x 4 node lines of 25 nodes
    # the mesh rebuilt through W from the fitted node lines is several times closer to the
    # simulated mesh than the one moved by inverse distance from curves of vertices
    assert lat.mesh_error_pde.max() < 0.5 * mesh.mesh_error_pde.max()
    assert lat.E_M_pde.max() < 0.01
    out = tmp_path / "r.npz"                                      # the same from the command line
    assert main(["reconstruct", str(tmp_path / "a.npz"), "--fit-frames", ",".join(map(str, FIT)),
                 "--curves-from", "lattice", "-o", str(out)]) == 0
    back = load_reconstruction(out)
    assert back.meta["curves_from"] == "lattice"
    np.testing.assert_allclose(back.vertices_pde, lat.vertices_pde, rtol=0, atol=1e-6)

    chair = load_animation(_animation("builtin:chair", tmp_path / "c.npz"))
    assert chair.lattice is not None
    from sc_fem.errors import InputError

    with pytest.raises(InputError, match="complete"):
        reconstruct_animation(chair, FIT, curves_from="lattice")
    with pytest.raises(InputError, match="curves_from"):
        reconstruct_animation(chair, FIT, curves_from="nodes")


def test_a_broken_lattice_track_is_a_file_format_error(tmp_path):
    from sc_fem.errors import FileFormatError
    from sc_fem.io.animation import load_animation

    path = _animation("builtin:beam", tmp_path / "a.npz")
    data = dict(np.load(path))
    for key, bad in (("lattice_displacements", data["lattice_displacements"][:-1]),
                     ("lattice_W_indices", data["lattice_W_indices"] + 10**6),
                     ("lattice_rest", None)):
        broken = {k: v for k, v in data.items() if not (bad is None and k == key)}
        if bad is not None:
            broken[key] = bad
        np.savez(tmp_path / "b.npz", **broken)
        with pytest.raises(FileFormatError, match="lattice|embedding"):
            load_animation(tmp_path / "b.npz")


def test_surface_point_curves_store_no_vertex_index_and_bad_counts_are_input_errors(tmp_path):
    """A box of 8 vertices gets its curves through points on its surface: those are not mesh
    vertices, so no ``curve_vertex_index`` is stored (it once indexed past the 8 vertices);
    non-integer piece or control-point counts are refused, not truncated."""
    from sc_fem.errors import InputError

    anim = load_animation(_animation("builtin:beam", tmp_path / "a.npz"))
    res = reconstruct_animation(anim, FIT, curves_from="mesh")
    assert res.curve_vertex_index is None and res.vertices_pde.shape[1] == 8
    for bad in ({"segments": 2.7}, {"segments": "x"}, {"n_control": 7.5}):
        with pytest.raises(InputError):
            reconstruct_animation(anim, FIT, **bad)
