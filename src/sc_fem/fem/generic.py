"""scikit-fem's generic assembly of the cube lattice: the reference for the fast scatter.

:func:`sc_fem.fem.assemble.assemble` with ``method="skfem"`` calls :func:`assemble_skfem`; the test
suite holds the fast assembly to it (to 1e-12).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from ..errors import InputError
from ..lattice.cubes import CubeModel
from .hexahedron import CENTRE_RULE


def assemble_skfem(model: CubeModel, element: str, lumped: bool,
                   free: np.ndarray) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """K (N/m) and M (kg) of ``model`` on the ``free`` DOFs (bool mask, shape (3 m,)) by scikit-fem's
    generic form assembly (``ElementVector(ElementHex1())``): the independent reference that the
    fast scatter of :class:`~sc_fem.fem.assemble.Assembler` is tested against (``"q1"``,
    ``"q1sri"``; scikit-fem has no incompatible modes). ``lumped``: row-sum mass.
    """
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
