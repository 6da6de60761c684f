"""Contact of the source-mesh vertices with static obstacles, resolved on the cube nodes.

As in the seed, contact is *detected on the original geometry*: the current position of every
source-mesh vertex is ``p = rest + (W u) / scale`` (model units; ``W`` the trilinear embedding,
``u`` node displacements in metres), and its signed penetration depth ``d`` (> 0 inside) and
outward obstacle normal ``n`` are evaluated against

* :class:`Ground` -- the half-space below the plane ``z = Z``;
* :class:`Sphere` -- a ball of centre ``c`` and radius ``r``;
* :class:`Box` -- an axis-aligned box ``[lo, hi]`` (pushed out through its nearest face).

Resolution (:meth:`Contact.project`, after every time step) is a *projection* distributed
barycentrically: a penetrating vertex ``p`` asks the free nodes ``k`` of its cube (the non-zeros
of its row of ``W``, i.e. the ``W^T`` pattern) for the least-norm correction
``delta_k = W_pk d_p / sum_j W_pj^2`` along ``n_p``, which moves ``p`` by exactly ``d_p``; a node
asked by several vertices takes the largest request. As the weights are non-negative, every
vertex then moves by at least its own depth along a common normal (ground, one box face): one
pass is enough. Curved obstacles (sphere) and box edges take a few passes (``max_passes``). (A
plain ``W^T`` sum would over-push a cube that carries many vertices, a weighted average would
under-push the deepest one.) The approach velocity ``n . (W v) < 0`` of every vertex in contact is
then removed with the same spreading (inelastic, frictionless contact; ``restitution`` > 0
reflects it instead).

Energy: the projection and the velocity step never push a vertex toward the obstacle, and with
a time step below about the explicit limit of the contacting cubes an impact only dissipates
energy. With implicit steps above that limit the instantaneous position change can feed energy
into the stiff modes of the contacting cubes. Measured on the soft block of ``tests/test_contact.py``
(0.4 x 0.2 x 0.1 m, E = 1 MPa, 8 cubes along x) dropped 5 cm onto the ground with Newmark for 0.2 s:
at ``dt = 2.2 dt_crit`` the total energy rises up to 0.62 m g h above its start undamped and up to
1.68 m g h with stiffness-proportional damping ``rayleigh = (0, 1e-3)`` (damping made it worse,
not better); at ``dt = 0.5 dt_crit`` it never rises above its start, with or without that damping.
Keep ``dt`` below about ``dt_crit`` during impacts.

Depth tolerance: after :meth:`Contact.project` no vertex is deeper than ``tol`` (model units,
default ``1e-6 * pitch``) unless it is embedded in a cube whose nodes are all fixed (those cannot
move; they are reported in :attr:`ContactInfo.max_depth`). The fixed nodes are those of the time
integrator: it binds the contact to them (:meth:`Contact.with_fixed_nodes`); a :class:`Contact`
used on its own moves every node.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .._validate import as_float_array, as_points, positive_scalar
from ..errors import InputError
from ..lattice.cubes import CubeModel
from ..lattice.embed import embed

TOL_FRACTION = 1e-6
"""Default depth tolerance as a fraction of the cube pitch."""


@dataclass(frozen=True)
class Ground:
    """The ground: everything below the plane ``p[axis] = z`` (model units) is solid; normal
    ``+axis`` (``axis`` 2 for a z-up model, 1 for y-up)."""

    z: float = 0.0
    axis: int = 2

    def __post_init__(self) -> None:
        if self.axis not in (0, 1, 2) or isinstance(self.axis, bool):
            raise InputError(f"Ground axis must be 0, 1 or 2 (x, y, z), got {self.axis!r}")

    def depth(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Signed depth (n,) model units (> 0 below the plane) and normal (n, 3)."""
        n = np.zeros_like(p)
        n[:, self.axis] = 1.0
        return self.z - p[:, self.axis], n


@dataclass(frozen=True)
class Sphere:
    """A static ball: ``center`` (3,) and ``radius``, model units."""

    center: tuple
    radius: float

    def depth(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = p - np.asarray(self.center, dtype=float)
        r = np.linalg.norm(d, axis=1)
        n = np.where(r[:, None] > 0, d / np.maximum(r, 1e-300)[:, None], np.array([0.0, 0.0, 1.0]))
        return self.radius - r, n


@dataclass(frozen=True)
class Box:
    """A static axis-aligned box from ``lo`` (3,) to ``hi`` (3,), model units."""

    lo: tuple
    hi: tuple

    def depth(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = np.asarray(self.lo, dtype=float), np.asarray(self.hi, dtype=float)
        gaps = np.concatenate([p - lo, hi - p], axis=1)                 # (n, 6) distance to each face
        face = np.argmin(gaps, axis=1)
        depth = gaps[np.arange(len(p)), face]                           # > 0 inside
        inside = np.all(gaps > 0, axis=1)
        normals = np.concatenate([-np.eye(3), np.eye(3)])               # outward normals of the 6 faces
        return np.where(inside, depth, -np.min(np.abs(gaps), axis=1)), normals[face]


@dataclass(frozen=True)
class ContactInfo:
    """What one projection did.

    Attributes
    ----------
    n_active : int
        Vertices that were penetrating before the projection.
    max_depth : float
        Largest penetration depth (model units) of any vertex after it (<= 0: none), including
        vertices that cannot move (embedded only in cubes with all nodes fixed).
    passes : int
        Projection passes used.
    """

    n_active: int
    max_depth: float
    passes: int


class Contact:
    """Vertex-obstacle contact for a cube lattice.

    Parameters
    ----------
    model : CubeModel
    points : array_like, shape (n, 3)
        Rest positions of the source-mesh vertices, model units.
    obstacles : sequence of Ground / Sphere / Box
    tol : float, optional
        Depth tolerance, model units (default ``1e-6 * model.pitch``).
    restitution : float
        0 (default): inelastic; 1: the normal velocity is reflected.
    max_passes : int
        Projection passes at most (curved obstacles need a few).
    W : scipy.sparse matrix (n, m), optional
        Embedding of ``points`` (computed if omitted).
    """

    def __init__(self, model: CubeModel, points, obstacles: Sequence, *, tol: float | None = None,
                 restitution: float = 0.0, max_passes: int = 20, W=None) -> None:
        self.model = model
        self.rest = as_points(points, "points")
        if not obstacles:
            raise InputError("Contact needs at least one obstacle (Ground, Sphere or Box)")
        for ob in obstacles:
            if not hasattr(ob, "depth"):
                raise InputError(f"unknown obstacle {ob!r}: use Ground, Sphere or Box")
        self.obstacles = tuple(obstacles)
        self.tol = TOL_FRACTION * model.pitch if tol is None else positive_scalar(tol, "tol")
        self.restitution = float(restitution)
        if not 0.0 <= self.restitution <= 1.0:
            raise InputError(f"restitution must lie in [0, 1], got {restitution!r}")
        self.max_passes = int(max_passes)
        self.W = (embed(model, self.rest) if W is None else W).tocoo()
        if self.W.shape != (len(self.rest), model.n_nodes):
            raise InputError(f"W must have shape ({len(self.rest)}, {model.n_nodes}), got {self.W.shape}")
        keep = self.W.data > 0
        self._rows, self._cols, self._w = self.W.row[keep], self.W.col[keep], self.W.data[keep]
        self._Wcsr = self.W.tocsr()
        self._set_free(np.ones(model.n_nodes, dtype=bool))

    def check_initial(self, u: np.ndarray) -> None:
        """Raise :class:`InputError` if an obstacle already cuts the model in the initial state ``u``
        (m, 3) metres: a time integration would start by projecting the overlap away and blow up."""
        p = self.positions(u)
        for ob in self.obstacles:     # a few obstacles
            d, _ = ob.depth(p)
            inside = (d > self.tol) & self.movable
            if inside.any():
                raise InputError(
                    f"{ob} already cuts the model at t = 0: {int(inside.sum())} of {len(d)} vertices lie up to "
                    f"{float(d[inside].max()):.4g} model units inside it; move the obstacle or the model so "
                    f"that they only touch")

    def _set_free(self, free: np.ndarray) -> None:
        self.free = free
        # vertices that can move at all (some free node in their cube)
        movable = np.zeros(len(self.rest), dtype=bool)
        movable[self._rows[free[self._cols]]] = True
        self.movable = movable

    def with_fixed_nodes(self, fixed_nodes) -> "Contact":
        """A copy (sharing the embedding) whose projection never moves ``fixed_nodes`` (int array);
        the time integrators call it with their own fixed nodes."""
        free = np.ones(self.model.n_nodes, dtype=bool)
        free[np.asarray(fixed_nodes, dtype=np.int64)] = False
        out = copy.copy(self)
        out._set_free(free)
        return out

    def positions(self, u: np.ndarray) -> np.ndarray:
        """Current vertex positions (n, 3), model units, for node displacements ``u`` (m, 3) metres."""
        return self.rest + np.asarray(self._Wcsr @ u) / self.model.scale

    def depths(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Deepest penetration over the obstacles per vertex (n,) model units, and its normal (n, 3)."""
        p = self.positions(u)
        best = np.full(len(p), -np.inf)
        normal = np.zeros_like(p)
        for ob in self.obstacles:                              # loop over a few obstacles
            d, n = ob.depth(p)
            sel = d > best
            best = np.where(sel, d, best)
            normal[sel] = n[sel]
        return best, normal

    def _spread(self, value: np.ndarray, normal: np.ndarray, active: np.ndarray) -> np.ndarray:
        """Node vectors (m, 3) that move every active vertex by at least ``value`` along its normal.

        Each active vertex ``p`` asks its free cube nodes for the least-norm correction
        ``W_pk value_p / sum_free W_pj^2`` (a ``W^T`` distribution); each node takes the largest
        request it receives (along the normal of the vertex that made it). With non-negative
        weights and a common normal every vertex then moves by at least its own ``value``."""
        sel = active[self._rows] & self.free[self._cols]
        r, c, w = self._rows[sel], self._cols[sel], self._w[sel]
        norm2 = np.bincount(r, weights=w * w, minlength=len(value))
        req = w * value[r] / np.maximum(norm2[r], 1e-300)
        order = np.lexsort((-req, c))                              # by node, largest request first
        c_s, r_s, q_s = c[order], r[order], req[order]
        first = np.ones(len(c_s), dtype=bool)
        first[1:] = c_s[1:] != c_s[:-1]
        out = np.zeros((self.model.n_nodes, 3))
        out[c_s[first]] = q_s[first, None] * normal[r_s[first]]
        return out

    def project(self, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, ContactInfo]:
        """Push penetrating vertices out and stop their approach; returns new ``u``, ``v`` (m, 3)
        (metres, m/s) and a :class:`ContactInfo`."""
        u, v = np.array(u, dtype=float), np.array(v, dtype=float)
        d, n = self.depths(u)
        touched = (d > 0) & self.movable
        active0 = int(np.count_nonzero(touched))
        passes = 0
        s = self.model.scale
        while passes < self.max_passes:
            act = (d > (0.5 * self.tol if passes else 0.0)) & self.movable
            if not act.any():
                break
            passes += 1
            touched |= act
            # metres; a small overshoot (0.1 tol) so that round-off does not leave vertices just below
            u += self._spread((np.maximum(d, 0.0) + 0.1 * self.tol) * s, n, act)
            d, n = self.depths(u)
        if active0:
            # velocity: remove the approach speed of every vertex that was in contact, same spreading
            # (d, n are those of the current u: computed after the last position update)
            vn = np.einsum("ij,ij->i", np.asarray(self._Wcsr @ v), n)
            app = touched & (vn < 0)
            if app.any():
                v += self._spread(-(1.0 + self.restitution) * np.minimum(vn, 0.0), n, app)
        d_after = float(d.max()) if len(d) else -np.inf      # all vertices, the unmovable ones too
        return u, v, ContactInfo(n_active=active0, max_depth=d_after, passes=passes)


def obstacles_from(ground=None, sphere=None, box=None, *, up: int = 2) -> list:
    """Obstacles from plain numbers: ``ground`` height along the ``up`` axis (0, 1, 2), ``sphere``
    (x, y, z, r), ``box`` (x0, y0, z0, x1, y1, z1)."""
    obs = []
    if ground is not None:
        obs.append(Ground(float(ground), int(up)))
    if sphere is not None:
        s = as_float_array(sphere, "sphere", (4,))
        obs.append(Sphere(tuple(s[:3]), positive_scalar(s[3], "sphere radius")))
    if box is not None:
        b = as_float_array(box, "box", (6,))
        if np.any(b[3:] <= b[:3]):
            raise InputError(f"box must be x0 y0 z0 x1 y1 z1 with x1 > x0 etc., got {b.tolist()}")
        obs.append(Box(tuple(b[:3]), tuple(b[3:])))
    return obs
