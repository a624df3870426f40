"""``slamlib bench transform --quick`` and ``slamlib bench particles --quick``: they run and write the rows the
book reads (fields named here), with the copy limit beside every kernel row and the GPU rows labelled."""

import json

import pytest

from slamlib.cli import main
from slamlib.commands.bench import load_benchmarks


@pytest.fixture()
def results(tmp_path, monkeypatch):
    monkeypatch.setenv("SLAMLIB_BENCH_RESULTS", str(tmp_path))
    return tmp_path


def test_transform_quick_writes_kernel_copy_program_and_gpu_rows(results):
    assert main(["bench", "transform", "--quick"]) == 0
    d = json.loads((results / "transform-quick.json").read_text())
    sizes = d["sizes"]
    assert sizes == [1000, 10000, 100000] and d["quick"] is True and d["threads"] >= 1
    assert (
        d["seed"]["whole_program_s"]["10000000"] == 0.374841
        and d["seed"]["whole_program_s"]["100000000"] is None
    )
    kinds = {(r["backend"], r["variant"], r["n"]) for r in d["kernel_rows"]}
    for n in sizes:
        assert {
            ("numpy", "alloc", n),
            ("cpu", "alloc", n),
            ("cpu", "out", n),
            ("cpu", "inplace", n),
            ("cpu", "out_1thread", n),
            ("cpu", "inplace_1thread", n),
        } <= kinds
        assert {r["method"] for r in d["copy_rows"] if r["n"] == n} == {
            "numpy.copyto",
            "numba_parallel_copy",
        }
    for r in d["kernel_rows"]:
        assert r["bytes_moved"] == 24 * r["n"] and 0 < r["min_s"] <= r["median_s"]
        # allocating rows apart
        assert r["rounds"] == ("fresh" if r["variant"] == "alloc" else "reuse"), r
        fastest = min(r["copyto_median_s"], r["parallel_copy_median_s"])
        assert r["ratio_to_fastest_copy"] == pytest.approx(r["median_s"] / fastest)
        assert r["ratio_to_copyto"] == pytest.approx(r["median_s"] / r["copyto_median_s"])
    prog = {(r["backend"], r["mode"], r["n"]): r for r in d["program_rows"]}
    for n in sizes:
        for key in (("cpu", "inplace", n), ("cpu", "out", n), ("numpy", "inplace", n)):
            r = prog[key]
            assert (
                r["ok"]
                and r["within_budget"]
                and r["peak_rss_bytes"] <= r["budget_bytes"]
            )
            assert r["startup_s"] == pytest.approx(
                r["interpreter_s"] + r["import_s"] + r["jit_s"], rel=0.5
            )
            assert r["wall_s"] >= r["startup_s"] > 0 and 0 < r["kernel_s"] < r["wall_s"]
            assert r["seed_wall_s"] == d["seed"]["whole_program_s"][str(n)]
    gpu = d["gpu_rows"]
    assert {r["n"] for r in gpu} == set(sizes)
    for r in gpu:
        if r["projected"]:
            assert r["label"] == "projected, not measured"
            assert r["kernel_s"] == pytest.approx(
                24 * r["n"] / r["bandwidth_bytes_per_s"]
            )
    if all(
        r["projected"] for r in gpu
    ):  # this machine has no GPU (tests run in the CUDA simulator)
        assert {r["card"] for r in gpu} == {
            "H100 SXM (HBM3)",
            "K40 (GDDR5, the seed's card)",
        }


def test_particles_quick_writes_rates_beside_the_seed(results):
    assert main(["bench", "particles", "--quick"]) == 0
    d = json.loads((results / "particles-quick.json").read_text())
    assert d["seed_particles_per_s"] == 1.6e8
    variants = {
        "lut_fused",
        "lut_fused_seed_tables",
        "lut_fused_1thread",
        "lut_fused_alloc",
        "lut_fused_soa",
        "lut_fused_soa32",
        "lut_fused_soa32_1thread",
        "lut_drawn",
        "numpy_drawn",
        "philox_drawn",
    }
    assert d["copy"]["particles"] == 10000 and d["copy_gb_per_s"] == pytest.approx(
        d["copy"]["gb_per_s"]
    )
    for P in (1000, 10000):
        rows = {r["variant"]: r for r in d["rows"] if r["particles"] == P}
        assert set(rows) == variants
        for r in rows.values():
            assert r["particles_per_s"] == pytest.approx(P / r["median_s"])
            assert r["ratio_to_seed"] == pytest.approx(r["particles_per_s"] / 1.6e8)
            moved = 2 * r["pose_bytes"] + (96 if r["noise_array"] else 0)
            assert r["limit_particles_per_s"] == pytest.approx(
                d["copy_gb_per_s"] * 1e9 / moved
            )
        assert (
            rows["lut_fused_seed_tables"]["table_entries"] == 256
            and rows["lut_fused"]["table_entries"] == 4096
        )
        assert (
            rows["lut_fused_soa32"]["pose_bytes"] == 48
            and rows["lut_fused_soa"]["pose_bytes"] == 96
        )
        assert (
            rows["lut_fused_soa"]["layout"] == "component-major"
            and rows["lut_fused"]["layout"] == "particle-major"
        )


def test_both_are_registered():
    assert {"transform", "particles"} <= set(load_benchmarks().BENCHMARKS)
