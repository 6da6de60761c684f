"""Finite-cell matrices of partly filled cubes: the element integrands integrated over a cube's
filled region only, from its 27 moments (:mod:`sc_fem.lattice.moments`).

Every integrand of the unit-cube element has degree <= 2 in each reference coordinate, so its
integral over any region is a linear combination of the region's moments
(:func:`_polynomial_parts`). A partly filled cube also gets :data:`FCM_ALPHA` of the full cube
(the finite cell method's regularisation), and q1i's incompatible modes are corrected so that
they pass the patch test (:func:`_patch_test_correction`) before being condensed.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from ..errors import InputError
from ..lattice.cubes import HEX_CORNERS
from ..lattice.moments import FULL, monomials
from .hexahedron import check_element


def _shape_gradients(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Trilinear shape functions (q, 8) and their gradients (q, 8, 3) on the unit cube at ``x`` (q, 3)."""
    c = HEX_CORNERS[None, :, :]                                       # (1, 8, 3)
    f = np.where(c == 1, x[:, None, :], 1.0 - x[:, None, :])          # (q, 8, 3) factor per axis
    df = np.where(c == 1, 1.0, -1.0) * np.ones_like(f)
    n = f.prod(axis=2)
    grad = np.stack([df[..., 0] * f[..., 1] * f[..., 2], f[..., 0] * df[..., 1] * f[..., 2],
                     f[..., 0] * f[..., 1] * df[..., 2]], axis=2)
    return n, grad


@lru_cache(maxsize=None)
def _polynomial_parts(element: str) -> dict[str, np.ndarray]:
    """Coefficients of the integrands in the 27 monomials of :data:`sc_fem.lattice.moments.EXPONENTS`.

    Every integrand of the unit-cube element (``B^T D B`` split into its lambda and mu parts,
    including the 9 incompatible modes of q1i, and ``N N^T``) has degree <= 2 in each reference
    coordinate, so it is fitted exactly from its values at the 3 x 3 x 3 Gauss points.
    Returns arrays (27, 33, 33) (``lambda``, ``mu``; the first 24 rows/columns compatible),
    (27, 24, 24) (``mass``) and (27, 33, 3, 3) (``grad``: the displacement gradient of every mode),
    read-only.
    """
    g, _ = np.polynomial.legendre.leggauss(3)
    g = 0.5 * (g + 1.0)
    x = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)   # (27, 3)
    n, grad = _shape_gradients(x)
    q = len(x)
    gc = np.zeros((q, 24, 3, 3))                                        # d u_c / d x_k of DOF 3a + c
    for c in range(3):          # three displacement components, not a loop over elements
        gc[:, c::3, c, :] = grad
    xi = 2.0 * x - 1.0
    gi = np.zeros((q, 9, 3, 3))
    for k in range(3):          # the 9 incompatible modes (1 - xi_k^2) e_c
        for c in range(3):
            gi[:, 3 * k + c, c, k] = -4.0 * xi[:, k]
    gr = np.concatenate([gc, gi], axis=1) if element == "q1i" else gc   # (q, d, 3, 3)
    tr = np.einsum("qicc->qi", gr)
    k_lam = np.einsum("qi,qj->qij", tr, tr)
    k_mu = np.einsum("qiab,qjab->qij", gr, gr) + np.einsum("qiab,qjba->qij", gr, gr)
    mass = np.zeros((q, 24, 24))
    nn = np.einsum("qa,qb->qab", n, n)
    for c in range(3):
        mass[:, c::3, c::3] = nn
    vinv = np.linalg.inv(monomials(x))                                  # (27 monomials, 27 points)
    out = {"lambda": np.einsum("kq,qij->kij", vinv, k_lam), "mu": np.einsum("kq,qij->kij", vinv, k_mu),
           "mass": np.einsum("kq,qij->kij", vinv, mass), "grad": np.einsum("kq,qiab->kiab", vinv, gr)}
    for a in out.values():
        a.flags.writeable = False
    return out


MOMENT_ELEMENTS = frozenset({"q1", "q1i"})
"""Elements whose matrices :func:`moment_stiffness` integrates over a cube's filled region."""

FCM_ALPHA = 1e-4
"""Finite-cell regularization: a partly filled cube's stiffness integrates over its filled region
plus ``FCM_ALPHA`` times the whole cube, so a node that only slivers of material reach is held
(its local mode stays far above the model's frequencies) without stiffening thin members: a plate
a tenth of a cube thick has about 1000x this in bending."""


def _patch_test_correction(k: np.ndarray, M: np.ndarray, grad: np.ndarray, lam, mu, h: float) -> np.ndarray:
    """Make the incompatible modes of partly filled q1i cubes pass the patch test.

    Over a full cube the 9 incompatible-mode gradients integrate to zero, so a uniform strain
    never excites them; over a partly filled region they do not (their mean ``gbar_i`` is not
    zero), the condensation then relaxes a uniform strain and the cube comes out too soft (measured
    on spot: q1i's frequency error stalled at 1.5 % from resolution 24 to 64, where q1 converged to
    0.5 %). As in the Taylor-Beresford-Wilson modification the incompatible gradients are replaced
    by ``g_i - gbar_i`` over the filled region ``f`` (``gbar_i = int_f g_i / V_f``), which changes
    ``K_ii`` by ``- V_f a(gbar_i, gbar_j)`` and ``K_ci`` by ``- a(int_f g_c, gbar_i)`` (``a`` the
    elastic bilinear form); full cubes are unchanged."""
    G = np.einsum("nk,kdab->ndab", M, grad)                      # integrals of every mode's gradient
    V = M[:, 0]
    gbar = G[:, 24:] / V[:, None, None, None]

    def form(g1, g2):                                            # a(g1_i, g2_j), (n, i, j), per unit lam/mu
        t1, t2 = np.einsum("niaa->ni", g1), np.einsum("niaa->ni", g2)
        sym = np.einsum("niab,njab->nij", g1, g2) + np.einsum("niab,njba->nij", g1, g2)
        return (lam * h)[:, None, None] * t1[:, :, None] * t2[:, None, :] + (mu * h)[:, None, None] * sym

    k = k.copy()
    k[:, 24:, 24:] -= V[:, None, None] * form(gbar, gbar)
    k[:, :24, 24:] -= form(G[:, :24], gbar)
    k[:, 24:, :24] = np.swapaxes(k[:, :24, 24:], 1, 2)
    return k


def moment_stiffness(element: str, moments: np.ndarray, lam: np.ndarray, mu: np.ndarray, h: float) -> np.ndarray:
    """Stiffness of partly filled cubes, integrated over the filled region only (finite cell method).

    Parameters
    ----------
    element : {"q1", "q1i"}
    moments : ndarray, shape (n, 27)
        Moments of each cube's filled region (:mod:`sc_fem.lattice.moments`); the full cube gives the
        ordinary element matrix.
    lam, mu : ndarray, shape (n,)
        Lame parameters of the material, Pa.
    h : float
        Cube edge, m.

    Returns
    -------
    ndarray, shape (n, 576)
        Flattened (row-major 24 x 24) matrices, N/m. For q1i the incompatible modes are
        integrated over the filled region too and condensed per cube.
    """
    element = check_element(element)
    if element not in MOMENT_ELEMENTS:
        raise InputError(f"element {element!r} has no moment integration; use one of {sorted(MOMENT_ELEMENTS)}")
    p = _polynomial_parts(element)
    d = p["lambda"].shape[1]
    M = _with_fcm_share(moments)
    k = (M @ p["lambda"].reshape(27, -1)) * (lam * h)[:, None] + (M @ p["mu"].reshape(27, -1)) * (mu * h)[:, None]
    k = k.reshape(-1, d, d)
    if element == "q1i":
        k = _patch_test_correction(k, M, p["grad"], lam, mu, h)
        kcc, kci, kii = k[:, :24, :24], k[:, :24, 24:], k[:, 24:, 24:]
        # a sliver of material barely constrains the internal modes: keep their block invertible
        reg = 1e-12 * np.einsum("nii->n", kii)[:, None, None] * np.eye(9)
        k = kcc - kci @ np.linalg.solve(kii + reg, np.swapaxes(kci, 1, 2))
    k = 0.5 * (k + np.swapaxes(k, 1, 2))
    return k.reshape(-1, 576)


PARTIAL_BELOW = 1.0 - 1e-12
"""A cube whose filled fraction is below this is partly filled."""


def _with_fcm_share(moments) -> np.ndarray:
    """Moments (n, 27) of the filled region plus :data:`FCM_ALPHA` of the full cube's for partly
    filled cubes (the finite cell method's regularisation)."""
    M = np.asarray(moments, dtype=np.float64)
    return M + FCM_ALPHA * (M[:, :1] < PARTIAL_BELOW) * FULL


def moment_mass(moments: np.ndarray, masses: np.ndarray) -> np.ndarray:
    """Consistent mass matrices (n, 576) of cubes whose mass ``masses`` (n,) kg is distributed
    like their filled region (``moments`` (n, 27); ``moments[:, 0]`` the filled fraction)."""
    # as for the stiffness, a node that only a sliver reaches keeps FCM_ALPHA of a full cube's mass
    # shape: the cube's mass is unchanged (normalised below) but M stays invertible (measured: the
    # chair at resolution 10 had a 726 x 726 M that Cholesky called singular without it)
    M = _with_fcm_share(moments)
    unit = M @ _polynomial_parts("q1")["mass"].reshape(27, -1)          # integral of N N^T over the fill
    return unit * (np.asarray(masses, dtype=np.float64) / M[:, 0])[:, None]
