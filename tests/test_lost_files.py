"""Issue 13, "no user file is lost": slamlib run --video, and slamlib synth / write_drive over existing folders.

Each test failed before its fix."""

from __future__ import annotations

import pytest

from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive


@pytest.fixture
def run_args(tmp_path):
    d = make_tiny_drive(tmp_path / "kitti", n_frames=3, point_stride=500)
    return ["run", "--basedir", str(d.parent.parent), "--date", SAMPLE_DATE, "--drive", SAMPLE_DRIVE,
            "--no-progress", "--no-plots", "--particles", "8", "--points", "30", "--backend", "numpy"]


def test_slamlib_run_refuses_an_existing_video_file_before_the_run(run_args, tmp_path, monkeypatch):
    pytest.importorskip("PIL")
    import slamlib.slam3d
    from slamlib.cli import main

    monkeypatch.setattr(slamlib.slam3d, "run_drive", lambda *a, **k: pytest.fail("the run started"))
    video = tmp_path / "mine.gif"
    video.write_bytes(b"GIF89a my holiday")
    with pytest.raises(SystemExit) as exc:
        main(run_args + ["--out", str(tmp_path / "o"), "--video", str(video)])
    msg = str(exc.value)
    assert msg.startswith("slamlib run: --video: ") and "--overwrite" in msg and "\n" not in msg, msg
    assert video.read_bytes() == b"GIF89a my holiday"


def test_slamlib_run_replaces_an_existing_video_with_overwrite(run_args, tmp_path):
    pytest.importorskip("PIL")
    from slamlib.cli import main

    video = tmp_path / "mine.gif"
    video.write_bytes(b"old")
    assert main(run_args + ["--out", str(tmp_path / "o"), "--video", str(video), "--overwrite"]) == 0
    assert video.read_bytes()[:6] in (b"GIF89a", b"GIF87a")


def test_slamlib_run_refuses_a_folder_as_video(run_args, tmp_path, monkeypatch):
    pytest.importorskip("PIL")
    import slamlib.slam3d
    from slamlib.cli import main

    monkeypatch.setattr(slamlib.slam3d, "run_drive", lambda *a, **k: pytest.fail("the run started"))
    (tmp_path / "v.gif").mkdir()
    with pytest.raises(SystemExit, match="--video: .*is a folder"):
        main(run_args + ["--out", str(tmp_path / "o"), "--video", str(tmp_path / "v.gif"), "--overwrite"])
