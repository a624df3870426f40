"""Benchmarks run by ``slamlib bench NAME``; results are JSON files committed under ``benchmarks/results``.

This package lives beside the library in a source checkout, not inside it: ``slamlib`` never imports it, except
the ``slamlib bench`` command (:mod:`slamlib.commands.bench`), which loads it from the checkout slamlib runs from.
Each module in :data:`BENCHMARKS` defines ``HELP`` (one line) and ``run(quick: bool) -> dict``. ``run`` returns
a JSON-serialisable dict of measurements; the harness adds the machine description (:mod:`benchmarks.machine`)
and writes the file to :func:`slamlib.paths.bench_results_dir`; :func:`slamlib.paths.load_bench_result` reads
it back. Timings are medians of repeated runs, measured side by side in one process, so ratios between rows are
meaningful even on a shared, noisy machine; absolute numbers are not.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

BENCHMARKS = {
    # name: module path; modules are imported only when run.
    "kernels": "benchmarks.kernels",
    "maps": "benchmarks.maps",
    "noise": "benchmarks.noise",
    "cuda": "benchmarks.cuda",
    "slam3d": "benchmarks.slam3d",
    "synth": "benchmarks.synth",
    "peers": "benchmarks.peers",
    "transform": "benchmarks.transform",
    "particles": "benchmarks.particles",
    "scaling": "benchmarks.scaling",
    "lidar_only": "benchmarks.lidar_only",
    "startup": "benchmarks.startup",
    "stages": "benchmarks.stages",
    "loops2d": "benchmarks.loops2d",
    "loops": "benchmarks.loops",
    "loops_route": "benchmarks.loops_route",
}


def median_time(fn: Callable[[], object], repeat: int = 7, warmup: int = 1) -> dict:
    """Time ``fn()`` ``repeat`` times after ``warmup`` untimed calls (which also trigger JIT compilation).

    Returns ``{"median_s", "min_s", "max_s", "repeat"}`` with wall-clock seconds from ``time.perf_counter``.
    """
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    arr = np.asarray(times)
    return {
        "median_s": float(np.median(arr)),
        "min_s": float(arr.min()),
        "max_s": float(arr.max()),
        "repeat": int(repeat),
    }
