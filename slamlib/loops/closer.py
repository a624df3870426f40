"""Loop closure behind the particle filter: local maps, place recognition, verification, a pose graph.

:class:`LoopCloser` takes the filter's frames one by one (``add_frame(index, pose, points)``) and
:func:`close_loops` a whole run. Every finished local map (:mod:`slamlib.loops.local_maps`) becomes a node of the
pose graph (:mod:`slamlib.loops.pose_graph`), joined to the previous node by the filter's odometry, and is

1. **looked up** among the earlier local maps by place recognition: MapClosures' density-image features
   (Gupta, Guadagnino, Vizzo, Behley & Stachniss, *Effectively Detecting Loop Closures using Point Cloud
   Density Maps*, ICRA 2024; the ``map-closures`` package, which KISS-SLAM uses too): each local map's
   points are projected to a bird's-eye density image, ORB features are matched against every earlier
   image, and the best match with at least :data:`MIN_INLIERS` RANSAC inliers is a candidate, with a
   first guess of the relative pose;
2. **verified** by registering the candidate's points onto the query's with point-to-plane ICP from that
   guess (open3d), kept when at least :data:`MIN_FITNESS` of the candidate's points find a query point within
   :data:`ICP_DISTANCE` metres; candidates fewer than :data:`MIN_NODE_GAP` nodes back are not loops but the
   road just driven, and are skipped;
3. **added** to the pose graph as a closure edge, which the graph keeps or rejects (a chi-square test of every
   edge once solved with it, :meth:`~slamlib.loops.pose_graph.PoseGraph.optimise`) before it re-optimises.

MapClosures itself compares a local map only with those more than three maps back, and needs more than two
descriptor matches to propose one: a return that overlaps an old local map only over a few tens of metres (the
end of route 07 against its start) may find no candidate at all.

After each optimisation every frame is **re-anchored** on its local map's optimised key pose:
``T_k' = T_key' T_key^{-1} T_k`` (:meth:`LoopCloser.corrected_poses`), the filter's own poses left alone.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from slamlib.geometry import invert_pose
from slamlib.loops.local_maps import (
    LOCAL_MAP_VOXEL,
    SPLITTING_DISTANCE,
    LocalMap,
    LocalMapper,
)
from slamlib.loops.pose_graph import PoseGraph

__all__ = [
    "ICP_DISTANCE",
    "MIN_FITNESS",
    "MIN_INLIERS",
    "MIN_NODE_GAP",
    "Closure",
    "LoopCloser",
    "close_loops",
    "verify_closure",
]

#: Place recognition: RANSAC inliers a candidate needs (MapClosures' own default).
MIN_INLIERS = 5
#: A loop joins local maps at least this many nodes apart (nearer ones are the road just driven).
MIN_NODE_GAP = 3
#: ICP correspondence distance (m): sqrt(3) voxels, the diagonal of a local map's voxel (as KISS-SLAM).
ICP_DISTANCE = float(np.sqrt(3) * LOCAL_MAP_VOXEL)
#: Share of the candidate's points that must find a query point within :data:`ICP_DISTANCE` after ICP.
MIN_FITNESS = 0.4


@dataclass(frozen=True)
class Closure:
    """A verified candidate: local map ``query`` (the newer) saw ``reference``; ``query_frame`` and
    ``reference_frame`` are their key poses' frames (the positions :meth:`LoopCloser.add_frame` was given);
    ``relative`` (4x4) is ``T_query^{-1} T_reference`` from ICP; ``inliers`` from place recognition, ``fitness``
    and ``rmse`` (m) from ICP; ``kept``: whether the pose graph kept it (:attr:`LoopCloser.closures` reads it
    from the graph)."""

    query: int
    reference: int
    query_frame: int
    reference_frame: int
    relative: np.ndarray
    inliers: int
    fitness: float
    rmse: float
    kept: bool = False


def verify_closure(reference_points, query_points, guess, distance: float = ICP_DISTANCE):
    """Point-to-plane ICP of ``reference_points`` (M, 3) onto ``query_points`` (N, 3) from ``guess`` (4x4,
    query <- reference). Returns ``(T, fitness, rmse)``: the refined ``T_query_reference``, the share of the
    reference points within ``distance`` of a query point after it, and their RMS distance (m)."""
    import open3d as o3d

    def cloud(p):
        pc = o3d.geometry.PointCloud()
        pc.points = o3d.utility.Vector3dVector(np.asarray(p, dtype=np.float64))
        return pc

    source, target = cloud(reference_points), cloud(query_points)
    target.estimate_normals(
        o3d.geometry.KDTreeSearchParamHybrid(radius=3 * distance, max_nn=20)
    )
    reg = o3d.pipelines.registration.registration_icp(
        source,
        target,
        distance,
        np.asarray(guess, dtype=np.float64),
        o3d.pipelines.registration.TransformationEstimationPointToPlane(),
        o3d.pipelines.registration.ICPConvergenceCriteria(max_iteration=50),
    )
    return np.asarray(reg.transformation), float(reg.fitness), float(reg.inlier_rmse)


class LoopCloser:
    """The back end; see the module. Attributes: ``mapper`` (:class:`LocalMapper`), ``graph``
    (:class:`PoseGraph`, node ``i`` = local map ``i``); :attr:`closures` the verified ones."""

    def __init__(
        self,
        splitting_distance: float = SPLITTING_DISTANCE,
        voxel: float = LOCAL_MAP_VOXEL,
        min_inliers: int = MIN_INLIERS,
        min_fitness: float = MIN_FITNESS,
        min_node_gap: int = MIN_NODE_GAP,
    ):
        self.mapper = LocalMapper(splitting_distance, voxel)
        self.graph = PoseGraph()
        self._verified: list[Closure] = []
        self.min_inliers, self.min_fitness, self.min_node_gap = (
            min_inliers,
            min_fitness,
            min_node_gap,
        )
        self._detector = None

    @property
    def closures(self) -> list[Closure]:
        """The verified closures in the order found, each ``kept`` as the pose graph decided (the graph holds
        one closure edge per verified closure, in the same order)."""
        kept = self.graph.closure_kept
        return [
            replace(c, kept=bool(k < len(kept) and kept[k]))
            for k, c in enumerate(self._verified)
        ]

    def _detect(self, local_map: LocalMap):
        if self._detector is None:
            try:
                from map_closures.config import MapClosuresConfig
                from map_closures.map_closures import MapClosures
            except ImportError as exc:  # pragma: no cover - the message is the point
                raise ImportError(
                    "loop closure needs map-closures 2.2.0 for place recognition: `make setup` installs it"
                ) from exc
            self._detector = MapClosures(
                MapClosuresConfig(inliers_threshold=self.min_inliers)
            )
        return self._detector.get_best_closure(local_map.node, local_map.points)

    def add_frame(self, frame: int, pose, points) -> Closure | None:
        """One frame of the filter: its index, world pose (4x4) and body-frame points (N, 3). Returns the
        closure this frame's local map made, if it finished one and found one."""
        done = self.mapper.add(frame, pose, points)
        return self._node(done) if done is not None else None

    def finish(self) -> Closure | None:
        """Close the last local map (and look it up), then optimise once more."""
        done = self.mapper.finish()
        closure = self._node(done) if done is not None else None
        self.graph.optimise()
        return closure

    def _node(self, m: LocalMap) -> Closure | None:
        if m.node == 0:
            self.graph.add_node(0, m.key_pose)
        else:
            prev = self.mapper.maps[m.node - 1]
            relative = invert_pose(prev.key_pose) @ m.key_pose
            # start the new node where the optimised graph puts it, not at the filter's drifted pose
            self.graph.add_node(m.node, self.graph.poses[prev.node] @ relative)
            self.graph.add_odometry(prev.node, m.node, relative)
        candidate = self._detect(m)
        if candidate.number_of_inliers < self.min_inliers:
            return None
        reference = int(candidate.source_id)
        if m.node - reference < self.min_node_gap:
            return None
        T, fitness, rmse = verify_closure(
            self.mapper.maps[reference].points, m.points, candidate.pose
        )
        if fitness < self.min_fitness:
            return None
        self._verified.append(
            Closure(
                m.node,
                reference,
                m.frames[0],
                self.mapper.maps[reference].frames[0],
                T,
                int(candidate.number_of_inliers),
                fitness,
                rmse,
            )
        )
        self.graph.add_closure(m.node, reference, T)
        self.graph.optimise()
        return self.closures[-1]

    def corrected_poses(self) -> np.ndarray:
        """``(K, 4, 4)`` every frame so far re-anchored on its local map's optimised key pose."""
        out = []
        for m in self.mapper.maps:
            key = self.graph.poses.get(m.node, m.key_pose)
            out.extend(key @ invert_pose(m.key_pose) @ np.asarray(m.poses))
        return np.asarray(out).reshape(-1, 4, 4)


def close_loops(poses, scans, **options) -> tuple[np.ndarray, LoopCloser]:
    """A whole run: ``poses (K, 4, 4)`` (world) and ``scans`` (K body-frame ``(N, 3)`` point arrays) through a
    :class:`LoopCloser` (``options`` go to it). Returns ``(corrected poses (K, 4, 4), the closer)``."""
    closer = LoopCloser(**options)
    for k, (pose, points) in enumerate(zip(poses, scans)):
        closer.add_frame(k, pose, points)
    closer.finish()
    return closer.corrected_poses(), closer
