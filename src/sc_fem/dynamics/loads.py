"""External loads of a dynamic run, given on the source geometry and carried to the cube nodes.

Every load ends up as lattice node forces ``(m, 3)`` in newtons:

* :class:`Gravity` -- each node gets its lumped mass times ``g`` (m/s^2), as in
  :func:`sc_fem.fem.static.solve_static`; it is the only load with a potential energy
  (``-f_g . u``, reported in the energy of a run).
* :class:`VertexForce` -- forces (N) on source-mesh vertices, shared by the lattice mass around
  each vertex (default) or mapped with ``W^T`` (:func:`sc_fem.lattice.embed.embed`), times a
  scalar time profile ``time(t)``.
* :class:`FacePressure` -- a pressure (Pa) on source-mesh faces, acting against the face normal
  of the rest geometry (``F = -p A n``, area in m^2 = model area x scale^2), split equally over
  the face's 3 vertices and mapped with ``W^T``, times ``time(t)``.

Impulses (:func:`impulse_nodes`) are spread over the *mass* around the vertex they hit, not
through ``W^T`` alone: a vertex inside a sliver cube would otherwise hand the whole impulse to
nodes of a few grams and tear the mesh.

Loads act on the rest geometry (small-displacement assumption). The time profiles
:func:`half_sine` (a gust) and :func:`step` are provided; any ``callable(t) -> float`` works.

:class:`LoadSet` pre-computes the constant node-force pattern of every load once, so
``LoadSet.force(t)`` costs one multiply-add per load and time step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from .._validate import as_float_array, as_indices, as_points
from ..errors import InputError
from ..lattice.cubes import CubeModel
from ..lattice.embed import embed
from ..units import GRAVITY

Profile = Callable[[float], float]

DOWN = (0.0, 0.0, -GRAVITY)
"""The default gravitational acceleration, m/s^2: 9.81 down the z axis (:class:`Gravity`,
:class:`~sc_fem.dynamics.xpbd.XPBDSolver`)."""

PATCH_RADIUS = 1.5
"""Radius (in cube edges) of the node patch that shares a vertex impulse (:func:`impulse_nodes`)."""


def _one(t: float) -> float:
    return 1.0


def half_sine(duration: float, start: float = 0.0) -> Profile:
    """Gust profile: ``sin(pi (t - start) / duration)`` on ``[start, start + duration]``, else 0."""
    if not duration > 0:
        raise InputError(f"duration must be > 0 s, got {duration!r}")

    def f(t: float) -> float:
        s = (t - start) / duration
        return float(np.sin(np.pi * s)) if 0.0 <= s <= 1.0 else 0.0

    return f


def step(start: float = 0.0) -> Profile:
    """Step profile: 0 before ``start`` s, 1 from then on."""
    return lambda t: 1.0 if t >= start else 0.0


@dataclass(frozen=True)
class Gravity:
    """Uniform gravitational acceleration ``g`` (m/s^2), shape (3,)."""

    g: tuple = DOWN


@dataclass(frozen=True, eq=False)
class VertexForce:
    """Forces on source-mesh vertices.

    Attributes
    ----------
    vertices : array_like of int, shape (k,)
        Vertex indices into the points given to :class:`LoadSet`.
    force : array_like, shape (k, 3) or (3,)
        Force per vertex, N (a (3,) force is applied to each vertex).
    time : callable, optional
        Scalar profile ``time(t)`` multiplying the force (default 1).
    spread : {"mass", "embedding"}
        ``"mass"`` (default): each vertex's force is shared by the lattice nodes within 1.5 cube
        edges of it in proportion to their mass (:func:`impulse_nodes`): the force acts on a patch
        of material, so a vertex inside a sliver cube does not tear away. ``"embedding"``: ``W^T f``
        (the virtual-work transpose of the trilinear map; for forces already spread over many
        vertices, such as a gust on all of them).
    """

    vertices: object
    force: object
    time: Profile | None = None
    spread: str = "mass"


@dataclass(frozen=True, eq=False)
class FacePressure:
    """Pressure on source-mesh faces (positive pushes against the outward normal).

    Attributes
    ----------
    faces : array_like of int, shape (k,)
        Face indices into the faces given to :class:`LoadSet`.
    pressure : float or array_like (k,)
        Pa.
    time : callable, optional
        Scalar profile (default 1).
    """

    faces: object
    pressure: object
    time: Profile | None = None


class LoadSet:
    """The loads of a run as node forces.

    Parameters
    ----------
    model : CubeModel
    loads : sequence of Gravity / VertexForce / FacePressure
    points : array_like, shape (n, 3), optional
        Source-mesh vertices, model units (needed by vertex forces and pressures).
    faces : array_like of int, shape (f, 3), optional
        Source-mesh triangles (needed by pressures).
    W : scipy.sparse matrix, shape (n, m), optional
        Embedding of ``points`` (computed with :func:`sc_fem.lattice.embed.embed` if not given).

    Attributes
    ----------
    gravity : ndarray, shape (3,)
        The gravitational acceleration of the :class:`Gravity` loads (their sum), m/s^2.
    gravity_force : ndarray, shape (m, 3)
        Constant node forces of gravity, N.
    n_forces : int
        The loads other than gravity (forces and pressures).
    """

    def __init__(self, model: CubeModel, loads: Sequence = (), *, points=None, faces=None, W=None) -> None:
        m = model.n_nodes
        self.model = model
        self.gravity = np.zeros(3)
        self.gravity_force = np.zeros((m, 3))
        self._timed: list[tuple[np.ndarray, Profile]] = []
        pts = None if points is None else as_points(points, "points")
        if W is None and pts is not None:
            W = embed(model, pts)
        self.W = None if W is None else sp.csr_matrix(W)
        if self.W is not None and pts is not None and self.W.shape != (len(pts), m):
            raise InputError(f"W must have shape ({len(pts)}, {m}), got {self.W.shape}")
        for ld in loads:                                    # loop over a handful of loads
            if isinstance(ld, Gravity):
                g = as_float_array(ld.g, "gravity", (3,))
                self.gravity = self.gravity + g
                self.gravity_force = self.gravity_force + model.node_masses()[:, None] * g[None, :]
            elif isinstance(ld, VertexForce):
                self._need(pts, "VertexForce")
                idx = self._indices(ld.vertices, len(pts), "vertices")
                f = np.broadcast_to(as_float_array(ld.force, "force"), (len(idx), 3)) if \
                    np.ndim(ld.force) == 1 else as_float_array(ld.force, "force", (len(idx), 3))
                if ld.spread == "mass":
                    pattern = impulse_nodes(model, pts, idx, f)
                elif ld.spread == "embedding":          # W^T: only the rows of the loaded vertices (repeats add up)
                    pattern = np.asarray(self.W[idx].T @ f)
                else:
                    raise InputError(f"VertexForce spread must be 'mass' or 'embedding', got {ld.spread!r}")
                self._timed.append((pattern, ld.time or _one))
            elif isinstance(ld, FacePressure):
                self._need(pts, "FacePressure")
                if faces is None:
                    raise InputError("FacePressure needs faces= (the source-mesh triangles)")
                tri = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
                fidx = self._indices(ld.faces, len(tri), "faces")
                p = np.broadcast_to(np.asarray(ld.pressure, dtype=float), (len(fidx),))
                v = pts[tri[fidx]]                                        # (k, 3, 3)
                an = 0.5 * np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]) * model.scale**2   # area * n, m^2
                fv = np.repeat((-p[:, None] * an / 3.0), 3, axis=0)        # (3k, 3), per face corner
                self._timed.append((np.asarray(self.W[tri[fidx].ravel()].T @ fv), ld.time or _one))
            else:
                raise InputError(f"unknown load {ld!r}: use Gravity, VertexForce or FacePressure")

    @property
    def n_forces(self) -> int:
        return len(self._timed)

    @staticmethod
    def _need(pts, what: str) -> None:
        if pts is None:
            raise InputError(f"{what} needs points= (the source-mesh vertices, model units)")

    @staticmethod
    def _indices(idx, n: int, name: str) -> np.ndarray:
        return as_indices(idx, n, f"{name} indices", allow_empty=False)

    def force(self, t: float) -> np.ndarray:
        """Total node forces at time ``t`` (s), shape (m, 3), N."""
        f = self.gravity_force.copy()
        for pattern, prof in self._timed:                  # loop over loads
            s = float(prof(t))
            if s:
                f += s * pattern
        return f

    def gravity_potential(self, u: np.ndarray) -> float:
        """Potential energy of gravity relative to the rest state, ``-f_g . u`` (J); ``u`` (m, 3) m."""
        return -float(np.sum(self.gravity_force * u))


def impulse_nodes(model: CubeModel, points, vertices, impulses, *, radius: float = PATCH_RADIUS) -> np.ndarray:
    """Node impulses (m, 3), N s, for impulses on source vertices, spread over the mass around each
    (or node forces, N, for point forces: the same sharing, :class:`VertexForce` ``spread="mass"``).

    An impulse ``J`` on vertex ``p`` is shared by the lattice nodes of its body within ``radius``
    cube edges of ``p`` (at least the 8 nodes of its cube) in proportion to their lumped masses ``m_i``:
    node ``i`` gets ``m_i J / m_patch``. With a lumped mass every node of the patch then starts
    with the same velocity ``J / m_patch`` (momentum ``J``, kinetic energy ``|J|^2 / (2 m_patch)``
    -- a rigid patch hit by ``J``); with the consistent mass ``M^-1`` of it is close to that.

    Parameters
    ----------
    model : CubeModel
    points : array_like, shape (n, 3)
        Source vertices, model units.
    vertices : array_like of int, shape (k,)
        The vertices hit.
    impulses : array_like, shape (k, 3)
        Impulses, N s.
    radius : float
        Patch radius in cube edges (default :data:`PATCH_RADIUS`).

    Returns
    -------
    ndarray, shape (m, 3)
    """
    pts = as_points(points, "points")
    idx = as_indices(vertices, len(pts), "impulse vertices")
    J = as_float_array(impulses, "impulses", (len(idx), 3))
    out = np.zeros((model.n_nodes, 3))
    if not len(idx):
        return out
    m = model.node_masses()
    near = cKDTree(model.nodes).query_ball_point(pts[idx], r=radius * model.pitch)   # one list per impulse
    own = embed(model, pts[idx]).tocsr()                              # the nodes of each vertex's cube
    rows = np.concatenate([np.full(len(a), k) for k, a in enumerate(near)] + [own.nonzero()[0]]).astype(np.int64)
    cols = np.concatenate([np.asarray(a, dtype=np.int64) for a in near] + [own.nonzero()[1]])
    if model.shares_cells:       # bodies in one cell: only the nodes of the hit vertex's own body
        node_piece = np.zeros(model.n_nodes, np.int64)
        node_piece[model.hexes.ravel()] = np.repeat(model.piece, 8)
        hit_piece = np.zeros(len(idx), np.int64)
        own_r, own_c = own.nonzero()
        hit_piece[own_r] = node_piece[own_c]
        same = node_piece[cols] == hit_piece[rows]
        rows, cols = rows[same], cols[same]
    P = sp.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(idx), model.n_nodes))
    P.data[:] = 1.0                                                   # duplicates summed: back to 0/1
    Pm = P.multiply(m[None, :]).tocsr()                               # m_i on each patch
    share = sp.diags(1.0 / np.maximum(np.asarray(Pm.sum(axis=1)).ravel(), 1e-300)) @ Pm
    return np.asarray(share.T @ J)
