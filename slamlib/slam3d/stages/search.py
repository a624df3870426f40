"""The search stage: annealing rounds inside a frame, coarse to fine.

With few particles in 6 dimensions the best of the cloud is still a few centimetres / tenths of a degree from the
likelihood's peak. Each annealing round (Deutscher, Blake & Reid, "Articulated body motion capture by annealed
particle filtering", CVPR 2000) resamples by the current weights, perturbs with step 6's spread shrunk by a factor,
and weighs again (steps 7 + 8). The result is still a particle filter (a sequence of importance-sampling /
resampling stages on the same posterior), just with a sharper proposal. ``AnnealConfig.anneal_rounds`` rounds
shrink the spread by ``anneal_shrink`` each; the motion stage may ask for more at the start of a LIDAR-only drive,
where no motion is known yet: ``start_rounds`` rounds first, the ``k``-th shrinking the (wide) spread by
``START_SHRINK**k``.
No rounds: the particles and weights pass through unchanged.

The start's line
----------------
At the second frame of a LIDAR-only drive no motion is known, and the car's speed is the one large unknown: the
spread is metres forward and centimetres in the other directions. Along the forward axis the score has a narrow
peak at the true motion, as wide as the scan resolves (a few tenths of a metre), beside broad basins: the road's
rings and the traffic moving with the car favour no motion at all. A hundred independent draws in six dimensions
rarely land in the narrow peak, and the halving rounds then settle in a basin; the filter holds the wrong speed,
its first frames' spread too narrow to leave it (on a drive that starts at 8 m/s: 0.3 m a frame backwards, 23 m
lost before the match pulled it out). So with ``start_line`` the start search first weighs a line instead
(:func:`forward_line`): ``P`` poses along the cloud's mean forward axis at the quantiles of the forward spread, the
same normal distribution stratified (one draw per ``1/P`` of probability), which puts a pose every few centimetres
near the speeds a car has; the rounds then search the other five dimensions around what it found.

Rounds when the weights collapse
--------------------------------
A fixed count is tuned to one drive: a frame whose likelihood is much narrower than step 6's spread (a sharp scan, a
wide spread after a jolt) leaves few particles near its peak, which the effective sample size
``ESS = 1 / sum w_i^2`` (Kong, Liu & Wong 1994) shows as a collapse, while on an easy frame extra rounds only cost
time. With ``AnnealConfig.collapse_ess > 0`` the stage runs further rounds, each shrinking the spread by
``anneal_shrink`` once more, while ``ESS < collapse_ess * P``, at most ``collapse_rounds`` of them: the
adaptive annealing of Deutscher & Reid (IJCV 2005), which sets each round by the survival rate of the weights.
"""

from __future__ import annotations

from statistics import NormalDist

import numpy as np

from slamlib.resampling import effective_sample_size, weights_from_log_weights
from slamlib.slam3d import steps
from slamlib.slam3d.steps import Particles3D

__all__ = ["START_SHRINK", "Annealing", "forward_line"]

#: Spread factor per round of the start search: each round halves the spread of the one before.
START_SHRINK = 0.5
#: Step 11 inside a round resamples whatever the effective sample size (``ess_fraction`` 1: always).
ROUND_ESS_FRACTION = 1.0


def forward_line(particles: Particles3D, spread: float) -> Particles3D:
    """``P`` poses (``P`` = the particles') on the forward axis (body x) of the cloud's mean pose, at offsets
    ``spread * Phi^-1((i + 1/2) / P)``, ``Phi`` the standard normal CDF: a draw of ``N(0, spread^2)`` forward,
    stratified (module docstring, "The start's line"). The mean pose: the particles' mean position and the rotation
    nearest their mean rotation matrix (the chordal L2 mean, projected onto SO(3) by an SVD; Hartley et al.,
    "Rotation Averaging", IJCV 2013, sec. 5.3). ``spread`` in metres."""
    P = len(particles.t)
    offsets = float(spread) * np.array(
        [NormalDist().inv_cdf((i + 0.5) / P) for i in range(P)]
    )
    U, _, Vt = np.linalg.svd(particles.R.mean(axis=0))
    R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    t = particles.t.mean(axis=0) + offsets[:, None] * R[:, 0]
    return Particles3D(np.repeat(R[None], P, axis=0), t)


class Annealing:
    """``rounds`` annealing rounds per frame, each shrinking step 6's spread by ``shrink`` (module docstring).

    ``weigh(particles, log_weights, sample) -> log_weights`` is the filter's steps 7 + 8 (with the prior's term);
    ``rng`` and ``backend`` are the filter's; ``collapse_ess`` and ``collapse_rounds`` the further rounds while the
    weights collapse (:class:`~slamlib.slam3d.config.AnnealConfig`); ``start_line``: a start search begins by
    weighing :func:`forward_line` (module docstring; ``ConstantVelocityConfig.start_line``). ``n_rounds`` counts
    the rounds run, ``n_collapse_rounds`` the further ones among them.
    """

    def __init__(
        self,
        rounds: int,
        shrink: float,
        weigh,
        rng,
        backend,
        collapse_ess: float,
        collapse_rounds: int,
        start_line: bool = False,
    ):
        self.rounds, self.shrink = int(rounds), float(shrink)
        self.start_line = bool(start_line)
        self.weigh, self.rng, self.backend = weigh, rng, backend
        self.collapse_ess, self.collapse_rounds = (
            float(collapse_ess),
            int(collapse_rounds),
        )
        self.n_rounds = 0
        self.n_collapse_rounds = 0

    def __call__(self, particles, log_weights, sample, sigma, start_rounds: int = 0):
        """The particles and log-weights after ``start_rounds`` start rounds (first the line, with
        ``start_line``) and then ``rounds`` rounds."""
        if start_rounds > 0 and self.start_line:
            particles = forward_line(particles, sigma[0])
            uniform = np.full(len(particles.t), -np.log(len(particles.t)))
            log_weights = self.weigh(particles, uniform, sample)
        shrinks = [START_SHRINK**k for k in range(1, start_rounds + 1)] + [
            self.shrink
        ] * self.rounds
        for shrink in shrinks:
            particles, log_weights = self._round(
                particles, log_weights, sample, sigma * shrink
            )
        shrink = self.shrink ** (self.rounds + 1)
        for _ in range(self.collapse_rounds):
            if effective_sample_size(weights_from_log_weights(log_weights)) >= (
                self.collapse_ess * len(log_weights)
            ):
                break
            particles, log_weights = self._round(
                particles, log_weights, sample, sigma * shrink
            )
            self.n_collapse_rounds += 1
            shrink *= self.shrink
        return particles, log_weights

    def _round(self, particles, log_weights, sample, sigma):
        """One round: resample, perturb with ``sigma``, weigh."""
        particles, log_weights, _ = steps.resample_particles(
            particles, log_weights, self.rng, ROUND_ESS_FRACTION, self.backend
        )
        particles = steps.perturb_with_noise(
            particles, sigma, self.rng, backend=self.backend
        )
        self.n_rounds += 1
        return particles, self.weigh(particles, log_weights, sample)
