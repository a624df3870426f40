"""KITTI Velodyne scans: ``velodyne_points/data/NNNNNNNNNN.bin``, validated.

Each file is a flat array of little-endian float32, four per point: ``x, y, z`` (metres, Velodyne frame:
x forward, y left, z up) and ``reflectance`` (0..1). The file size must therefore be a multiple of
16 bytes; a scan is returned as an ``(N, 4)`` float32 array (pykitti's ``load_velo_scan`` layout).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from slamlib.errors import DataFormatError

__all__ = [
    "POINT_BYTES",
    "SWEEP_PERIOD_S",
    "SYNTH_MARKER",
    "SYNTH_PARTIAL_MARKER",
    "check_complete",
    "read_velodyne_scan",
    "write_velodyne_scan",
    "scans_swept",
    "read_synth_marker",
]

#: Bytes per point: 4 float32 values.
POINT_BYTES = 16
#: Seconds one HDL-64E sweep takes on KITTI: the median ``timestamps_end - timestamps_start`` of raw drive 0001
#: (``../shared/notes/kitti-sensor-facts.md``); the scans are also this far apart. Every module that needs the
#: sweep (generator, de-skewing, the real samples, KISS-ICP's pose times) takes it from here.
SWEEP_PERIOD_S = 0.10315
#: The file a complete :mod:`slamlib.synth` drive or sequence folder holds: the generator's parameters (JSON),
#: among them ``"distortion": true`` when its scans were cast over a sweep (:func:`scans_swept`).
SYNTH_MARKER = ".slamlib_synth.json"
#: The file a :mod:`slamlib.synth` folder held while being written by slamlib before writes became atomic: a
#: folder that still holds it was left half written.
SYNTH_PARTIAL_MARKER = ".slamlib_synth.partial.json"


def check_complete(folder: str | os.PathLike, allow_incomplete: bool = False) -> None:
    """DataFormatError naming :data:`SYNTH_PARTIAL_MARKER` when ``folder`` was left half written by an interrupted
    ``slamlib synth`` (unless ``allow_incomplete``: then its frames are read as they are)."""
    partial = Path(folder) / SYNTH_PARTIAL_MARKER
    if partial.is_file() and not allow_incomplete:
        raise DataFormatError(
            partial,
            "this folder was left half written by an interrupted slamlib synth (it holds this marker); "
            "write it again with slamlib synth, or read the frames it has with --allow-incomplete",
        )


def scans_swept(folder: str | os.PathLike, unmarked: bool = True) -> bool:
    """Whether the scans of a drive or sequence ``folder`` were taken over a sweep, as a spinning LIDAR takes them
    (each column at its own instant, the car moving in between), and still are: they want de-skewing.

    A :mod:`slamlib.synth` folder says so in its :data:`SYNTH_MARKER` (``"distortion": true``; without it each scan
    was cast from one pose, and de-skewing would add the error it removes elsewhere). A folder without the marker
    (real data, or a marker that cannot be read) gets ``unmarked``: ``True`` for KITTI raw drives, whose "sync"
    scans are not motion-compensated, ``False`` for the KITTI odometry benchmark, whose scans are ("This effect has
    been eliminated from this postprocessed data by compensating for the egomotion", its devkit readme).
    """
    params = read_synth_marker(folder)
    if not isinstance(params, dict):  # no marker (real data) or an unreadable one
        return unmarked
    return bool(params.get("distortion", False))


def read_synth_marker(folder: str | os.PathLike):
    """The parsed :data:`SYNTH_MARKER` of ``folder`` (the generator's parameters), or None when it is missing or
    not JSON."""
    try:
        return json.loads((Path(folder) / SYNTH_MARKER).read_text(encoding="ascii"))
    except (OSError, ValueError):
        return None


def read_velodyne_scan(path: str | os.PathLike) -> np.ndarray:
    """Read a ``.bin`` scan into ``(N, 4)`` float32 ``x, y, z, reflectance`` (Velodyne frame, metres); a name
    ending in ``.xz`` is an xz-compressed ``.bin`` (read with the standard library's :mod:`lzma`).

    Raises
    ------
    DataFormatError
        Missing file, size not a multiple of 16 bytes, or any non-finite (nan / inf) value (the message
        gives how many points and the first bad point index).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise DataFormatError(path, "Velodyne scan file not found")
    # an xz-compressed .bin (the package's real sample scans): the same bytes inside
    if path.endswith(".xz"):
        import lzma

        try:
            with lzma.open(path) as f:
                # writable: the scan is a writable array, as from a .bin
                raw = bytearray(f.read())
        except (lzma.LZMAError, EOFError) as exc:
            raise DataFormatError(path, f"not a readable xz file: {exc}") from None
        size = len(raw)
    else:
        size = os.path.getsize(path)
    if size % POINT_BYTES:
        raise DataFormatError(
            path,
            f"Velodyne scan has {size} bytes, not a multiple of {POINT_BYTES} (4 float32 per point)",
        )
    scan = (
        np.frombuffer(raw, dtype="<f4")
        if path.endswith(".xz")
        else np.fromfile(path, dtype="<f4")
    ).reshape(-1, 4)
    # one flat pass (a row-wise test costs thirty times as much), the rows only to name a bad point
    if not np.isfinite(scan).all():
        bad = np.flatnonzero(~np.isfinite(scan).all(axis=1))
        raise DataFormatError(
            path,
            f"Velodyne scan has {bad.size} point(s) with nan/inf values (first at point index {bad[0]})",
        )
    return scan.astype(np.float32, copy=False)


def write_velodyne_scan(path: str | os.PathLike, scan: np.ndarray) -> None:
    """Write an ``(N, 4)`` (or ``(N, 3)``, reflectance 0) array as a KITTI ``.bin`` (little-endian float32)."""
    scan = np.asarray(scan)
    if scan.ndim != 2 or scan.shape[1] not in (3, 4):
        raise ValueError(f"scan must be (N, 4) or (N, 3), got {scan.shape}")
    if scan.shape[1] == 3:
        scan = np.concatenate(
            [scan, np.zeros((scan.shape[0], 1), dtype=scan.dtype)], axis=1
        )
    np.ascontiguousarray(scan, dtype="<f4").tofile(path)
