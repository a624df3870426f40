"""``slamlib bench maps``: score time per frame and merge time per scan for each map type, and their memory.

The workload is a synthetic street (:func:`slamlib.synth.street.street_scene`: ground, stepped facades, poles,
parked cars) sampled as points with 2 cm noise: the map is built from ``MAP_POINTS`` points merged in scans of
``MERGE_POINTS``, and ``score_particles`` (Numba CPU backend) is timed for ``P`` particles spread +-0.5 m / +-1
deg around the true pose and ``N`` body-frame scan points. Reported per map kind: median score seconds per call
for each (P, N), point-lookups per second, the (300, 1000) case with particles clustered within +-0.1 m (a
converged filter) and on one thread, median merge seconds for one fresh scan of ``MERGE_POINTS`` points (into a
map that already holds the street), elements and bytes.
"""

from __future__ import annotations

import numpy as np

from slamlib.synth.street import street_scan, street_scene

HELP = "map structures: score time per frame (P particles x N points), merge time per scan, memory"

MAP_POINTS = 400_000
MERGE_POINTS = 20_000
#: Hash-table slots of the voxel map measured here: those of results/maps.json, the map's own default when it was
#: measured (now :data:`slamlib.maps.DEFAULT_VOXEL_CAPACITY`, 2**19, the 3D filter's table).
VOXEL_CAPACITY = 2**18


def run(quick: bool) -> dict:
    import numba

    from benchmarks import median_time
    from slamlib.geometry import rpy_to_matrix
    from slamlib.kernels import get_backend
    from slamlib.maps import MortonBVHMap, VoxelHashMap

    rng = np.random.default_rng(12345)
    cpu = get_backend("cpu")
    n_map = 60_000 if quick else MAP_POINTS
    merge_n = 5_000 if quick else MERGE_POINTS
    particles = (100, 300) if quick else (100, 300, 1000)
    scan_sizes = (500, 1000) if quick else (500, 1000, 2000)
    repeat = 3 if quick else 9
    world = street_scene(rng, n_map)
    R_true = rpy_to_matrix([0.01, -0.02, 0.05])
    t_true = np.array([1.0, 0.3, 1.73])
    scans = {n: street_scan(rng, R_true, t_true, n) for n in scan_sizes}
    rows = []
    for name, factory in (
        ("voxel_hash", lambda: VoxelHashMap(capacity=VOXEL_CAPACITY)),
        ("morton_bvh", MortonBVHMap),
    ):
        m = factory()
        for k in range(0, n_map, merge_n):
            m.merge(world[k : k + merge_n])
        lookup = m.lookup()
        entry = {
            "map": name,
            "elements": len(m),
            "memory_bytes": m.memory_bytes(),
            "score": [],
        }
        for P in particles:
            R = rpy_to_matrix(np.deg2rad(rng.uniform(-1, 1, (P, 3)))) @ R_true
            t = t_true + rng.uniform(-0.5, 0.5, (P, 3))
            for n in scan_sizes:
                tm = median_time(
                    lambda: cpu.score_particles(R, t, scans[n], lookup), repeat=repeat
                )
                entry["score"].append(
                    {"P": P, "N": n, **tm, "lookups_per_s": P * n / tm["median_s"]}
                )
                print(
                    f"{name:10s} score P={P:5d} N={n:5d}: {tm['median_s'] * 1e3:8.2f} ms"
                )

        n1 = 1000 if 1000 in scans else scan_sizes[-1]
        # a converged filter: particles within +-0.1 m / +-0.2 deg (their look-ups share cache lines)
        Rc = rpy_to_matrix(np.deg2rad(rng.uniform(-0.2, 0.2, (300, 3)))) @ R_true
        tc = t_true + rng.uniform(-0.1, 0.1, (300, 3))
        tm = median_time(
            lambda: cpu.score_particles(Rc, tc, scans[n1], lookup), repeat=repeat
        )
        entry["score_clustered"] = {
            "P": 300,
            "N": n1,
            "spread_m": 0.1,
            "spread_deg": 0.2,
            **tm,
        }
        print(
            f"{name:10s} score P=300 N={n1} clustered (+-0.1 m): {tm['median_s'] * 1e3:.2f} ms"
        )

        R = rpy_to_matrix(np.deg2rad(rng.uniform(-1, 1, (300, 3)))) @ R_true
        t = t_true + rng.uniform(-0.5, 0.5, (300, 3))
        threads = numba.get_num_threads()
        numba.set_num_threads(1)
        try:
            tm = median_time(
                lambda: cpu.score_particles(R, t, scans[n1], lookup), repeat=repeat
            )
        finally:
            numba.set_num_threads(threads)
        entry["score_one_thread"] = {"P": 300, "N": n1, **tm}
        print(f"{name:10s} score P=300 N={n1} on 1 thread: {tm['median_s'] * 1e3:.2f} ms")

        # a new scan per merge
        fresh = iter([street_scene(rng, merge_n) for _ in range(repeat + 1)])
        entry["merge"] = {
            "points": merge_n,
            **median_time(lambda: m.merge(next(fresh)), repeat=repeat),
        }
        print(
            f"{name:10s} merge {merge_n} points: {entry['merge']['median_s'] * 1e3:.2f} ms; "
            f"{len(m)} elements, {m.memory_bytes() / 1e6:.1f} MB"
        )
        rows.append(entry)
    return {
        "map_points": n_map,
        "merge_points": merge_n,
        "threads": int(numba.get_num_threads()),
        "maps": rows,
    }
