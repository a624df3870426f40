"""A Velodyne HDL-64E model: ray casting a :class:`~slamlib.synth.scene.Scene` into KITTI-like scans.

Geometry (Velodyne frame: x forward, y left, z up):

* 64 beams at fixed elevations: the upper block of 32 lasers from +2.0 deg down to -8.33 deg (1/3 deg
  spacing), the lower block of 32 from -8.83 deg to -24.9 deg (~1/2 deg spacing), as in the HDL-64E S2
  manual and the elevation histogram of KITTI scans;
* ``columns`` azimuth steps over 360 deg: default 2000 (0.18 deg), the median azimuth spacing of one ring in
  the shipped real KITTI scans (0.179 deg; 1.3 M points/s at 10 Hz over 64 lasers); the HDL-64E's nominal
  0.09 deg (``columns=4000``) doubles the point count beyond KITTI's ~120 k per scan;
* ray ``(b, c)`` has direction ``d = (cos e_b cos a_c, cos e_b sin a_c, sin e_b)`` from the sensor origin;
* the ego vehicle's roof/rear (:data:`EGO_BOX`, an axis-aligned box in the Velodyne frame) hides the lowest
  beams behind the car, as in real scans (rays entering it are removed). The box is an effective occluder
  fitted to the per-ring point counts of the shipped real scans (rings are stored one after the other in a
  KITTI ``.bin``): no loss above about -17 deg, growing to about half of the lowest ring.

Measurement model for a ray hitting a surface at range ``r`` with unit normal ``n`` and albedo ``rho``:

* kept if ``min_range <= r <= max_range`` and not dropped: dropout probability
  ``p_keep = (1 - dropout) * (1 - exp(-(|n . d| / grazing_cos)^2))``. The second factor is the loss of returns
  at grazing incidence: the real scans' upper-block rings that meet the road 12-20 m out (``|n . d|`` about
  0.1) return ~25 % fewer points than the lower-block rings at -8.5 to -12 deg (``|n . d| >= 0.15``), which
  return almost every pulse; ``grazing_cos = 0.1`` reproduces that;
* range ``r' = r + sigma_range * N(0, 1)``, the point is ``r' d``;
* reflectance ``clip(rho * (0.3 + 0.7 |n . d|) * exp(-r / 200) + sigma_refl * N(0, 1), 0, 0.99)`` (Lambertian
  falloff with incidence, slight range attenuation).

Sweep timing (``column_poses``): a real HDL-64E turns once in 0.1 s, so at 10 m/s the end of a sweep is ~1 m from
its start, and KITTI's raw "sync" scans are not de-skewed. Measured on the shipped real scans: the sweep
starts behind the car at azimuth ``+pi``, turns clockwise seen from above (azimuth decreasing), faces forward at
the frame's timestamp (mid-sweep) and ends behind at ``-pi``, so the column at azimuth ``a`` (``atan2(y, x)``) fires
:func:`column_time_offsets` ``= -a / (2 pi) * period`` seconds after the timestamp. Given one sensor pose per
column, each column is cast from its own pose and stored in the sensor frame of that instant (``r' d``, as the
real sensor does): the scan is distorted exactly like a real one. Without them every ray is cast from one pose
(no distortion; the pose at the OXTS timestamp).

Moving objects (``movers``, :mod:`slamlib.synth.traffic`): every ray is also cast against a small scene of the
movers' boxes and the nearer hit is kept, with the albedo of whichever surface it hit. Without ``column_poses``
all rays see the movers at the frame's instant. With them the sweep is cut by firing time into
:data:`MOVER_BLOCKS` equal blocks and each block's rays see the movers where they are at the block's middle
instant: a mover of speed ``v`` is then at most ``v * period / (2 * MOVER_BLOCKS)`` from where it truly is when a
column fires (4.5 cm at 14 m/s), well inside the centimetres of range noise, instead of one mover scene per column.
Only the rays whose azimuth falls within a mover triangle's azimuth span are cast against the movers (a tenth of
them in a busy street; the same hits as casting all). Cost, default sensor along route 07 with the default traffic
(:class:`~slamlib.synth.traffic.TrafficConfig`, ~20 movers in view), on a 2-core machine: about +9 ms a scan
without sweep distortion and +10 ms with it (+30-40 % of ~28 ms); three times as dense, +7 and +14 ms.

Reference: Velodyne HDL-64E S2 user's manual (2008); Geiger et al., IJRR 2013, sec. 2.
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass

import numpy as np

from slamlib.kitti.velodyne import SWEEP_PERIOD_S

__all__ = [
    "Hdl64",
    "hdl64_elevations",
    "ray_directions",
    "ray_columns",
    "column_time_offsets",
    "simulate_scan",
    "EGO_BOX",
    "SCAN_PERIOD_S",
    "MOVER_BLOCKS",
]

#: The HDL-64E's sweep period on KITTI (s): :data:`slamlib.kitti.velodyne.SWEEP_PERIOD_S`.
SCAN_PERIOD_S = SWEEP_PERIOD_S

#: Ego-vehicle box in the Velodyne frame, ``((xmin, ymin, zmin), (xmax, ymax, zmax))`` m: the roof ~0.6 m below
#: the sensor, extending 1.6 m behind it (Geiger et al. IJRR 2013, Fig. 3). An effective occluder, not the car's
#: outline: its width and height were fitted to the real sample scans (``slamlib/data/kitti/velodyne_sample``),
#: to their elevation histogram (every 5-degree bin within 15 %, averaged along the route) and their per-ring
#: point counts (lower block within 10 % RMS; its lowest four rings keep about 40 % fewer points than the real
#: ones, whose apparent elevations sit higher because the lasers are not at the sensor origin).
EGO_BOX = ((-1.6, -1.4, -2.0), (0.5, 1.4, -0.6))

#: Blocks of the sweep (by firing time) that see the moving objects at one instant each (module docstring).
MOVER_BLOCKS = 16


def _hits_box(d: np.ndarray, box) -> np.ndarray:
    """Slab test: which rays from the origin along ``d (N, 3)`` enter the axis-aligned ``box``."""
    lo, hi = np.asarray(box[0]), np.asarray(box[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d.astype(np.float64)
        t1, t2 = lo * inv, hi * inv
    tmin = np.nanmax(np.minimum(t1, t2), axis=1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=1)
    return tmax >= np.maximum(tmin, 0.0)


def hdl64_elevations() -> np.ndarray:
    """Elevation angles (rad) of the 64 HDL-64E beams, top to bottom, shape (64,)."""
    upper = np.linspace(2.0, -8.33, 32)
    lower = np.linspace(-8.83, -24.9, 32)
    return np.deg2rad(np.r_[upper, lower])


@dataclass(frozen=True)
class Hdl64:
    """HDL-64E model parameters (see the module docstring). ``beam_stride`` / ``columns`` reduce resolution
    (e.g. for fast tests): beams ``elevations[::beam_stride]``, ``columns`` azimuth steps."""

    columns: int = 2000
    beam_stride: int = 1
    max_range: float = 120.0
    min_range: float = 2.5
    sigma_range: float = 0.02
    dropout: float = 0.02
    grazing_cos: float = 0.1
    sigma_refl: float = 0.03
    ego_occlusion: bool = True

    def as_dict(self) -> dict:
        return asdict(self)


def _ray_grid(model: Hdl64) -> tuple[np.ndarray, np.ndarray]:
    """Every ray's unit direction ``(M, 3)`` float64 and azimuth column ``(M,)``, beam-major, the rays the ego
    vehicle hides removed."""
    e = hdl64_elevations()[:: model.beam_stride]
    a = 2 * np.pi * np.arange(model.columns) / model.columns
    ce, se = np.cos(e)[:, None], np.sin(e)[:, None]
    d = np.stack(
        [
            ce * np.cos(a)[None],
            ce * np.sin(a)[None],
            np.broadcast_to(se, (len(e), len(a))),
        ],
        axis=-1,
    )
    d = d.reshape(-1, 3)
    cols = np.broadcast_to(np.arange(model.columns), (len(e), model.columns)).reshape(-1)
    if model.ego_occlusion:
        seen = ~_hits_box(d, EGO_BOX)
        d, cols = d[seen], cols[seen]
    return d, cols.astype(np.int64)


def ray_directions(model: Hdl64 = Hdl64()) -> np.ndarray:
    """Unit ray directions ``(M, 3)`` float32 in the Velodyne frame, beam-major (beam b, column c), without
    the rays the ego vehicle hides (``M <= B * C``)."""
    return _ray_grid(model)[0].astype(np.float32)


def ray_columns(model: Hdl64 = Hdl64()) -> np.ndarray:
    """The azimuth column ``(M,)`` int64 of each ray of :func:`ray_directions` (same order, same occlusion)."""
    return _ray_grid(model)[1]


def column_time_offsets(
    model: Hdl64 = Hdl64(), period: float = SCAN_PERIOD_S
) -> np.ndarray:
    """Firing time of each azimuth column relative to the frame's (mid-sweep) timestamp, ``(columns,)`` seconds:
    ``-a / (2 pi) * period`` with ``a`` the column's azimuth in ``(-pi, pi]`` (module docstring: the sweep runs
    from ``+pi`` at ``-period / 2`` through forward at 0 to ``-pi`` at ``+period / 2``)."""
    a = 2 * np.pi * np.arange(model.columns) / model.columns
    a = np.where(a > np.pi, a - 2 * np.pi, a)
    return -a / (2 * np.pi) * period


def simulate_scan(
    raycasting_scene,
    albedo: np.ndarray,
    T_w_velo: np.ndarray,
    rng: np.random.Generator,
    model: Hdl64 = Hdl64(),
    directions: np.ndarray | None = None,
    column_poses: np.ndarray | None = None,
    columns: np.ndarray | None = None,
    movers=None,
) -> np.ndarray:
    """One scan ``(N, 4)`` float32 ``x, y, z, reflectance`` in the Velodyne frame.

    Parameters
    ----------
    raycasting_scene : ``open3d.t.geometry.RaycastingScene`` of the town (``Scene.raycasting_scene()``).
    albedo : (F,) per-triangle albedo of that scene.
    T_w_velo : (4, 4) Velodyne pose in the world frame (used when ``column_poses`` is None).
    rng : noise source (dropouts, range and reflectance noise).
    model : sensor parameters; ``directions`` optionally the precomputed :func:`ray_directions` of it.
    column_poses : (columns, 4, 4), optional
        The Velodyne pose at each azimuth column's firing time (:func:`column_time_offsets`): the sweep is
        distorted as a real one; each point is stored in the sensor frame of its own column's instant.
        ``columns`` optionally the precomputed :func:`ray_columns` (with ``directions``).
    movers : callable, optional
        ``movers(dts (K,)) -> [(vertices (V, 3) float32, triangles (F, 3) uint32, albedo (F,) float32)] * K``: the
        moving objects (world frame) ``dts[k]`` seconds after the frame's instant (the instant of ``T_w_velo``, or
        the mid-sweep instant the ``column_poses`` are centred on), all asked for at once; see the module
        docstring. ``None``: a static world, exactly as without the argument.
    """
    import open3d as o3d

    d = ray_directions(model) if directions is None else directions
    rays = np.empty((len(d), 6), dtype=np.float32)
    if column_poses is None:
        R = np.asarray(T_w_velo[:3, :3], dtype=np.float32)
        rays[:, :3] = np.asarray(T_w_velo[:3, 3], dtype=np.float32)
        rays[:, 3:] = d @ R.T
    else:
        cols = ray_columns(model) if columns is None else columns
        if len(cols) != len(d) or len(column_poses) != model.columns:
            raise ValueError(
                f"column_poses must be ({model.columns}, 4, 4) for the model's own ray directions"
            )
        P = np.asarray(column_poses, dtype=np.float64)[cols]
        rays[:, :3] = P[:, :3, 3]
        rays[:, 3:] = np.einsum("nij,nj->ni", P[:, :3, :3], d.astype(np.float64))
    ans = raycasting_scene.cast_rays(o3d.core.Tensor(rays))
    r = ans["t_hit"].numpy()
    normals = ans["primitive_normals"].numpy()
    prim_all = ans["primitive_ids"].numpy()
    if movers is not None:
        if column_poses is None:
            blocks = [(0.0, np.arange(len(rays)), 0.0)]
        else:
            blocks = _sweep_blocks(cols, model, np.asarray(column_poses)[:, :3, 3])
        m_t, m_n, m_alb = _cast_movers(rays, movers, blocks)
        on_mover = m_t < r
        nearer = np.flatnonzero(on_mover)
        r, normals = r.copy(), normals.copy()
        r[nearer], normals[nearer] = m_t[nearer], m_n[nearer]
    hit = np.isfinite(r) & (r <= model.max_range) & (r >= model.min_range)
    idx = np.flatnonzero(hit)
    r = r[idx].astype(np.float64)
    prim = prim_all[idx]
    n_w = normals[idx]
    if movers is None:
        alb = albedo[prim]
    else:
        m = on_mover[idx]
        alb = np.where(m, m_alb[idx], albedo[np.where(m, 0, prim)])
    cos_inc = np.abs(np.einsum("ij,ij->i", n_w, rays[idx, 3:]))
    p_drop = 1.0 - (1.0 - model.dropout) * (
        -np.expm1(-((cos_inc / model.grazing_cos) ** 2)) if model.grazing_cos > 0 else 1.0
    )
    keep = rng.random(len(idx)) >= p_drop
    idx, r, alb, cos_inc = idx[keep], r[keep], alb[keep], cos_inc[keep]
    r_meas = r + model.sigma_range * rng.standard_normal(len(r))
    refl = alb * (0.3 + 0.7 * cos_inc) * np.exp(-r / 200.0)
    refl = np.clip(refl + model.sigma_refl * rng.standard_normal(len(r)), 0.0, 0.99)
    out = np.empty((len(idx), 4), dtype=np.float32)
    out[:, :3] = d[idx] * r_meas[:, None].astype(np.float32)
    out[:, 3] = refl
    return out


def _sweep_blocks(
    cols: np.ndarray, model: Hdl64, positions: np.ndarray, blocks: int = MOVER_BLOCKS
) -> list[tuple[float, np.ndarray, float]]:
    """Cut the sweep into ``blocks`` equal spans of firing time: ``[(dt, rays, spread)]``, the span's middle instant
    (s after the mid-sweep timestamp), the indices of its rays (``cols (M,)`` each ray's column) and the size (m) of
    the box holding its columns' sensor positions ``positions (columns, 3)`` (an upper bound of how far its rays'
    origins are from any one of them)."""
    block_of_col, parts = _block_partition(model, blocks, cols.tobytes())
    out = []
    for b, dt, sel in parts:
        spread = float(np.linalg.norm(np.ptp(positions[block_of_col == b], axis=0)))
        out.append((dt, sel, spread))
    return out


@functools.lru_cache(maxsize=8)
def _block_partition(
    model: Hdl64, blocks: int, cols_bytes: bytes
) -> tuple[np.ndarray, list]:
    """The sweep's blocks of :func:`_sweep_blocks` for one sensor and ray order (cached: the same every scan):
    ``(block of each column (columns,), [(block, dt, ray indices)])``, empty blocks left out."""
    cols = np.frombuffer(cols_bytes, dtype=np.int64)
    offsets = column_time_offsets(model)
    span = SCAN_PERIOD_S / blocks
    block_of_col = np.clip(
        np.floor((offsets + SCAN_PERIOD_S / 2) / span), 0, blocks - 1
    ).astype(np.int64)
    ray_block = block_of_col[cols]
    parts = []
    for b in range(blocks):
        sel = np.flatnonzero(ray_block == b)
        if len(sel):
            parts.append((b, (b + 0.5) * span - SCAN_PERIOD_S / 2, sel))
    return block_of_col, parts


def _cast_movers(
    rays: np.ndarray, movers, blocks
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cast ``rays (M, 6)`` against the movers of each block: ``(t_hit (M,) float32, inf for a miss; normals (M, 3)
    float32; albedo (M,) float32)``. ``blocks`` ``[(dt, ray indices, spread of their origins)]``, the movers taken
    from ``movers(all the blocks' dt)``.

    Only the rays whose world azimuth falls within a mover triangle's azimuth span (:func:`_azimuth_mask`) are
    cast: a few per cent of them in a city street, and the same hits as casting them all."""
    import open3d as o3d

    t_hit = np.full(len(rays), np.inf, dtype=np.float32)
    normals = np.zeros((len(rays), 3), dtype=np.float32)
    alb = np.zeros(len(rays), dtype=np.float32)
    azimuth = np.arctan2(rays[:, 4], rays[:, 3])
    meshes = movers(np.array([dt for dt, _, _ in blocks]))
    for (_dt, sel, spread), (v, f, a) in zip(blocks, meshes):
        if len(f) == 0:
            continue
        sel = sel[
            _azimuth_mask(
                rays[sel[0], :3],
                spread,
                azimuth[sel],
                np.asarray(v, np.float64),
                np.asarray(f),
            )
        ]
        if len(sel) == 0:
            continue
        rc = o3d.t.geometry.RaycastingScene()
        rc.add_triangles(
            o3d.core.Tensor(np.ascontiguousarray(v, np.float32)),
            o3d.core.Tensor(np.ascontiguousarray(f, np.uint32)),
        )
        ans = rc.cast_rays(o3d.core.Tensor(np.ascontiguousarray(rays[sel])))
        th = ans["t_hit"].numpy()
        ok = np.isfinite(th)
        t_hit[sel] = th
        normals[sel] = ans["primitive_normals"].numpy()
        alb[sel] = np.where(
            ok,
            np.asarray(a, np.float32)[np.where(ok, ans["primitive_ids"].numpy(), 0)],
            0.0,
        )
    return t_hit, normals, alb


#: Azimuth bins of the mover culling (:func:`_azimuth_mask`): 0.09 deg, half a column of the default sensor.
AZIMUTH_BINS = 4096


def _azimuth_mask(
    o: np.ndarray, spread: float, azimuth: np.ndarray, v: np.ndarray, f: np.ndarray
) -> np.ndarray:
    """Which rays (world azimuths ``azimuth (K,)`` rad, origins within ``spread`` m of ``o (3,)``) may hit the
    triangles ``v (V, 3)``, ``f (F, 3)``: bool (K,).

    Seen from ``o``, a triangle not containing ``o`` in its ground-plane projection covers the azimuths between its
    vertices' (unwrapped about its first vertex's). A ray leaving up to ``e = spread`` away sees a point at distance
    ``d`` turned by at most ``asin(e / d)``: the spans are widened by that (at the nearest vertex) and by two bins.
    Any vertex within ``e`` + 0.5 m of ``o`` keeps every ray (never for traffic, which stays metres away)."""
    rel = v[:, :2] - o[:2]
    dist = np.hypot(rel[:, 0], rel[:, 1])
    if dist.min() <= spread + 0.5:
        return np.ones(len(azimuth), dtype=bool)
    theta = np.arctan2(rel[:, 1], rel[:, 0])[f]  # (F, 3)
    # unwrapped about the first vertex, in (-pi, pi]
    d = np.angle(np.exp(1j * (theta - theta[:, :1])))
    width = 2 * np.pi / AZIMUTH_BINS
    margin = np.arcsin(min(1.0, spread / dist.min())) + 2 * width
    lo = theta[:, 0] + d.min(1) - margin
    hi = theta[:, 0] + d.max(1) + margin
    first = np.floor(lo / width).astype(np.int64)
    count = np.floor(hi / width).astype(np.int64) - first + 1
    start = first % AZIMUTH_BINS
    # two turns: spans crossing +-pi do not wrap
    marks = np.zeros(2 * AZIMUTH_BINS + 1, dtype=np.int64)
    np.add.at(marks, start, 1)
    np.add.at(marks, np.minimum(start + count, 2 * AZIMUTH_BINS), -1)
    covered = np.cumsum(marks)[:-1] > 0
    covered = covered[:AZIMUTH_BINS] | covered[AZIMUTH_BINS:]
    return covered[np.floor(azimuth / width).astype(np.int64) % AZIMUTH_BINS]
