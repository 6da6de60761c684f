"""Optional numba: whether the compiled kernels can run, which one a caller gets, how they compile.

The compiled kernels (:mod:`sc_fem.dynamics.xpbd_jit`, :mod:`sc_fem.fem.assemble_jit`) each have a
numpy fallback that gives the same result; numba is the optional extra ``sc_fem[fast]``.
"""

from __future__ import annotations

from contextlib import nullcontext

try:  # optional: every compiled kernel has a numpy fallback
    import numba
except ImportError:  # pragma: no cover - exercised when numba is absent
    numba = None

from .errors import InputError

KERNELS = ("auto", "numba", "numpy")
"""Names accepted by the ``kernel=`` options."""


def available() -> bool:
    """True when numba is importable (the compiled kernels can run)."""
    return numba is not None


def choose_kernel(kernel: str, applicable: bool = True, not_applicable: str = "") -> str:
    """``"numba"`` or ``"numpy"`` for the requested ``kernel``: ``"auto"`` takes the compiled one
    when numba is installed and it ``applicable`` to the caller's settings; ``"numba"`` without
    numba, or where it does not apply (``not_applicable`` says why), is an InputError."""
    if kernel not in KERNELS:
        raise InputError(f"kernel must be 'auto', 'numba' or 'numpy', got {kernel!r}")
    if kernel == "numba":
        if not available():
            raise InputError("kernel='numba' needs numba (pip install 'sc_fem[fast]'); kernel='numpy' runs without it")
        if not applicable:
            raise InputError(not_applicable)
        return "numba"
    return "numba" if kernel == "auto" and applicable and available() else "numpy"


def compiled(fn):
    """``fn`` compiled by numba (no Python objects, no GIL, cached on disk), or None without numba."""
    return numba.njit(cache=True, nogil=True)(fn) if numba is not None else None


def compiled_inline(fn):
    """``fn`` compiled by numba and inlined into the compiled kernels that call it (a helper of an
    inner loop, where a call would cost more than its body), or None without numba."""
    return numba.njit(cache=True, nogil=True, inline="always")(fn) if numba is not None else None


def compiled_parallel(fn):
    """``fn`` compiled by numba with its :data:`prange` loops split over the cores (cached on disk),
    or None without numba."""
    return numba.njit(cache=True, nogil=True, parallel=True)(fn) if numba is not None else None


prange = numba.prange if numba is not None else range
"""``numba.prange`` (a loop whose iterations the compiled kernel runs in parallel), or ``range``."""


def blas_single_threaded():
    """A context in which the BLAS (OpenBLAS, MKL) runs on one thread, while compiled parallel
    kernels use the cores: OpenBLAS's threads spin between its calls and starve numba's (LOBPCG at
    158,976 DOFs took 13.4 s with both on 2 threads, 9.0 s with the BLAS on one). Needs
    threadpoolctl (installed with the ``fast`` extra); without it, a context that changes nothing."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - exercised when threadpoolctl is absent
        return nullcontext()
    return threadpool_limits(limits=1, user_api="blas")
