"""``slamlib run``: 3D particle SLAM on a KITTI raw drive (or the embedded synthetic default drive).

Examples::

    slamlib run --out runs/default                                   # the default synthetic drive (300 frames)
    slamlib run --still-default --out runs/still                     # its still twin: one pose a scan, no traffic
    slamlib run --full-default --out runs/full                       # the whole synthetic drive (~690 m)
    slamlib run --basedir ~/kitti --date 2011_09_26 --drive 0005 --frames 0:150 --particles 1000 --out runs/05
    slamlib run --out runs/default --video map.mp4                   # and a video of the map being built (.gif too)
    slamlib run --odometry-dir ~/kitti/dataset --sequence 07 --out runs/07   # KITTI odometry layout, LIDAR-only

Writes into ``--out``: the SLAM and dead-reckoning trajectories (KITTI and TUM formats), the ground truth,
``times.txt``, the map (PLY or PCD, open3d), ``metrics.json`` (ATE, RPE and the KITTI metric for SLAM and dead
reckoning, frames/s) and two plots (see :func:`slamlib.slam3d.run.save_run`).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

NAME = "run"
HELP = (
    "Run 3D particle SLAM on a KITTI raw drive or odometry sequence (default: the synthetic drive); write "
    "trajectories, map, metrics."
)


def startup_line(frames: int, seconds: float, fps: float, startup: float) -> str:
    """The line a run ends with: its frames, wall time, the steady frames/s after the first
    :data:`~slamlib.slam3d.run.STARTUP_FRAMES` frames and the start-up before them, in seconds
    (``benchmarks/startup.py`` reads it back with :data:`STARTUP_LINE_RE`)."""
    from slamlib.slam3d.run import STARTUP_FRAMES

    return (
        f"{frames} frames in {seconds:.1f} s: {fps:.1f} frames/s after a start-up of {startup:.2f} s "
        f"(imports, kernels compiled or loaded, the first {STARTUP_FRAMES} frames)"
    )


#: :func:`startup_line` read back; groups: frames, seconds, frames/s (``nan`` for a run too short to tell), start-up.
STARTUP_LINE_RE = re.compile(
    r"(\d+) frames in ([\d.]+) s: ([\d.]+|nan) frames/s after a start-up of ([\d.]+) s"
)


def add_arguments(parser) -> None:
    g = parser.add_argument_group(
        "data (omit them all for the embedded synthetic default drive)"
    )
    g.add_argument(
        "--basedir", type=Path, default=None, help="KITTI raw root folder holding DATE/"
    )
    g.add_argument("--date", default=None, help="recording date, e.g. 2011_09_26")
    g.add_argument("--drive", default=None, help="drive number, e.g. 0005 or 5")
    g.add_argument(
        "--odometry-dir",
        type=Path,
        default=None,
        metavar="DIR",
        help="instead of a raw drive: a KITTI odometry folder holding sequences/NN (and poses/NN.txt); "
        "no IMU there, so the run is LIDAR-only",
    )
    g.add_argument(
        "--sequence",
        default=None,
        metavar="NN",
        help="with --odometry-dir: the sequence, e.g. 07",
    )
    g.add_argument(
        "--full-default",
        action="store_true",
        help="with no --basedir: the whole synthetic drive (~1,100 frames, ~690 m) instead of 300 frames",
    )
    g.add_argument(
        "--still-default",
        action="store_true",
        help="with no --basedir: the default drive without sweep distortion, traffic and wandering IMU "
        "biases (the book's first chapters explain SLAM on it)",
    )
    g.add_argument(
        "--frames",
        default=None,
        metavar="A:B",
        help="frame range A:B (drive frame numbers, B exclusive; A:, :B or B also work); default all",
    )
    g.add_argument(
        "--allow-incomplete",
        action="store_true",
        help="read a drive left half written by an interrupted slamlib synth, or with more scans than "
        "times, as far as it goes (refused by default)",
    )
    from slamlib.commands import particles as _particles
    from slamlib.commands import tilt_sigma
    from slamlib.kernels import BACKENDS
    from slamlib.slam3d.config import (
        AUTO,
        IMU_PARTICLES,
        LIDAR_ONLY_PARTICLES,
        MAP_KINDS,
        OLD_MAP_NAMES,
        TILT_BIAS_MODELS,
        TILT_UP_SOURCES,
        AnnealConfig,
        FilterConfig,
        MapConfig,
        MotionConfig,
        ScanMatchConfig,
        SLAM3DConfig,
        TiltConfig,
        UpkeepConfig,
    )
    from slamlib.slam3d.run import DEFAULT_MAP_FORMAT, MAP_FORMATS

    def tri_state(value: str):
        """``auto`` / ``on`` / ``off`` of a tri-state option."""
        return {"auto": AUTO, "on": True, "off": False}[value]

    # --deskew alone is --deskew on
    tri = {"type": tri_state, "choices": [AUTO, True, False], "metavar": "{auto,on,off}"}
    tri.update(nargs="?", const=True)
    sc = parser.add_argument_group(
        "scan stage (step 2; settings of slamlib.slam3d.config, defaults from there)"
    )
    sc.add_argument(
        "--deskew",
        default=AUTO,
        **tri,
        help="motion-compensate each scan to the frame's pose time (ScanConfig.deskew; default auto: "
        "when the scans were taken over a sweep and not yet motion-compensated, as those of real "
        "KITTI raw drives and the default drive are; not the KITTI odometry benchmark's, which "
        "KITTI compensated, nor synthetic drives written without --distortion)",
    )
    mo = parser.add_argument_group("motion stage (steps 3, 5, 6)")
    mo.add_argument(
        "--lidar-only",
        action="store_true",
        help="ignore the IMU: step 3 holds the filter's own last motion (constant velocity), as on data "
        "without an IMU (the odometry layout, where it is always on)",
    )
    mo.add_argument(
        "--noise",
        type=float,
        default=1.0,
        metavar="SCALE",
        help="scale of step 6's configured motion noise (all six sigmas; default 1.0 = the defaults); with "
        "self-tuning, the spread of the first frames only",
    )
    mo.add_argument(
        "--self-tuning",
        type=tri_state,
        choices=[True, False],
        metavar="{on,off}",
        default=MotionConfig.self_tuning,
        help="learn the motion source's scale errors, biases and scatter from the filter's innovations and "
        "spread step 6 by them (MotionConfig.self_tuning; default "
        f"{'on' if MotionConfig.self_tuning else 'off'}); off: the configured spread every frame",
    )
    mp = parser.add_argument_group("map (steps 8 and 10) and its upkeep (after step 10)")
    mp.add_argument(
        "--map",
        dest="map_kind",
        choices=MAP_KINDS + tuple(OLD_MAP_NAMES),
        default=MapConfig.kind,
        metavar="{" + ",".join(MAP_KINDS) + "}",
        help=f"map structure: hashed NDT voxels or exact points in a Morton BVH (default {MapConfig.kind}; "
        f"the old names {' and '.join(OLD_MAP_NAMES)} still work)",
    )
    mp.add_argument(
        "--transient-span",
        type=int,
        default=UpkeepConfig.transient_span,
        metavar="FRAMES",
        help="every FRAMES frames evict the map voxels hit only within fewer than FRAMES frames and not "
        "since: the trails of moving cars and people (UpkeepConfig.transient_span; 0 = off, the "
        f"default {UpkeepConfig.transient_span}; the voxel_hash map only)",
    )
    f = parser.add_argument_group("filter (steps 1, 8, 9, 11)")
    f.add_argument(
        "--particles",
        type=_particles,
        default=FilterConfig.particles,
        metavar="N|auto",
        help=f"number of particles (default {FilterConfig.particles}: {IMU_PARTICLES} with an IMU, "
        f"{LIDAR_ONLY_PARTICLES} LIDAR-only)",
    )
    f.add_argument(
        "--points",
        type=int,
        default=FilterConfig.scored_points,
        help=f"scan points scored per particle per frame (default {FilterConfig.scored_points})",
    )
    f.add_argument(
        "--temperature",
        type=float,
        default=FilterConfig.temperature,
        help=f"likelihood temperature: log L = score / (N * T) (default {FilterConfig.temperature})",
    )
    f.add_argument(
        "--seed",
        type=int,
        default=SLAM3DConfig.seed,
        help=f"seed of the filter's random numbers (default {SLAM3DConfig.seed})",
    )
    f.add_argument(
        "--backend",
        choices=BACKENDS,
        default=SLAM3DConfig.backend,
        help=f"compute backend (default {SLAM3DConfig.backend})",
    )
    pr = parser.add_argument_group("prior stage (step 8's second term)")
    pr.add_argument(
        "--tilt-sigma",
        type=tilt_sigma,
        default=TiltConfig.tilt_sigma,
        metavar="RAD|auto|adaptive",
        help="hold roll and pitch to the accelerometer's gravity with this uncertainty (TiltConfig."
        "tilt_sigma, radians; auto: weighed by the accelerometer's own consistency; adaptive: by the gain a "
        "Kalman filter would give it, from that consistency, the tilt's walk and the map's hold, in the scan "
        "match too; 0 = off; default "
        f"{TiltConfig.tilt_sigma}; needs an IMU)",
    )
    pr.add_argument(
        "--tilt-up",
        choices=TILT_UP_SOURCES,
        default=TiltConfig.tilt_up,
        help="what separates gravity from the car's acceleration over the window: the IMU's velocities or the "
        f"filter's own positions (TiltConfig.tilt_up; default {TiltConfig.tilt_up})",
    )
    pr.add_argument(
        "--tilt-bias",
        choices=TILT_BIAS_MODELS,
        default=TiltConfig.tilt_bias,
        help="how the accelerometer's bias is told from the map's tilt: least squares over heading sectors or a "
        f"Kalman filter that lets the tilt walk (TiltConfig.tilt_bias; default {TiltConfig.tilt_bias})",
    )
    se = parser.add_argument_group("search stage (steps 6-8 again inside a frame)")
    se.add_argument(
        "--anneal-rounds",
        type=int,
        default=AnnealConfig.anneal_rounds,
        metavar="N",
        help="coarse-to-fine annealing rounds per frame (AnnealConfig.anneal_rounds; default "
        f"{AnnealConfig.anneal_rounds})",
    )
    se.add_argument(
        "--refine",
        dest="refine",
        type=int,
        default=None,
        help=argparse.SUPPRESS,  # the name before the stages: --anneal-rounds, with a note
    )
    po = parser.add_argument_group("polish stage (step 9's pose sharpened)")
    po.add_argument(
        "--scan-match",
        default=AUTO,
        **tri,
        help="after step 9, move the best pose by Newton steps to the map score's nearest peak on the scan "
        "thinned to one point per 0.5 m cube (ScanMatchConfig.match_voxel) "
        "and move the particles with it, unless that moves the pose more than "
        f"{ScanMatchConfig.match_gate:g} of step 6's spreads "
        "(ScanMatchConfig.match_gate: a leap to a wrong peak) (ScanMatchConfig.scan_match; default auto: "
        "on, except with the tilt prior, whose pull it would undo, unless --match-tilt)",
    )
    po.add_argument(
        "--match-tilt",
        action=argparse.BooleanOptionalAction,
        default=ScanMatchConfig.match_tilt,
        help="with the tilt prior on (--tilt-sigma not 0), the scan match's cost holds it too, weighed as step 8 "
        "weighs it, and --scan-match auto is on (ScanMatchConfig.match_tilt; default "
        f"{'on' if ScanMatchConfig.match_tilt else 'off'})",
    )
    for old in (
        "--no-deskew",
        "--no-scan-match",
    ):  # the switches before the tri-states, with a note
        parser.add_argument(
            old,
            dest=old[2:].replace("-", "_"),
            action="store_true",
            help=argparse.SUPPRESS,
        )
    lc = parser.add_argument_group("loop closure (a back end behind the filter)")
    lc.add_argument(
        "--loop-closure",
        action="store_true",
        help="cut local maps from the trajectory, find revisits by place recognition (map-closures) and "
        "by position in the graph, verify them by ICP and optimise a pose graph (GTSAM); writes "
        "slam_loop_closed_poses.txt and closures.json beside the filter's own poses (slamlib.loops)",
    )
    o = parser.add_argument_group("output")
    o.add_argument(
        "--out",
        type=Path,
        default=Path("slam3d_run"),
        help="output folder (default ./slam3d_run)",
    )
    o.add_argument(
        "--overwrite",
        action="store_true",
        help="replace result files (slam_poses.txt, map.ply, ...) already in --out that an earlier run "
        "did not write (an earlier run's results are always replaced), and an existing --video file",
    )
    o.add_argument(
        "--map-format",
        choices=MAP_FORMATS,
        default=DEFAULT_MAP_FORMAT,
        help=f"map file format (default {DEFAULT_MAP_FORMAT})",
    )
    o.add_argument("--no-plots", action="store_true", help="do not write the PNG plots")
    o.add_argument("--no-progress", action="store_true", help="no progress bar")
    o.add_argument(
        "--video",
        type=Path,
        default=None,
        metavar="PATH",
        help="also write a video of the map being built (top-down map, trajectory, current pose): "
        "PATH ending in .mp4 (needs imageio-ffmpeg) or .gif (Pillow)",
    )


def _drive_hint(basedir: Path, date: str | None, drive: str | None) -> str:
    """What exists under ``basedir``, to make a wrong --basedir / --date / --drive easy to fix."""
    if not basedir.is_dir():
        return f"--basedir {basedir} is not a folder"
    dates = sorted(
        p.name for p in basedir.iterdir() if p.is_dir() and p.name[:4].isdigit()
    )
    if date is None or date not in dates:
        return f"--date {date!r} not found in {basedir}; dates there: {', '.join(dates) or 'none'}"
    drives = sorted(
        p.name.split("_drive_")[1].split("_")[0]
        for p in (basedir / date).iterdir()
        if p.is_dir() and "_drive_" in p.name
    )
    if any(
        d == str(drive) or (d.isdigit() and str(drive).isdigit() and int(d) == int(drive))
        for d in drives
    ):
        # the drive is there: the error is about its contents, which the message names
        return ""
    return f"--drive {drive!r} not found in {basedir / date}; drives there: {', '.join(drives) or 'none'}"


#: The ``slamlib run`` option of each setting name that appears in the configuration's ValueError messages.
_OPTION_OF = {
    "particles": "--particles",
    "scored_points": "--points",
    "temperature": "--temperature",
    "anneal_rounds": "--anneal-rounds",
    "tilt_sigma": "--tilt-sigma",
    "seed": "--seed",
    "sigma": "--noise",
    "kind": "--map",
    "backend": "--backend",
    "transient_span": "--transient-span",
}


def _old_options(args) -> None:
    """The options before the filter's stages, taken as their new names with a note: ``--refine N`` is
    ``--anneal-rounds N``; ``--no-deskew`` / ``--no-scan-match`` are ``--deskew off`` / ``--scan-match off``."""
    if args.refine is not None:
        print(
            f"slamlib run: note: --refine {args.refine} is now --anneal-rounds {args.refine}"
        )
        args.anneal_rounds = args.refine
    for name in ("deskew", "scan_match"):
        if getattr(args, f"no_{name}"):
            option = name.replace("_", "-")
            print(f"slamlib run: note: --no-{option} is now --{option} off")
            setattr(args, name, False)


def _option_error(exc: ValueError) -> str:
    """``--option: message`` for a configuration ValueError (``--a, --b: message`` when it names several settings)."""
    text = str(exc)
    hits = sorted((text.find(k), opt) for k, opt in _OPTION_OF.items() if k in text)
    # every option the message is about, in its order
    options = list(dict.fromkeys(opt for _, opt in hits))
    return f"{', '.join(options)}: {text}" if options else text


def _run(drive, cfg, args):
    """``run_drive`` with the command's options; its warnings (a gap in time) printed after it as one line each
    (``warning: ...``), not amid the progress bar."""
    import warnings

    from slamlib.slam3d import run_drive

    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always", UserWarning)
        if args.video is not None:
            from slamlib.experiments.video import snapshot_every_for

            run = run_drive(
                drive,
                cfg,
                progress=not args.no_progress,
                snapshot_every=snapshot_every_for(len(drive)),
                loop_closure=args.loop_closure,
            )
        else:
            run = run_drive(
                drive, cfg, progress=not args.no_progress, loop_closure=args.loop_closure
            )
    for w in seen:
        if issubclass(w.category, UserWarning):
            print(f"warning: {w.message}")
        else:  # as it would have been shown
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    return run


def main(args) -> int:
    import json
    from dataclasses import replace

    from slamlib.atomic import describe_os_error
    from slamlib.errors import BackendUnavailableError, DataFormatError
    from slamlib.kitti import KittiRawDrive
    from slamlib.slam3d import SLAM3DConfig, parse_frames, save_run
    from slamlib.slam3d.config import AUTO, OLD_MAP_NAMES

    given = [x is not None for x in (args.basedir, args.date, args.drive)]
    odometry = args.odometry_dir is not None or args.sequence is not None
    if any(given) and not all(given):
        raise SystemExit(
            "slamlib run: give all of --basedir, --date and --drive, or none (synthetic default drive)"
        )
    if odometry and (args.odometry_dir is None or args.sequence is None):
        raise SystemExit("slamlib run: give both --odometry-dir and --sequence")
    if odometry and any(given):
        raise SystemExit(
            "slamlib run: give either a raw drive (--basedir, --date, --drive) or an odometry sequence "
            "(--odometry-dir, --sequence), not both"
        )
    for flag, on in (
        ("--full-default", args.full_default),
        ("--still-default", args.still_default),
    ):
        if on and (odometry or any(given)):
            raise SystemExit(
                f"slamlib run: {flag} chooses among the synthetic default drives; it does not apply to "
                "a drive given by --basedir or --odometry-dir"
            )
    import math

    for option, value in (("--particles", args.particles), ("--points", args.points)):
        if value != AUTO and value < 1:
            raise SystemExit(f"slamlib run: {option} must be >= 1, got {value}")
    if not (math.isfinite(args.noise) and args.noise >= 0):
        raise SystemExit(
            f"slamlib run: --noise must be finite and >= 0, got {args.noise}"
        )
    from slamlib.slam3d.run import check_output_dir

    try:
        check_output_dir(args.out, overwrite=args.overwrite)
    except ValueError as exc:
        raise SystemExit(f"slamlib run: --out: {exc}") from None
    if args.video is not None:
        from slamlib.experiments.video import check_video_path

        try:
            check_video_path(args.video, overwrite=args.overwrite)
        except (ValueError, ImportError) as exc:
            raise SystemExit(f"slamlib run: --video: {exc}") from None
    _old_options(args)
    kind = OLD_MAP_NAMES.get(args.map_kind, args.map_kind)
    if kind != args.map_kind:
        print(f"slamlib run: note: --map {args.map_kind} is now called --map {kind}")
    try:
        cfg = SLAM3DConfig.of(
            particles=args.particles,
            scored_points=args.points,
            kind=kind,
            backend=args.backend,
            seed=args.seed,
            anneal_rounds=args.anneal_rounds,
            temperature=args.temperature,
            deskew=args.deskew,
            scan_match=args.scan_match,
            match_tilt=args.match_tilt,
            tilt_sigma=args.tilt_sigma,
            tilt_up=args.tilt_up,
            tilt_bias=args.tilt_bias,
            transient_span=args.transient_span,
            self_tuning=args.self_tuning,
        )
        cfg = replace(
            cfg,
            motion=replace(
                cfg.motion.scaled(float(args.noise)),
                model="constant_velocity" if args.lidar_only or odometry else "imu",
            ),
        )
    except ValueError as exc:
        raise SystemExit(f"slamlib run: {_option_error(exc)}") from None
    if odometry:
        basedir, date, drive_id, source = (
            args.odometry_dir,
            None,
            args.sequence,
            "kitti odometry",
        )
    elif all(given):
        # "5" and "0005" both work
        drive_id = int(args.drive) if str(args.drive).isdigit() else args.drive
        basedir, date, source = args.basedir, args.date, "kitti"
    else:
        from slamlib.synth import default_drive

        basedir, date, drive_id = default_drive(
            full=args.full_default,
            realism=not args.still_default,
            progress=not args.no_progress,
        )
        source = (
            "synthetic default drive"
            + (" (full)" if args.full_default else "")
            + (" (still)" if args.still_default else "")
        )
    allow = {"allow_incomplete": args.allow_incomplete}
    try:
        if odometry:
            from slamlib.kitti import KittiOdometrySequence

            probe = KittiOdometrySequence(basedir, drive_id, **allow)
            drive = KittiOdometrySequence(
                basedir,
                drive_id,
                frames=parse_frames(args.frames, probe.n_sequence_frames),
                **allow,
            )
        else:
            probe = KittiRawDrive(basedir, date, drive_id, **allow)
            sl = parse_frames(args.frames, probe.n_drive_frames)
            drive = KittiRawDrive(basedir, date, drive_id, frames=sl, **allow)
    except DataFormatError as exc:
        hint = _drive_hint(Path(basedir), date, drive_id) if all(given) else ""
        raise SystemExit(
            f"slamlib run: {exc}" + (f"\n  hint: {hint}" if hint else "")
        ) from None
    except ValueError as exc:
        raise SystemExit(f"slamlib run: {exc}") from None
    if len(drive) < 2:
        if args.frames is not None:
            raise SystemExit(
                f"slamlib run: --frames {args.frames!r} selects {len(drive)} frame(s) of the drive; "
                "need at least 2"
            )
        raise SystemExit(
            f"slamlib run: the drive has {len(drive)} frame(s); need at least 2"
        )

    lidar_only = cfg.motion.model != "imu"
    print(
        f"slamlib run: {source}: {drive.path} frames {drive.frames[0]}..{drive.frames[-1]} ({len(drive)}), "
        f"{cfg.filter.particle_count(lidar_only)} particles x {cfg.filter.scored_points} points, "
        f"map {cfg.map.kind}, backend {cfg.backend}"
        + (", LIDAR-only (constant velocity)" if lidar_only else "")
    )
    if cfg.backend == "cpu":
        from slamlib.kernels.cpu import kernels_cached

        if kernels_cached() is False:
            print(
                "compiling kernels (first run only: later runs load them from the cache)",
                flush=True,
            )
    try:
        run = _run(drive, cfg, args)
    except BackendUnavailableError as exc:
        raise SystemExit(f"slamlib run: {exc}") from None
    # bad frame data (e.g. IMU values beyond physical limits)
    except (DataFormatError, ValueError) as exc:
        raise SystemExit(f"slamlib run: {exc}") from None
    try:
        files = save_run(
            run,
            args.out,
            map_format=args.map_format,
            plots=not args.no_plots,
            extra={
                "source": source,
                "basedir": str(basedir),
                "date": date,
                ("sequence" if odometry else "drive"): str(drive_id),
            },
        )
    # a non-finite pose refused by the writers, a full disk, ...
    except (ValueError, OSError) as exc:
        why = describe_os_error(exc, args.out) if isinstance(exc, OSError) else exc
        raise SystemExit(
            f"slamlib run: could not write the results into {args.out}: {why}"
        ) from None
    startup = run.warm_at - getattr(args, "started", run.started_at)
    print(startup_line(len(run.poses), run.seconds, run.steady_fps, startup))
    info = json.loads(Path(files["metrics"]).read_text())
    if "metrics" in info:
        m = info["metrics"]

        def num(x):  # metrics.json holds null for a non-finite number
            return float("nan") if x is None else x

        print(
            f"path {num(m['path_length_m']):.0f} m{'':8s}{'ATE RMSE (m)':>14s}{'KITTI t_err (%)':>17s}"
        )
        for key, label in (
            ("slam", "particle SLAM"),
            ("slam_loop_closed", "  + loop closure"),
            ("dead_reckoning", "dead reckoning"),
        ):
            if key not in m:  # LIDAR-only: no dead reckoning; no loop closure asked
                continue
            k = num(m[key].get("kitti_t_err_percent"))
            # the KITTI metric needs 100 m segments
            kitti = f"{k:17.3f}" if math.isfinite(k) else f"{'n/a (path < 100 m)':>20s}"
            print(f"{label:22s}{num(m[key]['ate_rmse_m']):14.3f}{kitti}")
        if "segments" in m:
            print(f"{len(m['segments'])} segments (gaps in time): {m['evaluated']}")
    if run.loop_closer is not None:
        c = run.loop_closer.closures
        print(
            f"loop closure: {len(run.loop_closer.mapper.maps)} local maps, {len(c)} verified "
            f"closures, {sum(x.kept for x in c)} kept by the pose graph"
        )
    if info.get("n_skipped_frames"):
        print(f"warning: {info['warnings'][0]}")
    if args.video is not None:
        from slamlib.experiments.video import write_map_video

        v = write_map_video(run, args.video, progress=not args.no_progress)
        print(
            f"wrote {v['frames']} video frames ({v['seconds']:.1f} s, {v['bytes'] / 1e6:.2f} MB) to {args.video}"
        )
    print(f"wrote {len(files)} files to {args.out}")
    return 0
