"""Trajectory accuracy: absolute trajectory error (ATE), relative pose error (RPE), and the KITTI odometry metric.

All functions take trajectories as ``(N, 4, 4)`` poses ``T_w_body`` (or, for ATE, ``(N, 3)`` positions)
with row ``i`` of the estimate and of the ground truth at the same time (associate timestamps first).
Metres and radians unless a name says otherwise.

* **ATE** (Sturm et al., IROS 2012): ``e_i = || p_gt,i - (s R p_est,i + t) ||`` with ``(R, t, s)`` the identity
  (``align=False``), the least-squares rigid SE(3) alignment (``align=True``/``"se3"``) or similarity Sim(3)
  (``"sim3"``, monocular) from Umeyama (1991) / Horn (1987); reported as RMSE ``sqrt(mean e_i^2)``.
* **RPE** (Sturm et al. 2012; Geiger et al. 2012): for pairs ``(i, j)`` a fixed number of frames or metres of
  ground-truth path apart, ``E = inv(inv(P_i) P_j) inv(G_i) G_j`` (``P`` estimate, ``G`` ground truth);
  translational error ``|trans(E)|`` and
  rotational error ``angle(E) = arccos((trace R_E - 1) / 2)``.
* **KITTI odometry** (Geiger et al., CVPR 2012, devkit ``evaluate_odometry.cpp``): segments of ground-truth
  path length ``L in {100, 200, ..., 800}`` m starting every 10th frame; the last frame is the first whose
  cumulative distance exceeds the start's by more than ``L`` (``lastFrameFromSegmentLength``);
  ``E = inv(inv(P_f) P_l) inv(G_f) G_l``; translational error ``|trans(E)| / L`` (reported in %) and
  rotational error ``angle(E) / L`` (reported in deg/m), averaged over all segments of all lengths. The
  translational error splits exactly into a vertical and a horizontal part (``|e|^2 = v^2 + h^2``): the error of the
  segment's end in the ground truth's world axes, ``e = R_G,f (t(inv(G_f) G_l) - t(inv(P_f) P_l))``, ``v`` its
  component along the world's up (height: a tilt the estimate took for level), ``h`` the rest.

References
----------
S. Umeyama, "Least-squares estimation of transformation parameters between two point patterns", IEEE PAMI 1991.
B. K. P. Horn, "Closed-form solution of absolute orientation using unit quaternions", JOSA A 1987.
J. Sturm et al., "A Benchmark for the Evaluation of RGB-D SLAM Systems", IROS 2012.
A. Geiger, P. Lenz, R. Urtasun, "Are we ready for Autonomous Driving? The KITTI Vision Benchmark Suite",
CVPR 2012; KITTI odometry devkit ``cpp/evaluate_odometry.cpp``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from slamlib.geometry import invert_pose

__all__ = [
    "KITTI_LENGTHS",
    "json_safe",
    "umeyama_alignment",
    "trajectory_distances",
    "rotation_angle",
    "ATEResult",
    "absolute_trajectory_error",
    "RPEResult",
    "relative_pose_error",
    "trajectory_metrics",
    "tilt_errors",
    "KittiOdometryResult",
    "kitti_odometry_error",
    "plane_residuals",
]

#: Segment lengths (metres) of the KITTI odometry benchmark.
KITTI_LENGTHS = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


def _as_poses(T, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] not in ((4, 4), (3, 4)):
        raise ValueError(
            f"{name} must be (N, 4, 4) or (N, 3, 4) poses, got shape {T.shape}"
        )
    if T.shape[1] == 3:
        full = np.zeros((T.shape[0], 4, 4))
        full[:, :3] = T
        full[:, 3, 3] = 1.0
        T = full
    return T


def _as_positions(x, name: str) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim == 3 and x.shape[1:] in ((4, 4), (3, 4)):
        return x[:, :3, 3]
    if x.ndim == 2 and x.shape[1] == 3:
        return x
    raise ValueError(
        f"{name} must be (N, 4, 4) poses or (N, 3) positions, got shape {x.shape}"
    )


def _same_length(a: np.ndarray, b: np.ndarray) -> None:
    if a.shape[0] != b.shape[0]:
        raise ValueError(
            f"estimate has {a.shape[0]} poses but ground truth has {b.shape[0]}; associate them first"
        )


def rotation_angle(R) -> np.ndarray:
    """Angle (rad) of rotation matrices ``(..., 3, 3)``: ``arccos(clip((trace R - 1) / 2, -1, 1))``."""
    R = np.asarray(R, dtype=np.float64)
    c = 0.5 * (np.trace(R, axis1=-2, axis2=-1) - 1.0)
    return np.arccos(np.clip(c, -1.0, 1.0))


def umeyama_alignment(
    src, dst, with_scale: bool = False
) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares ``(R, t, s)`` minimising ``sum_i |dst_i - (s R src_i + t)|^2`` (Umeyama 1991).

    With means ``mu_s, mu_d``, covariance ``C = (1/N) sum (dst_i - mu_d)(src_i - mu_s)^T = U D V^T`` and
    ``S = diag(1, 1, det(U V^T))``: ``R = U S V^T``, ``s = trace(D S) / sigma_s^2`` (``1`` without scale),
    ``t = mu_d - s R mu_s``. ``src, dst``: ``(N, 3)``, ``N >= 3`` non-collinear for a unique rotation
    (degenerate input still returns a valid rotation).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ValueError(
            f"src and dst must both be (N, 3), got {src.shape} and {dst.shape}"
        )
    if src.shape[0] == 0:
        raise ValueError("cannot align empty trajectories")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    C = xd.T @ xs / src.shape[0]
    U, D, Vt = np.linalg.svd(C)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    if with_scale:
        var_s = (xs**2).sum() / src.shape[0]
        s = float(np.trace(np.diag(D) @ S) / var_s) if var_s > 0 else 1.0
    else:
        s = 1.0
    t = mu_d - s * R @ mu_s
    return R, t, s


def trajectory_distances(poses) -> np.ndarray:
    """Cumulative path length (metres) along ``(N, 4, 4)`` poses or ``(N, 3)`` positions: ``d_0 = 0``,
    ``d_i = d_{i-1} + |p_i - p_{i-1}|`` (devkit ``trajectoryDistances``)."""
    p = _as_positions(poses, "poses")
    d = np.zeros(p.shape[0])
    if p.shape[0] > 1:
        d[1:] = np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))
    return d


# ----------------------------------------------------------------------------------------------- ATE
@dataclass(frozen=True)
class ATEResult:
    """Absolute trajectory error. ``errors (N,)`` per-pose position errors (m) after alignment;
    ``rmse, mean, median, max`` of them; alignment ``rotation (3, 3)``, ``translation (3,)``, ``scale``
    applied to the estimate (identity/zeros/1 without alignment)."""

    rmse: float
    mean: float
    median: float
    max: float
    errors: np.ndarray = field(repr=False)
    rotation: np.ndarray = field(repr=False)
    translation: np.ndarray = field(repr=False)
    scale: float = 1.0


def absolute_trajectory_error(
    estimate, ground_truth, align: bool | str = False
) -> ATEResult:
    """ATE of ``estimate`` vs ``ground_truth`` (both ``(N, 4, 4)`` poses or ``(N, 3)`` positions, row-aligned).

    ``align``: ``False``/``"none"`` compares positions as they are (both in the same world frame, e.g. the
    first pose); ``True``/``"se3"`` first applies the rigid Umeyama/Horn alignment of the estimate onto the
    ground truth; ``"sim3"`` also fits a scale (monocular). RMSE ``= sqrt(mean_i |p_gt,i - (s R p_est,i + t)|^2)``.
    """
    pe = _as_positions(estimate, "estimate")
    pg = _as_positions(ground_truth, "ground_truth")
    _same_length(pe, pg)
    if pe.shape[0] == 0:
        raise ValueError("empty trajectories")
    mode = (
        {False: "none", True: "se3"}.get(align, align)
        if isinstance(align, bool)
        else str(align).lower()
    )
    if mode == "none":
        R, t, s = np.eye(3), np.zeros(3), 1.0
    elif mode in ("se3", "sim3"):
        R, t, s = umeyama_alignment(pe, pg, with_scale=(mode == "sim3"))
    else:
        raise ValueError(
            f"align must be False, True, 'none', 'se3' or 'sim3', got {align!r}"
        )
    e = np.linalg.norm(pg - (s * pe @ R.T + t), axis=1)
    return ATEResult(
        rmse=float(np.sqrt(np.mean(e**2))),
        mean=float(e.mean()),
        median=float(np.median(e)),
        max=float(e.max()),
        errors=e,
        rotation=R,
        translation=t,
        scale=float(s),
    )


# ----------------------------------------------------------------------------------------------- RPE
@dataclass(frozen=True)
class RPEResult:
    """Relative pose error over pairs ``(first (M,), last (M,))``: ``trans_errors (M,)`` metres,
    ``rot_errors (M,)`` radians; ``trans_rmse``, ``rot_rmse`` (rad), ``trans_mean``, ``rot_mean``."""

    trans_rmse: float
    rot_rmse: float
    trans_mean: float
    rot_mean: float
    trans_errors: np.ndarray = field(repr=False)
    rot_errors: np.ndarray = field(repr=False)
    first: np.ndarray = field(repr=False)
    last: np.ndarray = field(repr=False)


def _segment_motions(est, gt, first, last, rigid_inverse: bool = False):
    """The motions ``(inv(P_f) P_l, inv(G_f) G_l)`` (M, 4, 4) each of the estimate and the ground truth, and the
    inverse they were taken with: general 4x4 inverses (the devkit's ``Matrix::inv``) or, with ``rigid_inverse``,
    ``[R^T, -R^T t]``; they differ only when the files' rotations are not exactly orthonormal."""
    inv = invert_pose if rigid_inverse else np.linalg.inv
    return inv(est[first]) @ est[last], inv(gt[first]) @ gt[last], inv


def _relative_errors(est, gt, first, last, rigid_inverse: bool = False):
    """Error poses ``E = inv(inv(P_f) P_l) @ inv(G_f) G_l`` (M, 4, 4) (:func:`_segment_motions`)."""
    d_est, d_gt, inv = _segment_motions(est, gt, first, last, rigid_inverse)
    return inv(d_est) @ d_gt


def relative_pose_error(
    estimate, ground_truth, delta: float = 1, unit: str = "frames"
) -> RPEResult:
    """RPE over pairs ``delta`` frames apart (``unit="frames"``, ``j = i + delta``) or ``delta`` metres of
    ground-truth path apart (``unit="m"``: ``j`` = first frame with ``d_j - d_i >= delta``).

    Raises ValueError if no pair fits in the trajectory.
    """
    est = _as_poses(estimate, "estimate")
    gt = _as_poses(ground_truth, "ground_truth")
    _same_length(est, gt)
    n = est.shape[0]
    if unit in ("frames", "f"):
        k = int(delta)
        if k < 1:
            raise ValueError("delta must be >= 1 frame")
        first = np.arange(max(n - k, 0))
        last = first + k
    elif unit in ("m", "meters", "metres"):
        if delta <= 0:
            raise ValueError("delta must be > 0 metres")
        d = trajectory_distances(gt)
        last = np.searchsorted(d, d + delta, side="left")
        first = np.flatnonzero(last < n)
        last = last[first]
    else:
        raise ValueError(f"unit must be 'frames' or 'm', got {unit!r}")
    if first.size == 0:
        raise ValueError(
            f"no pose pair {delta} {unit} apart in a trajectory of {n} poses"
        )
    E = _relative_errors(est, gt, first, last)
    te = np.linalg.norm(E[:, :3, 3], axis=1)
    re = rotation_angle(E[:, :3, :3])
    return RPEResult(
        trans_rmse=float(np.sqrt(np.mean(te**2))),
        rot_rmse=float(np.sqrt(np.mean(re**2))),
        trans_mean=float(te.mean()),
        rot_mean=float(re.mean()),
        trans_errors=te,
        rot_errors=re,
        first=first,
        last=last,
    )


# ----------------------------------------------------------------------------------------------- KITTI
@dataclass(frozen=True)
class KittiOdometryResult:
    """KITTI odometry metric.

    ``t_err_percent``: mean over all segments of ``|trans(E)| / L * 100``; ``r_err_deg_per_m``: mean of
    ``angle(E) / L`` in deg/m. ``per_length``: ``{L: (t_err_percent, r_err_deg_per_m, n_segments)}`` for each
    length with at least one segment. Segment arrays (M,): ``first``, ``last``, ``length`` (m), ``t_err``
    (fraction, m/m), ``r_err`` (rad/m), ``speed`` (m/s, assuming 10 Hz as the devkit). The translational error's
    parts (module docstring): ``t_err_vertical_percent`` and ``t_err_horizontal_percent`` the means of
    ``|v| / L`` and ``|h| / L`` in %, ``t_err_vertical`` per segment (fraction, signed: + the estimate ends too low).
    """

    t_err_percent: float
    r_err_deg_per_m: float
    n_segments: int
    per_length: dict = field(repr=False)
    first: np.ndarray = field(repr=False)
    last: np.ndarray = field(repr=False)
    length: np.ndarray = field(repr=False)
    t_err: np.ndarray = field(repr=False)
    r_err: np.ndarray = field(repr=False)
    speed: np.ndarray = field(repr=False)
    t_err_vertical_percent: float = float("nan")
    t_err_horizontal_percent: float = float("nan")
    t_err_vertical: np.ndarray = field(default=None, repr=False)


def kitti_odometry_error(
    estimate,
    ground_truth,
    lengths=KITTI_LENGTHS,
    step: int = 10,
    rigid_inverse: bool = False,
    up=(0.0, 0.0, 1.0),
) -> KittiOdometryResult:
    """KITTI odometry translational (%) and rotational (deg/m) error, as ``evaluate_odometry.cpp``.

    For each first frame ``f = 0, step, 2 step, ...`` and length ``L``: ``l`` = the first frame with
    ``d_l > d_f + L`` (``d`` = ground-truth cumulative distance; segments running past the end are
    skipped), ``E = inv(inv(P_f) P_l) @ inv(G_f) G_l``, ``t_err = |trans(E)| / L``,
    ``r_err = arccos(clip((trace R_E - 1)/2)) / L``. Averages are over all segments of all lengths. ``up`` (3,) is
    the world's up in the ground truth's world frame (its z axis by default; a KITTI odometry ground truth in camera
    axes has ``(0, -1, 0)``), for the vertical part of the translational error (module docstring).
    Vectorised: one ``searchsorted`` for all segment ends and batched 4x4 products (~10 ms for 4,541 poses).

    Precision note: the devkit computes in double except ``rotationError``/``trajectoryDistances`` (float32);
    this function uses float64 throughout. The translational error agrees with the devkit to 5 significant
    digits; the rotational error of a good estimate (~1e-2 rad per segment) is sensitive, in its 4th digit, to
    the rounding of the poses in the files: 9-decimal rotations are orthonormal only to ~1e-7, and general
    (``rigid_inverse=False``, the devkit's choice) and rigid (``True``) inverses then differ. On KITTI 00 with
    the shipped ORB-SLAM2 result: 0.6997 % for both; 0.0025333 deg/m (general; a C++ port of the devkit with
    its float32 steps gives 0.0025335) vs 0.0025356 deg/m (rigid); the published figure is 0.002535.

    Raises ValueError if the trajectory is shorter than the smallest length (no segment).
    """
    est = _as_poses(estimate, "estimate")
    gt = _as_poses(ground_truth, "ground_truth")
    _same_length(est, gt)
    n = gt.shape[0]
    d = trajectory_distances(gt)
    starts = np.arange(0, n, int(step))
    L = np.asarray(lengths, dtype=np.float64)
    first = np.repeat(starts, L.size)
    length = np.tile(L, starts.size)
    # first index with d > d_f + L
    last = np.searchsorted(d, d[first] + length, side="right")
    ok = last < n
    first, last, length = first[ok], last[ok], length[ok]
    if first.size == 0:
        raise ValueError(
            f"trajectory ({d[-1]:.1f} m) is shorter than the shortest segment ({L.min():g} m)"
        )
    d_est, d_gt, inv = _segment_motions(est, gt, first, last, rigid_inverse)
    E = inv(d_est) @ d_gt
    t_err = np.linalg.norm(E[:, :3, 3], axis=1) / length
    r_err = rotation_angle(E[:, :3, :3]) / length
    # |trans(E)| = |t_dG - t_dP|, that difference in the start's ground-truth body axes: turned into the world's
    diff = d_gt[:, :3, 3] - d_est[:, :3, 3]
    e_world = np.einsum("mij,mj->mi", gt[first, :3, :3], diff)
    up = np.asarray(up, dtype=np.float64) / np.linalg.norm(up)
    t_vertical = (e_world @ up) / length
    t_horizontal = np.sqrt(np.maximum(t_err**2 - t_vertical**2, 0.0))
    speed = length / (0.1 * (last - first + 1))
    per_length = {}
    for Lk in L:
        m = length == Lk
        if m.any():
            per_length[float(Lk)] = (
                float(t_err[m].mean() * 100.0),
                float(np.degrees(r_err[m].mean())),
                int(m.sum()),
            )
    return KittiOdometryResult(
        t_err_percent=float(t_err.mean() * 100.0),
        r_err_deg_per_m=float(np.degrees(r_err.mean())),
        n_segments=int(first.size),
        per_length=per_length,
        first=first,
        last=last,
        length=length,
        t_err=t_err,
        r_err=r_err,
        speed=speed,
        t_err_vertical_percent=float(np.abs(t_vertical).mean() * 100.0),
        t_err_horizontal_percent=float(t_horizontal.mean() * 100.0),
        t_err_vertical=t_vertical,
    )


def tilt_errors(estimate, ground_truth) -> np.ndarray:
    """How far each estimated pose's roll and pitch are off, yaw aside: ``(F,)`` radians, the angle between the
    world's up as the estimated and as the true body sees it, ``angle(R_est^T e_z, R_gt^T e_z)`` (both
    ``T_world_body (F, 4, 4)`` in the same world frame, z up). A yaw error leaves it 0; for small errors it is
    ``sqrt(d_roll^2 + d_pitch^2)``."""
    est, gt = _as_poses(estimate, "estimate"), _as_poses(ground_truth, "ground_truth")
    _same_length(est, gt)
    up_est, up_gt = est[:, 2, :3], gt[:, 2, :3]  # R^T e_z: the third row
    cos = np.einsum("ij,ij->i", up_est, up_gt)
    sin = np.linalg.norm(np.cross(up_est, up_gt), axis=1)
    return np.arctan2(sin, cos)


def trajectory_metrics(estimate, ground_truth) -> dict:
    """The summary ``slamlib run`` reports for one trajectory against ground truth (same frame, same start).

    ``ate_rmse_m``, ``ate_max_m``, ``final_error_m`` (:func:`absolute_trajectory_error`, no alignment);
    ``tilt_err_max_deg``, the largest roll-and-pitch error of a frame (:func:`tilt_errors`); with more than 10
    poses ``rpe_10f_trans_rmse_m`` and ``rpe_10f_rot_rmse_deg`` (:func:`relative_pose_error`
    over 10 frames); for paths longer than 100 m the KITTI metric ``kitti_t_err_percent``,
    ``kitti_r_err_deg_per_m``, ``kitti_segments`` and the translational error's vertical and horizontal parts
    ``kitti_t_err_vertical_percent``, ``kitti_t_err_horizontal_percent`` (:func:`kitti_odometry_error`).
    """
    ate = absolute_trajectory_error(estimate, ground_truth)
    out = {
        "ate_rmse_m": ate.rmse,
        "ate_max_m": ate.max,
        "final_error_m": float(ate.errors[-1]),
        "tilt_err_max_deg": float(np.degrees(tilt_errors(estimate, ground_truth).max())),
    }
    if len(ate.errors) > 10:
        rpe = relative_pose_error(estimate, ground_truth, delta=10)
        out.update(
            rpe_10f_trans_rmse_m=rpe.trans_rmse,
            rpe_10f_rot_rmse_deg=float(np.degrees(rpe.rot_rmse)),
        )
    if trajectory_distances(ground_truth)[-1] > 100.0:
        k = kitti_odometry_error(estimate, ground_truth)
        out.update(
            kitti_t_err_percent=k.t_err_percent,
            kitti_r_err_deg_per_m=k.r_err_deg_per_m,
            kitti_segments=k.n_segments,
            kitti_t_err_vertical_percent=k.t_err_vertical_percent,
            kitti_t_err_horizontal_percent=k.t_err_horizontal_percent,
        )
    return out


def json_safe(obj):
    """A copy of ``obj`` (nested dicts, lists, tuples, numbers) with every non-finite float (NaN, +-inf) replaced by
    ``None``, and numpy scalars and arrays turned into Python numbers and lists, so that
    ``json.dumps(json_safe(obj), allow_nan=False)`` always succeeds (JSON has no NaN: it is written ``null``)."""
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    return obj


def plane_residuals(points, reference, k: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """How sharp a point cloud is against a reference one: each of ``points (N, 3)``'s distance (m) to the plane
    through its ``k`` nearest ``reference (M, 3)`` points (least squares: their centroid and the eigenvector of the
    smallest eigenvalue of their scatter matrix), and that plane's unit normal. Returns ``(distances (N,), normals
    (N, 3))``. The point-to-plane residual of ICP (Chen and Medioni, 1992), for a map's sharpness (a swept scan's
    walls lie off the planes of one taken from one instant)."""
    from scipy.spatial import cKDTree

    ref = np.asarray(reference, dtype=np.float64)
    q = np.asarray(points, dtype=np.float64)
    _, idx = cKDTree(ref).query(q, k)
    nb = ref[idx]
    centre = nb.mean(axis=1)
    d = nb - centre[:, None]
    normal = np.linalg.eigh(np.einsum("nki,nkj->nij", d, d))[1][:, :, 0]
    return np.abs(np.einsum("ni,ni->n", q - centre, normal)), normal
