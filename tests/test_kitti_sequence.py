"""Issue 12: the KITTI odometry layout (reader, synthetic writer, ``slamlib run --odometry-dir``) and LIDAR-only
SLAM (step 3 from the filter's own constant-velocity estimate)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import numpy as np
import pytest

from slamlib.errors import DataFormatError
from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.kitti import KittiOdometrySequence, KittiRawDrive
from slamlib.odometry import imu_increment, increment_matrix, twist_between
from slamlib.slam3d import SLAM3DConfig, evaluate, run_drive, steps
from slamlib.synth import Hdl64, write_drive, write_sequence

FAST = Hdl64(columns=500, beam_stride=2)
N = 12


@pytest.fixture(scope="module")
def odo(tmp_path_factory):
    """A 12-frame synthetic odometry sequence 07 and the raw drive of the same route, frames and seed."""
    base = tmp_path_factory.mktemp("odometry")
    write_sequence(base, "07", 7, frames=(0, N), seed=1, lidar=FAST, progress=False)
    write_drive(base / "raw", "07", frames=(0, N), seed=1, lidar=FAST, progress=False)
    return base


def _copy(odo, tmp_path):
    dst = tmp_path / "copy"
    shutil.copytree(odo, dst, ignore=shutil.ignore_patterns("raw"))
    return dst


def test_sequence_matches_the_raw_drive_of_the_same_route(odo):
    seq = KittiOdometrySequence(odo, "7")
    raw = KittiRawDrive(odo / "raw", "2011_09_26", 1)
    assert len(seq) == N and seq.sequence == "07"
    G = raw.ground_truth_poses("velo")
    G = (
        np.linalg.inv(G[0])[None] @ G
    )  # world = Velodyne at frame 0, as the odometry ground truth
    assert (
        np.abs(seq.ground_truth_poses() - G).max() < 1e-6
    )  # 12 printed digits in poses/07.txt
    np.testing.assert_array_equal(seq[5].scan, raw[5].scan)
    assert seq[0].dt == 0.0 and 0.09 < seq[3].dt < 0.11
    assert seq[4].velocity is None and seq[4].angular_rate is None
    np.testing.assert_array_equal(seq.T_velo_imu, np.eye(4))


def test_reader_agrees_with_pykitti_odometry(odo):
    """The hand-written reader against the library it replaces for validation (pykitti.odometry)."""
    import pykitti

    seq = KittiOdometrySequence(odo, 7)
    ref = pykitti.odometry(str(odo), "07")
    np.testing.assert_allclose(seq.Tr, ref.calib.T_cam0_velo, atol=1e-12)
    np.testing.assert_allclose(
        seq.Tr[None] @ seq.ground_truth @ np.linalg.inv(seq.Tr)[None],
        np.array(ref.poses),
        atol=1e-9,
    )
    np.testing.assert_allclose(
        seq.times, [t.total_seconds() for t in ref.timestamps], atol=1e-6
    )
    np.testing.assert_array_equal(seq[7].scan, ref.get_velo(7))


def test_frames_selection_and_dt(odo):
    seq = KittiOdometrySequence(odo, 7, frames=range(2, 12, 3))
    frames = list(seq)
    assert [f.index for f in frames] == [2, 5, 8, 11]
    assert frames[0].dt == 0.0
    assert frames[1].dt == pytest.approx(seq.times[5] - seq.times[2])
    np.testing.assert_array_equal(frames[2].T_w_body, seq.ground_truth[8])


def test_missing_sequence_lists_the_ones_there(odo):
    with pytest.raises(DataFormatError, match=r"sequences/05: .*sequences there: 07"):
        KittiOdometrySequence(odo, 5)


@pytest.mark.parametrize(
    "damage, pattern",
    [
        (
            lambda d: (d / "sequences/07/times.txt").unlink(),
            r"times\.txt: times file not found",
        ),
        (
            lambda d: (d / "sequences/07/times.txt").write_text("0.0\n0.1\nabc\n"),
            r"times\.txt:3: ",
        ),
        (
            lambda d: (d / "sequences/07/times.txt").write_text("0.0\n0.1\n0.1\n"),
            r"times\.txt:3: .*not later",
        ),
        (
            lambda d: (d / "poses/07.txt").write_text(
                "\n".join((d / "poses/07.txt").read_text().splitlines()[:5]) + "\n"
            ),
            r"poses/07\.txt:6: ground truth ends after 5 poses",
        ),
        (
            lambda d: (d / "sequences/07/velodyne/000004.bin").unlink(),
            r"velodyne: .*first: 000004\.bin",
        ),
        (
            lambda d: (d / "sequences/07/calib.txt").write_text("P0: 1 0 0\n"),
            r"calib\.txt: calibration key\(s\) missing: Tr",
        ),
        (
            lambda d: (d / "sequences/07/calib.txt").write_text(
                "Tr: 2 0 0 0 0 1 0 0 0 0 1 0\n"
            ),
            r"calib\.txt: calibration Tr's 3x3 block is not a rotation",
        ),
    ],
)
def test_bad_files_name_the_file_and_line(odo, tmp_path, damage, pattern):
    d = _copy(odo, tmp_path)
    damage(d)
    with pytest.raises(DataFormatError, match=pattern):
        KittiOdometrySequence(d, 7)


def test_truncated_scan_names_the_file_when_read(odo, tmp_path):
    d = _copy(odo, tmp_path)
    scan = d / "sequences/07/velodyne/000003.bin"
    scan.write_bytes(scan.read_bytes()[:1000])
    seq = KittiOdometrySequence(d, 7)
    with pytest.raises(DataFormatError, match=r"000003\.bin: .*not a multiple of 16"):
        seq[3]


def test_write_sequence_keeps_user_files_and_refuses_foreign_folders(odo, tmp_path):
    d = _copy(odo, tmp_path)
    (d / "sequences/07/notes.txt").write_text("mine")
    write_sequence(d, "07", 7, frames=(0, 6), seed=2, lidar=FAST, progress=False)
    assert (d / "sequences/07/notes.txt").read_text() == "mine"
    assert (
        len(KittiOdometrySequence(d, 7)) == 6
    )  # the older, longer sequence's scans were the generator's: gone
    (tmp_path / "other/sequences/03").mkdir(parents=True)
    (tmp_path / "other/sequences/03/data.bin").write_bytes(b"x")
    with pytest.raises(FileExistsError, match="not a slamlib synthetic drive"):
        write_sequence(
            tmp_path / "other", "07", 3, frames=(0, 6), lidar=FAST, progress=False
        )


# ------------------------------------------------------------------------------------------------ LIDAR-only
def test_twist_between_inverts_the_motion_model():
    Ta = make_pose(rpy_to_matrix(np.array([0.1, -0.2, 0.5])), np.array([1.0, 2.0, 3.0]))
    Tb = Ta @ make_pose(
        rpy_to_matrix(np.array([0.02, 0.01, -0.3])), np.array([1.2, -0.1, 0.05])
    )
    v, w = twist_between(Ta, Tb, 0.1)
    np.testing.assert_allclose(
        Ta @ increment_matrix(*imu_increment(v, w, v, w, 0.1)), Tb, atol=1e-12
    )
    # a straight constant-velocity motion is read back as that velocity
    v, w = twist_between(np.eye(4), make_pose(np.eye(3), np.array([1.0, 0.0, 0.0])), 0.1)
    np.testing.assert_allclose(v, [10.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(w, 0.0, atol=1e-12)
    assert all(np.all(x == 0) for x in twist_between(np.eye(4), Tb, 0.0))
    for dt in (
        0.0,
        -0.1,
        np.nan,
        np.inf,
    ):  # no motion known: two zero 3-vectors, like a real twist
        assert [(x.shape, x.dtype) for x in twist_between(np.eye(4), Tb, dt)] == [
            ((3,), np.float64)
        ] * 2


def test_without_an_imu_step_3_holds_the_filters_own_twist_checked(odo):
    from slamlib.slam3d.config import MotionConfig
    from slamlib.slam3d.stages import ConstantVelocity

    frame = KittiOdometrySequence(odo, 7)[1]
    with pytest.raises(ValueError, match="no IMU values"):
        steps.read_imu(frame)
    motion = ConstantVelocity(MotionConfig(), 100, 1.0)
    poses = [np.eye(4), make_pose(np.eye(3), np.array([1.0, 0.0, 0.0]))]
    v, w = motion.read(frame, poses, [0.0, 0.1])
    np.testing.assert_allclose(v, [10.0, 0.0, 0.0])
    np.testing.assert_array_equal(w, np.zeros(3))
    poses[1] = make_pose(np.eye(3), np.array([np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match=r"\(frame 1\) \(constant-velocity estimate\)"):
        motion.read(frame, poses, [0.0, 0.1])


def test_constant_velocity_noise_is_wider_by_the_acceleration_terms():
    from slamlib.slam3d.config import MotionConfig

    m = MotionConfig()
    dp, dt = np.array([1.0, 0.0, 0.0]), 0.1
    extra = m.sigma(dp, dt, constant_velocity=True) - m.sigma(dp, dt)
    np.testing.assert_allclose(extra, np.r_[m.cv_accel, m.cv_angular_accel] * dt**2)
    with pytest.raises(ValueError, match="model must be one of"):
        MotionConfig(model="wheel")
    assert (
        m.scaled(2.0).cv_accel == tuple(2 * a for a in m.cv_accel)
        and m.scaled(2.0).model == "imu"
    )


def test_lidar_only_run_follows_a_constant_velocity_street(tmp_path):
    """On the straight route (10 m/s) the constant-velocity model is exact after two frames: LIDAR-only SLAM must
    follow the ground truth closely, and it must do better than holding still (what the first frame predicts)."""
    write_sequence(tmp_path, "straight", 0, frames=20, seed=3, lidar=FAST, progress=False)
    seq = KittiOdometrySequence(tmp_path, 0)
    run = run_drive(seq, SLAM3DConfig.of(particles=100), progress=False)
    assert run.slam.lidar_only and run.dead_reckoning is None
    m = evaluate(run)
    assert "dead_reckoning" not in m
    travelled = np.linalg.norm(run.ground_truth[-1, :3, 3])
    assert travelled > 15
    assert m["slam"]["ate_rmse_m"] < 0.02 * travelled, m["slam"]


def test_lidar_only_flag_on_a_raw_drive_ignores_the_imu(odo):
    drive = KittiRawDrive(odo / "raw", "2011_09_26", 1)
    slam = run_drive(
        drive, SLAM3DConfig.of(particles=50, model="constant_velocity"), progress=False
    ).slam
    assert slam.lidar_only and slam.dead_reckoning is None
    slam = run_drive(drive, SLAM3DConfig.of(particles=50), progress=False).slam
    assert not slam.lidar_only and slam.dead_reckoning.shape == (N, 4, 4)


# ------------------------------------------------------------------------------------------------ CLI
def _run(*args):
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "slamlib.cli",
            "run",
            "--no-progress",
            "--no-plots",
            *args,
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_cli_runs_an_odometry_sequence(odo, tmp_path):
    out = tmp_path / "out"
    r = _run(
        "--odometry-dir",
        str(odo),
        "--sequence",
        "07",
        "--particles",
        "50",
        "--out",
        str(out),
    )
    assert r.returncode == 0, r.stderr
    assert "LIDAR-only" in r.stdout and "dead reckoning" not in r.stdout.split("ATE")[-1]
    info = json.loads((out / "metrics.json").read_text())
    assert (
        info["config"]["motion"]["model"] == "constant_velocity"
        and info["sequence"] == "07"
    )
    assert (
        "dead_reckoning" not in info["metrics"]
        and not (out / "dead_reckoning_poses.txt").exists()
    )
    assert len((out / "slam_poses.txt").read_text().splitlines()) == N
    # LIDAR-only, every frame after the first is scan-matched by default; --no-scan-match turns it off
    assert (
        info["config"]["filter"]["scan_match"] is None
        and info["n_matched_frames"] == N - 1
    )
    r = _run(
        "--odometry-dir",
        str(odo),
        "--sequence",
        "07",
        "--particles",
        "50",
        "--frames",
        "0:4",
        "--no-scan-match",
        "--out",
        str(tmp_path / "off"),
    )
    assert r.returncode == 0, r.stderr
    info = json.loads((tmp_path / "off" / "metrics.json").read_text())
    assert (
        info["config"]["filter"]["scan_match"] is False and info["n_matched_frames"] == 0
    )


@pytest.mark.parametrize(
    "damage, pattern",
    [
        (
            lambda d: (d / "sequences/07/times.txt").unlink(),
            r"times\.txt: times file not found",
        ),
        (
            lambda d: (d / "poses/07.txt").write_text(
                "\n".join((d / "poses/07.txt").read_text().splitlines()[:3]) + "\n"
            ),
            r"poses/07\.txt:4: ",
        ),
        (
            lambda d: (d / "sequences/07/velodyne/000005.bin").write_bytes(b"\0" * 40),
            r"000005\.bin: .*multiple of 16",
        ),
    ],
)
def test_cli_bad_odometry_files_stop_with_file_and_line(odo, tmp_path, damage, pattern):
    d = _copy(odo, tmp_path)
    damage(d)
    r = _run(
        "--odometry-dir",
        str(d),
        "--sequence",
        "7",
        "--particles",
        "20",
        "--out",
        str(tmp_path / "out"),
    )
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert __import__("re").search(pattern, r.stderr), r.stderr


def test_cli_odometry_options_go_together(odo, tmp_path):
    r = _run("--odometry-dir", str(odo), "--out", str(tmp_path / "o"))
    assert r.returncode == 1 and "--odometry-dir and --sequence" in r.stderr
    r = _run(
        "--odometry-dir",
        str(odo),
        "--sequence",
        "7",
        "--basedir",
        str(odo),
        "--date",
        "x",
        "--drive",
        "1",
        "--out",
        str(tmp_path / "o"),
    )
    assert r.returncode == 1 and "not both" in r.stderr


def test_synth_command_writes_the_odometry_layout(tmp_path):
    from slamlib.cli import main

    assert (
        main(
            [
                "synth",
                "--out",
                str(tmp_path),
                "--layout",
                "odometry",
                "--route",
                "07",
                "--frames",
                "0:6",
                "--columns",
                "300",
                "--no-progress",
            ]
        )
        == 0
    )
    seq = KittiOdometrySequence(tmp_path, 7)
    assert len(seq) == 6 and seq.ground_truth.shape == (6, 4, 4)
    with pytest.raises(SystemExit, match="--no-scans does not go with --layout odometry"):
        main(["synth", "--out", str(tmp_path), "--layout", "odometry", "--no-scans"])
    with pytest.raises(SystemExit, match="--sequence goes with --layout odometry"):
        main(["synth", "--out", str(tmp_path), "--sequence", "3"])
    (tmp_path / "sequences" / "02").mkdir()
    (tmp_path / "sequences" / "02" / "mine.txt").write_text("x")
    with pytest.raises(SystemExit, match="not a slamlib synthetic drive"):
        main(
            [
                "synth",
                "--out",
                str(tmp_path),
                "--layout",
                "odometry",
                "--route",
                "loop",
                "--frames",
                "3",
                "--sequence",
                "2",
                "--no-progress",
            ]
        )


def test_own_motion_window_and_damping():
    """LIDAR-only step 3 holds the twist over the last cv_window frames, times cv_damping per component."""
    from slamlib.slam3d.stages import held_twist

    damping = (1, 1, 0.5, 0, 0, 1)

    def own_motion(poses, dts):
        return held_twist(poses, dts, 2, damping)

    assert all(np.all(x == 0) for x in own_motion([], []))  # nothing known yet: at rest
    assert all(np.all(x == 0) for x in own_motion([np.eye(4)], [0.0]))
    steps_ = [
        make_pose(
            rpy_to_matrix(np.array([0.0, 0.0, 0.1 * k])),
            np.array([1.0 * k, 0.0, 0.2 * k]),
        )
        for k in range(3)
    ]
    v1, w1 = own_motion(
        steps_[:2], [0.0, 0.1]
    )  # one frame known: the window shrinks to it
    v_ref, w_ref = twist_between(steps_[0], steps_[1], 0.1)
    np.testing.assert_allclose(v1, v_ref * [1, 1, 0.5])
    np.testing.assert_allclose(w1, w_ref * [0, 0, 1])
    v2, w2 = own_motion(steps_, [0.0, 0.1, 0.1])
    v_ref, w_ref = twist_between(steps_[0], steps_[2], 0.2)
    np.testing.assert_allclose(v2, v_ref * [1, 1, 0.5])
    np.testing.assert_allclose(w2, w_ref * [0, 0, 1])
    with pytest.raises(ValueError, match="cv_damping must be 6 numbers in"):
        SLAM3DConfig.of(cv_damping=(1, 1, 1, 1, 1, 2))
    with pytest.raises(ValueError, match="cv_window must be in"):
        SLAM3DConfig.of(cv_window=0)
