"""Every public test mesh in ../shared/meshes (several badly broken) voxelizes and embeds."""

from __future__ import annotations

import numpy as np
import pytest

import sc_fem
from sc_fem.lattice.embed import embedding
from conftest import SHARED_MESHES

NAMES = sorted(p.name for p in SHARED_MESHES.glob("*") if p.suffix in (".obj", ".off", ".stl")) \
    if SHARED_MESHES.is_dir() else []


@pytest.fixture(scope="module")
def loaded():
    cache = {}

    def get(name):
        if name not in cache:
            cache[name] = sc_fem.load_mesh(SHARED_MESHES / name)
        return cache[name]

    return get


@pytest.mark.skipif(not NAMES, reason=f"shared test meshes not present at {SHARED_MESHES}")
@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("res, fill", [(8, "surface"), (16, "solid"), (32, "surface"), (64, "surface"), (64, "solid")])
def test_voxelize_and_embed(loaded, name, res, fill):
    mesh = loaded(name)
    model = sc_fem.voxelize(mesh, resolution=res, fill=fill)
    assert int(model.dims.max()) == res
    # one lattice component per body the geometry has (the teapot's lid is its own body), at every resolution
    kept = model.info["bodies"] - model.info.get("loose_bodies", 0)
    assert model.n_cubes >= 1 and model.n_components == kept and np.all(model.mass > 0)
    e = embedding(model, mesh.vertices)
    np.testing.assert_allclose(np.asarray(e.W.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    assert e.W.shape == (len(mesh.vertices), model.n_nodes)
    ok = ~e.detached
    np.testing.assert_allclose((e.W @ model.nodes)[ok], mesh.vertices[ok], atol=1e-9 * model.pitch * 1e3)
    if fill == "solid":
        surface = sc_fem.voxelize(mesh, resolution=res, keep="all")
        assert model.n_cubes >= surface.info["cubes_found"] * 0.5
