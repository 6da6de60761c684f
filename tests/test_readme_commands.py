"""Every ``sc-fem`` command in the README and in the documentation pages runs as written (in-process,
in one scratch folder, in reading order: the README, then the pages in the order of the docs'
table of contents, so later commands read earlier outputs; the two placeholder inputs,
``my_model.obj`` and ``assets/*.obj``, are made first)."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
import trimesh

from sc_fem._cli.main import main

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = ROOT / "docs"


def _toctree_order(page: Path, seen: list[Path]) -> None:
    """``page`` and the Markdown pages its ``{toctree}`` directives list, depth first."""
    seen.append(page)
    for tree in re.findall(r"```\{toctree\}\n(.*?)```", page.read_text(), flags=re.DOTALL):
        for entry in tree.splitlines():
            entry = entry.strip()
            if not entry or entry.startswith(":"):
                continue
            child = (page.parent / entry).with_suffix(".md")
            if child.is_file() and child not in seen:
                _toctree_order(child, seen)


def pages() -> list[Path]:
    """The README, then the docs pages in reading order (any page outside the tables of contents
    last)."""
    ordered: list[Path] = []
    _toctree_order(DOCS / "index.md", ordered)
    rest = [p for p in sorted(DOCS.rglob("*.md")) if p not in ordered]
    return [README, *ordered, *rest]


def _commands() -> list[str]:
    out = []
    blocks = [block for page in pages()
              for block in re.findall(r"```bash\n(.*?)```", page.read_text(), flags=re.DOTALL)]
    for block in blocks:
        text = block.replace("\\\n", " ")
        for line in text.splitlines():
            line = line.split(" #")[0].strip()
            if line.startswith("sc-fem "):
                out.append(line)
    return out


def test_the_readme_has_commands_to_check():
    cmds = _commands()
    assert len(cmds) >= 9 and any("reconstruct" in c for c in cmds) and any("simulate" in c for c in cmds)
    order = pages()                                 # the export page reads the modal page's mode file
    assert order.index(DOCS / "guide" / "modal.md") < order.index(DOCS / "guide" / "export.md")


@pytest.mark.slow
def test_every_readme_command_runs_as_written(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    box = trimesh.creation.box(extents=(300.0, 80.0, 40.0))          # a part in millimetres
    box.apply_translation((1000.0, 200.0, 20.0))
    box.export(tmp_path / "my_model.obj")
    (tmp_path / "assets").mkdir()
    for k, ext in enumerate(((0.4, 0.1, 0.1), (0.3, 0.2, 0.05))):
        trimesh.creation.box(extents=ext).export(tmp_path / "assets" / f"part{k}.obj")
    for cmd in _commands():                          # in README order: later commands read earlier outputs
        argv = shlex.split(cmd)[1:]
        assert main(argv + ["--quiet"] if "--quiet" not in argv and argv[0] != "reconstruct" else argv) == 0, cmd
    for name in ("bridge.png", "model.vtu", "chair.modes.npz", "chair.npz", "chair.mp4", "sheet.png",
                 "outdir/summary.csv", "bridge.npz", "rope.npz", "recon.npz", "table.md", "chair.glb",
                 "strike.glb", "chair.html"):
        assert (tmp_path / name).stat().st_size > 0, name
