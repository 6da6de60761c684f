"""Film strips of three contact scenes for the docs (``docs/contact_*.png``, shown on docs/guide/dynamics.md):

* **drop**: the built-in chair dropped 10 cm onto the ground (r24, friction 0.3);
* **stack**: a chair dropped onto another chair (one mesh, two bodies, r24);
* **self-contact**: a soft U whose upper arm sags onto its lower arm (r32; beside it the same
  run without self-contact, where the arm passes through).

Each strip is four frames of one run rendered off-screen with pyvista (``sc_fem.io.render``),
the simulated time stamped on each. Usage: ``python benchmarks/contact_pictures.py [--out DIR]``
(about 2 minutes; writes to ``docs/`` by default).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from sc_fem import Scene
from sc_fem.dynamics.contact import Ground
from sc_fem.dynamics.job import run_simulation
from sc_fem.geometry.mesh import load_mesh
from sc_fem.io.render import render_animation
from sc_fem.units import gravity_down

HERE = Path(__file__).resolve().parent


def strip(rec, faces, obstacles, path: Path, title: str, picks=(0.0, 0.25, 0.5, 1.0)) -> Path:
    """Render ``rec``'s frames at the fractions ``picks`` of the run side by side into ``path``."""
    import imageio.v2 as imageio

    idx = sorted({int(round(p * (len(rec.times) - 1))) for p in picks})
    with tempfile.TemporaryDirectory() as tmp:
        render_animation(rec.points[idx], faces, Path(tmp) / "frames", times=rec.times[idx],
                         obstacles=obstacles, window_size=(480, 520), title=title)
        imgs = [imageio.imread(Path(tmp) / "frames" / f"frame_{k:05d}.png") for k in range(len(idx))]
    imageio.imwrite(path, np.concatenate(imgs, axis=1))
    print(f"wrote {path}")
    return path


def u_shape(L=1.0, w=0.1, t=0.05, H=0.25) -> trimesh.Trimesh:
    return trimesh.util.concatenate([trimesh.creation.box(bounds=[[0, 0, 0], [L, w, t]]),
                                     trimesh.creation.box(bounds=[[0, 0, 0], [t, w, H]]),
                                     trimesh.creation.box(bounds=[[0, 0, H - t], [L, w, H]])])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=HERE.parent / "docs")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    t0 = time.perf_counter()
    chair = load_mesh("builtin:chair")
    scene = Scene.from_mesh(chair, resolution=24)
    g = float(scene.rest_vertices[:, 2].min()) - 0.1
    rec = run_simulation(scene, duration=0.6, gravity=gravity_down(), ground=g)
    strip(rec, scene.faces, [Ground(g)], args.out / "contact_drop.png",
          f"chair dropped 10 cm (ipc, r24): {rec.info['newton_iterations']} Newton its, {rec.seconds:.1f} s")

    top = chair.copy()
    top.apply_translation([0.08, 0.05, float(np.ptp(chair.vertices[:, 2])) + 0.15])
    both = trimesh.util.concatenate([chair, top])
    scene = Scene.from_mesh(both, resolution=32, keep="all")
    g = float(scene.rest_vertices[:, 2].min()) - 0.02
    rec = run_simulation(scene, duration=0.8, gravity=gravity_down(), ground=g)
    strip(rec, scene.faces, [Ground(g)], args.out / "contact_stack.png",
          f"a chair dropped on a chair ({rec.info['bodies']} bodies, r32), {rec.seconds:.1f} s")

    scene = Scene.from_mesh(u_shape(), resolution=32, youngs=1e7, density=1000.0, fill="solid",
                            fix=["x<min+0.04", "z<min+0.04"])
    for on, name in ((True, "contact_self.png"), (False, "contact_self_off.png")):
        rec = run_simulation(scene, method="ipc", duration=0.6, gravity=gravity_down(), self_contact=on, friction=0.0)
        strip(rec, scene.faces, [], args.out / name,
              f"soft U, self-contact {'on' if on else 'off'} (r32), {rec.seconds:.1f} s")
    print(f"total {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
