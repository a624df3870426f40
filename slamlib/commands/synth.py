"""``slamlib synth``: write a synthetic drive in the KITTI raw layout (:func:`slamlib.synth.write_drive`).

Examples::

    slamlib synth --out data/synth                                   # the default drive: route 07, key frames 0:300
    slamlib synth --out data/synth --route 00 --frames 1000:1600 --drive 2 --seed 4
    slamlib synth --out data/synth --route loop --frames 200 --imu-noise 0      # exact IMU fields
    slamlib synth --out data/synth --no-scans                        # OXTS + timestamps only (seconds)
    slamlib synth --out data/odometry --layout odometry --route 07 --frames 0:    # odometry layout, sequence 07

The drive goes to ``OUT/DATE/DATE_drive_NNNN_sync`` beside the real 2011_09_26 calibration files (copied into
``OUT/DATE``) and reads unmodified with ``pykitti.raw(OUT, DATE, "NNNN")`` or ``slamlib run --basedir OUT
--date DATE --drive NNNN``. The drive appears whole or not at all: it is written into a hidden temporary folder
beside it under a lock (a second ``slamlib synth`` into the same folder is told which process writes it) and renamed
into place; Ctrl-C or a full disk leaves nothing half written. A drive folder that already holds a synthetic drive
(complete, or left interrupted by an older slamlib: its ``.slamlib_synth.partial.json``) has the generator's files
replaced and keeps every other file (notes, a ``slamlib run --out DRIVE/out`` folder); a non-empty folder that is
not synthetic (no ``.slamlib_synth.json`` marker), or calibration files that differ from the ones written, are never
overwritten.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

NAME = "synth"
HELP = "Write a synthetic drive (town + HDL-64E scans + OXTS) in the KITTI raw layout, readable by pykitti."

# Kept here (and checked against slamlib.synth by the tests) so that `slamlib --help` does not import scipy/open3d.
ROUTES = ("straight", "loop", "00", "05", "07")
#: A road drawn from a seed (slamlib.synth.roads.RANDOM_PREFIX): "random:SEED".
RANDOM_ROUTE = re.compile(r"random:\d+")
#: Largest --traffic SCALE: ten times a city drive's density already fills the lanes (movers that would overlap are
#: dropped).
MAX_TRAFFIC = 10.0
KITTI_ROUTES = ("00", "05", "07")
DEFAULT_FRAMES = "0:300"  # slamlib.synth.DEFAULT_FRAMES
DEFAULT_COLUMNS = 2000  # slamlib.synth.Hdl64().columns


def add_arguments(parser) -> None:
    parser.add_argument(
        "--out",
        type=Path,
        required=True,
        metavar="BASEDIR",
        help="output root: the drive is written to BASEDIR/DATE/DATE_drive_NNNN_sync",
    )
    parser.add_argument(
        "--route",
        type=route_name,
        default="07",
        help="trajectory: a straight line (10 m/s, 60 s), a 60 m circle (8 m/s), the real ground "
        "truth of KITTI odometry sequence 00, 05 or 07 (default 07), or random:SEED, a fresh road of at least "
        "1 km drawn from SEED (turns, hairpins, roundabouts, grades, stops, revisits)",
    )
    parser.add_argument(
        "--frames",
        default=DEFAULT_FRAMES,
        metavar="A:B",
        help="KITTI routes: odometry key frames A:B (B exclusive; A: to the end; N = 0:N); "
        f"straight / loop: a count N or 0:N frames from the route's start (default {DEFAULT_FRAMES})",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="master seed: same arguments, same bytes (default 0)",
    )
    parser.add_argument(
        "--date",
        default="2011_09_26",
        help="recording date folder YYYY_MM_DD (default 2011_09_26; "
        "the calibration is always the real 2011_09_26 one)",
    )
    parser.add_argument(
        "--drive",
        type=int,
        default=1,
        help="drive number 0..9999 (default 1 -> drive_0001)",
    )
    parser.add_argument(
        "--columns",
        type=int,
        default=DEFAULT_COLUMNS,
        help=f"LIDAR azimuth steps per turn (default {DEFAULT_COLUMNS}, 0.18 deg like KITTI; fewer for "
        "small test drives)",
    )
    parser.add_argument(
        "--imu-noise",
        type=float,
        default=1.0,
        metavar="SCALE",
        help="multiply every IMU noise, bias and scale error by SCALE (default 1; 0 = exact fields)",
    )
    parser.add_argument(
        "--bias-walk",
        action="store_true",
        help="the IMU's velocity and gyro biases wander as random walks "
        "(slamlib.synth.WANDERING_BIASES: 5 mm/s and 0.2 mrad/s per sqrt(s)), scaled by --imu-noise",
    )
    parser.add_argument(
        "--distortion",
        action="store_true",
        help="sweep each scan column by column as KITTI's HDL-64E does (slamlib.synth.lidar): the car "
        "moves during the 0.1 s turn (default: every scan cast from one pose); slamlib run "
        "de-skews such a drive's scans by default",
    )
    parser.add_argument(
        "--layout",
        choices=("raw", "odometry"),
        default="raw",
        help="raw: a KITTI raw drive (OXTS + scans; default); odometry: a KITTI odometry sequence "
        "OUT/sequences/NN (scans, calib.txt, times.txt) with ground truth OUT/poses/NN.txt and no "
        "IMU, for slamlib run --odometry-dir OUT --sequence NN (LIDAR-only)",
    )
    parser.add_argument(
        "--sequence",
        type=int,
        default=None,
        metavar="NN",
        help="with --layout odometry: the sequence number 0..99 (default: the route's, e.g. 07, or 0)",
    )
    parser.add_argument(
        "--traffic",
        type=float,
        nargs="?",
        const=1.0,
        default=None,
        metavar="SCALE",
        help="moving cars, cyclists and pedestrians in the scans (slamlib.synth.traffic), SCALE times "
        "the density of a KITTI city drive (default without SCALE: 1; without --traffic: a static "
        f"town); SCALE in (0, {MAX_TRAFFIC:g}]",
    )
    parser.add_argument(
        "--no-scans",
        action="store_true",
        help="write OXTS packets and timestamps only (no Velodyne scans; slamlib run needs scans)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def route_name(text: str) -> str:
    """A ``--route`` value: one of :data:`ROUTES` or ``random:SEED`` (SEED an integer >= 0); raises
    ``argparse.ArgumentTypeError`` naming the choices otherwise."""
    import argparse

    name = str(text).strip()
    if name in ROUTES or RANDOM_ROUTE.fullmatch(name):
        return name
    raise argparse.ArgumentTypeError(
        f"route must be one of {', '.join(ROUTES)} or random:SEED (SEED an integer >= 0), got {text!r}"
    )


def _fail(message: str):
    raise SystemExit(f"slamlib synth: {message}")


def parse_route_frames(text: str, route: str):
    """``--frames`` text -> the ``frames`` argument of :func:`slamlib.synth.resolve_route`.

    KITTI routes: ``"A:B"`` -> ``(A, B)`` key frames, ``"A:"`` -> ``(A, None)``, ``":B"`` / ``"B"`` -> ``(0, B)``.
    Straight / loop / random:SEED: ``"N"``, ``"0:N"`` or ``":N"`` -> ``N`` frames; ``"0:"`` / ``":"`` -> the whole route
    (``None``). Raises ``ValueError`` with a one-line message otherwise.
    """
    s = str(text).strip()
    m = re.fullmatch(r"(\d*)\s*:\s*(\d*)|(\d+)", s)
    if m is None:
        raise ValueError(
            f"--frames must look like A:B, A:, :B or N (integers >= 0), got {text!r}"
        )
    if m.group(3) is not None:
        start, stop = 0, int(m.group(3))
    else:
        start = int(m.group(1)) if m.group(1) else 0
        stop = int(m.group(2)) if m.group(2) else None
    if stop is not None and stop <= start:
        raise ValueError(f"--frames {text!r} selects no frames")
    if route in KITTI_ROUTES:
        return (start, stop)
    if start != 0:
        raise ValueError(
            f"--frames {text!r}: route {route!r} always starts at its beginning; give a count N or 0:N"
        )
    return stop


#: Most LIDAR columns per revolution (a real HDL-64E has ~2,000 at 10 Hz; 20,000 = 1.3 million points a scan).
MAX_COLUMNS = 20_000
#: Largest IMU noise scale: 100 times the realistic noise; far beyond it the packets leave the OXTS physical ranges
#: that :func:`slamlib.kitti.oxts.parse_oxts_line` checks, and the drive could not be read back.
MAX_IMU_NOISE = 100.0


def _check_target(basedir: Path, date: str, drive: int) -> None:
    """Refuse to overwrite anything that is not ours: a non-synthetic drive folder, differing calibration files."""
    from slamlib.synth.writer import CALIB_FILES, MARKER, drive_dir, is_own_drive

    ddir = drive_dir(basedir, date, drive)
    if (basedir / date).exists() and not (basedir / date).is_dir():
        _fail(
            f"{basedir / date} exists and is not a folder; choose another --out or --date"
        )
    if ddir.is_symlink() or (ddir.exists() and not ddir.is_dir()):
        _fail(
            f"{ddir} exists and is not a folder; choose another --out, --date or --drive"
        )
    if ddir.is_dir() and not is_own_drive(ddir) and any(ddir.iterdir()):
        _fail(
            f"{ddir} exists and is not a slamlib synthetic drive (no {MARKER}); choose another --out, --date or "
            "--drive"
        )
    from slamlib.paths import kitti_sample_dir

    for name in CALIB_FILES:
        mine = kitti_sample_dir() / "raw" / "2011_09_26" / name
        theirs = basedir / date / name
        if theirs.is_file() and theirs.read_bytes() != mine.read_bytes():
            _fail(
                f"{theirs} exists and differs from the 2011_09_26 calibration this command writes; "
                "choose another --out or --date"
            )


def main(args) -> int:
    import datetime as dt
    import time

    from slamlib.synth import (
        WANDERING_BIASES,
        Hdl64,
        ImuNoise,
        resolve_route,
        write_drive,
    )

    if not 0 <= args.drive <= 9999:
        _fail(f"--drive must be in 0..9999, got {args.drive}")
    try:
        dt.datetime.strptime(args.date, "%Y_%m_%d")
    except ValueError:
        _fail(
            f"--date must be a date written YYYY_MM_DD (e.g. 2011_09_26), got {args.date!r}"
        )
    if not 8 <= args.columns <= MAX_COLUMNS:
        _fail(f"--columns must be in [8, {MAX_COLUMNS:,}], got {args.columns}")
    if not args.imu_noise <= MAX_IMU_NOISE:
        _fail(
            f"--imu-noise must be a finite number in [0, {MAX_IMU_NOISE:g}], got {args.imu_noise}"
        )
    try:
        noise = (WANDERING_BIASES if args.bias_walk else ImuNoise()).scaled(
            args.imu_noise
        )
    except ValueError:
        _fail(
            f"--imu-noise must be a finite number in [0, {MAX_IMU_NOISE:g}], got {args.imu_noise}"
        )
    if args.seed < 0:
        _fail(f"--seed must be >= 0, got {args.seed}")
    traffic = _traffic(args.traffic)
    try:
        frames = parse_route_frames(args.frames, args.route)
    except ValueError as exc:
        _fail(str(exc))
    if args.route in KITTI_ROUTES:
        from slamlib.synth import kitti_route

        keys = len(kitti_route(args.route).times)
        start, stop = frames
        if start > keys - 4 or (stop is not None and stop > keys):
            _fail(
                f"route {args.route} has key frames 0..{keys - 1}: --frames {args.frames!r} is out of range "
                f"(a drive needs at least 4 key frames of the sequence)"
            )
    try:
        route, n = resolve_route(args.route, frames)
    except ValueError as exc:
        _fail(f"--frames {args.frames!r}: {exc}")
    if args.route in KITTI_ROUTES and frames[1] is not None and n < frames[1] - frames[0]:
        _fail(
            f"route {args.route} has key frames 0..{keys - 1}: --frames {args.frames!r} spans only {n} frames, "
            f"asked for {frames[1] - frames[0]}"
        )
    basedir = args.out
    if basedir.exists() and not basedir.is_dir():
        _fail(f"--out {basedir} exists and is not a folder")
    if args.layout == "odometry":
        return _write_sequence(args, basedir, frames, n, traffic)
    if args.sequence is not None:
        _fail("--sequence goes with --layout odometry")
    _check_target(basedir, args.date, args.drive)

    frames_text = (
        f"key frames {frames[0]}:{'' if frames[1] is None else frames[1]}"
        if args.route in KITTI_ROUTES
        else "the whole route"
        if frames is None
        else f"frames 0:{frames}"
    )
    print(
        f"slamlib synth: route {args.route} ({frames_text}) -> {n} frames, seed {args.seed}, "
        f"{args.columns} LIDAR columns, IMU noise x{args.imu_noise:g}"
        + (", wandering biases" if args.bias_walk else "")
        + (", swept scans" if args.distortion else "")
        + (", no scans" if args.no_scans else "")
    )
    t0 = time.perf_counter()
    write_drive(
        basedir,
        args.route,
        date=args.date,
        drive=args.drive,
        frames=frames,
        seed=args.seed,
        noise=noise,
        lidar=Hdl64(columns=args.columns),
        scans=not args.no_scans,
        progress=not args.no_progress,
        traffic=traffic,
        distortion=args.distortion,
    )
    seconds = time.perf_counter() - t0
    from slamlib.synth.writer import drive_dir

    ddir = drive_dir(basedir, args.date, args.drive)
    drive = f"{args.drive:04d}"
    print(f"wrote {n} frames in {seconds:.1f} s to {ddir}")
    print("read it with:")
    print(f"  pykitti.raw({str(basedir)!r}, {args.date!r}, {drive!r})")
    if args.no_scans:
        print(
            "  (no Velodyne scans were written: pykitti reads the OXTS packets and timestamps; slamlib run needs "
            "scans)"
        )
    else:
        print(
            f"  slamlib run --basedir {shlex.quote(str(basedir))} --date {shlex.quote(args.date)} "
            f"--drive {drive}"
        )
    return 0


def check_traffic_scale(scale: float) -> None:
    """``ValueError`` naming ``--traffic`` unless ``0 < scale <= MAX_TRAFFIC`` (nan too); also for ``slamlib sweep``."""
    if not 0.0 < scale <= MAX_TRAFFIC:
        raise ValueError(
            f"--traffic must be a density scale in (0, {MAX_TRAFFIC:g}], got {scale}"
        )


def _traffic(scale):
    """``--traffic SCALE`` -> a :class:`slamlib.synth.TrafficConfig` SCALE times the default density, or ``None``."""
    if scale is None:
        return None
    try:
        check_traffic_scale(scale)
    except ValueError as exc:
        _fail(str(exc))
    from slamlib.synth import TrafficConfig

    return TrafficConfig().scaled(scale)


def _write_sequence(args, basedir: Path, frames, n: int, traffic=None) -> int:
    """``--layout odometry``: :func:`slamlib.synth.write_sequence` (no IMU: --imu-noise and --no-scans do not apply)."""
    import time

    from slamlib.synth import Hdl64, write_sequence

    if args.no_scans:
        _fail(
            "--no-scans does not go with --layout odometry: an odometry sequence is its scans"
        )
    sequence = (
        args.sequence
        if args.sequence is not None
        else (int(args.route) if args.route in KITTI_ROUTES else 0)
    )
    if not 0 <= sequence <= 99:
        _fail(f"--sequence must be in 0..99, got {sequence}")
    print(
        f"slamlib synth: route {args.route} -> {n} frames, seed {args.seed}, {args.columns} LIDAR columns, "
        f"KITTI odometry layout, sequence {sequence:02d}"
    )
    t0 = time.perf_counter()
    try:
        write_sequence(
            basedir,
            args.route,
            sequence,
            frames=frames,
            seed=args.seed,
            lidar=Hdl64(columns=args.columns),
            progress=not args.no_progress,
            traffic=traffic,
            distortion=args.distortion,
        )
    except FileExistsError as exc:
        _fail(f"{exc}")
    print(
        f"wrote {n} frames in {time.perf_counter() - t0:.1f} s to {basedir / 'sequences' / f'{sequence:02d}'}"
    )
    print("read it with:")
    print(f"  pykitti.odometry({str(basedir)!r}, {f'{sequence:02d}'!r})")
    print(
        f"  slamlib run --odometry-dir {shlex.quote(str(basedir))} --sequence {sequence:02d}"
    )
    return 0
