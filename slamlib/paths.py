"""Where slamlib's shipped sample data, its cache of generated data and the benchmark results live."""

from __future__ import annotations

import json
import os
from pathlib import Path

PACKAGE_DATA = Path(__file__).resolve().parent / "data"

#: The folder holding the ``slamlib`` package: the root of the source checkout when slamlib runs from one
#: (``pip install -e .``), ``site-packages`` when it is installed.
#:
#: :meta hide-value:
SOURCE_ROOT = Path(__file__).resolve().parents[1]


def kitti_sample_dir() -> Path:
    """Folder of the real KITTI pieces shipped with slamlib (CC BY-NC-SA 3.0, see its README.md)."""
    return PACKAGE_DATA / "kitti"


def cache_dir() -> Path:
    """Folder for generated data (e.g. the default synthetic drive): ``$SLAMLIB_CACHE`` or ``~/.cache/slamlib``."""
    root = os.environ.get("SLAMLIB_CACHE")
    path = Path(root) if root else Path.home() / ".cache" / "slamlib"
    path.mkdir(parents=True, exist_ok=True)
    return path


def benchmarks_dir() -> Path:
    """The ``benchmarks/`` package beside ``slamlib/`` in the source checkout (absent from an installed slamlib).

    Only the ``slamlib bench`` command loads it; the library never imports it.
    """
    return SOURCE_ROOT / "benchmarks"


def bench_results_dir() -> Path:
    """Folder of the benchmark results, where ``slamlib bench`` writes and the book reads.

    ``$SLAMLIB_BENCH_RESULTS`` if set, else ``benchmarks/results`` of the source checkout (whatever the current
    folder is). Files: ``NAME.json`` (``NAME-quick.json`` for ``--quick`` runs).
    """
    root = os.environ.get("SLAMLIB_BENCH_RESULTS")
    return Path(root) if root else benchmarks_dir() / "results"


def load_bench_result(name: str) -> dict | None:
    """The result ``NAME.json`` in :func:`bench_results_dir` as a dict, or ``None`` when it does not exist."""
    path = bench_results_dir() / f"{name}.json"
    return json.loads(path.read_text()) if path.is_file() else None
