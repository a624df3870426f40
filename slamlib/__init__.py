"""slamlib: particle-filter SLAM from a 1D toy world to 3D LIDAR + IMU SLAM on KITTI drives.

The pipeline is the same twelve steps at every dimension (see ``book/intro.md``):

1. initialise particles at the origin       7. transform the scan into the world frame per particle
2. read the LIDAR scan                        8. score each particle's scan against the map
3. read IMU velocities and gyro rates          9. pick the best particle
4. read the exact frame timing                10. merge the scan into the map with the best pose
5. offset each particle by the IMU motion     11. resample particles by score
6. perturb each particle with Gaussian noise  12. repeat
"""

__version__ = "0.1.0"

from slamlib.errors import DataFormatError  # noqa: E402

__all__ = ["__version__", "DataFormatError"]
