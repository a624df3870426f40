"""Statistics, views and pairwise alignment of single Velodyne scans (KITTI ``.bin`` layout).

Pure functions on ``(N, 3)`` or ``(N, 4)`` arrays of points in the Velodyne frame (x forward, y left, z up,
metres); a fourth column (reflectance) is ignored. Angles are in radians unless a name ends in ``_deg``:

* azimuth ``a = atan2(y, x) mod 2 pi`` in ``[0, 2 pi)``: 0 straight ahead, ``pi / 2`` to the left,
  increasing counter-clockwise seen from above (the way the HDL-64E spins in KITTI);
* elevation ``e = atan2(z, sqrt(x^2 + y^2))`` in ``[-pi/2, pi/2]``: 0 horizontal, negative towards the road;
* range ``r = sqrt(x^2 + y^2 + z^2)`` (m), from the sensor origin.

**Rings.** A KITTI raw ``.bin`` stores the 64 lasers' rings one after another, top laser first; within a ring
the points follow the spin, so the azimuth grows from just left of straight ahead (a few degrees) round to just
right of it (~355 deg), and drops by almost ``2 pi`` where the next ring starts. :func:`ring_index` splits a
scan there. (Elevation alone cannot separate rings: the lasers are mounted a few centimetres apart, so one
ring's elevation seen from the origin varies with range.) ``slamlib.synth`` writes its scans in the same order
(beam-major, azimuth from 0), so the split works on both. A ring with no return at all leaves no trace: the
split then finds fewer rings.

Reference: Velodyne HDL-64E S2 user's manual; Geiger et al., "Vision meets Robotics: The KITTI Dataset",
IJRR 2013; Triess et al., "Scan-based Semantic Segmentation of LiDAR Point Clouds: An Experimental Study",
IV 2020 (ring recovery from the azimuth wrap, "scan unfolding"); Rusinkiewicz & Levoy, "Efficient Variants of
the ICP Algorithm", 3DIM 2001 (point-to-plane ICP).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "ELEVATION_BINS_DEG",
    "azimuth",
    "elevation",
    "ranges",
    "ring_index",
    "ring_counts",
    "elevation_fractions",
    "front_view",
    "range_image",
    "IcpResult",
    "icp_align",
]

#: Elevation bin edges (deg) for comparing scans: the HDL-64E's +2 to -24.9 deg field of view in 5-degree bins
#: (the two end bins stretched to hold the top and bottom beams).
ELEVATION_BINS_DEG = (-26.0, -20.0, -15.0, -10.0, -5.0, 0.0, 3.0)


def _xyz(points) -> np.ndarray:
    p = np.asarray(points)
    if p.ndim != 2 or p.shape[1] < 3:
        raise ValueError(f"points must be (N, 3) or (N, 4), got shape {p.shape}")
    return p[:, :3].astype(np.float64, copy=False)


def azimuth(points) -> np.ndarray:
    """Azimuth ``atan2(y, x) mod 2 pi`` (rad, ``[0, 2 pi)``, counter-clockwise from x = forward), shape (N,)."""
    p = _xyz(points)
    return np.mod(np.arctan2(p[:, 1], p[:, 0]), 2 * np.pi)


def elevation(points) -> np.ndarray:
    """Elevation ``atan2(z, sqrt(x^2 + y^2))`` (rad, negative below the horizontal), shape (N,)."""
    p = _xyz(points)
    return np.arctan2(p[:, 2], np.hypot(p[:, 0], p[:, 1]))


def ranges(points) -> np.ndarray:
    """Range ``|p|`` (m) of each point from the sensor origin, shape (N,)."""
    return np.linalg.norm(_xyz(points), axis=1)


def ring_index(scan, min_drop: float = np.pi / 2) -> np.ndarray:
    """Ring number of each point of a scan stored ring after ring (KITTI ``.bin``), shape (N,) int64.

    A new ring starts at point ``k`` when the azimuth drops by more than ``min_drop`` (rad) from point ``k - 1``:
    ``ring[k] = #{j <= k : a[j-1] - a[j] > min_drop}``. Within a ring the azimuth only grows (the real samples
    step back by at most 0.01 deg), while a ring change drops it by ~340 deg, so any ``min_drop`` between a few
    degrees and ~300 deg gives the same split. Ring 0 is the first stored (the top laser in KITTI).
    """
    a = azimuth(scan)
    out = np.zeros(len(a), dtype=np.int64)
    if len(a) > 1:
        out[1:] = np.cumsum(a[:-1] - a[1:] > min_drop)
    return out


def ring_counts(scan, n_rings: int = 64, min_drop: float = np.pi / 2) -> np.ndarray:
    """Points per ring ``(max(n_rings, rings found),)`` int64 (see :func:`ring_index`); rings found beyond
    ``n_rings`` (a scan not stored ring after ring) make the result longer, so a caller can check its length."""
    idx = ring_index(scan, min_drop)
    return np.bincount(idx, minlength=n_rings).astype(np.int64)


def elevation_fractions(scan, edges_deg=ELEVATION_BINS_DEG) -> np.ndarray:
    """Fraction of the points whose elevation falls in each bin ``[edges[i], edges[i+1])`` (deg), shape (B,).

    ``h_i / sum(h)`` with ``h`` the histogram counts: points outside the edges are not counted, and the
    fractions sum to 1 (NaN for a scan with no point inside the edges).
    """
    h = np.histogram(
        np.degrees(elevation(scan)), bins=np.asarray(edges_deg, dtype=np.float64)
    )[0]
    total = h.sum()
    return h / total if total else np.full(len(h), np.nan)


def front_view(points, az_limits_deg=(-60.0, 60.0), max_range: float = np.inf):
    """The points ahead of the sensor as seen from it: ``(az_deg, el_deg, range_m)``, each (M,) float64.

    Keeps the points whose *signed* azimuth ``atan2(y, x)`` (deg, positive to the left) lies within
    ``az_limits_deg`` and whose range is at most ``max_range``; ordered from far to near, so a scatter plot
    of ``(-az_deg, el_deg)`` (left of the car on the left, as a driver sees it) draws near surfaces on top.
    """
    p = _xyz(points)
    az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    r = np.linalg.norm(p, axis=1)
    keep = (az >= az_limits_deg[0]) & (az <= az_limits_deg[1]) & (r <= max_range)
    order = np.argsort(-r[keep], kind="stable")
    az, r = az[keep][order], r[keep][order]
    el = np.degrees(
        np.arcsin(np.clip(p[keep][order][:, 2] / np.maximum(r, 1e-12), -1.0, 1.0))
    )
    return az, el, r


def range_image(
    scan,
    az_limits_deg=(-180.0, 180.0),
    columns: int = 2000,
    n_rings: int = 64,
    min_drop: float = np.pi / 2,
) -> np.ndarray:
    """The scan on the sensor's own grid: ``(n_rings, W)`` float64 ranges (m), NaN where no return.

    Row ``i`` is ring ``i`` (:func:`ring_index`; ring 0, the top laser in KITTI, at the top). Columns are
    ``d = 360 / columns`` deg apart and run **from the left**: column ``j`` holds the points whose signed
    azimuth ``atan2(y, x)`` (deg) is nearest ``az_limits_deg[1] - j d``, for the ``W = round((hi - lo) / d)``
    columns from ``hi = az_limits_deg[1]`` towards ``lo = az_limits_deg[0]``, so the image reads like a camera
    looking along x (the car's left on the left). Rounding to the nearest column (rather than cutting at
    multiples of ``d``) keeps scans fired at exact multiples of ``d`` (``slamlib.synth``) from landing on bin
    edges. A pixel holding several points keeps the nearest (smallest range); rings beyond ``n_rings`` are
    dropped.
    """
    lo, hi = float(az_limits_deg[0]), float(az_limits_deg[1])
    if not hi > lo or columns < 1:
        raise ValueError("need az_limits_deg[0] < az_limits_deg[1] and columns >= 1")
    step = 360.0 / columns
    width = max(1, int(round((hi - lo) / step)))
    p = _xyz(scan)
    ring = ring_index(scan, min_drop)
    az = np.degrees(np.arctan2(p[:, 1], p[:, 0]))
    col = np.round((hi - az) / step).astype(np.int64)
    keep = (ring < n_rings) & (col >= 0) & (col < width)
    img = np.full(n_rings * width, np.inf)
    np.minimum.at(img, ring[keep] * width + col[keep], np.linalg.norm(p[keep], axis=1))
    img[np.isinf(img)] = np.nan
    return img.reshape(n_rings, width)


@dataclass(frozen=True)
class IcpResult:
    """Result of :func:`icp_align`.

    ``T (4, 4)``: ``T_target_source``, maps source points into the target frame, ``p_t = T p_s``.
    ``fitness``: fraction of the (down-sampled) source points with a target point within ``max_distance``
    (the last, finest correspondence distance, m) after alignment; ``inlier_rmse`` (m): RMS distance of those
    pairs. ``fitness_init`` / ``inlier_rmse_init``: the same at the initial guess, for comparison.
    ``n_source``, ``n_target``: down-sampled point counts; ``max_distance`` (m).
    """

    T: np.ndarray
    fitness: float
    inlier_rmse: float
    fitness_init: float
    inlier_rmse_init: float
    n_source: int
    n_target: int
    max_distance: float


def icp_align(
    source,
    target,
    init=None,
    voxel_size: float = 0.2,
    max_distances=(1.0, 0.5, 0.25),
    min_range: float = 3.0,
    max_range: float = 80.0,
    max_iteration: int = 60,
) -> IcpResult:
    """Rigid pose ``T_target_source`` aligning two scans by point-to-plane ICP (open3d), coarse to fine.

    Both scans are cropped to ``min_range <= r <= max_range`` (m; drops the returns off the car itself),
    down-sampled to one point per ``voxel_size`` voxel, and the target gets normals ``n`` (PCA of its
    neighbours within ``3 voxel_size``). Each ICP round minimises ``sum_i ((T s_i - t_i) . n_i)^2`` over the
    pairs ``(s_i, t_i)`` of nearest neighbours closer than its distance; the rounds use ``max_distances`` (m)
    in turn, each starting from the previous result (the first from ``init``, default identity), so a
    wide first round catches large motions and the last one only pairs points on the same surfaces.

    ``open3d.pipelines.registration.registration_icp`` with ``TransformationEstimationPointToPlane``. ICP
    finds the *nearest* local optimum: ``init`` must be within about the first distance of the truth.
    Returns an :class:`IcpResult`.
    """
    import open3d as o3d

    reg = o3d.pipelines.registration

    def cloud(points):
        p = _xyz(points)
        r = np.linalg.norm(p, axis=1)
        pc = o3d.geometry.PointCloud(
            o3d.utility.Vector3dVector(p[(r >= min_range) & (r <= max_range)])
        )
        pc = pc.voxel_down_sample(voxel_size)
        pc.estimate_normals(
            o3d.geometry.KDTreeSearchParamHybrid(radius=3 * voxel_size, max_nn=30)
        )
        return pc

    src, tgt = cloud(source), cloud(target)
    if len(src.points) < 3 or len(tgt.points) < 3:
        raise ValueError(
            "icp_align: fewer than 3 points left in a scan after cropping and down-sampling"
        )
    T0 = np.eye(4) if init is None else np.asarray(init, dtype=np.float64)
    T = T0.copy()
    criteria = reg.ICPConvergenceCriteria(max_iteration=max_iteration)
    for d in max_distances:
        T = reg.registration_icp(
            src, tgt, float(d), T, reg.TransformationEstimationPointToPlane(), criteria
        ).transformation
    d = float(max_distances[-1])
    final = reg.evaluate_registration(src, tgt, d, T)
    start = reg.evaluate_registration(src, tgt, d, T0)
    return IcpResult(
        T=np.array(T),
        fitness=float(final.fitness),
        inlier_rmse=float(final.inlier_rmse),
        fitness_init=float(start.fitness),
        inlier_rmse_init=float(start.inlier_rmse),
        n_source=len(src.points),
        n_target=len(tgt.points),
        max_distance=d,
    )
