"""The hand-written rotation formulas agree with scipy's Rotation (property tests)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from slamlib.geometry import (invert_pose, make_pose, matrix_to_rpy, rot_x, rot_y, rot_z, rpy_to_matrix,
                              transform_points)

angle = st.floats(-np.pi, np.pi, allow_nan=False)
half = st.floats(-1.5, 1.5, allow_nan=False)


@given(angle, half, angle)
@settings(max_examples=200, deadline=None)
def test_rpy_to_matrix_matches_scipy_extrinsic_xyz(r, p, y):
    expected = Rotation.from_euler("xyz", [r, p, y]).as_matrix()
    np.testing.assert_allclose(rpy_to_matrix([r, p, y]), expected, atol=1e-12)
    np.testing.assert_allclose(rpy_to_matrix([r, p, y]), rot_z(y) @ rot_y(p) @ rot_x(r), atol=1e-12)


@given(angle, half, angle)
@settings(max_examples=200, deadline=None)
def test_matrix_to_rpy_round_trip(r, p, y):
    np.testing.assert_allclose(rpy_to_matrix(matrix_to_rpy(rpy_to_matrix([r, p, y]))),
                               rpy_to_matrix([r, p, y]), atol=1e-9)


def test_batched_rpy_to_matrix():
    rng = np.random.default_rng(0)
    rpy = rng.uniform(-1, 1, size=(5, 7, 3))
    R = rpy_to_matrix(rpy)
    assert R.shape == (5, 7, 3, 3)
    np.testing.assert_allclose(R[2, 3], rpy_to_matrix(rpy[2, 3]))


@given(angle, half, angle, st.floats(-100, 100), st.floats(-100, 100), st.floats(-100, 100))
@settings(max_examples=100, deadline=None)
def test_invert_pose_and_transform(r, p, y, x, yy, z):
    T = make_pose(rpy_to_matrix([r, p, y]), [x, yy, z])
    np.testing.assert_allclose(T @ invert_pose(T), np.eye(4), atol=1e-9)
    pts = np.random.default_rng(1).normal(size=(20, 3))
    back = transform_points(invert_pose(T), transform_points(T, pts))
    np.testing.assert_allclose(back, pts, atol=1e-9)
