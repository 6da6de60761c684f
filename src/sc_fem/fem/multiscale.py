"""Multiscale cubes: a partly filled cube's stiffness and mass condensed from a fine model of what it holds.

A degree-``p`` field per cube (:mod:`sc_fem.fem.highorder`) integrated over a partly filled cube
still moves everything inside the cube with one polynomial. A cube that holds the web and a
flange of an I-section (or the slats of a chair) needs each wall to bend, shear through its
thickness and warp on its own, which no polynomial of a cube does well at coarse resolutions
(``q3`` at 16 cubes: 21 % on an I-section beam). The multiscale finite element method gives the
cube the behaviour of a fine model of its content instead:

* the **fine model**: the source mesh voxelized ``s`` times finer (trilinear cubes with
  incompatible modes and moment-integrated partial cubes, :mod:`sc_fem.fem.elements`), one copy
  of it per coarse cube (fine nodes are keyed by coarse cube, so the coarse cubes' fine models
  share no node);
* **tied nodes**: a fine node on a face, edge or corner that its coarse cube shares with another
  cube of the same body holding material there follows the coarse degree-``p`` field (the cube's
  Lagrange nodes); so does every node of a fine piece that touches no such face (it would float);
* **free nodes**: every other fine node (the walls' interiors and their outer surfaces) takes the
  fine model's static response to the tied ones: ``u_f = -K_ff^-1 K_ft u_t``.

The cube's matrices are then the Schur complement ``K_c = P^T (K_tt - K_tf K_ff^-1 K_ft) P`` and the
consistent mass ``M_c = Phi^T M_f Phi`` of the shape functions ``Phi = [P; -K_ff^-1 K_ft P]``
(``P``: the coarse field at the tied nodes). They are exact for every field the fine model
represents exactly (rigid motions and linear fields: the patch test holds) and, since the
walls only meet the polynomial where cubes meet, an open section warps as its fine model does.
The source mesh's vertices in such a cube follow its fine field (:meth:`Condensation.point_map`).

Every coarse cube is condensed at once: the fine models of all cubes form one block-diagonal
system (one sparse factorization), solved for all cubes' ``j``-th coarse DOF together (the
blocks do not overlap), in chunks of :data:`CHUNK` columns -- no loop over cubes.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.spatial import cKDTree

from .._memory import available_memory
from ..errors import InputError
from ..lattice.cubes import CubeModel
from ..lattice.grid import estimate_bytes
from ..lattice.options import DEFAULT_SUBSAMPLES
from ..lattice.topology import HEX_CORNERS
from ..lattice.walls import shell_thickness, thinnest_walls
from .finemodel import FineSystem, fine_system
from .lagrange import shape_functions
from .linsolve import factorize

CHUNK = 64
"""Coarse DOFs (columns of the shape functions) solved for at a time (memory: fine DOFs x CHUNK floats)."""

REGULARIZE = 1e-8
"""Each free fine DOF is tied to the coarse field by a spring of this fraction of its own stiffness
(``K_ff`` stays invertible where a fine cube hangs on the rest by one edge). The spring is stretched
only by what the coarse field and the fine motion differ in: rigid motions and linear fields are
untouched, the rest changes by about this fraction."""

FINE_PER_WALL = 1.6
"""The automatic refinement puts a fine cube edge of about the thin walls' thickness / this
(:func:`choose_refine`): on the I-section (walls 5-8 mm) 1.6 gives 16 fine cubes per cube edge at
resolution 16, the fine model (trilinear cubes at 256) then within 1-1.5 % of the conforming reference."""

FINE_PER_SHELL = 1.0
"""For a model of shells alone (open sheets), a fine cube edge of at least the shell's thickness /
this: a shell is one layer of fine cubes holding its mass (its filled fraction the shell's thickness
over the fine cube's), so a fine cube thinner than the shell makes it too thin and soft and a thicker
one a little stiff (a 1 m, 10 mm sheet at 8 cubes against Kirchhoff's free plate: fine cubes of
6.3 mm 0.62x, of 9.6 mm 0.96x, of 10.4 mm (this) 1.04x, of 12.5 mm 1.13x; a 15 mm sheet 1.04x; a
4 mm one 1.30x, its fine cubes held at 5.2 mm by :data:`MAX_REFINE`)."""

MAX_REFINE = 24
"""The most fine cubes per cube edge the automatic refinement takes."""

FINE_BUDGET = 600_000
"""The automatic refinement keeps the fine model (every fine cube of the source, its full cubes
included) under about this many fine cubes."""

FINE_SPACING = 0.25
"""Surface samples of the fine model this fraction of a fine cube apart (the voxelizer's default
is 1/8: a closed part's cubes and moments come from its surface integrals and do not change)."""



def choose_refine(model: CubeModel, vertices: np.ndarray, faces: np.ndarray,
                  max_memory: float | None = None) -> tuple[int, float]:
    """Fine cubes per cube edge for the multiscale cubes of ``model``: a fine cube edge of about the
    thin walls' thickness / :data:`FINE_PER_WALL`, at least 2 and at most :data:`MAX_REFINE`, the
    fine model under :data:`FINE_BUDGET` fine cubes and its voxelization (surface samples
    :data:`FINE_SPACING` of a fine cube apart) within ``max_memory``. A model of shells alone takes
    a fine cube edge of the shell's thickness / :data:`FINE_PER_SHELL` instead.

    Parameters
    ----------
    model : CubeModel
        The coarse lattice.
    vertices, faces : ndarray
        Its source surface (model units).
    max_memory : float, optional
        Bytes the fine voxelization may take (default half the available memory).

    Returns
    -------
    refine : int
    thickness : float
        The walls' thickness it was chosen for (:func:`sc_fem.lattice.walls.thinnest_walls`), model
        units; ``inf`` without partly filled cubes.
    """
    wall = thinnest_walls(model, vertices, faces)
    if not np.isfinite(wall):
        return 2, wall
    per = model.pitch / max(wall, 1e-12 * model.pitch)
    if shell_thickness(model) is None:
        s = int(np.clip(np.ceil(FINE_PER_WALL * per), 2, MAX_REFINE))
    else:                                     # fine cubes no thinner than the shell they hold
        s = int(np.clip(np.floor(FINE_PER_SHELL * per), 2, MAX_REFINE))
    filled = float(np.sum(model.fraction))                     # in cubes
    tri = np.asarray(vertices, dtype=float)[np.asarray(faces, dtype=np.int64)]
    surface = 0.5 * float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()) \
        / model.pitch**2                                       # in cube faces
    budget = 0.5 * available_memory() if max_memory is None else float(max_memory)
    subsamples = int(model.info.get("subsamples", DEFAULT_SUBSAMPLES))

    def fits(s: int) -> bool:
        return (filled * s**3 + surface * s**2 <= FINE_BUDGET
                and estimate_bytes(vertices, faces, model.dims * s, FINE_SPACING * model.pitch / s, subsamples) <= budget)

    while s > 2 and not fits(s):
        s -= 1
    return s, wall


def _field(p: int, s: int, nb: int, n: int, node_q: np.ndarray, node_cube: np.ndarray, dofs: np.ndarray):
    """The coarse degree-``p`` field at fine ``dofs``: the basis values (len(dofs), nb), the block
    matrix (len(dofs), 3 n nb) with column ``(cube, 3 j + c)``, and each DOF's component."""
    node, comp = dofs // 3, dofs % 3
    N = shape_functions(p, node_q[node] / s)[0]
    r, j = np.nonzero(np.abs(N) > 1e-14)
    block = sp.csr_matrix((N[r, j], (r, node_cube[node[r]] * 3 * nb + 3 * j + comp[r])), shape=(len(dofs), 3 * n * nb))
    return N, block, comp


class Condensation:
    """The coarse ``cubes`` of degree ``p`` condensed from their fine models (:func:`fine_system`):
    set up once (the fine models and the factorization of their free DOFs), then :meth:`matrices`
    and :meth:`point_map`.

    Parameters
    ----------
    coarse : CubeModel
        The coarse lattice.
    cubes : ndarray of int, shape (n,)
        The coarse cubes to condense, sorted (partly filled ones).
    fine : CubeModel
        The same source voxelized with ``coarse.pitch / s`` from the same origin and topology.
    s : int
        Fine cubes per coarse cube edge.
    p : int
        Degree of the coarse field.
    element : str
        The fine cubes' element (:data:`sc_fem.fem.elements.ELEMENTS`).
    held : ndarray of bool, shape (m,), optional
        The coarse model's fixed nodes (:func:`fine_system`).
    backend : str
        Factorization backend of the fine models (:func:`sc_fem.fem.linsolve.factorize`).

    Attributes
    ----------
    fine : FineSystem
    """

    def __init__(self, coarse: CubeModel, cubes: np.ndarray, fine: CubeModel, s: int, p: int, *,
                 element: str = "q1i", held: np.ndarray | None = None, backend: str = "auto") -> None:
        self.coarse, self.cubes, self.s, self.p = coarse, np.asarray(cubes, dtype=np.int64), s, p
        self.fine = fs = fine_system(coarse, self.cubes, fine, s, element, held)
        self.nb = nb = (p + 1) ** 3
        self._t = np.flatnonzero(np.repeat(fs.tied, 3))
        self._f = np.flatnonzero(~np.repeat(fs.tied, 3))
        # P (Q): the coarse field at the tied (free) DOFs, stacked over the cubes; column (cube, 3 j + c)
        self._N, self._P, self._comp = _field(p, s, nb, fs.n, fs.node_q, fs.node_cube, self._t)
        self._Nf, self._Q, self._fcomp = _field(p, s, nb, fs.n, fs.node_q, fs.node_cube, self._f)
        t, f = self._t, self._f
        K = fs.K
        self._Ktt, self._Ktf = K[t][:, t], K[t][:, f]
        d = K[f][:, f].diagonal()
        self._D = sp.diags(REGULARIZE * np.where(d > 0, d, d.max(initial=1.0)))   # ties the free DOFs to the field, weakly
        self._fac = factorize((K[f][:, f] + self._D).tocsc(), backend) if len(f) else None

    def _columns(self, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For the local coarse DOFs ``cols``, all cubes stacked (their fine models do not overlap):
        the coarse field at the tied DOFs ``Pt`` and at the free ones ``Qt``, and the free DOFs'
        static response ``X`` (the penalty term vanishes on the fine model's exact fields)."""
        Pt = self._N[:, cols // 3] * (self._comp[:, None] == cols[None, :] % 3)          # (t, |K|)
        Qt = self._Nf[:, cols // 3] * (self._fcomp[:, None] == cols[None, :] % 3)        # (f, |K|)
        X = (-self._fac.solve(np.asarray(self._Ktf.T @ Pt - self._D @ Qt)) if self._fac is not None
             else np.zeros((0, len(cols))))
        return Pt, Qt, X

    def matrices(self, points: np.ndarray | None = None, point_cube: np.ndarray | None = None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Stiffness ``P^T (K_tt - K_tf K_ff^-1 K_ft) P`` (N/m) and mass ``Phi^T M Phi`` (kg) of every
        cube, each (n, 3 nb, 3 nb), DOF ``3 node + c``, and the map of ``points`` in the same
        solves (:meth:`point_map`; (0, 3, 3 nb) without points)."""
        return self._sweep(points, point_cube, True)

    def point_map(self, points: np.ndarray, point_cube: np.ndarray) -> np.ndarray:
        """How points inside the condensed cubes move: their fine model's field there.

        Parameters
        ----------
        points : ndarray, shape (k, 3)
            Positions, model units.
        point_cube : ndarray of int, shape (k,)
            The coarse cube of each (an index into the coarse model; each one of ``cubes``).

        Returns
        -------
        ndarray, shape (k, 3, 3 nb)
            Displacement of each point (3 components) per coarse DOF of its cube (the fine models
            solved once more; :meth:`matrices` maps points in its own solves).
        """
        return self._sweep(points, point_cube, False)[2]

    def _sweep(self, points, point_cube, matrices: bool):
        """The solves of :data:`CHUNK` coarse DOFs at a time: the cubes' matrices (if ``matrices``)
        and the shape functions at the fine nodes around ``points``."""
        fs, n, nb = self.fine, self.fine.n, self.nb
        t, f = self._t, self._f
        Mtt, Mtf, Mff = fs.M[t][:, t], fs.M[t][:, f], fs.M[f][:, f]
        Ktt, Ktf, P, Q, D = self._Ktt, self._Ktf, self._P, self._Q, self._D
        w, rows = _points(self.coarse, self.cubes, fs, self.s, points, point_cube)
        need = np.unique(rows)
        dof = (3 * need[:, None] + np.arange(3)).ravel()
        tpos, fpos = np.full(3 * len(fs.tied), -1, dtype=np.int64), np.full(3 * len(fs.tied), -1, dtype=np.int64)
        tpos[t], fpos[f] = np.arange(len(t)), np.arange(len(f))
        t_at, f_at = tpos[dof], fpos[dof]
        phi = np.zeros((len(dof), 3 * nb))                                   # shape functions at those nodes
        Kst = np.zeros((n, 3 * nb, 3 * nb)) if matrices else None
        Mst = np.zeros((n, 3 * nb, 3 * nb)) if matrices else None
        for c0 in range(0, 3 * nb, CHUNK):                                   # chunks of local coarse DOFs
            cols = np.arange(c0, min(c0 + CHUNK, 3 * nb))
            Pt, Qt, X = self._columns(cols)
            phi[t_at >= 0, c0:c0 + len(cols)] = Pt[t_at[t_at >= 0]]
            phi[f_at >= 0, c0:c0 + len(cols)] = X[f_at[f_at >= 0]]
            if not matrices:
                continue
            kc, mc = P.T @ (Ktt @ Pt), P.T @ (Mtt @ Pt)
            if self._fac is not None:
                kc = kc + P.T @ (Ktf @ X) + Q.T @ (D @ (Qt - X))
                Zf = self._fac.solve(np.asarray(Mtf.T @ Pt + Mff @ X))       # K_ff^-1 (M Phi)_f
                mc = mc + P.T @ (Mtf @ X - Ktf @ Zf) + Q.T @ (D @ Zf)
            Kst[:, :, cols] = np.asarray(kc).reshape(n, 3 * nb, len(cols))
            Mst[:, :, cols] = np.asarray(mc).reshape(n, 3 * nb, len(cols))
        pmap = np.einsum("kc,kcdj->kdj", w, phi.reshape(len(need), 3, 3 * nb)[np.searchsorted(need, rows)])
        if not matrices:
            return None, None, pmap
        slot = fs.slot
        return 0.5 * (Kst + Kst.transpose(0, 2, 1))[slot], 0.5 * (Mst + Mst.transpose(0, 2, 1))[slot], pmap


def _points(coarse: CubeModel, cubes: np.ndarray, fs: FineSystem, s: int, points, point_cube):
    """For each point: the trilinear weights (k, 8) in the fine cube holding it (in the fine model
    of its cube's content; the nearest fine cube of that content when the point lies just outside
    them) and that fine cube's nodes (k, 8)."""
    if points is None or not len(points):
        return np.zeros((0, 8)), np.zeros((0, 8), dtype=np.int64)
    pos = np.full(coarse.n_cubes, -1, dtype=np.int64)
    pos[cubes] = np.arange(len(cubes))
    pcube = pos[np.asarray(point_cube, dtype=np.int64)]
    if np.any(pcube < 0):
        raise InputError("every point must lie in one of the condensed cubes")
    xi = (np.asarray(points, float) - coarse.origin) / coarse.pitch - coarse.cells[cubes[pcube]]
    pslot = fs.slot[pcube]
    xf = np.clip(xi, 0.0, 1.0) * s
    cell = np.minimum(np.floor(xf).astype(np.int64), s - 1)
    fkey = fs.fine_cube * s**3 + np.ravel_multi_index(fs.fine_local.T, (s,) * 3)
    order = np.argsort(fkey)
    want = pslot * s**3 + np.ravel_multi_index(cell.T, (s,) * 3)
    fcube = order[np.minimum(np.searchsorted(fkey[order], want), len(order) - 1)]
    miss = fkey[fcube] != want
    if np.any(miss):                                    # just outside its content's fine cubes: the nearest
        far = 4.0 * s                                   # keeps the search inside one content
        tree = cKDTree(np.c_[fs.fine_local + 0.5, far * fs.fine_cube])
        _, fcube[miss] = tree.query(np.c_[xf[miss], far * pslot[miss]])
    loc = np.clip(xf - fs.fine_local[fcube], 0.0, 1.0)
    w = np.prod(np.where(HEX_CORNERS[None] == 1, loc[:, None, :], 1.0 - loc[:, None, :]), axis=2)
    return w, fs.hexes[fcube]
