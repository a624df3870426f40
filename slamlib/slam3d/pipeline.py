"""``ParticleSLAM3D``: the twelve steps as a per-frame method, around stages chosen once.

The filter object is thin state (particles, log-weights, map, trajectory) around the pure step functions of
:mod:`slamlib.slam3d.steps` and the stages of :mod:`slamlib.slam3d.stages`, each one job, built once:

* **motion** (steps 3, 5, 6): the IMU, or LIDAR-only the filter's own motion held (constant velocity);
* **scan** (step 2): crop, down-sample, de-skew a swept scan;
* **prior** (step 8's second term): roll and pitch held to gravity, or none;
* **search** (steps 6-8 again): annealing rounds, coarse to fine;
* **polish** (step 9): scan matching of the best pose, or none;
* **upkeep** (after step 10): pruning and eviction of the map.

The scan stage, the search and the upkeep depend on the settings only and are built with the filter; the motion
source, the prior and the polish depend on the data too (a drive without an IMU runs LIDAR-only) and are built
from the first frame (:func:`slamlib.slam3d.stages.choose_stages`). :meth:`ParticleSLAM3D.register_frame` is
step 12, the loop body: the numbered steps in order, with no mode decided per frame. Particles are poses
``T_world_body`` of the vehicle body = the IMU frame; the world is the body pose at the first registered frame
(see :mod:`slamlib.slam3d.steps`).

Likelihood tempering
--------------------
The map score of a particle is a sum over ``N`` scan points of per-point log-likelihoods (:mod:`slamlib.maps.base`)
which treats the points as independent. They are not (neighbouring points see the same surface, the map is
itself built from earlier noisy scans), so the raw sum is far too confident: weights would collapse onto one
particle. The filter weighs with ``log L_i = score_i / (N * temperature)`` (``FilterConfig.temperature``): the
scan counts as ``1 / temperature`` independent points whatever sample size ``N`` is chosen (Grisetti et al. 2007
and most LIDAR particle filters smooth the observation likelihood the same way).

Degenerate frames
-----------------
A frame whose scan keeps fewer than :data:`MIN_SCAN_POINTS` points after step 2 (an empty or all-zero scan, every
return outside ``[min_range, max_range]``) carries no usable evidence: scoring it would divide by zero points and
fill the weights with NaN. Such a frame is **skipped for scoring**: steps 5 and 6 stand (the particles move and
spread as usual), steps 7, 8 and 10 are skipped (weights unchanged, nothing merged), step 9's pose is the motion
prediction ``T_prev @ [dR, dp]`` (the previous estimate moved by this frame's increment), and step 11 is not
run. ``n_skipped_frames`` counts these frames (``slamlib run`` writes it into ``metrics.json``). While the map is
still empty (degenerate first frames) the first frame with enough points starts it at its predicted pose.
"""

from __future__ import annotations

import numpy as np

from slamlib.contract import StepInfo
from slamlib.kernels import get_backend
from slamlib.odometry import increment_matrix
from slamlib.resampling import (
    effective_sample_size,
    normalise_log_weights,
    weights_from_log_weights,
)
from slamlib.slam3d import steps
from slamlib.slam3d.config import SLAM3DConfig
from slamlib.slam3d.stages import Annealing, MapUpkeep, ScanPreparation, choose_stages

__all__ = ["ParticleSLAM3D", "MIN_SCAN_POINTS"]

#: Fewest body-frame points (after step 2's crop and down-sampling) a frame needs to be scored and merged; below it
#: the frame is skipped for scoring (module docstring, "Degenerate frames"). 10 points: far fewer than any real
#: LIDAR scan (~100k points, ~20k after down-sampling), yet enough that one frame's score is not a single return.
MIN_SCAN_POINTS = 10


class ParticleSLAM3D:
    """Particle-filter SLAM on 6-DoF poses with a LIDAR map (the twelve steps of :mod:`slamlib.slam3d.steps`).

    Parameters
    ----------
    config : :class:`~slamlib.slam3d.config.SLAM3DConfig`, optional
        Settings (defaults if omitted).
    T_velo_imu : (4, 4), optional
        Calibration ``p_velo = T_velo_imu p_imu`` (KITTI ``calib_imu_to_velo.txt``; default identity: scans
        already in the body frame).
    T0 : (4, 4), optional
        Body pose at the first frame (default identity: the world is the first body pose).

    Attributes
    ----------
    particles : :class:`~slamlib.slam3d.steps.Particles3D`; ``log_weights`` their log-weights ``(P,)``.
    map : :class:`slamlib.maps.Map3D` in the world frame.
    poses : list of (4, 4) SLAM estimates ``T_world_body``, one per registered frame; ``dts`` their ``dt`` (s).
    scan, search, upkeep : the stages built from the settings (:class:`~slamlib.slam3d.stages.ScanPreparation`,
        :class:`~slamlib.slam3d.stages.Annealing`, :class:`~slamlib.slam3d.stages.MapUpkeep`).
    motion, prior, polish : the stages built from the first frame (None before it):
        :class:`~slamlib.slam3d.stages.ImuMotion` or :class:`~slamlib.slam3d.stages.ConstantVelocity`,
        :class:`~slamlib.slam3d.stages.TiltPrior` or :class:`~slamlib.slam3d.stages.NoPrior`,
        :class:`~slamlib.slam3d.stages.ScanMatch` or :class:`~slamlib.slam3d.stages.NoPolish`.
    n_resampled : number of frames in which step 11 resampled; ``n_annealed`` the annealing rounds run.
    n_skipped_frames : number of frames skipped for scoring, with fewer than :data:`MIN_SCAN_POINTS` points
        (module docstring, "Degenerate frames").
    last : dict with this frame's intermediate results (scores, sample, sigma, ...), for plots and tests.
    """

    def __init__(self, config: SLAM3DConfig | None = None, T_velo_imu=None, T0=None):
        self.config = cfg = config if config is not None else SLAM3DConfig()
        self.backend = get_backend(cfg.backend)
        # step 9's: the best particle, or a local mean
        self.pose_estimate = cfg.filter.pose_estimate
        self.rng = np.random.default_rng(cfg.seed)
        self.T_body_velo = (
            None
            if T_velo_imu is None
            else np.linalg.inv(np.asarray(T_velo_imu, dtype=np.float64))
        )
        self.map = cfg.map.make()
        self.T0 = np.eye(4) if T0 is None else np.asarray(T0, dtype=np.float64)
        self.motion = self.prior = self.polish = None  # chosen at the first frame
        # step 1 (the count by the mode the settings ask for; the first frame may change it, see _choose_stages)
        self.particles, self.log_weights = steps.initialise_particles(
            cfg.filter.particle_count(self.lidar_only), self.T0
        )
        self.poses: list[np.ndarray] = []
        self.dts: list[float] = []
        self.n_resampled = 0
        self.n_skipped_frames = 0
        self.last: dict = {}
        f = cfg.search
        self.scan = ScanPreparation(cfg.scan, self.T_body_velo)
        self.search = Annealing(
            f.anneal_rounds,
            f.anneal_shrink,
            self.weigh,
            self.rng,
            self.backend,
            f.collapse_ess,
            f.collapse_rounds,
            cfg.motion.constant_velocity.start_line,
            self.last,
            self.map.resolution,
        )
        self.upkeep = MapUpkeep(cfg.upkeep)

    # ----------------------------------------------------------------------------------------- step 12
    def step(self, frame) -> StepInfo:
        """Step 12 as every dimension's filter offers it (:data:`slamlib.contract.FILTER_STEP`): steps 2-11 on
        one frame (:meth:`register_frame`) and what they did, as a :class:`slamlib.contract.StepInfo`.

        ``moved`` and ``log_weights`` are the particles and normalised log-weights step 11 resampled from (after
        annealing and the polish's correction), ``scores`` the raw step-8 scores of the last weighing (before
        tempering and the prior; zeros on a frame not scored), ``estimate`` the frame's pose ``T_world_body``
        (4, 4), which the polish may have moved off ``moved[best]``.
        """
        pose = self.register_frame(frame)
        log_w = self.last["log_weights"]
        weights = weights_from_log_weights(log_w)
        return StepInfo(
            moved=self.last["moved"],
            scores=self.last["scores"],
            log_weights=log_w,
            weights=weights,
            best=int(np.argmax(log_w)),
            estimate=pose,
            ess=effective_sample_size(weights),
            resampled=bool(self.last["resampled"]),
        )

    def register_frame(self, frame) -> np.ndarray:
        """Run steps 2-11 on one frame (``.scan``, ``.velocity``, ``.angular_rate``, ``.dt``); return the pose.

        The first frame chooses the data-dependent stages and only builds the map at the start pose. A frame with
        fewer than :data:`MIN_SCAN_POINTS` points is skipped for scoring: steps 5 and 6 stand, the pose is the
        motion prediction, and ``n_skipped_frames`` grows (module docstring, "Degenerate frames"). Returns
        ``T_world_body`` (4, 4). Raises ``ValueError`` for non-finite or physically impossible IMU values
        (:func:`~slamlib.slam3d.steps.read_imu`).
        """
        be, rng, poses = self.backend, self.rng, self.poses
        if not poses:  # the first frame: the stages that depend on the data
            self._choose_stages(frame)
        imu = self.motion.read(frame, poses, self.dts)  # 3
        dt = steps.read_timing(frame)  # 4
        points = self.scan.read(frame, imu)  # 2, a swept scan de-skewed with 3's motion
        if not poses:
            return self._start(points, imu, dt)
        dT, sigma, start_rounds = self.motion.predict(imu, dt, poses)  # for 5 and 6
        # 5: every particle moved by the increment dT; 6: each by its own Gaussian draw
        moved = steps.offset_by_motion(self.particles, imu, dt, increment=dT, backend=be)
        moved = steps.perturb_with_noise(moved, sigma, rng, backend=be)
        self.prior.measure(frame, imu, dt, dT, poses)  # what step 8's prior holds to
        if len(points) < MIN_SCAN_POINTS or len(self.map) == 0:  # degenerate frame
            return self._skip(moved, imu, dT, points, dt, sigma)
        sample = self.motion.scoring_sample(points, rng)
        log_w = self.weigh(moved, self.log_weights, sample)  # 7 + 8
        # 6-8 again, finer (annealing); 9: the best particle, sharpened (scan matching)
        moved, log_w = self.search(moved, log_w, sample, sigma, start_rounds, poses[-1])
        pose, best = steps.pick_best_particle(moved, log_w, self.pose_estimate)
        pose, moved = self.polish(pose, points, moved, self.map, sigma)
        self._learn(pose, dt)  # what 9 found tunes 5, 6 and 8's prior
        steps.merge_scan(self.map, pose, points, be)  # 10
        self._record(pose, imu, points, dt, sample=sample, sigma=sigma, best=best)
        self.upkeep(self.map, poses)
        self._resample(moved, log_w)  # 11
        return pose

    def predicted_pose(self, frame) -> np.ndarray:
        """Steps 3-5 without noise, the filter left as it was: the last pose moved by the motion stage's increment
        over ``frame.dt`` (where a new segment starts after a gap in time, :mod:`slamlib.slam3d.segments`).
        ``T_world_body`` (4, 4); the start pose before any frame."""
        if not self.poses:
            return self.T0.copy()
        imu = self.motion.read(frame, self.poses, self.dts)
        increment, _, _ = self.motion.predict(imu, steps.read_timing(frame), self.poses)
        return self.poses[-1] @ increment_matrix(*increment)

    # ----------------------------------------------------------------------------------------- helpers
    def _choose_stages(self, frame) -> None:
        """The motion source, prior and polish for the data whose first frame is ``frame``
        (:func:`slamlib.slam3d.stages.choose_stages`), and step 1's particle count for that mode
        (:meth:`~slamlib.slam3d.config.FilterConfig.particle_count`): the particles all still stand at the start
        pose with equal weights, so starting them again with another count loses nothing."""
        self.motion, self.prior, self.polish = choose_stages(self.config, frame, self.T0)
        P = self.config.filter.particle_count(self.motion.lidar_only)
        if P != len(self.particles):
            self.particles, self.log_weights = steps.initialise_particles(P, self.T0)

    def _learn(self, pose, dt: float) -> None:
        """After step 9, the stages learn from the frame's pose: the prior calibrates the accelerometer's bias (and
        in ``"auto"`` its own weight), the motion stage the source's errors from the innovation against the last
        pose (:mod:`slamlib.slam3d.stages.tuning`)."""
        self.prior.calibrate(pose, dt)
        self.motion.learn(self.poses[-1], pose, dt)

    def _resample(self, particles, log_weights) -> None:
        """Step 11 when the effective sample size is below ``FilterConfig.ess_fraction`` of the particles;
        ``n_resampled`` counts the frames it resampled."""
        ess = self.config.filter.ess_fraction
        self.last.update(moved=particles, log_weights=log_weights)
        self.particles, self.log_weights, resampled = steps.resample_particles(
            particles, log_weights, self.rng, ess, self.backend
        )
        self.last["resampled"] = resampled
        self.n_resampled += int(resampled)

    def score(self, particles, sample) -> np.ndarray:
        """Steps 7 + 8's scores ``(P,)`` of ``particles`` against the map, kept as the frame's last scores."""
        scores = steps.score_particles(particles, sample, self.map, self.backend)
        self.last["scores"] = scores
        return scores

    def weigh(self, particles, log_weights, sample) -> np.ndarray:
        """Steps 7 + 8 and the weight update: ``log_w + score / (N * temperature)`` (tempering, module docstring),
        plus the prior stage's term, normalised."""
        scores = self.score(particles, sample)
        log_w = log_weights + scores / (len(sample) * self.config.filter.temperature)
        return normalise_log_weights(self.prior.weigh(particles, log_w))

    def _start(self, points, imu, dt) -> np.ndarray:
        """The first frame: step 10 at the start pose, which is also the first pose of both trajectories."""
        self._unscored(self.T0, imu, points, dt)
        return self.poses[-1]

    def _skip(self, moved, imu, increment, points, dt, sigma) -> np.ndarray:
        """A frame not scored: keep the moved particles and their weights; the pose is the motion prediction."""
        self.particles = moved
        pose = self.poses[-1] @ increment_matrix(*increment)
        self._unscored(pose, imu, points, dt, sample=points[:0], sigma=sigma, best=None)
        return pose

    def _unscored(self, pose, imu, points, dt, **last) -> None:
        """A frame not scored (the first, a degenerate one) at ``pose``: its scan starts the map there when it has
        enough points (the map is still empty), else it counts as skipped; then the bookkeeping and upkeep. What
        :meth:`step` reports of it: the particles as they are, their weights unchanged, zero scores, no
        resampling."""
        if len(points) >= MIN_SCAN_POINTS:
            steps.merge_scan(self.map, pose, points, self.backend)
        else:
            self.n_skipped_frames += 1
        self._record(pose, imu, points, dt, **last)
        P = len(self.particles)
        self.last.update(moved=self.particles, log_weights=self.log_weights)
        self.last.update(scores=np.zeros(P), resampled=False)
        self.upkeep(self.map, self.poses)

    def _record(self, pose, imu, points, dt, **last) -> None:
        """Bookkeeping after step 10: the SLAM pose and its ``dt``, the motion stage's record of the frame (the
        dead-reckoning twin moved by the source's own increment), this frame's intermediate results."""
        self.poses.append(np.asarray(pose, dtype=np.float64))
        self.dts.append(float(dt))
        self.motion.record(imu)
        self.last.update(points=points, **last)

    def map_points(self) -> np.ndarray:
        """All map points (M, 3) float32, world frame: the live map's plus the pruned ones kept in ``archive``."""
        archive = self.archive
        return (
            np.concatenate(archive + [self.map.points()])
            if archive
            else self.map.points()
        )

    # ----------------------------------------------------------------------------------------- results
    @property
    def lidar_only(self) -> bool:
        """Whether step 3 holds the filter's own motion (constant velocity) instead of reading an IMU: the motion
        stage chosen at the first frame; before it, whether the settings ask for it."""
        if self.motion is None:
            return self.config.motion.model == "constant_velocity"
        return self.motion.lidar_only

    @property
    def imu_prev(self):
        """``(velocity (3,), angular_rate (3,))`` of the last registered frame (None before the first)."""
        return None if self.motion is None else self.motion.previous

    @property
    def archive(self) -> list[np.ndarray]:
        """``(K, 3)`` float32 world points pruned from the map (``UpkeepConfig.keep_pruned``); see
        :meth:`map_points`."""
        return self.upkeep.archive

    @property
    def n_deskewed(self) -> int:
        """Frames whose scan step 2 de-skewed (:func:`~slamlib.slam3d.steps.should_deskew`)."""
        return self.scan.n_deskewed

    @property
    def n_matched(self) -> int:
        """Frames whose pose was scan-matched after step 9 (the polish stage)."""
        return 0 if self.polish is None else self.polish.n_matched

    @property
    def n_match_rejected(self) -> int:
        """Frames whose scan match the gate rejected (``ScanMatchConfig.match_gate``): step 9's pose stood."""
        return 0 if self.polish is None else self.polish.n_rejected

    @property
    def match_max_kept_distance(self) -> float:
        """The largest correction a kept scan match made, in step 6's spreads
        (:func:`~slamlib.slam3d.stages.polish.correction_distance`; 0 before one): how near the gate came to
        closing."""
        return 0.0 if self.polish is None else float(self.polish.max_kept_distance)

    @property
    def n_start_lines_kept(self) -> int:
        """Start frames where the start line's search was kept over the drawn one's
        (``ConstantVelocityConfig.start_line``; :class:`~slamlib.slam3d.stages.Annealing`)."""
        return self.search.n_line_wins

    @property
    def n_annealed(self) -> int:
        """Annealing rounds run (the search stage), over all frames."""
        return self.search.n_rounds

    @property
    def trajectory(self) -> np.ndarray:
        """SLAM poses ``T_world_body`` (F, 4, 4) of the registered frames."""
        return np.array(self.poses).reshape(-1, 4, 4)

    @property
    def dr_poses(self) -> list[np.ndarray] | None:
        """The dead-reckoning poses (4, 4) so far, one per registered frame (the IMU motion stage's twin); None
        LIDAR-only."""
        if self.lidar_only:
            return None
        return [] if self.motion is None else self.motion.dr_poses

    @property
    def dead_reckoning(self) -> np.ndarray | None:
        """Dead-reckoning poses (F, 4, 4) from the same IMU samples; None LIDAR-only (no IMU to reckon with)."""
        dr = self.dr_poses
        return None if dr is None else np.array(dr).reshape(-1, 4, 4)
