"""The package is a strict stack: no import goes up a layer, and no modules import each other in a loop.

Every import in the package's source is read (module top and inside functions alike), resolved to
the ``sc_fem`` module it names, and held against :data:`LAYERS`, from the bottom up:

    foundation (errors, validation, array helpers, units, materials, memory)  ->  geometry  ->  lattice  ->  scene
    ->  fem  ->  modes, dynamics  ->  reconstruct  ->  io  ->  command line

A module may import its own layer and the layers below; ``modes`` and ``dynamics`` share a floor
and do not import each other. The module graph has no cycle.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"
PKG = SRC / "sc_fem"

LAYERS: tuple[tuple[str, ...], ...] = (
    ("errors", "_lazy", "_validate", "_atomic", "_jit", "_arrays", "_memory", "_log", "_progress", "units", "material"),
    ("geometry",),
    ("lattice",),
    ("scene",),
    ("fem",),
    ("modes", "dynamics"),
    ("reconstruct",),
    ("io",),
    ("_cli", "__main__", "__init__"),
)
"""The floors, bottom first; a name is the first part of a module's path below ``sc_fem``."""


def _modules() -> dict[str, Path]:
    mods = {}
    for path in PKG.rglob("*.py"):
        rel = path.relative_to(SRC).with_suffix("")
        parts = list(rel.parts)
        if parts[-1] == "__init__":
            parts = parts[:-1] if len(parts) > 1 else parts
        mods[".".join(parts)] = path
    return mods


MODULES = _modules()


def _resolve(name: str) -> str | None:
    """The package module a dotted name refers to (the longest prefix that is a module)."""
    parts = name.split(".")
    while parts:
        cand = ".".join(parts)
        if cand in MODULES:
            return cand
        parts.pop()
    return None


def _package_of(module: str) -> str:
    path = MODULES[module]
    return module if path.name == "__init__.py" else module.rsplit(".", 1)[0]


def imports(module: str) -> set[str]:
    """The ``sc_fem`` modules that ``module`` imports anywhere in its source."""
    tree = ast.parse(MODULES[module].read_text(encoding="utf-8"))
    pkg = _package_of(module)
    out: set[str] = set()
    for node in ast.walk(tree):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")
                base = base[: len(base) - (node.level - 1)]
                stem = ".".join(base + ([node.module] if node.module else []))
            else:
                stem = node.module or ""
            names = [f"{stem}.{a.name}" for a in node.names] + [stem]
        for n in names:
            if n == "sc_fem" or n.startswith("sc_fem."):
                target = _resolve(n)
                if target and target != module:
                    out.add(target)
    # "from . import x" names both the package and x; keep the most specific target per import
    return {t for t in out if not any(o != t and o.startswith(t + ".") for o in out) or t != pkg}


def floor(module: str) -> int:
    parts = module.split(".")
    head = parts[1] if len(parts) > 1 else "__init__"
    for i, names in enumerate(LAYERS):
        if head in names:
            return i
    raise AssertionError(f"module {module} is on no floor of LAYERS: add it")


GRAPH = {m: imports(m) for m in MODULES}


def test_every_module_is_on_a_floor():
    for m in MODULES:
        floor(m)


def test_no_import_goes_up():
    up = sorted(f"{m} -> {t}" for m, ts in GRAPH.items() for t in ts if floor(t) > floor(m))
    assert not up, "imports going up the stack:\n" + "\n".join(up)


def test_modes_and_dynamics_do_not_import_each_other():
    def head(m):
        return m.split(".")[1] if "." in m else ""
    side = sorted(f"{m} -> {t}" for m, ts in GRAPH.items() for t in ts
                  if {head(m), head(t)} == {"modes", "dynamics"})
    assert not side, "\n".join(side)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def strong(v):
        work = [(v, iter(sorted(graph[v])))]
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        while work:
            node, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter[0]
                    counter[0] += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on:
                    low[node] = min(low[node], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on.discard(w)
                        comp.append(w)
                        if w == node:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out


def test_no_import_cycle():
    # a package's __init__ that re-exports its modules is the package's face, not a participant
    graph = {m: {t for t in ts if MODULES[t].name != "__init__.py" or t == "sc_fem"}
             for m, ts in GRAPH.items()}
    cycles = _cycles(graph)
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_the_checker_sees_a_cycle_and_an_upward_import():
    assert _cycles({"a": {"b"}, "b": {"a"}, "c": set()}) == [["a", "b"]]
    assert floor("sc_fem.lattice.voxelize") > floor("sc_fem.geometry.mesh")
    assert "sc_fem.lattice.cubes" in GRAPH["sc_fem.lattice.embed"]


@pytest.mark.parametrize("limit, where", [(450, "module"), (600, "_cli")])
def test_sizes(limit, where):
    if where == "module":
        big = {str(p.relative_to(SRC)): n for p in PKG.rglob("*.py")
               if (n := len(p.read_text(encoding="utf-8").splitlines())) > limit}
        assert not big, f"modules over {limit} lines: {big}"
    else:
        total = sum(len(p.read_text(encoding="utf-8").splitlines()) for p in (PKG / "_cli").glob("*.py"))
        assert total <= limit, f"the command-line package has {total} lines (limit {limit})"


def test_the_batch_runner_knows_no_modes():
    """``io.batch`` runs any task on Dask; what a task computes (modes, a mode file) is the caller's
    (``io.precompute``), so the options a task takes pass the runner unopened."""
    assert GRAPH["sc_fem.io.batch"] and all(floor(t) == 0 for t in GRAPH["sc_fem.io.batch"]), GRAPH["sc_fem.io.batch"]
