"""Higher-order cubes: a degree-``p`` Lagrange field on the cubes (the p-version finite cell method).

A trilinear cube moves everything inside it with one trilinear field: a cube that holds the web
and a flange of an I-section cannot let both walls warp as they do in torsion, and the section
twists tens of times too stiffly. The higher-order cubes carry ``(p + 1)^3`` nodes per cube at the
points ``(i, j, k) / p`` (:mod:`sc_fem.fem.lagrange`), shared with the neighbouring cubes of the same
body (keyed by their position on the lattice refined ``p`` times and by the body, as the corners
are: :attr:`sc_fem.lattice.cubes.CubeModel.piece`). A full cube is integrated exactly (Gauss). A
partly filled cube (:data:`PARTIAL`) is by default condensed from a fine model of its content
(:mod:`sc_fem.fem.multiscale`: its walls deform as the fine model does, only the faces it shares
follow the polynomial), or integrated over its filled region (``"moments"``: the model voxelized
:data:`REFINE` times finer, six points of equal weight per fine cube reproducing its exact moments
of degree 2, :func:`sigma_points`). Material (Lame parameters, density) is the coarse cube's.

Measured on thin-walled steel members (``docs/accuracy.md``): the ten lowest frequencies of an
I-section beam at 32 cubes are 53 % off with ``q1i``, 4.9 % with ``"q3"`` integrated, 1.6 % with
``"q3"`` condensed (2.9 % at 16 cubes). Higher-order cubes serve the linear analyses
(:func:`sc_fem.modal`, :func:`sc_fem.solve_static`); the source mesh follows their field
(:attr:`HighOrderCubes.W`).
"""

from __future__ import annotations

import warnings
from functools import lru_cache

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from .._validate import positive_int
from ..errors import InputError
from ..lattice.cubes import HEX_CORNERS
from ..lattice.embed import embedding
from ..lattice.topology import fine_to_coarse, keyed_nodes
from ..lattice.voxelize import voxelize
from .cutcell import moment_integrals, sigma_points  # noqa: F401 (sigma_points re-exported)
from .lagrange import lagrange_1d, shape_functions  # noqa: F401 (lagrange_1d re-exported)
from .multiscale import FINE_SPACING, Condensation, choose_refine
from .scatter import block_pattern, scatter

PARTIAL = ("multiscale", "moments")
"""How a partly filled cube's matrices are made: condensed from a fine model of its content
(:mod:`sc_fem.fem.multiscale`), or integrated over its filled region (sigma points of finer cubes' moments)."""

DEGREES: dict[str, int] = {"q2": 2, "q3": 3}
"""Higher-order element names and their polynomial degree."""

REFINE = 4
"""Fine cubes per cube edge for the integrals over a partly filled cube."""

EMPTY = 1e-8
"""The empty part of a partly filled cube carries this fraction of the material (the finite cell
method's usual stabilisation: nodes whose support holds almost no material stay bounded)."""


@lru_cache(maxsize=None)
def _full_cube(p: int) -> tuple[np.ndarray, np.ndarray]:
    """``G[a, i, b, j] = int dN_i/dxi_a dN_j/dxi_b`` (3, nb, 3, nb) and ``int N_i N_j`` (nb, nb)
    over the unit cube (exact Gauss rule)."""
    g, w = np.polynomial.legendre.leggauss(p + 1)
    g, w = 0.5 * (g + 1.0), 0.5 * w
    xi = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    wq = np.einsum("i,j,k->ijk", w, w, w).ravel()
    N, dN = shape_functions(p, xi)
    return np.einsum("q,qai,qbj->aibj", wq, dN, dN), np.einsum("q,qi,qj->ij", wq, N, N)


def _stiffness_from_G(G: np.ndarray, lam: np.ndarray, mu: np.ndarray) -> np.ndarray:
    """Element matrices (e, 3 nb, 3 nb), DOF ``3 node + c``, from gradient integrals ``G`` (e, 3, nb,
    3, nb) (physical units): ``K[(i,c),(j,d)] = lam G[c,i,d,j] + mu (delta_cd sum_a G[a,i,a,j] + G[d,i,c,j])``."""
    e, _, nb = G.shape[:3]
    lam, mu = lam[:, None, None, None, None], mu[:, None, None, None, None]
    K = lam * np.einsum("ecidj->eicjd", G) + mu * np.einsum("edicj->eicjd", G)
    K = K + mu * np.einsum("eaiaj,cd->eicjd", G, np.eye(3))
    return K.reshape(e, 3 * nb, 3 * nb)


class HighOrderCubes:
    """A degree-``p`` field on the cubes of a scene: its nodes, stiffness, mass and vertex map.

    Parameters
    ----------
    scene : Scene
        The model, its source mesh (the partly filled cubes are made from it) and its fixed nodes.
    element : {"q2", "q3"}
        The degree (2 or 3).
    refine : int or "auto"
        Fine cubes per cube edge of the finer model that the partly filled cubes are made from;
        ``"auto"``: for ``"multiscale"`` about the thin walls' thickness
        (:func:`sc_fem.fem.multiscale.choose_refine`), for ``"moments"`` :data:`REFINE`.
    partial : {"multiscale", "moments"}
        How a partly filled cube's matrices are made (:data:`PARTIAL`): condensed from the fine
        model of its content (:mod:`sc_fem.fem.multiscale`; its vertices follow the fine field), or
        the degree-``p`` field integrated over its filled region (six points per fine cube).

    Attributes
    ----------
    degree : int
    nodes : ndarray, shape (N, 3)
        Node positions, model units.
    dofs : ndarray of int, shape (n_cubes, 3 (p+1)^3)
        Global DOFs of each cube (``3 node + c``).
    corner_nodes : ndarray of int, shape (m,)
        The node at each of the model's cube corners (:attr:`CubeModel.nodes` order).
    fixed_dofs : ndarray of int
        DOFs held by the scene's fixed nodes (:meth:`held_dofs`).
    W : scipy.sparse.csr_matrix, shape (3 n_vertices, 3 N)
        The field at the source vertices: node DOFs to vertex displacement components.
    refine : int
        Fine cubes per cube edge used.
    wall : float or None
        The walls' thickness ``refine="auto"`` chose it for, model units.
    """

    def __init__(self, scene, element: str, *, refine: int | str = "auto", partial: str = "multiscale") -> None:
        if element not in DEGREES:
            raise InputError(f"higher-order element must be one of {sorted(DEGREES)}, got {element!r}")
        if scene.mesh is None or not len(scene.faces):
            raise InputError(f"element {element!r} integrates the cubes over the source mesh: the scene has no "
                             "surface mesh (build it with Scene.from_mesh)")
        if partial not in PARTIAL:
            raise InputError(f"partial must be one of {PARTIAL}, got {partial!r}")
        self.scene, self.element, self.degree, self.partial = scene, element, DEGREES[element], partial
        self.wall = None                                 # the walls' thickness the refinement was chosen for
        if refine == "auto" and partial == "multiscale":
            refine, self.wall = choose_refine(scene.model, scene.mesh.vertices, scene.mesh.faces)
        self.refine = REFINE if refine == "auto" else positive_int(refine, "refine")
        model = scene.model
        p = self.degree
        nb = (p + 1) ** 3
        local = np.stack(np.meshgrid(*[np.arange(p + 1)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
        lattice, node = keyed_nodes(p * model.cells[:, None, :] + local[None], model.dims * p + 1, model.piece)
        self.nodes = model.origin + (model.pitch / p) * lattice
        self.n_nodes = len(lattice)
        self.dofs = (3 * node[:, :, None] + np.arange(3)).reshape(model.n_cubes, 3 * nb)
        self._node = node
        corner_local = (HEX_CORNERS * p) @ np.array([(p + 1) ** 2, p + 1, 1])          # (8,) local index
        self.corner_nodes = np.empty(model.n_nodes, dtype=np.int64)
        self.corner_nodes[model.hexes.ravel()] = node[:, corner_local].ravel()
        self._local = local
        self.fixed_dofs = self.held_dofs(scene.fixed_nodes)
        self._G = self._M = None
        self._condensation = self._condensed = self._W = self._vertex_map = self._pattern = None

    @property
    def n_dofs(self) -> int:
        return 3 * self.n_nodes

    @property
    def nodes_m(self) -> np.ndarray:
        """Node positions in metres, shape (N, 3)."""
        return self.nodes * self.scene.model.scale

    def held_dofs(self, fixed_corners: ArrayLike) -> np.ndarray:
        """DOFs held when the cube corners ``fixed_corners`` (model node indices) are fixed: every
        node of a cube vertex, edge, face or interior whose corners are all fixed.

        Parameters
        ----------
        fixed_corners : array_like of int, shape (k,)
            Fixed nodes of the model (:attr:`Scene.fixed_nodes` numbering).

        Returns
        -------
        ndarray of int
            The held DOFs (``3 node + c``), sorted.
        """
        model, p, local = self.scene.model, self.degree, self._local
        held = np.zeros(model.n_nodes, dtype=bool)
        held[np.asarray(fixed_corners, dtype=np.int64)] = True
        if not held.any():
            return np.zeros(0, dtype=np.int64)
        corner_held = held[model.hexes]                                          # (e, 8)
        # a local node lies on the entity spanned by the corners that agree with it on its boundary axes
        on_lo, on_hi = local == 0, local == p                                     # (nb, 3)
        agree = np.all(((HEX_CORNERS[None, :, :] == 0) | ~on_lo[:, None, :])
                       & ((HEX_CORNERS[None, :, :] == 1) | ~on_hi[:, None, :]), axis=2)   # (nb, 8)
        fixed_local = np.all(~agree[None] | corner_held[:, None, :], axis=2)            # (e, nb)
        nodes = np.unique(self._node[fixed_local])
        return (3 * nodes[:, None] + np.arange(3)).ravel()

    # ------------------------------------------------------------------ integrals
    def _fine_model(self):
        """The scene's source voxelized ``refine`` times finer, with the coarse model's options."""
        model, s = self.scene.model, self.refine
        info = model.info
        opts = dict(pitch=model.pitch / s, scale=model.scale, fill=info.get("fill", "auto"),
                    occupancy=info.get("occupancy", "sample"), topology=info.get("topology", "pieces"),
                    keep="all", stiffness="moments", spacing=FINE_SPACING * model.pitch / s)
        if info.get("weld") is not None:
            opts["weld"] = info["weld"]
        if info.get("shell_thickness"):
            opts["shell_thickness"] = info["shell_thickness"]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")              # the fine grid's notes repeat the coarse one's
            return voxelize(self.scene.mesh, **opts)

    def _quadrature(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points of the partly filled cubes: (cube (q,), reference coordinates (q, 3), weight (q,) in
        units of the cube's volume), from the model voxelized ``refine`` times finer."""
        model, s = self.scene.model, self.refine
        fine = self._fine_model()
        hit, cube, local = fine_to_coarse(model, fine, s)
        pts, w = sigma_points(fine.moments[hit])
        xi = (local[:, None, :] + pts) / s
        return np.repeat(cube, 6), xi.reshape(-1, 3), (w / s**3).ravel()

    def _integrals(self) -> tuple[np.ndarray, np.ndarray]:
        """Per cube ``G`` (e, 3, nb, 3, nb) (reference gradients, units of h^3 / h^2 = h) and
        ``int N_i N_j`` (e, nb, nb) over the filled region, units of the cube's volume."""
        if self._G is not None:
            return self._G, self._M
        model, p = self.scene.model, self.degree
        Gf, Mf = _full_cube(p)
        frac = np.asarray(model.fraction, dtype=float)
        partial = np.flatnonzero(frac < 1.0 - 1e-12)
        G = np.broadcast_to(Gf, (model.n_cubes,) + Gf.shape).copy()
        M = np.broadcast_to(Mf, (model.n_cubes,) + Mf.shape).copy()
        if len(partial) and self.partial == "multiscale":
            G[partial] *= EMPTY                      # the condensed fine models are added on top
            M[partial] *= EMPTY
        elif len(partial):                           # the field integrated over the filled region
            g, m = moment_integrals(p, partial, *self._quadrature())
            G[partial] = EMPTY * G[partial] + g
            M[partial] = EMPTY * M[partial] + m
        self._G, self._M = G, M
        return G, M

    @property
    def condensed_cubes(self) -> np.ndarray:
        """The partly filled cubes whose matrices are condensed from fine models (``partial="multiscale"``)."""
        if self.partial != "multiscale":
            return np.zeros(0, dtype=np.int64)
        return np.flatnonzero(np.asarray(self.scene.model.fraction, dtype=float) < 1.0 - 1e-12)

    @property
    def condensation(self) -> Condensation | None:
        """The partly filled cubes' fine models, set up once (:class:`sc_fem.fem.multiscale.Condensation`;
        None when nothing is condensed). Their material is held where the scene fixes a cube face."""
        cubes = self.condensed_cubes
        if self._condensation is None and len(cubes):
            model = self.scene.model
            held = np.zeros(model.n_nodes, dtype=bool)
            held[np.asarray(self.scene.fixed_nodes, dtype=np.int64)] = True
            self._condensation = Condensation(model, cubes, self._fine_model(), self.refine, self.degree, held=held)
        return self._condensation

    def _condensed_matrices(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The condensed cubes' stiffness and mass, and the map of the source vertices in them (the same solves)."""
        if self._condensed is None and self.condensation is not None:
            emb = embedding(self.scene.model, self.scene.rest_vertices)
            inside = np.flatnonzero(np.isin(emb.cube, self.condensed_cubes))
            K, M, pmap = self.condensation.matrices(self.scene.rest_vertices[inside], emb.cube[inside])
            self._condensed, self._vertex_map = (K, M), (inside, pmap)
        return self._condensed

    def element_stiffness(self) -> np.ndarray:
        """Element stiffness matrices (n_cubes, 3 nb, 3 nb), N/m."""
        model = self.scene.model
        G, _ = self._integrals()
        lam, mu = model.lame(material=True)
        h = float(model.pitch * model.scale)
        K = h * _stiffness_from_G(G, np.asarray(lam, float), np.asarray(mu, float))
        if (c := self._condensed_matrices()) is not None:
            K[self.condensed_cubes] += c[0]
        return K

    def element_mass(self) -> np.ndarray:
        """Consistent element mass matrices (n_cubes, 3 nb, 3 nb), kg: ``rho int N_i N_j`` per component."""
        model = self.scene.model
        _, M = self._integrals()
        h = float(model.pitch * model.scale)
        rho = np.asarray(model.density, dtype=float) * h**3
        nb = M.shape[1]
        out = (rho[:, None, None, None, None] * M[:, :, None, :, None] * np.eye(3)[None, None, :, None, :])
        out = out.reshape(model.n_cubes, 3 * nb, 3 * nb)
        if (c := self._condensed_matrices()) is not None:
            out[self.condensed_cubes] += c[1]
        return out

    def _assemble(self, Ke: np.ndarray) -> sp.csr_matrix:
        if self._pattern is None:                         # the stiffness and the mass share it
            self._pattern = block_pattern(self._node, self.n_nodes)
        return scatter(self._pattern, Ke)

    def stiffness(self) -> sp.csr_matrix:
        """Global stiffness, shape (n_dofs, n_dofs), N/m."""
        return self._assemble(self.element_stiffness())

    def mass(self) -> sp.csr_matrix:
        """Global consistent mass, shape (n_dofs, n_dofs), kg."""
        return self._assemble(self.element_mass())

    # ------------------------------------------------------------------ the source mesh
    def map_points(self, points: ArrayLike, *, _known: tuple | None = None) -> sp.csr_matrix:
        """The field at ``points``: node DOFs (``3 node + c``) to the points' displacement components.

        A point in a full cube follows the cube's polynomial; one in a condensed cube, its fine
        model's field (one more solve of the fine models, :meth:`Condensation.point_map`).

        Parameters
        ----------
        points : array_like, shape (k, 3)
            Positions, model units.

        Returns
        -------
        scipy.sparse.csr_matrix, shape (3 k, 3 N)
        """
        pts = np.asarray(points, dtype=float)
        emb = embedding(self.scene.model, pts)
        N, _ = shape_functions(self.degree, emb.local)
        nv, nb = N.shape
        vals = np.einsum("vj,cd->vcjd", N, np.eye(3))                       # (v, 3, nb, 3)
        cols = np.broadcast_to(self.dofs[emb.cube].reshape(nv, 1, nb, 3), vals.shape)
        inside = np.flatnonzero(np.isin(emb.cube, self.condensed_cubes))
        if len(inside):                                                      # the fine field instead
            pmap = _known[1] if _known is not None else self.condensation.point_map(pts[inside], emb.cube[inside])
            vals[inside] = pmap.reshape(-1, 3, nb, 3)
        rows = np.broadcast_to((3 * np.arange(nv)[:, None] + np.arange(3))[:, :, None, None], vals.shape)
        return sp.csr_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * nv, self.n_dofs))

    @property
    def W(self) -> sp.csr_matrix:
        """The field at the scene's source vertices, shape (3 n_vertices, 3 N) (:meth:`map_points`); computed once."""
        if self._W is None:
            known = self._vertex_map if self._condensed_matrices() is not None else None
            self._W = self.map_points(self.scene.rest_vertices, _known=known)
        return self._W


class HighOrderAssembler:
    """:class:`HighOrderCubes` with the fixed DOFs removed: the interface the linear analyses use.

    Parameters
    ----------
    cubes : HighOrderCubes
        The field (its integrals are computed once and shared by every assembler built on it).
    fixed_nodes : array_like of int, optional
        Cube corners held instead of the scene's fixed nodes (e.g. with floating parts pinned).

    Attributes
    ----------
    cubes : HighOrderCubes
    free_dofs : ndarray of int
        DOFs left free by the scene's fixed nodes.
    """

    def __init__(self, cubes: HighOrderCubes, *, fixed_nodes: ArrayLike | None = None) -> None:
        self.cubes = cubes
        self.model = cubes.scene.model
        free = np.ones(cubes.n_dofs, dtype=bool)
        free[cubes.fixed_dofs if fixed_nodes is None else cubes.held_dofs(fixed_nodes)] = False
        self.free_dofs = np.flatnonzero(free)

    @property
    def nodes_m(self) -> np.ndarray:
        """Node positions in metres, shape (N, 3)."""
        return self.cubes.nodes_m

    def stiffness(self) -> sp.csr_matrix:
        """Stiffness on the free DOFs, N/m."""
        K = self.cubes.stiffness()
        return K[self.free_dofs][:, self.free_dofs].tocsr()

    def mass(self, *, lumped: bool = False) -> sp.csr_matrix:
        """Consistent mass on the free DOFs, kg (``lumped=True`` is refused: row sums of a
        degree-2 or 3 Lagrange mass matrix are not all positive)."""
        if lumped:
            raise InputError(f"lumped mass is not defined for element {self.cubes.element!r} (row sums of its "
                             "mass matrix can be negative); use the consistent mass")
        M = self.cubes.mass()
        return M[self.free_dofs][:, self.free_dofs].tocsr()

    def expand_all(self, u_free: np.ndarray) -> np.ndarray:
        """The field at every node, shape (N, 3) or (N, 3, k), from free-DOF values (zeros where fixed)."""
        u_free = np.asarray(u_free)
        out = np.zeros((self.cubes.n_dofs,) + u_free.shape[1:], dtype=u_free.dtype)
        out[self.free_dofs] = u_free
        return out.reshape((self.cubes.n_nodes, 3) + u_free.shape[1:])

    def expand(self, u_free: np.ndarray) -> np.ndarray:
        """The field at the model's cube corners, shape (m, 3) or (m, 3, k)."""
        return self.expand_all(u_free)[self.cubes.corner_nodes]

    def restrict(self, f_nodes: np.ndarray) -> np.ndarray:
        """Free-DOF vector of point forces (m, 3) at the model's cube corners, N."""
        f = np.zeros((self.cubes.n_nodes, 3))
        np.add.at(f, self.cubes.corner_nodes, np.asarray(f_nodes, dtype=float).reshape(-1, 3))
        return f.reshape(-1)[self.free_dofs]

    def vertex_field(self, u_free: np.ndarray, W: sp.csr_matrix) -> np.ndarray:
        """The field at the source vertices, (n, 3) or (n, 3, k), through ``W`` = :attr:`HighOrderCubes.W`."""
        full = self.expand_all(u_free)
        flat = full.reshape(3 * full.shape[0], -1)
        return np.asarray(W @ flat).reshape((W.shape[0] // 3, 3) + full.shape[2:])
