"""Element reference matrices against slow loop-based oracles and element invariants."""

from __future__ import annotations

import numpy as np
import pytest

import sc_fem
from sc_fem.fem import elements as E
from sc_fem.errors import InputError
from sc_fem.lattice.cubes import HEX_CORNERS

GAUSS = np.array([-1.0, 1.0]) / np.sqrt(3.0)
SIGN = 2 * HEX_CORNERS - 1          # corner a at xi = SIGN[a] on [-1, 1]^3


# ------------------------------------------------------------------ loop-based oracle
def _dN_dx(xi):
    """Gradients (8, 3) of the trilinear shape functions on the unit cube (x = (xi + 1) / 2)."""
    g = np.zeros((8, 3))
    for a in range(8):
        for k in range(3):
            v = 1.0
            for l in range(3):
                v *= SIGN[a, l] / 8.0 if l == k else (1.0 + SIGN[a, l] * xi[l])
            g[a, k] = 2.0 * v
    return g


def _voigt_B(grads):
    """Voigt strain-displacement matrix (6, 3 n) for vector fields e_c * phi, phi with gradients (n, 3)."""
    n = len(grads)
    B = np.zeros((6, 3 * n))
    for a in range(n):
        gx, gy, gz = grads[a]
        B[0, 3 * a + 0] = gx
        B[1, 3 * a + 1] = gy
        B[2, 3 * a + 2] = gz
        B[3, 3 * a + 1], B[3, 3 * a + 2] = gz, gy     # gamma_yz
        B[4, 3 * a + 0], B[4, 3 * a + 2] = gz, gx     # gamma_xz
        B[5, 3 * a + 0], B[5, 3 * a + 1] = gy, gx     # gamma_xy
    return B


M_VEC = np.array([1.0, 1, 1, 0, 0, 0])
I_V = np.diag([1.0, 1, 1, 0.5, 0.5, 0.5])


def _D(lam, mu):
    return lam * np.outer(M_VEC, M_VEC) + 2 * mu * I_V


def _gauss_points():
    for i in GAUSS:
        for j in GAUSS:
            for k in GAUSS:
                yield np.array([i, j, k]), 1.0 / 8.0   # weight 1 times det J = 1/8


def oracle_q1(lam, mu):
    K = np.zeros((24, 24))
    for xi, w in _gauss_points():
        B = _voigt_B(_dN_dx(xi))
        K += w * B.T @ _D(lam, mu) @ B
    return K


def oracle_q1sri(lam, mu):
    kappa = lam + 2 * mu / 3
    K = np.zeros((24, 24))
    for xi, w in _gauss_points():
        B = _voigt_B(_dN_dx(xi))
        K += w * B.T @ (2 * mu * (I_V - np.outer(M_VEC, M_VEC) / 3)) @ B
    B0 = _voigt_B(_dN_dx(np.zeros(3)))
    K += 1.0 * B0.T @ (kappa * np.outer(M_VEC, M_VEC)) @ B0
    return K


def oracle_q1i(lam, mu):
    Kcc, Kci, Kii = np.zeros((24, 24)), np.zeros((24, 9)), np.zeros((9, 9))
    D = _D(lam, mu)
    for xi, w in _gauss_points():
        Bc = _voigt_B(_dN_dx(xi))
        gi = np.zeros((3, 3))
        for k in range(3):
            gi[k, k] = -2.0 * xi[k] * 2.0          # d/dx_k (1 - xi_k^2), dxi/dx = 2
        Bi = _voigt_B(gi)
        Kcc += w * Bc.T @ D @ Bc
        Kci += w * Bc.T @ D @ Bi
        Kii += w * Bi.T @ D @ Bi
    return Kcc - Kci @ np.linalg.solve(Kii, Kci.T)


def oracle_mass():
    M = np.zeros((24, 24))
    for xi, w in _gauss_points():
        N = np.array([np.prod(1 + SIGN[a] * xi) / 8 for a in range(8)])
        for a in range(8):
            for b in range(8):
                for c in range(3):
                    M[3 * a + c, 3 * b + c] += w * N[a] * N[b]
    return M


ORACLES = {"q1": oracle_q1, "q1sri": oracle_q1sri, "q1i": oracle_q1i}


# ------------------------------------------------------------------ tests
@pytest.mark.parametrize("element", E.ELEMENTS)
@pytest.mark.parametrize("lam_mu", [(1.0, 1.0), (3.7e9, 1.3e9), (0.2, 2.0)])
def test_element_matches_loop_oracle(element, lam_mu):
    lam, mu = lam_mu
    K = E.element_stiffness(element, [lam], [mu], 1.0)[0]
    ref = ORACLES[element](lam, mu)
    assert np.abs(K - ref).max() <= 1e-12 * np.abs(ref).max()


def test_mass_matches_oracle_and_unit_total():
    M = E.reference_mass()
    assert np.abs(M - oracle_mass()).max() < 1e-15
    assert M[0::3, 0::3].sum() == pytest.approx(1.0, rel=1e-14)
    # no coupling between components
    assert np.all(M[0::3, 1::3] == 0)


def _rigid_modes():
    X = HEX_CORNERS.astype(float) - 0.5
    R = np.zeros((24, 6))
    for c in range(3):
        R[c::3, c] = 1.0
    for k, (i, j) in enumerate([(1, 2), (2, 0), (0, 1)]):   # rotation in the (i, j) plane
        R[i::3, 3 + k] = -X[:, j]
        R[j::3, 3 + k] = X[:, i]
    return R


@pytest.mark.parametrize("element", E.ELEMENTS)
@pytest.mark.parametrize("nu", [0.0, 0.3, 0.49])
def test_invariants_symmetric_psd_six_rigid_modes(element, nu):
    lam, mu = nu / ((1 + nu) * (1 - 2 * nu)), 1 / (2 * (1 + nu))
    K = E.element_stiffness(element, [lam], [mu], 1.0)[0]
    assert np.array_equal(K, K.T)
    ev = np.linalg.eigvalsh(K)
    tol = 1e-12 * ev[-1]
    assert ev[0] > -tol
    assert np.count_nonzero(ev < tol) == 6
    assert ev[6] > 1e-4 * ev[-1]
    assert np.abs(K @ _rigid_modes()).max() < 1e-13 * ev[-1]


@pytest.mark.parametrize("element", E.ELEMENTS)
def test_constant_strain_gives_consistent_nodal_forces(element):
    """Single-cube patch check: a uniform strain field yields the traction forces of sigma."""
    rng = np.random.default_rng(3)
    G = rng.normal(size=(3, 3))
    lam, mu = 1.7, 0.9
    X = HEX_CORNERS.astype(float)
    u = X @ G.T                                         # u = G x, eps = sym(G)
    f = (E.element_stiffness(element, [lam], [mu], 1.0)[0] @ u.ravel()).reshape(8, 3)
    eps = 0.5 * (G + G.T)
    sig = lam * np.trace(eps) * np.eye(3) + 2 * mu * eps
    # nodal force of a constant stress on the unit cube: f_a = sigma . (integral of grad N_a) = sigma n_a / 4
    expected = ((2 * X - 1) / 4.0) @ sig.T
    assert np.abs(f - expected).max() < 1e-13 * np.abs(expected).max()


def test_q1i_homogeneous_in_lame_and_batched():
    nus = np.array([-0.5, 0.0, 0.25, 0.3, 0.45])
    lam, mu = 2 * nus / (1 - 2 * nus), np.ones_like(nus)
    Ks = E.element_stiffness("q1i", 3.0 * lam, 3.0 * mu, 0.5)
    for i in range(len(nus)):                           # loop: oracle per material
        assert np.allclose(Ks[i], 1.5 * oracle_q1i(lam[i], 1.0), rtol=0, atol=1e-12 * np.abs(Ks[i]).max())
    assert E.q1i_unit_stiffness(0.5).shape == (24, 24)


@pytest.mark.parametrize("element", E.ELEMENTS)
@pytest.mark.parametrize("precompute", [2048, 3])
def test_stiffness_chunks_match_loop_oracle(element, precompute, monkeypatch):
    """Chunked values == per-cube oracle, for q1i both with all unit matrices built once (few
    distinct nu) and per chunk (more distinct nu than ``_Q1I_PRECOMPUTE``)."""
    monkeypatch.setattr(E, "_Q1I_PRECOMPUTE", precompute)
    rng = np.random.default_rng(5)
    nu = rng.choice([0.1, 0.3, 0.3, 0.45, -0.2, 0.0, 0.25], size=9)    # repeats and > 3 distinct
    mu = rng.uniform(0.5, 2.0, size=9)
    lam = 2 * mu * nu / (1 - 2 * nu)
    values = E.stiffness_chunks(element, lam, mu, 0.7)
    for s, e in ((0, 4), (4, 9)):                                        # two chunks
        got = values(s, e).reshape(-1, 24, 24)
        for k in range(s, e):                                            # loop: oracle per cube
            ref = 0.7 * ORACLES[element](lam[k], mu[k])
            assert np.abs(got[k - s] - ref).max() <= 1e-12 * np.abs(ref).max()


def test_q1i_is_softer_than_q1_in_bending():
    """Incompatible modes only add deformation freedom: K_q1 - K_q1i is PSD and nonzero."""
    d = E.element_stiffness("q1", [1.0], [1.0], 1.0)[0] - E.element_stiffness("q1i", [1.0], [1.0], 1.0)[0]
    ev = np.linalg.eigvalsh(d)
    assert ev[0] > -1e-12 and ev[-1] > 0.1


def test_bad_element_names():
    with pytest.raises(InputError, match="element must be one of"):
        E.check_element("q2")
    with pytest.raises(InputError, match="not linear"):
        E.reference_stiffness("q1i")
    assert E.check_element(E.DEFAULT_ELEMENT.upper()) == E.DEFAULT_ELEMENT    # case-insensitive


@pytest.mark.parametrize("element", ["q1", "q1i"])
def test_partly_filled_cubes_pass_the_patch_test(element):
    """A uniform strain stores exactly int_fill a(eps, eps) dV in every partly filled cube (the
    integral of a constant over the filled volume), for q1 and for q1i after condensing its
    incompatible modes (which a uniform strain must not excite: before the correction some sliver
    cubes of this sphere kept only 5 % of that energy)."""
    import trimesh

    from sc_fem.fem.elements import moment_stiffness
    from sc_fem.lattice.cubes import HEX_CORNERS

    m = sc_fem.voxelize(trimesh.creation.icosphere(3, 0.5), resolution=8, fill="solid")
    part = np.flatnonzero(m.fraction < 1 - 1e-9)
    assert len(part) > 50
    lam, mu = m.lame(material=True)
    eps = np.array([[1e-3, 2e-4, 0.0], [2e-4, -5e-4, 1e-4], [0.0, 1e-4, 3e-4]])
    u = (HEX_CORNERS * m.h @ eps.T).ravel()
    k = moment_stiffness(element, m.moments[part], lam[part], mu[part], m.h).reshape(-1, 24, 24)
    energy = np.einsum("i,nij,j->n", u, k, u)
    density = lam[part] * np.trace(eps) ** 2 + 2 * mu[part] * np.sum(eps * eps)     # a(eps, eps), J/m^3
    from sc_fem.fem.elements import FCM_ALPHA

    volume = (m.moments[part, 0] + FCM_ALPHA) * m.h ** 3                # filled + the FCM share of the cube
    np.testing.assert_allclose(energy, density * volume, rtol=1e-9)


@pytest.mark.parametrize("element", ["q1", "q1i"])
def test_patch_test_holds_for_a_millimetre_part_far_from_the_origin(element):
    """The same patch test on a sphere of radius 500 mm centred at (1, -2, 5) m: the moments are
    taken relative to each cube and ``h`` is the edge in metres (pitch x scale), so the energy
    density times the filled volume in m^3 must still come out exactly."""
    import trimesh

    from sc_fem.fem.elements import FCM_ALPHA, moment_stiffness
    from sc_fem.lattice.cubes import HEX_CORNERS

    s = trimesh.creation.icosphere(3, 500.0)
    s.apply_translation((1e3, -2e3, 5e3))
    m = sc_fem.voxelize(s, resolution=8, fill="solid", scale=1e-3)
    assert m.h == pytest.approx(m.pitch * 1e-3)
    part = np.flatnonzero(m.fraction < 1 - 1e-9)
    lam, mu = m.lame(material=True)
    eps = np.array([[1e-3, 2e-4, 0.0], [2e-4, -5e-4, 1e-4], [0.0, 1e-4, 3e-4]])
    u = (HEX_CORNERS * m.h @ eps.T).ravel()
    k = moment_stiffness(element, m.moments[part], lam[part], mu[part], m.h).reshape(-1, 24, 24)
    energy = np.einsum("i,nij,j->n", u, k, u)
    density = lam[part] * np.trace(eps) ** 2 + 2 * mu[part] * np.sum(eps * eps)
    np.testing.assert_allclose(energy, density * (m.moments[part, 0] + FCM_ALPHA) * m.h ** 3, rtol=1e-9)


def test_cube_mass_chunks_equal_the_per_cube_formulas():
    """Loop oracle: full cubes get exactly m_e times the reference mass matrix, partly filled
    ones their moment mass; each cube keeps its mass (1^T M_e 1 per direction = m_e)."""
    import trimesh

    m = sc_fem.voxelize(trimesh.creation.icosphere(3, 0.5), resolution=8, fill="solid")
    assert m.stiffness == "moments"
    partial = m.fraction < E.PARTIAL_BELOW
    assert 0 < partial.sum() < m.n_cubes
    got = E.cube_mass_chunks(m, m.mass)(0, m.n_cubes)
    ref = E.reference_mass().ravel()
    for c in range(m.n_cubes):                                         # loop over cubes: the oracle
        if partial[c]:       # a batched matrix product: equal up to its rounding
            want = E.moment_mass(m.moments[c:c + 1], m.mass[c:c + 1])[0]
            np.testing.assert_allclose(got[c], want, rtol=0, atol=1e-10 * np.abs(want).max())
        else:
            np.testing.assert_array_equal(got[c], m.mass[c] * ref)
    per_dir = got.reshape(-1, 8, 3, 8, 3)[:, :, 0, :, 0].sum(axis=(1, 2))
    np.testing.assert_allclose(per_dir, m.mass, rtol=1e-12)
    # and a full cube's moment mass is the reference one up to round-off (why full cubes skip it)
    full = np.flatnonzero(~partial)[:5]
    np.testing.assert_allclose(E.moment_mass(m.moments[full], m.mass[full]), got[full], rtol=1e-12,
                               atol=1e-13 * np.abs(got[full]).max())
