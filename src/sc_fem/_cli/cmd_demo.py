"""``sc-fem demo -o out``: the main job on the built-in models, writing everything under ``out/``."""

from __future__ import annotations

from ..io.demo import run_demo
from .common import command, finish


def register(sub) -> None:
    p = command(sub, "demo", run, folder=True, help="run the main job on the built-in models",
                description="The main job on the built-in models, everything written under OUT: "
                            "pictures of the chair and bridge cubes over their meshes, the bridge swaying "
                            "under a gust (Newmark), the chair's modes baked onto its mesh, and the XPBD "
                            "cube-rope with its PDE reconstruction from the even frames.")
    p.add_argument("-o", "--output", default="out", help="output folder (default: out)")
    p.add_argument("--resolution", "-r", type=int, default=40, help="cubes along the longest axis (default 40)")


def run(args) -> int:
    return finish(args, run_demo(args.output, resolution=args.resolution))
