"""The batched kernels of the PDE fit (sc_fem.reconstruct.varpro and the fast paths of pde, rigid,
segments, basis) against simple loop oracles: explicit 32-column least squares per curve and
coordinate, explicit leave-one-out refits, per-frame Kabsch, per-point averaging of pieces."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sc_fem import reconstruct as R
from sc_fem.reconstruct import varpro as V
from sc_fem.reconstruct.basis import space_basis_rates, time_basis_rates
from sc_fem.errors import InputError
from sc_fem.reconstruct.pde import SEARCH_POINTS
from sc_fem.reconstruct.segments import fit_segmented


def _data(n_curves=3, n_frames=6, n_points=40, shared=True, seed=0):
    """Smooth random curves (F, C, P, 3), their parameter values (C, P) and normalised times."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, n_frames)
    u = np.linspace(0.0, 1.0, n_points)
    u = np.tile(u, (n_curves, 1)) if shared else np.sort(rng.random((n_curves, n_points)), axis=1)
    a = rng.normal(size=(n_curves, 3, 4))
    x = np.stack([np.stack([a[c, w, 0] * u[c] + a[c, w, 1] * np.sin(2 * u[c] + s[f]) + a[c, w, 2] * u[c] ** 2 * s[f]
                            + a[c, w, 3] * np.cos(3 * s[f]) * u[c] ** 3 for w in range(3)], axis=-1)
                  for f in range(n_frames) for c in range(n_curves)]).reshape(n_frames, n_curves, n_points, 3)
    return x + 0.01 * rng.normal(size=x.shape), u, s


def _design(u_c, s, r, alpha):
    """The 32-column design matrix of Eq. 25 for one curve, rows (frame, point): kron(T, U)."""
    return np.kron(R.time_basis(s, alpha), R.space_basis(u_c, r))


def _lstsq_residual(x, u, s, r, alpha):
    """Loop oracle: sum of squared residuals of per-curve, per-coordinate 32-column least squares."""
    total = 0.0
    for c, w in itertools.product(range(x.shape[1]), range(3)):     # slow oracle loop
        a = _design(u[c], s, r, alpha)
        rhs = x[:, c, :, w].ravel()
        sol = np.linalg.lstsq(a, rhs, rcond=None)[0]
        total += float(np.sum((a @ sol - rhs) ** 2))
    return total


RATES = np.array([1.2, 2.5, 4.0])
ALPHAS = np.array([0.6, 1.5, 2.7, 3.1])


@pytest.mark.parametrize("shared,n_frames", [(True, 6), (False, 6), (True, 3), (False, 2)])
def test_residual_grid_equals_explicit_lstsq_loop(shared, n_frames):
    x, u, s = _data(shared=shared, n_frames=n_frames)      # < 4 frames: fewer than 4 time singular values
    data = V.FitData.build(x, u)
    assert data.shared == shared and data.u_rows.shape[0] == (1 if shared else 3)
    grid = V.residual(V.space_side(data, RATES), V.time_side(s, ALPHAS), 1e-11)
    oracle = np.array([[_lstsq_residual(x, u, s, r, a) for a in ALPHAS] for r in RATES])
    np.testing.assert_allclose(grid, oracle, rtol=1e-9)


@pytest.mark.parametrize("shared,n_frames", [(True, 6), (False, 6), (True, 4)])
def test_leave_one_out_grid_equals_explicit_refits(shared, n_frames):
    x, u, s = _data(shared=shared, n_frames=n_frames, seed=1)
    data = V.FitData.build(x, u)
    grid = V.leave_one_out(V.space_side(data, RATES[1:]), s, ALPHAS[1:], 1e-11)
    oracle = np.zeros((2, 3))
    for (i, r), (k, a) in itertools.product(enumerate(RATES[1:]), enumerate(ALPHAS[1:])):
        for j in range(1, len(s) - 1):                                 # slow oracle loops
            keep = np.arange(len(s)) != j
            for c, w in itertools.product(range(x.shape[1]), range(3)):
                # columns scaled to unit norm on the kept frames: with fewer kept frames than time
                # functions the prediction is the minimum-norm one in these columns
                a_keep = _design(u[c], s[keep], r, a)
                norm = np.linalg.norm(a_keep, axis=0)
                sol = np.linalg.lstsq(a_keep / norm, x[keep, c, :, w].ravel(), rcond=None)[0] / norm
                oracle[i, k] += float(np.sum((_design(u[c], s[j:j + 1], r, a) @ sol - x[j, c, :, w]) ** 2))
    np.testing.assert_allclose(grid, oracle, rtol=1e-8)


@pytest.mark.parametrize("shared", [True, False])
def test_batched_fit_equals_per_curve_lstsq(shared):
    x, u, s = _data(n_curves=4, shared=shared, seed=2)
    m = R.fit(x, s, r=2.2, alpha=1.3, remove_rigid=False, u=u)
    t_new = np.array([0.0, 0.13, 0.5, 0.77, 1.0])
    out = m.evaluate(t_new)
    scale = np.abs(x).max()
    resid = 0.0
    for c, w in itertools.product(range(4), range(3)):                 # slow oracle loop
        sol = np.linalg.lstsq(_design(u[c], s, 2.2, 1.3), x[:, c, :, w].ravel(), rcond=None)[0]
        np.testing.assert_allclose(out[:, c, :, w], (_design(u[c], t_new, 2.2, 1.3) @ sol).reshape(5, -1),
                                   atol=1e-10 * scale, rtol=0)
        resid += float(np.sum((_design(u[c], s, 2.2, 1.3) @ sol - x[:, c, :, w].ravel()) ** 2))
    np.testing.assert_allclose(m.residual_rms, np.sqrt(resid / x.size), rtol=1e-8)


def test_parameter_rows_equal_to_rounding_share_one_basis():
    x, u, s = _data(n_curves=3, shared=True, seed=3)
    bumped = u.copy()
    bumped[1, 1:-1] += 2e-16 * (np.arange(u.shape[1] - 2) % 2)         # rounding-level differences
    assert V.space_rows(bumped).shape[0] == 1
    assert V.space_rows(u + np.array([[0.0], [1e-9], [0.0]])).shape[0] == 3
    a = R.fit(x, s, r=2.0, alpha=1.0, remove_rigid=False, u=bumped)
    scale = np.abs(x).max()
    for c in range(3):                                                 # each curve alone, its own u
        one = R.fit(x[:, c:c + 1], s, r=2.0, alpha=1.0, remove_rigid=False, u=bumped[c])
        np.testing.assert_allclose(a.evaluate(s)[:, c], one.evaluate(s)[:, 0], atol=1e-10 * scale, rtol=0)


def test_rate_batched_bases_equal_the_scalar_ones():
    u, t = np.random.default_rng(4).random((3, 11)), np.linspace(0, 1, 7)
    rates, alphas = np.array([0.2, 3.0, 30.0]), np.array([0.05, 1.0, 15.7])
    for k, r in enumerate(rates):
        np.testing.assert_allclose(space_basis_rates(u, rates)[k], R.space_basis(u, r), rtol=0, atol=1e-14)
    for k, a in enumerate(alphas):
        np.testing.assert_allclose(time_basis_rates(t, alphas)[k], R.time_basis(t, a), rtol=0, atol=1e-14)


def test_search_reports_the_objective_of_the_rates_it_returns():
    x, u, s = _data(n_curves=2, shared=True, seed=5)
    m = R.fit(x, s, remove_rigid=False, u=u, grid=(8, 8))
    assert m.search.best_objective <= m.search.objective.min()
    np.testing.assert_allclose(m.search.best_objective, m.residual_rms ** 2 * x.size, rtol=1e-6)
    # the refined alpha is a local minimum at the refined r
    data = V.FitData.build(x, u)
    f = V.residual(V.space_side(data, [m.r]), V.time_side(s, m.alpha * np.array([0.99, 1.0, 1.01])), 1e-11)[0]
    assert f[1] <= f[0] and f[1] <= f[2]


@pytest.mark.parametrize("shared", [True, False])
def test_search_on_a_subset_of_points_then_constants_from_all(shared):
    x, u, s = _data(n_curves=2, n_points=200, shared=shared, seed=6)
    m = R.fit(x, s, remove_rigid=False, u=u, grid=(8, 8))
    pts = m.search.points
    assert len(pts) == SEARCH_POINTS and pts[0] == 0 and pts[-1] == 199 and np.all(np.diff(pts) > 0)
    # the objective the search reports is the residual of the fit to those points alone ...
    sub = R.fit(x[:, :, pts], s, r=m.r, alpha=m.alpha, remove_rigid=False, u=u[:, pts])
    np.testing.assert_allclose(m.search.best_objective, sub.residual_rms ** 2 * x[:, :, pts].size, rtol=1e-6)
    # ... while the constants are the least squares of all points at the (r, alpha) found
    full = R.fit(x, s, r=m.r, alpha=m.alpha, remove_rigid=False, u=u)
    np.testing.assert_allclose(m.coefficients, full.coefficients, rtol=0, atol=1e-10 * np.abs(full.coefficients).max())
    every = R.fit(x, s, remove_rigid=False, u=u, grid=(8, 8), search_points=None)
    assert len(every.search.points) == 200
    for bad in (7, 2.5, 0, "64", True):
        with pytest.raises(InputError, match="search_points"):
            R.fit(x, s, remove_rigid=False, u=u, search_points=bad)


@pytest.mark.parametrize("noise", [1e-2, 0.0])
def test_residual_rms_equals_the_pointwise_residual(noise):
    """Noisy data takes the |X|^2 - |fit|^2 path, data the model fits exactly the pointwise one;
    both equal the RMS of the curves minus the evaluated fit."""
    x, u, s = _data(n_curves=3, n_points=50, seed=7)
    if noise == 0.0:
        x = R.fit(x, s, r=2.0, alpha=1.0, remove_rigid=False, u=u).evaluate_aligned(s)
    m = R.fit(x, s, r=2.0, alpha=1.0, remove_rigid=False, u=u)
    direct = np.sqrt(np.mean((m.evaluate_aligned(s) - x) ** 2))
    np.testing.assert_allclose(m.residual_rms, direct, rtol=1e-8, atol=1e-14 * np.abs(x).max())
    assert (m.residual_rms > 1e-3) == (noise > 0)


def test_remove_rigid_equals_per_frame_kabsch_loop():
    rng = np.random.default_rng(6)
    x = rng.normal(size=(4, 3, 25, 3)).cumsum(axis=2)                  # (F, C, P, 3) random walks
    al = R.remove_rigid(x)
    for f, c in itertools.product(range(4), range(3)):                 # slow oracle loop
        q, p = x[f, c] - x[f, c, 0], x[0, c] - x[0, c, 0]
        lam = 1e-6 * np.sum(np.linalg.norm(q, axis=1) * np.linalg.norm(p, axis=1))
        uu, _, vt = np.linalg.svd(q.T @ p + lam * np.eye(3))
        rot = vt.T @ np.diag([1, 1, np.sign(np.linalg.det(vt.T @ uu.T))]) @ uu.T
        if f == 0:
            rot = np.eye(3)
        np.testing.assert_allclose(al.rotations[f, c], rot, atol=1e-12)
        np.testing.assert_allclose(al.aligned[f, c], x[0, c, 0] + q @ rot.T, atol=1e-12)
    np.testing.assert_allclose(R.kabsch(x[1:] - x[1:, :, :1], x[0] - x[0, :, :1]), al.rotations[1:], atol=1e-12)


@pytest.mark.parametrize("offset", ["none", "first"])
def test_evaluate_rotating_the_constants_equals_to_world(offset):
    t = np.linspace(0, 1, 11)
    x = np.stack([np.stack([np.linspace(0, 1, 30), 0.1 * np.sin(2 * tt) * np.linspace(0, 1, 30) ** 2,
                            np.zeros(30)], -1) for tt in t])[:, None].repeat(2, axis=1)
    rot = Rotation.from_rotvec(np.outer(np.sin(2.5 * t), [0, 0, 0.6])).as_matrix()
    x = np.einsum("fij,fcpj->fcpi", rot, x) + (np.array([0.0, 0.2, 0.0]) * np.arange(2)[:, None])[:, None, :]
    m = R.fit(x[::2], t[::2], r=2.0, alpha=1.0, offset=offset)
    s = m.normalize(t)
    np.testing.assert_allclose(m.evaluate(t), m.rigid.to_world(m.evaluate_aligned(t), s), atol=1e-13)
    np.testing.assert_allclose(m.evaluate(0.37), m.rigid.to_world(m.evaluate_aligned(np.array([0.37])), [0.37])[0],
                               atol=1e-13)


@pytest.mark.parametrize("n_points,n_segments", [(60, 2), (61, 3), (50, 4)])
def test_segmented_evaluate_equals_per_point_average_of_pieces(n_points, n_segments):
    t = np.linspace(0, 1, 11)
    u = np.linspace(0, 1, n_points)
    x = np.stack([np.stack([u, 0.1 * np.sin(2 * tt + 3 * u), 0.05 * u ** 2 * tt], -1) for tt in t])[:, None]
    x = np.concatenate([x, 0.5 * x], axis=1)
    m = fit_segmented(x[::2], t[::2], n_segments, r=2.0, alpha=1.0)
    out = m.evaluate(t)
    pieces = m.model.evaluate(t).reshape(11, 2, n_segments, -1, 3)
    for c, k in itertools.product(range(2), range(n_points)):          # slow oracle loop
        owners = [(s, int(np.flatnonzero(m.index[s] == k)[0])) for s in range(n_segments) if k in m.index[s]]
        expect = np.mean([pieces[:, c, s, j] for s, j in owners], axis=0)
        np.testing.assert_allclose(out[:, c, k], expect, atol=1e-13)


def test_spline_weights_equal_the_cubic_spline_of_the_values():
    from scipy.interpolate import CubicSpline

    from sc_fem.reconstruct.rigid import spline_weights

    rng = np.random.default_rng(7)
    knots, s = np.sort(rng.random(6)), np.linspace(-0.1, 1.1, 9)
    y = rng.normal(size=(6, 4, 3))
    w = spline_weights(knots, s)
    for k in range(4):                                                 # one spline per column
        np.testing.assert_allclose(w @ y[:, k], CubicSpline(knots, y[:, k], axis=0)(s), atol=1e-12)


@pytest.mark.parametrize("shared", [True, False])
def test_world_evaluate_equals_per_point_rigid_motion_loop(shared):
    x, u, s = _data(n_curves=3, shared=shared, seed=8)
    rot = Rotation.from_rotvec(np.outer(s, [0.3, -0.2, 0.5])).as_matrix()
    x = np.einsum("fij,fcpj->fcpi", rot, x) + 0.1 * s[:, None, None, None]
    m = R.fit(x, s, r=2.0, alpha=1.2, u=u)
    t_new = np.array([0.05, 0.3, 0.62, 0.9])
    out = m.evaluate(t_new)
    aligned = m.evaluate_aligned(t_new)
    rots, anchors = m.rigid.at(t_new)
    for f, c in itertools.product(range(len(t_new)), range(3)):        # slow oracle loop
        for p in range(x.shape[2]):
            expect = anchors[f, c] + rots[f, c].T @ (aligned[f, c, p] - m.rigid.pivot[c])
            np.testing.assert_allclose(out[f, c, p], expect, atol=1e-12)


def test_rotation_vectors_equal_scipy_at_every_angle():
    """Loop-free rotation vectors of the cubic rigid interpolation vs scipy, for random rotations
    and angles near 0 and near pi (where the quaternion formula must switch branches)."""
    from sc_fem.reconstruct.rigid import rotvec_from_matrix

    rng = np.random.default_rng(8)
    axes = rng.normal(size=(200, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([np.geomspace(1e-12, 1e-2, 100), np.pi - np.geomspace(1e-12, 1e-2, 100)])
    for rot in (Rotation.random(500, random_state=9), Rotation.from_rotvec(axes * angles[:, None])):
        m = rot.as_matrix()
        got = rotvec_from_matrix(m.reshape(5, -1, 3, 3)).reshape(-1, 3)     # any leading shape
        ref = rot.as_rotvec()
        np.testing.assert_allclose(Rotation.from_rotvec(got).as_matrix(), m, rtol=0, atol=1e-14)
        near_pi = np.linalg.norm(ref, axis=1) > np.pi - 1e-6                 # axis sign free at pi
        np.testing.assert_allclose(got[~near_pi], ref[~near_pi], rtol=0, atol=1e-14)
