"""slamlib: particle-filter SLAM from a 1D toy world to 3D LIDAR + IMU SLAM on KITTI drives.

The pipeline is the same twelve steps at every dimension (see ``book/intro.md``):

1. initialise particles at the origin
2. read the LIDAR scan
3. read IMU velocities and gyro rates
4. read the exact frame timing
5. offset each particle by the IMU motion
6. perturb each particle with Gaussian noise
7. transform the scan into the world frame per particle
8. score each particle's scan against the map
9. pick the best particle
10. merge the scan into the map with the best pose
11. resample particles by score
12. repeat
"""

__version__ = "0.1.0"

import os as _os
import sys as _sys

#: The threading layers Numba tries, in order, unless the user names them (``NUMBA_THREADING_LAYER`` or
#: ``NUMBA_THREADING_LAYER_PRIORITY``). Numba's own order starts with TBB; a TBB older than Numba supports (as
#: Debian's 2021.5 with Numba 0.68) is refused with a ``NumbaWarning`` printed amid the progress bars, and OpenMP,
#: its next choice, is taken anyway. Asking for OpenMP first gives the same layer without the warning.
THREADING_LAYER_PRIORITY = ("omp", "tbb", "workqueue")
if not {"NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY"} & _os.environ.keys():
    _os.environ["NUMBA_THREADING_LAYER_PRIORITY"] = " ".join(THREADING_LAYER_PRIORITY)
    if (
        "numba" in _sys.modules
    ):  # imported before slamlib: its configuration is read already
        _sys.modules["numba"].config.THREADING_LAYER_PRIORITY = list(
            THREADING_LAYER_PRIORITY
        )

from slamlib.errors import DataFormatError  # noqa: E402

__all__ = ["__version__", "DataFormatError"]
