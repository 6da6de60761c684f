"""The collision meshes of contact inside the implicit step (:mod:`.ipc`): static obstacles as triangle
meshes, the lattice's outer surface and its bodies, and one IPC Toolkit collision mesh whose moving
vertices are a linear map of the lattice DOFs (:class:`CollisionLayer`).

Obstacles (:class:`~sc_fem.dynamics.contact.Ground`, ``Sphere``, ``Box``) are static triangle meshes:
the ground a square of 200 model sizes, a sphere an icosphere of 642 vertices (inscribed: at most
0.3 % of the radius inside the true sphere), a box its 12 triangles.

Units: the collision meshes are in metres (``rest * scale``); obstacles are given in model units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from ..errors import InputError
from ..lattice.cubes import HEX_CORNERS, CubeModel
from .contact import Box, Ground, Sphere

GROUND_SPAN = 100.0
"""Half-width of the ground square in model sizes (bounding-box diagonals)."""


def require_ipctk():
    """The IPC Toolkit module (an InputError naming the package when it is missing)."""
    try:
        import ipctk
    except ImportError as exc:      # pragma: no cover - ipctk is a dependency
        raise InputError("contact inside the implicit step needs the IPC Toolkit: pip install ipctk") from exc
    return ipctk


def fortran(a) -> np.ndarray:
    """``a`` as a Fortran-ordered float array (what ipctk takes without a copy)."""
    return np.asfortranarray(a, dtype=float)


def obstacle_mesh(ob, centre: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """A static obstacle as a triangle mesh, model units.

    Parameters
    ----------
    ob : Ground, Sphere or Box
    centre : ndarray, shape (3,)
        Centre of the model (the ground square is centred under it).
    size : float
        Model size (bounding-box diagonal), model units.

    Returns
    -------
    vertices : ndarray, shape (k, 3)
    faces : ndarray of int, shape (f, 3)
    """
    import trimesh

    if isinstance(ob, Ground):
        a, (b, c) = ob.axis, [k for k in range(3) if k != ob.axis]
        s = GROUND_SPAN * size
        V = np.zeros((4, 3))
        V[:, a] = ob.z
        V[:, b] = centre[b] + s * np.array([-1, 1, 1, -1])
        V[:, c] = centre[c] + s * np.array([-1, -1, 1, 1])
        return V, np.array([[0, 1, 2], [0, 2, 3]])
    if isinstance(ob, Sphere):
        m = trimesh.creation.icosphere(subdivisions=3, radius=float(ob.radius))
        return np.asarray(m.vertices) + np.asarray(ob.center, dtype=float), np.asarray(m.faces)
    if isinstance(ob, Box):
        m = trimesh.creation.box(bounds=np.array([ob.lo, ob.hi], dtype=float))
        return np.asarray(m.vertices), np.asarray(m.faces)
    raise InputError(f"unknown obstacle {ob!r}: use Ground, Sphere or Box")


class CollisionLayer:
    """One collision mesh: moving vertices (rows ``P`` of the node DOFs) first, then static ones.

    Parameters
    ----------
    rest : ndarray, shape (k, 3)
        Rest positions, metres.
    faces : ndarray of int, shape (f, 3)
    can_collide : ipctk.CollisionFilter
    P : scipy.sparse matrix, shape (3 n_moving, 3 m)
        Moving-vertex displacements from node displacements (both metres).
    dhat : float
        Barrier activation distance of this layer, metres.
    keep : tuple
        The filters ``can_collide`` was composed of (kept alive with the mesh).
    """

    def __init__(self, rest: np.ndarray, faces: np.ndarray, can_collide, P, dhat: float, keep=()) -> None:
        ipctk = require_ipctk()
        # ipctk's composed filters (a & b, ~a) refer to their operands without owning them: the
        # operands must live as long as the mesh (freed, they made ipctk segfault at random)
        self._keep = (can_collide, *keep)
        self.rest = fortran(rest)
        F = np.asfortranarray(faces, dtype=np.int32).reshape(-1, 3)
        E = ipctk.edges(F) if len(F) else np.zeros((0, 2), dtype=np.int32)
        self.mesh = ipctk.CollisionMesh(self.rest, np.asfortranarray(E, dtype=np.int32), F)
        self.mesh.can_collide = can_collide
        self.P = sp.csr_matrix(P)
        self.n_moving = self.P.shape[0] // 3
        self.dhat = float(dhat)
        self.Phi = self.PhiT = None

    def bind(self, free_dofs: np.ndarray) -> None:
        self.Phi = self.P[:, free_dofs].tocsr()
        self.PhiT = self.Phi.T.tocsr()

    def vertices(self, x: np.ndarray) -> np.ndarray:
        V = np.array(self.rest)
        V[: self.n_moving] += (self.Phi @ x).reshape(-1, 3)
        return np.asfortranarray(V)

    def collisions(self, V: np.ndarray):
        col = require_ipctk().NormalCollisions()
        col.build(self.mesh, V, self.dhat)
        return col

    def to_dofs(self, g: np.ndarray) -> np.ndarray:
        return self.PhiT @ g[: 3 * self.n_moving]

    def hessian_to_dofs(self, H) -> sp.csr_matrix:
        k = 3 * self.n_moving
        return (self.PhiT @ sp.csr_matrix(H)[:k, :k] @ self.Phi).tocsr()


@dataclass
class ContactState:
    """The collision meshes at one configuration: per layer, the vertices (metres) and the pairs
    closer than its ``dhat`` (``ipctk.NormalCollisions``)."""

    x: np.ndarray
    V: list
    col: list

    @property
    def n_pairs(self) -> int:
        return sum(len(c) for c in self.col)


def lattice_surface(model: CubeModel) -> np.ndarray:
    """The outer surface of the cube lattice as triangles of lattice nodes, shape (f, 3).

    Every cube face without a cube of the same body behind it becomes two triangles. The surface passes through
    lattice nodes only, so two of its faces are either a cube edge apart or share a node: it is
    free of intersections at rest whatever the source mesh is (the collision proxy of self-contact).
    """
    cells = np.asarray(model.cells, dtype=np.int64)
    dims = np.asarray(model.dims, dtype=np.int64) + 2
    piece = np.asarray(model.piece, dtype=np.int64)
    n_p = int(piece.max()) + 1 if len(piece) else 1
    # a cube face is open when no cube of the same body lies behind it (bodies sharing a cell are apart)
    key = lambda c: (((c[:, 0] + 1) * dims[1] + c[:, 1] + 1) * dims[2] + c[:, 2] + 1) * n_p + piece  # noqa: E731
    occupied = np.sort(key(cells))
    corner = {tuple(o): i for i, o in enumerate(HEX_CORNERS.tolist())}
    tris = []
    for a in range(3):                        # the 6 face directions
        b, c = [k for k in range(3) if k != a]
        for side in (0, 1):
            step = np.zeros(3, dtype=np.int64)
            step[a] = 2 * side - 1
            nb = key(cells + step)
            pos = np.searchsorted(occupied, nb)
            open_ = occupied[np.minimum(pos, len(occupied) - 1)] != nb
            quad = []
            for ob, oc in ((0, 0), (1, 0), (1, 1), (0, 1)):
                o = [0, 0, 0]
                o[a], o[b], o[c] = side, ob, oc
                quad.append(corner[tuple(o)])
            q = model.hexes[open_][:, quad]
            tris.append(np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]]))
    return np.concatenate(tris)


def node_bodies(model: CubeModel) -> np.ndarray:
    """The mechanical body of every lattice node, shape (m,): nodes linked through cubes (cubes
    that share any node move together)."""
    n = model.n_cubes
    rows = np.repeat(np.arange(n), 8)
    G = sp.csr_matrix((np.ones(8 * n), (rows, model.hexes.ravel())), shape=(n, model.n_nodes))
    _, labels = connected_components(G.T @ G, directed=False)
    return labels.astype(np.int32)
