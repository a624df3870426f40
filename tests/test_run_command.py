"""``slamlib run`` (:mod:`slamlib.commands.run`) on tiny synthetic and KITTI drives: what it writes, and the
one-line messages for a wrong drive or a bad setting."""

import json

import numpy as np
import pytest


# ------------------------------------------------------------------------------------------ slamlib run
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


def test_slamlib_run_writes_trajectories_map_metrics_and_plots(tiny_drive, tmp_path):
    from slamlib.cli import main
    from slamlib.kitti import read_kitti_poses, read_tum

    base, date, drive = tiny_drive
    out = tmp_path / "out"
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
            "50",
            "--points",
            "200",
            "--out",
            str(out),
            "--no-progress",
        ]
    )
    assert rc == 0
    slam = read_kitti_poses(out / "slam_poses.txt")
    _, tum = read_tum(out / "slam_tum.txt")
    assert slam.shape == (10, 4, 4) and np.allclose(tum, slam, atol=1e-9)
    assert read_kitti_poses(out / "dead_reckoning_poses.txt").shape == (10, 4, 4)
    info = json.loads((out / "metrics.json").read_text())
    assert info["frames"] == 10 and info["fps"] > 0 and info["frame_indices"] == [1, 10]
    assert {"slam", "dead_reckoning"} <= set(info["metrics"])
    assert info["metrics"]["slam"]["ate_rmse_m"] >= 0
    import open3d as o3d

    assert (
        len(o3d.io.read_point_cloud(str(out / "map.ply")).points)
        == info["map_points_written"]
        > 0
    )
    assert (out / "trajectory.png").stat().st_size > 1000 and (
        out / "map_topdown.png"
    ).stat().st_size > 1000


@pytest.mark.parametrize(
    "which,needle",
    [
        ("basedir", "is not a folder"),
        ("date", "dates there: 2011_09_26"),
        ("drive", "drives there: 0001"),
    ],
)
def test_slamlib_run_explains_a_wrong_drive(tiny_drive, tmp_path, which, needle):
    from slamlib.cli import main

    base, date, drive = tiny_drive
    args = {"basedir": str(base), "date": date, "drive": str(drive)}
    args[which] = {
        "basedir": str(tmp_path / "nowhere"),
        "date": "2011_10_03",
        "drive": "0042",
    }[which]
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "run",
                "--basedir",
                args["basedir"],
                "--date",
                args["date"],
                "--drive",
                args["drive"],
                "--out",
                str(tmp_path / "o"),
                "--no-progress",
            ]
        )
    assert needle in str(exc.value) and "not found" in str(exc.value)


def test_slamlib_run_map_names_and_bad_settings(tiny_drive, tmp_path, capsys):
    from slamlib.cli import main

    base, date, drive = tiny_drive
    common = [
        "run",
        "--basedir",
        str(base),
        "--date",
        date,
        "--drive",
        str(drive),
        "--no-progress",
        "--no-plots",
    ]
    with pytest.raises(SystemExit) as exc:
        main(common + ["--particles", "0", "--out", str(tmp_path / "a")])
    assert "particles" in str(exc.value) and ">= 1" in str(exc.value)
    assert (
        main(
            common
            + [
                "--frames",
                "0:3",
                "--particles",
                "5",
                "--points",
                "20",
                "--map",
                "bvh",
                "--out",
                str(tmp_path / "b"),
            ]
        )
        == 0
    )
    assert "--map bvh is now called --map morton_bvh" in capsys.readouterr().out
    info = json.loads((tmp_path / "b" / "metrics.json").read_text())
    assert (
        info["config"]["map"]["kind"] == "morton_bvh"
        and info["config"]["filter"]["particles"] == 5
    )
    # a still synthetic drive (no distortion): by default (deskew None) no scan is de-skewed; --deskew does all
    assert info["config"]["scan"]["deskew"] is None and info["n_deskewed_frames"] == 0
    assert (
        main(
            common
            + [
                "--frames",
                "0:3",
                "--particles",
                "5",
                "--points",
                "20",
                "--deskew",
                "--out",
                str(tmp_path / "c"),
            ]
        )
        == 0
    )
    info = json.loads((tmp_path / "c" / "metrics.json").read_text())
    assert info["config"]["scan"]["deskew"] is True and info["n_deskewed_frames"] == 3


def test_slamlib_run_default_drive_is_realistic_unless_still(
    tiny_drive, tmp_path, monkeypatch, capsys
):
    """With no drive given, ``slamlib run`` asks for the realistic default drive; ``--still-default`` for the still
    one (``default_drive(realism=False)``), and says so."""
    import slamlib.synth
    from slamlib.cli import main

    asked = []
    monkeypatch.setattr(
        slamlib.synth, "default_drive", lambda **kw: asked.append(kw) or tiny_drive
    )
    for flags, realism in (([], True), (["--still-default"], False)):
        assert (
            main(
                [
                    "run",
                    "--frames",
                    "0:3",
                    "--particles",
                    "5",
                    "--points",
                    "20",
                    "--no-progress",
                    "--no-plots",
                    "--out",
                    str(tmp_path / str(realism)),
                ]
                + flags
            )
            == 0
        )
        assert asked[-1]["realism"] is realism
        assert ("default drive (still)" in capsys.readouterr().out) is not realism
    base, date, drive = tiny_drive
    for flag in (
        "--still-default",
        "--full-default",
    ):  # not silently ignored beside a given drive
        with pytest.raises(
            SystemExit, match=f"{flag} chooses among the synthetic default drives"
        ):
            main(
                [
                    "run",
                    "--basedir",
                    str(base),
                    "--date",
                    date,
                    "--drive",
                    str(drive),
                    flag,
                    "--out",
                    str(tmp_path / "x"),
                ]
            )
