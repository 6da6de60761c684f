"""Vertex-animation files: round trip, extra arrays, and every corruption case."""

from __future__ import annotations

import numpy as np
import pytest

from sc_fem.io.animation import load_animation, save_animation
from sc_fem.errors import InputError, FileFormatError


def _anim(rng, T=4, n=5):
    rest = rng.normal(size=(n, 3))
    return dict(faces=np.array([[0, 1, 2], [2, 3, 4]]), rest_vertices=rest, times=np.arange(T) * 0.1,
                positions=rest[None] + 0.01 * rng.normal(size=(T, n, 3)), energy=np.ones(T), meta={"method": "x"})


def test_round_trip_with_curves(tmp_path, rng):
    a = _anim(rng)
    curves = rng.normal(size=(4, 2, 7, 3))
    p = save_animation(tmp_path / "a.npz", **a, extra={"curves": curves})
    b = load_animation(p)
    np.testing.assert_allclose(b.positions, a["positions"], rtol=1e-6)
    assert b.positions.dtype == np.float64 and b.meta == {"method": "x"} and b.n_frames == 4
    with np.load(p) as z:
        np.testing.assert_array_equal(z["curves"], curves)
    assert b.curves is not None and b.curves.dtype == np.float64
    np.testing.assert_array_equal(b.curves, curves)
    assert load_animation(save_animation(tmp_path / "nc.npz", **a)).curves is None


@pytest.mark.parametrize("bad, msg", [
    (lambda c: c[:3], "curves must have shape"),                 # wrong number of frames
    (lambda c: c[..., :2], "curves must have shape"),            # not 3-D points
    (lambda c: c[:, 0], "curves must have shape"),               # (T, P, 3): no curve axis
    (lambda c: np.where(np.arange(7)[:, None] == 3, np.nan, c), "non-finite"),
])
def test_bad_curves_raise(tmp_path, rng, bad, msg):
    a = _anim(rng)
    p = save_animation(tmp_path / "a.npz", **a, extra={"curves": bad(rng.normal(size=(4, 2, 7, 3)))})
    with pytest.raises(FileFormatError, match=msg):
        load_animation(p)


def test_bad_writes(tmp_path, rng):
    a = _anim(rng)
    with pytest.raises(InputError, match="reserved"):
        save_animation(tmp_path / "a.npz", **a, extra={"times": np.zeros(4)})
    b = dict(a, times=np.array([0.0, 0.2, 0.1, 0.3]))
    with pytest.raises(InputError, match="increasing"):
        save_animation(tmp_path / "a.npz", **b)
    c = dict(a, positions=a["positions"][:, :3])
    with pytest.raises(InputError, match="shape"):
        save_animation(tmp_path / "a.npz", **c)
    assert not list(tmp_path.iterdir())


def test_corrupted_truncated_foreign(tmp_path, rng):
    p = save_animation(tmp_path / "a.npz", **_anim(rng))
    data = p.read_bytes()
    (tmp_path / "t.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(FileFormatError, match="truncated or corrupted"):
        load_animation(tmp_path / "t.npz")
    np.savez(tmp_path / "f.npz", x=np.zeros(3))
    with pytest.raises(FileFormatError, match="not an sc_fem animation"):
        load_animation(tmp_path / "f.npz")
    with pytest.raises(FileFormatError, match="not found"):
        load_animation(tmp_path / "missing.npz")
    with np.load(p) as z:
        d = {k: z[k] for k in z.files}
    d["format_version"] = np.int64(99)
    np.savez(tmp_path / "v.npz", **d)
    with pytest.raises(FileFormatError, match="format_version 99"):
        load_animation(tmp_path / "v.npz")
    d["format_version"] = np.int64(2)
    d["displacements"] = d["displacements"].copy()
    d["displacements"][0, 0, 0] = np.nan
    np.savez(tmp_path / "n.npz", **d)
    with pytest.raises(FileFormatError, match="non-finite"):
        load_animation(tmp_path / "n.npz")


def test_displacements_keep_their_precision_far_from_the_origin(tmp_path, rng):
    """Version 2 stores float32 displacements: a model 1 km from the origin moving by 10 um keeps
    them to float32 precision (version 1's float32 positions lost most of such a motion)."""
    a = _anim(rng, n=50)
    rest = a["rest_vertices"] + 1000.0
    disp = 1e-5 * rng.normal(size=(4, 50, 3))
    b = load_animation(save_animation(tmp_path / "a.npz", **dict(a, rest_vertices=rest, positions=rest[None] + disp)))
    rel = np.abs(b.positions - b.rest_vertices[None] - disp).max() / np.abs(disp).max()
    assert rel < 1e-6
    v1 = np.abs((rest[None] + disp).astype(np.float32).astype(np.float64) - rest[None] - disp).max() / np.abs(disp).max()
    assert v1 > 0.1                                       # what the old schema did to the same motion


def test_version_1_files_are_still_read(tmp_path, rng):
    import json

    a = _anim(rng)
    np.savez(tmp_path / "v1.npz", format_version=np.int64(1), kind=np.str_("sc_fem.animation"), faces=a["faces"],
             rest_vertices=a["rest_vertices"], times=a["times"], positions=a["positions"].astype(np.float32),
             energy=a["energy"], meta_json=np.str_(json.dumps(a["meta"])))
    b = load_animation(tmp_path / "v1.npz")
    np.testing.assert_allclose(b.positions, a["positions"], rtol=1e-6, atol=1e-6)
    assert b.meta == {"method": "x"}


def test_xdmf_into_a_missing_folder_is_created_and_an_unwritable_one_is_an_output_error(tmp_path):
    from sc_fem.errors import OutputError
    from sc_fem.io.animation import write_xdmf

    rest = np.zeros((3, 3))
    rest[1, 0] = rest[2, 1] = 1.0
    out = write_xdmf(tmp_path / "new" / "a.xdmf", rest, np.array([[0, 1, 2]]), [0.0, 0.1], np.stack([rest, rest]))
    assert out.exists() and out.with_suffix(".h5").exists()
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError):
        write_xdmf(tmp_path / "file" / "a.xdmf", rest, np.array([[0, 1, 2]]), [0.0], rest[None])


def test_a_lattice_track_that_would_not_read_back_is_not_written(tmp_path):
    from sc_fem.io.animation import save_animation

    rest = np.zeros((3, 3))
    bad = {"lattice_node_index": np.zeros((2, 3), int), "lattice_rest": np.zeros((2, 3)),
           "lattice_displacements": np.zeros((5, 2, 3), np.float32),          # 5 frames, the animation has 2
           "lattice_W_data": np.ones(3), "lattice_W_indices": np.zeros(3, int), "lattice_W_indptr": np.arange(4)}
    with pytest.raises(InputError, match="lattice"):
        save_animation(tmp_path / "a.npz", faces=np.zeros((0, 3), int), rest_vertices=rest, times=[0.0, 0.1],
                       positions=np.stack([rest, rest]), extra=bad)
    assert not (tmp_path / "a.npz").exists()
