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

from slamlib.geometry import (
    SMALL_ANGLE,
    make_pose,
    matrix_to_rpy,
    rpy_to_matrix,
    skew,
    so3_exp,
    so3_log,
)

__all__ = [
    "imu_increment",
    "imu_increments",
    "increment_matrix",
    "dead_reckon",
    "so3_left_jacobian",
    "twist_between",
    "GRAVITY",
]

#: Gravity (m/s^2) in the accelerometer model ``f_b = R^T (a + g e_z)`` of the generator and of :func:`gravity_up`.
GRAVITY = 9.81


def so3_left_jacobian(phi) -> np.ndarray:
    """Left Jacobian of SO(3), ``J(phi) (..., 3, 3)`` for rotation vectors ``phi (..., 3)`` (rad).

    ``J = I + (1 - cos a)/a^2 K + (a - sin a)/a^3 K^2`` with ``a = |phi|``, ``K = [phi]x``; Taylor series
    ``(1/2 - a^2/24, 1/6 - a^2/120)`` below ``a <`` :data:`~slamlib.geometry.SMALL_ANGLE` to avoid cancellation.
    """
    phi = np.asarray(phi, dtype=np.float64)
    a = np.linalg.norm(phi, axis=-1)
    small = a < SMALL_ANGLE
    a_safe = np.where(small, 1.0, a)
    c1 = np.where(small, 0.5 - a**2 / 24.0, (1.0 - np.cos(a_safe)) / a_safe**2)
    c2 = np.where(small, 1.0 / 6.0 - a**2 / 120.0, (a_safe - np.sin(a_safe)) / a_safe**3)
    K = skew(phi)
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
    rpy = matrix_to_rpy(so3_exp(phi))
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

    ``T[k] = T[k-1] @ increment(v[k-1], w[k-1], v[k], w[k], dts[k])`` (:func:`imu_increments`).

    Parameters
    ----------
    velocities, angular_rates : (N, 3) body-frame samples ``(vf, vl, vu)`` m/s and ``(wf, wl, wu)`` rad/s.
    dts : (N,) ``dts[k] = t_k - t_{k-1}`` (s); ``dts[0]`` is ignored.
    T0 : (4, 4) initial pose (default identity).
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
    phi = so3_log(T_rel[:3, :3])
    v = np.linalg.solve(so3_left_jacobian(phi), T_rel[:3, 3])
    return v / dt, phi / dt
