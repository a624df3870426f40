"""The prior stage: step 8's second term, which holds what the map alone cannot fix.

Holding the tilt to gravity (:class:`TiltPrior`)
------------------------------------------------
The map fixes a particle's roll and pitch only *relative to the map*, and the map is built from the filter's own
earlier estimates: each frame's small tilt error goes into the map, and over thousands of frames it random-walks
(on a whole KITTI route tens of milliradians, which the motion turns into metres of height). Gravity is the one
absolute reference on board. Each frame the stage reads the accelerometer
(:func:`~slamlib.slam3d.steps.read_specific_force`), :func:`slamlib.odometry.gravity_up` separates gravity from the
vehicle's own acceleration over the last ``tilt_window`` seconds, and step 8 adds
:func:`~slamlib.slam3d.steps.tilt_log_prior` to every weight: a measurement of two of the six pose coordinates, as
an attitude filter uses its accelerometer. An accelerometer bias ``b`` tilts the measured up by ``b / g`` for good,
so after step 9 each frame's estimated rotation and measured up also go into a least-squares estimate of the bias
(:func:`slamlib.odometry.tilt_calibration_update`; a bias turns with the body, a tilted map does not), and step 8
compares each particle's ``R_i^T g_w`` with the measured up less the bias. ``g_w``, the world's up, is ``e_z``
(the first body pose taken as level) unless ``FilterConfig.tilt_world_sigma > 0`` lets the fit move it.

:class:`NoPrior` (``FilterConfig.tilt_sigma = 0``, or LIDAR-only: no accelerometer) adds nothing.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from slamlib.odometry import (
    gravity_up,
    increment_matrix,
    tilt_calibration_add,
    tilt_calibration_bins,
    tilt_calibration_estimate,
    tilt_calibration_prior,
)
from slamlib.slam3d import steps
from slamlib.slam3d.config import FilterConfig

__all__ = ["NoPrior", "TiltPrior"]


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
    up : (3,) the accelerometer's up direction in this frame's body (:func:`slamlib.odometry.gravity_up`); None
        until a frame with an accelerometer has been measured.
    samples : deque of ``(specific_force, velocity, dt)`` of the frames in the window; ``up_span`` the seconds
        it spans.
    world_up, up_bias : (3,) the estimated world's up (world frame) and accelerometer bias (an angle, body frame)
        (``e_z`` and 0 until frames come in). Behind them: ``calibration_prior`` ``(Lambda, eta, free)`` and
        ``bins`` ``(Lambdas, etas, weights)``, the least-squares sums of each heading sector.
    """

    def __init__(self, config: FilterConfig):
        self.sigma, self.window = config.tilt_sigma, config.tilt_window
        self.samples: deque = deque()
        self.up, self.up_span = None, 0.0
        self.calibration_prior = tilt_calibration_prior(
            config.tilt_world_sigma, config.tilt_bias_sigma
        )
        self.bins = tilt_calibration_bins(config.tilt_heading_bins)
        self.world_up, self.up_bias = tilt_calibration_estimate(
            self.calibration_prior, self.bins
        )

    def measure(self, frame, imu, dt: float, increment, poses) -> None:
        """This frame's up, from the accelerometer over the last ``tilt_window`` seconds
        (:func:`slamlib.odometry.gravity_up`): the samples of this frame and the registered frames before it,
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
        past = [T[:3, :3] for T in poses[len(poses) - len(samples) + 1 :]]
        R = np.array(past + [poses[-1][:3, :3] @ increment_matrix(*increment)[:3, :3]])
        force, velocity, dts = (np.array(x) for x in zip(*samples))
        self.up_span = float(dts[1:].sum())
        self.up = gravity_up(R, force, velocity, dts)

    def weigh(self, particles, log_weights):
        """``log_weights`` plus :func:`~slamlib.slam3d.steps.tilt_log_prior` of the measured up less the bias."""
        if self.up is None:
            return log_weights
        up = self.up - self.up_bias
        return log_weights + steps.tilt_log_prior(
            particles, up, self.sigma, self.world_up
        )

    def calibrate(self, pose, dt: float) -> None:
        """Add this frame's estimated rotation and measured up to the calibration (none while the window does
        not yet span ``tilt_window``: a shorter one measures up with errors ~ 1 / its span), in its heading's
        sector: each frame weighs ``dt / tilt_window`` of an independent up measurement of standard deviation
        ``tilt_sigma`` (consecutive windows overlap), and the sectors weigh alike
        (:func:`slamlib.odometry.balance_heading_bins`)."""
        if self.up is None or self.up_span < self.window:
            return
        weight = dt / self.window / self.sigma**2
        tilt_calibration_add(self.bins, pose[:3, :3], self.up, weight)
        self.world_up, self.up_bias = tilt_calibration_estimate(
            self.calibration_prior, self.bins
        )
