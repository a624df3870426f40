"""``slamlib bench transform``: one 4x4 transform of 1e3..1e8 float32 points, beside the copy limit and the seed.

The seed project's headline table timed whole programs on a 2017 K40 (0.220224 ... 0.374841 s for 1e3 ... 1e7
points; 1e8 ran out of memory); its report adds about 7 ms for 1e7 points in the kernel alone, 41 ms on one CPU
thread. This benchmark measures, for the numpy reference, the Numba CPU backend and (on a GPU) CUDA:

* ``kernel_rows``: the kernel alone, in this process, after a warm-up call: median and best of ``repeat`` runs.
  Variants: ``alloc`` (``transform_points(T, pts)``: the output is a fresh ``np.empty``, whose pages fault in
  and are zeroed by the OS during the kernel, as a caller pays it), ``out`` (into a preallocated, already
  touched buffer, ``out=``) and ``inplace`` (``out=pts``); for the CPU also ``out_1thread`` and
  ``inplace_1thread`` (Numba on one thread, like ``numpy.copyto``: comparable even when another job holds a
  core). Beside each row, the physical limit measured in the same rounds: streaming the same bytes (``12 N``
  read, ``12 N`` written) by ``numpy.copyto`` (memcpy, one thread) and by a Numba ``prange`` copy (all
  threads), into a touched buffer; ``ratio_to_copyto`` and ``ratio_to_fastest_copy`` are median / median
  (``best_ratio_*``: best / best). Every round times its rows of one size back to back, so the ratios compare
  like with like on a shared machine. The rows that allocate (``alloc``, for every backend) have rounds of
  their own (``"rounds": "fresh"``, the others ``"reuse"``), with the copies timed again in them: freeing a
  1.2 GB output each call leaves the OS reclaiming pages in the background, which slowed the rows timed after
  them (the ``out=`` median at 1e8 by 15 %, its best not at all). ``copy_rows`` are the ``reuse`` rounds'.
* ``program_rows``: whole programs as the seed measured them, one fresh interpreter per run
  (:mod:`benchmarks.transform_program`): start-up (interpreter, imports, JIT or cache load) as its own column,
  then allocate + fill, transfer, kernel, copy back, the outer wall time of the subprocess, and its peak RSS
  against the stated memory budget (``budget_bytes``: the arrays the mode needs plus ``RUNTIME_ALLOWANCE``).
* ``gpu_rows``: without a GPU, the bandwidth-bound projection of the CUDA kernel (bytes moved / the card's
  memory bandwidth, ``"projected": true``, not measured) for the cards in :data:`CARDS`; on a machine where
  ``numba.cuda.is_available()``, measured CUDA kernel rows (``"projected": false``) instead.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HELP = "transform 1e3..1e8 float32 points: kernel and whole-program times vs the copy limit and the seed's table"

#: The seed's whole-program table (K40, 2017), seconds; None: out of memory.
SEED_WHOLE_PROGRAM_S = {
    10**3: 0.220224,
    10**4: 0.223580,
    10**5: 0.227155,
    10**6: 0.247954,
    10**7: 0.374841,
    10**8: None,
}
#: The seed's final report, 1e7 points: the K40 kernel alone, and one CPU thread (Xeon E5-2620).
SEED_K40_KERNEL_1E7_S = 0.007
SEED_CPU_THREAD_1E7_S = 0.041
#: Memory bandwidth of named cards, bytes/s (vendor figures): the projection's denominators.
CARDS = {"H100 SXM (HBM3)": 3.35e12, "K40 (GDDR5, the seed's card)": 288e9}
#: Bytes read + written per point: 12 in (x, y, z float32) and 12 out.
BYTES_PER_POINT = 24
#: Peak-RSS allowance of a whole program beyond its arrays: interpreter, numpy, Numba/llvmlite, code, caches.
RUNTIME_ALLOWANCE = 512 * 2**20
#: Random points drawn once and tiled over the input (drawing 3e8 normals would dominate the run).
BLOCK = 1 << 16


def _numba_copy():
    from numba import njit, prange

    @njit(parallel=True)
    def pcopy(src, dst):
        for i in prange(src.shape[0]):
            dst[i] = src[i]

    return pcopy


def _one_thread(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` with Numba's parallel loops on one thread (the setting restored after)."""
    import numba

    n = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        return fn(*args, **kwargs)
    finally:
        numba.set_num_threads(n)


def _stats(times) -> dict:
    a = np.asarray(times)
    return {
        "median_s": float(np.median(a)),
        "min_s": float(a.min()),
        "max_s": float(a.max()),
        "repeat": int(a.size),
    }


def _rounds(fns: dict, repeat: int) -> dict:
    """Time every callable of ``fns`` once per round, ``repeat`` rounds after one untimed warm-up round."""
    for fn in fns.values():
        fn()
    times = {k: [] for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t0)
    return {k: _stats(v) for k, v in times.items()}


def kernel_rows(sizes, repeat_for, backends) -> tuple[list, list]:
    """In-process kernel timings and the copy limit per size (see the module docstring)."""
    from slamlib.geometry import make_pose, rpy_to_matrix

    pcopy = _numba_copy()
    T = make_pose(rpy_to_matrix([0.01, -0.02, 0.3]), [10.0, -3.0, 1.5])
    rows, copies = [], []
    for n in sizes:
        pts = np.empty((n, 3), np.float32)
        block = (
            np.random.default_rng(0)
            .normal(0.0, 20.0, (min(n, BLOCK), 3))
            .astype(np.float32)
        )
        # a random block tiled over the array (cheap at 1e8; touches every page)
        for a in range(0, n, BLOCK):
            pts[a : a + BLOCK] = block[: min(BLOCK, n - a)]
        out = np.empty_like(pts)
        # touched: the ``out`` and copy rows pay no page faults
        # the in-place rows transform this one (values drift; the time does not)
        out[...] = 0.0
        work = pts.copy()
        flat_in, flat_out = pts.reshape(-1), out.reshape(-1)
        copy_fns = {
            ("copy", "numpy.copyto"): lambda: np.copyto(out, pts),
            ("copy", "numba_parallel_copy"): lambda: pcopy(flat_in, flat_out),
        }
        reuse, fresh = dict(copy_fns), dict(copy_fns)
        for name, be in backends.items():
            fresh[(name, "alloc")] = lambda be=be: be.transform_points(T, pts)
            if name != "numpy":
                reuse[(name, "out")] = lambda be=be: be.transform_points(T, pts, out=out)
                reuse[(name, "inplace")] = lambda be=be: be.transform_points(
                    T, work, out=work
                )
            # one thread, like memcpy: a like-for-like pair even when another job holds a core
            if name == "cpu":
                reuse[(name, "out_1thread")] = lambda be=be: _one_thread(
                    be.transform_points, T, pts, out=out
                )
                reuse[(name, "inplace_1thread")] = lambda be=be: _one_thread(
                    be.transform_points, T, work, out=work
                )
        nbytes = BYTES_PER_POINT * n
        # Rows that allocate (and free) their output each call leave the OS reclaiming gigabytes of pages in the
        # background, which slows whatever runs next: they get rounds of their own, with the copies timed again.
        for group, fns in (("reuse", reuse), ("fresh", fresh)):
            res = _rounds(fns, repeat_for(n))
            rows += _kernel_records(res, n, nbytes, group)
            if group == "reuse":
                copies += [
                    {
                        "n": n,
                        "method": method,
                        "bytes_moved": nbytes,
                        **res[("copy", method)],
                        "gb_per_s": nbytes / res[("copy", method)]["median_s"] / 1e9,
                    }
                    for method in ("numpy.copyto", "numba_parallel_copy")
                ]
        pts = out = work = flat_in = flat_out = reuse = fresh = copy_fns = (
            None  # free this size
        )
    return rows, copies


def _kernel_records(res: dict, n: int, nbytes: int, group: str) -> list:
    """The JSON rows of one group of rounds: each kernel row beside the copies timed in the same rounds."""
    ct, pc = res[("copy", "numpy.copyto")], res[("copy", "numba_parallel_copy")]
    fastest_med = min(ct["median_s"], pc["median_s"])
    fastest_min = min(ct["min_s"], pc["min_s"])
    rows = []
    for (name, variant), st in res.items():
        if name == "copy":
            continue
        rows.append(
            {
                "backend": name,
                "variant": variant,
                "n": n,
                "rounds": group,
                "bytes_moved": nbytes,
                **st,
                "points_per_s": n / st["median_s"],
                "gb_per_s": nbytes / st["median_s"] / 1e9,
                "copyto_median_s": ct["median_s"],
                "copyto_min_s": ct["min_s"],
                "parallel_copy_median_s": pc["median_s"],
                "parallel_copy_min_s": pc["min_s"],
                "ratio_to_copyto": st["median_s"] / ct["median_s"],
                "ratio_to_fastest_copy": st["median_s"] / fastest_med,
                "best_ratio_to_copyto": st["min_s"] / ct["min_s"],
                "best_ratio_to_fastest_copy": st["min_s"] / fastest_min,
            }
        )
        print(
            f"kernel n={n:>10d} {name:6s} {variant:8s} {st['median_s'] * 1e3:10.3f} ms "
            f"(best {st['min_s'] * 1e3:.3f}) x{rows[-1]['ratio_to_fastest_copy']:.2f} of the fastest copy "
            f"({fastest_med * 1e3:.3f} ms)",
            flush=True,
        )
    return rows


def _budget(backend: str, mode: str, n: int) -> int:
    arrays = 12 * n * (1 if mode == "inplace" else 2)
    if backend == "numpy":
        from benchmarks.transform_program import NUMPY_CHUNK

        arrays += 64 * min(n, NUMPY_CHUNK)  # the float64 temporaries of one chunk
    return arrays + RUNTIME_ALLOWANCE


def program_rows(configs, sizes, runs: int) -> list:
    """Whole programs: a fresh interpreter per run (``benchmarks/transform_program.py``); medians over ``runs``."""
    script = Path(__file__).with_name("transform_program.py")
    rows = []
    for backend, mode in configs:
        # cache
        subprocess.run(
            [sys.executable, str(script), backend, "8", mode],
            check=True,
            capture_output=True,
        )
        for n in sizes:
            reports, walls = [], []
            for _ in range(runs):
                env = dict(os.environ, SLAMLIB_LAUNCH_TIME=repr(time.time()))
                t0 = time.perf_counter()
                res = subprocess.run(
                    [sys.executable, str(script), backend, str(n), mode],
                    env=env,
                    capture_output=True,
                    text=True,
                )
                walls.append(time.perf_counter() - t0)
                if res.returncode != 0:
                    raise RuntimeError(
                        f"transform_program {backend} {n} {mode} failed:\n{res.stderr}"
                    )
                reports.append(json.loads(res.stdout.strip().splitlines()[-1]))
            med = {
                k: float(np.median([r[k] for r in reports]))
                for k in (
                    "interpreter_s",
                    "import_s",
                    "jit_s",
                    "allocate_fill_s",
                    "transfer_s",
                    "kernel_s",
                    "copy_back_s",
                )
            }
            startup = [r["interpreter_s"] + r["import_s"] + r["jit_s"] for r in reports]
            rss = max(r["peak_rss_bytes"] for r in reports)
            budget = _budget(backend, mode, n)
            row = {
                "backend": backend,
                "mode": mode,
                "n": n,
                "runs": runs,
                "wall_s": float(np.median(walls)),
                "wall_min_s": float(np.min(walls)),
                "startup_s": float(np.median(startup)),
                **med,
                "after_startup_s": float(
                    np.median([w - s for w, s in zip(walls, startup)])
                ),
                "peak_rss_bytes": int(rss),
                "budget_bytes": int(budget),
                "within_budget": bool(rss <= budget),
                "ok": all(r["ok"] for r in reports),
                "seed_wall_s": SEED_WHOLE_PROGRAM_S.get(n),
            }
            rows.append(row)
            print(
                f"program {backend:5s} {mode:7s} n={n:>10d} wall {row['wall_s']:.3f} s (start-up "
                f"{row['startup_s']:.3f}, alloc+fill {row['allocate_fill_s']:.3f}, kernel {row['kernel_s']:.4f}) "
                f"peak {rss / 2**20:.0f} MiB / budget {budget / 2**20:.0f} MiB; seed {row['seed_wall_s']}",
                flush=True,
            )
    return rows


def gpu_rows(sizes, repeat: int) -> list:
    """Measured CUDA kernel rows when a GPU is usable, else the bandwidth-bound projection per card."""
    try:
        from numba import cuda

        available = (
            bool(cuda.is_available()) and os.environ.get("NUMBA_ENABLE_CUDASIM") != "1"
        )
    except ImportError:
        available = False
    rows = []
    if available:
        from benchmarks import median_time
        from slamlib.geometry import make_pose, rpy_to_matrix
        from slamlib.kernels import get_backend

        be = get_backend("cuda")
        T = make_pose(rpy_to_matrix([0.01, -0.02, 0.3]), [10.0, -3.0, 1.5])
        card = cuda.get_current_device().name
        card = card.decode() if isinstance(card, bytes) else str(card)
        for n in sizes:
            d = cuda.to_device(np.ones((n, 3), np.float32))

            def call():
                be.transform_points(T, d)
                cuda.synchronize()

            st = median_time(call, repeat=repeat)
            rows.append(
                {
                    "backend": "cuda",
                    "n": n,
                    "card": card,
                    "bytes_moved": BYTES_PER_POINT * n,
                    **st,
                    "kernel_s": st["median_s"],
                    "projected": False,
                }
            )
            del d
        return rows
    for n in sizes:
        for card, bw in CARDS.items():
            rows.append(
                {
                    "backend": "cuda",
                    "n": n,
                    "card": card,
                    "bytes_moved": BYTES_PER_POINT * n,
                    "bandwidth_bytes_per_s": bw,
                    "kernel_s": BYTES_PER_POINT * n / bw,
                    "projected": True,
                    "label": "projected, not measured",
                }
            )
    return rows


def run(quick: bool) -> dict:
    import numba

    from slamlib.kernels import get_backend

    sizes = [10**k for k in range(3, 6 if quick else 9)]
    backends = {"numpy": get_backend("numpy"), "cpu": get_backend("cpu")}

    def repeat_for(n):
        return 3 if quick else (7 if n >= 10**8 else (15 if n >= 10**7 else 31))

    load_before = os.getloadavg()
    krows, copies = kernel_rows(sizes, repeat_for, backends)
    configs = [("cpu", "inplace"), ("cpu", "out"), ("numpy", "inplace")]
    prows = program_rows(configs, sizes, 1 if quick else 3)
    return {
        "threads": int(numba.get_num_threads()),
        "sizes": sizes,
        "seed": {
            "whole_program_s": {str(k): v for k, v in SEED_WHOLE_PROGRAM_S.items()},
            "k40_kernel_1e7_s": SEED_K40_KERNEL_1E7_S,
            "cpu_one_thread_1e7_s": SEED_CPU_THREAD_1E7_S,
            "note": "K40 (2017) whole programs; 1e8: out of memory",
        },
        "bytes_per_point": BYTES_PER_POINT,
        "runtime_allowance_bytes": RUNTIME_ALLOWANCE,
        "kernel_rows": krows,
        "copy_rows": copies,
        "program_rows": prows,
        "gpu_rows": gpu_rows(sizes, 3 if quick else 7),
        "load_average_1min": {"start": load_before[0], "end": os.getloadavg()[0]},
    }
