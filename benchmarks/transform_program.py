"""One whole program, as the seed project timed it: ``python benchmarks/transform_program.py BACKEND N MODE``.

Run in a fresh interpreter by :mod:`benchmarks.transform` (one process per run). It reports its own phases as
one JSON line on stdout, in seconds of ``time.time()`` (wall clock, comparable with the parent's launch time,
which the parent passes in ``$SLAMLIB_LAUNCH_TIME``):

``interpreter_s``   launch (parent, just before ``subprocess.run``) to this module's first line: interpreter start-up;
``import_s``        ``import numpy`` and the backend module (Numba and llvmlite for ``cpu``);
``jit_s``           the first call on 8 points (same kernel and mode): Numba's on-disk cache load (or compilation
                    when cold) and the start of its thread pool;
``allocate_fill_s`` ``np.empty((N, 3), float32)`` and writing every point (the pages fault in here);
``transfer_s``      host to device (CUDA only; 0 on the CPU);
``kernel_s``        the transform of all ``N`` points (``MODE``: ``inplace`` writes over the input, ``out`` into a
                    second array allocated here, as a caller that does not reuse a buffer pays it; on CUDA the
                    result is a new device array and ``inplace`` copies it back over the input);
``copy_back_s``     device to host (CUDA only; 0 on the CPU);
``peak_rss_bytes``  the process's peak resident set at the end (:func:`peak_rss`).

``numpy`` transforms in chunks of ``NUMPY_CHUNK`` points in place (the reference computes in float64, so a
chunk bounds its temporaries). The result is checked on the first and last points (``ok``).
"""

import time

T_START = time.time()

import json  # noqa: E402
import os  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402

#: Points per chunk of the numpy whole program (its float64 temporaries: about 60 bytes per point).
NUMPY_CHUNK = 1 << 20
#: The transform: rotation about z by 90 degrees (exact in float32) and a translation; (x, y, z) -> (t - y, x, z).
POINT = (1.0, 2.0, 3.0)
TRANSLATION = (10.0, -3.0, 1.5)


def main(argv) -> dict:
    backend, n, mode = argv[0], int(argv[1]), argv[2]
    launch = float(os.environ.get("SLAMLIB_LAUNCH_TIME", T_START))
    t0 = time.time()
    import numpy as np

    if backend == "numpy":
        from slamlib.kernels import reference as be
    elif backend == "cpu":
        from slamlib.kernels import cpu as be
    elif backend == "cuda":
        from numba import cuda

        from slamlib.kernels import cuda as be
    else:
        raise SystemExit(f"unknown backend {backend!r}")
    T = np.eye(4)
    T[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = TRANSLATION
    t1 = time.time()
    # JIT (cache load or compile) of the very kernel timed below
    warm = np.zeros((8, 3), np.float32)
    be.transform_points(
        T, warm, **({"out": warm} if mode == "inplace" and backend != "cuda" else {})
    )
    t2 = time.time()
    pts = np.empty((n, 3), np.float32)
    pts[...] = POINT
    t3 = time.time()
    transfer = copy_back = 0.0
    # the seed's program: copy in, kernel, copy back (a new device array for the result)
    if backend == "cuda":
        d_pts = cuda.to_device(pts)
        cuda.synchronize()
        t4 = time.time()
        d_out = be.transform_points(T, d_pts)
        cuda.synchronize()
        t5 = time.time()
        res = d_out.copy_to_host(pts if mode == "inplace" else None)
        copy_back = time.time() - t5
        transfer = t4 - t3
        kernel = t5 - t4
    else:
        t4 = time.time()
        if backend == "numpy":
            res = pts if mode == "inplace" else np.empty_like(pts)
            for a in range(0, n, NUMPY_CHUNK):
                be.transform_points(
                    T, pts[a : a + NUMPY_CHUNK], out=res[a : a + NUMPY_CHUNK]
                )
        else:
            res = be.transform_points(T, pts, out=pts if mode == "inplace" else None)
        kernel = time.time() - t4
    expect = np.array(
        [TRANSLATION[0] - POINT[1], TRANSLATION[1] + POINT[0], TRANSLATION[2] + POINT[2]],
        np.float32,
    )
    ok = bool(
        n == 0 or (np.array_equal(res[0], expect) and np.array_equal(res[-1], expect))
    )
    return {
        "backend": backend,
        "n": n,
        "mode": mode,
        "interpreter_s": T_START - launch,
        "import_s": t1 - t0,
        "jit_s": t2 - t1,
        "allocate_fill_s": t3 - t2,
        "transfer_s": transfer,
        "kernel_s": kernel,
        "copy_back_s": copy_back,
        "peak_rss_bytes": peak_rss(),
        "ok": ok,
    }


def peak_rss() -> int:
    """Peak resident set of this process, bytes: ``VmHWM`` of ``/proc/self/status`` (``ru_maxrss`` of a child
    started by fork + exec can report its parent's peak), else ``ru_maxrss`` (KiB on Linux) x 1024."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1:])))
