"""In-process tests of ``sc-fem reconstruct`` on small synthetic animations."""

from __future__ import annotations

import numpy as np
import pytest

from sc_fem._cli.main import main
from sc_fem.animfile import save_animation


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
    save_animation(path, faces=np.zeros((0, 3), int), rest_vertices=rest, times=times, positions=pos)
    if extra is not None:   # append a curves array to the same file
        with np.load(path) as z:
            data = dict(z)
        data["curves"] = extra(pos)
        np.savez(path, **data)
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
        assert z["E_A_pde"].mean() < 0.01
        assert z["mesh_error_pde"].max() < 0.02
    text = rep.read_text()
    assert text.count("\n| ") >= 11 and "PDE E_A" in text and "B-spline scalars" in text
    assert "mean E_A" in capsys.readouterr().out
    assert not list(tmp_path.glob(".*tmp*"))                        # atomic writes left nothing


def test_cli_reconstruct_uses_stored_curves(tmp_path):
    anim = tmp_path / "anim.npz"
    _tube_animation(anim, extra=lambda pos: pos.reshape(len(pos), 40, 12, 3).transpose(0, 2, 1, 3)[:, :3])
    out = tmp_path / "recon.npz"
    assert main(["reconstruct", str(anim), "--fit-frames", "0,5,10", "-o", str(out), "--n-control", "10",
                 "--parametrization", "arclength", "--r", "1.5", "--alpha", "1.0"]) == 0
    with np.load(out) as z:
        assert z["curves_pde"].shape == (11, 3, 40, 3)
        assert float(z["r"]) == 1.5 and "vertices_pde" not in z.files
        assert z["E_A_pde"].mean() < 0.01


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
