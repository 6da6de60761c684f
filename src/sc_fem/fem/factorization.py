"""Sparse symmetric positive-definite factorization with a choice of backend.

``backend="auto"`` takes the first importable of

1. ``"cholmod"`` -- CHOLMOD through scikit-sparse (``sksparse.cholmod``; needs the system
   SuiteSparse),
2. ``"cholespy"`` -- CHOLMOD bundled in the ``cholespy`` binary wheels,
3. ``"splu"`` -- SciPy's SuperLU (always available; symmetric mode, no pivoting).

A matrix that is singular or indefinite (e.g. a floating, unsupported model) raises
:class:`~sc_fem.errors.SolverError` instead of returning garbage.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import time

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike
from scipy.sparse.linalg import splu

from ..errors import InputError, SolverError

BACKENDS: tuple[str, ...] = ("cholmod", "cholespy", "splu")
"""Backends in the order ``"auto"`` tries them."""

_PIVOT_RTOL = 1e-13
"""A pivot below this times the largest one means a numerically singular matrix (splu)."""


def available_backends() -> list[str]:
    """The importable backends, in preference order (looked up once per process)."""
    return list(_available_backends())


@functools.lru_cache(maxsize=1)
def _available_backends() -> tuple[str, ...]:
    out = []
    if importlib.util.find_spec("sksparse") is not None:
        out.append("cholmod")
    if importlib.util.find_spec("cholespy") is not None:
        out.append("cholespy")
    out.append("splu")
    return tuple(out)


def _singular_message(n: int, what: str) -> str:
    return (f"the {n}x{n} system matrix is {what}: the model is probably not held in place "
            "(no or too few fixed nodes: a floating part can move as a rigid body). "
            "Fix nodes with fix=[...] / --fix 'x<...' or --fix-vertices FILE.")


class Factorization:
    """A factorization of a sparse SPD matrix ``A`` (n x n).

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        Symmetric positive definite (e.g. a stiffness matrix in N/m); only symmetry is assumed.
    backend : {"auto", "cholmod", "cholespy", "splu"}
        ``"auto"``: the first installed of :data:`BACKENDS`.
    analysis : FillAnalysis, optional
        The fill analysis of ``A``'s pattern (:func:`sc_fem.fem.fill.analyze_fill`): the
        ``"cholmod"`` backend factorizes in its order instead of ordering ``A`` again.

    Raises
    ------
    SolverError
        The matrix is singular, not positive definite or has non-finite entries.

    Attributes
    ----------
    backend : str
        ``"cholmod"``, ``"cholespy"`` or ``"splu"``.
    shape : tuple
        ``(n, n)``.
    seconds : float
        Wall time of the factorization.
    """

    def __init__(self, A: sp.spmatrix, backend: str = "auto", analysis: object | None = None) -> None:
        if not sp.issparse(A):
            raise InputError(f"A must be a scipy.sparse matrix, got {type(A).__name__}")
        if A.ndim != 2 or A.shape[0] != A.shape[1] or A.shape[0] == 0:
            raise InputError(f"A must be a non-empty square matrix, got shape {A.shape}")
        if backend == "auto":
            backend = _available_backends()[0]
        if backend not in BACKENDS:
            raise InputError(f"backend must be 'auto' or one of {list(BACKENDS)}, got {backend!r}")
        if backend not in _available_backends():
            raise InputError(f"backend {backend!r} is not installed (available: {available_backends()})")
        self.backend = backend
        self.shape = A.shape
        self._perm = None
        n = A.shape[0]
        A = sp.csr_matrix(A, dtype=np.float64)
        if not np.all(np.isfinite(A.data)):
            raise SolverError("the system matrix contains non-finite entries")
        t0 = time.perf_counter()
        if backend == "cholmod":
            from sksparse.cholmod import CholmodNotPositiveDefiniteError, cholesky

            perm = getattr(analysis, "perm", None)
            if perm is not None:            # the analysis's order: A[perm][:, perm] factorized as it stands
                self._perm = perm
                A = A[perm][:, perm]
            A = sp.csc_matrix((A.data, A.indices, A.indptr), shape=A.shape)   # symmetric: its CSR arrays are CSC
            try:
                self._f = cholesky(A, ordering_method="natural" if perm is not None else "default")
            except CholmodNotPositiveDefiniteError:
                raise SolverError(_singular_message(n, "singular or not positive definite")) from None
            d = self._f.D()
            if np.any(d <= _PIVOT_RTOL * d.max()):
                raise SolverError(_singular_message(n, "numerically singular"))
        elif backend == "cholespy":
            from cholespy import CholeskySolverD, MatrixType

            # A symmetric: its CSR arrays are its CSC arrays
            try:
                self._f = CholeskySolverD(n, A.indptr.astype(np.int32), A.indices.astype(np.int32),
                                          np.ascontiguousarray(A.data), MatrixType.CSC)
            except ValueError as exc:
                raise SolverError(_singular_message(n, f"singular or not positive definite ({exc})")) from None
        else:
            try:
                self._f = splu(A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                               options={"SymmetricMode": True})
            except RuntimeError as exc:
                raise SolverError(_singular_message(n, f"singular ({exc})")) from None
            d = np.abs(self._f.U.diagonal())
            if not np.all(np.isfinite(d)) or d.min() <= _PIVOT_RTOL * d.max():
                raise SolverError(_singular_message(n, "numerically singular"))
            # symmetric without pivoting: A = L D L^T, so a negative pivot means indefinite
            if np.any(self._f.U.diagonal() < 0):
                raise SolverError(_singular_message(n, "not positive definite"))
        self.seconds = time.perf_counter() - t0

    def solve(self, b: ArrayLike) -> np.ndarray:
        """Solve ``A x = b``.

        Parameters
        ----------
        b : array_like, shape (n,) or (n, k)
            Right-hand side(s) (e.g. forces in N).

        Returns
        -------
        ndarray, same shape as ``b``
            The solution ``x`` (e.g. displacements in m).
        """
        b = np.asarray(b, dtype=np.float64)
        n = self.shape[0]
        if b.ndim not in (1, 2) or b.shape[0] != n:
            raise InputError(f"b must have shape ({n},) or ({n}, k), got {b.shape}")
        if self.backend == "cholespy":
            b = np.ascontiguousarray(b)
            x = np.zeros_like(b)
            self._f.solve(b, x)
        elif self.backend == "cholmod" and self._perm is not None:
            x = np.empty_like(b)
            x[self._perm] = self._f(b[self._perm])
        elif self.backend == "cholmod":
            x = self._f(b)
        else:
            x = self._f.solve(b)
        x = np.asarray(x).reshape(b.shape)
        if not np.all(np.isfinite(x)):
            raise SolverError(_singular_message(n, "singular (the solution is not finite)"))
        return x

    def __repr__(self) -> str:
        return f"Factorization({self.shape[0]}x{self.shape[1]}, backend={self.backend!r})"


def factorize(A: sp.spmatrix, backend: str | None = "auto", analysis: object | None = None) -> Factorization:
    """Factorize a sparse symmetric positive-definite matrix.

    Parameters
    ----------
    A : scipy.sparse matrix, shape (n, n)
        Symmetric positive definite (only symmetry is assumed, not checked).
    backend : {"auto", "cholmod", "cholespy", "splu"}
        ``"auto"`` (default; overridable with the environment variable ``SC_FEM_SOLVER``) picks
        the first installed of CHOLMOD (scikit-sparse), cholespy, SciPy ``splu``.
    analysis : FillAnalysis, optional
        The fill analysis of ``A`` (:func:`sc_fem.fem.fill.analyze_fill`): CHOLMOD factorizes in its order.

    Returns
    -------
    Factorization
        With ``.solve(b)`` and ``.backend``.

    Raises
    ------
    SolverError
        The matrix is singular or not positive definite.
    """
    return Factorization(A, resolve_backend(backend, keep_auto=True), analysis)


def resolve_backend(backend: str | None = "auto", *, keep_auto: bool = False) -> str:
    """The factorization backend that ``backend`` means: ``"auto"`` (or None) is the environment
    variable ``SC_FEM_SOLVER`` if set, else the first installed of :data:`BACKENDS`.

    Parameters
    ----------
    backend : str or None
        ``"auto"``, None or a name of :data:`BACKENDS`.
    keep_auto : bool
        Return ``"auto"`` rather than the first installed backend when nothing names one.

    Returns
    -------
    str
    """
    if backend in (None, "auto"):
        backend = os.environ.get("SC_FEM_SOLVER", "auto") or "auto"
    return backend if backend != "auto" or keep_auto else _available_backends()[0]
