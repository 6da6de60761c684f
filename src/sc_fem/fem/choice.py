"""Which cubes an analysis uses: ``element="auto"`` decides between the trilinear cubes and the
multiscale degree-3 cubes from how thin the model's walls are (:func:`choose_element`), and a
trilinear analysis of walls much thinner than its cubes says what it risks (the same call's note)."""

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
this fraction of its longest extent, and than :data:`AUTO_WALL_CUBES` cubes.
The I-section, channel and portal frame (1/160-1/200), plate, table, the built-in chair (1/64) and
bridge (1/140) and the armchair (1/56) are thin-walled; the bunny (1/18-1/19), spot (1/13) and the built-in
beam (1/24) are not."""

AUTO_WALL_CUBES = 1.0
"""``element="auto"`` keeps the trilinear cubes where the thin walls are at least this many cubes
thick: they resolve them there (the built-in chair at 64 cubes has walls of one cube and q1i is
2.7 % off its conforming reference), while q3 cubes would take ~7x the DOFs (the chair at 64:
751,113, more than LOBPCG or a factorization can hold in half of this 24 GiB machine's memory)."""

def choose_element(scene, element: str = AUTO, *, lumped: bool = False) -> tuple[str, str, str | None]:
    """The element an analysis of ``scene`` uses, why, and what it risks: ``element`` itself, or for
    ``"auto"`` the multiscale ``"q3"`` cubes when the model is thin-walled (:data:`THIN_WALLS`), its
    walls thinner than a cube (:data:`AUTO_WALL_CUBES`) and it has a surface to make them from, else the trilinear default (:data:`sc_fem.DEFAULT_ELEMENT`).
    The walls are measured once (:func:`sc_fem.lattice.walls.thinnest_walls`), for the choice and the note.

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
    note : str or None
        For trilinear cubes on a thin-walled model whose walls are thinner than
        :data:`TRILINEAR_WALLS` of a cube: a warning to give (the caller warns), else None.
    """
    if not isinstance(element, str):
        raise InputError(f"element must be 'auto', one of {list(ELEMENTS)} or {sorted(DEGREES)}, got {element!r}")
    name = element.lower()
    chosen = name if name in DEGREES or name == AUTO else check_element(name)
    surface = scene.mesh is not None and len(scene.faces) > 0
    model = scene.model
    partial = bool(np.any(np.asarray(model.fraction) < 1.0 - 1e-12))
    need = surface and ((chosen == AUTO and not lumped) or (chosen not in DEGREES and partial))
    wall = thinnest_walls(model, scene.mesh.vertices, scene.faces) if need else float("inf")
    longest = float(np.ptp(model.nodes, axis=0).max())
    thin = wall < THIN_WALLS * longest
    if chosen != AUTO:
        reason = "requested"
    elif not surface:
        chosen, reason = DEFAULT_ELEMENT, "auto: no surface mesh to make multiscale cubes from"
    elif lumped:
        chosen, reason = DEFAULT_ELEMENT, "auto: lumped mass (trilinear cubes)"
    else:
        ratio = (f"walls {wall * model.scale * 1e3:.3g} mm, 1/{longest / wall:.0f} of the model" if np.isfinite(wall)
                 else "no partly filled cube")
        if not thin:
            chosen, reason = DEFAULT_ELEMENT, f"auto: not thin-walled ({ratio})"
        elif wall >= AUTO_WALL_CUBES * model.pitch:
            chosen, reason = DEFAULT_ELEMENT, (f"auto: thin-walled ({ratio}) but the cubes resolve the walls "
                                               f"({wall / model.pitch:.2g} cubes thick): trilinear cubes")
        else:
            chosen, reason = "q3", f"auto: thin-walled ({ratio} < 1/{1 / THIN_WALLS:.0f}): multiscale cubes"
    note = None
    if chosen not in DEGREES and thin and wall < TRILINEAR_WALLS * model.pitch:
        mm = 1e3 * model.scale
        note = (f"the model's thin walls ({wall * mm:.3g} mm) are thinner than a third of a cube ({model.pitch * mm:.3g} "
                f"mm): trilinear cubes bend them roughly and can be far too stiff where walls meet inside a cube "
                f"(an I-section at 32 cubes: +53 % in its frequencies); element='q3' (--element q3) makes each cube "
                f"from a finer model of its walls (a few %, 10-50x slower)")
    return chosen, reason, note


TRILINEAR_WALLS = 1.0 / 3.0
"""A trilinear analysis warns when the model's thin walls are thinner than this fraction of a cube."""
