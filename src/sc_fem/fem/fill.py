"""How much a sparse Cholesky factorization will fill and cost, known before it is computed.

A factorization's cost is set by its fill, not by the matrix's size: a compact 3-D solid of ``n``
DOFs fills ``L`` with ~``n^(4/3)`` entries and costs ~``n^2`` flops under nested dissection, a
thin-walled or many-part model far less (its separators are small). :func:`analyze_fill` takes
CHOLMOD's fill-reducing ordering of the actual matrix, compressed to one row per lattice node
(``sksparse.cholmod.analyze`` of :func:`supervariables`), and counts the nonzeros of each
column of ``L`` from the elimination tree (:func:`column_counts`, compiled with numba), giving
``nnz(L)`` and the flops of the numeric factorization. The order is kept, so a
factorization that follows (:func:`sc_fem.fem.linsolve.factorize` with ``analysis=``) does not
order the matrix a second time. From the fill follow shift-invert's predicted time
(:func:`shift_invert_seconds`, :data:`FILL_SPEED_MODEL`) and memory
(:func:`sc_fem.fem.options.factor_memory_estimate`), and LOBPCG's: a set-up plus iterations, more on
a thin shape than on a compact solid (:func:`lobpcg_iterations`), times their cost (:func:`lobpcg_seconds`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from .._jit import compiled
from .factorization import resolve_backend


def _column_counts(indptr: np.ndarray, indices: np.ndarray, perm: np.ndarray, weight: np.ndarray) -> np.ndarray:
    n = len(perm)
    invp = np.empty(n, np.int64)
    for k in range(n):
        invp[perm[k]] = k
    parent = np.full(n, -1, np.int64)      # the elimination tree (Liu's algorithm, path compression)
    ancestor = np.full(n, -1, np.int64)
    for k in range(n):
        c = perm[k]
        for p in range(indptr[c], indptr[c + 1]):
            i = invp[indices[p]]
            while i != -1 and i < k:
                nxt = ancestor[i]
                ancestor[i] = k
                if nxt == -1:
                    parent[i] = k
                i = nxt
    mark = np.full(n, -1, np.int64)        # row k of L: the tree paths from A's row k up to k
    counts = np.empty(n, np.int64)
    for k in range(n):
        counts[k] = weight[perm[k]]
    for k in range(n):
        mark[k] = k
        c = perm[k]
        wk = weight[c]
        for p in range(indptr[c], indptr[c + 1]):
            i = invp[indices[p]]
            while i < k and mark[i] != k:
                counts[i] += wk
                mark[i] = k
                i = parent[i]
    return counts


_column_counts_jit = compiled(_column_counts)


def column_counts(A: sp.spmatrix, perm: np.ndarray, weight: np.ndarray | None = None) -> np.ndarray | None:
    """Nonzeros of each column of the Cholesky factor ``L`` of ``A[perm][:, perm]`` (diagonal included).

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        Structurally symmetric (only its pattern is read).
    perm : ndarray of int, shape (n,)
        The elimination order (e.g. CHOLMOD's ``Factor.P()``).
    weight : ndarray of int, shape (n,), optional
        Rows each row of ``A`` stands for (a compressed matrix's supervariable sizes,
        :func:`supervariables`), indexed by ``A``'s rows: the ``k``-th row eliminated
        (``perm[k]``) adds ``weight[perm[k]]`` to each column of ``L`` it touches. Default 1.

    Returns
    -------
    ndarray of int64, shape (n,), or None
        Column counts in elimination order (``sum`` = ``nnz(L)``); with ``weight``, the count of a
        supervariable's first column in the uncompressed factor (its ``t``-th column has ``t``
        fewer). None without numba (the elimination tree is a sequential walk that numpy cannot
        vectorize).
    """
    if _column_counts_jit is None:
        return None
    A = sp.csc_matrix(A)
    n = A.shape[0]
    weight = np.ones(n, np.int64) if weight is None else np.asarray(weight, dtype=np.int64)
    return _column_counts_jit(A.indptr.astype(np.int64), A.indices.astype(np.int64),
                              np.asarray(perm, dtype=np.int64), weight)


def _compress(indptr: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    n = len(indptr) - 1
    same = np.zeros(n, np.bool_)             # row i has row i - 1's pattern
    for i in range(1, n):
        a, b, m = indptr[i - 1], indptr[i], indptr[i + 1] - indptr[i]
        if m == 0 or b - a != m:
            continue
        eq = True
        for p in range(m):
            if indices[a + p] != indices[b + p]:
                eq = False
                break
        same[i] = eq
    group = np.empty(n, np.int64)
    g = -1
    for i in range(n):
        if not same[i]:
            g += 1
        group[i] = g
    start = np.empty(g + 2, np.int64)
    k = 0
    for i in range(n):
        if not same[i]:
            start[k] = i
            k += 1
    start[g + 1] = n
    gptr = np.zeros(g + 2, np.int64)          # the compressed pattern, a row per supervariable
    for j in range(g + 1):
        r = start[j]
        for p in range(indptr[r], indptr[r + 1]):
            c = indices[p]
            if start[group[c]] == c:
                gptr[j + 1] += 1
    for j in range(g + 1):
        gptr[j + 1] += gptr[j]
    gind = np.empty(gptr[g + 1], np.int64)
    for j in range(g + 1):
        r, q = start[j], gptr[j]
        for p in range(indptr[r], indptr[r + 1]):
            c = indices[p]
            if start[group[c]] == c:
                gind[q] = group[c]
                q += 1
    return start, gptr, gind


_compress_jit = compiled(_compress)


def _compress_numpy(indptr: np.ndarray, indices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_compress` in numpy (vectorized over the entries; its oracle, and the fallback)."""
    n = len(indptr) - 1
    length = np.diff(indptr)
    same = np.zeros(n, bool)
    cand = np.flatnonzero((length[1:] == length[:-1]) & (length[1:] > 0)) + 1
    if len(cand):
        m = length[cand]
        within = np.arange(int(m.sum())) - np.repeat(np.cumsum(m) - m, m)
        pos = np.repeat(indptr[cand], m) + within
        eq = indices[pos] == indices[pos - np.repeat(m, m)]
        same[cand] = np.logical_and.reduceat(eq, np.cumsum(m) - m)
    start = np.flatnonzero(~same)
    group = np.cumsum(~same) - 1
    m = length[start]
    cols = indices[np.repeat(indptr[start], m) + np.arange(int(m.sum())) - np.repeat(np.cumsum(m) - m, m)]
    first = start[group[cols]] == cols
    per_row = np.bincount(np.repeat(np.arange(len(m)), m), weights=first, minlength=len(m))   # empty rows: 0
    gptr = np.concatenate([[0], np.cumsum(per_row)])
    return np.append(start, n).astype(np.int64), gptr.astype(np.int64), group[cols[first]].astype(np.int64)


def supervariables(A: sp.spmatrix) -> tuple[np.ndarray, sp.csc_matrix]:
    """Runs of consecutive rows of ``A`` with one sparsity pattern (a lattice node's 3 DOFs).

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        Structurally symmetric, explicit zeros kept where a block has them (as
        :func:`sc_fem.fem.eigen.shifted` does): rows that differ only by a dropped zero are kept
        apart, which is exact, only less compressed.

    Returns
    -------
    start : ndarray of int64, shape (g + 1,)
        Supervariable ``j`` is rows ``start[j]:start[j + 1]``.
    G : scipy.sparse.csc_matrix, shape (g, g)
        The compressed pattern: ``G[i, j]`` is nonzero where ``A``'s block ``(i, j)`` is (every
        entry of a block is, by symmetry, when one is).
    """
    A = sp.csr_matrix(A)
    A.sort_indices()
    kernel = _compress_jit if _compress_jit is not None else _compress_numpy
    start, gptr, gind = kernel(A.indptr.astype(np.int64), A.indices.astype(np.int64))
    g = len(start) - 1
    return start, sp.csc_matrix((np.ones(len(gind)), gind, gptr), shape=(g, g))   # symmetric: CSR = CSC


@dataclass(frozen=True, eq=False)
class FillAnalysis:
    """The fill of a sparse Cholesky factorization, from its symbolic analysis.

    Attributes
    ----------
    n : int
        Rows of the matrix.
    nnz_l : int
        Nonzeros of the factor ``L`` (lower triangle, diagonal included), without the explicit
        zeros CHOLMOD's supernodes add (3-6 % more on the lattice models measured).
    flops : float
        ``sum_j c_j^2`` over the column counts ``c_j``: the numeric factorization's floating-point
        operations (the leading term of the count).
    seconds : float
        Wall time of the compression, the ordering and the column counts.
    perm : ndarray of int64, shape (n,) or None
        The fill-reducing elimination order the counts are for (``A[perm][:, perm]`` is
        factorized), for the factorization to reuse (:class:`sc_fem.fem.linsolve.Factorization`).
    """

    n: int
    nnz_l: int
    flops: float
    seconds: float
    perm: np.ndarray | None = None


def analyze_fill(A: sp.spmatrix, backend: str = "auto") -> FillAnalysis | None:
    """A fill-reducing order of ``A`` and the fill and flops of its factorization, without factorizing.

    The rows of one lattice node share a pattern, so the order is CHOLMOD's AMD or METIS
    (``sksparse.cholmod.analyze``), whichever fills less, of the compressed matrix, one row per node
    (:func:`supervariables`: 9x fewer entries; at 139,656 DOFs 0.5 s against 3.2 s for the DOF-level
    ordering, with 1.7 % more ``nnz(L)`` and the same flops), each node's rows kept together; the
    counts are exact for that order (:func:`column_counts` with the supervariables' sizes).

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        Symmetric (e.g. ``K - sigma M``); the analysis depends on its pattern only.
    backend : {"auto", "cholmod", "cholespy", "splu"}
        The factorization backend that would be used (:func:`sc_fem.fem.linsolve.factorize`;
        ``"auto"`` honours ``SC_FEM_SOLVER``): the order is for CHOLMOD, so another backend gets
        None.

    Returns
    -------
    FillAnalysis or None
        None when the backend is not CHOLMOD (scikit-sparse) or numba is missing.
    """
    if resolve_backend(backend) != "cholmod" or _column_counts_jit is None:
        return None
    from sksparse.cholmod import analyze

    t0 = time.perf_counter()
    start, G = supervariables(A)
    size = np.diff(start)
    best = None
    for method in ("amd", "metis"):               # CHOLMOD's own "default" picks one by DOF-level
        try:                                      # flops per entry, which the compressed graph hides
            order = analyze(G, ordering_method=method).P().astype(np.int64)
        except Exception:                         # noqa: BLE001 - METIS not compiled in: AMD alone
            continue
        c = column_counts(G, order, size).astype(np.float64)    # a supervariable's first column
        s = size[order].astype(np.float64)                      # its t-th column has t fewer
        nnz_l = float(np.sum(s * c - s * (s - 1) / 2))
        if best is None or nnz_l < best[0]:
            best = nnz_l, float(np.sum(s * c * c - c * s * (s - 1) + (s - 1) * s * (2 * s - 1) / 6)), order
    if best is None:                              # no ordering ran: the power law predicts instead
        return None
    nnz_l, flops, order = best
    so = size[order]
    perm = np.repeat(start[order], so) + (np.arange(A.shape[0]) - np.repeat(np.cumsum(so) - so, so))
    return FillAnalysis(n=A.shape[0], nnz_l=int(round(nnz_l)), flops=flops, seconds=time.perf_counter() - t0,
                        perm=perm)


FILL_SPEED_MODEL = {"flops_per_second": 21e9, "seconds_per_entry": 3.4e-9, "seconds_per_dof": 2.0e-7}
"""Shift-invert's seconds from the fill (:func:`shift_invert_seconds`): the analysis itself,
``flops / flops_per_second`` (CHOLMOD's numeric factorization) and ``(seconds_per_entry * nnz(L) +
seconds_per_dof * n) * ncv`` (ARPACK: solves with ``L`` and its own work, growing with its ``ncv =
max(2k + 1, k + 20)`` Lanczos vectors). CHOLMOD on Debian's serial OpenBLAS (``.ci/install-cholmod.sh``;
the reference BLAS was 5-9x slower): ``flops_per_second`` from the factorization of a 56,112-DOF bunny
(73.4 Gflop of ``sum c_j^2`` in 3.39 s), the two solve terms fitted (non-negative least squares,
relative) to the 10 shapes of ``python benchmarks/auto_choice.py --quick`` (2026-11-28, load 0.5-1.5):
taken / predicted 0.85-1.2 on 8 of 10, 1.47 on the bridge and 1.83 on the armchair. See
``docs/performance.md`` for the shapes it was not fitted to."""

def shift_invert_seconds(analysis: FillAnalysis, k: int) -> float:
    """Seconds shift-invert takes for ``k`` pairs (set-up included), from the fill (:data:`FILL_SPEED_MODEL`).

    Parameters
    ----------
    analysis : FillAnalysis
        The fill of the shifted matrix.
    k : int
        Eigenpairs.

    Returns
    -------
    float
    """
    m, n = FILL_SPEED_MODEL, analysis.n
    ncv = min(n, max(2 * k + 1, k + 20))
    return (analysis.seconds + analysis.flops / m["flops_per_second"]
            + (m["seconds_per_entry"] * analysis.nnz_l + m["seconds_per_dof"] * n) * ncv)


def lobpcg_block(k: int) -> int:
    """Vectors in LOBPCG's block for ``k`` wanted pairs (a few extra speed convergence; its cost grows with it).

    Parameters
    ----------
    k : int
        Wanted eigenpairs.

    Returns
    -------
    int
        ``k + max(4, k // 4)``.
    """
    return k + max(4, k // 4)


LOBPCG_FILL_MODEL = {"setup": 0.0446, "setup_per_dof": 3.63e-6, "c": 1.17e-7, "gamma": -0.0113, "iterations": 15.6,
                     "q0": 17.5, "beta": 0.965, "cap": 8.0}
"""LOBPCG + AMG's seconds when the fill is known (:func:`lobpcg_seconds`): a set-up, then
iterations times the cost of one.

* Set-up (the AMG hierarchy and the final Rayleigh--Ritz): ``setup + setup_per_dof * n`` s.
* One iteration on a block of ``b`` vectors (:func:`lobpcg_block`): ``c * e * (e / 1e6) ** gamma``
  s for ``e = n * b`` block entries (the V-cycle, the products and LOBPCG's dense algebra all
  touch each entry a fixed number of times; ``gamma`` fitted ~0: no slow-down per entry as the
  block grows, since :func:`sc_fem.fem.lobpcg.lobpcg` updates its blocks in place by row chunks).
* Iterations (:func:`lobpcg_iterations`): a compact solid's ``iterations`` times
  ``min((q0 / q) ** beta, cap)`` for a fill ``q = nnz(L) / n^(4/3)`` below ``q0``: thin, slender
  members fill little, and the lattice multigrid preconditions them worse.

Fitted (``python benchmarks/auto_choice.py --from-json out/auto_choice_fitdata3.json --fit``: one
``--quick --repeat 2`` run of our LOBPCG, 2026-11-28, load 0.7-2.5, the toy truck rerun from each
part's rigid motions as ``sc_fem.modal`` starts it) to 10 shapes' 20 runs (the bridge's stall
excluded), each step on what it predicts: the set-up to the runs' set-up seconds, ``c, gamma`` to
their seconds per iteration (0.8-1.45x of the law), the three iteration constants to the
iterations (rms 0.31 in log: the beam r48 17 taken / 31 predicted, the truss 94 / 61: the fill
cannot tell a prism of 5 x 5 cubes from a chair). The seconds came out within 1.5x on all 10 fitted
runs (0.76-1.31x); the shapes it was not fitted to are in ``docs/performance.md``.
"""


def lobpcg_iterations(analysis: FillAnalysis) -> float:
    """LOBPCG's predicted iterations (:data:`LOBPCG_FILL_MODEL`): a compact solid's ``iterations``,
    times ``min((q0 / q) ** beta, cap)`` when the fill ``q = nnz(L) / n^(4/3)`` is below ``q0``.

    Parameters
    ----------
    analysis : FillAnalysis
        The fill of the shifted matrix.

    Returns
    -------
    float
        Iterations (not rounded: the model's mean over the shapes it was fitted to).
    """
    m = LOBPCG_FILL_MODEL
    q = analysis.nnz_l / max(analysis.n, 1) ** (4.0 / 3.0)
    return m["iterations"] * float(min(max(m["q0"] / max(q, 1e-12), 1.0) ** m["beta"], m["cap"]))


def lobpcg_iteration_seconds(n: int, k: int) -> float:
    """Seconds of one LOBPCG + AMG iteration for ``k`` pairs of ``n`` DOFs (:data:`LOBPCG_FILL_MODEL`).

    Parameters
    ----------
    n, k : int
        Free DOFs and wanted eigenpairs.

    Returns
    -------
    float
        ``c * e * (e / 1e6) ** gamma`` for ``e = n * lobpcg_block(k)`` block entries.
    """
    m, e = LOBPCG_FILL_MODEL, float(max(n, 1)) * min(lobpcg_block(k), max(n - 1, 1))
    return m["c"] * e * (e / 1e6) ** m["gamma"]


def lobpcg_seconds(analysis: FillAnalysis, k: int) -> float:
    """Seconds LOBPCG + AMG takes for ``k`` pairs, set-up included, from the fill (:data:`LOBPCG_FILL_MODEL`).

    Parameters
    ----------
    analysis : FillAnalysis
        The fill of the shifted matrix (its ``n`` and ``nnz_l``).
    k : int
        Eigenpairs.

    Returns
    -------
    float
        ``setup + setup_per_dof * n + lobpcg_iterations(analysis) * lobpcg_iteration_seconds(n, k)``.
    """
    m, n = LOBPCG_FILL_MODEL, analysis.n
    return m["setup"] + m["setup_per_dof"] * n + lobpcg_iterations(analysis) * lobpcg_iteration_seconds(n, k)


FILL_ANALYSIS_MAX_DOFS = 400_000
"""``method="auto"`` analyzes the fill (:func:`analyze_fill`) up to this many DOFs;
above, :data:`SPEED_MODEL`'s power law (the ordering alone would take tens of seconds there)."""


def fill_analysis(A: sp.spmatrix, backend: str = "auto") -> FillAnalysis | None:
    """:func:`analyze_fill` of ``A`` when it has at most :data:`FILL_ANALYSIS_MAX_DOFS` rows.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        The matrix shift-invert would factorize (``K - sigma M``).
    backend : {"auto", "cholmod", "cholespy", "splu"}
        Its factorization backend.

    Returns
    -------
    FillAnalysis or None
        None above the size, or without CHOLMOD or numba: the prediction falls back on the power law.
    """
    return analyze_fill(A, backend) if A.shape[0] <= FILL_ANALYSIS_MAX_DOFS else None
