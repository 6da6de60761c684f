"""A model carried through the pipeline: the source mesh, its cube lattice, the trilinear
embedding that joins them, and the fixed nodes -- built once, used by every solver."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, Iterable

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from ._validate import as_points
from .errors import InputError
from .geometry.mesh import load_mesh
from .geometry.models import expand_fix
from .lattice.boundary import Fix, fixed_dofs, fixed_nodes
from .lattice.cubes import CubeModel
from .lattice.embed import Embedding, embedding
from .lattice.options import VoxelOptions
from .lattice.voxelize import voxelize


@dataclass(frozen=True, eq=False)
class Scene:
    """Source mesh + :class:`~sc_fem.CubeModel` + embedding + fixed nodes.

    Build it with :meth:`from_mesh` (voxelizes) or :meth:`from_model` (an existing lattice), or
    :meth:`coerce` (either, from what a convenience was given); the solvers
    (:func:`sc_fem.modes.modal.modal`, :func:`sc_fem.fem.static.solve_static`,
    :func:`sc_fem.dynamics.run_simulation`, the XPBD recorder) take it.

    Attributes
    ----------
    mesh : trimesh.Trimesh or None
        The source mesh, model units (None: the lattice nodes stand for it).
    model : CubeModel
        The cube lattice.
    fixed_nodes : ndarray of int, shape (k,)
        Fixed lattice nodes (sorted, unique).
    fix : tuple of str
        The fix specifications the nodes came from (for the records of output files).
    n_fix_vertices : int
        Source vertices whose cubes were fixed.
    """

    mesh: Any
    model: CubeModel
    fixed_nodes: np.ndarray
    fix: tuple = ()
    n_fix_vertices: int = 0

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_mesh(cls, source: Any, options: Any = None, *, fix: Iterable[Fix] | Fix | None = None,
                  fix_vertices: ArrayLike | None = None, **fields: Any) -> "Scene":
        """Load (any :func:`sc_fem.load_mesh` input), voxelize and fix.

        Parameters
        ----------
        source : path, ``"builtin:NAME"``, trimesh.Trimesh or (vertices, faces)
            The source mesh, model units.
        options : VoxelOptions or dict, optional
            How to voxelize (:class:`~sc_fem.lattice.options.VoxelOptions`).
        fix : str, FixSpec, callable or list, optional
            Fixed nodes (:func:`sc_fem.fixed_nodes`); ``"default"`` = a built-in's supports.
        fix_vertices : array_like of int, optional
            Source vertices whose cubes are fixed.
        **fields
            Fields of :class:`~sc_fem.lattice.options.VoxelOptions` overriding ``options``
            (``resolution``, ``scale``, ``fill``, ``youngs``, ...).

        Returns
        -------
        Scene
            The loaded mesh, its voxelized lattice and the fixed nodes.
        """
        options = VoxelOptions.coerce(options, **fields)       # a field given twice differently: an error
        mesh = load_mesh(source)
        model = voxelize(mesh, options)
        return cls.from_model(model, mesh, fix=fix, fix_vertices=fix_vertices)

    @classmethod
    def check(cls, scene: Any, caller: str, convenience: str) -> "Scene":
        """``scene`` if it is a Scene, else one :class:`~sc_fem.errors.InputError` naming the way to one.

        Parameters
        ----------
        scene : Any
            What a strict solver was given.
        caller : str
            The solver (``"sc_fem.modes.modal"``), named in the error.
        convenience : str
            The call that builds the Scene itself (``"sc_fem.modal(source, ...)"``).

        Returns
        -------
        Scene
        """
        if not isinstance(scene, cls):
            raise InputError(f"{caller} takes a Scene, got {type(scene).__name__}: build one with "
                             f"Scene.from_mesh / Scene.from_model, or call {convenience}, which does")
        return scene

    @classmethod
    def coerce(cls, source: Any, options: Any = None, *, mesh: Any = None, fix: Iterable[Fix] | Fix | None = None,
               fix_vertices: ArrayLike | None = None, **fields: Any) -> "Scene":
        """A Scene from what a solver's convenience was given: a Scene (as it is), a
        :class:`~sc_fem.CubeModel` (:meth:`from_model`) or a mesh (:meth:`from_mesh`).

        Parameters
        ----------
        source : Scene, CubeModel, path, ``"builtin:NAME"``, trimesh.Trimesh or (vertices, faces)
            What to build the scene from.
        options : VoxelOptions or dict, optional
            How a mesh is voxelized (not with a Scene or a CubeModel: they have their grid).
        mesh : mesh-like or ndarray, shape (n, 3), optional
            The source mesh or points of interest of a CubeModel (model units).
        fix : str, FixSpec, callable or list, optional
            Fixed nodes (:func:`sc_fem.fixed_nodes`); not with a Scene (it has its own).
        fix_vertices : array_like of int, optional
            Source vertices whose cubes are fixed; not with a Scene.
        **fields
            Fields of :class:`~sc_fem.lattice.options.VoxelOptions` (``resolution``, ``youngs``, ...)
            for a mesh.

        Returns
        -------
        Scene
            ``source`` itself, or the scene built from it.

        Raises
        ------
        InputError
            An argument that ``source`` already settles (a Scene's fixed nodes and mesh, a
            lattice's grid), or ``mesh`` beside a mesh ``source``.
        """
        grid = [k for k, v in {"voxel": options, **fields}.items() if v is not None]
        if isinstance(source, Scene):
            given = grid + [k for k, v in (("mesh", mesh), ("fix", fix), ("fix_vertices", fix_vertices)) if v is not None]
            if given:
                raise InputError(f"a Scene already has its grid, fixed nodes and mesh: do not pass {', '.join(given)}")
            return source
        if isinstance(source, CubeModel):
            if grid:
                raise InputError(f"a CubeModel already has its grid: do not pass {', '.join(grid)} "
                                 "(pass the mesh as the source to voxelize it)")
            return cls.from_model(source, mesh, fix=fix, fix_vertices=fix_vertices)
        if mesh is not None:
            raise InputError("mesh= goes with a CubeModel; a mesh to voxelize is the source itself")
        return cls.from_mesh(source, options, fix=fix, fix_vertices=fix_vertices, **fields)

    @classmethod
    def from_model(cls, model: CubeModel, mesh: Any = None, *, fix: Iterable[Fix] | Fix | None = None,
                   fix_vertices: ArrayLike | None = None) -> "Scene":
        """A scene around an existing lattice.

        ``mesh`` (optional; needed by ``fix_vertices``) is anything :func:`sc_fem.load_mesh`
        accepts, or an ``(n, 3)`` array of points of interest (any number, even one).

        Parameters
        ----------
        model : CubeModel
            The cube lattice.
        mesh : path, ``"builtin:NAME"``, trimesh.Trimesh, (vertices, faces) or ndarray, shape (n, 3), optional
            The source mesh or points of interest, model units.
        fix : str, FixSpec, callable or list, optional
            Fixed nodes (:func:`sc_fem.fixed_nodes`); ``"default"`` = a built-in's supports.
        fix_vertices : array_like of int, optional
            Source vertices whose cubes are fixed (needs ``mesh``).

        Returns
        -------
        Scene
            ``model`` with ``mesh`` and the fixed nodes.
        """
        if not isinstance(model, CubeModel):
            raise InputError(f"model must be a CubeModel, got {type(model).__name__}")
        mesh = None if mesh is None else _source(mesh)
        if fix_vertices is not None and mesh is None:
            raise InputError("fix_vertices needs the source mesh (mesh=) to locate the vertices")
        source = str(model.info.get("source", "")) if mesh is None else str(mesh.metadata.get("source", ""))
        if fix is None:
            specs = None
        else:
            specs = expand_fix(list(fix) if isinstance(fix, (list, tuple)) else [fix], source)
        emb = None
        if fix_vertices is not None:             # locating the vertices is the embedding: do it once
            emb = embedding(model, np.asarray(mesh.vertices, dtype=float))
        nodes = fixed_nodes(model, specs, vertices=fix_vertices, mesh_embedding=emb)
        record = () if specs is None else tuple(str(s) for s in specs)
        scene = cls(mesh=mesh, model=model, fixed_nodes=np.asarray(nodes, dtype=np.int64), fix=record,
                    n_fix_vertices=0 if fix_vertices is None else int(np.size(fix_vertices)))
        if emb is not None:
            scene.__dict__["embedding"] = emb    # the value the cached property would compute
        return scene

    # ------------------------------------------------------------------ the source surface
    @property
    def rest_vertices(self) -> np.ndarray:
        """Source vertices at rest, shape (n, 3), model units (the lattice nodes without a mesh)."""
        if self.mesh is None:
            return self.model.nodes
        return np.asarray(self.mesh.vertices, dtype=float)

    @property
    def faces(self) -> np.ndarray:
        """Source triangles, shape (f, 3) ((0, 3) without a mesh or for a point set)."""
        if self.mesh is None:
            return np.zeros((0, 3), dtype=np.int64)
        return np.asarray(self.mesh.faces, dtype=np.int64).reshape(-1, 3)

    @property
    def source(self) -> str:
        """Name of the source (file path or ``builtin:NAME``)."""
        meta = {} if self.mesh is None else self.mesh.metadata
        return str(meta.get("source", self.model.info.get("source", "")))

    @property
    def sha256(self) -> str:
        """Checksum of the source mesh's arrays."""
        meta = {} if self.mesh is None else self.mesh.metadata
        return str(meta.get("sha256", self.model.info.get("sha256", "")))

    @cached_property
    def embedding(self) -> Embedding:
        """Where the source vertices sit in the lattice (:class:`~sc_fem.Embedding`)."""
        return embedding(self.model, self.rest_vertices)

    @property
    def W(self) -> sp.csr_matrix:
        """Trilinear map, shape (n_vertices, n_nodes): node displacements to vertex displacements."""
        return self.embedding.W

    # ------------------------------------------------------------------ maps
    def vertex_displacements(self, u: ArrayLike) -> np.ndarray:
        """Displacements of the source vertices, model units, from node displacements ``u`` in
        metres: shape (m, 3) -> (n, 3), or a stack (k, m, 3) -> (k, n, 3).

        Parameters
        ----------
        u : array_like, shape (m, 3) or (k, m, 3)
            Node displacements, m.

        Returns
        -------
        ndarray, shape (n, 3) or (k, n, 3)
            Vertex displacements ``W u / scale``, model units.
        """
        u = np.asarray(u, dtype=float)
        m = self.model.n_nodes
        if u.shape[-2:] != (m, 3) or u.ndim not in (2, 3):
            raise InputError(f"u must have shape ({m}, 3) or (k, {m}, 3), got {u.shape}")
        if u.ndim == 2:
            return np.asarray(self.W @ u) / self.model.scale
        flat = u.transpose(1, 0, 2).reshape(m, -1)                 # (m, 3k)
        out = np.asarray(self.W @ flat).reshape(-1, u.shape[0], 3)
        return out.transpose(1, 0, 2) / self.model.scale

    def vertex_positions(self, u: ArrayLike) -> np.ndarray:
        """Positions of the source vertices (model units) for node displacements ``u`` (m):
        ``rest + W u / scale``; shapes as in :meth:`vertex_displacements`.

        Parameters
        ----------
        u : array_like, shape (m, 3) or (k, m, 3)
            Node displacements, m.

        Returns
        -------
        ndarray, shape (n, 3) or (k, n, 3)
            Deformed vertex positions, model units.
        """
        return self.rest_vertices + self.vertex_displacements(u)

    def forces_to_nodes(self, f: ArrayLike) -> np.ndarray:
        """Forces on the source vertices (n, 3), N, to the lattice nodes (m, 3): ``W^T f``, the
        transpose of ``W`` (node displacements in metres -> vertex displacements in metres), so
        the work done is the same. (:meth:`vertex_displacements` returns model units, ``W u / scale``.)

        Parameters
        ----------
        f : array_like, shape (n, 3)
            Forces on the source vertices, N.

        Returns
        -------
        ndarray, shape (m, 3)
            Equivalent forces on the lattice nodes, N.
        """
        f = np.asarray(f, dtype=float)
        n = self.W.shape[0]
        if f.shape != (n, 3):
            raise InputError(f"f must have shape ({n}, 3), got {f.shape}")
        return np.asarray(self.W.T @ f)

    @property
    def fixed_dofs(self) -> np.ndarray:
        """Fixed degrees of freedom (3 per fixed node)."""
        return fixed_dofs(self.fixed_nodes)

    def fix_record(self) -> dict:
        """What was fixed, for the records of output files.

        Returns
        -------
        dict
            ``"specs"`` (list of str), ``"vertices"`` (number of fixed source vertices) and
            ``"n_nodes"`` (number of fixed lattice nodes).
        """
        return {"specs": list(self.fix), "vertices": self.n_fix_vertices, "n_nodes": int(len(self.fixed_nodes))}

    def material_record(self) -> dict:
        """The material of the cubes (ranges over cubes) and the total mass, for file records.

        Returns
        -------
        dict
            ``"name"``; ``"youngs"`` (Pa), ``"poisson"`` and ``"density"`` (kg/m^3) as
            ``[min, max]`` over the cubes; ``"mass"``, the total in kg.
        """
        m = self.model
        return {"name": str(m.info.get("material", "")),
                "youngs": [float(m.youngs.min()), float(m.youngs.max())],
                "poisson": [float(m.poisson.min()), float(m.poisson.max())],
                "density": [float(m.density.min()), float(m.density.max())],
                "mass": m.total_mass}

    def __repr__(self) -> str:
        return (f"Scene({self.source or 'lattice'}: {self.model.n_cubes} cubes, "
                f"{self.rest_vertices.shape[0]} vertices, {len(self.fixed_nodes)} fixed nodes)")


def _source(mesh: Any):
    """A source mesh from anything :func:`sc_fem.load_mesh` reads; a bare ``(n, 3)`` array of
    points becomes a face-less mesh without the point-cloud checks (one point is fine here)."""
    points = isinstance(mesh, np.ndarray) and mesh.ndim == 2 or (
        isinstance(mesh, list) and len(mesh) > 0 and all(np.ndim(p) == 1 for p in mesh))
    if points:
        import trimesh

        return trimesh.Trimesh(vertices=as_points(mesh, "points"), faces=np.zeros((0, 3), dtype=np.int64),
                               process=False)
    return load_mesh(mesh)
