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
height; the matcher's climb takes the pitch the whole scan fits best ("Why these defaults", ``book/defaults.md``).
Voxel hash map only (other maps are left as they are). :class:`NoPolish` keeps step 9's pose.
"""

from __future__ import annotations

import numpy as np

from slamlib.slam3d.match import MATCH_TOLERANCE, match_scan
from slamlib.slam3d.preprocess import crop_and_downsample, road_mask
from slamlib.slam3d.steps import Particles3D

__all__ = ["NoPolish", "ScanMatch"]


class NoPolish:
    """Step 9's pose as it is."""

    n_matched = 0

    def __call__(self, pose, points, particles, world_map):
        """``(pose, particles)`` unchanged."""
        return pose, particles


class ScanMatch:
    """Scan matching of step 9's pose (module docstring): at most ``iterations`` Newton steps on the points
    thinned to one per ``voxel`` cube (0: all), ending at the first step shorter than ``tolerance``; ``road``: the
    road's points hold height and tilt only (LIDAR-only). ``n_matched`` counts the frames matched."""

    def __init__(
        self,
        iterations: int,
        road: bool = False,
        voxel: float = 0.0,
        tolerance: float = MATCH_TOLERANCE,
    ):
        self.iterations, self.road, self.voxel = int(iterations), bool(road), float(voxel)
        self.tolerance = float(tolerance)
        self.n_matched = 0

    def __call__(self, pose, points, particles, world_map):
        """``(matched pose (4, 4), particles moved by C = T_matched pose^-1)`` for the body-frame ``points``
        (thinned to one per ``voxel`` cube first when ``voxel > 0``)."""
        if self.voxel > 0:
            points = crop_and_downsample(points, voxel_size=self.voxel)
        road = road_mask(points) if self.road else None
        matched = match_scan(
            pose, points, world_map, self.iterations, road, self.tolerance
        )
        C = matched @ np.linalg.inv(pose)
        self.n_matched += 1
        moved = Particles3D(
            np.einsum("ij,pjk->pik", C[:3, :3], particles.R),
            particles.t @ C[:3, :3].T + C[:3, 3],
        )
        return matched, moved
