"""Test set-up. The CUDA simulator must be switched on before numba is imported anywhere."""

import os

#: The simulator's switch as pytest found it: the notebooks run with it (fixture ``book_environment``), as the book
#: build runs them.
CUDASIM_AT_START = os.environ.get("NUMBA_ENABLE_CUDASIM")
# Run numba.cuda kernels in Numba's CUDA simulator unless a real GPU run is asked for
# (SLAMLIB_REAL_CUDA=1 on a machine with a GPU and numba-cuda[cu12]).
if os.environ.get("SLAMLIB_REAL_CUDA") != "1":
    os.environ["NUMBA_ENABLE_CUDASIM"] = "1"

import signal  # noqa: E402

import matplotlib  # noqa: E402

matplotlib.use("Agg")

# Several tests stop a command with Ctrl-C (SIGINT) and check what it leaves. A shell without job control starts a
# background job (`make test &`) with SIGINT ignored, and a subprocess inherits that: restore Python's handler, so
# that the tests, and the commands they start, see SIGINT as a user's Ctrl-C.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


import numpy as np  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture
def book_environment(monkeypatch):
    """The environment ``jupyter-book build`` would give a notebook's kernel: the one pytest started in, without
    the CUDA simulator this file switches on for the tests (a kernel inherits the environment)."""
    if CUDASIM_AT_START is None:
        monkeypatch.delenv("NUMBA_ENABLE_CUDASIM", raising=False)
    else:
        monkeypatch.setenv("NUMBA_ENABLE_CUDASIM", CUDASIM_AT_START)


@pytest.fixture(scope="module")
def street_maps():
    """A small street-like world (a blob and a flat slab, 3,000 float32 points) merged into both map kinds:
    ``(world (M, 3) f4, [voxel_hash lookup, morton_bvh lookup])``, shared by the kernel tests."""
    from slamlib.maps import MortonBVHMap, VoxelHashMap

    rng = np.random.default_rng(5)
    world = np.concatenate(
        [rng.normal(0, 3, (1500, 3)), rng.uniform(-4, 4, (1500, 3)) * [1, 1, 0.02]]
    )
    world = world.astype(np.float32)
    out = []
    for m in (
        VoxelHashMap(voxel_size=1.0, capacity=2**12),
        MortonBVHMap(radius=0.5, sigma=0.2, quantum=0.01),
    ):
        m.merge(world)
        out.append(m.lookup())
    return world, out


@pytest.fixture(scope="module")
def drive():
    """A 30-frame drive through the tiny 3D world of ``world3d.py``: ``(frames, ground-truth poses)``, built once a
    module, shared by the 3D filter's tests (steps, pipeline, whole runs)."""
    from world3d import simulate

    return simulate()


# The tiny KITTI raw drive shared by the reader tests (test_kitti_errors.py, test_kitti_reader.py, test_kitti_oxts.py).
TINY_DRIVE_FRAMES = 4
TINY_DRIVE_POINT_STRIDE = 500  # every 500th point of the embedded sample scans: ~250 points a scan, fast to read


@pytest.fixture
def tiny_drive_frames():
    """How many frames the ``drive_dir`` drive has."""
    return TINY_DRIVE_FRAMES


@pytest.fixture
def drive_dir(tmp_path):
    """A tiny KITTI raw drive written under ``tmp_path``: the path of its ``DATE_drive_XXXX_sync`` folder."""
    from slamlib.kitti.sample import make_tiny_drive

    return make_tiny_drive(
        tmp_path, n_frames=TINY_DRIVE_FRAMES, point_stride=TINY_DRIVE_POINT_STRIDE
    )


@pytest.fixture
def open_drive(drive_dir):
    """``open_drive(**options)`` opens the ``drive_dir`` drive as a ``KittiRawDrive`` with the reader's options."""
    from slamlib.kitti import KittiRawDrive
    from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE

    return lambda **kw: KittiRawDrive(
        drive_dir.parent.parent, SAMPLE_DATE, SAMPLE_DRIVE, **kw
    )


@pytest.fixture
def cli_drive(tmp_path):
    """``slamlib run``'s arguments for a tiny KITTI raw drive (4 frames, every 50th point of the sample scans; 10
    particles, 50 points, no progress bar, no plots) and the drive's folder: ``(args, drive_dir)``."""
    from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive

    d = make_tiny_drive(tmp_path / "kitti", n_frames=TINY_DRIVE_FRAMES, point_stride=50)
    return [
        "run",
        "--basedir",
        str(d.parent.parent),
        "--date",
        SAMPLE_DATE,
        "--drive",
        SAMPLE_DRIVE,
        "--no-progress",
        "--no-plots",
        "--particles",
        "10",
        "--points",
        "50",
    ], d
