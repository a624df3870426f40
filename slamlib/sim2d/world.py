"""The 2D world: walls and pillars in a plane, a vehicle on a closed loop, wheel odometry and a scanning LIDAR.

Frames and units: metres, seconds, radians. The **world frame** is the vehicle's pose at the first frame
(x forward, y left, heading 0 along +x), as in 1D and 3D. The **body frame** has its origin at the vehicle,
x forward and y to the left; a pose ``(x, y, theta)`` maps body points ``q`` to world points
``p = R(theta) q + (x, y)`` with ``R(theta) = [[cos, -sin], [sin, cos]]``.

* **World** (:class:`World2D`): wall segments ``(S, 2, 2)`` (two end points each) and round pillars
  ``(C, 3)`` (centre x, y and radius). :func:`make_world` builds a courtyard: outer walls with a few alcoves, an
  inner block the route goes round, and seeded pillars and wall stubs between them.
* **Route**: a rounded rectangle (two straights of ``length`` and ``width`` metres, four quarter turns of radius
  ``turn_radius``), driven anticlockwise from the origin at speed ``v(t) = v_mean + v_amp sin(2 pi t / T)``.
  Frame ``k`` covers the arc length ``s_{k-1} -> s_k`` (``s(t)`` the exact integral of ``v``) and the heading
  change ``theta(s_k) - theta(s_{k-1})`` of the route; the **true controls** ``(v_k, w_k)`` are those divided by
  ``dt_k``, and the **true pose** is their exact SE(2) arc integration (:func:`integrate_arc`), so noise-free
  odometry integrated the same way reproduces the ground truth exactly.
* **Wheel odometry** (the IMU analogue): ``speed_k = v_k + b_v + sigma_v n``, ``yaw_rate_k = w_k + b_w +
  sigma_w n'`` (``n, n' ~ N(0, 1)``; ``b`` constant biases). Integrating it (dead reckoning) drifts: a heading
  error ``d theta`` grows as ``b_w t`` and turns every later metre travelled sideways.
* **LIDAR** (:func:`cast_rays`): ``n_beams`` beams evenly spread over 360 degrees in the body frame; each
  returns the range to the nearest wall or pillar plus ``N(0, sigma_r^2)`` noise, or nothing when that is beyond
  ``max_range`` or the beam drops out (probability ``dropout``). Points are ``(N, 2)`` float64 in the body frame.

Everything is pure numpy and seeded (``numpy.random.default_rng``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "Frame2D",
    "Recording2D",
    "Route2D",
    "SensorModel2D",
    "World2D",
    "cast_rays",
    "integrate_arc",
    "make_world",
    "scan_at",
    "simulate",
    "wrap_angle",
]


def wrap_angle(a):
    """Angles wrapped to ``[-pi, pi)``."""
    return (np.asarray(a, dtype=np.float64) + np.pi) % (2 * np.pi) - np.pi


def integrate_arc(pose, speed, yaw_rate, dt):
    """Exact SE(2) motion at constant speed ``v`` and yaw rate ``w`` for ``dt`` seconds, in the body frame.

    With ``d theta = w dt`` the vehicle drives along a circular arc (a straight line when ``w = 0``); the chord
    from start to end has length ``v dt sin(d theta / 2) / (d theta / 2)`` and points along the mean heading
    ``theta + d theta / 2``:

    .. math:: x' &= x + v\\,dt\\,\\mathrm{sinc}(\\tfrac{d\\theta}{2}) \\cos(\\theta + \\tfrac{d\\theta}{2}), \\\\
              y' &= y + v\\,dt\\,\\mathrm{sinc}(\\tfrac{d\\theta}{2}) \\sin(\\theta + \\tfrac{d\\theta}{2}), \\\\
              \\theta' &= \\theta + d\\theta

    (``sinc(u) = sin(u) / u``, 1 at 0: no division by ``w``, exact for straight driving too). ``pose`` is
    ``(..., 3)``; the heading is wrapped to ``[-pi, pi)``. Returns a new array.
    """
    pose = np.asarray(pose, dtype=np.float64)
    dth = float(yaw_rate) * float(dt)
    # np.sinc(x) = sin(pi x) / (pi x)
    chord = float(speed) * float(dt) * np.sinc(dth / (2 * np.pi))
    mid = pose[..., 2] + dth / 2
    out = np.empty(np.broadcast_shapes(pose.shape, (3,)))
    out[..., 0] = pose[..., 0] + chord * np.cos(mid)
    out[..., 1] = pose[..., 1] + chord * np.sin(mid)
    out[..., 2] = wrap_angle(pose[..., 2] + dth)
    return out


# -------------------------------------------------------------------------------------------- the world
@dataclass(frozen=True)
class World2D:
    """Structure in the plane (unknown to the filter).

    Attributes
    ----------
    segments : ndarray (S, 2, 2) float64, wall segments ``[[x0, y0], [x1, y1]]`` (m).
    circles : ndarray (C, 3) float64, pillars ``(cx, cy, radius)`` (m).
    """

    segments: np.ndarray
    circles: np.ndarray

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lo (2,), hi (2,))`` corners of the box holding all structure (m)."""
        pts = [self.segments.reshape(-1, 2)]
        if len(self.circles):
            c, r = self.circles[:, :2], self.circles[:, 2:]
            pts += [c - r, c + r]
        pts = np.concatenate(pts)
        return pts.min(axis=0), pts.max(axis=0)


@dataclass(frozen=True)
class Route2D:
    """A rounded-rectangle loop from the origin, heading +x, anticlockwise (m, rad).

    ``length`` and ``width`` are the straights, ``turn_radius`` the quarter turns' radius. The heading is a
    function of arc length ``s`` (:meth:`heading`), piecewise linear: constant on straights, rising at
    ``1 / turn_radius`` rad/m in turns; one lap adds ``2 pi``.
    """

    length: float = 20.0
    width: float = 10.0
    turn_radius: float = 2.5

    @property
    def perimeter(self) -> float:
        """Length of one lap (m)."""
        return 2 * (self.length + self.width) + 2 * np.pi * self.turn_radius

    def _knots(self):
        q = np.pi * self.turn_radius / 2
        pieces = [self.length, q, self.width, q, self.length, q, self.width, q]
        s = np.concatenate([[0.0], np.cumsum(pieces)])
        th = np.array([0, 0, 1, 1, 2, 2, 3, 3, 4], dtype=np.float64) * np.pi / 2
        return s, th

    def heading(self, s) -> np.ndarray:
        """Unwrapped heading ``theta(s)`` (rad) after ``s`` metres (any number of laps)."""
        s = np.asarray(s, dtype=np.float64)
        laps, rest = np.divmod(s, self.perimeter)
        knots, th = self._knots()
        return 2 * np.pi * laps + np.interp(rest, knots, th)


def make_world(
    seed: int = 0, route: Route2D | None = None, n_pillars: int = 14, n_stubs: int = 4
) -> World2D:
    """A courtyard round ``route``: outer walls with alcoves, an inner block, seeded pillars and wall stubs.

    The inner block sits 3 m inside the route's straights, the outer walls 3.5 m outside; pillars (radius
    0.2-0.45 m) and short wall stubs are placed at random (``seed``) at least 1.2 m from the route, so the vehicle
    never drives through them. The pillars and alcoves break the symmetry of the long parallel walls, along
    which a scan alone cannot tell how far the vehicle has come.
    """
    route = route or Route2D()
    rng = np.random.default_rng(seed)
    L, W, R = route.length, route.width, route.turn_radius
    # the route spans x in [-R, L + R], y in [0, W + 2R]
    x0, x1, y0, y1 = -R - 3.5, L + R + 3.5, -3.5, W + 2 * R + 3.5
    segs = []

    # outer walls with two alcoves (notches) on the long sides
    segs += [
        ((x0, y0), (6.0, y0)),
        ((6.0, y0), (6.0, y0 - 1.5)),
        ((6.0, y0 - 1.5), (9.0, y0 - 1.5)),
        ((9.0, y0 - 1.5), (9.0, y0)),
        ((9.0, y0), (x1, y0)),
        ((x1, y0), (x1, y1)),
        ((x1, y1), (13.0, y1)),
        ((13.0, y1), (13.0, y1 + 2.0)),
        ((13.0, y1 + 2.0), (11.0, y1 + 2.0)),
        ((11.0, y1 + 2.0), (11.0, y1)),
        ((11.0, y1), (x0, y1)),
        ((x0, y1), (x0, y0)),
    ]
    # the inner block, with a jog on one side
    bx0, bx1, by0, by1 = 3.0 - R, L - 3.0 + R, 3.0, W + 2 * R - 3.0
    segs += [
        ((bx0, by0), (bx1, by0)),
        ((bx1, by0), (bx1, by1)),
        ((bx1, by1), (bx0 + 4.0, by1)),
        ((bx0 + 4.0, by1), (bx0 + 4.0, by1 - 1.0)),
        ((bx0 + 4.0, by1 - 1.0), (bx0, by1 - 1.0)),
        ((bx0, by1 - 1.0), (bx0, by0)),
    ]
    # seeded pillars and stubs, clear of the route (sampled along the route and pushed to either side)
    s_grid = np.linspace(0, route.perimeter, 2000, endpoint=False)
    path = _route_points(route, s_grid)

    def clear(p, margin):
        return np.min(np.hypot(*(path - p).T)) > margin

    circles = []
    tries = 0
    while len(circles) < n_pillars and tries < 5000:
        tries += 1
        p = rng.uniform((x0 + 0.6, y0 + 0.6), (x1 - 0.6, y1 - 0.6))
        inside_block = bx0 - 0.5 < p[0] < bx1 + 0.5 and by0 - 0.5 < p[1] < by1 + 0.5
        r = rng.uniform(0.2, 0.45)
        if inside_block or not clear(p, 1.2 + r):
            continue
        if any(np.hypot(*(p - c[:2])) < 2.0 for c in circles):
            continue
        circles.append((p[0], p[1], r))
    tries = 0
    n_done = 0
    while n_done < n_stubs and tries < 5000:
        tries += 1
        p = rng.uniform((x0 + 1.0, y0 + 1.0), (x1 - 1.0, y1 - 1.0))
        ang = rng.choice([0.0, np.pi / 2]) + rng.uniform(-0.3, 0.3)
        q = p + rng.uniform(0.8, 1.6) * np.array([np.cos(ang), np.sin(ang)])
        mids = np.linspace(p, q, 6)
        if any(
            bx0 - 0.5 < m[0] < bx1 + 0.5 and by0 - 0.5 < m[1] < by1 + 0.5 for m in mids
        ):
            continue
        if not all(clear(m, 1.3) for m in mids):
            continue
        segs.append((tuple(p), tuple(q)))
        n_done += 1
    return World2D(
        segments=np.asarray(segs, dtype=np.float64).reshape(-1, 2, 2),
        circles=np.asarray(circles, dtype=np.float64).reshape(-1, 3),
    )


def _route_points(route: Route2D, s) -> np.ndarray:
    """(M, 2) positions along the route at arc lengths ``s`` (integrated finely; for placing structure)."""
    s = np.asarray(s, dtype=np.float64)
    fine = np.linspace(0, s.max() if s.size else 0, max(2, 8 * s.size))
    th = route.heading(fine)
    ds = np.diff(fine)
    mid = 0.5 * (th[1:] + th[:-1])
    xy = np.vstack(
        [
            [0.0, 0.0],
            np.cumsum(np.column_stack([ds * np.cos(mid), ds * np.sin(mid)]), axis=0),
        ]
    )
    return np.column_stack([np.interp(s, fine, xy[:, 0]), np.interp(s, fine, xy[:, 1])])


# -------------------------------------------------------------------------------------------- the LIDAR
def cast_rays(world: World2D, origin, angles, max_range: float) -> np.ndarray:
    """Range (m) from ``origin (2,)`` along world-frame directions ``angles (B,)`` to the nearest structure.

    Segments ``a + u e`` (``0 <= u <= 1``) against rays ``o + t d``: with the 2D cross product
    ``a x b = a_x b_y - a_y b_x``, ``t = ((a - o) x e) / (d x e)`` and ``u = ((a - o) x d) / (d x e)``. Circles
    ``|o + t d - c| = r``: ``t = -f.d - sqrt((f.d)^2 - |f|^2 + r^2)`` with ``f = o - c`` (the first crossing).
    Only ``t > 0`` counts. Returns ``(B,)`` float64; ``inf`` where nothing lies within ``max_range``.
    """
    o = np.asarray(origin, dtype=np.float64)
    angles = np.asarray(angles, dtype=np.float64)
    d = np.column_stack([np.cos(angles), np.sin(angles)])  # (B, 2)
    best = np.full(angles.shape, np.inf)
    if len(world.segments):
        a = world.segments[:, 0]
        e = world.segments[:, 1] - a  # (S, 2)
        ao = a - o
        denom = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]  # (B, S)
        t_num = ao[None, :, 0] * e[None, :, 1] - ao[None, :, 1] * e[None, :, 0]
        u_num = ao[None, :, 0] * d[:, None, 1] - ao[None, :, 1] * d[:, None, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = t_num / denom
            u = u_num / denom
        ok = (np.abs(denom) > 1e-12) & (t > 1e-9) & (u >= 0) & (u <= 1)
        best = np.minimum(best, np.where(ok, t, np.inf).min(axis=1))
    if len(world.circles):
        f = o - world.circles[:, :2]  # (C, 2)
        b = d @ f.T  # (B, C)
        disc = b**2 - (np.sum(f**2, axis=1) - world.circles[:, 2] ** 2)[None, :]
        with np.errstate(invalid="ignore"):
            t = -b - np.sqrt(disc)
        ok = (disc >= 0) & (t > 1e-9)
        best = np.minimum(best, np.where(ok, t, np.inf).min(axis=1))
    best[best > max_range] = np.inf
    return best


@dataclass(frozen=True)
class SensorModel2D:
    """Sensor and timing parameters (the filter may read them as a datasheet).

    Attributes
    ----------
    period, jitter : frame period (s) and relative jitter, ``dt = period (1 + U(-jitter, jitter))``.
    speed_noise, speed_bias : ``sigma_v``, ``b_v`` (m/s) of the wheel-speed reading.
    yaw_rate_noise, yaw_rate_bias : ``sigma_w``, ``b_w`` (rad/s) of the yaw-rate reading.
    n_beams : LIDAR beams over 360 degrees; max_range (m); range_noise ``sigma_r`` (m); dropout probability.
    """

    period: float = 0.1
    jitter: float = 0.1
    speed_noise: float = 0.1
    speed_bias: float = 0.05
    yaw_rate_noise: float = 0.02
    yaw_rate_bias: float = 0.01
    n_beams: int = 180
    max_range: float = 12.0
    range_noise: float = 0.02
    dropout: float = 0.05

    def __post_init__(self):
        if not self.period > 0 or not 0 <= self.jitter < 1:
            raise ValueError(
                f"need period > 0 and 0 <= jitter < 1, got {self.period}, {self.jitter}"
            )
        if min(self.speed_noise, self.yaw_rate_noise, self.range_noise) < 0:
            raise ValueError("noise levels must be non-negative")
        if self.n_beams < 1 or not self.max_range > 0 or not 0 <= self.dropout < 1:
            raise ValueError("need n_beams >= 1, max_range > 0 and 0 <= dropout < 1")

    @property
    def beam_angles(self) -> np.ndarray:
        """(B,) body-frame beam directions (rad), ``-pi + 2 pi j / B``."""
        return -np.pi + 2 * np.pi * np.arange(self.n_beams) / self.n_beams


def scan_at(
    world: World2D, pose, sensors: SensorModel2D, rng: np.random.Generator | None = None
) -> np.ndarray:
    """One LIDAR scan from ``pose (3,)``: ``(N, 2)`` body-frame points (noise and dropouts when ``rng`` is given)."""
    pose = np.asarray(pose, dtype=np.float64)
    beams = sensors.beam_angles
    r = cast_rays(world, pose[:2], pose[2] + beams, sensors.max_range)
    if rng is not None:
        r = r + sensors.range_noise * rng.standard_normal(r.size)
        r[rng.random(r.size) < sensors.dropout] = np.inf
    keep = np.isfinite(r) & (r > 0) & (r <= sensors.max_range)
    return np.column_stack([r[keep] * np.cos(beams[keep]), r[keep] * np.sin(beams[keep])])


# ------------------------------------------------------------------------------------------ the recording
@dataclass(frozen=True)
class Frame2D:
    """What the filter reads at frame ``k``: ``index``, ``time`` (s), ``dt`` (s, 0 first), ``speed`` (m/s) and
    ``yaw_rate`` (rad/s) over ``[t_{k-1}, t_k]`` (0 first), ``scan`` (N, 2) float64 body-frame points (m)."""

    index: int
    time: float
    dt: float
    speed: float
    yaw_rate: float
    scan: np.ndarray


@dataclass(frozen=True)
class Recording2D:
    """A simulated run: world, route, sensors, ground truth ``true_poses (K, 3)``, ``true_controls (K, 2)``
    (the noise-free speed and yaw rate of each frame) and the ``frames`` the filter reads."""

    world: World2D
    route: Route2D
    sensors: SensorModel2D
    times: np.ndarray
    true_poses: np.ndarray
    true_controls: np.ndarray
    frames: list = field(repr=False)

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def odometry(self) -> np.ndarray:
        """(K, 2) measured ``(speed, yaw_rate)``."""
        return np.array([(f.speed, f.yaw_rate) for f in self.frames])

    @property
    def dts(self) -> np.ndarray:
        """(K,) frame intervals (s)."""
        return np.array([f.dt for f in self.frames])


def simulate(
    world: World2D,
    route: Route2D | None = None,
    laps: float = 1.0,
    seed: int = 0,
    sensors: SensorModel2D | None = None,
    v_mean: float = 2.0,
    v_amp: float = 0.5,
    v_period: float = 9.0,
) -> Recording2D:
    """Drive ``laps`` laps of ``route`` through ``world`` and record odometry and LIDAR frames (seeded by ``seed``).

    The number of frames is that needed to cover ``laps * route.perimeter`` metres at ``v(t)``.
    """
    route = route or Route2D()
    sensors = sensors or SensorModel2D()
    if not laps > 0:
        raise ValueError(f"laps must be positive, got {laps}")
    rng = np.random.default_rng(seed)
    total = laps * route.perimeter
    w = 2 * np.pi / v_period

    def dist(t):
        return v_mean * t + v_amp / w * (1 - np.cos(w * t))

    n_max = (
        int(
            np.ceil(
                total / max(v_mean - v_amp, 0.1) / (sensors.period * (1 - sensors.jitter))
            )
        )
        + 2
    )
    dts = sensors.period * (1.0 + rng.uniform(-sensors.jitter, sensors.jitter, n_max))
    dts[0] = 0.0
    times = np.cumsum(dts)
    s = dist(times)
    k_frames = int(np.searchsorted(s, total, side="right"))
    times, dts, s = times[:k_frames], dts[:k_frames], s[:k_frames]
    th = route.heading(s)
    controls = np.zeros((k_frames, 2))
    controls[1:, 0] = np.diff(s) / dts[1:]
    controls[1:, 1] = np.diff(th) / dts[1:]
    poses = np.zeros((k_frames, 3))
    frames = []
    for k in range(k_frames):
        if k > 0:
            poses[k] = integrate_arc(poses[k - 1], controls[k, 0], controls[k, 1], dts[k])
            speed = (
                controls[k, 0]
                + sensors.speed_bias
                + sensors.speed_noise * rng.standard_normal()
            )
            yaw_rate = (
                controls[k, 1]
                + sensors.yaw_rate_bias
                + sensors.yaw_rate_noise * rng.standard_normal()
            )
        else:
            speed = yaw_rate = 0.0
        scan = scan_at(world, poses[k], sensors, rng)
        frames.append(
            Frame2D(
                index=k,
                time=float(times[k]),
                dt=float(dts[k]),
                speed=float(speed),
                yaw_rate=float(yaw_rate),
                scan=scan,
            )
        )
    return Recording2D(
        world=world,
        route=route,
        sensors=sensors,
        times=times,
        true_poses=poses,
        true_controls=controls,
        frames=frames,
    )
