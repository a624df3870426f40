"""Issue 13, "no user file is lost": slamlib run --video, and slamlib synth / write_drive over existing folders.

Each test failed before its fix."""

from __future__ import annotations

import json

import pytest

from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive


@pytest.fixture
def run_args(tmp_path):
    d = make_tiny_drive(tmp_path / "kitti", n_frames=3, point_stride=500)
    return [
        "run",
        "--basedir",
        str(d.parent.parent),
        "--date",
        SAMPLE_DATE,
        "--drive",
        SAMPLE_DRIVE,
        "--no-progress",
        "--no-plots",
        "--particles",
        "8",
        "--points",
        "30",
        "--backend",
        "numpy",
    ]


def test_slamlib_run_refuses_an_existing_video_file_before_the_run(
    run_args, tmp_path, monkeypatch
):
    pytest.importorskip("PIL")
    import slamlib.slam3d
    from slamlib.cli import main

    monkeypatch.setattr(
        slamlib.slam3d, "run_drive", lambda *a, **k: pytest.fail("the run started")
    )
    video = tmp_path / "mine.gif"
    video.write_bytes(b"GIF89a my holiday")
    with pytest.raises(SystemExit) as exc:
        main(run_args + ["--out", str(tmp_path / "o"), "--video", str(video)])
    msg = str(exc.value)
    assert (
        msg.startswith("slamlib run: --video: ")
        and "--overwrite" in msg
        and "\n" not in msg
    ), msg
    assert video.read_bytes() == b"GIF89a my holiday"


def test_slamlib_run_replaces_an_existing_video_with_overwrite(run_args, tmp_path):
    pytest.importorskip("PIL")
    from slamlib.cli import main

    video = tmp_path / "mine.gif"
    video.write_bytes(b"old")
    assert (
        main(
            run_args
            + ["--out", str(tmp_path / "o"), "--video", str(video), "--overwrite"]
        )
        == 0
    )
    assert video.read_bytes()[:6] in (b"GIF89a", b"GIF87a")


def test_slamlib_run_refuses_a_folder_as_video(run_args, tmp_path, monkeypatch):
    pytest.importorskip("PIL")
    import slamlib.slam3d
    from slamlib.cli import main

    monkeypatch.setattr(
        slamlib.slam3d, "run_drive", lambda *a, **k: pytest.fail("the run started")
    )
    (tmp_path / "v.gif").mkdir()
    with pytest.raises(SystemExit, match="--video: .*is a folder"):
        main(
            run_args
            + [
                "--out",
                str(tmp_path / "o"),
                "--video",
                str(tmp_path / "v.gif"),
                "--overwrite",
            ]
        )


# ------------------------------------------------------------------------------------------ synth


def _write(base, frames=3, seed=0, **kw):
    from slamlib.synth import Hdl64, write_drive

    return write_drive(
        base,
        "loop",
        frames=frames,
        seed=seed,
        lidar=Hdl64(columns=100),
        progress=False,
        **kw,
    )


def _drive_files(ddir):
    return {
        str(p.relative_to(ddir)): p.read_bytes()
        for p in sorted(ddir.rglob("*"))
        if p.is_file()
    }


def test_write_drive_refuses_a_folder_that_is_not_synthetic(tmp_path):
    from slamlib.synth.writer import drive_dir

    ddir = drive_dir(tmp_path, "2011_09_26", 1)
    ddir.mkdir(parents=True)
    (ddir / "real.bin").write_bytes(b"real data")
    with pytest.raises(FileExistsError, match="not a slamlib synthetic drive"):
        _write(tmp_path)
    assert [p.name for p in ddir.iterdir()] == ["real.bin"] and not (
        tmp_path / "2011_09_26" / "calib_imu_to_velo.txt"
    ).exists()


def test_write_drive_refuses_differing_calibration_before_writing(tmp_path):
    from slamlib.synth.writer import drive_dir

    (tmp_path / "2011_09_26").mkdir()
    calib = tmp_path / "2011_09_26" / "calib_imu_to_velo.txt"
    calib.write_text("R: 1 0 0 0 1 0 0 0 1\nT: 0 0 0\n")
    with pytest.raises(FileExistsError, match="differs"):
        _write(tmp_path)
    assert (
        calib.read_text().startswith("R: 1 0 0")
        and not drive_dir(tmp_path, "2011_09_26", 1).exists()
    )


def test_write_drive_into_an_empty_folder(tmp_path):
    from slamlib.synth.writer import MARKER, drive_dir

    drive_dir(tmp_path, "2011_09_26", 1).mkdir(parents=True)
    _write(tmp_path)
    assert (drive_dir(tmp_path, "2011_09_26", 1) / MARKER).is_file()


def test_rewriting_a_synthetic_drive_keeps_the_users_files_and_drops_stale_frames(
    tmp_path,
):
    from slamlib.kitti import KittiRawDrive
    from slamlib.synth.writer import MARKER, PARTIAL_MARKER, drive_dir

    _write(tmp_path, frames=5)
    ddir = drive_dir(tmp_path, "2011_09_26", 1)
    (ddir / "notes.txt").write_text("my notes")
    (ddir / "out").mkdir()
    (ddir / "out" / "slam_poses.txt").write_text("my run")
    (ddir / "oxts" / "README").write_text("mine too")
    _write(tmp_path, frames=3, seed=1)
    assert (ddir / "notes.txt").read_text() == "my notes" and (
        ddir / "out" / "slam_poses.txt"
    ).read_text() == "my run"
    assert (ddir / "oxts" / "README").read_text() == "mine too"
    assert (
        json.loads((ddir / MARKER).read_text())["seed"] == 1
        and not (ddir / PARTIAL_MARKER).exists()
    )
    assert (
        len(KittiRawDrive(tmp_path, "2011_09_26", 1)) == 3
    )  # frames 3 and 4 of the first drive are gone
    fresh = tmp_path / "fresh"
    _write(fresh, frames=3, seed=1)
    mine = {
        k: v
        for k, v in _drive_files(ddir).items()
        if k not in ("notes.txt", "out/slam_poses.txt", "oxts/README")
    }
    assert mine == _drive_files(drive_dir(fresh, "2011_09_26", 1))


class _Interrupt(BaseException):
    pass


def test_an_interrupted_drive_is_redone_by_the_next_synth(tmp_path, monkeypatch):
    import slamlib.synth.drive
    from slamlib.cli import main
    from slamlib.synth.writer import MARKER, PARTIAL_MARKER, drive_dir, write_scan

    calls = []

    def write_two_then_stop(*a, **k):
        if len(calls) == 2:
            raise _Interrupt
        calls.append(1)
        write_scan(*a, **k)

    args = [
        "synth",
        "--out",
        str(tmp_path / "o"),
        "--route",
        "loop",
        "--frames",
        "4",
        "--columns",
        "100",
        "--no-progress",
    ]
    with monkeypatch.context() as mp:
        mp.setattr(slamlib.synth.drive, "write_scan", write_two_then_stop)
        with pytest.raises(_Interrupt):
            main(args)
    ddir = drive_dir(tmp_path / "o", "2011_09_26", 1)
    assert (ddir / PARTIAL_MARKER).is_file() and not (ddir / MARKER).exists()
    (ddir / "notes.txt").write_text("my notes")
    assert main(args) == 0  # before: "not a slamlib synthetic drive"
    assert (ddir / MARKER).is_file() and not (ddir / PARTIAL_MARKER).exists()
    assert (ddir / "notes.txt").read_text() == "my notes"
    assert main(args[:2] + [str(tmp_path / "fresh")] + args[3:]) == 0
    mine = _drive_files(ddir)
    del mine["notes.txt"]
    assert mine == _drive_files(drive_dir(tmp_path / "fresh", "2011_09_26", 1))
