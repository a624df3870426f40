"""``slamlib sweep``: SLAM and its peers over routes x seeds x settings on a Dask cluster, into one tidy table.

Examples::

    slamlib sweep --out sweeps/quick                                   # route 07 key frames 0:150, seeds 0 and 1
    slamlib sweep --out sweeps/all --routes 00,05,07 --frames 0: --seeds 0,1       # the whole routes
    slamlib sweep --out sweeps/lidar --layouts odometry --particles 300,1000      # LIDAR-only, two settings
    slamlib sweep --out sweeps/real --routes 00,05,07 --frames 0: --distortion --traffic --bias-walk \\
        --deskew --anneal-rounds 2 --tilt-sigma 0.003                # realistic drives, annealed, tilt held
    slamlib sweep --out sweeps/loops --layouts odometry --frames 0: --methods slamlib_loop_closure,kiss_slam \\
        --distortion --traffic                            # loop closure against KISS-SLAM, whole routes
    slamlib sweep --out sweeps/x --scheduler tcp://10.0.0.5:8786                  # on an existing Dask cluster

Writes ``OUT/sweep.csv`` (one row per run: route, frames, seed, layout, method, settings, path length, KITTI
translational and rotational error, ATE RMSE, the translational error's vertical and horizontal parts, dead
reckoning's KITTI error, frames/s, seconds) and ``OUT/sweep.png`` (KITTI error per route and method). Drives are
generated once into ``--data`` and reused.
See :mod:`slamlib.experiments.sweep`.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import shlex
import time
from pathlib import Path

from slamlib.commands import tilt_sigma
from slamlib.commands.synth import route_name

NAME = "sweep"
HELP = "Run SLAM (and KISS-ICP) over routes x seeds x settings as Dask tasks; write one table (CSV) and a plot."

OUT_FILES = ("sweep.csv", "sweep.json", "sweep.png")
#: The rows finished so far (``slamlib.experiments.sweep.append_journal``): kept when a sweep is interrupted or a
#: task fails, so that the same command run again runs only the rest; removed once the table is written.
JOURNAL = "sweep.resume.jsonl"


def parse_settings(items) -> dict:
    """``{name: value}`` of ``--set NAME=VALUE`` items: VALUE read as JSON, else kept as the word; each checked by
    building the configuration (ValueError naming the item)."""
    from slamlib.slam3d.config import SLAM3DConfig

    out = {}
    for item in items:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise ValueError(f"expected NAME=VALUE, got {item!r}")
        try:
            value = json.loads(text)
        except ValueError:
            value = text
        out[name.strip()] = value
    SLAM3DConfig.of(**out)  # unknown names and bad values fail here, before any work
    return out


def add_arguments(parser) -> None:
    parser.add_argument(
        "--out",
        type=Path,
        required=True,
        help="output folder for sweep.csv and sweep.png",
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace sweep.csv / sweep.png already in --out",
    )
    parser.add_argument(
        "--routes",
        default="07",
        help="comma-separated routes: 00, 05, 07, straight, loop, random:SEED (default 07)",
    )
    parser.add_argument(
        "--frames",
        default="0:150",
        metavar="A:B",
        help="KITTI routes: key frames A:B (A: to the end); straight / loop: N or 0:N (default 0:150)",
    )
    parser.add_argument(
        "--seeds",
        default="0,1",
        help="comma-separated seeds: one synthetic drive and filter seed each "
        "(default 0,1)",
    )
    parser.add_argument(
        "--layouts",
        default="raw",
        help="comma-separated: raw (LIDAR + IMU), odometry (LIDAR only) (default raw)",
    )
    parser.add_argument(
        "--methods",
        default="slamlib,kiss_icp",
        help="comma-separated: slamlib, kiss_icp, slamlib_loop_closure (slamlib's filter with its loop-closing "
        "back end), kiss_slam (default slamlib,kiss_icp)",
    )
    parser.add_argument(
        "--particles",
        default=None,
        help="comma-separated particle counts, one slamlib setting "
        "each (default: the filter's default)",
    )
    parser.add_argument(
        "--anneal-rounds",
        "--refine",  # the name before the filter's stages
        dest="anneal_rounds",
        type=int,
        default=None,
        metavar="K",
        help="slamlib's coarse-to-fine annealing rounds per frame (AnnealConfig.anneal_rounds) in every "
        "setting (default: the filter's default)",
    )
    parser.add_argument(
        "--tilt-sigma",
        type=tilt_sigma,
        default=None,
        metavar="RAD|auto|adaptive",
        help="slamlib holds roll and pitch to the accelerometer's gravity with this uncertainty "
        "(TiltConfig.tilt_sigma, radians; auto: weighed by the accelerometer's own consistency; adaptive: "
        "by the gain a Kalman filter would give it, in the scan match too; 0 = off; "
        "default: the filter's default)",
    )
    parser.add_argument(
        "--deskew",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="slamlib de-skews every scan with the frame's motion, or none (ScanConfig.deskew; "
        "default: the swept scans, those of drives with --distortion; KISS-ICP de-skews "
        "whenever the drives have --distortion)",
    )
    parser.add_argument(
        "--scan-match",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="slamlib scan-matches its best pose after step 9, or never (ScanMatchConfig.scan_match; "
        "default: on, except with the tilt prior)",
    )
    parser.add_argument(
        "--set",
        dest="set_",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="any slamlib setting by name (SLAM3DConfig.setting_names), VALUE as JSON (true, 0.05, "
        '"auto", [1, 2, 3]) or else a word; repeatable, in every setting, e.g. --set self_tuning=false',
    )
    real = parser.add_argument_group(
        "drive realism (default: a still town, unswept scans, constant IMU biases)"
    )
    real.add_argument(
        "--distortion",
        action="store_true",
        help="scans swept column by column as a real HDL-64E (slamlib.synth.lidar)",
    )
    real.add_argument(
        "--traffic",
        type=float,
        nargs="?",
        const=1.0,
        default=None,
        metavar="SCALE",
        help="moving cars, cyclists and pedestrians at SCALE times a KITTI city drive's density "
        "(default without SCALE: 1)",
    )
    real.add_argument(
        "--bias-walk",
        action="store_true",
        help="the IMU biases wander as random walks (slamlib.synth.WANDERING_BIASES; raw layout)",
    )
    real.add_argument(
        "--imu-noise",
        type=float,
        default=1.0,
        metavar="SCALE",
        help="multiply every IMU noise, bias, scale error and bias walk by SCALE (raw layout; default 1)",
    )
    real.add_argument(
        "--start-tilt",
        default=None,
        metavar="ROLL,PITCH",
        help="the drive's first pose stands tilted against gravity by ROLL and PITCH radians, as a real drive's "
        "may (KITTI raw drive 0001's: 0.0358,0.0090); applied to the accelerometer as the drive is read "
        "(slamlib.synth.tilt.StartTilted; raw layout; default level)",
    )
    parser.add_argument(
        "--data",
        type=Path,
        default=None,
        help="folder for the generated drives, reused by later sweeps (default: the cache, "
        "$SLAMLIB_CACHE/sweep)",
    )
    parser.add_argument(
        "--discard-drives",
        action="store_true",
        help="remove each generated drive from --data once its runs are done: the disk then holds about "
        "one drive per worker (a 1,000-frame raw drive is 1.6 GB), and a later sweep generates them again",
    )
    parser.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="address of an existing Dask scheduler (default: a local cluster on this machine)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        help="worker processes of the local cluster (default: one per core)",
    )
    parser.add_argument(
        "--threads-per-run",
        type=int,
        default=None,
        metavar="N",
        help="threads each run (slamlib's Numba, KISS-ICP's registration) and each drive's generation may use "
        "(default with the local cluster: the cores divided among the workers, at least 1, so that each run's "
        "frames/s is its own; with --scheduler: the workers' own settings)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _version(distribution: str) -> str | None:
    """The installed version of ``distribution``, or None."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(distribution)
    except PackageNotFoundError:
        return None


def _run_resumable(tasks, data, args, journal: Path) -> list:
    """The sweep's rows: those in ``journal`` from an earlier, interrupted run of the same command, the others
    run now and appended to it as they finish; a failed task is one line naming it."""
    from slamlib.experiments.sweep import (
        SweepTaskError,
        append_journal,
        read_journal,
        run_sweep,
    )

    done = read_journal(journal)
    if done:
        print(f"resuming: {len(done)} runs already done in {journal}")
    try:
        return run_sweep(
            tasks,
            data,
            scheduler=args.scheduler,
            workers=args.workers,
            progress=not args.no_progress,
            done=done,
            on_row=lambda task, row: append_journal(journal, task, row),
            discard_drives=args.discard_drives,
            threads=args.threads_per_run,
        )
    except SweepTaskError as exc:
        n = len(read_journal(journal))
        _fail(
            f"{exc}; the {n} runs finished are kept in {journal}: the same command runs only the rest"
        )
    except (OSError, TimeoutError) as exc:
        _fail(f"could not reach or run the Dask cluster: {exc}")


def _write_outputs(out: Path, rows: list, info: dict) -> None:
    """``sweep.csv``, ``sweep.json`` and ``sweep.png`` into ``out``, whole (:func:`slamlib.atomic.atomic_folder`;
    the caller holds the lock), then the journal of finished rows removed."""
    import matplotlib

    from slamlib.atomic import atomic_folder
    from slamlib.experiments.sweep import plot_sweep, write_table

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with atomic_folder(
        out, lambda path: path not in OUT_FILES, what="--out", locked=True
    ) as tmp:
        write_table(rows, tmp / "sweep.csv")
        (tmp / "sweep.json").write_text(
            json.dumps(info, indent=1) + "\n", encoding="utf-8"
        )
        fig = plot_sweep(rows)
        fig.savefig(tmp / "sweep.png", dpi=100, bbox_inches="tight")
        plt.close(fig)
    (out / JOURNAL).unlink(missing_ok=True)


def _fail(message: str):
    raise SystemExit(f"slamlib sweep: {message}")


def _list(text: str, option: str, allowed=None, kind=str) -> list:
    items = [x.strip() for x in str(text).split(",") if x.strip()]
    if not items:
        _fail(f"{option} needs at least one value, got {text!r}")
    try:
        items = [kind(x) for x in items]
    except ValueError:
        _fail(f"{option} must be comma-separated {kind.__name__} values, got {text!r}")
    if allowed is not None:
        bad = [x for x in items if x not in allowed]
        if bad:
            _fail(f"{option}: {', '.join(map(str, bad))} not one of {', '.join(allowed)}")
    return items


def _routes(text: str) -> list[str]:
    """``--routes``: each a route ``slamlib synth --route`` takes (:func:`slamlib.commands.synth.route_name`)."""
    items = _list(text, "--routes")
    for item in items:
        try:
            route_name(item)
        except argparse.ArgumentTypeError as error:
            _fail(f"--routes: {error}")
    return items


def main(args) -> int:
    from slamlib.commands.synth import parse_route_frames

    routes = _routes(args.routes)
    seeds = _list(args.seeds, "--seeds", kind=int)
    if any(s < 0 for s in seeds):
        _fail(f"--seeds must be >= 0, got {args.seeds!r}")
    layouts = _list(args.layouts, "--layouts", ("raw", "odometry"))
    from slamlib.experiments.sweep import METHODS

    methods = _list(args.methods, "--methods", METHODS)
    settings = [{}]
    if args.particles is not None:
        counts = _list(args.particles, "--particles", kind=int)
        from slamlib.slam3d.config import MAX_PARTICLES

        if any(not 1 <= p <= MAX_PARTICLES for p in counts):
            _fail(
                f"--particles must be in [1, {MAX_PARTICLES:,}], got {args.particles!r}"
            )
        settings = [{"particles": p} for p in counts]
    from slamlib.commands.synth import check_traffic_scale

    if args.traffic is not None:
        try:
            check_traffic_scale(args.traffic)
        except ValueError as exc:
            _fail(str(exc))
    from slamlib.commands.synth import MAX_IMU_NOISE

    if not (math.isfinite(args.imu_noise) and 0 <= args.imu_noise <= MAX_IMU_NOISE):
        _fail(
            f"--imu-noise must be a finite number in [0, {MAX_IMU_NOISE:g}], got {args.imu_noise}"
        )
    if args.anneal_rounds is not None:
        from slamlib.slam3d.config import MAX_ANNEAL_ROUNDS

        rounds = args.anneal_rounds
        if not 0 <= rounds <= MAX_ANNEAL_ROUNDS:
            _fail(f"--anneal-rounds must be in [0, {MAX_ANNEAL_ROUNDS}], got {rounds}")
        settings = [dict(s, anneal_rounds=rounds) for s in settings]
    if args.tilt_sigma is not None:
        numeric = not isinstance(args.tilt_sigma, str)
        if numeric and not (math.isfinite(args.tilt_sigma) and args.tilt_sigma >= 0):
            _fail(
                f"--tilt-sigma must be a finite number >= 0 (radians), auto or adaptive, got "
                f"{args.tilt_sigma}"
            )
        settings = [dict(s, tilt_sigma=args.tilt_sigma) for s in settings]
    if args.deskew is not None:
        settings = [dict(s, deskew=args.deskew) for s in settings]
    if args.scan_match is not None:
        settings = [dict(s, scan_match=args.scan_match) for s in settings]
    if args.set_:
        try:
            extra = parse_settings(args.set_)
        except ValueError as exc:
            _fail(f"--set: {exc}")
        settings = [dict(s, **extra) for s in settings]
    if args.workers is not None and args.workers < 1:
        _fail(f"--workers must be >= 1, got {args.workers}")
    if args.threads_per_run is not None and args.threads_per_run < 1:
        _fail(f"--threads-per-run must be >= 1, got {args.threads_per_run}")
    from slamlib.experiments.sweep import sweep_threads

    args.threads_per_run = sweep_threads(
        args.threads_per_run, args.scheduler, args.workers
    )
    frames = set()
    for route in routes:
        try:
            f = parse_route_frames(args.frames, route)
        except ValueError as exc:
            _fail(str(exc))
        frames.add((f[0], f[1]) if isinstance(f, tuple) else (0, f))
    if len(frames) != 1:
        _fail(
            "--frames must mean the same for every route: use A:B for KITTI routes and straight / loop alike"
        )
    (frames,) = frames
    out = args.out
    if out.exists() and not out.is_dir():
        _fail(f"--out {out} exists and is not a folder")
    clash = [n for n in OUT_FILES if (out / n).exists()]
    if clash and not args.overwrite:
        _fail(
            f"--out {out} holds {', '.join(clash)}: pass --overwrite to replace, or choose another folder"
        )
    if "kiss_icp" in methods:
        from slamlib.peers import INSTALL_HINT, kiss_icp_available

        if not kiss_icp_available():
            _fail(INSTALL_HINT + " (or --methods slamlib)")
    if "kiss_slam" in methods and importlib.util.find_spec("kiss_slam") is None:
        _fail(
            "--methods kiss_slam: KISS-SLAM is not installed (`make setup` installs kiss-slam 0.0.2, "
            "see pyproject.toml's `loops` extra)"
        )
    try:
        import distributed  # noqa: F401
    except ImportError:
        _fail(
            "slamlib sweep needs Dask: pip install 'dask[distributed]' (or pip install -e '.[sweep]')"
        )

    from slamlib.experiments.sweep import (
        DriveOptions,
        sweep_tasks,
    )
    from slamlib.paths import cache_dir
    from slamlib.synth import GENERATOR_VERSION

    try:
        tilt = (
            tuple(float(a) for a in args.start_tilt.split(","))
            if args.start_tilt is not None
            else (0.0, 0.0)
        )
        drive = DriveOptions(
            args.distortion, args.traffic or 0.0, args.bias_walk, args.imu_noise, tilt
        )
    except ValueError as exc:
        _fail(f"--start-tilt: {exc}")
    tasks = sweep_tasks(routes, seeds, layouts, methods, settings, frames, drive)
    data = args.data if args.data is not None else cache_dir() / "sweep"
    print(
        f"slamlib sweep: {len(tasks)} runs ({', '.join(routes)} x seeds {', '.join(map(str, seeds))} x "
        f"{', '.join(layouts)} x {', '.join(methods)}), drives {drive.label() or 'still, unswept'} in {data}, "
        f"scheduler {args.scheduler or 'local cluster'}"
    )
    from slamlib.machine import describe

    started = time.perf_counter()
    info = {
        "command": "slamlib " + " ".join(shlex.quote(a) for a in args.argv),
        "machine": describe(),
        "workers": args.workers,
        "threads_per_run": args.threads_per_run,
        "scheduler": args.scheduler,
        "generator_version": GENERATOR_VERSION,
        "kiss_icp_version": _version("kiss-icp"),
        "kiss_slam_version": _version("kiss-slam"),
        "slamlib_version": _version("slamlib"),
    }
    from slamlib.atomic import folder_lock

    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    try:
        with folder_lock(out, what="--out"):
            rows = _run_resumable(tasks, data, args, out / JOURNAL)
            info["seconds"] = (
                time.perf_counter() - started
            )  # the machine's "utc" is the start
            _write_outputs(out, rows, info)
    finally:  # an interrupted or failed first sweep into a new folder leaves no empty folder
        if created and out.is_dir() and not any(out.iterdir()):
            out.rmdir()
    print(
        f"{'route':>8s} {'seed':>4s} {'layout':>8s} {'method':>9s} {'settings':>18s} {'t_err %':>8s} "
        f"{'height %':>8s} {'ATE m':>7s}"
    )
    for r in rows:
        print(
            f"{r['route']:>8s} {r['seed']:4d} {r['layout']:>8s} {r['method']:>9s} {r['settings']:>18s} "
            f"{r['kitti_t_err_percent']:8.3f} {r.get('kitti_t_err_vertical_percent', float('nan')):8.3f} "
            f"{r['ate_rmse_m']:7.3f}"
        )
    print(
        f"wrote {out / 'sweep.csv'}, {out / 'sweep.json'} (command, machine, versions) and {out / 'sweep.png'}"
    )
    return 0
