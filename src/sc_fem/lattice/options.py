"""The options of :func:`sc_fem.voxelize`, grouped in one frozen object that travels unchanged
from the command line (or a notebook) through :class:`sc_fem.Scene` and :func:`sc_fem.modal`
to the voxelizer."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Mapping

from .._validate import positive_int, positive_scalar
from ..errors import InputError, ResolutionError
from .cubes import CONNECTIVITY

FILLS = ("auto", "solid", "surface")
OCCUPANCIES = ("sample", "exact")
KEEPS = ("bodies", "largest", "all")
TOPOLOGIES = ("pieces", "grid")
STIFFNESS = ("moments", "fraction", "full")
DEFAULT_SUBSAMPLES = 4     # n: n^3 inside-test samples per boundary cube
DEFAULT_RESOLUTION = 32    # cubes along the longest axis when neither resolution nor pitch is given
MAX_RESOLUTION = 100_000   # cubes along an axis beyond any machine's memory


def check_resolution(resolution: int) -> int:
    """``resolution`` (cubes along the longest axis, a positive int already), refused beyond
    :data:`MAX_RESOLUTION` with a :class:`~sc_fem.errors.ResolutionError`."""
    if resolution > MAX_RESOLUTION:
        raise ResolutionError(f"resolution {resolution} is beyond any machine's memory (max {MAX_RESOLUTION})")
    return resolution


@dataclass(frozen=True, eq=False)
class VoxelOptions:
    """How a mesh becomes cubes: grid, units, material and the Squashing Cubes choices.

    Every field has a default, so ``VoxelOptions()`` is the voxelizer's default;
    ``opts.replace(resolution=48)`` is a copy with one field changed. Choices and numbers are
    checked when the object is made (per-face material arrays when the mesh is known).

    Parameters
    ----------
    resolution : int, optional
        Cubes along the longest bounding-box axis (default 32). Exclusive with ``pitch``.
    pitch : float, optional
        Cube edge in model units.
    scale : float
        Metres per model unit (a model in millimetres: ``scale=0.001``).
    youngs, poisson, density : float, array_like (n_faces,) or callable, optional
        Young's modulus (Pa), Poisson's ratio, density (kg/m^3): a scalar, one value per source
        face, or ``f(points (n, 3) model units) -> (n,)``. Default: the built-in model's
        material, else :data:`sc_fem.lattice.voxelize.DEFAULT_MATERIAL`.
    mass : float, optional
        Total mass in kg; rescales the mass implied by ``density`` and the geometry.
    fill : {"auto", "solid", "surface"}
        How the mass is found from the geometry. Parts are sets of faces connected through
        shared vertices; a part *encloses volume* when the generalized winding number just inside
        and outside its faces sums to about 1 (:mod:`sc_fem.geometry.inside`; works on broken
        meshes). ``"auto"`` (default): parts that enclose volume are solids, the others shells;
        ``"solid"``: every part is a solid (inside = winding number > 1/2); ``"surface"``: every
        part is a shell of ``shell_thickness``. A solid's mass is ``rho`` times the volume inside
        each cube; a shell's is ``rho * area * shell_thickness``.
    occupancy : {"sample", "exact"}
        Which cubes the surface occupies: ``"sample"``, the paper's point sampling; ``"exact"``,
        conservative triangle-box overlap, so no touched voxel is ever lost.
    keep : {"bodies", "largest", "all"}
        Which connected components of the lattice stay. ``"bodies"`` (default): the largest
        component of every body (see ``topology``), except *loose* bodies lighter than 1 % of
        the heaviest (stray polygons), whose vertices then follow the nearest kept cube;
        ``"largest"``: only the largest component (dropping more than half the cubes warns);
        ``"all"``: everything.
    topology : {"pieces", "grid"}
        What is connected to what. ``"pieces"`` (default): parts of the mesh (faces connected
        through shared vertex positions) closer than ``weld``, crossing or inside one another
        form one body (:mod:`sc_fem.geometry.bodies`); cubes of different bodies never share a
        node, also where they occupy the same cell (virtual nodes), so the number of bodies does
        not change with the resolution. ``"grid"``: everything in one cell moves together (the
        original Squashing Cubes; two parts a third of a cube apart move as one).
    weld : float, optional
        Weld distance of ``topology="pieces"``, model units (>= 0). Default: 0.5 % of the longest
        bounding-box extent, independent of the resolution.
    connectivity : {"face", "edge", "vertex"}, optional
        Which cubes count as connected. Default ``"face"`` (cubes that touch only along an edge
        or a corner share 1--2 nodes and would act as free hinges), ``"vertex"`` for point clouds.
    n_samples : int, optional
        Use N random area-weighted samples (the paper's scheme) instead of the stratified grid.
    spacing : float, optional
        Stratified-grid sample spacing in model units (default ``pitch / 8``).
    shell_thickness : float, optional
        Physical thickness of shell parts, model units. Default: 1 % of the longest bounding-box
        extent (independent of the resolution).
    stiffness : {"moments", "fraction", "full"}
        ``"moments"`` (default): a partly filled cube's element matrices are integrated over its
        filled region (finite cell method, :mod:`sc_fem.lattice.moments`); ``"fraction"``: its
        Lame parameters are scaled by its filled volume fraction; ``"full"``: every cube at the
        full material stiffness (the original Squashing Cubes).
    subsamples : int
        Inside tests per boundary-cube edge (``subsamples^3`` per cube; default 4).
    seed : int
        Random seed (only ``n_samples`` sampling is random).
    max_memory : float, optional
        Bytes the grid and samples may use; default half the available memory. A grid that would
        not fit is refused before allocation, with a resolution that would.
    """

    resolution: int | None = None
    pitch: float | None = None
    scale: float = 1.0
    youngs: Any = None
    poisson: Any = None
    density: Any = None
    mass: float | None = None
    fill: str = "auto"
    occupancy: str = "sample"
    keep: str = "bodies"
    topology: str = "pieces"
    weld: float | None = None
    connectivity: str | None = None
    n_samples: int | None = None
    spacing: float | None = None
    shell_thickness: float | None = None
    stiffness: str = "moments"
    subsamples: int = DEFAULT_SUBSAMPLES
    seed: int = 0
    max_memory: float | None = None

    def __post_init__(self) -> None:
        for name, allowed in (("fill", FILLS), ("occupancy", OCCUPANCIES), ("keep", KEEPS), ("stiffness", STIFFNESS),
                              ("topology", TOPOLOGIES)):
            if getattr(self, name) not in allowed:
                raise InputError(f"{name} must be one of {', '.join(repr(a) for a in allowed)}, "
                                 f"got {getattr(self, name)!r}")
        if self.connectivity is not None and self.connectivity not in CONNECTIVITY:
            raise InputError(f"connectivity must be one of {sorted(CONNECTIVITY)}, got {self.connectivity!r}")
        if self.resolution is not None and self.pitch is not None:
            raise InputError("give resolution or pitch, not both")
        norm: dict[str, Any] = {"scale": positive_scalar(self.scale, "scale"),
                                "subsamples": positive_int(self.subsamples, "subsamples"),
                                "seed": positive_int(self.seed, "seed", minimum=0)}
        for name in ("resolution", "n_samples"):
            if getattr(self, name) is not None:
                norm[name] = positive_int(getattr(self, name), name)
        if "resolution" in norm:
            check_resolution(norm["resolution"])
        for name in ("pitch", "mass", "spacing", "shell_thickness", "max_memory"):
            if getattr(self, name) is not None:
                norm[name] = positive_scalar(getattr(self, name), name)
        if self.weld is not None:
            norm["weld"] = positive_scalar(self.weld, "weld", allow_zero=True)
        for name, value in norm.items():
            object.__setattr__(self, name, value)

    @classmethod
    def fields(cls) -> tuple[str, ...]:
        """The option names, in declaration order.

        Returns
        -------
        tuple of str
            The dataclass field names.
        """
        return tuple(f.name for f in dataclasses.fields(cls))

    def replace(self, **changes: Any) -> "VoxelOptions":
        """A copy with some fields changed; an unknown name is an :class:`~sc_fem.errors.InputError`.

        Parameters
        ----------
        **changes
            New values of fields (see the class attributes), checked like the constructor's.

        Returns
        -------
        VoxelOptions
            The copy (``self`` when nothing changes).
        """
        unknown = sorted(set(changes) - set(self.fields()))
        if unknown:
            raise InputError(f"unknown voxelize option(s) {', '.join(map(repr, unknown))}; "
                             f"the options are {', '.join(self.fields())}")
        return dataclasses.replace(self, **changes) if changes else self

    @classmethod
    def coerce(cls, options: "VoxelOptions | Mapping[str, Any] | None" = None, **changes: Any) -> "VoxelOptions":
        """``options`` (a VoxelOptions, a mapping of its fields or None) with ``changes`` applied.

        Parameters
        ----------
        options : VoxelOptions, mapping of str to value, or None
            The base options (``None``: the defaults).
        **changes
            Further fields: ones that ``options`` leaves at their defaults, or the same values
            again; a field given twice with two values is an :class:`~sc_fem.errors.InputError`.

        Returns
        -------
        VoxelOptions
            The combined options.
        """
        if options is None:
            base = cls()
        elif isinstance(options, cls):
            base = options
        elif isinstance(options, Mapping):
            base = cls().replace(**dict(options))
        else:
            raise InputError(f"voxelize options must be a VoxelOptions or a dict, got {type(options).__name__}")
        given = base.changed()
        clash = [f"{k}={v!r}" for k, v in changes.items() if k in given and not _same(given[k], v)]
        if clash:
            raise InputError(f"{', '.join(clash)} contradicts the voxel options {base!r}: give each once")
        return base.replace(**changes)

    def changed(self) -> dict[str, Any]:
        """The fields that differ from the defaults (for records and reprs).

        Returns
        -------
        dict of str to value
            Field name to value, in declaration order.
        """
        default = VoxelOptions()
        return {k: getattr(self, k) for k in self.fields() if getattr(self, k) is not getattr(default, k)
                and not (_is_plain(getattr(self, k)) and getattr(self, k) == getattr(default, k))}

    def __repr__(self) -> str:
        return "VoxelOptions(" + ", ".join(f"{k}={_short(v)}" for k, v in self.changed().items()) + ")"


def _is_plain(v: Any) -> bool:
    return v is None or isinstance(v, (str, int, float))


def _short(v: Any) -> str:
    if _is_plain(v):
        return repr(v)
    return f"<{type(v).__name__}>"


def _same(a: Any, b: Any) -> bool:
    """One option value given twice: the same object, or equal numbers or names."""
    return a is b or (isinstance(a, (str, int, float)) and isinstance(b, (str, int, float)) and a == b)
