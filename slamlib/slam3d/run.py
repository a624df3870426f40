"""Run :class:`~slamlib.slam3d.ParticleSLAM3D` over a whole KITTI raw drive and evaluate it.

:func:`run_drive` iterates a :class:`slamlib.kitti.KittiRawDrive` (or any sequence of frames), registers every
frame, and returns a :class:`SLAMRun` with the SLAM and dead-reckoning trajectories, the ground truth (when the
frames carry ``T_w_imu``), timing, and the map. :func:`evaluate` computes ATE, RPE and the KITTI odometry metric
for both trajectories.

Frames: all trajectories are body (IMU) poses in the world = the IMU pose at the **first processed frame**;
ground truth ``T_w_imu`` of a drive is re-expressed in that frame (``inv(G_0) G_k``), so ``--frames 100:400``
is evaluated from frame 100 on.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
from dataclasses import dataclass, field

import numpy as np

from slamlib.geometry import invert_pose
from slamlib.slam3d.config import SLAM3DConfig
from slamlib.slam3d.pipeline import ParticleSLAM3D

__all__ = [
    "SLAMRun",
    "run_drive",
    "frames_calibration",
    "evaluate",
    "parse_frames",
    "save_run",
    "check_output_dir",
    "RUN_FILES",
    "MAP_FORMATS",
    "DEFAULT_MAP_FORMAT",
]


@dataclass
class SLAMRun:
    """Result of :func:`run_drive`.

    Attributes
    ----------
    poses, dead_reckoning : (F, 4, 4) SLAM and dead-reckoning ``T_world_body`` (world = first processed body pose);
        ``dead_reckoning`` is None for a LIDAR-only run (no IMU).
    ground_truth : (F, 4, 4) or None
        Ground-truth body poses in the same world, when the frames have ``T_w_imu``.
    timestamps : (F,) seconds since the first processed frame.
    frame_indices : (F,) drive frame numbers.
    seconds : wall-clock time of the SLAM loop (frame reading included), ``fps = F / seconds``.
    slam : the filter (its ``map``, ``config``, particles).
    snapshots : list of ``(frame position, map points (M, 3), pose (4, 4))`` taken every ``snapshot_every`` frames.
    frame_seconds : (F,) wall-clock seconds of each ``register_frame`` call (reading the frame not included).
    started_at, warm_at : ``time.perf_counter()`` when the loop over the frames began, and when the first
        :data:`STARTUP_FRAMES` frames were done (the kernels compiled or loaded from Numba's cache, the map
        begun); ``steady_fps`` is the rate after them.
    segment_starts : (S,) frame positions where a segment starts (``[0]`` without a gap in time,
        :mod:`slamlib.slam3d.segments`); ``segments`` the filter of each (``slam`` is the last).
    loop_closed : (F, 4, 4) or None, the poses re-anchored by loop closure (``run_drive(loop_closure=True)``,
        :mod:`slamlib.loops`); ``loop_closer`` the :class:`~slamlib.loops.LoopCloser` (its ``closures``, graph).
    """

    poses: np.ndarray
    dead_reckoning: np.ndarray | None
    ground_truth: np.ndarray | None
    timestamps: np.ndarray
    frame_indices: np.ndarray
    seconds: float
    slam: ParticleSLAM3D = field(repr=False)
    snapshots: list = field(default_factory=list, repr=False)
    frame_seconds: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    segment_starts: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    segments: list = field(default_factory=list, repr=False)
    warm_at: float = float("nan")
    started_at: float = float("nan")
    loop_closed: np.ndarray | None = field(default=None, repr=False)
    loop_closer: object = field(default=None, repr=False)

    @property
    def steady_fps(self) -> float:
        """Frames per second after the first :data:`STARTUP_FRAMES` (frame reading included): the rate a longer
        drive runs at, without the one-off cost of compiling or loading the kernels; NaN for a run that short."""
        n = len(self.poses) - STARTUP_FRAMES
        spent = self.seconds - (self.warm_at - self.started_at)
        return n / spent if n > 0 and spent > 0 else float("nan")

    def frame_time_ratio(self) -> float:
        """The slowest frame's ``register_frame`` time over the median frame's, after the first
        :data:`STARTUP_FRAMES` (which compile or load the kernels): how far one frame stalls a real-time run (nan
        without frames after the start-up)."""
        steady = np.asarray(self.frame_seconds[STARTUP_FRAMES:], dtype=np.float64)
        if len(steady) == 0:
            return float("nan")
        return float(steady.max() / np.median(steady))

    def filters(self) -> list:
        """The filter of every segment, in order (one without a gap in time)."""
        return self.segments or [self.slam]

    def map_points(self) -> np.ndarray:
        """The map points (M, 3) of every segment's filter (:meth:`ParticleSLAM3D.map_points`), world frame."""
        parts = [f.map_points() for f in self.filters()]
        return np.concatenate(parts) if len(parts) > 1 else parts[0]

    @property
    def fps(self) -> float:
        """Frames per second of the SLAM loop."""
        return len(self.poses) / self.seconds if self.seconds > 0 else float("nan")

    def _over_segments(self, name: str, reduce=sum):
        """``reduce`` (sum, max) of every segment's filter's attribute ``name``."""
        return reduce(getattr(f, name) for f in self.filters())

    @property
    def n_deskewed(self) -> int:
        """Frames whose swept scans step 2 de-skewed, over every segment (``ScanConfig.deskew``)."""
        return int(self._over_segments("n_deskewed"))

    @property
    def n_matched(self) -> int:
        """Frames whose best pose was scan-matched after step 9, over every segment."""
        return int(self._over_segments("n_matched"))

    @property
    def n_match_rejected(self) -> int:
        """Scan matches the gate rejected (``ScanMatchConfig.match_gate``), over every segment."""
        return int(self._over_segments("n_match_rejected"))

    @property
    def match_max_kept_distance(self) -> float:
        """The largest correction a kept scan match made, in step 6's spreads, over every segment."""
        return float(self._over_segments("match_max_kept_distance", max))

    @property
    def n_start_lines_kept(self) -> int:
        """Segment starts where the start line's search was kept (``ConstantVelocityConfig.start_line``)."""
        return int(self._over_segments("n_start_lines_kept"))


#: Frames a run takes to reach its steady pace: the first builds the map only, the second is the first scored one
#: (the move and score kernels run, compiled or loaded from Numba's cache, for the first time).
STARTUP_FRAMES = 2


def parse_frames(text: str | None, n: int | None = None) -> slice | None:
    """``"A:B"``, ``"A:"``, ``":B"`` or ``"B"`` (first B frames) -> ``slice``; ``None``/``""`` -> ``None`` (all).

    Raises ``ValueError`` on anything else, or on an empty range.
    """
    if text is None or str(text).strip() == "":
        return None
    s = str(text).strip()
    try:
        if ":" in s:
            a, b = s.split(":", 1)
            sl = slice(int(a) if a.strip() else 0, int(b) if b.strip() else None)
        else:
            sl = slice(0, int(s))
    except ValueError:
        raise ValueError(
            f"--frames must look like A:B, A:, :B or B (integers), got {text!r}"
        ) from None
    if sl.start < 0 or (sl.stop is not None and sl.stop <= sl.start):
        raise ValueError(f"--frames {text!r} selects no frames")
    if n is not None and sl.start >= n:
        raise ValueError(f"--frames {text!r} starts after the last frame ({n - 1})")
    return sl


def run_drive(
    frames,
    config: SLAM3DConfig | None = None,
    T_velo_imu=None,
    progress: bool = True,
    snapshot_every: int = 0,
    desc: str = "slam3d",
    loop_closure: bool = False,
) -> SLAMRun:
    """Register every frame of ``frames`` with a fresh :class:`ParticleSLAM3D`.

    A gap in time (a frame interval over :data:`~slamlib.slam3d.segments.GAP_PERIODS` typical ones) starts a new
    segment with a fresh filter, its start pose predicted across the gap, and warns naming the frames
    (:mod:`slamlib.slam3d.segments`). Returns a :class:`SLAMRun`.

    Parameters
    ----------
    frames : iterable of frames (``.scan``, ``.velocity``, ``.angular_rate``, ``.dt``; optional ground truth
        ``.T_w_body`` or ``.T_w_imu``, ``.time_s``, ``.index``), e.g. a :class:`slamlib.kitti.KittiRawDrive` or a
        :class:`slamlib.kitti.KittiOdometrySequence` (its ``T_velo_imu`` is used when ``T_velo_imu`` is not given;
        for a list of a raw drive's frames or a generator over them, the first frame's, :func:`frames_calibration`).
    config : filter settings.
    progress : show a tqdm bar with frames/s.
    snapshot_every : keep a copy of the map points every that many frames (0: none), for animations.
    loop_closure : feed every frame's pose and prepared scan to a :class:`slamlib.loops.LoopCloser` (local maps,
        loop candidates, verified closures, a pose graph), inside each frame's timing (the last local map and the
        final optimisation spread evenly over the frames); the re-anchored poses are the run's ``loop_closed``, the
        filter's own ``poses`` stay as they were.
    """
    import warnings

    from tqdm.auto import tqdm

    from slamlib.slam3d.segments import gap_warning, is_gap

    _check_frames(frames)
    if config is not None and not isinstance(config, SLAM3DConfig):
        hint = (
            f": SLAM3DConfig.of(**{config!r}) builds one from a dict of settings"
            if isinstance(config, dict)
            else ""
        )
        raise TypeError(
            f"config must be a SLAM3DConfig, got {type(config).__name__}{hint}"
        )
    if T_velo_imu is None:
        T_velo_imu = getattr(frames, "T_velo_imu", None)
    if T_velo_imu is None:
        frames, T_velo_imu = frames_calibration(frames)
    slam = ParticleSLAM3D(config, T_velo_imu=T_velo_imu)
    closer = None
    if loop_closure:
        from slamlib.loops import LoopCloser

        closer = LoopCloser()
    filters, starts, intervals = [slam], [0], []
    gt, times, idx, snaps, frame_seconds = [], [], [], [], []
    total = len(frames) if hasattr(frames, "__len__") else None
    bar = tqdm(
        frames, total=total, desc=desc, unit="frame", disable=not progress, smoothing=0.1
    )
    t0 = warm_at = time.perf_counter()
    for k, frame in enumerate(bar):
        dt = float(getattr(frame, "dt", 0.0))
        if k > 0 and is_gap(dt, intervals):
            before, after = idx[-1], int(getattr(frame, "index", k))
            warnings.warn(
                gap_warning(before, after, dt, float(np.median(intervals))), stacklevel=2
            )
            slam = ParticleSLAM3D(
                config, T_velo_imu=T_velo_imu, T0=slam.predicted_pose(frame)
            )
            filters.append(slam)
            starts.append(k)
        elif k > 0:
            intervals.append(dt)
        tf = time.perf_counter()
        pose = slam.register_frame(frame)
        if closer is not None:
            closer.add_frame(k, pose, slam.last.get("points", np.zeros((0, 3))))
        frame_seconds.append(time.perf_counter() - tf)
        # odometry layout: T_w_body
        gt.append(getattr(frame, "T_w_body", getattr(frame, "T_w_imu", None)))
        times.append(float(getattr(frame, "time_s", k * 0.1)))
        idx.append(int(getattr(frame, "index", k)))
        if snapshot_every and k % snapshot_every == 0:
            snaps.append((k, slam.map_points(), pose.copy()))
        if k == STARTUP_FRAMES - 1:
            warm_at = time.perf_counter()
    loop_closed, frame_seconds = None, np.asarray(frame_seconds)
    if closer is not None:
        tf = time.perf_counter()
        closer.finish()
        loop_closed = closer.corrected_poses()
        # the last local map and the final optimisation belong to the run: spread over its frames
        frame_seconds += (time.perf_counter() - tf) / max(1, len(frame_seconds))
    seconds = time.perf_counter() - t0
    bar.close()
    ground_truth = None
    if gt and all(g is not None for g in gt):
        G = np.asarray(gt, dtype=np.float64)
        ground_truth = invert_pose(G[0])[None] @ G
    times = np.asarray(times)
    lidar_only = any(f.dead_reckoning is None for f in filters)
    return SLAMRun(
        np.concatenate([f.trajectory for f in filters]),
        None if lidar_only else np.concatenate([f.dead_reckoning for f in filters]),
        ground_truth,
        times - (times[0] if len(times) else 0.0),
        np.asarray(idx, dtype=np.int64),
        seconds,
        slam,
        snaps,
        frame_seconds,
        np.asarray(starts, dtype=np.int64),
        filters,
        warm_at,
        t0,
        loop_closed,
        closer,
    )


def frames_calibration(frames):
    """``(frames, T_velo_imu)`` for frames that do not carry their drive's calibration: a list of a drive's frames,
    or a generator over them (``itertools.islice(drive, n)``). A KITTI raw frame
    (:class:`slamlib.kitti.raw.Frame`) has both ground-truth poses, ``T_w_velo = T_w_imu inv(T_velo_imu)``, so the
    first frame gives ``T_velo_imu = inv(T_w_velo) T_w_imu`` (4, 4); None (the identity: the scans are in the body
    frame) when it lacks either pose. ``frames`` comes back whole: an iterator with its first frame put back in
    front, anything else as it was."""
    import itertools

    it = iter(frames)
    first = next(it, None)
    if it is frames:  # a one-pass iterator: the first frame is taken from it
        frames = itertools.chain([] if first is None else [first], it)
    T_w_imu, T_w_velo = (getattr(first, name, None) for name in ("T_w_imu", "T_w_velo"))
    if T_w_imu is None or T_w_velo is None:
        return frames, None
    # the general inverse, as the reader's (T_imu_velo = inv(T_velo_imu)): the calibration comes back as it was read
    return frames, np.linalg.inv(np.asarray(T_w_velo, dtype=np.float64)) @ np.asarray(
        T_w_imu, dtype=np.float64
    )


def _check_frames(frames) -> None:
    """TypeError / ValueError saying what ``run_drive`` needs when ``frames`` is not a sequence of frames."""
    from os import PathLike

    if isinstance(frames, (str, bytes, PathLike)):
        raise TypeError(
            f"run_drive takes frames, not a path ({frames!r}): open the drive first, e.g. "
            "KittiRawDrive(basedir, date, drive) or KittiOdometrySequence(basedir, sequence)"
        )
    if frames is None or not hasattr(frames, "__iter__"):
        raise TypeError(
            "run_drive takes an iterable of frames (a KittiRawDrive, a KittiOdometrySequence or a list "
            f"of their frames), got {type(frames).__name__}"
        )
    if hasattr(frames, "__len__") and len(frames) == 0:
        raise ValueError("run_drive got no frames: there is nothing to run")


def evaluate(run: SLAMRun) -> dict:
    """ATE (RMSE, m, no alignment: both start at the same pose), RPE over 10 frames, and the KITTI odometry
    metric (segments of 100..800 m; only for paths over 100 m) of the SLAM and dead-reckoning trajectories.

    Returns ``{"slam": {...}, "dead_reckoning": {...}, "path_length_m", "frames", "fps"}`` (no
    ``"dead_reckoning"`` for a LIDAR-only run; ``"slam_loop_closed"`` too for a run with loop closure); raises
    ValueError
    without ground truth.
    """
    from slamlib.metrics import trajectory_distances, trajectory_metrics
    from slamlib.slam3d.segments import stitch_segments

    if run.ground_truth is None:
        raise ValueError("this run has no ground truth (frames without T_w_imu)")
    G, starts = run.ground_truth, run.segment_starts
    out = {
        "frames": int(len(run.poses)),
        "path_length_m": float(trajectory_distances(G)[-1]),
        "fps": float(run.fps),
        "slam": trajectory_metrics(stitch_segments(run.poses, G, starts), G),
    }
    if run.dead_reckoning is not None:
        dr = stitch_segments(run.dead_reckoning, G, starts)
        out["dead_reckoning"] = trajectory_metrics(dr, G)
    if run.loop_closed is not None:
        out["slam_loop_closed"] = trajectory_metrics(
            stitch_segments(run.loop_closed, G, starts), G
        )
    if len(starts) > 1:
        ends = list(starts[1:]) + [len(run.poses)]
        out["segments"] = [
            {"frames": [int(run.frame_indices[a]), int(run.frame_indices[b - 1])]}
            for a, b in zip(starts, ends)
        ]
        out["evaluated"] = (
            "each segment from its own first pose (a gap in time before it)"
        )
    return out


#: Bytes a point takes in the map file at most (open3d writes x, y, z as float64, in binary PLY and PCD).
MAP_BYTES_PER_POINT = 24
#: Map file formats :func:`save_run` writes (open3d), and the one it writes when none is named (``slamlib run``'s
#: ``--map-format`` reads both from here).
MAP_FORMATS = ("ply", "pcd")
DEFAULT_MAP_FORMAT = "ply"
#: A map file of no points (PLY and PCD headers), written when the map is empty.
_EMPTY_MAP = {
    "ply": "ply\nformat ascii 1.0\nelement vertex 0\nproperty double x\nproperty double y\n"
    "property double z\nend_header\n",
    "pcd": "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z\nSIZE 8 8 8\nTYPE F F F\n"
    "COUNT 1 1 1\nWIDTH 0\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 0\nDATA ascii\n",
}
#: The files :func:`save_run` may write into its folder (the ones :func:`check_output_dir` will not let it overwrite
#: unless they come from an earlier run).
RUN_FILES = tuple(
    f"{name}_{kind}.txt"
    for name in ("slam", "slam_loop_closed", "dead_reckoning", "ground_truth")
    for kind in ("poses", "tum")
) + (
    "closures.json",
    "times.txt",
    "map.ply",
    "map.pcd",
    "metrics.json",
    "trajectory.png",
    "map_topdown.png",
)


def _is_earlier_run(out) -> bool:
    """Whether folder ``out`` holds the results of an earlier :func:`save_run`: its metrics.json reads as one."""
    import json

    try:
        info = json.loads((out / "metrics.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(info, dict) and {"frames", "config", "map_elements"} <= set(info)


def check_output_dir(out_dir, overwrite: bool = False) -> None:
    """Raise ``ValueError`` unless ``out_dir`` can become the output folder: a new folder under a writable one, an
    empty folder, or the folder of an earlier run (its ``metrics.json`` written by :func:`save_run`). ``slamlib
    run`` calls it before the run, not after.

    No user file is lost: a non-empty folder that is not an earlier run's is refused unless ``overwrite``; then
    only the files named like :data:`RUN_FILES` are replaced and every other file stays.
    """
    import os
    from pathlib import Path

    out = Path(out_dir)
    if out.exists():
        if not out.is_dir():
            raise ValueError(f"{out} exists and is not a folder")
        if not os.access(out, os.W_OK):
            raise ValueError(f"{out} is not writable")
        if overwrite or _is_earlier_run(out):
            return
        theirs = sorted(p.name for p in out.iterdir())
        clash = [name for name in RUN_FILES if name in theirs]
        if clash:
            raise ValueError(
                f"{out} holds {', '.join(clash)}, not from an earlier slamlib run; they would be "
                f"overwritten: choose another folder or pass --overwrite"
            )
        if theirs:
            shown = ", ".join(theirs[:3]) + (
                f" and {len(theirs) - 3} more" if len(theirs) > 3 else ""
            )
            raise ValueError(
                f"{out} is not empty ({shown}) and is not an earlier slamlib run's folder: choose a new "
                f"or empty folder, or pass --overwrite (files named like the results are replaced, "
                f"the others kept)"
            )
        return
    parent = out.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(f"cannot create {out}: {parent} is not a folder")
    if not os.access(parent, os.W_OK):
        raise ValueError(f"cannot create {out}: {parent} is not writable")


def save_run(
    run: SLAMRun,
    out_dir,
    map_format: str = DEFAULT_MAP_FORMAT,
    plots: bool = True,
    extra: dict | None = None,
) -> dict:
    """Write a run's results into ``out_dir`` and return ``{name: path}`` of the files written.

    * ``slam_poses.txt`` / ``slam_tum.txt``: SLAM trajectory in KITTI (12 numbers per line) and TUM formats;
    * ``dead_reckoning_poses.txt`` / ``dead_reckoning_tum.txt``: the IMU-only baseline (not LIDAR-only);
    * ``ground_truth_poses.txt`` / ``ground_truth_tum.txt`` when the frames had ground truth;
    * ``slam_loop_closed_poses.txt`` / ``slam_loop_closed_tum.txt`` and ``closures.json``: with loop closure,
      the re-anchored trajectory and the local maps and closures (:func:`run_drive`'s ``loop_closure``);
    * ``times.txt``: seconds since the first processed frame (KITTI odometry ``times.txt``);
    * ``map.ply`` or ``map.pcd`` (open3d): the map's points (voxel means or stored points, including the parts
      pruned on the way, :meth:`ParticleSLAM3D.map_points`), world frame;
    * ``metrics.json``: frames/s, settings, ``n_deskewed_frames`` (scans step 2 de-skewed), ``n_matched_frames``
      (poses scan-matched after step 9), ``n_match_rejected_frames`` (matches the gate rejected),
      ``match_max_kept_distance`` (the largest correction a kept match made, in step 6's spreads), ``n_skipped_frames``
      (frames skipped for scoring, with a ``warnings`` entry when there were any; :mod:`slamlib.slam3d.pipeline`)
      and, with ground truth, :func:`evaluate` (ATE, RPE, KITTI metric). Always valid JSON: a non-finite number
      is written ``null`` (:func:`slamlib.metrics.json_safe`);
    * ``trajectory.png`` (with and without SLAM vs ground truth; with loop closure its trajectory too, each
      closure a line between the places it joins) and ``map_topdown.png`` (coloured by height).

    The results appear whole or not at all (:func:`slamlib.atomic.atomic_folder`): they are written into a
    temporary folder beside ``out_dir`` (``.NAME.PID.partial``) under an exclusive lock (a second writer of the same
    folder gets :class:`~slamlib.errors.FolderBusyError` naming the first), and the finished folder is renamed into
    place; an existing ``out_dir`` is swapped for it by renames, its other files (not :data:`RUN_FILES`) moved
    across. An earlier run's result files that this run does not write (another map format, plots, dead
    reckoning) are therefore gone, so that no stale result stands beside the new ones; a run that fails or is
    interrupted while writing leaves ``out_dir`` as it was.
    """
    from pathlib import Path

    from slamlib.atomic import atomic_folder

    final = Path(out_dir)
    if not isinstance(run, SLAMRun):
        raise TypeError(
            f"run must be the SLAMRun that run_drive returns, got {type(run).__name__}"
        )
    with atomic_folder(final, lambda path: path not in RUN_FILES, what="--out") as tmp:
        files = _write_results(run, tmp, map_format, plots, extra)
    return {key: final / Path(path).name for key, path in files.items()}


@contextlib.contextmanager
def _quiet_stderr():
    """The process's stderr (file descriptor 2, where C libraries print) sent to ``/dev/null`` for the block."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _closures_json(run: SLAMRun) -> dict:
    """The loop closer's local maps (first frame, key pose) and closures (the local maps and frames they join,
    ``T_query^{-1} T_reference``, how it was proposed, place-recognition inliers, ICP fitness and RMSE, whether
    the graph kept it)."""
    closer, frames = run.loop_closer, run.frame_indices
    return {
        "local_maps": [
            {
                "node": m.node,
                "first_frame": int(frames[m.frames[0]]),
                "frames": len(m.frames),
            }
            for m in closer.mapper.maps
        ],
        "closures": [
            {
                "query": c.query,
                "reference": c.reference,
                "query_frame": int(frames[c.query_frame]),
                "reference_frame": int(frames[c.reference_frame]),
                "relative": np.round(c.relative, 6).tolist(),
                "proposed_by": c.proposed_by,
                "inliers": c.inliers,
                "fitness": round(c.fitness, 4),
                "rmse_m": round(c.rmse, 4),
                "kept": c.kept,
            }
            for c in closer.closures
        ],
    }


def _write_results(
    run: SLAMRun, out, map_format: str, plots: bool, extra: dict | None
) -> dict:
    """Every result file of :func:`save_run` written into the existing folder ``out``; returns ``{name: path}``."""
    import json
    from pathlib import Path

    from slamlib.kitti.trajectory_io import write_kitti_poses, write_times, write_tum
    from slamlib.metrics import json_safe

    out = Path(out)
    files = {}
    trajs = {"slam": run.poses}
    if run.loop_closed is not None:
        trajs["slam_loop_closed"] = run.loop_closed
    if run.dead_reckoning is not None:
        trajs["dead_reckoning"] = run.dead_reckoning
    if run.ground_truth is not None:
        trajs["ground_truth"] = run.ground_truth
    for name, T in trajs.items():
        files[f"{name}_kitti"] = out / f"{name}_poses.txt"
        write_kitti_poses(files[f"{name}_kitti"], T)
        files[f"{name}_tum"] = out / f"{name}_tum.txt"
        write_tum(files[f"{name}_tum"], run.timestamps, T)
    files["times"] = out / "times.txt"
    write_times(files["times"], run.timestamps)
    if run.loop_closer is not None:
        files["closures"] = out / "closures.json"
        files["closures"].write_text(
            json.dumps(_closures_json(run), indent=1), encoding="utf-8"
        )

    if map_format not in MAP_FORMATS:
        raise ValueError(f"map_format must be 'ply' or 'pcd', got {map_format!r}")
    import open3d as o3d

    pts = run.map_points()
    files["map"] = out / f"map.{map_format}"
    # every scan degenerate: open3d writes no empty cloud, so an empty file in the same format
    if len(pts) == 0:
        files["map"].write_text(_EMPTY_MAP[map_format], encoding="ascii")
    else:
        pcd = o3d.geometry.PointCloud(
            o3d.utility.Vector3dVector(np.asarray(pts, dtype=np.float64))
        )
        with (
            _quiet_stderr()
        ):  # open3d's writer prints a line per failed block ("RPly: Failed writing")
            written = o3d.io.write_point_cloud(str(files["map"]), pcd)
        if not written:
            import errno

            from slamlib.atomic import free_bytes, write_error

            # open3d says only that it failed: a full disk is the usual reason
            full = OSError(errno.ENOSPC, "no space left")
            if (free_bytes(files["map"]) or 0) < MAP_BYTES_PER_POINT * len(pts):
                raise write_error(files["map"], full) from None
            raise OSError(errno.EIO, "open3d could not write it", str(files["map"]))

    info = {
        "frames": int(len(run.poses)),
        "seconds": float(run.seconds),
        "fps": float(run.fps),
        "frame_indices": [int(run.frame_indices[0]), int(run.frame_indices[-1])]
        if len(run.poses)
        else [],
        "map_elements": int(sum(len(f.map) for f in run.filters())),
        "map_points_written": int(len(pts)),
        "config": run.slam.config.as_dict(),
    }
    skipped = int(sum(getattr(f, "n_skipped_frames", 0) for f in run.filters()))
    info["n_skipped_frames"] = skipped
    # ScanConfig.deskew auto: the frames whose scans were swept
    info["n_deskewed_frames"] = run.n_deskewed
    # ScanMatchConfig.scan_match auto: every frame after the first, unless the tilt prior is on
    info["n_matched_frames"] = run.n_matched
    # ScanMatchConfig.match_gate: matches that would have moved the pose beyond the frame's spreads
    info["n_match_rejected_frames"] = run.n_match_rejected
    info["match_max_kept_distance"] = run.match_max_kept_distance
    # ConstantVelocityConfig.start_line: the starts where the line's search was kept
    info["n_start_lines_kept"] = run.n_start_lines_kept
    info["segment_starts"] = [int(run.frame_indices[k]) for k in run.segment_starts]
    warnings = []
    if skipped:
        from slamlib.slam3d.pipeline import MIN_SCAN_POINTS

        warnings.append(
            f"{skipped} of {len(run.poses)} frames had fewer than {MIN_SCAN_POINTS} scan points "
            f"after cropping: scoring skipped, the motion prediction stands"
        )
    if len(run.segment_starts) > 1:
        gaps = ", ".join(
            f"{run.frame_indices[k - 1]}-{run.frame_indices[k]}"
            for k in run.segment_starts[1:]
        )
        warnings.append(
            f"{len(run.segment_starts) - 1} gap(s) in time (between frames {gaps}): "
            f"{len(run.segment_starts)} segments, each evaluated from its own first pose"
        )
    if warnings:
        info["warnings"] = warnings
    if extra:
        info.update(extra)
    if run.ground_truth is not None:
        info["metrics"] = evaluate(run)
    files["metrics"] = out / "metrics.json"
    files["metrics"].write_text(
        json.dumps(json_safe(info), indent=2, allow_nan=False) + "\n"
    )

    if plots:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from slamlib.slam3d.plot import plot_map_topdown, plot_trajectories

        closures = []
        if run.loop_closer is not None:
            closures = [
                (c.query_frame, c.reference_frame, c.kept)
                for c in run.loop_closer.closures
            ]
        fig = plot_trajectories(
            run.poses,
            run.dead_reckoning,
            run.ground_truth,
            pts,
            loop_closed=run.loop_closed,
            closures=closures,
        )
        files["trajectory_plot"] = out / "trajectory.png"
        fig.savefig(files["trajectory_plot"], dpi=120, bbox_inches="tight")
        plt.close(fig)
        fig = plot_map_topdown(pts, run.poses)
        files["map_plot"] = out / "map_topdown.png"
        fig.savefig(files["map_plot"], dpi=120, bbox_inches="tight")
        plt.close(fig)
    return files
