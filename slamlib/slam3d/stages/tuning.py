"""Self-tuning motion: the motion stage learns its source's errors from the filter's own innovations.

Step 5 moves every particle by the motion source's increment (the IMU's, or LIDAR-only the held twist) and step 6
spreads them around it. Both used to take the source's errors as settings: a spread tuned to one IMU is too wide
for a better one (the particles spread thin, and the best of them lies farther from the likelihood's peak) and too
narrow for a worse one, whose biases push the truth to the edge of the cloud every frame. The filter measures those
errors itself. After step 9 the pose it chose says how the vehicle moved in the frame; the **innovation** is how far
that is from what the source predicted, in the coordinates of step 6's noise (body x, y, z, then roll, pitch, yaw):

    e = (dp_measured - dp_predicted,  rpy(dR_predicted^T dR_measured)),

with ``(dR, dp)`` the body-frame increments ``T_prev^-1 T`` (:func:`motion_innovation`). Per axis ``a`` it is
modelled as a scale error of the predicted increment ``u_a`` and a bias over the frame's time ``dt``,

    e_a = s_a u_a + b_a dt + n_a,        n_a ~ N(0, q_a^2),

the errors of an IMU's velocities and rates: a wheel or speed scale error ``s`` (1.5 % on KITTI's OXTS-like
synthetic IMU), biases ``b`` (m/s, rad/s) that wander. Each axis's ``(s_a, b_a)`` is a recursive least-squares
fit with exponential forgetting (memory ``memory`` seconds: the factor ``lambda = exp(-dt / memory)`` per frame;
Ljung & Soederstroem, "Theory and Practice of Recursive Identification", 1983, ch. 2), regularised toward zero
by a prior (:data:`PRIOR_SIGMA_TRANSLATION`, :data:`PRIOR_SIGMA_ROTATION`) so that an axis that never moves (the
lateral one's ``u``) has a defined scale. Then:

* step 5 moves by the **corrected** increment ``u_a + s_a u_a + b_a dt`` (:meth:`SelfTuning.correct`) on the
  axes of :data:`CORRECTED_AXES`, forward, left and yaw, so the cloud is centred where the vehicle is likely to
  be, not where the biased source says. Not in height, roll and pitch: there the innovation also holds the map's
  own slow drift (the map is built from the filter's estimates, and its tilt random-walks), which the fit would
  take for a bias and then follow, giving up the IMU's hold on exactly the drift the filter most needs held;
  the tilt prior (:mod:`slamlib.slam3d.stages.prior`) corrects those axes against gravity instead;
* step 6's spread is the source's own scatter, ``sigma_a = sqrt((gain q_a)^2 + floor_a^2)`` with ``q_a^2`` from the
  *predictive* residuals ``r_a = e_a - s_a u_a - b_a dt`` (each computed before the frame enters the fit, so an
  over-fitted model cannot shrink it): their running mean square less what the filter's own jitter adds, which
  shows as a negative correlation of consecutive residuals (:attr:`SelfTuning.source_variance`;
  :meth:`SelfTuning.spread`). ``gain`` > 1 keeps the truth inside the cloud when the errors grow; ``floor`` keeps
  a spread where the source is exact, for the map's own corrections. Until ``warmup`` frames have been seen, the
  configured spread stands.

The residual cannot shrink below what step 8 resolves (the posterior's width), whatever the spread, so the estimate
does not collapse onto itself; and it grows with the truth's distance from the prediction, which widens the spread
after a sudden change (a slip, a turn the held twist did not know), as KISS-ICP's adaptive threshold does for its
correspondences (Vizzo et al., "KISS-ICP", RA-L 2023, sec. III-C). LIDAR-only the same fit learns the constant
velocity model's error, the accelerations it cannot know.

Stability
---------
The innovation holds the source's error and the filter's own jitter, and the jitter grows with the spread: roughly
``q^2 = q_src^2 + c sigma^2`` for some ``c < 1`` that depends on the scan. Were the spread ``gain q``, it would
settle at ``q^2 = q_src^2 / (1 - c gain^2)`` and run away once ``c gain^2 >= 1``: on the development drives a gain
of 3 on the raw mean square did (errors of metres). Taking the jitter out (:attr:`SelfTuning.source_variance`) cuts
that loop; ``gain`` (1.5 by default) leaves room for errors that grow between frames, and
:data:`MAX_SPREAD_FACTOR` bounds what is left.
"""

from __future__ import annotations

import numpy as np

from slamlib.geometry import matrix_to_rpy, rpy_to_matrix

__all__ = [
    "MAX_SPREAD_FACTOR",
    "PRIOR_SIGMA_ROTATION",
    "PRIOR_SIGMA_TRANSLATION",
    "FixedSpread",
    "ForgettingMean",
    "SelfTuning",
    "motion_innovation",
    "innovation_update",
    "innovation_model",
    "AXES",
    "CORRECTED_AXES",
]

#: Step 6's axes, in the order of its spread and of an innovation: body x, y, z (m), roll, pitch, yaw (rad).
AXES = ("x", "y", "z", "roll", "pitch", "yaw")
#: The axes whose fitted errors step 5 corrects (module docstring): forward, left, yaw.
CORRECTED_AXES = np.array([True, True, False, False, False, True])
#: The most the learnt spread may exceed the configured one: a bound on the loop in which a wider spread lets the
#: chosen pose jitter more, which widens the innovations' scatter (module docstring, "Stability").
MAX_SPREAD_FACTOR = 4.0
#: Unknowns per axis: the scale error ``s`` and the bias ``b`` (per second).
UNKNOWNS = 2
#: Prior standard deviations of ``(s, b)`` for the translation axes (a scale error of 5 %, a velocity bias of
#: 0.1 m/s) and the rotation axes (5 %, 10 mrad/s): what a car's odometry and a MEMS gyro may have. They keep an axis
#: that never moves well-posed, and they split what a drive at one speed cannot (``s u + b dt`` with ``u``
#: constant): mostly into the scale forward, into the bias where the increment is small.
PRIOR_SIGMA_TRANSLATION = (0.05, 0.1)
PRIOR_SIGMA_ROTATION = (0.05, 0.01)
#: A frame's typical innovation scatter on the translation (m) and rotation (rad) axes, the scale of the prior: with
#: it the bias's prior weighs as much as a few frames.
REFERENCE_SCATTER = (0.02, 0.002)


def motion_innovation(measured, predicted) -> np.ndarray:
    """The innovation ``e (6,)`` of a frame: how far the motion the filter measured is from the one predicted.

    ``measured`` and ``predicted`` are body-frame increments ``(rpy (3,) rad, dp (3,) m)`` of
    :func:`slamlib.slam3d.steps.motion_increment`'s form (``T_new = T_old [R(rpy), dp]``); the result is
    ``(dp_m - dp_p, rpy(R(rpy_p)^T R(rpy_m)))`` in step 6's axis order (:data:`AXES`).
    """
    rpy_m, dp_m = (np.asarray(x, dtype=np.float64) for x in measured)
    rpy_p, dp_p = (np.asarray(x, dtype=np.float64) for x in predicted)
    rot = matrix_to_rpy(rpy_to_matrix(rpy_p).T @ rpy_to_matrix(rpy_m))
    return np.concatenate([dp_m - dp_p, rot])


def innovation_model(u, dt: float) -> np.ndarray:
    """Rows ``H (6, 2)`` of the innovation model ``e_a = s_a u_a + b_a dt``: ``H[a] = (u_a, dt)`` for the predicted
    increment ``u (6,)`` (step 6's axis order) over ``dt`` seconds."""
    u = np.asarray(u, dtype=np.float64)
    return np.column_stack([u, np.full(6, float(dt))])


def innovation_update(info, eta, H, e, forget: float):
    """One frame into the per-axis least-squares sums (information form, forgetting): returns new
    ``(info (6, 2, 2), eta (6, 2))`` with ``info_a <- forget info_a + h_a h_a^T``, ``eta_a <- forget eta_a + h_a e_a``
    for the rows ``H (6, 2)`` (:func:`innovation_model`) and the innovation ``e (6,)``."""
    H = np.asarray(H, dtype=np.float64)
    e = np.asarray(e, dtype=np.float64)
    return (
        forget * np.asarray(info) + np.einsum("ai,aj->aij", H, H),
        forget * np.asarray(eta) + H * e[:, None],
    )


def _prior_information() -> np.ndarray:
    """The weak prior's information ``(6, 2, 2)`` on ``(s, b)`` per axis, zero mean. The fit's sums are unweighted
    (each frame's residual counts 1), so the prior is ``(q_ref / sigma)^2``: a frame's scatter ``q_ref``
    (:data:`REFERENCE_SCATTER`) over the prior's standard deviation."""
    sig = np.array([PRIOR_SIGMA_TRANSLATION] * 3 + [PRIOR_SIGMA_ROTATION] * 3)
    q = np.repeat(REFERENCE_SCATTER, 3)[:, None]
    info = np.zeros((6, UNKNOWNS, UNKNOWNS))
    idx = np.arange(UNKNOWNS)
    info[:, idx, idx] = (q / sig) ** 2
    return info


_PRIOR = _prior_information()


class ForgettingMean:
    """A running mean that forgets with a memory of ``memory`` seconds: after samples ``x_1 .. x_k``, the ``j``-th
    ``t_kj`` seconds old,

        m_k = sum_j lambda_j x_j / sum_j lambda_j,        lambda_j = exp(-t_kj / memory),

    kept as ``W_k = exp(-dt / memory) W_{k-1} + 1`` and ``m_k = m_{k-1} + (x_k - m_{k-1}) / W_k`` (exponential
    forgetting, Ljung & Soederstroem 1983, ch. 2): normalised by its own total weight ``W``, so the first samples
    are not pulled toward the zero it starts from. ``value`` the mean (a number or an array), ``weight`` ``W``.
    """

    def __init__(self, memory: float, value=0.0):
        self.memory, self.value, self.weight = float(memory), value, 0.0

    def add(self, x, dt: float) -> None:
        """The sample ``x``, ``dt`` seconds after the one before, into the mean."""
        self.weight = np.exp(-float(dt) / self.memory) * self.weight + 1.0
        self.value = self.value + (x - self.value) / self.weight


class SelfTuning:
    """The motion source's scale errors, biases and scatter, learnt from the innovations (module docstring).

    Attributes: ``scale (6,)``, ``bias (6,)`` (per second) the fit; ``mean_square (6,)`` the residuals' ``q^2`` and
    ``lag_product (6,)`` the mean product of consecutive residuals (both :class:`ForgettingMean` over
    ``noise_memory``); ``frames`` the frames learnt.

    Parameters
    ----------
    memory : float
        Seconds the fit of ``(s, b)`` remembers (forgetting factor ``exp(-dt / memory)`` per frame).
    noise_memory : float
        Seconds the mean square of the residuals remembers.
    gain : float
        ``sigma = sqrt((gain q)^2 + floor^2)``.
    floor : (6,)
        Least spread per axis (m, m, m, rad, rad, rad).
    warmup : int
        Frames learnt before :meth:`spread` and :meth:`correct` use the estimate.
    correct_bias : bool
        Whether :meth:`correct` applies the fitted ``(s, b)`` (LIDAR-only the held twist has no bias to learn).
    """

    def __init__(
        self,
        memory: float,
        noise_memory: float,
        gain: float,
        floor,
        warmup: int,
        correct_bias: bool = True,
    ):
        self.memory, self.noise_memory = float(memory), float(noise_memory)
        self.gain, self.warmup = float(gain), int(warmup)
        self.floor = np.asarray(floor, dtype=np.float64)
        self.correct_bias = bool(correct_bias)
        self.info = np.zeros((6, UNKNOWNS, UNKNOWNS))
        self.eta = np.zeros((6, UNKNOWNS))
        self.scale, self.bias = np.zeros(6), np.zeros(6)
        self._mean_square = ForgettingMean(noise_memory, np.zeros(6))
        self._lag_product = ForgettingMean(noise_memory, np.zeros(6))
        self.frames = 0
        self._residual = None

    @property
    def mean_square(self) -> np.ndarray:
        """The predictive residuals' running mean square ``(6,)``."""
        return self._mean_square.value

    @property
    def lag_product(self) -> np.ndarray:
        """The running mean ``(6,)`` of the products of consecutive predictive residuals."""
        return self._lag_product.value

    @property
    def source_variance(self) -> np.ndarray:
        """The source's own error variance per axis ``(6,)``: the residuals' mean square less what the filter's
        jitter adds. A pose off by ``eps_k`` puts ``eps_k - eps_{k-1}`` into the frame's innovation, which adds
        ``2 var(eps)`` to the mean square and ``-var(eps)`` to the product of consecutive residuals; the source's
        white noise adds nothing to that product. So ``q_src^2 = mean(r_k^2) + 2 mean(r_k r_{k-1})``, at least a
        quarter of the mean square (a floor for the estimate's own noise)."""
        return np.maximum(
            self.mean_square + 2.0 * self.lag_product, 0.25 * self.mean_square
        )

    @property
    def ready(self) -> bool:
        """Whether ``warmup`` frames have been learnt."""
        return self.frames >= self.warmup

    def correct(self, increment, dt: float):
        """The increment ``(rpy (3,), dp (3,))`` corrected by the fitted scale errors and biases (unchanged before
        the warm-up, or with ``correct_bias`` off)."""
        if not (self.ready and self.correct_bias):
            return increment
        u = _as_vector(increment)
        c = u + np.where(CORRECTED_AXES, self.scale * u + self.bias * float(dt), 0.0)
        return c[3:], c[:3]

    def spread(self, configured) -> np.ndarray:
        """Step 6's spread ``(6,)``: ``sqrt((gain q)^2 + floor^2)`` once warmed up, at most
        :data:`MAX_SPREAD_FACTOR` times ``configured``; ``configured`` before."""
        configured = np.asarray(configured, dtype=np.float64)
        if not self.ready:
            return configured
        learnt = np.sqrt(self.gain**2 * self.source_variance + self.floor**2)
        return np.minimum(learnt, MAX_SPREAD_FACTOR * np.maximum(configured, self.floor))

    def learn(self, predicted, measured, dt: float) -> None:
        """One frame: the residual of ``measured`` against ``predicted`` (both increments, the source's own
        prediction before any correction) under the current fit enters the scatter, then the frame the fit."""
        u = _as_vector(predicted)
        e = motion_innovation(measured, predicted)
        H = innovation_model(u, dt)
        residual = e - (self.scale * u + self.bias * float(dt))
        previous = residual if self._residual is None else self._residual
        self._mean_square.add(residual**2, dt)
        self._lag_product.add(residual * previous, dt)
        self._residual = residual
        self.info, self.eta = innovation_update(
            self.info, self.eta, H, e, np.exp(-float(dt) / self.memory)
        )
        x = np.linalg.solve(self.info + _PRIOR, self.eta[..., None])[..., 0]
        self.scale, self.bias = x[:, 0], x[:, 1]
        self.frames += 1


class FixedSpread:
    """No self-tuning: the source's increment as it is, the configured spread (``MotionConfig.self_tuning`` off)."""

    ready = False

    def correct(self, increment, dt: float):
        """``increment`` unchanged."""
        return increment

    def spread(self, configured) -> np.ndarray:
        """``configured``."""
        return np.asarray(configured, dtype=np.float64)

    def learn(self, predicted, measured, dt: float) -> None:
        """Nothing to learn."""


def _as_vector(increment) -> np.ndarray:
    """``(rpy, dp)`` as one vector ``(6,)`` in step 6's axis order ``(dp, rpy)``."""
    rpy, dp = increment
    return np.concatenate(
        [np.asarray(dp, dtype=np.float64), np.asarray(rpy, dtype=np.float64)]
    )
