"""Scan matching (:mod:`slamlib.slam3d.match`): its cost is the filter's map score, its gradient that cost's,
it finds a known pose and never makes the pose worse, a plane fixes what a plane can, and the pipeline matches
LIDAR-only by default."""

from __future__ import annotations

import numpy as np
import pytest

from slamlib.geometry import make_pose, rpy_to_matrix, so3_exp
from slamlib.maps import MortonBVHMap, VoxelHashMap
from slamlib.slam3d import SLAM3DConfig, run_drive, steps
from slamlib.slam3d.match import (
    gradient_jacobian,
    match_scan,
    normal_equations,
    tilt_equations,
)


def _room(rng, n=20000):
    """Points on a floor, four walls and two boxes (every pose coordinate constrained), metres, body frame."""
    u = rng.uniform(-1.0, 1.0, (n, 2))
    face = rng.integers(0, 7, n)
    p = np.zeros((n, 3))
    p[face == 0] = np.c_[
        12 * u[face == 0, 0], 9 * u[face == 0, 1], np.zeros((face == 0).sum())
    ]  # floor
    for k, (axis, c) in enumerate(
        ((0, 12.0), (0, -12.0), (1, 9.0), (1, -9.0)), start=1
    ):  # walls
        sel = face == k
        other = 1 - axis
        p[sel, axis] = c
        p[sel, other] = (12.0 if other == 0 else 9.0) * u[sel, 0]
        p[sel, 2] = 1.5 + 1.5 * u[sel, 1]
    for k, (cx, cy) in enumerate(
        ((4.0, 3.0), (-5.0, -2.0)), start=5
    ):  # a box's two faces each
        sel = face == k
        half = sel & (u[:, 0] > 0)
        p[half] = np.c_[np.full(half.sum(), cx), cy + u[half, 0], 1 + u[half, 1]]
        p[sel & ~half] = np.c_[
            cx + u[sel & ~half, 0],
            np.full((sel & ~half).sum(), cy),
            1 + u[sel & ~half, 1],
        ]
    return (p + rng.normal(0.0, 0.01, p.shape)).astype(np.float32)


def _map(points, kind=VoxelHashMap):
    m = kind(voxel_size=0.5, capacity=2**15) if kind is VoxelHashMap else kind(radius=0.5)
    m.merge(points)
    return m


def _error(T, truth):
    D = np.linalg.inv(truth) @ T
    angle = np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1))
    return np.linalg.norm(D[:3, 3]), angle


def test_cost_is_the_negated_map_score_of_that_pose():
    rng = np.random.default_rng(0)
    world = _room(rng)
    m = _map(world)
    scan = world[rng.choice(len(world), 3000, replace=False)]
    for _ in range(4):
        T = make_pose(rpy_to_matrix(rng.normal(0, 0.02, 3)), rng.normal(0, 0.2, 3))
        H, g, E = normal_equations(T, scan, m.lookup())
        particles = steps.Particles3D(T[None, :3, :3].copy(), T[None, :3, 3].copy())
        for backend in ("numpy", "cpu"):
            score = steps.score_particles(particles, scan, m, backend)[0]
            assert E == pytest.approx(-score, rel=1e-9, abs=1e-6), (backend, E, score)
        np.testing.assert_allclose(H, H.T)
        # J^T A J with A positive definite
        assert np.linalg.eigvalsh(H).min() >= -1e-9 * np.trace(H)


def _frozen_corners(T, scan, lookup):
    """Each point's 8 voxels at ``T`` (numpy, from the lookup's fields as documented on VoxelHashLookup): the
    rotated points ``r = R p`` (N, 3) and, per corner, (trilinear weight (N,), voxel found (N,), its slot (N,))."""
    from slamlib.maps.codes import axis_indices, pack_keys

    occupied = np.flatnonzero(lookup.keys >= 0)
    order = np.argsort(lookup.keys[occupied])
    stored, occupied = lookup.keys[occupied][order], occupied[order]
    r = scan.astype(np.float64) @ T[:3, :3].T
    g = (r + T[:3, 3]) * lookup.inv_voxel_size - 0.5
    base = np.floor(g)
    f = g - base
    corners = []
    for corner in np.ndindex(2, 2, 2):
        d = np.asarray(corner)
        u, ok = axis_indices(base + d, 1.0)
        keys = pack_keys(np.where(ok[:, None], u, 0))
        pos = np.minimum(np.searchsorted(stored, keys), stored.size - 1)
        hit = ok & (stored[pos] == keys)
        corners.append(
            (np.prod(np.where(d == 1, f, 1.0 - f), axis=1), hit, occupied[pos])
        )
    return r, corners


def _frozen_cost(T, scan, lookup, road=None):
    """E as a function of the step (omega, v) with each point's 8 voxels and trilinear weights frozen at ``T``:
    the function g and H are derived from. ``road`` points move only by the vertical part of the step's
    displacement."""
    r, corners = _frozen_corners(T, scan, lookup)
    vertical_only = np.zeros(len(scan), bool) if road is None else road

    def cost(step):
        q = r @ so3_exp(step[:3]).T + T[:3, 3] + step[3:]
        q0 = r + T[:3, 3]
        q[vertical_only, :2] = q0[vertical_only, :2]
        total = 0.0
        for w, hit, slot in corners:
            e = q - lookup.mean[slot].astype(np.float64)
            a = lookup.icov[slot].astype(np.float64)
            A = a[:, [0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(-1, 3, 3)
            m = np.where(hit, np.einsum("ni,nij,nj->n", e, A, e), lookup.m_max)
            total += np.sum(w * 0.5 * np.minimum(m, lookup.m_max))
        return total

    return cost


def _gauss_newton(T, scan, lookup, road):
    """``(H, g)`` summed corner by corner in numpy: ``sum w J^T A J`` and ``sum w J^T A d`` over the untruncated
    terms, ``J = [-[r]_x | I]`` with a road point's first two rows zero (the module docstring's definitions)."""
    r, corners = _frozen_corners(T, scan, lookup)
    n = len(scan)
    J = np.zeros((n, 3, 6))
    J[:, 0, 1], J[:, 0, 2], J[:, 1, 0] = r[:, 2], -r[:, 1], -r[:, 2]
    J[:, 1, 2], J[:, 2, 0], J[:, 2, 1] = r[:, 0], r[:, 1], -r[:, 0]
    J[:, :, 3:] = np.eye(3)
    J[road, :2] = 0.0
    H, g = np.zeros((6, 6)), np.zeros(6)
    for w, hit, slot in corners:
        e = r + T[:3, 3] - lookup.mean[slot].astype(np.float64)
        a = lookup.icov[slot].astype(np.float64)
        A = a[:, [0, 1, 2, 1, 3, 4, 2, 4, 5]].reshape(-1, 3, 3)
        m = np.einsum("ni,nij,nj->n", e, A, e)
        use = hit & (m < lookup.m_max)
        wu = np.where(use, w, 0.0)
        H += np.einsum("n,nki,nkl,nlj->ij", wu, J, A, J)
        g += np.einsum("n,nki,nkl,nl->i", wu, J, A, e)
    return H, g


def test_h_and_g_are_the_gauss_newton_sums_on_any_number_of_threads():
    """The kernel sums each point's corners before multiplying by J, in fixed chunks over threads: the same H and
    g as summing corner by corner (to rounding), and the very same numbers on one thread as on several."""
    import numba

    rng = np.random.default_rng(4)
    world = _room(rng)
    m = _map(world)
    scan = world[rng.choice(len(world), 4000, replace=False)]
    T = make_pose(rpy_to_matrix([0.01, -0.004, 0.02]), np.array([0.1, -0.05, 0.04]))
    road = rng.random(len(scan)) < 0.3
    H, g, E = normal_equations(T, scan, m.lookup(), road)
    H_ref, g_ref = _gauss_newton(T, scan, m.lookup(), road)
    np.testing.assert_allclose(H, H_ref, rtol=1e-10, atol=1e-10 * np.abs(H_ref).max())
    np.testing.assert_allclose(g, g_ref, rtol=1e-10, atol=1e-10 * np.abs(g_ref).max())
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = normal_equations(T, scan, m.lookup(), road)
    finally:
        numba.set_num_threads(threads)
    assert np.array_equal(one[0], H) and np.array_equal(one[1], g) and one[2] == E


def test_gradient_is_the_derivative_of_the_cost_with_the_voxels_held():
    """g is dE/d(omega, v) with each point's voxels and trilinear weights held (Gauss-Newton's model); central
    differences of that cost, written independently in numpy, agree."""
    rng = np.random.default_rng(1)
    world = _room(rng)
    m = _map(world)
    scan = world[:5000]
    T = make_pose(rpy_to_matrix([0.004, -0.003, 0.01]), np.array([0.06, -0.04, 0.03]))
    for road in (
        None,
        rng.random(len(scan)) < 0.5,
    ):  # road points: the vertical part of the motion only
        _, g, E = normal_equations(T, scan, m.lookup(), road)
        cost = _frozen_cost(T, scan, m.lookup(), road)
        assert cost(np.zeros(6)) == pytest.approx(E, rel=1e-9)
        h = 1e-6
        numeric = np.array([(cost(h * e) - cost(-h * e)) / (2 * h) for e in np.eye(6)])
        np.testing.assert_allclose(g, numeric, rtol=1e-4, atol=1e-6 * np.abs(g).max())


def test_newton_matrix_is_the_jacobian_of_the_gradient():
    """The Newton step's matrix ``H + K`` is ``dg/d(omega, v)``: central differences of g (each pass re-weighting
    the corners) agree to rounding, with and without road points, where H alone misses the weights' share by
    tens of percent (why Gauss-Newton with held weights converges only linearly)."""
    rng = np.random.default_rng(1)
    world = _room(rng)
    m = _map(world)
    scan = world[:5000]
    T = make_pose(rpy_to_matrix([0.004, -0.003, 0.01]), np.array([0.06, -0.04, 0.03]))
    h = 1e-6

    def g_at(step, road):
        moved = T.copy()
        moved[:3, :3] = so3_exp(step[:3]) @ T[:3, :3]
        moved[:3, 3] = T[:3, 3] + step[3:]
        return normal_equations(moved, scan, m.lookup(), road)[1]

    for road in (None, rng.random(len(scan)) < 0.5):
        N = gradient_jacobian(T, scan, m.lookup(), road)
        H = normal_equations(T, scan, m.lookup(), road)[0]
        numeric = np.array(
            [(g_at(h * e, road) - g_at(-h * e, road)) / (2 * h) for e in np.eye(6)]
        ).T
        scale = np.abs(numeric).max()
        np.testing.assert_allclose(N, numeric, rtol=0, atol=1e-9 * scale)
        assert np.abs(H - numeric).max() > 0.1 * scale


def test_newton_steps_take_fewer_passes_than_gauss_newton(monkeypatch):
    """From the same starts, the Newton step (K from the first pass) takes fewer passes over the points than
    Gauss-Newton with the weights held (K = 0), and ends within a millimetre of it."""
    import slamlib.slam3d.match as match

    rng = np.random.default_rng(2)
    world = _room(rng)
    m = _map(world)
    scan = world[rng.choice(len(world), 8000, replace=False)]
    inner = match._normal_equations_nb
    passes = []

    def counted(*a):
        passes.append(1)
        return inner(*a)

    def gauss_newton(*a):
        H, g, cost, K = counted(*a)
        return H, g, cost, np.zeros_like(K)

    # a particle filter's best pose: a centimetre and a tenth of a degree from the peak
    starts = [
        make_pose(rpy_to_matrix(rng.normal(0, 0.002, 3)), rng.normal(0, 0.02, 3))
        for _ in range(4)
    ]
    found, n = {}, {}
    for name, kernel in (("newton", counted), ("gauss_newton", gauss_newton)):
        monkeypatch.setattr(match, "_normal_equations_nb", kernel)
        passes.clear()
        found[name] = [match_scan(s, scan, m, 50, tolerance=1e-6) for s in starts]
        n[name] = len(passes)
    assert n["newton"] < 0.75 * n["gauss_newton"], n
    # both stop near the same peak (Gauss-Newton often earlier, at the first step that raises the cost)
    for a, b in zip(found["newton"], found["gauss_newton"]):
        assert max(_error(a, b)) < 1e-3


def test_recovers_a_known_pose_and_never_scores_worse():
    rng = np.random.default_rng(2)
    world = _room(rng)
    m = _map(world)
    truth = np.eye(4)
    scan = world[rng.choice(len(world), 8000, replace=False)]
    for k in range(5):
        start = make_pose(rpy_to_matrix(rng.normal(0, 0.01, 3)), rng.normal(0, 0.1, 3))
        found = match_scan(start, scan, m, iterations=20)
        dt, da = _error(found, truth)
        assert dt < 0.01 and da < 1e-3, (k, dt, da, _error(start, truth))
        E0 = normal_equations(start, scan, m.lookup())[2]
        E1 = normal_equations(found, scan, m.lookup())[2]
        assert E1 <= E0


def test_the_iteration_ends_at_the_first_step_shorter_than_the_tolerance(monkeypatch):
    """A step shorter than ``tolerance`` ends the match without being evaluated (no pass over the points for it);
    a looser tolerance takes fewer passes, and what it leaves is about the size of the tolerance."""
    import slamlib.slam3d.match as match

    rng = np.random.default_rng(2)
    world = _room(rng)
    m = _map(world)
    scan = world[rng.choice(len(world), 8000, replace=False)]
    start = make_pose(
        rpy_to_matrix([0.004, -0.003, 0.008]), np.array([0.05, -0.04, 0.02])
    )
    passes = []
    inner = match._normal_equations_nb
    monkeypatch.setattr(
        match, "_normal_equations_nb", lambda *a: passes.append(1) or inner(*a)
    )
    found = {}
    for tolerance in (1e3, 1e-2, 1e-7):
        passes.clear()
        found[tolerance] = match_scan(start, scan, m, 50, tolerance=tolerance)
        found[tolerance, "passes"] = len(passes)
    # the first step is longer than 1e-2 but shorter than 1e3: one pass, the start pose kept
    np.testing.assert_array_equal(found[1e3], start)
    assert found[1e3, "passes"] == 1
    assert 1 < found[1e-2, "passes"] < found[1e-7, "passes"]
    assert max(_error(found[1e-2], found[1e-7])) < 1e-2


def test_a_plane_alone_brings_back_height_roll_and_pitch():
    """A flat floor fixes the three coordinates it can (height, roll, pitch), and the damped solve stays defined
    where the others are (nearly) free."""
    rng = np.random.default_rng(3)
    floor = np.c_[rng.uniform(-15, 15, (20000, 2)), rng.normal(0, 0.01, 20000)].astype(
        np.float32
    )
    m = _map(floor)
    start = make_pose(rpy_to_matrix([0.01, -0.008, 0.02]), np.array([0.3, -0.2, 0.15]))
    found = match_scan(start, floor, m, iterations=20)
    assert np.all(np.isfinite(found))
    assert abs(found[2, 3]) < 0.01  # height
    # the body's z stands up again: roll, pitch
    assert np.abs(found[2, :3] - [0, 0, 1]).max() < 2e-3


def test_gravity_terms_gradient_is_the_derivative_of_its_cost():
    """Gravity's term ``0.5 w |R^T g_w - u|^2``: ``g`` is its derivative under ``R <- Exp(omega) R`` (central
    differences), ``H`` its Gauss-Newton matrix ``w J^T J`` with ``J`` that of the residual, and neither touches
    the translation."""
    R = rpy_to_matrix([0.02, -0.015, 0.7])
    world_up = np.array([0.003, -0.002, 1.0])
    world_up /= np.linalg.norm(world_up)
    up = np.array([0.01, 0.004, 1.0])
    up /= np.linalg.norm(up)
    w = 2.5e5
    H, g, E = tilt_equations(R, up, world_up, w)

    def residual(step):
        return (so3_exp(step) @ R).T @ world_up - up

    assert E == pytest.approx(0.5 * w * residual(np.zeros(3)) @ residual(np.zeros(3)))
    h = 1e-7
    J = np.array([(residual(h * e) - residual(-h * e)) / (2 * h) for e in np.eye(3)]).T

    def cost(step):
        return 0.5 * w * residual(step) @ residual(step)

    numeric = [(cost(h * e) - cost(-h * e)) / (2 * h) for e in np.eye(3)]
    np.testing.assert_allclose(g[:3], numeric, rtol=1e-5)
    np.testing.assert_allclose(H[:3, :3], w * J.T @ J, rtol=1e-6, atol=1e-9 * w)
    assert not g[3:].any() and not H[3:].any() and not H[:, 3:].any()
    assert np.all(np.linalg.eigvalsh(H[:3, :3]) > -1e-9 * w)  # a cost's matrix: PSD


def test_gravity_term_holds_the_tilt_a_tilted_map_pulls_away():
    """A room mapped with a roll error of 10 mrad (the map's tilt drift): the match on the map alone climbs to the
    map's roll; with gravity's term it ends between the map's roll and gravity's, nearer gravity the more the term
    weighs."""
    rng = np.random.default_rng(3)
    room = _room(rng).astype(np.float64)
    tilt = 0.01
    m = _map((room @ rpy_to_matrix([tilt, 0.0, 0.0]).T).astype(np.float32))
    scan = room.astype(np.float32)

    def roll(T):
        return float(np.arctan2(T[2, 1], T[2, 2]))

    alone = match_scan(np.eye(4), scan, m, iterations=20)
    assert roll(alone) == pytest.approx(tilt, abs=1.5e-3)
    up = np.array([0.0, 0.0, 1.0])  # gravity says the body is level
    rolls = [
        roll(match_scan(np.eye(4), scan, m, iterations=20, tilt=(up, up, w)))
        for w in (1e6, 1e7, 1e8, 1e10)
    ]
    assert roll(alone) > rolls[0] > rolls[1] > rolls[2] > rolls[3], rolls
    assert abs(rolls[3]) < 1e-4


def test_it_returns_the_maps_curvature_at_the_pose_it_started_from():
    """``return_hessian``: the same pose as without it, and the symmetric part of the Newton matrix ``H + K`` of
    the map score alone at the start pose (gravity's term left out); zeros where it matched nothing."""
    rng = np.random.default_rng(6)
    room = _room(rng)
    m = _map(room)
    T0 = make_pose(rpy_to_matrix([0.01, -0.005, 0.03]), np.array([0.2, -0.1, 0.05]))
    up = np.array([0.0, 0.0, 1.0])
    tilt = (up, up, 1e7)
    T, H = match_scan(T0, room, m, 10, tilt=tilt, return_hessian=True)
    np.testing.assert_array_equal(T, match_scan(T0, room, m, 10, tilt=tilt))
    newton = gradient_jacobian(T0, room, m.lookup())
    np.testing.assert_allclose(H, 0.5 * (newton + newton.T), rtol=1e-9)
    assert np.all(np.linalg.eigvalsh(H) > 0)
    T, H = match_scan(T0, room, VoxelHashMap(), 10, return_hessian=True)
    np.testing.assert_array_equal(T, T0)
    np.testing.assert_array_equal(H, np.zeros((6, 6)))


@pytest.mark.parametrize("gain", [0.5, 0.8])
def test_gravitys_weight_from_the_maps_curvature_moves_the_tilt_by_that_gain(gain):
    """A map tilted by 10 mrad in roll, gravity saying level: with gravity's weight ``w = h k / (1 - k)`` for the
    map's information ``h`` on the roll at its peak (from :func:`match_scan`'s ``return_hessian``, the other
    coordinates free: ``1 / (C^-1)_00``), the match from the map's peak ends a fraction ``k`` of the way to
    gravity's roll, as ``"adaptive"`` sets the weight (:func:`slamlib.slam3d.stages.prior.tilt_sigma_for_gain`)."""
    rng = np.random.default_rng(3)
    room = _room(rng).astype(np.float64)
    tilt = 0.01
    m = _map((room @ rpy_to_matrix([tilt, 0.0, 0.0]).T).astype(np.float32))
    scan = room.astype(np.float32)
    peak = match_scan(np.eye(4), scan, m, iterations=20)
    roll_map = float(np.arctan2(peak[2, 1], peak[2, 2]))
    _, C = match_scan(peak, scan, m, iterations=1, return_hessian=True)
    h = 1 / np.linalg.inv(C)[0, 0]
    up = np.array([0.0, 0.0, 1.0])
    tilt = (up, up, h * gain / (1 - gain))
    T = match_scan(peak, scan, m, iterations=50, tolerance=1e-9, tilt=tilt)
    roll = float(np.arctan2(T[2, 1], T[2, 2]))
    assert roll == pytest.approx((1 - gain) * roll_map, abs=0.05 * roll_map)


def _rings(rng, height=1.73, per_ring=3000):
    """Road returns of a spinning LIDAR at ``height`` m: circles around the sensor, one per laser (body frame)."""
    radii = height / np.tan(np.radians([6.0, 7.5, 9.0, 11.0, 13.5, 17.0, 22.0]))
    a = rng.uniform(0, 2 * np.pi, (len(radii), per_ring))
    r = radii[:, None] + rng.normal(0, 0.01, a.shape)
    return np.c_[
        (r * np.cos(a)).ravel(), (r * np.sin(a)).ravel(), np.full(a.size, -height)
    ]


def test_road_points_do_not_pull_a_moving_scan_back_onto_the_rings():
    """The ring artifact: the road's rings move with the sensor, so matched against the last scan's rings they
    pull toward no motion. Marked as road they hold only height and tilt, and the walls find the true motion."""
    from slamlib.slam3d.preprocess import road_mask

    rng = np.random.default_rng(6)
    walls = _room(rng, 6000).astype(np.float64)
    walls = walls[walls[:, 2] > 0.3]  # the room without its floor: the road is the rings
    step = np.array([0.3, 0.0, 0.0])  # the car moved 30 cm forward between the scans
    scan0 = np.r_[walls, _rings(rng)].astype(np.float32)
    scan1 = np.r_[walls - step, _rings(rng)].astype(np.float32)
    m = _map(scan0)
    truth = make_pose(np.eye(3), step)
    road = road_mask(scan1)
    assert road.sum() == len(scan1) - len(walls)  # the rings, and only they, are road
    found = {
        name: match_scan(truth, scan1, m, 20, mask)
        for name, mask in (("all", None), ("road", road))
    }
    assert abs(found["road"][0, 3] - step[0]) < 0.02, found["road"][:3, 3]
    assert found["all"][0, 3] < step[0] - 0.05, found["all"][
        :3, 3
    ]  # pulled back toward the rings
    assert abs(found["road"][2, 3]) < 0.01  # the road still holds the height


def test_the_stage_matches_the_thinned_scan_and_moves_the_particles_with_it(monkeypatch):
    """``ScanMatch(voxel=...)`` matches one point per cube of that edge (far fewer than the scan's), still finds
    the pose, and moves every particle by the same correction."""
    import slamlib.slam3d.stages.polish as polish
    from slamlib.slam3d.preprocess import voxel_downsample
    from slamlib.slam3d.stages import ScanMatch
    from slamlib.slam3d.steps import Particles3D

    rng = np.random.default_rng(7)
    world = _room(rng)
    m, truth = _map(world), np.eye(4)
    start = make_pose(
        rpy_to_matrix([0.004, -0.003, 0.008]), np.array([0.08, -0.05, 0.03])
    )
    seen = []
    monkeypatch.setattr(
        polish,
        "match_scan",
        lambda pose, pts, *a: seen.append(len(pts)) or match_scan(pose, pts, *a),
    )
    particles = Particles3D(
        np.stack([start[:3, :3]] * 3), start[:3, 3] + np.eye(3) * 0.01
    )
    found, moved = ScanMatch(20, voxel=1.0)(start, world, particles, m)
    assert seen == [len(voxel_downsample(world, 1.0))] and seen[0] < len(world) / 4
    dt, da = _error(found, truth)
    assert dt < 0.01 and da < 1e-3, (dt, da)
    C = found @ np.linalg.inv(start)
    np.testing.assert_allclose(moved.t, particles.t @ C[:3, :3].T + C[:3, 3], atol=1e-12)
    np.testing.assert_allclose(moved.R[0], C[:3, :3] @ start[:3, :3], atol=1e-12)


def test_leaves_the_pose_alone_where_it_cannot_match():
    rng = np.random.default_rng(4)
    world = _room(rng, 2000)
    T = make_pose(rpy_to_matrix([0.0, 0.0, 0.1]), np.array([0.2, 0.0, 0.0]))
    # no voxel Gaussians
    np.testing.assert_array_equal(match_scan(T, world, _map(world, MortonBVHMap), 5), T)
    np.testing.assert_array_equal(match_scan(T, world, VoxelHashMap(), 5), T)  # empty map
    # asked for none
    np.testing.assert_array_equal(match_scan(T, world, _map(world), 0), T)
    # no points
    np.testing.assert_array_equal(match_scan(T, world[:0], _map(world), 5), T)


def test_pipeline_matches_every_frame_by_default_in_both_modes_and_none_when_off(
    tmp_path,
):
    from slamlib.kitti import KittiOdometrySequence, KittiRawDrive
    from slamlib.synth import Hdl64, write_drive, write_sequence

    fast = Hdl64(columns=500, beam_stride=2)
    write_sequence(tmp_path, "07", 7, frames=(0, 6), seed=1, lidar=fast, progress=False)
    write_drive(tmp_path / "raw", "07", frames=(0, 6), seed=1, lidar=fast, progress=False)
    seq, raw = (
        KittiOdometrySequence(tmp_path, 7),
        KittiRawDrive(tmp_path / "raw", "2011_09_26", 1),
    )
    slam = run_drive(seq, SLAM3DConfig.of(particles=50), progress=False).slam
    assert slam.lidar_only and slam.n_matched == 5
    assert (
        run_drive(
            seq, SLAM3DConfig.of(particles=50, scan_match=False), progress=False
        ).slam.n_matched
        == 0
    )
    # with an IMU: on by default as well, off only when asked
    assert (
        run_drive(raw, SLAM3DConfig.of(particles=50), progress=False).slam.n_matched == 5
    )
    assert (
        run_drive(
            raw, SLAM3DConfig.of(particles=50, scan_match=False), progress=False
        ).slam.n_matched
        == 0
    )
    # with the tilt prior: on, the match's cost carrying the prior too (match_tilt, the default); off with
    # match_tilt off
    tilt = dict(particles=50, tilt_sigma="auto")
    off = SLAM3DConfig.of(**tilt, match_tilt=False)
    assert run_drive(raw, off, progress=False).slam.n_matched == 0
    held = run_drive(raw, SLAM3DConfig.of(**tilt), progress=False).slam
    assert held.n_matched == 5 and held.polish.prior is held.prior


@pytest.mark.parametrize(
    "bad",
    [
        dict(scan_match="yes"),
        dict(scan_match=1),
        dict(scan_match_iterations=0),
        dict(scan_match_iterations=1.5),
        dict(scan_match_iterations=10**6),
        dict(match_voxel=-0.5),
        dict(match_voxel=float("nan")),
        dict(match_tilt="yes"),
    ],
)
def test_config_rejects_bad_scan_match_settings(bad):
    with pytest.raises(ValueError, match="scan_match|match_voxel|match_tilt"):
        SLAM3DConfig.of(**bad)
