"""Lazy, validated reader of one KITTI **odometry** sequence (``basedir/sequences/NN``): LIDAR scans, no IMU.

Layout read (the KITTI odometry benchmark, as ``pykitti.odometry`` reads it and ``slamlib synth --layout odometry``
writes it)::

    basedir/sequences/NN/calib.txt           P0 .. P3 (3x4 camera projections), Tr (3x4: Velodyne -> left camera)
    basedir/sequences/NN/times.txt           one time per frame, seconds since the sequence start
    basedir/sequences/NN/velodyne/NNNNNN.bin one scan per frame (float32 x, y, z, reflectance)
    basedir/poses/NN.txt                     (optional; 00-10 only) ground truth: 3x4 left-camera poses, 12 numbers
                                             a line, in the frame of the camera's first pose

Frames: the sequence has **no IMU**, so the body frame is the Velodyne frame (``T_velo_imu`` is the identity and
a frame's ``velocity`` / ``angular_rate`` are ``None``: the filter predicts the motion itself, LIDAR-only). The
camera ground truth ``P_k = T_cam0_cam_k`` becomes the LIDAR's with the calibration ``Tr = T_cam_velo`` (4x4)::

    T_w_body_k = inv(Tr) P_k Tr          (world = the Velodyne pose at frame 0; P_0 = I gives T_w_body_0 = I)

At open: the folder, ``calib.txt`` (``Tr`` a rigid transform), ``times.txt`` (strictly increasing), the scan file
list (one per time) and the ground truth (at least one pose per time) are validated. Scans are read, and
validated, only when their frame is read. Every problem is a :class:`slamlib.errors.DataFormatError` naming the
file and, in text files, the line.

Reference: A. Geiger, P. Lenz, R. Urtasun, "Are we ready for autonomous driving? The KITTI vision benchmark
suite", CVPR 2012 (the odometry devkit's ``readme.txt`` describes these files).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from slamlib.errors import DataFormatError
from slamlib.kitti.calib import read_calib_file, rigid_transform
from slamlib.kitti.trajectory_io import read_kitti_poses, read_times
from slamlib.kitti.velodyne import (
    SYNTH_MARKER,
    check_complete,
    read_synth_marker,
    read_velodyne_scan,
    scans_swept,
)

__all__ = [
    "OdometryFrame",
    "KittiOdometrySequence",
    "sequence_name",
    "CALIB_KEYS",
    "SCAN_DIGITS",
]

#: Keys of an odometry ``calib.txt`` and how many numbers each holds (``Tr`` is the one slamlib needs).
CALIB_KEYS = {"P0": 12, "P1": 12, "P2": 12, "P3": 12, "Tr": 12}
#: Digits of the odometry scan file names (``000000.bin``), against 10 in the raw layout.
SCAN_DIGITS = 6


def _check_synth_poses(sdir: Path, poses_path: Path, found: bool) -> None:
    """DataFormatError when ``poses_path`` (``found`` beside the sequence, not given by the user) is not the ground
    truth a :mod:`slamlib.synth` sequence was written with (its marker's ``poses_sha1``): a synth run into the same
    folder was cut short between the two, or the file was replaced."""
    import hashlib

    marker = read_synth_marker(sdir)
    expected = marker.get("poses_sha1") if found and isinstance(marker, dict) else None
    if expected and hashlib.sha1(poses_path.read_bytes()).hexdigest() != expected:
        raise DataFormatError(
            poses_path,
            f"is not the ground truth {sdir} was written with (its {SYNTH_MARKER} records another "
            "SHA-1): write the sequence again with slamlib synth",
        )


def sequence_name(sequence: str | int) -> str:
    """``"07"`` from ``7``, ``"7"`` or ``"07"``: the two-digit KITTI sequence folder name."""
    s = str(sequence).strip()
    if not s.isdigit():
        raise ValueError(f"sequence must be a number like 07, got {sequence!r}")
    return f"{int(s):02d}"


@dataclass(frozen=True, eq=False)
class OdometryFrame:
    """One frame of a KITTI odometry sequence.

    Attributes
    ----------
    index : int
        Frame number in the sequence (the ``NNNNNN`` of its scan file).
    time_s : float
        ``times.txt`` value, seconds since the sequence start.
    dt : float
        Seconds since the previous frame of the iteration/selection; 0.0 for the first.
    scan : (N, 4) float32
        ``x, y, z, reflectance`` in the Velodyne frame (= the body frame).
    T_w_body : (4, 4) float64 or None
        Ground-truth Velodyne pose (world = Velodyne at frame 0), when the sequence has a poses file.
    velocity, angular_rate : None
        No IMU in this layout: step 3 takes the filter's own constant-velocity estimate
        (:func:`slamlib.slam3d.steps.read_imu`).
    velodyne_path : Path
        The scan file.
    swept : bool
        Whether the scan was taken over a sweep and wants de-skewing (the sequence's ``swept``; default False, as the
        odometry benchmark's scans are motion-compensated; the shipped real raw scans,
        :func:`slamlib.kitti.sample.real_scan_frames`, are swept).
    """

    index: int
    time_s: float
    dt: float
    scan: np.ndarray = field(repr=False)
    T_w_body: np.ndarray | None = field(repr=False)
    velodyne_path: Path = field(repr=False)
    velocity: None = None
    angular_rate: None = None
    swept: bool = False


class KittiOdometrySequence:
    """A KITTI odometry sequence, read lazily frame by frame with validation and clear errors.

    Parameters
    ----------
    basedir : path
        Folder holding ``sequences/`` (and ``poses/`` for ground truth), e.g. KITTI's ``dataset/``.
    sequence : str or int
        ``"07"``, ``"7"`` or ``7``.
    frames : range, slice or sequence of int, optional
        Frames to iterate, default all; ``len(seq)`` counts the selection.
    poses : path, optional
        Ground-truth file (default ``basedir/poses/NN.txt`` when it exists; none otherwise).
    progress : bool
        A tqdm bar while iterating.

    Attributes
    ----------
    path : Path
        ``basedir/sequences/NN``.
    Tr : (4, 4)
        ``calib.txt``'s ``Tr``: ``p_cam0 = Tr p_velo``.
    T_velo_imu : (4, 4)
        The identity: the body frame is the Velodyne frame (no IMU in this layout).
    times : (F,) float64
        ``times.txt`` of every frame; ``frames (N,)`` the selected frame numbers.
    ground_truth : (F, 4, 4) or None
        ``T_w_body`` of every frame (module docstring), when a poses file is there.
    poses_path : Path or None
        The ground-truth file read.
    swept : bool
        Whether the scans were taken over a sweep and are not yet motion-compensated
        (:func:`~slamlib.kitti.velodyne.scans_swept`): not the real odometry benchmark's (KITTI compensated them), a
        synthetic sequence's when written with ``distortion``.
    """

    def __init__(
        self,
        basedir,
        sequence: str | int,
        frames=None,
        poses=None,
        progress: bool = False,
        allow_incomplete: bool = False,
    ):
        from slamlib.kitti.raw import (
            _normalise_frames,
            check_numbered_files,
        )

        self.basedir = Path(basedir)
        self.sequence = sequence_name(sequence)
        self.path = self.basedir / "sequences" / self.sequence
        self.progress = progress
        if not self.path.is_dir():
            found = (
                sorted(
                    p.name
                    for p in (self.basedir / "sequences").glob("[0-9]*")
                    if p.is_dir()
                )
                if (self.basedir / "sequences").is_dir()
                else []
            )
            raise DataFormatError(
                self.path,
                "KITTI odometry sequence folder not found (expected "
                f"basedir/sequences/NN); sequences there: {', '.join(found) or 'none'}",
            )
        check_complete(self.path, allow_incomplete)
        calib = read_calib_file(self.path / "calib.txt", {"Tr": CALIB_KEYS["Tr"]})
        self.calib = calib
        Tr = calib["Tr"].reshape(3, 4)
        self.Tr = rigid_transform(
            self.path / "calib.txt", Tr[:, :3], Tr[:, 3], "Tr's 3x3 block", "Tr's offset"
        )
        self.T_velo_imu = np.eye(4)
        # the odometry benchmark's scans are motion-compensated; a synthetic sequence's are swept if written so
        self.swept = scans_swept(self.path, unmarked=False)
        times_path = self.path / "times.txt"
        if not times_path.is_file():
            raise DataFormatError(
                times_path,
                "times file not found (one time in seconds per frame; the odometry "
                "layout needs it for the frame intervals)",
            )
        self.times = read_times(times_path, strictly_increasing=True)
        n = self.n_sequence_frames = int(self.times.size)
        if n == 0:
            raise DataFormatError(
                times_path, "holds no times: the sequence has no frames"
            )
        self.velo_dir = self.path / "velodyne"
        check_numbered_files(
            self.velo_dir,
            ".bin",
            n,
            "Velodyne scans",
            "times in times.txt",
            SCAN_DIGITS,
            None if allow_incomplete else times_path,
        )
        self.poses_path = (
            Path(poses)
            if poses is not None
            else self.basedir / "poses" / f"{self.sequence}.txt"
        )
        if poses is None and not self.poses_path.is_file():
            self.poses_path, self.ground_truth = None, None
        else:
            P = read_kitti_poses(self.poses_path, check_rotation=True)
            if len(P) < n:
                raise DataFormatError(
                    self.poses_path,
                    f"ground truth ends after {len(P)} poses, but times.txt has "
                    f"{n} frames: pose {len(P)} (this line) is missing",
                    len(P) + 1,
                )
            _check_synth_poses(self.path, self.poses_path, poses is None)
            Tr_inv = np.linalg.inv(self.Tr)
            self.ground_truth = Tr_inv[None] @ P[:n] @ self.Tr[None]
        self.frames = _normalise_frames(frames, n)

    def velodyne_path(self, index: int) -> Path:
        """``velodyne/NNNNNN.bin`` of frame ``index``."""
        return self.velo_dir / f"{int(index):0{SCAN_DIGITS}d}.bin"

    def __len__(self) -> int:
        return int(self.frames.size)

    def __repr__(self) -> str:
        return f"KittiOdometrySequence({str(self.path)!r}, {len(self)} of {self.n_sequence_frames} frames)"

    def _frame(self, pos: int) -> OdometryFrame:
        index = int(self.frames[pos])
        dt = (
            0.0
            if pos == 0
            else float(self.times[index] - self.times[int(self.frames[pos - 1])])
        )
        return OdometryFrame(
            index=index,
            time_s=float(self.times[index]),
            dt=dt,
            scan=read_velodyne_scan(self.velodyne_path(index)),
            T_w_body=None if self.ground_truth is None else self.ground_truth[index],
            velodyne_path=self.velodyne_path(index),
            swept=self.swept,
        )

    def __getitem__(self, pos: int) -> OdometryFrame:
        """Frame at position ``pos`` of the selection (negative counts from the end)."""
        n = len(self)
        if not -n <= pos < n:
            raise IndexError(f"frame position {pos} out of range for {n} frames")
        return self._frame(pos % n)

    def __iter__(self) -> Iterator[OdometryFrame]:
        """The selected frames in order, each scan read (and validated) when its frame is reached."""
        from tqdm.auto import tqdm

        for pos in tqdm(
            range(len(self)),
            desc="frames",
            unit="frame",
            disable=not self.progress,
            leave=False,
        ):
            yield self._frame(pos)

    def ground_truth_poses(self) -> np.ndarray:
        """``T_w_body`` ``(N, 4, 4)`` of the selected frames; ValueError without a poses file."""
        if self.ground_truth is None:
            raise ValueError(
                f"{self.path} has no ground truth ({self.basedir / 'poses' / self.sequence}.txt)"
            )
        return self.ground_truth[self.frames]
