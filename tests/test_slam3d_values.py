"""Value tests of the 3D steps and pipeline that pin what mutation testing found unpinned (issue 15).

Each test states the formula or rule it pins; expected values are computed independently in the test.
"""

import numpy as np

from slamlib import geometry
from slamlib.slam3d import steps
from slamlib.slam3d.config import ScanConfig
from slamlib.slam3d.preprocess import deskew, sweep_times


def _scan(n=200, seed=0):
    rng = np.random.default_rng(seed)
    az = rng.uniform(-np.pi, np.pi, n)
    r = rng.uniform(3.0, 30.0, n)
    return np.column_stack(
        [r * np.cos(az), r * np.sin(az), rng.uniform(-1.5, 1.0, n)]
    ).astype(np.float32)


TWIST = (np.array([12.0, 0.3, -0.1]), np.array([0.01, -0.02, 0.25]))


def test_deskew_scan_times_points_by_their_azimuth_in_the_velodyne_frame():
    """``steps.deskew_scan(points, imu, scan_config, T_body_velo)`` = ``preprocess.deskew`` of the body-frame points
    with the twist ``imu`` and firing times ``sweep_times(inv(T_body_velo) p, sweep_period)``: the azimuth is read
    in the Velodyne frame. A mounting turned 90 degrees about z shifts every firing time by a quarter sweep."""
    pts = _scan()
    config = ScanConfig(sweep_period=0.1)
    T = geometry.make_pose(
        geometry.rpy_to_matrix([0.0, 0.0, np.pi / 2]), [0.8, -0.3, 1.7]
    )
    velo = (pts.astype(np.float64) - T[:3, 3]) @ T[:3, :3]  # inv(T) p, written out
    expected = deskew(pts, *TWIST, sweep_times(velo, 0.1))
    got = steps.deskew_scan(pts, TWIST, config, T_body_velo=T)
    assert got.dtype == np.float32 and got.flags.c_contiguous and got.shape == pts.shape
    np.testing.assert_array_equal(got, expected)
    untilted = steps.deskew_scan(pts, TWIST, config)
    np.testing.assert_array_equal(untilted, deskew(pts, *TWIST, sweep_times(pts, 0.1)))
    assert (
        np.abs(got - untilted).max() > 0.1
    )  # the mounting matters: a quarter sweep at 12 m/s is 0.3 m


def test_deskew_scan_moves_points_to_the_pose_time_given_the_scan_offset():
    """``time_offset`` (the scan's stamp relative to the pose's, ``Frame.scan_time_offset_s``) shifts every firing
    time: the points go to the frame at the pose's time. A point fired at the scan's stamp then moves by the twist
    over ``-time_offset``: 12 m/s x 20 ms = 0.24 m forward for a point straight ahead."""
    pts = _scan()
    config = ScanConfig(sweep_period=0.1)
    got = steps.deskew_scan(pts, TWIST, config, time_offset=-0.02)
    np.testing.assert_array_equal(got, deskew(pts, *TWIST, sweep_times(pts, 0.1) - 0.02))
    np.testing.assert_array_equal(
        steps.deskew_scan(pts, TWIST, config, time_offset=0.0),
        steps.deskew_scan(pts, TWIST, config),
    )
    ahead = np.array(
        [[20.0, 0.0, 0.0]], np.float32
    )  # azimuth 0: fired at the scan's stamp
    moved = steps.deskew_scan(
        ahead, (np.array([12.0, 0.0, 0.0]), np.zeros(3)), config, time_offset=-0.02
    )
    np.testing.assert_allclose(moved, [[20.0 - 0.24, 0.0, 0.0]], atol=1e-5)


def test_deskew_scan_uses_the_configured_sweep_period_and_keeps_empty_scans():
    """The firing times scale with ``ScanConfig.sweep_period`` (twice the period: twice each point's offset from
    where it was fired, to first order), and an empty scan comes back empty (0, 3) float32."""
    pts = _scan(50, 1)
    v = (np.array([10.0, 0.0, 0.0]), np.zeros(3))
    d1 = steps.deskew_scan(pts, v, ScanConfig(sweep_period=0.1)) - pts
    d2 = steps.deskew_scan(pts, v, ScanConfig(sweep_period=0.2)) - pts
    np.testing.assert_allclose(d1[:, 0], 10.0 * sweep_times(pts, 0.1), atol=1e-5)
    np.testing.assert_allclose(d2, 2 * d1, atol=1e-5)
    empty = steps.deskew_scan(np.zeros((0, 3), np.float32), v, ScanConfig())
    assert empty.shape == (0, 3) and empty.dtype == np.float32
