"""The result of a modal analysis: :class:`ModalBasis`, mass-normalized modes baked onto a mesh.

Units: a mode value is a displacement in metres per unit modal coordinate (m kg^-1/2), so a
modal coordinate ``q`` (m kg^1/2) gives the displacement ``sum_k q_k phi_k`` in metres; an
impulse ``J`` (N s) on a vertex ``v`` gives the modal velocity ``phi_k(v) . J``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..lattice.cubes import CubeModel


@dataclass(frozen=True, eq=False)
class ModalBasis:
    """Mass-normalized vibration modes baked onto a mesh.

    Attributes
    ----------
    frequencies : ndarray, shape (k,)
        Natural frequencies, Hz, ascending (0 for rigid modes).
    modes : ndarray, shape (k, n, 3)
        Mode shapes at the ``vertices``: displacement in metres per unit modal coordinate
        (m kg^-1/2); ``phi^T M phi = 1`` on the lattice.
    vertices : ndarray, shape (n, 3)
        Rest positions of the mesh the modes are baked on, model units.
    faces : ndarray of int, shape (f, 3)
        Triangles of that mesh ((0, 3) for a point set).
    damping : ndarray, shape (k,)
        Damping ratio ``zeta`` of each mode (0 for rigid modes).
    damping_spec : dict
        How ``damping`` was specified: ``{"kind": "ratio", "zeta": ...}`` or
        ``{"kind": "rayleigh", "alpha": ..., "beta": ...}``.
    rigid : ndarray of bool, shape (k,)
        Which modes are rigid-body modes (frequency 0). All False unless ``keep_rigid=True``:
        rigid modes are removed by default. Stored (not derived from ``frequencies == 0``) because
        the mode file format has it.
    residuals : ndarray, shape (k,)
        ``||K phi - omega^2 M phi|| / ||K phi||`` of each mode (see :func:`sc_fem.fem.ritz.relative_residuals`).
    n_rigid_removed : int
        Rigid-body modes found and dropped.
    scale : float
        Metres per model unit (divide a displacement in metres by it to get model units).
    pitch : float
        Cube edge, model units.
    resolution : int
        Cubes along the longest axis of the lattice the modes were computed on.
    element : str
        Element type.
    material : dict
        ``name``, ``youngs`` / ``poisson`` / ``density`` (min and max over cubes), ``mass`` (kg).
    fix_record : dict
        ``specs`` (the ``--fix`` specs), ``vertices`` (count of ``--fix-vertices``),
        ``n_nodes`` (fixed lattice nodes).
    source : str
        Source model name / file name.
    source_sha256 : str
        Checksum of the source file (or of the arrays).
    n_cubes, n_dofs : int
        Size of the lattice problem.
    eigen : dict
        Solver report: ``method``, ``backend``, ``reason``, ``sigma``, ``seconds``, memory estimate.
    timings : dict
        Wall seconds per stage.
    resolution_table : list of dict or None
        ``resolution="auto"``: one row per grid tried (resolution, cubes, DOFs, seconds,
        frequencies, max relative change to the next finer grid, chosen).
    lattice : CubeModel or None
        The lattice (``keep_lattice=True`` only).
    node_modes : ndarray, shape (k, m, 3) or None
        Modes at the lattice nodes, m kg^-1/2 (``keep_lattice=True`` only).
    fixed_points : ndarray, shape (q, 3) or None
        Positions of the fixed lattice nodes, model units (drawn on mode sheets).
    """

    frequencies: np.ndarray
    modes: np.ndarray
    vertices: np.ndarray
    faces: np.ndarray
    damping: np.ndarray
    damping_spec: dict
    rigid: np.ndarray
    residuals: np.ndarray
    n_rigid_removed: int
    scale: float
    pitch: float
    resolution: int
    element: str
    material: dict = field(default_factory=dict)
    fix_record: dict = field(default_factory=dict)
    source: str = ""
    source_sha256: str = ""
    n_cubes: int = 0
    n_dofs: int = 0
    eigen: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    resolution_table: list | None = None
    lattice: CubeModel | None = None
    node_modes: np.ndarray | None = None
    fixed_points: np.ndarray | None = None

    @property
    def n_modes(self) -> int:
        """Number of modes ``k``."""
        return len(self.frequencies)

    @property
    def n_vertices(self) -> int:
        """Number of vertices ``n``."""
        return len(self.vertices)

    @property
    def omegas(self) -> np.ndarray:
        """Angular frequencies ``2 pi f``, rad/s, shape (k,)."""
        return 2.0 * np.pi * self.frequencies

    def summary(self) -> str:
        """A short text table: frequencies, damping ratios and residuals.

        Returns
        -------
        str
            One line per mode: index, frequency (Hz), damping ratio, residual, ``rigid`` tag.
        """
        rows = [f"  {'mode':>4}  {'f [Hz]':>12}  {'zeta':>8}  {'residual':>9}"]
        for i in range(self.n_modes):
            tag = "  rigid" if self.rigid[i] else ""
            rows.append(f"  {i:>4}  {self.frequencies[i]:>12.5g}  {self.damping[i]:>8.4g}  "
                        f"{self.residuals[i]:>9.2e}{tag}")
        return "\n".join(rows)

    def __repr__(self) -> str:
        f = ", ".join(f"{x:.4g}" for x in self.frequencies[:6])
        more = ", ..." if self.n_modes > 6 else ""
        return (f"ModalBasis({self.n_modes} modes on {self.n_vertices} vertices, f = [{f}{more}] Hz, "
                f"{self.n_cubes} cubes, element {self.element!r}, {self.n_rigid_removed} rigid removed)")
