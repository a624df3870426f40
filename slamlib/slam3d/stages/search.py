"""The search stage: annealing rounds inside a frame, coarse to fine.

With few particles in 6 dimensions the best of the cloud is still a few centimetres / tenths of a degree from the
likelihood's peak. Each annealing round (Deutscher, Blake & Reid, "Articulated body motion capture by annealed
particle filtering", CVPR 2000) resamples by the current weights, perturbs with step 6's spread shrunk by a factor,
and weighs again (steps 7 + 8). The result is still a particle filter (a sequence of importance-sampling /
resampling stages on the same posterior), just with a sharper proposal. ``AnnealConfig.anneal_rounds`` rounds
shrink the spread by ``anneal_shrink`` each; the motion stage may ask for more at the start of a LIDAR-only drive,
where no motion is known yet: ``start_rounds`` rounds first, the ``k``-th shrinking the (wide) spread by
``START_SHRINK**k``, and the frame's regular rounds shrink on from the last of them.
No rounds: the particles and weights pass through unchanged.

The start's line
----------------
At the second frame of a LIDAR-only drive no motion is known, and the car's speed is the one large unknown: the
spread is metres forward and centimetres in the other directions. Along the forward axis the score has a narrow
peak at the true motion, as wide as the scan resolves (a few tenths of a metre), beside broad basins: the road's
rings and the traffic moving with the car favour no motion at all. A hundred independent draws in six dimensions
rarely land in the narrow peak, and the halving rounds then settle in a basin; the filter holds the wrong speed,
its first frames' spread too narrow to leave it, until the scan match pulls it out (``book/defaults_record.md``, "The
LIDAR-only start"). So with ``start_line`` the start search runs a second time from a line (:func:`forward_line`):
``P`` poses along the cloud's mean forward axis at the quantiles of the forward spread, the same normal distribution
stratified (one draw per ``1/P`` of probability), which puts a pose every few centimetres near the speeds a car has;
its rounds then search the other five dimensions around what it found. The stage keeps the line's search only where
it found another optimum than the drawn search did, a better one, and not the one at standing still: its best
particle scores higher, lies farther from the drawn search's best than the map's resolution (a voxel's edge), below
which the two are one optimum of the score, seen from about the same pose, and differ only by the searches' noise,
and lies farther than that from the last pose (no motion). The score alone cannot choose between two optima: the
rings and the traffic that move with the car make an optimum at no motion, which scores above the true motion on a
street whose walls run along the car (the test suite's straight street) and below it on a street with structure
across it (route 00's starts). That optimum always lies at standing still, so a higher score there may be the bias
alone, while a higher score elsewhere is the structure's; where the drawn search overshot, to more than twice the
true motion (route 00, seed 103 of the fifth fresh sweep; ``start_line_dev/start_ends.json``), the line's optimum is
nearer to standing still than the drawn one's and still the true one. Otherwise the stage keeps the drawn search,
and the filter's run is the one without the line: the line's search draws from its own stream. Replacing the drawn
cloud by the line instead would search the other five dimensions from half the spread only and lose what the draws
find there; keeping the higher score alone would trade the drawn search's answer for a sample of the same optimum,
or, on the street, for the rings' optimum. The second search costs ``1 + start_rounds`` weighings, at one frame of
the drive.

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

from slamlib.resampling import (
    effective_sample_size,
    uniform_log_weights,
    weights_from_log_weights,
)
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
    ``rng`` and ``backend`` are the filter's; ``collapse_ess`` and ``collapse_rounds`` the further rounds while
    the weights collapse (:class:`~slamlib.slam3d.config.AnnealConfig`); ``start_line``: a start search is run
    twice, from the drawn cloud and from :func:`forward_line`, and the line's is kept where its best particle
    scores higher and lies more than ``resolution`` metres both from the drawn search's best (the map's,
    :attr:`slamlib.maps.base.Map3D.resolution`) and from ``last_pose``'s position, else the drawn one (module
    docstring; ``ConstantVelocityConfig.start_line``). The scores are the raw step-8 scores each
    weighing leaves in ``last["scores"]`` (the filter's record of the frame, needed with ``start_line``), read
    after each search, so that no particle is weighed twice; the stage leaves the kept search's there. The search
    from the line draws from its own stream (``rng``'s, jumped ahead), so that where the drawn search is kept the
    filter's stream is as without the line. ``n_rounds`` counts the rounds run, ``n_collapse_rounds`` the further
    ones among them, ``n_line_searches`` the starts searched from the line too, ``n_line_wins`` those where the
    line's search was kept; ``last_start`` records the last such choice: both searches' best positions
    (``drawn``, ``line``, (3,) world frame, m), their raw scores, ``standstill`` and which was ``kept``.
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
        last: dict | None = None,
        resolution: float = 0.0,
    ):
        self.rounds, self.shrink = int(rounds), float(shrink)
        self.start_line = bool(start_line)
        if self.start_line and last is None:
            raise ValueError(
                "start_line needs the filter's last scores to choose between the two searches"
            )
        self.last, self.resolution = last, float(resolution)
        self.line_rng = np.random.Generator(rng.bit_generator.jumped())
        self.weigh, self.rng, self.backend = weigh, rng, backend
        self.collapse_ess, self.collapse_rounds = (
            float(collapse_ess),
            int(collapse_rounds),
        )
        self.n_rounds = 0
        self.n_collapse_rounds = 0
        self.n_line_searches = 0
        self.n_line_wins = 0
        self.last_start: dict | None = None

    def __call__(
        self, particles, log_weights, sample, sigma, start_rounds=0, last_pose=None
    ):
        """The particles and log-weights after ``start_rounds`` start rounds and then ``rounds`` rounds; with
        ``start_line`` at a start (``start_rounds > 0``), the better of that search and the same search from
        :func:`forward_line` (module docstring, "The start's line"). ``last_pose``: the last frame's
        ``T_world_body`` (4, 4), whose position is standing still; needed with ``start_line``."""
        drawn = self._search(
            particles, log_weights, sample, sigma, start_rounds, self.rng
        )
        if not (start_rounds > 0 and self.start_line):
            return drawn
        # the search's last weighing: its particles' scores
        drawn_scores = self.last["scores"]
        line = forward_line(particles, sigma[0])
        self.n_line_searches += 1
        lined = self._search(
            line,
            self.weigh(line, uniform_log_weights(len(line.t)), sample),
            sample,
            sigma,
            start_rounds,
            self.line_rng,
        )
        line_scores = self.last["scores"]
        line_best = lined[0].t[np.argmax(line_scores)]
        drawn_best = drawn[0].t[np.argmax(drawn_scores)]
        line_top, drawn_top = float(line_scores.max()), float(drawn_scores.max())
        standstill = last_pose[:3, 3]
        # two optima, unless within the map's resolution of each other; the line's not the rings' at standstill
        apart = np.linalg.norm(line_best - drawn_best) > self.resolution
        moving = np.linalg.norm(line_best - standstill) > self.resolution
        better = line_top > drawn_top and apart and moving
        self.n_line_wins += int(better)
        self.last_start = dict(
            drawn=drawn_best.copy(),
            line=line_best.copy(),
            drawn_score=drawn_top,
            line_score=line_top,
            standstill=standstill.copy(),
            kept="line" if better else "drawn",
        )
        # the kept search's scores, as if it had been the only one
        self.last["scores"] = line_scores if better else drawn_scores
        return lined if better else drawn

    def _search(self, particles, log_weights, sample, sigma, start_rounds, rng):
        """``start_rounds`` start rounds, ``rounds`` rounds, then the rounds while the weights collapse; each
        round's spread shrinks from the one before, so the rounds after a start go on from where it ended."""
        ended = START_SHRINK**start_rounds  # 1 without a start
        shrinks = [START_SHRINK**k for k in range(1, start_rounds + 1)] + [
            ended * self.shrink**k for k in range(1, self.rounds + 1)
        ]
        for shrink in shrinks:
            particles, log_weights = self._round(
                particles, log_weights, sample, sigma * shrink, rng
            )
        shrink = ended * self.shrink ** (self.rounds + 1)
        for _ in range(self.collapse_rounds):
            if effective_sample_size(weights_from_log_weights(log_weights)) >= (
                self.collapse_ess * len(log_weights)
            ):
                break
            particles, log_weights = self._round(
                particles, log_weights, sample, sigma * shrink, rng
            )
            self.n_collapse_rounds += 1
            shrink *= self.shrink
        return particles, log_weights

    def _round(self, particles, log_weights, sample, sigma, rng):
        """One round: resample, perturb with ``sigma``, weigh."""
        particles, log_weights, _ = steps.resample_particles(
            particles, log_weights, rng, ROUND_ESS_FRACTION, self.backend
        )
        particles = steps.perturb_with_noise(particles, sigma, rng, backend=self.backend)
        self.n_rounds += 1
        return particles, self.weigh(particles, log_weights, sample)
