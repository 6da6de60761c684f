"""Which cubes an analysis uses: ``element="auto"`` decides between the trilinear cubes and the
multiscale degree-3 cubes from how thin the model's walls are (:func:`choose_element`), and a
trilinear analysis of walls much thinner than its cubes says what it risks (:func:`trilinear_note`)."""

from __future__ import annotations

import numpy as np

from ..errors import InputError
from ..lattice.walls import thinnest_walls
from .hexahedron import DEFAULT_ELEMENT, ELEMENTS, check_element
from .highorder import DEGREES

AUTO = "auto"
"""The element name that lets :func:`choose_element` decide (the linear analyses' default)."""

THIN_WALLS = 1.0 / 40.0
"""``element="auto"`` takes multiscale ``"q3"`` cubes for a model whose thin walls are thinner than
this fraction of its longest extent (resolution-independent: the choice does not flip between grids).
The I-section, channel and portal frame (1/160-1/200), plate, table, the built-in chair (1/64) and
bridge (1/140) and the armchair (1/56) are thin-walled; the bunny (1/18), spot (1/13) and the built-in
beam (1/24) are not."""

def choose_element(scene, element: str = AUTO, *, lumped: bool = False) -> tuple[str, str]:
    """The element an analysis of ``scene`` uses: ``element`` itself, or for ``"auto"`` the multiscale
    ``"q3"`` cubes when the model is thin-walled (:data:`THIN_WALLS`) and has a surface to make them
    from, else the trilinear default (:data:`sc_fem.DEFAULT_ELEMENT`).

    Parameters
    ----------
    scene : Scene
        The model and its source mesh.
    element : str
        ``"auto"``, a trilinear element (:data:`sc_fem.ELEMENTS`) or ``"q2"`` / ``"q3"``.
    lumped : bool
        The analysis lumps the mass (defined for trilinear cubes only: ``"auto"`` takes them).

    Returns
    -------
    element : str
    reason : str
        Why (for ``"auto"``: the walls' thickness against the model's size).
    """
    if not isinstance(element, str):
        raise InputError(f"element must be 'auto', one of {list(ELEMENTS)} or {sorted(DEGREES)}, got {element!r}")
    name = element.lower()
    if name != AUTO:
        return (name if name in DEGREES else check_element(name)), "requested"
    if scene.mesh is None or not len(scene.faces):
        return DEFAULT_ELEMENT, "auto: no surface mesh to make multiscale cubes from"
    if lumped:
        return DEFAULT_ELEMENT, "auto: lumped mass (trilinear cubes)"
    model = scene.model
    wall = thinnest_walls(model, scene.mesh.vertices, scene.faces)
    longest = float(np.ptp(model.nodes, axis=0).max())
    ratio = f"walls {wall * model.scale * 1e3:.3g} mm, 1/{longest / wall:.0f} of the model" if np.isfinite(wall) \
        else "no partly filled cube"
    if wall < THIN_WALLS * longest:
        return "q3", f"auto: thin-walled ({ratio} < 1/{1 / THIN_WALLS:.0f}): multiscale cubes"
    return DEFAULT_ELEMENT, f"auto: not thin-walled ({ratio})"


TRILINEAR_WALLS = 1.0 / 3.0
"""A trilinear analysis warns when the model's thin walls are thinner than this fraction of a cube."""


def trilinear_note(scene, element: str) -> str | None:
    """A warning for a trilinear analysis of a thin-walled model (:data:`THIN_WALLS`) whose walls are
    much thinner than its cubes (:data:`TRILINEAR_WALLS`), None otherwise (or for higher-order cubes,
    or without a surface).

    Parameters
    ----------
    scene : Scene
        The model and its source mesh.
    element : str
        The element the analysis uses.

    Returns
    -------
    str or None
    """
    if element in DEGREES or scene.mesh is None or not len(scene.faces):
        return None
    model = scene.model
    if not np.any(np.asarray(model.fraction) < 1.0 - 1e-12):
        return None
    wall = thinnest_walls(model, scene.mesh.vertices, scene.faces)
    longest = float(np.ptp(model.nodes, axis=0).max())
    if not (wall < TRILINEAR_WALLS * model.pitch and wall < THIN_WALLS * longest):
        return None
    mm = 1e3 * model.scale
    return (f"the model's thin walls ({wall * mm:.3g} mm) are thinner than a third of a cube ({model.pitch * mm:.3g} "
            f"mm): trilinear cubes bend them roughly and can be far too stiff where walls meet inside a cube "
            f"(an I-section at 32 cubes: +53 % in its frequencies); element='q3' (--element q3) makes each cube from a finer "
            f"model of its walls (a few %, 10-50x slower)")
