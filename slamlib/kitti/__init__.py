"""Reading KITTI raw drives and odometry sequences (pykitti underneath) with clear errors, and trajectory file formats.

Public API
----------
Reader (:mod:`slamlib.kitti.raw`)::

    from slamlib.kitti import KittiRawDrive
    drive = KittiRawDrive(basedir, "2011_09_26", "0001", frames=range(0, 100))  # frames: range/slice/list
    len(drive)                      # number of selected frames
    for f in drive:                 # lazy: one scan in memory at a time
        f.index                     # drive frame number (int)
        f.timestamp_ns              # int, nanoseconds since 1970, full precision
        f.time_s                    # float, seconds since the drive's frame 0
        f.dt                        # float, seconds since the previous selected frame; 0.0 for the first
        f.scan                      # (N, 4) float32 x, y, z, reflectance, Velodyne frame
        f.oxts                      # OxtsPacket, all 30 named fields (f.oxts.lat, .vf, .wu, .navstat, ...)
        f.velocity                  # (3,) (vf, vl, vu) m/s, body frame
        f.angular_rate              # (3,) (wf, wl, wu) rad/s
        f.acceleration              # (3,) (af, al, au) m/s^2, level heading frame on real drives
        f.specific_force            # (3,) (ax, ay, az) m/s^2, body frame, gravity included
        f.T_w_imu, f.T_w_velo       # (4, 4) ground truth, world = IMU pose at drive frame 0
    drive[k]                        # the k-th selected frame (random access)
    drive.T_velo_imu                # (4, 4) from calib_imu_to_velo.txt: p_velo = T_velo_imu p_imu
    drive.timestamps_ns             # (N,) int64 of the selection
    drive.ground_truth_poses("imu" | "velo")   # (N, 4, 4), reads OXTS only
    drive.imu_arrays()              # ImuArrays: index, timestamps_ns, time_s, dt, velocity, angular_rate,
                                    # acceleration, specific_force as arrays, reads OXTS only
    drive.calib                     # pykitti's full calibration namedtuple (cameras too)

Odometry layout (:mod:`slamlib.kitti.sequence`; no IMU, the body frame is the Velodyne's)::

    seq = KittiOdometrySequence(basedir, "07", frames=range(0, 100))   # basedir/sequences/07, basedir/poses/07.txt
    for f in seq:
        f.index, f.time_s, f.dt, f.scan  # as above; f.velocity and f.angular_rate are None
        f.T_w_body                      # (4, 4) ground truth of the Velodyne (None without poses/NN.txt)
    seq.Tr                              # (4, 4) calib.txt Tr: p_cam0 = Tr p_velo

Low-level readers/writers (also what :mod:`slamlib.synth` writes with): :func:`read_timestamps_ns`,
:func:`write_timestamps_ns`, :func:`format_timestamp_ns`, :func:`read_oxts_packet`, :func:`write_oxts_packet`,
:func:`read_velodyne_scan`, :func:`write_velodyne_scan`, :func:`read_calib_file`, :func:`load_T_velo_imu`,
:func:`poses_from_packets`.

Trajectory files (:mod:`slamlib.kitti.trajectory_io`): :func:`read_kitti_poses`, :func:`write_kitti_poses`,
:func:`read_tum`, :func:`write_tum`, :func:`read_times`, :func:`write_times`.

Every reader raises :class:`slamlib.errors.DataFormatError` (``"path:line: message"``) on bad input.
"""

from slamlib.kitti.calib import (
    REQUIRED_KEYS,
    check_calibration,
    load_T_velo_imu,
    read_calib_file,
    read_rigid,
)
from slamlib.kitti.oxts import (
    OXTS_FIELDS,
    OxtsPacket,
    enu_pose_from_packet,
    format_oxts_packet,
    mercator_scale,
    parse_oxts_line,
    poses_from_packets,
    read_oxts_packet,
    write_oxts_packet,
)
from slamlib.kitti.raw import Frame, ImuArrays, KittiRawDrive, drive_folder_name
from slamlib.kitti.sequence import KittiOdometrySequence, OdometryFrame, sequence_name
from slamlib.kitti.timestamps import (
    format_timestamp_ns,
    parse_timestamp_ns,
    read_timestamps_ns,
    write_timestamps_ns,
)
from slamlib.kitti.trajectory_io import (
    read_kitti_poses,
    read_times,
    read_tum,
    write_kitti_poses,
    write_times,
    write_tum,
)
from slamlib.kitti.velodyne import (
    SYNTH_MARKER,
    read_velodyne_scan,
    scans_swept,
    write_velodyne_scan,
)

__all__ = [
    "KittiRawDrive",
    "Frame",
    "ImuArrays",
    "drive_folder_name",
    "KittiOdometrySequence",
    "OdometryFrame",
    "sequence_name",
    "OXTS_FIELDS",
    "OxtsPacket",
    "read_oxts_packet",
    "write_oxts_packet",
    "parse_oxts_line",
    "format_oxts_packet",
    "mercator_scale",
    "enu_pose_from_packet",
    "poses_from_packets",
    "read_timestamps_ns",
    "write_timestamps_ns",
    "parse_timestamp_ns",
    "format_timestamp_ns",
    "read_velodyne_scan",
    "write_velodyne_scan",
    "scans_swept",
    "SYNTH_MARKER",
    "REQUIRED_KEYS",
    "read_calib_file",
    "read_rigid",
    "check_calibration",
    "load_T_velo_imu",
    "read_kitti_poses",
    "write_kitti_poses",
    "read_tum",
    "write_tum",
    "read_times",
    "write_times",
]
