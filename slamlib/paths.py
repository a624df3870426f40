"""Where slamlib's shipped sample data and its cache of generated data live."""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE_DATA = Path(__file__).resolve().parent / "data"


def kitti_sample_dir() -> Path:
    """Folder of the real KITTI pieces shipped with slamlib (CC BY-NC-SA 3.0, see its README.md)."""
    return PACKAGE_DATA / "kitti"


def cache_dir() -> Path:
    """Folder for generated data (e.g. the default synthetic drive): ``$SLAMLIB_CACHE`` or ``~/.cache/slamlib``."""
    root = os.environ.get("SLAMLIB_CACHE")
    path = Path(root) if root else Path.home() / ".cache" / "slamlib"
    path.mkdir(parents=True, exist_ok=True)
    return path
