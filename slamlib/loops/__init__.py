"""Loop closure in 3D: a back end behind the particle filter.

* :mod:`slamlib.loops.local_maps`: local maps cut from the filter's trajectory every few tens of metres, the
  nodes of the pose graph;
* :mod:`slamlib.loops.pose_graph`: the pose graph (GTSAM), odometry edges and robust loop-closure edges;
* :mod:`slamlib.loops.closer`: :class:`LoopCloser`: loop candidates by place recognition (``map-closures``) and
  by position (:func:`nearby_maps`), verification (ICP with a fitness test), the graph re-optimised after each
  closure and the trajectory re-anchored on it.
"""

from slamlib.loops.closer import (
    Closure,
    LoopCloser,
    close_loops,
    nearby_maps,
    verify_closure,
)
from slamlib.loops.local_maps import LocalMap, LocalMapper, voxel_down_sample
from slamlib.loops.pose_graph import PoseGraph, odometry_sigmas

__all__ = [
    "Closure",
    "LocalMap",
    "LocalMapper",
    "LoopCloser",
    "PoseGraph",
    "close_loops",
    "nearby_maps",
    "odometry_sigmas",
    "verify_closure",
    "voxel_down_sample",
]
