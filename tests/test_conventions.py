"""The conventions module: quaternion order, rotation naming, specific force."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kfusion.conventions import (
    as_wxyz,
    integrate_gyroscope,
    matrix_from_wxyz,
    quaternion_multiply,
    rotation_from_wxyz,
    specific_force,
    wxyz_from_rotation,
)


def test_scalar_first_order_hand_example():
    # 90 deg about z: [w, x, y, z] = [cos 45, 0, 0, sin 45] takes x to y
    quaternion = [np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)]
    np.testing.assert_allclose(matrix_from_wxyz(quaternion) @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(rotation_from_wxyz(quaternion).apply([1, 0, 0]), [0, 1, 0],
                               atol=1e-15)


def test_matrix_matches_scipy_for_random_rotations():
    rotations = Rotation.random(50, random_state=np.random.default_rng(0))
    quaternion = wxyz_from_rotation(rotations)
    assert (quaternion[:, 0] >= 0).all()
    np.testing.assert_allclose(matrix_from_wxyz(quaternion), rotations.as_matrix(), atol=1e-14)


def test_multiply_composes_like_matrices():
    rng = np.random.default_rng(1)
    a, b = wxyz_from_rotation(Rotation.random(2, random_state=rng))
    np.testing.assert_allclose(matrix_from_wxyz(quaternion_multiply(a, b)),
                               matrix_from_wxyz(a) @ matrix_from_wxyz(b), atol=1e-14)


def test_gyroscope_integration_is_exact_for_constant_rate():
    rate = np.array([0.3, -1.2, 0.7])  # rad/s, IMU frame
    quaternion = np.array([1.0, 0.0, 0.0, 0.0])
    for _ in range(100):
        quaternion = integrate_gyroscope(quaternion, rate, 0.01)
    expected = Rotation.from_rotvec(rate * 1.0).as_matrix()
    np.testing.assert_allclose(matrix_from_wxyz(quaternion), expected, atol=1e-12)


def test_accelerometer_at_rest_reads_up():
    # y-up world, IMU aligned with it: at rest the accelerometer reads +9.81 along y
    np.testing.assert_allclose(specific_force(np.eye(3), [0, 0, 0], [0, -9.81, 0]), [0, 9.81, 0])


def test_as_wxyz_rejects_wrong_shape():
    with pytest.raises(ValueError, match=r"expected shape \(4,\) or \(n, 4\) \[w, x, y, z\], "
                       r"got \(3,\)"):
        as_wxyz([1.0, 0.0, 0.0])
