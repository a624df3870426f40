"""KITTI OXTS (GPS/IMU) packets: validated reading, writing, and ground-truth poses.

A KITTI raw drive has one packet per frame in ``oxts/data/NNNNNNNNNN.txt``: one line of 30
space-separated numbers, named in ``oxts/dataformat.txt`` (and :data:`OXTS_FIELDS`):

====================  =====================================================================
lat, lon, alt         WGS84 position of the OXTS unit (deg, deg, m)
roll, pitch, yaw      orientation (rad); ``R_world_imu = Rz(yaw) Ry(pitch) Rx(roll)``, yaw 0 = east
vn, ve                velocity north / east (m/s)
vf, vl, vu            velocity forward / left / up in the body frame (m/s)
ax, ay, az            acceleration in the body x, y, z axes (m/s^2)
af, al, au            acceleration forward / left / up (m/s^2)
wx, wy, wz            angular rate about the body x, y, z axes (rad/s)
wf, wl, wu            angular rate about forward / left / up (rad/s)
pos_accuracy          position accuracy (m);  vel_accuracy: velocity accuracy (m/s)
navstat, numsats      navigation status, number of satellites (integers)
posmode, velmode,     GPS modes (integers)
orimode
====================  =====================================================================

Poses follow pykitti (``pykitti.utils.pose_from_oxts_packet``): a Mercator projection with scale
``s = cos(lat_0)`` taken from a reference packet (the drive's first)::

    t = (s * lon * pi * r / 180,  s * r * ln(tan((90 + lat) * pi / 360)),  alt),   r = 6378137 m
    R = Rz(yaw) Ry(pitch) Rx(roll)

which gives ``T_enu_imu`` in a local east-north-up frame. slamlib's world frame is the IMU pose of the
drive's first frame: ``T_w_imu[i] = inv(T_enu_imu[0]) @ T_enu_imu[i]`` (so ``T_w_imu[0] = I``).

The packet type and the projection are written here rather than imported from pykitti, which the tests check
them against (``tests/test_kitti_oxts.py``): importing ``pykitti.utils`` runs ``pykitti/__init__.py``, which loads
all of pykitti's readers and pandas with them, a fifth of a second of every ``slamlib run``'s start-up.

Reference: Geiger et al., "Vision meets Robotics: The KITTI Dataset", IJRR 2013; pykitti 0.3.1 ``utils.py``.
"""

from __future__ import annotations

import math
import os
from collections import namedtuple
from collections.abc import Sequence

import numpy as np

from slamlib.errors import DataFormatError
from slamlib.geometry import make_pose, rpy_to_matrix

__all__ = [
    "OXTS_FIELDS",
    "OXTS_RANGES",
    "oxts_range_problem",
    "OxtsPacket",
    "read_oxts_packet",
    "check_oxts_for_pykitti",
    "parse_oxts_line",
    "format_oxts_packet",
    "write_oxts_packet",
    "mercator_scale",
    "enu_pose_from_packet",
    "EARTH_RADIUS_M",
    "poses_from_packets",
]

#: The 30 OXTS field names in file order (pykitti's ``OxtsPacket`` namedtuple fields).
OXTS_FIELDS: tuple[str, ...] = (
    *("lat", "lon", "alt", "roll", "pitch", "yaw", "vn", "ve", "vf", "vl", "vu"),
    *("ax", "ay", "az", "af", "al", "au", "wx", "wy", "wz", "wf", "wl", "wu"),
    *(
        "pos_accuracy",
        "vel_accuracy",
        "navstat",
        "numsats",
        "posmode",
        "velmode",
        "orimode",
    ),
)
#: One OXTS packet, the 30 fields by name: pykitti's ``OxtsPacket`` (same name, same fields, same order).
OxtsPacket = namedtuple("OxtsPacket", OXTS_FIELDS)
#: The earth radius (m) of pykitti's and KITTI's devkit Mercator projection (WGS84's equatorial radius).
EARTH_RADIUS_M = 6378137.0
#: The last five fields are integers (flags and counts).
N_INT_FIELDS = 5
assert len(OXTS_FIELDS) == 30

# Physical ranges checked at read time (:func:`oxts_range_problem`). They are generous on purpose: they only catch
# values no vehicle can produce, which would otherwise turn into NaN poses far downstream.
#: Latitude limit (deg): the Mercator projection of the ground truth (``ln tan((90 + lat) / 2)``) diverges at the
#: poles (lat -90 gives -inf, +90 overflows), so a latitude must lie strictly inside, here within 89 degrees.
MAX_ABS_LATITUDE_DEG = 89.0
#: Longitude limit (deg): WGS84 longitudes lie in [-180, 180].
MAX_ABS_LONGITUDE_DEG = 180.0
#: Altitude range (m): from below the Dead Sea shore and deep mines (-1 km) to above any airliner (20 km).
MIN_ALTITUDE_M, MAX_ALTITUDE_M = -1_000.0, 20_000.0
#: Orientation limit (rad) of roll, pitch and yaw: one full turn either way covers every wrapping convention.
MAX_ABS_ANGLE_RAD = 2.0 * math.pi
#: Speed limit (m/s) of vn, ve, vf, vl, vu: 150 m/s = 540 km/h, beyond any road vehicle.
MAX_SPEED_MPS = 150.0
#: Acceleration limit (m/s^2) of ax..au: 100 g, beyond a crash pulse.
MAX_ACCELERATION_MPS2 = 1_000.0
#: Angular-rate limit (rad/s) of wx..wu: 50 rad/s = 8 turns a second, beyond a spinning car.
MAX_ANGULAR_RATE_RADPS = 50.0
#: ``{field: (low, high)}``: the allowed closed range of every float field (accuracies only non-negative).
OXTS_RANGES: dict[str, tuple[float, float]] = {
    "lat": (-MAX_ABS_LATITUDE_DEG, MAX_ABS_LATITUDE_DEG),
    "lon": (-MAX_ABS_LONGITUDE_DEG, MAX_ABS_LONGITUDE_DEG),
    "alt": (MIN_ALTITUDE_M, MAX_ALTITUDE_M),
    **{k: (-MAX_ABS_ANGLE_RAD, MAX_ABS_ANGLE_RAD) for k in ("roll", "pitch", "yaw")},
    **{k: (-MAX_SPEED_MPS, MAX_SPEED_MPS) for k in ("vn", "ve", "vf", "vl", "vu")},
    **{
        k: (-MAX_ACCELERATION_MPS2, MAX_ACCELERATION_MPS2)
        for k in ("ax", "ay", "az", "af", "al", "au")
    },
    **{
        k: (-MAX_ANGULAR_RATE_RADPS, MAX_ANGULAR_RATE_RADPS)
        for k in ("wx", "wy", "wz", "wf", "wl", "wu")
    },
    "pos_accuracy": (0.0, math.inf),
    "vel_accuracy": (0.0, math.inf),
}
assert set(OXTS_RANGES) == set(OXTS_FIELDS[: len(OXTS_FIELDS) - N_INT_FIELDS])


def oxts_range_problem(name: str, value: float) -> str | None:
    """Why ``value`` is outside the physical range of OXTS field ``name`` (:data:`OXTS_RANGES`), or None."""
    rng = OXTS_RANGES.get(name)
    if rng is None or rng[0] <= value <= rng[1]:
        return None
    return f"OXTS field {name} = {value!r} is outside its physical range [{rng[0]:g}, {rng[1]:g}]"


def parse_oxts_line(
    text: str, path: str | os.PathLike = "<string>", line: int | None = 1
) -> OxtsPacket:
    """Parse one OXTS line of 30 numbers into an :class:`OxtsPacket` (floats, last five ``int``).

    Raises
    ------
    DataFormatError
        Wrong number of fields (KITTI has 30), a field that is not a number, a non-finite value
        (nan / inf), an integer field (navstat, numsats, posmode, velmode, orimode) with a fraction, or a value
        outside its physical range (:data:`OXTS_RANGES`: latitude within 89 degrees, longitude within 180,
        speeds, accelerations and rates within generous vehicle limits).
    """
    parts = text.split()
    if len(parts) != len(OXTS_FIELDS):
        raise DataFormatError(
            path,
            f"OXTS line has {len(parts)} fields, expected {len(OXTS_FIELDS)} (see oxts/dataformat.txt)",
            line,
        )
    values: list = []
    for k, (name, tok) in enumerate(zip(OXTS_FIELDS, parts)):
        try:
            v = float(tok)
        except ValueError:
            raise DataFormatError(
                path, f"OXTS field {k + 1} ({name}) is not a number: {tok!r}", line
            ) from None
        if not math.isfinite(v):
            raise DataFormatError(
                path, f"OXTS field {k + 1} ({name}) is not finite: {tok!r}", line
            )
        if k >= len(OXTS_FIELDS) - N_INT_FIELDS:
            if v != int(v):
                raise DataFormatError(
                    path,
                    f"OXTS field {k + 1} ({name}) must be an integer, got {tok!r}",
                    line,
                )
            v = int(v)
        else:
            problem = oxts_range_problem(name, v)
            if problem:
                raise DataFormatError(path, f"field {k + 1}: {problem}", line)
        values.append(v)
    return OxtsPacket(*values)


def read_oxts_packet(path: str | os.PathLike) -> OxtsPacket:
    """Read one ``oxts/data/NNNNNNNNNN.txt`` file (exactly one non-blank line of 30 numbers).

    Raises
    ------
    DataFormatError
        Missing file, no data line, more than one data line, or a bad line (see :func:`parse_oxts_line`).
    """
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise DataFormatError(path, "OXTS packet file not found")
    with open(path, encoding="ascii", errors="replace") as f:
        lines = f.read().splitlines()
    data = [(i + 1, s) for i, s in enumerate(lines) if s.strip()]
    if not data:
        raise DataFormatError(
            path, "OXTS packet file is empty (expected one line of 30 numbers)"
        )
    if len(data) > 1:
        raise DataFormatError(
            path,
            "OXTS packet file has more than one data line (expected exactly one)",
            data[1][0],
        )
    line_no, text = data[0]
    return parse_oxts_line(text, path, line_no)


def check_oxts_for_pykitti(path: str | os.PathLike) -> None:
    """Check that ``pykitti.raw`` can read an OXTS packet file slamlib accepted: pykitti reads *every* line as a
    packet, so a blank line (which slamlib skips) makes it raise.

    Raises
    ------
    DataFormatError
        The first blank line (file and 1-based line named).
    """
    path = os.fspath(path)
    with open(path, encoding="ascii", errors="replace") as f:
        lines = f.readlines()
    for i, text in enumerate(lines, start=1):
        if not text.split():
            raise DataFormatError(
                path,
                "blank line in an OXTS packet file: pykitti reads every line as a packet "
                "(expected exactly one line of 30 numbers)",
                i,
            )


def format_oxts_packet(packet: OxtsPacket | Sequence[float]) -> str:
    """One OXTS line: 25 floats with ``repr`` precision (round-trips exactly), then 5 integers."""
    vals = list(packet)
    if len(vals) != len(OXTS_FIELDS):
        raise ValueError(f"an OXTS packet has {len(OXTS_FIELDS)} values, got {len(vals)}")
    n_float = len(OXTS_FIELDS) - N_INT_FIELDS
    return " ".join(
        [repr(float(v)) for v in vals[:n_float]] + [str(int(v)) for v in vals[n_float:]]
    )


def write_oxts_packet(
    path: str | os.PathLike, packet: OxtsPacket | Sequence[float]
) -> None:
    """Write one packet as ``oxts/data/NNNNNNNNNN.txt`` (one line, newline-terminated)."""
    with open(path, "w", encoding="ascii") as f:
        f.write(format_oxts_packet(packet) + "\n")


def mercator_scale(lat_deg: float) -> float:
    """Mercator scale ``cos(lat * pi / 180)`` of the reference latitude (pykitti's ``scale``)."""
    return float(np.cos(lat_deg * np.pi / 180.0))


def enu_pose_from_packet(packet: OxtsPacket, scale: float) -> np.ndarray:
    """4x4 ``T_enu_imu`` of one packet (pykitti's Mercator convention, absolute, no origin shift): ``R = Rz(yaw)
    Ry(pitch) Rx(roll)`` and ``t = (s lon pi r / 180, s r ln tan((90 + lat) pi / 360), alt)``, ``r`` =
    :data:`EARTH_RADIUS_M`, ``s = scale``."""
    t = (
        scale * packet.lon * math.pi * EARTH_RADIUS_M / 180.0,
        scale
        * EARTH_RADIUS_M
        * math.log(math.tan((90.0 + packet.lat) * math.pi / 360.0)),
        packet.alt,
    )
    return make_pose(rpy_to_matrix((packet.roll, packet.pitch, packet.yaw)), t)


def poses_from_packets(
    packets: Sequence[OxtsPacket], reference: OxtsPacket | None = None
) -> np.ndarray:
    """Ground-truth IMU poses ``T_w_imu`` (N, 4, 4), world = IMU pose of ``reference`` (default: packets[0]).

    ``T_w_imu[i] = inv(T_enu_imu(reference)) @ T_enu_imu(packets[i])`` with the Mercator scale of the
    reference latitude. This equals ``inv(oxts[0].T_w_imu) @ oxts[i].T_w_imu`` of ``pykitti.raw``
    (pykitti subtracts the first position but keeps the absolute ENU rotation).
    """
    if len(packets) == 0:
        return np.zeros((0, 4, 4))
    ref = packets[0] if reference is None else reference
    scale = mercator_scale(ref.lat)
    T0 = enu_pose_from_packet(ref, scale)
    T = np.stack([enu_pose_from_packet(p, scale) for p in packets])
    # [R0^T Ri, R0^T (ti - t0)]: subtract the reference position first (as pykitti does) so the large
    # Mercator coordinates (~1e6 m) cancel exactly before rotating.
    R0t = T0[:3, :3].T
    out = np.zeros_like(T)
    out[:, :3, :3] = np.einsum("ij,njk->nik", R0t, T[:, :3, :3])
    out[:, :3, 3] = (T[:, :3, 3] - T0[:3, 3]) @ R0t.T
    out[:, 3, 3] = 1.0
    return out
