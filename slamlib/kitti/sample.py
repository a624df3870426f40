"""Tiny KITTI raw drives built from the real pieces shipped in :func:`slamlib.paths.kitti_sample_dir`.

Used by the tests and for small examples: the real 2011_09_26 calibration files, the first ``n_frames``
real OXTS / Velodyne timestamps of drive 0001, OXTS packets derived from the one real packet (moved along
its heading at its forward speed), and the two real Velodyne scans alternated (optionally subsampled).
"""

from __future__ import annotations

import math
import os
import shutil
from pathlib import Path

from slamlib.kitti.calib import CAM_TO_CAM, IMU_TO_VELO, VELO_TO_CAM
from slamlib.kitti.oxts import read_oxts_packet, write_oxts_packet
from slamlib.kitti.raw import drive_folder_name
from slamlib.kitti.timestamps import read_timestamps_ns, write_timestamps_ns
from slamlib.kitti.velodyne import SWEEP_PERIOD_S, read_velodyne_scan, write_velodyne_scan
from slamlib.paths import kitti_sample_dir

__all__ = [
    "SAMPLE_DATE",
    "SAMPLE_DRIVE",
    "sample_raw_paths",
    "make_tiny_drive",
    "REAL_SCANS",
    "real_scan_path",
    "real_scan_frames",
    "NOMINAL_SCAN_PERIOD",
]

#: How many consecutive real Velodyne scans the package ships (``velodyne_sample/``: frames 0 and 9 as ``.bin``,
#: 1-8 xz-compressed as ``.bin.xz``, ~0.64 MB each instead of 1.8 MB).
REAL_SCANS = 10
#: The HDL-64E's scan period measured on the real drive 0001 (median ``timestamps_end - timestamps_start``, s):
#: the sample scans come without their timestamps, so they are given this nominal spacing.
NOMINAL_SCAN_PERIOD = SWEEP_PERIOD_S

SAMPLE_DATE = "2011_09_26"
SAMPLE_DRIVE = "0001"


def sample_raw_paths() -> dict[str, Path]:
    """Paths of the shipped real raw pieces: calib files, OXTS packet, timestamps, the two scans."""
    root = kitti_sample_dir()
    date_dir = root / "raw" / SAMPLE_DATE
    drive_dir = date_dir / drive_folder_name(SAMPLE_DATE, SAMPLE_DRIVE)
    return {
        "date_dir": date_dir,
        "drive_dir": drive_dir,
        IMU_TO_VELO: date_dir / IMU_TO_VELO,
        VELO_TO_CAM: date_dir / VELO_TO_CAM,
        CAM_TO_CAM: date_dir / CAM_TO_CAM,
        "oxts_packet": drive_dir / "oxts" / "data" / "0000000000.txt",
        "oxts_timestamps": drive_dir / "oxts" / "timestamps.txt",
        "velo_timestamps": drive_dir / "velodyne_points" / "timestamps.txt",
        "scan0": root / "velodyne_sample" / "0000000000.bin",
        "scan9": root / "velodyne_sample" / "0000000009.bin",
    }


def make_tiny_drive(
    basedir: str | os.PathLike,
    n_frames: int = 5,
    point_stride: int = 50,
    yaw_rate: float = 0.05,
    date: str = SAMPLE_DATE,
    drive: str = SAMPLE_DRIVE,
) -> Path:
    """Write a small KITTI raw drive under ``basedir`` and return its drive folder.

    OXTS packet ``i`` is the real packet with the position moved ``i`` steps along the heading (forward speed
    ``vf`` times the real frame interval, converted to degrees of lat/lon on a sphere of radius 6378137 m) and
    ``yaw += i * yaw_rate * dt``. Scans alternate the two real scans, keeping every ``point_stride``-th point.
    ``n_frames`` may be at most 108 (the real timestamps).
    """
    p = sample_raw_paths()
    basedir = Path(basedir)
    date_dir = basedir / date
    drive_dir = date_dir / drive_folder_name(date, drive)
    (drive_dir / "oxts" / "data").mkdir(parents=True, exist_ok=True)
    (drive_dir / "velodyne_points" / "data").mkdir(parents=True, exist_ok=True)
    for name in (IMU_TO_VELO, VELO_TO_CAM, CAM_TO_CAM):
        shutil.copyfile(p[name], date_dir / name)
    shutil.copyfile(
        p["drive_dir"] / "oxts" / "dataformat.txt", drive_dir / "oxts" / "dataformat.txt"
    )

    ts = read_timestamps_ns(p["oxts_timestamps"])
    if not 1 <= n_frames <= ts.size:
        raise ValueError(f"n_frames must be in 1..{ts.size}")
    ts = ts[:n_frames]
    write_timestamps_ns(drive_dir / "oxts" / "timestamps.txt", ts)
    write_timestamps_ns(
        drive_dir / "velodyne_points" / "timestamps.txt",
        read_timestamps_ns(p["velo_timestamps"])[:n_frames],
    )

    base = read_oxts_packet(p["oxts_packet"])
    r = 6378137.0
    lat, lon, yaw = base.lat, base.lon, base.yaw
    scans = [
        read_velodyne_scan(p["scan0"])[::point_stride],
        read_velodyne_scan(p["scan9"])[::point_stride],
    ]
    for i in range(n_frames):
        if i > 0:
            dt = (ts[i] - ts[i - 1]) * 1e-9
            step = base.vf * dt
            # yaw 0 = east, counter-clockwise
            lat += math.degrees(step * math.sin(yaw) / r)
            lon += math.degrees(step * math.cos(yaw) / (r * math.cos(math.radians(lat))))
            yaw += yaw_rate * dt
        write_oxts_packet(
            drive_dir / "oxts" / "data" / f"{i:010d}.txt",
            base._replace(lat=lat, lon=lon, yaw=yaw, wu=yaw_rate),
        )
        write_velodyne_scan(
            drive_dir / "velodyne_points" / "data" / f"{i:010d}.bin", scans[i % 2]
        )
    return drive_dir


def real_scan_path(k: int) -> Path:
    """The shipped real scan ``k`` (0..9): ``velodyne_sample/NNNNNNNNNN.bin`` or ``.bin.xz``."""
    if not 0 <= int(k) < REAL_SCANS:
        raise ValueError(
            f"the package ships real scans 0..{REAL_SCANS - 1}, asked for {k}"
        )
    base = kitti_sample_dir() / "velodyne_sample" / f"{int(k):010d}.bin"
    return base if base.is_file() else base.with_name(base.name + ".xz")


def real_scan_frames(
    frames=range(REAL_SCANS), period: float = NOMINAL_SCAN_PERIOD
) -> list:
    """The shipped real scans as LIDAR-only frames (:class:`slamlib.kitti.OdometryFrame`, no IMU, no ground
    truth), ``period`` seconds apart (nominal: their timestamps are not shipped). For ``slamlib.slam3d.run_drive``.
    They are raw scans, not motion-compensated: ``swept`` is True (the filter de-skews them by default).
    """
    from slamlib.kitti.sequence import OdometryFrame

    out = []
    for pos, k in enumerate(frames):
        out.append(
            OdometryFrame(
                index=int(k),
                time_s=float(k) * period,
                dt=0.0 if pos == 0 else float(k - frames[pos - 1]) * period,
                scan=read_velodyne_scan(real_scan_path(k)),
                T_w_body=None,
                velodyne_path=real_scan_path(k),
                swept=True,
            )
        )
    return out
