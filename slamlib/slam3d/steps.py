"""The twelve steps of particle SLAM on 6-DoF poses, one pure function per step (shared names, CONTRIBUTING.md).

State and frames
----------------
* A particle is a pose ``T_world_body = [R_i, t_i]`` of the **vehicle body = the IMU/OXTS frame** (x forward,
  y left, z up): ``R (P, 3, 3)`` float64, ``t (P, 3)`` float64. The body is the IMU because the motion model
  (step 5) integrates the IMU's body-frame velocities and rates, and KITTI's ground truth is ``T_w_imu``.
* **World** = the body (IMU) pose at the first processed frame: every particle starts at the identity.
* Scans are read in the Velodyne frame and moved once into the body frame with the calibration
  ``T_body_velo = inv(T_velo_imu)`` (step 2), so scoring needs only the particle poses.
* Weights are kept as **log-weights** ``(P,)`` float64 (normalised so that ``logsumexp = 0``), never as
  products of tiny likelihoods.

The steps
---------
1. :func:`initialise_particles` -- ``P`` copies of the start pose (the map defines the world, so there is no
   uncertainty at frame 0), as :class:`Particles3D`, and uniform log-weights.
2. :func:`read_scan` -- range crop, voxel down-sampling, Velodyne -> body frame.
3. :func:`read_imu` -- body velocities ``(vf, vl, vu)`` m/s and angular rates ``(wf, wl, wu)`` rad/s (LIDAR-only,
   no IMU: the motion stage holds the filter's own last estimated twist, :mod:`slamlib.slam3d.stages.motion`). With
   a tilt prior, also :func:`read_specific_force`: the accelerometer, which tells up from down
   (:func:`slamlib.slam3d.stages.prior.gravity_up`).
4. :func:`read_timing` -- ``dt`` seconds since the previous frame (and, for de-skewing, :func:`read_scan_time_offset`:
   the scan's timestamp relative to the pose).
5. :func:`offset_by_motion` -- ``T_i <- T_i [dR, dp]`` with the IMU increment ``(dR, dp)`` over ``dt``
   (:func:`motion_increment`: the midpoint twist of the previous and this IMU sample, integrated on SE(3)).
6. :func:`perturb_with_noise` -- ``T_i <- T_i [N_i, sigma_t n_i]``: Gaussian noise in the body frame with the
   spread of :func:`motion_noise_sigma` (grows with distance travelled and with ``dt``).
7. :func:`transform_scan` -- body points into the world with each particle's pose (or one pose): ``R p_b + t``.
8. :func:`score_particles` -- fused 7 + 8 for every particle against the map built so far (the backend's
   ``score_particles``; never builds ``P x N`` points). Returns log-likelihood scores. With a tilt prior,
   :func:`slamlib.slam3d.stages.prior.tilt_log_prior` adds how well each particle's roll and pitch agree with the
   accelerometer's up.
9. :func:`pick_best_particle` -- the maximum-weight particle, or the weighted mean around it.
10. :func:`merge_scan` -- the whole down-sampled scan, moved with the chosen pose, into the map (in place).
11. :func:`resample_particles` -- systematic resampling (Kitagawa 1996) when the effective sample size falls
    below a fraction of ``P``; weights reset to uniform.
12. the loop: :meth:`slamlib.slam3d.ParticleSLAM3D.register_frame`.

The signatures follow the contract of :mod:`slamlib.contract`, shared with 1D: the leading parameters (particles,
log-weights, map, pose, points, rng) in the same order at every dimension; what 3D adds comes after them with a
default, in particular ``backend`` -- a name (``"numpy"``, ``"cpu"``, ``"cuda"``) or a
:class:`slamlib.kernels.Backend` -- and the setting groups of :mod:`slamlib.slam3d.config`, whose defaults are
the pipeline's.

Steps 5 and 6 call the backend's fused ``move_particles`` kernel, step 5 with zero noise and step 6 with zero
motion, so step 5 then step 6 equals one fused call. The kernels apply ``trans_delta`` *after* the rotation
increment (``t + R dR trans_delta``, CONTRIBUTING.md); step 5 passes ``dR^T dp`` so that the particles move by
exactly the SE(3) increment ``[dR, dp]`` that dead reckoning uses.

References: S. Thrun, W. Burgard, D. Fox, *Probabilistic Robotics* (2005), ch. 4.3 (particle filter), 5.3
(motion model), 6.4 (likelihood field), 13 (FastSLAM); G. Grisetti et al., "Improved techniques for grid
mapping with Rao-Blackwellized particle filters", IEEE T-RO 2007; Gothoskar & Tabrizi, CMU 15-418 project
page (the twelve steps, 2017).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.kernels import DEFAULT_BACKEND, Backend, get_backend
from slamlib.kitti.oxts import (
    MAX_ACCELERATION_MPS2,
    MAX_ANGULAR_RATE_RADPS,
    MAX_SPEED_MPS,
)
from slamlib.odometry import imu_increment
from slamlib.resampling import (
    DEFAULT_ESS_FRACTION,
    normalise_log_weights,
    resample_indexes,
    uniform_log_weights,
)
from slamlib.slam3d.config import AUTO, FilterConfig, MotionConfig, ScanConfig
from slamlib.slam3d.preprocess import crop_and_downsample, deskew, sweep_times

__all__ = [
    "Particles3D",
    "initialise_particles",
    "read_scan",
    "should_deskew",
    "deskew_scan",
    "read_imu",
    "check_twist",
    "frame_label",
    "read_timing",
    "read_scan_time_offset",
    "read_specific_force",
    "motion_increment",
    "motion_noise_sigma",
    "offset_by_motion",
    "perturb_with_noise",
    "transform_scan",
    "score_particles",
    "pick_best_particle",
    "merge_scan",
    "resample_particles",
    "weighted_mean_pose",
    "project_to_rotation",
]


def _backend(backend) -> Backend:
    """A :class:`~slamlib.kernels.Backend` from a name or a backend object."""
    return get_backend(backend) if isinstance(backend, str) else backend


@dataclass(frozen=True)
class Particles3D:
    """``P`` poses ``T_world_body = [R_i, t_i]``: ``R (P, 3, 3)`` float64 rotations, ``t (P, 3)`` float64 positions.

    ``len(particles)`` is ``P``; ``particles[idx]`` with an index array selects particles (resampling).
    """

    R: np.ndarray
    t: np.ndarray

    def __len__(self) -> int:
        return len(self.t)

    def __getitem__(self, idx) -> Particles3D:
        return Particles3D(self.R[idx], self.t[idx])

    def poses(self) -> np.ndarray:
        """The particles as 4x4 poses ``(P, 4, 4)``."""
        return make_pose(self.R, self.t)


# ------------------------------------------------------------------------------------------------ step 1
def initialise_particles(n_particles: int, pose0=None) -> tuple[Particles3D, np.ndarray]:
    """Step 1: ``n_particles`` particles all at the start pose ``pose0`` (4x4, default identity = the world origin).

    Returns ``(particles, log_weights)``: :class:`Particles3D` and uniform log-weights ``-log P`` ``(P,)``.
    """
    n = int(n_particles)
    if n < 1:
        raise ValueError(f"need at least one particle, got {n}")
    T0 = np.eye(4) if pose0 is None else np.asarray(pose0, dtype=np.float64)
    R = np.repeat(T0[None, :3, :3], n, axis=0).copy()
    t = np.repeat(T0[None, :3, 3], n, axis=0).copy()
    return Particles3D(R, t), uniform_log_weights(n)


# ------------------------------------------------------------------------------------------------ steps 2-4
def read_scan(
    frame, scan_config: ScanConfig = ScanConfig(), T_body_velo=None
) -> np.ndarray:
    """Step 2: the frame's scan, cropped, down-sampled and moved into the body (IMU) frame.

    Parameters
    ----------
    frame : object with ``.scan`` (N, 4) float32 ``x, y, z, reflectance`` in the Velodyne frame
        (e.g. :class:`slamlib.kitti.Frame`), or an (N, 3)/(N, 4) array.
    scan_config : :class:`~slamlib.slam3d.config.ScanConfig`
        Range crop ``[min_range, max_range]`` in the Velodyne frame
        (:func:`~slamlib.slam3d.preprocess.crop_range`) and the down-sampling voxel edge ``downsample_voxel``
        (:func:`~slamlib.slam3d.preprocess.voxel_downsample`; 0 = off), metres.
    T_body_velo : (4, 4), optional
        Velodyne pose in the body frame, ``p_body = T_body_velo p_velo`` (KITTI: ``inv(T_velo_imu)``);
        default identity.

    Returns
    -------
    (M, 3) float32 points in the body frame.
    """
    scan = frame.scan if hasattr(frame, "scan") else frame
    scan = np.asarray(scan)
    if scan.ndim != 2 or scan.shape[1] not in (3, 4):
        raise ValueError(f"scan must have shape (N, 3) or (N, 4), got {scan.shape}")
    c = scan_config
    # one O(N) pass over the whole rows (the matcher's thinning then loads the same kernel), x, y, z kept
    pts = crop_and_downsample(
        scan, c.min_range, c.max_range, c.downsample_voxel, columns=3
    )
    pts = np.asarray(pts, dtype=np.float32)
    if T_body_velo is not None:
        T = np.asarray(T_body_velo, dtype=np.float64)
        pts = (pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    return np.ascontiguousarray(pts)


def should_deskew(frame, scan_config: ScanConfig = ScanConfig()) -> bool:
    """Step 2's choice: de-skew this frame's scan? ``scan_config.deskew`` when True or False; by default
    (``"auto"``) whether
    the scan was taken over a sweep and is not yet motion-compensated, ``frame.swept``
    (:func:`slamlib.kitti.velodyne.scans_swept`: real KITTI raw scans and synthetic ones written with
    ``distortion``; not the KITTI odometry benchmark's). Frames without ``swept`` (simulated, hand-made) count
    as cast from one pose."""
    if scan_config.deskew != AUTO:
        return bool(scan_config.deskew)
    return bool(getattr(frame, "swept", False))


def deskew_scan(
    points,
    imu,
    scan_config: ScanConfig = ScanConfig(),
    T_body_velo=None,
    time_offset: float = 0.0,
) -> np.ndarray:
    """Step 2's motion compensation, once step 3 has the motion: body-frame ``points (N, 3)`` of a scan taken over
    a sweep, each moved to where it was at the frame's pose time for the body twist ``imu = (velocity,
    angular_rate)`` (:func:`slamlib.slam3d.preprocess.deskew`). Each point's firing time comes from its azimuth
    in the Velodyne frame (:func:`~slamlib.slam3d.preprocess.sweep_times`, ``scan_config.sweep_period``; the
    points are taken back there with ``inv(T_body_velo)`` for it), relative to the scan's timestamp; ``time_offset``
    (s) is that timestamp relative to the pose's (``Frame.scan_time_offset_s``: on KITTI raw the OXTS pose comes
    12-24 ms after the mid-sweep stamp; 0 moves the points to the scan's own timestamp). Returns ``(N, 3)`` float32.
    """
    pts = np.asarray(points, dtype=np.float32)
    if len(pts) == 0:
        return pts
    velo = pts
    if T_body_velo is not None:
        T = np.linalg.inv(np.asarray(T_body_velo, dtype=np.float64))
        velo = pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    times = sweep_times(velo, scan_config.sweep_period) + float(time_offset)
    return np.ascontiguousarray(deskew(pts, imu[0], imu[1], times))


def frame_label(frame) -> str:
    """`` (frame N)`` for a frame with an ``index``, empty otherwise: where an error message says it happened."""
    return f" (frame {frame.index})" if hasattr(frame, "index") else ""


def read_imu(frame) -> tuple[np.ndarray, np.ndarray]:
    """Step 3: ``imu = (velocity, angular_rate)``: body velocity ``(vf, vl, vu)`` m/s and rates ``(wf, wl, wu)``
    rad/s, each (3,), checked by :func:`check_twist`.

    Raises ``ValueError`` on a frame without IMU values (``frame.velocity is None``, as in the KITTI odometry
    layout: LIDAR-only, the motion stage holds the filter's own motion instead,
    :class:`slamlib.slam3d.stages.ConstantVelocity`), and as :func:`check_twist` does.
    """
    where = frame_label(frame)
    if (
        getattr(frame, "velocity", None) is None
        or getattr(frame, "angular_rate", None) is None
    ):
        raise ValueError(
            f"frame{where} has no IMU values: LIDAR-only step 3 needs the filter's own motion estimate"
        )
    return check_twist(frame.velocity, frame.angular_rate, where)


def check_twist(velocity, angular_rate, where: str = "") -> tuple[np.ndarray, np.ndarray]:
    """``(velocity (3,), angular_rate (3,))`` as float64, or ``ValueError`` (naming ``where``) on a non-finite value
    or one beyond the OXTS physical limits (:data:`slamlib.kitti.oxts.MAX_SPEED_MPS`,
    :data:`~slamlib.kitti.oxts.MAX_ANGULAR_RATE_RADPS`), which would otherwise give NaN poses."""
    v = np.asarray(velocity, dtype=np.float64).reshape(3)
    w = np.asarray(angular_rate, dtype=np.float64).reshape(3)
    for name, x, limit, unit in (
        ("velocity", v, MAX_SPEED_MPS, "m/s"),
        ("angular_rate", w, MAX_ANGULAR_RATE_RADPS, "rad/s"),
    ):
        if not np.all(np.isfinite(x)) or np.any(np.abs(x) > limit):
            raise ValueError(
                f"IMU {name}{where} must be finite and within +-{limit:g} {unit}, got {x.tolist()}"
            )
    return v, w


def read_timing(frame) -> float:
    """Step 4: ``dt`` seconds since the previous frame (0 for the first; KITTI's ~0.1 s varies by a few ms)."""
    dt = float(frame.dt)
    if not np.isfinite(dt) or dt < 0:
        raise ValueError(f"frame dt must be finite and >= 0, got {dt}")
    return dt


def read_scan_time_offset(frame, scan_config: ScanConfig = ScanConfig()) -> float:
    """Step 4's other reading, for de-skewing: the scan's timestamp minus the frame's pose time (s).

    On KITTI raw the pose (OXTS) comes 12-24 ms after the scan's mid-sweep timestamp, so this is about -0.017 s
    (``Frame.scan_time_offset_s``); 0.0 for frames without it (the odometry layout, whose poses are the scans',
    and synthetic or simulated frames). Raises ``ValueError`` for a non-finite offset or one longer than a sweep
    (``scan_config.sweep_period``), which no real pairing of a scan with its pose gives.
    """
    offset = float(getattr(frame, "scan_time_offset_s", 0.0))
    if not np.isfinite(offset) or abs(offset) > scan_config.sweep_period:
        where = frame_label(frame)
        raise ValueError(
            f"scan time offset{where} must be finite and within one sweep "
            f"(+-{scan_config.sweep_period:g} s) of the pose, got {offset}"
        )
    return offset


def read_specific_force(frame) -> np.ndarray | None:
    """Step 3's accelerometer reading: the body-frame specific force ``(ax, ay, az)`` m/s^2, gravity included
    (``frame.specific_force``; ``+9.81`` on z when level and still), or None when the frame has none (the KITTI
    odometry layout). KITTI's ``af, al, au`` are *not* used: on real drives they are axes of the level heading
    frame, where gravity is always straight down, so they cannot tell the body's tilt.

    Raises ``ValueError`` on a non-finite value or one beyond :data:`slamlib.kitti.oxts.MAX_ACCELERATION_MPS2`.
    """
    f = getattr(frame, "specific_force", None)
    if f is None:
        return None
    f = np.asarray(f, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(f)) or np.any(np.abs(f) > MAX_ACCELERATION_MPS2):
        where = frame_label(frame)
        raise ValueError(
            f"IMU specific_force{where} must be finite and within +-{MAX_ACCELERATION_MPS2:g} m/s^2, "
            f"got {f.tolist()}"
        )
    return f


# ------------------------------------------------------------------------------------------------ step 5
def motion_increment(imu, dt: float, previous_imu=None) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame motion over ``dt``: ``(rpy_delta (3,) rad, trans_delta (3,) m)``.

    The midpoint-twist SE(3) increment of :func:`slamlib.odometry.imu_increment` between ``previous_imu`` and
    ``imu`` (each ``(velocity, angular_rate)``; without ``previous_imu`` the twist of ``imu`` is held over
    ``dt``) -- the same increment dead reckoning uses, so that
    ``T_new = T_old @ make_pose(rpy_to_matrix(rpy_delta), trans_delta)``.
    """
    v, w = imu
    v_prev, w_prev = imu if previous_imu is None else previous_imu
    rpy, trans = imu_increment(v_prev, w_prev, v, w, dt)
    return np.asarray(rpy, dtype=np.float64).reshape(3), np.asarray(
        trans, dtype=np.float64
    ).reshape(3)


def offset_by_motion(
    particles: Particles3D,
    imu,
    dt: float,
    previous_imu=None,
    backend=DEFAULT_BACKEND,
    increment=None,
) -> Particles3D:
    """Step 5: move every particle by the body-frame increment: ``R_i <- R_i dR``, ``t_i <- t_i + R_i dp``.

    ``(dR, dp)`` from :func:`motion_increment` (``imu``, ``dt``, ``previous_imu``): the SE(3) product
    ``T_i [dR, dp]``, the same increment as dead reckoning. The backend's ``move_particles`` with zero noise;
    it applies the translation after the rotation increment, hence the ``dR^T dp`` passed to it. A caller that
    needs the increment too (the noise spread, the dead-reckoning twin) passes it as ``increment`` (that very
    ``motion_increment(imu, dt, previous_imu)``) so it is computed once per frame (~0.2 ms each).
    """
    rpy, dp = motion_increment(imu, dt, previous_imu) if increment is None else increment
    P = len(particles)
    R, t = _backend(backend).move_particles(
        particles.R,
        particles.t,
        rpy,
        rpy_to_matrix(rpy).T @ dp,
        np.zeros((P, 6)),
        np.zeros(6),
    )
    return Particles3D(R, t)


def motion_noise_sigma(
    imu,
    dt: float,
    previous_imu=None,
    motion_config: MotionConfig = MotionConfig(),
    constant_velocity: bool = False,
    start: bool = False,
) -> np.ndarray:
    """Standard deviations ``(6,)`` of step 6's noise for this frame: translation x, y, z (m), roll, pitch, yaw (rad).

    ``motion_config.sigma(dp, dt, constant_velocity, start)`` (:class:`~slamlib.slam3d.config.MotionConfig`) with
    ``dp`` the translation of :func:`motion_increment`: the spread grows with the distance travelled and with time,
    and LIDAR-only (``constant_velocity``; ``start``: no motion known yet) with what that model cannot know.
    """
    return motion_config.sigma(
        motion_increment(imu, dt, previous_imu)[1], dt, constant_velocity, start
    )


# ------------------------------------------------------------------------------------------------ step 6
def perturb_with_noise(
    particles: Particles3D,
    sigma,
    rng: np.random.Generator,
    noise=None,
    backend=DEFAULT_BACKEND,
) -> Particles3D:
    """Step 6: ``T_i <- T_i [N_i, sigma[:3] * n_i[:3]]``, ``N_i = rpy_to_matrix(sigma[3:] * n_i[3:])``.

    ``n_i ~ N(0, I_6)`` drawn from ``rng`` as a ``(P, 6)`` array (translation x, y, z then roll, pitch, yaw), or
    passed in as ``noise``. The noise acts in each particle's body frame (the backend's ``move_particles`` with
    zero motion).
    """
    P = len(particles)
    if noise is None:
        noise = rng.standard_normal((P, 6))
    R, t = _backend(backend).move_particles(
        particles.R,
        particles.t,
        np.zeros(3),
        np.zeros(3),
        noise,
        np.asarray(sigma, dtype=np.float64),
    )
    return Particles3D(R, t)


# ------------------------------------------------------------------------------------------------ step 7
def transform_scan(particles, points, backend=DEFAULT_BACKEND) -> np.ndarray:
    """Step 7: body-frame ``points (N, 3)`` into the world with each particle's pose: ``R_i p + t_i``.

    ``particles`` is a :class:`Particles3D` -> ``(P, N, 3)`` float32, or one pose ``T_world_body`` (4, 4) ->
    ``(N, 3)`` float32 (the backend's ``transform_points``). Scoring (step 8) fuses this step for all particles
    and never builds the ``P x N`` points.
    """
    be = _backend(backend)
    pts = np.ascontiguousarray(points, dtype=np.float32)
    if isinstance(particles, Particles3D):
        out = np.empty((len(particles), len(pts), 3), np.float32)
        # each particle's scan straight into its slice: no stacking copy
        for i, T in enumerate(particles.poses()):
            be.transform_points(T, pts, out=out[i])
        return out
    return be.transform_points(np.asarray(particles, dtype=np.float64), pts)


# ------------------------------------------------------------------------------------------------ step 8
def score_particles(
    particles: Particles3D, points, world_map, backend=DEFAULT_BACKEND
) -> np.ndarray:
    """Step 8 (fused with 7): log-likelihood score ``(P,)`` of each particle's pose for the body-frame scan.

    ``score_i = sum_j term(R_i p_j + t_i)`` with the map's robust per-point term (truncated NDT Mahalanobis
    distance for the voxel map, truncated nearest-neighbour distance for the BVH map; see
    :mod:`slamlib.maps.base`). Higher is better; the maximum is 0. ``points`` is the scoring sample (N, 3)
    float32, ``world_map`` the :class:`slamlib.maps.Map3D` built so far.
    """
    return _backend(backend).score_particles(
        particles.R,
        particles.t,
        np.ascontiguousarray(points, dtype=np.float32),
        world_map.lookup(),
    )


# ------------------------------------------------------------------------------------------------ step 9
def project_to_rotation(M) -> np.ndarray:
    """Closest rotation (Frobenius norm) to a 3x3 matrix: ``U diag(1, 1, det(U V^T)) V^T`` from ``M = U S V^T``.

    The chordal L2 mean of rotations (Hartley et al., "Rotation averaging", IJCV 2013, sec. 5.3).
    """
    U, _, Vt = np.linalg.svd(np.asarray(M, dtype=np.float64))
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt)) or 1.0
    return U @ D @ Vt


def weighted_mean_pose(R, t, weights) -> np.ndarray:
    """Weighted mean pose (4, 4): ``t = sum w_i t_i``, ``R`` = chordal mean ``project(sum w_i R_i)``."""
    w = np.asarray(weights, dtype=np.float64)
    w = w / w.sum()
    return make_pose(project_to_rotation(np.einsum("p,pij->ij", w, R)), w @ t)


def pick_best_particle(
    particles: Particles3D,
    log_weights,
    pose_estimate: str | None = None,
    radius: float = 0.5,
) -> tuple[np.ndarray, int]:
    """Step 9: the pose estimate of this frame and the index of the highest-weight particle.

    ``pose_estimate="best"``: the maximum-weight particle's pose (ties to the lowest index).
    ``pose_estimate="mean"``: the weighted mean (:func:`weighted_mean_pose`) of the particles within ``radius``
    metres of the best one -- a local mean that averages out the sampling noise of the cloud without blending
    separate modes. ``None``: the default, :attr:`FilterConfig.pose_estimate
    <slamlib.slam3d.config.FilterConfig>` (``"best"``).

    Returns ``(T_world_body (4, 4), best_index)``.
    """
    if pose_estimate is None:
        pose_estimate = FilterConfig.pose_estimate
    log_w = np.asarray(log_weights, dtype=np.float64)
    R, t = particles.R, particles.t
    i = int(np.argmax(log_w))
    if pose_estimate == "best":
        return make_pose(R[i], t[i]), i
    if pose_estimate != "mean":
        raise ValueError(f"pose_estimate must be 'best' or 'mean', got {pose_estimate!r}")
    near = np.sum((t - t[i]) ** 2, axis=1) <= radius**2
    w = np.exp(log_w[near] - log_w[i])
    return weighted_mean_pose(R[near], t[near], w), i


# ------------------------------------------------------------------------------------------------ step 10
def merge_scan(world_map, pose, points, backend=DEFAULT_BACKEND):
    """Step 10: add the body-frame scan ``points (N, 3)`` placed by ``pose`` (``T_world_body``, 4x4) to ``world_map``.

    Merges the whole down-sampled scan (not only the scoring sample). Changes ``world_map`` in place and returns it.
    """
    world_map.merge(transform_scan(pose, points, backend))
    return world_map


# ------------------------------------------------------------------------------------------------ step 11
def resample_particles(
    particles: Particles3D,
    log_weights,
    rng: np.random.Generator,
    ess_fraction: float | None = DEFAULT_ESS_FRACTION,
    backend=DEFAULT_BACKEND,
) -> tuple[Particles3D, np.ndarray, bool]:
    """Step 11: systematic resampling by weight when ``ESS < ess_fraction * P`` (``None``: always).

    :func:`slamlib.resampling.resample_indexes` with the backend's ``systematic_resample`` (Kitagawa 1996): one
    offset ``u0 ~ U[0, 1)`` from ``rng``, every particle copied ``floor(P w_i)`` or ``ceil(P w_i)`` times, and
    the log-weights reset to uniform. ``ESS = 1 / sum w_i^2`` (Kong, Liu & Wong 1994).

    Returns ``(particles, log_weights, resampled: bool)``; ``P`` is unchanged.
    """
    idx = resample_indexes(
        log_weights, rng, ess_fraction, _backend(backend).systematic_resample
    )
    if idx is None:
        return particles, normalise_log_weights(log_weights), False
    return particles[idx], uniform_log_weights(len(particles)), True
