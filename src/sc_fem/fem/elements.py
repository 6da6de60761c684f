"""Reference 24x24 matrices of the hexahedral elements used for the Squashing Cubes lattice.

All cubes of a :class:`~sc_fem.lattice.cubes.CubeModel` are identical up to their edge ``h`` (m) and
material, so every element matrix is a scaled copy of a few matrices computed **once** on the
unit cube ``[0, 1]^3`` with scikit-fem (``MeshHex`` + ``ElementVector(ElementHex1())``).

Local DOF ``3 a + c`` is displacement component ``c`` (x, y, z) of corner ``a`` in
:data:`~sc_fem.lattice.cubes.HEX_CORNERS` order -- the order scikit-fem's ``ElementVector`` uses, so
the global DOF of node ``i`` component ``c`` is ``3 i + c``.

Elements (``element=``)

``"q1"``
    Trilinear brick, full 2x2x2 Gauss integration (scikit-fem's physics).
    ``K_e = h (lambda_e K_lambda + mu_e K_mu)``. Shear-locks in bending when a member is only
    one or two cubes thick (cantilever with 1 cube through the thickness: first frequency
    +24.30 %, tip deflection -35.28 %).
``"q1sri"``
    Selective reduced integration: the volumetric (bulk) term ``kappa div u div v`` at the
    cube centre (1 point), the deviatoric term ``2 mu dev(eps):dev(eps)`` at 2x2x2 points.
    Removes volumetric (Poisson) locking but **not** shear locking: on the same cantilever it
    overshoots with 1 cube through the thickness (tip deflection +20.53 %, first frequency
    -8.84 %) and is close with 2 (-1.76 % / +0.91 %, against -12.51 % / +7.02 % for q1 and
    -0.67 % / +0.44 % for q1i); ``benchmarks/accuracy_vs_speed.py``. Kept as the classical
    alternative. Still linear in (lambda, mu).
``"q1i"`` (default)
    Incompatible-modes hexahedron (Wilson; Taylor--Beresford--Wilson, identical on cubes):
    the trilinear field is enriched with the 9 bubble modes ``(1 - xi_k^2) e_c`` that let a cube
    bend without parasitic shear, and the internal modes are condensed per element, so the
    matrix stays 24x24 with the Q1 sparsity. It passes the patch test on the lattice (cubes are
    parallelepipeds). The condensed matrix is homogeneous of degree one in (lambda, mu) but not
    linear: ``K_e = h mu_e K(lambda_e / mu_e)`` with one unit matrix per distinct ratio
    (i.e. per distinct nu), computed in a batch.

The default is ``"q1i"`` because voxelized members are 1--3 cubes thick and there it is
one to two orders of magnitude more accurate than ``"q1"`` at the same DOFs and sparsity (1 cube
thick: tip -0.78 %, f1 +0.48 %; see ``benchmarks/accuracy_vs_speed.py``). Its assembly costs
a little more with one material and several times more with a different nu in every cube (one
9x9 condensation per distinct nu): refilling ``K`` of the 40,960-cube cantilever (16 cubes thick)
took 0.11--0.15 s with q1, 0.15--0.17 s with q1i (one material) and 0.66--0.89 s with q1i and a
random nu per cube (single-threaded BLAS, minimum of 7, on a shared 2-core machine).

Mass: :func:`reference_mass` is the consistent mass matrix of a cube of **unit total mass**;
a cube of mass ``m_e`` (kg) gets ``m_e * reference_mass()``.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Callable

import numpy as np

from ..errors import InputError
from ..lattice.cubes import HEX_CORNERS

ELEMENTS: tuple[str, ...] = ("q1", "q1i", "q1sri")
"""Names accepted by ``element=``."""

DEFAULT_ELEMENT = "q1i"
"""The default element (locking-free in bending, same DOFs and sparsity as Q1)."""

LINEAR_ELEMENTS = frozenset({"q1", "q1sri"})
"""Elements whose matrix is linear in (lambda, mu): ``K_e = h (lambda K_lambda + mu K_mu)``."""


CENTRE_RULE = (np.full((3, 1), 0.5), np.ones(1))
"""One-point rule at the centre of scikit-fem's reference hexahedron [0, 1]^3 (``quadrature=``);
scikit-fem's ``intorder=1`` on hexahedra still uses 2x2x2 points."""


def check_element(element: str) -> str:
    """Validate an element name and return it (lower case)."""
    if not isinstance(element, str) or element.lower() not in ELEMENTS:
        raise InputError(f"element must be one of {list(ELEMENTS)}, got {element!r}")
    return element.lower()


# ---------------------------------------------------------------------------------------- scikit-fem
@lru_cache(maxsize=None)
def _unit_cube_bases():
    """scikit-fem vector bases on the unit cube: 2x2x2 Gauss and 1-point (centre) rules."""
    from skfem import Basis, ElementHex1, ElementVector, MeshHex

    mesh = MeshHex(np.ascontiguousarray(HEX_CORNERS.T, dtype=float), np.arange(8, dtype=np.int64)[:, None])
    full = Basis(mesh, ElementVector(ElementHex1()), intorder=3)   # 2x2x2 Gauss, exact on cubes
    one = Basis(mesh, ElementVector(ElementHex1()), quadrature=CENTRE_RULE)   # 1 point at the centre
    if not np.array_equal(full.element_dofs[:, 0], np.arange(24)):
        raise RuntimeError("unexpected scikit-fem ElementVector DOF order")  # pragma: no cover
    return full, one


def _dense(A) -> np.ndarray:
    return np.asarray(A.toarray(), dtype=np.float64)


@lru_cache(maxsize=None)
def _skfem_parts() -> dict[str, np.ndarray]:
    """Unit-cube matrices from scikit-fem (read-only arrays)."""
    from skfem import BilinearForm, asm
    from skfem.helpers import dot, trace
    from skfem.models.elasticity import linear_elasticity

    full, one = _unit_cube_bases()

    @BilinearForm
    def divdiv(u, v, w):
        return trace(u.grad) * trace(v.grad)

    @BilinearForm
    def mass(u, v, w):
        return dot(u, v)

    parts = {
        "K_lambda": _dense(asm(linear_elasticity(1.0, 0.0), full)),
        "K_mu": _dense(asm(linear_elasticity(0.0, 1.0), full)),
        "K_vol1": _dense(asm(divdiv, one)),
        "M": _dense(asm(mass, full)),
    }
    # deviatoric part 2 dev(eps):dev(eps) = 2 eps:eps - (2/3) div^2, integrated at 2x2x2
    parts["K_dev"] = parts["K_mu"] - (2.0 / 3.0) * parts["K_lambda"]
    for a in parts.values():
        a.flags.writeable = False
    return parts


# ---------------------------------------------------------------------------------------- public
def reference_stiffness(element: str) -> tuple[np.ndarray, np.ndarray]:
    """Unit-cube matrices ``(K_lambda, K_mu)`` of a linear element, each shape (24, 24).

    A cube of edge ``h`` (m) with Lame parameters ``lambda, mu`` (Pa) has stiffness
    ``h * (lambda * K_lambda + mu * K_mu)`` in N/m.

    Raises
    ------
    InputError
        For ``"q1i"`` (not linear in the Lame parameters; use :func:`element_stiffness`).
    """
    element = check_element(element)
    if element not in LINEAR_ELEMENTS:
        raise InputError("element 'q1i' is not linear in (lambda, mu); use element_stiffness()")
    return _linear_parts(element)


@lru_cache(maxsize=None)
def _linear_parts(element: str) -> tuple[np.ndarray, np.ndarray]:
    """``(K_lambda, K_mu)`` of a linear element, built once per element (read-only)."""
    p = _skfem_parts()
    if element == "q1":
        return p["K_lambda"], p["K_mu"]
    # q1sri: kappa K_vol1 + mu K_dev with kappa = lambda + 2 mu / 3
    k_mu = p["K_dev"] + (2.0 / 3.0) * p["K_vol1"]
    k_mu.flags.writeable = False
    return p["K_vol1"], k_mu


@lru_cache(maxsize=None)
def _linear_rows(element: str) -> np.ndarray:
    """``(2, 576)``: the flattened ``K_lambda`` and ``K_mu`` of a linear element (read-only)."""
    rows = np.stack([k.ravel() for k in _linear_parts(element)])
    rows.flags.writeable = False
    return rows


def reference_mass() -> np.ndarray:
    """Consistent mass matrix of a cube of unit total mass (kg), shape (24, 24).

    Every 3x3 block is ``m_ab I``; the entries of one component sum to 1 (the total mass).
    """
    return _skfem_parts()["M"]


_Q1I_PRECOMPUTE = 2048
"""Up to this many distinct ``lambda / mu`` ratios, :func:`stiffness_chunks` builds all q1i unit
matrices once per call (at most 2048 x 576 floats, 9.4 MB); beyond, per chunk."""


@lru_cache(maxsize=None)
def _q1i_parts() -> dict[str, np.ndarray]:
    """Lambda- and mu-parts of the compatible/incompatible blocks of Wilson's brick (unit cube).

    Compatible gradients come from scikit-fem's basis at the 2x2x2 Gauss points; the 9
    incompatible modes ``(1 - xi_k^2) e_c`` (``xi = 2 x - 1``) are evaluated with numpy.
    Integration at 2x2x2 points is exact on a cube for every product involved.
    """
    full, _ = _unit_cube_bases()
    w = full.dx[0]                                                         # (q,) weights
    gc = np.stack([full.basis[i][0].grad[:, :, 0, :] for i in range(24)])  # (24, 3, 3, q)
    xi = 2.0 * full.X - 1.0                                                # (3, q) reference coords
    gi = np.zeros((9, 3, 3, xi.shape[1]))                                  # mode 3k + c
    for k in range(3):          # loop over the 9 mode definitions, not over elements
        for c in range(3):
            gi[3 * k + c, c, k, :] = -4.0 * xi[k]                          # d/dx_k (1 - xi_k^2)
    g = np.concatenate([gc, gi])                                           # (33, 3, 3, q)
    tr = np.einsum("iccq->iq", g)
    k_lam = np.einsum("q,iq,jq->ij", w, tr, tr)
    k_mu = np.einsum("q,iabq,jabq->ij", w, g, g) + np.einsum("q,iabq,jbaq->ij", w, g, g)
    out = {
        "cc_lambda": k_lam[:24, :24], "cc_mu": k_mu[:24, :24],
        "ci_lambda": k_lam[:24, 24:], "ci_mu": k_mu[:24, 24:],
        "ii_lambda": k_lam[24:, 24:], "ii_mu": k_mu[24:, 24:],
    }
    for a in out.values():
        a.flags.writeable = False
    return out


def q1i_unit_stiffness(ratio) -> np.ndarray:
    """Condensed Wilson-brick stiffness of the unit cube per unit ``mu``.

    Parameters
    ----------
    ratio : array_like, shape (u,) or scalar
        ``lambda / mu = 2 nu / (1 - 2 nu)`` (> -2/3).

    Returns
    -------
    ndarray, shape (u, 24, 24) (or (24, 24) for a scalar)
        ``K(r) = K_cc - K_ci K_ii^{-1} K_ic`` with every block ``r K_lambda + K_mu``.
        A cube of edge ``h`` and shear modulus ``mu`` has ``h * mu * K(r)``.
    """
    r = np.asarray(ratio, dtype=np.float64)
    scalar = r.ndim == 0
    r = np.atleast_1d(r)[:, None, None]
    p = _q1i_parts()
    kcc = r * p["cc_lambda"] + p["cc_mu"]
    kci = r * p["ci_lambda"] + p["ci_mu"]
    kii = r * p["ii_lambda"] + p["ii_mu"]
    k = kcc - kci @ np.linalg.solve(kii, np.swapaxes(kci, 1, 2))
    k = 0.5 * (k + np.swapaxes(k, 1, 2))
    return k[0] if scalar else k


def element_stiffness(element: str, lam, mu, h: float) -> np.ndarray:
    """Stiffness matrices of cubes, vectorized.

    Parameters
    ----------
    element : {"q1", "q1i", "q1sri"}
    lam, mu : array_like, shape (n,)
        Lame parameters per cube, Pa.
    h : float
        Cube edge, m.

    Returns
    -------
    ndarray, shape (n, 24, 24)
        Element stiffness matrices, N/m.
    """
    element = check_element(element)
    lam = np.atleast_1d(np.asarray(lam, dtype=np.float64))
    mu = np.atleast_1d(np.asarray(mu, dtype=np.float64))
    return stiffness_values(element, lam, mu, h).reshape(-1, 24, 24)


def stiffness_chunks(element: str, lam: np.ndarray, mu: np.ndarray, h: float) -> Callable[[int, int], np.ndarray]:
    """Element matrices of cubes ``s:e`` on demand, for the assembler's chunked scatter.

    The per-call work is done once here: the reference rows of a linear element (cached per
    element) or, for ``"q1i"``, the distinct ``lambda / mu`` ratios of all cubes and (up to
    2048 of them) their unit matrices; each chunk then only scales and indexes them. With more
    distinct ratios (per-cube nu) a chunk builds the unit matrices of its own ratios, so the
    memory stays bounded by the chunk size.

    Parameters
    ----------
    element : {"q1", "q1i", "q1sri"}
    lam, mu : ndarray, shape (n,)
        Lame parameters per cube, Pa.
    h : float
        Cube edge, m.

    Returns
    -------
    callable
        ``values(s, e) -> ndarray (e - s, 576)``: flattened (row-major 24x24) matrices, N/m.
    """
    if element in LINEAR_ELEMENTS:
        rows = _linear_rows(element)                                        # (2, 576)
        coef = np.stack([lam * h, mu * h], axis=1)                          # (n, 2)
        return lambda s, e: coef[s:e] @ rows                               # (e - s, 576)
    uniq, inv = np.unique(lam / mu, return_inverse=True)
    inv = inv.ravel()
    muh = mu * h
    if len(uniq) <= _Q1I_PRECOMPUTE:          # a few materials: every unit matrix once, chunks index
        units = q1i_unit_stiffness(uniq).reshape(len(uniq), 576)
        return lambda s, e: muh[s:e, None] * units[inv[s:e]]

    def chunk(s: int, e: int) -> np.ndarray:  # many distinct nu: only this chunk's ratios (bounded memory)
        used, local = np.unique(inv[s:e], return_inverse=True)
        return muh[s:e, None] * q1i_unit_stiffness(uniq[used]).reshape(len(used), 576)[local.ravel()]

    return chunk


def stiffness_values(element: str, lam: np.ndarray, mu: np.ndarray, h: float) -> np.ndarray:
    """Flattened element matrices ``(n, 576)`` (row-major 24x24), N/m."""
    return stiffness_chunks(element, lam, mu, h)(0, len(lam))


# ---------------------------------------------------------------------------------------- finite cell
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
    from ..lattice.moments import monomials

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
    from ..lattice.moments import FULL

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


def cube_stiffness_chunks(model, element: str) -> Callable[[int, int], np.ndarray]:
    """Element matrices of a model's cubes ``s:e`` (flattened, N/m), honouring its partial-cube
    stiffness (:attr:`sc_fem.CubeModel.stiffness`): ``"moments"`` integrates the partly filled
    cubes over their filled region (elements in :data:`MOMENT_ELEMENTS`; others fall back to
    ``"fraction"``), full cubes use the reference matrix."""
    element = check_element(element)
    h = model.h
    if model.stiffness != "moments" or element not in MOMENT_ELEMENTS:
        return stiffness_chunks(element, *model.lame(), h)
    lam, mu = model.lame(material=True)
    ref = stiffness_chunks(element, lam, mu, h)
    partial = model.fraction < PARTIAL_BELOW
    mom = model.moments

    def chunk(s: int, e: int) -> np.ndarray:
        v = np.array(ref(s, e))
        part = s + np.flatnonzero(partial[s:e])
        if len(part):
            v[part - s] = moment_stiffness(element, mom[part], lam[part], mu[part], h)
        return v

    return chunk


def cube_mass_chunks(model, masses: np.ndarray) -> Callable[[int, int], np.ndarray]:
    """Consistent mass matrices (flattened, kg) of a model's cubes ``s:e`` with masses ``masses``
    (n,) kg: partly filled cubes of a ``"moments"`` model distribute their mass like their filled
    region (:func:`moment_mass`), every other cube is ``m_e`` times the reference matrix (as the
    stiffness: a full cube's moments give it up to round-off, at a matrix product per cube)."""
    mref = reference_mass().ravel()
    masses = np.asarray(masses, dtype=np.float64)
    if model.stiffness != "moments":
        return lambda s, e: masses[s:e, None] * mref[None, :]
    partial = model.fraction < PARTIAL_BELOW
    mom = model.moments

    def chunk(s: int, e: int) -> np.ndarray:
        v = masses[s:e, None] * mref[None, :]
        part = s + np.flatnonzero(partial[s:e])
        if len(part):
            v[part - s] = moment_mass(mom[part], masses[part])
        return v

    return chunk


def cube_stiffness(model, element: str) -> np.ndarray:
    """All element matrices of a model, shape (n, 24, 24), N/m (see :func:`cube_stiffness_chunks`)."""
    return cube_stiffness_chunks(model, element)(0, model.n_cubes).reshape(-1, 24, 24)
