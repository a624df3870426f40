"""slamlib.results: one committed value per fact, with the machine that measured it."""

from __future__ import annotations

import math

import pytest

from slamlib import results
from slamlib.paths import load_bench_result
from slamlib.results import FACTS, MEASURED_TWICE, MEASURED_TWICE_TOLERANCE, fact


@pytest.mark.parametrize("key", sorted(FACTS))
def test_every_fact_reads_a_number_from_its_committed_result(key):
    stated = fact(key)
    assert math.isfinite(stated.value) and stated.value > 0, stated
    assert stated.bench == FACTS[key].bench and stated.what
    machine = load_bench_result(stated.bench)["machine"]
    assert machine["cpu"] in stated.machine and stated.date == machine["utc"][:10]
    assert key.replace("-", "").isalnum() and key == key.lower()  # a glue name


@pytest.mark.parametrize("key", sorted(MEASURED_TWICE))
def test_a_fact_two_benchmarks_measure_has_one_value(key):
    """Both benchmarks run the same deterministic configuration: their committed values agree only when they
    ran on the same code, so a rerun of one without the other fails here."""
    bench, read = MEASURED_TWICE[key]
    other = read(load_bench_result(bench))
    assert bench != FACTS[key].bench
    assert abs(fact(key).value - other) <= MEASURED_TWICE_TOLERANCE, (
        f"{key}: {fact(key).value} in {FACTS[key].bench}.json but {other} in {bench}.json"
    )


def test_the_committed_loop_benchmark_is_a_whole_run_on_its_named_seeds():
    """``loops.json`` holds every route at every seed that ``benchmarks.loops`` names, whole routes (not the
    ``--quick`` smoke test), and the short drive without revisits at each seed: a partial or stale run fails."""
    from itertools import product

    from benchmarks import loops as bench

    loops = load_bench_result("loops")
    assert loops["quick"] is False and loops["seeds"] == list(bench.SEEDS)
    assert [(r["route"], r["seed"]) for r in loops["drives"]] == [
        (route, seed) for seed, route in product(bench.SEEDS, bench.ROUTES)
    ]
    assert all(r["frames"] > 1000 for r in loops["drives"])
    assert [(r["seed"], r["frames"]) for r in loops["no_revisit"]] == [
        (seed, list(bench.NO_REVISIT_FRAMES)) for seed in bench.SEEDS
    ]


def test_the_loop_route_benchmark_is_the_loop_benchmarks_run_of_its_drive():
    """``loops_route`` keeps one drive of ``loops`` whole for chapter 10's figures; slamlib is deterministic at a
    seed, so its committed errors agree with that drive's row only when both ran the same code."""
    route = load_bench_result("loops_route")
    row = next(
        r
        for r in load_bench_result("loops")["drives"]
        if (r["route"], r["seed"]) == (route["route"], route["seed"])
    )
    assert route["quick"] is False and route["frames"] == row["frames"]
    for method in ("slamlib", "slamlib_loop_closure"):
        for key in ("ate_rmse_m", "kitti_t_err_percent"):
            assert (
                abs(route[method][key] - row[method][key]) <= MEASURED_TWICE_TOLERANCE
            ), (
                method,
                key,
            )
    kept = [
        (c["query_frame"], c["reference_frame"]) for c in route["closures"] if c["kept"]
    ]
    assert kept == [
        (c["query_frame"], c["reference_frame"]) for c in row["closures"] if c["kept"]
    ]
    n = len(route["distance_m"])
    assert all(len(p) == n for p in route["positions"].values())


def test_an_unknown_fact_names_the_known_ones():
    with pytest.raises(KeyError, match="default-fps"):
        fact("default-fsp")


def test_a_missing_result_names_the_command(monkeypatch, tmp_path):
    monkeypatch.setenv("SLAMLIB_BENCH_RESULTS", str(tmp_path))
    with pytest.raises(FileNotFoundError, match="slamlib bench slam3d"):
        fact("default-fps")


def test_facts_are_glued_under_their_keys_with_their_machine(monkeypatch):
    import myst_nb

    glued = {}
    monkeypatch.setattr(
        myst_nb, "glue", lambda name, value, display=True: glued.__setitem__(name, value)
    )
    values = results.glue_facts("default-fps", "whole-ate-m")
    assert values == {k: fact(k).value for k in ("default-fps", "whole-ate-m")}
    assert glued["default-fps"] == values["default-fps"]
    assert glued["whole-ate-m-machine"] == results.machine_label("slam3d")
    assert results.machine_label("slam3d").endswith(fact("default-fps").date)


def test_live_timings_are_labelled_as_this_build_machines():
    assert results.this_machine().startswith("on the machine that built this page (")
