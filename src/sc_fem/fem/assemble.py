"""Global stiffness and mass matrices of a :class:`~sc_fem.lattice.cubes.CubeModel`.

DOFs are node-major and interleaved: x, y, z of node ``i`` are DOFs ``3i, 3i+1, 3i+2``
(scikit-fem's ``ElementVector`` numbering). ``K`` is in N/m, ``M`` in kg, both
``scipy.sparse.csr_matrix``.

Two paths:

``method="fast"`` (default)
    Every cube's matrix is a scaled copy of unit-cube reference matrices
    (:mod:`sc_fem.fem.elements`), scattered into a CSR sparsity pattern that :class:`Assembler`
    builds **once** from the lattice structure (no sort of the element entries). Re-assembly
    with new per-cube materials or per-cube (e.g. rotated) element matrices only refills
    ``data``. Fixed DOFs are dropped while the pattern is built, so no slicing afterwards.
    The consistent ``M`` shares ``K``'s ``indptr``/``indices`` (so ``K - sigma M`` is a
    ``data`` operation).
``method="skfem"``
    The reference: scikit-fem ``MeshHex`` + ``ElementVector(ElementHex1())`` with per-element
    Lame parameters from :mod:`skfem.models.elasticity` (2x2x2 Gauss). Supports ``"q1"`` and
    ``"q1sri"``; the incompatible modes of ``"q1i"`` are not in scikit-fem.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .._validate import as_float_array, as_indices
from .elements import (CENTRE_RULE, DEFAULT_ELEMENT, check_element, cube_stiffness_chunks, moment_mass,
                       reference_mass, stiffness_chunks)
from ..errors import InputError
from ..lattice.cubes import HEX_CORNERS, CubeModel

_CHUNK = 2048
"""Cubes per scatter chunk (keeps the (chunk, 576) value block in cache)."""

# offset id (0..26) of corner b seen from corner a, shape (8, 8)
_PAIR_OFFSET = np.ravel_multi_index((HEX_CORNERS[None, :, :] - HEX_CORNERS[:, None, :] + 1).transpose(2, 0, 1),
                                    (3, 3, 3))


def _check_fixed(fixed_dofs, n_dofs: int) -> np.ndarray:
    if fixed_dofs is None:
        return np.zeros(0, dtype=np.int64)
    return np.unique(as_indices(fixed_dofs, n_dofs, "fixed_dofs", allow_mask=True))


def _per_cube(value, name: str, n: int, *, scalar: bool = True) -> np.ndarray:
    """A finite per-cube array of shape (n,); a scalar is repeated when ``scalar``."""
    arr = as_float_array(value, name)
    if scalar and arr.ndim == 0:
        return np.full(n, float(arr))
    if arr.shape != (n,):
        raise InputError(f"{name} must have shape ({n},){' or be a scalar' if scalar else ''}, got {arr.shape}")
    return arr


class Assembler:
    """Sparsity pattern of a lattice, built once; re-assembles ``K`` and ``M`` into it.

    Parameters
    ----------
    model : CubeModel
    element : {"q1", "q1i", "q1sri"}
        Element type (see :mod:`sc_fem.fem.elements`).
    fixed_dofs : array_like of int or bool mask (3m,), optional
        DOFs removed from the matrices (homogeneous Dirichlet condition). The returned
        matrices act on the free DOFs :attr:`free_dofs` only.

    Attributes
    ----------
    free_dofs : ndarray of int, shape (n_free,)
        Full DOF index of every row/column of the assembled matrices.
    fixed_dofs : ndarray of int
        The removed DOFs.
    shape : tuple
        ``(n_free, n_free)``.
    indptr, indices : ndarray of int32
        The CSR pattern shared by every matrix this assembler returns.
    """

    def __init__(self, model: CubeModel, element: str = DEFAULT_ELEMENT, *, fixed_dofs=None) -> None:
        if not isinstance(model, CubeModel):
            raise InputError(f"model must be a CubeModel, got {type(model).__name__}")
        self.model = model
        self.element = check_element(element)
        m = model.n_nodes
        self.fixed_dofs = _check_fixed(fixed_dofs, 3 * m)
        free = np.ones(3 * m, dtype=bool)
        free[self.fixed_dofs] = False
        self.free_dofs = np.flatnonzero(free)
        self._build(free)

    # ------------------------------------------------------------------ pattern
    def _build(self, free: np.ndarray) -> None:
        model = self.model
        hexes = model.hexes
        m = model.n_nodes
        # node blocks: node i couples with its lattice neighbour at offset o (27 offsets);
        # node numbers increase with the lattice linear index, so offset order = column order.
        present = np.zeros((m, 27), dtype=bool)
        present[hexes[:, :, None], _PAIR_OFFSET[None]] = True
        bid = np.cumsum(present.ravel()).reshape(m, 27) - 1            # block id, CSR order
        nnzb = int(present.sum())
        jb = np.empty(nnzb, dtype=np.int64)                           # column node of each block
        jb[bid[hexes[:, :, None], _PAIR_OFFSET[None]]] = np.broadcast_to(hexes[:, None, :], (len(hexes), 8, 8))
        blocks_per_row = present.sum(axis=1)
        ib = np.repeat(np.arange(m), blocks_per_row)                  # row node of each block

        free3 = free.reshape(m, 3)
        nfree = free3.sum(axis=1)                                     # free DOFs per node
        dloc = np.where(free3, np.cumsum(free3, axis=1) - 1, -1)      # rank of d among free DOFs
        width = nfree[jb]                                             # free columns per block
        cw = np.cumsum(width)
        row_first = np.concatenate([[0], np.cumsum(blocks_per_row)])[:-1]
        row_len = np.add.reduceat(width, row_first) if nnzb else np.zeros(m, dtype=np.int64)
        row_len = np.where(blocks_per_row > 0, row_len, 0)
        coloff = cw - width - (cw - width)[row_first][ib]              # offset of block within row
        red = np.cumsum(free) - 1                                     # reduced index of each DOF
        lengths = np.repeat(row_len, 3)[free]
        indptr = np.concatenate([[0], np.cumsum(lengths)])
        nnz = int(indptr[-1])
        rowstart = np.full(3 * m, -1, dtype=np.int64)
        rowstart[free] = indptr[:-1]
        self.nnz = nnz
        itype = np.int32 if max(nnz, 3 * m) < 2**31 - 1 else np.int64

        # column indices, block by block: (nnzb, 3 rows c, 3 cols d)
        pos_b = (rowstart.reshape(m, 3)[ib][:, :, None] + coloff[:, None, None]
                 + dloc[jb][:, None, :]).ravel()
        col_b = np.repeat(red.reshape(m, 3)[jb].astype(itype), 3, axis=0).ravel()
        indices = np.empty(nnz, dtype=itype)
        if free.all():
            indices[pos_b] = col_b
        else:
            ok = np.flatnonzero((free3[ib][:, :, None] & free3[jb][:, None, :]).ravel())
            indices[pos_b[ok]] = col_b[ok]
        self.indptr = indptr.astype(itype)
        self.indices = indices
        n_free = int(free.sum())
        self.shape = (n_free, n_free)

        # per-cube slot map: CSR position of each of the 576 entries, relative to the chunk's
        # lowest slot (chunks of consecutive cubes touch a contiguous range of rows); entries on
        # fixed DOFs go to a dummy slot one past the chunk's range.
        self._chunks: list[tuple[int, int, int, int, np.ndarray]] = []
        rs3 = rowstart.reshape(m, 3)
        row_end = np.full(3 * m, -1, dtype=np.int64)
        row_end[free] = indptr[1:]
        re3 = row_end.reshape(m, 3)
        all_free = bool(free.all())
        for s in range(0, len(hexes), _CHUNK):                        # loop over chunks
            hx = hexes[s:s + _CHUNK]
            nodes = np.unique(hx)
            fr = free3[nodes]
            if fr.any():   # the chunk's rows form a contiguous CSR range
                lo, hi = int(rs3[nodes][fr].min()), int(re3[nodes][fr].max())
            else:
                lo, hi = 0, 0
            span = hi - lo
            it = np.int32 if span < 2**31 - 2 else np.int64
            kb = bid[hx[:, :, None], _PAIR_OFFSET[None]]              # (c, 8, 8)
            rel = ((rs3[hx] - lo).astype(it)[:, :, :, None, None] + coloff[kb].astype(it)[:, :, None, :, None]
                   + dloc[hx].astype(it)[:, None, None, :, :])         # (c, 8a, 3c, 8b, 3d)
            if not all_free:
                valid = free3[hx][:, :, :, None, None] & free3[hx][:, None, None, :, :]
                rel[~valid] = span
            self._chunks.append((s, s + len(hx), lo, span, rel.reshape(len(hx), 576)))

    # ------------------------------------------------------------------ assembly
    def _scatter(self, values_of_chunk) -> sp.csr_matrix:
        data = np.zeros(self.nnz)
        for s, e, lo, span, rel in self._chunks:                     # loop over chunks
            vals = values_of_chunk(s, e)
            data[lo:lo + span] += np.bincount(rel.ravel(), weights=vals.ravel(), minlength=span + 1)[:span]
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape, copy=False)

    def stiffness(self, youngs=None, poisson=None, element_matrices=None) -> sp.csr_matrix:
        """Assemble ``K`` (N/m) on the stored pattern.

        Parameters
        ----------
        youngs, poisson : array_like, shape (n,) or scalar, optional
            Per-cube E (Pa) and nu; default: the model's.
        element_matrices : ndarray, shape (n, 24, 24), optional
            Full per-cube stiffness matrices in N/m (already including ``h`` and the
            material, e.g. corotated ``R K_e R^T``) in local DOF order ``3 a + c``.
            Overrides ``youngs``/``poisson`` and ``element``.

        Returns
        -------
        scipy.sparse.csr_matrix, shape :attr:`shape`
        """
        n = self.model.n_cubes
        if element_matrices is not None:
            if youngs is not None or poisson is not None:
                raise InputError("pass either element_matrices or youngs/poisson, not both")
            km = np.asarray(element_matrices, dtype=np.float64)
            if km.shape != (n, 24, 24):
                raise InputError(f"element_matrices must have shape ({n}, 24, 24), got {km.shape}")
            flat = km.reshape(n, 576)
            return self._scatter(lambda s, e: flat[s:e])
        from .material import lame

        h = self.model.h
        if youngs is None and poisson is None:
            # the model's partial-cube stiffness (finite-cell moments or fraction-scaled)
            return self._scatter(cube_stiffness_chunks(self.model, self.element))
        else:
            E = self.model.youngs if youngs is None else _per_cube(youngs, "youngs", n)
            nu = self.model.poisson if poisson is None else _per_cube(poisson, "poisson", n)
            lam, mu = lame(E, nu)
        h = self.model.h
        return self._scatter(stiffness_chunks(self.element, lam, mu, h))

    def mass(self, *, lumped: bool = False, masses=None) -> sp.csr_matrix:
        """Assemble ``M`` (kg).

        Parameters
        ----------
        lumped : bool
            ``False``: consistent mass (each cube ``m_e * reference_mass()``), on the same
            pattern as :meth:`stiffness`. ``True``: diagonal, each of a cube's 8 nodes gets
            ``m_e / 8`` in each direction.
        masses : array_like, shape (n,), optional
            Per-cube masses in kg; default ``model.mass`` (the voxelizer's sample mass).
        """
        n = self.model.n_cubes
        mass = self.model.mass if masses is None else _per_cube(masses, "masses", n, scalar=False)
        if lumped:
            nm = self.model.node_masses(mass)
            return sp.diags(np.repeat(nm, 3)[self.free_dofs]).tocsr()
        if self.model.stiffness == "moments":       # mass distributed like the filled region
            mom = self.model.moments
            return self._scatter(lambda s, e: moment_mass(mom[s:e], mass[s:e]))
        mref = reference_mass().ravel()
        return self._scatter(lambda s, e: mass[s:e, None] * mref[None, :])

    # ------------------------------------------------------------------ helpers
    def expand(self, u_free: np.ndarray) -> np.ndarray:
        """Full node field ``(m, 3)`` (or ``(m, 3, k)``) from a free-DOF vector, zeros on fixed DOFs."""
        u_free = np.asarray(u_free)
        out = np.zeros((3 * self.model.n_nodes,) + u_free.shape[1:], dtype=u_free.dtype)
        out[self.free_dofs] = u_free
        return out.reshape((self.model.n_nodes, 3) + u_free.shape[1:])

    def restrict(self, f_nodes: np.ndarray) -> np.ndarray:
        """Free-DOF vector from a node field of shape ``(m, 3)``."""
        f = np.asarray(f_nodes, dtype=float).reshape(3 * self.model.n_nodes, *np.shape(f_nodes)[2:])
        return f[self.free_dofs]


# ---------------------------------------------------------------------------------------- skfem
def _assemble_skfem(model: CubeModel, element: str, lumped: bool, free: np.ndarray):
    from skfem import Basis, BilinearForm, ElementHex1, ElementVector, asm
    from skfem.helpers import dot, trace
    from skfem.models.elasticity import linear_elasticity

    if element == "q1i":
        raise InputError("method='skfem' supports element 'q1' and 'q1sri' (scikit-fem has no incompatible "
                         "modes); use method='fast' for 'q1i'")
    mesh = model.to_skfem(metres=True)
    basis = Basis(mesh, ElementVector(ElementHex1()), intorder=3)
    lam, mu = model.lame()
    lam, mu = lam[:, None], mu[:, None]
    if element == "q1":
        K = asm(linear_elasticity(lam, mu), basis)
    else:
        @BilinearForm
        def volumetric(u, v, w):
            return (lam + 2.0 * mu / 3.0) * trace(u.grad) * trace(v.grad)

        @BilinearForm
        def deviatoric(u, v, w):
            return mu * (2.0 * _ddot_sym(u.grad, v.grad) - (2.0 / 3.0) * trace(u.grad) * trace(v.grad))

        one = Basis(mesh, ElementVector(ElementHex1()), quadrature=CENTRE_RULE)
        K = asm(volumetric, one) + asm(deviatoric, basis)
    rho = (model.mass / model.h**3)[:, None]

    @BilinearForm
    def mass_form(u, v, w):
        return rho * dot(u, v)

    M = asm(mass_form, basis)
    if lumped:
        M = sp.diags(np.asarray(M.sum(axis=1)).ravel())
    K, M = sp.csr_matrix(K), sp.csr_matrix(M)
    if not free.all():
        idx = np.flatnonzero(free)
        K, M = K[idx][:, idx], M[idx][:, idx]
    return K.tocsr(), M.tocsr()


def _ddot_sym(a, b):
    """sym(a) : sym(b) for gradient arrays of shape (3, 3, ...)."""
    return 0.5 * (np.einsum("ij...,ij...->...", a, b) + np.einsum("ij...,ji...->...", a, b))


def assemble(model: CubeModel, element: str = DEFAULT_ELEMENT, *, lumped: bool = False,
             fixed_dofs=None, method: str = "fast") -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """Stiffness and mass matrices of a cube lattice.

    Parameters
    ----------
    model : CubeModel
        The lattice (edge ``model.h`` m, per-cube E, nu, and sample mass ``model.mass`` kg).
    element : {"q1i", "q1", "q1sri"}
        Element type; ``"q1i"`` (incompatible modes, locking-free in bending) by default.
    lumped : bool
        Lumped (diagonal, ``m_e / 8`` per node and direction) instead of consistent mass.
    fixed_dofs : array_like of int or bool mask (3m,), optional
        DOFs to remove (dropped during the scatter; matrices are on the free DOFs in
        increasing order).
    method : {"fast", "skfem"}
        Reference-matrix scatter (default) or scikit-fem's generic assembly (reference).

    Returns
    -------
    K : scipy.sparse.csr_matrix, shape (n_free, n_free)
        Stiffness, N/m.
    M : scipy.sparse.csr_matrix, shape (n_free, n_free)
        Mass, kg.
    """
    element = check_element(element)
    if method == "fast":
        asm_ = Assembler(model, element, fixed_dofs=fixed_dofs)
        return asm_.stiffness(), asm_.mass(lumped=lumped)
    if method == "skfem":
        if not isinstance(model, CubeModel):
            raise InputError(f"model must be a CubeModel, got {type(model).__name__}")
        fixed = _check_fixed(fixed_dofs, model.n_dofs)
        free = np.ones(model.n_dofs, dtype=bool)
        free[fixed] = False
        return _assemble_skfem(model, element, lumped, free)
    raise InputError(f"method must be 'fast' or 'skfem', got {method!r}")
