"""The Squashing Cubes lattice: occupied voxels as elastic cubes (:class:`CubeModel`).

Corners follow scikit-fem's ``MeshHex`` order (:data:`~sc_fem.lattice.topology.HEX_CORNERS`), so
``MeshHex(nodes.T, hexes.T)`` is valid without reordering (:meth:`CubeModel.to_skfem`). Geometry
(``origin``, ``pitch``, ``nodes``) is in the source model's units; ``scale`` converts model units to
metres, so the cube edge in metres is :attr:`CubeModel.h`. Masses in kg, moduli in Pa, densities in kg/m^3.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from .._arrays import column_bounds
from .._validate import as_float_array, check_material, positive_scalar
from ..errors import InputError
from ..material import lame
from .topology import CONNECTIVITY, HEX_CORNERS, components, nodes_and_hexes, voxel_index  # noqa: F401

if TYPE_CHECKING:
    from skfem import MeshHex

STIFFNESS_MODES = ("full", "fraction", "moments")
"""How partly filled cubes are stiffened (:attr:`CubeModel.stiffness`)."""

@dataclass(frozen=True, eq=False)
class CubeModel:
    """A lattice of elastic cubes built from a geometric model.

    Attributes
    ----------
    origin : ndarray, shape (3,)
        Lowest corner of the voxel grid, model units.
    pitch : float
        Cube edge length, model units.
    scale : float
        Metres per model unit (``h = pitch * scale`` is the edge in metres).
    dims : ndarray of int, shape (3,)
        Grid size in cubes along x, y, z.
    cells : ndarray of int, shape (n, 3)
        Lattice index (i, j, k) of each cube, sorted lexicographically.
    mass : ndarray, shape (n,)
        Mass of each cube in kg (sum of its samples' masses).
    youngs : ndarray, shape (n,)
        Young's modulus of each cube's material, Pa (mass-weighted average of its samples').
        Solvers use :meth:`lame`, which applies ``stiffness``.
    poisson : ndarray, shape (n,)
        Poisson's ratio per cube.
    density : ndarray, shape (n,)
        Density per cube, kg/m^3 (mass-weighted average of its samples').
    nodes : ndarray, shape (m, 3)
        Cube corner positions, model units.
    node_index : ndarray of int, shape (m, 3)
        Lattice index of each node (corner (i, j, k) sits at ``origin + pitch * (i, j, k)``).
    hexes : ndarray of int, shape (n, 8)
        Node indices of each cube in :data:`HEX_CORNERS` (scikit-fem) order.
    component : ndarray of int, shape (n,)
        Connected-component label of each cube (0 = largest).
    fraction : ndarray, shape (n,)
        Filled volume fraction of each cube in (0, 1] (1 for full cubes).
    stiffness : str
        How partly filled cubes are stiffened: ``"full"`` (every cube at its material's
        stiffness, the original Squashing Cubes), ``"fraction"`` (Lame parameters times
        ``fraction``) or ``"moments"`` (the element matrices integrated over the filled region,
        from ``moments``; solvers that take one pair of Lame parameters per cube use
        ``"fraction"``).
    moments : ndarray, shape (n, 27), or None
        Moments of each cube's filled region (:mod:`sc_fem.lattice.moments`), when known.
    connectivity : str
        Neighbourhood used for components: ``"face"``, ``"edge"`` or ``"vertex"``.
    n_components : int
        Number of connected components in this model.
    info : dict
        Provenance and statistics (samples, method, fill, dropped cubes, ...).
    piece : ndarray of int, shape (n,)
        Body of each cube (:mod:`sc_fem.geometry.bodies`; all 0 for one body). Cubes of different
        bodies may occupy the same cell: each has its own nodes (virtual nodes), and nodes are
        shared only between cubes of one body.
    sites : ndarray, shape (s, 3), or None
        Points of the source surface (model units) with their bodies in ``site_piece``: a point
        is located in the cube of the body of its nearest site (:meth:`piece_at`).
    site_piece : ndarray of int, shape (s,), or None
        Body of each site.
    """

    origin: np.ndarray
    pitch: float
    scale: float
    dims: np.ndarray
    cells: np.ndarray
    mass: np.ndarray
    youngs: np.ndarray
    poisson: np.ndarray
    density: np.ndarray
    nodes: np.ndarray
    node_index: np.ndarray
    hexes: np.ndarray
    component: np.ndarray
    fraction: np.ndarray
    stiffness: str = "full"
    moments: np.ndarray | None = None
    connectivity: str = "face"
    info: dict = field(default_factory=dict)
    piece: np.ndarray | None = None
    sites: np.ndarray | None = None
    site_piece: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.piece is None:
            object.__setattr__(self, "piece", np.zeros(len(self.cells), dtype=np.int64))

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_cells(cls, cells: ArrayLike, *, origin: ArrayLike, pitch: float, mass: ArrayLike,
                   youngs: ArrayLike, poisson: ArrayLike, density: ArrayLike,
                   scale: float = 1.0, dims: ArrayLike | None = None, connectivity: str = "face",
                   info: dict | None = None, fraction: ArrayLike = 1.0, stiffness: str = "full",
                   moments: ArrayLike | None = None, piece: ArrayLike | None = None,
                   sites: ArrayLike | None = None, site_piece: ArrayLike | None = None) -> "CubeModel":
        """Build a model from occupied lattice cells and per-cube properties.

        Parameters
        ----------
        cells : array_like of int, shape (n, 3)
            Lattice indices (i, j, k) >= 0 of the occupied cubes (duplicates are an error).
        origin : array_like, shape (3,)
            Grid origin, model units.
        pitch : float
            Cube edge, model units.
        mass, youngs, poisson, density : array_like, shape (n,) or scalar
            Per-cube mass (kg), E (Pa), nu, rho (kg/m^3).
        fraction : array_like, shape (n,) or scalar
            Filled volume fraction of each cube, in (0, 1] (default 1).
        stiffness : {"full", "fraction", "moments"}
            See the class attributes.
        moments : array_like, shape (n, 27), optional
            Moments of the filled region per cube (needed for ``stiffness="moments"``).
        scale : float
            Metres per model unit.
        dims : array_like of int, shape (3,), optional
            Grid size; defaults to ``cells.max(0) + 1``.
        connectivity : {"face", "edge", "vertex"}
            Neighbourhood for component labelling.
        piece : array_like of int, shape (n,), optional
            Body of each cube (default all 0). A cell may hold one cube per body; nodes are shared
            only between cubes of the same body.
        sites, site_piece : array_like, shapes (s, 3) and (s,), optional
            Points on the source surface and their bodies (see :meth:`piece_at`).
        info : dict, optional
            Provenance and statistics, stored (copied) as :attr:`info`.

        Returns
        -------
        CubeModel
            Cubes sorted lexicographically by cell (then body), with their nodes, hexes and
            connected components.
        """
        cells = np.asarray(cells)
        if cells.ndim != 2 or cells.shape[1] != 3 or len(cells) == 0:
            raise InputError(f"cells must have shape (n, 3) with n >= 1, got {cells.shape}")
        if not np.issubdtype(cells.dtype, np.integer):
            raise InputError(f"cells must be integers, got dtype {cells.dtype}")
        cells = cells.astype(np.int64)
        if cells.min() < 0:
            raise InputError("cells must be non-negative lattice indices")
        origin = as_float_array(origin, "origin", (3,))
        pitch = positive_scalar(pitch, "pitch")
        scale = positive_scalar(scale, "scale")
        if connectivity not in CONNECTIVITY:
            raise InputError(f"connectivity must be one of {sorted(CONNECTIVITY)}, got {connectivity!r}")
        n = len(cells)

        def per_cube(v, name):
            a = as_float_array(np.broadcast_to(np.asarray(v, dtype=float), (n,)), name, (n,))
            return np.array(a, dtype=float)

        mass = per_cube(mass, "mass")
        youngs, poisson, density = per_cube(youngs, "youngs"), per_cube(poisson, "poisson"), per_cube(density, "density")
        if np.any(mass <= 0):
            raise InputError(f"mass must be > 0 kg for every cube, got min {mass.min():g}")
        check_material(youngs, poisson, density, where="per-cube material")
        fraction = per_cube(fraction, "fraction")
        if np.any(fraction <= 0) or np.any(fraction > 1):
            raise InputError(f"fraction must be in (0, 1] for every cube, got {fraction.min():g} .. {fraction.max():g}")
        if stiffness not in STIFFNESS_MODES:
            raise InputError(f"stiffness must be one of {STIFFNESS_MODES}, got {stiffness!r}")
        if moments is not None:
            moments = as_float_array(moments, "moments", (n, 27))
        elif stiffness == "moments":
            raise InputError("stiffness='moments' needs the moments of every cube")
        top = column_bounds(cells)[1]
        dims = top + 1 if dims is None else np.asarray(dims, dtype=np.int64)
        if np.any(top >= dims):
            raise InputError(f"cells exceed the grid dims {tuple(dims)}")
        piece = np.zeros(n, np.int64) if piece is None else np.asarray(piece)
        if piece.shape != (n,) or not np.issubdtype(piece.dtype, np.integer) or piece.min() < 0:
            raise InputError(f"piece must be ({n},) non-negative integers, got {piece.shape} {piece.dtype}")
        piece = piece.astype(np.int64)
        if (sites is None) != (site_piece is None):
            raise InputError("give sites and site_piece together")
        if sites is not None:
            sites = as_float_array(sites, "sites")
            site_piece = np.asarray(site_piece, dtype=np.int64)
            if sites.ndim != 2 or sites.shape[1] != 3 or site_piece.shape != (len(sites),):
                raise InputError(f"sites must be (s, 3) with site_piece (s,), got {sites.shape}, {site_piece.shape}")
        # sort cells lexicographically, then by body (stable, deterministic numbering)
        lin = np.ravel_multi_index(cells.T, dims)
        key = lin * (int(piece.max()) + 1) + piece
        order = np.argsort(key, kind="stable")
        if np.any(np.diff(key[order]) == 0):
            raise InputError("cells contain duplicate lattice indices (of the same piece)")
        cells, mass, youngs, poisson, density, fraction, piece = (
            a[order] for a in (cells, mass, youngs, poisson, density, fraction, piece))
        moments = None if moments is None else moments[order]

        node_index, hexes = nodes_and_hexes(cells, dims, piece)
        nodes = origin + pitch * node_index.astype(float)
        component = components(cells, dims, connectivity, piece)
        return cls(origin=origin, pitch=pitch, scale=scale, dims=np.asarray(dims, dtype=np.int64),
                   cells=cells, mass=mass, youngs=youngs, poisson=poisson, density=density,
                   nodes=nodes, node_index=node_index, hexes=hexes, component=component, fraction=fraction,
                   stiffness=stiffness, moments=moments, connectivity=connectivity, info=dict(info or {}),
                   piece=piece, sites=sites, site_piece=site_piece)

    @classmethod
    def box(cls, shape: ArrayLike, pitch: float, *, youngs: float = 200e9, poisson: float = 0.3,
            density: float = 7850.0, origin: ArrayLike = (0.0, 0.0, 0.0), scale: float = 1.0) -> "CubeModel":
        """A solid box of ``shape = (nx, ny, nz)`` cubes with mass ``density * h^3`` each.

        Handy for verification (cantilevers, patch tests) without any mesh.

        Parameters
        ----------
        shape : array_like of int, shape (3,)
            Number of cubes along x, y, z (each >= 1).
        pitch : float
            Cube edge, model units.
        youngs : float
            Young's modulus, Pa (default steel, 200 GPa).
        poisson : float
            Poisson's ratio.
        density : float
            Density, kg/m^3.
        origin : array_like, shape (3,)
            Lowest corner of the box, model units.
        scale : float
            Metres per model unit.

        Returns
        -------
        CubeModel
            ``nx * ny * nz`` full cubes of edge ``h = pitch * scale`` m.
        """
        shape = np.asarray(shape, dtype=np.int64)
        if shape.shape != (3,) or np.any(shape < 1):
            raise InputError(f"shape must be three positive integers, got {shape.tolist()}")
        cells = np.stack(np.meshgrid(*[np.arange(s) for s in shape], indexing="ij"), -1).reshape(-1, 3)
        h = positive_scalar(pitch, "pitch") * positive_scalar(scale, "scale")
        return cls.from_cells(cells, origin=origin, pitch=pitch, scale=scale, dims=shape,
                              mass=density * h**3, youngs=youngs, poisson=poisson, density=density,
                              info={"occupancy": "box"})

    # ------------------------------------------------------------------ derived
    @property
    def n_cubes(self) -> int:
        """Number of cubes."""
        return len(self.cells)

    @property
    def n_nodes(self) -> int:
        """Number of lattice nodes."""
        return len(self.nodes)

    @property
    def n_dofs(self) -> int:
        """Number of displacement degrees of freedom (3 per node)."""
        return 3 * len(self.nodes)

    @property
    def h(self) -> float:
        """Cube edge length in metres."""
        return self.pitch * self.scale

    @property
    def n_components(self) -> int:
        """Number of connected components."""
        return int(self.component.max()) + 1

    @property
    def component_sizes(self) -> np.ndarray:
        """Cubes per component, largest first."""
        return np.bincount(self.component)

    @property
    def n_pieces(self) -> int:
        """Number of bodies with cubes in this model (1 unless cells hold cubes of several bodies)."""
        return len(np.unique(self.piece))

    @property
    def shares_cells(self) -> bool:
        """Whether some cell holds cubes of more than one body."""
        lin = np.ravel_multi_index(self.cells.T, self.dims)
        return bool(np.any(np.diff(lin) == 0))

    def piece_at(self, points: ArrayLike) -> np.ndarray:
        """Body of each point (n, 3), model units: that of the nearest site (all 0 without sites).

        Parameters
        ----------
        points : array_like, shape (n, 3)
            Positions, model units.

        Returns
        -------
        ndarray of int64, shape (n,)
            Body (:attr:`piece` label) of each point.
        """
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        if self.sites is None or not len(self.sites):
            return np.zeros(len(points), np.int64)

        _, i = cKDTree(self.sites).query(points)
        return self.site_piece[i]

    @property
    def total_mass(self) -> float:
        """Total mass, kg."""
        return float(self.mass.sum())

    @property
    def nodes_m(self) -> np.ndarray:
        """Node positions in metres, shape (m, 3)."""
        return self.nodes * self.scale

    @property
    def cell_centers(self) -> np.ndarray:
        """Cube centres in model units, shape (n, 3)."""
        return self.origin + self.pitch * (self.cells + 0.5)

    def lame(self, *, material: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Per-cube Lame parameters (lambda, mu) in Pa, each shape (n,).

        The effective values a one-pair-per-cube solver should use: the material's times
        ``fraction`` unless ``stiffness == "full"``; ``material=True``: the material's own.

        Parameters
        ----------
        material : bool
            Return the material's own Lame parameters, without the ``fraction`` scaling.

        Returns
        -------
        lam, mu : ndarray, shape (n,)
            First Lame parameter and shear modulus of each cube, Pa.
        """
        lam, mu = lame(self.youngs, self.poisson)
        if material or self.stiffness == "full":
            return lam, mu
        return lam * self.fraction, mu * self.fraction

    def node_masses(self, masses: ArrayLike | None = None) -> np.ndarray:
        """Lumped node masses in kg, shape (m,): each cube gives 1/8 of its mass to each corner.

        Parameters
        ----------
        masses : array_like, shape (n,), optional
            Per-cube masses in kg; default :attr:`mass`.

        Returns
        -------
        ndarray, shape (m,)
            Mass lumped at each node, kg.
        """
        if masses is None:
            mass = self.mass
        else:
            mass = as_float_array(masses, "masses")
            if mass.shape != (self.n_cubes,):
                raise InputError(f"masses must have shape ({self.n_cubes},), got {mass.shape}")
        return np.bincount(self.hexes.ravel(), weights=np.repeat(mass / 8.0, 8), minlength=self.n_nodes)

    def to_skfem(self, metres: bool = True) -> MeshHex:
        """The lattice as a scikit-fem ``MeshHex`` (node coordinates in metres by default).

        Parameters
        ----------
        metres : bool
            Node coordinates in metres (``True``) or in model units.

        Returns
        -------
        skfem.MeshHex
            The nodes and hexes (same numbering, :data:`HEX_CORNERS` order).
        """
        from skfem import MeshHex

        p = self.nodes_m if metres else self.nodes
        return MeshHex(np.ascontiguousarray(p.T), np.ascontiguousarray(self.hexes.T))

    def subset(self, mask: ArrayLike) -> "CubeModel":
        """A new model with only the cubes where ``mask`` (shape (n,) bool) is true; nodes renumbered.

        Parameters
        ----------
        mask : array_like of bool, shape (n,)
            Cubes to keep (at least one).

        Returns
        -------
        CubeModel
            The kept cubes with their properties; components relabelled (every cube kept: the model).
        """
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != (self.n_cubes,):
            raise InputError(f"mask must have shape ({self.n_cubes},), got {mask.shape}")
        if not mask.any():
            raise InputError("mask selects no cube")
        if mask.all():                      # immutable: a rebuild would give the same arrays
            return self
        return CubeModel.from_cells(self.cells[mask], origin=self.origin, pitch=self.pitch, scale=self.scale,
                                    dims=self.dims, mass=self.mass[mask], youngs=self.youngs[mask],
                                    poisson=self.poisson[mask], density=self.density[mask],
                                    fraction=self.fraction[mask], stiffness=self.stiffness,
                                    moments=None if self.moments is None else self.moments[mask],
                                    connectivity=self.connectivity, info=dict(self.info), piece=self.piece[mask],
                                    sites=self.sites, site_piece=self.site_piece)

    def with_info(self, **kw: Any) -> "CubeModel":
        """A copy with ``info`` updated.

        Parameters
        ----------
        **kw
            Entries to add to (or replace in) :attr:`info`.

        Returns
        -------
        CubeModel
            The same lattice (arrays shared) with the new ``info``.
        """
        return replace(self, info={**self.info, **kw})

    def __repr__(self) -> str:
        return (f"CubeModel({self.n_cubes} cubes, {self.n_nodes} nodes, pitch={self.pitch:g} "
                f"(h={self.h:g} m), dims={tuple(int(d) for d in self.dims)}, "
                f"{self.n_components} component(s), mass={self.total_mass:g} kg)")
