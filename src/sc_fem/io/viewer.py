"""``sc-fem view``: one self-contained HTML page that plays a mode file in the browser.

The page inlines the JavaScript bundle (three.js + :file:`_viewer/main.js`, built from the npm
registry by ``make viewer`` into :file:`_viewer/viewer.js`), the modes as a ``.glb`` (morph
targets, :mod:`sc_fem.io.gltf`) and a small JSON config, so it opens from disk with no network.
It shows per-mode sliders, a *strike* (click the model: an impulse into the surface, played back
as the exact damped modal response), the frequency table and the time scale.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

from ..errors import InputError, RenderError

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


def write_viewer(modes, path, *, amplitude: float | None = None, up: str = "z", title: str | None = None) -> Path:
    """Write the HTML viewer of a mode file (or :class:`~sc_fem.ModalBasis`) to ``path`` (``.html``).

    Raises
    ------
    FileFormatError
        ``modes`` is a missing, truncated, non-zip or corrupted file.
    RenderError
        The JavaScript bundle has not been built (``make viewer`` needs npm).
    """
    from .._atomic import atomic_path
    from .gltf import DEFAULT_AMPLITUDE, _load, glb_bytes, mode_scales
    from .animation import Animation

    path = Path(path)
    if path.suffix.lower() not in (".html", ".htm"):
        raise InputError(f"the viewer is an .html page, got {path.name!r}")
    if up not in ("x", "y", "z"):
        raise InputError(f"up must be 'x', 'y' or 'z', got {up!r}")
    basis = _load(modes, what="mode file")                  # the input's faults first, then the machine's
    if isinstance(basis, Animation):
        raise InputError("sc-fem view plays mode files; export an animation with sc-fem export instead")
    if not BUNDLE.is_file():
        raise RenderError(f"the web viewer's JavaScript bundle {BUNDLE} is not built: run `make viewer` "
                          "(it fetches three.js and esbuild from the npm registry; needs node and npm)")
    amplitude = DEFAULT_AMPLITUDE if amplitude is None else float(amplitude)
    glb = glb_bytes(basis, amplitude=amplitude)
    config = {"frequencies_hz": [float(f) for f in basis.frequencies],
              "damping_ratios": [float(z) for z in basis.damping],
              "mode_scales": [float(s) for s in mode_scales(basis, amplitude)],
              "scale_m_per_unit": float(basis.scale), "up_vector": [1 if a == up else 0 for a in "xyz"]}
    name = title or f"{basis.source or 'model'}: {basis.n_modes} modes"
    summary = (f"{basis.n_vertices:,} vertices, {basis.n_modes} modes, "
               f"{basis.frequencies[0]:.3g}&ndash;{basis.frequencies[-1]:.3g} Hz; "
               f"{html.escape(str(basis.material.get('name', '')))}")
    page = _PAGE.format(title=html.escape(name), summary=summary, amplitude=amplitude,
                        config=json.dumps(config).replace("</", "<\\/"),
                        glb=base64.b64encode(glb).decode("ascii"),
                        bundle=BUNDLE.read_text(encoding="utf-8").replace("</script", "<\\/script"))
    with atomic_path(path, suffix=".html") as tmp:
        Path(tmp).write_text(page, encoding="utf-8")
    return path
