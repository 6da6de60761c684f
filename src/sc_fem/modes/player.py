"""Real-time modal playback: :class:`ModalPlayer` (exact damped modal oscillators) and mode sheets.

Each modal coordinate ``q_k`` obeys ``q'' + 2 zeta w q' + w^2 q = 0`` between excitations and is
advanced by its **exact** solution (no time-stepping error, any frame rate), with
``w_d = w sqrt(1 - zeta^2)``:

* ``zeta < 1``: ``q(t) = e^{-zeta w t} (q0 cos w_d t + (v0 + zeta w q0) / w_d sin w_d t)``,
* ``zeta = 1``: ``q(t) = e^{-w t} (q0 + (v0 + w q0) t)``,
* ``zeta > 1``: ``q(t) = A e^{r1 t} + B e^{r2 t}``, ``r1,2 = -w (zeta -+ sqrt(zeta^2 - 1))``,
* ``w = 0`` (a kept rigid mode): ``q(t) = q0 + v0 t`` (free drift).

An impulse ``J`` (N s) on source vertex ``v`` adds ``phi_k(v) . J`` to each modal velocity
(mass-normalized modes). Vertex positions of a frame are ``rest + (U q) / scale`` with ``U`` the
``(3n, k)`` matrix of baked modes: one matrix-vector product per frame.
"""

from __future__ import annotations


import numpy as np
from numpy.typing import ArrayLike, DTypeLike

from .._validate import as_float_array, positive_scalar
from ..errors import InputError
from .basis import ModalBasis


def transition(omega: np.ndarray, zeta: np.ndarray, t) -> tuple[np.ndarray, ...]:
    """Exact state-transition coefficients of damped oscillators after time ``t``.

    Parameters
    ----------
    omega : ndarray, shape (k,)
        Undamped angular frequencies, rad/s (0 = free mass).
    zeta : ndarray, shape (k,)
        Damping ratios (>= 0).
    t : float or ndarray, shape (T,)
        Elapsed time(s), s.

    Returns
    -------
    a, b, c, d : ndarray, shape (T, k) (or (k,) for scalar ``t``)
        ``q(t) = a q0 + b v0`` and ``v(t) = c q0 + d v0``.
    """
    w = np.asarray(omega, dtype=float)[None, :]
    z = np.asarray(zeta, dtype=float)[None, :]
    scalar = np.ndim(t) == 0
    tt = np.atleast_1d(np.asarray(t, dtype=float))[:, None]
    shape = np.broadcast(tt, w).shape
    a, b, c, d = (np.zeros(shape) for _ in range(4))
    rigid = (w == 0) & np.ones_like(tt, dtype=bool)
    under = (w > 0) & (z < 1)
    crit = (w > 0) & (z == 1)
    over = (w > 0) & (z > 1)
    wz = w * z
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        # under-damped
        wd = w * np.sqrt(np.abs(1.0 - z**2))
        e = np.exp(-wz * tt)
        cs, sn = np.cos(wd * tt), np.sin(wd * tt)
        wd_safe = np.where(under, wd, 1.0)
        au = e * (cs + wz / wd_safe * sn)
        bu = e * sn / wd_safe
        cu = -e * (w**2 / wd_safe) * sn
        du = e * (cs - wz / wd_safe * sn)
        # critically damped
        ec = np.exp(-w * tt)
        ac, bc = ec * (1.0 + w * tt), ec * tt
        cc, dc = -ec * w**2 * tt, ec * (1.0 - w * tt)
        # over-damped: r1 = -w (z - s), r2 = -w (z + s), s = sqrt(z^2 - 1)
        s = np.sqrt(np.where(over, z**2 - 1.0, 1.0))
        r1, r2 = -w * (z - s), -w * (z + s)
        e1, e2 = np.exp(r1 * tt), np.exp(r2 * tt)
        den = np.where(over, r1 - r2, 1.0)
        ao = (r1 * e2 - r2 * e1) / den
        bo = (e1 - e2) / den
        co = r1 * r2 * (e2 - e1) / den
        do = (r1 * e1 - r2 * e2) / den
    for out, (u, cr, ov, rg) in zip((a, b, c, d), ((au, ac, ao, 1.0), (bu, bc, bo, tt), (cu, cc, co, 0.0),
                                                     (du, dc, do, 1.0))):
        out[...] = np.where(under, u, np.where(crit, cr, np.where(over, ov, 0.0)))
        out[...] = np.where(rigid, np.broadcast_to(rg, shape), out)
    if scalar:
        return a[0], b[0], c[0], d[0]
    return a, b, c, d


class ModalPlayer:
    """Plays a :class:`~sc_fem.modes.modal.ModalBasis` back in real time.

    Parameters
    ----------
    basis : ModalBasis
        Modes (:func:`sc_fem.io.modes.load_modes` reads a mode file).
    dtype : numpy dtype
        Precision of the per-frame matrix-vector product (``float32`` by default, as stored).

    Attributes
    ----------
    q, v : ndarray, shape (k,)
        Current modal coordinates (m kg^1/2) and velocities.
    time : float
        Current time, s.
    """

    def __init__(self, basis: ModalBasis, *, dtype: DTypeLike = np.float32) -> None:
        if not isinstance(basis, ModalBasis):
            raise InputError(f"basis must be a ModalBasis (sc_fem.io.modes.load_modes reads a mode file), "
                             f"got {type(basis).__name__}")
        self.basis = basis
        k, n = basis.n_modes, basis.n_vertices
        self.omega = np.asarray(basis.omegas, dtype=float)        # rigid modes have frequency 0
        self.zeta = np.asarray(basis.damping, dtype=float)
        # U: (3n, k) so that displacement (model units) = U @ q
        self._U = np.ascontiguousarray(
            (np.asarray(basis.modes).reshape(k, 3 * n).T / basis.scale).astype(dtype))
        self.rest = np.asarray(basis.vertices, dtype=float)
        self.q = np.zeros(k)
        self.v = np.zeros(k)
        self.time = 0.0

    # ------------------------------------------------------------------ excitation
    @property
    def n_modes(self) -> int:
        """Number of modes ``k``."""
        return len(self.omega)

    def reset(self) -> None:
        """Back to rest at time 0."""
        self.q[:] = 0.0
        self.v[:] = 0.0
        self.time = 0.0

    def impulse(self, vertex: int, impulse: ArrayLike) -> np.ndarray:
        """Apply an impulse ``J`` (N s, shape (3,)) at source vertex ``vertex``.

        Returns the modal velocity change, shape (k,): ``phi_k(vertex) . J``.

        Parameters
        ----------
        vertex : int
            Index of the source vertex, ``0 <= vertex < n``.
        impulse : array_like, shape (3,)
            The impulse ``J``, N s.

        Returns
        -------
        ndarray, shape (k,)
            Change of the modal velocities, m kg^1/2 / s (added to :attr:`v`).
        """
        n = self.basis.n_vertices
        if isinstance(vertex, bool) or not isinstance(vertex, (int, np.integer)) or not 0 <= vertex < n:
            raise InputError(f"vertex must be an integer in [0, {n}), got {vertex!r}")
        J = as_float_array(impulse, "impulse", (3,))
        dv = np.asarray(self.basis.modes[:, int(vertex), :], dtype=float) @ J
        self.v += dv
        return dv

    def excite(self, mode: int, amplitude: float = 0.01) -> None:
        """Displace mode ``mode`` so its largest vertex displacement is ``amplitude`` (model units).

        Parameters
        ----------
        mode : int
            Index of the mode, ``0 <= mode < k``.
        amplitude : float
            Largest vertex displacement the mode gets, model units (added to the current state).
        """
        k = self.n_modes
        if isinstance(mode, bool) or not isinstance(mode, (int, np.integer)) or not 0 <= mode < k:
            raise InputError(f"mode must be an integer in [0, {k}), got {mode!r}")
        amp = float(amplitude)
        if not np.isfinite(amp):
            raise InputError(f"amplitude must be finite, got {amplitude!r}")
        peak = float(np.linalg.norm(np.asarray(self.basis.modes[mode], dtype=float), axis=1).max())
        if peak == 0.0:
            raise InputError(f"mode {mode} has no displacement at the vertices (all fixed?)")
        self.q[mode] += amp * self.basis.scale / peak

    # ------------------------------------------------------------------ evaluation
    def coordinates(self, times: ArrayLike) -> np.ndarray:
        """Modal coordinates at ``times`` after the current state (s, shape (T,)): shape (T, k). Exact.

        Parameters
        ----------
        times : float or array_like, shape (T,)
            Times after the current state, s (the state does not advance).

        Returns
        -------
        ndarray, shape (T, k)
            Modal coordinates, m kg^1/2.
        """
        a, b, _, _ = transition(self.omega, self.zeta, np.atleast_1d(np.asarray(times, dtype=float)))
        return a * self.q[None, :] + b * self.v[None, :]

    def displacements(self, q: ArrayLike) -> np.ndarray:
        """Vertex displacements (n, 3) in model units for modal coordinates ``q`` (k,).

        Parameters
        ----------
        q : array_like, shape (k,)
            Modal coordinates, m kg^1/2.

        Returns
        -------
        ndarray, shape (n, 3)
            Vertex displacements, model units (in the player's ``dtype``).
        """
        return (self._U @ np.asarray(q, dtype=self._U.dtype)).reshape(-1, 3)

    def positions(self, q: ArrayLike | None = None) -> np.ndarray:
        """Vertex positions (n, 3), model units, for ``q`` (default: the current state).

        Parameters
        ----------
        q : array_like, shape (k,), optional
            Modal coordinates, m kg^1/2; default :attr:`q`.

        Returns
        -------
        ndarray, shape (n, 3)
            Rest positions plus the displacements, model units.
        """
        return self.rest + self.displacements(self.q if q is None else q)

    def step(self, dt: float) -> np.ndarray:
        """Advance the state exactly by ``dt`` seconds; returns the new vertex positions (n, 3).

        Parameters
        ----------
        dt : float
            Time step, s (>= 0; any size, the step is exact).

        Returns
        -------
        ndarray, shape (n, 3)
            Vertex positions after the step, model units.
        """
        dt = positive_scalar(dt, "dt", allow_zero=True)
        a, b, c, d = transition(self.omega, self.zeta, dt)
        self.q, self.v = a * self.q + b * self.v, c * self.q + d * self.v
        self.time += dt
        return self.positions()

    def frames(self, duration: float, fps: float = 30.0, *, dtype: DTypeLike = np.float32) -> np.ndarray:
        """Play ``duration`` seconds at ``fps`` from the current state (which advances).

        Parameters
        ----------
        duration : float
            Length of the playback, s.
        fps : float
            Frames per second.
        dtype : numpy dtype
            Precision of the returned positions.

        Returns
        -------
        ndarray, shape (T, n, 3)
            Vertex positions, model units; frame 0 is the current state, ``T = round(duration * fps) + 1``.
        """
        times = self.times(duration, fps)
        T = len(times)
        a, b, c, d = transition(self.omega, self.zeta, times[1] if T > 1 else 0.0)  # one exact step, reused
        out = np.empty((T, self.basis.n_vertices, 3), dtype=dtype)
        q, v = self.q.copy(), self.v.copy()
        for i in range(T):                                      # loop over frames: one mat-vec each
            out[i] = self.positions(q)
            if i < T - 1:
                q, v = a * q + b * v, c * q + d * v
        self.q, self.v = q, v
        self.time += float(times[-1])
        return out

    def times(self, duration: float, fps: float = 30.0) -> np.ndarray:
        """Frame times of :meth:`frames`, s, shape (T,), relative to the start.

        Parameters
        ----------
        duration : float
            Length of the playback, s.
        fps : float
            Frames per second.

        Returns
        -------
        ndarray, shape (T,)
            ``arange(T) / fps`` with ``T = round(duration * fps) + 1``, s.
        """
        fps = positive_scalar(fps, "fps")
        T = int(round(positive_scalar(duration, "duration") * fps)) + 1
        return np.arange(T) / fps


def playback_warnings(basis, frames: np.ndarray, fps: float, exaggerate: float = 1.0) -> list[str]:
    """What would make a playback misleading, as sentences (empty when nothing).

    Parameters
    ----------
    basis : ModalBasis
    frames : ndarray, shape (T, n, 3)
        Vertex positions (model units) as they will be drawn.
    fps : float
        Frames per second of the playback.
    exaggerate : float
        The displacement factor already applied to ``frames``.

    Notes
    -----
    Modes above ``fps / 2`` alias into a slow sway that is not there. Motion below
    :data:`INVISIBLE_FRACTION` of the model's bounding-box diagonal is less than a pixel on a
    1000-pixel picture; the sentence suggests an ``--exaggerate`` factor that makes it 5 %.
    """
    out = []
    nyquist = 0.5 * float(fps)
    high = np.flatnonzero(np.asarray(basis.frequencies) > nyquist)
    if len(high):
        fs = ", ".join(f"{basis.frequencies[i]:.3g}" for i in high[:6]) + (", ..." if len(high) > 6 else "")
        out.append(f"{len(high)} mode(s) ({fs} Hz) lie above half the frame rate ({nyquist:g} Hz): they alias "
                   f"into a slow sway that is not there; raise --fps or precompute with --max-frequency {nyquist:g}")
    rest = np.asarray(basis.vertices)
    diag = float(np.linalg.norm(np.ptp(rest, axis=0)))
    moved = float(np.linalg.norm(np.asarray(frames) - rest[None], axis=2).max()) if len(frames) else 0.0
    if moved < INVISIBLE_FRACTION * diag:
        factor = 0.05 * diag / max(moved, 1e-300) * exaggerate
        out.append(f"the motion is at most {moved:.3g} model units ({100 * moved / diag:.2g} % of the model's "
                   f"size): it will not be visible; try --exaggerate {factor:.3g}")
    return out


INVISIBLE_FRACTION = 1e-3
"""Largest displacement, as a fraction of the bounding-box diagonal, below which motion is invisible."""
