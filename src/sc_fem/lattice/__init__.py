"""The cube lattice: voxelizing a mesh into elastic cubes (:class:`CubeModel`), their filled
volumes and moments, and the trilinear embedding of the source mesh in the lattice."""

from .._lazy import lazy_getattr
from .embed import embed  # functions named like their module are bound eagerly
from .voxelize import voxelize

_NAMES = {"CubeModel": ".cubes", "Embedding": ".embed", "embedding": ".embed", "voxel_index": ".cubes",
          "VoxelOptions": ".options"}
__all__ = sorted([*_NAMES, "embed", "voxelize"])
__getattr__ = lazy_getattr(__name__, _NAMES)
