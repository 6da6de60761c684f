"""Global stiffness and mass matrices of a :class:`~sc_fem.lattice.cubes.CubeModel`.

DOFs are node-major and interleaved: x, y, z of node ``i`` are DOFs ``3i, 3i+1, 3i+2``
(scikit-fem's ``ElementVector`` numbering). ``K`` is in N/m, ``M`` in kg, both
``scipy.sparse.csr_matrix``.

Two paths:

``method="fast"`` (default)
    Every cube's matrix is a scaled copy of unit-cube reference matrices
    (:mod:`sc_fem.fem.elements`), scattered into a CSR sparsity pattern that :class:`Assembler`
    builds **once** from the lattice structure: row ``(i, c)`` holds the free DOFs of the nodes
    of node ``i``'s 27-node stencil that share a cube with it, so ``indptr``/``indices`` are
    written directly (node chunk by node chunk, no COO pass, no sort). Re-assembly with new
    per-cube materials or per-cube (e.g. rotated) element matrices only refills ``data``,
    chunk by chunk of cubes: the CSR position of each element entry is computed on the fly from
    small per-node tables (row starts, the offset of each of the 27 neighbour blocks in a row),
    so no per-entry slot map is stored (it would take 2.3 KB per cube) unless asked for
    (``cache_slots``). With numba installed a compiled kernel (:mod:`sc_fem.fem.assemble_jit`)
    adds every chunk's entries into ``data`` computing each position inline (no position array,
    no ``np.add.at``; ``kernel=``). Fixed DOFs are dropped while the pattern is built, so no slicing
    afterwards. The consistent ``M`` shares ``K``'s ``indptr``/``indices`` (``K - sigma M`` is a
    ``data`` operation) or keeps its nonzeros alone (``compact=True``, :mod:`sc_fem.fem.nodemass`).
    Memory is the output's: ``indices`` (4 bytes per nonzero) once, ``data`` (8 bytes per nonzero)
    per matrix, about 50 bytes per node (:meth:`Assembler.release` drops the pattern).
``method="skfem"``
    The reference: scikit-fem ``MeshHex`` + ``ElementVector(ElementHex1())`` with per-element
    Lame parameters from :mod:`skfem.models.elasticity` (2x2x2 Gauss). Supports ``"q1"`` and
    ``"q1sri"``; the incompatible modes of ``"q1i"`` are not in scikit-fem.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from .._jit import choose_kernel
from .._progress import stage_bar
from .._validate import as_float_array, as_indices
from .generic import assemble_skfem
from .nodemass import compact_mass
from .shift import without_zeros
from .elements import (DEFAULT_ELEMENT, check_element, cube_mass_chunks, cube_stiffness_chunks,
                       stiffness_chunks)
from ..errors import InputError
from ..lattice.cubes import HEX_CORNERS, CubeModel
from ..material import lame

_CHUNK = 2048
"""Cubes per scatter chunk (keeps the (chunk, 576) value and slot blocks in cache)."""

_AUTO_CACHE_BYTES = 2**28
"""``cache_slots=None`` keeps the slots of re-fills up to this size (256 MiB, ~116,000 cubes)."""

_NODE_CHUNK = 8192
"""Nodes per chunk while the column indices are written."""

_PATTERN = ("indptr", "indices", "nnz", "_rowstart", "_coloff", "_free3", "_all_free", "_interior", "_dloc")
"""The attributes :meth:`Assembler._build` sets, which :meth:`Assembler.release` drops."""

# offset id (0..26) of corner b seen from corner a, shape (8, 8)
_PAIR_OFFSET = np.ascontiguousarray(np.ravel_multi_index(
    (HEX_CORNERS[None, :, :] - HEX_CORNERS[:, None, :] + 1).transpose(2, 0, 1), (3, 3, 3)))
_D_PATTERN = np.tile(np.arange(3, dtype=np.int32), 192)
"""Column component d of each of a cube's 576 entries (a, c, b, d)."""
_INTERIOR = (81 * np.arange(3)[None, :, None, None] + 3 * _PAIR_OFFSET[:, None, :, None]
             + np.arange(3)[None, None, None, :]).reshape(8, 72).astype(np.int32)
"""Position of entry (a, c, b, d) relative to the start of row (node a, 0) when node a's rows hold
all 27 neighbours with 3 free DOFs each (81 columns; block o at column 3 o)."""


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
    cache_slots : bool or None
        Keep the CSR position of every element entry after a fill (4 bytes per entry, 2.3 KB per
        cube), so later fills skip computing them (about 20-30 % of a fill). ``True``: after the
        first fill; ``False``: never; ``None`` (default): after the first re-fill from
        ``element_matrices`` (the repeated path, e.g. every step of a corotational integrator)
        when the positions take at most 256 MiB (about 116,000 cubes).
    kernel : {"auto", "numba", "numpy"}
        How each chunk of element entries is summed into the CSR ``data``: ``"numba"``, a compiled
        loop (:mod:`sc_fem.fem.assemble_jit`, needs numba) that computes every entry's position
        inline from the per-node tables (no per-chunk position array, no ``np.add.at``; the
        scatter of 296,000 cubes took 0.15 s instead of 0.5 s); ``"numpy"``, the vectorized
        positions and ``np.add.at``; ``"auto"`` (default): ``"numba"`` when numba is installed.
        Both add the same entries in the same order, so the matrices are identical. With cached
        positions (``cache_slots``) the compiled kernel does only the ``add.at``.

    Attributes
    ----------
    free_dofs : ndarray of int, shape (n_free,)
        Full DOF index of every row/column of the assembled matrices.
    fixed_dofs : ndarray of int
        The removed DOFs.
    shape : tuple
        ``(n_free, n_free)``.
    indptr, indices : ndarray of int32
        The CSR pattern shared by every matrix this assembler returns (int64 beyond 2**31 - 1
        nonzeros).
    nnz : int
        Number of stored entries.
    kernel : {"numba", "numpy"}
        The scatter in use (see ``kernel`` above).

    Raises
    ------
    InputError
        For an unknown ``kernel``, or ``kernel="numba"`` without numba.

    Notes
    -----
    Node numbers must increase with the nodes' lattice linear index (as
    :class:`~sc_fem.lattice.cubes.CubeModel` numbers them), so that the 27 stencil offsets in
    order are the columns in increasing order.
    """

    def __init__(self, model: CubeModel, element: str = DEFAULT_ELEMENT, *, fixed_dofs: ArrayLike | None = None,
                 cache_slots: bool | None = None, kernel: str = "auto") -> None:
        if not isinstance(model, CubeModel):
            raise InputError(f"model must be a CubeModel, got {type(model).__name__}")
        self.kernel = choose_kernel(kernel)
        self.model = model
        self.element = check_element(element)
        m = model.n_nodes
        self.fixed_dofs = _check_fixed(fixed_dofs, 3 * m)
        free = np.ones(3 * m, dtype=bool)
        free[self.fixed_dofs] = False
        self.free_dofs = np.flatnonzero(free)
        self._build(free)
        if cache_slots is None:
            cache_slots = None if 2304 * model.n_cubes <= _AUTO_CACHE_BYTES else False
        self._cache_all = bool(cache_slots)          # True: every fill; None: re-fills only
        self._cache: dict[tuple[int, int], tuple[np.ndarray, np.ndarray | None]] | None = (
            None if cache_slots is False else {})

    def release(self) -> None:
        """Drop the pattern, its per-node tables (``indices``: ~320 bytes per DOF of a solid lattice)
        and cached positions; :meth:`expand`, :meth:`restrict` need none, the next fill rebuilds them."""
        for name in _PATTERN:
            self.__dict__.pop(name, None)
        if self._cache is not None:
            self._cache = {}

    def __getattr__(self, name: str):
        """The pattern's arrays, built again after :meth:`release`."""
        if name in _PATTERN and "free_dofs" in self.__dict__:
            self._build(np.isin(np.arange(3 * self.model.n_nodes), self.free_dofs))
            return self.__dict__[name]
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    # ------------------------------------------------------------------ pattern
    def _build(self, free: np.ndarray) -> None:
        """CSR pattern from the 27-node stencil of the lattice, and the small per-node tables
        :meth:`_slots` computes every chunk's CSR positions from (no per-entry slot map)."""
        model = self.model
        hexes = model.hexes
        m = model.n_nodes
        free3 = free.reshape(m, 3)
        nfree = free3.sum(axis=1).astype(np.uint8)                    # free DOFs per node
        n_free = int(free.sum())
        # nbr[i, o]: the node at lattice offset o (0..26) of node i if a cube holds both, else -1.
        # Node numbers increase with the lattice linear index, so offset order = column order.
        nt = np.int32 if m < 2**31 - 1 else np.int64
        nbr = np.full((m, 27), -1, dtype=nt)
        hx = hexes.astype(nt)
        for a in range(8):                                            # the 8 corners of a cube
            nbr[hexes[:, a, None], _PAIR_OFFSET[a]] = hx
        present = nbr >= 0
        width = np.where(present, nfree[nbr], np.uint8(0))            # free columns per node block
        coloff = np.cumsum(width, axis=1, dtype=np.uint8)             # <= 81 columns per row
        row_len = coloff[:, -1].astype(np.int64)
        coloff -= width                                               # offset of block o within its row
        del width
        lengths = np.repeat(row_len, 3)[free]
        nnz = int(lengths.sum())
        itype = np.int32 if max(nnz, n_free) < 2**31 - 1 else np.int64
        indptr = np.zeros(n_free + 1, dtype=itype)
        np.cumsum(lengths, dtype=itype, out=indptr[1:])
        del lengths
        rowstart = np.zeros(3 * m, dtype=itype)
        rowstart[free] = indptr[:-1]
        # per node, padded to 4 (a 4-byte gather) with a last all-fixed row that nbr = -1 selects:
        # which DOFs are free, and their reduced indices
        free4 = np.zeros((m + 1, 4), dtype=bool)
        free4[:m, :3] = free3
        red4 = np.zeros((m + 1, 4), dtype=itype)
        red4[:m, :3] = (np.cumsum(free, dtype=itype) - 1).reshape(m, 3)
        free4 = free4.view(np.uint32).ravel()

        # column indices, written in place node chunk by node chunk: rows (i, c), blocks o, columns d
        indices = np.empty(nnz, dtype=itype)
        pos = 0
        for r0 in range(0, m, _NODE_CHUNK):                           # loop over chunks
            nb = nbr[r0:r0 + _NODE_CHUNK]
            k = len(nb)
            mask = free4[nb].view(bool).reshape(k, 1, 108) & free3[r0:r0 + k, :, None]   # (k, 3c, 27o 4d)
            seg = np.broadcast_to(red4[nb].reshape(k, 1, 108), (k, 3, 108))[mask]
            indices[pos:pos + len(seg)] = seg
            pos += len(seg)
        assert pos == nnz
        self.indptr, self.indices, self.nnz = indptr, indices, nnz
        self.shape = (n_free, n_free)
        # per-node tables for the slots: row starts (3, m), block offsets (m, 27), column rank of
        # each DOF among its node's free DOFs (only needed when a node is partly fixed)
        self._rowstart = np.ascontiguousarray(rowstart.reshape(m, 3).T)
        self._coloff = coloff.ravel()
        self._free3 = free3
        self._all_free = n_free == 3 * m
        full = (row_len == 81) & (nfree == 3)          # free node whose 27 neighbours are all free
        self._interior = full[hexes].all(axis=1)        # cubes whose slots follow _INTERIOR
        partial = bool(np.any((nfree > 0) & (nfree < 3)))
        self._dloc = (np.where(free3, np.cumsum(free3, axis=1) - 1, 0).astype(itype).reshape(m, 1, 1, 3)
                      if partial else None)

    def _slots(self, s: int, e: int) -> tuple[np.ndarray, np.ndarray | None]:
        """CSR positions (e - s, 576) of the element entries of cubes ``s:e``, and the mask of the
        entries on free DOFs (``None`` when all are); computed from the lattice tables."""
        hx = self.model.hexes[s:e]
        c = len(hx)
        # interior cubes (every node with its full 81-column rows): row start + a fixed template
        slot = (self._rowstart[0][hx][:, :, None] + _INTERIOR).reshape(c, 576)
        other = np.flatnonzero(~self._interior[s:e])
        if len(other):
            slot[other] = self._general_slots(hx[other])
        if self._all_free:
            return slot, None
        f = self._free3[hx].reshape(c, 24)
        if f.all():
            return slot, None
        return slot, (f[:, :, None] & f[:, None, :]).reshape(c, 576)

    def _general_slots(self, hx: np.ndarray) -> np.ndarray:
        """CSR positions (c, 576) of the entries of cubes with nodes ``hx`` (c, 8), any stencil;
        entries on fixed DOFs get arbitrary in-range positions (the caller masks them)."""
        c = len(hx)
        co = np.take(self._coloff, (27 * hx)[:, :, None] + _PAIR_OFFSET)   # (c, 8a, 8b)
        base = np.empty((c, 8, 3, 8), dtype=self.indices.dtype)      # (c, 8a, 3 rows, 8b)
        for k in range(3):                                            # the 3 row components
            np.add(self._rowstart[k][hx][:, :, None], co, out=base[:, :, k, :])
        slot = np.repeat(base.reshape(c, 192), 3, axis=1)             # (c, 8a 3c 8b 3d)
        if self._dloc is None:                                        # column d of a free node: + d
            slot += _D_PATTERN
        else:
            slot.reshape(c, 8, 3, 24)[...] += self._dloc[hx].reshape(c, 1, 1, 24)
        return slot

    # ------------------------------------------------------------------ assembly
    def _scatter(self, values_of_chunk, refill: bool = False, matrix: str = "K") -> sp.csr_matrix:
        """Sum the element entries of every chunk of cubes into a new ``data`` array, in place; a
        progress bar over the cubes (:func:`~sc_fem._progress.stage_bar`) names the ``matrix``."""
        data = np.zeros(self.nnz)
        n = self.model.n_cubes
        store = self._cache is not None and (self._cache_all or refill)
        jit = None
        if self.kernel == "numba":
            from . import assemble_jit as jit

            hexes = np.ascontiguousarray(self.model.hexes)
        with stage_bar(f"assemble {matrix}", n, unit="cube") as bar:
            for s in range(0, n, _CHUNK):                             # loop over chunks
                e = min(s + _CHUNK, n)
                got = None if self._cache is None else self._cache.get((s, e))
                vals = np.asarray(values_of_chunk(s, e)).reshape(e - s, 576)
                bar.update(e - s)
                if jit is not None:
                    vals = np.ascontiguousarray(vals, dtype=np.float64)
                    if got is None and not store:                     # positions computed inline
                        jit.fill(data, vals, hexes, s, self._interior, self._rowstart, self._coloff, self._free3,
                                 _PAIR_OFFSET, _INTERIOR)
                        continue
                if got is None:
                    slot, keep = self._slots(s, e)
                    got = (slot.ravel(), None) if keep is None else (slot[keep], keep)
                    if store:
                        self._cache[(s, e)] = got
                slot, keep = got
                if jit is None:
                    np.add.at(data, slot, vals.ravel() if keep is None else vals[keep])
                elif keep is None:
                    jit.add_at(data, slot, vals.ravel())
                else:
                    jit.add_at_masked(data, slot, vals.ravel(), keep.ravel())
        return sp.csr_matrix((data, self.indices, self.indptr), shape=self.shape, copy=False)

    def stiffness(self, youngs: ArrayLike | None = None, poisson: ArrayLike | None = None,
                  element_matrices: ArrayLike | None = None) -> sp.csr_matrix:
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
            return self._scatter(lambda s, e: flat[s:e], refill=True)
        if youngs is None and poisson is None:
            # the model's partial-cube stiffness (finite-cell moments or fraction-scaled)
            return self._scatter(cube_stiffness_chunks(self.model, self.element))
        E = self.model.youngs if youngs is None else _per_cube(youngs, "youngs", n)
        nu = self.model.poisson if poisson is None else _per_cube(poisson, "poisson", n)
        return self._scatter(stiffness_chunks(self.element, *lame(E, nu), self.model.h))

    def mass(self, *, lumped: bool = False, masses: ArrayLike | None = None, compact: bool = False) -> sp.csr_matrix:
        """Assemble ``M`` (kg).

        Parameters
        ----------
        lumped : bool
            ``False``: consistent mass (each cube ``m_e * reference_mass()``; a partly filled
            cube of a ``"moments"`` model distributes ``m_e`` like its filled region,
            :func:`~sc_fem.fem.elements.cube_mass_chunks`), on the same pattern as :meth:`stiffness`. ``True``: diagonal, each of a cube's 8 nodes gets
            ``m_e / 8`` in each direction.
        masses : array_like, shape (n,), optional
            Per-cube masses in kg; default ``model.mass`` (the voxelizer's sample mass).
        compact : bool
            The consistent ``M`` with its nonzeros alone, on its own pattern (27 per row of a solid
            lattice instead of 81: half the memory of its values on ``K``'s pattern;
            :mod:`sc_fem.fem.nodemass`), the same matrix.

        Returns
        -------
        scipy.sparse.csr_matrix, shape :attr:`shape`
            Mass matrix on the free DOFs, kg (diagonal when ``lumped``).
        """
        n = self.model.n_cubes
        mass = self.model.mass if masses is None else _per_cube(masses, "masses", n, scalar=False)
        if lumped:
            nm = self.model.node_masses(mass)
            return sp.diags(np.repeat(nm, 3)[self.free_dofs]).tocsr()
        chunks = cube_mass_chunks(self.model, mass)           # partial cubes: like their filled region
        M = compact_mass(self, chunks, _CHUNK, _PAIR_OFFSET) if compact else None
        if compact and M is None:                             # nodes partly fixed: the zeros dropped
            M = without_zeros(self._scatter(chunks, matrix="M"))
        return self._scatter(chunks, matrix="M") if M is None else M

    # ------------------------------------------------------------------ helpers
    def expand(self, u_free: np.ndarray) -> np.ndarray:
        """Full node field ``(m, 3)`` (or ``(m, 3, k)``) from a free-DOF vector, zeros on fixed DOFs.

        Parameters
        ----------
        u_free : ndarray, shape (n_free,) or (n_free, k)
            Values on the free DOFs :attr:`free_dofs` (e.g. displacements in metres).

        Returns
        -------
        ndarray, shape (m, 3) or (m, 3, k)
            The field per node and direction, same units and dtype as ``u_free``.
        """
        u_free = np.asarray(u_free)
        out = np.zeros((3 * self.model.n_nodes,) + u_free.shape[1:], dtype=u_free.dtype)
        out[self.free_dofs] = u_free
        return out.reshape((self.model.n_nodes, 3) + u_free.shape[1:])

    def restrict(self, f_nodes: ArrayLike) -> np.ndarray:
        """Free-DOF vector from a node field of shape ``(m, 3)``.

        Parameters
        ----------
        f_nodes : array_like, shape (m, 3) or (m, 3, k)
            A field per node and direction (e.g. nodal forces in N).

        Returns
        -------
        ndarray of float, shape (n_free,) or (n_free, k)
            Its values on the free DOFs :attr:`free_dofs`, same units.
        """
        f = np.asarray(f_nodes, dtype=float).reshape(3 * self.model.n_nodes, *np.shape(f_nodes)[2:])
        return f[self.free_dofs]


def assemble(model: CubeModel, element: str = DEFAULT_ELEMENT, *, lumped: bool = False,
             fixed_dofs: ArrayLike | None = None, method: str = "fast") -> tuple[sp.csr_matrix, sp.csr_matrix]:
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
        return assemble_skfem(model, element, lumped, free)
    raise InputError(f"method must be 'fast' or 'skfem', got {method!r}")
