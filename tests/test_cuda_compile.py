"""Every CUDA kernel compiles for real cards (sm_80 = A100, sm_90 = H100) with no register spill: no GPU needed.

The simulator tests (test_kernels_cuda.py) check the arithmetic; this checks what NVVM and ptxas make of the
kernels. The argument types come from the host wrappers themselves (each run once in the simulator, launches
recorded), the compile runs in a subprocess without the simulator (conftest.py turns it on for this session):
see :mod:`slamlib.kernels.cuda_static`. NVVM and nvJitLink come from the ``cudacompile`` extra (``make setup``).
"""

import pytest

from slamlib.kernels import cuda as kc
from slamlib.kernels import cuda_static as cs

#: Block sizes of the per-block-size kernels compiled here: the default and twice it.
BLOCK_SIZES = (kc.SCORE_THREADS, 2 * kc.SCORE_THREADS)


@pytest.fixture(scope="module")
def report():
    return cs.static_report(cs.DEFAULT_CCS, BLOCK_SIZES)


def test_every_kernel_is_launched_by_a_wrapper(report):
    factories = {
        name
        for name, obj in vars(kc).items()
        if name.endswith("_kernels") and hasattr(obj, "cache_info")
    }
    # a new per-block-size factory must be listed there
    assert factories == set(cs.FACTORIES)
    kernels = set(cs.module_kernels(kc)) | set(cs.BLOCK_KERNELS)
    assert len(kernels) >= 12
    launched = {launch["kernel"] for launch in report["launches"]}
    assert launched == kernels, (
        f"kernels no wrapper launched: {sorted(kernels - launched)}"
    )
    sizes = {
        launch["threads"]
        for launch in report["launches"]
        if launch["kernel"] in cs.BLOCK_KERNELS
    }
    assert sizes == set(BLOCK_SIZES)


def test_every_kernel_compiles_for_sm80_and_sm90_without_spills(report):
    assert len(report["results"]) == len(report["launches"]) * len(cs.DEFAULT_CCS)
    assert {tuple(r["cc"]) for r in report["results"]} == set(cs.DEFAULT_CCS)
    problems = []
    for r in report["results"]:
        where = f"{r['kernel']} (threads={r['threads']}, sm_{r['cc'][0]}{r['cc'][1]})"
        if not r["ok"]:
            problems.append(f"{where} does not compile: {r['error']}")
        elif r["spill_stores_bytes"] or r["spill_loads_bytes"]:
            problems.append(
                f"{where} spills registers: {r['spill_stores_bytes']} B stored, "
                f"{r['spill_loads_bytes']} B loaded ({r['registers']} registers)"
            )
        elif r["local_bytes"]:
            problems.append(f"{where} uses {r['local_bytes']} B of local memory")
    assert not problems, "\n".join(problems)
    for r in report["results"]:
        assert 0 < r["registers"] <= 255 and r["occupancy"]["blocks_per_sm"] >= 1
        if (
            r["kernel"] in cs.BLOCK_KERNELS
        ):  # the shared float64 array of the reduction / scan
            assert r["shared_bytes"] >= 8 * r["threads"]


LOG = """ptxas info    : Function properties for helper
ptxas         .     16 bytes stack frame, 8 bytes spill stores, 12 bytes spill loads
ptxas info    : Compiling entry function 'kern' for 'sm_80'
ptxas info    : Function properties for kern
ptxas         .     0 bytes stack frame, 4 bytes spill stores, 4 bytes spill loads
ptxas info    : Used 255 registers, used 1 barriers
info    : Function properties for 'kern':
info    : used 255 registers, used 1 barriers, 16 stack, 1024 bytes smem, 1048 bytes cmem[0], 0 bytes lmem
"""


def test_parse_ptxas_log_counts_the_spills_of_every_function():
    got = cs.parse_ptxas_log(LOG, "kern")
    assert got == {
        "registers": 255,
        "stack_bytes": 16,
        "shared_bytes": 1024,
        "local_bytes": 0,
        "spill_stores_bytes": 12,
        "spill_loads_bytes": 16,
    }
    clean = LOG.replace("8 bytes spill stores, 12", "0 bytes spill stores, 0").replace(
        "4 bytes spill", "0 bytes spill"
    )
    assert cs.parse_ptxas_log(clean, "kern")["spill_stores_bytes"] == 0
    with pytest.raises(ValueError, match="no resource summary"):
        cs.parse_ptxas_log(LOG, "other")


def test_occupancy_from_the_documented_limits():
    # 32 registers x 128 threads, no shared memory: 16 blocks of 4 warps fill the 64 warps
    assert cs.occupancy(32, 0, 128, "H100") == {
        "blocks_per_sm": 16,
        "limited_by": "warps",
        "active_warps": 64,
        "occupancy": 1.0,
    }
    # 56 registers: 56 * 32 = 1792 per warp, 65536 // 1792 = 36 warps -> 9 blocks of 4 warps
    assert cs.occupancy(56, 0, 128, "A100")["blocks_per_sm"] == 9
    assert cs.occupancy(56, 0, 128, "A100")["limited_by"] == "registers"
    # 107 registers round up to 3584 per warp: 18 warps -> 4 blocks, 16 of 64 warps
    assert cs.occupancy(107, 2048, 128, "H100")["occupancy"] == 0.25
    # 48 KB of shared memory per block: 164 KB // 49 KB = 3 blocks on an A100
    assert cs.occupancy(16, 48 * 1024, 32, "A100") == {
        "blocks_per_sm": 3,
        "limited_by": "shared",
        "active_warps": 3,
        "occupancy": 3 / 64,
    }
    # tiny blocks: at most 32 blocks per SM
    assert cs.occupancy(16, 0, 32, "H100")["limited_by"] == "blocks"


def test_type_specs_round_trip():
    from numba.core import types

    for t in (
        types.Array(types.float32, 2, "C"),
        types.Array(types.int64, 1, "A"),
        types.int64,
        types.float64,
        types.boolean,
    ):
        assert cs.spec_type(cs.type_spec(t)) == t


def test_committed_static_report_covers_every_kernel_on_both_cards():
    """benchmarks/results/cuda-static.json (``slamlib bench cuda --static``), which the kernels chapter shows."""
    from slamlib.paths import load_bench_result

    result = load_bench_result("cuda-static")
    assert result is not None and result["static_analysis"] is True
    kernels = set(cs.module_kernels(kc)) | set(cs.BLOCK_KERNELS)
    for gpu in cs.GPUS:
        rows = [r for r in result["rows"] if r["gpu"] == gpu]
        assert {r["kernel"] for r in rows} == kernels
        assert all(
            r["ok"] and r["spill_stores_bytes"] == 0 and r["spill_loads_bytes"] == 0
            for r in rows
        )
        assert all(0 < r["occ_occupancy"] <= 1 for r in rows)


def test_bench_static_is_refused_by_benchmarks_without_it(tmp_path):
    import subprocess
    import sys

    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "slamlib.cli",
            "bench",
            "kernels",
            "--static",
            "--out",
            str(tmp_path / "x.json"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert res.returncode == 2 and "no --static" in res.stderr
    assert not (tmp_path / "x.json").exists()
