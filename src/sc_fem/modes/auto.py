"""The coarsest grid whose first frequencies agree with the next finer grid: :func:`modal_converged`.

A model no bigger than the scene needs, one level above :func:`sc_fem.modes.modal.modal`: scenes
are built from the mesh at increasing resolutions (:class:`~sc_fem.modes.options.AutoResolution`)
and solved coarsest first, only the last two are kept in memory, and only the chosen one is baked;
the table the choice was made from is returned in :attr:`sc_fem.ModalBasis.resolution_table`.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, Iterable

import numpy as np
from numpy.typing import ArrayLike

from ..errors import InputError
from ..lattice.options import VoxelOptions
from ..scene import Scene
from .basis import ModalBasis
from .options import AutoResolution, ModalRequest
from .._log import say
from .solve import finish, solve_scene

if TYPE_CHECKING:
    from ..lattice.boundary import Fix


def modal_converged(source: Any, auto: AutoResolution | None = None, *, voxel: VoxelOptions | dict | None = None,
                    fix: Iterable[Fix] | Fix | None = None, fix_vertices: ArrayLike | None = None,
                    **request: Any) -> ModalBasis:
    """The modes at the coarsest grid of ``auto.resolutions`` whose first frequencies agree with
    those of the next finer grid within ``auto.tolerance``.

    Parameters
    ----------
    source : path, ``"builtin:NAME"``, trimesh.Trimesh or (vertices, faces)
        The source mesh (anything :func:`sc_fem.load_mesh` accepts), loaded once (by the first grid).
    auto : AutoResolution, optional
        Grids tried (cubes along the longest axis) and the relative tolerance of the frequencies
        compared (the first ``n_modes``, or those below ``max_frequency``); default
        ``AutoResolution()``.
    voxel : VoxelOptions or dict, optional
        How the mesh is voxelized at every grid; without ``resolution`` or ``pitch`` (the grids
        are ``auto``'s).
    fix : str, FixSpec, callable or list, optional
        Fixed nodes (:func:`sc_fem.fixed_nodes`); ``"default"`` = a built-in model's supports.
    fix_vertices : array_like of int, optional
        Source-mesh vertex indices whose cubes are fixed.
    **request
        The keywords of :func:`sc_fem.modes.modal.modal` (``n_modes``, ``max_frequency``,
        ``element``, ``damping``, ``eigen``, ``progress``, ...).

    Returns
    -------
    ModalBasis
        The chosen grid's modes (frequencies in Hz, shapes in m kg^-1/2), with the
        ``resolution_table`` of every grid solved and ``eigen["auto_converged"]``.

    Raises
    ------
    InputError
        ``voxel`` gives a resolution or pitch, or a bad option.
    """
    auto = AutoResolution() if auto is None else auto
    if not isinstance(auto, AutoResolution):
        raise InputError(f"auto must be an AutoResolution, got {auto!r}")
    voxel = VoxelOptions.coerce(voxel)
    if voxel.pitch is not None or voxel.resolution is not None:
        raise InputError("modal_converged chooses the grid; do not give a pitch or resolution in the voxel options")
    req = ModalRequest(**request)
    tol = auto.tolerance
    table: list[dict] = []
    prev = cur = None                                             # solutions of the last two grids
    for r in auto.resolutions:                                    # loop over grids (a handful)
        t0 = time.perf_counter()
        scene = Scene.from_mesh(source, voxel.replace(resolution=r), fix=fix, fix_vertices=fix_vertices)
        source, lattice = scene.mesh, scene.model                 # the mesh is loaded once, by the first grid
        t_vox = time.perf_counter() - t0
        say(f"[auto] resolution {r}: {lattice.n_cubes} cubes, {lattice.n_dofs} DOFs", req.progress)
        prev, cur = cur, None                                     # drop the grid before prev first
        cur = solve_scene(scene, req)
        cur.timings["voxelize"] = t_vox
        el = cur.elastic_frequencies
        table.append({"resolution": r, "cubes": lattice.n_cubes, "dofs": lattice.n_dofs,
                      "seconds": time.perf_counter() - t0, "frequencies": el.tolist(),
                      "max_rel_change": None, "chosen": False})
        if prev is not None:
            fp = prev.elastic_frequencies
            kk = min(len(fp), len(el))
            if req.n_modes is not None:
                kk = min(kk, req.n_modes)
            change = float(np.max(np.abs(fp[:kk] - el[:kk]) / np.maximum(el[:kk], 1e-300))) if kk else np.inf
            table[-2]["max_rel_change"] = change
            if change <= tol:
                break
    converged = table[-2]["max_rel_change"] is not None and table[-2]["max_rel_change"] <= tol
    chosen = prev if converged else cur
    table[-2 if converged else -1]["chosen"] = True
    for row in table:
        row["converged"] = converged
    chosen.info.update(auto_tolerance=tol, auto_converged=converged)
    return finish(chosen, req, resolution_table=table)


def format_resolution_table(table: list[dict], n_show: int = 4) -> str:
    """The ``resolution="auto"`` table as text (one row per grid)."""
    lines = [f"  {'res':>4} {'cubes':>8} {'DOFs':>9} {'time [s]':>9}  {'first frequencies [Hz]':<40} "
             f"{'max change':>10}"]
    for r in table:
        f = ", ".join(f"{x:.4g}" for x in r["frequencies"][:n_show])
        ch = "" if r["max_rel_change"] is None else f"{100 * r['max_rel_change']:.2f} %"
        mark = "  <- chosen" if r["chosen"] else ""
        lines.append(f"  {r['resolution']:>4} {r['cubes']:>8,} {r['dofs']:>9,} {r['seconds']:>9.2f}  {f:<40} "
                     f"{ch:>10}{mark}")
    if table and not table[0].get("converged", True):
        lines.append("  (not converged within the tolerance: the finest grid tried is used)")
    return "\n".join(lines)
