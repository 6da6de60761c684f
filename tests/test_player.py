"""Modal playback: exact oscillator solution vs an ODE oracle, decay at the stored damping, impulses."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from sc_fem.errors import InputError
from sc_fem.lattice.cubes import CubeModel
from sc_fem import modal
from sc_fem.modes.player import ModalPlayer, transition


@pytest.fixture(scope="module")
def basis():
    m = CubeModel.box((6, 2, 2), 0.05, youngs=1e7, poisson=0.3, density=1000.0)
    return modal(m, n_modes=4, fix="x<min+0", damping=[0.02, 0.05, 1.0, 2.0])


@pytest.mark.parametrize("zeta", [0.0, 0.05, 0.7, 1.0, 2.5])
def test_transition_matches_ode_oracle(zeta):
    w, q0, v0 = 7.0, 0.2, -1.3
    ts = np.array([0.0, 0.31, 1.1, 2.7])
    a, b, c, d = transition(np.array([w]), np.array([zeta]), ts)
    sol = solve_ivp(lambda t, y: [y[1], -2 * zeta * w * y[1] - w * w * y[0]], (0, ts[-1]), [q0, v0],
                    t_eval=ts, rtol=1e-11, atol=1e-13)
    np.testing.assert_allclose(a[:, 0] * q0 + b[:, 0] * v0, sol.y[0], atol=1e-9)
    np.testing.assert_allclose(c[:, 0] * q0 + d[:, 0] * v0, sol.y[1], atol=1e-8)


def test_rigid_mode_drifts_freely():
    a, b, c, d = transition(np.array([0.0]), np.array([0.0]), np.array([0.0, 2.0]))
    np.testing.assert_allclose([a[1, 0], b[1, 0], c[1, 0], d[1, 0]], [1.0, 2.0, 0.0, 1.0])


def test_playback_decays_at_the_stored_damping(basis):
    p = ModalPlayer(basis)
    p.excite(0, 0.001)
    w, z = basis.omegas[0], basis.damping[0]
    fps = 40 * basis.frequencies[0]
    frames = p.frames(duration=6 / basis.frequencies[0], fps=fps, dtype=np.float64)
    u = frames - basis.vertices[None]
    v = int(np.argmax(np.linalg.norm(basis.modes[0], axis=1)))
    x = u[:, v, np.argmax(np.abs(basis.modes[0, v]))]
    peaks = np.flatnonzero((x[1:-1] > x[:-2]) & (x[1:-1] >= x[2:])) + 1
    assert len(peaks) >= 4
    # logarithmic decrement between successive positive peaks: 2 pi zeta / sqrt(1 - zeta^2)
    delta = np.log(x[peaks[:-1]] / x[peaks[1:]])
    np.testing.assert_allclose(delta, 2 * np.pi * z / np.sqrt(1 - z**2), rtol=0.02)
    # the peak amplitude after 5 periods follows exp(-zeta w t)
    t = np.arange(len(x)) / fps
    np.testing.assert_allclose(x[peaks[-1]] / x[peaks[0]], np.exp(-z * w * (t[peaks[-1]] - t[peaks[0]])), rtol=0.02)
    assert abs(x[0]) == pytest.approx(0.001 * np.abs(basis.modes[0, v]).max() / np.linalg.norm(basis.modes[0, v]),
                                      rel=1e-5)


def test_impulse_excites_modes_through_the_baked_values(basis):
    p = ModalPlayer(basis)
    J = np.array([0.0, 0.3, -0.2])
    dv = p.impulse(17, J)
    np.testing.assert_allclose(dv, [basis.modes[k, 17] @ J for k in range(basis.n_modes)])
    times = np.linspace(0, 0.2, 9)
    q = p.coordinates(times)
    frames = p.frames(0.2, 40.0, dtype=np.float64)          # same times, via the per-frame transition
    disp = np.einsum("tk,kni->tni", q, basis.modes) / basis.scale
    np.testing.assert_allclose(frames - basis.vertices, disp, atol=1e-6 * np.abs(disp).max())
    assert p.time == pytest.approx(0.2)


def test_step_equals_frames_and_undamped_energy_is_conserved(basis):
    zero = modal(CubeModel.box((4, 2, 2), 0.05, youngs=1e7, poisson=0.3, density=1000.0), n_modes=3,
                 fix="x<min+0", damping=0.0)
    p = ModalPlayer(zero)
    p.impulse(10, [0.1, 0.2, 0.3])
    e0 = 0.5 * np.sum(p.v**2 + p.omega**2 * p.q**2)
    ref = ModalPlayer(zero)
    ref.impulse(10, [0.1, 0.2, 0.3])
    frames = ref.frames(1.0, 25.0, dtype=np.float64)
    for i in range(1, 26):                                    # 25 exact steps of 1/25 s
        pos = p.step(1.0 / 25.0)
    np.testing.assert_allclose(pos, frames[-1], atol=1e-9 * np.abs(frames).max())
    e1 = 0.5 * np.sum(p.v**2 + p.omega**2 * p.q**2)
    assert e1 == pytest.approx(e0, rel=1e-10)


def test_player_validates_input(basis):
    p = ModalPlayer(basis)
    with pytest.raises(InputError, match="vertex"):
        p.impulse(basis.n_vertices, [1, 0, 0])
    with pytest.raises(InputError, match="impulse"):
        p.impulse(0, [1, 0])
    with pytest.raises(InputError, match="mode"):
        p.excite(99)
