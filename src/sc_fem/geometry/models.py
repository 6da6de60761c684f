"""Built-in models, generated procedurally with trimesh primitives (no files needed).

=========  =================================================================  ===========================
name       what                                                               default material
=========  =================================================================  ===========================
chair      plastic chair, 0.47 x 0.49 x 0.86 m: seat, tilted back, 4 legs     polypropylene: E 1.5 GPa,
           and a rail; parts overlap and intersect like an artist's model     nu 0.42, rho 905 kg/m^3
bridge     cable-stayed bridge superstructure, 24 x 4.2 x 9 m: deck,          structural steel: E 200 GPa,
           2 towers, cross beams through the towers, 16 thin cables that      nu 0.30, rho 7850 kg/m^3
           stop 5 cm short of the deck, isolated polygons and skinny
           triangles
rope       cube-rope: 20 overlapping cubes along x, 1.0 x 0.0525 x 0.0525 m   soft rubber: E 1 MPa,
           (19:1), each cube subdivided for a dense surface                   nu 0.45, rho 1100 kg/m^3
beam       clean box cantilever 1.0 x 0.1 x 0.1 m along x (verification)      steel: E 200 GPa, nu 0.30,
                                                                              rho 7850 kg/m^3
=========  =================================================================  ===========================

All models are in metres (``scale=1``) with z up; their lowest z is 0 (beam: x from 0).
:func:`fix_specs` gives the natural supports (chair feet, bridge tower bases and abutments, rope
end, beam root) in the ``--fix`` syntax of the command line.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..errors import BoundaryConditionError, InputError
from ..material import Material


@dataclass(frozen=True)
class BuiltinModel:
    """A built-in model: geometry factory, default material and natural supports."""

    name: str
    description: str
    material: Material
    fix: tuple[str, ...]
    build: Callable[[], "object"]


def _box(extents, center, transform=None):
    import trimesh

    m = trimesh.creation.box(extents=extents)
    if transform is not None:
        m.apply_transform(transform)
    m.apply_translation(center)
    return m


def _cyl(radius, p0, p1, sections=12):
    import trimesh

    return trimesh.creation.cylinder(radius=radius, segment=np.array([p0, p1], dtype=float), sections=sections)


def _concat(parts):
    import trimesh

    out = trimesh.util.concatenate(parts)
    return trimesh.Trimesh(vertices=out.vertices, faces=out.faces, process=False)


def _chair():
    import trimesh

    seat_h, w, d = 0.45, 0.46, 0.44
    parts = [_box([w, d, 0.03], [0, 0, seat_h])]                      # seat
    tilt = trimesh.transformations.rotation_matrix(np.radians(-10), [1, 0, 0])
    parts.append(_box([w, 0.025, 0.42], [0, d / 2 - 0.005, seat_h + 0.2], tilt))   # back, through the seat
    for sx in (-1, 1):
        for sy in (-1, 1):
            top = [sx * (w / 2 - 0.03), sy * (d / 2 - 0.03), seat_h + 0.01]   # leg pokes into the seat
            foot = [sx * (w / 2 - 0.01), sy * (d / 2 - 0.01), 0.0]
            parts.append(_cyl(0.014, foot, top))
    # rear posts run from the back legs up into the backrest (overlapping both)
    for sx in (-1, 1):
        parts.append(_cyl(0.012, [sx * (w / 2 - 0.04), d / 2 - 0.02, seat_h - 0.02],
                          [sx * (w / 2 - 0.04), d / 2 + 0.025, seat_h + 0.38]))
    parts.append(_cyl(0.01, [-w / 2 + 0.005, -d / 2 + 0.018, 0.15], [w / 2 - 0.005, -d / 2 + 0.018, 0.15]))  # rail through the front legs
    m = _concat(parts)
    m.apply_translation([0, 0, -m.bounds[0, 2]])
    return m


def _bridge():
    L, W = 24.0, 3.0
    deck_z = 3.0
    parts = [_box([L, W, 0.4], [0, 0, deck_z])]                             # deck
    for x in (-6.0, 6.0):
        for y in (-W / 2 - 0.25, W / 2 + 0.25):
            parts.append(_box([0.5, 0.5, 9.0], [x, y, 4.5]))                 # towers from the ground
        parts.append(_box([0.4, W + 1.2, 0.4], [x, 0, 8.2]))                # top cross beam (intersects)
        parts.append(_box([0.4, W + 1.2, 0.3], [x, 0, deck_z - 0.1]))       # deck cross beam (intersects deck)
    for x in (-L / 2 + 0.5, L / 2 - 0.5):                                    # abutments
        parts.append(_box([1.0, W, deck_z - 0.2], [x, 0, (deck_z - 0.2) / 2]))
    # cables: from tower tops down to the deck edge, stopping 5 cm short of the deck (small gaps)
    for tx in (-6.0, 6.0):
        for y in (-W / 2 - 0.25, W / 2 + 0.25):
            top = np.array([tx, y, 8.6])
            for dx in (-4.5, -2.5, 2.5, 4.5):
                anchor = np.array([tx + dx, np.sign(y) * (W / 2 - 0.1), deck_z + 0.2])
                direction = (anchor - top) / np.linalg.norm(anchor - top)
                parts.append(_cyl(0.04, top, anchor - 0.05 * direction, sections=8))
    m = _concat(parts)
    # modelling shortcuts: isolated polygons floating near the deck and skinny triangles along it
    v0 = len(m.vertices)
    extra_v = np.array([
        [2.0, 0.0, deck_z + 0.6], [2.3, 0.0, deck_z + 0.6], [2.0, 0.3, deck_z + 0.6],        # isolated tri
        [-3.0, 1.0, deck_z + 0.55], [-2.6, 1.0, deck_z + 0.55], [-3.0, 1.3, deck_z + 0.55],  # isolated tri
        [-L / 2, W / 2 + 0.02, deck_z + 0.2], [L / 2, W / 2 + 0.02, deck_z + 0.2],
        [0.0, W / 2 + 0.02, deck_z + 0.23],                                                 # skinny (railing strip)
        [-L / 2, -W / 2 - 0.02, deck_z + 0.2], [L / 2, -W / 2 - 0.02, deck_z + 0.21],
        [0.0, -W / 2 - 0.02, deck_z + 0.24],                                                # skinny
    ])
    extra_f = np.arange(12).reshape(4, 3) + v0
    import trimesh

    m = trimesh.Trimesh(vertices=np.vstack([m.vertices, extra_v]), faces=np.vstack([m.faces, extra_f]),
                        process=False)
    m.apply_translation([0, 0, -m.bounds[0, 2]])
    return m


def _rope():
    import trimesh

    a, n = 0.0525, 20
    step = (1.0 - a) / (n - 1)          # cubes overlap by 2.5 mm; total length exactly 1.0 m
    parts = []
    for i in range(n):                   # 20 primitives: a loop over parts, not over vertices
        c = trimesh.creation.box(extents=[a, a, a])
        c = c.subdivide().subdivide().subdivide()
        c.apply_translation([a / 2 + i * step, 0.0, 0.0])
        parts.append(c)
    m = _concat(parts)
    m.apply_translation([0, 0, -m.bounds[0, 2]])
    return m


def _beam():
    import trimesh

    m = trimesh.creation.box(extents=[1.0, 0.1, 0.1])
    m.apply_translation([0.5, 0.0, 0.05])
    return trimesh.Trimesh(vertices=m.vertices, faces=m.faces, process=False)


_MODELS: dict[str, BuiltinModel] = {
    "chair": BuiltinModel("chair", "plastic chair with overlapping, intersecting parts (0.47 x 0.49 x 0.86 m)",
                          Material(1.5e9, 0.42, 905.0, "polypropylene"), ("z<min+0.01",), _chair),
    "bridge": BuiltinModel("bridge", "cable-stayed bridge superstructure with gaps, intersections, "
                           "isolated polygons and skinny triangles (24 x 4.2 x 9 m)",
                           Material(200e9, 0.30, 7850.0, "structural steel"), ("z<min+0.05",), _bridge),
    "rope": BuiltinModel("rope", "cube-rope: 20 overlapping cubes along x (1.0 x 0.0525 x 0.0525 m)",
                         Material(1.0e6, 0.45, 1100.0, "soft rubber"), ("x<min+0.02",), _rope),
    "beam": BuiltinModel("beam", "clean box cantilever 1.0 x 0.1 x 0.1 m along x",
                         Material(200e9, 0.30, 7850.0, "steel"), ("x<min+1e-6",), _beam),
}


def names() -> list[str]:
    """Names of the built-in models."""
    return sorted(_MODELS)


def get(name: str) -> BuiltinModel:
    """The :class:`BuiltinModel` record of ``name``."""
    key = str(name).strip().lower()
    if key.startswith("builtin:"):
        key = key[len("builtin:"):]
    if key not in _MODELS:
        raise InputError(f"unknown built-in model {name!r}; choose one of {', '.join(names())}")
    return _MODELS[key]


def load(name: str):
    """Generate the built-in model ``name`` as a ``trimesh.Trimesh`` (metres, z up)."""
    rec = get(name)
    mesh = rec.build()
    mesh.metadata["source"] = f"builtin:{rec.name}"
    return mesh


def material(name: str) -> Material:
    """Default material of the built-in model ``name``."""
    return get(name).material


def fix_specs(name: str) -> tuple[str, ...]:
    """Natural supports of ``name`` in ``--fix`` syntax (model units = metres)."""
    return get(name).fix


def expand_fix(specs, source: str) -> list:
    """Replace every ``"default"`` in a list of fix specs by the natural supports of the built-in
    model ``source`` (``"builtin:NAME"``); other entries pass through unchanged.

    Raises
    ------
    BoundaryConditionError
        ``"default"`` used for a model that is not built in.
    """
    out: list = []
    for s in specs:
        if isinstance(s, str) and s.strip().lower() == "default":
            if not str(source).startswith("builtin:"):
                raise BoundaryConditionError("--fix default is only defined for builtin:NAME models")
            out += list(fix_specs(source))
        else:
            out.append(s)
    return out
