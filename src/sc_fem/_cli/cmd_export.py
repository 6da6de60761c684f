"""``sc-fem export`` (glTF 2.0 for engines, Blender and the browser; OpenUSD; .vtu, .vtkhdf) and ``sc-fem view`` (one
HTML page that plays the modes in real time)."""

from __future__ import annotations

from ..io.export import EXPORT_FORMATS, export_to_file
from ..io.viewer import write_viewer
from .common import add_amplitude_arg, add_impulse_arg, add_quiet, add_up_arg, command, finish, impulse_arg


def register(sub) -> None:
    p = command(sub, "export", run_export, outputs=tuple(EXPORT_FORMATS),
                help="write modes or an animation as glTF 2.0 (.glb/.gltf), OpenUSD (.usd/.usda/.usdc) or .vtu/.vtkhdf",
                description="glTF 2.0: +Y up (--up turned onto it), metres, a dielectric material, normals; two morph "
                            "targets per mode (+mode, -mode: weights in [0, 1]; scales, frequencies, damping in "
                            "meshes[0].extras), a baked playback (--impulse, --mode) as a weights animation, an "
                            "animation (sc-fem simulate .npz) as one morph target per frame (at most 256). OpenUSD "
                            "(pip install 'sc_fem[usd]'): metres, upAxis from --up, one UsdSkel blend shape per mode, "
                            "a playback as weight time samples, an animation as time-sampled points.")
    p.add_argument("source", metavar="FILE", help="mode file or animation file (.npz)")
    p.add_argument("-o", "--output", required=True, help="output .glb (or .gltf); .usd/.usda/.usdc: OpenUSD (usdview, "
                   "Blender, Houdini); .vtu, .vtkhdf: the mode shapes for ParaView (one point array per mode)")
    add_amplitude_arg(p, "of a mode at weight 1 (--mode: at its release)")
    g = p.add_mutually_exclusive_group()
    add_impulse_arg(g, "bake the exact response to an impulse (N s) on a source vertex")
    g.add_argument("--mode", type=int, default=None, help="bake this mode released from weight 1")
    p.add_argument("--duration", type=float, default=None,
                   help="seconds: of a baked playback (default 2), of an animation from its first frame (default all)")
    p.add_argument("--fps", type=float, default=None,
                   help="frames per second: of a baked playback (default 30, exact; moving modes above fps/2 alias: a "
                        "warning), of an animation (default its own; another resamples it, linearly in time)")
    add_up_arg(p, uses="glTF turns it onto +Y (the up axis of glTF, three.js, Blender); USD's upAxis (x: onto +Y)")
    p.add_argument("--mesh", metavar="MESH", default=None, help="the source mesh the file was computed from (same "
                   "vertices): its UVs (glTF TEXCOORD_0, USD primvars:st) and its file normals, if any, are kept")
    p.add_argument("--quantize", action="store_true", help="glTF only: 16-bit positions and mode displacements, "
                   "8-bit normals (KHR_mesh_quantization, required by the file; weights unchanged): 2/3 of the size")
    add_quiet(p)

    v = command(sub, "view", run_view, outputs=(".html", ".htm"),
                help="write a self-contained HTML page that plays a mode file in the browser",
                description="Write one HTML page (three.js and the modes inlined; no network needed) with "
                            "per-mode sliders, click-to-strike (the exact damped modal response), the "
                            "frequency table and the time scale. Open it in any browser.")
    v.add_argument("modes", metavar="MODES", help="mode file (.npz) from precompute-modes")
    v.add_argument("-o", "--output", required=True, help="output .html")
    add_amplitude_arg(v, "of a mode at weight 1 (a slider's end)")
    add_up_arg(v)
    add_quiet(v)


def run_export(args) -> int:
    return finish(args, export_to_file(args.source, args.output, amplitude=args.amplitude,
                                       impulse=impulse_arg(args.impulse), mode=args.mode, duration=args.duration,
                                       fps=args.fps, up=args.up, mesh=args.mesh, quantize=args.quantize))


def run_view(args) -> int:
    path = write_viewer(args.modes, args.output, amplitude=args.amplitude, up=args.up)
    if not args.quiet:
        print(f"wrote {path} ({path.stat().st_size / 1024:.0f} KiB): open it in a browser (file://{path.resolve()})")
    return 0
