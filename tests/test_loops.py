"""Loop closure in 3D (slamlib.loops): the pose graph keeps true closures and drops false ones, local maps cut
the trajectory, ICP verification recovers a known pose, and the whole back end closes a synthetic loop."""

import numpy as np
import pytest

from slamlib.geometry import invert_pose, make_pose, rot_z, transform_points
from slamlib.loops import (
    LocalMapper,
    LoopCloser,
    PoseGraph,
    close_loops,
    nearby_maps,
    odometry_sigmas,
    verify_closure,
    voxel_down_sample,
)
from slamlib.loops.pose_graph import chi2_gate


# ------------------------------------------------------------------------------------------- the pose graph
def _square(drift_yaw=0.0015, drift_x=0.12):
    """20 key poses 40 m apart round a square, and odometry that drifts by a yaw bias and a scale error."""
    truth, T = [], np.eye(4)
    for k in range(20):
        truth.append(T.copy())
        T = T @ make_pose(rot_z(np.pi / 2) if k % 5 == 4 else np.eye(3), [40.0, 0, 0])
    est = [np.eye(4)]
    for a, b in zip(truth[:-1], truth[1:]):
        est.append(
            est[-1] @ invert_pose(a) @ b @ make_pose(rot_z(drift_yaw), [drift_x, 0, 0])
        )
    graph = PoseGraph()
    for k, pose in enumerate(est):
        graph.add_node(k, pose)
    for k in range(1, 20):
        graph.add_odometry(k - 1, k, invert_pose(est[k - 1]) @ est[k])
    return graph, truth, est


def _end_error(poses, truth):
    return float(np.linalg.norm(poses[19][:3, 3] - truth[19][:3, 3]))


def test_a_true_closure_takes_the_drift_back():
    graph, truth, est = _square()
    before = _end_error(dict(enumerate(est)), truth)
    graph.add_closure(19, 0, invert_pose(truth[19]) @ truth[0])
    after = _end_error(graph.optimise(), truth)
    assert before > 3.0 and after < 0.1 * before
    assert graph.closure_kept.tolist() == [True]
    assert 0 < graph.closure_statistic[0] <= chi2_gate()


def test_a_false_closure_is_dropped_and_bends_nothing():
    graph, truth, est = _square()
    graph.add_closure(10, 0, make_pose(rot_z(1.0), [120.0, 50.0, 0.0]))
    poses = graph.optimise()
    assert graph.closure_kept.tolist() == [False]
    assert (
        graph.closure_statistic[0] > 100 * chi2_gate()
    )  # far beyond the gate, not near it
    assert all(np.allclose(poses[k], est[k], atol=1e-6) for k in range(20))


def test_a_false_closure_beside_a_true_one_changes_nothing():
    results = []
    for with_false in (False, True):
        graph, truth, _ = _square()
        if with_false:
            graph.add_closure(10, 0, make_pose(rot_z(1.0), [120.0, 50.0, 0.0]))
        graph.add_closure(19, 0, invert_pose(truth[19]) @ truth[0])
        results.append((graph.optimise(), graph.closure_kept.tolist()))
    assert results[1][1] == [False, True]
    assert all(
        np.allclose(results[0][0][k], results[1][0][k], atol=1e-6) for k in range(20)
    )


def test_graph_sigmas_and_gate():
    from scipy.stats import chi2

    for probability, dof in ((0.99, 6), (0.95, 6), (0.5, 2), (0.999, 12)):
        assert chi2_gate(probability, dof) == pytest.approx(
            chi2.ppf(probability, dof), rel=1e-9
        )
    with pytest.raises(ValueError, match="even dof"):
        chi2_gate(0.99, 3)
    short, long = (
        odometry_sigmas(make_pose(np.eye(3), [1, 0, 0])),
        odometry_sigmas(make_pose(np.eye(3), [100, 0, 0])),
    )
    assert np.all(long > short) and long[3] == pytest.approx(0.5)
    graph = PoseGraph()
    graph.add_node(0, np.eye(4))
    with pytest.raises(KeyError, match="node 1"):
        graph.add_odometry(0, 1, np.eye(4))
    with pytest.raises(ValueError, match="4x4"):
        graph.add_node(1, np.eye(3))


# ------------------------------------------------------------------------------------------ local maps, ICP
def test_voxel_down_sample_keeps_one_point_per_voxel():
    rng = np.random.default_rng(0)
    p = rng.uniform(0, 4, (5000, 3))
    q = voxel_down_sample(p, 1.0)
    keys = np.floor(q).astype(int)
    assert len(q) == 64 and len(np.unique(keys, axis=0)) == 64
    assert all((p == x).all(axis=1).any() for x in q)  # points kept, not averaged


def test_local_maps_cut_the_drive_by_distance_in_key_pose_frames():
    poses = [make_pose(rot_z(0.01 * k), [2.0 * k, 0, 0]) for k in range(60)]  # 118 m
    wall = np.column_stack([np.linspace(0, 130, 600), np.full(600, 5.0), np.zeros(600)])
    mapper = LocalMapper(splitting_distance=50.0, voxel=0.25)
    done = [
        mapper.add(k, T, transform_points(invert_pose(T), wall))
        for k, T in enumerate(poses)
    ]
    done.append(mapper.finish())
    maps = [m for m in done if m is not None]
    assert [m.frames[0] for m in maps] == [0, 25, 50]
    assert sum(len(m.frames) for m in maps) == 60
    for m in maps:  # the key frame's points put back in the world lie on the wall
        world = transform_points(m.key_pose, m.points)
        assert np.allclose(world[:, 1], 5.0, atol=1e-6)


def test_icp_verification_recovers_a_known_pose():
    rng = np.random.default_rng(1)
    boxes = [
        rng.uniform(-20, 20, 3) * [1, 1, 0] + rng.uniform(-2, 2, (400, 3)) * [1, 1, 3]
        for _ in range(12)
    ]
    query = np.concatenate(
        boxes + [np.column_stack([rng.uniform(-30, 30, (3000, 2)), np.zeros(3000)])]
    )
    true = make_pose(rot_z(0.3), [4.0, -2.0, 0.1])
    reference = transform_points(invert_pose(true), query)  # query <- reference is `true`
    guess = true @ make_pose(rot_z(0.02), [0.3, 0.2, 0.0])
    T, fitness, rmse = verify_closure(reference, query, guess)
    assert np.allclose(T, true, atol=1e-3) and fitness > 0.95 and rmse < 0.01


# --------------------------------------------------------------------------------- the back end, end to end
def _town(rng, length=160.0, width=80.0, n=120):
    """Box buildings beside a rectangular road and a flat ground: points (M, 3) in the world."""
    pts = []
    while len(pts) < n:
        c = rng.uniform([-30, -30], [length + 30, width + 30])
        near_x = min(abs(c[0]), abs(c[0] - length)) if -5 < c[1] < width + 5 else np.inf
        near_y = min(abs(c[1]), abs(c[1] - width)) if -5 < c[0] < length + 5 else np.inf
        if min(near_x, near_y) <= 9:
            continue
        sx, sy, h = rng.uniform(3, 10), rng.uniform(3, 10), rng.uniform(4, 15)
        u, z, side = (
            rng.uniform(-1, 1, (600, 2)),
            rng.uniform(0, h, 600),
            rng.integers(0, 4, 600),
        )
        x = np.where(side < 2, np.where(side == 0, -1, 1), u[:, 0]) * sx / 2
        y = np.where(side >= 2, np.where(side == 2, -1, 1), u[:, 1]) * sy / 2
        xy = np.column_stack([x, y]) @ rot_z(rng.uniform(0, np.pi))[:2, :2].T + c
        pts.append(np.column_stack([xy, z]))
    ground = rng.uniform([-40, -40], [length + 40, width + 40], (20000, 2))
    return np.concatenate(pts + [np.column_stack([ground, np.zeros(len(ground))])])


def _drive(laps, length=160.0, width=80.0, step=2.0):
    corners = np.array([[0, 0], [length, 0], [length, width], [0, width], [0, 0]], float)
    xy = np.concatenate(
        [
            a
            + (b - a)
            * np.arange(int(np.linalg.norm(b - a) / step))[:, None]
            / int(np.linalg.norm(b - a) / step)
            for a, b in zip(corners[:-1], corners[1:])
        ]
    )
    xy = np.concatenate([xy, xy])[: int(len(xy) * laps)]
    d = np.diff(np.concatenate([xy, xy[:1]]), axis=0)
    yaw = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    return np.array([make_pose(rot_z(t), [p[0], p[1], 0.0]) for p, t in zip(xy, yaw)])


@pytest.fixture(scope="module")
def town_drive():
    rng = np.random.default_rng(0)
    world = _town(rng)
    truth = _drive(1.25)
    scans = []
    for T in truth:
        local = transform_points(invert_pose(T), world)
        keep = (np.linalg.norm(local[:, :2], axis=1) < 35) & (
            rng.random(len(local)) < 0.5
        )
        scans.append(local[keep] + rng.normal(0, 0.02, (keep.sum(), 3)))
    drifted = [truth[0]]  # the filter's odometry: a yaw bias and a scale error
    for a, b in zip(truth[:-1], truth[1:]):
        drifted.append(
            drifted[-1] @ invert_pose(a) @ b @ make_pose(rot_z(2e-4), [0.004, 0, 0])
        )
    return truth, np.array(drifted), scans


def _rmse(poses, truth):
    return float(
        np.sqrt(np.mean(np.sum((poses[:, :3, 3] - truth[:, :3, 3]) ** 2, axis=1)))
    )


def test_the_back_end_closes_a_loop_with_closures_true_to_the_ground(town_drive):
    truth, drifted, scans = town_drive
    corrected, closer = close_loops(drifted, scans)
    assert len(corrected) == len(truth)
    assert closer.closures and all(c.kept for c in closer.closures)
    for c in closer.closures:  # each within 0.5 m and 1 degree of the true relative pose
        assert c.query_frame == closer.mapper.maps[c.query].frames[0]
        assert c.reference_frame == closer.mapper.maps[c.reference].frames[0]
        true = invert_pose(truth[c.query_frame]) @ truth[c.reference_frame]
        err = invert_pose(true) @ c.relative
        assert np.linalg.norm(err[:3, 3]) < 0.5
        assert (
            np.degrees(np.arccos(np.clip((np.trace(err[:3, :3]) - 1) / 2, -1, 1))) < 1.0
        )
        assert c.query - c.reference >= 3
    assert _rmse(corrected, truth) < 0.5 * _rmse(drifted, truth)


def test_re_anchored_frames_move_smoothly_from_one_local_map_to_the_next(town_drive):
    """Corrections blended between key poses: no frame-to-frame step of the corrected path differs from the
    truth's by more than a centimetre and a half (re-anchoring each local map rigidly on its key pose jumps by
    3 cm where one map hands over to the next on this drive)."""
    truth, drifted, scans = town_drive
    corrected, _ = close_loops(drifted, scans)

    def steps(poses):
        return np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)

    assert np.abs(steps(corrected) - steps(truth)).max() < 0.015


def test_no_closure_on_a_drive_without_revisits(town_drive):
    truth, drifted, scans = town_drive
    n = int(0.8 * len(truth) / 1.25)  # 0.8 of a lap: never back where it began
    corrected, closer = close_loops(drifted[:n], scans[:n])
    assert closer.closures == [] and len(closer.mapper.maps) >= 4
    assert np.allclose(corrected, drifted[:n])


def test_candidates_by_position_are_the_earlier_paths_within_the_drift_bound():
    """Maps 3 or more back whose path passes within radius + drift x distance driven, nearest first."""
    line = np.column_stack([np.arange(0, 50, 5.0), np.zeros(10), np.zeros(10)])
    paths = [line + [100.0 * j, 0, 0] for j in range(5)] + [line + [0, 12.0, 0]]
    distances = [100.0 * j for j in range(6)]
    # map 0 is 12 m away after 500 m driven: inside 10 + 0.02 x 500 = 20 m, outside a 10 m radius alone
    assert nearby_maps(paths, distances) == [(0, 12.0)]
    assert nearby_maps(paths, distances, drift=0.0) == []
    # beside map 3, two maps back: the road just driven, unless the gap allowed is 2
    paths[-1] = line + [300.0, 12.0, 0]
    assert nearby_maps(paths, distances) == []
    assert nearby_maps(paths, distances, min_node_gap=2) == [(3, 12.0)]
    # several in reach: nearest first
    paths[-1] = line + [0, 12.0, 0]
    paths[1] = line + [0, 23.0, 0]
    assert nearby_maps(paths, distances) == [(1, 11.0), (0, 12.0)]


def test_a_return_that_place_recognition_misses_is_closed_by_position(town_drive):
    """With place recognition unable to propose (an inlier threshold no match reaches), the graph's own
    estimate of where the car is proposes the old local maps, and ICP verifies them."""
    truth, drifted, scans = town_drive
    corrected, closer = close_loops(drifted, scans, min_inliers=10**6)
    assert closer.closures and all(c.proposed_by == "position" for c in closer.closures)
    for c in closer.closures:
        true = invert_pose(truth[c.query_frame]) @ truth[c.reference_frame]
        assert np.linalg.norm((invert_pose(true) @ c.relative)[:3, 3]) < 0.5
    assert _rmse(corrected, truth) < 0.5 * _rmse(drifted, truth)
    _, neither = close_loops(drifted, scans, min_inliers=10**6, max_proposals=0)
    assert neither.closures == []


def test_the_closer_is_fed_frame_by_frame_as_the_filter_runs(town_drive):
    truth, drifted, scans = town_drive
    closer = LoopCloser()
    found = [closer.add_frame(k, T, p) for k, (T, p) in enumerate(zip(drifted, scans))]
    closer.finish()
    assert any(c is not None for c in found)
    assert len(closer.corrected_poses()) == len(truth)


def test_the_trajectory_plot_marks_each_closure(town_drive):
    """slamlib run's trajectory.png with loop closure: the re-anchored path and one line per closure, solid when
    the graph kept it, dotted when it did not."""
    from slamlib.slam3d.plot import plot_trajectories

    truth, drifted, _ = town_drive
    fig = plot_trajectories(
        drifted,
        ground_truth=truth,
        loop_closed=truth,
        closures=[(290, 10, True), (200, 20, False)],
    )
    ax = fig.axes[0]
    lines = [ln for ln in ax.lines if ln.get_color() == "tab:purple"]
    assert [ln.get_linestyle() for ln in lines] == ["-", ":"]
    assert np.allclose(lines[0].get_xdata(), [truth[290][0, 3], truth[10][0, 3]])
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "particle SLAM + loop closure" in labels and labels.count("loop closure") == 1
