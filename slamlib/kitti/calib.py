"""KITTI raw calibration files (``basedir/DATE/calib_*.txt``), validated before pykitti reads them.

Files and the keys slamlib (and ``pykitti.raw``) need, ``key: numbers`` one per line:

* ``calib_imu_to_velo.txt``: ``R`` (9, row-major 3x3) and ``T`` (3, metres): ``T_velo_imu``, which maps
  IMU-frame points into the Velodyne frame, ``p_velo = R p_imu + T``.
* ``calib_velo_to_cam.txt``: ``R`` (9), ``T`` (3): ``T_cam0unrect_velo``.
* ``calib_cam_to_cam.txt``: ``P_rect_0k`` (12, 3x4) and ``R_rect_0k`` (9) for k = 0..3.

Other lines (``calib_time: 25-May-2012 16:47:16``, ``S_00``, ...) are kept only if numeric, like pykitti.
"""

from __future__ import annotations

import locale
import os
from pathlib import Path

import numpy as np

from slamlib.errors import DataFormatError

__all__ = [
    "IMU_TO_VELO",
    "VELO_TO_CAM",
    "CAM_TO_CAM",
    "REQUIRED_KEYS",
    "read_calib_file",
    "read_rigid",
    "rigid_transform",
    "check_calibration",
    "check_calibration_for_pykitti",
    "load_T_velo_imu",
]

IMU_TO_VELO = "calib_imu_to_velo.txt"
VELO_TO_CAM = "calib_velo_to_cam.txt"
CAM_TO_CAM = "calib_cam_to_cam.txt"

#: For each calibration file, the keys that must be present and how many numbers each holds.
REQUIRED_KEYS: dict[str, dict[str, int]] = {
    IMU_TO_VELO: {"R": 9, "T": 3},
    VELO_TO_CAM: {"R": 9, "T": 3},
    CAM_TO_CAM: {
        **{f"P_rect_0{k}": 12 for k in range(4)},
        **{f"R_rect_0{k}": 9 for k in range(4)},
    },
}


def read_calib_file(
    path: str | os.PathLike, required: dict[str, int] | None = None
) -> dict[str, np.ndarray]:
    """Read a ``key: v1 v2 ...`` calibration file into ``{key: float64 array}``.

    Lines whose values are not all numbers (e.g. ``calib_time``) are skipped unless their key is in
    ``required``. Each key in ``required`` must appear with exactly that many finite numbers.

    Raises
    ------
    DataFormatError
        Missing file; a line without ``:``; a required key missing, non-numeric, non-finite or with the
        wrong count (file and line named).
    """
    path = os.fspath(path)
    required = required or {}
    if not os.path.isfile(path):
        raise DataFormatError(path, "calibration file not found")
    data: dict[str, np.ndarray] = {}
    with open(path, encoding="ascii", errors="replace") as f:
        lines = f.read().splitlines()
    for i, text in enumerate(lines, start=1):
        if not text.strip():
            continue
        if ":" not in text:
            raise DataFormatError(
                path, f"calibration line is not 'key: values': {text.strip()!r}", i
            )
        key, value = text.split(":", 1)
        key = key.strip()
        toks = value.split()
        try:
            vals = np.array([float(x) for x in toks], dtype=np.float64)
        except ValueError:
            if key in required:
                raise DataFormatError(
                    path, f"calibration key {key!r} has a non-numeric value", i
                ) from None
            continue
        if key in required:
            if vals.size != required[key]:
                raise DataFormatError(
                    path,
                    f"calibration key {key!r} has {vals.size} numbers, expected {required[key]}",
                    i,
                )
            if not np.all(np.isfinite(vals)):
                raise DataFormatError(
                    path, f"calibration key {key!r} has a non-finite value", i
                )
        data[key] = vals
    missing = [k for k in required if k not in data]
    if missing:
        raise DataFormatError(path, f"calibration key(s) missing: {', '.join(missing)}")
    return data


#: Largest sensor-to-sensor offset ``|T|`` (m) a rigid calibration may hold (KITTI's are ~1 m; a vehicle rig is
#: a few metres).
MAX_SENSOR_OFFSET = 100.0


def read_rigid(path: str | os.PathLike) -> np.ndarray:
    """4x4 rigid transform ``[[R, T], [0, 1]]`` from a file with keys ``R`` (9, row-major) and ``T`` (3).

    Raises DataFormatError also if ``R`` is not a rotation (``|R^T R - I| > 1e-3`` or ``det R < 0``) or the
    offset ``|T|`` is more than :data:`MAX_SENSOR_OFFSET`.
    """
    d = read_calib_file(path, {"R": 9, "T": 3})
    return rigid_transform(path, d["R"].reshape(3, 3), d["T"])


#: Most a rigid calibration's rotation block may differ from a rotation, ``max |R^T R - I|``.
ROTATION_TOLERANCE = 1e-3


def rigid_transform(
    path, R, t, rotation_name: str = "R", offset_name: str = "T"
) -> np.ndarray:
    """4x4 ``[[R, t], [0, 1]]`` read from calibration file ``path``, or DataFormatError naming it when ``R`` is not a
    rotation (``|R^T R - I| > ROTATION_TOLERANCE`` or ``det R < 0``) or ``|t|`` is more than
    :data:`MAX_SENSOR_OFFSET`; the messages call them ``rotation_name`` and ``offset_name``."""
    R, t = np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)
    if np.abs(R.T @ R - np.eye(3)).max() > ROTATION_TOLERANCE or np.linalg.det(R) < 0:
        raise DataFormatError(
            path,
            f"calibration {rotation_name} is not a rotation matrix (R^T R != I or det R < 0)",
        )
    if np.linalg.norm(t) > MAX_SENSOR_OFFSET:
        raise DataFormatError(
            path,
            f"calibration {offset_name} = {t.tolist()} m is farther than {MAX_SENSOR_OFFSET:g} "
            "m: not an offset between two sensors of one vehicle",
        )
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _key_line(path: str | os.PathLike, key: str) -> int | None:
    """1-based line of the last ``key:`` line of a calibration file (the one :func:`read_calib_file` keeps)."""
    with open(path, encoding="ascii", errors="replace") as f:
        found = [
            i
            for i, text in enumerate(f.read().splitlines(), start=1)
            if ":" in text and text.split(":", 1)[0].strip() == key
        ]
    return found[-1] if found else None


def check_cam_to_cam(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read ``calib_cam_to_cam.txt`` (:data:`REQUIRED_KEYS`) and check the values pykitti computes with.

    Raises DataFormatError (file and line named) if a rectifying rotation ``R_rect_0k`` is not a rotation
    (``|R^T R - I| > 1e-3`` or ``det R < 0``; pykitti inverts ``R_rect_00``) or a projection ``P_rect_0k`` has a
    focal length ``P[0, 0] <= 0`` (pykitti divides by it).
    """
    d = read_calib_file(path, REQUIRED_KEYS[CAM_TO_CAM])
    for k in range(4):
        R = d[f"R_rect_0{k}"].reshape(3, 3)
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
            raise DataFormatError(
                path,
                f"calibration R_rect_0{k} is not a rotation matrix (R^T R != I or det R < 0)",
                _key_line(path, f"R_rect_0{k}"),
            )
        f_u = d[f"P_rect_0{k}"][0]
        if not f_u > 0:
            raise DataFormatError(
                path,
                f"calibration P_rect_0{k} has focal length P[0, 0] = {f_u:g}: it must be "
                "positive",
                _key_line(path, f"P_rect_0{k}"),
            )
    return d


def check_calibration(date_dir: str | os.PathLike) -> None:
    """Check the three calibration files in ``basedir/DATE`` have every key :data:`REQUIRED_KEYS` lists, the rigid
    transforms are rigid (:func:`read_rigid`) and the camera values usable (:func:`check_cam_to_cam`)."""
    date_dir = Path(date_dir)
    for name, keys in REQUIRED_KEYS.items():
        if keys.keys() == {"R", "T"}:
            read_rigid(date_dir / name)
        else:
            check_cam_to_cam(date_dir / name)


def check_calibration_for_pykitti(date_dir: str | os.PathLike) -> None:
    """Check that ``pykitti.raw`` reads the three calibration files as slamlib did (call after
    :func:`check_calibration`).

    pykitti reads each file in the locale's encoding (a byte it cannot decode raises), splits *every* line at its
    first ``:`` (a blank line raises) and keeps the key unstripped (``' R_rect_00'`` is not ``'R_rect_00'``).

    Raises
    ------
    DataFormatError
        The first line pykitti would fail on, or a required key pykitti would not find (file and line named).
    """
    from pykitti.utils import read_calib_file as pykitti_read_calib_file

    encoding = locale.getpreferredencoding(False)
    for name, keys in REQUIRED_KEYS.items():
        path = os.fspath(Path(date_dir) / name)
        with open(path, "rb") as f:
            raw = f.read()
        try:
            raw.decode(encoding)
        except (UnicodeDecodeError, LookupError) as exc:
            start = getattr(exc, "start", 0)
            raise DataFormatError(
                path,
                f"byte {raw[start : start + 1]!r} is not {encoding} text: pykitti cannot read "
                "the file (KITTI calibration files are ASCII)",
                raw[:start].count(b"\n") + 1,
            ) from None
        with open(path, encoding=encoding) as f:
            lines = f.readlines()
        for i, text in enumerate(lines, start=1):
            if ":" not in text:
                raise DataFormatError(
                    path,
                    "line without ':' (a blank line too): pykitti reads every line as "
                    "'key: values'",
                    i,
                )
        theirs = pykitti_read_calib_file(path)
        for key in keys:
            if key not in theirs:
                line = _key_line(path, key)
                problem = "is missing" if line is None else "has spaces around it"
                raise DataFormatError(
                    path,
                    f"calibration key {key!r} {problem}: pykitti needs '{key}:' at the start "
                    "of a line",
                    line,
                )


def load_T_velo_imu(date_dir: str | os.PathLike) -> np.ndarray:
    """``T_velo_imu`` (4x4) from ``basedir/DATE/calib_imu_to_velo.txt``: ``p_velo = T_velo_imu p_imu``."""
    return read_rigid(Path(date_dir) / IMU_TO_VELO)
