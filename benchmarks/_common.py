"""Helpers shared by the benchmark scripts: output folder, timing, table printing."""

from __future__ import annotations

import os
import time
from pathlib import Path

os.environ.setdefault("MPLBACKEND", "Agg")

OUT = Path(__file__).resolve().parent / "out"
SHARED_MESHES = Path(__file__).resolve().parents[2] / "shared" / "meshes"


def out_path(name: str) -> Path:
    OUT.mkdir(parents=True, exist_ok=True)
    return OUT / name


def best_time(fn, repeat: int = 3):
    """Best wall time of ``repeat`` calls (seconds) and the last result."""
    best, result = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def print_table(headers: list[str], rows: list[list], floatfmt: str = ".4g") -> str:
    def fmt(v):
        if isinstance(v, float):
            return format(v, floatfmt)
        return str(v)

    cells = [[fmt(v) for v in r] for r in rows]
    widths = [max(len(h), *(len(r[i]) for r in cells)) if cells else len(h) for i, h in enumerate(headers)]
    lines = ["| " + " | ".join(h.ljust(w) for h, w in zip(headers, widths)) + " |",
             "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    lines += ["| " + " | ".join(c.rjust(w) for c, w in zip(r, widths)) + " |" for r in cells]
    text = "\n".join(lines)
    print(text)
    return text


def save_figure(fig, name: str, dpi: int = 110) -> Path:
    """Write a matplotlib figure to ``benchmarks/out/NAME`` atomically and say so."""
    from sc_fem._atomic import atomic_path

    path = out_path(name)
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    print(f"wrote {path}")
    return path


BUNNY = {"youngs": 1e7, "poisson": 0.3, "density": 1000.0}
"""The bunny benchmarks' material: E 10 MPa, nu 0.3, 1000 kg/m^3."""


def bunny_scene(r: int, clamp: bool = True):
    """The Stanford bunny of the shared meshes (y up) at resolution ``r``, :data:`BUNNY`'s material,
    the nodes of its lowest 2 % held when ``clamp`` (voxelized here, not timed by the callers)."""
    import warnings

    import numpy as np

    import sc_fem

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mesh = sc_fem.load_mesh(str(SHARED_MESHES / "bunny.obj"))
        ext = float(np.ptp(np.asarray(mesh.vertices)[:, 1]))
        return sc_fem.Scene.from_mesh(mesh, resolution=r, fix=f"y<min+{0.02 * ext:.6g}" if clamp else None, **BUNNY)
