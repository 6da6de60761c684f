"""The barrier contact of a run (:class:`BarrierContact`): the source surface moving with the lattice,
static obstacles and the lattice's outer surface for self-contact, as IPC Toolkit collision meshes
(:mod:`.collision`), with their log barrier, lagged smooth Coulomb friction and continuous collision
detection, evaluated in the free DOFs of the integrator :class:`~sc_fem.dynamics.ipc.IPC`.

Pairs within one body of the source mesh are not tested (its parts may intersect at rest: the
chair's legs pass through its seat; the lattice holds them together); pairs of different bodies
(objects in one scene) and source-obstacle pairs are.

Units: the collision meshes are in metres (``rest * scale``); ``dhat`` is given in model units.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._validate import as_points, positive_scalar
from ..errors import InputError
from ..lattice.cubes import CubeModel
from ..lattice.embed import embed
from .collision import (CollisionLayer, ContactState, fortran, lattice_surface, node_bodies, obstacle_mesh,
                        require_ipctk)
from .contact import Ground

DHAT_FRACTION = 1e-3
"""Default barrier activation distance as a fraction of the source mesh's bounding-box diagonal."""

CCD_TOLERANCE = 1e-4
"""Tight Inclusion CCD's tolerance (its default 1e-6 took up to 3.3 s for one step of the chair's
legs landing together, against 4 ms at 1e-4 with the same step, 0.25 instead of 0.2527: the
answer stays conservative, only a little shorter)."""

CCD_MAX_ITERATIONS = 100_000
"""Tight Inclusion CCD's iteration cap (on reaching it, it returns a conservative step)."""


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
        ipctk = require_ipctk()
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
        layers = [CollisionLayer(np.vstack(Vs) * s, np.vstack(Fs), static & patches, sp.kron(self.W, eye, format="csr"),
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
            layers.append(CollisionLayer(model.nodes_m[used], inv.reshape(-1, 3), ~other_bodies, sp.kron(sel, eye, format="csr"),
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
        ipctk = require_ipctk()
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
        ipctk = require_ipctk()
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
        ipctk = require_ipctk()
        D = ipctk.FrictionPotential(self.eps_v_m)
        out = 0.0 if need != "h" else None
        for L, V, V0, tc in zip(self.layers, st.V, st0.V, fric):
            if not len(tc):
                continue
            vel = fortran((V - V0) / dt)
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
        ipctk = require_ipctk()
        ccd = ipctk.TightInclusionCCD(CCD_TOLERANCE, CCD_MAX_ITERATIONS)
        return min(float(ipctk.compute_collision_free_stepsize(L.mesh, V, L.vertices(x1), narrow_phase_ccd=ccd))
                   for L, V in zip(self.layers, st.V))

    def min_distance_sq(self, st: ContactState) -> float:
        """Smallest squared distance (m^2) of any close pair at ``st`` (``inf`` with none)."""
        d = [float(col.compute_minimum_distance(L.mesh, V)) for L, V, col in zip(self.layers, st.V, st.col)
             if len(col)]
        return min(d) if d else np.inf
