"""``sc-fem simulate``: outputs, summary, blow-up handling (in-process)."""

from __future__ import annotations

import numpy as np
import pytest

from sc_fem._cli.main import main
from sc_fem.io.animation import load_animation

BEAM = ["builtin:beam", "--resolution", "10", "--fix", "default", "--no-progress"]


def test_npz_animation_with_gravity_and_impulse(tmp_path, capsys):
    from sc_fem.geometry.mesh import load_mesh

    tip_vertex = int(np.argmax(load_mesh("builtin:beam").vertices[:, 0]))
    out = tmp_path / "beam.npz"
    rc = main(["simulate", *BEAM, "--gravity", "--impulse", str(tip_vertex), "0", "0", "1.0",
               "--duration", "0.02", "--dt", "0.001", "--fps", "1000", "-o", str(out)])
    assert rc == 0
    text = capsys.readouterr().out
    for key in ("steps", "time per step", "energy created", "energy at the end", "wrote"):
        assert key in text
    a = load_animation(out)
    assert a.positions.shape == (21, len(a.rest_vertices), 3) and a.positions.dtype == np.float64
    np.testing.assert_allclose(a.times, np.arange(21) * 1e-3, atol=1e-12)
    assert a.meta["method"] == "newmark" and a.faces.shape[1] == 3
    # the beam sags (tip vertices go down) and the energy is reported
    tip = a.rest_vertices[:, 0] > 0.99
    assert np.all(np.isfinite(a.energy)) and a.energy[0] > 0      # the impulse's kinetic energy
    assert (a.positions[1:, tip, 2] - a.rest_vertices[tip, 2]).max() > 0   # kicked upward


def test_central_blow_up_writes_nothing(tmp_path, capsys):
    out = tmp_path / "bad.npz"
    rc = main(["simulate", *BEAM, "--gravity", "--method", "central", "--duration", "0.01", "--dt", "1e-4",
               "-o", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    assert "blew up at step" in err and "dt_crit" in err
    assert not out.exists() and not list(tmp_path.iterdir())


def test_central_below_limit_and_xdmf(tmp_path, monkeypatch):
    import meshio

    out = tmp_path / "beam.xdmf"
    rc = main(["simulate", *BEAM, "--gravity", "--method", "central", "--duration", "0.002", "--dt", "2e-6",
               "--fps", "5000", "-o", str(out), "--quiet"])
    assert rc == 0 and out.exists()
    with meshio.xdmf.TimeSeriesReader(str(out)) as r:
        points, cells = r.read_points_cells()
        assert r.num_steps == 11
        t, pd, _ = r.read_data(r.num_steps - 1)
    assert t == pytest.approx(0.002)
    assert pd["displacement"].shape == points.shape and pd["displacement"][:, 2].min() < 0
    # heavy data in HDF5 beside it (inline XML of a large run is more than VTK's reader takes), and
    # ParaView's reader (VTK through pyvista) reads it too, from another working directory
    assert out.with_suffix(".h5").exists() and out.stat().st_size < 20_000
    import pyvista as pv

    monkeypatch.chdir(tmp_path.parent)
    reader = pv.get_reader(str(out))
    assert reader.number_time_points == 11
    reader.set_active_time_point(10)
    block = reader.read()[0]
    np.testing.assert_allclose(block.point_data["displacement"], pd["displacement"], rtol=1e-12)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]          # no temporary left


def test_ground_contact_and_corotational(tmp_path):
    out = tmp_path / "drop.npz"
    rc = main(["simulate", "builtin:beam", "--resolution", "10", "--youngs", "1e6", "--gravity", "--ground", "-0.002",
               "--method", "corotational", "--duration", "0.03", "--dt", "5e-4", "--rayleigh", "0", "1e-4",
               "--no-progress", "--quiet", "-o", str(out)])
    assert rc == 0
    a = load_animation(out)
    assert a.positions[..., 2].min() >= -0.002 - 1e-6 * 0.1       # tolerance 1e-6 pitch
    assert a.positions[-1, :, 2].min() < -0.0019                    # it fell onto the ground


def test_bad_arguments(tmp_path, capsys):
    assert main(["simulate", *BEAM, "--duration", "1", "--dt", "0.1", "-o", str(tmp_path / "x.txt")]) == 2
    assert main(["simulate", *BEAM, "--duration", "1", "--dt", "-0.1", "-o", str(tmp_path / "x.npz")]) == 2
    assert "--dt must be > 0" in capsys.readouterr().err
    assert main(["simulate", *BEAM, "--duration", "nan", "--dt", "0.1", "-o", str(tmp_path / "x.npz")]) == 2
    assert "--duration must be > 0 and finite" in capsys.readouterr().err
    assert main(["simulate", *BEAM, "--duration", "0.01", "--dt", "0.001", "--impulse", "99999", "0", "0", "1",
                 "-o", str(tmp_path / "x.npz")]) == 2
    assert "impulse VERTEX must be a vertex index" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_gif_output(tmp_path):
    from sc_fem.errors import RenderError
    from sc_fem.io.render import ensure_rendering

    try:
        ensure_rendering()
    except RenderError as exc:
        pytest.skip(f"no off-screen rendering here: {exc}")
    out = tmp_path / "beam.gif"
    rc = main(["simulate", *BEAM, "--gravity", "--duration", "0.01", "--dt", "0.001", "--fps", "500",
               "--exaggerate", "100", "--quiet", "-o", str(out)])
    assert rc == 0 and out.stat().st_size > 1000


def test_xpbd_method_writes_an_animation_that_reconstruct_reads(tmp_path):
    from sc_fem._cli.main import main
    from sc_fem.io.animation import load_animation

    out = tmp_path / "rope.npz"
    assert main(["simulate", "builtin:rope", "-r", "16", "--fix", "default", "--gravity", "--method", "xpbd",
                 "--dt", "0.05", "--substeps", "60", "--duration", "0.3", "--fps", "20", "-o", str(out), "-q"]) == 0
    anim = load_animation(out)
    assert anim.n_frames == 7 and anim.meta["method"] == "xpbd" and anim.meta["substeps"] == 60
    drop = anim.positions[-1, :, 2].min() - anim.rest_vertices[:, 2].min()
    assert drop < -0.05                                  # the free end falls under gravity
    fixed_end = anim.rest_vertices[:, 0] < 0.01
    assert np.abs(anim.positions[-1][fixed_end] - anim.rest_vertices[fixed_end]).max() < 0.02
    assert main(["reconstruct", str(out), "--fit-frames", "0,2,4,6", "-o", str(tmp_path / "r.npz")]) == 0


def test_xpbd_refuses_options_it_does_not_support(tmp_path, capsys):
    from sc_fem._cli.main import main

    rc = main(["simulate", "builtin:rope", "-r", "8", "--method", "xpbd", "--ground", "0", "--dt", "0.05",
               "--fps", "20", "--duration", "0.1", "-o", str(tmp_path / "x.npz")])
    assert rc == 2 and "supports gravity and fixed nodes only, not ground" in capsys.readouterr().err
    assert not (tmp_path / "x.npz").exists()


def test_element_option_lists_the_library_elements(capsys):
    from sc_fem.fem.elements import DEFAULT_ELEMENT, ELEMENTS

    with pytest.raises(SystemExit):
        main(["simulate", *BEAM, "--element", "p2", "--duration", "0.01", "--dt", "0.001", "-o", "x.npz"])
    err = capsys.readouterr().err
    assert all(e in err for e in ELEMENTS)
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    assert f"(default {DEFAULT_ELEMENT})" in capsys.readouterr().out


def test_up_axis_turns_gravity_and_the_ground(tmp_path):
    """A y-up model: --up y pulls it down -y and the ground is a height along y."""
    out = tmp_path / "y.npz"
    assert main(["simulate", "builtin:beam", "-r", "8", "--fix", "default", "--gravity", "--up", "y",
                 "--ground", "-0.06", "--duration", "0.02", "--dt", "1e-3", "-o", str(out), "--quiet"]) == 0
    a = load_animation(out)
    d = a.positions[-1] - a.rest_vertices
    assert d[:, 1].min() < 0 and np.abs(d[:, 2]).max() < 0.02 * np.abs(d[:, 1]).max()     # (Poisson: 0.7 %)
    assert a.meta["up"] == "y" and a.meta["ground"] == -0.06



def test_y_up_ground_is_a_plane_across_y(tmp_path):
    """A y-up beam dropped onto a ground 2 mm below it: it falls along -y (4.4 mm of free fall in
    0.03 s) and comes to rest on the plane y = ground -- a z-normal ground would let it through."""
    out = tmp_path / "drop_y.npz"
    base = ["simulate", "builtin:beam", "--resolution", "10", "--youngs", "1e6", "--gravity", "--up", "y",
            "--method", "corotational", "--duration", "0.03", "--dt", "5e-4", "--rayleigh", "0", "1e-4",
            "--no-progress", "--quiet"]
    ground = -0.05 - 0.002                                       # the beam spans y in [-0.05, 0.05]
    assert main(base + ["--ground", repr(ground), "-o", str(out)]) == 0
    a = load_animation(out)
    assert a.rest_vertices[:, 1].min() == pytest.approx(-0.05)
    assert a.positions[..., 1].min() >= ground - 1e-6 * 0.1       # tolerance 1e-6 pitch
    assert a.positions[-1, :, 1].min() < ground + 1e-4            # it fell onto the ground
    assert np.abs(a.positions[..., 2] - a.rest_vertices[None, :, 2]).max() < 1e-3   # not along z
