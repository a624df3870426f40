"""Local maps cut from a trajectory as the vehicle moves: the nodes of the pose graph.

A **local map** holds the scans of a stretch of ``splitting_distance`` metres of driving, placed by the filter's
poses and expressed in the frame of the stretch's first pose, its **key pose** ``T_world_key``; its points are
down-sampled to one per ``voxel`` metres (the first point of each voxel). Successive key poses are joined by
odometry edges, ``T_key_i^{-1} T_key_{i+1}`` as the filter estimated it; a loop closure is a registration of two
local maps (KISS-SLAM cuts its local maps the same way, Vizzo et al.).

Frames: world = the filter's world frame; body = the frame the scan points are in (the filter's body frame);
``points`` are ``(N, 3)`` in metres.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from slamlib.geometry import invert_pose, transform_points

__all__ = [
    "LOCAL_MAP_VOXEL",
    "SPLITTING_DISTANCE",
    "LocalMap",
    "LocalMapper",
    "voxel_down_sample",
]

#: Metres of driving per local map.
SPLITTING_DISTANCE = 50.0
#: Voxel (m) of a local map's points (one point kept per voxel).
LOCAL_MAP_VOXEL = 0.5


#: Bits per axis of a packed voxel key (:func:`voxel_down_sample`): voxel indexes within +-2^20 of the origin,
#: +-524 km at 0.5 m.
_KEY_BITS = 21


def voxel_down_sample(points, voxel: float) -> np.ndarray:
    """The first point of each occupied ``voxel``-metre cube, in the points' order: ``(M, 3)`` float64.

    Each point's voxel index ``floor(p / voxel)`` is packed into one int64 (21 bits an axis), so that one sort of
    integers finds the first point of every voxel.
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if not len(p):
        return p
    keys = np.floor(p / voxel).astype(np.int64) + (1 << (_KEY_BITS - 1))
    if keys.min() < 0 or keys.max() >= 1 << _KEY_BITS:
        raise ValueError(
            f"points further than {voxel * (1 << (_KEY_BITS - 1)):.0f} m from the origin"
        )
    packed = (keys[:, 0] << (2 * _KEY_BITS)) | (keys[:, 1] << _KEY_BITS) | keys[:, 2]
    _, first = np.unique(packed, return_index=True)
    return p[np.sort(first)]


@dataclass
class LocalMap:
    """Node ``node`` of the pose graph: ``key_pose`` (4x4, world), ``points`` (M, 3) in the key pose's frame,
    ``frames`` the frame indexes it holds, ``poses`` (K, 4, 4) the filter's world poses of those frames and
    ``distance`` the metres driven from the first frame to the key pose."""

    node: int
    key_pose: np.ndarray
    points: np.ndarray
    frames: list = field(default_factory=list)
    poses: list = field(default_factory=list)
    distance: float = 0.0


class LocalMapper:
    """Collects frames into local maps; :meth:`add` returns a finished :class:`LocalMap` when a stretch of
    ``splitting_distance`` metres is complete (the frame that completes it starts the next)."""

    def __init__(
        self,
        splitting_distance: float = SPLITTING_DISTANCE,
        voxel: float = LOCAL_MAP_VOXEL,
    ):
        if not splitting_distance > 0 or not voxel > 0:
            raise ValueError(
                f"need splitting_distance > 0 and voxel > 0, got {splitting_distance}, {voxel}"
            )
        self.splitting_distance, self.voxel = float(splitting_distance), float(voxel)
        self.maps: list[LocalMap] = []
        self._open: LocalMap | None = None
        self._chunks: list[np.ndarray] = []
        self._driven = 0.0
        self._last = None

    def add(self, frame: int, pose, points) -> LocalMap | None:
        """Frame ``frame`` at world pose ``pose`` (4x4) with body-frame ``points`` (N, 3)."""
        pose = np.asarray(pose, dtype=np.float64)
        done = None
        if self._open is not None:
            self._driven += float(np.linalg.norm(pose[:3, 3] - self._last[:3, 3]))
            if self._driven - self._open.distance >= self.splitting_distance:
                done = self.finish()
        if self._open is None:
            self._open = LocalMap(
                len(self.maps), pose.copy(), np.zeros((0, 3)), distance=self._driven
            )
            self._chunks = []
        key_from_body = invert_pose(self._open.key_pose) @ pose
        self._chunks.append(
            voxel_down_sample(transform_points(key_from_body, points), self.voxel)
        )
        self._open.frames.append(int(frame))
        self._open.poses.append(pose.copy())
        self._last = pose
        return done

    def finish(self) -> LocalMap | None:
        """Close the open local map (if any) and return it."""
        if self._open is None:
            return None
        done, self._open = self._open, None
        done.points = voxel_down_sample(np.concatenate(self._chunks), self.voxel)
        done.poses = np.asarray(done.poses)
        self._chunks = []
        self.maps.append(done)
        return done
