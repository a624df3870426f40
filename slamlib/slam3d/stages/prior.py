"""The prior stage: step 8's second term, which holds what the map alone cannot fix.

Holding the tilt to gravity (:class:`TiltPrior`)
------------------------------------------------
The map fixes a particle's roll and pitch only *relative to the map*, and the map is built from the filter's own
earlier estimates: each frame's small tilt error goes into the map, and over thousands of frames it random-walks
(on a whole KITTI route tens of milliradians, which the motion turns into metres of height). Gravity is the one
absolute reference on board. Each frame the stage reads the accelerometer
(:func:`~slamlib.slam3d.steps.read_specific_force`), :func:`gravity_up` separates gravity from the
vehicle's own acceleration over the last ``tilt_window`` seconds (with ``TiltConfig.tilt_up = "positions"``,
:func:`gravity_up_from_positions`: by the filter's own positions over the window instead of the IMU's velocities
at its ends, whose noise and scale error then drop out), and, once the window spans them (a shorter one
measures up with errors ~ 1 / its span: tens of milliradians in a drive's first frames), step 8 adds
:func:`tilt_log_prior` to every weight: a measurement of two of the six pose coordinates, as
an attitude filter uses its accelerometer. An accelerometer bias ``b`` tilts the measured up by ``b / g`` for good,
so after step 9 each frame's estimated rotation and measured up also go into a least-squares estimate of the bias
(:func:`tilt_calibration_update`; a bias turns with the body, a tilted map does not), and step 8
compares each particle's ``R_i^T g_w`` with the measured up less the bias. ``g_w``, the world's up, is ``e_z``
(the first body pose taken as level) unless ``TiltConfig.tilt_world_sigma > 0`` lets the fit move it.

That fit takes the filter's own rotation as the truth, so whatever the map's tilt has walked between two turns it
passes to the bias, and the prior then holds the tilt to an up that has moved with the map. With
``TiltConfig.tilt_bias = "kalman"`` a Kalman filter estimates both (:func:`tilt_kalman_update`): the map's tilt
error as a random walk of rate :data:`TILT_WALK_RATE`, the bias as a constant, from the same residual; a change
the body's turning explains is bias, the rest is tilt.

The guard
---------
An accelerometer cannot tell the car's acceleration from gravity in one sample; the window separates them only as
well as its inputs allow. Where it fails (an acceleration the window does not explain, a glitch), the measured up
is wrong, and at the prior's weight the particles follow it within a frame or two; the calibration then takes the
wrong up for bias or the world's tilt, the filter's own rotations turn the next windows, and the error feeds on
itself: a prior held to gravity diverges with nothing to stop it. So the scan keeps a say. Each frame the scan
match (:class:`~slamlib.slam3d.stages.ScanMatch`) also fits the map alone, and :meth:`TiltPrior.check` tests the
measured up against that fit as a Kalman filter tests a measurement against its prediction (Bar-Shalom, Li &
Kirubarajan, "Estimation with Applications to Tracking and Navigation", 2001, sec. 5.4): the innovation ``nu`` of
the calibration's measurement, with covariance ``S = H P H^T + s^2 I`` (the calibration's uncertainty and the
up's own noise against the map, :data:`TILT_GATE_NOISE`), and ``nu^T S^-1 nu`` against the chi-square's 99.9 %
(:data:`TILT_GATE_CHI2`). Where it fails, the prior steps back: the frame's pose is the map's fit, and until the
two agree again step 8, the match and the calibration hold to no up. The scan decides while the accelerometer
cannot; a map's slow tilt walk stays well inside the gate, which opens wide at the start, while the world's tilt
is still unknown.

:class:`NoPrior` (``TiltConfig.tilt_sigma = 0``, or LIDAR-only: no accelerometer) adds nothing.

How much to trust the accelerometer (``tilt_sigma = "auto"``)
-------------------------------------------------------------
The prior's ``sigma`` is the measured up's error, which depends on the IMU (its velocity noise ``dv`` tilts a window
of ``T`` seconds by ``dv / (g T)``) and the drive (a bumpy road, hard braking). With ``tilt_sigma = "auto"`` the
stage measures it from the accelerometer's own consistency (:func:`up_scatter`): the residual
``r = u - beta - R^T g_w`` of each frame (measured up less the bias against the filter's own up) and the residual
one window earlier, from non-overlapping windows, differ by the two windows' independent errors plus the change of
the filter's tilt error over a window, which random-walks slowly. So ``E |r_k - r_{k-W}|^2 = 4 sigma^2`` (two
windows, two tilt components): the up's noise is the square root of a quarter of the running mean of that
(memory :data:`UP_SCATTER_MEMORY_S`; :data:`AUTO_TILT_SIGMA_START` until the first window has turned over). The
difference cannot see the bias, which is the same in both windows: the prior holds the up *less the fitted bias*,
whose error is the fit's own (:func:`tilt_calibration_bias_variance`), large before the drive has turned and
shrinking as it does. So ``sigma^2`` = the noise's variance + the bias's, within [:data:`AUTO_TILT_SIGMA_MIN`,
:data:`AUTO_TILT_SIGMA_MAX`]: a weak hold until the bias is known, a firm one after.

That is the measured up's error bar, not yet the prior's best *weight*: each frame's window overlaps the last
``tilt_window / dt`` ones, and the map pulls every frame too. ``tilt_sigma = "adaptive"`` sets the weight as a
Kalman filter would (Maybeck, "Stochastic Models, Estimation and Control", vol. 1, 1979, ch. 5), with the map's
tilt error ``e``, a random walk of rate ``q`` (rad^2/s per axis), as the state, and each frame's up as a
measurement of it with variance ``R = sigma_u^2 tilt_window / dt`` (``sigma_u`` the window's noise: a frame adds
``dt / tilt_window`` of an independent sample). The steady state's gain per frame (:func:`tilt_gain`) is

    k = P / (P + R),     P = (Q + sqrt(Q^2 + 4 Q R)) / 2,     Q = q dt        (k ~ dt sqrt(q / (sigma_u^2 W))).

``q`` is read off the residuals at two lags, ``2 W`` (``W = tilt_window``) and ``L`` = :data:`ADAPTIVE_TILT_LAG_S`:
over either their difference holds the two windows' noise, and the walk over the lag (the bias, the same at both
ends, drops out). So with ``D(tau)`` the running mean of :func:`up_scatter` at lag ``tau``, ``D(tau) = sigma_u^2 + q
tau / 2``: ``q = 2 (D(L) - D(2 W)) / (L - 2 W)`` and ``sigma_u^2 = D(2 W) - q W`` (:meth:`TiltPrior.walk_rate`,
:meth:`TiltPrior.window_noise`). (Not the lag ``W`` of ``"auto"``: two windows that meet share the velocity at their
common end, whose error then enters their difference twice.) Over the running means' memory that difference holds
only a few independent samples, one per lag ``L``, and it often comes out at or below 0 while the tilt walks; a
gain from ``q = 0`` would hold nothing. So the gain takes the walk's mean given that it is at least 0
(:func:`truncated_normal_mean`): ``q`` read as a normal of its standard error ``s``
(:meth:`TiltPrior.walk_standard_error`, from the scatter of the frames' differences) truncated at 0,
``q + s phi(q / s) / Phi(q / s)``, which is ``q`` where the walk is well read and about ``0.8 s`` where it reads
none. ``s`` counts one independent difference per lag ``L``, right for the walk's part; the noise's part
decorrelates within a window, so ``s`` overstates the standard error (an upper bound: several times on white
noise), and the walk it gives leans toward a firmer hold. The map fixes the tilt with
information ``I_m`` (step 8's log-weight curvature in roll and pitch: the scan match's curvature ``h`` there, the
other coordinates free, over ``n T``, ``n`` matched points and ``T`` the temperature,
:meth:`TiltPrior.observe_map`), gravity with ``1 / sigma^2``, so a frame moves the tilt toward gravity by ``(1 /
sigma^2) / (I_m + 1 / sigma^2)``; setting that to ``k`` gives ``1 / sigma^2 = I_m k / (1 - k)``
(:func:`tilt_sigma_for_gain`). Where the map holds its tilt ``q`` is small and so is the pull; a noisier
accelerometer weakens it. Until the residuals span ``L`` seconds, or before a match, ``sigma`` is
:data:`AUTO_TILT_SIGMA_START`; it stays within [:data:`AUTO_TILT_SIGMA_MIN`, :data:`ADAPTIVE_TILT_SIGMA_MAX`].
"""

from __future__ import annotations

from collections import deque

import numpy as np

from slamlib.odometry import increment_matrix
from slamlib.slam3d import steps
from slamlib.slam3d.config import (
    ADAPTIVE,
    AUTO,
    TILT_BIAS_MODELS,
    TILT_UP_SOURCES,
    TiltConfig,
)
from slamlib.slam3d.stages.tuning import ForgettingMean

__all__ = [
    "AUTO_TILT_SIGMA_MAX",
    "AUTO_TILT_SIGMA_MIN",
    "AUTO_TILT_SIGMA_START",
    "UP_SCATTER_MEMORY_S",
    "ADAPTIVE_TILT_SIGMA_MAX",
    "ADAPTIVE_TILT_LAG_S",
    "up_scatter",
    "tilt_gain",
    "tilt_sigma_for_gain",
    "truncated_normal_mean",
    "NoPrior",
    "TiltPrior",
    "TILT_CALIBRATION_UNKNOWNS",
    "gravity_up",
    "gravity_up_from_positions",
    "tilt_log_prior",
    "tilt_calibration_prior",
    "tilt_calibration_rows",
    "tilt_calibration_update",
    "tilt_calibration",
    "heading_bin",
    "balance_heading_bins",
    "tilt_calibration_bins",
    "tilt_calibration_add",
    "tilt_calibration_estimate",
    "tilt_calibration_bias_variance",
    "tilt_kalman_update",
    "TILT_WALK_RATE",
    "TILT_GATE_NOISE",
    "TILT_GATE_CHI2",
    "tilt_kalman_rows",
]


#: ``tilt_sigma = "auto"``: the least and most ``sigma`` (rad): 1 mrad, the accelerometer's bias stability of a
#: good MEMS unit; 20 mrad, past which the prior holds nothing the map does not.
AUTO_TILT_SIGMA_MIN = 0.001
AUTO_TILT_SIGMA_MAX = 0.02
#: ... and ``sigma`` before the first window has turned over (rad): a weak hold.
AUTO_TILT_SIGMA_START = 0.01
#: Seconds the running mean square of :func:`up_scatter` remembers.
UP_SCATTER_MEMORY_S = 30.0
#: ``tilt_sigma = "adaptive"``: the longer lag ``L`` (s) at which the residuals' scatter shows the tilt's walk:
#: several windows, short against the drive.
ADAPTIVE_TILT_LAG_S = 12.0
#: ... and the most ``sigma`` (rad): where the tilt does not walk, a hold this weak leaves the map's tilt alone.
ADAPTIVE_TILT_SIGMA_MAX = 0.1
#: ``tilt_bias = "kalman"``: the rate ``q`` (rad^2/s per axis) at which the Kalman filter lets the map's tilt walk.
#: Without the prior the filter's tilt walked 8-12 mrad over the 100 s of route 07's development drive (scene seed
#: 0, filter seeds 0 and 1): ``q ~ (10 mrad)^2 / 100 s``.
TILT_WALK_RATE = 1e-6
#: The guard: the measured up's own noise against the map's fit of a scan (rad), beside the calibration's
#: uncertainty: the up's window noise and the map-only match's own tilt error, a few milliradians each.
TILT_GATE_NOISE = 0.01
#: ... and the most ``nu^T S^-1 nu`` it lets pass: the chi-square of two degrees of freedom (the tilt's two axes) at
#: 99.9 %. Once the calibration knows the world and the bias, a disagreement of about 2 degrees.
TILT_GATE_CHI2 = 13.8

# ------------------------------------------------------------------------------------------------ the math


def up_scatter(residual, residual_before) -> float:
    """One sample of the measured up's variance per tilt axis (rad^2): ``|r - r_before|^2 / 4`` for the residuals
    ``r = u - beta - R^T g_w`` (3,) of a frame and of the frame one window earlier (module docstring, "How much to
    trust the accelerometer"); the mean of such samples estimates ``sigma^2``."""
    d = np.asarray(residual, dtype=np.float64) - np.asarray(
        residual_before, dtype=np.float64
    )
    return float(d @ d) / 4.0


def tilt_gain(walk_rate: float, noise_variance: float, window: float, dt: float) -> float:
    """The steady-state Kalman gain ``k`` (module docstring, "How much to trust the accelerometer") of one frame's
    up for a tilt error that random-walks at ``walk_rate`` ``q`` (rad^2/s per axis), measured with ``R =
    noise_variance * window / dt`` (a frame adds ``dt / window`` of an independent sample of the window's noise):
    ``Q = q dt``, ``P = (Q + sqrt(Q^2 + 4 Q R)) / 2``, ``k = P / (P + R)``. 0 when ``q <= 0``."""
    Q = max(float(walk_rate), 0.0) * float(dt)
    if not Q > 0:
        return 0.0
    R = float(noise_variance) * float(window) / float(dt)
    P = 0.5 * (Q + np.sqrt(Q * Q + 4 * Q * R))
    return float(P / (P + R))


def tilt_sigma_for_gain(gain: float, map_information: float) -> float:
    """The prior's ``sigma`` (rad) that moves the tilt toward gravity by ``gain`` against the map's information
    ``I_m`` on it (rad^-2, step 8's log-weight curvature): ``1 / sigma^2 = I_m k / (1 - k)``; ``inf`` for no
    gain."""
    k = float(gain)
    if not k > 0:
        return float("inf")
    return float(np.sqrt((1 - k) / (float(map_information) * k)))


def truncated_normal_mean(mean: float, sd: float) -> float:
    """The mean of a normal of ``mean`` and standard deviation ``sd`` truncated to ``[0, inf)``:
    ``mean + sd phi(z) / Phi(z)`` with ``z = mean / sd`` (Johnson, Kotz & Balakrishnan, "Continuous Univariate
    Distributions", vol. 1, 1994, ch. 13), the posterior mean of a rate known to be at least 0 and read as ``mean``
    with that standard error; ``max(mean, 0)`` for ``sd`` 0. ``phi / Phi`` as ``sqrt(2 / pi) / erfcx(-z / sqrt 2)``,
    which stays finite far below 0 (where it tends to ``sd^2 / |mean|``)."""
    from scipy.special import erfcx

    mean, sd = float(mean), float(sd)
    if not sd > 0:
        return max(mean, 0.0)
    return float(mean + sd * np.sqrt(2 / np.pi) / erfcx(-mean / sd / np.sqrt(2)))


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

    Returns the unit vector ``R_K^T e_z`` (3,) as measured, or None when the window spans no time (``K = 0``).

    Parameters
    ----------
    rotations : (K + 1, 3, 3) body-to-world rotations ``R_k`` (any common world frame).
    specific_force : (K + 1, 3) accelerometer samples ``f_b`` (m/s^2, body frame, gravity included: KITTI OXTS
        ``ax, ay, az``; ``+g`` on z when level and still).
    velocity : (K + 1, 3) body velocities ``v`` (m/s; OXTS ``vf, vl, vu``).
    dts : (K + 1,) ``dts[k] = t_k - t_{k-1}`` (s); ``dts[0]`` is ignored.
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


def gravity_up_from_positions(
    rotations, positions, specific_force, dts
) -> np.ndarray | None:
    """Which way is up, in the body frame of the last of ``K + 1`` frames, from the accelerometer and the frames'
    *positions* over them, not the IMU's velocities (:func:`gravity_up`'s other measurement).

    Integrating ``a = R f_b - g e_z`` twice from ``t_0`` (``tau = t - t_0``; ``S(tau)``, the double integral of
    ``R f_b``, by the trapezoid rule twice over the samples)::

        p(tau) - S(tau) = p_0 + v_0 tau - g e_z tau^2 / 2,

    so a least-squares fit of ``c_0 + c_1 tau + c_2 tau^2 / 2`` to ``p_k - S(tau_k)`` (three unknown vectors, each
    axis alike) gives ``c_2 = -g e_z``: the up is ``-c_2``, normalised, turned into the last body frame by
    ``R_K^T`` (only rotations and positions *relative* to the last frame matter, as in :func:`gravity_up`). The
    start velocity is fitted, not read from the IMU, so the velocity's noise, scale error and bias drop out: over
    ``T`` seconds a position error ``dp`` tilts the up by about ``dp / (g T^2 / 2)`` (1 cm over 2 s: 0.5 mrad,
    against :func:`gravity_up`'s ``dv / (g T)``, 2.5 mrad for 0.05 m/s). A filter passes its own estimates: the
    scan-matched positions over a second or two are good to centimetres. An accelerometer bias still tilts it by
    ``b / g``.

    Returns the unit vector ``R_K^T e_z`` (3,) as measured, or None when fewer than three frames or no time span.

    Parameters
    ----------
    rotations : (K + 1, 3, 3) body-to-world rotations ``R_k``.
    positions : (K + 1, 3) body positions ``p_k`` (m, world frame).
    specific_force : (K + 1, 3) accelerometer samples ``f_b`` (m/s^2, body frame, gravity included).
    dts : (K + 1,) ``dts[k] = t_k - t_{k-1}`` (s); ``dts[0]`` is ignored.
    """
    R = np.asarray(rotations, dtype=np.float64)
    p = np.asarray(positions, dtype=np.float64)
    dts = np.asarray(dts, dtype=np.float64)
    if len(dts) < 3 or not dts[1:].sum() > 0:
        return None
    f_w = np.einsum("kij,kj->ki", R, np.asarray(specific_force, dtype=np.float64))
    h = dts[1:, None]
    velocity = np.concatenate(
        [np.zeros((1, 3)), np.cumsum(0.5 * (f_w[:-1] + f_w[1:]) * h, axis=0)]
    )
    S = np.concatenate(
        [np.zeros((1, 3)), np.cumsum(0.5 * (velocity[:-1] + velocity[1:]) * h, axis=0)]
    )
    tau = np.concatenate([[0.0], np.cumsum(dts[1:])])
    A = np.stack([np.ones_like(tau), tau, 0.5 * tau * tau], axis=1)
    c, *_ = np.linalg.lstsq(A, p - S, rcond=None)
    up_b = R[-1].T @ -c[2]
    norm = np.linalg.norm(up_b)
    return up_b / norm if norm > 0 else None


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


def tilt_calibration_rows(R, up) -> tuple[np.ndarray, np.ndarray]:
    """The tilt calibration's linear measurement of one frame, ``(H (3, 4), y (3,))`` with ``y = u - R^T e_z =
    H x``: ``H = [R^T e_x, R^T e_y, e_x, e_y]`` (the rows of ``R`` are ``R^T e_i``) for the unknowns of
    :data:`TILT_CALIBRATION_UNKNOWNS` (derivation: :func:`tilt_calibration_update`)."""
    R = np.asarray(R, dtype=np.float64)
    H = np.column_stack([R[0], R[1], np.eye(3)[:, 0], np.eye(3)[:, 1]])
    return H, np.asarray(up, dtype=np.float64) - R[2]


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
    H, y = tilt_calibration_rows(R, up)
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


def tilt_calibration_bias_variance(prior, sums) -> float:
    """The variance (rad^2, per axis: the mean of the two) of the accelerometer bias that
    :func:`tilt_calibration_estimate` returns: the bias block of the inverse of the balanced information plus the
    prior's, over the free unknowns; 0 when the bias is held at 0 (prior sigma 0)."""
    info0, _, free = prior
    free = np.asarray(free, dtype=bool)
    if not free[2:].any():
        return 0.0
    info, _ = balance_heading_bins(*sums)
    cov = np.linalg.inv((info0 + info)[np.ix_(free, free)])
    bias = np.flatnonzero(free) >= 2  # which of the free unknowns are the bias's
    return float(np.mean(np.diag(cov)[bias]))


def tilt_kalman_rows(n_states: int, R, up) -> tuple[np.ndarray, np.ndarray]:
    """:func:`tilt_calibration_rows` for the Kalman filter's state of ``n_states`` (4 or 6, :func:`tilt_kalman_update`):
    ``(H (3, n_states), y (3,))``, ``y = u - R^T e_z = H x + noise``; with six, the world's tilt and the map's walk
    enter alike."""
    H, y = tilt_calibration_rows(R, up)
    if n_states == 6:
        H = np.column_stack([H[:, :2], H])
    return H, y


def tilt_kalman_update(
    state, cov, R, up, noise_variance: float, walk_variance: float
) -> tuple[np.ndarray, np.ndarray]:
    """One frame of the tilt calibration as a Kalman filter (``TiltConfig.tilt_bias = "kalman"``; returns new
    arrays): the state ``x = (a, b, c, d)`` of :data:`TILT_CALIBRATION_UNKNOWNS`, but with ``(a, b)`` the *filter's*
    world up off gravity's, its map's tilt error, which random-walks, and ``(c, d)`` the accelerometer's bias,
    which holds. The measurement is :func:`tilt_calibration_update`'s,

        y = u - R^T e_z = H x + noise,    H = [R^T e_x, R^T e_y, e_x, e_y]    (3, 4),

    the prediction adds ``walk_variance`` (``q dt``, rad^2 per axis) to the tilt's variance, and the update is the
    standard one (Joseph form; Maybeck 1979, ch. 5): ``K = P H^T (H P H^T + r I)^-1``, ``x += K (y - H x)``,
    ``P = (I - K H) P (I - K H)^T + r K K^T`` with ``r = noise_variance``. With no walk it is the least squares of
    :func:`tilt_calibration_update` with weight ``1 / r``, the world's up free; those hold the world's up still
    and pass the map's walk to the bias between turns, this one lets the tilt move and keeps as bias only what
    stays put in the body as it turns.

    With a state of six, ``x = (a_0, b_0, a, b, c, d)``, ``(a_0, b_0)`` is the *world's* up off gravity's, which
    holds (the first body pose defines the world, and a drive that starts on a slope or a cambered road starts
    tilted), and ``(a, b)`` the map's tilt error from there on, which walks, starting at 0: both enter ``y`` alike
    (``H = [R^T e_x, R^T e_y, R^T e_x, R^T e_y, e_x, e_y]``), so only their priors tell them apart: what the first
    windows measure goes to the world, what comes later as a walk to the map.

    Parameters
    ----------
    state : (4,) ``(a, b, c, d)`` or (6,) ``(a_0, b_0, a, b, c, d)`` (rad); cov : (4, 4) or (6, 6) its covariance
        (rad^2).
    R : (3, 3) the filter's body-to-world rotation; up : (3,) the measured up (body frame, :func:`gravity_up`).
    noise_variance : the frame's measurement variance per axis (rad^2; a window of ``T`` s measured every ``dt``:
        ``sigma_u^2 T / dt``, as each frame adds ``dt / T`` of an independent sample).
    walk_variance : the tilt's random walk over the frame, ``q dt`` (rad^2 per axis).
    """
    x = np.asarray(state, dtype=np.float64)
    walk = len(x) - 4  # the map's tilt: after the world's, when the state has it
    P = np.array(cov, dtype=np.float64)
    P[walk : walk + 2, walk : walk + 2] += float(walk_variance) * np.eye(2)
    H, y = tilt_kalman_rows(len(x), R, up)
    r = float(noise_variance)
    K = P @ H.T @ np.linalg.inv(H @ P @ H.T + r * np.eye(3))
    x = x + K @ (y - H @ x)
    A = np.eye(len(x)) - K @ H
    return x, A @ P @ A.T + r * K @ K.T


def tilt_log_prior(particles, up, sigma: float, world_up=None) -> np.ndarray:
    """Step 8's second term: log-prior ``(P,)`` of each particle's roll and pitch given the measured up direction.

    ``log p_i = -|R_i^T g_w - u|^2 / (2 sigma^2)``, with ``u`` the unit up vector in the body frame measured by
    the accelerometer (:func:`gravity_up`, less its bias when estimated) and ``R_i^T g_w`` the
    particle's own, ``g_w`` the world's up (default ``e_z``: then it is ``R_i``'s third row). For small angles
    ``|R_i^T g_w - u|`` is the tilt between the two in radians; yaw does not enter. ``sigma`` (rad) is the
    measured up's uncertainty. The map alone fixes the tilt only relative to the map, which is itself built from
    earlier estimates, so its error random-walks over a long drive; this term holds it to gravity (Thrun et al.
    2005, ch. 7: a direct measurement of part of the state).
    """
    if world_up is None:
        own = particles.R[:, 2, :]
    else:
        own = np.einsum("pji,j->pi", particles.R, np.asarray(world_up, dtype=np.float64))
    diff = own - np.asarray(up, dtype=np.float64)[None, :]
    return -0.5 * np.sum(diff * diff, axis=1) / float(sigma) ** 2


# ------------------------------------------------------------------------------------------------ the stage


class NoPrior:
    """No second term: the weights are the map's alone."""

    up = None

    def measure(self, frame, imu, dt, increment, poses) -> None:
        """Nothing to measure."""

    def weigh(self, particles, log_weights):
        """``log_weights`` unchanged."""
        return log_weights

    def calibrate(self, pose, dt) -> None:
        """Nothing to calibrate."""


class TiltPrior:
    """Roll and pitch held to the accelerometer's up (module docstring), with the bias and the world's up fitted.

    Attributes
    ----------
    up : (3,) the accelerometer's up direction in this frame's body (:func:`gravity_up`, or
        :func:`gravity_up_from_positions` with ``tilt_up = "positions"``); None until a frame with an accelerometer
        has been measured.
    samples : deque of ``(specific_force, velocity, dt)`` of the frames in the window; ``up_span`` the seconds
        it spans.
    stepped_back : whether the guard has stepped the prior back (:meth:`check`); ``disagreement`` the last
        frame's innovation test ``nu^T S^-1 nu``, ``n_stepped_back`` the frames it stepped back.
    world_up, up_bias : (3,) the estimated world's up (world frame) and accelerometer bias (an angle, body frame)
        (``e_z`` and 0 until frames come in). Behind them: with ``tilt_bias = "sectors"`` ``calibration_prior``
        ``(Lambda, eta, free)`` and ``bins`` ``(Lambdas, etas, weights)``, the least-squares sums of each heading
        sector; with ``"kalman"`` ``state`` and ``cov`` of :func:`tilt_kalman_update`: (4,) and (4, 4), the map's
        tilt error and the bias, ``world_up`` then staying ``e_z`` (the tilt error is the filter's to correct, not
        the world's), or with ``tilt_world_sigma`` > 0 (``world_state`` true) (6,) and (6, 6), the world's tilt
        ahead of them, which ``world_up`` follows.
    """

    def __init__(self, config: TiltConfig):
        self.auto = config.tilt_sigma == AUTO
        self.adaptive = config.tilt_sigma == ADAPTIVE
        measured = self.auto or self.adaptive
        # "auto": the measured up's own scatter, and the prior's sigma with the bias's uncertainty added
        self.noise_sigma = AUTO_TILT_SIGMA_START if measured else config.tilt_sigma
        self.sigma = self.noise_sigma
        self.window = config.tilt_window
        self.from_positions = config.tilt_up == TILT_UP_SOURCES[1]
        # (time, residual) of the frames of the last window ("auto") or ADAPTIVE_TILT_LAG_S ("adaptive"), oldest
        # first, and the running mean of up_scatter at lag W
        self.history: deque = deque()
        self.span = ADAPTIVE_TILT_LAG_S if self.adaptive else self.window
        self.time, self.scatter = 0.0, ForgettingMean(UP_SCATTER_MEMORY_S)
        # "adaptive": the means of up_scatter at lags 2 W and L, and the map's information on the tilt
        self.scatter_near = ForgettingMean(UP_SCATTER_MEMORY_S)
        self.scatter_lagged = ForgettingMean(UP_SCATTER_MEMORY_S)
        # ... the mean square of the difference of the two samples (for the walk's standard error) and the last dt
        self.walk_square = ForgettingMean(UP_SCATTER_MEMORY_S)
        self.dt = 0.1
        self.map_information = None
        self.samples: deque = deque()
        self.up, self.up_span = None, 0.0
        # the guard's verdict on this frame's up, its innovation test, the frames it stepped back (check)
        self.stepped_back, self.n_stepped_back, self.disagreement = False, 0, 0.0
        self.kalman = config.tilt_bias == TILT_BIAS_MODELS[1]
        if self.kalman:
            # the map's tilt error and the bias as a Kalman filter's state, the tilt starting at 0; with
            # tilt_world_sigma the world's tilt too, ahead of them
            sigmas = [0.0, config.tilt_bias_sigma]
            self.world_state = config.tilt_world_sigma > 0
            if self.world_state:
                sigmas = [config.tilt_world_sigma, *sigmas]
            self.state = np.zeros(2 * len(sigmas))
            self.cov = np.diag(np.repeat(sigmas, 2) ** 2)
            self.world_up, self.up_bias = np.array([0.0, 0.0, 1.0]), np.zeros(3)
        else:
            self.calibration_prior = tilt_calibration_prior(
                config.tilt_world_sigma, config.tilt_bias_sigma
            )
            self.bins = tilt_calibration_bins(config.tilt_heading_bins)
            self.world_up, self.up_bias = tilt_calibration_estimate(
                self.calibration_prior, self.bins
            )

    def measure(self, frame, imu, dt: float, increment, poses) -> None:
        """This frame's up, from the accelerometer over the last ``tilt_window`` seconds
        (:func:`gravity_up`): the samples of this frame and the registered frames before it,
        turned by the filter's own estimated rotations (``poses``) and this frame's predicted one (``increment``
        on the last estimate). A frame without an accelerometer empties the window (``up`` None)."""
        force = steps.read_specific_force(frame)
        if force is None:
            self.samples.clear()
            self.up = None
            return
        samples = self.samples  # (force, velocity, dt) per frame, oldest first
        samples.append((force, imu[0], dt))
        while len(samples) > 2 and sum(s[2] for s in list(samples)[2:]) >= self.window:
            samples.popleft()  # the rest still spans the window
        past = list(poses[len(poses) - len(samples) + 1 :])
        T = np.array(past + [poses[-1] @ increment_matrix(*increment)])
        force, velocity, dts = (np.array(x) for x in zip(*samples))
        self.up_span = float(dts[1:].sum())
        if self.from_positions:
            self.up = gravity_up_from_positions(T[:, :3, :3], T[:, :3, 3], force, dts)
        else:
            self.up = gravity_up(T[:, :3, :3], force, velocity, dts)

    def measured_up(self) -> np.ndarray | None:
        """This frame's measured up less the fitted bias (3,), body frame (:func:`tilt_calibration`: a body ``R``
        measures ``u = R^T g_w + beta``); None until the window spans ``tilt_window`` (a window of ``T`` seconds
        measures up with errors ~ ``1 / T``, tens of milliradians over the first frames, which ``sigma``, the full
        window's, would hold the tilt to)."""
        if self.up is None or self.up_span < self.window:
            return None
        return self.up - self.up_bias

    def held_up(self) -> np.ndarray | None:
        """The up the prior holds the tilt to: :meth:`measured_up`, or None while the guard has stepped the prior
        back (:meth:`check`). Step 8 (:meth:`weigh`), the scan match's gravity term and the calibration all hold
        to this one vector."""
        return None if self.stepped_back else self.measured_up()

    def check(self, R_map) -> bool:
        """The guard (module docstring, "The guard"): whether the measured up agrees with the body rotation ``R_map``
        (3, 3) that the map alone fits this frame's scan best. The innovation ``nu = y - H x`` of the calibration's
        measurement (:func:`tilt_kalman_rows`; without the Kalman filter, the measured up less the bias against
        ``R_map^T g_w``) is weighed by its covariance ``S = H P H^T + s^2 I`` (``P`` the Kalman filter's, 0
        without it; ``s`` = :data:`TILT_GATE_NOISE`): where ``nu^T S^-1 nu`` exceeds :data:`TILT_GATE_CHI2`, the
        prior steps back (:attr:`stepped_back`: no weight, no gravity in the match, no calibration) until they agree
        again. ``disagreement`` keeps the frame's ``nu^T S^-1 nu``, ``n_stepped_back`` counts the frames. True (and
        not stepped back) while the prior measures no up."""
        up = self.measured_up()
        if up is None:
            self.stepped_back, self.disagreement = False, 0.0
            return True
        R_map = np.asarray(R_map, dtype=np.float64)
        if self.kalman:
            H, y = tilt_kalman_rows(len(self.state), R_map, self.up)
            nu, S = y - H @ self.state, H @ self.cov @ H.T
        else:
            nu, S = up - R_map.T @ self.world_up, np.zeros((3, 3))
        S = S + TILT_GATE_NOISE**2 * np.eye(3)
        self.disagreement = float(nu @ np.linalg.solve(S, nu))
        self.stepped_back = self.disagreement > TILT_GATE_CHI2
        self.n_stepped_back += int(self.stepped_back)
        return not self.stepped_back

    def weigh(self, particles, log_weights):
        """``log_weights`` plus :func:`tilt_log_prior` of the measured up less the bias (:meth:`held_up`)."""
        up = self.held_up()
        if up is None:
            return log_weights
        return log_weights + tilt_log_prior(particles, up, self.sigma, self.world_up)

    def calibrate(self, pose, dt: float) -> None:
        """Add this frame's estimated rotation and measured up to the calibration (none while the window does
        not yet span ``tilt_window``: a shorter one measures up with errors ~ 1 / its span), in its heading's
        sector: each frame weighs ``dt / tilt_window`` of an independent up measurement of standard deviation
        ``tilt_sigma`` (consecutive windows overlap), and the sectors weigh alike
        (:func:`balance_heading_bins`)."""
        if self.held_up() is None:
            return
        if self.auto or self.adaptive:
            self._weigh_by_consistency(pose, dt)
        if self.kalman:
            self.state, self.cov = tilt_kalman_update(
                self.state,
                self.cov,
                pose[:3, :3],
                self.up,
                self.noise_sigma**2 * self.window / dt,
                TILT_WALK_RATE * dt,
            )
            self.up_bias = np.array([*self.state[-2:], 0.0])
            if self.world_state:
                world = np.array([*self.state[:2], 1.0])
                self.world_up = world / np.linalg.norm(world)
        else:
            weight = dt / self.window / self.noise_sigma**2
            tilt_calibration_add(self.bins, pose[:3, :3], self.up, weight)
            self.world_up, self.up_bias = tilt_calibration_estimate(
                self.calibration_prior, self.bins
            )
        if self.auto:
            # the up less the fitted bias is off by the window's noise and by the fit's own error
            variance = self.noise_sigma**2 + self.bias_variance()
            self.sigma = float(
                np.clip(np.sqrt(variance), AUTO_TILT_SIGMA_MIN, AUTO_TILT_SIGMA_MAX)
            )
        elif self.adaptive:
            self.sigma = self._adaptive_sigma(dt)

    def bias_variance(self) -> float:
        """The fitted bias's variance per axis (rad^2): the Kalman filter's, or the sectors' least squares'
        (:func:`tilt_calibration_bias_variance`)."""
        if self.kalman:
            return float(np.mean(np.diag(self.cov)[-2:]))
        return tilt_calibration_bias_variance(self.calibration_prior, self.bins)

    def observe_map(self, hessian, n: int, temperature: float) -> None:
        """``"adaptive"``: the map's information on the tilt, from the scan match's curvature ``hessian`` (6, 6;
        rotation first, world frame; :func:`slamlib.slam3d.match.match_scan`'s ``return_hessian``) of ``n`` points
        at ``temperature``: the information on roll and pitch with the other four coordinates free (the inverse of
        the world x, y block of the inverse: a roll the map would take back partly by a shift sideways is held only
        by what is left), the mean of its two diagonal entries, over ``n T`` as step 8's log-weight sees it. A
        curvature that is not positive definite (a match on a flat patch) leaves the last value."""
        C = np.asarray(hessian, dtype=np.float64)
        if n <= 0 or not np.all(np.linalg.eigvalsh(C) > 0):
            return
        tilt = np.linalg.inv(np.linalg.inv(C)[:2, :2])
        self.map_information = 0.5 * float(np.trace(tilt)) / (n * float(temperature))

    def walk_reading(self) -> float:
        """``"adaptive"``: the tilt's walk as read, ``q = 2 (D(L) - D(2 W)) / (L - 2 W)`` (rad^2/s per axis; module
        docstring), which the few independent samples can put below 0."""
        D_L, D_near = self.scatter_lagged.value, self.scatter_near.value
        return 2 * (D_L - D_near) / (ADAPTIVE_TILT_LAG_S - 2 * self.window)

    def walk_rate(self) -> float:
        """``"adaptive"``: :meth:`walk_reading`, at least 0."""
        return max(self.walk_reading(), 0.0)

    def walk_standard_error(self) -> float:
        """``"adaptive"``: the standard error ``s`` of :meth:`walk_reading`'s ``q`` (rad^2/s; module docstring): the
        scatter of the frames' differences ``x = up_scatter at L - up_scatter at 2 W`` about their mean, over the
        independent samples in the running means' memory (one per lag ``L``), times ``2 / (L - 2 W)``. An upper bound:
        the noise in the differences decorrelates within a window, sooner than a lag ``L``."""
        span = ADAPTIVE_TILT_LAG_S - 2 * self.window
        d = self.scatter_lagged.value - self.scatter_near.value
        spread = max(self.walk_square.value - d * d, 0.0)
        independent = max(self.scatter_lagged.weight * self.dt / ADAPTIVE_TILT_LAG_S, 1.0)
        return float(2 * np.sqrt(spread / independent) / span)

    def window_noise(self) -> float:
        """``"adaptive"``: the window's noise ``sigma_u^2 = D(2 W) - q W`` (rad^2 per axis; module docstring), at
        least :data:`AUTO_TILT_SIGMA_MIN` squared."""
        noise = self.scatter_near.value - self.walk_rate() * self.window
        return max(noise, AUTO_TILT_SIGMA_MIN**2)

    def _adaptive_sigma(self, dt: float) -> float:
        """``"adaptive"``: ``sigma`` from the gain a Kalman filter would give this frame's up (module docstring);
        :data:`AUTO_TILT_SIGMA_START` until the residuals span :data:`ADAPTIVE_TILT_LAG_S` and a match has
        measured the map."""
        if self.map_information is None or self.scatter_lagged.weight == 0:
            return AUTO_TILT_SIGMA_START
        # the walk's mean given that it is at least 0
        walk = truncated_normal_mean(self.walk_reading(), self.walk_standard_error())
        k = tilt_gain(walk, self.window_noise(), self.window, dt)
        sigma = tilt_sigma_for_gain(k, self.map_information)
        return float(np.clip(sigma, AUTO_TILT_SIGMA_MIN, ADAPTIVE_TILT_SIGMA_MAX))

    def _earlier(self, lag: float):
        """The residual (3,) of the newest frame in :attr:`history` at least ``lag`` seconds before the last; None
        if there is none."""
        return next((r for t, r in reversed(self.history) if self.time - t >= lag), None)

    def record(self, residual, dt: float) -> None:
        """This frame's ``residual`` (3,), body frame, ``dt`` seconds after the last, into :attr:`history` and the
        running means of :func:`up_scatter`: against the residual a window earlier (``scatter``, ``"auto"``'s noise),
        and for ``"adaptive"``, once the history reaches back :data:`ADAPTIVE_TILT_LAG_S`, against those ``2 W`` and
        ``L`` earlier (``scatter_near`` and ``scatter_lagged``: ``D(2 W)`` and ``D(L)``, module docstring)."""
        self.time += dt
        self.history.append((self.time, residual))
        while len(self.history) > 1 and self.time - self.history[1][0] >= self.span:
            self.history.popleft()  # the rest still reaches back span seconds
        earlier = self._earlier(self.window)
        if earlier is not None:
            self.scatter.add(up_scatter(residual, earlier), dt)
        before = self._earlier(ADAPTIVE_TILT_LAG_S) if self.adaptive else None
        if before is not None:
            near = up_scatter(residual, self._earlier(2 * self.window))
            lagged = up_scatter(residual, before)
            self.scatter_near.add(near, dt)
            self.scatter_lagged.add(lagged, dt)
            self.walk_square.add((lagged - near) ** 2, dt)
            self.dt = dt

    def _weigh_by_consistency(self, pose, dt: float) -> None:
        """``tilt_sigma = "auto"`` or ``"adaptive"``: this frame's residual ``r = u - beta - R^T g_w`` into
        :meth:`record`, and the up's own noise ``noise_sigma`` from ``scatter`` (module docstring); :meth:`calibrate`
        adds the bias fit's uncertainty to make ``sigma``."""
        R = pose[:3, :3]
        self.record(self.held_up() - R.T @ self.world_up, dt)
        if self.scatter.weight > 0:
            self.noise_sigma = float(
                np.clip(
                    np.sqrt(self.scatter.value), AUTO_TILT_SIGMA_MIN, AUTO_TILT_SIGMA_MAX
                )
            )
