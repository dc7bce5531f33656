"""Quaternion maths and pose interpolation against independent formulas."""

from __future__ import annotations

import numpy as np
import pytest

from evperc.logs.transforms import (
    extrinsic_matrix,
    interpolate_pose,
    invert,
    pose_matrix,
    quaternion_to_matrix,
    slerp,
)
from tests.logs.reference import geodesic_interpolation, rodrigues
from tests.mcap_writers import quaternion_xyzw


def _quat_from_axis_angle(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.array([*(np.sin(angle / 2) * axis), np.cos(angle / 2)])


def test_quaternion_to_matrix_matches_rodrigues():
    rng = np.random.default_rng(3)
    for _ in range(20):
        axis, angle = rng.normal(size=3), rng.uniform(-np.pi, np.pi)
        expected = rodrigues(axis / np.linalg.norm(axis) * angle)
        got = quaternion_to_matrix(_quat_from_axis_angle(axis, angle))
        np.testing.assert_allclose(got, expected, atol=1e-12)


def test_quaternion_90_deg_about_z_by_hand():
    q = (0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4))
    np.testing.assert_allclose(quaternion_to_matrix(q), [[0, -1, 0], [1, 0, 0], [0, 0, 1]],
                               atol=1e-12)


def test_slerp_about_fixed_axis_is_angle_interpolation():
    axis = np.array([1.0, 2.0, -0.5])
    q0, q1 = _quat_from_axis_angle(axis, 0.3), _quat_from_axis_angle(axis, 1.9)
    for alpha in (0.0, 0.25, 0.5, 0.9, 1.0):
        expected = _quat_from_axis_angle(axis, 0.3 + alpha * 1.6)
        np.testing.assert_allclose(slerp(q0, q1, alpha), expected, atol=1e-12)


def test_slerp_takes_the_short_arc_for_negated_quaternions():
    q0 = _quat_from_axis_angle([0, 0, 1], 0.0)
    q1 = -_quat_from_axis_angle([0, 0, 1], 0.4)  # same rotation as +q1
    R = quaternion_to_matrix(slerp(q0, q1, 0.5))
    np.testing.assert_allclose(R, rodrigues(np.array([0, 0, 0.2])), atol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_interpolate_pose_matches_geodesic_reference(seed):
    rng = np.random.default_rng(seed)
    T0 = np.eye(4)
    T1 = np.eye(4)
    T0[:3, :3] = rodrigues(rng.normal(size=3))
    T1[:3, :3] = T0[:3, :3] @ rodrigues(rng.normal(size=3) * 0.5)
    T0[:3, 3], T1[:3, 3] = rng.normal(size=3), rng.normal(size=3)
    alpha = rng.uniform()
    got = interpolate_pose(T0[:3, 3], quaternion_xyzw(T0), T1[:3, 3], quaternion_xyzw(T1),
                           alpha)
    np.testing.assert_allclose(got, geodesic_interpolation(T0, T1, alpha), atol=1e-9)


def test_invert_and_extrinsic():
    T = pose_matrix([1.0, -2.0, 0.5], _quat_from_axis_angle([0.3, 1, 0.2], 0.8))
    np.testing.assert_allclose(invert(T) @ T, np.eye(4), atol=1e-12)
    E = extrinsic_matrix(x_m=1.0, z_m=2.0, yaw_deg=90.0)
    np.testing.assert_allclose(E @ [1.0, 0.0, 0.0, 1.0], [1.0, 1.0, 2.0, 1.0], atol=1e-12)
    E = extrinsic_matrix(roll_deg=90.0)  # y axis -> z axis
    np.testing.assert_allclose(E @ [0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 1.0, 1.0], atol=1e-12)


def test_zero_quaternion_is_identity():
    np.testing.assert_allclose(quaternion_to_matrix([0.0, 0.0, 0.0, 0.0]), np.eye(3))
