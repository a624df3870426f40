"""Loop closure behind the particle filter: local maps, loop candidates, verification, a pose graph.

:class:`LoopCloser` takes the filter's frames one by one (``add_frame(index, pose, points)``) and
:func:`close_loops` a whole run. Every finished local map (:mod:`slamlib.loops.local_maps`) becomes a node of the
pose graph (:mod:`slamlib.loops.pose_graph`), joined to the previous node by the filter's odometry, and is

1. **looked up** among the earlier local maps, two ways:

   - by *place recognition*: MapClosures' density-image features (Gupta, Guadagnino, Vizzo, Behley &
     Stachniss, *Effectively Detecting Loop Closures using Point Cloud Density Maps*, ICRA 2024; the
     ``map-closures`` package, which KISS-SLAM uses too): each local map's points are projected to a
     bird's-eye density image, ORB features are matched against every earlier image, and the best match with
     at least :data:`MIN_INLIERS` RANSAC inliers is a candidate, with a first guess of the relative pose;
   - by *position* (:func:`nearby_maps`): an earlier local map whose path, placed by the optimised graph,
     passes within :data:`SEARCH_RADIUS` metres plus :data:`SEARCH_DRIFT` of the distance driven since of the
     new map's path is a candidate, with the graph's relative pose as first guess. MapClosures compares a map
     only with those more than three back and needs more than two descriptor matches: a return that overlaps
     an old local map only over a few tens of metres (the end of KITTI route 07 against its start) gives it
     nothing, while the graph, drifting a fraction of a percent, knows the car is back;

2. **verified** by registering the candidate's points onto the query's with point-to-plane ICP from that
   guess (open3d), coarse to fine (correspondences within :data:`COARSE_DISTANCES` metres on thinned clouds,
   then :data:`ICP_DISTANCE`), kept when at least :data:`MIN_FITNESS` of the candidate's points find a query
   point within :data:`ICP_DISTANCE` metres; candidates fewer than :data:`MIN_NODE_GAP` nodes back are not
   loops but the road just driven, and are skipped; the first candidate that passes (place recognition's,
   then the nearest by position) makes the closure;
3. **added** to the pose graph as a closure edge, which the graph keeps or rejects (a chi-square test of every
   edge once solved with it, :meth:`~slamlib.loops.pose_graph.PoseGraph.optimise`) before it re-optimises.

After each optimisation every frame is **re-anchored** on the optimised key poses: ``T_k' = C T_k`` with ``C``
the key poses' corrections ``T_key' T_key^{-1}`` blended by the frame's place between its local map's key pose
and the next (:meth:`LoopCloser.corrected_poses`), the filter's own poses left alone.
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
    "COARSE_DISTANCES",
    "ICP_DISTANCE",
    "MAX_PROPOSALS",
    "MIN_FITNESS",
    "MIN_INLIERS",
    "MIN_NODE_GAP",
    "PATH_STRIDE",
    "SEARCH_DRIFT",
    "SEARCH_RADIUS",
    "Closure",
    "LoopCloser",
    "close_loops",
    "nearby_maps",
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
#: ICP's coarse passes (m of correspondence distance, each on clouds thinned to half of it) before the fine one
#: at :data:`ICP_DISTANCE`: a first guess from the pose graph is off by the drift since the candidate, metres
#: after a kilometre.
COARSE_DISTANCES = (4.0, 2.0)
#: Proposal by position: an earlier path within this many metres of the new one's is a candidate ...
SEARCH_RADIUS = 10.0
#: ... plus this share of the distance driven between them (the drift the graph may have gathered).
SEARCH_DRIFT = 0.02
#: At most this many candidates by position are verified per local map, the nearest first.
MAX_PROPOSALS = 3
#: Every this many frames of a local map's path are compared by :func:`nearby_maps`.
PATH_STRIDE = 5


@dataclass(frozen=True)
class Closure:
    """A verified candidate: local map ``query`` (the newer) saw ``reference``; ``query_frame`` and
    ``reference_frame`` are their key poses' frames (the positions :meth:`LoopCloser.add_frame` was given);
    ``relative`` (4x4) is ``T_query^{-1} T_reference`` from ICP; ``inliers`` from place recognition (0 for a
    candidate by position), ``fitness`` and ``rmse`` (m) from ICP; ``proposed_by``: ``"place"`` (place
    recognition) or ``"position"`` (:func:`nearby_maps`); ``kept``: whether the pose graph kept it
    (:attr:`LoopCloser.closures` reads it from the graph)."""

    query: int
    reference: int
    query_frame: int
    reference_frame: int
    relative: np.ndarray
    inliers: int
    fitness: float
    rmse: float
    proposed_by: str = "place"
    kept: bool = False


def verify_closure(
    reference_points,
    query_points,
    guess,
    distance: float = ICP_DISTANCE,
    coarse: tuple = COARSE_DISTANCES,
):
    """Point-to-plane ICP of ``reference_points`` (M, 3) onto ``query_points`` (N, 3) from ``guess`` (4x4,
    query <- reference), first at each correspondence distance of ``coarse`` (m, larger first) on both clouds
    thinned to a point per half that distance, then at ``distance`` on the full clouds. Returns ``(T, fitness,
    rmse)``: the refined ``T_query_reference``, the share of the reference points within ``distance`` of a query
    point after it, and their RMS distance (m)."""
    import open3d as o3d

    reg = o3d.pipelines.registration

    def cloud(p):
        pc = o3d.geometry.PointCloud()
        pc.points = o3d.utility.Vector3dVector(np.asarray(p, dtype=np.float64))
        return pc

    def icp(source, target, d, T):
        target.estimate_normals(
            o3d.geometry.KDTreeSearchParamHybrid(radius=3 * d, max_nn=20)
        )
        return reg.registration_icp(
            source,
            target,
            d,
            T,
            reg.TransformationEstimationPointToPlane(),
            reg.ICPConvergenceCriteria(max_iteration=50),
        )

    source, target = cloud(reference_points), cloud(query_points)
    T = np.asarray(guess, dtype=np.float64)
    for d in coarse:
        thin = 0.5 * float(d)
        T = icp(
            source.voxel_down_sample(thin), target.voxel_down_sample(thin), d, T
        ).transformation
    result = icp(source, target, distance, T)
    return (
        np.asarray(result.transformation),
        float(result.fitness),
        float(result.inlier_rmse),
    )


def nearby_maps(
    paths,
    distances,
    min_node_gap: int = MIN_NODE_GAP,
    radius: float = SEARCH_RADIUS,
    drift: float = SEARCH_DRIFT,
) -> list:
    """Loop candidates by position for the last local map, nearest first.

    ``paths``: one ``(K_i, 3)`` array per local map, the positions (m, world) of its frames as the optimised pose
    graph places them, the last one the query's; ``distances`` ``(N,)``: metres driven at each map's key pose.
    Map ``j`` at least ``min_node_gap`` maps back is a candidate when the closest pair of positions of the two
    paths is within ``radius + drift * (distances[-1] - distances[j])`` metres. Returns ``[(j, gap), ...]``, the
    gap (m) that closest distance, sorted by it.
    """
    query = np.asarray(paths[-1], dtype=np.float64).reshape(-1, 3)
    out = []
    for j in range(len(paths) - min_node_gap):
        other = np.asarray(paths[j], dtype=np.float64).reshape(-1, 3)
        gap = float(np.sqrt(((query[:, None] - other[None]) ** 2).sum(-1).min()))
        if gap <= radius + drift * (distances[-1] - distances[j]):
            out.append((j, gap))
    return sorted(out, key=lambda c: c[1])


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
        search_radius: float = SEARCH_RADIUS,
        search_drift: float = SEARCH_DRIFT,
        max_proposals: int = MAX_PROPOSALS,
    ):
        self.mapper = LocalMapper(splitting_distance, voxel)
        self.search_radius, self.search_drift = float(search_radius), float(search_drift)
        self.max_proposals = int(max_proposals)
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
        for reference, guess, inliers, by in self._candidates(m):
            T, fitness, rmse = verify_closure(
                self.mapper.maps[reference].points, m.points, guess
            )
            if fitness < self.min_fitness:
                continue
            self._verified.append(
                Closure(
                    m.node,
                    reference,
                    m.frames[0],
                    self.mapper.maps[reference].frames[0],
                    T,
                    inliers,
                    fitness,
                    rmse,
                    by,
                )
            )
            self.graph.add_closure(m.node, reference, T)
            self.graph.optimise()
            return self.closures[-1]
        return None

    def _candidates(self, m: LocalMap) -> list:
        """``[(reference, guess T_query_reference, inliers, proposed_by), ...]`` for local map ``m``: place
        recognition's candidate first, then up to ``max_proposals`` by position."""
        out = []
        found = self._detect(m)
        reference = int(found.source_id)
        if (
            found.number_of_inliers >= self.min_inliers
            and m.node - reference >= self.min_node_gap
        ):
            out.append((reference, found.pose, int(found.number_of_inliers), "place"))
        if self.max_proposals:
            maps, poses = self.mapper.maps, self.graph.poses
            paths = [
                (poses[o.node] @ invert_pose(o.key_pose) @ o.poses[::PATH_STRIDE])[
                    :, :3, 3
                ]
                for o in maps[: m.node + 1]
            ]
            near = nearby_maps(
                paths,
                [o.distance for o in maps[: m.node + 1]],
                self.min_node_gap,
                self.search_radius,
                self.search_drift,
            )
            query_inverse = invert_pose(poses[m.node])
            out += [
                (j, query_inverse @ poses[j], 0, "position")
                for j, _ in near
                if all(j != c[0] for c in out)
            ][: self.max_proposals]
        return out

    def corrected_poses(self) -> np.ndarray:
        """``(K, 4, 4)`` every frame so far re-anchored on the optimised key poses.

        Local map ``i``'s key pose moved by the correction ``C_i = T_key_i' T_key_i^{-1}`` (world frame, left
        multiplied). A frame a share ``f`` of the way (in metres driven) from key pose ``i`` to key pose ``i + 1``
        gets the correction blended between the two, ``C = (slerp(R_i, R_{i+1}, f), (1 - f) t_i + f t_{i+1})``, so
        the path stays continuous where one local map hands over to the next; the last local map's frames get
        its own ``C_i``. At ``f = 0`` this is ``T_k' = T_key' T_key^{-1} T_k``, the re-anchoring on the key pose.
        """
        from scipy.spatial.transform import Rotation

        maps = self.mapper.maps
        corrections = [
            self.graph.poses.get(m.node, m.key_pose) @ invert_pose(m.key_pose)
            for m in maps
        ]
        out = []
        for i, m in enumerate(maps):
            poses = np.asarray(m.poses).reshape(-1, 4, 4)
            if i + 1 == len(maps):
                out.append(corrections[i] @ poses)
                continue
            steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
            span = max(maps[i + 1].distance - m.distance, np.finfo(float).eps)
            f = np.clip(np.r_[0.0, np.cumsum(steps)] / span, 0.0, 1.0)
            a, b = corrections[i], corrections[i + 1]
            turn = Rotation.from_matrix(a[:3, :3].T @ b[:3, :3]).as_rotvec()
            C = np.tile(np.eye(4), (len(f), 1, 1))
            C[:, :3, :3] = a[:3, :3] @ Rotation.from_rotvec(f[:, None] * turn).as_matrix()
            C[:, :3, 3] = (1 - f)[:, None] * a[:3, 3] + f[:, None] * b[:3, 3]
            out.append(C @ poses)
        return np.concatenate(out) if out else np.zeros((0, 4, 4))


def close_loops(poses, scans, **options) -> tuple[np.ndarray, LoopCloser]:
    """A whole run: ``poses (K, 4, 4)`` (world) and ``scans`` (K body-frame ``(N, 3)`` point arrays) through a
    :class:`LoopCloser` (``options`` go to it). Returns ``(corrected poses (K, 4, 4), the closer)``."""
    closer = LoopCloser(**options)
    for k, (pose, points) in enumerate(zip(poses, scans)):
        closer.add_frame(k, pose, points)
    closer.finish()
    return closer.corrected_poses(), closer
