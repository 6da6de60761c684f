"""Every public callable has a numpydoc docstring and type annotations.

Walks ``sc_fem.__all__`` (each name resolved with ``getattr(sc_fem, name)``): functions, classes
(the class docstring documents ``__init__``'s parameters, or a dataclass's fields in "Attributes"
or "Parameters"), and the public methods and properties those classes define in sc_fem (inherited
ones from an sc_fem base class included; those inherited from the standard library not). Checked
with :mod:`numpydoc.docscrape`:

* a callable with parameters (other than ``self``/``cls``) has a "Parameters" section naming each
  of them (``*args``/``**kwargs`` may be written with their stars, e.g. ``**fields``);
* a callable returning something (return annotation not ``None``) has "Returns" or "Yields";
* every parameter and the return carry a type annotation;
* a property has a docstring (one line suffices) and a return annotation.

One test per callable, so a failure names it and says what it lacks.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import types
import warnings

import pytest
from numpydoc.docscrape import NumpyDocString

import sc_fem

EXCLUDED: dict[str, str] = {
    # not callables: data documented where they are defined
    "__version__": "the version string",
    "ELEMENTS": "a tuple of element names (data, documented in sc_fem.fem.hexahedron)",
    "DEFAULT_ELEMENT": "a string constant (data, documented in sc_fem.fem.hexahedron)",
    # re-exported subpackages: modules, not callables (their public names have their own tests)
    "geometry": "re-exported subpackage",
    "lattice": "re-exported subpackage",
    "fem": "re-exported subpackage",
    "modes": "re-exported subpackage",
    "dynamics": "re-exported subpackage",
    "reconstruct": "re-exported subpackage",
    "io": "re-exported subpackage",
}
"""Names of ``sc_fem.__all__`` that are not checked, each with why (none is a callable:
:func:`test_exclusions_are_not_callables` holds the list to that)."""

PENDING: set[str] = set()
"""Test ids expected to fail for now (strict xfail)."""

_NO_RETURN = {"None", "NoReturn", "Never", "typing.NoReturn", "typing.Never"}


def _in_package(obj) -> bool:
    module = getattr(obj, "__module__", None) or ""
    return module == "sc_fem" or module.startswith("sc_fem.")


def _doc(obj) -> NumpyDocString:
    """The parsed numpydoc docstring of ``obj`` (a parse warning is a failure)."""
    text = inspect.getdoc(obj) or ""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return NumpyDocString(text)


def _names(section) -> set[str]:
    """Documented names of a Parameters/Attributes section: ``x, y : float`` names both, and the
    stars of ``*args``/``**fields`` are dropped."""
    out = set()
    for entry in section:
        for name in entry.name.split(","):
            out.add(name.strip().lstrip("*"))
    return out


def _annotation_missing(annotation) -> bool:
    return annotation is inspect.Parameter.empty


def _returns_nothing(annotation) -> bool:
    return annotation is None or annotation is type(None) or (isinstance(annotation, str) and annotation in _NO_RETURN)


def _check_callable(func, *, skip_first: bool) -> list[str]:
    """What ``func``'s docstring and signature lack."""
    if not (inspect.getdoc(func) or "").strip():
        return ["no docstring"]
    doc = _doc(func)
    sig = inspect.signature(func)
    params = list(sig.parameters.values())[1 if skip_first else 0:]
    problems = _check_parameters(params, _names(doc["Parameters"]), "Parameters")
    if _annotation_missing(sig.return_annotation):
        problems.append("no return annotation")
    elif not _returns_nothing(sig.return_annotation) and not (doc["Returns"] or doc["Yields"]):
        problems.append(f"returns {sig.return_annotation} but has no Returns/Yields section")
    return problems


def _check_parameters(params: list[inspect.Parameter], documented: set[str], where: str) -> list[str]:
    """Parameters missing from the ``documented`` names, and those without an annotation."""
    problems = []
    undocumented = [p.name for p in params if p.name not in documented]
    if undocumented:
        problems.append(f"not in {where}: {', '.join(undocumented)}")
    unannotated = [p.name for p in params if _annotation_missing(p.annotation)]
    if unannotated:
        problems.append(f"parameters without annotation: {', '.join(unannotated)}")
    return problems


def _check_class(cls: type) -> list[str]:
    """The class docstring documents ``__init__``'s parameters ("Parameters"; a dataclass: its
    fields and parameters in "Attributes" or "Parameters"), which are annotated. An ``__init__``
    inherited from the standard library (exceptions) has nothing to check."""
    if not (cls.__dict__.get("__doc__") or "").strip():
        return ["no class docstring"]
    doc = _doc(cls)
    owner = next(c for c in cls.__mro__ if "__init__" in c.__dict__)
    params = list(inspect.signature(owner.__dict__["__init__"]).parameters.values())[1:] if _in_package(owner) else []
    if not dataclasses.is_dataclass(cls):
        return _check_parameters(params, _names(doc["Parameters"]), "the class docstring's Parameters")
    documented = _names(doc["Attributes"]) | _names(doc["Parameters"])
    fields = [f.name for f in dataclasses.fields(cls) if not f.name.startswith("_")]
    problems = []
    missing = [f for f in fields if f not in documented]
    if missing:
        problems.append(f"dataclass fields not in Attributes/Parameters: {', '.join(missing)}")
    return problems + _check_parameters([p for p in params if p.name not in fields], documented,
                                        "Attributes/Parameters")


def _check_member(cls: type, name: str) -> list[str]:
    """A method is checked like a function (without ``self``/``cls``); a property needs a
    docstring (one line suffices) and a return annotation."""
    raw = next(c.__dict__[name] for c in cls.__mro__ if name in c.__dict__)
    if isinstance(raw, (property, functools.cached_property)):
        fget = raw.fget if isinstance(raw, property) else raw.func
        problems = [] if (inspect.getdoc(fget) or "").strip() else ["property without docstring"]
        if _annotation_missing(inspect.signature(fget).return_annotation):
            problems.append("property without return annotation")
        return problems
    if isinstance(raw, staticmethod):
        return _check_callable(raw.__func__, skip_first=False)
    if isinstance(raw, classmethod):
        return _check_callable(raw.__func__, skip_first=True)
    return _check_callable(raw, skip_first=True)


def _members(cls: type) -> list[tuple[str, type, str]]:
    """(id, class, name) of the public methods and properties ``cls`` has from sc_fem classes."""
    out = []
    for name in sorted(dir(cls)):
        if name.startswith("_"):
            continue
        owner = next((c for c in cls.__mro__ if name in c.__dict__), None)
        if owner is None or not _in_package(owner):
            continue
        raw = owner.__dict__[name]
        if isinstance(raw, (staticmethod, classmethod)):
            raw = raw.__func__
        if isinstance(raw, (property, functools.cached_property)) or inspect.isfunction(raw):
            out.append((f"{owner.__qualname__}.{name}", cls, name))
    return out


def _cases() -> list:
    """One pytest param per public callable (methods reached through several classes once)."""
    cases: dict[str, tuple] = {}
    for name in sc_fem.__all__:
        if name in EXCLUDED:
            continue
        try:
            obj = getattr(sc_fem, name)
        except Exception as exc:  # noqa: BLE001 -- reported by the test, not at collection
            cases[name] = ("unresolved", name, exc)
            continue
        if not callable(obj):
            cases[name] = ("data", name, type(obj).__name__)
        elif isinstance(obj, type):
            cases[name] = ("class", obj, None)
            for case_id, cls, member in _members(obj):
                cases.setdefault(case_id, ("member", cls, member))
        else:
            cases[name] = ("function", obj, None)
    marks = {True: pytest.mark.xfail(strict=True, reason="pending: lives in dynamics/, io/ or _cli/")}
    return [pytest.param(*case, id=case_id, marks=marks.get(case_id in PENDING, ())) for case_id, case in cases.items()]


CASES = _cases()


@pytest.mark.parametrize(("kind", "obj", "member"), CASES)
def test_public_callable_is_documented(kind, obj, member):
    if kind == "unresolved":
        pytest.fail(f"sc_fem.{obj} does not resolve: {member!r}")
    if kind == "data":
        pytest.fail(f"sc_fem.{obj} is a {member}, not a callable: list it in EXCLUDED with the reason")
    if kind == "class":
        problems = _check_class(obj)
    elif kind == "member":
        problems = _check_member(obj, member)
    else:
        problems = _check_callable(obj, skip_first=False)
    assert problems == [], "; ".join(problems)


def test_exclusions_are_not_callables():
    """The exclusion list hides no callable: each name is a module or plain data, and is public."""
    for name, why in EXCLUDED.items():
        assert name in sc_fem.__all__, f"{name} is excluded but not public"
        assert why
        obj = getattr(sc_fem, name)
        assert isinstance(obj, types.ModuleType) or not callable(obj), f"{name} is callable: check it"


def test_pending_names_exist():
    """Every PENDING entry is a test id of this file (a stale entry would hide nothing, but misleads)."""
    ids = {param.id for param in CASES}
    assert sorted(PENDING - ids) == []
