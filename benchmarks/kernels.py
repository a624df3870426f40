"""``slamlib bench kernels``: point transforms and particle moves, numpy reference vs Numba ``prange``.

Like the seed project's table (1e7 points: about 41 ms single-threaded CPU, 7 ms on a K40 kernel), for
``transform_points`` on 1e3..1e7 float32 points and ``move_particles`` (steps 5 + 6 fused) on 1e3..1e6
particles, plus ``systematic_resample``. Medians of repeated runs (after a warm-up call that also compiles);
rates are points (or particles) per second of the median. The fuller studies: ``slamlib bench transform``
(1e3..1e8 points, kernel and whole-program times beside the copy limit and the seed's table) and ``slamlib bench
particles`` (particles/s with LUT noise fused into the kernel, and with numpy / Philox noise).
"""

from __future__ import annotations

import numpy as np

HELP = "transform_points (1e3..1e7 points) and move_particles (1e3..1e6 particles): numpy vs Numba prange"


def _row(kind, n, backend, tm):
    return {
        "kernel": kind,
        "n": int(n),
        "backend": backend,
        **tm,
        "per_s": n / tm["median_s"],
    }


def run(quick: bool) -> dict:
    import numba

    from benchmarks import median_time
    from slamlib.geometry import make_pose, rpy_to_matrix
    from slamlib.kernels import get_backend

    rng = np.random.default_rng(0)
    backends = {"numpy": get_backend("numpy"), "cpu": get_backend("cpu")}
    point_sizes = [10**k for k in range(3, 6 if quick else 8)]
    particle_sizes = [10**k for k in range(3, 5 if quick else 7)]
    repeat = 3 if quick else 7
    T = make_pose(rpy_to_matrix([0.01, -0.02, 0.3]), [10.0, -3.0, 1.5])
    rows = []
    for n in point_sizes:
        pts = rng.normal(0, 20, (n, 3)).astype(np.float32)
        for name, b in backends.items():
            tm = median_time(lambda: b.transform_points(T, pts), repeat=repeat)
            rows.append(_row("transform_points", n, name, tm))
            print(f"transform_points n={n:>9d} {name:6s} {tm['median_s'] * 1e3:9.3f} ms")
    for n in particle_sizes:
        R = rpy_to_matrix(rng.normal(0, 0.1, (n, 3)))
        t = rng.normal(0, 5, (n, 3))
        noise = rng.standard_normal((n, 6))
        sigma = np.array([0.1, 0.05, 0.02, 0.002, 0.002, 0.01])
        for name, b in backends.items():
            tm = median_time(
                lambda: b.move_particles(
                    R, t, [0.0, 0.0, 0.05], [1.0, 0.0, 0.0], noise, sigma
                ),
                repeat=repeat,
            )
            rows.append(_row("move_particles", n, name, tm))
            print(f"move_particles   n={n:>9d} {name:6s} {tm['median_s'] * 1e3:9.3f} ms")
        w = rng.random(n)
        for name, b in backends.items():
            tm = median_time(lambda: b.systematic_resample(w, 0.5), repeat=repeat)
            rows.append(_row("systematic_resample", n, name, tm))
            print(f"resample         n={n:>9d} {name:6s} {tm['median_s'] * 1e3:9.3f} ms")
    return {"threads": int(numba.get_num_threads()), "rows": rows}
