"""Element matrices of cubes: the unit-cube matrices of the hexahedral elements
(:mod:`sc_fem.fem.hexahedron`: ``"q1"``, ``"q1sri"``, ``"q1i"``) scaled by each cube's edge and
Lame parameters, on demand in chunks for the assembler; for the partly filled cubes of a model
with ``stiffness="moments"``, the finite-cell matrices of :mod:`sc_fem.fem.finite_cell`,
integrated over their filled region. The assembler and the integrators take their element
matrices from here, and the element names of both modules are importable from here too.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from .finite_cell import FCM_ALPHA, MOMENT_ELEMENTS, PARTIAL_BELOW, moment_mass, moment_stiffness
from .hexahedron import (CENTRE_RULE, DEFAULT_ELEMENT, ELEMENTS, LINEAR_ELEMENTS, _linear_rows, check_element,
                         q1i_unit_stiffness, reference_mass, reference_stiffness)

__all__ = ["CENTRE_RULE", "DEFAULT_ELEMENT", "ELEMENTS", "FCM_ALPHA", "LINEAR_ELEMENTS", "MOMENT_ELEMENTS",
           "PARTIAL_BELOW", "check_element", "cube_mass_chunks", "cube_stiffness", "cube_stiffness_chunks",
           "element_stiffness", "moment_mass", "moment_stiffness", "q1i_unit_stiffness", "reference_mass",
           "reference_stiffness", "stiffness_chunks", "stiffness_values"]

_Q1I_PRECOMPUTE = 2048
"""Up to this many distinct ``lambda / mu`` ratios, :func:`stiffness_chunks` builds all q1i unit
matrices once per call (at most 2048 x 576 floats, 9.4 MB); beyond, per chunk."""


def element_stiffness(element: str, lam, mu, h: float) -> np.ndarray:
    """Stiffness matrices of cubes, vectorized.

    Parameters
    ----------
    element : {"q1", "q1i", "q1sri"}
    lam, mu : array_like, shape (n,)
        Lame parameters per cube, Pa.
    h : float
        Cube edge, m.

    Returns
    -------
    ndarray, shape (n, 24, 24)
        Element stiffness matrices, N/m.
    """
    element = check_element(element)
    lam = np.atleast_1d(np.asarray(lam, dtype=np.float64))
    mu = np.atleast_1d(np.asarray(mu, dtype=np.float64))
    return stiffness_values(element, lam, mu, h).reshape(-1, 24, 24)


def stiffness_chunks(element: str, lam: np.ndarray, mu: np.ndarray, h: float) -> Callable[[int, int], np.ndarray]:
    """Element matrices of cubes ``s:e`` on demand, for the assembler's chunked scatter.

    The per-call work is done once here: the reference rows of a linear element (cached per
    element) or, for ``"q1i"``, the distinct ``lambda / mu`` ratios of all cubes and (up to
    2048 of them) their unit matrices; each chunk then only scales and indexes them. With more
    distinct ratios (per-cube nu) a chunk builds the unit matrices of its own ratios, so the
    memory stays bounded by the chunk size.

    Parameters
    ----------
    element : {"q1", "q1i", "q1sri"}
    lam, mu : ndarray, shape (n,)
        Lame parameters per cube, Pa.
    h : float
        Cube edge, m.

    Returns
    -------
    callable
        ``values(s, e) -> ndarray (e - s, 576)``: flattened (row-major 24x24) matrices, N/m.
    """
    if element in LINEAR_ELEMENTS:
        rows = _linear_rows(element)                                        # (2, 576)
        coef = np.stack([lam * h, mu * h], axis=1)                          # (n, 2)
        return lambda s, e: coef[s:e] @ rows                               # (e - s, 576)
    uniq, inv = np.unique(lam / mu, return_inverse=True)
    inv = inv.ravel()
    muh = mu * h
    if len(uniq) <= _Q1I_PRECOMPUTE:          # a few materials: every unit matrix once, chunks index
        units = q1i_unit_stiffness(uniq).reshape(len(uniq), 576)
        return lambda s, e: muh[s:e, None] * units[inv[s:e]]

    def chunk(s: int, e: int) -> np.ndarray:  # many distinct nu: only this chunk's ratios (bounded memory)
        used, local = np.unique(inv[s:e], return_inverse=True)
        return muh[s:e, None] * q1i_unit_stiffness(uniq[used]).reshape(len(used), 576)[local.ravel()]

    return chunk


def stiffness_values(element: str, lam: np.ndarray, mu: np.ndarray, h: float) -> np.ndarray:
    """Flattened element matrices ``(n, 576)`` (row-major 24x24), N/m."""
    return stiffness_chunks(element, lam, mu, h)(0, len(lam))


def cube_stiffness_chunks(model, element: str) -> Callable[[int, int], np.ndarray]:
    """Element matrices of a model's cubes ``s:e`` (flattened, N/m), honouring its partial-cube
    stiffness (:attr:`sc_fem.CubeModel.stiffness`): ``"moments"`` integrates the partly filled
    cubes over their filled region (elements in :data:`MOMENT_ELEMENTS`; others fall back to
    ``"fraction"``), full cubes use the reference matrix."""
    element = check_element(element)
    h = model.h
    if model.stiffness != "moments" or element not in MOMENT_ELEMENTS:
        return stiffness_chunks(element, *model.lame(), h)
    lam, mu = model.lame(material=True)
    ref = stiffness_chunks(element, lam, mu, h)
    partial = model.fraction < PARTIAL_BELOW
    mom = model.moments

    def chunk(s: int, e: int) -> np.ndarray:
        v = np.array(ref(s, e))
        part = s + np.flatnonzero(partial[s:e])
        if len(part):
            v[part - s] = moment_stiffness(element, mom[part], lam[part], mu[part], h)
        return v

    return chunk


def cube_mass_chunks(model, masses: np.ndarray) -> Callable[[int, int], np.ndarray]:
    """Consistent mass matrices (flattened, kg) of a model's cubes ``s:e`` with masses ``masses``
    (n,) kg: partly filled cubes of a ``"moments"`` model distribute their mass like their filled
    region (:func:`moment_mass`), every other cube is ``m_e`` times the reference matrix (as the
    stiffness: a full cube's moments give it up to round-off, at a matrix product per cube)."""
    mref = reference_mass().ravel()
    masses = np.asarray(masses, dtype=np.float64)
    if model.stiffness != "moments":
        return lambda s, e: masses[s:e, None] * mref[None, :]
    partial = model.fraction < PARTIAL_BELOW
    mom = model.moments

    def chunk(s: int, e: int) -> np.ndarray:
        v = masses[s:e, None] * mref[None, :]
        part = s + np.flatnonzero(partial[s:e])
        if len(part):
            v[part - s] = moment_mass(mom[part], masses[part])
        return v

    return chunk


def cube_stiffness(model, element: str) -> np.ndarray:
    """All element matrices of a model, shape (n, 24, 24), N/m (see :func:`cube_stiffness_chunks`)."""
    return cube_stiffness_chunks(model, element)(0, model.n_cubes).reshape(-1, 24, 24)
