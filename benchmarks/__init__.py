"""Benchmarks run by ``slamlib bench NAME``; results are JSON files committed under ``benchmarks/results``.

Each module in :data:`BENCHMARKS` defines ``HELP`` (one line) and ``run(quick: bool) -> dict``. ``run`` returns
a JSON-serialisable dict of measurements; the harness (:mod:`slamlib.commands.bench`) adds the machine
description and writes the file. Timings are medians of repeated runs, measured side by side in one process,
so ratios between rows are meaningful even on a shared, noisy machine; absolute numbers are not.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Callable

import numpy as np

BENCHMARKS = {
    # name: module path; modules are imported only when run.
    "kernels": "slamlib.bench.kernels",
    "maps": "slamlib.bench.maps",
    "noise": "slamlib.bench.noise",
    "cuda": "slamlib.bench.cuda",
    "slam3d": "slamlib.bench.slam3d",
    "synth": "slamlib.bench.synth",
    "peers": "slamlib.bench.peers",
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


def results_dir() -> Path:
    """``benchmarks/results`` of the source checkout this package runs from (where ``slamlib bench`` writes)."""
    return Path(__file__).resolve().parents[2] / "benchmarks" / "results"


def load_result(name: str) -> dict | None:
    """The committed result ``benchmarks/results/NAME.json`` as a dict, or ``None`` when it does not exist."""
    path = results_dir() / f"{name}.json"
    return json.loads(path.read_text()) if path.is_file() else None
