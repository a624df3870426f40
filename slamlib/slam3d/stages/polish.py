"""The polish stage: step 9's pose sharpened by scan matching, the particles moved with it.

Annealing sharpens the particle search; scan matching finishes it with a local optimiser. :class:`ScanMatch`
moves the pose of step 9 by a few Newton steps to the nearest peak of the same map score, computed on the
down-sampled scan thinned to one point per ``ScanMatchConfig.match_voxel`` cube rather than step 8's sample
(:func:`slamlib.slam3d.match.match_scan`), and every particle by the same correction ``C = T_matched T^-1``
(applied in the world frame) before step 11 resamples them: the particles are then drawn around the scan-matched
pose, the *improved proposal* of Grisetti, Stachniss & Burgard (IEEE T-RO 2007). LIDAR-only this matters most:
the constant-velocity prior is weak, and the map's pull toward the truth has to do what the IMU does otherwise;
there the road's points keep only the vertical row of the Jacobian (:func:`slamlib.slam3d.preprocess.road_mask`),
so the LIDAR's rings on the road cannot pull a moving scan back. With an IMU it is on too: the particles' tilt
walks by step 6's noise between resamplings, and a pitch off by a few milliradians climbs or sinks the drive's
height; the matcher's climb takes the pitch the whole scan fits best ("Why these defaults", ``defaults_record.md``).
Voxel hash map only (other maps are left as they are). :class:`NoPolish` keeps step 9's pose.

With the tilt prior on and ``ScanMatchConfig.match_tilt``, the match's cost carries the prior's term as well
(:func:`slamlib.slam3d.match.tilt_equations`; ``match``'s "Gravity's term"): the climb then ends where the map and
gravity agree best, rather than undoing step 8's pull toward the measured up.

The gate
--------
The Newton climb is local: started near a wrong peak of the score (a car driving alongside, a repeated facade) it
ends there, and the frame's scan is merged into the map at that pose, which corrupts the map for the frames after.
Step 6 drew the particles from the motion's uncertainty, so step 9's pose is already within a few spreads of the
truth. The match's correction ``D = T^-1 T_matched``, in step 6's coordinates ``c = (t_D, rpy(R_D))`` (body frame),
is kept only when its normalised distance ``d = sqrt(sum_a (c_a / sigma_a)^2)`` is at most ``gate``: the validation
gate of a tracking filter (Bar-Shalom & Fortmann, "Tracking and Data Association", 1988, sec. 2.3), with the
frame's spread ``sigma`` for the prediction's standard deviations. A rejected match leaves step 9's pose.
"""

from __future__ import annotations

import numpy as np

from slamlib.slam3d.match import MATCH_TOLERANCE, match_scan
from slamlib.slam3d.preprocess import crop_and_downsample, road_mask
from slamlib.slam3d.stages.motion import measured_increment
from slamlib.slam3d.steps import Particles3D

__all__ = ["NoPolish", "ScanMatch", "correction_distance", "GUARD_ITERATIONS"]

#: Newton steps of the guard's match on the map alone, from the match with gravity's term: near the map's own peak
#: already (the two terms pull apart by milliradians, or the guard is what is wanted), one step reaches it to
#: well within the gate, at a fraction of a whole match's passes over the points.
GUARD_ITERATIONS = 1


def correction_distance(pose, matched, sigma) -> float:
    """``d = sqrt(sum_a (c_a / sigma_a)^2)``: how far ``matched`` lies from ``pose`` (both ``T_world_body``
    (4, 4)) in step 6's spreads ``sigma`` (6,) (body x, y, z in metres, roll, pitch, yaw in radians), with
    ``c = (t_D, rpy(R_D))`` of the body-frame correction ``D = pose^-1 matched``
    (:func:`~slamlib.slam3d.stages.motion.measured_increment`; module docstring, "The gate")."""
    rpy, dp = measured_increment(pose, matched)
    c = np.concatenate([dp, rpy])
    return float(np.sqrt(np.sum((c / np.asarray(sigma, dtype=np.float64)) ** 2)))


class NoPolish:
    """Step 9's pose as it is."""

    n_matched = n_rejected = 0
    max_kept_distance = 0.0

    def __call__(self, pose, points, particles, world_map, sigma=None):
        """``(pose, particles)`` unchanged."""
        return pose, particles


class ScanMatch:
    """Scan matching of step 9's pose (module docstring): at most ``iterations`` Newton steps on the points
    thinned to one per ``voxel`` cube (0: all), ending at the first step shorter than ``tolerance``; ``road``: the
    road's points hold height and tilt only (LIDAR-only); ``gate``: the farthest a kept match may move the pose, in
    step 6's spreads (0: no gate; module docstring, "The gate"); ``prior``: a
    :class:`~slamlib.slam3d.stages.TiltPrior` whose measured up the match's cost also holds, weighed as step 8
    weighs it against a scan at ``temperature`` (None: the map score alone). ``n_matched`` counts the frames matched,
    ``n_rejected`` those whose match the gate rejected, ``last_distance`` the last frame's
    :func:`correction_distance` and ``max_kept_distance`` the largest of a kept match (0 before one; how near the
    gate came to closing on a run)."""

    def __init__(
        self,
        iterations: int,
        road: bool = False,
        voxel: float = 0.0,
        tolerance: float = MATCH_TOLERANCE,
        gate: float = 0.0,
        prior=None,
        temperature: float = 1.0,
    ):
        self.iterations, self.road, self.voxel = int(iterations), bool(road), float(voxel)
        self.tolerance, self.gate = float(tolerance), float(gate)
        self.prior, self.temperature = prior, float(temperature)
        self.n_matched = self.n_rejected = 0
        self.last_distance = float("nan")
        self.max_kept_distance = 0.0

    def __call__(self, pose, points, particles, world_map, sigma=None):
        """``(matched pose (4, 4), particles moved by C = T_matched pose^-1)`` for the body-frame ``points``
        (thinned to one per ``voxel`` cube first when ``voxel > 0``); ``(pose, particles)`` unchanged when the
        match moved the pose more than ``gate`` of the frame's spreads ``sigma`` (6,) (None: no gate)."""
        if self.voxel > 0:
            points = crop_and_downsample(points, voxel_size=self.voxel)
        road = road_mask(points) if self.road else None
        args = (pose, points, world_map, self.iterations, road, self.tolerance)
        tilt = self._tilt(len(points))
        # "adaptive" weighs itself by the map's information on the tilt, which the match measures
        if getattr(self.prior, "adaptive", False):
            matched, hessian = match_scan(*args, tilt, return_hessian=True)
            self.prior.observe_map(hessian, len(points), self.temperature)
        else:
            matched = match_scan(*args, tilt)
        matched = self._guard(matched, points, world_map, road, tilt)
        self.n_matched += 1
        if sigma is not None:
            self.last_distance = correction_distance(pose, matched, sigma)
            if 0 < self.gate < self.last_distance:
                self.n_rejected += 1
                return pose, particles
            self.max_kept_distance = max(self.max_kept_distance, self.last_distance)
        C = matched @ np.linalg.inv(pose)
        moved = Particles3D(
            np.einsum("ij,pjk->pik", C[:3, :3], particles.R),
            particles.t @ C[:3, :3].T + C[:3, 3],
        )
        return matched, moved

    def _guard(self, matched, points, world_map, road, tilt):
        """The guard (:mod:`slamlib.slam3d.stages.prior`, "The guard"): the map's own fit of the scan, matched on from
        ``matched`` without gravity's term, checked against the prior's measured up; where they disagree, the map's
        fit is the frame's pose and the prior steps back. ``matched`` as it is without a prior."""
        if self.prior is None:
            return matched
        free = matched
        if tilt is not None:
            free = match_scan(
                matched, points, world_map, GUARD_ITERATIONS, road, self.tolerance
            )
        return matched if self.prior.check(free[:3, :3]) else free

    def _tilt(self, n: int):
        """``match_scan``'s ``tilt`` for ``n`` matched points: the prior's up less its bias, its world's up and
        ``w = n * temperature / sigma^2`` (:mod:`slamlib.slam3d.match`, "Gravity's term"); None without a prior
        or while it holds nothing (:meth:`TiltPrior.held_up`: until its window spans ``tilt_window``)."""
        prior = self.prior
        up = None if prior is None else prior.held_up()
        if up is None:
            return None
        return up, prior.world_up, n * self.temperature / prior.sigma**2
