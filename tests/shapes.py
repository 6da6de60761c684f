"""Test meshes "that users bring": deterministic, small (< ~5,000 faces), built with trimesh and
manifold3d.

Conventions (unless a docstring says otherwise): SI metres, z up, resting on the floor plane
``z = 0``. Members "along x" (cantilevers, bridges) start at ``x = 0`` (the clamped root) and are
centred in y; furniture, vehicles and plates are centred in x and y. Every docstring gives the
bounding box.

Three kinds of mesh:

* watertight solids (``WATERTIGHT``): one closed 2-manifold, overlapping boxes united by
  manifold3d, as the conforming tetrahedral reference needs;
* soups (``SOUPS``): parts that pass through each other, never united, like real game assets;
  each part keeps its own vertices, so ``parts(mesh)`` returns them (note: trimesh's plain
  ``mesh.split(only_watertight=False)`` would also *fill* the open boxes' holes);
* open surfaces (``toy_truck``, ``open_sheet``): faces with no volume behind them.

``mesh.metadata`` holds ``"units"`` ("m" or "mm") and ``"parts"`` (number of separate bodies
as built). ``REGISTRY`` maps each shape's name to a zero-argument builder of its default.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import manifold3d
import numpy as np
import trimesh

# --------------------------------------------------------------------------------- helpers ---

_UNIT = trimesh.creation.box(bounds=[[0, 0, 0], [1, 1, 1]])
_CORNERS, _BOX_FACES = np.asarray(_UNIT.vertices, float), np.asarray(_UNIT.faces)  # unit cube, outward faces


def _mesh(vertices, faces, *, units: str = "m", parts: int = 1) -> trimesh.Trimesh:
    """A Trimesh kept exactly as given (no vertex merging, so soup parts stay separate)."""
    m = trimesh.Trimesh(np.asarray(vertices, float), np.asarray(faces, np.int64), process=False)
    m.metadata.update(units=units, parts=parts)
    return m


def _soup(meshes: Sequence[trimesh.Trimesh], **kw) -> trimesh.Trimesh:
    """Concatenate without merging anything: each input stays its own body."""
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes])[:-1]
    return _mesh(np.vstack([m.vertices for m in meshes]),
                 np.vstack([m.faces + o for m, o in zip(meshes, offsets)]), parts=len(meshes), **kw)


def _boxes(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (8n, 3) and faces (12n, 3) of n axis-aligned boxes with corners ``lo``, ``hi`` (n, 3)."""
    lo, hi = np.atleast_2d(lo).astype(float), np.atleast_2d(hi).astype(float)
    v = lo[:, None] + _CORNERS[None] * (hi - lo)[:, None]
    f = _BOX_FACES[None] + 8 * np.arange(len(lo))[:, None, None]
    return v.reshape(-1, 3), f.reshape(-1, 3)


def _bars(p0, p1, a) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of n square bars of side ``a`` from points ``p0`` to ``p1`` (n, 3), the
    square's sides along y (or x for bars along y) and its other axis; vectorized."""
    p0, p1 = np.atleast_2d(p0).astype(float), np.atleast_2d(p1).astype(float)
    d = p1 - p0
    length = np.linalg.norm(d, axis=1)
    e1 = d / length[:, None]
    ref = np.where(np.abs(e1[:, [1]]) > 0.9, [[1.0, 0, 0]], [[0.0, 1, 0]])
    e2 = np.cross(ref, e1)
    e2 /= np.linalg.norm(e2, axis=1, keepdims=True)
    e3 = np.cross(e1, e2)
    local = (_CORNERS - [0, 0.5, 0.5])[None] * np.c_[length, np.full((len(d), 2), a)][:, None]  # (n, 8, 3)
    v = p0[:, None] + np.einsum("nkj,nji->nki", local, np.stack([e1, e2, e3], axis=1))
    f = _BOX_FACES[None] + 8 * np.arange(len(d))[:, None, None]
    return v.reshape(-1, 3), f.reshape(-1, 3)


def _union(lo, hi) -> trimesh.Trimesh:
    """Watertight union (manifold3d) of axis-aligned boxes with corners ``lo``, ``hi`` (n, 3)."""
    lo, hi = np.atleast_2d(lo).astype(float), np.atleast_2d(hi).astype(float)
    solids = [manifold3d.Manifold.cube(h - l).translate(l) for l, h in zip(lo, hi)]
    out = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add).to_mesh64()
    mesh = trimesh.Trimesh(np.asarray(out.vert_properties)[:, :3], np.asarray(out.tri_verts), process=True)
    mesh.metadata.update(units="m", parts=1)
    return mesh


def _i_section(length, depth, width, web, flange, axis: int = 0, depth_axis: int = 2):
    """Box corners (3, 3), (3, 3) of an I-section member from 0 to ``length`` along ``axis``,
    its web depth along ``depth_axis``, flange width along the remaining axis, centred there.
    The web reaches half a flange into each flange, so the union has no coincident faces there."""
    w_axis = 3 - axis - depth_axis
    lo, hi = np.zeros((3, 3)), np.zeros((3, 3))
    lo[:, axis], hi[:, axis] = 0.0, length
    lo[:, depth_axis] = [0.0, depth - flange, flange / 2]
    hi[:, depth_axis] = [flange, depth, depth - flange / 2]
    lo[:, w_axis] = [-width / 2, -width / 2, -web / 2]
    hi[:, w_axis] = [width / 2, width / 2, web / 2]
    return lo, hi


# -------------------------------------------------------------------------- watertight solids ---

def i_beam(length: float = 1.0, height: float = 0.1, width: float = 0.06, web: float = 0.005,
           flange: float = 0.008) -> trimesh.Trimesh:
    """I-section cantilever along x, watertight (manifold3d union of web and two flanges).

    Parameters
    ----------
    length, height, width : float
        Overall dimensions (m); bounding box ``[0, length] x [-width/2, width/2] x [0, height]``.
    web, flange : float
        Web and flange thicknesses (m).
    """
    return _union(*_i_section(length, height, width, web, flange))


def channel(length: float = 1.0, height: float = 0.1, width: float = 0.05, web: float = 0.005,
            flange: float = 0.008) -> trimesh.Trimesh:
    """C (channel) section cantilever along x, watertight; web at ``y = -width/2``, flanges
    opening towards +y.

    Parameters
    ----------
    length, height, width : float
        Overall dimensions (m); bounding box ``[0, length] x [-width/2, width/2] x [0, height]``.
    web, flange : float
        Web and flange thicknesses (m).
    """
    y0, y1 = -width / 2, width / 2
    lo = [[0, y0, 0], [0, y0, height - flange], [0, y0, flange / 2]]
    hi = [[length, y1, flange], [length, y1, height], [length, y0 + web, height - flange / 2]]
    return _union(lo, hi)


def portal_frame(width: float = 1.0, height: float = 1.0, depth: float = 0.1, flange_width: float = 0.06,
                 web: float = 0.004, flange: float = 0.006) -> trimesh.Trimesh:
    """Portal frame in the x-z plane: two I-section columns and an I-section beam, one
    watertight solid (manifold3d union); steel-like thin walls.

    Parameters
    ----------
    width, height : float
        Overall span and height (m); bounding box
        ``[-width/2, width/2] x [-flange_width/2, flange_width/2] x [0, height]``.
    depth, flange_width : float
        Section depth (in the frame's plane) and flange width (out of plane), m.
    web, flange : float
        Web and flange thicknesses (m).
    """
    col_lo, col_hi = _i_section(height - flange / 2, depth, flange_width, web, flange, axis=2, depth_axis=0)
    beam_lo, beam_hi = _i_section(width, depth, flange_width, web, flange, axis=0, depth_axis=2)
    shift_l, shift_r = np.array([-width / 2, 0, 0]), np.array([width / 2 - depth, 0, 0])
    beam_shift = np.array([-width / 2, 0, height - depth])
    lo = np.vstack([col_lo + shift_l, col_lo + shift_r, beam_lo + beam_shift])
    hi = np.vstack([col_hi + shift_l, col_hi + shift_r, beam_hi + beam_shift])
    return _union(lo, hi)


def plate(lx: float = 1.0, ly: float = 0.5, t: float = 0.01) -> trimesh.Trimesh:
    """Thin plate, a watertight box ``[-lx/2, lx/2] x [-ly/2, ly/2] x [0, t]`` (m)."""
    return _mesh(*_boxes([-lx / 2, -ly / 2, 0], [lx / 2, ly / 2, t]))


def table(length: float = 1.0, width: float = 0.6, height: float = 0.75, top: float = 0.02,
          leg: float = 0.04, inset: float = 0.05) -> trimesh.Trimesh:
    """Table: a thin top on four square legs, watertight (manifold3d union; the legs reach half
    way into the top).

    Parameters
    ----------
    length, width, height : float
        Overall dimensions (m); bounding box
        ``[-length/2, length/2] x [-width/2, width/2] x [0, height]``.
    top, leg, inset : float
        Top thickness, leg side, and leg inset from the top's edges (m).
    """
    sx, sy = np.meshgrid([-1, 1], [-1, 1])
    cx = (sx.ravel() * (length / 2 - inset - leg / 2))[:, None]
    cy = (sy.ravel() * (width / 2 - inset - leg / 2))[:, None]
    lo = np.hstack([cx - leg / 2, cy - leg / 2, np.zeros((4, 1))])
    hi = np.hstack([cx + leg / 2, cy + leg / 2, np.full((4, 1), height - top / 2)])
    lo = np.vstack([lo, [-length / 2, -width / 2, height - top]])
    hi = np.vstack([hi, [length / 2, width / 2, height]])
    return _union(lo, hi)


# ------------------------------------------------------------------------- separate bodies ---

def two_plates(gap: float = 0.005, lx: float = 0.5, ly: float = 0.5, t: float = 0.005) -> trimesh.Trimesh:
    """Two parallel thin plates stacked in z, ``gap`` apart (separate bodies, not touching).

    Bounding box ``[-lx/2, lx/2] x [-ly/2, ly/2] x [0, 2 t + gap]`` (m); the plates are
    ``z in [0, t]`` and ``[t + gap, 2 t + gap]``.
    """
    v, f = _boxes([[-lx / 2, -ly / 2, 0], [-lx / 2, -ly / 2, t + gap]],
                  [[lx / 2, ly / 2, t], [lx / 2, ly / 2, 2 * t + gap]])
    return _mesh(v, f, parts=2)


def near_touching_boxes(gap: float = 0.001, size: float = 0.1) -> trimesh.Trimesh:
    """Two cubes of side ``size`` side by side along x, ``gap`` apart (0: touching faces,
    negative: overlapping by ``-gap``); separate bodies.

    Bounding box ``[-size - gap/2, size + gap/2] x [-size/2, size/2] x [0, size]`` (m).
    """
    g, s = gap / 2, size
    v, f = _boxes([[-s - g, -s / 2, 0], [g, -s / 2, 0]], [[-g, s / 2, s], [s + g, s / 2, s]])
    return _mesh(v, f, parts=2)


# ------------------------------------------------------------------------------------ soups ---

def slatted_chair(width: float = 0.5, depth: float = 0.5, height: float = 0.9, seat: float = 0.45,
                  arm: float = 0.65, leg: float = 0.03, slat: float = 0.02) -> trimesh.Trimesh:
    """Chair of thin slats as a SOUP of 19 boxes that pass through each other (legs through the
    seat frame, slats and armrests), NOT united. Front towards -y.

    Parts: 4 legs (back ones run to the top as back posts, front ones up to the armrests),
    4 seat-frame rails, 5 seat slats, 4 back slats (the top one is the back's top rail), 2 armrests.

    Parameters
    ----------
    width, depth, height : float
        Overall dimensions (m); bounding box
        ``[-width/2, width/2] x [-depth/2, depth/2] x [0, height]``.
    seat, arm : float
        Heights of the seat top and of the armrests' top (m).
    leg, slat : float
        Leg side and slat thickness (m).
    """
    W, D, s, L = width / 2, depth / 2, slat, leg
    xl, yl = W - L, D - L                                   # leg inner corners
    z_rail = seat - s                                       # seat slats lie on the rails
    # legs (front left, front right, back left, back right): lower and upper corners
    leg_lo = [[-W, -D, 0], [xl, -D, 0], [-W, yl, 0], [xl, yl, 0]]
    leg_hi = [[-xl, -yl, arm - s / 2], [W, -yl, arm - s / 2], [-xl, D, height], [W, D, height]]
    # seat frame: rails 0.06 high, just inside the legs' outer faces, running through the legs
    rail_lo = [[-W + L / 4, -D + L / 4, z_rail - 0.06], [-W + L / 4, D - 3 * L / 4, z_rail - 0.06],
               [-W + L / 4, -D + L / 4, z_rail - 0.06], [W - 3 * L / 4, -D + L / 4, z_rail - 0.06]]
    rail_hi = [[W - L / 4, -D + 3 * L / 4, z_rail], [W - L / 4, D - L / 4, z_rail],
               [-W + 3 * L / 4, D - L / 4, z_rail], [W - L / 4, D - L / 4, z_rail]]
    # seat slats along x, spaced in y, overhanging the rails; they cut through the legs too
    ys = np.linspace(-D + 0.01, D - 0.09, 5)
    seat_lo = np.c_[np.full(5, -W + 0.005), ys, np.full(5, z_rail - 0.005)]
    seat_hi = np.c_[np.full(5, W - 0.005), ys + 0.08, np.full(5, seat)]
    # back slats along x through the back posts (a top rail at the very top)
    zs = np.linspace(seat + 0.08, height - 0.06, 4)
    back_lo = np.c_[np.full(4, -W + L / 3), np.full(4, D - L / 2 - s / 2), zs]
    back_hi = np.c_[np.full(4, W - L / 3), np.full(4, D - L / 2 + s / 2), zs + np.r_[0.05, 0.05, 0.05, 0.06]]
    # armrests along y from the front legs into the back posts
    arm_lo = [[-W, -D + 0.004, arm - s], [W - L - 0.01, -D + 0.004, arm - s]]
    arm_hi = [[-W + L + 0.01, D - L / 3, arm], [W, D - L / 3, arm]]
    lo = np.vstack([leg_lo, rail_lo, seat_lo, back_lo, arm_lo])
    hi = np.vstack([leg_hi, rail_hi, seat_hi, back_hi, arm_hi])
    v, f = _boxes(lo, hi)
    return _mesh(v, f, parts=len(lo))


def truss_bridge_mm(length: float = 2000.0, height: float = 300.0, width: float = 400.0,
                    member: float = 20.0, panels: int = 6, deck: float = 6.0) -> trimesh.Trimesh:
    """Pratt truss bridge in MILLIMETRES, a soup of overlapping square bars plus a deck plate.

    Two plane trusses (top and bottom chords, ``panels + 1`` verticals, ``panels`` diagonals each)
    at ``y = +-(width - member)/2``, ``panels + 1`` floor beams across at the bottom nodes, and a
    deck plate cutting through the bottom chords: ``5 panels + 7`` members (37 by default) and the
    deck. Bars run node centre to node centre, chords and verticals extended by half a member
    so they overlap at the joints.

    Parameters
    ----------
    length, height, width : float
        Overall dimensions (mm); bounding box
        ``[0, length] x [-width/2, width/2] x [0, height]``.
    member : float
        Side of the square members (mm).
    panels : int
        Number of panels (even).
    deck : float
        Deck plate thickness (mm).
    """
    a, h = member, member / 2
    x = np.linspace(h, length - h, panels + 1)
    zb, zt = h, height - h
    n = panels + 1
    half = x[:-1] < length / 2                                      # diagonals fall towards mid-span
    d0 = np.c_[x[:-1], np.where(half, zb, zt)]                      # (x, z) per panel
    d1 = np.c_[x[1:], np.where(half, zt, zb)]
    p0 = [[0, zb], [0, zt], *np.c_[x, np.full(n, zb - h)], *d0]
    p1 = [[length, zb], [length, zt], *np.c_[x, np.full(n, zt + h)], *d1]
    p0, p1 = np.array(p0, float), np.array(p1, float)
    ys = np.repeat([-(width - a) / 2, (width - a) / 2], len(p0))
    q0 = np.c_[np.tile(p0[:, 0], 2), ys, np.tile(p0[:, 1], 2)]
    q1 = np.c_[np.tile(p1[:, 0], 2), ys, np.tile(p1[:, 1], 2)]
    floor0 = np.c_[x, np.full(n, -width / 2), np.full(n, zb)]       # floor beams along y
    floor1 = np.c_[x, np.full(n, width / 2), np.full(n, zb)]
    v, f = _bars(np.vstack([q0, floor0]), np.vstack([q1, floor1]), a)
    dv, df = _boxes([0, -width / 2 + h, a - deck / 2], [length, width / 2 - h, a + deck / 2])
    return _mesh(np.vstack([v, dv]), np.vstack([f, df + len(v)]), units="mm", parts=len(f) // 12 + 1)


def toy_truck(length: float = 0.4) -> trimesh.Trimesh:
    """Toy truck of open and intersecting parts (non-watertight), front towards +x; all
    dimensions scale with ``length``.

    Parts: a closed chassis box; a cab that is an open box (its bottom faces removed) sitting
    into the chassis; a cargo bed that is an open-topped box; a cargo cover that is an open
    arched sheet (single-sided, no thickness); two axle cylinders; four wheel cylinders the
    axles pass into.

    Bounding box (``length = 0.4``): ``[-0.2, 0.2] x [-0.0925, 0.0925] x [0, 0.17]`` (m), i.e.
    ``length * ([-0.5, 0.5] x [-0.23125, 0.23125] x [0, 0.425])``.
    """
    k = length / 0.4
    chassis = _mesh(*_boxes([-0.2, -0.07, 0.05], [0.2, 0.07, 0.07]))
    cab = trimesh.creation.box(bounds=[[0.08, -0.075, 0.06], [0.2, 0.075, 0.17]])
    cab = _mesh(cab.vertices, cab.faces[cab.face_normals[:, 2] > -0.5])          # no bottom
    bed = trimesh.creation.box(bounds=[[-0.18, -0.07, 0.065], [0.07, 0.07, 0.13]])
    bed = _mesh(bed.vertices, bed.faces[bed.face_normals[:, 2] < 0.5])           # no top
    cover = open_sheet(lx=0.26, ly=0.15, sag=0.02, n=(12, 6))
    cover.apply_translation([-0.055, 0, 0.131])
    rot_y = trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0])        # cylinder axis z -> y
    axles = [trimesh.creation.cylinder(0.008, 0.18, sections=12, transform=trimesh.transformations
                                       .translation_matrix([x, 0, 0.04]) @ rot_y) for x in (-0.12, 0.13)]
    wheels = [trimesh.creation.cylinder(0.04, 0.025, sections=24, transform=trimesh.transformations
                                        .translation_matrix([x, y, 0.04]) @ rot_y)
              for x in (-0.12, 0.13) for y in (-0.08, 0.08)]
    truck = _soup([chassis, cab, bed, cover, *axles, *wheels])
    truck.apply_scale(k)
    return truck


def open_sheet(lx: float = 0.5, ly: float = 0.3, sag: float = 0.02,
               n: tuple[int, int] = (20, 12)) -> trimesh.Trimesh:
    """Single open triangulated rectangle (no thickness), arched along x:
    ``z = sag (1 - (2x/lx)^2)``; ``n = (nx, ny)`` cells, ``2 nx ny`` triangles, normals +z.

    Bounding box ``[-lx/2, lx/2] x [-ly/2, ly/2] x [0, sag]`` (m).
    """
    nx, ny = n
    gx, gy = np.meshgrid(np.linspace(-lx / 2, lx / 2, nx + 1), np.linspace(-ly / 2, ly / 2, ny + 1), indexing="ij")
    v = np.c_[gx.ravel(), gy.ravel(), sag * (1 - (2 * gx.ravel() / lx) ** 2)]
    c = (np.arange(nx)[:, None] * (ny + 1) + np.arange(ny)[None]).ravel()         # cell corner ids
    f = np.r_[np.c_[c, c + ny + 1, c + ny + 2], np.c_[c, c + ny + 2, c + 1]]
    return _mesh(v, f)


# ------------------------------------------------------------------------------ transforms ---

def parts(mesh: trimesh.Trimesh) -> list[trimesh.Trimesh]:
    """The separate bodies of ``mesh`` (face-connected components), returned as they are: open
    parts stay open (``repair=False``; trimesh's default would close small holes)."""
    return mesh.split(only_watertight=False, repair=False)


#: Proper rotation (det +1) by -90 degrees about x taking a z-up model to y-up:
#: ``(x, y, z) -> (x, z, -y)``, so the old +z becomes +y and the old +y becomes -z.
Y_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])


def y_up(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Copy of a z-up ``mesh`` rotated to y-up: ``(x, y, z) -> (x, z, -y)`` (``Y_UP``, -90 degrees
    about x; a proper rotation, so normals and volume keep their sign)."""
    out = mesh.copy()
    out.apply_transform(Y_UP)
    return out


def to_millimetres(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """Copy of a mesh in metres scaled by 1000 to millimetres."""
    out = mesh.copy()
    out.apply_scale(1000.0)
    out.metadata["units"] = "mm"
    return out


def off_origin(mesh: trimesh.Trimesh, offset: Sequence[float] = (1000.0, -500.0, 250.0)) -> trimesh.Trimesh:
    """Copy of ``mesh`` translated by ``offset`` (in the mesh's own units)."""
    out = mesh.copy()
    out.apply_translation(np.asarray(offset, float))
    return out


def stacked_on(a: trimesh.Trimesh, b: trimesh.Trimesh, gap: float = 0.0, axis: int = 2) -> trimesh.Trimesh:
    """``a`` placed above ``b`` (along ``axis``, default z) with ``gap`` between their bounding
    boxes, ``a`` centred over ``b`` across; ``b`` stays put. One mesh of the two bodies (not
    merged); ``metadata["parts"]`` adds up."""
    shift = b.bounds.mean(axis=0) - a.bounds.mean(axis=0)
    shift[axis] = b.bounds[1, axis] + gap - a.bounds[0, axis]
    out = _soup([off_origin(a, shift), b], units=b.metadata.get("units", "m"))
    out.metadata["parts"] = a.metadata.get("parts", 1) + b.metadata.get("parts", 1)
    return out


# -------------------------------------------------------------------------------- registry ---

REGISTRY: dict[str, Callable[[], trimesh.Trimesh]] = {
    "i_beam": i_beam,
    "channel": channel,
    "portal_frame": portal_frame,
    "plate": plate,
    "two_plates": two_plates,
    "table": table,
    "slatted_chair": slatted_chair,
    "truss_bridge_mm": truss_bridge_mm,
    "toy_truck": toy_truck,
    "open_sheet": open_sheet,
    "near_touching_boxes": near_touching_boxes,
}

#: Shapes that are closed 2-manifolds enclosing volume (one body unless noted by metadata).
WATERTIGHT = ("i_beam", "channel", "portal_frame", "plate", "two_plates", "table", "near_touching_boxes")
#: Self-intersecting soups (parts pass through each other).
SOUPS = ("slatted_chair", "truss_bridge_mm", "toy_truck")
#: Shapes with open (boundary) edges.
OPEN = ("toy_truck", "open_sheet")


def box_obj_with_normals(folder) -> tuple:
    """An OBJ box (0.2 x 0.3 x 0.5) whose ``vn`` lines are corner normals, deliberately not the
    faces' normals: the file's path and those normals (8, 3)."""
    from pathlib import Path

    box = trimesh.creation.box(extents=(0.2, 0.3, 0.5))
    v, f = np.asarray(box.vertices), np.asarray(box.faces)
    vn = v / np.linalg.norm(v, axis=1, keepdims=True)
    lines = [f"v {a} {b} {c}" for a, b, c in v] + [f"vn {a} {b} {c}" for a, b, c in vn]
    lines += [f"f {a + 1}//{a + 1} {b + 1}//{b + 1} {c + 1}//{c + 1}" for a, b, c in f]
    obj = Path(folder) / "box.obj"
    obj.write_text("\n".join(lines) + "\n")
    return obj, vn
