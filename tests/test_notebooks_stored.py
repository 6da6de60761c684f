"""The notebooks are committed with their outputs (they show on a code host): those outputs must
not carry paths of the machine that executed them (user names, checkouts, virtual environments).
The check is ``notebooks/execute.py``'s, which also refuses to store such outputs."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parents[1] / "notebooks"
NOTEBOOKS = sorted(HERE.glob("*.ipynb"))
_spec = importlib.util.spec_from_file_location("nb_execute", HERE / "execute.py")
nb_execute = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(nb_execute)


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_stored_outputs_name_no_path_of_this_machine(path):
    found = nb_execute.machine_paths(json.loads(path.read_text()))
    assert not found, f"{path.name} stores outputs naming machine paths: {found[:3]}"


def test_the_check_sees_a_leaked_path():
    leaky = {"cells": [{"outputs": [{"name": "stderr", "output_type": "stream",
                                     "text": ["/home/someone/project/.venv/lib/python3.11/site-packages/tqdm/auto.py:21: x\n"]}]},
                       {"outputs": [{"data": {"text/plain": "C:\\Users\\me\\x.npz"}}]}]}
    assert nb_execute.machine_paths(leaky) == ["/home/someone/project/.venv/lib/python3.11/site-packages/tqdm/auto.py:21:",
                                               "C:\\Users\\"]
    clean = {"cells": [{"outputs": [{"text": "mode file: chair.modes.npz 25 KiB\n"}]}, {"cells_without": 1}]}
    assert nb_execute.machine_paths({"cells": clean["cells"][:1]}) == []
