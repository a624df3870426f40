"""``slamlib bench scaling``: the fits it reports recover a known line, and a tiny run writes the fields the
benchmarks chapter reads."""

import importlib
import json

import numpy as np
import pytest

from slamlib.cli import main
from slamlib.commands.bench import load_benchmarks


@pytest.fixture()
def scaling():
    load_benchmarks()  # the checkout's benchmarks package, importable from any folder
    return importlib.import_module("benchmarks.scaling")


def test_fit_recovers_a_line_and_reports_how_well(scaling):
    x = np.array([100.0, 300.0, 1000.0, 3000.0])
    f = scaling._fit(x, 12.5 + 0.02 * x)
    assert (
        np.isclose(f["intercept"], 12.5)
        and np.isclose(f["slope"], 0.02)
        and np.isclose(f["r2"], 1.0)
    )
    noisy = scaling._fit(x, 12.5 + 0.02 * x + np.array([3.0, -3.0, 3.0, -3.0]))
    assert noisy["r2"] < 1.0 and abs(noisy["slope"] - 0.02) < 0.01


def test_quick_run_writes_sweeps_fits_and_route(scaling, tmp_path, monkeypatch):
    monkeypatch.setenv("SLAMLIB_BENCH_RESULTS", str(tmp_path))
    monkeypatch.setattr(scaling, "QUICK_FRAMES", (0, 6))
    monkeypatch.setattr(scaling, "QUICK_PARTICLES", (20, 40))
    monkeypatch.setattr(scaling, "QUICK_POINTS", (100, 200))
    runs, row = [], scaling._row  # the runs behind the sweep rows, in order
    monkeypatch.setattr(
        scaling, "_row", lambda run, *a, **kw: runs.append(run) or row(run, *a, **kw)
    )
    assert main(["bench", "scaling", "--quick"]) == 0
    d = json.loads((tmp_path / "scaling-quick.json").read_text())
    assert [r["particles"] for r in d["particles"]] == [20, 40]
    assert [r["points"] for r in d["points"]] == [100, 200]
    for r, run in zip(d["particles"] + d["points"], runs, strict=True):
        assert r["frames"] == 6 and 0 < r["frame_ms_best"] <= r["frame_ms_median"]
        # ATE: the RMSE of the position errors, no alignment (both start at the origin), to 4 decimals
        err = run.poses[:, :3, 3] - run.ground_truth[:, :3, 3]
        ate = np.sqrt(np.mean(np.sum(err**2, axis=1)))
        assert ate > 0 and r["ate_rmse_m"] == pytest.approx(ate, abs=5e-5 + 1e-12)
    assert {"intercept", "slope", "r2"} <= set(d["fit_ms_vs_particles"]) and "slope" in d[
        "fit_ms_vs_points"
    ]
    route = d["route"]
    assert (
        route["frames"] == len(route["frame_ms"]) == 6
        and route["map_elements"][0][0] == 0
    )
    assert "slope" in route["fit_frame_ms_vs_frame"]
