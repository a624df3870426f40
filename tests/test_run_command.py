"""``slamlib run`` (:mod:`slamlib.commands.run`) on tiny synthetic and KITTI drives: what it writes (never over a
user's file), and the one-line messages, given before the run, for a wrong drive, a bad option or bad data."""

import json

import numpy as np
import pytest
from drive_edits import set_oxts_field


# ------------------------------------------------------------------ whole runs on a tiny synthetic drive
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


def _ten_frame_run(tiny_drive, out) -> list[str]:
    """``slamlib run``'s arguments for frames 1 to 10 of ``tiny_drive`` (50 particles, 200 points, no progress
    bar), writing to ``out``."""
    base, date, drive = tiny_drive
    return ["run", "--basedir", str(base), "--date", date, "--drive", str(drive)] + [
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


def test_slamlib_run_writes_trajectories_map_metrics_and_plots(tiny_drive, tmp_path):
    from slamlib.cli import main
    from slamlib.kitti import read_kitti_poses, read_tum

    out = tmp_path / "out"
    rc = main(_ten_frame_run(tiny_drive, out))
    assert rc == 0
    slam = read_kitti_poses(out / "slam_poses.txt")
    _, tum = read_tum(out / "slam_tum.txt")
    assert slam.shape == (10, 4, 4) and np.allclose(tum, slam, atol=1e-9)
    assert read_kitti_poses(out / "dead_reckoning_poses.txt").shape == (10, 4, 4)
    info = json.loads((out / "metrics.json").read_text())
    assert info["frames"] == 10 and info["fps"] > 0 and info["frame_indices"] == [1, 10]
    assert {"slam", "dead_reckoning"} <= set(info["metrics"])
    # ATE: the RMSE of the position errors against the written ground truth, no alignment (both start at 0)
    gt = read_kitti_poses(out / "ground_truth_poses.txt")
    ate = np.sqrt(np.mean(np.sum((slam[:, :3, 3] - gt[:, :3, 3]) ** 2, axis=1)))
    assert ate > 0 and info["metrics"]["slam"]["ate_rmse_m"] == pytest.approx(
        ate, rel=1e-6
    )
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
    # a still synthetic drive (no distortion): by default (deskew auto) no scan is de-skewed; --deskew does all
    assert info["config"]["scan"]["deskew"] == "auto" and info["n_deskewed_frames"] == 0
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


# ---------------------------------------------------------- bad options and outputs, refused in one line before the run
@pytest.mark.parametrize(
    "option,value",
    [
        ("--temperature", "0"),
        ("--temperature", "-1"),
        ("--temperature", "nan"),
        ("--temperature", "inf"),
        ("--seed", "-1"),
        ("--particles", "1000000000"),
        ("--anneal-rounds", "-1"),
        ("--noise", "inf"),
        ("--noise", "nan"),
        ("--tilt-sigma", "-0.01"),
        ("--tilt-sigma", "nan"),
    ],
)
def test_slamlib_run_bad_option_is_one_line_naming_it(
    cli_drive, tmp_path, monkeypatch, option, value
):
    import slamlib.slam3d
    from slamlib.cli import main

    monkeypatch.setattr(
        slamlib.slam3d, "run_drive", lambda *a, **k: pytest.fail("the run started")
    )
    args, _ = cli_drive
    with pytest.raises(SystemExit) as exc:
        main(args + [option, value, "--out", str(tmp_path / "o")])
    msg = str(exc.value)
    assert msg.startswith(f"slamlib run: {option}") and "\n" not in msg, msg


def test_slamlib_run_out_at_an_existing_file_is_refused_before_the_run(
    cli_drive, tmp_path, monkeypatch
):
    import slamlib.slam3d
    from slamlib.cli import main

    monkeypatch.setattr(
        slamlib.slam3d, "run_drive", lambda *a, **k: pytest.fail("the run started")
    )
    args, _ = cli_drive
    f = tmp_path / "file.txt"
    f.write_text("keep me\n")
    with pytest.raises(SystemExit, match="--out: .*file.txt exists and is not a folder"):
        main(args + ["--out", str(f)])
    assert f.read_text() == "keep me\n"


def test_slamlib_run_with_an_empty_scan_counts_it_and_writes_valid_json(
    cli_drive, tmp_path, capsys
):
    from slamlib.cli import main
    from slamlib.kitti import read_kitti_poses

    args, d = cli_drive
    (d / "velodyne_points" / "data" / "0000000002.bin").write_bytes(b"")
    out = tmp_path / "o"
    assert main(args + ["--out", str(out)]) == 0
    text = (out / "metrics.json").read_text()
    info = json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in metrics.json"))
    assert info["n_skipped_frames"] == 1 and "1 of 4 frames" in info["warnings"][0]
    assert np.all(np.isfinite(read_kitti_poses(out / "slam_poses.txt")))
    assert "warning: 1 of 4 frames" in capsys.readouterr().out


def test_slamlib_run_tilt_sigma_reaches_the_filter(cli_drive, tmp_path):
    """``--tilt-sigma`` turns on the tilt prior on the real OXTS samples (ax, ay, az) and is recorded."""
    from slamlib.cli import main
    from slamlib.kitti import read_kitti_poses

    args, _ = cli_drive
    out = tmp_path / "o"
    assert main(args + ["--tilt-sigma", "0.005", "--out", str(out)]) == 0
    info = json.loads((out / "metrics.json").read_text())
    assert info["config"]["prior"]["tilt_sigma"] == 0.005
    assert np.all(np.isfinite(read_kitti_poses(out / "slam_poses.txt")))


def test_slamlib_run_tilt_sigma_auto_and_self_tuning_reach_the_filter(
    cli_drive, tmp_path
):
    """``--tilt-sigma auto`` (the default) and ``--self-tuning off`` are recorded; a word other than auto is an
    option error naming it."""
    from slamlib.cli import main

    args, _ = cli_drive
    out = tmp_path / "o"
    assert (
        main(args + ["--tilt-sigma", "auto", "--self-tuning", "off", "--out", str(out)])
        == 0
    )
    config = json.loads((out / "metrics.json").read_text())["config"]
    assert (
        config["prior"]["tilt_sigma"] == "auto"
        and config["motion"]["self_tuning"] is False
    )
    with pytest.raises(SystemExit) as exc:
        main(args + ["--tilt-sigma", "strong", "--out", str(tmp_path / "p")])
    assert exc.value.code == 2


def test_slamlib_run_match_tilt_reaches_the_filter(cli_drive, tmp_path):
    """``--match-tilt`` (the default) with the tilt prior is recorded, and the scan match then runs on every frame
    after the first (``auto``), where with ``--no-match-tilt`` the prior turns the match off; ``--tilt-up`` and
    ``--tilt-bias`` are recorded as given."""
    from slamlib.cli import main

    args, _ = cli_drive
    for flag, out in (
        (
            ["--no-match-tilt", "--tilt-up", "velocity", "--tilt-bias", "sectors"],
            tmp_path / "a",
        ),
        ([], tmp_path / "b"),
    ):
        assert main(args + ["--tilt-sigma", "0.005", *flag, "--out", str(out)]) == 0
    off, on = (json.loads((tmp_path / d / "metrics.json").read_text()) for d in "ab")
    assert off["config"]["polish"]["match_tilt"] is False
    assert on["config"]["polish"]["match_tilt"] is True
    assert (off["config"]["prior"]["tilt_up"], off["config"]["prior"]["tilt_bias"]) == (
        "velocity",
        "sectors",
    )
    assert (on["config"]["prior"]["tilt_up"], on["config"]["prior"]["tilt_bias"]) == (
        "positions",
        "kalman",
    )
    assert off["n_matched_frames"] == 0 < on["n_matched_frames"]


#: ``slamlib run`` options that tune the filter: the run examples of the README and the book carry none (the
#: defaults tune themselves; issue "one default for every drive").
TUNING_OPTIONS = {
    "--noise",
    "--self-tuning",
    "--tilt-sigma",
    "--anneal-rounds",
    "--refine",
    "--transient-span",
    "--particles",
    "--points",
    "--temperature",
    "--scan-match",
    "--match-tilt",
    "--tilt-up",
    "--tilt-bias",
    "--deskew",
}


def _run_examples():
    """Every ``slamlib run`` command line in the fenced code blocks of the README, the book's pages and the
    notebooks' text, with its continuation lines joined: ``(file, line)``. (Prose may name an override, as
    "``slamlib run --deskew off`` switches it off"; an example to copy may not.)"""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    files = [root / "README.md", *sorted((root / "book").glob("*.md"))]
    files += sorted((root / "notebooks").glob("*.ipynb"))
    found = []
    for path in files:
        text = path.read_text(encoding="utf-8")
        if path.suffix == ".ipynb":
            cells = json.loads(text)["cells"]
            text = "\n".join("".join(c["source"]) for c in cells)
        for block in re.findall(r"```[^\n]*\n(.*?)```", text, flags=re.S):
            block = re.sub(r"\\\n\s*", " ", block)
            found += [(path.name, m) for m in re.findall(r"slamlib run\b[^\n]*", block)]
    return found


def test_the_run_examples_carry_data_paths_only():
    examples = _run_examples()
    assert len(examples) >= 8  # the README's alone has eight
    tuned = [
        (name, line)
        for name, line in examples
        if TUNING_OPTIONS & set(line.split("#")[0].split())
    ]
    assert tuned == []


def test_slamlib_run_transient_span_reaches_the_map_and_names_itself(cli_drive, tmp_path):
    """``--transient-span`` turns on the eviction of movers' trails (recorded in metrics.json); with the Morton
    map, which keeps no hit times, the error names both options."""
    from slamlib.cli import main

    args, _ = cli_drive
    out = tmp_path / "o"
    assert main(args + ["--transient-span", "2", "--out", str(out)]) == 0
    assert (
        json.loads((out / "metrics.json").read_text())["config"]["upkeep"][
            "transient_span"
        ]
        == 2
    )
    with pytest.raises(
        SystemExit,
        match=r"--transient-span, --map: transient_span needs the 'voxel_hash' map",
    ):
        main(
            args
            + [
                "--transient-span",
                "2",
                "--map",
                "morton_bvh",
                "--out",
                str(tmp_path / "p"),
            ]
        )
    with pytest.raises(
        SystemExit, match=r"--transient-span: transient_span must be >= 0"
    ):
        main(args + ["--transient-span", "-1", "--out", str(tmp_path / "q")])


def test_slamlib_run_bad_oxts_is_one_message_without_a_wrong_drive_hint(
    cli_drive, tmp_path
):
    from slamlib.cli import main

    args, d = cli_drive
    set_oxts_field(d, 2, "lat", "91")
    with pytest.raises(SystemExit) as exc:
        main(args + ["--out", str(tmp_path / "o")])
    msg = str(exc.value)
    assert (
        "0000000002.txt:1:" in msg and "lat = 91.0" in msg and "drives there" not in msg
    ), msg
    assert not (tmp_path / "o" / "metrics.json").exists()


def test_slamlib_run_refuses_to_write_a_nan_trajectory_with_a_message(
    cli_drive, tmp_path, monkeypatch
):
    import slamlib.slam3d
    from slamlib.cli import main

    real = slamlib.slam3d.run_drive

    def poisoned(*a, **k):
        run = real(*a, **k)
        run.poses[2, 0, 3] = np.nan  # what a filter bug would leave behind
        return run

    monkeypatch.setattr(slamlib.slam3d, "run_drive", poisoned)
    args, _ = cli_drive
    out = tmp_path / "o"
    with pytest.raises(SystemExit, match="could not write the results into .*non-finite"):
        main(args + ["--out", str(out)])
    assert not (out / "slam_poses.txt").exists() and not (out / "metrics.json").exists()


def test_slamlib_run_refuses_to_overwrite_user_files_but_replaces_its_own(
    cli_drive, tmp_path
):
    from slamlib.cli import main

    args, _ = cli_drive
    out = tmp_path / "o"
    out.mkdir()
    (out / "map.ply").write_text("my own map")
    with pytest.raises(SystemExit, match="--out: .*map.ply.*--overwrite"):
        main(args + ["--out", str(out)])
    assert (out / "map.ply").read_text() == "my own map"
    assert main(args + ["--out", str(out), "--overwrite"]) == 0
    # an earlier run's results are replaced without asking
    assert main(args + ["--out", str(out)]) == 0


def test_slamlib_run_again_with_another_map_format_drops_the_stale_map(
    cli_drive, tmp_path
):
    from slamlib.cli import main

    args, _ = cli_drive
    out = tmp_path / "o"
    assert main(args + ["--out", str(out), "--map-format", "ply"]) == 0
    assert main(args + ["--out", str(out), "--map-format", "pcd"]) == 0
    assert (out / "map.pcd").is_file() and not (out / "map.ply").exists()


# -------------------------------------------------- counts and frame selections named in one line; a run of empty scans
@pytest.mark.parametrize(
    "option,value",
    [
        ("--points", "0"),
        ("--points", "-3"),
        ("--particles", "0"),
        ("--points", "100000000"),
    ],
)
def test_slamlib_run_count_error_names_the_option_given(
    tmp_path, monkeypatch, option, value
):
    import slamlib.slam3d
    from slamlib.cli import main

    monkeypatch.setattr(
        slamlib.slam3d, "run_drive", lambda *a, **k: pytest.fail("the run started")
    )
    with pytest.raises(SystemExit) as exc:
        main(["run", "--no-progress", option, value, "--out", str(tmp_path / "o")])
    msg = str(exc.value)
    assert (
        msg.startswith("slamlib run: ")
        and option in msg.split(":")[1]
        and "\n" not in msg
    ), msg


@pytest.mark.parametrize("frames", ["1", "0:1", "2:"])
def test_slamlib_run_one_frame_selection_names_frames(tmp_path, monkeypatch, frames):
    import slamlib.slam3d
    from slamlib.cli import main
    from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive

    monkeypatch.setattr(
        slamlib.slam3d, "run_drive", lambda *a, **k: pytest.fail("the run started")
    )
    d = make_tiny_drive(tmp_path / "k", n_frames=3, point_stride=500)
    with pytest.raises(SystemExit) as exc:
        main(
            [
                "run",
                "--basedir",
                str(d.parent.parent),
                "--date",
                SAMPLE_DATE,
                "--drive",
                SAMPLE_DRIVE,
                "--frames",
                frames,
                "--out",
                str(tmp_path / "o"),
            ]
        )
    assert str(exc.value).startswith(
        f"slamlib run: --frames {frames!r} selects 1 frame"
    ), str(exc.value)


@pytest.mark.parametrize("fmt", ["ply", "pcd"])
def test_slamlib_run_with_every_scan_empty_writes_an_empty_map(tmp_path, fmt):
    import json

    import open3d as o3d

    from slamlib.cli import main
    from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive

    d = make_tiny_drive(tmp_path / "k", n_frames=3, point_stride=500)
    for p in (d / "velodyne_points" / "data").iterdir():
        p.write_bytes(b"")
    out = tmp_path / "o"
    assert (
        main(
            [
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
                "--map-format",
                fmt,
                "--out",
                str(out),
            ]
        )
        == 0
    )
    assert len(o3d.io.read_point_cloud(str(out / f"map.{fmt}")).points) == 0
    info = json.loads((out / "metrics.json").read_text())
    assert info["map_points_written"] == 0 and info["n_skipped_frames"] == 3


def test_slamlib_run_help_groups_the_options_by_stage(capsys):
    from slamlib.cli import main

    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = capsys.readouterr().out
    heads = [
        line.split(" (")[0]
        for line in text.splitlines()
        if line.endswith(":") and "stage" in line
    ]
    assert heads == [
        "scan stage",
        "motion stage",
        "prior stage",
        "search stage",
        "polish stage",
    ]
    for option, group in (
        ("--deskew", "scan stage"),
        ("--lidar-only", "motion stage"),
        ("--tilt-sigma", "prior stage"),
        ("--tilt-up", "prior stage"),
        ("--tilt-bias", "prior stage"),
        ("--anneal-rounds", "search stage"),
        ("--scan-match", "polish stage"),
        ("--match-tilt", "polish stage"),
    ):
        section = text.split(group, 1)[1].split("\n\n", 1)[0]
        assert option in section, (option, group)
    assert "--refine" not in text  # the old name works (with a note) but is not offered


def test_slamlib_run_old_options_are_taken_with_a_note(
    cli_drive, tmp_path, monkeypatch, capsys
):
    import slamlib.slam3d
    from slamlib.cli import main

    seen = {}

    def fake_run(frames, config, **kw):
        seen["config"] = config
        raise SystemExit(0)

    monkeypatch.setattr(slamlib.slam3d, "run_drive", fake_run)
    args = cli_drive[0] + ["--refine", "3", "--no-scan-match", "--no-deskew"]
    args += ["--out", str(tmp_path / "o")]
    with pytest.raises(SystemExit):
        main(args)
    out = capsys.readouterr().out
    assert (
        "--refine 3 is now --anneal-rounds 3" in out
        and "--no-scan-match is now --scan-match off" in out
    )
    c = seen["config"]
    assert (c.search.anneal_rounds, c.polish.scan_match, c.scan.deskew) == (
        3,
        False,
        False,
    )


def test_a_run_prints_no_library_warning(cli_drive, tmp_path):
    """No library warning reaches the user of ``slamlib run`` (Numba's about an old TBB was one: slamlib asks
    for OpenMP first, ``slamlib.THREADING_LAYER_PRIORITY``), unless they chose the layers themselves."""
    import os
    import subprocess
    import sys

    args, _ = cli_drive
    env = {
        k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER")
    }
    result = subprocess.run(
        [sys.executable, "-m", "slamlib.cli", *args, "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert "Warning" not in result.stderr and "warnings.warn" not in result.stderr


def test_run_reports_steady_frames_per_second_apart_from_the_start_up(
    cli_drive, tmp_path, capsys
):
    """The rate after the first ``STARTUP_FRAMES`` frames, and the start-up (imports, kernels, those frames) on
    its own: a new user's first number is not the compile time. The numbers come from the run's own clocks."""
    from slamlib.cli import main
    from slamlib.commands.run import STARTUP_LINE_RE, startup_line
    from slamlib.slam3d.run import STARTUP_FRAMES

    args, _ = cli_drive
    assert main(args + ["--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    m = STARTUP_LINE_RE.search(out)
    assert m, out
    assert float(m.group(4)) > 0
    assert (
        f"(imports, kernels compiled or loaded, the first {STARTUP_FRAMES} frames)" in out
    )
    # what benchmarks/startup.py reads back is what was printed
    line = startup_line(300, 12.34, 88.25, 2.5)
    assert STARTUP_LINE_RE.search(line).groups() == ("300", "12.3", "88.2", "2.50")
    assert (
        STARTUP_LINE_RE.search(startup_line(3, 1.0, float("nan"), 1.0)).group(3) == "nan"
    )


def test_steady_frames_per_second_leaves_out_the_start_up_frames():
    from slamlib.slam3d.run import STARTUP_FRAMES, SLAMRun

    def run(n, seconds, warm_after):
        return SLAMRun(
            np.zeros((n, 4, 4)),
            None,
            None,
            np.zeros(n),
            np.arange(n),
            seconds,
            None,
            warm_at=100.0 + warm_after,
            started_at=100.0,
        )

    assert run(12, 3.0, 1.0).steady_fps == pytest.approx((12 - STARTUP_FRAMES) / 2.0)
    assert np.isnan(run(STARTUP_FRAMES, 3.0, 3.0).steady_fps)


def test_a_path_under_100_m_has_no_kitti_error_and_says_so(cli_drive, tmp_path, capsys):
    """The KITTI metric needs 100 m segments: a shorter drive prints "n/a (path < 100 m)", not nan."""
    from slamlib.cli import main

    args, _ = cli_drive
    assert main(args + ["--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    rows = [
        line
        for line in out.splitlines()
        if line.startswith(("particle SLAM", "dead reckoning"))
    ]
    assert len(rows) == 2 and all(row.endswith("n/a (path < 100 m)") for row in rows)
    assert "nan" not in out


def test_slamlib_run_loop_closure_writes_its_poses_and_closures(
    tiny_drive, tmp_path, capsys
):
    """--loop-closure: the re-anchored trajectory and closures.json beside the filter's own poses, its row in the
    printed table and in metrics.json; a 10-frame drive is one local map, so no closure and the same poses."""
    from slamlib.cli import main
    from slamlib.kitti import read_kitti_poses

    out = tmp_path / "out"
    assert main(_ten_frame_run(tiny_drive, out) + ["--no-plots", "--loop-closure"]) == 0
    slam = read_kitti_poses(out / "slam_poses.txt")
    closed = read_kitti_poses(out / "slam_loop_closed_poses.txt")
    assert closed.shape == slam.shape and np.allclose(closed, slam, atol=1e-6)
    closures = json.loads((out / "closures.json").read_text())
    assert closures["closures"] == [] and len(closures["local_maps"]) == 1
    assert closures["local_maps"][0]["first_frame"] == 1
    info = json.loads((out / "metrics.json").read_text())
    assert "slam_loop_closed" in info["metrics"]
    printed = capsys.readouterr().out
    assert "+ loop closure" in printed and "1 local maps, 0 verified closures" in printed


def test_the_run_commands_start_imports_no_heavy_library_it_does_not_use():
    """What `slamlib run` imports before its first frame (the command, the filter, the readers, the default drive's
    cache key) leaves out pykitti's package (pandas with it), scipy.spatial and scipy.interpolate: together about half
    a second of every warm start-up on the 2-core machine (`slamlib bench startup`). They are imported where they
    are used: a drive's camera calibration, a TUM file, the generator's splines and its scene."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "from slamlib.cli import build_parser\n"
        "build_parser()\n"
        "import slamlib.commands.run, slamlib.kitti, slamlib.slam3d, slamlib.synth\n"
        "from slamlib.synth.drive import resolve_route\n"
        "resolve_route('07', (0, 300))\n"
        "heavy = ('pykitti', 'pandas', 'scipy.spatial', 'scipy.interpolate', 'open3d')\n"
        "print(sorted(m for m in sys.modules if m.startswith(heavy)))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    )
    assert done.stdout.strip() == "[]", done.stdout
