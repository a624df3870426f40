"""``slamlib bench cuda``: the CUDA kernels' timings on a real GPU (device arrays, synchronised).

Rows: ``move_particles`` with device LUT noise (tables uploaded once) and with a noise array already on the device
(the rotation + translation kernels; up to 10^7 particles, past the seed's saturation at 10^6),
``transform_points`` (grid-stride), fused ``score_particles`` on the synthetic street of
:func:`slamlib.synth.street.street_scene` in the voxel-hash map in both layouts (one block per particle; blocks
over particle x point tiles, ``layout="tiles"``, which keeps more SMs busy at the default 300 particles),
``systematic_resample`` (scan + binary search),
and the LUT noise fill alone. Each is timed with ``cuda.synchronize()`` after the call, inputs already on the
device (copies excluded), one launch untimed first (JIT compilation).

Without a GPU there is nothing to measure: the benchmark exits non-zero saying so (it never reports
simulator timings, which are ~10^6 times slower and meaningless), and no JSON is written.

``slamlib bench cuda --static`` needs no GPU: every kernel compiled for A100 and H100, registers, shared memory,
spills and theoretical occupancy (:mod:`benchmarks.cuda_static`; static analysis, no timing).
"""

from __future__ import annotations

import os

import numpy as np

HELP = "CUDA kernels on a real GPU: move, transform, fused score, resample, LUT noise (exits if no GPU)"


def _no_gpu_reason() -> str | None:
    """Why no real GPU can be timed here, or ``None`` when one can."""
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
        return "NUMBA_ENABLE_CUDASIM=1: the CUDA simulator runs kernels in Python; its timings mean nothing"
    from slamlib.errors import BackendUnavailableError

    try:
        from slamlib.kernels.cuda import check_available

        check_available()
    except (BackendUnavailableError, ImportError) as exc:
        return str(exc)
    return None


def run(
    quick: bool = False,
    allow_simulator: bool = False,
    sizes: dict | None = None,
    static: bool = False,
) -> dict:
    """Time the kernels; ``SystemExit`` (non-zero) when no GPU. ``allow_simulator`` / ``sizes`` exist only for
    the smoke test of this code in the simulator (its numbers are then marked ``"simulator": true``).

    ``static=True`` (``slamlib bench cuda --static``): no GPU and no timing, the kernels' compiled resources and
    theoretical occupancy instead (:func:`benchmarks.cuda_static.run_static`, ``results/cuda-static.json``)."""
    if static:
        from benchmarks.cuda_static import run_static

        return run_static()
    reason = _no_gpu_reason()
    simulator = os.environ.get("NUMBA_ENABLE_CUDASIM") == "1"
    if reason is not None and not (allow_simulator and simulator):
        raise SystemExit(f"slamlib bench cuda: no GPU, nothing measured ({reason})")
    from numba import cuda

    from benchmarks import median_time
    from slamlib import geometry
    from slamlib import noise as N
    from slamlib.kernels import cuda as kc
    from slamlib.maps import VoxelHashMap
    from slamlib.synth.street import street_scene

    if sizes is None:
        sizes = (
            {
                "P": [300, 1000, 10000],
                "move": [300, 1000, 10000],
                "N": [10000],
                "points": [10**6],
                "resample": [10**4, 10**6],
                "map": 100_000,
            }
            if quick
            else {
                "P": [300, 1000, 10000, 100000],
                # up to the seed's saturation (1e6 particles and more on its K40)
                "move": [300, 1000, 10000, 100000, 10**6, 10**7],
                "N": [1000, 10000, 120000],
                "points": [10**6, 10**7],
                "resample": [10**3, 10**4, 10**6],
                "map": 400_000,
            }
        )
    repeat = 3 if (quick or simulator) else 7
    rng = np.random.default_rng(0)
    rows = []

    def timed(kernel, n, fn, **extra):
        def call():
            fn()
            cuda.synchronize()

        t = median_time(call, repeat=repeat)
        rows.append({"kernel": kernel, "n": n, **extra, **t, "per_s": n / t["median_s"]})

    sigma = np.array([0.05, 0.05, 0.02, 0.002, 0.002, 0.005])
    tables = kc.tables_to_device(N.make_tables(1))  # uploaded once, as a filter would
    for P in sizes["move"]:
        R = kc.to_device(geometry.rpy_to_matrix(rng.normal(0, 0.01, (P, 3))))
        t = kc.to_device(rng.normal(0, 0.3, (P, 3)))
        noise_d = kc.to_device(rng.standard_normal((P, 6)))
        lut = N.LutNoise(tables, 3, 7)
        timed(
            "move_particles",
            P,
            lambda: kc.move_particles(R, t, [0, 0, 0.01], [1, 0, 0], lut, sigma),
            noise="LUT on device",
        )
        timed(
            "move_particles",
            P,
            lambda: kc.move_particles(R, t, [0, 0, 0.01], [1, 0, 0], noise_d, sigma),
            noise="array on device",
        )
        timed("lut_noise_fill", P * 6, lambda: kc.lut_normal_device(lut, P))
    for n in sizes["points"]:
        pts = kc.to_device(rng.normal(0, 20, (n, 3)).astype(np.float32))
        T = geometry.make_pose(
            geometry.rpy_to_matrix(np.array([0.01, 0.02, 0.3])), np.array([1.0, 2.0, 0.1])
        )
        timed("transform_points", n, lambda: kc.transform_points(T, pts))
    world = street_scene(np.random.default_rng(1), sizes["map"])
    vmap = VoxelHashMap()
    vmap.merge(world)
    lookup_d = kc.lookup_to_device(vmap.lookup())
    for P in sizes["P"]:
        R = kc.to_device(geometry.rpy_to_matrix(rng.normal(0, 0.01, (P, 3))))
        t = kc.to_device(rng.normal(0, 0.3, (P, 3)))
        for n in sizes["N"]:
            pts = kc.to_device(world[rng.choice(len(world), n)])
            # one block per particle, or particle x point tiles
            for layout in kc.SCORE_LAYOUTS:
                timed(
                    "score_particles",
                    P * n,
                    lambda: kc.score_particles(R, t, pts, lookup_d, layout=layout),
                    P=P,
                    N=n,
                    map="voxel_hash",
                    layout=layout,
                    unit="point lookups",
                )
    for P in sizes["resample"]:
        w = kc.to_device(rng.random(P))
        timed("systematic_resample", P, lambda: kc.systematic_resample(w, 0.5))
    name = getattr(cuda.get_current_device(), "name", "CUDA simulator")
    name = name.decode() if isinstance(name, bytes) else str(name)
    return {
        "gpu": name,
        "simulator": simulator,
        "rows": rows,
        "note": "device arrays in and out (copies excluded); medians of synchronised calls",
    }
