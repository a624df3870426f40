"""``slamlib sweep`` (:mod:`slamlib.experiments.sweep`) runs SLAM and KISS-ICP over routes x seeds x settings as
Dask tasks."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest

from slamlib.experiments.sweep import (
    COLUMNS,
    SweepTask,
    read_table,
    run_sweep,
    sweep_tasks,
    write_table,
)
from slamlib.slam3d.config import MATCH_GATE


def test_tasks_are_the_cross_product_with_kiss_icp_once_per_drive():
    tasks = sweep_tasks(
        ["07", "loop"],
        [0, 1],
        ["raw", "odometry"],
        ["slamlib", "kiss_icp"],
        [{"particles": 100}, {"particles": 300}],
        (0, 50),
    )
    assert len(tasks) == 2 * 2 * 2 * (2 + 1)
    assert len({t.drive_key() for t in tasks}) == 8
    assert sum(t.method == "kiss_icp" for t in tasks) == 8 and all(
        t.settings == {} for t in tasks if t.method == "kiss_icp"
    )
    with pytest.raises(ValueError, match="layout must be one of"):
        sweep_tasks(["07"], [0], ["bag"])
    with pytest.raises(ValueError, match="method must be one of"):
        sweep_tasks(["07"], [0], ["raw"], ["orb_slam"])


def test_loop_closure_runs_take_the_settings_and_kiss_slam_runs_once_per_drive():
    methods = ["slamlib", "slamlib_loop_closure", "kiss_slam"]
    settings = [{"particles": 100}, {"particles": 300}]
    tasks = sweep_tasks(["07"], [0, 1], ["odometry"], methods, settings, (0, 50))
    per_method = {m: [t.settings for t in tasks if t.method == m] for m in methods}
    assert per_method == {
        "slamlib": settings * 2,
        "slamlib_loop_closure": settings * 2,
        "kiss_slam": [{}, {}],
    }


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    c = LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
    )
    yield c
    c.close()


def test_sweep_on_a_dask_cluster_writes_one_tidy_row_per_run(cluster, tmp_path):
    tasks = sweep_tasks(
        ["loop"],
        [0, 1],
        ["raw", "odometry"],
        ["slamlib", "kiss_icp"],
        [{"particles": 40}],
        (0, 6),
    )
    rows = run_sweep(
        tasks, tmp_path / "data", scheduler=cluster.scheduler_address, progress=False
    )
    assert len(rows) == len(tasks) == 8
    # one drive per (seed, layout), generated once
    assert len(list((tmp_path / "data").iterdir())) == 4
    for task, row in zip(tasks, rows):
        assert tuple(row) == COLUMNS
        assert (row["seed"], row["layout"], row["method"]) == (
            task.seed,
            task.layout,
            task.method,
        )
        assert row["frames"] == 6 and math.isfinite(row["ate_rmse_m"]) and row["fps"] > 0
        # a 6-frame drive is far shorter than 100 m
        assert math.isnan(row["kitti_t_err_percent"])
        assert math.isnan(row["kitti_t_err_vertical_percent"])
        assert math.isnan(row["dead_reckoning_kitti_t_err_percent"])
        # dead reckoning: slamlib's IMU-only twin, on the raw layout (the odometry layout has no IMU)
        assert math.isfinite(row["dead_reckoning_ate_rmse_m"]) == (
            task.method == "slamlib" and task.layout == "raw"
        )
        assert row["settings"] == (
            '{"particles": 40}' if task.method == "slamlib" else ""
        )
        # the scan match's gate: slamlib's counts (matched every frame after the first), empty for
        # KISS-ICP
        gate = (
            row["match_rejected_frames"],
            row["match_max_kept_distance"],
            row["start_lines_kept"],
        )
        if task.method == "slamlib":  # a slow start: the drawn search kept
            assert gate[0] == 0 and 0 < gate[1] < MATCH_GATE and gate[2] == 0, gate
        else:
            assert all(math.isnan(g) for g in gate), gate
    # the same seed gives the same drive: slamlib's result on it does not depend on which worker ran it
    again = run_sweep(
        tasks[:1], tmp_path / "data", scheduler=cluster.scheduler_address, progress=False
    )
    assert again[0]["ate_rmse_m"] == rows[0]["ate_rmse_m"]
    path = write_table(rows, tmp_path / "sweep.csv")
    back = read_table(path)
    assert [r["method"] for r in back] == [r["method"] for r in rows]
    np.testing.assert_allclose(
        [r["ate_rmse_m"] for r in back], [r["ate_rmse_m"] for r in rows], rtol=1e-12
    )
    # a row journalled before the height columns existed is written with them empty
    old = {k: v for k, v in rows[0].items() if "_t_err_vertical" not in k}
    back = read_table(write_table([old], tmp_path / "old.csv"))[0]
    assert math.isnan(back["kitti_t_err_vertical_percent"])
    assert back["ate_rmse_m"] == pytest.approx(rows[0]["ate_rmse_m"], rel=1e-12)


def _drives_on_disk_per_row(scheduler, data) -> list[int]:
    """Run a one-worker sweep of 3 drives x 2 runs with ``--discard-drives``; the number of drive folders in ``data``
    as each run's row arrives."""
    tasks = sweep_tasks(
        ["loop"],
        [0, 1, 2],
        ["raw"],
        ["slamlib"],
        [{"particles": 20}, {"particles": 30}],
        (0, 4),
    )
    on_disk = []

    def count(task, row):
        on_disk.append(sum(1 for p in data.iterdir() if p.is_dir()))

    rows = run_sweep(
        tasks,
        data,
        scheduler=scheduler,
        progress=False,
        on_row=count,
        discard_drives=True,
    )
    assert all(r is not None for r in rows) and len(on_disk) == len(tasks) == 6
    # each drive is gone after its last run
    assert not [p for p in data.iterdir() if p.is_dir()]
    return on_disk


def test_a_sweep_finishes_each_drive_before_the_next_and_can_discard_it(
    cluster, tmp_path
):
    data = tmp_path / "data"
    on_disk = _drives_on_disk_per_row(cluster.scheduler_address, data)
    # one worker: a drive's two runs go before the next drive is generated (all three
    # generated first would show 3)
    assert max(on_disk) <= 2, on_disk
    # kept by default
    tasks = sweep_tasks(["loop"], [0], ["raw"], ["slamlib"], [{"particles": 20}], (0, 4))
    run_sweep(tasks, data, scheduler=cluster.scheduler_address, progress=False)
    assert [p.name for p in data.iterdir() if p.is_dir()] == [tasks[0].drive_key()]


@pytest.mark.filterwarnings(
    "ignore:Port .* is already in use"
)  # the module's cluster has it
@pytest.mark.parametrize("priorities", [True, False], ids=["priorities", "inverted"])
def test_without_dask_queuing_the_priorities_still_put_a_drives_runs_first(
    priorities, tmp_path, monkeypatch
):
    """A scheduler without Dask's queuing (``worker-saturation: inf``) sends every ready task to the worker at
    once, which runs them by their priority: the runs' is higher than the drives'."""
    import dask
    from distributed import LocalCluster

    from slamlib.experiments import sweep

    if not priorities:  # the check can fail: drives first, all three are on disk at once
        monkeypatch.setattr(sweep, "RUN_PRIORITY", sweep.DRIVE_PRIORITY - 1)
    with dask.config.set({"distributed.scheduler.worker-saturation": float("inf")}):
        with LocalCluster(
            n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
        ) as c:
            on_disk = _drives_on_disk_per_row(c.scheduler_address, tmp_path / "data")
    assert (max(on_disk) <= 2) == priorities, on_disk


def test_threads_per_run_shares_the_cores_out_among_the_workers():
    from slamlib.experiments.sweep import threads_per_run

    assert [threads_per_run(w, cores=8) for w in (1, 2, 3, 8, 16)] == [8, 4, 2, 1, 1]
    assert threads_per_run(None, cores=8) == 1  # one worker per core
    assert threads_per_run(None) == 1


def test_sweep_threads_is_the_one_rule_for_the_local_cluster_and_another_scheduler():
    import os

    from slamlib.experiments.sweep import sweep_threads, threads_per_run

    assert sweep_threads(3, None, 2) == 3  # given: kept, on any scheduler
    assert sweep_threads(3, "tcp://127.0.0.1:1", None) == 3
    assert sweep_threads(None, None, 1) == threads_per_run(1) == os.cpu_count()
    assert sweep_threads(None, None, None) == 1
    assert sweep_threads(None, "tcp://127.0.0.1:1", 1) is None  # the workers' own


def test_each_run_uses_the_threads_it_is_given(cluster, tmp_path, monkeypatch):
    """slamlib's Numba loops and KISS-ICP's registration run on the sweep's ``threads`` in the worker."""
    import numba

    import slamlib.peers
    import slamlib.slam3d

    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("one Numba thread: nothing to limit")
    seen = []
    run_drive, kiss = slamlib.slam3d.run_drive, slamlib.peers.kiss_icp_poses

    def spy_run_drive(*a, **kw):
        seen.append(("slamlib", numba.get_num_threads()))
        return run_drive(*a, **kw)

    def spy_kiss(*a, **kw):
        seen.append(("kiss_icp", kw["max_threads"]))
        return kiss(*a, **kw)

    # the cluster's worker runs in this process
    monkeypatch.setattr(slamlib.slam3d, "run_drive", spy_run_drive)
    monkeypatch.setattr(slamlib.peers, "kiss_icp_poses", spy_kiss)
    tasks = sweep_tasks(
        ["loop"], [0], ["raw"], ["slamlib", "kiss_icp"], [{"particles": 20}], (0, 4)
    )
    address = cluster.scheduler_address
    run_sweep(tasks, tmp_path / "data", scheduler=address, progress=False, threads=1)
    assert sorted(seen) == [("kiss_icp", 1), ("slamlib", 1)]
    seen.clear()
    run_sweep(tasks, tmp_path / "data", scheduler=address, progress=False, threads=2)
    assert sorted(seen) == [("kiss_icp", 2), ("slamlib", 2)]


def test_a_sweep_closes_loops_and_runs_kiss_slam_on_the_same_drive(cluster, tmp_path):
    """``slamlib_loop_closure`` is slamlib's filter with the back end: on a drive too short for a loop the back
    end has nothing to correct, so its row is slamlib's. Likewise KISS-SLAM's is KISS-ICP's, its odometry."""
    methods = ["slamlib", "slamlib_loop_closure", "kiss_icp", "kiss_slam"]
    tasks = sweep_tasks(["loop"], [0], ["odometry"], methods, [{"particles": 40}], (0, 6))
    rows = run_sweep(
        tasks, tmp_path / "data", scheduler=cluster.scheduler_address, progress=False
    )
    by = {r["method"]: r for r in rows}
    assert set(by) == set(methods) and len(rows) == len(methods)
    assert len(list((tmp_path / "data").iterdir())) == 1  # one drive, generated once
    assert by["slamlib_loop_closure"]["settings"] == '{"particles": 40}'
    assert by["kiss_slam"]["settings"] == ""
    assert by["slamlib_loop_closure"]["ate_rmse_m"] == pytest.approx(
        by["slamlib"]["ate_rmse_m"], abs=1e-9
    )
    assert by["kiss_slam"]["ate_rmse_m"] == pytest.approx(
        by["kiss_icp"]["ate_rmse_m"], rel=1e-6
    )
    assert all(math.isfinite(r["ate_rmse_m"]) and r["fps"] > 0 for r in rows)


def test_a_failing_task_names_itself_in_one_line_and_the_others_rows_are_kept(
    cluster, tmp_path
):
    """One bad task among good ones: the good ones finish and reach the journal, the error is one line naming the
    bad task, and a re-run with the journal runs nothing again (no cluster is even started)."""
    from slamlib.experiments.sweep import SweepTaskError, append_journal, read_journal

    good = SweepTask("loop", (0, 6), 0, "raw", "slamlib", {"particles": 20})
    bad = SweepTask("loop", (0, 6), 0, "raw", "slamlib", {"particles": 0})
    journal = tmp_path / "j.jsonl"
    with pytest.raises(SweepTaskError) as err:
        run_sweep(
            [bad, good],
            tmp_path,
            scheduler=cluster.scheduler_address,
            progress=False,
            on_row=lambda task, row: append_journal(journal, task, row),
        )
    message = str(err.value)
    assert "\n" not in message and err.value.task == bad
    assert message.startswith(
        'sweep task failed (route loop, frames 0:6, seed 0, raw, slamlib {"particles": 0}): ValueError: '
    )
    done = read_journal(journal)
    assert len(done) == 1
    with open(journal, "a") as f:
        f.write('{"task": "cut sho')  # a kill in the middle of an append
    assert read_journal(journal) == done
    rows = run_sweep(
        [good], tmp_path / "unused", scheduler="tcp://127.0.0.1:1", done=done
    )
    assert rows == list(done.values())


def test_sweep_takes_fresh_roads_by_seed():
    from slamlib.commands.sweep import _routes

    assert _routes("07, random:12,random:0") == ["07", "random:12", "random:0"]


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--routes", "99"], "--routes: route must be one of .*got '99'"),
        (["--routes", "07,random:x"], "--routes: .* or random:SEED .*got 'random:x'"),
        (["--seeds", "a"], "--seeds must be comma-separated int"),
        (["--seeds", "-1"], "--seeds must be >= 0"),
        (["--layouts", "bag"], "--layouts: bag not one of"),
        (["--particles", "0"], "--particles must be in"),
        (["--anneal-rounds", "-1"], "--anneal-rounds must be in"),
        (["--tilt-sigma", "nan"], "--tilt-sigma must be a finite number"),
        (["--workers", "0"], "--workers must be >= 1"),
        (["--routes", "07,loop", "--frames", "5:9"], "always starts at its beginning"),
        (["--set", "bogus=1"], "--set: unknown SLAM3D setting 'bogus'"),
        (["--set", "tuning_gain=0"], "--set: tuning_gain must be finite and > 0"),
        (["--set", "self_tuning"], "--set: expected NAME=VALUE, got 'self_tuning'"),
        (["--set", "tuning_floor=[1, 2]"], "--set: tuning_floor must be 6 finite"),
        (["--start-tilt", "0.03"], "--start-tilt: start_tilt must be \\(roll, pitch\\)"),
        (["--start-tilt", "0.03,x"], "--start-tilt: could not convert"),
        (["--start-tilt", "0.6,0"], "--start-tilt: start_tilt must be"),
    ],
)
def test_sweep_options_are_checked_before_any_work(tmp_path, argv, message):
    from slamlib.cli import main

    with pytest.raises(SystemExit, match=message):
        main(["sweep", "--out", str(tmp_path / "o")] + argv)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    "word, value", [("0.003", 0.003), ("auto", "auto"), ("Adaptive", "adaptive")]
)
def test_sweep_tilt_sigma_reaches_every_slamlib_setting(
    tmp_path, monkeypatch, word, value
):
    """``--tilt-sigma`` as a number or a word: every setting the sweep's tasks are made of carries it."""
    import slamlib.experiments.sweep as sweep_module
    from slamlib.cli import main

    seen = []

    def tasks(routes, seeds, layouts, methods, settings, *rest):
        seen.extend(settings)
        raise SystemExit("stop before any run")

    monkeypatch.setattr(sweep_module, "sweep_tasks", tasks)
    argv = ["sweep", "--out", str(tmp_path / "o"), "--particles", "20,40"]
    with pytest.raises(SystemExit, match="stop before any run"):
        main(argv + ["--tilt-sigma", word])
    assert seen == [
        {"particles": 20, "tilt_sigma": value},
        {"particles": 40, "tilt_sigma": value},
    ]


def test_sweep_set_gives_any_setting_to_every_slamlib_run():
    """``--set NAME=VALUE`` (repeatable): VALUE read as JSON, else a word; added to every setting."""
    from slamlib.commands.sweep import parse_settings

    assert parse_settings(
        [
            "self_tuning=false",
            "tilt_sigma=auto",
            "collapse_ess=0.05",
            "tuning_floor=[0,0,0,0,0,0]",
        ]
    ) == {
        "self_tuning": False,
        "tilt_sigma": "auto",
        "collapse_ess": 0.05,
        "tuning_floor": [0, 0, 0, 0, 0, 0],
    }


def test_a_seed_among_the_settings_is_the_filters_on_the_same_drive(cluster, tmp_path):
    """The drive's seed is the filter's too, unless the settings name a ``seed``: then the same drive is run again
    with that filter seed (repeats for development)."""
    settings = [
        {"particles": 40},
        {"particles": 40, "seed": 0},
        {"particles": 40, "seed": 5},
    ]
    tasks = sweep_tasks(["loop"], [0], ["raw"], ["slamlib"], settings, (0, 6))
    rows = run_sweep(
        tasks, tmp_path / "data", scheduler=cluster.scheduler_address, progress=False
    )
    errors = {r["settings"]: r["ate_rmse_m"] for r in rows}
    assert len(errors) == 3 and {r["seed"] for r in rows} == {0}
    same, again, other = (errors[json.dumps(s, sort_keys=True)] for s in settings)
    assert same == again != other


def test_sweep_refuses_to_overwrite_its_table(tmp_path):
    from slamlib.cli import main

    (tmp_path / "sweep.csv").write_text("mine\n")
    with pytest.raises(SystemExit, match="holds sweep.csv: pass --overwrite"):
        main(["sweep", "--out", str(tmp_path)])
    assert (tmp_path / "sweep.csv").read_text() == "mine\n"


def test_a_start_tilt_reads_the_level_drive_with_gravity_turned(tmp_path, monkeypatch):
    """``DriveOptions.start_tilt``: the drive's folder is the level drive's (only the reading differs), the label
    and the journal's task key name it, the level drive's key is as before, and the run reads the drive through
    :class:`slamlib.synth.tilt.StartTilted`."""
    from slamlib.experiments import sweep as sweep_module
    from slamlib.experiments.sweep import DriveOptions, task_key
    from slamlib.synth.tilt import StartTilted

    level = DriveOptions(True, 1.0, True)
    tilted = DriveOptions(True, 1.0, True, 1.0, (0.0358, 0.009))
    a, b = (
        sweep_tasks(["07"], [0], ["raw"], ["slamlib"], [{}], (0, 5), o)[0]
        for o in (level, tilted)
    )
    assert a.drive_key() == b.drive_key() and task_key(a) != task_key(b)
    assert "start_tilt" not in task_key(a)  # journals of level drives keep their keys
    assert (
        tilted.label() == "distortion, traffic x1, bias walk, start tilted 35.8, 9 mrad"
    )
    import slamlib.kitti

    class _Drive:
        def ground_truth_poses(self, frame="imu"):
            return np.eye(4)[None]

    monkeypatch.setattr(slamlib.kitti, "KittiRawDrive", lambda *a: _Drive())
    read = sweep_module._frames_of(b, str(tmp_path))
    assert isinstance(read, StartTilted) and read.start_tilt == (0.0358, 0.009)
    assert isinstance(sweep_module._frames_of(a, str(tmp_path)), _Drive)


def test_drive_options_name_their_drives_and_reach_the_generator(monkeypatch, tmp_path):
    """Drive options: drives without any keep their old names; each option gives another drive; the generator gets
    sweep distortion, traffic at the asked density and wandering biases (no IMU noise in the odometry layout); the
    label lists what is on."""
    from slamlib import synth
    from slamlib.experiments.sweep import DriveOptions, drive_task
    from slamlib.synth.traffic import KITTI_CITY

    plain = sweep_tasks(["07"], [0], ["raw"], ["slamlib"], [{}], (0, 5))[0]
    same = sweep_tasks(["07"], [0], ["raw"], ["slamlib"], [{}], (0, 5), DriveOptions())[0]
    assert plain.drive_key() == same.drive_key() and plain.drive.label() == ""
    options = [
        DriveOptions(distortion=True),
        DriveOptions(traffic=2.0),
        DriveOptions(bias_walk=True),
        DriveOptions(True, 1.0, True),
        DriveOptions(True, 1.0, True, 2.0),
        DriveOptions(imu_noise=0.5),
    ]
    keys = {
        sweep_tasks(["07"], [0], ["raw"], ["slamlib"], [{}], (0, 5), o)[0].drive_key()
        for o in options
    }
    assert len(keys) == 6 and plain.drive_key() not in keys
    assert DriveOptions(True, 2.0, True).label() == "distortion, traffic x2, bias walk"
    assert DriveOptions(bias_walk=True, imu_noise=2).label() == "bias walk, IMU noise x2"
    with pytest.raises(ValueError, match="traffic must be a finite number >= 0"):
        DriveOptions(traffic=-1.0)
    with pytest.raises(ValueError, match="imu_noise must be a finite number >= 0"):
        DriveOptions(imu_noise=float("nan"))
    calls = []
    monkeypatch.setattr(synth, "write_drive", lambda *a, **kw: calls.append(("raw", kw)))
    monkeypatch.setattr(
        synth, "write_sequence", lambda *a, **kw: calls.append(("odometry", kw))
    )
    for layout in ("raw", "odometry"):
        drive_task(
            sweep_tasks(
                ["07"],
                [0],
                [layout],
                ["slamlib"],
                [{}],
                (0, 5),
                DriveOptions(True, 2.0, True),
            )[0],
            tmp_path,
        )
    for layout in ("raw", "odometry"):
        drive_task(
            sweep_tasks(
                ["07"],
                [1],
                [layout],
                ["slamlib"],
                [{}],
                (0, 5),
                DriveOptions(imu_noise=2),
            )[0],
            tmp_path,
        )
    (raw, kw_raw), (odo, kw_odo), (_, kw_x2), (_, kw_odo_x2) = calls
    assert kw_raw["distortion"] is True and kw_raw["traffic"] == KITTI_CITY.scaled(2.0)
    assert kw_raw["noise"] == synth.WANDERING_BIASES and "noise" not in kw_odo
    assert kw_x2["noise"] == synth.ImuNoise().scaled(2) != synth.ImuNoise()
    assert "noise" not in kw_odo_x2
    assert kw_odo["distortion"] is True and kw_odo["traffic"] == KITTI_CITY.scaled(2.0)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--traffic", "0"], r"--traffic must be a density scale in \(0, 10\], got "),
        (["--traffic", "11"], r"--traffic must be a density scale in \(0, 10\], got "),
        (["--traffic", "nan"], r"--traffic must be a density scale in \(0, 10\], got "),
        (
            ["--imu-noise", "-1"],
            r"--imu-noise must be a finite number in \[0, 100\], got -1",
        ),
        (
            ["--imu-noise", "inf"],
            r"--imu-noise must be a finite number in \[0, 100\], got inf",
        ),
    ],
)
def test_sweep_drive_options_are_checked(tmp_path, argv, message):
    from slamlib.cli import main

    with pytest.raises(SystemExit, match=message):
        main(["sweep", "--out", str(tmp_path / "o")] + argv)
    assert not (tmp_path / "o").exists()


def test_a_sweep_with_every_drive_option_runs_end_to_end(cluster, tmp_path):
    """Swept scans, traffic and wandering biases on, slamlib de-skewing, KISS-ICP beside it: every run gives a
    finite result, the table names the drive options, the drive's marker records them."""
    import json

    from slamlib.experiments.sweep import DriveOptions
    from slamlib.synth.writer import MARKER, drive_dir

    tasks = sweep_tasks(
        ["loop"],
        [0],
        ["raw"],
        ["slamlib", "kiss_icp"],
        [{"particles": 40, "deskew": True}],
        (0, 6),
        DriveOptions(True, 1.0, True),
    )
    rows = run_sweep(
        tasks, tmp_path / "data", scheduler=cluster.scheduler_address, progress=False
    )
    assert [r["drive"] for r in rows] == ["distortion, traffic x1, bias walk"] * 2
    assert all(math.isfinite(r["ate_rmse_m"]) for r in rows)
    assert json.loads(rows[0]["settings"]) == {"deskew": True, "particles": 40}
    marker = json.loads(
        (
            drive_dir(tmp_path / "data" / tasks[0].drive_key(), "2011_09_26", 1) / MARKER
        ).read_text()
    )
    assert (
        marker["distortion"] is True
        and "traffic" in marker
        and marker["noise"]["gyro_bias_walk"] > 0
    )


def test_the_sweep_command_writes_its_table_plot_and_provenance(
    cluster, tmp_path, capsys
):
    from slamlib.cli import main
    from slamlib.synth import GENERATOR_VERSION

    out = tmp_path / "out"
    assert (
        main(
            [
                "sweep",
                "--out",
                str(out),
                "--data",
                str(tmp_path / "data"),
                "--routes",
                "loop",
                "--frames",
                "4",
                "--seeds",
                "0",
                "--methods",
                "slamlib",
                "--particles",
                "20",
                "--anneal-rounds",
                "1",
                "--tilt-sigma",
                "0.01",
                "--scan-match",
                "--no-progress",
                "--scheduler",
                cluster.scheduler_address,
            ]
        )
        == 0
    )
    rows = read_table(out / "sweep.csv")
    assert [(r["route"], r["seed"], r["method"], r["frames"]) for r in rows] == [
        ("loop", 0, "slamlib", 4)
    ]
    assert json.loads(rows[0]["settings"]) == {
        "particles": 20,
        "anneal_rounds": 1,
        "tilt_sigma": 0.01,
        "scan_match": True,
    }
    info = json.loads((out / "sweep.json").read_text())
    assert (
        info["command"].startswith("slamlib sweep ")
        and "--particles 20" in info["command"]
    )
    assert (
        info["generator_version"] == GENERATOR_VERSION
        and info["scheduler"] == cluster.scheduler_address
    )
    assert info["threads_per_run"] is None  # another scheduler's workers keep their own
    assert info["machine"]["cores"] >= 1 and info["seconds"] > 0
    assert (
        out / "sweep.png"
    ).stat().st_size > 0 and "sweep.json" in capsys.readouterr().out


def test_sweep_command_keeps_finished_rows_and_resumes_after_a_failed_task(
    tmp_path, monkeypatch, capsys
):
    """``slamlib sweep``: a task failing after another finished is one line naming it, the finished row is kept
    in ``sweep.resume.jsonl``; the same command again runs only the rest and writes the table (whole, no journal
    or temporary left)."""
    import slamlib.experiments.sweep as sweep_module
    from slamlib.cli import main
    from slamlib.commands.sweep import JOURNAL
    from slamlib.experiments.sweep import COLUMNS, SweepTaskError

    calls = []

    def fake_run_sweep(tasks, data, done=None, on_row=None, **kw):
        calls.append((len(tasks), dict(done or {}), kw["discard_drives"], kw["threads"]))
        rows = [
            dict(
                {k: 0.5 for k in COLUMNS},
                route=t.route,
                frames=4,
                seed=t.seed,
                layout=t.layout,
                drive="",
                method=t.method,
                settings="",
            )
            for t in tasks
        ]
        if len(calls) == 1:
            on_row(tasks[0], rows[0])
            raise SweepTaskError(tasks[1], ValueError("particles must be >= 1\nmore"))
        assert len(done) == 1  # the row kept from the first run
        return rows

    monkeypatch.setattr(sweep_module, "run_sweep", fake_run_sweep)
    out = tmp_path / "o"
    argv = ["sweep", "--out", str(out), "--methods", "slamlib", "--no-progress"]
    with pytest.raises(SystemExit) as exc:
        main(argv)
    message = str(exc.value.code)
    assert "\n" not in message
    assert message.startswith(
        "slamlib sweep: sweep task failed (route 07, frames 0:150, seed 1, "
    )
    assert message.endswith(
        f"ValueError: particles must be >= 1; the 1 runs finished are kept in {out / JOURNAL}: "
        "the same command runs only the rest"
    )
    assert sorted(p.name for p in out.iterdir()) == [JOURNAL]
    # the rest, removing each drive once its runs are done (--discard-drives reaches the sweep)
    assert main(argv + ["--discard-drives", "--workers", "1"]) == 0
    assert [c[2] for c in calls] == [False, True]
    # on the local cluster the cores are shared out among the workers (one per core by default)
    assert [c[3] for c in calls] == [1, os.cpu_count()]
    assert (
        json.loads((out / "sweep.json").read_text())["threads_per_run"] == os.cpu_count()
    )
    assert "resuming: 1 runs already done" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == [
        "sweep.csv",
        "sweep.json",
        "sweep.png",
    ]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]


def test_a_drive_another_process_is_writing_is_waited_for(tmp_path, capsys):
    """Two sweeps sharing ``--data``: ``drive_task`` waits while another process holds the drive's lock, then
    uses the drive (here: writes it, the other having written nothing) instead of failing."""
    import subprocess
    import sys
    import textwrap
    import time

    from slamlib.experiments.sweep import drive_task
    from slamlib.synth.writer import drive_dir, read_marker

    task = SweepTask("loop", (0, 4), 0, "raw", "slamlib")
    folder = drive_dir(tmp_path / task.drive_key(), "2011_09_26", 1)
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            textwrap.dedent(
                f"""
                import time
                from slamlib.atomic import folder_lock
                with folder_lock({str(folder)!r}):
                    print("held", flush=True)
                    time.sleep(1.5)
                """
            ),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    assert holder.stdout.readline().strip() == "held"
    t0 = time.monotonic()
    base = drive_task(task, tmp_path)
    assert time.monotonic() - t0 > 0.5
    holder.wait(10)
    assert read_marker(folder)["frames"] == 4 and base == str(tmp_path / task.drive_key())
    assert "is being written by process" in capsys.readouterr().err
