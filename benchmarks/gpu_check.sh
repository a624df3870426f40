#!/usr/bin/env bash
# What a session lent a GPU runs, in one go (CONTRIBUTING.md, "On a machine with a GPU"):
#   1. the CUDA tests on the card instead of Numba's simulator (SLAMLIB_REAL_CUDA=1, tests/conftest.py);
#   2. `slamlib bench cuda` (the kernels, device arrays, synchronised medians);
#   3. the transform benchmark's GPU rows at the seed's sizes, 1e3 to 1e8 points (benchmarks/transform.py);
#   4. the tests' outcome with the card named (benchmarks/gpu_tests_summary.py).
# The three JSON files it writes (cuda.json, transform-gpu.json, cuda-tests.json) are committed under
# benchmarks/results/ with the card they name; chapter 07 shows them.
# Usage: bash benchmarks/gpu_check.sh OUT_DIR   (run from the checkout's root; PYTHON picks the interpreter)
# Each step has its own time limit and the script goes on after a failure, so one broken step still leaves
# the others' results; the exit status is the number of failed steps.
set -u
out=${1:?usage: gpu_check.sh OUT_DIR}
py=${PYTHON:-python3}
mkdir -p "$out"
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
unset NUMBA_ENABLE_CUDASIM
failed=0
step() {  # step SECONDS NAME COMMAND...: run with a limit, log to OUT/NAME.log, count failures
    local limit=$1 name=$2 t0=$SECONDS rc
    shift 2
    echo "== $name"
    timeout "$limit" "$@" >"$out/$name.log" 2>&1
    rc=$?
    tail -n 15 "$out/$name.log"
    echo "== $name: exit $rc after $((SECONDS - t0)) s"
    [ "$rc" -eq 0 ] || failed=$((failed + 1))
}

nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.max.sm --format=csv | tee "$out/nvidia-smi.csv"
$py -m pip list 2>/dev/null | grep -i -E "^(numba|numba-cuda|llvmlite|numpy|cuda-bindings|cuda-core|nvidia-nvvm|nvidia-cuda-nvrtc|scipy|pytest|hypothesis|pykitti) " |
    tee "$out/versions.txt"

step 240 cuda-tests env SLAMLIB_REAL_CUDA=1 $py -m pytest -p no:cacheprovider -q \
    tests/test_kernels_cuda.py tests/test_cuda_tiles.py \
    tests/test_pipeline.py::test_cuda_backend_gives_the_cpu_trajectory \
    --junitxml="$out/cuda-tests.xml"
step 200 bench-cuda $py -c "from slamlib.cli import main; raise SystemExit(main(['bench', 'cuda', '--out', '$out/cuda.json']))"
step 120 transform-gpu $py - "$out/transform-gpu.json" <<'EOF'
import json
import sys

from benchmarks.transform import gpu_rows
from slamlib.machine import describe

SEED_SIZES = [10**k for k in range(3, 9)]  # the seed's table: 1e3 to 1e8 points (out of memory at 1e8 on a K40)
rows = gpu_rows(SEED_SIZES, repeat=7)
assert rows and not rows[0]["projected"], "no GPU: gpu_rows fell back to the projection"
json.dump({"benchmark": "transform-gpu", "machine": describe(), "rows": rows}, open(sys.argv[1], "w"), indent=1)
print(*(f"{r['n']:>10,} points  {r['kernel_s'] * 1e3:9.4f} ms  ({r['card']})" for r in rows), sep="\n")
EOF
step 60 cuda-tests-summary $py -m benchmarks.gpu_tests_summary "$out/cuda-tests.xml" "$out/nvidia-smi.csv" \
    "$out/cuda-tests.json"
echo "failed steps: $failed"
exit "$failed"
