"""Tests of the fresh roads (slamlib.synth.roads): the drawn road holds every feature, the car's motion is
physical (speed, accelerations, lean), revisits meet the same ground, and `random:SEED` names a route everywhere a
route is named."""

import numpy as np
import pytest

from slamlib.geometry import matrix_to_rpy
from slamlib.synth import get_route, resolve_route
from slamlib.synth.roads import (
    PITCH_PER_ACCEL,
    ROAD_FEATURES,
    ROLL_PER_ACCEL,
    Leg,
    random_road,
    random_route,
    road_route,
    road_statistics,
)

SEEDS = (0, 1, 2)


@pytest.fixture(scope="module", params=SEEDS)
def drawn(request):
    return request.param, random_route(request.param)


def test_a_drawn_road_holds_every_feature_and_is_over_a_kilometre(drawn):
    seed, route = drawn
    assert {leg.feature for leg in random_road(seed)} >= set(ROAD_FEATURES)
    assert route.length() >= 1000.0
    assert route.name == f"random:{seed}"


def test_same_seed_same_road_other_seed_other_road():
    a, b, c = random_route(5), random_route(5), random_route(6)
    t = np.linspace(0, min(a.t1, c.t1), 50)
    assert np.array_equal(a.pose(t), b.pose(t))
    assert not np.allclose(a.position(t), c.position(t))


def test_the_motion_stays_within_a_cars(drawn):
    _, route = drawn
    s = road_statistics(route)
    assert s["speed"].max() <= 25.0 + 1e-6
    assert np.abs(s["grade"]).max() <= 0.12 + 1e-3
    assert (
        np.abs(s["grade"]).max() >= 0.08 - 1e-3
    )  # the steepest grade is drawn in [8 %, 12 %]
    assert s["longitudinal"].min() < -5.5  # hard braking
    assert np.abs(s["lateral"]).max() < 7.0
    assert np.abs(s["curvature"]).max() > 1 / 13.0  # a hairpin or a sharp turn
    # the body's lean: a few degrees, not more
    assert np.degrees(np.abs(s["roll"]).max()) < 10.0
    assert np.degrees(np.abs(s["pitch"]).max()) < 12.0


def test_the_car_stands_still_at_its_stops(drawn):
    seed, route = drawn
    t = np.arange(route.t0, route.t1, 0.1)
    speed = np.linalg.norm(route.velocity_world(t), axis=1)
    stops = [leg.stop for leg in random_road(seed) if leg.stop > 0]
    standing = speed < 0.05
    assert stops and standing.sum() * 0.1 >= 0.8 * sum(stops)
    # the start from standstill
    assert speed[0] < 0.05


def test_a_road_driven_again_in_either_direction_meets_itself_on_the_same_ground(drawn):
    _, route = drawn
    t = np.arange(route.t0, route.t1, 0.5)
    p, v = route.position(t), route.velocity_world(t)
    found = set()
    for i in range(len(t)):
        earlier = t < t[i] - 15.0
        if not earlier.any() or np.linalg.norm(v[i]) < 1.0:
            continue
        d = np.linalg.norm(p[earlier, :2] - p[i, :2], axis=1)
        j = np.argmin(d)
        if d[j] < 6.0:
            found.add("same" if v[earlier][j] @ v[i] > 0 else "opposite")
            assert (
                abs(p[earlier][j, 2] - p[i, 2]) < 0.8
            )  # the terrain is one height field
    assert found == {"same", "opposite"}


def test_the_body_leans_against_its_acceleration_and_follows_the_grade():
    # level ground: a straight driven up to speed then braked hard to a stop, then a left turn
    legs = [
        Leg(120.0, speed=15.0, stop=2.0, brake=6.5),
        Leg(40.0 * np.pi / 2, np.pi / 2, 14.0, 4.0),
    ]
    route = road_route(legs)
    t = np.arange(route.t0, route.t1, 0.05)
    rpy = matrix_to_rpy(route.rotation(t))
    acc, vel = route.accel_world(t), route.velocity_world(t)
    speed = np.linalg.norm(vel, axis=1)
    moving = speed > 1.0
    along = np.einsum("ij,ij->i", acc, vel)[moving] / speed[moving]
    across = (vel[:, 0] * acc[:, 1] - vel[:, 1] * acc[:, 0])[moving] / speed[moving]
    # nose down braking (positive pitch), rolled out of a left turn (positive roll), up to the gains' sums
    np.testing.assert_allclose(rpy[moving, 1], -PITCH_PER_ACCEL * along, atol=2e-3)
    np.testing.assert_allclose(rpy[moving, 0], ROLL_PER_ACCEL * across, atol=3e-3)
    assert along.min() < -6.0 and across.max() > 3.5
    # a climb: the pitch follows the grade (nose up, negative pitch)
    climb = road_route([Leg(300.0, speed=10.0)], max_grade=0.12, terrain_seed=4)
    s = road_statistics(climb)
    steady = np.abs(s["longitudinal"]) < 0.05
    np.testing.assert_allclose(
        s["pitch"][steady], -np.arctan(s["grade"][steady]), atol=2e-3
    )
    assert np.abs(s["grade"]).max() == pytest.approx(0.12, abs=5e-3)


def test_the_accelerometer_reads_gravity_and_the_cars_acceleration():
    route = road_route(
        [Leg(100.0, speed=12.0, stop=1.0, brake=6.0)], max_grade=0.1, terrain_seed=1
    )
    t = np.arange(1.0, route.t1 - 1.0, 0.5)
    f = route.specific_force_body(t)
    R = route.rotation(t)
    np.testing.assert_allclose(
        np.einsum("nij,nj->ni", R, f), route.accel_world(t) + [0.0, 0.0, 9.81], atol=1e-2
    )


def test_random_seed_names_a_route_everywhere():
    route = get_route("random:3")
    assert route.name == "random:3"
    r, n = resolve_route("random:3", 20)
    assert n == 20 and r.length() > 1000.0
    with pytest.raises(ValueError, match="random:SEED"):
        get_route("random:x")
    with pytest.raises(ValueError, match="random:SEED"):
        get_route("moon")


def test_a_leg_refuses_impossible_values():
    with pytest.raises(ValueError, match="length"):
        Leg(0.0)
    with pytest.raises(ValueError, match="stop"):
        Leg(10.0, stop=-1.0)
