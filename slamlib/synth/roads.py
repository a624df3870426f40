"""Fresh roads: routes drawn from a seed, with the features that break a filter tuned on three KITTI roads.

A road is a list of :class:`Leg` s (a straight, or an arc of constant curvature), driven by a car with a speed
profile and a body that leans. :func:`road_route` turns legs into a :class:`~slamlib.synth.routes.Route`,
:func:`random_road` draws legs from a seed and :func:`random_route` (``get_route("random:SEED")``) does both.

Geometry (horizontal)
    The curvature ``kappa(s)`` (1/m, left positive) along the horizontal arc length ``s`` is each leg's
    ``turn / length``, its steps eased over :data:`EASEMENT_M` (a moving average: a clothoid-like transition,
    the way roads are built); heading ``psi(s) = int kappa ds`` and ``(x, y) = int (cos psi, sin psi) ds``.
Height
    The ground is one smooth terrain ``z = h(x, y)`` (a sum of :data:`TERRAIN_WAVES` plane waves, wavelengths
    :data:`TERRAIN_WAVELENGTHS_M`), scaled so that the steepest grade along the road is ``max_grade``; a
    revisit meets the same ground. The road's pitch is ``-atan(dz/ds)`` (``R = Rz Ry Rx``: positive pitch is nose
    down).
Speed
    The classic two-pass profile of vehicle motion planning: each sample's limit is the leg's speed and
    ``sqrt(a_lat / |kappa|)`` (the lateral acceleration the driver accepts in that leg), 0 where a leg ends
    with a stop; a forward pass limits acceleration (``v_{i+1}^2 <= v_i^2 + 2 a ds``), a backward pass
    braking (``v_i^2 <= v_{i+1}^2 + 2 b ds``, ``b`` the braking leg's). Time is ``int ds / v``, each stop
    held for its dwell; the speed is then smoothed over :data:`JERK_SMOOTHING_S` (a driver's finite jerk).
Body
    The body leans on its springs against its own acceleration: nose down by :data:`PITCH_PER_ACCEL` rad per
    m/s^2 of braking, rolled out of a turn by :data:`ROLL_PER_ACCEL` per m/s^2 of lateral acceleration
    ``v^2 kappa``, and a banked leg tilts the road toward the inside of its curve. ``R = Rz(psi)
    Ry(pitch_road + pitch_body) Rx(roll_body - bank)``.

The route's world is level (gravity along ``-z``) with the start at the origin heading along ``x``; a start on a
slope stands tilted, as real drives do. :func:`road_statistics` gives curvature, grade, speed and accelerations
for comparing a road with KITTI's (book chapter 09).

References: Gillespie, "Fundamentals of Vehicle Dynamics", SAE 1992 (body roll and pitch gains, ch. 7 and 2);
Lipp & Boyd, "Minimum-time speed optimisation over a fixed path", Int. J. Control 2014 (the two-pass profile).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.synth.routes import RANDOM_PREFIX, Route

__all__ = [
    "Leg",
    "road_route",
    "random_road",
    "random_route",
    "road_statistics",
    "hard_road",
    "RANDOM_PREFIX",
    "ROAD_FEATURES",
]

#: Sample spacing along the road (m) of the geometry and the speed profile.
ROAD_STEP_M = 0.25
#: Length (m) over which a change of curvature is eased in.
EASEMENT_M = 4.0
#: Body pitch (rad) per m/s^2 of longitudinal acceleration (nose down braking): 0.5 deg per m/s^2, a saloon car.
PITCH_PER_ACCEL = np.deg2rad(0.5)
#: Body roll (rad) per m/s^2 of lateral acceleration (out of the turn): 1 deg per m/s^2.
ROLL_PER_ACCEL = np.deg2rad(1.0)
#: Time (s, a Gaussian's sigma) over which the speed and the body's lean are smoothed: finite jerk, damped springs.
JERK_SMOOTHING_S = 0.25
#: Acceleration from a stop or up to a faster leg (m/s^2).
DRIVE_ACCEL = 2.0
#: The terrain: this many plane waves of wavelengths in this range (m).
TERRAIN_WAVES = 6
TERRAIN_WAVELENGTHS_M = (250.0, 900.0)
#: Lane width (m): a road driven back runs this far beside itself.
LANE_M = 3.5
#: Key poses of the route per second (the spline's knots).
KEY_RATE_HZ = 10.0
#: The features a drawn road holds at least once each (:func:`random_road`).
ROAD_FEATURES = (
    "gentle turn",
    "sharp turn",
    "hairpin",
    "roundabout",
    "banked curve",
    "hard braking",
    "stop",
    "revisit, same direction",
    "revisit, opposite direction",
)


@dataclass(frozen=True)
class Leg:
    """One stretch of road: ``length`` m (horizontal), turning by ``turn`` rad over it (left positive; 0: a
    straight), driven at up to ``speed`` m/s and ``lateral_accel`` m/s^2 in the turn, ending in a stop of
    ``stop`` s (0: none) braked into at ``brake`` m/s^2; a turn's road banked by ``bank`` rad toward its
    inside. ``feature`` names it (:data:`ROAD_FEATURES`, or "" for a plain leg)."""

    length: float
    turn: float = 0.0
    speed: float = 14.0
    lateral_accel: float = 3.0
    stop: float = 0.0
    brake: float = 2.5
    bank: float = 0.0
    feature: str = ""

    def __post_init__(self):
        if not (
            self.length > 0
            and self.speed > 0
            and self.lateral_accel > 0
            and self.brake > 0
        ):
            raise ValueError(
                f"a leg needs length, speed, lateral_accel and brake > 0, got {self}"
            )
        if self.stop < 0 or not np.isfinite(self.turn):
            raise ValueError(f"a leg needs stop >= 0 and a finite turn, got {self}")


def _smooth(x: np.ndarray, sigma_samples: float) -> np.ndarray:
    """``x`` smoothed by a Gaussian of ``sigma_samples`` samples, the ends held (``scipy.ndimage``)."""
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(
        np.asarray(x, dtype=np.float64), sigma_samples, mode="nearest"
    )


def _terrain(rng: np.random.Generator):
    """A smooth height field ``h(x, y)`` (unscaled): :data:`TERRAIN_WAVES` plane waves of random direction,
    wavelength and phase, amplitude proportional to wavelength (every wave as steep)."""
    lam = rng.uniform(*TERRAIN_WAVELENGTHS_M, TERRAIN_WAVES)
    ang = rng.uniform(0, 2 * np.pi, TERRAIN_WAVES)
    k = 2 * np.pi / lam[:, None] * np.c_[np.cos(ang), np.sin(ang)]
    amp, phase = lam / (2 * np.pi), rng.uniform(0, 2 * np.pi, TERRAIN_WAVES)

    def height(x, y):
        return np.sin(np.outer(x, k[:, 0]) + np.outer(y, k[:, 1]) + phase) @ amp

    return height


def road_route(
    legs,
    *,
    max_grade: float = 0.0,
    terrain_seed: int = 0,
    start_dwell: float = 1.0,
    start_speed: float = 0.0,
    name: str = "road",
) -> Route:
    """The :class:`~slamlib.synth.routes.Route` of driving ``legs`` from standstill (module docstring).

    ``max_grade``: the steepest grade (rise over run) along the road, of a terrain drawn from ``terrain_seed``
    (0: level). ``start_speed`` (m/s): the speed at the start (0: from standstill, standing ``start_dwell``
    seconds first). The route starts at the origin heading along
    ``x``, level ground or not (its world is gravity's)."""
    legs = list(legs)
    if not legs:
        raise ValueError("a road needs at least one leg")
    ds = ROAD_STEP_M
    ends = np.cumsum([leg.length for leg in legs])
    s = np.arange(0.0, ends[-1] + ds / 2, ds)
    which = np.minimum(np.searchsorted(ends, s, side="left"), len(legs) - 1)
    field = lambda name: np.array([getattr(leg, name) for leg in legs])[which]  # noqa: E731
    kappa_leg = field("turn") / field("length")
    kappa = _smooth(kappa_leg, EASEMENT_M / ds / 2)
    psi = np.concatenate([[0.0], np.cumsum(0.5 * (kappa[1:] + kappa[:-1]) * ds)])
    x = np.concatenate(
        [[0.0], np.cumsum(0.5 * (np.cos(psi[1:]) + np.cos(psi[:-1])) * ds)]
    )
    y = np.concatenate(
        [[0.0], np.cumsum(0.5 * (np.sin(psi[1:]) + np.sin(psi[:-1])) * ds)]
    )
    z = np.zeros_like(s)
    if max_grade > 0:
        z = _terrain(np.random.default_rng(terrain_seed))(x, y)
        z = _smooth(z, 2.0 / ds)  # a road evens out the ground under it over a few metres
        steepest = np.max(np.abs(np.gradient(z, ds)))
        z = (z - z[0]) * (max_grade / steepest if steepest > 0 else 0.0)
    bank = _smooth(field("bank") * np.sign(kappa_leg), EASEMENT_M / ds / 2)

    # the speed profile: limits, then the forward (accelerate) and backward (brake) passes
    v = np.minimum(
        field("speed"), np.sqrt(field("lateral_accel") / np.maximum(np.abs(kappa), 1e-9))
    )
    stop_at = np.searchsorted(s, ends - ds / 2)  # the sample at each leg's end
    dwell = np.zeros_like(s)
    for leg, i in zip(legs, stop_at):
        if leg.stop > 0:
            v[i], dwell[i] = 0.0, leg.stop
    v[0] = min(v[0], start_speed)
    brake = field("brake")
    for i in range(len(s) - 1):
        v[i + 1] = min(v[i + 1], np.sqrt(v[i] ** 2 + 2 * DRIVE_ACCEL * ds))
    for i in range(len(s) - 2, -1, -1):
        v[i] = min(v[i], np.sqrt(v[i + 1] ** 2 + 2 * brake[i] * ds))
    dwell[0] += start_dwell if start_speed == 0 else 0.0
    dt = 2 * ds / np.maximum(v[1:] + v[:-1], 1e-9)
    t_arrive = np.concatenate([[0.0], np.cumsum(dt + dwell[:-1])])
    # s(t) on a fine clock: each sample reached at t_arrive, left after its dwell
    t_knots = np.ravel(np.c_[t_arrive, t_arrive + dwell])
    s_knots = np.repeat(s, 2)
    keep = np.r_[True, np.diff(t_knots) > 0]
    fine_dt = 0.01
    t_fine = np.arange(0.0, t_knots[-1], fine_dt)
    s_fine = np.interp(t_fine, t_knots[keep], s_knots[keep])
    speed = _smooth(np.gradient(s_fine, fine_dt), JERK_SMOOTHING_S / fine_dt)
    s_fine = np.minimum(
        np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * fine_dt)]),
        s[-1],
    )
    accel = np.gradient(speed, fine_dt)

    # key poses at KEY_RATE_HZ
    step = int(round(1.0 / (KEY_RATE_HZ * fine_dt)))
    tk, sk = t_fine[::step], s_fine[::step]
    vk, ak = speed[::step], accel[::step]
    at = lambda q: np.interp(sk, s, q)  # noqa: E731
    grade = np.gradient(z, ds)
    kap = at(kappa)
    lateral = vk**2 * kap
    pitch = -np.arctan(at(grade)) - PITCH_PER_ACCEL * ak
    roll = ROLL_PER_ACCEL * lateral - at(bank)
    R = rpy_to_matrix(np.c_[roll, pitch, at(psi)])
    poses = make_pose(R, np.c_[at(x), at(y), at(z)])
    return Route(tk, poses, name)


def _roundabout(rng, round_: float, feature: str = "roundabout") -> list[Leg]:
    """In, round and out (at 10 m/s) on roads that point at the ring's centre: bear right by ``beta`` on a curve
    of radius ``r`` into the ring of radius ``R``, round it left by ``round_`` rad and both bearings, bear right
    out. The road's centre line passes :data:`LANE_M` / 2 beside the ring's centre when ``cos beta = (r + LANE_M /
    2) / (r + R)``; so ``round_ = pi`` leaves on the same road, in the other lane."""
    r, ring, a = rng.uniform(10.0, 14.0), rng.uniform(12.0, 20.0), rng.uniform(2.5, 3.5)
    bear = np.arccos((r + LANE_M / 2) / (r + ring))
    turn = round_ + 2 * bear
    return [
        Leg(r * bear, -bear, 10.0, a, feature=feature),
        Leg(ring * turn, turn, 10.0, a, feature=feature),
        Leg(r * bear, -bear, 10.0, a, feature=feature),
    ]


def random_road(seed: int, length: float = 1000.0) -> list[Leg]:
    """Legs of a road of at least ``length`` m drawn from ``seed``, holding every feature of
    :data:`ROAD_FEATURES` at least once, in a drawn order, between straights and gentle turns.

    Two features drive part of the road again: "revisit, same direction" is a block driven round (four left
    turns with equal straights) and its first straight driven once more; "revisit, opposite direction" turns
    back at a roundabout and drives the straight before it back."""
    rng = np.random.default_rng(seed)
    deg = np.deg2rad

    def straight(lo=40.0, hi=150.0, **kw):
        return Leg(rng.uniform(lo, hi), 0.0, rng.uniform(8.0, 25.0), **kw)

    def gentle():
        return _arc(
            rng.uniform(80, 250),
            deg(rng.uniform(20, 90)),
            rng.uniform(10, 22),
            2.5,
            "gentle turn",
        )

    def _arc(radius, turn, speed, lateral_accel, feature, **kw):
        side = rng.choice([-1.0, 1.0])
        return Leg(
            radius * turn, side * turn, speed, lateral_accel, feature=feature, **kw
        )

    features = {
        "gentle turn": lambda: [gentle()],
        "sharp turn": lambda: [
            _arc(
                rng.uniform(10, 20),
                deg(rng.uniform(60, 100)),
                14.0,
                rng.uniform(4.0, 5.5),
                "sharp turn",
            )
        ],
        "hairpin": lambda: [
            _arc(rng.uniform(8, 12), np.pi, 12.0, rng.uniform(5.0, 6.5), "hairpin")
        ],
        "roundabout": lambda: _roundabout(
            rng, np.deg2rad(rng.choice([90.0, 180.0, 270.0]))
        ),
        "banked curve": lambda: [
            _arc(
                rng.uniform(60, 120),
                deg(70),
                22.0,
                3.5,
                "banked curve",
                bank=deg(rng.uniform(3, 6)),
            )
        ],
        "hard braking": lambda: [
            Leg(
                rng.uniform(120, 200),
                0.0,
                rng.uniform(14, 20),
                stop=rng.uniform(2, 5),
                brake=rng.uniform(6.0, 7.5),
                feature="hard braking",
            )
        ],
        "stop": lambda: [
            straight(stop=rng.uniform(2, 8), brake=rng.uniform(2, 3.5), feature="stop")
        ],
        "revisit, same direction": lambda: _block(rng),
        "revisit, opposite direction": lambda: _there_and_back(rng, straight()),
    }
    order = list(rng.permutation(ROAD_FEATURES))
    legs = [straight()]
    for name in order:
        legs += features[name]()
        if rng.uniform() < 0.5:
            legs.append(straight() if rng.uniform() < 0.7 else gentle())
    while sum(leg.length for leg in legs) < length:
        legs.append(straight() if rng.uniform() < 0.5 else gentle())
    return legs


def _block(rng) -> list[Leg]:
    """A block driven round: four equal straights, four left turns, then the first straight again."""
    side, r, v = rng.uniform(40, 80), rng.uniform(10, 15), rng.uniform(10, 14)
    corner = Leg(r * np.pi / 2, np.pi / 2, v, 3.0, feature="revisit, same direction")
    leg = Leg(side, 0.0, v, feature="revisit, same direction")
    return [leg, corner] * 4 + [leg]


def _there_and_back(rng, there: Leg) -> list[Leg]:
    """A straight, a roundabout left the way the car came (round by 180 degrees), the straight driven back."""
    feature = "revisit, opposite direction"
    back = Leg(there.length, 0.0, there.speed, feature=feature)
    return [there, *_roundabout(rng, np.pi, feature), back]


def hard_road() -> Route:
    """A short road (about 180 m, 34 s) with every motion an accelerometer reads as tilt: moving off at 7.5 m/s and
    braking to 2 m/s within the first three seconds on level ground, hard braking (6.5 m/s^2) to a stop, a hairpin
    whose body roll passes 6 degrees, grades of 12 %. The filter's tests and book chapter 09 drive it."""
    legs = [
        Leg(14.0, speed=7.5),
        Leg(20.0, speed=2.0, brake=2.0),
        Leg(40.0, speed=12.0, stop=1.0, brake=6.5),
        Leg(20.0, speed=10.0),
        Leg(9.0 * np.pi, np.pi, 12.0, 6.0),
        Leg(60.0, speed=10.0),
    ]
    return road_route(legs, max_grade=0.12, terrain_seed=2, start_speed=7.5, name="hard")


def random_route(seed: int, length: float = 1000.0) -> Route:
    """The road of :func:`random_road` (``seed``, ``length``) on a terrain of the same seed, its steepest grade
    drawn in [8 %, 12 %]: ``get_route("random:SEED")``."""
    grade = np.random.default_rng([seed, 1]).uniform(0.08, 0.12)
    return road_route(
        random_road(seed, length),
        max_grade=grade,
        terrain_seed=seed,
        name=f"{RANDOM_PREFIX}{seed}",
    )


def road_statistics(
    route: Route, dt: float = 0.1, moving: float = 1.0
) -> dict[str, np.ndarray]:
    """What a road asks of a filter, sampled every ``dt`` s where the car moves faster than ``moving`` m/s:
    ``speed`` (m/s), ``curvature`` (1/m, horizontal, left positive: ``(v_x a_y - v_y a_x) / |v_xy|^3``),
    ``grade`` (``v_z / |v_xy|``), ``longitudinal`` and ``lateral`` acceleration (m/s^2, along and across the
    velocity), and ``roll``, ``pitch`` (rad) of the body, each ``(N,)``."""
    from slamlib.geometry import matrix_to_rpy

    t = np.arange(route.t0, route.t1, dt)
    vel, acc = route.velocity_world(t), route.accel_world(t)
    vxy = np.linalg.norm(vel[:, :2], axis=1)
    go = vxy > moving
    vel, acc, vxy = vel[go], acc[go], vxy[go]
    speed = np.linalg.norm(vel, axis=1)
    rpy = matrix_to_rpy(route.rotation(t[go]))
    return {
        "speed": speed,
        "curvature": (vel[:, 0] * acc[:, 1] - vel[:, 1] * acc[:, 0]) / vxy**3,
        "grade": vel[:, 2] / vxy,
        "longitudinal": np.einsum("ij,ij->i", acc, vel) / speed,
        "lateral": (vel[:, 0] * acc[:, 1] - vel[:, 1] * acc[:, 0]) / vxy,
        "roll": rpy[:, 0],
        "pitch": rpy[:, 1],
    }
