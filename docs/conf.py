"""Sphinx configuration of the sc_fem documentation: ``make docs`` -> ``build/docs``.

Pages are Markdown (MyST), the notebooks are shown with their stored outputs (not executed), and
the API reference is generated from ``sc_fem.__all__`` and the subpackages' ``__all__`` on every
build (``api/gen/``, not committed), so it follows the package as it changes.
"""

from __future__ import annotations

import importlib
import os
import pkgutil
import shutil
import sys
import types
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT / "src"))

import sc_fem

project = "sc_fem"
author = "sc_fem developers"
copyright = "sc_fem developers, MIT licence"
release = version = sc_fem.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "numpydoc",
    "myst_nb",              # Markdown pages (myst-parser) and the stored notebooks
]
templates_path = ["_templates"]
exclude_patterns = ["_templates", "**.ipynb_checkpoints", "Thumbs.db", ".DS_Store"]
source_suffix = {".rst": "restructuredtext", ".md": "myst-nb", ".ipynb": "myst-nb"}

# MyST: relative links between the .md files work on GitHub and here
myst_enable_extensions = ["colon_fence"]
myst_heading_anchors = 3
nb_execution_mode = "off"            # the notebooks carry their outputs; `make test` executes them
nb_merge_streams = True

# API reference
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"member-order": "bysource"}
autodoc_typehints = "none"           # the numpydoc sections give the types
numpydoc_show_class_members = False  # the class template lists members with autodoc
numpydoc_xref_param_type = False
numpydoc_validation_checks: set[str] = set()

html_theme = "pydata_sphinx_theme"
html_title = f"sc_fem {release}"
html_theme_options = {
    "navigation_depth": 3,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
# top-level pages have no section to navigate: no left sidebar, more room for the tables
html_sidebars = {page: [] for page in ("index", "getting_started", "units", "accuracy", "performance",
                                       "corotational", "xpbd", "formats", "cli", "notebooks")}
html_static_path = ["_static"]
html_css_files = ["custom.css"]
html_show_sourcelink = False
html_last_updated_fmt = None


# ---------------------------------------------------------------- a Sphinx bug, worked around

def _fix_autosummary_summaries() -> None:
    """autosummary's ``extract_summary`` means to extend the first sentence until it parses (a
    period inside ``literal . text`` is not a sentence end) but re-parses the whole stanza instead
    of the candidate sentence, so it always cuts at the first period and the summary table gets
    an unterminated literal. Same function, parsing the candidate."""
    from docutils import nodes
    from sphinx.ext import autosummary as asm

    original = asm.extract_summary

    def extract_summary(doc, settings):
        summary = original(doc, settings)
        stanza = []
        for line in doc:
            if line.strip():
                stanza.append(line)
            elif stanza:
                break
        sentences = asm.periods_re.split(" ".join(stanza))
        if len(sentences) < 2 or not summary:
            return summary
        for i in range(len(sentences)):
            candidate = ". ".join(sentences[: i + 1]).rstrip(".") + "."
            if candidate.endswith(asm.WELL_KNOWN_ABBREVIATIONS):
                continue
            if not any(asm._parse_summary([candidate], settings).findall(nodes.system_message)):
                return asm.literal_re.sub(".", candidate)
        return summary

    asm.extract_summary = extract_summary


_fix_autosummary_summaries()


# ---------------------------------------------------------------- generated sources

def _write(path: Path, text: str) -> None:
    """Write only when the text changed, so Sphinx does not re-read unchanged pages."""
    if not path.exists() or path.read_text() != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def _copy_notebooks() -> None:
    """``notebooks/*.ipynb`` -> ``docs/notebooks/`` (the notebooks stay in one place in the repo)."""
    dest = HERE / "notebooks"
    dest.mkdir(exist_ok=True)
    wanted = {p.name for p in (ROOT / "notebooks").glob("*.ipynb")}
    for old in dest.glob("*.ipynb"):
        if old.name not in wanted:
            old.unlink()
    for name in sorted(wanted):
        src, dst = ROOT / "notebooks" / name, dest / name
        if not dst.exists() or dst.read_bytes() != src.read_bytes():
            shutil.copy2(src, dst)


SUBPACKAGES = ["geometry", "lattice", "fem", "modes", "dynamics", "reconstruct", "io"]


def _kind(obj) -> str:
    if isinstance(obj, type) and issubclass(obj, BaseException):
        return "Exceptions and warnings"
    if isinstance(obj, type):
        return "Classes"
    if callable(obj):
        return "Functions"
    return "Constants"


def _table(names: list[str], objects: dict, toctree: bool) -> str:
    out = []
    for kind in ("Functions", "Classes", "Exceptions and warnings", "Constants"):
        group = [n for n in names if _kind(objects[n]) == kind]
        if not group:
            continue
        out += [f".. rubric:: {kind}", "", ".. autosummary::"]
        if toctree:
            out.append("   :toctree: obj")
        out.append("")
        out += [f"   {n}" for n in group]
        out.append("")
    return "\n".join(out)


def _public_modules(package: types.ModuleType) -> list[str]:
    """The package's public modules, named relative to it (autosummary's current module)."""
    return [m.name for m in pkgutil.iter_modules(package.__path__)
            if not m.name.startswith("_") and not m.ispkg]


def _api_pages() -> None:
    """One page for ``sc_fem`` (its ``__all__``) and one per subpackage (the names it adds, the
    names it shares with ``sc_fem``, its modules)."""
    gen = HERE / "api" / "gen"
    top = [n for n in sc_fem.__all__ if n != "__version__" and n not in SUBPACKAGES]
    top_objects = {n: getattr(sc_fem, n) for n in top}
    modules = _public_modules(sc_fem)
    _write(gen / "sc_fem.rst", "\n".join([
        "sc_fem", "======", "",
        ".. automodule:: sc_fem", "   :no-members:", "",
        ".. currentmodule:: sc_fem", "",
        "Everything in ``sc_fem.__all__`` (the subpackages have pages of their own).", "",
        _table(sorted(top, key=str.lower), top_objects, toctree=True),
        ".. rubric:: Modules", "",
        ".. autosummary::", "   :toctree: obj", "",
        *[f"   {m}" for m in modules], ""]))
    for name in SUBPACKAGES:
        pkg = importlib.import_module(f"sc_fem.{name}")
        names = list(getattr(pkg, "__all__", []))
        objects = {n: getattr(pkg, n) for n in names}
        own = [n for n in names if n not in top and not isinstance(objects[n], types.ModuleType)]
        shared = [n for n in names if n in top]
        title = f"sc_fem.{name}"
        lines = [title, "=" * len(title), "",
                 f".. automodule:: sc_fem.{name}", "   :no-members:", "",
                 f".. currentmodule:: sc_fem.{name}", ""]
        if shared:
            lines += ["Also exported by :mod:`sc_fem` (documented there): "
                      + ", ".join(f":obj:`~sc_fem.{n}`" for n in shared) + ".", ""]
        if own:
            lines += [_table(own, objects, toctree=True)]
        lines += [".. rubric:: Modules", "", ".. autosummary::", "   :toctree: obj", "",
                  *[f"   {m}" for m in _public_modules(pkg)], ""]
        _write(gen / f"{name}.rst", "\n".join(lines))


def _cli_reference() -> None:
    """``sc-fem --help`` and every ``sc-fem COMMAND --help``, as the parser prints them
    (``api/gen/cli.inc``, included by ``cli.md``)."""
    import argparse

    from sc_fem._cli.main import build_parser

    os.environ["COLUMNS"] = "96"               # argparse wraps to the terminal's width
    parser = build_parser()
    parser.prog = "sc-fem"
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    parts = ["### sc-fem", "", "```text", parser.format_help().rstrip(), "```", ""]
    for name, command in sub.choices.items():
        parts += [f"### sc-fem {name}", "", "```text", command.format_help().rstrip(), "```", ""]
    _write(HERE / "api" / "gen" / "cli.inc", "\n".join(parts))


_copy_notebooks()
_api_pages()
_cli_reference()
