"""The conventions module: quaternion order, rotation naming, specific force."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from kfusion.conventions import (
    as_wxyz,
    canonical_wxyz,
    integrate_gyroscope,
    matrix_from_quaternion,
    matrix_from_wxyz,
    median_interval,
    quaternion_about_axis,
    quaternion_exp,
    quaternion_exp_rows,
    quaternion_log,
    quaternion_multiply,
    quaternion_product,
    quaternion_step,
    rotation_angle,
    rotation_from_wxyz,
    specific_force,
    wxyz_from_rotation,
)
from kfusion.simulate.trajectories import chain_quaternion


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


# ------------------------------------------------------------------------------------------
# one implementation per quaternion operation: the per-sample (floats) and row (numpy) forms
# agree with each other and with scipy, an independent implementation
# ------------------------------------------------------------------------------------------


def _random_cases(count: int, seed: int):
    rng = np.random.default_rng(seed)
    first = wxyz_from_rotation(Rotation.random(count, random_state=rng))
    second = wxyz_from_rotation(Rotation.random(count, random_state=rng))
    # rotation vectors from 1e-14 rad (first-order branch) to 3 rad
    theta = rng.normal(size=(count, 3)) * rng.choice([1e-14, 1e-7, 1e-3, 1.0, 3.0],
                                                      size=(count, 1))
    return first, second, theta


def test_product_and_matrix_per_sample_forms_equal_the_row_forms():
    first, second, _ = _random_cases(200, 2)
    rows = quaternion_multiply(first, second)
    np.testing.assert_allclose(
        quaternion_multiply(first, second),
        wxyz_from_rotation(rotation_from_wxyz(first) * rotation_from_wxyz(second))
        * np.sign(rows[:, :1]), atol=1e-14)
    for a, b, product in zip(first, second, rows, strict=True):
        np.testing.assert_array_equal(quaternion_product(tuple(a), tuple(b)), product)
        np.testing.assert_allclose(matrix_from_quaternion(tuple(a)), matrix_from_wxyz(a),
                                   atol=1e-15)


def test_exponential_map_forms_agree_with_each_other_and_scipy():
    _, _, theta = _random_cases(300, 3)
    rows = quaternion_exp_rows(theta)
    np.testing.assert_allclose(canonical_wxyz(rows),
                               wxyz_from_rotation(Rotation.from_rotvec(theta)), atol=1e-12)
    for vector, row in zip(theta, rows, strict=True):
        np.testing.assert_allclose(quaternion_exp(tuple(vector)), row, atol=1e-15)
        if np.linalg.norm(vector) < np.pi:  # the logarithm returns |theta| <= pi
            np.testing.assert_allclose(quaternion_log(quaternion_exp(tuple(vector))), vector,
                                       atol=1e-12)
    # hand value: 90 degrees about z
    np.testing.assert_allclose(quaternion_exp((0.0, 0.0, np.pi / 2)),
                               [np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)], atol=1e-16)
    assert np.isnan(quaternion_exp((np.inf, 0.0, 0.0))).all()


def test_axis_angle_is_the_exponential_map_of_angle_times_axis():
    rng = np.random.default_rng(4)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle = rng.uniform(-np.pi, np.pi, 100)  # signed: negative angles turn the other way
    np.testing.assert_allclose(quaternion_about_axis(axis, angle),
                               quaternion_exp_rows(angle[:, None] * axis), atol=1e-15)


def test_angle_chain_composes_like_scipy():
    rng = np.random.default_rng(5)
    axes = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    base = wxyz_from_rotation(Rotation.random(random_state=rng))
    angles = rng.uniform(-np.pi, np.pi, (50, 3))
    expected = rotation_from_wxyz(base) * Rotation.from_rotvec(angles[:, :1] * axes[0]) \
        * Rotation.from_rotvec(angles[:, 1:2] * axes[1]) \
        * Rotation.from_rotvec(angles[:, 2:] * axes[2])
    np.testing.assert_allclose(matrix_from_wxyz(chain_quaternion(base, axes, angles)),
                               expected.as_matrix(), atol=1e-14)


def test_gyroscope_step_forms_agree_and_match_scipy():
    first, _, theta = _random_cases(200, 6)
    for q, rate in zip(first, theta, strict=True):
        step = quaternion_step(tuple(q), tuple(rate), 0.01)
        np.testing.assert_array_equal(integrate_gyroscope(q, rate, 0.01), step)
        expected = rotation_from_wxyz(q) * Rotation.from_rotvec(rate * 0.01)
        np.testing.assert_allclose(matrix_from_wxyz(step), expected.as_matrix(), atol=1e-14)


def test_rotation_angle_and_canonical_sign():
    first, second, _ = _random_cases(100, 7)
    expected = (rotation_from_wxyz(first).inv() * rotation_from_wxyz(second)).magnitude()
    measured = [rotation_angle(a, b) for a, b in zip(first, second, strict=True)]
    np.testing.assert_allclose(measured, expected, atol=1e-12)
    flipped = first * np.where(np.arange(100) % 2, -1.0, 1.0)[:, None]
    np.testing.assert_array_equal(canonical_wxyz(flipped), first)
    assert rotation_angle([1.0, 0.0, 0.0, 0.0], [np.cos(0.5), np.sin(0.5), 0.0, 0.0]) \
        == pytest.approx(1.0, abs=1e-15)


def test_median_interval_is_the_nominal_period_despite_dropouts_and_bursts():
    # 10 ms frames with one dropped frame (20 ms) and a burst (two 1 ms steps): median 10 ms
    t = [0.0, 0.01, 0.02, 0.04, 0.05, 0.051, 0.052, 0.06, 0.07]
    assert median_interval(t) == pytest.approx(0.01, abs=1e-15)
    assert median_interval([0.0, 0.5, 1.5]) == pytest.approx(0.75)  # even count: the mean of two
    assert median_interval([3.0]) == 0.0
    assert median_interval([], default=0.01) == 0.01
