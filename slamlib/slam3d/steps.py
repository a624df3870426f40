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
   uncertainty at frame 0).
2. :func:`read_scan` -- range crop, voxel down-sampling, Velodyne -> body frame.
3. :func:`read_imu` -- body velocities ``(vf, vl, vu)`` m/s and angular rates ``(wf, wl, wu)`` rad/s.
4. :func:`read_timing` -- ``dt`` seconds since the previous frame.
5. :func:`offset_by_motion` -- ``T_i <- T_i [dR, dp]`` with the IMU increment ``(dR, dp)`` over ``dt``
   (:func:`slamlib.odometry.imu_increment`, midpoint twist integrated on SE(3)).
6. :func:`perturb_with_noise` -- ``T_i <- T_i [N_i, sigma_t n_i]``: Gaussian noise in the body frame with the
   spread of :func:`motion_noise_sigma` (grows with distance travelled and with ``dt``).
7. :func:`transform_scan` -- body points into the world with one pose: ``p_w = R p_b + t``.
8. :func:`score_particles` -- fused 7 + 8 for every particle against the map built so far (the backend's
   ``score_particles``; never builds ``P x N`` points). Returns log-likelihood scores.
9. :func:`pick_best_particle` -- the maximum-weight particle, or the weighted mean around it.
10. :func:`merge_scan` -- the whole down-sampled scan, moved with the chosen pose, into the map.
11. :func:`resample_particles` -- systematic resampling (Kitagawa 1996) when the effective sample size falls
    below a fraction of ``P``; weights reset to uniform.
12. the loop: :meth:`slamlib.slam3d.ParticleSLAM3D.register_frame`.

Steps 5 and 6 are one call to the backend's fused ``move_particles`` in the pipeline (:func:`move_particles`);
the separate functions call the same kernel with zero noise / zero motion, so they compose to exactly the fused
result. Note: the backends' ``move_particles`` applies ``trans_delta`` *after* the rotation increment
(``t + R dR trans_delta``, CONTRIBUTING.md); :func:`move_particles` passes ``dR^T dp`` so that the particles move
by exactly the SE(3) increment ``[dR, dp]`` that dead reckoning uses.

References: S. Thrun, W. Burgard, D. Fox, *Probabilistic Robotics* (2005), ch. 4.3 (particle filter), 5.3
(motion model), 6.4 (likelihood field), 13 (FastSLAM); G. Grisetti et al., "Improved techniques for grid
mapping with Rao-Blackwellized particle filters", IEEE T-RO 2007; Gothoskar & Tabrizi, CMU 15-418 project
page (the twelve steps, 2017).
"""

from __future__ import annotations

import numpy as np

from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.odometry import imu_increment
from slamlib.resampling import effective_sample_size
from slamlib.slam3d.preprocess import crop_range, voxel_downsample

__all__ = [
    "initialise_particles", "read_scan", "read_imu", "read_timing", "motion_increment", "motion_noise_sigma",
    "offset_by_motion", "perturb_with_noise", "move_particles", "transform_scan", "score_particles",
    "normalise_log_weights",
    "pick_best_particle", "merge_scan", "resample_particles", "weighted_mean_pose", "project_to_rotation",
]


# ------------------------------------------------------------------------------------------------ step 1
def initialise_particles(n: int, T0=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Step 1: ``n`` particles all at the start pose ``T0`` (4x4, default identity = the world origin).

    Returns
    -------
    R : (n, 3, 3) float64, t : (n, 3) float64
        Particle poses ``T_world_body``.
    log_w : (n,) float64
        Uniform log-weights ``-log n``.
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"need at least one particle, got {n}")
    T0 = np.eye(4) if T0 is None else np.asarray(T0, dtype=np.float64)
    R = np.repeat(T0[None, :3, :3], n, axis=0).copy()
    t = np.repeat(T0[None, :3, 3], n, axis=0).copy()
    return R, t, np.full(n, -np.log(n))


# ------------------------------------------------------------------------------------------------ steps 2-4
def read_scan(frame, T_body_velo=None, min_range: float = 3.0, max_range: float = 60.0,
              voxel_size: float = 0.25) -> np.ndarray:
    """Step 2: the frame's scan, cropped, down-sampled and moved into the body (IMU) frame.

    Parameters
    ----------
    frame : object with ``.scan`` (N, 4) float32 ``x, y, z, reflectance`` in the Velodyne frame
        (e.g. :class:`slamlib.kitti.Frame`), or an (N, 3)/(N, 4) array.
    T_body_velo : (4, 4), optional
        Velodyne pose in the body frame, ``p_body = T_body_velo p_velo`` (KITTI: ``inv(T_velo_imu)``);
        default identity.
    min_range, max_range : float
        Range crop in the Velodyne frame, metres (:func:`~slamlib.slam3d.preprocess.crop_range`).
    voxel_size : float
        Down-sampling voxel edge, metres (:func:`~slamlib.slam3d.preprocess.voxel_downsample`; 0 = off).

    Returns
    -------
    (M, 3) float32 points in the body frame.
    """
    scan = frame.scan if hasattr(frame, "scan") else frame
    scan = np.asarray(scan)
    if scan.ndim != 2 or scan.shape[1] not in (3, 4):
        raise ValueError(f"scan must have shape (N, 3) or (N, 4), got {scan.shape}")
    pts = voxel_downsample(crop_range(scan[:, :3], min_range, max_range), voxel_size)
    pts = np.asarray(pts, dtype=np.float32)
    if T_body_velo is not None:
        T = np.asarray(T_body_velo, dtype=np.float64)
        pts = (pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    return np.ascontiguousarray(pts)


def read_imu(frame) -> tuple[np.ndarray, np.ndarray]:
    """Step 3: body-frame velocity ``(vf, vl, vu)`` m/s and angular rate ``(wf, wl, wu)`` rad/s, each (3,)."""
    return (np.asarray(frame.velocity, dtype=np.float64).reshape(3),
            np.asarray(frame.angular_rate, dtype=np.float64).reshape(3))


def read_timing(frame) -> float:
    """Step 4: ``dt`` seconds since the previous frame (0 for the first; KITTI's ~0.1 s varies by a few ms)."""
    dt = float(frame.dt)
    if not np.isfinite(dt) or dt < 0:
        raise ValueError(f"frame dt must be finite and >= 0, got {dt}")
    return dt


# ------------------------------------------------------------------------------------------------ step 5
def motion_increment(v_prev, w_prev, v_cur, w_cur, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame motion over ``dt`` from two IMU samples: ``(rpy_delta (3,) rad, trans_delta (3,) m)``.

    The midpoint-twist SE(3) increment of :func:`slamlib.odometry.imu_increment` -- the same one dead reckoning
    uses -- so that ``T_new = T_old @ make_pose(rpy_to_matrix(rpy_delta), trans_delta)``.
    """
    rpy, trans = imu_increment(v_prev, w_prev, v_cur, w_cur, dt)
    return np.asarray(rpy, dtype=np.float64).reshape(3), np.asarray(trans, dtype=np.float64).reshape(3)


def _kernel_translation(rpy_delta, trans_delta) -> np.ndarray:
    """The ``trans_delta`` argument for the backends' ``move_particles`` that applies the body increment exactly.

    The backends compute ``t_new = t_i + R_i dR (trans_delta + sigma_t n_i)`` (CONTRIBUTING.md): the translation
    is expressed *after* the rotation increment. The SE(3) composition ``T_i [dR, dp]`` (what dead reckoning
    does) needs ``t_i + R_i dp``, so the pipeline passes ``dR^T dp``: then
    ``t_new = t_i + R_i dp + R_i dR sigma_t n_i``, exactly step 5 followed by step 6.
    """
    return rpy_to_matrix(np.asarray(rpy_delta, dtype=np.float64)).T @ np.asarray(trans_delta, dtype=np.float64)


def move_particles(R, t, rpy_delta, trans_delta, noise, sigma, backend) -> tuple[np.ndarray, np.ndarray]:
    """Steps 5 + 6 fused (one backend call): ``T_i <- T_i [dR, dp] [N_i, sigma[:3] * n_i[:3]]``.

    ``dR = rpy_to_matrix(rpy_delta)``, ``dp = trans_delta`` (body increment from :func:`motion_increment`),
    ``N_i = rpy_to_matrix(sigma[3:] * noise[i, 3:])``, ``noise (P, 6)`` standard normal. Equals
    :func:`offset_by_motion` then :func:`perturb_with_noise` with the same ``noise``.
    """
    return backend.move_particles(R, t, rpy_delta, _kernel_translation(rpy_delta, trans_delta), noise,
                                  np.asarray(sigma, dtype=np.float64))


def offset_by_motion(R, t, rpy_delta, trans_delta, backend) -> tuple[np.ndarray, np.ndarray]:
    """Step 5: move every particle by the body-frame increment: ``R_i <- R_i dR``, ``t_i <- t_i + R_i dp``.

    ``dR = rpy_to_matrix(rpy_delta)``, ``dp = trans_delta`` (see :func:`motion_increment`): the SE(3) product
    ``T_i [dR, dp]``, the same increment as dead reckoning. Implemented as :func:`move_particles` with zero
    noise, so step 5 then step 6 equals the fused call.
    """
    P = len(R)
    return move_particles(R, t, rpy_delta, trans_delta, np.zeros((P, 6)), np.zeros(6), backend)


def motion_noise_sigma(trans_delta, dt: float, sigma_xyz_per_m=(0.02, 0.02, 0.01), sigma_xyz_per_s=(0.05, 0.05, 0.05),
                       sigma_rpy_per_m=(0.0005, 0.0005, 0.002), sigma_rpy_per_s=(0.002, 0.002, 0.005)) -> np.ndarray:
    """Standard deviations ``(6,)`` of step 6's noise for one frame: translation x, y, z (m), roll, pitch, yaw (rad).

    ``sigma_xyz = sigma_xyz_per_m * |dp| + sigma_xyz_per_s * dt`` and
    ``sigma_rpy = sigma_rpy_per_m * |dp| + sigma_rpy_per_s * dt``: odometry errors grow with the distance
    travelled (speed scale errors, slip) and with time (biases, integration), as the usual odometry motion
    model's ``alpha`` parameters (Thrun et al. 2005, table 5.5). ``|dp|`` is the length of ``trans_delta`` (m).
    Per-axis in the body frame (x forward, y left, z up).
    """
    d = float(np.linalg.norm(trans_delta))
    dt = float(dt)
    s = np.empty(6)
    s[:3] = np.asarray(sigma_xyz_per_m, dtype=np.float64) * d + np.asarray(sigma_xyz_per_s, dtype=np.float64) * dt
    s[3:] = np.asarray(sigma_rpy_per_m, dtype=np.float64) * d + np.asarray(sigma_rpy_per_s, dtype=np.float64) * dt
    return s


# ------------------------------------------------------------------------------------------------ step 6
def perturb_with_noise(R, t, sigma, rng: np.random.Generator, backend, noise=None) -> tuple[np.ndarray, np.ndarray]:
    """Step 6: ``T_i <- T_i [N_i, sigma[:3] * n_i[:3]]``, ``N_i = rpy_to_matrix(sigma[3:] * n_i[3:])``.

    ``n_i ~ N(0, I_6)`` drawn from ``rng`` as a ``(P, 6)`` array (translation x, y, z then roll, pitch, yaw), or
    passed in as ``noise``. The noise acts in each particle's body frame (backend ``move_particles`` with zero
    motion). Returns the new ``(R, t)``.
    """
    P = len(R)
    if noise is None:
        noise = rng.standard_normal((P, 6))
    return backend.move_particles(R, t, np.zeros(3), np.zeros(3), noise, np.asarray(sigma, dtype=np.float64))


# ------------------------------------------------------------------------------------------------ step 7
def transform_scan(R, t, points, backend) -> np.ndarray:
    """Step 7: body-frame ``points (N, 3)`` into the world with one pose ``(R (3,3), t (3,))``: ``R p + t``.

    Returns (N, 3) float32 (backend ``transform_points``). Scoring (step 8) fuses this for all particles.
    """
    return backend.transform_points(make_pose(R, t), np.ascontiguousarray(points, dtype=np.float32))


# ------------------------------------------------------------------------------------------------ step 8
def score_particles(R, t, points, world_map, backend) -> np.ndarray:
    """Step 8 (fused with 7): log-likelihood score ``(P,)`` of each particle's pose for the body-frame scan.

    ``score_i = sum_j term(R_i p_j + t_i)`` with the map's robust per-point term (truncated NDT Mahalanobis
    distance for the voxel map, truncated nearest-neighbour distance for the BVH map; see
    :mod:`slamlib.maps.base`). Higher is better; the maximum is 0. ``points`` is the scoring sample (N, 3)
    float32, ``world_map`` the :class:`slamlib.maps.Map3D` built so far.
    """
    return backend.score_particles(R, t, np.ascontiguousarray(points, dtype=np.float32), world_map.lookup())


def normalise_log_weights(log_w) -> np.ndarray:
    """Log-weights shifted so that ``logsumexp(log_w) = 0`` (``exp`` then sums to 1); stable for any scale."""
    log_w = np.asarray(log_w, dtype=np.float64)
    m = np.max(log_w)
    return log_w - (m + np.log(np.sum(np.exp(log_w - m))))


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


def pick_best_particle(log_w, R, t, mode: str = "best", radius: float = 0.5) -> tuple[np.ndarray, int]:
    """Step 9: the pose estimate of this frame and the index of the highest-weight particle.

    ``mode="best"``: the maximum-weight particle's pose. ``mode="mean"``: the weighted mean
    (:func:`weighted_mean_pose`) of the particles within ``radius`` metres of the best one -- a local mean that
    averages out the sampling noise of the cloud without blending separate modes.

    Returns ``(T_world_body (4, 4), best_index)``.
    """
    log_w = np.asarray(log_w, dtype=np.float64)
    i = int(np.argmax(log_w))
    if mode == "best":
        return make_pose(R[i], t[i]), i
    if mode != "mean":
        raise ValueError(f"mode must be 'best' or 'mean', got {mode!r}")
    near = np.sum((t - t[i]) ** 2, axis=1) <= radius**2
    w = np.exp(log_w[near] - log_w[i])
    return weighted_mean_pose(R[near], t[near], w), i


# ------------------------------------------------------------------------------------------------ step 10
def merge_scan(world_map, T_world_body, points, backend):
    """Step 10: add the body-frame scan ``points (N, 3)`` moved by ``T_world_body`` (4, 4) into ``world_map``.

    Merges the whole down-sampled scan (not only the scoring sample). Returns the map (changed in place).
    """
    T = np.asarray(T_world_body, dtype=np.float64)
    world_map.merge(transform_scan(T[:3, :3], T[:3, 3], points, backend))
    return world_map


# ------------------------------------------------------------------------------------------------ step 11
def resample_particles(R, t, log_w, rng: np.random.Generator, backend, ess_fraction: float = 1.0):
    """Step 11: systematic resampling by weight when ``ESS < ess_fraction * P``.

    ``ESS = 1 / sum w_i^2`` (Kong, Liu & Wong 1994) of the normalised weights ``w = exp(log_w)``.
    ``ess_fraction = 1.0`` resamples at every frame (unless all weights are equal), ``0.5`` only when half
    the particles carry the weight. Resampling draws one offset ``u0 ~ U[0, 1)`` from ``rng`` and calls the
    backend's ``systematic_resample`` (Kitagawa 1996): every particle is copied ``floor(P w_i)`` or
    ``ceil(P w_i)`` times; the weights are then uniform.

    Returns ``(R, t, log_w, resampled: bool)``; ``P`` is unchanged.
    """
    log_w = normalise_log_weights(log_w)
    w = np.exp(log_w)
    P = len(w)
    ess = effective_sample_size(w)
    if not ess < ess_fraction * P:
        return R, t, log_w, False
    u0 = float(rng.random())
    idx = backend.systematic_resample(w, u0)
    return R[idx], t[idx], np.full(P, -np.log(P)), True
