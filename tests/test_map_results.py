"""Tests of the map-results helpers: the map-building video (slamlib.experiments.video, ``slamlib run --video``) and
the 3D map render (slamlib.experiments.render), on a tiny synthetic drive."""

from __future__ import annotations

import numpy as np
import pytest

from slamlib.experiments.render import (
    offscreen_available,
    render_map_3d,
    scale_bar_length,
)
from slamlib.experiments.video import (
    PLAYER_CONTROLS_PX,
    check_video_path,
    snapshot_every_for,
    write_map_video,
)
from slamlib.kitti import KittiRawDrive
from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive
from slamlib.slam3d import SLAM3DConfig, run_drive


@pytest.fixture(scope="module")
def tiny_drive(tmp_path_factory):
    from slamlib.synth import Hdl64, write_drive

    base = tmp_path_factory.mktemp("kitti")
    return write_drive(
        base,
        route="07",
        frames=(0, 12),
        seed=1,
        lidar=Hdl64(columns=500, beam_stride=2),
        progress=False,
    )


@pytest.fixture(scope="module")
def tiny_run(tiny_drive):
    base, date, drive = tiny_drive
    cfg = SLAM3DConfig.of(particles=40, scored_points=200, seed=2)
    return run_drive(
        KittiRawDrive(base, date, drive), cfg, progress=False, snapshot_every=2
    )


def count_video_frames(path) -> int:
    if str(path).endswith(".gif"):
        from PIL import Image

        with Image.open(path) as im:
            return im.n_frames
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    frames = list(reader)
    assert meta["size"] == (320, 240)
    assert all(len(f) == 320 * 240 * 3 for f in frames)
    return len(frames)


@pytest.mark.parametrize("name", ["map.mp4", "map.gif"])
def test_write_map_video_has_one_frame_per_snapshot(tiny_run, tmp_path, name):
    assert len(tiny_run.snapshots) == 6  # 12 frames, every 2nd
    info = write_map_video(
        tiny_run, tmp_path / name, fps=5, size=(320, 240), progress=False
    )
    assert info["frames"] == 6 and info["bytes"] > 1000 and info["size"] == (320, 240)
    assert count_video_frames(tmp_path / name) == 6


def test_video_frames_show_the_map_growing(tiny_run):
    from slamlib.experiments.video import map_video_frames

    frames = list(
        map_video_frames(
            tiny_run.snapshots, tiny_run.poses, tiny_run.ground_truth, size=(320, 240)
        )
    )
    assert (
        len(frames) == 6
        and frames[0].shape == (240, 320, 3)
        and frames[0].dtype == np.uint8
    )
    assert not np.array_equal(frames[0], frames[-1])
    controls = frames[0][-PLAYER_CONTROLS_PX:]
    assert np.all(
        controls == 255
    )  # nothing under a browser's video controls: the x label is above them


def test_video_rejects_unknown_extension_and_runs_without_snapshots(tiny_run, tmp_path):
    with pytest.raises(ValueError, match=r"\.mp4 or \.gif"):
        write_map_video(tiny_run, tmp_path / "map.avi")
    with pytest.raises(ValueError, match="no extension"):
        check_video_path(tmp_path / "map")
    assert not (tmp_path / "map.avi").exists()
    empty = type(tiny_run)(**{**tiny_run.__dict__, "snapshots": []})
    with pytest.raises(ValueError, match="snapshot_every"):
        write_map_video(empty, tmp_path / "map.mp4")


def test_video_names_the_missing_package(monkeypatch, tmp_path):
    import builtins

    real_import = builtins.__import__

    def no_ffmpeg(name, *args, **kw):
        if name == "imageio_ffmpeg":
            raise ImportError("No module named 'imageio_ffmpeg'")
        return real_import(name, *args, **kw)

    monkeypatch.setattr(builtins, "__import__", no_ffmpeg)
    with pytest.raises(ImportError, match="pip install imageio-ffmpeg"):
        check_video_path(tmp_path / "map.mp4")


def test_snapshot_every_for():
    assert (
        snapshot_every_for(10) == 1
        and snapshot_every_for(300, 100) == 3
        and snapshot_every_for(301, 100) == 4
    )


def test_slamlib_run_video_end_to_end(tiny_drive, tmp_path):
    from slamlib.cli import main

    base, date, drive = tiny_drive
    out, video = tmp_path / "out", tmp_path / "v" / "map.mp4"
    rc = main(
        [
            "run",
            "--basedir",
            str(base),
            "--date",
            date,
            "--drive",
            str(drive),
            "--frames",
            "1:11",
            "--particles",
            "40",
            "--points",
            "200",
            "--out",
            str(out),
            "--no-progress",
            "--no-plots",
            "--video",
            str(video),
        ]
    )
    assert rc == 0 and (out / "slam_poses.txt").exists()
    import imageio_ffmpeg

    n, secs = imageio_ffmpeg.count_frames_and_secs(str(video))
    assert n == 10 and secs > 0  # one video frame per SLAM frame for a short run


def test_slamlib_run_video_bad_extension_fails_before_running(tiny_drive, tmp_path):
    from slamlib.cli import main

    base, date, drive = tiny_drive
    with pytest.raises(SystemExit, match=r"\.mp4 or \.gif"):
        main(
            [
                "run",
                "--basedir",
                str(base),
                "--date",
                date,
                "--drive",
                str(drive),
                "--out",
                str(tmp_path / "o"),
                "--no-progress",
                "--video",
                str(tmp_path / "map.webm"),
            ]
        )
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("engine", ["open3d", "matplotlib"])
def test_render_map_3d_returns_an_image_of_the_requested_size(tiny_run, engine):
    if engine == "open3d" and not offscreen_available():
        pytest.skip(
            "open3d OffscreenRenderer is unavailable here (no EGL/Vulkan driver); matplotlib is the fallback"
        )
    pts = tiny_run.slam.map_points()
    img = render_map_3d(pts, tiny_run.poses, size=(200, 120), engine=engine)
    assert img.shape == (120, 200, 3) and img.dtype == np.uint8
    background = np.all(img == 255, axis=2)
    assert 0.02 < 1 - background.mean() < 0.98  # something was drawn, not everything
    no_path = render_map_3d(pts, None, size=(200, 120), engine=engine)
    assert np.any(np.any(img != no_path, axis=2))  # the trajectory is drawn
    assert np.any(
        np.all(img < 40, axis=2)
    )  # the black scale bar (the height colours are never black)


def test_the_scale_bar_is_a_round_length_of_at_most_a_quarter_of_the_map():
    span = lambda metres: np.c_[np.linspace(0, metres, 5), np.zeros(5), np.zeros(5)]  # noqa: E731
    assert scale_bar_length(span(692.0)) == 100.0
    assert scale_bar_length(span(199.0)) == 20.0
    assert scale_bar_length(span(200.0)) == 50.0
    assert scale_bar_length(span(1.0)) == 1.0  # the shortest, however small the map


def test_render_map_3d_rejects_bad_input():
    with pytest.raises(ValueError, match="engine"):
        render_map_3d(np.zeros((3, 3)), engine="vtk")
    with pytest.raises(ValueError, match="no map points"):
        render_map_3d(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="16 x 16"):
        render_map_3d(np.ones((5, 3)), size=(8, 8))


# ----------------------------------------------------------- --video where it would lose a file, refused before the run
def test_slamlib_run_video_under_a_file_is_refused_before_the_run(cli_drive, tmp_path):
    from slamlib.cli import main

    args, _ = cli_drive
    (tmp_path / "a-file").write_text("mine\n")
    with pytest.raises(SystemExit) as exc:
        main(
            args
            + [
                "--out",
                str(tmp_path / "o"),
                "--video",
                str(tmp_path / "a-file" / "x.mp4"),
            ]
        )
    assert "--video" in str(exc.value) and not (tmp_path / "o").exists()


# ------------------------------------------------------------------ an existing video is replaced only with --overwrite
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
