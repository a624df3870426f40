"""Whole drives and their results (:mod:`slamlib.slam3d.run`): ``run_drive``, the frame selection of ``--frames``,
the output folder (``check_output_dir``) and ``save_run``, which writes the results whole or not at all."""

import numpy as np
import pytest
from world3d import tiny_config

from slamlib.metrics import absolute_trajectory_error
from slamlib.slam3d import parse_frames, run_drive


def test_refine_and_bvh_map_also_track(drive):
    frames, gt = drive
    run = run_drive(
        frames[:15],
        tiny_config(kind="morton_bvh", anneal_rounds=1, pose_estimate="mean"),
        progress=False,
    )
    assert run.ground_truth is not None and np.allclose(run.ground_truth, gt[:15])
    ate_slam = absolute_trajectory_error(run.poses, run.ground_truth).rmse
    ate_dr = absolute_trajectory_error(run.dead_reckoning, run.ground_truth).rmse
    assert ate_slam < ate_dr / 2


def test_parse_frames():
    assert parse_frames("10:20") == slice(10, 20)
    assert parse_frames("5:") == slice(5, None)
    assert parse_frames("30") == slice(0, 30)
    assert parse_frames(None) is None
    for bad in ("a:b", "20:10", "-3:5"):
        with pytest.raises(ValueError):
            parse_frames(bad)
    with pytest.raises(ValueError):
        parse_frames("100:200", n=50)


# -------------------------------------------------- the output folder: the user's files kept, the results written whole
def test_check_output_dir_keeps_user_files_unless_overwrite(tmp_path):
    from slamlib.slam3d.run import check_output_dir

    out = tmp_path / "o"
    check_output_dir(out)  # a new folder
    out.mkdir()
    check_output_dir(out)  # an empty one
    (out / "notes.txt").write_text("mine")
    with pytest.raises(
        ValueError,
        match=r"is not empty \(notes.txt\) and is not an earlier slamlib run's.*--overwrite",
    ):
        check_output_dir(out)  # a folder of the user's: refused, though no name clashes
    check_output_dir(out, overwrite=True)
    (out / "slam_poses.txt").write_text("mine")
    with pytest.raises(
        ValueError, match="slam_poses.txt, not from an earlier slamlib run.*--overwrite"
    ):
        check_output_dir(out)
    check_output_dir(out, overwrite=True)
    (out / "metrics.json").write_text("{not json")
    with pytest.raises(ValueError, match="--overwrite"):
        check_output_dir(out)


def test_save_run_writes_through_a_temporary_folder_and_keeps_other_files(
    cli_drive, tmp_path, monkeypatch
):
    """The results appear whole or not at all: a write that fails midway leaves --out as it was."""
    from slamlib.cli import main
    from slamlib.slam3d import run as run_module

    args, _ = cli_drive
    out = tmp_path / "o"
    assert main(args + ["--out", str(out)]) == 0
    (out / "notes.txt").write_text("mine")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    real = run_module._write_results

    def fail_midway(run, folder, *rest):
        real(run, folder, *rest)
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(run_module, "_write_results", fail_midway)
    with pytest.raises(SystemExit, match="could not write the results.*disk full"):
        main(args + ["--out", str(out)])
    assert {
        p.name: p.read_bytes() for p in out.iterdir()
    } == before  # nothing replaced, notes kept
    assert not [
        p for p in tmp_path.iterdir() if p.name.endswith(".partial")
    ]  # the temporary folder is gone
    monkeypatch.setattr(run_module, "_write_results", real)
    assert main(args + ["--out", str(out), "--map-format", "pcd"]) == 0
    assert (out / "notes.txt").read_text() == "mine" and (out / "map.pcd").is_file()
    assert not (out / "map.ply").exists() and oct(out.stat().st_mode & 0o777) != oct(
        0o700
    )


def test_run_drive_and_save_run_say_what_was_wrong_with_their_arguments(tmp_path):
    from slamlib.slam3d import SLAM3DConfig, run_drive, save_run

    with pytest.raises(
        TypeError, match=r"run_drive takes an iterable of frames .* got NoneType"
    ):
        run_drive(None)
    with pytest.raises(
        TypeError, match=r"run_drive takes frames, not a path \('/a/folder'\): open"
    ):
        run_drive("/a/folder")
    with pytest.raises(TypeError, match=r"run_drive takes frames, not a path"):
        run_drive(tmp_path)
    with pytest.raises(
        TypeError,
        match=r"config must be a SLAM3DConfig, got dict: SLAM3DConfig\.of\(\*\*\{'particles': 10\}\)",
    ):
        run_drive([object()], {"particles": 10})
    with pytest.raises(ValueError, match="run_drive got no frames"):
        run_drive([])
    with pytest.raises(
        TypeError, match="run must be the SLAMRun that run_drive returns, got list"
    ):
        save_run([], tmp_path / "o")
    assert not (tmp_path / "o").exists()
    with pytest.raises(
        ValueError, match=r"backend must be one of 'numpy', 'cpu', 'cuda', got 'gpu'"
    ):
        SLAM3DConfig.of(backend="gpu")


def test_run_drive_takes_the_calibration_from_a_raw_drives_own_frames(open_drive):
    """A list of a raw drive's frames, or a generator over them, runs as the drive does: the first frame's two
    ground-truth poses give ``T_velo_imu`` (not the identity, which would leave the scans in the Velodyne's frame);
    frames without them give None."""
    from types import SimpleNamespace

    from slamlib.slam3d import SLAM3DConfig
    from slamlib.slam3d.run import frames_calibration

    drive = open_drive()
    frames = list(drive)
    assert not np.allclose(drive.T_velo_imu, np.eye(4))
    same, T = frames_calibration(frames)
    assert same is frames
    np.testing.assert_allclose(T, drive.T_velo_imu, atol=1e-12)
    rest, T = frames_calibration(iter(frames))
    assert list(rest) == frames  # the first frame put back
    np.testing.assert_allclose(T, drive.T_velo_imu, atol=1e-12)
    bare = [SimpleNamespace(T_w_imu=np.eye(4))]
    assert frames_calibration(bare) == (bare, None)
    assert list(frames_calibration(iter([]))[0]) == []
    config = SLAM3DConfig.of(particles=10, scored_points=50, seed=0)
    want = run_drive(drive, config, progress=False).poses
    for given in (frames, (f for f in frames)):
        np.testing.assert_array_equal(
            run_drive(given, config, progress=False).poses, want
        )
