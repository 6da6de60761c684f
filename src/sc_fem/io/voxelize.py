"""Voxelize a mesh and write the cube model or its picture (``sc-fem voxelize``); :func:`model_summary`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from ..geometry.mesh import load_mesh
from ..lattice.cubes import CubeModel
from ..lattice.voxelize import voxelize
from .model import save_model
from .render import plot_cubes_over_mesh
from .report import JobResult, stage, table

VOXELIZE_OUTPUTS = (".png", ".npz", ".vtu")
"""Extensions :func:`voxelize_to_file` writes."""


def _bodies_line(model: CubeModel) -> str:
    info = model.info
    if info.get("topology") != "pieces":
        return f"{model.n_components} (topology {info.get('topology', 'grid')}: cubes glue what they share)"
    shared = int(np.sum(np.diff(np.ravel_multi_index(model.cells.T, model.dims)) == 0))
    return (f"{model.n_components} kept of {info.get('bodies', 1)} (weld {info.get('weld', 0):.4g} model units: "
            f"{info.get('welds_by_distance', 0)} joins by distance, "
            f"{info.get('welds_by_containment', 0)} by nesting; {info.get('loose_bodies', 0)} loose; "
            f"{shared} cells hold cubes of two bodies)")


def model_summary(model: CubeModel) -> str:
    """A cube model described for a person: grid, sizes, samples, bodies, mass and material.

    Parameters
    ----------
    model : CubeModel

    Returns
    -------
    str
        Aligned ``key  value`` lines.
    """
    info = model.info
    return table([
        ("source", info.get("source", "")),
        ("grid", " x ".join(str(int(d)) for d in model.dims)
         + f"  (pitch {model.pitch:.4g} model units, h {model.h:.4g} m)"),
        ("cubes / nodes / DOFs", f"{model.n_cubes:,} / {model.n_nodes:,} / {model.n_dofs:,}"),
        ("samples", f"{info.get('n_samples', 0):,} ({info.get('sampler', '')}, {info.get('occupancy', '')}, "
                    f"fill {info.get('fill', '')})"),
        ("bodies", _bodies_line(model)),
        ("components", f"{info.get('components_found', model.n_components)} found, "
                       f"{info.get('dropped_cubes', 0)} cubes dropped"),
        ("size", " x ".join(f"{e:.4g}" for e in model.dims * model.h) + " m (bounding box of the cubes)"),
        ("mass", f"{model.total_mass:.6g} kg"),
        ("E", f"{model.youngs.min():.4g} .. {model.youngs.max():.4g} Pa ({info.get('material', '')})"),
    ])


def voxelize_to_file(mesh: object, output: str | Path, options: object = None, *, up: str = "z",
                     verbose: bool = False) -> JobResult:
    """Load and voxelize ``mesh`` and write the model, or a picture of its cubes over the mesh.

    Parameters
    ----------
    mesh : path, ``"builtin:NAME"`` or anything :func:`sc_fem.load_mesh` takes
    output : str or Path
        ``.png`` (picture), ``.npz`` (reloadable, :func:`sc_fem.io.model.load_model`) or ``.vtu``
        (ParaView).
    options : VoxelOptions or dict, optional
        How to voxelize (:class:`sc_fem.VoxelOptions`).
    up : {"x", "y", "z"}
        The model's up axis, drawn upward in a picture.
    verbose : bool
        Print every stage (load, voxelize, write) and its time on stderr.

    Returns
    -------
    JobResult
        ``result`` the :class:`~sc_fem.CubeModel`; the summary is :func:`model_summary` and the
        file written.
    """
    out = Path(output)
    if out.suffix.lower() not in VOXELIZE_OUTPUTS:
        raise InputError(f"unsupported output {out.name!r}: use .png, .npz or .vtu")
    timings: dict = {}
    with stage("load", timings, verbose):
        mesh = load_mesh(mesh)
    with stage("voxelize", timings, verbose):
        model = voxelize(mesh, options)
    with stage("write", timings, verbose):
        if out.suffix.lower() == ".png":
            plot_cubes_over_mesh(model, mesh, out, up=up)
        else:
            save_model(model, out)
    return JobResult(written=[out], result=model, text=f"{model_summary(model)}\nwrote {out}")
