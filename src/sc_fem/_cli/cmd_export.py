"""``sc-fem export`` (glTF 2.0 for engines, Blender and the browser; OpenUSD; .vtu) and ``sc-fem view`` (one
HTML page that plays the modes in real time)."""

from __future__ import annotations

from ..errors import InputError
from ..io.export import EXPORT_FORMATS
from .common import add_quiet, add_up_arg, command, finish


def register(sub) -> None:
    p = command(sub, "export", run_export, outputs=tuple(EXPORT_FORMATS),
                help="write modes or an animation as glTF 2.0 (.glb/.gltf), OpenUSD (.usd/.usda/.usdc) or .vtu",
                description="glTF 2.0: +Y up (the model's --up axis turned onto it), metres, a dielectric material, "
                            "normals; two morph targets per mode (+mode, -mode: every weight in [0, 1]; weight 1 = "
                            "--amplitude of the model's size; scales, frequencies, damping in meshes[0].extras), "
                            "a baked playback (--impulse or --mode) as a weights animation, an animation (sc-fem "
                            "simulate .npz) as one morph target per frame. OpenUSD (pip install 'sc_fem[usd]'): "
                            "metres, upAxis from --up, one UsdSkel blend shape per mode (frequency, damping, scale as "
                            "scfem: attributes), a baked playback as weight time samples at --fps, an animation as "
                            "time-sampled points at its frame rate. A mode file stores no UVs: --mesh keeps them.")
    p.add_argument("source", metavar="FILE", help="mode file or animation file (.npz)")
    p.add_argument("-o", "--output", required=True, help="output .glb (or .gltf); .usd/.usda/.usdc: OpenUSD (usdview, "
                   "Blender, Houdini); .vtu: the mode shapes for ParaView (one point array per mode)")
    p.add_argument("--amplitude", type=float, default=0.05,
                   help="largest displacement of a mode at weight 1, fraction of the bounding-box diagonal (0.05)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--impulse", type=float, nargs=4, default=None, metavar=("VERTEX", "JX", "JY", "JZ"),
                   help="bake the exact response to an impulse (N s) on a source vertex")
    g.add_argument("--mode", type=int, default=None, help="bake this mode released from weight 1")
    p.add_argument("--duration", type=float, default=2.0, help="seconds of baked playback (2)")
    p.add_argument("--fps", type=float, default=30.0,
                   help="samples per second of the baked playback (30); moving modes above fps/2 alias (a warning)")
    add_up_arg(p, uses="glTF turns it onto +Y (the up axis of glTF, three.js, Blender); USD's upAxis (x: onto +Y)")
    p.add_argument("--mesh", metavar="MESH", default=None, help="the source mesh the file was computed from (same "
                   "vertices): its UVs (glTF TEXCOORD_0, USD primvars:st) and its file normals, if any, are kept")
    add_quiet(p)

    v = command(sub, "view", run_view, outputs=(".html", ".htm"),
                help="write a self-contained HTML page that plays a mode file in the browser",
                description="Write one HTML page (three.js and the modes inlined; no network needed) with "
                            "per-mode sliders, click-to-strike (the exact damped modal response), the "
                            "frequency table and the time scale. Open it in any browser.")
    v.add_argument("modes", metavar="MODES", help="mode file (.npz) from precompute-modes")
    v.add_argument("-o", "--output", required=True, help="output .html")
    v.add_argument("--amplitude", type=float, default=0.05, help="weight 1 as a fraction of the model's size (0.05)")
    add_up_arg(v)
    add_quiet(v)


def run_export(args) -> int:
    from ..io.export import export_to_file

    if args.impulse is not None and not float(args.impulse[0]).is_integer():
        raise InputError(f"--impulse VERTEX must be an integer vertex index, got {args.impulse[0]:g}")
    impulse = None if args.impulse is None else (int(args.impulse[0]), args.impulse[1:])
    return finish(args, export_to_file(args.source, args.output, amplitude=args.amplitude, impulse=impulse,
                                       mode=args.mode, duration=args.duration, fps=args.fps, up=args.up,
                                       mesh=args.mesh))


def run_view(args) -> int:
    from ..io.viewer import write_viewer

    path = write_viewer(args.modes, args.output, amplitude=args.amplitude, up=args.up)
    if not args.quiet:
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB): open it in a browser (file://{path.resolve()})")
    return 0
