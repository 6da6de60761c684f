"""``sc-fem voxelize MESH -o OUT``: build the Squashing Cubes model; write a picture or the model."""

from __future__ import annotations

from pathlib import Path

from .common import add_grid_args, add_material_args, add_mesh_arg, add_up_arg, model_summary, stage


def register(sub) -> None:
    p = sub.add_parser("voxelize", help="voxelize a mesh into elastic cubes",
                       description="Voxelize MESH into elastic cubes and write OUT: a .png picture of the "
                                   "cubes over the mesh, the model as .npz (reloadable with "
                                   "sc_fem.io.model.load_model) or .vtu (ParaView).")
    add_mesh_arg(p)
    add_grid_args(p)
    add_material_args(p)
    p.add_argument("-o", "--output", required=True, help="output file: .png, .npz or .vtu")
    add_up_arg(p)
    p.add_argument("--quiet", "-q", action="store_true", help="print only errors")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..errors import InputError
    from ..geometry.mesh import load_mesh
    from ..io.model import save_model

    out = Path(args.output)
    if out.suffix.lower() not in (".png", ".npz", ".vtu"):
        raise InputError(f"unsupported output {out.name!r}: use .png, .npz or .vtu")
    timings: dict = {}
    with stage("load", timings, args.quiet):
        mesh = load_mesh(args.mesh)
    from .common import voxelize_from_args

    with stage("voxelize", timings, args.quiet):
        model = voxelize_from_args(args, mesh=mesh)
    with stage("write", timings, args.quiet):
        if out.suffix.lower() == ".png":
            from ..io.render import plot_cubes_over_mesh

            plot_cubes_over_mesh(model, mesh, out, up=args.up)
        else:
            save_model(model, out)
    if not args.quiet:
        print(model_summary(model))
        print(f"wrote {out}")
    return 0
