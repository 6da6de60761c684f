"""Mode files: round trip, atomic write, and every corruption case raises FileFormatError."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

import sc_fem
from sc_fem.errors import FileFormatError
from sc_fem.lattice.cubes import CubeModel
from sc_fem import modal
from sc_fem.modes.options import Damping
from sc_fem.io.modes import MODES_FORMAT_VERSION, load_modes, save_modes


@pytest.fixture(scope="module")
def basis():
    m = CubeModel.box((4, 2, 2), 0.05, youngs=1e7, poisson=0.3, density=1000.0)
    return modal(m, n_modes=4, fix="x<min+0", keep_lattice=True, damping=Damping(rayleigh=(0.5, 1e-4)))


@pytest.fixture
def saved(tmp_path, basis):
    return save_modes(basis, tmp_path / "m.npz")


def _rewrite(src, dst, **changes):
    with np.load(src, allow_pickle=False) as z:
        data = {k: z[k] for k in z.files}
    for k, v in changes.items():
        if v is None:
            data.pop(k)
        else:
            data[k] = v
    np.savez(dst, **data)
    return dst


def test_round_trip(saved, basis):
    b = load_modes(saved)
    np.testing.assert_array_equal(b.frequencies, basis.frequencies)
    np.testing.assert_array_equal(b.modes, basis.modes.astype(np.float32))
    assert b.modes.dtype == np.float32 and b.modes.shape == (4, basis.n_vertices, 3)
    np.testing.assert_array_equal(b.vertices, basis.vertices)
    np.testing.assert_array_equal(b.faces, basis.faces)
    np.testing.assert_array_equal(b.damping, basis.damping)
    assert b.damping_spec == {"kind": "rayleigh", "alpha": 0.5, "beta": 1e-4}
    assert b.element == "q1i" and b.pitch == basis.pitch and b.scale == basis.scale
    assert b.fix_record == basis.fix_record and b.material == json.loads(json.dumps(basis.material))
    assert b.n_cubes == basis.n_cubes and b.eigen["method"] == basis.eigen["method"]
    assert b.lattice is not None and b.lattice.n_nodes == basis.lattice.n_nodes
    np.testing.assert_allclose(b.node_modes, basis.node_modes, rtol=1e-6, atol=1e-6 * np.abs(basis.node_modes).max())


def test_round_trip_of_a_mesh_basis_without_lattice(tmp_path):
    b = modal("builtin:chair", resolution=12, n_modes=2, fix="z<min+0.01")
    p = save_modes(b, tmp_path / "chair.npz")
    r = load_modes(p)
    assert r.lattice is None and r.source == "builtin:chair" and len(r.source_sha256) == 64
    np.testing.assert_allclose(r.modes, b.modes, rtol=1e-6, atol=1e-6 * np.abs(b.modes).max())
    assert list(tmp_path.iterdir()) == [p]


def test_interrupted_write_leaves_no_file_and_keeps_the_old_one(tmp_path, basis, monkeypatch):
    def fail(*args, **kwargs):
        raise OSError("disk full (simulated)")

    target = tmp_path / "m.npz"
    with monkeypatch.context() as mp:
        mp.setattr(np, "savez_compressed", fail)
        with pytest.raises(OSError, match="disk full"):
            save_modes(basis, target)
    assert list(tmp_path.iterdir()) == []                    # neither the target nor a temporary file
    save_modes(basis, target)
    before = target.read_bytes()
    monkeypatch.setattr(np, "savez_compressed", fail)
    with pytest.raises(OSError, match="disk full"):
        save_modes(basis, target)                            # a failed overwrite keeps the old file intact
    assert list(tmp_path.iterdir()) == [target] and target.read_bytes() == before


def test_truncated_file(saved, tmp_path):
    data = saved.read_bytes()
    bad = tmp_path / "trunc.npz"
    bad.write_bytes(data[: len(data) // 2])
    with pytest.raises(FileFormatError, match="truncated or corrupted"):
        load_modes(bad)


def test_corrupted_bytes(saved, tmp_path):
    data = bytearray(saved.read_bytes())
    with zipfile.ZipFile(saved) as z:
        info = z.getinfo("modes.npy")
    start = info.header_offset + 30 + len(info.filename) + 10
    for i in range(start, start + 64):
        data[i] ^= 0xFF
    bad = tmp_path / "corrupt.npz"
    bad.write_bytes(bytes(data))
    with pytest.raises(FileFormatError):
        load_modes(bad)


def test_foreign_files(saved, tmp_path):
    other = tmp_path / "other.npz"
    np.savez(other, a=np.arange(3))
    with pytest.raises(FileFormatError, match="not an sc_fem mode file"):
        load_modes(other)
    text = tmp_path / "text.npz"
    text.write_text("hello, I am not a zip file")
    with pytest.raises(FileFormatError, match="not a readable"):
        load_modes(text)
    with pytest.raises(FileFormatError, match="not found"):
        load_modes(tmp_path / "missing.npz")


def test_wrong_version(saved, tmp_path):
    bad = _rewrite(saved, tmp_path / "v.npz", format_version=np.int64(MODES_FORMAT_VERSION + 1))
    with pytest.raises(FileFormatError, match="format_version"):
        load_modes(bad)


def test_nan_and_shape_errors(saved, tmp_path):
    with np.load(saved) as z:
        modes, freqs = z["modes"].copy(), z["frequencies"].copy()
    modes[1, 0, 0] = np.nan
    with pytest.raises(FileFormatError, match="non-finite"):
        load_modes(_rewrite(saved, tmp_path / "nan.npz", modes=modes))
    with pytest.raises(FileFormatError, match="modes must be"):
        load_modes(_rewrite(saved, tmp_path / "shape.npz", modes=modes[:, :-1]))
    with pytest.raises(FileFormatError, match="missing keys"):
        load_modes(_rewrite(saved, tmp_path / "key.npz", damping=None))
    with pytest.raises(FileFormatError, match="ascending"):
        load_modes(_rewrite(saved, tmp_path / "order.npz", frequencies=freqs[::-1].copy()))


def test_modes_open_in_paraview_readers_as_vtu(tmp_path, capsys):
    """``sc-fem export modes.npz -o modes.vtu``: meshio and pyvista (VTK's own reader) read one
    point array per mode equal to the modes, and the frequencies as field data."""
    import meshio
    import pyvista as pv

    from sc_fem._cli.main import main

    basis = sc_fem.modal("builtin:beam", resolution=8, n_modes=3, fix="x<min+0.01")
    npz = sc_fem.save_modes(basis, tmp_path / "beam.modes.npz")
    out = tmp_path / "beam.vtu"
    assert main(["export", str(npz), "-o", str(out), "--quiet"]) == 0
    m = meshio.read(out)
    assert sorted(m.point_data) == ["mode_0", "mode_1", "mode_2"]
    for k in range(3):
        np.testing.assert_allclose(m.point_data[f"mode_{k}"], basis.modes[k], rtol=1e-6, atol=1e-7 * np.abs(basis.modes).max())
    np.testing.assert_allclose(np.ravel(m.field_data["frequency_Hz"]), basis.frequencies, rtol=1e-12)
    grid = pv.read(out)
    assert grid.n_points == len(basis.vertices) and "mode_2" in grid.point_data
    np.testing.assert_allclose(np.ravel(grid.field_data["frequency_Hz"]), basis.frequencies, rtol=1e-12)
    assert main(["export", str(npz), "-o", str(out), "--mode", "0"]) != 0        # one clear line
    assert "playback" in capsys.readouterr().err
