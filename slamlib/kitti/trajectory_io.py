"""Trajectory files: KITTI odometry poses, TUM RGB-D trajectories, and times files (all readable by ``evo``).

* **KITTI** (``evo_traj kitti poses.txt``): one pose per line, 12 numbers, the top 3x4 of ``T_w_body``
  row-major: ``r11 r12 r13 tx r21 r22 r23 ty r31 r32 r33 tz``. No timestamps (see :func:`read_times`).
* **TUM** (``evo_traj tum traj.txt``): ``timestamp tx ty tz qx qy qz qw`` per line (seconds, metres,
  unit quaternion with the scalar LAST, Hamilton convention as :class:`scipy.spatial.transform.Rotation`);
  lines starting with ``#`` are comments.
* **times** (KITTI odometry ``times.txt``): one time in seconds per line.

Poses are ``(N, 4, 4)`` float64 arrays ``T_w_body``. Numbers are written with ``repr`` precision (17
significant digits), so write -> read round-trips exactly. Bad lines raise
:class:`~slamlib.errors.DataFormatError` with the file and 1-based line.

References: KITTI odometry devkit (``readme.txt``); Sturm et al., "A Benchmark for the Evaluation of RGB-D
SLAM Systems", IROS 2012 (TUM format); M. Grupp, evo, https://github.com/MichaelGrupp/evo.
"""

from __future__ import annotations

import math
import os

import numpy as np

from slamlib.errors import DataFormatError, bom_error

__all__ = [
    "read_kitti_poses",
    "write_kitti_poses",
    "read_tum",
    "write_tum",
    "read_times",
    "write_times",
]


def _numbers(path, text: str, line: int, count: int | None, what: str) -> list[float]:
    toks = text.split()
    if count is not None and len(toks) != count:
        raise DataFormatError(
            path, f"{what} line has {len(toks)} numbers, expected {count}", line
        )
    out = []
    for k, tok in enumerate(toks):
        try:
            v = float(tok)
        except ValueError:
            raise DataFormatError(
                path, f"{what} value {k + 1} is not a number: {tok!r}", line
            ) from None
        if not math.isfinite(v):
            raise DataFormatError(
                path, f"{what} value {k + 1} is not finite: {tok!r}", line
            )
        out.append(v)
    return out


def _data_lines(path, comments: bool):
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise DataFormatError(path, "trajectory file not found")
    with open(path, encoding="utf-8", errors="replace") as f:
        for i, text in enumerate(f, start=1):
            if i == 1 and text.startswith("\ufeff"):
                raise bom_error(path)
            s = text.strip()
            if not s or (comments and s.startswith("#")):
                continue
            yield i, s


def _check_poses(poses) -> np.ndarray:
    T = np.asarray(poses, dtype=np.float64)
    if T.ndim != 3 or T.shape[1:] not in ((4, 4), (3, 4)):
        raise ValueError(f"poses must be (N, 4, 4) or (N, 3, 4), got {T.shape}")
    # per pose; an empty trajectory (0, 4, 4) is fine
    bad = ~np.isfinite(T).all(axis=(1, 2))
    if bad.any():
        raise ValueError(
            f"refusing to write a trajectory with non-finite (NaN / inf) poses: {int(bad.sum())} of "
            f"{T.shape[0]}, the first at index {int(np.argmax(bad))}"
        )
    return T


def read_kitti_poses(path: str | os.PathLike, check_rotation: bool = False) -> np.ndarray:
    """Read a KITTI pose file -> ``(N, 4, 4)`` float64 (bottom row ``0 0 0 1``).

    With ``check_rotation``, each 3x3 block must be a rotation to 1e-4 (``|R^T R - I|``, ``det R > 0``).

    Raises DataFormatError for a missing file, a line without exactly 12 finite numbers, or (checked) a
    non-rotation; file and line named.
    """
    path = os.fspath(path)
    rows = []
    for i, s in _data_lines(path, comments=False):
        vals = _numbers(path, s, i, 12, "KITTI pose")
        if check_rotation:
            R = np.array(vals).reshape(3, 4)[:, :3]
            if np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or np.linalg.det(R) <= 0:
                raise DataFormatError(
                    path, "KITTI pose rotation block is not a rotation matrix", i
                )
        rows.append(vals)
    T = np.zeros((len(rows), 4, 4))
    if rows:
        T[:, :3, :] = np.array(rows).reshape(-1, 3, 4)
    T[:, 3, 3] = 1.0
    return T


def write_kitti_poses(path: str | os.PathLike, poses) -> None:
    """Write ``(N, 4, 4)`` (or ``(N, 3, 4)``) poses as a KITTI pose file, 12 numbers per line.

    Raises ``ValueError`` (before opening the file) when a pose holds NaN or inf."""
    T = _check_poses(poses)
    with open(path, "w", encoding="ascii") as f:
        for P in T:
            f.write(" ".join(repr(float(v)) for v in P[:3, :4].ravel()) + "\n")


def read_tum(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Read a TUM trajectory -> ``(timestamps (N,) float64 s, poses (N, 4, 4))``.

    The quaternion ``(qx, qy, qz, qw)`` is normalised; a zero-norm quaternion is an error.
    Raises DataFormatError (file + line) for a line without 8 finite numbers or a zero quaternion.
    """
    path = os.fspath(path)
    rows = []
    for i, s in _data_lines(path, comments=True):
        vals = _numbers(path, s, i, 8, "TUM")
        if np.linalg.norm(vals[4:8]) < 1e-12:
            raise DataFormatError(path, "TUM quaternion (qx qy qz qw) has zero norm", i)
        rows.append(vals)
    a = np.array(rows, dtype=np.float64).reshape(-1, 8)
    T = np.zeros((a.shape[0], 4, 4))
    T[:, 3, 3] = 1.0
    if a.shape[0]:
        from scipy.spatial.transform import (
            Rotation,
        )  # here: scipy.spatial costs 0.2 s of start-up

        T[:, :3, :3] = Rotation.from_quat(a[:, 4:8]).as_matrix()
        T[:, :3, 3] = a[:, 1:4]
    return a[:, 0].copy(), T


def write_tum(path: str | os.PathLike, timestamps, poses, header: bool = False) -> None:
    """Write a TUM trajectory ``timestamp tx ty tz qx qy qz qw`` (quaternion from scipy, scalar last).

    ``header=True`` writes a ``# timestamp tx ty tz qx qy qz qw`` comment first (evo skips it). Raises
    ``ValueError`` (before opening the file) when a pose or a timestamp is NaN or inf.
    """
    T = _check_poses(poses)
    t = np.asarray(timestamps, dtype=np.float64).reshape(-1)
    if t.shape[0] != T.shape[0]:
        raise ValueError(f"{t.shape[0]} timestamps for {T.shape[0]} poses")
    if not np.all(np.isfinite(t)):
        raise ValueError(
            "refusing to write a trajectory with non-finite (NaN / inf) timestamps"
        )
    from scipy.spatial.transform import (
        Rotation,
    )  # here: scipy.spatial costs 0.2 s of start-up

    q = Rotation.from_matrix(T[:, :3, :3]).as_quat() if T.shape[0] else np.zeros((0, 4))
    with open(path, "w", encoding="ascii") as f:
        if header:
            f.write("# timestamp tx ty tz qx qy qz qw\n")
        for k in range(T.shape[0]):
            vals = [t[k], *T[k, :3, 3], *q[k]]
            f.write(" ".join(repr(float(v)) for v in vals) + "\n")


def read_times(path: str | os.PathLike, strictly_increasing: bool = False) -> np.ndarray:
    """Read a times file (one number of seconds per line, e.g. KITTI odometry ``times.txt``) -> ``(N,)`` float64.

    With ``strictly_increasing``, each time must be later than the one before (DataFormatError otherwise).
    """
    path = os.fspath(path)
    out: list[float] = []
    for i, s in _data_lines(path, comments=True):
        v = _numbers(path, s, i, 1, "time")[0]
        if strictly_increasing and out and v <= out[-1]:
            raise DataFormatError(
                path, f"time {v!r} is not later than the previous {out[-1]!r}", i
            )
        out.append(v)
    return np.array(out, dtype=np.float64)


def write_times(path: str | os.PathLike, times) -> None:
    """Write times in seconds, one per line (``repr`` precision); ``ValueError`` on NaN or inf."""
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    if not np.all(np.isfinite(times)):
        raise ValueError("refusing to write non-finite (NaN / inf) times")
    with open(path, "w", encoding="ascii") as f:
        for v in times:
            f.write(repr(float(v)) + "\n")
