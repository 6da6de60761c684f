"""The linear solver of a simulation is the user's to choose (``run_simulation(solver=)``,
``sc-fem simulate --linear-solver``), for the methods that solve linear systems, and refused for
those that do not; the run records which one ran. One frame-step rule for the library and the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sc_fem import Scene
from sc_fem._cli.main import main
from sc_fem.dynamics.job import frame_steps, run_simulation
from sc_fem.errors import InputError
from sc_fem.fem.options import DynamicOptions
from sc_fem.units import gravity_down


@pytest.fixture(scope="module")
def beam():
    return Scene.from_mesh("builtin:beam", {"resolution": 8}, fix="default")


@pytest.mark.parametrize("method", ["newmark", "corotational"])
def test_cg_amg_is_chosen_by_the_caller_and_gives_the_direct_trajectory(beam, method):
    runs = {s: run_simulation(beam, duration=0.2, method=method, gravity=gravity_down(), solver=s)
            for s in ("direct", "cg-amg")}
    assert runs["direct"].info["linear_solver"] == "direct"
    assert runs["cg-amg"].info["linear_solver"] == "cg-amg" and runs["cg-amg"].info["cg_iterations"] > 0
    a, b = runs["cg-amg"].points, runs["direct"].points
    moved = np.abs(b - b[0]).max()
    assert moved > 0 and np.abs(a - b).max() < 1e-5 * moved


def test_options_object_and_auto_below_the_threshold(beam):
    rec = run_simulation(beam, duration=0.05, method="newmark", gravity=gravity_down(),
                         solver=DynamicOptions(solver="cg-amg", tol=1e-10))
    assert rec.info["linear_solver"] == "cg-amg"
    rec = run_simulation(beam, duration=0.05, method="newmark", gravity=gravity_down())
    assert rec.info["linear_solver"] == "direct"          # 'auto' factorizes a model this small


@pytest.mark.parametrize("method", ["central", "xpbd"])
def test_methods_without_linear_systems_refuse_a_solver(beam, method):
    with pytest.raises(InputError, match="not linear solver"):
        run_simulation(beam, duration=0.05, method=method, solver="cg-amg")
    with pytest.raises(InputError):
        run_simulation(beam, duration=0.05, method="newmark", solver="multigrid")


def test_cli_linear_solver_is_recorded(tmp_path, capsys):
    out = tmp_path / "run.npz"
    rc = main(["simulate", "builtin:beam", "-r", "8", "--fix", "default", "--duration", "0.05", "--gravity",
               "--linear-solver", "cg-amg", "-o", str(out), "--quiet"])
    assert rc == 0, capsys.readouterr().err
    with np.load(out) as data:
        meta = json.loads(str(data["meta_json"]))
    assert meta["linear_solver"] == "cg-amg"


def test_one_frame_step_rule():
    assert frame_steps(1.0, 0.01, 50.0) == (100, 2)
    with pytest.raises(InputError, match="does not divide the frame step"):
        frame_steps(1.0, 0.003, 50.0)
    with pytest.raises(InputError, match="shorter than one step"):
        frame_steps(0.001, 0.01, 50.0)


def test_run_simulation_takes_a_scene_and_says_so(beam):
    with pytest.raises(InputError, match=r"takes a Scene, got CubeModel.*simulate_to_file"):
        run_simulation(beam.model, duration=0.05)
