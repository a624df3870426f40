"""``slamlib bench startup``: what a user waits for before the first steady frame, cold and warm.

Each run is a fresh interpreter running the real command, ``slamlib run --frames 0:FRAMES`` on the embedded default
drive (generated into the cache once, before any timing), in both motion modes (the IMU's, and ``--lidar-only``):

* ``cold``: an empty Numba cache (``NUMBA_CACHE_DIR`` a new temporary folder per run): every kernel the mode uses
  is compiled, as on a user's first run;
* ``warm``: the same command again with the cache a cold run left: the kernels are loaded, not compiled.

Reported per mode and cache, medians and bests (``min``) over the repeats:

* ``wall_s``: the whole process, interpreter start to exit (results written, plots off);
* ``startup_s``: what ``slamlib run`` prints as its start-up: from the command's entry (before slamlib's heavy
  imports) until the first :data:`slamlib.slam3d.run.STARTUP_FRAMES` frames are done (imports, the kernels compiled
  or loaded, the map begun);
* ``steady_fps``: the frames/s after them, as printed;
* ``overhead_s``: the start-up less what those frames take at the steady rate, ``startup_s - STARTUP_FRAMES /
  steady_fps``: the time spent importing, compiling or loading kernels, and opening the drive.

Beside them, ``kiss_icp``: a fresh interpreter that imports KISS-ICP 1.3.0 (through :mod:`slamlib.peers`) and
registers the first :data:`STARTUP_FRAMES` frames of the same drive, timed from the process's start: the start-up
of a peer without a compile step. And ``numba_floor``: a fresh interpreter that imports numpy and Numba and calls
one trivial kernel (``x + 1.0``) from a warm cache, timed the same way: what any Numba program pays before its
first result, whatever its kernels. On its first call Numba builds its CPU target, importing its own lowering
registries and, through them, ``scipy.linalg`` (its BLAS check), and loads the kernel from the cache.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from slamlib.commands.run import STARTUP_LINE_RE

HELP = "start-up: fresh `slamlib run` with an empty and a warm Numba cache (IMU and LIDAR-only), beside KISS-ICP"

#: Frames of each run: the start-up frames and enough after them for a steady rate.
FRAMES = 30
QUICK_FRAMES = 8
MODES = {"imu": [], "lidar_only": ["--lidar-only"]}

KISS_SCRIPT = """
import sys, time
t0 = time.perf_counter()
from slamlib.kitti import KittiRawDrive
from slamlib.peers import kiss_icp_poses
from slamlib.slam3d.run import STARTUP_FRAMES
basedir, date, drive = sys.argv[1], sys.argv[2], int(sys.argv[3])
frames = KittiRawDrive(basedir, date, drive, frames=range(STARTUP_FRAMES))
kiss_icp_poses(frames, deskew=True)
print(time.perf_counter() - t0)
"""


FLOOR_KERNEL = """
from numba import njit


@njit(cache=True)
def plus_one(x):
    return x + 1.0
"""

FLOOR_SCRIPT = """
import sys, time
t0 = time.perf_counter()
import numpy as np
sys.path.insert(0, sys.argv[1])
from floor_kernel import plus_one
plus_one(np.float64(1.0))
print(time.perf_counter() - t0)
"""


def _timed_script(script: str, args: list[str], env: dict | None = None) -> dict:
    """A fresh interpreter running ``script`` (which prints its own seconds from its start as its last word):
    the process's wall time and that start-up."""
    t0 = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-c", script, *args],
        capture_output=True,
        text=True,
        check=True,
        env=env,
    )
    return {
        "wall_s": time.perf_counter() - t0,
        "startup_s": float(done.stdout.split()[-1]),
    }


def _numba_floor(tmp: Path, repeat: int) -> dict:
    """:data:`FLOOR_SCRIPT` ``repeat`` times on a warm cache (one untimed run compiles the kernel first)."""
    (tmp / "floor_kernel.py").write_text(FLOOR_KERNEL, encoding="utf-8")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp / "numba-floor")}
    _timed_script(FLOOR_SCRIPT, [str(tmp)], env)
    return _summary([_timed_script(FLOOR_SCRIPT, [str(tmp)], env) for _ in range(repeat)])


def _slamlib_run(args: list[str], cache: str, out: str) -> dict:
    """One fresh ``slamlib run`` with ``NUMBA_CACHE_DIR=cache``; its wall time and what it printed."""
    from slamlib.slam3d.run import STARTUP_FRAMES

    env = {**os.environ, "NUMBA_CACHE_DIR": cache}
    command = [sys.executable, "-m", "slamlib.cli", "run", *args, "--out", out]
    command += ["--overwrite", "--no-plots", "--no-progress"]
    t0 = time.perf_counter()
    done = subprocess.run(command, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        raise RuntimeError(
            f"{' '.join(command)} failed ({done.returncode}):\n{done.stderr[-2000:]}"
        )
    match = STARTUP_LINE_RE.search(done.stdout)
    if match is None:
        raise RuntimeError(
            f"no start-up line in the output of {' '.join(command)}:\n{done.stdout}"
        )
    fps, startup = float(match.group(3)), float(match.group(4))
    return {
        "wall_s": wall,
        "startup_s": startup,
        "steady_fps": fps,
        "overhead_s": startup - STARTUP_FRAMES / fps,
    }


def _summary(runs: list[dict]) -> dict:
    """Median and smallest of each measure over the runs (for a time the best run, for frames/s the worst)."""
    out = {"repeat": len(runs)}
    for key in runs[0]:
        values = np.array([r[key] for r in runs], dtype=float)
        out[f"{key}_median"] = float(np.median(values))
        out[f"{key}_min"] = float(np.min(values))
    return out


def run(quick: bool = False) -> dict:
    from slamlib.synth import default_drive
    from slamlib.synth.drive import DEFAULT_FRAMES

    n = QUICK_FRAMES if quick else FRAMES
    repeat = 1 if quick else 5
    basedir, date, drive = default_drive(progress=False)  # generated before any timing
    frames = ["--frames", f"0:{n}"]
    rows = {}
    with tempfile.TemporaryDirectory(prefix="slamlib-bench-startup-") as tmp:
        out = str(Path(tmp) / "run")
        for mode, flags in MODES.items():
            caches = [str(Path(tmp) / f"numba-{mode}-{k}") for k in range(repeat)]
            cold = [_slamlib_run(frames + flags, cache, out) for cache in caches]
            # the warm runs load what the last cold run compiled
            warm = [_slamlib_run(frames + flags, caches[-1], out) for _ in range(repeat)]
            rows[mode] = {"cold": _summary(cold), "warm": _summary(warm)}
            print(
                f"{mode}: start-up cold {rows[mode]['cold']['startup_s_median']:.2f} s, "
                f"warm {rows[mode]['warm']['startup_s_median']:.2f} s (medians); steady "
                f"{rows[mode]['warm']['steady_fps_median']:.1f} frames/s, warm overhead "
                f"{rows[mode]['warm']['overhead_s_median']:.2f} s"
            )
        kiss = [
            _timed_script(KISS_SCRIPT, [str(basedir), date, str(drive)])
            for _ in range(repeat)
        ]
        rows["kiss_icp"] = _summary(kiss)
        rows["numba_floor"] = _numba_floor(Path(tmp), repeat)
    print(f"KISS-ICP: start-up {rows['kiss_icp']['startup_s_median']:.2f} s (median)")
    print(
        f"Numba alone (import, one cached kernel): {rows['numba_floor']['startup_s_median']:.2f} s (median)"
    )
    return {
        "drive": f"default drive (route 07, key frames 0:{DEFAULT_FRAMES[1]}), frames 0:{n}",
        "frames": n,
        "rows": rows,
    }
