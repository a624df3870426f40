"""Write synthetic drives in the exact KITTI raw ("sync") layout, readable unmodified by ``pykitti.raw``.

Layout written (``DATE`` e.g. ``2011_09_26``, ``NNNN`` the drive number)::

    basedir/DATE/calib_imu_to_velo.txt, calib_velo_to_cam.txt, calib_cam_to_cam.txt   (the real 2011_09_26 files)
    basedir/DATE/DATE_drive_NNNN_sync/oxts/dataformat.txt, timestamps.txt, data/0000000000.txt ...
    basedir/DATE/DATE_drive_NNNN_sync/velodyne_points/timestamps.txt, timestamps_start.txt,
        timestamps_end.txt, data/0000000000.bin ...   (float32 x, y, z, reflectance)

Timing, modelled on the shipped real drive 2011_09_26_drive_0001 (its files give: scan period 0.10315 s
with 45 us jitter; a sweep runs from the previous sweep's end to ``timestamp + 51.6 ms``; the OXTS unit stamps
its packets on its own 100 Hz clock, 0-0.7 ms off a 10 ms grid, and each frame gets the first packet at least
~11.8 ms after the scan stamp, so the delay is a sawtooth that shrinks by ``103.15 mod 10 = 3.15`` ms a frame and
jumps back up by 10 ms: 11.8-24.0 ms, OXTS intervals of 100 or 110 ms)::

    t_velo[k]  = t_start + k * period + N(0, jitter)          (period 0.10315 s, jitter 3.2e-5 s)
    t_oxts[k]  = g0 + tick * ceil((t_velo[k] + theta_k - g0) / tick) + U(0, 0.5 ms)
                 (tick 10 ms, grid phase g0 = t_velo[0] + U(0, tick), theta_k = 11.55 ms + Exp(0.3 ms))
    t_end[k]   = t_velo[k] + 0.0516,   t_start_sweep[k] = t_end[k-1]  (t_velo[0] - 0.0516 for k = 0)

The exponential tail of ``theta_k`` reproduces the real drive's occasional later packet (4 of its 108 delays exceed
21.8 ms: the packet one tick later than the shortest delay would pick; ~3 % here).

The vehicle state of frame ``k`` (OXTS packet and the scan's sensor pose) is the route at
``t_oxts[k] - t_oxts[0] + route_t0`` (so ``pykitti``'s ``T_w_velo`` is exactly the pose the scan was cast
from). A drive is written into a temporary sibling folder and renamed into place when complete
(:mod:`slamlib.atomic`); it holds a ``.slamlib_synth.json`` marker (parameters + generator version). That marker,
or the ``.slamlib_synth.partial.json`` an older slamlib left in a drive it was writing when interrupted, makes the
folder the generator's own: rewriting it replaces only the files the generator writes (:func:`generator_file`)
and keeps everything else (notes, a ``slamlib run --out DRIVE/out`` folder).
"""

from __future__ import annotations

import datetime as _dt
import json
import re
import shutil
from pathlib import Path

import numpy as np

from slamlib.kitti.oxts import format_oxts_packet
from slamlib.kitti.timestamps import write_timestamps_ns
from slamlib.kitti.velodyne import (
    SWEEP_PERIOD_S,
    SYNTH_MARKER,
    SYNTH_PARTIAL_MARKER,
    read_synth_marker,
)
from slamlib.paths import kitti_sample_dir

__all__ = [
    "CALIB_FILES",
    "MARKER",
    "PARTIAL_MARKER",
    "drive_dir",
    "is_own_drive",
    "generator_file",
    "own_files",
    "check_calib",
    "write_calib",
    "frame_timestamps_ns",
    "write_oxts",
    "write_velodyne_timestamps",
    "write_scan",
    "SCAN_PERIOD",
    "odometry_calib",
    "write_odometry_calib",
    "write_odometry_scan",
    "own_sequence_files",
]

CALIB_FILES = ("calib_imu_to_velo.txt", "calib_velo_to_cam.txt", "calib_cam_to_cam.txt")
MARKER = SYNTH_MARKER
#: Held by a drive an older slamlib was writing when interrupted (readers refuse it: ``check_complete``).
PARTIAL_MARKER = SYNTH_PARTIAL_MARKER
#: The files the generator writes in a drive folder (besides the frame files matched by :data:`_FRAME_FILES`).
_FIXED_FILES = (
    "oxts/dataformat.txt",
    "oxts/timestamps.txt",
    "velodyne_points/timestamps.txt",
    "velodyne_points/timestamps_start.txt",
    "velodyne_points/timestamps_end.txt",
)
_FRAME_FILES = (
    ("oxts/data", re.compile(r"\d{10}\.txt")),
    ("velodyne_points/data", re.compile(r"\d{10}\.bin")),
)
#: Seconds between scan stamps: the sweep period (:data:`slamlib.kitti.velodyne.SWEEP_PERIOD_S`).
SCAN_PERIOD = SWEEP_PERIOD_S
#: The OXTS clock (100 Hz) and how its packets are matched to scans (module docstring; all in ns), from drive 0001:
OXTS_TICK_NS = 10_000_000
# the shortest delay of a frame's packet tick after the scan stamp
# mean extra threshold (exponential): ~3 % of packets a tick later
# packets stamped up to 0.5 ms after their tick (real: 5-95 % of 0.03-0.48 ms)
OXTS_MIN_DELAY_NS = 11_550_000
OXTS_LATE_MEAN_NS = 300_000
OXTS_GRID_JITTER_NS = 500_000
_SAMPLE = kitti_sample_dir() / "raw" / "2011_09_26"


def drive_dir(basedir, date: str, drive: int) -> Path:
    """``basedir/DATE/DATE_drive_NNNN_sync``."""
    return Path(basedir) / date / f"{date}_drive_{int(drive):04d}_sync"


def is_own_drive(ddir) -> bool:
    """Whether ``ddir`` holds a drive of this generator, complete (:data:`MARKER`) or interrupted
    (:data:`PARTIAL_MARKER`)."""
    return (Path(ddir) / MARKER).is_file() or (Path(ddir) / PARTIAL_MARKER).is_file()


def generator_file(path: str, sequence: bool = False) -> bool:
    """Whether ``path`` (relative to a drive folder, ``/``-separated; ``sequence``: to an odometry sequence folder)
    is a file the generator writes (:func:`own_files`, :func:`own_sequence_files`)."""
    fixed = (MARKER, PARTIAL_MARKER) + (_SEQUENCE_FILES if sequence else _FIXED_FILES)
    frames = (("velodyne", _SEQUENCE_SCAN),) if sequence else _FRAME_FILES
    parent, _, name = path.rpartition("/")
    return path in fixed or any(parent == sub and p.fullmatch(name) for sub, p in frames)


def own_files(ddir) -> list[Path]:
    """The files of ``ddir`` that the generator writes: the markers, the OXTS and Velodyne timestamps, OXTS
    ``dataformat.txt``, and the 10-digit frame files in ``oxts/data`` (``.txt``) and ``velodyne_points/data``
    (``.bin``). Anything else in the folder is not the generator's."""
    ddir = Path(ddir)
    out = [ddir / name for name in (MARKER, PARTIAL_MARKER) + _FIXED_FILES]
    for sub, pattern in _FRAME_FILES:
        if (ddir / sub).is_dir():
            out += sorted(p for p in (ddir / sub).iterdir() if pattern.fullmatch(p.name))
    return [p for p in out if p.is_file() and not p.is_symlink()]


def check_calib(basedir, date: str) -> None:
    """Raise ``FileExistsError`` if a calibration file in ``basedir/DATE`` differs from the one written."""
    for name in CALIB_FILES:
        theirs = Path(basedir) / date / name
        if theirs.is_file() and theirs.read_bytes() != (_SAMPLE / name).read_bytes():
            raise FileExistsError(
                f"{theirs} exists and differs from the 2011_09_26 calibration the generator "
                "writes; choose another basedir or date"
            )


def write_calib(basedir, date: str) -> Path:
    """Copy the three real 2011_09_26 calibration files into ``basedir/DATE``; returns that folder.

    Raises ``FileExistsError`` (before writing anything) if one is already there and differs."""
    from slamlib.atomic import atomic_file

    check_calib(basedir, date)
    d = Path(basedir) / date
    d.mkdir(parents=True, exist_ok=True)
    # whole, by a rename: another drive of the date may be read meanwhile
    for name in CALIB_FILES:
        atomic_file(d / name, (_SAMPLE / name).read_bytes())
    return d


def frame_timestamps_ns(
    n: int, date: str, rng: np.random.Generator, start_time: str = "13:02:25.9"
) -> dict:
    """Integer-nanosecond timestamps of ``n`` frames (see the module docstring for the model).

    Returns ``{"velo", "start", "end", "oxts"}`` each ``(n,)`` int64 ns since 1970 (wall clock as UTC).
    """
    day = _dt.datetime.strptime(date + " " + start_time, "%Y_%m_%d %H:%M:%S.%f").replace(
        tzinfo=_dt.timezone.utc
    )
    t0 = int(round(day.timestamp() * 1e9))
    k = np.arange(n)
    velo = t0 + np.round(
        (k * SCAN_PERIOD + 3.2e-5 * rng.standard_normal(n)) * 1e9
    ).astype(np.int64)
    end = velo + 51_600_000 + rng.integers(-20_000, 20_000, n)
    start = np.r_[velo[:1] - 51_600_000, end[:-1]]
    g0 = velo[0] + int(rng.integers(0, OXTS_TICK_NS))
    theta = OXTS_MIN_DELAY_NS + np.round(rng.exponential(OXTS_LATE_MEAN_NS, n)).astype(
        np.int64
    )
    # ceil((velo + theta - g0) / tick) in exact integers
    ticks = -((g0 - velo - theta) // OXTS_TICK_NS)
    oxts = g0 + ticks * OXTS_TICK_NS + rng.integers(0, OXTS_GRID_JITTER_NS, n)
    return {"velo": velo, "start": start, "end": end, "oxts": oxts}


def write_oxts(ddir: Path, packets: np.ndarray, oxts_ns: np.ndarray) -> None:
    """``oxts/dataformat.txt`` (copied from the real drive), ``timestamps.txt`` and one packet per frame."""
    o = Path(ddir) / "oxts"
    (o / "data").mkdir(parents=True, exist_ok=True)
    shutil.copyfile(
        _SAMPLE / "2011_09_26_drive_0001_sync" / "oxts" / "dataformat.txt",
        o / "dataformat.txt",
    )
    write_timestamps_ns(o / "timestamps.txt", oxts_ns)
    for i, p in enumerate(packets):
        (o / "data" / f"{i:010d}.txt").write_text(
            format_oxts_packet(p) + "\n", encoding="ascii"
        )


def write_velodyne_timestamps(ddir: Path, ts: dict) -> None:
    v = Path(ddir) / "velodyne_points"
    (v / "data").mkdir(parents=True, exist_ok=True)
    write_timestamps_ns(v / "timestamps.txt", ts["velo"])
    write_timestamps_ns(v / "timestamps_start.txt", ts["start"])
    write_timestamps_ns(v / "timestamps_end.txt", ts["end"])


def write_scan(ddir: Path, index: int, scan: np.ndarray) -> None:
    """``velodyne_points/data/NNNNNNNNNN.bin``: ``scan (N, 4)`` as little-endian float32."""
    _tofile(scan, Path(ddir) / "velodyne_points" / "data" / f"{index:010d}.bin")


def write_marker(ddir: Path, params: dict) -> None:
    (Path(ddir) / MARKER).write_text(
        json.dumps(params, indent=1, sort_keys=True), encoding="ascii"
    )


#: The marker of a drive or sequence folder, parsed (None when missing or not JSON); the readers use it too.
read_marker = read_synth_marker


# ------------------------------------------------------------------------------------------ odometry layout
#: The files the generator writes in an odometry sequence folder (besides ``velodyne/NNNNNN.bin``).
_SEQUENCE_FILES = ("calib.txt", "times.txt")
_SEQUENCE_SCAN = re.compile(r"\d{6}\.bin")


def own_sequence_files(sdir) -> list[Path]:
    """The files of an odometry sequence folder ``sdir`` that the generator writes: the markers, ``calib.txt``,
    ``times.txt`` and the 6-digit ``velodyne/*.bin`` scans."""
    sdir = Path(sdir)
    out = [sdir / name for name in (MARKER, PARTIAL_MARKER) + _SEQUENCE_FILES]
    if (sdir / "velodyne").is_dir():
        out += sorted(
            p for p in (sdir / "velodyne").iterdir() if _SEQUENCE_SCAN.fullmatch(p.name)
        )
    return [p for p in out if p.is_file() and not p.is_symlink()]


def odometry_calib() -> dict[str, np.ndarray]:
    """An odometry ``calib.txt`` from the real 2011_09_26 raw calibration, as KITTI derived theirs:
    ``P0..P3 = P_rect_00..P_rect_03`` (3x4) and ``Tr = R_rect_00 T_cam0unrect_velo`` (3x4: Velodyne -> rectified
    left camera). Returns ``{key: (3, 4) float64}``."""
    from slamlib.kitti.calib import (
        CAM_TO_CAM,
        REQUIRED_KEYS,
        VELO_TO_CAM,
        read_calib_file,
        read_rigid,
    )

    cam = read_calib_file(_SAMPLE / CAM_TO_CAM, REQUIRED_KEYS[CAM_TO_CAM])
    R_rect = np.eye(4)
    R_rect[:3, :3] = cam["R_rect_00"].reshape(3, 3)
    out = {f"P{k}": cam[f"P_rect_0{k}"].reshape(3, 4) for k in range(4)}
    out["Tr"] = (R_rect @ read_rigid(_SAMPLE / VELO_TO_CAM))[:3]
    return out


def write_odometry_calib(sdir) -> np.ndarray:
    """Write ``sdir/calib.txt`` (:func:`odometry_calib`, KITTI's ``%e`` format); returns ``Tr`` as 4x4."""
    calib = odometry_calib()
    lines = [
        f"{key}: " + " ".join(f"{v:.12e}" for v in M.ravel()) for key, M in calib.items()
    ]
    (Path(sdir) / "calib.txt").write_text("\n".join(lines) + "\n", encoding="ascii")
    Tr = np.eye(4)
    Tr[:3] = calib["Tr"]
    return Tr


def write_odometry_scan(sdir, index: int, scan: np.ndarray) -> None:
    """``sdir/velodyne/NNNNNN.bin``: ``scan (N, 4)`` as little-endian float32."""
    _tofile(scan, Path(sdir) / "velodyne" / f"{index:06d}.bin")


def _tofile(scan: np.ndarray, path: Path) -> None:
    """``scan`` as little-endian float32 into ``path``; a failed write is one ``OSError`` naming ``path`` (and a
    full disk, with the free space: :func:`slamlib.atomic.write_error`)."""
    from slamlib.atomic import write_error

    try:
        _write_array(np.ascontiguousarray(scan, dtype="<f4"), path)
    except OSError as exc:
        raise write_error(path, exc) from None


def _write_array(array: np.ndarray, path: Path) -> None:
    """``array.tofile(path)``: the one place a scan's bytes reach the disk."""
    array.tofile(path)
