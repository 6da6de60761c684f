"""Explicit central differences: the stability limit dt_crit = 2 / omega_max, and what happens around it."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import eigh

from sc_fem.lattice.boundary import fixed_nodes
from sc_fem.errors import InstabilityError
from sc_fem.dynamics import record, simulate
from sc_fem.dynamics.base import critical_time_step, max_frequency
from sc_fem.dynamics.central import CentralDifference
from sc_fem.dynamics.loads import Gravity, LoadSet
from sc_fem.dynamics.newmark import Newmark
from sc_fem.lattice.cubes import CubeModel


def cantilever():
    m = CubeModel.box((6, 2, 2), 0.05, youngs=1e7, poisson=0.3, density=1000.0)
    return m, fixed_nodes(m, "x<min+0")


def test_omega_max_matches_dense_eigenvalues():
    m, fx = cantilever()
    integ = CentralDifference(m, 1e-5, fixed_nodes=fx)
    w2 = eigh(integ.K.toarray(), integ.M.toarray(), eigvals_only=True)
    assert max_frequency(integ.K, integ.M) == pytest.approx(np.sqrt(w2.max()), rel=1e-6)
    assert integ.dt_crit == pytest.approx(2.0 / np.sqrt(w2.max()), rel=1e-6)
    # every integrator reports the same explicit limit (built with the lumped mass even when its
    # own mass is consistent)
    assert Newmark(m, 1e-5, fixed_nodes=fx).dt_crit == pytest.approx(integ.dt_crit, rel=1e-6)
    # scaling: dt_crit ~ h / c_p, so halving the cube size halves it
    m2 = CubeModel.box((12, 4, 4), 0.025, youngs=1e7, poisson=0.3, density=1000.0)
    dt2 = critical_time_step(*_km(m2))
    assert dt2 / integ.dt_crit == pytest.approx(0.5, rel=0.03)


def _km(m):
    i = CentralDifference(m, 1.0, fixed_nodes=fixed_nodes(m, "x<min+0"))
    return i.K, i.M


def _mech_energy(integ, factor, n_steps=3000):
    integ_dt = factor * integ.dt_crit
    m, fx = integ.model, integ.fixed_nodes
    run = CentralDifference(m, integ_dt, fixed_nodes=fx, loads=LoadSet(m, [Gravity()]))
    return record(run, n_steps, check=False).mechanical


def test_stable_just_below_dt_crit_and_grows_just_above():
    m, fx = cantilever()
    base = CentralDifference(m, 1.0, fixed_nodes=fx)
    below = _mech_energy(base, 0.98)
    above = _mech_energy(base, 1.02)
    assert np.all(np.isfinite(below))
    early, late = below[: len(below) // 3].max(), below[-len(below) // 3:].max()
    assert late < 1.05 * early                          # bounded
    assert not np.all(np.isfinite(above)) or above[-1] > 1e6 * above[: len(above) // 3].max()


def test_blow_up_is_reported_with_step_and_dt_crit():
    m, fx = cantilever()
    base = CentralDifference(m, 1.0, fixed_nodes=fx)
    run = CentralDifference(m, 1.5 * base.dt_crit, fixed_nodes=fx, loads=LoadSet(m, [Gravity()]))
    with pytest.raises(InstabilityError, match=r"central blew up at step \d+ .*dt_crit = .* s \(dt / dt_crit = 1.5\)"):
        for _ in simulate(run, 2000):
            pass


def test_agrees_with_newmark_for_small_steps():
    m, fx = cantilever()
    ld = LoadSet(m, [Gravity()])
    c = CentralDifference(m, 1.0, fixed_nodes=fx)
    dt = 0.2 * c.dt_crit
    n = 2000
    a = record(CentralDifference(m, dt, fixed_nodes=fx, loads=ld), n).u[-1]
    b = record(Newmark(m, dt, fixed_nodes=fx, loads=ld, lumped=True), n).u[-1]
    assert np.linalg.norm(a - b) < 2e-2 * np.linalg.norm(b)
