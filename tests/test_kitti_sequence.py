"""The KITTI odometry layout (:mod:`slamlib.kitti.sequence`: the reader, the synthetic writer,
``slamlib run --odometry-dir``) and LIDAR-only SLAM on it (step 3 from the filter's own constant-velocity
estimate); the reader's exact values and whole messages on hand-written sequences."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys

import numpy as np
import pytest

from slamlib.errors import DataFormatError
from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.kitti import KittiOdometrySequence, KittiRawDrive
from slamlib.kitti.sequence import sequence_name
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
    # world = Velodyne at frame 0, as the odometry ground truth
    G = np.linalg.inv(G[0])[None] @ G
    # 12 printed digits in poses/07.txt
    assert np.abs(seq.ground_truth_poses() - G).max() < 1e-6
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
    # the older, longer sequence's scans were the generator's: gone
    assert len(KittiOdometrySequence(d, 7)) == 6
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
    motion = ConstantVelocity(MotionConfig(), 100)
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
    cv = m.constant_velocity
    np.testing.assert_allclose(extra, np.r_[cv.accel, cv.angular_accel] * dt**2)
    with pytest.raises(ValueError, match="model must be one of"):
        MotionConfig(model="wheel")
    assert (
        m.scaled(2.0).constant_velocity.accel == tuple(2 * a for a in cv.accel)
        and m.scaled(2.0).model == "imu"
    )


@pytest.mark.parametrize("start_line", [False, True])
def test_lidar_only_run_follows_a_constant_velocity_street(tmp_path, start_line):
    """On the straight route (10 m/s) the constant-velocity model is exact after two frames: LIDAR-only SLAM must
    follow the ground truth closely, and it must do better than holding still (what the first frame predicts). With
    the start's line too: on this street, its walls along the car, the scan's own rings score no motion above the
    true motion, and the line's search ends there (``slamlib.slam3d.stages.search``, "The start's line")."""
    write_sequence(tmp_path, "straight", 0, frames=20, seed=3, lidar=FAST, progress=False)
    seq = KittiOdometrySequence(tmp_path, 0)
    config = SLAM3DConfig.of(
        particles=100, **{"constant_velocity.start_line": start_line}
    )
    run = run_drive(seq, config, progress=False)
    assert run.slam.lidar_only and run.dead_reckoning is None
    m = evaluate(run)
    assert "dead_reckoning" not in m
    travelled = np.linalg.norm(run.ground_truth[-1, :3, 3])
    assert travelled > 15
    assert m["slam"]["ate_rmse_m"] < 0.02 * travelled, m["slam"]
    # the drawn search found the true motion: the line's search, ending at no motion, is not kept
    assert run.n_start_lines_kept == 0


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
    # LIDAR-only, every frame after the first is scan-matched by default; --scan-match off turns it off
    assert (
        info["config"]["polish"]["scan_match"] == "auto"
        and info["n_matched_frames"] == N - 1
    )
    # the gate: none rejected on a short clean drive, the largest kept correction within it
    assert info["n_match_rejected_frames"] == 0
    assert 0 < info["match_max_kept_distance"] <= info["config"]["polish"]["match_gate"]
    assert info["n_start_lines_kept"] == 0  # a slow start: the drawn search kept
    r = _run(
        "--odometry-dir",
        str(odo),
        "--sequence",
        "07",
        "--particles",
        "50",
        "--frames",
        "0:4",
        "--scan-match",
        "off",
        "--out",
        str(tmp_path / "off"),
    )
    assert r.returncode == 0, r.stderr
    info = json.loads((tmp_path / "off" / "metrics.json").read_text())
    assert (
        info["config"]["polish"]["scan_match"] is False and info["n_matched_frames"] == 0
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
    # one frame known: the window shrinks to it
    v1, w1 = own_motion(steps_[:2], [0.0, 0.1])
    v_ref, w_ref = twist_between(steps_[0], steps_[1], 0.1)
    np.testing.assert_allclose(v1, v_ref * [1, 1, 0.5])
    np.testing.assert_allclose(w1, w_ref * [0, 0, 1])
    v2, w2 = own_motion(steps_, [0.0, 0.1, 0.1])
    v_ref, w_ref = twist_between(steps_[0], steps_[2], 0.2)
    np.testing.assert_allclose(v2, v_ref * [1, 1, 0.5])
    np.testing.assert_allclose(w2, w_ref * [0, 0, 1])
    with pytest.raises(ValueError, match="damping must be 6 numbers in"):
        SLAM3DConfig.of(constant_velocity={"damping": (1, 1, 1, 1, 1, 2)})
    with pytest.raises(ValueError, match="window must be in"):
        SLAM3DConfig.of(**{"constant_velocity.window": 0})


# ------------------------------------------------------------------ the reader on hand-written sequences
# A rotation of 90 degrees about z and a 1 m / 2 m / 3 m offset: a valid, non-trivial calibration Tr.
TR = np.array([[0.0, -1.0, 0.0, 1.0], [1.0, 0.0, 0.0, 2.0], [0.0, 0.0, 1.0, 3.0]])
TIMES = [0.0, 0.25, 0.75]


def _line(values):
    return " ".join(repr(float(v)) for v in np.ravel(values))


def _scan(i):
    """Two points whose values encode the frame number ``i``."""
    return (np.arange(8, dtype=np.float32).reshape(2, 4) + 10 * i).astype(np.float32)


def _pose(k):
    """Camera pose ``k``: a turn of ``0.1 k`` rad about z and a translation ``(k, k / 2, 0)`` m."""
    c, s = math.cos(0.1 * k), math.sin(0.1 * k)
    return np.array([[c, -s, 0.0, float(k)], [s, c, 0.0, 0.5 * k], [0.0, 0.0, 1.0, 0.0]])


def _make_sequence(base, seq="04", times=TIMES, tr=TR, poses=True, scans=None):
    """Write ``base/sequences/<seq>`` by hand: calib.txt (P0..P3, Tr), times.txt, velodyne/*.bin, poses."""
    d = base / "sequences" / seq
    (d / "velodyne").mkdir(parents=True)
    p = _line(np.hstack([np.eye(3), np.zeros((3, 1))]))
    (d / "calib.txt").write_text(
        "".join(f"P{i}: {p}\n" for i in range(4)) + f"Tr: {_line(tr)}\n"
    )
    (d / "times.txt").write_text("".join(f"{t!r}\n" for t in times))
    for i in range(len(times) if scans is None else scans):
        _scan(i).astype("<f4").tofile(d / "velodyne" / f"{i:06d}.bin")
    if poses:
        (base / "poses").mkdir(exist_ok=True)
        (base / "poses" / f"{seq}.txt").write_text(
            "".join(_line(_pose(k)) + "\n" for k in range(len(times)))
        )
    return d


def _tr4():
    T = np.eye(4)
    T[:3] = TR
    return T


@pytest.fixture
def base(tmp_path):
    _make_sequence(tmp_path)
    return tmp_path


def _err(fn, exc=DataFormatError):
    with pytest.raises(exc) as info:
        fn()
    return info.value


# ------------------------------------------------------------------ sequence_name
def test_sequence_name_error_message_is_whole():
    """A non-numeric sequence is refused with the message naming the value (repr)."""
    assert (
        str(_err(lambda: sequence_name("x7"), ValueError))
        == "sequence must be a number like 07, got 'x7'"
    )


# ------------------------------------------------------------------ opening
def test_values_read_at_open(base):
    """calib, Tr (4x4), times and the ground truth inv(Tr) P_k Tr of a hand-written sequence."""
    seq = KittiOdometrySequence(base, 4)
    np.testing.assert_array_equal(seq.calib["Tr"], TR.ravel())
    np.testing.assert_array_equal(seq.Tr, _tr4())
    np.testing.assert_array_equal(seq.times, TIMES)
    assert seq.poses_path == base / "poses" / "04.txt"
    for k in range(3):
        P = np.eye(4)
        P[:3] = _pose(k)
        np.testing.assert_allclose(
            seq.ground_truth[k], np.linalg.inv(_tr4()) @ P @ _tr4(), atol=1e-12
        )


def test_missing_sequence_folder_lists_the_sequences_there(tmp_path):
    """The message lists only the numbered folders under sequences/ (not files, not other names), sorted."""
    for name in ("11", "03", "abc"):
        (tmp_path / "sequences" / name).mkdir(parents=True)
    (tmp_path / "sequences" / "05").write_text("")
    err = _err(lambda: KittiOdometrySequence(tmp_path, 7))
    path = tmp_path / "sequences" / "07"
    assert str(err) == (
        f"{path}: KITTI odometry sequence folder not found (expected basedir/sequences/NN); "
        "sequences there: 03, 11"
    )
    assert err.path == str(path)


def test_missing_sequences_folder_says_none(tmp_path):
    """Without a sequences/ folder the list reads ``none``."""
    err = _err(lambda: KittiOdometrySequence(tmp_path, "00"))
    assert str(err) == (
        f"{tmp_path / 'sequences' / '00'}: KITTI odometry sequence folder not found (expected "
        "basedir/sequences/NN); sequences there: none"
    )


def test_tr_offset_too_far_names_tr_offset(tmp_path):
    """A Tr translation over 100 m is refused, the message calling it Tr's offset."""
    tr = TR.copy()
    tr[:, 3] = [200.0, 0.0, 0.0]
    d = _make_sequence(tmp_path, tr=tr)
    err = _err(lambda: KittiOdometrySequence(tmp_path, 4))
    assert str(err) == (
        f"{d / 'calib.txt'}: calibration Tr's offset = [200.0, 0.0, 0.0] m is farther than 100 m: "
        "not an offset between two sensors of one vehicle"
    )


def test_missing_times_file_message(base):
    """No times.txt: the whole message, naming the file."""
    times = base / "sequences" / "04" / "times.txt"
    times.unlink()
    assert str(_err(lambda: KittiOdometrySequence(base, 4))) == (
        f"{times}: times file not found (one time in seconds per frame; the odometry layout needs it for the "
        "frame intervals)"
    )


def test_empty_times_file_has_no_frames(base):
    """An empty times.txt: DataFormatError naming it (path attribute too), no line."""
    times = base / "sequences" / "04" / "times.txt"
    times.write_text("")
    err = _err(lambda: KittiOdometrySequence(base, 4))
    assert str(err) == f"{times}: holds no times: the sequence has no frames"
    assert err.path == str(times) and err.line is None


def test_one_frame_sequence_opens(tmp_path):
    """One time, one scan, one pose: a valid 1-frame sequence (the lower bound)."""
    _make_sequence(tmp_path, times=[0.5])
    seq = KittiOdometrySequence(tmp_path, 4)
    assert len(seq) == 1 and seq[0].time_s == 0.5 and seq[0].dt == 0.0
    np.testing.assert_array_equal(seq[0].scan, _scan(0))


def test_missing_scan_message(tmp_path):
    """Fewer scans than times: the message says what is missing against what."""
    d = _make_sequence(tmp_path, scans=2)
    assert str(_err(lambda: KittiOdometrySequence(tmp_path, 4))) == (
        f"{d / 'velodyne'}: fewer Velodyne scans than the 3 times in times.txt: 1 of 3 missing "
        "(first: 000002.bin; files are numbered 000000.bin upwards)"
    )


def test_missing_velodyne_folder_message(base):
    """No velodyne/ folder: the message names the folder and what it should hold."""
    d = base / "sequences" / "04" / "velodyne"
    for f in d.iterdir():
        f.unlink()
    d.rmdir()
    assert str(_err(lambda: KittiOdometrySequence(base, 4))) == (
        f"{d}: folder of Velodyne scans not found (needed for 3 frames)"
    )


def test_explicit_poses_file_is_read(base, tmp_path):
    """``poses=`` reads that file, not basedir/poses/NN.txt."""
    other = tmp_path / "gt.txt"
    P = np.eye(4)
    P[:3, 3] = [5.0, 6.0, 7.0]
    other.write_text("".join(_line(P[:3]) + "\n" for _ in range(3)))
    seq = KittiOdometrySequence(base, 4, poses=other)
    assert seq.poses_path == other
    np.testing.assert_allclose(
        seq.ground_truth[1], np.linalg.inv(_tr4()) @ P @ _tr4(), atol=1e-12
    )


def test_explicit_missing_poses_file_is_an_error(base, tmp_path):
    """An explicit poses file that does not exist is an error naming it, not silently no ground truth."""
    err = _err(lambda: KittiOdometrySequence(base, 4, poses=tmp_path / "nope.txt"))
    assert err.path == str(tmp_path / "nope.txt")


def test_poses_rotation_is_checked(base):
    """A pose whose 3x3 block is not a rotation is refused at open (check_rotation)."""
    bad = _pose(1)
    bad[0, 0] = 2.0
    f = base / "poses" / "04.txt"
    f.write_text(_line(_pose(0)) + "\n" + _line(bad) + "\n" + _line(_pose(2)) + "\n")
    err = _err(lambda: KittiOdometrySequence(base, 4))
    assert err.path == str(f) and err.line == 2


def test_no_poses_file_means_no_ground_truth(tmp_path):
    """Without poses/NN.txt: poses_path and ground_truth None, frames without T_w_body, a clear ValueError."""
    _make_sequence(tmp_path, poses=False)
    seq = KittiOdometrySequence(tmp_path, 4)
    assert seq.poses_path is None and seq.ground_truth is None
    assert seq[1].T_w_body is None
    err = _err(seq.ground_truth_poses, ValueError)
    assert (
        str(err)
        == f"{tmp_path / 'sequences' / '04'} has no ground truth ({tmp_path / 'poses' / '04'}.txt)"
    )


# ------------------------------------------------------------------ frames
def test_frame_values(base):
    """index, time_s, dt against the previous selected frame, scan, T_w_body and the scan path."""
    seq = KittiOdometrySequence(base, 4, frames=[0, 2])
    f = seq[1]
    assert f.index == 2 and f.time_s == 0.75 and f.dt == 0.75
    assert f.velodyne_path == base / "sequences" / "04" / "velodyne" / "000002.bin"
    np.testing.assert_array_equal(f.scan, _scan(2))
    np.testing.assert_array_equal(f.T_w_body, seq.ground_truth[2])
    assert (
        repr(seq)
        == f"KittiOdometrySequence({str(base / 'sequences' / '04')!r}, 2 of 3 frames)"
    )


def test_getitem_bounds(base):
    """Positions -n..n-1 are valid (-n is the first), n and -n-1 raise IndexError with the whole message."""
    seq = KittiOdometrySequence(base, 4)
    assert seq[-3].index == 0 and seq[2].index == 2
    assert (
        str(_err(lambda: seq[3], IndexError))
        == "frame position 3 out of range for 3 frames"
    )
    assert (
        str(_err(lambda: seq[-4], IndexError))
        == "frame position -4 out of range for 3 frames"
    )


def test_progress_bar_only_when_asked(base, capsys):
    """progress=True draws a transient 'frames' bar counting 'frame' units on stderr; the default draws none."""
    assert [f.index for f in KittiOdometrySequence(base, 4)] == [0, 1, 2]
    assert capsys.readouterr().err == ""
    assert [f.index for f in KittiOdometrySequence(base, 4, progress=True)] == [0, 1, 2]
    err = capsys.readouterr().err
    assert err.startswith("\rframes:   0%|") and " 0/3 " in err and "frame/s]" in err
    # leave=False: the bar is cleared, not left on its own line
    assert not err.endswith("\n")


def test_readers_refuse_incomplete_data_unless_allowed(odo, tmp_path):
    """A sequence with synth's in-progress marker, with a scan beyond its times (``times.txt`` one line short),
    or beside ground truth that is not the one it was written with: an error naming the file, unless
    ``allow_incomplete`` (not for the ground truth)."""
    from slamlib.kitti.velodyne import SYNTH_PARTIAL_MARKER

    d = _copy(odo, tmp_path)
    sdir = d / "sequences/07"
    (sdir / SYNTH_PARTIAL_MARKER).write_text("{}")
    with pytest.raises(DataFormatError) as err:
        KittiOdometrySequence(d, 7)
    assert str(err.value) == (
        f"{sdir / SYNTH_PARTIAL_MARKER}: this folder was left half written by an interrupted slamlib synth "
        "(it holds this marker); write it again with slamlib synth, or read the frames it has with "
        "--allow-incomplete"
    )
    assert len(KittiOdometrySequence(d, 7, allow_incomplete=True)) == N
    (sdir / SYNTH_PARTIAL_MARKER).unlink()
    times = (sdir / "times.txt").read_text().splitlines()
    (sdir / "times.txt").write_text("\n".join(times[:-1]) + "\n")
    with pytest.raises(DataFormatError) as err:
        KittiOdometrySequence(d, 7)
    assert str(err.value) == (
        f"{sdir / 'times.txt'}: times {N - 1} frames, but {sdir / 'velodyne'} holds {N} Velodyne scans "
        f"({N - 1:06d}.bin onwards have no time): one line is missing, or pass --allow-incomplete to read "
        f"the first {N - 1}"
    )
    assert len(KittiOdometrySequence(d, 7, allow_incomplete=True)) == N - 1
    (sdir / "times.txt").write_text("\n".join(times) + "\n")
    poses = d / "poses/07.txt"
    rows = poses.read_text().splitlines()
    rows[2] = rows[1]  # still a valid pose file, but not this sequence's
    poses.write_text("\n".join(rows) + "\n")
    with pytest.raises(
        DataFormatError, match=r"07\.txt: is not the ground truth .* SHA-1"
    ):
        KittiOdometrySequence(d, 7)
    # a ground truth the user names is theirs to choose
    assert KittiOdometrySequence(d, 7, poses=poses).ground_truth.shape == (N, 4, 4)
