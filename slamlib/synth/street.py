"""A synthetic street sampled as points: ground, stepped facades, poles and parked cars (for map tests and benchmarks).

:func:`street_primitives` describes the street as rectangles and vertical cylinders, :func:`street_scene` samples
world points on it uniformly by area (with LIDAR-like noise) and :func:`street_scan` a body-frame scan seen from a
pose. Metres, world frame with z up; point arrays ``(N, 3)`` float32.
"""

from __future__ import annotations

import numpy as np


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
            # step face
            rects.append(_rect([x0, side * W, 0.0], [0, side * 0.6, 0], [0, 0, 7.0]))
    cylinders = [
        (x, s * (W - 1.5), 0.12, 4.5)
        for x in np.arange(-L / 2 + 3, L / 2, 6.0)
        for s in (-1, 1)
    ]
    for cx, cy in [
        (-27.0, 5.2),
        (-20.0, -5.2),
        (-9.5, 5.3),
        (-3.0, -5.2),
        (4.0, -5.1),
        (8.5, 5.2),
        (13.0, 5.2),
        (19.0, -5.1),
        (26.0, -5.3),
        (31.0, 5.2),
    ]:
        x0, y0, x1, y1, h = cx - 2.1, cy - 0.9, cx + 2.1, cy + 0.9, 1.5
        rects += [
            _rect([x0, y0, 0], [4.2, 0, 0], [0, 0, h]),
            _rect([x0, y1, 0], [4.2, 0, 0], [0, 0, h]),
            _rect([x0, y0, 0], [0, 1.8, 0], [0, 0, h]),
            _rect([x1, y0, 0], [0, 1.8, 0], [0, 0, h]),
            _rect([x0, y0, h], [4.2, 0, 0], [0, 1.8, 0]),
        ]
    return rects, cylinders


def street_scene(
    rng: np.random.Generator, n_points: int, noise: float = 0.02, **kwargs
) -> np.ndarray:
    """``n_points`` (N, 3) float32 world points sampled uniformly by area on :func:`street_primitives`.

    Gaussian noise of ``noise`` metres is added on each axis (a LIDAR's range noise is about 2 cm).
    """
    rects, cyls = street_primitives(**kwargs)
    areas = [np.linalg.norm(np.cross(u, v)) for _, u, v in rects] + [
        2 * np.pi * r * h for _, _, r, h in cyls
    ]
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


def street_scan(
    rng: np.random.Generator,
    R,
    t,
    n_points: int,
    max_range: float = 30.0,
    noise: float = 0.02,
) -> np.ndarray:
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
