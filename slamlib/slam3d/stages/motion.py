"""The motion stage: where step 3's motion comes from, and what steps 5 and 6 and the scoring sample make of it.

Two sources, chosen once for a drive (:func:`slamlib.slam3d.stages.choose_stages`):

:class:`ImuMotion`
    Step 3 reads the IMU's body velocities and rates (:func:`slamlib.slam3d.steps.read_imu`); step 5's increment
    is the midpoint twist of the previous and this sample integrated on SE(3)
    (:func:`~slamlib.slam3d.steps.motion_increment`); step 6's spread grows with the distance travelled and the
    time (:meth:`slamlib.slam3d.config.MotionConfig.sigma`). The same increments, without noise and without the
    scans, move a dead-reckoning twin: the baseline the SLAM estimate is compared with.

:class:`ConstantVelocity` (LIDAR-only)
    Data without an IMU (the KITTI odometry layout, :class:`slamlib.kitti.KittiOdometrySequence`), or
    ``MotionConfig.model = "constant_velocity"``. Step 3 holds the filter's own last estimated motion
    (:func:`held_twist`: the twist between its recent poses) over the next ``dt``: the constant-velocity model of
    LIDAR odometry (KISS-ICP). Step 6 widens its spread by the accelerations that model cannot know. At the second
    frame no motion is known yet (the vehicle may already drive at 15 m/s): step 6 spreads the particles by the
    speeds a car may have (``start_speed``) and the search stage runs ``start_rounds`` extra annealing
    rounds, each halving the spread (:class:`slamlib.slam3d.stages.Annealing`). Step 8 scores mostly what stands
    above the road (:func:`slamlib.slam3d.preprocess.thin_ground`, ``ground_share``): the
    road's rings in the map would pull the estimate toward zero motion, a pull the IMU outweighs but the
    constant-velocity model does not. There is no dead-reckoning twin.

Both offer the same methods: ``read(frame, poses, dts)`` (step 3), ``predict(imu, dt, poses)`` (what steps 5 and 6
need: the increment, the spread and the start search's extra rounds), ``scoring_sample(points, rng)`` (step 8's
points) and ``record(imu)`` (after the frame).
"""

from __future__ import annotations

import numpy as np

from slamlib.geometry import matrix_to_rpy
from slamlib.odometry import increment_matrix, twist_between
from slamlib.slam3d import steps
from slamlib.slam3d.config import MotionConfig
from slamlib.slam3d.preprocess import sample_points, sample_thinned
from slamlib.slam3d.stages.tuning import FixedSpread, SelfTuning

__all__ = ["ConstantVelocity", "ImuMotion", "has_imu", "held_twist"]


def has_imu(frame) -> bool:
    """Whether ``frame`` carries IMU values (``frame.velocity``); the KITTI odometry layout's frames do not."""
    return getattr(frame, "velocity", None) is not None


def make_tuning(config: MotionConfig, correct_bias: bool):
    """The motion stage's learner of its source's errors: :class:`~slamlib.slam3d.stages.tuning.SelfTuning` with
    the settings of ``config`` when ``config.self_tuning``, else :class:`~slamlib.slam3d.stages.tuning.FixedSpread`."""
    if not config.self_tuning:
        return FixedSpread()
    return SelfTuning(
        config.tuning_memory,
        config.tuning_noise_memory,
        config.tuning_gain,
        config.tuning_floor,
        config.tuning_warmup,
        correct_bias=correct_bias,
    )


def measured_increment(previous_pose, pose):
    """The body-frame increment ``(rpy (3,), dp (3,))`` that took ``previous_pose`` to ``pose`` (both
    ``T_world_body`` (4, 4)): what the filter measured the vehicle to move in the frame."""
    D = np.linalg.inv(previous_pose) @ pose
    return matrix_to_rpy(D[:3, :3]), D[:3, 3].copy()


def held_twist(
    poses, dts, window: int = 1, damping=(1.0,) * 6
) -> tuple[np.ndarray, np.ndarray]:
    """LIDAR-only step 3: the twist ``(v, w)`` that took the pose ``k = min(window, F - 1)`` frames back to the last
    of ``poses`` (``F`` of them, ``T_world_body`` (4, 4)) in their time ``sum(dts[-k:])`` seconds
    (:func:`slamlib.odometry.twist_between`), its six components (forward, left, up, then the rates about them)
    multiplied by ``damping``; zero before two poses (the vehicle is taken to start at rest, as KISS-ICP does).
    ``window`` and ``damping`` are :class:`~slamlib.slam3d.config.ConstantVelocityConfig`'s.
    """
    if len(poses) < 2:
        return np.zeros(3), np.zeros(3)
    k = min(window, len(poses) - 1)
    v, w = twist_between(poses[-1 - k], poses[-1], sum(dts[-k:]))
    damping = np.asarray(damping)
    return v * damping[:3], w * damping[3:]


class ImuMotion:
    """Step 3 from the IMU; steps 5 and 6 from its midpoint twist; a dead-reckoning twin from the same increments.

    Attributes: ``previous`` the ``(velocity, angular_rate)`` of the last registered frame (None before the
    first); ``dr_poses`` the dead-reckoning poses ``T_world_body`` (4, 4), one per registered frame.
    """

    lidar_only = False

    def __init__(self, config: MotionConfig, scored_points: int, T0):
        self.config, self.scored_points, self.T0 = config, scored_points, T0
        self.previous = None
        self.dr_poses: list[np.ndarray] = []
        self.tuning = make_tuning(config, correct_bias=True)
        self.predicted = None

    def read(self, frame, poses, dts):
        """Step 3: the frame's IMU sample (:func:`slamlib.slam3d.steps.read_imu`)."""
        return steps.read_imu(frame)

    def predict(self, imu, dt: float, poses):
        """``(increment, sigma, start_rounds)``: the body-frame increment over ``dt`` from the previous and this
        sample, corrected by the learnt scale errors and biases, step 6's spread ``(6,)`` for it (the learnt
        scatter; :mod:`slamlib.slam3d.stages.tuning`), and no start search (0 rounds)."""
        self.predicted = steps.motion_increment(imu, dt, self.previous)
        increment = self.tuning.correct(self.predicted, dt)
        return increment, self.tuning.spread(self.config.sigma(increment[1], dt)), 0

    def learn(self, previous_pose, pose, dt: float) -> None:
        """After step 9: the frame's innovation, ``pose`` against the IMU's own increment from ``previous_pose``,
        into the self-tuning (:mod:`slamlib.slam3d.stages.tuning`)."""
        self.tuning.learn(self.predicted, measured_increment(previous_pose, pose), dt)

    def scoring_sample(self, points, rng):
        """Step 8's points: ``scored_points`` of the scan drawn at random."""
        return sample_points(points, self.scored_points, rng)

    def record(self, imu) -> None:
        """After a frame: the twin moved by the IMU's own increment of this frame (the start pose on the first
        frame), and this sample kept for the next frame's midpoint twist."""
        # the twin moves by the IMU's own increment, not the one self-tuning corrected: dead reckoning is the baseline
        T = (
            self.dr_poses[-1] @ increment_matrix(*self.predicted)
            if self.dr_poses
            else self.T0
        )
        self.dr_poses.append(np.asarray(T, dtype=np.float64))
        self.previous = imu


class ConstantVelocity:
    """LIDAR-only: step 3 holds the filter's own last motion (module docstring); no dead-reckoning twin."""

    lidar_only = True
    dr_poses = None

    def __init__(self, config: MotionConfig, scored_points: int):
        self.config, self.scored_points = config, scored_points
        self.held = config.constant_velocity  # ConstantVelocityConfig
        self.previous = None
        # the held twist has no bias to correct: only its scatter (the accelerations) is learnt
        self.tuning = make_tuning(config, correct_bias=False)
        self.predicted, self.searched = None, False

    def read(self, frame, poses, dts):
        """Step 3: :func:`held_twist` of the poses so far, checked as an IMU sample would be
        (:func:`slamlib.slam3d.steps.check_twist`: a diverged estimate stops with a clear error)."""
        v, w = held_twist(poses, dts, self.held.window, self.held.damping)
        return steps.check_twist(
            v, w, steps.frame_label(frame) + " (constant-velocity estimate)"
        )

    def predict(self, imu, dt: float, poses):
        """``(increment, sigma, start_rounds)``: the held twist over ``dt``; the spread widened by the
        accelerations the model cannot know, and at the second frame (one pose: no motion known yet) by the
        speeds a car may have, with ``start_rounds`` annealing rounds to narrow it."""
        increment = self.predicted = steps.motion_increment(imu, dt)
        start = self.searched = len(poses) == 1
        sigma = self.config.sigma(increment[1], dt, constant_velocity=True, start=start)
        if start:
            return increment, sigma, self.held.start_rounds
        return increment, self.tuning.spread(sigma), 0

    def learn(self, previous_pose, pose, dt: float) -> None:
        """After step 9: the frame's innovation against the held twist (the accelerations it did not know) into
        the self-tuning, from the third frame on (the second's motion was not held but searched for)."""
        if not self.searched:
            self.tuning.learn(self.predicted, measured_increment(previous_pose, pose), dt)

    def scoring_sample(self, points, rng):
        """Step 8's points: ``scored_points`` drawn with the road thinned to ``ground_share`` of them
        (:func:`~slamlib.slam3d.preprocess.sample_thinned`)."""
        return sample_thinned(points, self.held.ground_share, self.scored_points, rng)

    def record(self, imu) -> None:
        """After a frame: keep the held twist (``previous``)."""
        self.previous = imu
