"""The hand-written rotation formulas agree with scipy's Rotation (property tests)."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from slamlib.geometry import (
    invert_pose,
    make_pose,
    matrix_to_rpy,
    rot_x,
    rot_y,
    rot_z,
    rpy_to_matrix,
    skew,
    so3_exp,
    so3_log,
    transform_points,
)

angle = st.floats(-np.pi, np.pi, allow_nan=False)
half = st.floats(-1.5, 1.5, allow_nan=False)


@given(angle, half, angle)
@settings(max_examples=200, deadline=None)
def test_rpy_to_matrix_matches_scipy_extrinsic_xyz(r, p, y):
    expected = Rotation.from_euler("xyz", [r, p, y]).as_matrix()
    np.testing.assert_allclose(rpy_to_matrix([r, p, y]), expected, atol=1e-12)
    np.testing.assert_allclose(
        rpy_to_matrix([r, p, y]), rot_z(y) @ rot_y(p) @ rot_x(r), atol=1e-12
    )


@given(angle, half, angle)
@settings(max_examples=200, deadline=None)
def test_matrix_to_rpy_round_trip(r, p, y):
    np.testing.assert_allclose(
        rpy_to_matrix(matrix_to_rpy(rpy_to_matrix([r, p, y]))),
        rpy_to_matrix([r, p, y]),
        atol=1e-9,
    )


def test_batched_rpy_to_matrix():
    rng = np.random.default_rng(0)
    rpy = rng.uniform(-1, 1, size=(5, 7, 3))
    R = rpy_to_matrix(rpy)
    assert R.shape == (5, 7, 3, 3)
    np.testing.assert_allclose(R[2, 3], rpy_to_matrix(rpy[2, 3]))


@given(
    angle, half, angle, st.floats(-100, 100), st.floats(-100, 100), st.floats(-100, 100)
)
@settings(max_examples=100, deadline=None)
def test_invert_pose_and_transform(r, p, y, x, yy, z):
    T = make_pose(rpy_to_matrix([r, p, y]), [x, yy, z])
    np.testing.assert_allclose(T @ invert_pose(T), np.eye(4), atol=1e-9)
    pts = np.random.default_rng(1).normal(size=(20, 3))
    back = transform_points(invert_pose(T), transform_points(T, pts))
    np.testing.assert_allclose(back, pts, atol=1e-9)


# ------------------------------------------------------------------ the formulas, value by value
def test_elementary_rotations_at_a_known_angle():
    a = np.pi / 6
    c, s = np.sqrt(3) / 2, 0.5
    np.testing.assert_allclose(rot_x(a), [[1, 0, 0], [0, c, -s], [0, s, c]], atol=1e-15)
    np.testing.assert_allclose(rot_y(a), [[c, 0, s], [0, 1, 0], [-s, 0, c]], atol=1e-15)
    np.testing.assert_allclose(rot_z(a), [[c, -s, 0], [s, c, 0], [0, 0, 1]], atol=1e-15)


def test_matrix_to_rpy_clips_rounding_beyond_plus_minus_one():
    # R[2, 0] = -sin(pitch) one ulp beyond +-1 (rounding in a product of rotations) gives pitch -+pi/2, not NaN
    for v, pitch in [
        (np.nextafter(1.0, 2.0), -np.pi / 2),
        (np.nextafter(-1.0, -2.0), np.pi / 2),
    ]:
        R = np.zeros((3, 3))
        R[2, 0] = v
        R[0, 0] = R[2, 2] = 1.0
        rpy = matrix_to_rpy(R)
        assert np.isfinite(rpy).all()
        assert rpy[1] == pitch


def test_matrix_to_rpy_batched_shape_and_values():
    rpy = np.random.default_rng(2).uniform(-1, 1, size=(4, 5, 3))
    out = matrix_to_rpy(rpy_to_matrix(rpy))
    assert out.shape == (4, 5, 3)
    np.testing.assert_allclose(out, rpy, atol=1e-12)


def test_make_pose_and_invert_pose_values():
    R = rot_z(np.pi / 2)
    T = make_pose(R, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(T[3], [0, 0, 0, 1])
    np.testing.assert_array_equal(T[:3, 3], [1, 2, 3])
    Ti = invert_pose(T)
    np.testing.assert_allclose(Ti[:3, :3], R.T, atol=1e-15)
    # (-2, 1, -3)
    np.testing.assert_allclose(Ti[:3, 3], -R.T @ [1.0, 2.0, 3.0], atol=1e-15)
    np.testing.assert_array_equal(Ti[3], [0, 0, 0, 1])
    # batched: (2, 4, 4)
    Tb = make_pose(np.stack([R, R.T]), [[1.0, 0, 0], [0, 1.0, 0]])
    Tib = invert_pose(Tb)
    assert Tib.shape == (2, 4, 4)
    np.testing.assert_allclose(Tib[1], invert_pose(Tb[1]), atol=1e-15)
    np.testing.assert_allclose(
        Tb @ Tib, np.broadcast_to(np.eye(4), (2, 4, 4)), atol=1e-15
    )


def test_transform_points_values_and_dtype():
    T = make_pose(rot_z(np.pi / 2), [10.0, 0.0, -1.0])
    pts = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 3.0]])
    # Rz(90) maps x -> y, y -> -x
    np.testing.assert_allclose(
        transform_points(T, pts), [[10.0, 1.0, -1.0], [8.0, 0.0, 2.0]], atol=1e-12
    )
    out32 = transform_points(T, pts.astype(np.float32))
    assert out32.dtype == np.float32
    np.testing.assert_allclose(out32, [[10.0, 1.0, -1.0], [8.0, 0.0, 2.0]], atol=1e-5)
    # integer points -> float64
    outi = transform_points(T, np.array([[1, 0, 0], [0, 2, 3]]))
    assert outi.dtype == np.float64
    np.testing.assert_allclose(outi, [[10.0, 1.0, -1.0], [8.0, 0.0, 2.0]], atol=1e-12)


def test_float32_inputs_are_computed_in_float64():
    # rotations and inverses are formed in float64 even from float32 angles, matrices or poses
    rpy32 = np.float32([0.3, -1.1, 2.9])
    R = rpy_to_matrix(rpy32)
    assert R.dtype == np.float64
    np.testing.assert_allclose(
        R, rpy_to_matrix(rpy32.astype(np.float64)), rtol=0, atol=1e-15
    )
    R32 = R.astype(np.float32)
    out = matrix_to_rpy(R32)
    assert out.dtype == np.float64
    np.testing.assert_allclose(
        out, matrix_to_rpy(R32.astype(np.float64)), rtol=0, atol=1e-15
    )
    T32 = make_pose(R, [1000.1, -2000.3, 3.7]).astype(np.float32)
    np.testing.assert_allclose(
        invert_pose(T32), invert_pose(T32.astype(np.float64)), rtol=0, atol=1e-12
    )


def _rotation_vectors(rng, n):
    """Rotation vectors over every angle from 0 to pi: random axes and angles, tiny angles (the series branch),
    angles just past the series' threshold, and half turns about random and coordinate axes."""
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1)[:, None]
    angles = rng.uniform(0.0, np.pi, n)
    angles[:20] = 10.0 ** rng.uniform(-12, -4.5, 20)
    angles[20:40] = 10.0 ** rng.uniform(-4, -3, 20)
    angles[40:60] = np.pi
    axes[60:63], angles[60:63] = np.eye(3), np.pi
    return axes * angles[:, None]


def test_so3_exp_matches_scipy_at_every_angle():
    phi = _rotation_vectors(np.random.default_rng(5), 2000)
    np.testing.assert_allclose(
        so3_exp(phi), Rotation.from_rotvec(phi).as_matrix(), rtol=0, atol=2e-15
    )
    # one vector in, one matrix out; the zero vector is the identity
    np.testing.assert_allclose(
        so3_exp(phi[100]), Rotation.from_rotvec(phi[100]).as_matrix(), atol=2e-15
    )
    np.testing.assert_array_equal(so3_exp(np.zeros(3)), np.eye(3))


def test_so3_log_inverts_exp_and_matches_scipy_at_every_angle():
    phi = _rotation_vectors(np.random.default_rng(6), 2000)
    R = Rotation.from_rotvec(phi).as_matrix()
    logs = np.array([so3_log(r) for r in R])
    # a half turn's vector is +-phi: both are right, scipy and Log may pick either
    half = np.isclose(np.linalg.norm(phi, axis=1), np.pi)
    np.testing.assert_allclose(logs[~half], phi[~half], rtol=0, atol=4e-15)
    np.testing.assert_allclose(
        logs[~half], Rotation.from_matrix(R[~half]).as_rotvec(), rtol=0, atol=4e-15
    )
    np.testing.assert_allclose(np.abs(logs[half]), np.abs(phi[half]), rtol=0, atol=1e-7)
    np.testing.assert_allclose(so3_exp(logs), R, rtol=0, atol=4e-15)
    # tiny angles keep their digits relative to the angle (the series branch)
    tiny = np.linalg.norm(phi, axis=1) < 1e-6
    assert tiny.sum() >= 10
    np.testing.assert_allclose(logs[tiny], phi[tiny], rtol=1e-9, atol=0)
    np.testing.assert_array_equal(so3_log(np.eye(3)), np.zeros(3))


def test_skew_is_the_cross_product():
    rng = np.random.default_rng(7)
    v, u = rng.normal(size=(2, 50, 3))
    np.testing.assert_allclose(
        np.einsum("nij,nj->ni", skew(v), u), np.cross(v, u), atol=1e-14
    )
    np.testing.assert_allclose(skew(v[0]) @ u[0], np.cross(v[0], u[0]), atol=1e-14)
    v, u = np.array([0.3, -1.2, 2.5]), np.array([-0.7, 0.4, 1.1])
    np.testing.assert_allclose(skew(v) @ u, np.cross(v, u), atol=1e-15)
    np.testing.assert_allclose(skew(np.stack([v, u]))[1] @ v, np.cross(u, v), atol=1e-15)
