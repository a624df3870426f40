"""A procedural town around a route, as one triangle mesh for ray casting (``open3d.t.geometry.RaycastingScene``).

Built once per drive from the route's positions (world frame = IMU pose at the drive's first frame, z up),
deterministic from ``seed``:

* **ground**: a grid (``ground_cell`` m) covering only the cells within ``extent`` m of the route (culling);
  its height is the road height under the route (IMU height minus :data:`IMU_HEIGHT`), interpolated by
  inverse-distance weighting of the nearest route samples, plus a gentle undulation growing away from the
  road (so slopes are gentle and the road stays where the car drives).
* **along each side of the road**, walking along the route: building blocks (facades 8-30 m long, set back
  8-16 m from the centre line, 6-22 m tall) separated by gaps, walls (1-2.5 m), parked cars (4.2 x 1.8 x 1.5
  m boxes at 4-5 m; three in ten are vans of 2.0-2.6 m, the only vehicles that reach the sensor's 1.73 m and
  return the near-horizontal beams), poles (0.15 m, 6 m tall) and trees (trunk + crown); some stretches are *repetitive*
  (identical poles/trees every 10 m, the hard case for scan matching).
* objects whose footprint comes within ``road_clearance`` m of *any* part of the route are dropped, so
  crossings and revisits (loops) stay drivable.

Each triangle carries an albedo (:attr:`Scene.albedo`, in [0, 1]) used by the LIDAR model for reflectance.
Objects are instanced from low-poly numpy templates (box, octagonal prism, octahedral crown) and
concatenated, which is much faster than merging many ``open3d`` meshes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Scene", "build_scene", "IMU_HEIGHT"]

#: Height of the IMU above the road (m): the Velodyne is 1.73 m above the road and 0.80 m above the IMU
#: (``calib_imu_to_velo.txt``), see Geiger et al. IJRR 2013 Fig. 3.
IMU_HEIGHT = 0.93


@dataclass
class Scene:
    """Triangle soup of the town: ``vertices (V, 3)`` float32 world coordinates, ``triangles (F, 3)`` uint32,
    ``albedo (F,)`` float32 per-triangle reflectivity, ``kind (F,)`` uint8 object class (0 ground, 1 building,
    2 wall, 3 car, 4 pole, 5 trunk, 6 crown)."""

    vertices: np.ndarray
    triangles: np.ndarray
    albedo: np.ndarray
    kind: np.ndarray

    KINDS = ("ground", "building", "wall", "car", "pole", "trunk", "crown")

    @classmethod
    def from_boxes(cls, boxes, albedo: float = 0.5) -> Scene:
        """A scene of axis-aligned boxes ``[(lo (3,), hi (3,)), ...]`` (opposite corners, world frame, m), each of
        kind ``"wall"`` and reflectivity ``albedo``: a yard to try the sensor model in (the book's swept wall)."""
        b = _Builder()
        for lo, hi in boxes:
            lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
            if lo.shape != (3,) or hi.shape != (3,) or not np.all(hi > lo):
                raise ValueError(
                    f"a box is two corners (lo, hi) with hi > lo on every axis, got {lo}, {hi}"
                )
            b.add(
                _BOX,
                np.r_[(lo[:2] + hi[:2]) / 2, lo[2]],
                hi - lo,
                0.0,
                albedo,
                cls.KINDS.index("wall"),
            )
        return b.build()

    def raycasting_scene(self):
        """An ``open3d.t.geometry.RaycastingScene`` holding the mesh (geometry id 0)."""
        import open3d as o3d

        rc = o3d.t.geometry.RaycastingScene()
        rc.add_triangles(o3d.core.Tensor(self.vertices), o3d.core.Tensor(self.triangles))
        return rc

    def to_open3d(self):
        """The mesh as a legacy ``open3d.geometry.TriangleMesh`` (for viewing)."""
        import open3d as o3d

        m = o3d.geometry.TriangleMesh(
            o3d.utility.Vector3dVector(self.vertices.astype(np.float64)),
            o3d.utility.Vector3iVector(self.triangles.astype(np.int32)),
        )
        m.compute_vertex_normals()
        return m

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)


# --- templates: unit shapes centred at the origin of their footprint, base at z = 0 -------------------------
def _box_template():
    v = np.array(
        [[x, y, z] for z in (0, 1) for y in (-0.5, 0.5) for x in (-0.5, 0.5)],
        dtype=np.float64,
    )
    # vertex index = 4*z + 2*y + x
    # -x, +x
    f = np.array(
        [
            [0, 2, 1],
            [1, 2, 3],
            [4, 5, 6],
            [5, 7, 6],  # bottom, top
            [0, 1, 4],
            [1, 5, 4],
            [2, 6, 3],
            [3, 6, 7],  # -y, +y
            [0, 4, 2],
            [2, 4, 6],
            [1, 3, 5],
            [3, 7, 5],
        ]
    )
    return v, f


def _prism_template(k: int = 8):
    a = 2 * np.pi * np.arange(k) / k
    ring = np.c_[0.5 * np.cos(a), 0.5 * np.sin(a)]
    v = np.vstack([np.c_[ring, np.zeros(k)], np.c_[ring, np.ones(k)], [[0, 0, 1]]])
    f = []
    for i in range(k):
        j = (i + 1) % k
        f += [[i, j, k + i], [j, k + j, k + i], [k + i, k + j, 2 * k]]
    return v, np.array(f)


def _crown_template():
    """Octahedron squashed to a crown, unit diameter, base at z = 0 and top at z = 1 (+ side mid-ring)."""
    k = 8
    a = 2 * np.pi * np.arange(k) / k
    ring = np.c_[0.5 * np.cos(a), 0.5 * np.sin(a), np.full(k, 0.5)]
    v = np.vstack([ring, [[0, 0, 0]], [[0, 0, 1]]])
    f = []
    for i in range(k):
        j = (i + 1) % k
        f += [[i, k, j], [i, j, k + 1]]
    return v, np.array(f)


_BOX, _PRISM, _CROWN = _box_template(), _prism_template(), _crown_template()


class _Builder:
    def __init__(self):
        self.v, self.f, self.alb, self.kind, self.nv = [], [], [], [], 0

    def add(self, template, centre, size, yaw, albedo, kind):
        """Instance ``template`` scaled by ``size (3,)``, rotated by ``yaw`` about z, base centre at ``centre``."""
        tv, tf = template
        c, s = np.cos(yaw), np.sin(yaw)
        v = tv * size
        v = np.c_[c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]] + centre
        self.v.append(v)
        self.f.append(tf + self.nv)
        self.nv += len(v)
        self.alb.append(np.full(len(tf), albedo, np.float32))
        self.kind.append(np.full(len(tf), kind, np.uint8))

    def add_mesh(self, v, f, albedo, kind):
        self.v.append(v)
        self.f.append(f + self.nv)
        self.nv += len(v)
        self.alb.append(np.asarray(albedo, np.float32) * np.ones(len(f), np.float32))
        self.kind.append(np.full(len(f), kind, np.uint8))

    def build(self) -> Scene:
        return Scene(
            np.vstack(self.v).astype(np.float32),
            np.vstack(self.f).astype(np.uint32),
            np.concatenate(self.alb),
            np.concatenate(self.kind),
        )


def _resample_by_arclength(p: np.ndarray, step: float) -> np.ndarray:
    d = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    s = np.arange(0.0, d[-1] + 1e-9, step)
    return np.c_[[np.interp(s, d, p[:, i]) for i in range(3)]].T


def build_scene(
    route_positions,
    seed: int = 0,
    extent: float = 90.0,
    ground_cell: float = 2.0,
    road_clearance: float = 3.2,
    parking_sides: tuple = (-1, 1),
) -> Scene:
    """Procedural town around a route (see the module docstring).

    Parameters
    ----------
    route_positions : (N, 3) IMU positions along the driven part of the route (world frame, m), densely
        sampled (any spacing; re-sampled every 1 m).
    seed : seed of the ``np.random.Generator`` laying out the objects.
    extent : ground is built within this distance (m) of the route (LIDAR range is ~120 m but returns
        beyond ~80 m are rare at street level).
    ground_cell : ground grid spacing (m).
    road_clearance : no object footprint within this distance (m) of the route centre line (parked cars:
        0.75 of it).
    parking_sides : the sides of the road with parked cars, -1 right and +1 left (moving traffic,
        :mod:`slamlib.synth.traffic`, drives its oncoming lane where the left ones would stand). The other
        objects and the random draws stay the same whatever the sides.
    """
    rng = np.random.default_rng(seed)
    p = _resample_by_arclength(np.asarray(route_positions, dtype=np.float64), 1.0)
    if len(p) < 2:
        p = np.vstack([p, p + [1.0, 0, 0]])
    # extend the street straight on by `lead` m before the start and after the end, so the drive does not
    # begin or end at the edge of the town
    lead = 60
    u0 = p[0] - p[min(5, len(p) - 1)]
    u1 = p[-1] - p[max(-6, -len(p))]
    u0[2] = u1[2] = 0.0
    u0 /= np.linalg.norm(u0) + 1e-12
    u1 /= np.linalg.norm(u1) + 1e-12
    steps = np.arange(1, lead + 1)[:, None]
    p = np.vstack([p[0] + steps[::-1] * u0, p, p[-1] + steps * u1])
    road = p.copy()
    road[:, 2] -= IMU_HEIGHT
    # imported here, not at the top: scipy.spatial costs 0.2 s of `slamlib run`'s start-up
    from scipy.spatial import cKDTree

    tree = cKDTree(road[:, :2])
    b = _Builder()

    # ---- ground ------------------------------------------------------------------------------------------
    lo = road[:, :2].min(0) - extent
    hi = road[:, :2].max(0) + extent
    nx = int(np.ceil((hi[0] - lo[0]) / ground_cell)) + 1
    ny = int(np.ceil((hi[1] - lo[1]) / ground_cell)) + 1
    gx, gy = np.meshgrid(
        lo[0] + ground_cell * np.arange(nx),
        lo[1] + ground_cell * np.arange(ny),
        indexing="ij",
    )
    gxy = np.c_[gx.ravel(), gy.ravel()]
    k = min(8, len(road))
    dist, idx = tree.query(gxy, k=k)
    dist, idx = dist.reshape(len(gxy), k), idx.reshape(len(gxy), k)
    w = 1.0 / (dist + 1.0) ** 2
    gz = (w * road[idx, 2]).sum(1) / w.sum(1)
    dmin = dist[:, 0]
    phase = rng.uniform(0, 2 * np.pi, 2)
    away = np.clip(dmin - 6.0, 0.0, None)
    gz += (
        0.015
        * away
        * np.sin(gxy[:, 0] / 37.0 + phase[0])
        * np.cos(gxy[:, 1] / 29.0 + phase[1])
    )
    gv = np.c_[gxy, gz]
    ii, jj = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="ij")
    a = (ii * ny + jj).ravel()
    quads = np.c_[a, a + ny, a + ny + 1, a + 1]
    keep = dmin.reshape(nx, ny)[:-1, :-1].ravel() < extent
    quads = quads[keep]
    tris = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    used, inv = np.unique(tris, return_inverse=True)
    b.add_mesh(gv[used], inv.reshape(-1, 3), 0.35, 0)

    def ground_z(xy):
        d, i = tree.query(np.atleast_2d(xy), k=k)
        w = 1.0 / (d.reshape(-1, k) + 1.0) ** 2
        return (w * road[i.reshape(-1, k), 2]).sum(1) / w.sum(1)

    def clear(centre_xy, size, yaw, clearance) -> bool:
        c, s = np.cos(yaw), np.sin(yaw)
        hx, hy = size[0] / 2, size[1] / 2
        pts = [(0, 0)] + [
            (sx * hx * f, sy * hy * f)
            for sx in (-1, 1)
            for sy in (-1, 1)
            for f in (0.5, 1.0)
        ]
        pts = np.array(
            [[centre_xy[0] + c * x - s * y, centre_xy[1] + s * x + c * y] for x, y in pts]
        )
        return bool(tree.query(pts)[0].min() >= clearance)

    def place(template, s_idx, side, offset, along, size, albedo, kind, z_lift=0.0):
        """Object at route sample ``s_idx``, ``offset`` m to the left (side=+1) / right (-1), ``along`` m ahead."""
        i0 = int(np.clip(s_idx, 1, len(p) - 2))
        tangent = p[i0 + 1, :2] - p[i0 - 1, :2]
        tangent /= np.linalg.norm(tangent) + 1e-12
        normal = np.array([-tangent[1], tangent[0]])
        yaw = np.arctan2(tangent[1], tangent[0])
        xy = p[i0, :2] + side * offset * normal + along * tangent
        if kind == 3 and side not in parking_sides:
            return
        if not clear(
            xy, size, yaw, 0.75 * road_clearance if kind == 3 else road_clearance
        ):
            return
        # sink 0.3 m so sloped ground never shows a gap underneath
        z = ground_z(xy)[0] - 0.3 + z_lift
        b.add(
            template,
            np.r_[xy, z],
            np.asarray(size, dtype=np.float64) + [0.0, 0.0, 0.3],
            yaw,
            albedo,
            kind,
        )

    n = len(p)
    for side in (-1, 1):
        # buildings, walls and gaps
        s = 0.0
        while s < n:
            r = rng.random()
            if r < 0.7:
                length = rng.uniform(8, 30)
                depth = rng.uniform(8, 15)
                setback = rng.uniform(7, 14)
                place(
                    _BOX,
                    int(s + length / 2),
                    side,
                    setback + depth / 2,
                    0.0,
                    (length, depth, rng.uniform(6, 22)),
                    rng.uniform(0.2, 0.6),
                    1,
                )
                s += length + rng.uniform(0.5, 3)
            elif r < 0.85:
                length = rng.uniform(10, 30)
                place(
                    _BOX,
                    int(s + length / 2),
                    side,
                    rng.uniform(6.5, 9),
                    0.0,
                    (length, 0.3, rng.uniform(1.0, 2.5)),
                    rng.uniform(0.3, 0.5),
                    2,
                )
                s += length
            else:
                s += rng.uniform(4, 15)
        # street furniture: repetitive or random stretches of ~60 m
        s = 0.0
        while s < n:
            stretch = rng.uniform(40, 80)
            repetitive = rng.random() < 0.3
            x = s
            while x < min(s + stretch, n):
                if repetitive:
                    place(_PRISM, int(x), side, 5.5, 0.0, (0.15, 0.15, 6.0), 0.5, 4)
                    place(_PRISM, int(x + 5), side, 6.5, 0.0, (0.35, 0.35, 2.5), 0.3, 5)
                    place(
                        _CROWN,
                        int(x + 5),
                        side,
                        6.5,
                        0.0,
                        (3.5, 3.5, 3.5),
                        0.25,
                        6,
                        z_lift=2.3,
                    )
                    x += 10.0
                else:
                    u = rng.random()
                    if u < 0.5:
                        # vans and SUVs: the only vehicles taller than the sensor
                        van = rng.random() < 0.3
                        size = (
                            (rng.uniform(4.8, 5.6), 2.0, rng.uniform(2.0, 2.6))
                            if van
                            else (4.2, 1.8, 1.5)
                        )
                        place(
                            _BOX,
                            int(x),
                            side,
                            rng.uniform(3.6, 4.6),
                            0.0,
                            size,
                            rng.uniform(0.1, 0.8),
                            3,
                            z_lift=0.3,
                        )
                        x += rng.uniform(4.8, 8)
                    elif u < 0.65:
                        place(
                            _PRISM,
                            int(x),
                            side,
                            rng.uniform(5, 6),
                            0.0,
                            (0.15, 0.15, rng.uniform(4, 8)),
                            0.5,
                            4,
                        )
                        x += rng.uniform(10, 30)
                    elif u < 0.88:
                        h = rng.uniform(2, 4)
                        off = rng.uniform(6, 8)
                        place(_PRISM, int(x), side, off, 0.0, (0.35, 0.35, h), 0.3, 5)
                        place(
                            _CROWN,
                            int(x),
                            side,
                            off,
                            0.0,
                            (rng.uniform(2.5, 5),) * 2 + (rng.uniform(2.5, 5),),
                            0.25,
                            6,
                            z_lift=h - 0.2,
                        )
                        x += rng.uniform(6, 15)
                    else:
                        x += rng.uniform(5, 15)
            s += stretch
    return b.build()
