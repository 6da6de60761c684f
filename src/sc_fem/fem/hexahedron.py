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

Partly filled cubes integrate the same elements over their filled region
(:mod:`sc_fem.fem.finite_cell`); :mod:`sc_fem.fem.elements` scales these unit-cube matrices into
the matrices of a model's cubes.
"""

from __future__ import annotations

from functools import lru_cache

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
