"""``sc-fem view``: one self-contained HTML page that plays a mode file in the browser.

The page inlines the JavaScript bundle (three.js + :file:`_viewer/main.js`, built from the npm
registry by ``make viewer`` into :file:`_viewer/viewer.js`), the modes as a ``.glb`` (morph
targets, :mod:`sc_fem.io.gltf`) and a small JSON config, so it opens from disk with no network.
It shows per-mode sliders, a *strike* (click the model: an impulse into the surface, played back
as the exact damped modal response), the frequency table and the time scale.

**Size.** The ``.glb`` is quantized (``KHR_mesh_quantization``: 16-bit positions and per-mode
16-bit displacements, :mod:`sc_fem.io.quantize`), and the page carries it *packed*
(:func:`pack_glb`, undone by the page's JavaScript before three.js reads the ``.glb``): in each
16-bit vertex stream (positions, every mode) a vertex is stored as its difference from an earlier
vertex (its nearest mesh neighbour of lower index, else the previous one; the parent list is in
the payload), zigzag-coded and split into byte planes, and the whole is zlib-compressed. The
transform is lossless; smooth mode shapes then take about half of their 16 bits per component
(the Stanford bunny subdivided to 139,122 vertices, 16 modes: a 12.2 MB page instead of 45 MB
with float32). :func:`read_viewer_glb` gives the ``.glb`` a page carries.
"""

from __future__ import annotations

import base64
import binascii
import html
import json
import re
import zlib
from pathlib import Path

import numpy as np

from .._atomic import atomic_path
from ..errors import FileFormatError, InputError, RenderError
from ..units import up_axis
from .animation import Animation
from .gltf import DEFAULT_AMPLITUDE, _load, gltf_document, mode_scales

BUNDLE = Path(__file__).with_name("_viewer") / "viewer.js"
"""The JavaScript bundle written by ``make viewer`` (esbuild of three.js and main.js)."""

_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>{title}</title>
<style>
 html, body {{ margin: 0; height: 100%; font: 13px system-ui, sans-serif; color: #222; }}
 #wrap {{ display: flex; height: 100%; }}
 #view {{ flex: 1; position: relative; min-width: 0; }}
 #side {{ width: 330px; padding: 10px 12px; overflow-y: auto; border-left: 1px solid #ddd; background: #fafafa; }}
 #clock {{ position: absolute; right: 10px; bottom: 8px; background: rgba(255,255,255,.8); padding: 2px 6px; }}
 #hint {{ position: absolute; left: 10px; top: 8px; background: rgba(255,255,255,.8); padding: 2px 6px; }}
 table {{ border-collapse: collapse; width: 100%; }} td, th {{ padding: 2px 4px; text-align: right; }}
 input[type=range] {{ width: 110px; }} h1 {{ font-size: 15px; margin: 4px 0 8px; }}
</style></head>
<body><div id="wrap">
<div id="view"><div id="hint">click the model to strike it &middot; drag to orbit</div><div id="clock"></div></div>
<div id="side">
 <h1>{title}</h1>
 <div>{summary}</div>
 <p><label>time <select id="slow">
   <option value="1">real time</option><option value="0.1">&times; 0.1</option>
   <option value="0.01" selected>&times; 0.01</option><option value="0.001">&times; 0.001</option></select></label>
   <span id="scale-note"></span></p>
 <p><button id="reset">reset</button></p>
 <p id="impulse">no strike yet</p>
 <table><thead><tr><th>mode</th><th>f, Hz</th><th>&zeta;</th><th>weight</th></tr></thead><tbody id="modes"></tbody></table>
 <p style="color:#666">Weight 1 is a displacement of {amplitude:.0%} of the model's size; a strike plays the
 exact damped response of every mode (sc_fem.ModalPlayer).</p>
</div></div>
<script type="application/json" id="sc-config">{config}</script>
<script type="application/octet-stream" id="sc-glb">{glb}</script>
<script>{bundle}</script>
</body></html>
"""


def _parents(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Each vertex's predictor, shape (n,) int64: its nearest mesh neighbour of lower index (ties:
    the higher index), else the previous vertex; -1 for vertex 0."""
    n = len(vertices)
    parent = np.arange(n) - 1
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    lo, hi = e.min(axis=1), e.max(axis=1)
    lo, hi = lo[lo != hi], hi[lo != hi]
    if len(hi):
        dist = np.einsum("ij,ij->i", vertices[hi] - vertices[lo], vertices[hi] - vertices[lo])
        order = np.lexsort((-lo, dist, hi))                  # per vertex: nearest first, then the higher index
        first = np.ones(len(order), dtype=bool)
        first[1:] = hi[order][1:] != hi[order][:-1]
        parent[hi[order][first]] = lo[order][first]
    return parent


def _planes(a: np.ndarray) -> np.ndarray:
    """Byte planes of an unsigned array ``a`` (n, c): byte ``b`` of column ``j`` of every row,
    plane ``j * itemsize + b`` (little endian), shape (c * itemsize, n) uint8."""
    return np.ascontiguousarray(a.astype(a.dtype.newbyteorder("<")).view(np.uint8).reshape(len(a), -1).T)


def pack_glb(glb: bytes, streams, vertices, faces) -> tuple[bytes, dict]:
    """The page's payload of a quantized ``.glb`` and its description (lossless).

    Parameters
    ----------
    glb : bytes
        The ``.glb``.
    streams : sequence of int
        Byte offsets (from the start of ``glb``) of its 16-bit vertex streams: ``n`` elements of
        four int16 (x, y, z, padding), e.g. the POSITION and target accessors of
        :mod:`sc_fem.io.quantize`.
    vertices : ndarray, shape (n, 3)
        Rest positions (any units: only their distances choose the predictors).
    faces : ndarray of int, shape (f, 3)
        Triangles ((0, 3) for a point set).

    Returns
    -------
    payload : bytes
        ``zlib(glb' + parents)``: in ``glb'`` each stream is replaced by the residuals
        ``r_i = v_i - v_parent(i)`` (mod 2^16; 0 for no parent), zigzag-coded, as 8 byte planes
        of ``n`` bytes; ``parents`` are the gaps ``i - parent(i)`` (0: none) as 4 byte planes.
    spec : dict
        ``codec`` ("zlib"), ``bytes`` (inflated length), ``glb_bytes``, ``vertices`` (``n``),
        ``streams`` (the offsets): what the page's JavaScript and :func:`unpack_glb` read.
    """
    vertices = np.asarray(vertices, dtype=float)
    n = len(vertices)
    parent = _parents(vertices, faces)
    data = bytearray(glb)
    for off in streams:
        v = np.frombuffer(glb, "<i2", 4 * n, off).reshape(n, 4).astype(np.int32)
        r = (v - np.where(parent[:, None] >= 0, v[np.maximum(parent, 0)], 0)).astype(np.int16).astype(np.int32)
        data[off:off + 8 * n] = _planes(((r << 1) ^ (r >> 31)).astype(np.uint16)).tobytes()
    gaps = np.where(parent >= 0, np.arange(n) - parent, 0).astype(np.uint32)
    data += _planes(gaps[:, None]).tobytes()
    spec = {"codec": "zlib", "bytes": len(data), "glb_bytes": len(glb), "vertices": n,
            "streams": [int(o) for o in streams]}
    return zlib.compress(bytes(data), 6), spec


def unpack_glb(payload: bytes, spec: dict) -> bytes:
    """The ``.glb`` of :func:`pack_glb`'s ``payload`` (as the page's JavaScript undoes it)."""
    data = bytearray(zlib.decompress(payload))
    n, size = int(spec["vertices"]), int(spec["glb_bytes"])
    if len(data) != spec["bytes"]:
        raise FileFormatError(f"the viewer's payload inflates to {len(data)} bytes, not {spec['bytes']}")
    gaps = np.frombuffer(bytes(data[size:]), np.uint8).reshape(4, n).T.copy().view("<u4").ravel().astype(np.int64)
    parent = np.where(gaps > 0, np.arange(n) - gaps, -1)
    for off in spec["streams"]:
        z = np.frombuffer(bytes(data[off:off + 8 * n]), np.uint8).reshape(8, n).T.copy().view("<u2").astype(np.int64)
        total, up = (z >> 1) ^ -(z & 1), parent.copy()       # the residuals; pointer jumping sums them to the root
        while (up >= 0).any():
            has = up >= 0
            total = np.where(has[:, None], total + total[np.maximum(up, 0)], total)
            up = np.where(has, up[np.maximum(up, 0)], -1)
        data[off:off + 8 * n] = (total & 0xFFFF).astype("<u2").tobytes()
    return bytes(data[:size])


def read_viewer_glb(page) -> bytes:
    """The ``.glb`` a page of :func:`write_viewer` carries (its payload unpacked).

    Raises
    ------
    FileFormatError
        ``page`` is not such a page, or its payload is damaged.
    """
    text = Path(page).read_text(encoding="utf-8")
    config = re.search(r'<script type="application/json" id="sc-config">(.*?)</script>', text, re.DOTALL)
    glb = re.search(r'<script type="application/octet-stream" id="sc-glb">(.*?)</script>', text, re.DOTALL)
    if not (config and glb):
        raise FileFormatError(f"{page} is not a page of sc-fem view")
    try:
        return unpack_glb(base64.b64decode(glb.group(1)), json.loads(config.group(1))["payload"])
    except (binascii.Error, zlib.error, ValueError, KeyError, TypeError) as exc:
        raise FileFormatError(f"{page}: the model in the page is damaged ({type(exc).__name__}: {exc})") from None


def write_viewer(modes, path, *, amplitude: float | None = None, up: str = "z", title: str | None = None,
                 quantize: bool = True) -> Path:
    """Write the HTML viewer of a mode file (or :class:`~sc_fem.ModalBasis`) to ``path`` (``.html``).

    ``quantize=True`` (default): the modes as 16-bit integers (``KHR_mesh_quantization``, each
    mode on its own range), packed (see the module docstring); ``False``: float32, zlib only.

    Raises
    ------
    FileFormatError
        ``modes`` is a missing, truncated, non-zip or corrupted file.
    RenderError
        The JavaScript bundle has not been built (``make viewer`` needs npm).
    """
    path = Path(path)
    if path.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"the viewer is an .html page, got {path.name!r}")
    up_axis(up)
    basis = _load(modes, what="mode file")                  # the input's faults first, then the machine's
    if isinstance(basis, Animation):
        raise InputError("sc-fem view plays mode files; export an animation with sc-fem export instead")
    if not BUNDLE.is_file():
        raise RenderError(f"the web viewer's JavaScript bundle {BUNDLE} is not built: run `make viewer` "
                          "(it fetches three.js and esbuild from the npm registry; needs node and npm)")
    amplitude = DEFAULT_AMPLITUDE if amplitude is None else float(amplitude)
    doc = gltf_document(basis, amplitude=amplitude, layout="viewer", quantize=quantize)
    glb = b"".join(doc.save_to_bytes())
    streams = []
    if quantize:                                        # the 16-bit vertex streams: POSITION, every target
        prim = doc.meshes[0].primitives[0]
        start = 28 + int.from_bytes(glb[12:16], "little")          # the BIN chunk's data (after the JSON chunk)
        streams = [start + doc.bufferViews[doc.accessors[i].bufferView].byteOffset
                   for i in [prim.attributes.POSITION] + [t["POSITION"] for t in prim.targets or []]]
    payload, spec = pack_glb(glb, streams, basis.vertices, basis.faces)
    factors = doc.meshes[0].extras["sc_fem"].get("quantization", {}).get("weight_factors", [1.0] * basis.n_modes)
    config = {"frequencies_hz": [float(f) for f in basis.frequencies],
              "damping_ratios": [float(z) for z in basis.damping],
              "mode_scales": [float(s) for s in mode_scales(basis, amplitude)],
              "weight_factors": [float(f) for f in factors], "amplitude": amplitude,
              "scale_m_per_unit": float(basis.scale), "up_vector": [1 if a == up else 0 for a in "xyz"],
              "payload": spec}
    name = title or f"{basis.source or 'model'}: {basis.n_modes} modes"
    summary = (f"{basis.n_vertices:,} vertices, {basis.n_modes} modes, "
               f"{basis.frequencies[0]:.3g}&ndash;{basis.frequencies[-1]:.3g} Hz; "
               f"{html.escape(str(basis.material.get('name', '')))}")
    page = _PAGE.format(title=html.escape(name), summary=summary, amplitude=amplitude,
                        config=json.dumps(config).replace("</", "<\\/"),
                        glb=base64.b64encode(payload).decode("ascii"),
                        bundle=BUNDLE.read_text(encoding="utf-8").replace("</script", "<\\/script"))
    with atomic_path(path, suffix=".html") as tmp:
        Path(tmp).write_text(page, encoding="utf-8")
    return path
