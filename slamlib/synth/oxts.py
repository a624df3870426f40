"""Synthetic OXTS packets (all 30 KITTI fields) from a route's true motion, with IMU-like noise.

Pose fields (exact ground truth): the IMU pose ``T_w_imu(t)`` is placed in a local east-north-up frame,
``T_enu_imu = Rz(enu_yaw0) T_w_imu`` with origin at ``(lat0, lon0, alt0)``, then converted to latitude /
longitude by inverting pykitti's Mercator projection (``pykitti.utils.pose_from_oxts_packet``, earth radius
``er = 6378137`` m, scale ``s = cos(lat0)`` from the first packet)::

    mx = s * er * lon * pi / 180                 ->  lon = mx * 180 / (pi * s * er)
    my = s * er * ln(tan((90 + lat) * pi / 360)) ->  lat = 360 / pi * atan(exp(my / (s * er))) - 90
    (mx, my, alt) = (mx0 + x, my0 + y, alt0 + z)

and ``roll, pitch, yaw = matrix_to_rpy(R_enu_imu)`` (``R = Rz Ry Rx``), so pykitti recovers ``T_w_imu`` to
floating-point precision (sub-millimetre; latitude is written with ``repr`` precision ~1e-15 deg). ``vn, ve``
are the true ENU velocities.

IMU-like fields (corrupted): ``(vf, vl, vu)`` body velocity, ``(wf, wl, wu)`` body angular rate and
``(af, al, au)`` body specific force (gravity included, ``au ~ +9.81`` when level). Measurement model, per
axis, for a true value ``x`` and white standard normal ``n_k``::

    x_meas = (1 + scale) * x + bias + sigma * n_k

with the parameters of :class:`ImuNoise`. The velocity and gyro biases may also wander (``vel_bias_walk``,
``gyro_bias_walk``, zero by default): ``bias(t) = bias + q W(t - t_0)``, ``W`` a standard Wiener process per axis
(a *bias random walk*, the "rate random walk" of IEEE Std 952-1997 for gyros), sampled at the packet times as
``b_k = b_{k-1} + q sqrt(t_k - t_{k-1}) n_k``; both gyro field groups (``wx..wz``, ``wf..wu``) measure the same
wandering bias. Its standard deviation after ``T`` seconds is ``q sqrt(T)``.

slamlib reads ``f, l, u`` as *body* axes (KITTI documents them as axes of the level tangent plane; the difference is
the few-degree roll/pitch); ``x, y, z`` fields (``ax..az``, ``wx..wz``) get the same body-frame quantity with
independent noise draws.

Status fields: ``pos_accuracy`` 0.05 m, ``vel_accuracy`` 0.02 m/s, ``navstat 4``, ``numsats`` 8-11,
``posmode velmode orimode = 6`` (RTK integer, as in good KITTI drives).

Reference: Geiger et al., "Vision meets Robotics: The KITTI Dataset", IJRR 2013 (OXTS RT3003 fields);
pykitti 0.3.1 ``utils.pose_from_oxts_packet``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields

import numpy as np

from slamlib.geometry import matrix_to_rpy, rot_z
from slamlib.kitti.oxts import EARTH_RADIUS_M as EARTH_RADIUS
from slamlib.synth.routes import Route

__all__ = [
    "ImuNoise",
    "ZERO_NOISE",
    "WANDERING_BIASES",
    "bias_walk",
    "EARTH_RADIUS",
    "KARLSRUHE",
    "oxts_packets",
    "latlon_from_mercator",
]

#: (lat, lon, alt) of the first packet of 2011_09_26_drive_0001 (Karlsruhe).
KARLSRUHE = (49.015003823272, 8.4342971002335, 116.43032836914)


@dataclass(frozen=True)
class ImuNoise:
    """IMU noise of the OXTS velocity / rate / acceleration fields (body axes f, l, u).

    ``x_meas = (1 + *_scale) * x + *_bias + *_sigma * n``, ``n ~ N(0, 1)`` white per packet and axis.
    The defaults (1.5 % speed scale error, 0.03 m/s lateral bias, 3 mrad/s yaw-rate bias, white noise)
    make dead reckoning over a few hundred metres drift by several percent of the distance, like a low-grade
    wheel-odometry + MEMS gyro; the real OXTS RT3003 is far better.

    The biases may also wander as random walks (``*_bias_walk``, 0 here; :data:`WANDERING_BIASES` turns them
    on): the bias then starts at ``*_bias`` and after ``T`` seconds is off from it by ``N(0, (q^2 T))`` per axis.

    Attributes (units): ``vel_sigma`` m/s, ``vel_bias (3,)`` m/s, ``vel_scale (3,)`` (fraction),
    ``gyro_sigma`` rad/s, ``gyro_bias (3,)`` rad/s, ``acc_sigma`` m/s^2, ``acc_bias (3,)`` m/s^2,
    ``vel_bias_walk`` m/s/sqrt(s), ``gyro_bias_walk`` rad/s/sqrt(s).
    """

    vel_sigma: float = 0.05
    vel_bias: tuple = (0.0, 0.03, 0.0)
    vel_scale: tuple = (0.015, 0.0, 0.0)
    gyro_sigma: float = 0.003
    gyro_bias: tuple = (0.0005, -0.0005, 0.003)
    acc_sigma: float = 0.05
    acc_bias: tuple = (0.03, -0.03, 0.05)
    vel_bias_walk: float = 0.0
    gyro_bias_walk: float = 0.0

    def as_dict(self) -> dict:
        return {
            k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()
        }

    def scaled(self, k: float) -> ImuNoise:
        """Every term (``*_sigma``, ``*_bias``, ``*_scale``) multiplied by ``k >= 0``: ``k = 0`` gives exact
        fields (equal to :data:`ZERO_NOISE`), ``k = 2`` twice the errors. Dead-reckoning drift grows about
        linearly in ``k`` (it is dominated by the biases and the scale error)."""
        k = float(k)
        if not (k >= 0 and np.isfinite(k)):
            raise ValueError(f"noise scale must be a finite number >= 0, got {k}")

        # "+ 0.0" turns the -0.0 of 0 * (negative bias) into 0.0, so as_dict() matches ZERO_NOISE's
        def scale(x):
            return k * float(x) + 0.0

        out = {}
        for f in fields(self):
            v = getattr(self, f.name)
            out[f.name] = tuple(scale(x) for x in v) if isinstance(v, tuple) else scale(v)
        return ImuNoise(**out)


ZERO_NOISE = ImuNoise(
    0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, (0.0, 0.0, 0.0), 0.0, (0.0, 0.0, 0.0)
)

#: The default noise with wandering biases: a gyro bias random walk of 2e-4 rad/s/sqrt(s) (after 100 s the yaw-rate
#: bias is off by 2 mrad/s, 0.11 deg/s, one sigma: a consumer MEMS gyro, cf. the 3 mrad/s constant bias) and a
#: velocity bias walk of 5 mm/s/sqrt(s) (5 cm/s after 100 s). Dead reckoning over the whole KITTI 07, 05 and 00 routes
#: (114, 287, 471 s) then drifts 5.7, 6.5 and 6.7 % (KITTI translational error, mean of seeds 0-3; 2-9 % by seed)
#: instead of 4.2, 5.2 and 5.4 % with the constant biases alone (``dead_reckon`` of ``oxts_packets`` at 9.7 Hz).
WANDERING_BIASES = ImuNoise(vel_bias_walk=0.005, gyro_bias_walk=2e-4)


def latlon_from_mercator(mx, my, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of pykitti's Mercator projection: ``(mx, my)`` m -> ``(lat, lon)`` degrees (see module doc)."""
    lon = np.asarray(mx, dtype=np.float64) * 180.0 / (np.pi * scale * EARTH_RADIUS)
    lat = (
        360.0
        / np.pi
        * np.arctan(np.exp(np.asarray(my, dtype=np.float64) / (scale * EARTH_RADIUS)))
        - 90.0
    )
    return lat, lon


def _corrupt(x, sigma, bias, scale, rng):
    x = np.asarray(x, dtype=np.float64)
    return (
        (1.0 + np.asarray(scale)) * x
        + np.asarray(bias)
        + sigma * rng.standard_normal(x.shape)
    )


def bias_walk(times, q: float, rng: np.random.Generator) -> np.ndarray:
    """A bias random walk ``(N, 3)`` at ``times (N,)`` s: 0 at ``times[0]``, then
    ``b_k = b_{k-1} + q sqrt(t_k - t_{k-1}) n_k`` with ``n_k ~ N(0, I_3)`` (a Wiener process of intensity ``q``
    sampled exactly at the times). ``q = 0`` gives zeros and draws nothing from ``rng``."""
    t = np.asarray(times, dtype=np.float64)
    if q == 0.0 or len(t) == 0:
        return np.zeros((len(t), 3))
    steps = q * np.sqrt(np.diff(t))[:, None] * rng.standard_normal((len(t) - 1, 3))
    return np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)])


def oxts_packets(
    route: Route,
    times,
    noise: ImuNoise = ImuNoise(),
    seed: int = 0,
    origin: tuple = KARLSRUHE,
    enu_yaw0: float = 0.0,
) -> np.ndarray:
    """OXTS packets ``(N, 30)`` float64 (KITTI field order) of ``route`` at ``times (N,)`` seconds.

    Parameters
    ----------
    route : the true trajectory.
    times : (N,) route times of the packets (s).
    noise : IMU noise of the velocity / rate / acceleration fields (:data:`ZERO_NOISE` for exact values).
    seed : seed of the noise (``np.random.default_rng(seed)``).
    origin : ``(lat0, lon0, alt0)`` of the route's origin (deg, deg, m).
    enu_yaw0 : heading (rad, 0 = east, counter-clockwise) of the route's x axis in the ENU frame.
    """
    rng = np.random.default_rng(seed)
    t = np.asarray(times, dtype=np.float64)
    n = len(t)
    Rz0 = rot_z(enu_yaw0)
    T = route.pose(t)
    R_enu = np.einsum("ij,njk->nik", Rz0, T[:, :3, :3])
    p_enu = T[:, :3, 3] @ Rz0.T
    lat0, lon0, alt0 = origin
    s = np.cos(lat0 * np.pi / 180.0)
    mx0 = s * EARTH_RADIUS * lon0 * np.pi / 180.0
    my0 = s * EARTH_RADIUS * np.log(np.tan((90.0 + lat0) * np.pi / 360.0))
    lat, lon = latlon_from_mercator(mx0 + p_enu[:, 0], my0 + p_enu[:, 1], s)
    lat[0], lon[0] = lat0, lon0  # exact first packet (defines the Mercator scale)
    out = np.zeros((n, 30))
    out[:, 0], out[:, 1], out[:, 2] = lat, lon, alt0 + p_enu[:, 2]
    out[:, 3:6] = matrix_to_rpy(R_enu)
    v_enu = route.velocity_world(t) @ Rz0.T
    out[:, 6], out[:, 7] = v_enu[:, 1], v_enu[:, 0]
    v_b, w_b, f_b = (
        route.velocity_body(t),
        route.angular_rate_body(t),
        route.specific_force_body(t),
    )
    vel = _corrupt(v_b, noise.vel_sigma, noise.vel_bias, noise.vel_scale, rng)
    out[:, 8:11] = vel
    out[:, 11:14] = _corrupt(f_b, noise.acc_sigma, noise.acc_bias, 0.0, rng)  # ax ay az
    out[:, 14:17] = _corrupt(f_b, noise.acc_sigma, noise.acc_bias, 0.0, rng)  # af al au
    out[:, 17:20] = _corrupt(w_b, noise.gyro_sigma, noise.gyro_bias, 0.0, rng)  # wx wy wz
    out[:, 20:23] = _corrupt(w_b, noise.gyro_sigma, noise.gyro_bias, 0.0, rng)  # wf wl wu
    out[:, 23] = 0.05
    out[:, 24] = 0.02
    out[:, 25] = 4
    out[:, 26] = rng.integers(8, 12, size=n)
    out[:, 27:30] = 6
    # drawn last, so that drives without wandering biases keep the noise they always had
    out[:, 8:11] += bias_walk(t, noise.vel_bias_walk, rng)
    gyro_walk = bias_walk(t, noise.gyro_bias_walk, rng)
    out[:, 17:20] += gyro_walk
    out[:, 20:23] += gyro_walk
    return out
