"""``slamlib bench stages``: where a frame's time goes, stage by stage, in each mode of the filter.

The default synthetic drive (``default_drive()``: swept scans, traffic, wandering biases; 300 key frames of route
07), read into memory first, so that no stage waits for the disk. Each mode registers
:data:`WARMUP_FRAMES` frames first (the kernels compiled, the map begun), then the rest with a
:class:`slamlib.slam3d.profile.StageProfile` attached: every stage's own milliseconds per frame, which add up to
the frame's time. Modes (all slamlib defaults otherwise):

* ``imu``: the default, the IMU's motion with self-tuning;
* ``lidar_only``: ``MotionConfig.model = "constant_velocity"`` on the same frames (the mode of the KITTI odometry
  layout): the held twist, the start search, road thinning and scan matching;
* ``loop_closure``: the default with a :class:`slamlib.loops.LoopCloser` fed every frame, as ``slamlib run
  --loop-closure`` does (:func:`slamlib.slam3d.run.run_drive`); its work is the ``loop_closure`` stage, its
  final optimisation included.

``--quick`` profiles :data:`QUICK_FRAMES` frames. Reported per mode: ``ms_per_frame`` per stage, their sum
``total_ms`` and ``frames_per_s``, each the median over :data:`REPEATS` runs (fresh filters on the same frames),
with ``total_ms_min`` the best run.
"""

from __future__ import annotations

import numpy as np

HELP = (
    "per-stage profile of a frame (ms per stage) in the IMU, LIDAR-only and loop-closure modes, on the default "
    "drive"
)

#: Frames registered before the profile starts: the first builds the map, the next compile or load the kernels.
WARMUP_FRAMES = 5
QUICK_FRAMES = 30
REPEATS = 3
MODES = {"imu": {}, "lidar_only": {"model": "constant_velocity"}, "loop_closure": {}}
#: The modes that feed a loop closer.
WITH_CLOSER = {"loop_closure"}


def _profile(frames, T_velo_imu, settings: dict, loop_closure: bool = False) -> dict:
    """One fresh filter over ``frames`` (and a fresh loop closer with ``loop_closure``): the profile's ms per frame
    per stage after the warm-up."""
    from slamlib.loops import LoopCloser
    from slamlib.slam3d import ParticleSLAM3D, SLAM3DConfig
    from slamlib.slam3d.profile import StageProfile

    slam = ParticleSLAM3D(SLAM3DConfig.of(**settings), T_velo_imu=T_velo_imu)
    closer = LoopCloser() if loop_closure else None

    def register(k, frame):
        pose = slam.register_frame(frame)
        if closer is not None:
            closer.add_frame(k, pose, slam.last["points"])

    for k, frame in enumerate(frames[:WARMUP_FRAMES]):
        register(k, frame)
    profile = StageProfile()
    with profile.attached(slam, closer):
        for k, frame in enumerate(frames[WARMUP_FRAMES:], start=WARMUP_FRAMES):
            register(k, frame)
        if closer is not None:
            closer.finish()
    return profile.ms_per_frame()


def run(quick: bool = False) -> dict:
    from slamlib.kitti import KittiRawDrive
    from slamlib.slam3d.profile import STAGES
    from slamlib.synth import default_drive

    basedir, date, number = default_drive(progress=False)
    drive = KittiRawDrive(basedir, date, number)
    n = min(len(drive), WARMUP_FRAMES + QUICK_FRAMES if quick else len(drive))
    frames = [
        drive[k] for k in range(n)
    ]  # in memory: the profile times the filter, not the disk
    repeats = 1 if quick else REPEATS
    modes = {}
    for mode, settings in MODES.items():
        runs = [
            _profile(frames, drive.T_velo_imu, settings, mode in WITH_CLOSER)
            for _ in range(repeats)
        ]
        totals = np.array([sum(r.values()) for r in runs])
        ms = {s: float(np.median([r[s] for r in runs])) for s in STAGES}
        modes[mode] = {
            "settings": settings,
            "loop_closure": mode in WITH_CLOSER,
            "ms_per_frame": ms,
            "total_ms": float(np.median(totals)),
            "total_ms_min": float(totals.min()),
            "frames_per_s": float(1e3 / np.median(totals)),
            "repeat": repeats,
        }
        top = sorted(ms.items(), key=lambda kv: -kv[1])[:4]
        print(
            f"{mode}: {np.median(totals):.1f} ms/frame; "
            + ", ".join(f"{s} {v:.1f}" for s, v in top)
        )
    return {
        "drive": f"default drive ({number:04d}, {len(drive)} frames)",
        "frames_profiled": n - WARMUP_FRAMES,
        "warmup_frames": WARMUP_FRAMES,
        "stages": list(STAGES),
        "modes": modes,
    }
