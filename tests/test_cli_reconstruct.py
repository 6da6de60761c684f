"""In-process tests of ``sc-fem reconstruct`` on small synthetic animations."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sc_fem._cli.main import main
from sc_fem.io.animation import save_animation


def _tube_animation(path, n_frames=11, extra=None):
    """A tube of vertices along x bending and swinging about its x = 0 end."""
    s = np.linspace(0.0, 2.0, 40)
    ang = np.linspace(-np.pi, np.pi, 12, endpoint=False)
    S, A = np.meshgrid(s, ang, indexing="ij")
    rest = np.stack([S.ravel(), 0.1 * np.cos(A.ravel()), 0.1 * np.sin(A.ravel())], axis=-1)
    times = np.linspace(0.0, 0.5, n_frames)
    pos = []
    for t in times:
        th = 0.4 * np.sin(3.0 * t)
        x = rest.copy()
        x[:, 1] += 0.05 * np.sin(2 * t) * x[:, 0] ** 2
        c, sn = np.cos(th), np.sin(th)
        pos.append(np.stack([c * x[:, 0] - sn * x[:, 1], sn * x[:, 0] + c * x[:, 1], x[:, 2]], axis=-1))
    pos = np.array(pos)
    save_animation(path, faces=np.zeros((0, 3), int), rest_vertices=rest, times=times, positions=pos,
                   extra=None if extra is None else {"curves": extra(pos)})
    return rest, times, pos


def test_cli_reconstruct_extracted_curves(tmp_path, capsys):
    anim = tmp_path / "anim.npz"
    _, times, pos = _tube_animation(anim)
    out, rep = tmp_path / "recon.npz", tmp_path / "table.md"
    code = main(["reconstruct", str(anim), "--fit-frames", "0,2,4,6,8,10", "-o", str(out),
                 "--report", str(rep), "--curves", "6", "--points", "20", "--n-control", "8"])
    assert code == 0
    with np.load(out) as z:
        assert str(z["kind"]) == "sc_fem.reconstruction"
        assert z["curves_pde"].shape == (11, 6, 20, 3)
        assert z["E_A_pde"].shape == (11, 6)
        assert z["vertices_pde"].shape == pos.shape
        # the reconstruction is close to the truth and reproduces the stored reference
        np.testing.assert_allclose(z["curves_reference"], pos[:, z["curve_vertex_index"]], atol=1e-6)
        # measured: PDE mean E_A 8.1e-6 (B-spline 7.9e-4), mesh error 2.3e-3 of the bbox diagonal
        assert z["E_A_pde"].mean() < 1e-4
        assert z["E_A_pde"].mean() < z["E_A_bspline"].mean()
        assert z["mesh_error_pde"].max() < 5e-3
        # the animation file is recorded beside the mesh the animation came from, not over it
        meta = json.loads(str(z["meta_json"]))
        assert meta["animation"] == str(anim) and meta["source"] != str(anim)
    text = rep.read_text()
    assert text.count("\n| ") >= 11 and "PDE E_A" in text and "B-spline scalars" in text
    assert "mean E_A" in capsys.readouterr().out
    assert not list(tmp_path.glob(".*tmp*"))                        # atomic writes left nothing


def test_cli_reconstruct_uses_stored_curves(tmp_path):
    anim = tmp_path / "anim.npz"
    _tube_animation(anim, extra=lambda pos: pos.reshape(len(pos), 40, 12, 3).transpose(0, 2, 1, 3)[:, :3])
    out = tmp_path / "recon.npz"
    assert main(["reconstruct", str(anim), "--fit-frames", "0,5,10", "-o", str(out), "--n-control", "10",
                 "--parametrization", "arclength", "--r", "1.5", "--segments", "1", "--offset", "none"]) == 0
    from sc_fem import reconstruct as rec
    from sc_fem.io.animation import load_animation

    a = load_animation(anim)
    fit = [0, 5, 10]
    # the stored curves are used, --r is held and only alpha is searched (with the searched r,
    # alpha ends near 3.0 instead of 0.105), exactly as the library does it
    model = rec.fit(a.curves[fit], a.times[fit], r=1.5, parametrization="arclength")
    assert model.search is not None and model.search.r_grid.tolist() == [1.5]
    with np.load(out) as z:
        assert z["curves_pde"].shape == (11, 3, 40, 3) and "vertices_pde" not in z.files
        np.testing.assert_array_equal(z["curves_reference"], a.curves)
        assert float(z["r"]) == 1.5
        assert float(z["alpha"]) == pytest.approx(model.alpha, rel=1e-9)
        np.testing.assert_allclose(z["curves_pde"], model.evaluate(a.times), rtol=0,
                                   atol=1e-9 * np.abs(a.curves).max())
        # measured: PDE mean E_A 2.4e-3, B-spline 6.2e-3
        assert z["E_A_pde"].mean() < 5e-3
        assert z["E_A_pde"].mean() < z["E_A_bspline"].mean()


@pytest.mark.parametrize("frames, msg", [("0", "at least 2"), ("0,2,99", "strictly increasing"),
                                         ("a,b", "integers"), ("4,2", "strictly increasing")])
def test_cli_reconstruct_bad_frames(tmp_path, capsys, frames, msg):
    anim = tmp_path / "anim.npz"
    _tube_animation(anim)
    assert main(["reconstruct", str(anim), "--fit-frames", frames, "-o", str(tmp_path / "o.npz")]) == 2
    assert msg in capsys.readouterr().err
    assert not (tmp_path / "o.npz").exists()


def test_cli_reconstruct_missing_file(tmp_path, capsys):
    assert main(["reconstruct", str(tmp_path / "nope.npz"), "-o", str(tmp_path / "o.npz")]) == 2
    assert "not found" in capsys.readouterr().err


def test_reconstruction_file_round_trips_through_its_reader(tmp_path):
    from sc_fem.errors import FileFormatError, InputError
    from sc_fem.io.animation import load_animation
    from sc_fem.io.reconstruction import load_reconstruction, save_reconstruction
    from sc_fem.reconstruct import reconstruct_animation

    anim = tmp_path / "anim.npz"
    _tube_animation(anim)
    res = reconstruct_animation(load_animation(anim), [0, 5, 10], n_curves=4, n_points=16, n_control=8)
    path = save_reconstruction(tmp_path / "r.npz", res)
    back = load_reconstruction(path)
    for name in ("frames", "fit_frames", "curves_pde", "curves_bspline", "E_A_pde", "E_M_bspline", "vertices_pde"):
        np.testing.assert_array_equal(getattr(back, name), getattr(res, name))
    assert back.r == res.r and back.alpha == res.alpha and back.meta == res.meta
    assert back.fitted.tolist() == [f in (0, 5, 10) for f in range(11)]
    # the same file read from the CLI's output, and refused when foreign or truncated
    assert main(["reconstruct", str(anim), "--fit-frames", "0,5,10", "-o", str(tmp_path / "c.npz"),
                 "--curves", "4", "--points", "16", "--n-control", "8"]) == 0
    np.testing.assert_allclose(load_reconstruction(tmp_path / "c.npz").curves_pde, res.curves_pde)
    with pytest.raises(FileFormatError, match="not an sc_fem reconstruction file"):
        load_reconstruction(anim)
    (tmp_path / "cut.npz").write_bytes(path.read_bytes()[:200])
    with pytest.raises(FileFormatError, match="truncated or corrupted"):
        load_reconstruction(tmp_path / "cut.npz")
    with pytest.raises(InputError, match="written as .npz"):
        save_reconstruction(tmp_path / "r.csv", res)
