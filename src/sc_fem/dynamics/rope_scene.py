"""The paper's cube-rope scene: the built-in rope, fixed at one end, released from horizontal and
swinging under gravity, simulated by XPBD; 24 curves x 832 points on the source surface carried by
the trilinear embedding W at every frame."""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from .._validate import positive_int, positive_scalar
from ..geometry import models
from ..lattice.cubes import CubeModel
from ..lattice.embed import embed
from ..lattice.voxelize import voxelize
from .xpbd import XPBDSolver

if TYPE_CHECKING:
    import trimesh


@dataclass(frozen=True, eq=False)
class RopeScene:
    """Result of :func:`rope_scene`.

    Attributes
    ----------
    curves : ndarray, shape (n_frames, n_curves, n_points, 3)
        Curve points per frame, model units (= metres for the built-in rope).
    times : ndarray, shape (n_frames,)
        Seconds.
    vertex_positions : ndarray, shape (n_frames, n_vertices, 3)
        Source-mesh vertices per frame, model units.
    faces : ndarray of int, shape (n_faces, 3)
    node_positions : ndarray, shape (n_frames, n_nodes, 3)
        Lattice node positions per frame, model units.
    model : CubeModel
    timings : dict
        Wall seconds: ``"voxelize"``, ``"simulate"``, ``"per_frame"``, ``"total"``; and
        ``"simulate_cpu"``, the process CPU seconds of the simulation.
    """

    curves: np.ndarray
    times: np.ndarray
    vertex_positions: np.ndarray
    faces: np.ndarray
    node_positions: np.ndarray
    model: CubeModel
    timings: dict = field(default_factory=dict)


def rope_curve_points(mesh: trimesh.Trimesh, n_curves: int = 24, n_points: int = 832) -> np.ndarray:
    """Points on the surface of a rope lying along x: ``n_curves`` angular positions around the
    long axis x ``n_points`` stations along it, projected onto the surface by ray casting from the
    axis outwards. Returns shape (n_curves, n_points, 3), model units."""
    lo, hi = mesh.bounds
    centre = 0.5 * (lo + hi)
    xs = np.linspace(lo[0], hi[0], n_points + 2)[1:-1]
    ang = 2 * np.pi * np.arange(n_curves) / n_curves
    d = np.stack([np.zeros(n_curves), np.cos(ang), np.sin(ang)], -1)                 # (c, 3)
    origins = np.zeros((n_curves, n_points, 3))
    origins[..., 0] = xs[None, :]
    origins[..., 1:] = centre[1:]
    dirs = np.broadcast_to(d[:, None, :], origins.shape)
    o, dd = origins.reshape(-1, 3), dirs.reshape(-1, 3)
    locs, ray, _ = mesh.ray.intersects_location(o, dd, multiple_hits=True)
    # outermost hit of each ray (rays start on the axis inside the rope)
    dist = np.einsum("ij,ij->i", locs - o[ray], dd[ray])
    best = np.full(len(o), -np.inf)
    np.maximum.at(best, ray, dist)
    missing = ~np.isfinite(best)
    best[missing] = 0.0
    pts = o + dd * best[:, None]
    if np.any(missing):            # fall back to the closest surface point
        import trimesh

        cp, _, _ = trimesh.proximity.closest_point(mesh, o[missing] + dd[missing] * 0.5 * (hi[1] - lo[1]))
        pts[missing] = cp
    return pts.reshape(n_curves, n_points, 3)


def rope_scene(n_frames: int = 201, fps: float = 60.0, resolution: int = 40, substeps: int = 60,
               iterations: int = 1, youngs: float | None = None, mesh: trimesh.Trimesh | None = None,
               constraints: str = "neohookean", n_curves: int = 24, n_points: int = 832, damping: float = 0.0,
               progress: bool = False, kernel: str = "auto") -> RopeScene:
    """Simulate the cube-rope scene with XPBD.

    Parameters
    ----------
    n_frames : int
        Frames including the rest frame 0.
    fps : float
        Frames per second (frame step ``1 / fps`` s).
    resolution : int
        Cubes along the rope's length.
    substeps, iterations : int
        XPBD substeps per frame and iterations per substep.
    youngs : float, optional
        Young's modulus, Pa (default: the built-in rope's material ``sc_fem.geometry.models.material("rope")``,
        1 MPa; its Poisson's ratio and density are always used).
    mesh : trimesh.Trimesh, optional
        Rope mesh along x (default ``sc_fem.geometry.models.load("rope")``).
    constraints, damping, kernel : str, float, str
        As :class:`~sc_fem.dynamics.xpbd.XPBDSolver` (``damping`` in 1/s).
    n_curves, n_points : int
        Curves around the rope's axis and points along each (:func:`rope_curve_points`).
    progress : bool
        Show a progress bar on stderr.

    Returns
    -------
    RopeScene
        Curves, vertices and nodes per frame (model units), and the timings.
    """
    n_frames = positive_int(n_frames, "n_frames")
    fps = positive_scalar(fps, "fps")
    t0 = _time.perf_counter()
    if mesh is None:
        mesh = models.load("rope")
    mat = models.material("rope")
    E = mat.youngs if youngs is None else positive_scalar(youngs, "youngs")
    model = voxelize(mesh, resolution=resolution, youngs=E, poisson=mat.poisson, density=mat.density)
    verts = np.asarray(mesh.vertices, dtype=float)
    curves0 = rope_curve_points(mesh, n_curves, n_points)
    pts = np.vstack([verts, curves0.reshape(-1, 3)])
    W = embed(model, pts)
    t1, c1 = _time.perf_counter(), _time.process_time()
    fixed = np.flatnonzero(model.node_index[:, 0] == model.node_index[:, 0].min())
    solver = XPBDSolver(model, 1.0 / fps, substeps=substeps, iterations=iterations, constraints=constraints,
                        fixed_nodes=fixed, damping=damping, kernel=kernel)
    rest = model.nodes_m
    out = np.empty((n_frames, len(pts), 3))
    nodes = np.empty((n_frames, model.n_nodes, 3))
    for f, st in enumerate(solver.run(n_frames - 1, progress=progress)):
        out[f] = pts + (W @ (st.positions - rest)) / model.scale
        nodes[f] = st.positions / model.scale
    t2, c2 = _time.perf_counter(), _time.process_time()
    nv = len(verts)
    return RopeScene(curves=out[:, nv:].reshape(n_frames, n_curves, n_points, 3),
                     times=np.arange(n_frames) / fps, vertex_positions=out[:, :nv],
                     faces=np.asarray(mesh.faces, dtype=np.int64), node_positions=nodes, model=model,
                     timings={"voxelize": t1 - t0, "simulate": t2 - t1, "simulate_cpu": c2 - c1,
                              "per_frame": (t2 - t1) / max(n_frames - 1, 1), "total": t2 - t0})
