"""ParaView files (:mod:`sc_fem.io.paraview`): mode shapes as VTKHDF, read back by VTK's own reader
(through pyvista); the lattice series of a simulated ``.xdmf`` run with its strain energy density,
read back by meshio and VTK; the energy density against the analytic one of a uniform strain."""

from __future__ import annotations

import numpy as np
import pytest

import sc_fem
from sc_fem.errors import InputError
from sc_fem.lattice.cubes import CubeModel
from sc_fem.material import lame
from sc_fem.units import gravity_down


@pytest.fixture(scope="module")
def beam_modes():
    return sc_fem.modal("builtin:beam", resolution=8, n_modes=3, fix="x<min+0.01")


def test_modes_export_as_vtkhdf_read_back_by_vtk_equal_the_vtu(beam_modes, tmp_path):
    """``sc-fem export modes.npz -o modes.vtkhdf``: pyvista (vtkHDFReader) reads the mesh, one point
    array per mode (the stored float32 modes exactly) and the field data; the same arrays as the .vtu."""
    import h5py
    import pyvista as pv
    import vtk

    from sc_fem._cli.main import main

    npz = sc_fem.save_modes(beam_modes, tmp_path / "beam.modes.npz")
    stored = sc_fem.load_modes(npz)
    out, vtu = tmp_path / "beam.vtkhdf", tmp_path / "beam.vtu"
    assert main(["export", str(npz), "-o", str(out), "--quiet"]) == 0
    assert main(["export", str(npz), "-o", str(vtu), "--quiet"]) == 0
    with h5py.File(out, "r") as f:                                     # the layout every VTKHDF reader takes
        assert f["VTKHDF"].attrs["Type"] == b"UnstructuredGrid" and list(f["VTKHDF"].attrs["Version"]) == [1, 0]
    grid, ref = pv.read(out), pv.read(vtu)
    assert isinstance(grid, pv.UnstructuredGrid)
    np.testing.assert_array_equal(grid.points, stored.vertices)
    assert set(grid.celltypes) == {pv.CellType.TRIANGLE} and grid.n_cells == len(stored.faces)
    np.testing.assert_array_equal(grid.cell_connectivity, np.ravel(stored.faces))
    assert sorted(grid.point_data) == ["mode_0", "mode_1", "mode_2"] == sorted(ref.point_data)
    for k in range(3):
        np.testing.assert_array_equal(grid.point_data[f"mode_{k}"], stored.modes[k])
        np.testing.assert_array_equal(grid.point_data[f"mode_{k}"], ref.point_data[f"mode_{k}"])
    np.testing.assert_array_equal(grid.field_data["frequency_Hz"], stored.frequencies)
    np.testing.assert_array_equal(grid.field_data["damping_ratio"], stored.damping)
    np.testing.assert_array_equal(grid.field_data["rigid"], stored.rigid.astype(np.int8))
    np.testing.assert_array_equal(grid.field_data["scale"], [stored.scale])
    for name in ref.field_data:
        np.testing.assert_array_equal(grid.field_data[name], ref.field_data[name])
    reader = vtk.vtkHDFReader()                                        # VTK itself, without pyvista
    reader.SetFileName(str(out))
    reader.Update()
    assert reader.GetOutput().GetNumberOfPoints() == len(stored.vertices)


def test_vtkhdf_of_a_point_set_and_bad_input(beam_modes, tmp_path):
    import dataclasses

    import pyvista as pv

    from sc_fem.io.paraview import save_modes_vtkhdf

    cloud = dataclasses.replace(beam_modes, faces=np.zeros((0, 3), np.int64))
    grid = pv.read(save_modes_vtkhdf(cloud, tmp_path / "cloud.vtkhdf"))
    assert grid.n_cells == grid.n_points == len(cloud.vertices) and set(grid.celltypes) == {pv.CellType.VERTEX}
    with pytest.raises(InputError, match=r"\.vtkhdf"):
        save_modes_vtkhdf(beam_modes, tmp_path / "x.h5")
    with pytest.raises(InputError, match="ModalBasis"):
        save_modes_vtkhdf("not modes", tmp_path / "x.vtkhdf")
    assert not list(tmp_path.glob("x*")) and not list(tmp_path.glob(".*"))


@pytest.mark.parametrize("element", ["q1", "q1i", "q1sri"])
def test_uniform_strain_gives_the_analytic_energy_density_in_every_cube(element):
    """u = eps x (+ a translation) on a box: w = 0.5 sigma:eps = 0.5 (lambda tr(eps)^2 + 2 mu eps:eps)
    in every cube and frame, to 1e-10 relative."""
    from sc_fem.io.paraview import strain_energy_density

    E, nu = 3e6, 0.35
    model = CubeModel.box((3, 2, 4), 0.5, youngs=E, poisson=nu, scale=0.02, origin=(1.0, -2.0, 0.5))
    lam, mu = (float(np.ravel(v)[0]) for v in lame(E, nu))
    rng = np.random.default_rng(7)
    a = rng.normal(size=(5, 3, 3)) * 1e-3
    eps = 0.5 * (a + a.transpose(0, 2, 1))                                       # (T, 3, 3)
    eps[0] = np.diag([1e-3, 0.0, 0.0])                                           # a plain stretch
    u = np.einsum("tij,mj->tmi", eps, model.nodes_m) + rng.normal(size=(5, 1, 3)) * 1e-4   # (T, m, 3) m
    sigma = lam * np.trace(eps, axis1=1, axis2=2)[:, None, None] * np.eye(3) + 2 * mu * eps
    exact = 0.5 * np.einsum("tij,tij->t", sigma, eps)                            # (T,) J/m^3
    w = strain_energy_density(model, u, element)
    assert w.shape == (5, model.n_cubes)
    np.testing.assert_allclose(w, np.broadcast_to(exact[:, None], w.shape), rtol=1e-10, atol=0)
    np.testing.assert_allclose(strain_energy_density(model, u[2], element), w[2], rtol=1e-14)   # one frame
    assert np.allclose(strain_energy_density(model, np.zeros_like(u)), 0.0)
    with pytest.raises(InputError, match="shape"):
        strain_energy_density(model, u[:, :-1])
    with pytest.raises(InputError, match="non-finite"):
        strain_energy_density(model, np.full_like(u, np.nan))


def test_simulated_xdmf_carries_the_lattice_with_its_energy_density(tmp_path, monkeypatch):
    """``simulate -o run.xdmf``: ``run_lattice.xdmf`` beside it reads back with meshio (hexahedra, the
    cell data at every step) and VTK (positive hexahedron volumes); the energy density integrates
    to the run's elastic energy and the node displacements are the run's."""
    import meshio
    import pyvista as pv

    from sc_fem.io.simulation import simulate_to_file
    from sc_fem.scene import Scene

    out = tmp_path / "run.xdmf"
    res = simulate_to_file("builtin:beam", out, duration=0.01, fps=500, voxel={"resolution": 10}, fix="default",
                           gravity=gravity_down(), dt=1e-3)
    rec, lattice = res.result, tmp_path / "run_lattice.xdmf"
    assert res.written == [out, lattice] and "run_lattice.xdmf" in res.text
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.h5", "run.xdmf", "run_lattice.h5", "run_lattice.xdmf"]
    model = Scene.from_mesh("builtin:beam", {"resolution": 10}, fix="default").model
    with meshio.xdmf.TimeSeriesReader(str(lattice)) as r:
        points, cells = r.read_points_cells()
        assert [c.type for c in cells] == ["hexahedron"] and len(cells[0].data) == model.n_cubes
        assert r.num_steps == len(rec.times) == 6
        frames = [r.read_data(k) for k in range(r.num_steps)]
    np.testing.assert_allclose(points, model.nodes, rtol=0, atol=0)
    np.testing.assert_allclose([t for t, _, _ in frames], rec.times, rtol=1e-12)
    w = np.array([cd["strain_energy_density"][0] for _, _, cd in frames])          # (T, n) J/m^3
    u = np.array([pd["displacement"] for _, pd, _ in frames])                      # (T, m, 3) model units
    assert w.shape == (6, model.n_cubes) and np.all(w >= 0) and w[-1].max() > 0
    np.testing.assert_allclose(u * model.scale, rec.u, rtol=1e-12, atol=0)
    elastic = rec.parts["elastic"]                                                 # 0.5 u^T K u of the run
    np.testing.assert_allclose(w.sum(axis=1) * model.h**3, elastic, rtol=0, atol=1e-9 * elastic.max())
    monkeypatch.chdir(tmp_path.parent)                                             # ParaView's reader
    reader = pv.get_reader(str(lattice))
    assert reader.number_time_points == 6
    reader.set_active_time_point(5)
    block = reader.read()[0]
    assert set(block.celltypes) == {pv.CellType.HEXAHEDRON}
    np.testing.assert_allclose(block.cell_data["strain_energy_density"], w[5], rtol=1e-12)
    assert block.volume == pytest.approx(model.n_cubes * model.pitch**3, rel=1e-12)   # VTK corner order


def test_a_failed_lattice_write_leaves_no_files_and_keeps_the_old_run(tmp_path, monkeypatch):
    from sc_fem.io import paraview
    from sc_fem.io.animation import write_xdmf

    model = CubeModel.box((2, 1, 1), 1.0, youngs=1e6, poisson=0.3)
    rest = np.asarray(model.nodes, float)[:3]
    times = np.array([0.0, 0.1])
    positions = np.stack([rest, rest + 0.01])
    u = np.zeros((2, model.n_nodes, 3))
    out = tmp_path / "run.xdmf"
    assert write_xdmf(out, rest, np.array([[0, 1, 2]]), times, positions, model=model, node_displacements=u) == out
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert sorted(before) == ["run.h5", "run.xdmf", "run_lattice.h5", "run_lattice.xdmf"]
    series = paraview._series

    def fail_on_the_lattice(name, *args):
        series(name, *args)                 # write it, then fail: the surface series is already written too
        if "lattice" in name:
            raise RuntimeError("disk gone")

    monkeypatch.setattr(paraview, "_series", fail_on_the_lattice)
    with pytest.raises(RuntimeError, match="disk gone"):
        write_xdmf(out, rest, np.array([[0, 1, 2]]), times, positions + 1, model=model, node_displacements=u + 1)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before      # nothing new, nothing half-written
    fresh = tmp_path / "new"
    with pytest.raises(RuntimeError):
        write_xdmf(fresh / "a.xdmf", rest, np.array([[0, 1, 2]]), times, positions, model=model, node_displacements=u)
    assert not list(fresh.iterdir())
    with pytest.raises(InputError, match="both"):
        write_xdmf(out, rest, np.array([[0, 1, 2]]), times, positions, model=model)
    with pytest.raises(InputError, match="shape"):
        write_xdmf(out, rest, np.array([[0, 1, 2]]), times, positions, model=model, node_displacements=u[:1])
