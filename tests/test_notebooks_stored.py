"""The notebooks are committed with their outputs (they show on a code host): those outputs must
not carry paths of the machine that executed them (user names, checkouts, virtual environments)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
# absolute paths of a checkout, a home directory or a Python installation
MACHINE_PATH = re.compile(r"(/(home|Users|root|work|tmp|opt|usr)/[^\s\"']*|[A-Za-z]:\\\\Users\\\\)")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_stored_outputs_name_no_path_of_this_machine(path):
    nb = json.loads(path.read_text())
    found = []
    for cell in nb["cells"]:
        for out in cell.get("outputs", []):
            texts = [out.get("text", "")] + [v for k, v in out.get("data", {}).items() if k.startswith("text/")]
            for t in texts:
                t = "".join(t) if isinstance(t, list) else t
                found += MACHINE_PATH.findall(t)
    assert not found, f"{path.name} stores outputs naming machine paths: {[f[0] for f in found][:3]}"


def test_the_check_sees_a_leaked_path(tmp_path):
    leaky = {"cells": [{"outputs": [{"name": "stderr", "output_type": "stream",
                                     "text": ["/work/main/.venv/lib/python3.11/site-packages/tqdm/auto.py:21: x\n"]}]}]}
    p = tmp_path / "leaky.ipynb"
    p.write_text(json.dumps(leaky))
    with pytest.raises(AssertionError, match="machine paths"):
        test_stored_outputs_name_no_path_of_this_machine(p)
