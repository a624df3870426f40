"""Scan preprocessing for the 3D pipeline: range crop, voxel down-sampling, a fixed-size seeded sample.

A KITTI HDL-64E scan holds ~120,000 points (the synthetic ones ~100,000), far more than the particle filter
needs: scoring costs ``P x N`` map lookups (``P`` particles, ``N`` points), and consecutive points of one ring are
a few centimetres apart near the car and metres apart far away. Step 2 (``read_scan``) therefore

1. **crops by range** in the sensor frame, ``min_range <= |p| <= max_range``: drops returns from the ego
   vehicle and very far, sparse, noisy returns;
2. **voxel down-samples**: keeps the first point of every occupied voxel of edge ``voxel_size`` (exact LIDAR
   points, not voxel centres, so the map keeps the sensor's precision), which evens out the density (the ground
   next to the car no longer dominates);
3. for step 8 only, LIDAR-only, **thins the road** (:func:`thin_ground`: the "ring artifact"), and
4. for step 8 only, **samples** ``n`` of those points at random without replacement, with a
   ``numpy.random.Generator`` passed in (seeded, reproducible). The map merge (step 10) uses the whole
   down-sampled scan.

Steps 1 and 2 run as one ``O(N)`` Numba pass (:func:`crop_and_downsample`); :func:`crop_range` and
:func:`voxel_downsample` are its numpy reference. All functions are pure: arrays in, arrays out. Points are
``(N, 3)`` float32 metres.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from slamlib.maps.base import EMPTY_KEY
from slamlib.maps.codes import AXIS_MASK, AXIS_OFFSET_I64, hash_slot_nb, pack_key_nb

__all__ = [
    "crop_range",
    "voxel_downsample",
    "crop_and_downsample",
    "sample_points",
    "road_mask",
    "thin_ground",
    "sample_thinned",
    "GROUND_BAND_M",
    "GROUND_PERCENTILE",
    "sweep_times",
    "deskew",
]

#: Height above the scan's road surface (its :data:`GROUND_PERCENTILE` of z, body frame) below which a point counts
#: as road for :func:`thin_ground`: 0.8 m also takes the curbs, the road's slope within the crop, and the lower
#: bodies of cars, whose returns lie on the same rings (on the ten real scans a 0.3 m band still left the
#: LIDAR-only estimate of their motion short of the direct registration's, every seed tried; 0.8 m did not).
GROUND_BAND_M = 0.8
#: The percentile of the scan's heights taken as the road surface (robust to a few returns from below it).
GROUND_PERCENTILE = 5.0


def crop_range(points, min_range: float = 0.0, max_range: float = np.inf) -> np.ndarray:
    """Keep the points with ``min_range <= |p| <= max_range`` (Euclidean range from the frame's origin, m).

    Parameters
    ----------
    points : (N, 3) or (N, 4) array
        Points in the sensor frame (a 4th reflectance column is kept).
    min_range, max_range : float
        Range limits in metres.

    Returns
    -------
    (M, 3) or (M, 4) array, same dtype, in the input order.
    """
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise ValueError(f"points must have shape (N, 3) or (N, 4), got {pts.shape}")
    r2 = np.einsum("ij,ij->i", pts[:, :3], pts[:, :3], dtype=np.float64)
    keep = (r2 >= float(min_range) ** 2) & (r2 <= float(max_range) ** 2)
    return pts[keep]


def voxel_downsample(points, voxel_size: float) -> np.ndarray:
    """One point per occupied voxel: the first point (in input order) of each voxel of edge ``voxel_size`` m.

    Voxel of point ``p``: ``floor(p / voxel_size)`` per axis. The kept points are exact input points (not voxel
    centres or means), in the order of their first appearance, so the output is deterministic.
    ``voxel_size <= 0`` returns the points unchanged.

    Parameters
    ----------
    points : (N, 3) or (N, 4) array
    voxel_size : float, metres

    Returns
    -------
    (M, 3) or (M, 4) array, ``M <= N``.
    """
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise ValueError(f"points must have shape (N, 3) or (N, 4), got {pts.shape}")
    if voxel_size <= 0 or len(pts) == 0:
        return pts
    idx = np.floor(pts[:, :3].astype(np.float64) / float(voxel_size)).astype(np.int64)
    idx -= idx.min(axis=0)
    span = idx.max(axis=0) + 1
    if np.prod(span.astype(np.float64)) < 2.0**62:
        keys = (idx[:, 0] * span[1] + idx[:, 1]) * span[2] + idx[:, 2]
        _, first = np.unique(keys, return_index=True)
    else:  # astronomically spread points: fall back to row-unique
        _, first = np.unique(idx, axis=0, return_index=True)
    return pts[np.sort(first)]


def crop_and_downsample(
    points,
    min_range: float = 0.0,
    max_range: float = np.inf,
    voxel_size: float = 0.0,
    columns: int | None = None,
) -> np.ndarray:
    """:func:`crop_range` then :func:`voxel_downsample`, in two passes: the same points in the same order, with their
    first ``columns`` columns only when given (step 2 keeps x, y, z of a scan's rows, gathered once).

    The first pass (:func:`_crop_keys_nb`, in parallel over :data:`CROP_CHUNK` points a task) marks each point
    outside ``[min_range, max_range]`` and packs the voxel ``floor(p / voxel_size)`` of the others into a key
    (:mod:`slamlib.maps.codes`); the second (:func:`_first_of_each_key_nb`, in order) keeps a point whose key is new
    to a hash set (open addressing, linear probing, at most half full). ``O(N)`` against the sort of
    :func:`voxel_downsample`'s ``np.unique`` (step 2 took a quarter of a frame's time). The set starts sized for a
    quarter of the points to be distinct (about a sixth are, on KITTI scans at 0.25 m) and grows fourfold when it
    fills. Points whose voxel index leaves the packed range (more than ``2**20`` voxels from the origin) take the
    two reference functions instead.
    """
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] < 3:
        raise ValueError(f"points must have shape (N, 3) or (N, 4), got {pts.shape}")
    cols = slice(None) if columns is None else slice(0, int(columns))
    if len(pts) == 0:
        return pts[:, cols]
    h = float(voxel_size) if voxel_size > 0 else 0.0
    # the whole rows, read in place (a contiguous copy of x, y, z cost a third more): the kernel reads columns 0-2,
    # and a scan's (N, 4) rows and the matcher's (M, 3) points are then one array type, one kernel to load
    key_of = _crop_keys_nb(
        pts, float(min_range) ** 2, float(max_range) ** 2, h, CROP_CHUNK
    )
    log2_capacity = max(4, int(np.ceil(np.log2(len(pts) / 2))))
    while True:  # at 2N slots it cannot fill: at most N keys
        keep = _first_of_each_key_nb(key_of, log2_capacity, h > 0)
        if not (len(keep) == 1 and keep[0] == _TABLE_FULL):
            break
        log2_capacity += 2
    if len(keep) == 1 and keep[0] == _OUT_OF_RANGE:
        return voxel_downsample(crop_range(pts, min_range, max_range), voxel_size)[
            :, cols
        ]
    return pts[keep, cols]


#: Points per task of :func:`crop_and_downsample`'s parallel first pass.
CROP_CHUNK = 4096
#: :func:`_first_of_each_key_nb`'s answers when a voxel index leaves the packed key range, and when its hash set
#: is half full (:func:`crop_and_downsample` then grows it).
_OUT_OF_RANGE, _TABLE_FULL = -1, -2
#: :func:`_crop_keys_nb`'s marks (keys are >= 0): outside the range crop; voxel index outside the key range.
_CROPPED, _BEYOND_KEYS = -2, -3


@njit(cache=True, parallel=True)
def _crop_keys_nb(xyz, min_r2, max_r2, h, chunk):
    """Per point of ``xyz (N, >= 3)`` (x, y, z its first three columns): :data:`_CROPPED` outside the range crop,
    else the packed key of its voxel (0 for every point when ``h = 0``), or :data:`_BEYOND_KEYS` when a voxel
    index leaves ``[0, 2**21)`` after the offset. A module-level kernel: its helpers are globals, which Numba's
    cache key leaves out (a closure's cells are in it, and a jitted function in a cell made every run compile it
    again)."""
    n = xyz.shape[0]
    key_of = np.empty(n, np.int64)
    for task in prange((n + chunk - 1) // chunk):
        for i in range(task * chunk, min(n, (task + 1) * chunk)):
            x, y, z = np.float64(xyz[i, 0]), np.float64(xyz[i, 1]), np.float64(xyz[i, 2])
            r2 = x * x + y * y + z * z
            if r2 < min_r2 or r2 > max_r2:
                key_of[i] = _CROPPED
                continue
            if h <= 0:
                key_of[i] = 0
                continue
            ux = np.int64(math.floor(x / h)) + AXIS_OFFSET_I64
            uy = np.int64(math.floor(y / h)) + AXIS_OFFSET_I64
            uz = np.int64(math.floor(z / h)) + AXIS_OFFSET_I64
            if (
                ux < 0
                or ux > AXIS_MASK
                or uy < 0
                or uy > AXIS_MASK
                or uz < 0
                or uz > AXIS_MASK
            ):
                key_of[i] = _BEYOND_KEYS
                continue
            key_of[i] = pack_key_nb(ux, uy, uz)
    return key_of


@njit(cache=True)
def _first_of_each_key_nb(key_of, log2_capacity, dedupe):
    """Indexes (input order) of the points not cropped, only the first of each key when ``dedupe``;
    ``[_OUT_OF_RANGE]`` when a point is beyond the keys, ``[_TABLE_FULL]`` when the set of ``2**log2_capacity``
    slots would be more than half full."""
    n = key_of.shape[0]
    keep = np.empty(n, np.int64)
    capacity = np.int64(1) << log2_capacity
    keys = np.full(capacity if dedupe else 1, EMPTY_KEY, np.int64)
    mask = capacity - 1
    m = 0
    last = _CROPPED  # the key of the last point looked up
    for i in range(n):
        key = key_of[i]
        if key == _CROPPED:
            continue
        if key == _BEYOND_KEYS:
            out = np.empty(1, np.int64)
            out[0] = _OUT_OF_RANGE
            return out
        if dedupe:
            # a scan's neighbours in storage order share voxels: the same key as the last is not new
            if key == last:
                continue
            last = key
            s = hash_slot_nb(key, log2_capacity)
            while keys[s] != EMPTY_KEY and keys[s] != key:
                s = (s + 1) & mask
            if keys[s] == key:
                continue
            if 2 * (m + 1) > capacity:
                out = np.empty(1, np.int64)
                out[0] = _TABLE_FULL
                return out
            keys[s] = key
        keep[m] = i
        m += 1
    return keep[:m]


def sample_points(points, n: int, rng: np.random.Generator) -> np.ndarray:
    """``min(n, N)`` distinct points drawn uniformly at random without replacement (order randomised).

    Parameters
    ----------
    points : (N, 3) array
    n : int
        Sample size (``n <= 0`` or ``n >= N`` returns all points, in the input order).
    rng : numpy.random.Generator
        The randomness (seeded by the caller).
    """
    pts = np.asarray(points)
    if n <= 0 or n >= len(pts):
        return pts
    return pts[rng.choice(len(pts), size=int(n), replace=False)]


def road_mask(points) -> np.ndarray:
    """Which body-frame ``points (N, 3)`` lie on the road: at most :data:`GROUND_BAND_M` above the road surface, the
    :data:`GROUND_PERCENTILE` of z (N,) bool; all False for no points."""
    pts = np.asarray(points)
    if len(pts) == 0:
        return np.zeros(0, dtype=bool)
    return pts[:, 2] <= np.percentile(pts[:, 2], GROUND_PERCENTILE) + GROUND_BAND_M


def thin_ground(points, share: float, rng: np.random.Generator) -> np.ndarray:
    """The body-frame ``points (N, 3)`` with the road thinned to ``share`` of the result: every point more than
    :data:`GROUND_BAND_M` above the road surface (the :data:`GROUND_PERCENTILE` of z), and of the road points a
    random subset of ``share / (1 - share)`` times their number (all of them if fewer; ``share = 1`` keeps all).

    Why: the road's returns lie on the LIDAR's rings, circles around the sensor. The map holds those rings, and
    a scan taken from nearly the same place matches them best with **no** motion: the "ring artifact" that pulls a
    registration of slowly moving scans toward zero motion. An IMU outweighs that pull; LIDAR-only, the filter
    scores mostly what stands above the road, and keeps a little road for the height, roll and pitch
    (:mod:`slamlib.slam3d.pipeline`, "LIDAR-only"). Fewer than ten points above the road: all points.
    """
    pts = np.asarray(points)
    if share >= 1 or len(pts) == 0:
        return pts
    low = road_mask(pts)
    above, road = pts[~low], pts[low]
    if len(above) < 10:
        return pts
    k = min(len(road), int(share / (1.0 - share) * len(above)))
    return (
        np.concatenate([above, road[rng.choice(len(road), k, replace=False)]])
        if k
        else above
    )


def sample_thinned(points, share: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` points drawn as ``sample_points(thin_ground(points, share, rng), n, rng)`` draws them, without
    building the thinned pool: the same distribution, for a fifth of the time (LIDAR-only step 8's sample).

    The pool is the ``A`` points above the road and a uniform ``k``-subset of the road's ``G`` points, ``k`` as in
    :func:`thin_ground`. Drawing ``n`` of its ``A + k`` places uniformly without replacement, the places that fall
    on the subset are ``r`` uniform distinct road points whichever ``k`` the subset held, so they are drawn from the
    road directly: ``n`` distinct places of ``A + k``, then ``r`` distinct road points, each set uniform. Returns
    the whole pool (as :func:`thin_ground`) when ``n <= 0`` or ``n >= A + k``; ``points`` as it is for ``share >=
    1`` or fewer than ten points above the road, then sampled as :func:`sample_points` does.
    """
    pts = np.asarray(points)
    if share >= 1 or len(pts) == 0:
        return sample_points(pts, n, rng)
    low = road_mask(pts)
    above, road = np.flatnonzero(~low), np.flatnonzero(low)
    if len(above) < 10:
        return sample_points(pts, n, rng)
    k = min(len(road), int(share / (1.0 - share) * len(above)))
    if n <= 0 or n >= len(above) + k:
        return thin_ground(pts, share, rng)
    places = rng.choice(len(above) + k, size=int(n), replace=False)
    on_road = places >= len(above)
    chosen = np.empty(len(places), np.int64)
    chosen[~on_road] = above[places[~on_road]]
    chosen[on_road] = road[rng.choice(len(road), int(on_road.sum()), replace=False)]
    return pts[chosen]


def sweep_times(points_velo, period: float) -> np.ndarray:
    """Firing time ``(N,)`` s of each point relative to the scan's timestamp (mid-sweep), from its azimuth in the
    Velodyne frame: ``t = -atan2(y, x) / (2 pi) * period``.

    KITTI's HDL-64E sweep starts behind the car (azimuth ``+pi``), turns clockwise seen from above, faces forward
    at the timestamp and ends behind (``-pi``): measured on the real scans (surfaces just behind the car are
    nearer at ``+179`` than at ``-179`` deg while driving forward) and KISS-ICP's rule for KITTI,
    ``s = 0.5 (1 - atan2(y, x) / pi)`` in ``[0, 1]`` (``t = (s - 0.5) period``). Storage order is not firing order.
    """
    p = np.asarray(points_velo, dtype=np.float64)
    return -np.arctan2(p[:, 1], p[:, 0]) / (2.0 * np.pi) * float(period)


def deskew(points, velocity, angular_rate, times) -> np.ndarray:
    """Motion-compensate a scan: each point moved from the sensor frame at its firing time ``times[i]`` (s, relative
    to the scan's timestamp) into the frame at the timestamp, for a body moving with the constant twist
    ``(velocity (3,) m/s, angular_rate (3,) rad/s)`` (body frame).

    With ``phi = w t``: ``p' = Exp(phi) p + J(phi) v t`` (the SE(3) exponential of the twist over ``t``,
    :mod:`slamlib.odometry`): the pose at ``t`` relative to the timestamp's, applied to the point measured there.
    Rodrigues' formula about the one axis ``w / |w|`` for every point; ``J`` to second order
    (``v t + (phi x v t) / 2``: below 1 mm for the 0.05 s half-sweep at the rates cars turn at).
    Returns ``(N, 3)`` float32. (KISS-ICP de-skews the same way: Vizzo et al., RA-L 2023, sec. III-A.)
    """
    p = np.asarray(points, dtype=np.float64)
    t = np.asarray(times, dtype=np.float64)[:, None]
    v = np.asarray(velocity, dtype=np.float64).reshape(1, 3)
    w = np.asarray(angular_rate, dtype=np.float64).reshape(3)
    rate = float(np.linalg.norm(w))
    out = p.copy()
    if rate > 0:
        k = (w / rate).reshape(1, 3)
        theta = rate * t
        out = (
            p * np.cos(theta)
            + np.cross(k, p) * np.sin(theta)
            + k * (p @ k.T) * (1.0 - np.cos(theta))
        )
    vt = v * t
    out += vt + 0.5 * np.cross(w.reshape(1, 3) * t, vt)
    return out.astype(np.float32)
