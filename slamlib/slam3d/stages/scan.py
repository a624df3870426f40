"""The scan stage (step 2): crop, down-sample and move the scan into the body frame; de-skew a swept scan.

A scan taken over a sweep (real KITTI raw drives, synthetic drives written with ``distortion``) is moved, point by
point, to where it was at the frame's pose time, with step 3's motion (:func:`slamlib.slam3d.steps.deskew_scan`);
a scan cast from one pose (the KITTI odometry benchmark's, already motion-compensated) is left as it is
(:func:`~slamlib.slam3d.steps.should_deskew`: ``ScanConfig.deskew``, by default the frame's own ``swept``).
"""

from __future__ import annotations

import numpy as np

from slamlib.slam3d import steps
from slamlib.slam3d.config import ScanConfig

__all__ = ["ScanPreparation"]


class ScanPreparation:
    """Step 2 for every frame: :meth:`read` the scan, de-skewed with step 3's motion when it is swept.

    ``T_body_velo`` (4, 4): the Velodyne pose in the body frame (None: scans already in the body frame).
    ``n_deskewed`` counts the frames de-skewed.
    """

    def __init__(self, config: ScanConfig, T_body_velo=None):
        self.config, self.T_body_velo = config, T_body_velo
        self.n_deskewed = 0

    def read(self, frame, imu) -> np.ndarray:
        """The frame's scan cropped, down-sampled, in the body frame (:func:`slamlib.slam3d.steps.read_scan`), and
        moved to the pose time with the body twist ``imu = (velocity, angular_rate)`` when the scan is swept
        (module docstring)."""
        points = steps.read_scan(frame, self.config, self.T_body_velo)
        if not steps.should_deskew(frame, self.config):
            return points
        offset = steps.read_scan_time_offset(frame, self.config)
        points = steps.deskew_scan(points, imu, self.config, self.T_body_velo, offset)
        self.n_deskewed += 1
        return points
