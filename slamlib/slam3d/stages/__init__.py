"""The stages of the 3D filter: each one job around the twelve steps, chosen once from the settings and the data.

:class:`~slamlib.slam3d.pipeline.ParticleSLAM3D` builds one object per stage when it sees the first frame
(:func:`choose_stages`), and its per-frame method calls them in the order of the steps, with no mode flag read
per frame. Each stage has a *null* form that does nothing, so a feature that is off costs no branch:

============== ============================================== ===============================================
stage          serves                                         forms
============== ============================================== ===============================================
motion         step 3's source, step 5's increment, step 6's  :class:`ImuMotion` (IMU velocities and rates,
               spread, the scoring sample, the start search   dead-reckoning twin), :class:`ConstantVelocity`
               (both learning their source's errors:          (LIDAR-only: the filter's own motion held)
               :mod:`~slamlib.slam3d.stages.tuning`)
scan           step 2: crop, down-sample, de-skew             :class:`ScanPreparation`
prior          step 8's second term                           :class:`TiltPrior` (roll and pitch held to
                                                              gravity), :class:`NoPrior`
search         steps 6-8 again inside the frame               :class:`Annealing` (no rounds: nothing)
polish         step 9's pose sharpened                        :class:`ScanMatch`, :class:`NoPolish`
upkeep         after step 10: what the map forgets            :class:`MapUpkeep`
============== ============================================== ===============================================
"""

from __future__ import annotations

from slamlib.slam3d.config import ADAPTIVE, AUTO
from slamlib.slam3d.stages.motion import ConstantVelocity, ImuMotion, has_imu, held_twist
from slamlib.slam3d.stages.polish import NoPolish, ScanMatch
from slamlib.slam3d.stages.prior import NoPrior, TiltPrior
from slamlib.slam3d.stages.scan import ScanPreparation
from slamlib.slam3d.stages.search import Annealing
from slamlib.slam3d.stages.upkeep import MapUpkeep

__all__ = [
    "Annealing",
    "ConstantVelocity",
    "ImuMotion",
    "MapUpkeep",
    "NoPolish",
    "NoPrior",
    "ScanMatch",
    "ScanPreparation",
    "TiltPrior",
    "choose_stages",
    "has_imu",
    "held_twist",
]


def choose_stages(config, frame, T0):
    """The data-dependent stages for a drive whose first frame is ``frame``: ``(motion, prior, polish)``.

    LIDAR-only (:class:`ConstantVelocity`) when ``config.motion.model == "constant_velocity"`` or the frame has no
    IMU values (the KITTI odometry layout); then there is no tilt prior (no accelerometer) and the scan matcher
    holds the road's points to height and tilt. With an IMU: :class:`ImuMotion`, the tilt prior when
    ``config.prior.tilt_sigma`` is not 0. Scan matching (``config.polish.scan_match``): True on, False off,
    ``"auto"`` on unless the tilt prior is, whose pull toward gravity a matcher on the map score alone would undo,
    climbing back to the roll and pitch the map was built with; with ``config.polish.match_tilt``, or the prior
    ``"adaptive"`` (which reads the map's information on the tilt from the match), the match's cost carries the
    prior too, and ``"auto"`` is on with it.
    """
    points = config.filter.scored_points
    lidar_only = config.motion.model == "constant_velocity" or not has_imu(frame)
    if lidar_only:
        motion = ConstantVelocity(config.motion, points)
    else:
        motion = ImuMotion(config.motion, points, T0)
    tilt = bool(config.prior.tilt_sigma) and not lidar_only
    prior = TiltPrior(config.prior) if tilt else NoPrior()
    held = tilt and (config.polish.match_tilt or config.prior.tilt_sigma == ADAPTIVE)
    match = config.polish.scan_match
    match = (held or not tilt) if match == AUTO else match
    polish = (
        ScanMatch(
            config.polish.scan_match_iterations,
            road=lidar_only,
            voxel=config.polish.match_voxel,
            tolerance=config.polish.match_tolerance,
            gate=config.polish.match_gate,
            prior=prior if held else None,
            temperature=config.filter.temperature,
        )
        if match
        else NoPolish()
    )
    return motion, prior, polish
