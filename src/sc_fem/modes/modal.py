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

*A model no bigger than the scene needs*: ``n_modes=K``, ``max_frequency=F`` (all modes below
``F`` Hz, e.g. half the playback frame rate -- faster modes only alias), and
``resolution="auto"`` (or an :class:`~sc_fem.modes.options.AutoResolution`): the coarsest grid
whose first ``K`` frequencies agree with those of the next finer grid; the table it decided from
is in :attr:`ModalBasis.resolution_table`.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, Iterable

from numpy.typing import ArrayLike

from ..errors import InputError
from ..fem.eigen import EigenOptions
from ..fem.elements import DEFAULT_ELEMENT
from ..geometry.mesh import load_mesh
from ..lattice.cubes import CubeModel
from ..lattice.options import VoxelOptions
from ..scene import Scene
from .auto import modal_auto
from .basis import ModalBasis
from .options import AutoResolution, Damping, ModalRequest, parse_resolution
from .._log import say
from .solve import finish, solve_scene

if TYPE_CHECKING:
    from ..lattice.boundary import Fix


def modal(model: Any, *, n_modes: int | None = None, max_frequency: float | None = None, max_modes: int = 200,
          mesh: Any = None, resolution: int | str | AutoResolution | None = None,
          voxel: VoxelOptions | dict | None = None, fix: Iterable[Fix] | Fix | None = None,
          fix_vertices: ArrayLike | None = None, element: str = DEFAULT_ELEMENT,
          lumped: bool = False, damping: Damping | float | None = None, eigen: EigenOptions | str | None = None,
          keep_rigid: bool = False, keep_lattice: bool = False, progress: bool = False) -> ModalBasis:
    """Vibration modes of a model, baked onto its source mesh.

    Parameters
    ----------
    model : Scene, CubeModel or mesh-like
        A :class:`~sc_fem.Scene` (mesh, lattice and fixed nodes together; then ``mesh``, ``fix``,
        ``fix_vertices``, ``resolution`` and ``voxel`` are not given), a lattice, or anything
        :func:`sc_fem.load_mesh` accepts (then voxelized with ``resolution`` and ``voxel``).
    n_modes : int, optional
        Number of (elastic) modes. Default :data:`DEFAULT_N_MODES` unless ``max_frequency`` is given.
    max_frequency : float, optional
        Keep all modes below this frequency, Hz (at most ``n_modes`` when both are given).
    max_modes : int
        Upper limit on the elastic modes returned (``eigen["truncated"]`` says when it cut the
        ``max_frequency`` or ``n_modes`` request short).
    mesh : mesh-like, optional
        Source mesh to bake onto when ``model`` is a :class:`CubeModel`; without it the modes are
        given at the lattice nodes (``vertices = model.nodes``, no faces).
    resolution : int, "auto" or AutoResolution, optional
        Grid for a mesh-like ``model`` (cubes along the longest axis; default 32). ``"auto"`` or
        :class:`~sc_fem.modes.options.AutoResolution` (``resolutions``, ``tolerance``): the
        coarsest grid whose first ``n_modes`` frequencies (or those below ``max_frequency``)
        agree with the next finer grid.
    voxel : VoxelOptions or dict, optional
        How a mesh-like ``model`` is voxelized (:class:`~sc_fem.lattice.options.VoxelOptions`:
        ``scale``, ``youngs``, ``fill``, ...).
    fix : str, FixSpec, callable or list, optional
        Fixed nodes (:func:`sc_fem.lattice.boundary.fixed_nodes`), e.g. ``"z<min+0.01"``;
        ``"default"`` = a built-in model's supports.
    fix_vertices : array_like of int, optional
        Source-mesh vertex indices whose cubes are fixed (needs a mesh).
    element : {"q1i", "q1", "q1sri"}
        Element type.
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
        Bad arguments (e.g. ``resolution="auto"`` with a :class:`CubeModel`).
    SolverError
        The eigensolver failed or the problem does not fit in memory.
    """
    req = ModalRequest(n_modes=n_modes, max_frequency=max_frequency, max_modes=max_modes, element=element,
                       lumped=lumped, damping=damping, eigen=eigen, keep_rigid=keep_rigid,
                       keep_lattice=keep_lattice, progress=progress)
    if isinstance(model, (Scene, CubeModel)):
        given = [k for k, v in (("resolution", resolution), ("voxel", voxel)) if v is not None]
        if isinstance(model, Scene):
            given += [k for k, v in (("mesh", mesh), ("fix", fix), ("fix_vertices", fix_vertices)) if v is not None]
        if given:
            raise InputError(f"a {type(model).__name__} already has its grid{' and fixed nodes' if isinstance(model, Scene) else ''}: "
                             f"do not pass {', '.join(given)} (pass the mesh as model= to voxelize it)")
        scene = model if isinstance(model, Scene) else Scene.from_model(model, mesh, fix=fix, fix_vertices=fix_vertices)
        return finish(solve_scene(scene, req), req, {})
    if mesh is not None:
        raise InputError("mesh= is only used with a CubeModel; pass the mesh as model=")
    vopts = VoxelOptions.coerce(voxel)
    resolution = parse_resolution(resolution)
    t0 = time.perf_counter()
    src_mesh = load_mesh(model)
    timings = {"load": time.perf_counter() - t0}
    if isinstance(resolution, AutoResolution):
        return modal_auto(src_mesh, resolution, vopts, req, fix=fix, fix_vertices=fix_vertices, timings=timings)
    if resolution is not None:
        if vopts.resolution not in (None, resolution) or vopts.pitch is not None:
            raise InputError(f"resolution={resolution} contradicts voxel options {vopts!r}")
        vopts = vopts.replace(resolution=resolution)
    t0 = time.perf_counter()
    scene = Scene.from_mesh(src_mesh, vopts, fix=fix, fix_vertices=fix_vertices)
    timings["voxelize"] = time.perf_counter() - t0
    say(f"  voxelized: {scene.model.n_cubes} cubes, {scene.model.n_dofs} DOFs", progress)
    return finish(solve_scene(scene, req), req, timings)
