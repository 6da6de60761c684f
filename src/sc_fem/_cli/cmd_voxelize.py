"""``sc-fem voxelize MESH -o OUT``: build the Squashing Cubes model; write a picture or the model."""

from __future__ import annotations

from ..io.voxelize import voxelize_to_file
from .common import (add_grid_args, add_material_args, add_mesh_arg, add_quiet, add_up_arg, command, finish,
                     voxel_options)


def register(sub) -> None:
    p = command(sub, "voxelize", run, outputs=(".png", ".npz", ".vtu"), help="voxelize a mesh into elastic cubes",
                description="Voxelize MESH into elastic cubes and write OUT: a .png picture of the cubes over the "
                            "mesh, the model as .npz (reloadable with sc_fem.io.model.load_model) or .vtu (ParaView).")
    add_mesh_arg(p)
    add_grid_args(p)
    add_material_args(p)
    p.add_argument("-o", "--output", required=True, help="output file: .png, .npz or .vtu")
    add_up_arg(p)
    add_quiet(p)


def run(args) -> int:
    job = voxelize_to_file(args.mesh, args.output, voxel_options(args), up=args.up, verbose=not args.quiet)
    return finish(args, job)
