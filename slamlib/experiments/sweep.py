"""Sweeps: SLAM (and its peers) over routes x seeds x settings, as tasks on a Dask cluster, into one tidy table.

A sweep is the cross product of

* **routes** of the synthetic generator (``"07"``, ``"05"``, ``"00"``: the real KITTI odometry routes;
  ``"straight"``, ``"loop"``) with a frame selection (:func:`slamlib.synth.resolve_route`),
* **seeds**: each seed is one synthetic drive (town, sensor and IMU noise) *and* the filter's seed (unless the
  settings name a ``seed``: then that is the filter's, to repeat runs on the same drives),
* **layouts**: ``"raw"`` (KITTI raw drive: LIDAR + IMU) or ``"odometry"`` (KITTI odometry sequence: LIDAR only),
* **methods**: ``"slamlib"`` for every entry of ``settings`` (dicts of :meth:`SLAM3DConfig.of` settings, e.g.
  ``{"particles": 100}`` or ``{"deskew": True}``), ``"slamlib_loop_closure"`` likewise, its poses re-anchored by
  the loop-closing back end (:func:`slamlib.slam3d.run_drive`'s ``loop_closure``), and the peers once per drive:
  ``"kiss_icp"`` (:func:`slamlib.peers.kiss_icp_poses`) and ``"kiss_slam"`` (:func:`slamlib.peers.kiss_slam_poses`),
  each with its de-skewing on exactly when the drive's scans are swept, and then its poses moved from the sweep's
  end to the frames' pose times, where the ground truth is,
* one set of **drive options** (:class:`DriveOptions`) for every drive: sweep distortion, moving traffic, wandering
  IMU biases (all off by default: the town holds still and every scan is cast from one pose).

Each (route, seed, layout) drive is generated once, by one task, into ``data_dir`` (:func:`drive_task`); every run
on it is a task that depends on it (:func:`run_task`), so Dask schedules the generation first and spreads the
runs over the workers. Every run returns one row (:data:`COLUMNS`); :func:`run_sweep` collects the rows as they
complete (a progress bar) and :func:`write_table` writes them as CSV, one row per run ("tidy": one observation per
row, one variable per column; Wickham, J. Stat. Softw. 2014). :func:`plot_sweep` draws the KITTI error per route
and method.

The scheduler is Dask's (``distributed``): a ``LocalCluster`` of one single-threaded worker process per core by
default (each run uses Numba's threads inside its worker), or an existing cluster at ``scheduler`` (an address
such as ``tcp://10.0.0.5:8786``), whose workers must see ``data_dir``.
"""

from __future__ import annotations

import csv
import hashlib
import json
import logging
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

__all__ = [
    "DriveOptions",
    "SweepTask",
    "sweep_tasks",
    "drive_task",
    "run_task",
    "run_sweep",
    "discard_drive",
    "RUN_PRIORITY",
    "DRIVE_PRIORITY",
    "threads_per_run",
    "sweep_threads",
    "use_threads",
    "SweepTaskError",
    "task_key",
    "append_journal",
    "read_journal",
    "write_table",
    "read_table",
    "plot_sweep",
    "COLUMNS",
    "METHODS",
    "SLAMLIB_METHODS",
    "LAYOUTS",
]

METHODS = ("slamlib", "kiss_icp", "slamlib_loop_closure", "kiss_slam")
#: The methods that are slamlib's filter, run once per entry of a sweep's ``settings``.
SLAMLIB_METHODS = ("slamlib", "slamlib_loop_closure")
LAYOUTS = ("raw", "odometry")
#: The columns of a sweep's table, in order (``drive`` is :meth:`DriveOptions.label`, empty for a still town seen by
#: unswept scans; ``settings`` is the slamlib settings as JSON, empty for KISS-ICP; the KITTI error's vertical and
#: horizontal parts are :func:`slamlib.metrics.kitti_odometry_error`'s, empty in tables written before them;
#: ``match_rejected_frames`` and ``match_max_kept_distance``, slamlib's only, are the scan match's gate's
#: :attr:`~slamlib.slam3d.ParticleSLAM3D.n_match_rejected` and ``match_max_kept_distance``, empty in older tables;
#: ``start_lines_kept``, slamlib's only, the starts where ``ConstantVelocityConfig.start_line``'s search was kept,
#: :attr:`~slamlib.slam3d.ParticleSLAM3D.n_start_lines_kept`, empty in older tables; ``tilt_err_max_deg`` the largest
#: roll-and-pitch error of a frame, :func:`slamlib.metrics.tilt_errors`, and ``frame_time_max_ratio``, slamlib's
#: only, its slowest frame over its median one after the start-up, :meth:`~slamlib.slam3d.run.SLAMRun.frame_time_ratio`,
#: both empty in older tables).
COLUMNS = (
    "route",
    "frames",
    "seed",
    "layout",
    "drive",
    "method",
    "settings",
    "path_length_m",
    "kitti_t_err_percent",
    "kitti_r_err_deg_per_m",
    "ate_rmse_m",
    "kitti_t_err_vertical_percent",
    "kitti_t_err_horizontal_percent",
    "dead_reckoning_kitti_t_err_percent",
    "dead_reckoning_ate_rmse_m",
    "fps",
    "seconds",
    "match_rejected_frames",
    "match_max_kept_distance",
    "start_lines_kept",
    "tilt_err_max_deg",
    "frame_time_max_ratio",
)


@dataclass(frozen=True)
class DriveOptions:
    """How real the synthetic drives of a sweep are (:func:`slamlib.synth.write_drive` / ``write_sequence``).

    ``distortion``: each scan swept column by column as a real HDL-64E (:mod:`slamlib.synth.lidar`); ``traffic``:
    moving cars, cyclists and pedestrians at that multiple of a KITTI city drive's density
    (:data:`slamlib.synth.traffic.KITTI_CITY`; 0 = none); ``bias_walk``: the IMU biases wander
    (:data:`slamlib.synth.WANDERING_BIASES`); ``imu_noise``: every IMU noise, bias, scale error and bias walk
    multiplied by this (:meth:`slamlib.synth.ImuNoise.scaled`; 1 = the generator's); ``start_tilt``: ``(roll,
    pitch)`` (rad) the drive's first pose stands tilted against gravity, applied to the accelerometer as the drive
    is read (:class:`slamlib.synth.tilt.StartTilted`; the files, and so the drive's folder, are the level drive's).
    The last three: raw layout only, the odometry layout has no IMU.
    """

    distortion: bool = False
    traffic: float = 0.0
    bias_walk: bool = False
    imu_noise: float = 1.0
    start_tilt: tuple = (0.0, 0.0)

    def __post_init__(self):
        if not (np.isfinite(self.traffic) and self.traffic >= 0):
            raise ValueError(f"traffic must be a finite number >= 0, got {self.traffic}")
        if not (np.isfinite(self.imu_noise) and self.imu_noise >= 0):
            raise ValueError(
                f"imu_noise must be a finite number >= 0, got {self.imu_noise}"
            )
        tilt = tuple(float(a) for a in self.start_tilt)
        if len(tilt) != 2 or not all(np.isfinite(a) and abs(a) < 0.5 for a in tilt):
            raise ValueError(
                f"start_tilt must be (roll, pitch) in radians, each finite and under 0.5 in size, got "
                f"{self.start_tilt!r}"
            )
        object.__setattr__(self, "start_tilt", tilt)

    def label(self) -> str:
        """``"distortion, traffic x2, bias walk"`` (the options that are on), ``""`` for none."""
        on = (
            (["distortion"] if self.distortion else [])
            + ([f"traffic x{self.traffic:g}"] if self.traffic else [])
            + (["bias walk"] if self.bias_walk else [])
            + ([f"IMU noise x{self.imu_noise:g}"] if self.imu_noise != 1 else [])
            + (
                [
                    "start tilted {:g}, {:g} mrad".format(
                        *(1e3 * a for a in self.start_tilt)
                    )
                ]
                if any(self.start_tilt)
                else []
            )
        )
        return ", ".join(on)

    def write_kwargs(self, layout: str) -> dict:
        """The keyword arguments of the generator that give these options."""
        from slamlib.synth import WANDERING_BIASES, ImuNoise
        from slamlib.synth.traffic import KITTI_CITY

        kw = {
            "distortion": bool(self.distortion),
            "traffic": KITTI_CITY.scaled(self.traffic) if self.traffic else None,
        }
        if layout == "raw" and (self.bias_walk or self.imu_noise != 1):
            noise = WANDERING_BIASES if self.bias_walk else ImuNoise()
            kw["noise"] = noise.scaled(self.imu_noise)
        return kw


@dataclass(frozen=True)
class SweepTask:
    """One run of a sweep: a method with its settings on one synthetic drive."""

    route: str
    frames: tuple
    seed: int
    layout: str
    method: str
    settings: dict = field(default_factory=dict, hash=False, compare=False)
    drive: DriveOptions = DriveOptions()

    def drive_key(self) -> str:
        """Name of this task's drive in ``data_dir``: route, frames, seed, layout, drive options (when any is on)
        and the generator's version."""
        from slamlib.synth import GENERATOR_VERSION

        key = [GENERATOR_VERSION, self.route, list(self.frames), self.seed, self.layout]
        # drives without options keep the names they always had; a start tilt is applied as the drive is read
        if replace(self.drive, start_tilt=(0.0, 0.0)) != DriveOptions():
            options = [self.drive.distortion, self.drive.traffic, self.drive.bias_walk]
            # drives at the generator's IMU noise keep the names they had before the option
            if self.drive.imu_noise != 1:
                options.append(self.drive.imu_noise)
            key.append(options)
        text = json.dumps(key)
        return f"{self.layout}-{self.route}-s{self.seed}-{hashlib.sha1(text.encode()).hexdigest()[:10]}"


def sweep_tasks(
    routes,
    seeds,
    layouts=("raw",),
    methods=METHODS,
    settings=({},),
    frames=(0, None),
    drive: DriveOptions = DriveOptions(),
) -> list:
    """The cross product, as :class:`SweepTask` s (the peers once per drive: they have no slamlib settings),
    every drive written with the options ``drive``."""
    tasks = []
    for route in routes:
        for seed in seeds:
            for layout in layouts:
                if layout not in LAYOUTS:
                    raise ValueError(
                        f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}"
                    )
                for method in methods:
                    if method not in METHODS:
                        raise ValueError(
                            f"method must be one of {', '.join(METHODS)}, got {method!r}"
                        )
                    for s in settings if method in SLAMLIB_METHODS else ({},):
                        tasks.append(
                            SweepTask(
                                str(route),
                                tuple(frames),
                                int(seed),
                                layout,
                                method,
                                dict(s),
                                drive,
                            )
                        )
    return tasks


def drive_task(task: SweepTask, data_dir, threads: int | None = None) -> str:
    """Generate ``task``'s synthetic drive into ``data_dir`` unless a complete one is there; returns its folder.

    Raw layout: :func:`slamlib.synth.write_drive`; odometry layout: :func:`slamlib.synth.write_sequence`; both with
    the task's :class:`DriveOptions`, on at most ``threads`` threads (:func:`use_threads`). Another process
    writing the same drive (a second sweep sharing ``--data``) is waited for, and its drive used.
    """
    from slamlib.atomic import folder_lock
    from slamlib.synth import GENERATOR_VERSION, write_drive, write_sequence
    from slamlib.synth.writer import read_marker

    base = Path(data_dir) / task.drive_key()
    raw = task.layout == "raw"
    folder = _drive_folders(base)[task.layout]

    def missing() -> bool:
        marker = read_marker(folder)
        return marker is None or marker.get("version") != GENERATOR_VERSION

    if not missing():
        return str(base)
    use_threads(threads)
    with folder_lock(folder, wait=True, what="--data"):
        if missing():
            write = write_drive if raw else write_sequence
            write(
                base,
                task.route,
                *(() if raw else (0,)),
                frames=task.frames,
                seed=task.seed,
                progress=False,
                _locked=True,
                **task.drive.write_kwargs(task.layout),
            )
    return str(base)


def threads_per_run(workers: int | None = None, cores: int | None = None) -> int:
    """The threads each run of a sweep gets when ``workers`` worker processes (default: one per core) share
    ``cores`` cores (default: this machine's): ``cores // workers``, at least 1.

    Each worker runs one task at a time, so the workers' threads then add up to the cores. Left to their own
    defaults, every run's Numba (and KISS-ICP's) would take every core; on a shared machine their threads then
    wait on each other at each parallel loop's barrier, and a run's frames/s measures its neighbours more than
    itself.
    """
    import os

    cores = cores or os.cpu_count() or 1
    return max(1, cores // (workers or cores))


def sweep_threads(
    threads: int | None = None, scheduler: str | None = None, workers: int | None = None
) -> int | None:
    """The threads each task of a sweep uses: ``threads`` when given; otherwise, on the local cluster
    (``scheduler`` None), :func:`threads_per_run` of its ``workers``; on another scheduler None, the workers'
    own settings. :func:`run_sweep` uses it, and ``slamlib sweep`` records its value in ``sweep.json``."""
    if threads is not None:
        return int(threads)
    if scheduler is None:
        return threads_per_run(workers)
    return None


def use_threads(threads: int | None) -> None:
    """Numba's parallel loops called from this thread use at most ``threads`` threads (``numba.set_num_threads``,
    capped at ``NUMBA_NUM_THREADS``); None leaves them as they are.

    The setting belongs to the calling thread and stays after the task: on a Dask worker, later tasks on the same
    worker thread inherit it. Every sweep task sets its own, so sweeps do not leak into each other; a user's own
    tasks on the same workers should call this too (``use_threads(None)`` does not restore the default)."""
    if threads is None:
        return
    import numba

    numba.set_num_threads(max(1, min(int(threads), numba.config.NUMBA_NUM_THREADS)))


def _drive_folders(base: Path) -> dict[str, Path]:
    """The folder each layout writes a drive's frames to under ``base`` (its lock and marker are beside them)."""
    from slamlib.synth.writer import drive_dir

    return {
        "raw": drive_dir(base, "2011_09_26", 1),
        "odometry": base / "sequences" / "00",
    }


def _frames_of(task: SweepTask, base: str):
    from slamlib.kitti import KittiOdometrySequence, KittiRawDrive

    if task.layout == "raw":
        drive = KittiRawDrive(base, "2011_09_26", 1)
        if any(task.drive.start_tilt):
            from slamlib.synth.tilt import StartTilted

            drive = StartTilted(drive, *task.drive.start_tilt)
        return drive
    return KittiOdometrySequence(base, 0)


def run_task(task: SweepTask, base: str, threads: int | None = None) -> dict:
    """Run ``task`` on its drive folder ``base`` (from :func:`drive_task`) on at most ``threads`` threads
    (:func:`use_threads`; KISS-ICP's ``max_num_threads`` likewise, 0 = its default, all cores); returns one row
    of :data:`COLUMNS`."""
    from slamlib.metrics import trajectory_distances, trajectory_metrics

    use_threads(threads)
    frames = _frames_of(task, base)
    row = {
        "route": task.route,
        "frames": len(frames),
        "seed": task.seed,
        "layout": task.layout,
        "drive": task.drive.label(),
        "method": task.method,
        "settings": json.dumps(task.settings, sort_keys=True) if task.settings else "",
    }
    t0 = time.perf_counter()
    if task.method in SLAMLIB_METHODS:
        from slamlib.slam3d import SLAM3DConfig, run_drive

        closing = task.method == "slamlib_loop_closure"
        run = run_drive(
            frames,
            SLAM3DConfig.of(**{"seed": task.seed, **task.settings}),
            progress=False,
            loop_closure=closing,
        )
        poses = run.loop_closed if closing else run.poses
        gt, dr = run.ground_truth, run.dead_reckoning
    else:
        from slamlib.peers import kiss_icp_poses, kiss_slam_poses

        # the peers de-skew swept scans, their poses then moved to the frames' pose times
        swept = task.drive.distortion
        peer = kiss_icp_poses if task.method == "kiss_icp" else kiss_slam_poses
        poses = peer(frames, deskew=swept, pose_times=swept, max_threads=threads or 0)[0]
        gt = (
            frames.ground_truth_poses()
            if task.layout == "odometry"
            else frames.ground_truth_poses("imu")
        )
        gt = np.linalg.inv(gt[0])[None] @ gt
        dr = run = None
    seconds = time.perf_counter() - t0
    # slamlib's runs only: the scan match's gate (ScanMatchConfig.match_gate: how often it closed, how near it
    # came) and the starts where the start line's search was kept
    counts = (
        dict(
            match_rejected_frames=run.n_match_rejected,
            match_max_kept_distance=run.match_max_kept_distance,
            start_lines_kept=run.n_start_lines_kept,
            frame_time_max_ratio=run.frame_time_ratio(),
        )
        if run is not None
        else {}
    )
    m = trajectory_metrics(poses, gt)
    # slamlib's runs only: the IMU-only twin
    m_dr = trajectory_metrics(dr, gt) if dr is not None else {}
    row.update(
        path_length_m=float(trajectory_distances(gt)[-1]),
        kitti_t_err_percent=m.get("kitti_t_err_percent", float("nan")),
        kitti_r_err_deg_per_m=m.get("kitti_r_err_deg_per_m", float("nan")),
        ate_rmse_m=m["ate_rmse_m"],
        kitti_t_err_vertical_percent=m.get("kitti_t_err_vertical_percent", float("nan")),
        kitti_t_err_horizontal_percent=m.get(
            "kitti_t_err_horizontal_percent", float("nan")
        ),
        dead_reckoning_kitti_t_err_percent=m_dr.get("kitti_t_err_percent", float("nan")),
        dead_reckoning_ate_rmse_m=m_dr.get("ate_rmse_m", float("nan")),
        fps=len(poses) / seconds,
        seconds=seconds,
        match_rejected_frames=counts.get("match_rejected_frames", float("nan")),
        match_max_kept_distance=counts.get("match_max_kept_distance", float("nan")),
        start_lines_kept=counts.get("start_lines_kept", float("nan")),
        tilt_err_max_deg=m["tilt_err_max_deg"],
        frame_time_max_ratio=counts.get("frame_time_max_ratio", float("nan")),
    )
    return {k: row[k] for k in COLUMNS}


class SweepTaskError(RuntimeError):
    """A sweep task failed: ``str(err)`` is one line naming the task and the error (``err.task``, ``err.cause``)."""

    def __init__(self, task: SweepTask, cause: BaseException, n_more: int = 0):
        self.task, self.cause, self.n_more = task, cause, n_more
        why = (str(cause).strip().splitlines() or [""])[0]
        super().__init__(
            f"sweep task failed (route {task.route}, frames {_frames_text(task.frames)}, seed "
            f"{task.seed}, {task.layout}, {task.method}"
            + (f" {json.dumps(task.settings, sort_keys=True)}" if task.settings else "")
            + f"): {type(cause).__name__}: {why}"
            + (f" (and {n_more} more failed)" if n_more else "")
        )


def _frames_text(frames) -> str:
    a, b = frames
    return f"{a}:{'' if b is None else b}"


def task_key(task: SweepTask) -> str:
    """A task's identity in a journal of finished rows (:func:`append_journal`): every field, as JSON."""
    from dataclasses import asdict

    drive = asdict(task.drive)
    if not any(task.drive.start_tilt):
        del drive["start_tilt"]  # journals written before the option keep their keys
    return json.dumps(
        [
            task.route,
            list(task.frames),
            task.seed,
            task.layout,
            task.method,
            task.settings,
            drive,
        ],
        sort_keys=True,
    )


def append_journal(path, task: SweepTask, row: dict) -> None:
    """Append ``task``'s finished ``row`` to the journal ``path`` (one JSON line, flushed to the disk), so that an
    interrupted or failed sweep keeps it and a re-run does not run it again (:func:`read_journal`)."""
    import os

    line = json.dumps({"task": task_key(task), "row": row}) + "\n"
    with open(path, "a", encoding="utf-8") as f:
        f.write(line)
        f.flush()
        os.fsync(f.fileno())


def read_journal(path) -> dict[str, dict]:
    """``{task_key: row}`` of a journal written by :func:`append_journal`; a line cut short by a kill, or one of
    another format, is skipped (its task runs again)."""
    done = {}
    if not Path(path).is_file():
        return done
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        try:
            entry = json.loads(line)
            row = entry["row"]
            if set(row) == set(COLUMNS):
                done[entry["task"]] = row
        except (ValueError, KeyError, TypeError):
            continue
    return done


def run_sweep(
    tasks,
    data_dir,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
    done: dict | None = None,
    on_row=None,
    discard_drives: bool = False,
    threads: int | None = None,
) -> list[dict]:
    """Run ``tasks`` on Dask: one :func:`drive_task` per distinct drive, then every :func:`run_task` after its drive.

    ``scheduler``: the address of an existing Dask scheduler; default a ``distributed.LocalCluster`` of
    ``workers`` single-threaded worker processes (default: the machine's cores), closed at the end. ``done``:
    rows already computed, ``{task_key(task): row}`` (:func:`read_journal`), not run again; ``on_row(task, row)``
    is called as each task finishes (:func:`append_journal`). Returns the rows in the order of ``tasks``. A failing
    task does not stop the others; at the end the first one (in ``tasks``' order) raises :class:`SweepTaskError`
    naming it, every finished row having reached ``on_row``.

    The runs go before the drives not yet generated (Dask task priorities), so a worker finishes the drives it has
    before it starts another. ``discard_drives``: each drive's folder is removed from ``data_dir`` once its last
    run is done (:func:`discard_drive`), so the disk holds about one drive per worker, not the whole sweep's
    (``slamlib sweep --discard-drives`` says how large a drive is); a later sweep generates what it needs again.

    ``threads``: the threads each task may use (:func:`use_threads`, and KISS-ICP's), resolved by
    :func:`sweep_threads`: on the local cluster, the cores shared out among the workers, so that frames/s measure
    each run, not its neighbours; on another ``scheduler``, the workers' own settings. The setting stays on each
    worker thread after the sweep (:func:`use_threads`).
    """
    from distributed import Client, as_completed
    from tqdm.auto import tqdm

    data_dir = str(Path(data_dir).resolve())
    done = done or {}
    rows: list = [done.get(task_key(t)) for t in tasks]
    todo = [i for i, row in enumerate(rows) if row is None]
    if not todo:
        return rows
    cluster = None
    threads = sweep_threads(threads, scheduler, workers)
    if scheduler is None:
        cluster = _local_cluster(workers)
    client = Client(scheduler if scheduler is not None else cluster)
    try:
        drives = {}
        for i in todo:
            key = tasks[i].drive_key()
            if key not in drives:
                drives[key] = client.submit(
                    drive_task,
                    tasks[i],
                    data_dir,
                    threads,
                    key=f"drive-{key}",
                    pure=False,
                    priority=DRIVE_PRIORITY,
                )
        runs = {
            client.submit(
                run_task,
                tasks[i],
                drives[tasks[i].drive_key()],
                threads,
                pure=False,
                priority=RUN_PRIORITY,
            ): i
            for i in todo
        }
        # runs left per drive, to discard each drive after its last
        left = Counter(tasks[i].drive_key() for i in todo)
        failed = []
        with tqdm(
            total=len(tasks),
            initial=len(tasks) - len(todo),
            desc="sweep",
            unit="run",
            disable=not progress,
        ) as bar:
            for fut in as_completed(list(runs)):
                i = runs[fut]
                key = tasks[i].drive_key()
                left[key] -= 1
                if discard_drives and not left[key]:
                    discard_drive(data_dir, key)
                try:
                    rows[i] = fut.result()
                except Exception as exc:  # the other tasks go on: their rows are kept
                    failed.append((i, exc))
                    continue
                if on_row is not None:
                    on_row(tasks[i], rows[i])
                bar.update(1)
        if failed:
            i, exc = min(failed, key=lambda f: f[0])
            raise SweepTaskError(tasks[i], exc, len(failed) - 1)
        return rows
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
            # workers stopped mid-write (Ctrl-C, a failure) leave temporaries: cleaned now their processes are gone
            _clean_drives(data_dir, [tasks[i] for i in todo])


#: Dask priorities (higher first): a generated drive's runs before the next drive, so drives do not pile up.
RUN_PRIORITY = 1
DRIVE_PRIORITY = 0


def discard_drive(data_dir, key: str) -> None:
    """Remove the drive ``key`` (:meth:`SweepTask.drive_key`) from ``data_dir``, once any process still writing it
    (a second sweep sharing ``--data``) is done."""
    import shutil

    from slamlib.atomic import folder_lock

    base = Path(data_dir) / key
    for folder in _drive_folders(base).values():
        if folder.is_dir():
            with folder_lock(folder, wait=True, what="--data"):
                shutil.rmtree(folder)
    shutil.rmtree(base, ignore_errors=True)


def _local_cluster(workers: int | None):
    """A ``distributed.LocalCluster`` of ``workers`` single-threaded worker processes (default: the machine's
    cores) that leave Ctrl-C to this process.

    Ctrl-C goes to the whole process group. The workers start with SIGINT ignored (a disposition their processes
    inherit), so this process alone stops the sweep and closes them in order, instead of each printing its own
    traceback. While they start, SIGINT is blocked here as well: one pressed then stays pending (Linux keeps a
    blocked signal even when its action is to ignore it) and arrives once the handler is back.
    """
    import os
    import signal
    import sys
    import threading

    from distributed import LocalCluster

    # workers stopped mid-task leave semaphores that multiprocessing's tracker process warns about as this process
    # exits, after the command's last line; the tracker takes its warning filters from these options
    quiet = "ignore:resource_tracker:UserWarning"
    if quiet not in sys.warnoptions:
        sys.warnoptions.append(quiet)
    main = threading.current_thread() is threading.main_thread()
    if main:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        return LocalCluster(
            n_workers=workers or os.cpu_count() or 1,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            # its log (a task cancelled, a worker killed on Ctrl-C, a heartbeat cut at shutdown) would break the
            # one-line messages; task errors reach us through their futures
            silence_logs=logging.CRITICAL,
        )
    finally:
        if main:
            signal.signal(signal.SIGINT, previous)
            signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


#: Seconds a stopped worker is given to exit (and free its drive's lock) before its temporaries are left to the
#: next writer of that drive.
WORKER_EXIT_S = 15.0


def _clean_drives(data_dir: str, tasks) -> None:
    """Remove what stopped writers left beside the drives of ``tasks`` (:func:`slamlib.atomic.clean_stale`), except
    where another process holds a drive's lock (a second sweep sharing ``--data``)."""
    from slamlib.atomic import clean_stale, folder_lock
    from slamlib.errors import FolderBusyError

    for key in dict.fromkeys(t.drive_key() for t in tasks):
        for folder in _drive_folders(Path(data_dir) / key).values():
            if folder.parent.is_dir():
                try:
                    # a worker the cluster stopped may take a moment to exit and free its lock
                    with folder_lock(folder, wait=True, timeout=WORKER_EXIT_S):
                        clean_stale(folder)
                except FolderBusyError:
                    pass


def write_table(rows, path) -> Path:
    """Write the rows as CSV with the header :data:`COLUMNS` (numbers with ``repr`` precision; NaN as empty)."""
    path = Path(path)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=COLUMNS)
        w.writeheader()
        for r in rows:
            w.writerow(
                {
                    # rows journalled before a column was added have no value for it
                    k: ("" if isinstance(v, float) and not np.isfinite(v) else v)
                    for k, v in ((k, r.get(k, float("nan"))) for k in COLUMNS)
                }
            )
    return path


def read_table(path) -> list[dict]:
    """The rows of a sweep CSV, numbers as float/int (empty cells as NaN)."""
    out = []
    with open(path, newline="", encoding="utf-8") as f:
        for r in csv.DictReader(f):
            row = {}
            for k, v in r.items():
                if k in ("route", "layout", "drive", "method", "settings"):
                    row[k] = v
                elif k in ("frames", "seed"):
                    row[k] = int(v)
                else:
                    row[k] = float(v) if v != "" else float("nan")
            out.append(row)
    return out


def _label(row) -> str:
    """A run's legend entry: method, layout, settings and drive options (those not empty)."""
    drive = f"({row['drive']})" if row.get("drive") else ""
    return " ".join(
        x for x in (row["method"], row["layout"], row["settings"], drive) if x
    )


def plot_sweep(rows, ax=None):
    """KITTI translational error (%) per route (x) and method (colour): each run a dot, the mean a bar."""
    import matplotlib.pyplot as plt

    from slamlib.plotstyle import MAX_FIGURE_WIDTH_IN

    if ax is None:
        fig, ax = plt.subplots(figsize=(MAX_FIGURE_WIDTH_IN, 3.6))
    else:
        fig = ax.figure
    routes = list(dict.fromkeys(r["route"] for r in rows))
    labels = list(dict.fromkeys(_label(r) for r in rows))
    width = 0.8 / max(1, len(labels))
    for j, label in enumerate(labels):
        for i, route in enumerate(routes):
            vals = [
                r["kitti_t_err_percent"]
                for r in rows
                if r["route"] == route and _label(r) == label
            ]
            vals = [v for v in vals if np.isfinite(v)]
            x = i - 0.4 + width * (j + 0.5)
            if vals:
                ax.bar(
                    x,
                    np.mean(vals),
                    width * 0.9,
                    color=f"C{j}",
                    alpha=0.5,
                    label=label if i == 0 else None,
                )
                ax.plot([x] * len(vals), vals, "o", color=f"C{j}", ms=4)
    ax.set_xticks(range(len(routes)), [f"route {r}" for r in routes])
    ax.set_ylabel("KITTI translational error (%)")
    # drives shorter than 100 m have no KITTI error to draw
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=10)
    return fig
