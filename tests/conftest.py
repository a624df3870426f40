"""Test set-up. The CUDA simulator must be switched on before numba is imported anywhere."""

import os

# Run numba.cuda kernels in Numba's CUDA simulator unless a real GPU run is asked for
# (SLAMLIB_REAL_CUDA=1 on a machine with a GPU and numba-cuda[cu12]).
if os.environ.get("SLAMLIB_REAL_CUDA") != "1":
    os.environ["NUMBA_ENABLE_CUDASIM"] = "1"

import matplotlib  # noqa: E402

matplotlib.use("Agg")
