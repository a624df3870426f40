"""IMU motion increments and dead reckoning (step 5's motion model, shared by dead reckoning and 3D SLAM).

The vehicle state between two OXTS packets ``k-1`` and ``k`` is described by body-frame (IMU frame: x
forward, y left, z up) linear velocities ``v = (vf, vl, vu)`` (m/s) and angular rates ``w = (wf, wl, wu)``
(rad/s), sampled at both ends of the interval ``dt = t_k - t_{k-1}`` (s).

Model (second order, "midpoint twist"): over the interval the body moves with the constant twist given by
the mean of the two samples, ``w_bar = (w_prev + w_cur) / 2``, ``v_bar = (v_prev + v_cur) / 2``. The exact
solution of ``dT/dt = T [w_bar]^, T(0) = T_old`` over ``dt`` is the SE(3) exponential::

    phi = w_bar dt                                    (rotation vector, rad)
    dR  = Exp(phi)                                    (Rodrigues)
    dt_ = J(phi) v_bar dt,  J(phi) = I + (1 - cos|phi|)/|phi|^2 [phi]x + (|phi| - sin|phi|)/|phi|^3 [phi]x^2
    T_new = T_old @ [[dR, dt_], [0, 1]]

``J`` is the left Jacobian of SO(3); for small ``|phi|`` it is ``I + [phi]x / 2 + ...``, i.e. to second
order the translation is ``v_bar dt`` rotated by half the rotation (the midpoint rule). Because the twist
is integrated exactly, constant-velocity straight lines and constant-rate turns (circles, helices) are
reproduced exactly for any ``dt``; for smoothly varying ``v, w`` the local error is ``O(dt^3)``.

The increment is returned in the backend-interface convention of CONTRIBUTING.md: ``rpy_delta`` with
``rpy_to_matrix(rpy_delta) = dR`` (``R = Rz Ry Rx``, via :func:`slamlib.geometry.matrix_to_rpy`) and
``trans_delta = dt_`` in the old body frame, so that ``T_new = T_old @ make_pose(rpy_to_matrix(rpy_delta),
trans_delta)``, exactly what ``move_particles`` applies.

References: Barfoot, "State Estimation for Robotics" (2017), sec. 7.1.3 (SE(3) exponential, left Jacobian);
Sola et al., "A micro Lie theory for state estimation in robotics" (2018), eq. (174)-(176).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from slamlib.geometry import make_pose, matrix_to_rpy, rpy_to_matrix

__all__ = [
    "imu_increment",
    "imu_increments",
    "increment_matrix",
    "dead_reckon",
    "so3_left_jacobian",
    "twist_between",
    "gravity_up",
    "GRAVITY",
    "tilt_calibration_prior",
    "tilt_calibration_update",
    "tilt_calibration",
    "heading_bin",
    "balance_heading_bins",
    "tilt_calibration_bins",
    "tilt_calibration_add",
    "tilt_calibration_estimate",
]

#: Gravity (m/s^2) in the accelerometer model ``f_b = R^T (a + g e_z)`` of the generator and of :func:`gravity_up`.
GRAVITY = 9.81


def _skew(v: np.ndarray) -> np.ndarray:
    """``[v]x`` for ``v (..., 3)`` -> ``(..., 3, 3)``."""
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -v[..., 2], v[..., 1]
    K[..., 1, 0], K[..., 1, 2] = v[..., 2], -v[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -v[..., 1], v[..., 0]
    return K


def so3_left_jacobian(phi) -> np.ndarray:
    """Left Jacobian of SO(3), ``J(phi) (..., 3, 3)`` for rotation vectors ``phi (..., 3)`` (rad).

    ``J = I + (1 - cos a)/a^2 K + (a - sin a)/a^3 K^2`` with ``a = |phi|``, ``K = [phi]x``; Taylor series
    ``(1/2 - a^2/24, 1/6 - a^2/120)`` below ``a < 1e-4`` to avoid cancellation.
    """
    phi = np.asarray(phi, dtype=np.float64)
    a = np.linalg.norm(phi, axis=-1)
    small = a < 1e-4
    a_safe = np.where(small, 1.0, a)
    c1 = np.where(small, 0.5 - a**2 / 24.0, (1.0 - np.cos(a_safe)) / a_safe**2)
    c2 = np.where(small, 1.0 / 6.0 - a**2 / 120.0, (a_safe - np.sin(a_safe)) / a_safe**3)
    K = _skew(phi)
    return np.eye(3) + c1[..., None, None] * K + c2[..., None, None] * (K @ K)


def imu_increments(v_prev, w_prev, v_cur, w_cur, dt) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised :func:`imu_increment`: ``v_*, w_* (..., 3)``, ``dt (...)`` -> ``rpy_delta, trans_delta (..., 3)``."""
    v_bar = 0.5 * (
        np.asarray(v_prev, dtype=np.float64) + np.asarray(v_cur, dtype=np.float64)
    )
    w_bar = 0.5 * (
        np.asarray(w_prev, dtype=np.float64) + np.asarray(w_cur, dtype=np.float64)
    )
    dt = np.asarray(dt, dtype=np.float64)[..., None]
    phi = w_bar * dt
    dR = (
        Rotation.from_rotvec(phi.reshape(-1, 3))
        .as_matrix()
        .reshape(phi.shape[:-1] + (3, 3))
    )
    rpy = matrix_to_rpy(dR)
    trans = np.einsum("...ij,...j->...i", so3_left_jacobian(phi), v_bar * dt)
    return rpy, trans


def imu_increment(
    v_prev, w_prev, v_cur, w_cur, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Motion increment between two IMU samples (see the module docstring for the math).

    Parameters
    ----------
    v_prev, v_cur : (3,) body-frame velocities (m/s) at the start and end of the interval.
    w_prev, w_cur : (3,) body-frame angular rates (rad/s) at the start and end.
    dt : interval (s).

    Returns
    -------
    rpy_delta : (3,) roll, pitch, yaw (rad) of the rotation increment ``dR = Exp(w_bar dt)``.
    trans_delta : (3,) translation increment (m) in the old body frame.
        ``T_new = T_old @ make_pose(rpy_to_matrix(rpy_delta), trans_delta)``.
    """
    rpy, trans = imu_increments(v_prev, w_prev, v_cur, w_cur, dt)
    return rpy, trans


def increment_matrix(rpy_delta, trans_delta) -> np.ndarray:
    """``(..., 4, 4)`` pose ``[[rpy_to_matrix(rpy_delta), trans_delta], [0, 1]]``."""
    return make_pose(rpy_to_matrix(rpy_delta), trans_delta)


def dead_reckon(velocities, angular_rates, dts, T0=None) -> np.ndarray:
    """Integrate body-frame velocities and rates into poses ``T_w_imu (N, 4, 4)``.

    Parameters
    ----------
    velocities, angular_rates : (N, 3) body-frame samples ``(vf, vl, vu)`` m/s and ``(wf, wl, wu)`` rad/s.
    dts : (N,) ``dts[k] = t_k - t_{k-1}`` (s); ``dts[0]`` is ignored.
    T0 : (4, 4) initial pose (default identity).

    ``T[k] = T[k-1] @ increment(v[k-1], w[k-1], v[k], w[k], dts[k])`` (:func:`imu_increments`).
    """
    v = np.asarray(velocities, dtype=np.float64)
    w = np.asarray(angular_rates, dtype=np.float64)
    dts = np.asarray(dts, dtype=np.float64)
    n = len(v)
    T = np.empty((n, 4, 4))
    T[0] = np.eye(4) if T0 is None else np.asarray(T0, dtype=np.float64)
    if n == 1:
        return T
    rpy, trans = imu_increments(v[:-1], w[:-1], v[1:], w[1:], dts[1:])
    inc = increment_matrix(rpy, trans)
    for k in range(1, n):
        T[k] = T[k - 1] @ inc[k - 1]
    return T


def twist_between(T_a, T_b, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The constant body twist ``(v (3,) m/s, w (3,) rad/s)`` that moves pose ``T_a`` to ``T_b`` in ``dt`` seconds.

    The inverse of the module's motion model with equal samples: with ``T_rel = inv(T_a) T_b = [R, p]``,
    ``phi = Log(R)``, ``w = phi / dt`` and ``v = J(phi)^-1 p / dt`` (:func:`so3_left_jacobian`), so that
    ``imu_increment(v, w, v, w, dt)`` gives back exactly ``T_rel``. This is the constant-velocity model of
    LIDAR-only odometry (KISS-ICP, Vizzo et al., RA-L 2023, sec. III-A): the last estimated motion, held.
    ``dt <= 0`` (or non-finite) gives zero twist: no motion is known yet.
    """
    dt = float(dt)
    if not (np.isfinite(dt) and dt > 0):
        return np.zeros(3), np.zeros(3)
    T_rel = np.linalg.solve(
        np.asarray(T_a, dtype=np.float64), np.asarray(T_b, dtype=np.float64)
    )
    phi = Rotation.from_matrix(T_rel[:3, :3]).as_rotvec()
    v = np.linalg.solve(so3_left_jacobian(phi), T_rel[:3, 3])
    return v / dt, phi / dt


def gravity_up(rotations, specific_force, velocity, dts) -> np.ndarray | None:
    """Which way is up, in the body frame of the last of ``K + 1`` frames, from the accelerometer over them.

    An accelerometer measures the specific force ``f_b = R^T (a - g_w)`` with ``g_w = -g e_z``: the vehicle's own
    acceleration ``a`` plus gravity, in the body frame. One sample cannot tell the two apart (braking looks like
    pitching forward), but over a window they separate: integrating ``a = R f_b - g e_z`` from ``t_0`` to ``t_K``,

        v_w(t_K) - v_w(t_0) = int R f_b dt - g e_z (t_K - t_0)
        =>  g (t_K - t_0) e_z = int R f_b dt - (R_K v_K - R_0 v_0),

    with the body velocities ``v`` turned into the world by the same rotations. The integral is the trapezoid rule
    over the samples. Only the rotations *relative* to the last one enter (the result is ``R_K^T e_z``, normalised),
    so a filter may pass its own estimates, whose absolute tilt drifts but whose rotation over a second or two is
    accurate: the answer is the absolute up direction it can hold its roll and pitch to. Errors: a velocity error
    ``dv`` at either end tilts it by about ``dv / (g T)`` (0.05 m/s over 2 s: 2.5 mrad), an accelerometer bias ``b``
    by ``b / g`` (0.03 m/s^2: 3 mrad), for ever: a constant bias is indistinguishable from a tilt.

    Parameters
    ----------
    rotations : (K + 1, 3, 3) body-to-world rotations ``R_k`` (any common world frame).
    specific_force : (K + 1, 3) accelerometer samples ``f_b`` (m/s^2, body frame, gravity included: KITTI OXTS
        ``ax, ay, az``; ``+g`` on z when level and still).
    velocity : (K + 1, 3) body velocities ``v`` (m/s; OXTS ``vf, vl, vu``).
    dts : (K + 1,) ``dts[k] = t_k - t_{k-1}`` (s); ``dts[0]`` is ignored.

    Returns the unit vector ``R_K^T e_z`` (3,) as measured, or None when the window spans no time (``K = 0``).
    """
    R = np.asarray(rotations, dtype=np.float64)
    f_w = np.einsum("kij,kj->ki", R, np.asarray(specific_force, dtype=np.float64))
    v_w = np.einsum("kij,kj->ki", R, np.asarray(velocity, dtype=np.float64))
    dts = np.asarray(dts, dtype=np.float64)[1:]
    if len(dts) == 0 or not dts.sum() > 0:
        return None
    up_w = np.sum(0.5 * (f_w[:-1] + f_w[1:]) * dts[:, None], axis=0) - (v_w[-1] - v_w[0])
    up_b = R[-1].T @ up_w
    return up_b / np.linalg.norm(up_b)


#: Unknowns of the tilt calibration, in order: the world's up ``g_w = normalise(e_z + (a, b, 0))`` (world x, y
#: components, rad) and the accelerometer's bias as an angle ``beta = (c, d, 0)`` (body x, y components: ``b / g``).
TILT_CALIBRATION_UNKNOWNS = ("world_up_x", "world_up_y", "bias_x", "bias_y")


def tilt_calibration_prior(
    sigma_world: float, sigma_bias: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tilt calibration's prior in information form ``(Lambda (4, 4), eta (4,), free (4,) bool)``: zero mean,
    standard deviations ``sigma_world`` for the world's up (rad: how far from level the first body pose, which
    defines the world, may stand) and ``sigma_bias`` for the accelerometer's bias (rad, ``b / g``). A sigma of 0
    holds that pair at 0 (``free`` False: :func:`tilt_calibration` leaves it out); unknowns in
    :data:`TILT_CALIBRATION_UNKNOWNS`."""
    sig = np.repeat(np.array([sigma_world, sigma_bias], dtype=np.float64), 2)
    if not np.all(np.isfinite(sig)) or np.any(sig < 0):
        raise ValueError(
            f"need finite sigma_world, sigma_bias >= 0, got {sigma_world}, {sigma_bias}"
        )
    free = sig > 0
    info = np.zeros(4)
    info[free] = 1.0 / sig[free] ** 2
    return np.diag(info), np.zeros(4), free


def tilt_calibration_update(
    info, eta, R, up, weight: float
) -> tuple[np.ndarray, np.ndarray]:
    """Add one frame to the tilt calibration (recursive least squares, information form; returns new arrays).

    A measured up ``u`` (body frame, :func:`gravity_up`) of a body with rotation ``R`` (body to world) is, to
    first order in the small unknowns,

        u - R^T e_z = a R^T e_x + b R^T e_y + c e_x + d e_y + noise,    i.e.  y = H x + noise,

    the world's up off the world's z by ``(a, b)`` and the accelerometer's bias ``(c, d) = b_perp / g`` (a bias
    ``b`` adds ``b / g`` to the measured up). The world part turns with the body, the bias does not: one heading
    cannot tell them apart, a turn can (as in an IMU's in-motion alignment; Groves, "Principles of GNSS,
    Inertial, and Multisensor Integrated Navigation Systems", 2nd ed. 2013, ch. 14). ``Lambda += w H^T H``,
    ``eta += w H^T y`` with ``weight w = 1 / sigma_u^2`` times the frame's share of an independent sample.
    """
    R = np.asarray(R, dtype=np.float64)
    H = np.column_stack(
        [R[0], R[1], np.eye(3)[:, 0], np.eye(3)[:, 1]]
    )  # rows of R: R^T e_x, R^T e_y
    y = np.asarray(up, dtype=np.float64) - R[2]
    return info + weight * H.T @ H, eta + weight * H.T @ y


def tilt_calibration(info, eta, free) -> tuple[np.ndarray, np.ndarray]:
    """The current estimate from ``(Lambda, eta)``: the world's up ``g_w`` (3,) unit vector, world frame, and the
    accelerometer's bias ``beta`` (3,) as an angle in the body frame (z component 0), so that a body ``R``
    measures ``u = R^T g_w + beta``. Unknowns not ``free`` (prior sigma 0) stay 0."""
    free = np.asarray(free, dtype=bool)
    x = np.zeros(4)
    if free.any():
        x[free] = np.linalg.solve(info[np.ix_(free, free)], eta[free])
    world_up = np.array([x[0], x[1], 1.0])
    return world_up / np.linalg.norm(world_up), np.array([x[2], x[3], 0.0])


def heading_bin(R, bins: int) -> int:
    """Which of ``bins`` equal sectors of heading (yaw ``atan2(R[1, 0], R[0, 0])``, from ``-pi``) the body of
    rotation ``R`` faces."""
    yaw = np.arctan2(R[1][0], R[0][0])
    return int(np.floor((yaw + np.pi) / (2 * np.pi) * bins)) % bins


def balance_heading_bins(infos, etas, weights) -> tuple[np.ndarray, np.ndarray]:
    """The data part ``(Lambda (4, 4), eta (4,))`` of the tilt calibration with every heading sector weighing alike.

    ``infos (B, 4, 4)``, ``etas (B,  4)`` hold each sector's own sums of :func:`tilt_calibration_update` (from zero)
    and ``weights (B,)`` its total weight. Each sector that has frames is scaled to ``W / n`` (``W`` the total
    weight, ``n`` the sectors with frames), so the data weigh as much as before in all, but a long straight counts
    no more than a short stretch the other way. Why: the fit's residual holds the filter's own tilt error, and a tilt
    of the *map* is fixed in the world, so in the body frame it turns with the heading. Over headings spread evenly
    it cancels, a bias does not; weighed by time, the headings of the longest straights win and their share of the
    map's tilt is taken for a bias. Add the prior (:func:`tilt_calibration_prior`) and pass the sums to
    :func:`tilt_calibration`.
    """
    weights = np.asarray(weights, dtype=np.float64)
    used = weights > 0
    if not used.any():
        return np.zeros((4, 4)), np.zeros(4)
    scale = np.zeros_like(weights)
    scale[used] = weights.sum() / (used.sum() * weights[used])
    return np.einsum("b,bij->ij", scale, infos), scale @ np.asarray(
        etas, dtype=np.float64
    )


def tilt_calibration_bins(bins: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Empty per-sector sums ``(Lambdas (B, 4, 4), etas (B, 4), weights (B,))`` for :func:`tilt_calibration_add`."""
    return np.zeros((bins, 4, 4)), np.zeros((bins, 4)), np.zeros(bins)


def tilt_calibration_add(sums, R, up, weight: float) -> None:
    """Add one frame (rotation ``R``, measured ``up``, ``weight``) to its heading sector of ``sums``
    (:func:`tilt_calibration_bins`), in place: :func:`tilt_calibration_update` on that sector's sums."""
    infos, etas, weights = sums
    b = heading_bin(R, len(weights))
    infos[b], etas[b] = tilt_calibration_update(infos[b], etas[b], R, up, weight)
    weights[b] += weight


def tilt_calibration_estimate(prior, sums) -> tuple[np.ndarray, np.ndarray]:
    """The world's up and the bias (:func:`tilt_calibration`) from the ``prior`` ``(Lambda, eta, free)``
    (:func:`tilt_calibration_prior`) and the sectors' ``sums``, weighed alike (:func:`balance_heading_bins`)."""
    info0, eta0, free = prior
    info, eta = balance_heading_bins(*sums)
    return tilt_calibration(info0 + info, eta0 + eta, free)
