"""Saving a :class:`~sc_fem.lattice.cubes.CubeModel`: ``.npz`` (reloadable) or ``.vtu`` (ParaView)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .._atomic import atomic_path, save_npz_atomic
from ._npz import read_versioned_npz
from ..errors import InputError
from ..lattice.cubes import CubeModel
from .render import _VTK_HEX_ORDER

MODEL_FORMAT_VERSION = 1
MODEL_KIND = "sc_fem.cubemodel"


def save_model(model: CubeModel, path: str | Path) -> Path:
    """Write ``model`` atomically as ``.npz`` (see :func:`load_model`) or ``.vtu`` (hexahedra with
    per-cube mass, E, nu, rho, component and body as cell data, node coordinates in model units).

    Parameters
    ----------
    model : CubeModel
        The lattice.
    path : str or Path
        Output file, ``.npz`` or ``.vtu``.

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    ext = path.suffix.lower()
    if ext == ".npz":
        return save_npz_atomic(
            path, format_version=np.int64(MODEL_FORMAT_VERSION), kind=np.str_(MODEL_KIND),
            origin=model.origin, pitch=np.float64(model.pitch), scale=np.float64(model.scale),
            dims=model.dims, cells=model.cells, mass=model.mass, youngs=model.youngs,
            poisson=model.poisson, density=model.density, connectivity=np.str_(model.connectivity),
            fraction=model.fraction, stiffness=np.str_(model.stiffness),
            **({} if model.moments is None else {"moments": model.moments}),
            piece=model.piece,
            **({} if model.sites is None else {"sites": model.sites, "site_piece": model.site_piece}),
            info_json=np.str_(json.dumps(model.info, default=str)))
    if ext == ".vtu":
        import meshio

        m = meshio.Mesh(model.nodes, [("hexahedron", model.hexes[:, _VTK_HEX_ORDER])],
                        cell_data={"mass_kg": [model.mass], "youngs_Pa": [model.youngs],
                                   "fraction": [model.fraction],
                                   "poisson": [model.poisson], "density_kg_m3": [model.density],
                                   "component": [model.component], "body": [model.piece]})
        with atomic_path(path, suffix=".vtu") as tmp:
            meshio.write(str(tmp), m, file_format="vtu")
        return path
    raise InputError(f"unsupported model output {path.name!r}: use .npz or .vtu (or .png for a picture)")


def load_model(path: str | Path) -> CubeModel:
    """Read a model written by :func:`save_model` (``.npz``).

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    CubeModel
    """
    d = read_versioned_npz(path, kind=MODEL_KIND, version=MODEL_FORMAT_VERSION, what="cube-model file")
    return CubeModel.from_cells(d["cells"], origin=d["origin"], pitch=float(d["pitch"]), scale=float(d["scale"]),
                                dims=d["dims"], mass=d["mass"], youngs=d["youngs"], poisson=d["poisson"],
                                density=d["density"], connectivity=str(d["connectivity"]),
                                fraction=d["fraction"] if "fraction" in d else 1.0,
                                stiffness=str(d["stiffness"]) if "stiffness" in d else "full",
                                moments=d["moments"] if "moments" in d else None,
                                piece=d["piece"] if "piece" in d else None,
                                sites=d["sites"] if "sites" in d else None,
                                site_piece=d["site_piece"] if "site_piece" in d else None,
                                info=json.loads(str(d["info_json"])))
