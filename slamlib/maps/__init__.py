"""3D map structures behind one interface (:class:`~slamlib.maps.base.Map3D`) for steps 8 and 10.

* :class:`VoxelHashMap`: hashed voxels holding per-voxel Gaussians (NDT), fixed memory, fast (the default).
* :class:`MortonBVHMap`: exact points sorted by Morton code (implicit linear BVH), nearest-neighbour score.

``map.lookup()`` gives the flat tuple (:class:`VoxelHashLookup` / :class:`MortonLookup`) that
``slamlib.kernels.get_backend(name).score_particles`` reads. See :mod:`slamlib.maps.base` for the layouts.
"""

from slamlib.maps.base import (
    KIND_MORTON,
    KIND_VOXEL_HASH,
    Map3D,
    MortonLookup,
    VoxelHashLookup,
)
from slamlib.maps.morton_bvh import MortonBVHMap
from slamlib.maps.voxel_hash import DEFAULT_VOXEL_CAPACITY, VoxelHashMap

#: The map kinds by name: the one list of them (:data:`slamlib.slam3d.config.MAP_KINDS` is its keys).
MAP_TYPES = {"voxel_hash": VoxelHashMap, "morton_bvh": MortonBVHMap}
#: The kind :func:`make_map` builds when none is named, and :attr:`slamlib.slam3d.config.MapConfig.kind`'s default.
DEFAULT_MAP_KIND = "voxel_hash"


def make_map(kind: str = DEFAULT_MAP_KIND, **kwargs) -> Map3D:
    """Construct a map by name (a key of :data:`MAP_TYPES`: ``"voxel_hash"`` or ``"morton_bvh"``) with keyword
    parameters (the constructor's defaults for the others)."""
    if kind not in MAP_TYPES:
        raise ValueError(
            f"unknown map kind {kind!r}; choose one of {', '.join(MAP_TYPES)}"
        )
    return MAP_TYPES[kind](**kwargs)


__all__ = [
    "Map3D",
    "VoxelHashMap",
    "MortonBVHMap",
    "VoxelHashLookup",
    "MortonLookup",
    "KIND_VOXEL_HASH",
    "KIND_MORTON",
    "MAP_TYPES",
    "DEFAULT_MAP_KIND",
    "DEFAULT_VOXEL_CAPACITY",
    "make_map",
]
