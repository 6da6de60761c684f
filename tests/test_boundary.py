"""Fix specs, node selection, vertex files."""

from __future__ import annotations

import numpy as np
import pytest

from sc_fem.lattice.boundary import FixSpec, fixed_dofs, fixed_nodes, parse_fix, read_vertex_file
from sc_fem.errors import BoundaryConditionError
from sc_fem.lattice.cubes import CubeModel


@pytest.fixture
def model():
    # 4 x 2 x 3 cubes of pitch 0.5 starting at (1, 2, -1): nodes x in [1, 3], y in [2, 3], z in [-1, 0.5]
    return CubeModel.box((4, 2, 3), 0.5, origin=(1.0, 2.0, -1.0))


def test_parse_forms():
    assert parse_fix("x<0.01").conditions == ((0, "<", None, 0.01),)
    assert parse_fix("z<min+0.02").conditions == ((2, "<", "min", 0.02),)
    assert parse_fix(" y > max - 0.1 ").conditions == ((1, ">", "max", -0.1),)
    assert parse_fix("X>=-1e-3").conditions == ((0, ">", None, -1e-3),)
    assert parse_fix("x>0.2 & x<0.4").conditions == ((0, ">", None, 0.2), (0, "<", None, 0.4))
    assert parse_fix("z<min").conditions == ((2, "<", "min", 0.0),)


@pytest.mark.parametrize("bad", ["", "w<1", "x<", "x<min*2", "x=1", "x<1 &", "1<x"])
def test_parse_errors(bad):
    with pytest.raises(BoundaryConditionError):
        parse_fix(bad)


def test_half_spaces_absolute_and_relative(model):
    X = model.nodes
    a = fixed_nodes(model, "x<1.01")
    assert np.array_equal(a, np.flatnonzero(np.isclose(X[:, 0], 1.0)))
    b = fixed_nodes(model, ["z<min+0"])                      # the lowest face, within tolerance
    assert np.array_equal(b, np.flatnonzero(np.isclose(X[:, 2], -1.0)))
    c = fixed_nodes(model, "y>max-0.1")
    assert np.array_equal(c, np.flatnonzero(np.isclose(X[:, 1], 3.0)))
    both = fixed_nodes(model, ["x<1.01", "y>max-0.1"])         # union
    assert np.array_equal(both, np.union1d(a, c))


def test_box_slab_and_predicate(model):
    X = model.nodes
    slab = fixed_nodes(model, "x>1.9 & x<2.6")
    assert np.array_equal(slab, np.flatnonzero((X[:, 0] > 1.9) & (X[:, 0] < 2.6)))
    box = fixed_nodes(model, FixSpec.box([1.4, 2.0, -0.6], [2.1, 2.6, 0.0]))
    inside = np.all((X >= np.array([1.4, 2.0, -0.6]) - 1e-9) & (X <= np.array([2.1, 2.6, 0.0]) + 1e-9), axis=1)
    assert np.array_equal(box, np.flatnonzero(inside))
    pred = fixed_nodes(model, lambda p: np.linalg.norm(p - [1, 2, -1], axis=1) < 0.6)
    assert np.array_equal(pred, np.flatnonzero(np.linalg.norm(X - [1, 2, -1], axis=1) < 0.6))


def test_selection_errors(model):
    with pytest.raises(BoundaryConditionError, match="selects no node"):
        fixed_nodes(model, "x<0.5")
    with pytest.raises(BoundaryConditionError, match="bool array"):
        fixed_nodes(model, lambda p: p[:, 0])
    with pytest.raises(BoundaryConditionError, match="failed"):
        fixed_nodes(model, lambda p: 1 / 0)
    with pytest.raises(BoundaryConditionError, match="mesh_vertices"):
        fixed_nodes(model, vertices=[0])


def test_vertices_fix_the_nodes_of_their_cubes(model):
    verts = np.array([[1.1, 2.1, -0.9],       # inside cube (0, 0, 0)
                      [2.75, 2.75, 0.25],     # inside cube (3, 1, 2)
                      [9.0, 9.0, 9.0]])
    nodes = fixed_nodes(model, vertices=[0, 1], mesh_vertices=verts)
    cubes = [np.flatnonzero(np.all(model.cells == c, axis=1))[0] for c in [(0, 0, 0), (3, 1, 2)]]
    assert np.array_equal(nodes, np.unique(model.hexes[cubes]))
    with pytest.raises(BoundaryConditionError, match="vertex indices"):
        fixed_nodes(model, vertices=[3], mesh_vertices=verts)
    # a precomputed embedding of all vertices gives the same nodes (and the same range check)
    from sc_fem.lattice.embed import embedding

    emb = embedding(model, verts)
    assert np.array_equal(fixed_nodes(model, vertices=[0, 1], mesh_embedding=emb), nodes)
    with pytest.raises(BoundaryConditionError, match="vertex indices"):
        fixed_nodes(model, vertices=[3], mesh_embedding=emb)
    # mesh_vertices without vertices is ignored: only the specs count
    assert np.array_equal(fixed_nodes(model, "x<min+0", mesh_vertices=verts), fixed_nodes(model, "x<min+0"))
    assert fixed_nodes(model, mesh_vertices=verts).size == 0


def test_vertex_file(tmp_path):
    p = tmp_path / "v.txt"
    p.write_text("# fixed\n3\n 7 \n\n12  # comment\n")
    assert read_vertex_file(p).tolist() == [3, 7, 12]
    p.write_text("3\nseven\n")
    with pytest.raises(BoundaryConditionError, match="not an integer"):
        read_vertex_file(p)
    with pytest.raises(BoundaryConditionError, match="cannot read"):
        read_vertex_file(tmp_path / "missing.txt")
    p.write_text("# nothing\n")
    with pytest.raises(BoundaryConditionError, match="no vertex"):
        read_vertex_file(p)


def test_fixed_dofs():
    assert fixed_dofs([0, 2]).tolist() == [0, 1, 2, 6, 7, 8]
