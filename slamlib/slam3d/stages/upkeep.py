"""The upkeep stage, after step 10: what the map forgets.

Every ``UpkeepConfig.prune_every`` frames the map drops what lies farther than ``prune_radius`` from the vehicle
(bounded memory and lookup time on long drives), keeping those points for the exported map when ``keep_pruned``;
every ``transient_span`` frames the voxel map evicts the voxels hit only within fewer than ``transient_span``
consecutive frames and not lately (:meth:`slamlib.maps.VoxelHashMap.evict_transients`): the trails of moving cars
and people, which a static surface in view does not leave. Either at 0 is off.
"""

from __future__ import annotations

import numpy as np

from slamlib.slam3d.config import UpkeepConfig

__all__ = ["MapUpkeep"]


class MapUpkeep:
    """Pruning and eviction on their schedules (module docstring). ``archive``: list of ``(K, 3)`` float32 world
    points pruned from the map (``keep_pruned``)."""

    def __init__(self, config: UpkeepConfig):
        self.config = config
        self.archive: list[np.ndarray] = []

    def __call__(self, world_map, poses) -> None:
        """Prune and evict when the frame count ``len(poses)`` is due; ``poses[-1]`` is the vehicle's pose."""
        every, span = self.config.prune_every, self.config.transient_span
        if every and len(poses) % every == 0:
            self.prune(world_map, poses[-1][:3, 3])
        if span and len(poses) % span == 0:
            world_map.evict_transients(span)

    def prune(self, world_map, center) -> None:
        """Drop map elements farther than ``prune_radius`` from ``center``; keep their points in ``archive``."""
        r = self.config.prune_radius
        if self.config.keep_pruned:
            pts = world_map.points()
            # the maps' own eviction rule
            far = np.sum((pts.astype(np.float64) - center) ** 2, axis=1) > r**2
            if far.any():
                self.archive.append(pts[far])
        world_map.prune(center, r)
