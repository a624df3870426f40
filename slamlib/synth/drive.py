"""Generate whole synthetic KITTI raw drives: route -> OXTS + town scene + HDL-64E scans -> files.

:func:`write_drive` is deterministic from its ``seed`` (timestamps, IMU noise, scene layout and LIDAR noise
use independent streams spawned from it). :func:`default_drive` generates the package's default drive once
into :func:`slamlib.paths.cache_dir` (keyed by its parameters and :data:`GENERATOR_VERSION`, regenerated
when incomplete or stale) and returns ``(basedir, date, drive)`` for ``pykitti.raw(basedir, date, f"{drive:04d}")``
or ``slamlib.kitti.KittiRawDrive(basedir, date, drive)``.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from slamlib.atomic import atomic_folder, folder_lock
from slamlib.geometry import invert_pose
from slamlib.paths import cache_dir
from slamlib.synth.lidar import Hdl64, ray_directions, simulate_scan
from slamlib.synth.oxts import WANDERING_BIASES, ImuNoise, oxts_packets
from slamlib.synth.routes import Route, get_route
from slamlib.synth.scene import build_scene
from slamlib.synth.traffic import KITTI_CITY, TrafficConfig, build_traffic
from slamlib.synth.writer import (
    _SAMPLE,
    MARKER,
    SCAN_PERIOD,
    check_calib,
    drive_dir,
    frame_timestamps_ns,
    generator_file,
    is_own_drive,
    read_marker,
    write_calib,
    write_marker,
    write_odometry_calib,
    write_odometry_scan,
    write_oxts,
    write_scan,
    write_velodyne_timestamps,
)

__all__ = [
    "GENERATOR_VERSION",
    "write_drive",
    "write_sequence",
    "default_drive",
    "resolve_route",
    "DEFAULT_FRAMES",
    "drive_traffic",
]

#: Bump when the generator's output changes: cached drives of another version are regenerated.
GENERATOR_VERSION = "synth-4"
#: KITTI 07 key frames of the default drive (30 s, ~220 m through the town part of sequence 07).
DEFAULT_FRAMES = (0, 300)


def resolve_route(route, frames=None) -> tuple[Route, int]:
    """``(Route, n_frames)`` from a :class:`Route` or name and a frame selection.

    ``frames``: ``None`` (as many 10 Hz frames as the route spans), an ``int`` n, or ``(start, stop)`` /
    ``slice``: for a KITTI route name those select the odometry key frames (the drive then has
    ``stop - start`` frames); for other routes ``(0, n)`` means n frames.
    """
    if isinstance(route, str):
        if route in ("00", "05", "07") and isinstance(frames, (tuple, list, slice)):
            sl = frames if isinstance(frames, slice) else slice(*frames)
            start = sl.start or 0
            stop = sl.stop
            key = slice(start, None if stop is None else stop + 2)
            r = get_route(route, key)
            n = int((r.t1 - r.t0 - 0.03) / SCAN_PERIOD) + 1
            return r, (n if stop is None else min(n, stop - start))
        r = get_route(route)
    else:
        r = route
    n_max = int((r.t1 - r.t0 - 0.03) / SCAN_PERIOD) + 1
    if frames is None:
        n = n_max
    elif isinstance(frames, int):
        n = frames
    else:
        sl = frames if isinstance(frames, slice) else slice(*frames)
        n = len(range(*sl.indices(n_max)))
    if n < 1 or n > n_max:
        raise ValueError(f"route {r.name!r} spans at most {n_max} frames, asked for {n}")
    return r, n


def write_drive(
    basedir,
    route="07",
    date: str = "2011_09_26",
    drive: int = 1,
    frames=DEFAULT_FRAMES,
    seed: int = 0,
    noise: ImuNoise = ImuNoise(),
    lidar: Hdl64 = Hdl64(),
    scans: bool = True,
    progress: bool = True,
    distortion: bool = False,
    traffic: TrafficConfig | None = None,
    wait: bool = False,
    _locked: bool = False,
) -> tuple[Path, str, int]:
    """Write a synthetic drive under ``basedir`` in the KITTI raw layout (see :mod:`slamlib.synth.writer`).

    Returns ``(Path(basedir), date, drive)``.

    The drive appears whole or not at all (:func:`slamlib.atomic.atomic_folder`): it is written into a temporary
    sibling folder under an exclusive lock and renamed into place. An existing drive folder is rewritten only if it
    is this generator's (complete or interrupted, see :func:`slamlib.synth.writer.is_own_drive`) or empty: then the
    generator's part (markers, ``oxts/``, ``velodyne_points/``) is replaced and the user's other files in it stay.
    Raises ``FileExistsError``, before writing anything, for another non-empty folder or for differing calibration
    files in ``basedir/DATE``.

    Parameters
    ----------
    basedir : output root; the drive goes to ``basedir/DATE/DATE_drive_NNNN_sync``.
    route : a :class:`Route` or a name (``"straight"``, ``"loop"``, ``"00"``, ``"05"``, ``"07"``).
    frames : frame selection, see :func:`resolve_route`.
    seed : master seed; the same arguments give byte-identical files.
    noise : IMU noise of the OXTS velocity / rate / acceleration fields.
    lidar : sensor model (reduce ``columns`` / raise ``beam_stride`` for fast tests).
    scans : write Velodyne scans (``False``: OXTS + timestamps only, empty ``velodyne_points/data``; the
        drive then still loads in ``pykitti.raw`` for OXTS but has no scans).
    progress : show a tqdm progress bar.
    distortion : cast each scan column by column along the sweep, as a real HDL-64E (KITTI's timing:
        :mod:`slamlib.synth.lidar`), centred on the scan's timestamp; off: every scan from one pose, the
        pose at its OXTS timestamp. The OXTS ground truth stays at the OXTS timestamps, 12-24 ms after the
        scans' (as in KITTI raw data).
    traffic : moving cars, cyclists and pedestrians in the scans (:mod:`slamlib.synth.traffic`, e.g.
        ``TrafficConfig()`` for a KITTI city drive, ``TrafficConfig().scaled(2)`` twice as dense), drawn from a
        fifth random stream; ``None``: a static town, the same bytes as without the argument. With traffic the
        town has no parked cars on the left (``TrafficConfig.clear_left_parking``).

    wait : when another process writes the same drive folder, wait for it (``False``: raise
        :class:`~slamlib.errors.FolderBusyError` naming that process).
    """
    from slamlib.kitti.calib import load_T_velo_imu

    r, n = resolve_route(route, frames)
    rng_time, rng_imu, rng_scene, rng_lidar, rng_traffic = _streams(seed)
    ddir = drive_dir(basedir, date, drive)
    _check_own_folder(ddir, "basedir, date or drive")
    check_calib(basedir, date)
    params = {
        "version": GENERATOR_VERSION,
        "route": r.name,
        "frames": n,
        "seed": seed,
        "noise": noise.as_dict(),
        "lidar": lidar.as_dict(),
        "scans": scans,
        **_realism(distortion, traffic),
    }
    with atomic_folder(
        ddir, _user_entry(False), wait, "--out, --date or --drive", _locked
    ) as tmp:
        _check_own_folder(
            ddir, "basedir, date or drive"
        )  # as it is now that we hold the lock
        date_dir = write_calib(basedir, date)
        ts, t_route = _frame_times(r, n, date, rng_time)
        packets = oxts_packets(r, t_route, noise, seed=int(rng_imu.integers(2**63)))
        write_oxts(tmp, packets, ts["oxts"])
        write_velodyne_timestamps(tmp, ts)
        if scans:
            T_imu_velo = invert_pose(load_T_velo_imu(date_dir))
            T_w_velo = r.pose(t_route) @ T_imu_velo
            t_sweep = _route_time(r, ts, "velo") if distortion else None
            for k, scan in _cast_scans(
                r,
                t_route,
                T_w_velo,
                rng_scene,
                rng_lidar,
                lidar,
                progress,
                f"synth drive {drive:04d}",
                t_sweep,
                T_imu_velo,
                traffic,
                rng_traffic,
            ):
                write_scan(tmp, k, scan)
        write_marker(tmp, params)
    return Path(basedir), date, drive


#: The generator's random streams: timestamps, IMU noise, scene, LIDAR noise, traffic (the fifth was added later;
#: ``SeedSequence`` children are derived by index, so the first four are those of the four-stream versions).
N_STREAMS = 5


def drive_traffic(
    route="07",
    frames=DEFAULT_FRAMES,
    seed: int = 0,
    traffic: TrafficConfig = TrafficConfig(),
    date: str = "2011_09_26",
):
    """The movers that :func:`write_drive` (raw layout) puts in the scans of a drive with these arguments, from
    the same random streams: ``(route, t_route (F,), traffic)``, with ``t_route[k]`` frame k's OXTS instant on the
    route (s) and :class:`~slamlib.synth.traffic.Traffic` ``traffic`` (``.boxes(t)``, ``.inside(points, t)``). The
    route's world frame is the drive's ground truth's moved by the route's pose at ``t_route[0]``:
    ``p_route = route.pose(t_route[0])[0] @ p_drive``. For plots and checks of what the scans hold."""
    r, n = resolve_route(route, frames)
    rng_time, _, _, _, rng_traffic = _streams(seed)
    _, t_route = _frame_times(r, n, date, rng_time)
    return r, t_route, build_traffic(r, t_route[0], t_route[-1], traffic, rng_traffic)


def _frame_times(r: Route, n: int, date: str, rng_time):
    """The ``n`` frames' timestamps (:func:`~slamlib.synth.writer.frame_timestamps_ns`, from ``rng_time``) and their
    OXTS instants on the route ``t_route (n,)`` s (the first frame's packet at the route's start)."""
    ts = frame_timestamps_ns(n, date, rng_time)
    return ts, _route_time(r, ts, "oxts")


def _route_time(r: Route, ts: dict, which: str) -> np.ndarray:
    """Route time (s) of the stamps ``ts[which]`` (``"oxts"``, ``"velo"``, ...), the first OXTS stamp at ``r.t0``."""
    return r.t0 + (ts[which] - ts["oxts"][0]) * 1e-9


def _realism(distortion: bool, traffic: TrafficConfig | None) -> dict:
    """The marker's (and the default drive's cache key's) record of a drive's realism: ``distortion`` and ``traffic``
    only when on, so that a still drive's parameters, and the cache keys made from them, are those it had before
    drives could be realistic."""
    return {
        **({"distortion": True} if distortion else {}),
        **({"traffic": traffic.as_dict()} if traffic is not None else {}),
    }


def _streams(seed: int):
    """The generator's independent random streams (timestamps, IMU noise, scene, LIDAR noise, traffic) from ``seed``."""
    return tuple(
        np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(N_STREAMS)
    )


def _check_own_folder(folder: Path, what: str) -> None:
    """FileExistsError, before anything is written, unless ``folder`` is absent, empty or the generator's own
    (and every existing folder above it is a folder)."""
    for above in folder.parents:
        if above.exists() and not above.is_dir():
            raise FileExistsError(
                f"{above} exists and is not a folder; choose another {what}"
            )
    if folder.is_symlink() or (folder.exists() and not folder.is_dir()):
        raise FileExistsError(
            f"{folder} exists and is not a folder; choose another {what}"
        )
    if folder.is_dir() and not is_own_drive(folder) and any(folder.iterdir()):
        raise FileExistsError(
            f"{folder} exists and is not a slamlib synthetic drive (no {MARKER}); choose another "
            f"{what}"
        )


def _user_entry(sequence: bool):
    """``keep(path)`` for :func:`slamlib.atomic.atomic_folder`: a file or folder of a drive (``sequence``: of an
    odometry sequence) that the generator did not write, which a rewrite keeps."""
    return lambda path: not generator_file(path, sequence)


def _cast_scans(
    r: Route,
    t_route,
    T_w_velo,
    rng_scene,
    rng_lidar,
    lidar: Hdl64,
    progress: bool,
    desc: str,
    t_sweep=None,
    T_imu_velo=None,
    traffic: TrafficConfig | None = None,
    rng_traffic=None,
):
    """Yield ``(k, scan (N, 4) float32)`` for every frame: the town along the route, cast from ``T_w_velo[k]``, or,
    with ``t_sweep`` (each frame's mid-sweep time on the route, s), column by column from the Velodyne pose
    ``r.pose(t) @ T_imu_velo`` at each column's firing time (:func:`slamlib.synth.lidar.column_time_offsets`).
    With ``traffic`` the movers (built from ``rng_traffic``) are in the scans where they are at the frame's instant
    (``t_route[k]``, or the sweep's blocks around ``t_sweep[k]``)."""
    from tqdm.auto import tqdm

    from slamlib.synth.lidar import column_time_offsets, ray_columns

    dense_t = np.linspace(
        t_route[0], t_route[-1], max(2, int((t_route[-1] - t_route[0]) * 20) + 2)
    )
    if traffic is None:
        scene = build_scene(r.position(dense_t), seed=int(rng_scene.integers(2**63)))
    else:
        sides = (-1,) if traffic.clear_left_parking else (-1, 1)
        scene = build_scene(
            r.position(dense_t), seed=int(rng_scene.integers(2**63)), parking_sides=sides
        )
        movers = build_traffic(r, t_route[0], t_route[-1], traffic, rng_traffic)
    rc = scene.raycasting_scene()
    dirs = ray_directions(lidar)
    offsets = column_time_offsets(lidar)
    cols = ray_columns(lidar) if t_sweep is not None else None
    for k in tqdm(range(len(t_route)), desc=desc, disable=not progress, unit="scan"):
        poses = (
            None
            if t_sweep is None
            else r.pose_extended(t_sweep[k] + offsets) @ T_imu_velo
        )
        at = (
            None
            if traffic is None
            else _movers_at(movers, t_route[k] if t_sweep is None else t_sweep[k])
        )
        yield (
            k,
            simulate_scan(
                rc,
                scene.albedo,
                T_w_velo[k],
                rng_lidar,
                lidar,
                dirs,
                column_poses=poses,
                columns=cols,
                movers=at,
            ),
        )


def _movers_at(movers, t_frame: float):
    """``dts -> movers.meshes(t_frame + dts)``: the movers' triangles ``dts (K,)`` s after a frame's instant (route
    time, s), as :func:`~slamlib.synth.lidar.simulate_scan` asks for them."""
    return lambda dts: movers.meshes(t_frame + np.asarray(dts))


def write_sequence(
    basedir,
    route="07",
    sequence: int | str = 7,
    frames=DEFAULT_FRAMES,
    seed: int = 0,
    lidar: Hdl64 = Hdl64(),
    progress: bool = True,
    distortion: bool = False,
    traffic: TrafficConfig | None = None,
    wait: bool = False,
    _locked: bool = False,
) -> tuple[Path, str]:
    """Write a synthetic drive in the KITTI **odometry** layout (:mod:`slamlib.kitti.sequence`): scans, ``calib.txt``,
    ``times.txt`` and the ground truth ``poses/NN.txt`` -- no IMU, as the benchmark has none.

    The scans, timing and poses are those :func:`write_drive` writes for the same ``route``, ``frames`` and
    ``seed`` (the same random streams; ``traffic`` as there; ``distortion`` as there, the ground truth then at the
    mid-sweep instants, as KITTI's odometry poses are the scans'): ``times.txt`` holds the scans' mid-sweep times
    since the first, the poses are the left camera's, ``P_k = Tr inv(T_w_velo_0) T_w_velo_k inv(Tr)``, with ``Tr``
    the real 2011_09_26 Velodyne -> rectified left camera calibration (:func:`slamlib.synth.writer.odometry_calib`).

    Returns ``(Path(basedir), "NN")``; the sequence folder is ``basedir/sequences/NN``. Rewrites only a folder of
    this generator's (or an empty one), like :func:`write_drive`, and appears whole or not at all as there;
    ``basedir/poses/NN.txt`` is written (whole, by a rename) only if absent or written by the generator before
    (its sequence folder carries the marker), and the marker records its SHA-1 (``poses_sha1``), so that the
    reader can tell ground truth that is not the sequence's (:class:`slamlib.kitti.sequence.KittiOdometrySequence`).
    """
    from slamlib.kitti.calib import load_T_velo_imu
    from slamlib.kitti.sequence import sequence_name
    from slamlib.kitti.trajectory_io import write_kitti_poses, write_times

    name = sequence_name(sequence)
    r, n = resolve_route(route, frames)
    rng_time, _, rng_scene, rng_lidar, rng_traffic = _streams(seed)
    sdir = Path(basedir) / "sequences" / name
    poses_path = Path(basedir) / "poses" / f"{name}.txt"
    _check_own_folder(sdir, "basedir or sequence")
    if poses_path.exists() and not is_own_drive(sdir):
        raise FileExistsError(
            f"{poses_path} exists and was not written by slamlib synth; choose another basedir "
            "or sequence"
        )
    params = {
        "version": GENERATOR_VERSION,
        "layout": "odometry",
        "route": r.name,
        "frames": n,
        "seed": seed,
        "lidar": lidar.as_dict(),
        **_realism(distortion, traffic),
    }
    with atomic_folder(
        sdir, _user_entry(True), wait, "--out or --sequence", _locked
    ) as tmp:
        _check_own_folder(sdir, "basedir or sequence")
        ts, t_route = _frame_times(r, n, "2011_09_26", rng_time)
        T_imu_velo = invert_pose(load_T_velo_imu(_SAMPLE))
        T_w_velo = r.pose(t_route) @ T_imu_velo
        t_sweep = _route_time(r, ts, "velo") if distortion else None
        # the odometry ground truth is the scan's pose: its mid-sweep instant, not the OXTS one
        if distortion:
            T_w_velo = r.pose_extended(t_sweep) @ T_imu_velo
        Tr = write_odometry_calib(tmp)
        write_times(tmp / "times.txt", (ts["velo"] - ts["velo"][0]) * 1e-9)
        poses_tmp = tmp / ".poses.txt"
        write_kitti_poses(
            poses_tmp, Tr @ (invert_pose(T_w_velo[0])[None] @ T_w_velo) @ invert_pose(Tr)
        )
        params["poses_sha1"] = hashlib.sha1(poses_tmp.read_bytes()).hexdigest()
        (tmp / "velodyne").mkdir()
        for k, scan in _cast_scans(
            r,
            t_route,
            T_w_velo,
            rng_scene,
            rng_lidar,
            lidar,
            progress,
            f"synth sequence {name}",
            t_sweep,
            T_imu_velo,
            traffic,
            rng_traffic,
        ):
            write_odometry_scan(tmp, k, scan)
        write_marker(tmp, params)
        # the ground truth beside the sequence, whole: a reader checks it against the marker's SHA-1
        poses_path.parent.mkdir(parents=True, exist_ok=True)
        os.replace(poses_tmp, poses_path)
    return Path(basedir), name


def default_drive(
    frames=DEFAULT_FRAMES,
    seed: int = 0,
    full: bool = False,
    route: str = "07",
    noise: ImuNoise | None = None,
    lidar: Hdl64 = Hdl64(),
    scans: bool = True,
    progress: bool = True,
    realism: bool = True,
) -> tuple[Path, str, int]:
    """The default synthetic drive (KITTI 07 route, key frames ``frames``), generated once into the cache.

    ``realism`` (on by default) makes it a drive as a real one is: scans swept column by column as KITTI's HDL-64E
    (``distortion``), moving cars, cyclists and pedestrians at a KITTI city drive's density
    (:data:`~slamlib.synth.traffic.KITTI_CITY`) and wandering IMU biases
    (:data:`~slamlib.synth.oxts.WANDERING_BIASES`, when ``noise`` is not given). ``realism=False``: a still town,
    each scan cast from one pose, constant biases (``noise`` default :class:`~slamlib.synth.oxts.ImuNoise`), the
    drive the book's first chapters explain SLAM on. ``full=True`` takes the whole 07 route (~1,100 frames, a few
    minutes to generate). The cache folder is ``cache_dir()/synth/<hash of the parameters and
    GENERATOR_VERSION>``; a drive whose completion marker is missing or differs is regenerated. Returns
    ``(basedir, date, drive)``.
    """
    if full:
        frames = (0, None)
    if noise is None:
        noise = WANDERING_BIASES if realism else ImuNoise()
    traffic = KITTI_CITY if realism else None
    params = {
        "version": GENERATOR_VERSION,
        "route": route,
        "frames": list(frames) if frames else None,
        "seed": seed,
        "noise": noise.as_dict(),
        "lidar": lidar.as_dict(),
        "scans": scans,
        **_realism(realism, traffic),
    }
    key = hashlib.sha1(json.dumps(params, sort_keys=True).encode()).hexdigest()[:12]
    basedir = cache_dir() / "synth" / key
    date, drive = "2011_09_26", 1
    ddir = drive_dir(basedir, date, drive)
    _, n = resolve_route(route, frames)

    def stale() -> bool:
        marker = read_marker(ddir)
        return (
            marker is None
            or marker.get("version") != GENERATOR_VERSION
            or marker.get("frames") != n
        )

    if not stale():
        return basedir, date, drive
    # two first runs at once: the second waits for the first's drive instead of writing it again
    with folder_lock(ddir, wait=True, what="cache entry"):
        if not stale():
            return basedir, date, drive
        write_drive(
            basedir,
            route,
            date,
            drive,
            frames=frames,
            seed=seed,
            noise=noise,
            lidar=lidar,
            scans=scans,
            progress=progress,
            distortion=realism,
            traffic=traffic,
            _locked=True,
        )
    return basedir, date, drive
