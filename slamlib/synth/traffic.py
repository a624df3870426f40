"""Moving traffic for the synthetic town: cars, cyclists and pedestrians as boxes moving along the route.

Frames and units: world frame of the drive (IMU pose at the drive's first frame, z up), metres, seconds on the
route's clock (:class:`~slamlib.synth.routes.Route`). The ego car drives along the route itself.

Every mover follows the route's **centre line** parametrised by arc length ``s`` (m): the IMU positions of the
driven part sampled densely (:data:`CENTRE_LINE_HZ`), re-sampled every :data:`CENTRE_LINE_STEP` m and extended
straight on by :data:`EXTEND` m before the start and after the end (as the town is,
:func:`~slamlib.synth.scene.build_scene`). A mover at arc length ``s`` with lateral offset ``y`` (m, + to the left
of the route direction) stands at ``c(s) + y n(s)`` with ``c`` the centre line, ``n`` its left unit normal in the
ground plane; its box stands on the road (IMU height minus :data:`~slamlib.synth.scene.IMU_HEIGHT`) and is yawed
along the tangent (reversed for movers driving against the route). Its arc length moves as one of::

    s(t) = s_ego(t) +- smax(|s_ego(t +- gap) - s_ego(t)|, FOLLOW_MIN_DIST)   # follows the ego car by a time gap
    s(t) = s_0 + v (t - t_0)                                                # own constant speed v (signed)
    s(t) = s_ego(t) + dv (t - t_pass)                                       # overtakes the ego car at dv

with ``s_ego(t)`` the ego car's arc length (linear beyond the drive at the end speeds), ``t_0`` the drive's start
and ``smax(a, m) = m + w log(1 + exp((a - m) / w))`` a smooth maximum (w = :data:`SMOOTH_MAX_WIDTH`), so every
trajectory is smooth.

Kinds (:data:`KINDS`) and their lanes: Germany drives on the right and the ego car keeps to its lane, the centre
line; the left lane (:data:`LEFT_LANE` m) carries the oncoming and the overtaking cars, the right edge
(:data:`CYCLE_LANE` m) the cyclists, the sidewalks (``+-`` :data:`SIDEWALK` m) the pedestrians. Densities are
movers per km of street (:class:`TrafficConfig`), laid on the whole extended centre line, so that a short drive
sees as busy a street as a long one. Movers of one lane never overlap one another: a candidate that would (checked
every :data:`CONFLICT_STEP` s) is drawn again, at most :data:`MAX_TRIES` times, then dropped (:data:`BUILD_ORDER`).
Following cars appear and vanish at the ends of their time slots, overtaking cars at the ends of
:data:`OVERTAKE_SPAN` (as if turning in from / off into a side street).

Static scene (:mod:`slamlib.synth.scene`): objects keep 3.2 m from the centre line, parked cars stand at 3.6-4.6 m
(inner edge 2.6-3.7 m), poles at 5-6 m, trees at 6-8 m, walls at 6.5-9 m, building facades at 7-14 m. The left
lane runs where the left parked cars would stand, so with traffic the town has parking on the right side only
(``TrafficConfig.clear_left_parking``). Known overlaps, not avoided: cyclists (edge at 2.9-3.5 m) pass through the
inner edge of right-hand parked cars parked closer than 4.4 m, and pedestrians walk through the poles, trunks and
walls that stand on the sidewalk (the scene has no kerb or sidewalk model). Offsets are taken along the centre
line's normal, so on the inside of a corner tighter than the offset (the KITTI routes' sharpest turns have radii of
about 4-6 m at the centre line) a pedestrian's path folds and it moves faster or briefly backwards there.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from slamlib.synth.scene import _BOX, IMU_HEIGHT

__all__ = [
    "TrafficConfig",
    "Traffic",
    "CentreLine",
    "build_traffic",
    "points_in_boxes",
    "KINDS",
    "KITTI_CITY",
    "LEFT_LANE",
    "CYCLE_LANE",
    "SIDEWALK",
    "FOLLOW_MIN_DIST",
    "CAR_SIZE",
    "CYCLIST_SIZE",
    "PEDESTRIAN_SIZE",
]

#: Mover kinds; ``Traffic.kind`` holds indices into this tuple.
KINDS = ("ahead", "behind", "oncoming", "overtaking", "cyclist", "pedestrian")
AHEAD, BEHIND, ONCOMING, OVERTAKING, CYCLIST, PEDESTRIAN = range(len(KINDS))

#: Lateral offsets of the lanes from the centre line (m, + left). The left lane is 3.5 m from the ego lane (a
#: German urban lane is 3.0-3.5 m wide); cyclists ride 3.2 m to the right, between the ego car's lane and the
#: parked cars; the sidewalks are 6.5 m out, pedestrians keep :data:`KEEP_RIGHT` m to their right of its middle
#: (so the two directions pass each other), jittered by up to :data:`SIDEWALK_JITTER` m.
LEFT_LANE = 3.5
CYCLE_LANE = -3.2
SIDEWALK = 6.5
KEEP_RIGHT = 0.4
SIDEWALK_JITTER = 0.1

#: Box sizes ``(length, width, height)`` m: a car (a van is :data:`VAN_HEIGHT` tall), a cyclist on a bike, a
#: pedestrian.
CAR_SIZE = (4.2, 1.8, 1.5)
VAN_HEIGHT = 2.2
VAN_FRACTION = 0.3
CYCLIST_SIZE = (1.8, 0.6, 1.7)
PEDESTRIAN_SIZE = (0.5, 0.5, 1.75)

#: Following cars: time gap range (s) and the closest centre-to-centre distance (m) to the ego car (IMU).
FOLLOW_GAP_S = (1.5, 4.0)
FOLLOW_MIN_DIST = 8.0
SMOOTH_MAX_WIDTH = 1.0
#: Fraction of its time slot a following car is present (it turns in / off a side street outside it).
FOLLOW_PRESENCE = (0.5, 1.0)
#: Speed ranges (m/s): oncoming cars, cyclists, pedestrians; overtaking cars' excess speed over the ego car.
ONCOMING_SPEED = (8.0, 14.0)
CYCLIST_SPEED = (4.0, 6.0)
PEDESTRIAN_SPEED = (1.0, 1.5)
OVERTAKE_EXCESS = (4.0, 8.0)
#: An overtaking car appears this far behind the ego car and leaves this far ahead (m): it comes from / turns
#: into a side street.
OVERTAKE_SPAN = (-20.0, 25.0)
#: Albedo ranges of the boxes (cars: paint from black to white).
CAR_ALBEDO = (0.1, 0.8)
PERSON_ALBEDO = (0.2, 0.45)

#: Centre line: route sampling rate (Hz), re-sampling step (m), shortest route time it covers (s) and straight
#: extension at both ends (m; LIDAR returns beyond ~100 m are rare).
CENTRE_LINE_HZ = 50.0
CENTRE_LINE_STEP = 0.5
MIN_LINE_S = 1.0
EXTEND = 120.0
#: Chord length (m) giving the centre line's tangent: long enough to smooth the ground truth's centimetre jitter,
#: short against the routes' corners.
TANGENT_BASE = 4.0
#: Boxes are sunk this far into the road (and made as much taller) so a sloped road shows no gap underneath.
SINK = 0.2
#: Overlap check of movers in one lane: time step (s), extra along-lane clearance (m), redraws per mover, and how
#: long (s) before and after the drive it is checked (a sweep starts half a period before its frame's time).
CONFLICT_STEP = 0.05
CONFLICT_MARGIN = 1.0
MAX_TRIES = 12
CONFLICT_PAD = 0.2
#: Time step (s) of the finite difference giving the movers' speeds (:meth:`Traffic.boxes`).
SPEED_DT = 1e-3
#: Kinds are laid out in this order, each avoiding the ones before: overtaking cars before the oncoming ones, whose
#: stream then leaves the left lane free while a car overtakes (an oncoming car every ~4 s would leave no gap the
#: other way round).
BUILD_ORDER = (AHEAD, BEHIND, OVERTAKING, ONCOMING, CYCLIST, PEDESTRIAN)


@dataclass(frozen=True)
class TrafficConfig:
    """How much traffic: movers per km of street of each kind, times ``density``.

    The defaults are an estimate of a KITTI city drive (Karlsruhe, daytime, the "City" category of the raw data),
    not a measurement on the real recordings: a car in front or behind most of the time, an oncoming car every
    ~100 m of its lane (met every ~50 m of the drive at equal speeds), a cyclist every ~300 m, a pedestrian every
    ~50 m of street (both sidewalks).

    ``ahead`` / ``behind``: following cars per km of street (each present in its own slot of the drive, so one at
    a time, for 50-100 % of it); ``oncoming``: cars per km of the left lane; ``overtaking``: cars per km overtaking
    the ego car (fewer where the oncoming lane is busy, :data:`BUILD_ORDER`); ``cyclists``, ``pedestrians``: per
    km of street. ``density`` multiplies them all (:meth:`scaled`). ``clear_left_parking``: no parked cars on the
    left side (where the oncoming lane runs) of the town.
    """

    ahead: float = 3.0
    behind: float = 3.0
    oncoming: float = 10.0
    overtaking: float = 2.0
    cyclists: float = 3.0
    pedestrians: float = 20.0
    density: float = 1.0
    clear_left_parking: bool = True

    def __post_init__(self):
        rates = (
            self.ahead,
            self.behind,
            self.oncoming,
            self.overtaking,
            self.cyclists,
            self.pedestrians,
            self.density,
        )
        if not all(np.isfinite(x) and x >= 0 for x in rates):
            raise ValueError(
                f"traffic rates and density must be finite and >= 0, got {rates}"
            )

    def scaled(self, k: float) -> TrafficConfig:
        """The same traffic ``k`` times as dense (``k = 2``: twice the default density)."""
        return replace(self, density=self.density * float(k))

    def per_km(self) -> np.ndarray:
        """Movers per km of each kind of :data:`KINDS`, ``density`` applied, shape (6,)."""
        return self.density * np.array(
            [
                self.ahead,
                self.behind,
                self.oncoming,
                self.overtaking,
                self.cyclists,
                self.pedestrians,
            ]
        )

    def as_dict(self) -> dict:
        return asdict(self)


#: The default traffic, a KITTI city drive.
KITTI_CITY = TrafficConfig()


class CentreLine:
    """The route's centre line by arc length, and the ego car's arc length in time.

    ``times (N,)`` route times (s) of the driven part, ``positions (N, 3)`` the IMU positions there (world, m).
    """

    def __init__(self, times: np.ndarray, positions: np.ndarray):
        times = np.asarray(times, dtype=np.float64)
        p = np.asarray(positions, dtype=np.float64)
        s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
        self.length = float(s[-1])
        self._t, self._s = times, s
        # end speeds (m/s) for extrapolating s_ego beyond the drive
        self._v0 = (s[1] - s[0]) / (times[1] - times[0])
        self._v1 = (s[-1] - s[-2]) / (times[-1] - times[-2])
        moving = np.r_[True, np.diff(s) > 1e-9]
        grid = np.arange(
            -EXTEND, self.length + EXTEND + CENTRE_LINE_STEP, CENTRE_LINE_STEP
        )
        inside = np.clip(grid, 0.0, self.length)
        pts = np.stack(
            [np.interp(inside, s[moving], p[moving, i]) for i in range(3)], axis=1
        )
        # the extensions go on along the chords of the first and last TANGENT_BASE m (not the last samples: the car
        # may stand still there, its ground truth jittering by millimetres in any direction)
        at = np.clip(
            [0.0, TANGENT_BASE, self.length - TANGENT_BASE, self.length], 0.0, self.length
        )
        ends = np.stack(
            [np.interp(at, s[moving], p[moving, i]) for i in range(2)], axis=1
        )
        u0, u1 = self._unit_xy(ends[1] - ends[0]), self._unit_xy(ends[3] - ends[2])
        pts[:, :2] += (
            np.minimum(grid, 0.0)[:, None] * u0
            + np.maximum(grid - self.length, 0.0)[:, None] * u1
        )
        # tangent = chord over TANGENT_BASE m: the ground truth wiggles by centimetres while the car stands still,
        # which turns a 0.5 m difference by up to ~150 deg and would throw the movers 6 m out sideways
        k = max(1, int(round(TANGENT_BASE / 2 / CENTRE_LINE_STEP)))
        ahead = pts[np.minimum(np.arange(len(pts)) + k, len(pts) - 1), :2]
        behind = pts[np.maximum(np.arange(len(pts)) - k, 0), :2]
        tangent = ahead - behind
        tangent /= np.linalg.norm(tangent, axis=1, keepdims=True) + 1e-12
        self._grid, self._pts, self._tan = grid, pts, tangent

    @staticmethod
    def _unit_xy(v: np.ndarray) -> np.ndarray:
        return v[:2] / (np.linalg.norm(v[:2]) + 1e-12)

    @property
    def s_range(self) -> tuple[float, float]:
        """Arc lengths covered by the extended centre line (m)."""
        return float(self._grid[0]), float(self._grid[-1])

    def ego_s(self, t) -> np.ndarray:
        """The ego car's arc length at route times ``t`` (m, same shape), linear beyond the drive."""
        t = np.asarray(t, dtype=np.float64)
        s = np.interp(t, self._t, self._s)
        s = np.where(t < self._t[0], (t - self._t[0]) * self._v0, s)
        return np.where(t > self._t[-1], self.length + (t - self._t[-1]) * self._v1, s)

    def frame(self, s) -> tuple[np.ndarray, np.ndarray]:
        """Road point under the centre line ``(..., 3)`` (IMU height removed) and the unit tangent ``(..., 2)``
        at arc lengths ``s`` (clamped to :attr:`s_range`)."""
        s = np.asarray(s, dtype=np.float64)
        pts = np.stack(
            [np.interp(s, self._grid, self._pts[:, i]) for i in range(3)], axis=-1
        )
        pts[..., 2] -= IMU_HEIGHT
        tan = np.stack(
            [np.interp(s, self._grid, self._tan[:, i]) for i in range(2)], axis=-1
        )
        return pts, tan / (np.linalg.norm(tan, axis=-1, keepdims=True) + 1e-12)


@dataclass
class Traffic:
    """The movers of one drive, ``N`` of them; every array has length ``N`` (``size`` is ``(N, 3)``).

    ``kind`` index into :data:`KINDS`; ``lateral`` offset (m, + left); ``heading`` +1 along the route, -1 against;
    ``size`` box length, width, height (m); ``albedo``; arc-length law (module docstring)
    ``s(t) = a s_ego(t) + b + c (t - t_ref) + f sign smax(|s_ego(t + sign gap) - s_ego(t)|, FOLLOW_MIN_DIST)``;
    present for ``t_on <= t <= t_off`` while ``s`` is on the extended centre line.
    """

    line: CentreLine
    kind: np.ndarray
    lateral: np.ndarray
    heading: np.ndarray
    size: np.ndarray
    albedo: np.ndarray
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    t_ref: np.ndarray
    f: np.ndarray
    sign: np.ndarray
    gap: np.ndarray
    t_on: np.ndarray
    t_off: np.ndarray

    def __len__(self) -> int:
        return len(self.kind)

    def arc_length(self, t: float) -> np.ndarray:
        """Every mover's arc length at route time ``t`` (m): shape (N,) for a scalar ``t``, (T, N) for ``t (T, 1)``."""
        se = self.line.ego_s(t)
        ahead = np.abs(self.line.ego_s(t + self.sign * self.gap) - se)
        z = (ahead - FOLLOW_MIN_DIST) / SMOOTH_MAX_WIDTH
        follow = FOLLOW_MIN_DIST + SMOOTH_MAX_WIDTH * np.logaddexp(0.0, z)
        return (
            self.a * se + self.b + self.c * (t - self.t_ref) + self.f * self.sign * follow
        )

    def present(self, t: float, s: np.ndarray | None = None) -> np.ndarray:
        """Which movers are in the town at time ``t``, bool (N,) (or (T, N) for ``t (T, 1)``)."""
        s = self.arc_length(t) if s is None else s
        lo, hi = self.line.s_range
        return (self.t_on <= t) & (t <= self.t_off) & (s >= lo) & (s <= hi)

    def boxes(self, t: float) -> dict:
        """The boxes of the movers present at route time ``t``: ``index (M,)`` into the movers, ``kind (M,)``,
        ``centre (M, 3)`` centre of the box's base on the road (world, m), ``yaw (M,)`` rad about z (the box's
        length along it), ``size (M, 3)``, ``albedo (M,)``, ``speed (M,)`` m/s along the heading."""
        s, present, centre, yaw = (
            x[0] for x in self._state(np.array([t], dtype=np.float64))
        )
        idx = np.flatnonzero(present)
        speed = np.abs(self.arc_length(t + SPEED_DT)[idx] - s[idx]) / SPEED_DT
        return {
            "index": idx,
            "kind": self.kind[idx],
            "centre": centre[idx],
            "yaw": yaw[idx],
            "size": self.size[idx],
            "albedo": self.albedo[idx],
            "speed": speed,
        }

    def inside(self, points, t: float, margin: float = 0.1) -> np.ndarray:
        """``(N,)`` bool: which of the world ``points (N, 3)`` lie in a mover's box at route time ``t``, grown by
        ``margin`` m on every side (a scan's range noise, and a swept scan's block timing)."""
        return points_in_boxes(points, self.boxes(t), margin).any(axis=0)

    def _state(
        self, times: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every mover at each of ``times (T,)``: arc length ``(T, N)``, present ``(T, N)`` bool, base centre
        ``(T, N, 3)`` and yaw ``(T, N)`` (module docstring)."""
        t = times[:, None]
        s = self.arc_length(t)
        present = self.present(t, s)
        road, tan = self.line.frame(s)
        centre = road
        # + lateral x the left normal (-tan_y, tan_x)
        centre[..., 0] -= self.lateral * tan[..., 1]
        centre[..., 1] += self.lateral * tan[..., 0]
        yaw = np.arctan2(self.heading * tan[..., 1], self.heading * tan[..., 0])
        return s, present, centre, yaw

    def mesh(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The movers at time ``t`` as one triangle soup: ``vertices (8M, 3)`` float32, ``triangles (12M, 3)``
        uint32, per-triangle ``albedo (12M,)`` float32 (boxes sunk :data:`SINK` m into the road)."""
        return self.meshes(np.array([t], dtype=np.float64))[0]

    def meshes(self, times) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """:meth:`mesh` at each of ``times (T,)`` (route times, s), computed together."""
        _, present, centre, yaw = self._state(np.asarray(times, dtype=np.float64))
        tv, tf = _BOX
        # (N, 8, 3) box in its own frame
        # (T, N, 1)
        v = tv[None] * (self.size + [0.0, 0.0, SINK])[:, None, :]
        c, s = np.cos(yaw)[..., None], np.sin(yaw)[..., None]
        world = np.stack(
            [
                c * v[..., 0] - s * v[..., 1],
                s * v[..., 0] + c * v[..., 1],
                np.broadcast_to(v[..., 2], c.shape[:2] + (len(tv),)),
            ],
            axis=-1,
        )
        world += (centre - [0.0, 0.0, SINK])[:, :, None, :]
        out = []
        for k in range(len(present)):
            idx = np.flatnonzero(present[k])
            f = tf[None] + (len(tv) * np.arange(len(idx)))[:, None, None]
            out.append(
                (
                    world[k, idx].reshape(-1, 3).astype(np.float32),
                    f.reshape(-1, 3).astype(np.uint32),
                    np.repeat(self.albedo[idx], len(tf)).astype(np.float32),
                )
            )
        return out


def points_in_boxes(
    points, boxes: dict, margin: float = 0.1, lift: float | None = None
) -> np.ndarray:
    """``(M, N)`` bool: which of the world ``points (N, 3)`` lie in each of the ``M`` boxes of :meth:`Traffic.boxes`,
    grown by ``margin`` m on every side; ``lift`` (m above the box's base, default ``-margin``) raises the floor, to
    leave out the road under a box sunk into it (:data:`SINK`)."""
    p = np.asarray(points, dtype=np.float64)
    floor = -margin if lift is None else lift
    out = np.zeros((len(boxes["centre"]), len(p)), dtype=bool)
    for i, (c, yaw, size) in enumerate(zip(boxes["centre"], boxes["yaw"], boxes["size"])):
        d = p - c
        along = np.cos(yaw) * d[:, 0] + np.sin(yaw) * d[:, 1]
        across = -np.sin(yaw) * d[:, 0] + np.cos(yaw) * d[:, 1]
        out[i] = (
            (np.abs(along) <= size[0] / 2 + margin)
            & (np.abs(across) <= size[1] / 2 + margin)
            & (d[:, 2] >= floor)
            & (d[:, 2] <= size[2] + margin)
        )
    return out


def _count(rate_per_km: float, length_m: float) -> int:
    """Number of movers of a kind: the expected count rounded (deterministic, so counts scale with density)."""
    return int(round(rate_per_km * length_m / 1000.0))


#: Mean speed (m/s) of the kinds that keep their own speed: their street stretch is longer by speed x duration.
_MEAN_SPEED = {
    ONCOMING: np.mean(ONCOMING_SPEED),
    CYCLIST: np.mean(CYCLIST_SPEED),
    PEDESTRIAN: np.mean(PEDESTRIAN_SPEED),
}


def _counts(config: TrafficConfig, line: CentreLine, duration: float) -> list[int]:
    """Movers of each kind of :data:`KINDS` for a drive of ``duration`` s: the rate per km times the street they are
    laid on, the extended centre line (plus speed x duration for the kinds that keep their own speed)."""
    lo, hi = line.s_range
    stretch = [
        hi - lo + _MEAN_SPEED.get(kind, 0.0) * duration for kind in range(len(KINDS))
    ]
    return [_count(r, length) for r, length in zip(config.per_km(), stretch)]


def _car_size(rng: np.random.Generator) -> tuple[np.ndarray, float]:
    size = np.array(CAR_SIZE, dtype=np.float64)
    if rng.random() < VAN_FRACTION:
        size[2] = VAN_HEIGHT
    return size, rng.uniform(*CAR_ALBEDO)


def _person(rng: np.random.Generator, size) -> tuple[np.ndarray, float]:
    return np.array(size, dtype=np.float64), rng.uniform(*PERSON_ALBEDO)


def _draw(
    kind: int,
    rng: np.random.Generator,
    line: CentreLine,
    t0: float,
    t1: float,
    slot=None,
    oncoming_speed: float = ONCOMING_SPEED[0],
) -> dict:
    """One mover of ``kind`` (a dict of the :class:`Traffic` fields) for a drive over route times ``[t0, t1]``;
    ``slot (t_a, t_b)`` for following cars; ``oncoming_speed`` (m/s) the oncoming lane's.

    A mover keeping its own speed ``c`` (signed) starts at ``s(t0)`` uniform in ``[lo - max(c, 0) T, hi - min(c, 0)
    T]`` (``lo, hi`` the extended centre line, ``T = t1 - t0``): the street holds the same density all along the
    drive. An overtaking car passes the ego car at a time uniform over the times its span overlaps the drive.
    """
    m = dict(
        kind=kind,
        heading=1.0,
        a=0.0,
        b=0.0,
        c=0.0,
        t_ref=t0,
        f=0.0,
        sign=1.0,
        gap=0.0,
        t_on=-np.inf,
        t_off=np.inf,
    )
    if kind in (AHEAD, BEHIND):
        size, alb = _car_size(rng)
        frac = rng.uniform(*FOLLOW_PRESENCE)
        start = rng.uniform(slot[0], slot[1] - frac * (slot[1] - slot[0]))
        m.update(
            lateral=0.0,
            a=1.0,
            f=1.0,
            sign=1.0 if kind == AHEAD else -1.0,
            gap=rng.uniform(*FOLLOW_GAP_S),
            t_on=start,
            t_off=start + frac * (slot[1] - slot[0]),
        )
    elif kind == OVERTAKING:
        size, alb = _car_size(rng)
        dv = rng.uniform(*OVERTAKE_EXCESS)
        t_pass = rng.uniform(t0 - OVERTAKE_SPAN[1] / dv, t1 - OVERTAKE_SPAN[0] / dv)
        m.update(
            lateral=LEFT_LANE,
            a=1.0,
            c=dv,
            t_ref=t_pass,
            t_on=t_pass + OVERTAKE_SPAN[0] / dv,
            t_off=t_pass + OVERTAKE_SPAN[1] / dv,
        )
    else:
        if kind == ONCOMING:
            size, alb = _car_size(rng)
            lateral, heading, v = LEFT_LANE, -1.0, oncoming_speed
        elif kind == CYCLIST:
            size, alb = _person(rng, CYCLIST_SIZE)
            lateral, heading, v = CYCLE_LANE, 1.0, rng.uniform(*CYCLIST_SPEED)
        else:
            size, alb = _person(rng, PEDESTRIAN_SIZE)
            side, heading = rng.choice([-1.0, 1.0]), rng.choice([-1.0, 1.0])
            # the right of a walker heading along the route is -y (the normal's opposite), against it +y
            lateral = (
                side * SIDEWALK
                - heading * KEEP_RIGHT
                + rng.uniform(-SIDEWALK_JITTER, SIDEWALK_JITTER)
            )
            v = rng.uniform(*PEDESTRIAN_SPEED)
        c = heading * v
        lo, hi = line.s_range
        s0 = rng.uniform(lo - max(c, 0.0) * (t1 - t0), hi - min(c, 0.0) * (t1 - t0))
        m.update(lateral=lateral, heading=heading, b=s0, c=c, t_ref=t0)
    m.update(size=size, albedo=alb)
    return m


_FIELDS = (
    "kind",
    "lateral",
    "heading",
    "size",
    "albedo",
    "a",
    "b",
    "c",
    "t_ref",
    "f",
    "sign",
    "gap",
    "t_on",
    "t_off",
)


def _stack(line: CentreLine, movers: list[dict]) -> Traffic:
    fields = _FIELDS
    if not movers:
        empty = {k: np.zeros((0, 3) if k == "size" else 0) for k in fields}
        empty["kind"] = empty["kind"].astype(np.int64)
        return Traffic(line, **empty)
    arrays = {
        k: np.array([m[k] for m in movers], dtype=np.int64 if k == "kind" else np.float64)
        for k in fields
    }
    return Traffic(line, **arrays)


def _conflicts(candidate: Traffic, accepted: Traffic, times: np.ndarray) -> bool:
    """Whether the single mover ``candidate`` overlaps any ``accepted`` one sharing its lane during ``times (T,)``
    (a regular grid over the drive): lateral footprints overlap and the along-line distance is below half the summed
    lengths plus :data:`CONFLICT_MARGIN` while both are present.

    Two movers of constant speed are checked in closed form over the whole span of ``times`` (conservatively, as if
    always present); the others on the grid, within the presence windows."""
    if len(accepted) == 0:
        return False
    lane = (
        np.abs(accepted.lateral - candidate.lateral[0])
        < (accepted.size[:, 1] + candidate.size[0, 1]) / 2
    )
    if not lane.any():
        return False
    others = _subset(accepted, lane)
    reach = (others.size[:, 0] + candidate.size[0, 0]) / 2 + CONFLICT_MARGIN
    steady = _steady(others)
    if _steady(candidate)[0]:
        if np.any(
            _linear_gap(candidate, _subset(others, steady), times[0], times[-1])
            < reach[steady]
        ):
            return True
        others, reach = _subset(others, ~steady), reach[~steady]
        if len(others) == 0:
            return False
    if np.isfinite(candidate.t_on[0]) or len(others) == 1:
        t_on, t_off = (
            max(candidate.t_on[0], others.t_on.min()),
            min(candidate.t_off[0], others.t_off.max()),
        )
        t = times[(times >= t_on) & (times <= t_off)][:, None]
        s_c = candidate.arc_length(t)
        s_o = others.arc_length(t)
        both = candidate.present(t, s_c) & others.present(t, s_o)
        return bool(np.any(both & (np.abs(s_o - s_c) < reach)))
    # an always present candidate against movers present for a while: each over its own window
    return any(
        _conflicts(candidate, _subset(others, [i]), times) for i in range(len(others))
    )


def _steady(traffic: Traffic) -> np.ndarray:
    """Which movers keep their own constant speed (``s(t) = b + c (t - t_ref)``, always present), bool (N,)."""
    return (
        (traffic.a == 0)
        & (traffic.f == 0)
        & np.isinf(traffic.t_on)
        & np.isinf(traffic.t_off)
    )


def _linear_gap(one: Traffic, others: Traffic, t0: float, t1: float) -> np.ndarray:
    """Least along-line distance (m) over ``[t0, t1]`` between the steady mover ``one`` and each steady one of
    ``others``: ``min |A + B t|`` with ``A + B t`` their arc-length difference (zero if it changes sign)."""
    A = (others.b - others.c * others.t_ref) - (one.b[0] - one.c[0] * one.t_ref[0])
    B = others.c - one.c[0]
    d0, d1 = A + B * t0, A + B * t1
    return np.where(np.sign(d0) != np.sign(d1), 0.0, np.minimum(np.abs(d0), np.abs(d1)))


def _subset(traffic: Traffic, keep: np.ndarray) -> Traffic:
    """The movers ``keep`` (bool or index array) of ``traffic``."""
    fields = {k: getattr(traffic, k)[keep] for k in _FIELDS}
    return Traffic(traffic.line, **fields)


def build_traffic(
    route, t_start: float, t_end: float, config: TrafficConfig, rng: np.random.Generator
) -> Traffic:
    """The movers of a drive along ``route`` over route times ``[t_start, t_end]`` (s), deterministic from ``rng``.

    Counts: ``round(per_km * S / 1000)`` of each kind (:meth:`TrafficConfig.per_km`, ``S`` the street they are laid
    on, :func:`_counts`); following cars each get an equal time slot of the drive, the others a place or a passing
    time drawn uniformly (:func:`_draw`); the oncoming cars share one speed per drive, drawn in
    :data:`ONCOMING_SPEED`.
    Movers that would overlap another of their lane are redrawn (at most :data:`MAX_TRIES` times) or dropped.
    """
    # the centre line spans at least MIN_LINE_S of the route, so a one-frame drive still has a direction and speed
    line_end = min(max(t_end, t_start + MIN_LINE_S), route.t1)
    line_start = max(min(t_start, line_end - MIN_LINE_S), route.t0)
    n_line = max(4, int((line_end - line_start) * CENTRE_LINE_HZ) + 2)
    times = np.linspace(line_start, line_end, n_line)
    line = CentreLine(times, route.position(times))
    # the drive and a sweep either side of it (a sweep reaches half a period before its first frame's time)
    check = np.arange(t_start - CONFLICT_PAD, t_end + CONFLICT_PAD, CONFLICT_STEP)
    counts = _counts(config, line, t_end - t_start)
    # the oncoming lane flows at one speed: cars of different speeds would catch up with one another in it
    oncoming_speed = rng.uniform(*ONCOMING_SPEED)
    accepted: list[dict] = []
    for kind in BUILD_ORDER:
        n = counts[kind]
        edges = np.linspace(t_start, t_end, n + 1)
        for i in range(n):
            slot = (edges[i], edges[i + 1])
            for _ in range(MAX_TRIES):
                m = _draw(kind, rng, line, t_start, t_end, slot, oncoming_speed)
                if not _conflicts(_stack(line, [m]), _stack(line, accepted), check):
                    accepted.append(m)
                    break
    return _stack(line, accepted)
