"""``ParticleSLAM3D``: the twelve steps as a per-frame method, with its configuration and a dead-reckoning twin.

The filter object is thin state (particles, log-weights, map, previous IMU sample, trajectories) around the pure
step functions of :mod:`slamlib.slam3d.steps`. :meth:`ParticleSLAM3D.register_frame` is step 12, the loop body:
it reads like the list of steps (one call per numbered step; the weight update, annealing and bookkeeping each in
one named line between them). Particles are poses ``T_world_body`` of the vehicle body = the IMU frame; the
world is the body pose at the first registered frame (see :mod:`slamlib.slam3d.steps`).

Dead reckoning from the same IMU samples (the same :func:`slamlib.odometry.imu_increment` as step 5, without
noise and without the scans) is kept alongside as the baseline: ``slam.dr_poses``.

LIDAR-only (no IMU)
-------------------
Data without an IMU (the KITTI odometry layout, :class:`slamlib.kitti.KittiOdometrySequence`), or
``MotionConfig.model = "constant_velocity"``, runs the same twelve steps with step 3 reading the filter's own last
estimated motion instead of an IMU (:meth:`ParticleSLAM3D.own_motion`): the twist between its last two poses,
held over the next ``dt`` -- the constant-velocity model of LIDAR odometry (KISS-ICP). Step 6 widens its spread by
the accelerations that model cannot know (:class:`slamlib.slam3d.config.MotionConfig`). At the second frame no
motion is known yet (the vehicle may already drive at 15 m/s): step 6 spreads the particles by the speeds a car
may have (``cv_start_speed``) and ``cv_start_rounds`` annealing rounds, each halving the spread, find the motion
(coarse to fine, below). LIDAR-only, step 8 scores mostly what stands above the road
(:func:`slamlib.slam3d.preprocess.thin_ground`, ``FilterConfig.lidar_only_ground_share``): the road's rings in the
map would pull the estimate toward zero motion, a pull the IMU outweighs but the constant-velocity model does not.
There is then no dead-reckoning twin (``dead_reckoning`` is None).

Likelihood tempering
--------------------
The map score of a particle is a sum over ``N`` scan points of per-point log-likelihoods (:mod:`slamlib.maps.base`)
which treats the points as independent. They are not (neighbouring points see the same surface, the map is
itself built from earlier noisy scans), so the raw sum is far too confident: weights would collapse onto one
particle. The pipeline uses ``log L_i = score_i / (N * temperature)`` (``FilterConfig.temperature``): the scan
counts as ``1 / temperature``
independent points whatever sample size ``N`` is chosen (Grisetti et al. 2007 and most LIDAR particle filters
smooth the observation likelihood the same way).

Coarse to fine (``refine``)
---------------------------
With few particles in 6 dimensions the best of the cloud is still a few centimetres / tenths of a degree from the
likelihood's peak. ``refine = k`` adds ``k`` annealing rounds inside the frame (Deutscher, Blake & Reid, "Articulated
body motion capture by annealed particle filtering", CVPR 2000): resample by the current weights, perturb with the
noise shrunk by ``refine_shrink``, score again. The result is still a particle filter (a sequence of
importance-sampling / resampling stages on the same posterior), just with a sharper proposal.

Scan matching
-------------
Annealing sharpens the particle search; scan matching finishes it with a local optimiser. With
``FilterConfig.scan_match`` (by default on LIDAR-only) the pose of step 9 is moved by a few Gauss-Newton steps to
the nearest peak of the same map score, computed on the whole down-sampled scan rather than step 8's sample
(:func:`slamlib.slam3d.match.match_scan`), and every particle is moved by the same correction before step 11
resamples them: the particles are then drawn around the scan-matched pose, the *improved proposal* of Grisetti,
Stachniss & Burgard (IEEE T-RO 2007). LIDAR-only this matters most: the constant-velocity prior is weak, and the
map's pull toward the truth has to do what the IMU does otherwise.

Holding the tilt to gravity
---------------------------
The map fixes a particle's roll and pitch only *relative to the map*, and the map is built from the filter's own
earlier estimates: each frame's small tilt error goes into the map, and over thousands of frames it random-walks
(on a whole KITTI route tens of milliradians, which the motion turns into metres of height). Gravity is the one
absolute reference on board. With ``FilterConfig.tilt_sigma > 0`` step 3 also reads the accelerometer
(:func:`~slamlib.slam3d.steps.read_specific_force`), :func:`slamlib.odometry.gravity_up` separates gravity from the
vehicle's own acceleration over the last ``tilt_window`` seconds, and step 8 adds
:func:`~slamlib.slam3d.steps.tilt_log_prior` to every weight: a measurement of two of the six pose coordinates,
as an attitude filter uses its accelerometer. An accelerometer bias ``b`` tilts the measured up by ``b / g`` for
good, so after step 9 each frame's estimated rotation and measured up also go into a least-squares estimate of
the bias (:func:`slamlib.odometry.tilt_calibration_update`; a bias turns with the body, a tilted map does not), and
step 8 compares each particle's ``R_i^T g_w`` with the measured up less the bias. ``g_w``, the world's up, is
``e_z`` (the first body pose taken as level) unless ``FilterConfig.tilt_world_sigma > 0`` lets the fit move it.

Degenerate frames
-----------------
A frame whose scan keeps fewer than :data:`MIN_SCAN_POINTS` points after step 2 (an empty or all-zero scan, every
return outside ``[min_range, max_range]``) carries no usable evidence: scoring it would divide by zero points and
fill the weights with NaN. Such a frame is **skipped for scoring**: steps 5 and 6 stand (the particles move and
spread as usual), steps 7, 8 and 10 are skipped (weights unchanged, nothing merged), step 9's pose is the motion
prediction ``T_prev @ [dR, dp]`` (the previous estimate moved by this frame's IMU increment), and step 11 is not
run. ``n_skipped_frames`` counts these frames (``slamlib run`` writes it into ``metrics.json``). While the map is
still empty (degenerate first frames) the first frame with enough points starts it at its predicted pose.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from slamlib.kernels import get_backend
from slamlib.odometry import (
    gravity_up,
    increment_matrix,
    tilt_calibration_add,
    tilt_calibration_bins,
    tilt_calibration_estimate,
    tilt_calibration_prior,
    twist_between,
)
from slamlib.resampling import normalise_log_weights
from slamlib.slam3d import steps
from slamlib.slam3d.config import SLAM3DConfig
from slamlib.slam3d.match import match_scan
from slamlib.slam3d.preprocess import road_mask, sample_points, thin_ground

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
    poses : list of (4, 4) SLAM estimates ``T_world_body``, one per registered frame.
    dr_poses : list of (4, 4) dead-reckoning poses from the same IMU samples.
    n_resampled : number of frames in which step 11 resampled.
    n_deskewed : number of frames whose scan step 2 de-skewed (:func:`~slamlib.slam3d.steps.should_deskew`).
    n_matched : number of frames whose pose was scan-matched after step 9 (``FilterConfig.scan_match``).
    n_skipped_frames : number of frames skipped for scoring, with fewer than :data:`MIN_SCAN_POINTS` points
        (module docstring, "Degenerate frames").
    archive : list of (K, 3) float32 points pruned from the map (``keep_pruned``); see :meth:`map_points`.
    imu_prev : ``(velocity (3,), angular_rate (3,))`` of the last registered frame (None before the first).
    dts : list of each registered frame's ``dt`` (s).
    lidar_only : whether step 3 holds the filter's own last motion (constant velocity, :meth:`own_motion`)
        instead of reading an IMU: ``MotionConfig.model == "constant_velocity"``, or set at the first frame when
        it has no IMU values (the KITTI odometry layout). LIDAR-only there is no dead-reckoning twin.
    up : (3,) the accelerometer's up direction in this frame's body (:func:`slamlib.odometry.gravity_up`), which
        step 8's tilt prior holds the particles to; None when the prior is off (``FilterConfig.tilt_sigma = 0``).
    tilt_samples : deque of ``(specific_force, velocity, dt)`` of the frames in the tilt prior's window;
        ``up_span`` the seconds it spans.
    world_up, up_bias : (3,) the estimated world's up (world frame) and accelerometer bias (an angle, body frame) of
        the tilt prior (``e_z`` and 0 until frames come in). Behind them: ``tilt_prior`` ``(Lambda, eta, free)``
        and ``tilt_bins`` ``(Lambdas, etas, weights)``, the least-squares sums of each heading sector.
    last : dict with this frame's intermediate results (scores, sample, sigma, ...), for plots and tests.
    """

    def __init__(self, config: SLAM3DConfig | None = None, T_velo_imu=None, T0=None):
        self.config = cfg = config if config is not None else SLAM3DConfig()
        self.backend = get_backend(cfg.backend)
        self.rng = np.random.default_rng(cfg.seed)
        self.T_body_velo = (
            None
            if T_velo_imu is None
            else np.linalg.inv(np.asarray(T_velo_imu, dtype=np.float64))
        )
        self.map = cfg.map.make()
        self.T0 = np.eye(4) if T0 is None else np.asarray(T0, dtype=np.float64)
        self.particles, self.log_weights = steps.initialise_particles(
            cfg.filter.particles, self.T0
        )  # step 1
        self.poses: list[np.ndarray] = []
        self.dr_poses: list[np.ndarray] = []
        self.n_resampled = 0
        self.n_deskewed = 0
        self.n_matched = 0
        self.n_skipped_frames = 0
        self.archive: list[np.ndarray] = []
        self.last: dict = {}
        self.imu_prev = None
        self.dts: list[float] = []
        self.lidar_only = self.config.motion.model == "constant_velocity"
        self.tilt_samples: deque = (
            deque()
        )  # the accelerometer window of the tilt prior (_gravity_up)
        self.up, self.up_span = None, 0.0
        self.tilt_prior = tilt_calibration_prior(
            cfg.filter.tilt_world_sigma, cfg.filter.tilt_bias_sigma
        )
        self.tilt_bins = tilt_calibration_bins(cfg.filter.tilt_heading_bins)
        self.world_up, self.up_bias = tilt_calibration_estimate(
            self.tilt_prior, self.tilt_bins
        )

    # ----------------------------------------------------------------------------------------- step 12
    def register_frame(self, frame) -> np.ndarray:
        """Run steps 2-11 on one frame (``.scan``, ``.velocity``, ``.angular_rate``, ``.dt``); return the pose.

        The first frame only builds the map at the start pose. A frame with fewer than :data:`MIN_SCAN_POINTS`
        points is skipped for scoring: steps 5 and 6 stand, the pose is the motion prediction, and
        ``n_skipped_frames`` grows (module docstring, "Degenerate frames"). Returns ``T_world_body`` (4, 4).
        Raises ``ValueError`` for non-finite or physically impossible IMU values
        (:func:`~slamlib.slam3d.steps.read_imu`).
        """
        cfg, be = self.config, self.backend
        if (
            self.imu_prev is None
        ):  # first frame: LIDAR-only if asked to, or if the data has no IMU
            self.lidar_only = (
                cfg.motion.model == "constant_velocity"
                or getattr(frame, "velocity", None) is None
            )
        prev = (
            None if self.lidar_only else self.imu_prev
        )  # constant velocity: the twist is held over dt
        points = steps.read_scan(frame, cfg.scan, self.T_body_velo)  # 2
        imu = steps.read_imu(frame, self.own_motion() if self.lidar_only else None)  # 3
        tilt = (
            cfg.filter.tilt_sigma and not self.lidar_only
        )  # 3's accelerometer, for step 8's tilt prior
        force = steps.read_specific_force(frame) if tilt else None
        dt = steps.read_timing(frame)  # 4
        if steps.should_deskew(
            frame, cfg.scan
        ):  # step 2's motion compensation, with step 3's motion, to the pose time
            points = steps.deskew_scan(
                points,
                imu,
                cfg.scan,
                self.T_body_velo,
                steps.read_scan_time_offset(frame, cfg.scan),
            )
            self.n_deskewed += 1
        if self.imu_prev is None:  # first frame: the map starts at the start pose
            return self._start(points, imu, dt)
        increment = steps.motion_increment(
            imu, dt, prev
        )  # once: steps 5 and 6 and the dead-reckoning twin
        self.up = self._gravity_up(
            imu, force, dt, increment
        )  # step 8's tilt prior (None when off)
        moved = steps.offset_by_motion(self.particles, imu, dt, prev, be, increment)  # 5
        start = (
            self.lidar_only and len(self.poses) == 1
        )  # no motion estimate yet: search widely
        sigma = cfg.motion.sigma(
            increment[1], dt, self.lidar_only, start
        )  # = steps.motion_noise_sigma(...)
        moved = steps.perturb_with_noise(moved, sigma, self.rng, backend=be)  # 6
        if (
            len(points) < MIN_SCAN_POINTS or len(self.map) == 0
        ):  # degenerate frame: no scoring, no merge
            return self._skip(moved, imu, increment, points, dt, sigma)
        pool = (
            thin_ground(points, cfg.filter.lidar_only_ground_share, self.rng)
            if self.lidar_only
            else points
        )
        sample = sample_points(pool, cfg.filter.scored_points, self.rng)
        log_w = self._weigh(moved, self.log_weights, sample)  # 7 + 8
        moved, log_w = self._anneal(
            moved, log_w, sample, sigma, start
        )  # cfg.filter.refine rounds (none by default)
        pose, best = steps.pick_best_particle(moved, log_w, cfg.filter.estimate)  # 9
        if (
            self._matching()
        ):  # 9, sharpened: the pose scan-matched to the map, the particles moved with it
            pose, moved = self._match(pose, points, moved)
        self._calibrate_tilt(
            pose, dt
        )  # the world's up and the accelerometer's bias, for the next frames
        steps.merge_scan(self.map, pose, points, be)  # 10
        self._record(
            pose, imu, increment, points, dt, sample=sample, sigma=sigma, best=best
        )
        self.particles, self.log_weights, resampled = steps.resample_particles(  # 11
            moved, log_w, self.rng, cfg.filter.ess_fraction, be
        )
        self.n_resampled += int(resampled)
        return pose

    # ----------------------------------------------------------------------------------------- helpers
    def _weigh(self, particles, log_w, sample) -> np.ndarray:
        """Steps 7 + 8 and the weight update: ``log_w + score / (N * temperature)``, normalised (tempering, above),
        plus the tilt prior when on (module docstring, "Holding the tilt to gravity")."""
        scores = steps.score_particles(particles, sample, self.map, self.backend)
        self.last["scores"] = scores
        log_w = log_w + scores / (len(sample) * self.config.filter.temperature)
        if self.up is not None:
            log_w = log_w + steps.tilt_log_prior(
                particles,
                self.up - self.up_bias,
                self.config.filter.tilt_sigma,
                self.world_up,
            )
        return normalise_log_weights(log_w)

    def _calibrate_tilt(self, pose, dt) -> None:
        """Add this frame's estimated rotation and measured up to the tilt calibration (none when the prior is off
        or the window does not yet span ``tilt_window``), in its heading's sector: each frame weighs
        ``dt / tilt_window`` of an independent up measurement of standard deviation ``tilt_sigma`` (consecutive
        windows overlap), and the sectors weigh alike (:func:`slamlib.odometry.balance_heading_bins`)."""
        f = self.config.filter
        if self.up is None or self.up_span < f.tilt_window:
            return  # a shorter window (the drive's first seconds) measures up with errors ~ 1 / its span
        tilt_calibration_add(
            self.tilt_bins, pose[:3, :3], self.up, dt / f.tilt_window / f.tilt_sigma**2
        )
        self.world_up, self.up_bias = tilt_calibration_estimate(
            self.tilt_prior, self.tilt_bins
        )

    def _gravity_up(self, imu, force, dt, increment):
        """The up direction in this frame's body, from the accelerometer over the last ``tilt_window`` seconds
        (:func:`slamlib.odometry.gravity_up`): the samples of this frame and the registered frames before it,
        turned by the filter's own estimated rotations and this frame's predicted one (the IMU increment on the
        last estimate). None when the prior is off, LIDAR-only, or the frame has no accelerometer."""
        samples = self.tilt_samples  # (force, velocity, dt) per frame, oldest first
        if (
            force is None
        ):  # register_frame reads no accelerometer when the prior is off or LIDAR-only
            samples.clear()
            return None
        samples.append((force, imu[0], dt))
        while (
            len(samples) > 2
            and sum(s[2] for s in list(samples)[2:]) >= self.config.filter.tilt_window
        ):
            samples.popleft()  # the rest still spans the window
        past = [T[:3, :3] for T in self.poses[len(self.poses) - len(samples) + 1 :]]
        R = np.array(
            past + [self.poses[-1][:3, :3] @ increment_matrix(*increment)[:3, :3]]
        )
        force, velocity, dts = (np.array(x) for x in zip(*samples))
        self.up_span = float(dts[1:].sum())
        return gravity_up(R, force, velocity, dts)

    def _anneal(self, particles, log_w, sample, sigma, start: bool = False):
        """``refine`` coarse-to-fine rounds: resample, perturb with the noise shrunk by ``refine_shrink``, weigh.
        ``start`` (LIDAR-only, the first frame that moves: its motion is unknown) first adds
        ``MotionConfig.cv_start_rounds`` rounds that halve the wide start spread each time."""
        f = self.config.filter
        shrinks = [f.refine_shrink] * f.refine
        if start:
            shrinks = [
                0.5**k for k in range(1, self.config.motion.cv_start_rounds + 1)
            ] + shrinks
        for shrink in shrinks:
            particles, log_w, resampled = steps.resample_particles(
                particles, log_w, self.rng, 1.0, self.backend
            )
            self.n_resampled += int(resampled)
            particles = steps.perturb_with_noise(
                particles, sigma * shrink, self.rng, backend=self.backend
            )
            log_w = self._weigh(particles, log_w, sample)
        return particles, log_w

    def _matching(self) -> bool:
        """Scan-match after step 9? ``FilterConfig.scan_match``, by default (None) only LIDAR-only."""
        flag = self.config.filter.scan_match
        return self.lidar_only if flag is None else bool(flag)

    def _match(self, pose, points, particles):
        """The pose moved to the map score's nearest peak for the whole scan (:func:`slamlib.slam3d.match.match_scan`),
        and every particle by the same correction ``C = T_matched T^-1`` (applied in the world frame), so that step
        11 resamples around the matched pose: the improved proposal (module docstring, "Scan matching")."""
        road = (
            road_mask(points) if self.lidar_only else None
        )  # LIDAR-only: the road holds height and tilt only
        matched = match_scan(
            pose, points, self.map, self.config.filter.scan_match_iterations, road
        )
        C = matched @ np.linalg.inv(pose)
        self.n_matched += 1
        moved = steps.Particles3D(
            np.einsum("ij,pjk->pik", C[:3, :3], particles.R),
            particles.t @ C[:3, :3].T + C[:3, 3],
        )
        return matched, moved

    def own_motion(self) -> tuple[np.ndarray, np.ndarray]:
        """LIDAR-only step 3: the twist ``(v, w)`` that took the estimated pose ``k = min(cv_window, F - 1)`` frames
        back to the last one in their time (:func:`slamlib.odometry.twist_between`), times ``cv_damping``
        (:class:`~slamlib.slam3d.config.MotionConfig`); zero before two frames (the vehicle is taken to start at
        rest, as KISS-ICP does)."""
        if len(self.poses) < 2:
            return np.zeros(3), np.zeros(3)
        m = self.config.motion
        k = min(m.cv_window, len(self.poses) - 1)
        v, w = twist_between(self.poses[-1 - k], self.poses[-1], sum(self.dts[-k:]))
        damping = np.asarray(m.cv_damping)
        return v * damping[:3], w * damping[3:]

    def _start(self, points, imu, dt) -> np.ndarray:
        """The first frame: step 10 at the start pose, which is also the first pose of both trajectories."""
        if len(points) >= MIN_SCAN_POINTS:
            steps.merge_scan(self.map, self.T0, points, self.backend)
        else:
            self.n_skipped_frames += 1
        self._record(self.T0, imu, None, points, dt)
        return self.poses[-1]

    def _skip(self, moved, imu, increment, points, dt, sigma) -> np.ndarray:
        """A frame not scored: keep the moved particles and their weights; the pose is the motion prediction.
        With enough points but no map yet (the earlier frames were degenerate) the scan starts the map there."""
        self.particles = moved
        pose = self.poses[-1] @ increment_matrix(*increment)
        if (
            len(points) >= MIN_SCAN_POINTS
        ):  # the map is empty: start it, like the first frame
            steps.merge_scan(self.map, pose, points, self.backend)
        else:
            self.n_skipped_frames += 1
        self._record(
            pose, imu, increment, points, dt, sample=points[:0], sigma=sigma, best=None
        )
        return pose

    def _record(self, pose, imu, increment, points, dt, **last) -> None:
        """Bookkeeping after step 10: the SLAM pose and its ``dt``, the dead-reckoning twin (moved by this frame's
        IMU ``increment``, None on the first frame; none LIDAR-only), the IMU sample, map pruning."""
        self.poses.append(np.asarray(pose, dtype=np.float64))
        self.dts.append(float(dt))
        if not self.lidar_only:
            T_dr = (
                self.T0
                if increment is None
                else self.dr_poses[-1] @ increment_matrix(*increment)
            )
            self.dr_poses.append(np.asarray(T_dr, dtype=np.float64))
        self.imu_prev = imu
        self.last.update(points=points, **last)
        every, span = self.config.map.prune_every, self.config.map.transient_span
        if every and len(self.poses) % every == 0:
            self._prune(self.poses[-1][:3, 3])
        if (
            span and len(self.poses) % span == 0
        ):  # the movers' trails (MapConfig.transient_span)
            self.map.evict_transients(span)

    def _prune(self, center) -> None:
        """Drop map elements farther than ``prune_radius`` from ``center``; keep their points in ``archive``."""
        r = self.config.map.prune_radius
        if self.config.map.keep_pruned:
            pts = self.map.points()
            far = (
                np.sum((pts.astype(np.float64) - center) ** 2, axis=1) > r**2
            )  # the maps' own eviction rule
            if far.any():
                self.archive.append(pts[far])
        self.map.prune(center, r)

    def map_points(self) -> np.ndarray:
        """All map points (M, 3) float32, world frame: the live map's plus the pruned ones kept in ``archive``."""
        return (
            np.concatenate(self.archive + [self.map.points()])
            if self.archive
            else self.map.points()
        )

    # ----------------------------------------------------------------------------------------- results
    @property
    def trajectory(self) -> np.ndarray:
        """SLAM poses ``T_world_body`` (F, 4, 4) of the registered frames."""
        return np.array(self.poses).reshape(-1, 4, 4)

    @property
    def dead_reckoning(self) -> np.ndarray | None:
        """Dead-reckoning poses (F, 4, 4) from the same IMU samples; None LIDAR-only (no IMU to reckon with)."""
        return None if self.lidar_only else np.array(self.dr_poses).reshape(-1, 4, 4)
