"""Dirichlet boundary conditions: which lattice nodes are held fixed.

A node set is the union of

* half-spaces and boxes in model coordinates, written like on the command line
  ``--fix "x<0.01"``, ``--fix "z<min+0.02"``, ``--fix "y>max-0.1"`` (axis, ``<`` or ``>``, a value
  in model units, optionally relative to the bounding box ``min``/``max`` of the lattice nodes);
  several conditions joined by ``&`` must all hold (``"x>0.2 & x<0.4"`` is a slab, six make a box);
* predicates ``f(points (n, 3) model units) -> bool (n,)``;
* source-mesh vertices (``--fix-vertices FILE``: indices, one a line): all 8 nodes of the cube
  each vertex is embedded in (the cube of :func:`sc_fem.lattice.embed.embedding`, the same as ``W``'s).

Comparisons include a tolerance of ``1e-6 * pitch``, so ``"x<min+0"`` selects the nodes on the
lowest face. Each spec must select at least one node, else :class:`BoundaryConditionError`.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Union

import numpy as np
from numpy.typing import ArrayLike

from .._validate import as_indices, as_points
from ..errors import BoundaryConditionError, InputError
from .cubes import CubeModel
from .embed import Embedding, embedding

_AXES = {"x": 0, "y": 1, "z": 2}
_UNUM = r"(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_COND = re.compile(rf"^\s*([xyzXYZ])\s*([<>])=?\s*(?:(min|max)\s*(?:([+-])\s*({_UNUM}))?|([+-]?{_UNUM}))\s*$")


@dataclass(frozen=True)
class FixSpec:
    """A half-space or an intersection of half-spaces (slab, box) in model coordinates.

    Parameters
    ----------
    conditions : tuple of (axis, op, ref, value)
        ``axis`` 0/1/2, ``op`` ``"<"`` or ``">"``, ``ref`` ``None`` (absolute), ``"min"`` or
        ``"max"`` (relative to the nodes' bounding box), ``value`` in model units.
    text : str
        The spec as written (for messages).
    """

    conditions: tuple[tuple[int, str, str | None, float], ...]
    text: str = ""

    @classmethod
    def box(cls, lo: ArrayLike, hi: ArrayLike) -> "FixSpec":
        """All nodes with ``lo <= p <= hi`` (model units, each shape (3,)).

        Parameters
        ----------
        lo, hi : array_like, shape (3,)
            Lowest and highest corner of the box, model units.

        Returns
        -------
        FixSpec
            The six half-spaces of the box.
        """
        lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
        if lo.shape != (3,) or hi.shape != (3,):
            raise InputError(f"box corners must have shape (3,), got {lo.shape} and {hi.shape}")
        conds = tuple((a, ">", None, float(lo[a])) for a in range(3)) + \
            tuple((a, "<", None, float(hi[a])) for a in range(3))
        return cls(conds, text=f"box {lo.tolist()}..{hi.tolist()}")

    def select(self, points: np.ndarray, lo: np.ndarray, hi: np.ndarray, tol: float) -> np.ndarray:
        """Boolean mask ``(n,)`` of ``points`` (model units) inside; ``lo``/``hi`` the bounding box.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            Positions, model units (e.g. the lattice nodes).
        lo, hi : ndarray, shape (3,)
            Bounding box that ``"min"``/``"max"`` conditions refer to, model units.
        tol : float
            Tolerance added to every comparison, model units.

        Returns
        -------
        ndarray of bool, shape (n,)
            Points satisfying every condition.
        """
        mask = np.ones(len(points), dtype=bool)
        for axis, op, ref, value in self.conditions:      # loop over conditions (a handful)
            bound = value + (0.0 if ref is None else (lo[axis] if ref == "min" else hi[axis]))
            if op == "<":
                mask &= points[:, axis] <= bound + tol
            else:
                mask &= points[:, axis] >= bound - tol
        return mask

    def __str__(self) -> str:
        return self.text or " & ".join(f"{'xyz'[a]}{op}{(ref or '')}{v:+g}" for a, op, ref, v in self.conditions)


def parse_fix(spec: str) -> FixSpec:
    """Parse ``"x<0.01"``, ``"z<min+0.02"``, ``"y>max-0.1"`` or ``"x>0.2 & x<0.4"``.

    Parameters
    ----------
    spec : str
        Conditions ``AXIS<VALUE`` or ``AXIS>VALUE`` joined by ``&``; values in model units,
        absolute or ``min+number`` / ``max-number`` (relative to the nodes' bounding box).

    Returns
    -------
    FixSpec
        The parsed conditions, with ``spec`` as its text.

    Raises
    ------
    BoundaryConditionError
        If the text is not of that form.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise BoundaryConditionError(f"fix spec must be a non-empty string like 'x<0.01', got {spec!r}")
    conds = []
    for part in spec.split("&"):
        mt = _COND.match(part)
        if mt is None:
            raise BoundaryConditionError(
                f"cannot parse fix spec {spec!r} (part {part.strip()!r}); expected AXIS<VALUE or AXIS>VALUE "
                "with AXIS in x, y, z and VALUE a number, 'min+number' or 'max-number', e.g. 'x<0.01', "
                "'z<min+0.02', 'y>max-0.1'")
        axis, op, ref, sign, rel, absval = mt.groups()
        if ref is not None:
            value = float(rel) * (-1.0 if sign == "-" else 1.0) if rel is not None else 0.0
        else:
            value = float(absval)
        conds.append((_AXES[axis.lower()], op, ref, value))
    return FixSpec(tuple(conds), text=spec.strip())


Fix = Union[str, FixSpec, Callable[[np.ndarray], np.ndarray]]


def read_vertex_file(path: str | os.PathLike) -> np.ndarray:
    """Vertex indices from a text file, one non-negative integer a line (``#`` comments allowed).

    Parameters
    ----------
    path : str or os.PathLike
        The text file (integers may also be separated by spaces or commas).

    Returns
    -------
    ndarray of int64, shape (k,)
        The indices, in file order.

    Raises
    ------
    BoundaryConditionError
        The file cannot be read, holds a token that is not a non-negative integer, or no index.
    """
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise BoundaryConditionError(f"cannot read vertex file {str(p)!r}: {exc.strerror or exc}") from None
    out = []
    for lineno, line in enumerate(text.splitlines(), 1):   # loop over lines of a user file
        s = line.split("#", 1)[0].strip()
        if not s:
            continue
        for tok in s.replace(",", " ").split():
            try:
                v = int(tok)
            except ValueError:
                raise BoundaryConditionError(f"{p}:{lineno}: {tok!r} is not an integer vertex index") from None
            if v < 0:
                raise BoundaryConditionError(f"{p}:{lineno}: vertex index must be >= 0, got {v}")
            out.append(v)
    if not out:
        raise BoundaryConditionError(f"vertex file {str(p)!r} contains no vertex index")
    return np.asarray(out, dtype=np.int64)


def fixed_nodes(model: CubeModel, fix: Iterable[Fix] | Fix | None = None, *, vertices: ArrayLike | None = None,
                mesh_vertices: ArrayLike | None = None, mesh_embedding: Embedding | None = None) -> np.ndarray:
    """Indices of the lattice nodes to hold fixed.

    Parameters
    ----------
    model : CubeModel
        The lattice whose nodes (model units) are selected.
    fix : str, FixSpec, callable, or a list of them, optional
        Specs (see :func:`parse_fix`) or predicates ``f(nodes (m, 3) model units) -> (m,) bool``;
        the union is taken.
    vertices : array_like of int, shape (k,), optional
        Indices into ``mesh_vertices`` of source-mesh vertices whose cubes' nodes are fixed.
    mesh_vertices : array_like, shape (V, 3), optional
        Source-mesh vertex positions in model units (needed with ``vertices``, ignored without).
    mesh_embedding : sc_fem.lattice.embed.Embedding, optional
        The embedding of all ``V`` source-mesh vertices, if the caller already has it (then
        ``mesh_vertices`` is not needed and the vertices are not located again).

    Returns
    -------
    ndarray of int64, shape (f,)
        Sorted unique node indices.

    Raises
    ------
    BoundaryConditionError
        A spec cannot be parsed or selects no node; a vertex is out of range or outside the lattice.
    """
    if not isinstance(model, CubeModel):
        raise InputError(f"model must be a CubeModel, got {type(model).__name__}")
    nodes = model.nodes
    lo, hi = nodes.min(axis=0), nodes.max(axis=0)
    tol = 1e-6 * model.pitch
    mask = np.zeros(model.n_nodes, dtype=bool)
    if fix is None:
        fix = []
    elif isinstance(fix, (str, FixSpec)) or callable(fix):
        fix = [fix]
    for item in fix:                                          # loop over user specs
        if isinstance(item, str):
            item = parse_fix(item)
        if isinstance(item, FixSpec):
            sel = item.select(nodes, lo, hi, tol)
            name = f"fix spec {str(item)!r}"
        elif callable(item):
            try:
                sel = np.asarray(item(nodes.copy()))
            except Exception as exc:
                raise BoundaryConditionError(f"fix predicate {item!r} failed on the node positions: {exc}") from exc
            if sel.shape != (model.n_nodes,) or sel.dtype != bool:
                raise BoundaryConditionError(
                    f"fix predicate must return a bool array of shape ({model.n_nodes},), got {sel.dtype} {sel.shape}")
            name = f"fix predicate {getattr(item, '__name__', item)!r}"
        else:
            raise BoundaryConditionError(f"fix entries must be strings, FixSpec or callables, got {type(item).__name__}")
        if not sel.any():
            raise BoundaryConditionError(
                f"{name} selects no node (nodes span x [{lo[0]:g}, {hi[0]:g}], y [{lo[1]:g}, {hi[1]:g}], "
                f"z [{lo[2]:g}, {hi[2]:g}] model units)")
        mask |= sel
    if vertices is not None:
        if mesh_vertices is None and mesh_embedding is None:
            raise BoundaryConditionError("vertices= needs mesh_vertices= (the source-mesh vertex positions)")
        mv = None if mesh_embedding is not None else as_points(mesh_vertices, "mesh_vertices")
        n_v = len(mesh_embedding.cube) if mv is None else len(mv)
        idx = as_indices(vertices, n_v, f"vertex indices (a mesh of {n_v} vertices)", allow_empty=False,
                         error=BoundaryConditionError)
        if mv is None:
            cubes = mesh_embedding.cube[idx]
        else:
            cubes = embedding(model, mv[idx]).cube     # the cube each vertex is embedded in (as W)
        mask[model.hexes[cubes].ravel()] = True
    return np.flatnonzero(mask)


def fixed_dofs(nodes: ArrayLike) -> np.ndarray:
    """All three DOFs of each node: ``[3i, 3i+1, 3i+2, ...]``, shape (3f,).

    Parameters
    ----------
    nodes : array_like of int, shape (f,)
        Node indices (e.g. from :func:`fixed_nodes`).

    Returns
    -------
    ndarray of int64, shape (3f,)
        DOF indices ``3 i + c`` (node-major, x, y, z), in the order of ``nodes``.
    """
    nodes = np.asarray(nodes, dtype=np.int64).ravel()
    return (3 * nodes[:, None] + np.arange(3)).ravel()
