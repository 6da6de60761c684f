"""Batch precomputation on Dask: one task per mesh, a broken mesh fails alone, CSV summary."""

from __future__ import annotations

import csv

import pytest

from sc_fem.io.batch import expand_inputs
from sc_fem.io.precompute import output_name, run_batch
from sc_fem.errors import InputError
from sc_fem.io.modes import load_modes

OPTS = {"voxel": {"resolution": 10}, "n_modes": 3, "fix": ["default"]}


def test_one_broken_mesh_fails_alone(tmp_path):
    bad = tmp_path / "broken.obj"
    bad.write_text("v 0 0 0\nv 1 nan 0\nf 1 2 3\n")
    res = run_batch(["builtin:chair", str(bad), "builtin:beam"], tmp_path / "out", options=OPTS,
                    processes=False, n_workers=2, progress=False)
    assert [r["status"] for r in res.rows] == ["ok", "error", "ok"]
    assert res.n_ok == 2 and res.n_failed == 1
    assert "broken.obj" in res.rows[1]["error"] and res.rows[1]["output"] == ""
    for r in (res.rows[0], res.rows[2]):
        b = load_modes(r["output"])
        assert b.n_modes == 3 and b.fix_record["n_nodes"] > 0
    with open(res.summary, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["status"] for r in rows] == ["ok", "error", "ok"] and rows[1]["error"]
    assert rows[0]["mesh"] == "builtin:chair" and int(rows[0]["cubes"]) > 0


def test_existing_scheduler_address(tmp_path):
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        res = run_batch(["builtin:beam"], tmp_path / "o", options={**OPTS, "fix": ["x<min+0.01"]},
                        scheduler=cluster.scheduler_address, progress=False)
        assert res.scheduler == cluster.scheduler_address
    assert res.n_ok == 1 and (tmp_path / "o" / "beam.modes.npz").is_file()


def test_inputs_and_names(tmp_path):
    for n in ("a.obj", "b.obj"):
        (tmp_path / n).write_text("")
    assert expand_inputs([str(tmp_path / "*.obj"), "builtin:chair"]) == \
        [str(tmp_path / "a.obj"), str(tmp_path / "b.obj"), "builtin:chair"]
    assert output_name("builtin:bridge") == "bridge.modes.npz" and output_name("x/y.stl") == "y.modes.npz"
    with pytest.raises(InputError, match="no file matches"):
        expand_inputs([str(tmp_path / "*.ply")])


def test_without_dask_runs_serially_and_scheduler_is_refused(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "dask.distributed", None)       # import now raises ImportError
    bad = tmp_path / "broken.obj"
    bad.write_text("v 0 0 0\nv 1 nan 0\nf 1 2 3\n")
    res = run_batch(["builtin:beam", str(bad)], tmp_path / "out", options=OPTS, progress=False)
    assert res.scheduler.startswith("serial") and [r["status"] for r in res.rows] == ["ok", "error"]
    assert load_modes(res.rows[0]["output"]).n_modes == 3
    with pytest.raises(InputError, match="dask"):
        run_batch(["builtin:beam"], tmp_path / "out2", options=OPTS, scheduler="tcp://127.0.0.1:1")


def test_one_fix_spec_as_a_string(tmp_path):
    """``fix`` as one spec string (as modal takes it): it was split into single characters."""
    from sc_fem.io.precompute import precompute_one

    row = precompute_one("builtin:beam", str(tmp_path / "b.npz"), {"fix": "x<min+0.01", "n_modes": 2, "voxel": {"resolution": 8}})
    assert row["status"] == "ok", row["error"]
    row = precompute_one("/nonexistent/x.obj", str(tmp_path / "x.npz"), {"fix": ["default"], "n_modes": 2})
    assert row["status"] == "error" and "not found" in row["error"]
