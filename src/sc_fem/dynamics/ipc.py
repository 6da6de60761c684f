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

CG_REFACTOR = 10
"""CG iterations after which a Newton step with contact factorizes its Hessian (and keeps the
factor as the preconditioner of the next ones)."""

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


class BarrierContact:
    """The collision mesh of a run: the source surface (moving with the lattice) and static obstacles.

    Parameters
    ----------
    model : CubeModel
    points : array_like, shape (n, 3)
        Source-mesh vertices at rest, model units.
    faces : array_like of int, shape (f, 3)
        Source-mesh triangles ((0, 3): the points collide as points).
    obstacles : sequence of Ground / Sphere / Box
        Static obstacles (may be empty when ``bodies`` has several objects).
    W : scipy.sparse matrix, shape (n, m), optional
        Embedding of ``points`` (computed if omitted).
    bodies : array_like of int, shape (n,), optional
        Object of every vertex (:func:`merge_scenes`); pairs of one object are not tested,
        pairs of different objects are. Default: one object.
    friction : float
        Coulomb coefficient ``mu`` (0: frictionless).
    dhat : float, optional
        Barrier activation distance, model units (default ``1e-3`` of the source's
        bounding-box diagonal). Bodies rest about ``dhat / 2`` above what they lie on.
    eps_v : float, optional
        Friction's static-dynamic transition speed, model units per second (default
        ``1e-3`` diagonals per second).

    Raises
    ------
    InputError
        An obstacle cuts the source mesh at rest (a ground that the mesh merely touches, or cuts
        by less than ``dhat``, is lowered to ``dhat`` below its lowest vertex instead and the
        shift is reported in ``ground_shift``), or objects overlap at rest.
    """

    def __init__(self, model: CubeModel, points, faces, obstacles=(), *, W=None, bodies=None,
                 friction: float = 0.0, dhat: float | None = None, eps_v: float | None = None) -> None:
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
        self.bodies = np.zeros(n, dtype=np.int32) if bodies is None else np.asarray(bodies, dtype=np.int32)
        if self.bodies.shape != (n,):
            raise InputError(f"bodies must have one entry per vertex ({n}), got shape {self.bodies.shape}")
        self.ground_shift = 0.0
        obstacles = tuple(self._placed(ob, pts) for ob in obstacles)
        self.obstacles = obstacles
        # static obstacle meshes after the moving vertices
        Vs, Fs, ids = [pts], [tri[np.ptp(pts[tri], axis=1).max(axis=1) > 0] if tri.size else tri], [self.bodies]
        off, nb = n, int(self.bodies.max()) + 1 if n else 1
        centre = 0.5 * (lo + hi)
        for k, ob in enumerate(obstacles):
            V, F = obstacle_mesh(ob, centre, size)
            Vs.append(V)
            Fs.append(F + off)
            ids.append(np.full(len(V), nb + k, dtype=np.int32))
            off += len(V)
        s = model.scale
        self.n_moving = n
        self.rest = _f(np.vstack(Vs) * s)                        # metres
        F = np.ascontiguousarray(np.vstack(Fs), dtype=np.int32).reshape(-1, 3)
        E = ipctk.edges(np.asfortranarray(F)) if len(F) else np.zeros((0, 2), dtype=np.int32)
        self.mesh = ipctk.CollisionMesh(self.rest, np.asfortranarray(E, dtype=np.int32), np.asfortranarray(F))
        self.mesh.can_collide = ipctk.make_static_obstacle_filter(n) & ipctk.make_vertex_patches_filter(
            np.concatenate(ids).astype(np.int32))
        self.W = (embed(model, pts) if W is None else sp.csr_matrix(W))
        if self.W.shape != (n, model.n_nodes):
            raise InputError(f"W must have shape ({n}, {model.n_nodes}), got {self.W.shape}")
        self.diag_m = size * s
        self.dhat_m = self.dhat * s
        self.eps_v_m = self.eps_v * s
        self._Phi = None
        if ipctk.has_intersections(self.mesh, self.rest):
            raise InputError("the objects (or an object and an obstacle) intersect at rest: move them apart")

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
        """Set the DOF map ``Phi`` (3n x free DOFs, metres per metre) for these free DOFs."""
        P = sp.kron(self.W, sp.identity(3, format="csr"), format="csr")
        self._Phi = P[:, free_dofs].tocsr()
        self._PhiT = self._Phi.T.tocsr()

    # ------------------------------------------------------------------ evaluation
    def vertices(self, x: np.ndarray) -> np.ndarray:
        """Collision-mesh vertices (k, 3), metres, for free-DOF displacements ``x`` (m)."""
        V = np.array(self.rest)
        V[: self.n_moving] += (self._Phi @ x).reshape(-1, 3)
        return np.asfortranarray(V)

    def collisions(self, V: np.ndarray):
        """The pairs closer than ``dhat`` at vertices ``V`` (an ``ipctk.NormalCollisions``)."""
        col = _ipctk().NormalCollisions()
        col.build(self.mesh, V, self.dhat_m)
        return col

    def to_dofs(self, g: np.ndarray) -> np.ndarray:
        """``Phi^T g`` of a collision-mesh gradient (3k,) -> free DOFs."""
        return self._PhiT @ g[: 3 * self.n_moving]

    def hessian_to_dofs(self, H) -> sp.csr_matrix:
        """``Phi^T H Phi`` of a collision-mesh Hessian (3k, 3k) -> free DOFs."""
        k = 3 * self.n_moving
        Hm = sp.csr_matrix(H)[:k, :k]
        return (self._PhiT @ Hm @ self._Phi).tocsr()

    def stepsize(self, V0: np.ndarray, V1: np.ndarray) -> float:
        """Largest ``alpha`` in [0, 1] with the straight path ``V0 -> V0 + alpha (V1 - V0)``
        intersection-free (CCD)."""
        return float(_ipctk().compute_collision_free_stepsize(self.mesh, V0, V1))

    def min_distance(self, V: np.ndarray, col=None) -> float:
        """Smallest distance (m) of a moving vertex to anything it may collide with, at most
        ``dhat`` (``inf`` when nothing is closer); ``col``: the collisions at ``V`` if known."""
        col = self.collisions(V) if col is None else col
        return float(np.sqrt(col.compute_minimum_distance(self.mesh, V))) if len(col) else np.inf


@dataclass
class _Step:
    """Counters of the Newton iterations of a run (``IPC.info``)."""

    newton: int = 0
    factorizations: int = 0
    contact_steps: int = 0
    line_search_cuts: int = 0
    cg_iterations: int = 0


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
        Newton iterations per step at most (default 60); a step that does not converge raises
        :class:`~sc_fem.errors.InstabilityError` naming ``dt``.
    """

    name = "ipc"
    implicit = True

    def __init__(self, model, dt, *, contact: BarrierContact | None = None, tol: float = 1e-5,
                 max_newton: int = 60, **kw) -> None:
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
        self._last = None             # (x, V, collisions) of the last state _advance returned
        super().__init__(model, dt, **kw)
        dt = self.dt
        a0, a1 = self.rayleigh
        self._C = None if not (a0 or a1) else (a0 * self.M + a1 * self.K).tocsr()
        self._S = ((1.0 / dt**2 + a0 / dt) * self.M + (1.0 + a1 / dt) * self.K).tocsr()
        self._Sfac = factorize(self._S, self.backend)
        self._pre = self._Sfac
        self.stats.factorizations += 1
        self._mass_avg = float(self.M.diagonal().mean()) if self.M.shape[0] else 1.0
        if contact is not None:
            contact.bind(self.asm.free_dofs)
            self._scale_x = contact.diag_m
        else:
            self._scale_x = float(np.linalg.norm(np.ptp(model.nodes_m, axis=0))) or 1.0

    # ------------------------------------------------------------------ energy of a state
    def contact_energy(self, x: np.ndarray) -> float:
        """Barrier energy ``kappa B`` (J) at free-DOF displacements ``x``."""
        c = self.barrier
        if c is None or self._kappa is None:
            return 0.0
        last = self._last
        if last is not None and last[0] is x:                 # the state _advance just made
            V, col = last[1], last[2]
        else:
            V = c.vertices(x)
            col = c.collisions(V)
        return float(self._B()(col, c.mesh, V)) if len(col) else 0.0

    def energy(self):
        from .base import Energy

        e = super().energy()
        return Energy(kinetic=e.kinetic, elastic=e.elastic, gravity=e.gravity, contact=self.contact_energy(self._u))

    @property
    def info(self) -> dict:
        s = self.stats
        return {"newton_iterations": s.newton, "factorizations": s.factorizations, "contact_steps": s.contact_steps,
                "line_search_cuts": s.line_search_cuts,
                "cg_iterations": s.cg_iterations,
                "dhat": None if self.barrier is None else self.barrier.dhat,
                "friction": None if self.barrier is None else self.barrier.friction,
                "ground_shift": None if self.barrier is None else self.barrier.ground_shift}

    # ------------------------------------------------------------------ the potential
    def _B(self):
        """The barrier potential with the current physical stiffness (N/m^... per ipctk's scaling)."""
        return _ipctk().BarrierPotential(self.barrier.dhat_m, self._kappa / self.dt**2)

    def _smooth(self, x, u, ut, f) -> tuple[float, np.ndarray]:
        """Energy and gradient of the terms without contact."""
        dt = self.dt
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

    def _contact_terms(self, x, V, col, fric, Vn, need: str):
        """Barrier + friction: energy, gradient or Hessian (``need``) in free DOFs."""
        ipctk = _ipctk()
        c = self.barrier
        B = self._B()
        dt = self.dt
        if need == "e":
            e = float(B(col, c.mesh, V)) if len(col) else 0.0
            if fric is not None:
                e += dt * float(fric[0](fric[1], c.mesh, _f((V - Vn) / dt)))
            return e
        if need == "g":
            g = c.to_dofs(B.gradient(col, c.mesh, V)) if len(col) else 0.0
            if fric is not None:
                g = g + c.to_dofs(fric[0].gradient(fric[1], c.mesh, _f((V - Vn) / dt)))
            return g
        H = c.hessian_to_dofs(B.hessian(col, c.mesh, V, ipctk.PSDProjectionMethod.CLAMP)) if len(col) else None
        if fric is not None:
            Hf = c.hessian_to_dofs(fric[0].hessian(fric[1], c.mesh, _f((V - Vn) / dt),
                                                   ipctk.PSDProjectionMethod.CLAMP)) / dt
            H = Hf if H is None else H + Hf
        return H

    def _update_kappa(self, x, u, ut, f, V, col) -> None:
        """IPC's adaptive barrier stiffness: set from the gradients at the step's start, never lowered."""
        ipctk = _ipctk()
        c = self.barrier
        dt2 = self.dt**2
        _, gE = self._smooth(x, u, ut, f)
        gB = c.to_dofs(ipctk.BarrierPotential(c.dhat_m, 1.0).gradient(col, c.mesh, V)) if len(col) else 0 * x
        k, kmax = ipctk.initial_barrier_stiffness(c.diag_m, ipctk.BarrierPotential(c.dhat_m, 1.0).barrier, c.dhat_m,
                                                  self._mass_avg, dt2 * gE, gB)
        self._kappa = max(k, self._kappa or 0.0)
        self._kappa_max = max(kmax, self._kappa_max or 0.0)

    def _solve_contact(self, H, g: np.ndarray) -> np.ndarray:
        """``H^-1 g`` for ``H = S + (contact Hessian)``: conjugate gradients preconditioned with the
        latest factorization (first ``S``'s, then that of an earlier Newton iteration's ``H``: while
        the contacts change little it preconditions well); ``H`` is factorized, and that factor kept,
        when CG needs more than ``CG_REFACTOR`` iterations."""
        from scipy.sparse.linalg import LinearOperator, cg

        count = [0]

        def tick(_):
            count[0] += 1

        pre = LinearOperator(H.shape, matvec=self._pre.solve, dtype=float)
        y, info = cg(H, g, rtol=CG_RTOL, atol=0.0, maxiter=CG_REFACTOR, M=pre, callback=tick)
        self.stats.cg_iterations += count[0]
        if info == 0:
            return y
        self._pre = factorize(H, self.backend)
        self.stats.factorizations += 1
        return self._pre.solve(g)

    # ------------------------------------------------------------------ one step
    def _advance(self, u, v, a, t0, t1):
        from ..errors import InstabilityError

        dt = self.dt
        f = self.external_force(t1)
        ut = u + dt * v
        c = self.barrier
        x = u.copy()
        if c is None:                                   # linear backward Euler: one back-solve
            _, g = self._smooth(x, u, ut, f)
            x = x - self._Sfac.solve(g)
            self.stats.newton += 1
            v1 = (x - u) / dt
            return x, v1, (v1 - v) / dt
        last = self._last
        if last is not None and last[0] is u:
            V, col = last[1], last[2]
        else:
            V = c.vertices(x)
            col = c.collisions(V)
        if self._kappa is None or len(col):
            self._update_kappa(x, u, ut, f, V, col)
        fric = None
        if c.friction > 0 and len(col):                  # lagged friction: contacts and forces of x_n
            ipctk = _ipctk()
            tc = ipctk.TangentialCollisions()
            tc.build(c.mesh, V, col, self._B(), c.friction)
            fric = (ipctk.FrictionPotential(c.eps_v_m), tc)
        Vn = V
        tol_x = self.tol * self._scale_x
        contact_seen = False
        prev_d = c.min_distance(V, col) ** 2 if len(col) else np.inf
        for it in range(self.max_newton):
            self.stats.newton += 1
            e_s, g = self._smooth(x, u, ut, f)
            quadratic = not len(col) and fric is None
            if quadratic:
                p = -self._Sfac.solve(g)
            else:
                contact_seen = True
                g = g + self._contact_terms(x, V, col, fric, Vn, "g")
                H = self._S + self._contact_terms(x, V, col, fric, Vn, "h")
                p = -self._solve_contact(H.tocsr(), g)
            if float(np.abs(p).max(initial=0.0)) <= tol_x:
                break
            V1 = c.vertices(x + p)
            alpha = min(1.0, c.stepsize(V, V1))
            e0 = e_s + (self._contact_terms(x, V, col, fric, Vn, "e") if not quadratic else 0.0)
            gp = float(g @ p)
            while True:
                xt = x + alpha * p
                Vt = c.vertices(xt)
                colt = c.collisions(Vt)
                et = self._smooth(xt, u, ut, f)[0]
                if len(colt) or fric is not None:
                    et += self._contact_terms(xt, Vt, colt, fric, Vn, "e")
                if et <= e0 + 1e-4 * alpha * gp + 1e-12 * abs(e0) or alpha < 1e-12:
                    break
                alpha *= 0.5
                self.stats.line_search_cuts += 1
            if alpha < 1e-12:
                raise InstabilityError(f"ipc: the line search stalled at step {self.n_steps + 1} "
                                       f"(t = {t1:.6g} s, dt = {dt:.4g} s); try a smaller dt")
            x, V, col = xt, Vt, colt
            if quadratic and alpha == 1.0 and not len(col):
                break                                   # the exact minimiser of the quadratic, still free
            if len(col):
                d = float(col.compute_minimum_distance(c.mesh, V))
                if np.isfinite(prev_d):
                    self._kappa = _ipctk().update_barrier_stiffness(prev_d, d, self._kappa_max, self._kappa,
                                                                    c.diag_m)
                prev_d = d
        else:
            raise InstabilityError(f"ipc: Newton did not converge in {self.max_newton} iterations at step "
                                   f"{self.n_steps + 1} (t = {t1:.6g} s, dt = {dt:.4g} s); try a smaller dt")
        self.stats.contact_steps += int(contact_seen)
        self._last = (x, V, col)
        v1 = (x - u) / dt
        return x, v1, (v1 - v) / dt

    @property
    def max_contact_depth(self) -> float:
        """Barrier contact never lets a vertex through: always ``-inf`` (no penetration)."""
        return -np.inf

    @max_contact_depth.setter
    def max_contact_depth(self, value) -> None:       # the base class initialises it
        pass
