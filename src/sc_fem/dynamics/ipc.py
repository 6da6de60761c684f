r"""Contact inside the implicit step: the incremental potential with barriers (IPC).

The seed's workflow detects contact on the *source* geometry. Here the source mesh is the
collision mesh, a linear map of the lattice DOFs: its vertices move by ``W u`` (``W`` the
trilinear embedding). A time step of backward (implicit) Euler is the minimiser of the
incremental potential (Li et al. 2020, "Incremental Potential Contact")

.. math::

   E(x) = \tfrac{1}{2 h^2} \|x - x_n - h v_n\|_M^2 + \Psi(x) - f \cdot x
          + \tfrac{1}{2h} \|x - x_n\|_C^2 + \kappa B(V(x)) + h D\big((V(x) - V(x_n)) / h\big)

over the free node displacements ``x`` (m): inertia, elastic energy ``Psi`` (``1/2 x.Kx``),
loads, Rayleigh damping ``C``, the log barrier ``B`` of every vertex-triangle and edge-edge
pair of the collision mesh closer than ``dhat``, and the lagged smooth Coulomb friction ``D``
(coefficient ``friction``). The barrier, its derivatives, the friction potential and the
continuous collision detection (CCD) are the IPC Toolkit's (``ipctk``); gradients and Hessians
come back to the DOFs through ``Phi = W (x) I_3`` (``Phi^T g``, ``Phi^T H Phi``).

Newton's method with the Hessian's contact blocks projected to PSD, a line search that starts
at the CCD's collision-free step and halves until ``E`` decreases: every state is
intersection-free by construction and the step is stable at any ``dt``. When no pair is within
``dhat`` and there is no friction, ``E`` is the quadratic of linear implicit Euler: one
back-solve with a factorization kept for the run (the fast path).

Obstacles (:class:`~sc_fem.dynamics.contact.Ground`, ``Sphere``, ``Box``) are static triangle
meshes in the same collision mesh: the ground a square of 200 model sizes, a sphere an
icosphere of 642 vertices (inscribed: at most 0.3 % of the radius inside the true sphere),
a box its 12 triangles. Pairs within the source mesh are not tested (its parts may intersect
at rest: the chair's legs pass through its seat; the lattice holds them together); pairs of
different objects (:func:`merge_scenes`) and source-obstacle pairs are.

Units: the collision mesh is in metres (``rest * scale``); ``dhat`` is given in model units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .._validate import positive_scalar
from ..errors import InputError
from ..fem.linsolve import factorize
from ..lattice.cubes import CubeModel
from .base import TimeIntegrator
from .contact import Box, Ground, Sphere

DHAT_FRACTION = 1e-3
"""Default barrier activation distance as a fraction of the source mesh's bounding-box diagonal."""

CG_RTOL = 1e-8
"""Relative residual of the conjugate-gradient solves of a Newton step with contact."""

MAX_HALVINGS = 3
"""A step whose Newton solve does not converge is cut in two, at most this many times nested."""

CG_REFACTOR = 8
"""CG iterations of a contact solve past which the next one factorizes its Hessian (and keeps
the factor as the preconditioner of the ones after it)."""

CG_MAXITER = 40
"""CG iterations after which a contact solve factorizes its Hessian at once."""

CCD_TOLERANCE = 1e-4
"""Tight Inclusion CCD's tolerance (its default 1e-6 took up to 3.3 s for one step of the chair's
legs landing together, against 4 ms at 1e-4 with the same step, 0.25 instead of 0.2527: the
answer stays conservative, only a little shorter)."""

CCD_MAX_ITERATIONS = 100_000
"""Tight Inclusion CCD's iteration cap (on reaching it, it returns a conservative step)."""

GROUND_SPAN = 100.0
"""Half-width of the ground square in model sizes (bounding-box diagonals)."""


def _ipctk():
    try:
        import ipctk
    except ImportError as exc:      # pragma: no cover - ipctk is a dependency
        raise InputError("contact inside the implicit step needs the IPC Toolkit: pip install ipctk") from exc
    return ipctk


def _f(a) -> np.ndarray:
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


class _Layer:
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
        ipctk = _ipctk()
        # ipctk's composed filters (a & b, ~a) refer to their operands without owning them: the
        # operands must live as long as the mesh (freed, they made ipctk segfault at random)
        self._keep = (can_collide, *keep)
        self.rest = _f(rest)
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
        col = _ipctk().NormalCollisions()
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
    from .._validate import as_float_array  # noqa: F401  (keeps the import graph of this module flat)
    from ..lattice.cubes import HEX_CORNERS

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
    from scipy.sparse.csgraph import connected_components

    n = model.n_cubes
    rows = np.repeat(np.arange(n), 8)
    G = sp.csr_matrix((np.ones(8 * n), (rows, model.hexes.ravel())), shape=(n, model.n_nodes))
    _, labels = connected_components(G.T @ G, directed=False)
    return labels.astype(np.int32)


class BarrierContact:
    """The collision meshes of a run: the source surface moving with the lattice, static
    obstacles, and the lattice's outer surface for self-contact.

    Two layers, each an IPC Toolkit collision mesh with its own barrier:

    * **source**: the source mesh (vertices ``rest + W u``; its triangles split until no edge is
      longer than a cube, the new vertices embedded like the others) and the obstacles. Pairs of one body
      are not tested (a source mesh may intersect itself at rest -- the chair's legs pass through
      its seat -- and the lattice holds its parts together); pairs of different bodies (parts of
      the lattice that share no node: objects in one scene) and body-obstacle pairs are.
    * **self** (``self_contact=True``): the outer surface of the cube lattice
      (:func:`lattice_surface`) as the collision proxy of each body with itself: intersection-free
      at rest by construction, it keeps a body that folds onto itself from passing through itself.
      It sits up to a cube outside the source surface, so a body touches itself up to a cube early.

    Parameters
    ----------
    model : CubeModel
    points : array_like, shape (n, 3)
        Source-mesh vertices at rest, model units.
    faces : array_like of int, shape (f, 3)
        Source-mesh triangles ((0, 3): the points collide as points).
    obstacles : sequence of Ground / Sphere / Box
        Static obstacles (none: only bodies against each other and themselves).
    W : scipy.sparse matrix, shape (n, m), optional
        Embedding of ``points`` (computed if omitted).
    friction : float
        Coulomb coefficient ``mu`` (0: frictionless).
    dhat : float, optional
        Barrier activation distance, model units (default ``1e-3`` of the source's
        bounding-box diagonal). Bodies rest less than ``dhat`` above what they lie on.
    eps_v : float, optional
        Friction's static-dynamic transition speed, model units per second (default
        ``1e-3`` diagonals per second).
    self_contact : bool
        Add the self layer (default True).

    Raises
    ------
    InputError
        An obstacle cuts the source mesh at rest (a ground that the mesh merely touches, or cuts
        by less than ``dhat``, is lowered to ``dhat`` below its lowest vertex instead and the
        shift is reported in ``ground_shift``), or bodies intersect each other at rest.
    """

    def __init__(self, model: CubeModel, points, faces, obstacles=(), *, W=None, friction: float = 0.0,
                 dhat: float | None = None, eps_v: float | None = None, self_contact: bool = True) -> None:
        from .._validate import as_points
        from ..lattice.embed import embed

        ipctk = _ipctk()
        self.model = model
        pts = as_points(points, "points")
        n = len(pts)
        tri = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        if tri.size and (tri.min() < 0 or tri.max() >= n):
            raise InputError(f"faces index vertices outside [0, {n})")
        self.friction = float(friction)
        if not 0.0 <= self.friction <= 10.0 or not np.isfinite(self.friction):
            raise InputError(f"friction must lie in [0, 10], got {friction!r}")
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        size = float(np.linalg.norm(hi - lo)) or 1.0
        self.size = size
        self.dhat = DHAT_FRACTION * size if dhat is None else positive_scalar(dhat, "dhat")
        self.eps_v = DHAT_FRACTION * size if eps_v is None else positive_scalar(eps_v, "eps_v")
        W = (embed(model, pts) if W is None else sp.csr_matrix(W))
        if W.shape != (n, model.n_nodes):
            raise InputError(f"W must have shape ({n}, {model.n_nodes}), got {W.shape}")
        # the collision surface: the source triangles split until no edge is longer than a cube, so
        # that a coarse mesh (a plate of 8 vertices) cannot let the lattice sag through an obstacle
        # between its vertices; the new vertices lie on the source surface, embedded like the others
        tri = tri[np.ptp(pts[tri], axis=1).max(axis=1) > 0] if tri.size else tri
        if tri.size:
            import trimesh

            pts_c, tri = trimesh.remesh.subdivide_to_size(pts, tri, max_edge=model.pitch, max_iter=12)
            if len(pts_c) > n:
                W = sp.vstack([W, embed(model, pts_c[n:])]).tocsr()
                pts, n = pts_c, len(pts_c)
        self.W = W
        nb = node_bodies(model)
        Wc = self.W.tocsr()
        self.bodies = nb[Wc.indices[Wc.indptr[:-1]]] if n else np.zeros(0, dtype=np.int32)
        self.n_bodies = int(nb.max()) + 1 if len(nb) else 0
        self.ground_shift = 0.0
        self.obstacles = tuple(self._placed(ob, pts) for ob in obstacles)
        s = model.scale
        self.diag_m, self.dhat_m, self.eps_v_m = size * s, self.dhat * s, self.eps_v * s
        # source layer: the source mesh, then the static obstacle meshes
        Vs, Fs, ids = [pts], [tri], [self.bodies]
        off, centre = n, 0.5 * (lo + hi)
        for k, ob in enumerate(self.obstacles):
            V, F = obstacle_mesh(ob, centre, size)
            Vs.append(V)
            Fs.append(F + off)
            ids.append(np.full(len(V), self.n_bodies + k, dtype=np.int32))
            off += len(V)
        eye = sp.identity(3, format="csr")
        static = ipctk.make_static_obstacle_filter(n)
        patches = ipctk.make_vertex_patches_filter(np.concatenate(ids).astype(np.int32))
        layers = [_Layer(np.vstack(Vs) * s, np.vstack(Fs), static & patches, sp.kron(self.W, eye, format="csr"),
                         self.dhat_m, keep=(static, patches))]
        if ipctk.has_intersections(layers[0].mesh, layers[0].rest):
            raise InputError("bodies of the model intersect each other or an obstacle at rest: move them apart "
                             "(parts that share a cube are one body and may intersect)")
        self.self_contact = bool(self_contact)
        if self.self_contact:
            surf = lattice_surface(model)
            used, inv = np.unique(surf, return_inverse=True)
            sel = sp.csr_matrix((np.ones(len(used)), (np.arange(len(used)), used)), shape=(len(used), model.n_nodes))
            other_bodies = ipctk.make_vertex_patches_filter(nb[used].astype(np.int32))
            layers.append(_Layer(model.nodes_m[used], inv.reshape(-1, 3), ~other_bodies, sp.kron(sel, eye, format="csr"),
                                 min(self.dhat_m, 0.1 * model.h), keep=(other_bodies,)))
        self.layers = layers

    # ------------------------------------------------------------------ set-up
    def _placed(self, ob, pts: np.ndarray):
        """``ob``, or for a ground the mesh touches or cuts by less than ``dhat``, a ground
        lowered to ``dhat`` below the lowest vertex."""
        d, _ = ob.depth(pts)                                     # > 0 inside
        worst = float(d.max()) if len(d) else -np.inf
        if worst <= -self.dhat:
            return ob
        if isinstance(ob, Ground) and worst <= self.dhat:
            self.ground_shift = worst + self.dhat
            return Ground(ob.z - self.ground_shift, ob.axis)
        raise InputError(f"{ob} already cuts or touches the model at t = 0 ({int((d > -self.dhat).sum())} of "
                         f"{len(d)} vertices lie within the contact distance dhat = {self.dhat:.3g} model units, "
                         f"the deepest {worst:.4g} inside): move the obstacle or the model apart")

    def bind(self, free_dofs: np.ndarray) -> None:
        """Restrict every layer's DOF map to these free DOFs (the integrator's)."""
        for L in self.layers:
            L.bind(free_dofs)

    # ------------------------------------------------------------------ evaluation
    def state(self, x: np.ndarray) -> ContactState:
        """The layers' vertices and close pairs at free-DOF displacements ``x`` (m)."""
        V = [L.vertices(x) for L in self.layers]
        return ContactState(x=x, V=V, col=[L.collisions(v) for L, v in zip(self.layers, V)])

    def barrier(self, st: ContactState, kappa: float, need: str):
        """The barrier ``kappa B`` at ``st``: energy (J), gradient or PSD-projected Hessian in free
        DOFs (``need`` "e", "g" or "h"); ``kappa`` the physical stiffness."""
        ipctk = _ipctk()
        out = 0.0 if need != "h" else None
        for L, V, col in zip(self.layers, st.V, st.col):
            if not len(col):
                continue
            B = ipctk.BarrierPotential(L.dhat, kappa)
            if need == "e":
                out += float(B(col, L.mesh, V))
            elif need == "g":
                out = out + L.to_dofs(B.gradient(col, L.mesh, V))
            else:
                H = L.hessian_to_dofs(B.hessian(col, L.mesh, V, ipctk.PSDProjectionMethod.CLAMP))
                out = H if out is None else out + H
        return out

    def lagged_friction(self, st: ContactState, kappa: float):
        """IPC's lagged friction at ``st`` (the start of a step): per layer the tangential pairs and
        their normal forces, or None without friction or contact."""
        if self.friction <= 0 or not st.n_pairs:
            return None
        ipctk = _ipctk()
        out = []
        for L, V, col in zip(self.layers, st.V, st.col):
            tc = ipctk.TangentialCollisions()
            if len(col):
                tc.build(L.mesh, V, col, ipctk.BarrierPotential(L.dhat, kappa), self.friction)
            out.append(tc)
        return out

    def friction_terms(self, fric, st: ContactState, st0: ContactState, dt: float, need: str):
        """The friction term ``dt D((V - V_n) / dt)`` at ``st`` (``st0``: the step's start):
        energy, gradient or PSD Hessian in free DOFs."""
        ipctk = _ipctk()
        D = ipctk.FrictionPotential(self.eps_v_m)
        out = 0.0 if need != "h" else None
        for L, V, V0, tc in zip(self.layers, st.V, st0.V, fric):
            if not len(tc):
                continue
            vel = _f((V - V0) / dt)
            if need == "e":
                out += dt * float(D(tc, L.mesh, vel))
            elif need == "g":
                out = out + L.to_dofs(D.gradient(tc, L.mesh, vel))
            else:
                H = L.hessian_to_dofs(D.hessian(tc, L.mesh, vel, ipctk.PSDProjectionMethod.CLAMP)) / dt
                out = H if out is None else out + H
        return out

    def stepsize(self, st: ContactState, x1: np.ndarray) -> float:
        """Largest ``alpha`` in [0, 1] with the straight path from ``st`` towards ``x1``
        intersection-free in every layer (CCD)."""
        ipctk = _ipctk()
        ccd = ipctk.TightInclusionCCD(CCD_TOLERANCE, CCD_MAX_ITERATIONS)
        return min(float(ipctk.compute_collision_free_stepsize(L.mesh, V, L.vertices(x1), narrow_phase_ccd=ccd))
                   for L, V in zip(self.layers, st.V))

    def min_distance_sq(self, st: ContactState) -> float:
        """Smallest squared distance (m^2) of any close pair at ``st`` (``inf`` with none)."""
        d = [float(col.compute_minimum_distance(L.mesh, V)) for L, V, col in zip(self.layers, st.V, st.col)
             if len(col)]
        return min(d) if d else np.inf

class _NotConverged(Exception):
    """A Newton solve of :class:`IPC` that did not converge (the step is then cut in two)."""


@dataclass
class _Step:
    """Counters of the Newton iterations of a run (``IPC.info``)."""

    newton: int = 0
    factorizations: int = 0
    contact_steps: int = 0
    line_search_cuts: int = 0
    cg_iterations: int = 0
    halvings: int = 0


class IPC(TimeIntegrator):
    """Backward Euler as the minimisation of the incremental potential with barrier contact.

    Parameters
    ----------
    model, dt, element, fixed_nodes, loads, rayleigh, lumped, u0, v0, backend
        See :class:`~sc_fem.dynamics.base.TimeIntegrator`.
    contact : BarrierContact, optional
        The collision mesh (none: linear backward Euler, one back-solve per step).
    tol : float
        Newton stops when the largest step of a vertex-free DOF is below ``tol`` times the
        model size (default 1e-5).
    max_newton : int
        Newton iterations per solve at most (default 100). A step whose solve does not converge
        is cut into two half steps, up to ``MAX_HALVINGS`` times nested (counted in
        ``info["halvings"]``); past that :class:`~sc_fem.errors.InstabilityError` says why.
    """

    name = "ipc"
    implicit = True

    def __init__(self, model, dt, *, contact: BarrierContact | None = None, tol: float = 1e-5,
                 max_newton: int = 100, **kw) -> None:
        if contact is not None and not isinstance(contact, BarrierContact):
            raise InputError(f"contact must be a BarrierContact for method 'ipc', got {type(contact).__name__}")
        if contact is not None and contact.model.n_nodes != model.n_nodes:
            raise InputError(f"contact was built for a model with {contact.model.n_nodes} nodes, "
                             f"this one has {model.n_nodes}")
        self.barrier = contact
        self.tol = positive_scalar(tol, "tol")
        self.max_newton = int(max_newton)
        self.stats = _Step()
        self._kappa = None            # barrier stiffness in IPC's h^2-scaled units, and its maximum
        self._kappa_max = None
        self._last = None             # the ContactState of the last state _advance returned
        super().__init__(model, dt, **kw)
        a0, a1 = self.rayleigh
        self._C = None if not (a0 or a1) else (a0 * self.M + a1 * self.K).tocsr()
        self._levels: dict = {}       # step length -> (S, its factorization)
        self._h = self.dt             # the length of the (sub)step being solved
        self._S, self._Sfac = self._level(self.dt)
        self._pre, self._pre_h, self._stale = self._Sfac, self.dt, False
        self._mass_avg = float(self.M.diagonal().mean()) if self.M.shape[0] else 1.0
        if contact is not None:
            contact.bind(self.asm.free_dofs)
            self._scale_x = contact.diag_m
        else:
            self._scale_x = float(np.linalg.norm(np.ptp(model.nodes_m, axis=0))) or 1.0

    # ------------------------------------------------------------------ energy of a state
    def _state_at(self, x: np.ndarray) -> ContactState:
        last = self._last
        return last if last is not None and last.x is x else self.barrier.state(x)

    def contact_energy(self, x: np.ndarray) -> float:
        """Barrier energy ``kappa B`` (J) at free-DOF displacements ``x``."""
        if self.barrier is None or self._kappa is None:
            return 0.0
        return float(self.barrier.barrier(self._state_at(x), self._kphys(), "e"))

    def energy(self):
        from .base import Energy

        e = super().energy()
        return Energy(kinetic=e.kinetic, elastic=e.elastic, gravity=e.gravity, contact=self.contact_energy(self._u))

    @property
    def info(self) -> dict:
        s, c = self.stats, self.barrier
        return {"newton_iterations": s.newton, "factorizations": s.factorizations, "contact_steps": s.contact_steps,
                "line_search_cuts": s.line_search_cuts, "cg_iterations": s.cg_iterations,
                "halvings": s.halvings,
                "dhat": None if c is None else c.dhat, "friction": None if c is None else c.friction,
                "ground_shift": None if c is None else c.ground_shift,
                "self_contact": None if c is None else c.self_contact,
                "bodies": None if c is None else c.n_bodies}

    # ------------------------------------------------------------------ the potential
    def _level(self, h: float):
        """``S = (1/h^2 + a0/h) M + (1 + a1/h) K`` for a (sub)step ``h`` and its factorization (kept)."""
        if h not in self._levels:
            a0, a1 = self.rayleigh
            S = ((1.0 / h**2 + a0 / h) * self.M + (1.0 + a1 / h) * self.K).tocsr()
            self._levels[h] = (S, factorize(S, self.backend))
            self.stats.factorizations += 1
        return self._levels[h]

    def _kphys(self) -> float:
        """The physical barrier stiffness: IPC's (for the ``h^2``-scaled potential) over ``h^2``."""
        return self._kappa / self.dt**2

    def _smooth(self, x, u, ut, f) -> tuple[float, np.ndarray]:
        """Energy and gradient of the terms without contact (step length ``self._h``)."""
        dt = self._h
        dx = x - ut
        Mdx = self.M @ dx
        Kx = self.K @ x
        e = 0.5 / dt**2 * float(dx @ Mdx) + 0.5 * float(x @ Kx) - float(f @ x)
        g = Mdx / dt**2 + Kx - f
        if self._C is not None:
            Cd = self._C @ (x - u)
            e += 0.5 / dt * float((x - u) @ Cd)
            g = g + Cd / dt
        return e, g

    def _contact(self, st: ContactState, fric, st0: ContactState, need: str):
        """Barrier + friction at ``st``: energy, gradient or Hessian (``need``) in free DOFs."""
        c = self.barrier
        out = c.barrier(st, self._kphys(), need)
        if fric is not None:
            f = c.friction_terms(fric, st, st0, self._h, need)
            out = f if out is None else (out if f is None else out + f)
        return out

    def _update_kappa(self, x, u, ut, f, st: ContactState) -> None:
        """IPC's adaptive barrier stiffness: set from the gradients at the step's start, never lowered."""
        ipctk = _ipctk()
        c = self.barrier
        _, gE = self._smooth(x, u, ut, f)
        gB = c.barrier(st, 1.0, "g") if st.n_pairs else 0 * x
        gB = gB if np.ndim(gB) else 0 * x
        B = ipctk.BarrierPotential(c.dhat_m, 1.0)       # alive through the call: .barrier is B's own, not a copy
        k, kmax = ipctk.initial_barrier_stiffness(c.diag_m, B.barrier, c.dhat_m, self._mass_avg, self.dt**2 * gE, gB)
        self._kappa = max(k, self._kappa or 0.0)
        self._kappa_max = max(kmax, self._kappa_max or 0.0)

    def _solve_contact(self, H, g: np.ndarray) -> np.ndarray:
        """``H^-1 g`` for ``H = S + (contact Hessian)``: conjugate gradients preconditioned with the
        latest factorization (first ``S``'s, then that of an earlier Newton iteration's ``H``: while
        the contacts change little it preconditions well). A solve that needs more than
        ``CG_REFACTOR`` iterations makes the next one factorize its ``H`` (kept as the new
        preconditioner); CG that does not converge in ``CG_MAXITER`` factorizes at once."""
        from scipy.sparse.linalg import LinearOperator, cg

        if not self._stale:
            count = [0]

            def tick(_):
                count[0] += 1

            pre = LinearOperator(H.shape, matvec=self._pre.solve, dtype=float)
            y, info = cg(H, g, rtol=CG_RTOL, atol=0.0, maxiter=CG_MAXITER, M=pre, callback=tick)
            self.stats.cg_iterations += count[0]
            self._stale = count[0] > CG_REFACTOR
            if info == 0:
                return y
        self._pre, self._stale = factorize(H, self.backend), False
        self.stats.factorizations += 1
        return self._pre.solve(g)

    # ------------------------------------------------------------------ one step
    def _advance(self, u, v, a, t0, t1):
        dt = self.dt
        if self.barrier is None:                        # linear backward Euler: one back-solve
            self._h = dt
            _, g = self._smooth(u, u, u + dt * v, self.external_force(t1))
            x = u - self._Sfac.solve(g)
            self.stats.newton += 1
        else:
            x = self._substeps(u, v, t0, t1, 0)[0]
        v1 = (x - u) / dt
        return x, v1, (v1 - v) / dt

    def _substeps(self, u, v, t0, t1, depth: int):
        """``(x, v)`` at ``t1`` from ``(u, v)`` at ``t0``: one Newton solve, or, when it does not
        converge, two half steps (at most ``MAX_HALVINGS`` times nested)."""
        from ..errors import InstabilityError

        try:
            x = self._newton(u, v, t1, t1 - t0)
        except _NotConverged as exc:
            if depth >= MAX_HALVINGS:
                m = self.model
                raise InstabilityError(
                    f"ipc: {exc} at step {self.n_steps + 1} (t = {t1:.6g} s), not even with the step cut to "
                    f"dt / {2 ** MAX_HALVINGS} = {(t1 - t0):.3g} s: raise max_newton (now {self.max_newton}), or "
                    f"check that the model is not far softer than meant for its size (E = "
                    f"{float(np.median(m.youngs)):.3g} Pa over {float(np.linalg.norm(np.ptp(m.nodes_m, axis=0))):.3g} "
                    f"m; a model in millimetres read as metres is 1000 times too large)") from None
            self.stats.halvings += 1
            tm = 0.5 * (t0 + t1)
            xm, vm = self._substeps(u, v, t0, tm, depth + 1)
            return self._substeps(xm, vm, tm, t1, depth + 1)
        return x, (x - u) / (t1 - t0)

    def _newton(self, u, v, t1, h):
        """Minimise the incremental potential of a step of length ``h`` from ``(u, v)``; returns ``x``.
        Raises ``_NotConverged``."""
        c = self.barrier
        self._h = h
        S, Sfac = self._level(h)
        if self._pre_h != h:
            self._pre, self._pre_h, self._stale = Sfac, h, False
        f = self.external_force(t1)
        ut = u + h * v
        x = u.copy()
        st0 = self._state_at(u)
        st = ContactState(x=x, V=st0.V, col=st0.col)
        if self._kappa is None or st.n_pairs:
            self._update_kappa(x, u, ut, f, st)
        fric = c.lagged_friction(st0, self._kphys())    # contacts and normal forces of x_n
        tol_x = self.tol * self._scale_x
        contact_seen = False
        prev_d = c.min_distance_sq(st)
        for it in range(self.max_newton):
            self.stats.newton += 1
            e_s, g = self._smooth(x, u, ut, f)
            quadratic = not st.n_pairs and fric is None
            if quadratic:
                p = -Sfac.solve(g)
            else:
                contact_seen = True
                g = g + self._contact(st, fric, st0, "g")
                p = -self._solve_contact((S + self._contact(st, fric, st0, "h")).tocsr(), g)
            if float(np.abs(p).max(initial=0.0)) <= tol_x:
                break
            alpha = min(1.0, c.stepsize(st, x + p))
            e0 = e_s + (self._contact(st, fric, st0, "e") if not quadratic else 0.0)
            gp = float(g @ p)
            while True:
                xt = x + alpha * p
                stt = c.state(xt)
                et = self._smooth(xt, u, ut, f)[0]
                if stt.n_pairs or fric is not None:
                    et += self._contact(stt, fric, st0, "e")
                if et <= e0 + 1e-4 * alpha * gp + 1e-12 * abs(e0) or alpha < 1e-12:
                    break
                alpha *= 0.5
                self.stats.line_search_cuts += 1
            if alpha < 1e-12:
                raise _NotConverged("the line search stalled")
            x, st = xt, stt
            if quadratic and alpha == 1.0 and not st.n_pairs:
                break                                   # the exact minimiser of the quadratic, still free
            if st.n_pairs:
                d = c.min_distance_sq(st)
                if np.isfinite(prev_d):
                    self._kappa = _ipctk().update_barrier_stiffness(prev_d, d, self._kappa_max, self._kappa,
                                                                    c.diag_m)
                prev_d = d
        else:
            raise _NotConverged(f"Newton did not converge in {self.max_newton} iterations")
        self.stats.contact_steps += int(contact_seen)
        self._last = st
        return x

    @property
    def max_contact_depth(self) -> float:
        """Barrier contact never lets a vertex through: always ``-inf`` (no penetration)."""
        return -np.inf

    @max_contact_depth.setter
    def max_contact_depth(self, value) -> None:       # the base class initialises it
        pass
