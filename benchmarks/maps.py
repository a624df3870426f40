"""``slamlib bench maps``: score time per frame and merge time per scan for each map type, and their memory.

The workload is a synthetic street (:func:`street_scene`: ground, stepped facades, poles, parked cars) sampled
as points with 2 cm noise: the map is built from ``MAP_POINTS`` points merged in scans of ``MERGE_POINTS``, and
``score_particles`` (Numba CPU backend) is timed for ``P`` particles spread +-0.5 m / +-1 deg around the true
pose and ``N`` body-frame scan points. Reported per map kind: median score seconds per call for each (P, N),
point-lookups per second, the (300, 1000) case with particles clustered within +-0.1 m (a converged filter)
and on one thread, median merge seconds for one fresh scan of
``MERGE_POINTS`` points (into a map that already holds the street), elements and bytes.
"""

from __future__ import annotations

import numpy as np

HELP = "map structures: score time per frame (P particles x N points), merge time per scan, memory"

MAP_POINTS = 400_000
MERGE_POINTS = 20_000


def _rect(o, u, v):
    return (np.asarray(o, float), np.asarray(u, float), np.asarray(v, float))


def street_primitives(length: float = 80.0, half_width: float = 8.0):
    """Rectangles ``(origin, edge_u, edge_v)`` and vertical cylinders ``(x, y, radius, height)`` of a street.

    The street runs along x in ``[-length/2, length/2]``; the ground is ``z = 0``; facades at ``|y| ~ half_width``
    step in and out by 0.6 m every 4 m (so the step faces, normal to x, pin down x); poles every 6 m at
    ``|y| = half_width - 1.5``; parked cars are 4.2 x 1.8 x 1.5 m boxes.
    """
    L, W = length, half_width
    rects = [_rect([-L / 2, -W, 0.0], [L, 0, 0], [0, 2 * W, 0])]  # ground
    xs = np.arange(-L / 2, L / 2, 4.0)
    for side in (-1.0, 1.0):
        for k, x0 in enumerate(xs):
            y = side * (W + (0.6 if k % 2 else 0.0))
            rects.append(_rect([x0, y, 0.0], [4.0, 0, 0], [0, 0, 7.0]))  # facade segment
            rects.append(_rect([x0, side * W, 0.0], [0, side * 0.6, 0], [0, 0, 7.0]))  # step face
    cylinders = [(x, s * (W - 1.5), 0.12, 4.5) for x in np.arange(-L / 2 + 3, L / 2, 6.0) for s in (-1, 1)]
    for cx, cy in [(-27.0, 5.2), (-20.0, -5.2), (-9.5, 5.3), (-3.0, -5.2), (4.0, -5.1), (8.5, 5.2), (13.0, 5.2),
                   (19.0, -5.1), (26.0, -5.3), (31.0, 5.2)]:
        x0, y0, x1, y1, h = cx - 2.1, cy - 0.9, cx + 2.1, cy + 0.9, 1.5
        rects += [_rect([x0, y0, 0], [4.2, 0, 0], [0, 0, h]), _rect([x0, y1, 0], [4.2, 0, 0], [0, 0, h]),
                  _rect([x0, y0, 0], [0, 1.8, 0], [0, 0, h]), _rect([x1, y0, 0], [0, 1.8, 0], [0, 0, h]),
                  _rect([x0, y0, h], [4.2, 0, 0], [0, 1.8, 0])]
    return rects, cylinders


def street_scene(rng: np.random.Generator, n_points: int, noise: float = 0.02, **kwargs) -> np.ndarray:
    """``n_points`` (N, 3) float32 world points sampled uniformly by area on :func:`street_primitives`.

    Gaussian noise of ``noise`` metres is added on each axis (a LIDAR's range noise is about 2 cm).
    """
    rects, cyls = street_primitives(**kwargs)
    areas = [np.linalg.norm(np.cross(u, v)) for _, u, v in rects] + [2 * np.pi * r * h for _, _, r, h in cyls]
    areas = np.asarray(areas)
    which = rng.choice(len(areas), size=n_points, p=areas / areas.sum())
    out = np.empty((n_points, 3))
    for k in np.unique(which):
        idx = np.flatnonzero(which == k)
        a, b = rng.random(len(idx)), rng.random(len(idx))
        if k < len(rects):
            o, u, v = rects[k]
            out[idx] = o + a[:, None] * u + b[:, None] * v
        else:
            x, y, r, h = cyls[k - len(rects)]
            ang = 2 * np.pi * a
            out[idx] = np.c_[x + r * np.cos(ang), y + r * np.sin(ang), h * b]
    out += rng.normal(0.0, noise, out.shape)
    return out.astype(np.float32)


def street_scan(rng: np.random.Generator, R, t, n_points: int, max_range: float = 30.0,
                noise: float = 0.02) -> np.ndarray:
    """A body-frame scan (n_points, 3) float32 of the street seen from pose ``T_world_body = [R, t]``.

    Fresh surface samples (independent of the map's) within ``max_range`` metres of ``t`` are mapped to the body
    frame with ``p_body = R^T (p_world - t)``; occlusion is ignored.
    """
    R = np.asarray(R, float)
    t = np.asarray(t, float)
    pts = np.zeros((0, 3))
    while len(pts) < n_points:
        cand = street_scene(rng, 4 * n_points, noise=noise).astype(np.float64)
        cand = cand[np.linalg.norm(cand - t, axis=1) <= max_range]
        pts = np.vstack([pts, cand])
    return ((pts[:n_points] - t) @ R).astype(np.float32)


def run(quick: bool) -> dict:
    import numba

    from slamlib.bench import median_time
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
    for name, factory in (("voxel_hash", VoxelHashMap), ("morton_bvh", MortonBVHMap)):
        m = factory()
        for k in range(0, n_map, merge_n):
            m.merge(world[k:k + merge_n])
        lookup = m.lookup()
        entry = {"map": name, "elements": len(m), "memory_bytes": m.memory_bytes(), "score": []}
        for P in particles:
            R = rpy_to_matrix(np.deg2rad(rng.uniform(-1, 1, (P, 3)))) @ R_true
            t = t_true + rng.uniform(-0.5, 0.5, (P, 3))
            for n in scan_sizes:
                tm = median_time(lambda: cpu.score_particles(R, t, scans[n], lookup), repeat=repeat)
                entry["score"].append({"P": P, "N": n, **tm, "lookups_per_s": P * n / tm["median_s"]})
                print(f"{name:10s} score P={P:5d} N={n:5d}: {tm['median_s'] * 1e3:8.2f} ms")

        n1 = 1000 if 1000 in scans else scan_sizes[-1]
        # a converged filter: particles within +-0.1 m / +-0.2 deg (their look-ups share cache lines)
        Rc = rpy_to_matrix(np.deg2rad(rng.uniform(-0.2, 0.2, (300, 3)))) @ R_true
        tc = t_true + rng.uniform(-0.1, 0.1, (300, 3))
        tm = median_time(lambda: cpu.score_particles(Rc, tc, scans[n1], lookup), repeat=repeat)
        entry["score_clustered"] = {"P": 300, "N": n1, "spread_m": 0.1, "spread_deg": 0.2, **tm}
        print(f"{name:10s} score P=300 N={n1} clustered (+-0.1 m): {tm['median_s'] * 1e3:.2f} ms")

        R = rpy_to_matrix(np.deg2rad(rng.uniform(-1, 1, (300, 3)))) @ R_true
        t = t_true + rng.uniform(-0.5, 0.5, (300, 3))
        threads = numba.get_num_threads()
        numba.set_num_threads(1)
        try:
            tm = median_time(lambda: cpu.score_particles(R, t, scans[n1], lookup), repeat=repeat)
        finally:
            numba.set_num_threads(threads)
        entry["score_one_thread"] = {"P": 300, "N": n1, **tm}
        print(f"{name:10s} score P=300 N={n1} on 1 thread: {tm['median_s'] * 1e3:.2f} ms")

        fresh = iter([street_scene(rng, merge_n) for _ in range(repeat + 1)])  # a new scan per merge
        entry["merge"] = {"points": merge_n, **median_time(lambda: m.merge(next(fresh)), repeat=repeat)}
        print(f"{name:10s} merge {merge_n} points: {entry['merge']['median_s'] * 1e3:.2f} ms; "
              f"{len(m)} elements, {m.memory_bytes() / 1e6:.1f} MB")
        rows.append(entry)
    return {"map_points": n_map, "merge_points": merge_n, "threads": int(numba.get_num_threads()), "maps": rows}
