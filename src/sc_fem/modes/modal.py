"""Modal analysis of a cube lattice, baked onto the source mesh: :func:`modal` -> :class:`ModalBasis`.

The generalized eigenproblem ``K phi = omega^2 M phi`` (consistent mass by default) is solved by
:func:`sc_fem.fem.eigen.solve_eigen` (shift-invert with a negative shift through the Cholesky
backend, or LOBPCG + AMG when a factorization would not fit). Modes are mass-normalized
(``phi^T M phi = 1``), frequencies are in Hz, and the relative residual
``||K phi - omega^2 M phi|| / ||K phi||`` of every mode is reported.

Rigid-body modes (6 per unsupported connected part) are recognised by their frequency
(``omega^2 < RIGID_FRACTION * mean(diag K) / mean(diag M)``, i.e. numerically zero next to the
stiffest element) and removed unless ``keep_rigid=True`` (then flagged in ``ModalBasis.rigid``).

The modes are then *baked*: with the trilinear embedding ``W`` (:func:`sc_fem.lattice.embed.embed`),
each mode on the source mesh is ``W @ phi`` -- an ``(n_vertices, 3)`` array -- and the lattice is
thrown away unless ``keep_lattice=True``.

Units: a mode value is a displacement in metres per unit modal coordinate (m kg^-1/2), so a
modal coordinate ``q`` (m kg^1/2) gives the displacement ``sum_k q_k phi_k`` in metres; an
impulse ``J`` (N s) on a vertex ``v`` gives the modal velocity ``phi_k(v) . J``.

Damping (stored per mode as a ratio ``zeta_k``): ``damping=`` a ratio (one value or one per mode,
default :data:`~sc_fem.modes.options.DEFAULT_DAMPING_RATIO`) or a :class:`~sc_fem.modes.options.Damping`
(``Damping(rayleigh=(alpha, beta))`` for ``C = alpha M + beta K``).

*A model no bigger than the scene needs*: ``n_modes=K`` and ``max_frequency=F`` (all modes below
``F`` Hz, e.g. half the playback frame rate -- faster modes only alias); the coarsest grid whose
first frequencies have converged is :func:`sc_fem.modes.auto.modal_converged`, which builds scenes
at increasing resolutions and solves each as :func:`modal` does.
"""

from __future__ import annotations

from typing import Any

from ..fem.eigen import EigenOptions
from ..fem.elements import DEFAULT_ELEMENT
from ..scene import Scene
from .basis import ModalBasis
from .options import Damping, ModalRequest
from .solve import finish, solve_scene
from .._log import say


def modal(scene: Scene, *, n_modes: int | None = None, max_frequency: float | None = None, max_modes: int = 200,
          element: str = DEFAULT_ELEMENT, lumped: bool = False, damping: Damping | float | None = None,
          eigen: EigenOptions | str | None = None, keep_rigid: bool = False, keep_lattice: bool = False,
          progress: bool = False) -> ModalBasis:
    """Vibration modes of a scene, baked onto its source mesh.

    Parameters
    ----------
    scene : Scene
        Mesh, lattice and fixed nodes together (:meth:`Scene.from_mesh`, :meth:`Scene.from_model`);
        :func:`sc_fem.modal` builds one from a path, a mesh or a CubeModel.
    n_modes : int, optional
        Number of (elastic) modes. Default :data:`~sc_fem.modes.solve.DEFAULT_N_MODES` unless
        ``max_frequency`` is given.
    max_frequency : float, optional
        Keep all modes below this frequency, Hz (at most ``n_modes`` when both are given).
    max_modes : int
        Upper limit on the elastic modes returned (``eigen["truncated"]`` says when it cut the
        ``max_frequency`` or ``n_modes`` request short).
    element : {"auto", "q1i", "q1", "q1sri", "q2", "q3"}
        Element type (default ``"q1i"``: trilinear, fast; warns when the walls are thinner than a
        third of a cube); ``"q3"``: degree-3 cubes, partly filled ones condensed from a finer model
        (multiscale: thin-walled members to a few %); ``"auto"``: ``"q3"`` for a thin-walled model,
        ``"q1i"`` otherwise (:func:`sc_fem.fem.choice.choose_element`; ``eigen["element_reason"]``
        says why).
    lumped : bool
        Lumped instead of consistent mass.
    damping : float, array_like (k,) or Damping, optional
        Modal damping ratio(s), or :class:`~sc_fem.modes.options.Damping` (e.g. Rayleigh);
        default :data:`~sc_fem.modes.options.DEFAULT_DAMPING_RATIO`.
    eigen : EigenOptions or str, optional
        Eigensolver options (:class:`~sc_fem.fem.eigen.EigenOptions`: ``solver``, ``backend``,
        ``max_memory``) or just the solver's name (``"lobpcg"``). ``"auto"`` (default) takes the
        one predicted faster on this machine whose memory fits (the reason is in
        ``eigen["reason"]`` of the result).
    keep_rigid : bool
        Keep rigid-body modes (flagged in ``rigid``) instead of removing them.
    keep_lattice : bool
        Keep the lattice and the node modes in the result.
    progress : bool
        Print stage messages to stderr.

    Returns
    -------
    ModalBasis
        Frequencies (Hz, shape (k,)), damping ratios and the mass-normalized mode shapes at the
        source-mesh vertices (m kg^-1/2, shape (k, n, 3)).

    Raises
    ------
    InputError
        ``scene`` is no Scene, or a bad option.
    SolverError
        The eigensolver failed or the problem does not fit in memory.
    """
    req = ModalRequest(n_modes=n_modes, max_frequency=max_frequency, max_modes=max_modes, element=element,
                       lumped=lumped, damping=damping, eigen=eigen, keep_rigid=keep_rigid,
                       keep_lattice=keep_lattice, progress=progress)
    scene = _scene(scene)
    say(f"  voxelized: {scene.model.n_cubes} cubes, {scene.model.n_dofs} DOFs", progress)
    return finish(solve_scene(scene, req), req)


def _scene(scene: Any) -> Scene:
    """``scene``, checked to be one."""
    return Scene.check(scene, "sc_fem.modes.modal", "sc_fem.modal(source, ...)")
