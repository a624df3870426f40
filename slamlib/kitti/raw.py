"""Lazy, validated reader of one KITTI raw drive (``basedir/DATE/DATE_drive_XXXX_sync``).

Layout read (the synchronised KITTI raw format, as written by ``slamlib.synth`` too)::

    basedir/DATE/calib_imu_to_velo.txt, calib_velo_to_cam.txt, calib_cam_to_cam.txt
    basedir/DATE/DATE_drive_XXXX_sync/oxts/timestamps.txt          one time per frame
    basedir/DATE/DATE_drive_XXXX_sync/oxts/data/NNNNNNNNNN.txt     one OXTS packet per frame
    basedir/DATE/DATE_drive_XXXX_sync/velodyne_points/data/NNNNNNNNNN.bin   one scan per frame
    basedir/DATE/DATE_drive_XXXX_sync/velodyne_points/timestamps.txt       (optional) scan times

At open: the folder, the calibration files and keys, and the OXTS timestamps are validated, the file
lists are checked (one OXTS packet per timestamp, at least as many scans as packets), and the first
OXTS packet is read (it defines the world frame). Every other file is read, and validated, only when its
frame is read, so iterating a 4,500-frame drive holds one scan in memory at a time.

Frames and conventions (see CONTRIBUTING.md): world = the IMU pose at the drive's first frame (frame 0,
whatever ``frames`` selects); ``T_w_imu`` from the OXTS packets in pykitti's Mercator convention
(:mod:`slamlib.kitti.oxts`); ``T_w_velo = T_w_imu @ inv(T_velo_imu)``.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from slamlib.errors import DataFormatError
from slamlib.kitti.calib import (
    check_calibration,
    check_calibration_for_pykitti,
    load_T_velo_imu,
)
from slamlib.kitti.oxts import OXTS_FIELDS as _FIELDS
from slamlib.kitti.oxts import (
    OxtsPacket,
    check_oxts_for_pykitti,
    poses_from_packets,
    read_oxts_packet,
)
from slamlib.kitti.timestamps import check_timestamps_for_pykitti, read_timestamps_ns
from slamlib.kitti.velodyne import (
    SWEEP_PERIOD_S,
    check_complete,
    read_velodyne_scan,
    scans_swept,
)

__all__ = ["Frame", "ImuArrays", "KittiRawDrive", "drive_folder_name"]


def drive_folder_name(date: str, drive: str | int, dataset: str = "sync") -> str:
    """``DATE_drive_XXXX_sync``: KITTI's drive folder name (``drive`` as ``'0001'`` or ``1``)."""
    return f"{date}_drive_{_drive_str(drive)}_{dataset}"


def _drive_str(drive: str | int) -> str:
    return f"{int(drive):04d}" if isinstance(drive, (int, np.integer)) else str(drive)


@dataclass(frozen=True, eq=False)
class Frame:
    """One frame of a KITTI raw drive: scan, OXTS packet, IMU quantities, timing and ground truth.

    Attributes
    ----------
    index : int
        Frame number in the drive (the ``NNNNNNNNNN`` of its files), not the position in a selection.
    timestamp_ns : int
        OXTS timestamp, integer nanoseconds since 1970 (wall clock read as UTC), full precision.
    time_s : float
        Seconds since the drive's first frame (frame 0): ``(timestamp_ns - timestamps_ns[0]) * 1e-9``.
    dt : float
        Seconds since the previous frame *of the iteration/selection* (e.g. 0.2 s with every 2nd frame);
        **0.0 for the first frame** of the selection (no motion to integrate).
    scan : (N, 4) float32
        ``x, y, z, reflectance`` in the Velodyne frame (metres).
    oxts : OxtsPacket
        All 30 named OXTS fields (see :mod:`slamlib.kitti.oxts`).
    velocity : (3,) float64
        ``(vf, vl, vu)`` m/s, body (IMU) frame: forward, left, up.
    angular_rate : (3,) float64
        ``(wf, wl, wu)`` rad/s about the body forward, left, up axes.
    acceleration : (3,) float64
        ``(af, al, au)`` m/s^2 (includes gravity on ``au``, ~9.81 m/s^2). On real KITTI drives these are axes of the
        level heading frame (forward, left, up: gravity always on ``au``); the synthetic drives write body axes.
    specific_force : (3,) float64
        ``(ax, ay, az)`` m/s^2, body frame, gravity included: what the accelerometer measures, which tells the
        body's roll and pitch (:func:`slamlib.slam3d.stages.prior.gravity_up`).
    T_w_imu, T_w_velo : (4, 4) float64
        Ground-truth poses of the IMU and Velodyne in the world (= IMU at frame 0);
        ``T_w_velo = T_w_imu @ inv(T_velo_imu)``.
    velodyne_path : Path
        The scan file.
    scan_time_offset_s : float
        The scan's own timestamp (mid-sweep, ``velodyne_points/timestamps.txt``) minus the frame's OXTS timestamp,
        in seconds: about -12 to -24 ms on KITTI (the sweep is centred that long before the pose); 0.0 when the drive
        has no Velodyne timestamps.
    swept : bool
        Whether the scan was taken over a sweep and wants de-skewing (the drive's
        :func:`~slamlib.kitti.velodyne.scans_swept`: real KITTI scans are; a synthetic drive's only when written
        with ``distortion``).
    """

    index: int
    timestamp_ns: int
    time_s: float
    dt: float
    scan: np.ndarray = field(repr=False)
    oxts: OxtsPacket = field(repr=False)
    velocity: np.ndarray = field(repr=False)
    angular_rate: np.ndarray = field(repr=False)
    acceleration: np.ndarray = field(repr=False)
    specific_force: np.ndarray = field(repr=False)
    T_w_imu: np.ndarray = field(repr=False)
    T_w_velo: np.ndarray = field(repr=False)
    velodyne_path: Path = field(repr=False)
    scan_time_offset_s: float = 0.0
    swept: bool = True


@dataclass(frozen=True, eq=False)
class ImuArrays:
    """IMU quantities of every selected frame, as arrays (no scans read). ``N`` = number of frames.

    ``index (N,)`` int64 frame numbers, ``timestamps_ns (N,)`` int64, ``time_s (N,)`` since frame 0,
    ``dt (N,)`` seconds since the previous selected frame (``dt[0] = 0.0``), ``velocity (N, 3)`` (vf, vl, vu)
    m/s, ``angular_rate (N, 3)`` (wf, wl, wu) rad/s, ``acceleration (N, 3)`` (af, al, au) m/s^2 and
    ``specific_force (N, 3)`` (ax, ay, az) m/s^2, as in :class:`Frame`.
    """

    index: np.ndarray
    timestamps_ns: np.ndarray
    time_s: np.ndarray
    dt: np.ndarray
    velocity: np.ndarray
    angular_rate: np.ndarray
    acceleration: np.ndarray
    specific_force: np.ndarray


def check_numbered_files(
    folder: Path,
    ext: str,
    n: int,
    what: str,
    against: str,
    digits: int = 10,
    times: Path | None = None,
) -> None:
    """DataFormatError naming ``folder`` unless it holds ``0..n-1`` as zero-padded ``digits``-digit names ending in
    ``ext`` (KITTI raw: 10 digits; odometry scans: 6). ``what`` names the files, ``against`` what counts them.

    With ``times`` (the file that times the ``n`` frames), numbered files beyond ``n - 1`` are an error naming it
    too: a frame without a time would be dropped without a word (the readers' ``allow_incomplete`` passes no
    ``times`` and reads the first ``n``). One listing of ``folder`` serves both checks."""
    if not folder.is_dir():
        raise DataFormatError(
            folder, f"folder of {what} not found (needed for {n} frames)"
        )
    names = {e.name for e in os.scandir(folder) if e.name.endswith(ext)}
    missing = [i for i in range(n) if f"{i:0{digits}d}{ext}" not in names]
    if missing:
        raise DataFormatError(
            folder,
            f"fewer {what} than the {n} {against}: {len(missing)} of {n} missing "
            f"(first: {missing[0]:0{digits}d}{ext}; files are numbered {0:0{digits}d}{ext} upwards)",
        )
    extra = sorted(
        name
        for name in names
        if len(name) == digits + len(ext)
        and name[:digits].isdigit()
        and int(name[:digits]) >= n
    )
    if times is not None and extra:
        raise DataFormatError(
            times,
            f"times {n} frames, but {folder} holds {n + len(extra)} {what} ({extra[0]} onwards have no "
            "time): one line is missing, or pass --allow-incomplete to read the first "
            f"{n}",
        )


def _normalise_frames(frames, n: int) -> np.ndarray:
    if frames is None:
        return np.arange(n, dtype=np.int64)
    if isinstance(frames, slice):
        return np.arange(n, dtype=np.int64)[frames]
    given = np.asarray(
        list(frames) if not isinstance(frames, (range, np.ndarray)) else frames
    )
    if given.ndim != 1:
        raise ValueError(
            "frames must be a range, a slice or a 1-D sequence of frame numbers"
        )
    if np.issubdtype(given.dtype, np.integer):
        whole = np.ones(given.shape, bool)
    # 2.0 is frame 2; 0.5 is no frame (astype would truncate it)
    elif np.issubdtype(given.dtype, np.floating):
        whole = np.isfinite(given) & (given == np.floor(given))
    else:
        whole = np.zeros(given.shape, bool)
    if not whole.all():
        raise ValueError(f"frames must be whole frame numbers, got {given[~whole][0]!r}")
    idx = given.astype(np.int64)
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise ValueError(
            f"frames out of range: the drive has frames 0..{n - 1}, asked for {idx.min()}..{idx.max()}"
        )
    return idx


class KittiRawDrive:
    """A KITTI raw drive, read lazily frame by frame with validation and clear errors.

    Parameters
    ----------
    basedir : path
        Folder holding ``DATE/`` (e.g. the folder you unpacked KITTI raw into).
    date : str
        Recording date, e.g. ``"2011_09_26"``.
    drive : str or int
        Drive number, e.g. ``"0001"`` or ``1``.
    frames : range, slice or sequence of int, optional
        Frames to iterate (drive frame numbers), default all. ``len(drive)`` counts the selection.
    dataset : str
        Folder suffix, ``"sync"`` (KITTI's synchronised data).
    progress : bool
        Show tqdm progress bars while iterating frames and when reading every OXTS packet
        (:meth:`imu_arrays`, :meth:`ground_truth_poses`). Off by default.

    Attributes
    ----------
    path : Path
        The drive folder. ``calib_dir``: ``basedir/DATE``.
    T_velo_imu : (4, 4) float64
        From ``calib_imu_to_velo.txt``: ``p_velo = T_velo_imu @ p_imu``.
    timestamps_ns : (N,) int64
        OXTS timestamps of the selected frames (``all_timestamps_ns``: of every frame of the drive).
    velo_timestamps_ns : (N,) int64 or None
        ``velodyne_points/timestamps.txt`` of the selected frames, when that file exists.
    frames : (N,) int64
        The selected frame numbers.
    n_drive_frames : int
        Frames in the whole drive (= OXTS timestamps).
    swept : bool
        Whether the scans were taken over a sweep (:func:`~slamlib.kitti.velodyne.scans_swept`: real drives; a
        synthetic one written with ``distortion``): the filter de-skews them unless told otherwise
        (:attr:`slamlib.slam3d.config.ScanConfig.deskew`).

    Examples
    --------
    >>> drive = KittiRawDrive(basedir, "2011_09_26", "0001", frames=range(0, 20))   # doctest: +SKIP
    >>> for frame in drive:                                                          # doctest: +SKIP
    ...     frame.scan, frame.velocity, frame.angular_rate, frame.dt, frame.T_w_velo
    """

    def __init__(
        self,
        basedir,
        date: str,
        drive: str | int,
        frames=None,
        dataset: str = "sync",
        progress: bool = False,
        allow_incomplete: bool = False,
    ):
        self.basedir = Path(basedir)
        self.date = str(date)
        self.drive = _drive_str(drive)
        self.dataset = dataset
        self.progress = progress
        self.calib_dir = self.basedir / self.date
        self.path = self.calib_dir / drive_folder_name(self.date, self.drive, dataset)
        if not self.path.is_dir():
            raise DataFormatError(
                self.path,
                f"KITTI raw drive folder not found (expected basedir/DATE/DATE_drive_XXXX_{dataset} with "
                f"basedir={str(self.basedir)!r}, date={self.date!r}, drive={self.drive!r})",
            )
        check_complete(self.path, allow_incomplete)
        check_calibration(self.calib_dir)
        self.T_velo_imu = load_T_velo_imu(self.calib_dir)
        # general inverse, as T_w_velo = T_w_imu @ inv(T_velo_imu)
        self.T_imu_velo = np.linalg.inv(self.T_velo_imu)
        # real scans are; a synthetic drive's only if written with distortion
        self.swept = scans_swept(self.path)

        self.oxts_dir = self.path / "oxts" / "data"
        self.velo_dir = self.path / "velodyne_points" / "data"
        self.all_timestamps_ns = read_timestamps_ns(self.path / "oxts" / "timestamps.txt")
        n = self.n_drive_frames = int(self.all_timestamps_ns.size)
        self._check_files(
            self.oxts_dir, ".txt", n, "OXTS packets", "timestamps in oxts/timestamps.txt"
        )
        self._check_files(
            self.velo_dir,
            ".bin",
            n,
            "Velodyne scans",
            "OXTS packets",
            None if allow_incomplete else self.path / "oxts" / "timestamps.txt",
        )

        velo_ts = self.path / "velodyne_points" / "timestamps.txt"
        # Scan times are informational (dt comes from the OXTS times): format checked, order not required.
        self.all_velo_timestamps_ns = (
            read_timestamps_ns(velo_ts, strictly_increasing=False)
            if velo_ts.is_file()
            else None
        )
        if (
            self.all_velo_timestamps_ns is not None
            and self.all_velo_timestamps_ns.size < n
        ):
            raise DataFormatError(
                velo_ts,
                f"has {self.all_velo_timestamps_ns.size} timestamps, fewer than the "
                f"{n} OXTS packets",
            )

        self.frames = _normalise_frames(frames, n)
        self.timestamps_ns = self.all_timestamps_ns[self.frames]
        self.velo_timestamps_ns = (
            None
            if self.all_velo_timestamps_ns is None
            else self.all_velo_timestamps_ns[self.frames]
        )
        # The world frame: IMU pose of the drive's first frame.
        self.reference_packet = read_oxts_packet(self.oxts_path(0))
        self._packets: dict[int, OxtsPacket] = {0: self.reference_packet}
        self._pykitti = None

    # ------------------------------------------------------------------ files
    @staticmethod
    def _check_files(
        folder: Path, ext: str, n: int, what: str, against: str, times: Path | None = None
    ) -> None:
        check_numbered_files(folder, ext, n, what, against, times=times)

    def oxts_path(self, index: int) -> Path:
        """``oxts/data/NNNNNNNNNN.txt`` of drive frame ``index``."""
        return self.oxts_dir / f"{int(index):010d}.txt"

    def velodyne_path(self, index: int) -> Path:
        """``velodyne_points/data/NNNNNNNNNN.bin`` of drive frame ``index``."""
        return self.velo_dir / f"{int(index):010d}.bin"

    # ------------------------------------------------------------------ pykitti
    @property
    def pykitti(self):
        """A ``pykitti.raw`` over frame 0 only (its full camera calibration in ``.calib``), built on first use.

        pykitti reads every OXTS packet at construction without validation; slamlib validates first and
        gives pykitti only frame 0, reading the other frames itself, lazily. What pykitti parses more strictly
        than slamlib (blank lines, trailing spaces, the encoding, unstripped keys) is checked before, so a file
        pykitti cannot read is a :class:`DataFormatError` naming it, not an error from inside pykitti.
        """
        if self._pykitti is None:
            import pykitti

            check_calibration_for_pykitti(self.calib_dir)
            check_timestamps_for_pykitti(self.path / "oxts" / "timestamps.txt")
            first = min(
                e.name
                for e in os.scandir(self.oxts_dir)
                if e.name.endswith(".txt") and e.name[0] != "."
            )
            # pykitti takes the first *.txt by name as frame 0
            if first != self.oxts_path(0).name:
                raise DataFormatError(
                    self.oxts_dir / first,
                    "pykitti would read this file as frame 0's OXTS packet "
                    "(it sorts every *.txt in oxts/data): move it out",
                )
            check_oxts_for_pykitti(self.oxts_path(0))
            self._pykitti = pykitti.raw(
                str(self.basedir), self.date, self.drive, frames=[0], dataset=self.dataset
            )
        return self._pykitti

    @property
    def calib(self):
        """pykitti's calibration namedtuple (``T_velo_imu``, ``T_cam0_velo``, ``K_cam2``, ``P_rect_20``, ...)."""
        return self.pykitti.calib

    # ------------------------------------------------------------------ frames
    def __len__(self) -> int:
        return int(self.frames.size)

    def __repr__(self) -> str:
        return f"KittiRawDrive({str(self.path)!r}, {len(self)} of {self.n_drive_frames} frames)"

    def oxts_packet(self, index: int) -> OxtsPacket:
        """The validated OXTS packet of drive frame ``index`` (cached: 30 numbers)."""
        index = int(index)
        p = self._packets.get(index)
        if p is None:
            p = self._packets[index] = read_oxts_packet(self.oxts_path(index))
        return p

    def T_w_imu_of(self, index: int) -> np.ndarray:
        """Ground-truth ``T_w_imu`` (4x4) of drive frame ``index`` (world = IMU pose at frame 0)."""
        return poses_from_packets(
            [self.oxts_packet(index)], reference=self.reference_packet
        )[0]

    def _frame(self, pos: int, prev_ns: int | None) -> Frame:
        index = int(self.frames[pos])
        ts = int(self.all_timestamps_ns[index])
        packet = self.oxts_packet(index)
        T_w_imu = self.T_w_imu_of(index)
        scan = read_velodyne_scan(self.velodyne_path(index))
        return Frame(
            index=index,
            timestamp_ns=ts,
            time_s=(ts - int(self.all_timestamps_ns[0])) * 1e-9,
            dt=0.0 if prev_ns is None else (ts - prev_ns) * 1e-9,
            scan=scan,
            oxts=packet,
            velocity=np.array([packet.vf, packet.vl, packet.vu]),
            angular_rate=np.array([packet.wf, packet.wl, packet.wu]),
            acceleration=np.array([packet.af, packet.al, packet.au]),
            specific_force=np.array([packet.ax, packet.ay, packet.az]),
            T_w_imu=T_w_imu,
            T_w_velo=T_w_imu @ self.T_imu_velo,
            velodyne_path=self.velodyne_path(index),
            scan_time_offset_s=self._scan_time_offset(index, ts),
            swept=self.swept,
        )

    def _scan_time_offset(self, index: int, ts: int) -> float:
        """The scan's timestamp minus the pose's (s) of drive frame ``index`` (0 without scan stamps); a
        DataFormatError naming both timestamp files and the line when the two are more than one sweep apart
        (:data:`~slamlib.kitti.velodyne.SWEEP_PERIOD_S`): no real pairing of a scan with its pose gives that."""
        if self.all_velo_timestamps_ns is None:
            return 0.0
        offset = (int(self.all_velo_timestamps_ns[index]) - ts) * 1e-9
        if not abs(offset) <= SWEEP_PERIOD_S:
            raise DataFormatError(
                self.path / "velodyne_points" / "timestamps.txt",
                f"scan stamp is {offset:+.6f} s from the pose stamp on the same line of "
                f"oxts/timestamps.txt, more than one sweep ({SWEEP_PERIOD_S} s): the two files disagree",
                line=index + 1,
            )
        return offset

    def __getitem__(self, pos: int) -> Frame:
        """Frame at position ``pos`` of the selection (negative counts from the end); ``dt`` to position pos-1."""
        n = len(self)
        if not -n <= pos < n:
            raise IndexError(f"frame position {pos} out of range for {n} frames")
        pos %= n
        prev = None if pos == 0 else int(self.all_timestamps_ns[self.frames[pos - 1]])
        return self._frame(pos, prev)

    def __iter__(self) -> Iterator[Frame]:
        """Yield the selected frames in order, reading (and validating) each frame's files as it is reached."""
        from tqdm.auto import tqdm

        prev = None
        for pos in tqdm(
            range(len(self)),
            desc="frames",
            unit="frame",
            disable=not self.progress,
            leave=False,
        ):
            frame = self._frame(pos, prev)
            prev = frame.timestamp_ns
            yield frame

    # ------------------------------------------------------------------ arrays without scans
    def _all_packets(self) -> list[OxtsPacket]:
        from tqdm.auto import tqdm

        it = tqdm(
            self.frames,
            desc="OXTS",
            unit="packet",
            disable=not self.progress,
            leave=False,
        )
        return [self.oxts_packet(i) for i in it]

    def oxts_array(self) -> np.ndarray:
        """All 30 OXTS fields of the selected frames, ``(N, 30)`` float64 in :data:`OXTS_FIELDS` order."""
        return np.array(
            [tuple(p) for p in self._all_packets()], dtype=np.float64
        ).reshape(len(self), 30)

    def ground_truth_poses(self, frame: str = "imu") -> np.ndarray:
        """Ground-truth poses of the selected frames, ``(N, 4, 4)``: ``frame='imu'`` -> ``T_w_imu``,
        ``'velo'`` -> ``T_w_velo = T_w_imu @ inv(T_velo_imu)``. World = IMU pose of drive frame 0."""
        if frame not in ("imu", "velo"):
            raise ValueError(f"frame must be 'imu' or 'velo', got {frame!r}")
        T = poses_from_packets(self._all_packets(), reference=self.reference_packet)
        return T if frame == "imu" else T @ self.T_imu_velo

    def imu_arrays(self) -> ImuArrays:
        """Velocities, angular rates, accelerations and timing of every selected frame (no scans read)."""
        a = self.oxts_array()
        col = {name: k for k, name in enumerate(_FIELDS)}
        pick = lambda names: a[:, [col[n] for n in names]]  # noqa: E731
        ts = self.timestamps_ns
        dt = np.zeros(len(self))
        if len(self) > 1:
            dt[1:] = np.diff(ts) * 1e-9
        return ImuArrays(
            index=self.frames.copy(),
            timestamps_ns=ts.copy(),
            time_s=(ts - self.all_timestamps_ns[0]) * 1e-9,
            dt=dt,
            velocity=pick(("vf", "vl", "vu")),
            angular_rate=pick(("wf", "wl", "wu")),
            acceleration=pick(("af", "al", "au")),
            specific_force=pick(("ax", "ay", "az")),
        )
