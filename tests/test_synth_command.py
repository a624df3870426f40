"""``slamlib synth``: writes a drive pykitti and KittiRawDrive read; bad arguments exit with a one-line message."""

import json

import numpy as np
import pykitti
import pytest

from slamlib.cli import main
from slamlib.commands import synth as synth_command
from slamlib.kitti import KittiRawDrive
from slamlib.kitti.sample import SAMPLE_DATE
from slamlib.synth import (
    DEFAULT_FRAMES,
    ROUTE_NAMES,
    WANDERING_BIASES,
    ZERO_NOISE,
    Hdl64,
    ImuNoise,
)
from slamlib.synth.writer import MARKER, drive_dir

TINY = ["--columns", "200", "--frames", "0:3", "--no-progress"]


def test_command_constants_match_the_library():
    """The command keeps these without importing slamlib.synth (fast --help): they must not drift."""
    assert synth_command.ROUTES == ROUTE_NAMES
    assert synth_command.DEFAULT_FRAMES == f"{DEFAULT_FRAMES[0]}:{DEFAULT_FRAMES[1]}"
    assert synth_command.DEFAULT_COLUMNS == Hdl64().columns


def test_writes_a_drive_pykitti_reads(tmp_path, capsys):
    out = tmp_path / "synth"
    assert main(["synth", "--out", str(out), "--seed", "2", "--drive", "7", *TINY]) == 0
    text = capsys.readouterr().out
    assert f"pykitti.raw({str(out)!r}, '2011_09_26', '0007')" in text
    assert f"slamlib run --basedir {out} --date 2011_09_26 --drive 0007" in text
    data = pykitti.raw(str(out), "2011_09_26", "0007")
    assert len(data.oxts) == 3 and len(data.velo_files) == 3
    scan = data.get_velo(1)
    assert scan.dtype == np.float32 and scan.shape[1] == 4 and 1000 < len(scan) < 64 * 200
    drive = KittiRawDrive(out, "2011_09_26", 7)
    assert len(drive) == 3 and np.allclose(drive.ground_truth_poses()[0], np.eye(4))
    marker = json.loads((drive_dir(out, "2011_09_26", 7) / MARKER).read_text())
    assert (
        marker["seed"] == 2
        and marker["lidar"]["columns"] == 200
        and marker["route"] == "kitti07"
    )


def test_no_scans_writes_no_bin_files(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["synth", "--out", str(out), "--no-scans", *TINY]) == 0
    assert "slamlib run needs scans" in capsys.readouterr().out
    d = drive_dir(out, "2011_09_26", 1)
    assert not list(d.rglob("*.bin"))
    assert len(list((d / "oxts" / "data").glob("*.txt"))) == 3
    assert len(pykitti.raw(str(out), "2011_09_26", "0001").oxts) == 3


def test_imu_noise_zero_gives_exact_fields(tmp_path):
    out = tmp_path / "z"
    assert (
        main(
            [
                "synth",
                "--out",
                str(out),
                "--route",
                "loop",
                "--frames",
                "4",
                "--imu-noise",
                "0",
                "--no-scans",
                "--no-progress",
            ]
        )
        == 0
    )
    marker = json.loads((drive_dir(out, "2011_09_26", 1) / MARKER).read_text())
    assert marker["noise"] == ZERO_NOISE.as_dict() and marker["frames"] == 4
    packets = pykitti.raw(str(out), "2011_09_26", "0001").oxts
    vf = np.array([p.packet.vf for p in packets])
    wu = np.array([p.packet.wu for p in packets])
    # the 60 m, 8 m/s circle
    assert np.allclose(vf, 8.0, atol=1e-6) and np.allclose(wu, 8.0 / 60.0, atol=1e-6)


def test_imu_noise_scaled():
    assert (
        ImuNoise().scaled(0) == ZERO_NOISE
        and ImuNoise().scaled(0).as_dict() == ZERO_NOISE.as_dict()
    )
    assert ImuNoise().scaled(1) == ImuNoise()
    two = ImuNoise().scaled(2)
    assert (
        two.gyro_bias == tuple(2 * x for x in ImuNoise().gyro_bias)
        and two.vel_sigma == 2 * ImuNoise().vel_sigma
    )
    with pytest.raises(ValueError):
        ImuNoise().scaled(-0.5)


def test_rewrites_its_own_drive_but_never_a_real_one(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["synth", "--out", str(out), "--no-scans", *TINY]) == 0
    # ours: replaced
    assert main(["synth", "--out", str(out), "--no-scans", "--seed", "1", *TINY]) == 0
    real = drive_dir(out, "2011_09_26", 2)
    real.mkdir(parents=True)
    (real / "keep.txt").write_text("real data")
    with pytest.raises(SystemExit) as exc:
        main(["synth", "--out", str(out), "--drive", "2", "--no-scans", *TINY])
    assert (
        "not a slamlib synthetic drive" in str(exc.value) and (real / "keep.txt").exists()
    )
    (out / "2011_09_30").mkdir()
    (out / "2011_09_30" / "calib_imu_to_velo.txt").write_text(
        "R: 1 0 0 0 1 0 0 0 1\nT: 0 0 0\n"
    )
    with pytest.raises(SystemExit) as exc:
        main(["synth", "--out", str(out), "--date", "2011_09_30", "--no-scans", *TINY])
    assert "differs from the 2011_09_26 calibration" in str(exc.value)


@pytest.mark.parametrize(
    "args, message",
    [
        (
            ["--frames", "0:5000"],
            "out of range",
        ),  # past the end of sequence 07 (1101 key frames)
        (["--frames", "5000:"], "out of range"),
        (
            ["--frames", "1095:1101"],
            "spans only",
        ),  # the last key frames span fewer frames
        (["--frames", "3:2"], "selects no frames"),
        (["--frames", "a:b"], "--frames must look like"),
        (["--route", "loop", "--frames", "5:9"], "always starts at its beginning"),
        (["--route", "straight", "--frames", "5000"], "spans at most"),
        (["--imu-noise", "-1"], "--imu-noise"),
        (["--imu-noise", "nan"], "--imu-noise"),
        (["--date", "2011-09-26"], "YYYY_MM_DD"),
        (["--drive", "10000"], "--drive"),
        (["--columns", "3"], "--columns"),
        (["--seed", "-2"], "--seed"),
    ],
)
def test_bad_arguments_exit_with_one_line(tmp_path, args, message):
    out = tmp_path / "bad"
    with pytest.raises(SystemExit) as exc:
        main(["synth", "--out", str(out), "--no-progress", "--columns", "200", *args])
    text = str(exc.value)
    assert text.startswith("slamlib synth: ") and message in text and "\n" not in text
    assert not out.exists()


def test_unknown_route_is_an_argparse_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["synth", "--out", str(tmp_path), "--route", "08"])
    err = capsys.readouterr().err
    assert exc.value.code == 2 and "route must be one of" in err and "random:SEED" in err


def test_a_random_route_is_written_from_its_seed(tmp_path):
    out = tmp_path / "fresh"
    main(
        [
            "synth",
            "--out",
            str(out),
            "--route",
            "random:4",
            "--frames",
            "3",
            "--columns",
            "200",
            "--no-progress",
        ]
    )
    import pykitti

    data = pykitti.raw(str(out), "2011_09_26", "0001")
    assert len(data.oxts) == 3


def test_parse_route_frames():
    p = synth_command.parse_route_frames
    assert (
        p("10:20", "07") == (10, 20)
        and p("10:", "00") == (10, None)
        and p("25", "05") == (0, 25)
    )
    assert p(":7", "07") == (0, 7)
    assert (
        p("40", "loop") == 40 and p("0:40", "straight") == 40 and p("0:", "loop") is None
    )


def test_bias_walk_flag_writes_wandering_biases(tmp_path):
    """``--bias-walk`` writes the drive with :data:`WANDERING_BIASES` (recorded in the marker, scaled by
    ``--imu-noise``); without it the biases stay constant (walks 0)."""
    out = tmp_path / "w"
    assert (
        main(
            [
                "synth",
                "--out",
                str(out),
                "--route",
                "loop",
                "--frames",
                "4",
                "--imu-noise",
                "2",
                "--bias-walk",
                "--no-scans",
                "--no-progress",
            ]
        )
        == 0
    )
    marker = json.loads((drive_dir(out, "2011_09_26", 1) / MARKER).read_text())
    assert marker["noise"] == WANDERING_BIASES.scaled(2).as_dict()
    assert (
        marker["noise"]["gyro_bias_walk"] == 4e-4
        and ImuNoise().as_dict()["gyro_bias_walk"] == 0.0
    )


@pytest.mark.parametrize("layout", ["raw", "odometry"])
def test_distortion_flag_writes_swept_scans(tmp_path, layout):
    """``--distortion`` reaches the generator in either layout (recorded in the marker); without it, none."""
    from slamlib.synth.writer import read_marker

    for flag, name in (([], "plain"), (["--distortion"], "swept")):
        out = tmp_path / name
        assert (
            main(
                [
                    "synth",
                    "--out",
                    str(out),
                    "--route",
                    "loop",
                    "--frames",
                    "3",
                    "--columns",
                    "90",
                    "--layout",
                    layout,
                    "--no-progress",
                ]
                + flag
            )
            == 0
        )
        folder = (
            drive_dir(out, "2011_09_26", 1)
            if layout == "raw"
            else out / "sequences" / "00"
        )
        assert read_marker(folder).get("distortion", False) is bool(flag)


# ------------------------------------------------------------------ bad options and --out, refused before writing
@pytest.mark.parametrize(
    "option,value",
    [("--columns", "1000000000"), ("--imu-noise", "1e300"), ("--imu-noise", "nan")],
)
def test_synth_bad_option_is_refused_before_writing(tmp_path, option, value):
    from slamlib.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["synth", "--out", str(tmp_path / "d"), "--frames", "0:4", option, value])
    assert str(exc.value).startswith(f"slamlib synth: {option} must be"), str(exc.value)
    assert not (tmp_path / "d").exists()


def test_synth_out_whose_date_folder_is_a_file_is_one_line(tmp_path):
    from slamlib.cli import main

    (tmp_path / SAMPLE_DATE).write_text("a file\n")
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "synth",
                "--out",
                str(tmp_path),
                "--route",
                "straight",
                "--frames",
                "3",
                "--no-progress",
            ]
        )
    assert str(exc.value).startswith("slamlib synth: ") and SAMPLE_DATE in str(exc.value)


# ------------------------------------------------------------------ frames beyond the route
def test_synth_frames_beyond_the_route_names_frames(tmp_path):
    from slamlib.cli import main

    with pytest.raises(SystemExit) as exc:
        main(
            [
                "synth",
                "--out",
                str(tmp_path / "s"),
                "--route",
                "straight",
                "--frames",
                "583",
                "--no-progress",
            ]
        )
    assert str(exc.value).startswith(
        "slamlib synth: --frames '583': route 'straight' spans at most"
    ), str(exc.value)
    assert not (tmp_path / "s").exists()


def test_the_printed_run_command_quotes_a_path_with_spaces(tmp_path, capsys):
    """The "read it with" line runs as printed, even from a folder whose name has spaces."""
    import shlex

    out = tmp_path / "my drives"
    assert main(["synth", "--out", str(out), *TINY]) == 0
    line = next(
        x.strip()
        for x in capsys.readouterr().out.splitlines()
        if "slamlib run --basedir" in x
    )
    argv = shlex.split(line)
    assert argv[argv.index("--basedir") + 1] == str(out)
