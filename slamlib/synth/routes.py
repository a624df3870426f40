"""Routes: smooth vehicle trajectories ``T_w_imu(t)`` for synthetic drives.

A :class:`Route` interpolates key poses with a cubic spline on positions (``scipy.interpolate.CubicSpline``)
and a cubic rotation spline (``scipy.spatial.transform.RotationSpline``, C2 in the rotation vector), so the
pose is a smooth (C2) function of time and velocities, accelerations and angular rates are its exact
derivatives:

* ``p(t)``, ``R(t)``: IMU position and orientation in the world frame (world = IMU pose at ``t0``, z up).
* body velocity ``v_b = R^T dp/dt`` (m/s), body angular rate ``w_b`` with ``dR/dt = R [w_b]x`` (rad/s),
* world acceleration ``a = d2p/dt2`` and body specific force ``f_b = R^T (a + g e_z)`` (what an
  accelerometer measures, ``g = 9.81 m/s^2``).

Built-in routes: ``"straight"`` (constant speed along x) and ``"loop"`` (a closed circle), and the real
KITTI odometry ground-truth trajectories ``"00"``, ``"05"``, ``"07"`` shipped in
``kitti_sample_dir()/'odometry'``. Those are poses of the rectified left camera ``P_k = T_cam0(0)_cam0(k)``;
they are converted to the IMU frame with the real 2011_09_26 calibration::

    T_cam_imu = R_rect_00 @ T_cam0_velo @ T_velo_imu        (calib_cam_to_cam, calib_velo_to_cam, calib_imu_to_velo)
    T_w_imu(k) = inv(T_cam_imu) @ P_k @ T_cam_imu           (identity at k = 0)

(The odometry sequences were recorded on 2011_09_30 / 2011_10_03 whose calibrations differ by a few
millimetres / tenths of a degree; the 2011_09_26 calibration is used so that the synthetic drive and its
calib files agree.) A frame range re-expresses the poses so the first selected IMU pose is the identity.

Reference: Geiger et al., "Are we ready for autonomous driving? The KITTI vision benchmark suite", CVPR 2012
(odometry poses, camera frame x right, y down, z forward).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slamlib.geometry import invert_pose, make_pose
from slamlib.odometry import GRAVITY
from slamlib.paths import kitti_sample_dir

__all__ = [
    "Route",
    "GRAVITY",
    "straight_route",
    "loop_route",
    "kitti_route",
    "get_route",
    "ROUTE_NAMES",
    "kitti_T_cam_imu",
]

ROUTE_NAMES = ("straight", "loop", "00", "05", "07")
#: The name of a road drawn from a seed, ``"random:SEED"`` (:func:`slamlib.synth.roads.random_route`).
RANDOM_PREFIX = "random:"


@dataclass
class Route:
    """A smooth trajectory through key poses ``poses (K, 4, 4)`` (``T_w_imu``) at ``times (K,)`` seconds.

    ``name`` is a label; ``t0, t1`` the time span. Evaluate with :meth:`pose`, :meth:`velocity_body`, ...
    (``t`` scalar or ``(N,)``; results ``(N, ...)``).
    """

    times: np.ndarray
    poses: np.ndarray
    name: str = "route"

    def __post_init__(self):
        self.times = np.asarray(self.times, dtype=np.float64)
        self.poses = np.asarray(self.poses, dtype=np.float64)
        if (
            self.times.ndim != 1
            or len(self.times) < 4
            or np.any(np.diff(self.times) <= 0)
        ):
            raise ValueError("a route needs >= 4 strictly increasing key times")
        if self.poses.shape != (len(self.times), 4, 4):
            raise ValueError(
                f"poses must be ({len(self.times)}, 4, 4), got {self.poses.shape}"
            )

    # The splines are built on first use, and scipy imported then: a route whose span is all that is asked (the
    # cache key of a generated drive, on every `slamlib run`) needs neither, and scipy.interpolate costs 0.15 s of
    # start-up.
    @functools.cached_property
    def _pos(self):
        from scipy.interpolate import CubicSpline

        return CubicSpline(self.times, self.poses[:, :3, 3], axis=0)

    @functools.cached_property
    def _rot(self):
        from scipy.spatial.transform import Rotation, RotationSpline

        return RotationSpline(self.times, Rotation.from_matrix(self.poses[:, :3, :3]))

    @property
    def t0(self) -> float:
        return float(self.times[0])

    @property
    def t1(self) -> float:
        return float(self.times[-1])

    def position(self, t) -> np.ndarray:
        """World position of the IMU ``(N, 3)`` m."""
        return self._pos(np.atleast_1d(t))

    def rotation(self, t) -> np.ndarray:
        """``R_w_imu (N, 3, 3)``."""
        return self._rot(np.atleast_1d(t)).as_matrix()

    def pose(self, t) -> np.ndarray:
        """``T_w_imu (N, 4, 4)``."""
        return make_pose(self.rotation(t), self.position(t))

    def pose_extended(self, t) -> np.ndarray:
        """``T_w_imu (N, 4, 4)`` at any time: :meth:`pose` within ``[t0, t1]``; beyond an end, the end's pose moved on
        at the end's constant body twist ``(v, w)``, ``T(t) = T(t_e) Exp((t - t_e) [w, v])`` (the SE(3) exponential
        of :func:`slamlib.odometry.imu_increments`). A sweep reaches past the route: the first scan's starts about
        70 ms before the first OXTS stamp, the last scan's ends about 35 ms after the last; the car keeps moving then
        (a cubic spline's own extrapolation would bend, and holding the end pose would leave half a sweep unswept).
        """
        from slamlib.odometry import imu_increments, increment_matrix

        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        out = self.pose(np.clip(t, self.t0, self.t1))
        for end, beyond in ((self.t0, t < self.t0), (self.t1, t > self.t1)):
            if np.any(beyond):
                v, w = self.velocity_body(end)[0], self.angular_rate_body(end)[0]
                out[beyond] = self.pose(end)[0] @ increment_matrix(
                    *imu_increments(v, w, v, w, t[beyond] - end)
                )
        return out

    def velocity_world(self, t) -> np.ndarray:
        """``dp/dt (N, 3)`` m/s in the world frame."""
        return self._pos(np.atleast_1d(t), 1)

    def velocity_body(self, t) -> np.ndarray:
        """``R^T dp/dt (N, 3)`` m/s: (forward, left, up) velocity."""
        return np.einsum("nji,nj->ni", self.rotation(t), self.velocity_world(t))

    def angular_rate_body(self, t) -> np.ndarray:
        """Body angular rate ``w_b (N, 3)`` rad/s, ``dR/dt = R [w_b]x`` (scipy RotationSpline order 1)."""
        return np.atleast_2d(self._rot(np.atleast_1d(t), 1))

    def accel_world(self, t) -> np.ndarray:
        """``d2p/dt2 (N, 3)`` m/s^2."""
        return self._pos(np.atleast_1d(t), 2)

    def specific_force_body(self, t) -> np.ndarray:
        """Accelerometer reading ``R^T (a + g e_z) (N, 3)`` m/s^2 (gravity included, as in OXTS ax..au)."""
        a = self.accel_world(t) + np.array([0.0, 0.0, GRAVITY])
        return np.einsum("nji,nj->ni", self.rotation(t), a)

    def length(self, n: int = 20000) -> float:
        """Path length (m), by dense sampling of the position spline."""
        p = self.position(np.linspace(self.t0, self.t1, n))
        return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())


def straight_route(
    duration: float = 60.0, speed: float = 10.0, name: str = "straight"
) -> Route:
    """Constant ``speed`` (m/s) along +x for ``duration`` s, level."""
    t = np.linspace(0.0, duration, max(int(duration) + 1, 4))
    poses = np.tile(np.eye(4), (len(t), 1, 1))
    poses[:, 0, 3] = speed * t
    return Route(t, poses, name)


def loop_route(
    radius: float = 60.0, speed: float = 8.0, laps: float = 1.0, name: str = "loop"
) -> Route:
    """A counter-clockwise circle of ``radius`` m at ``speed`` m/s, starting at the origin heading +x."""
    duration = laps * 2 * np.pi * radius / speed
    t = np.linspace(0.0, duration, max(int(duration * 2) + 1, 8))
    yaw = speed / radius * t
    poses = np.tile(np.eye(4), (len(t), 1, 1))
    from scipy.spatial.transform import Rotation

    poses[:, :3, :3] = Rotation.from_euler("z", yaw[:, None]).as_matrix()
    poses[:, 0, 3] = radius * np.sin(yaw)
    poses[:, 1, 3] = radius * (1 - np.cos(yaw))
    return Route(t, poses, name)


def _read_calib(path: Path) -> dict[str, np.ndarray]:
    from slamlib.kitti.calib import read_calib_file

    return read_calib_file(path)


def kitti_T_cam_imu(date_dir: Path | None = None) -> np.ndarray:
    """``T_cam_imu = R_rect_00 @ T_cam0_velo @ T_velo_imu`` (4x4) from a KITTI raw date folder's calib files."""
    from slamlib.kitti.calib import read_rigid

    date_dir = (
        Path(date_dir)
        if date_dir is not None
        else kitti_sample_dir() / "raw" / "2011_09_26"
    )
    T_velo_imu = read_rigid(date_dir / "calib_imu_to_velo.txt")
    T_cam_velo = read_rigid(date_dir / "calib_velo_to_cam.txt")
    cc = _read_calib(date_dir / "calib_cam_to_cam.txt")
    R_rect = np.eye(4)
    R_rect[:3, :3] = np.asarray(cc["R_rect_00"], dtype=np.float64).reshape(3, 3)
    return R_rect @ T_cam_velo @ T_velo_imu


def kitti_route(sequence: str = "07", frames: slice | tuple | None = None) -> Route:
    """The KITTI odometry ground truth of ``sequence`` as an IMU route (see the module docstring).

    ``frames`` selects key frames (``slice`` or ``(start, stop)``, stop exclusive); times are shifted so
    the route starts at ``t = 0`` and poses so the first selected IMU pose is the identity.
    """
    from slamlib.kitti.trajectory_io import read_kitti_poses

    root = kitti_sample_dir() / "odometry"
    P = read_kitti_poses(root / "poses" / f"{sequence}.txt")
    times = np.loadtxt(root / "times" / f"{sequence}.txt", dtype=np.float64).reshape(-1)
    n = min(len(P), len(times))
    P, times = P[:n], times[:n]
    if frames is not None:
        sl = frames if isinstance(frames, slice) else slice(*frames)
        P, times = P[sl], times[sl]
        if len(P) < 4:
            raise ValueError(
                f"KITTI sequence {sequence} has key frames 0..{n - 1}: the selection {frames!r} "
                f"keeps {len(P)} of them, a route needs at least 4"
            )
    T_ci = kitti_T_cam_imu()
    T = invert_pose(T_ci) @ P @ T_ci
    T = invert_pose(T[0]) @ T
    return Route(times - times[0], T, f"kitti{sequence}")


def get_route(name: str, frames=None) -> Route:
    """Route by name: ``"straight"``, ``"loop"``, a KITTI odometry sequence ``"00"``, ``"05"``, ``"07"``, or
    ``"random:SEED"``, a fresh road drawn from ``SEED`` (:func:`slamlib.synth.roads.random_route`)."""
    if name.startswith(RANDOM_PREFIX):
        from slamlib.synth.roads import random_route  # scipy: only for a drawn road

        seed = name[len(RANDOM_PREFIX) :]
        if not seed.isdigit():
            raise ValueError(
                f"route {name!r}: {RANDOM_PREFIX}SEED needs an integer SEED >= 0"
            )
        return random_route(int(seed))
    if name == "straight":
        return straight_route()
    if name == "loop":
        return loop_route()
    if name in ("00", "05", "07"):
        return kitti_route(name, frames)
    raise ValueError(
        f"unknown route {name!r}; choose one of {ROUTE_NAMES} or {RANDOM_PREFIX}SEED"
    )
