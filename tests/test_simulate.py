"""The simulator: physics, sensor error statistics, occlusion placement, files and CLI."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from kfusion.cli import main
from kfusion.conventions import (
    OPTITRACK_GRAVITY,
    matrix_from_wxyz,
    quaternion_multiply,
    rotation_from_wxyz,
    specific_force,
)
from kfusion.profiles import MPU9255, OPTITRACK, MocapProfile
from kfusion.recording import occlusion_durations, occlusion_runs, read_recording
from kfusion.simulate import (
    SCENARIOS,
    OcclusionSpec,
    Simulation,
    read_truth,
    simulate,
    write_simulation,
)
from kfusion.simulate.imu import bias_walk, error_matrix, measure, quantise, white_noise_std
from kfusion.simulate.occlusions import gap_frame_limits
from kfusion.simulate.trajectories import (
    AngleChainOrientation,
    QuinticSpline,
    quintic_coefficients,
)

GRAVITY = np.array(OPTITRACK_GRAVITY)
SHORT = 20.0  # s, enough for several gaps; keeps the tests fast


def error_free_imu():
    """The MPU9255 profile with every error switched off (what a model-matched test uses)."""
    return dataclasses.replace(
        MPU9255, name="perfect",
        accelerometer_noise_density=0.0, accelerometer_bias_random_walk=0.0,
        accelerometer_turn_on_bias=0.0, accelerometer_scale_error=0.0,
        accelerometer_cross_axis=0.0, accelerometer_range=np.inf, accelerometer_resolution=0.0,
        gyroscope_noise_density=0.0, gyroscope_bias_random_walk=0.0,
        gyroscope_turn_on_bias=0.0, gyroscope_scale_error=0.0, gyroscope_cross_axis=0.0,
        gyroscope_range=np.inf, gyroscope_resolution=0.0,
    )


PERFECT_MOCAP = MocapProfile(name="perfect", position_noise=0.0, orientation_noise=0.0,
                             rate=100.0)


@pytest.fixture(scope="module")
def perfect() -> dict[str, Simulation]:
    return {name: simulate(name, seed=3, imu=error_free_imu(), mocap=PERFECT_MOCAP,
                           duration=SHORT) for name in SCENARIOS}


@pytest.fixture(scope="module")
def realistic() -> Simulation:
    return simulate("arm_lift", seed=5)


# --------------------------------------------------------------------------------------------
# Building blocks, against hand-derived numbers
# --------------------------------------------------------------------------------------------


def test_quintic_rest_to_rest_is_minimum_jerk():
    # x(s) = 10 s^3 - 15 s^4 + 6 s^5 on [0, 1] (Flash & Hogan)
    coefficients = quintic_coefficients([1.0], ([[0.0]], [[0.0]], [[0.0]]),
                                        ([[1.0]], [[0.0]], [[0.0]]))
    np.testing.assert_allclose(coefficients[0, :, 0], [0, 0, 0, 10, -15, 6], atol=1e-12)


def test_quintic_spline_meets_its_knots_and_derivatives():
    rng = np.random.default_rng(0)
    knots = np.array([0.0, 0.4, 1.1, 2.0])
    value, first, second = (rng.normal(size=(4, 2)) for _ in range(3))
    spline = QuinticSpline(knots, value, first, second)
    # at each knot from both sides
    for side in (-1e-12, 0.0):
        x, v, a = spline.evaluate(np.clip(knots + side, 0, 2))
        np.testing.assert_allclose(x, value, atol=1e-9)
        np.testing.assert_allclose(v, first, atol=1e-9)
        np.testing.assert_allclose(a, second, atol=1e-8)
    # derivatives against central differences of the value
    t = np.linspace(0.01, 1.99, 50)
    h = 1e-5
    x, v, a = spline.evaluate(t)
    np.testing.assert_allclose(v, (spline.evaluate(t + h)[0] - spline.evaluate(t - h)[0]) / (2 * h),
                               atol=1e-6)
    np.testing.assert_allclose(a, (spline.evaluate(t + h)[1] - spline.evaluate(t - h)[1]) / (2 * h),
                               atol=1e-5)


def test_quintic_spline_rejects_times_outside_its_knots():
    spline = QuinticSpline(np.array([0.0, 1.0]), np.zeros(2), np.zeros(2), np.zeros(2))
    with pytest.raises(ValueError, match=r"inside \[0.0, 1.0\]"):
        spline.evaluate(np.array([1.5]))


def test_angle_chain_rate_for_a_single_axis_is_the_angle_rate():
    angles = QuinticSpline(np.array([0.0, 1.0]), np.array([[0.0], [1.0]]), np.zeros((2, 1)),
                           np.zeros((2, 1)))
    axis = np.array([[0.0, 0.6, 0.8]])
    orientation = AngleChainOrientation(base=np.array([1.0, 0, 0, 0]), axes=axis, angles=angles)
    t = np.array([0.25, 0.5])
    quaternion, rate = orientation.evaluate(t)
    theta, theta_rate, _ = angles.evaluate(t)
    np.testing.assert_allclose(rate, theta_rate * axis, atol=1e-15)
    expected = np.column_stack([np.cos(theta[:, 0] / 2), np.sin(theta[:, 0] / 2)[:, None] * axis])
    np.testing.assert_allclose(quaternion, expected, atol=1e-15)


def test_error_matrix_places_scale_on_the_diagonal_and_cross_axis_off_it():
    matrix = error_matrix([1.0, -2.0, 0.5], [1, 2, 3, 4, 5, 6], scale_error=0.01, cross_axis=0.1)
    expected = np.array([[1.01, 0.1, 0.2], [0.3, 0.98, 0.4], [0.5, 0.6, 1.005]])
    np.testing.assert_allclose(matrix, expected, atol=1e-15)


def test_bias_walk_starts_at_turn_on_and_steps_by_rw_sqrt_dt():
    bias = bias_walk([1.0, 2.0, 3.0], random_walk=0.5, dt=0.04, step_normals=np.ones((2, 3)))
    # step = 0.5 * sqrt(0.04) = 0.1
    np.testing.assert_allclose(bias, [[1, 2, 3], [1.1, 2.1, 3.1], [1.2, 2.2, 3.2]], atol=1e-15)


def test_noise_quantisation_and_saturation():
    assert white_noise_std(0.01, 0.0025) == pytest.approx(0.2)  # 0.01 * sqrt(400 Hz)
    np.testing.assert_array_equal(quantise(np.array([0.26, -0.74]), 0.5), [0.5, -0.5])
    np.testing.assert_array_equal(quantise(np.array([0.26]), 0.0), [0.26])
    measured = measure(np.array([[1.0, 5.0, -9.0]]), np.eye(3), np.array([0.5, 0, 0]),
                       np.zeros((1, 3)), limit=4.0, resolution=0.0)
    np.testing.assert_array_equal(measured, [[1.5, 4.0, -4.0]])


def test_gap_frame_limits_round_into_the_range():
    # at 100 Hz a gap of k hidden frames lasts (k + 1) / 100 s
    assert gap_frame_limits((0.1, 0.3), 100.0) == (9, 29)
    assert gap_frame_limits((0.105, 0.2), 100.0) == (10, 19)
    with pytest.raises(ValueError, match="no whole number of frames"):
        gap_frame_limits((0.101, 0.105), 100.0)


# --------------------------------------------------------------------------------------------
# API, determinism, validation
# --------------------------------------------------------------------------------------------


def test_scenario_names():
    assert SCENARIOS == ("arm_lift", "circle", "pick_tool", "random_reach")


def test_unknown_scenario_names_the_known_ones():
    with pytest.raises(ValueError, match="arm_lift.*circle.*pick_tool.*random_reach"):
        simulate("arm_raise", seed=0)


@pytest.mark.parametrize("kwargs, message", [
    ({"seed": -1}, "seed: expected a non-negative integer"),
    ({"seed": 0, "duration": 2.0}, "duration: expected 5-3600 s"),
    ({"seed": 0, "imu": "bno055"}, "unknown IMU profile"),
    ({"seed": 0, "imu_rate": 0.0}, "imu_rate: expected a positive rate"),
    ({"seed": 0, "occlusions": (0.1, 0.3)}, "occlusions: expected an OcclusionSpec"),
])
def test_bad_arguments_are_value_errors(kwargs, message):
    with pytest.raises(ValueError, match=message):
        simulate("circle", **kwargs)


@pytest.mark.parametrize("kwargs, message", [
    ({"gap_range": (0.3, 0.1)}, r"expected 0 < min <= max"),
    ({"placement": "anywhere"}, r"expected one of \['random', 'mid_motion'"),
    ({"spacing": 0.0}, "expected a positive number of seconds"),
    ({"count": 0}, "expected None or a positive integer"),
])
def test_bad_occlusion_specs_are_value_errors(kwargs, message):
    with pytest.raises(ValueError, match=message):
        OcclusionSpec(**kwargs)


def _arrays(simulation: Simulation) -> list[np.ndarray]:
    recording, truth = simulation.recording, simulation.truth
    return [recording.imu.accelerometer, recording.imu.gyroscope, recording.mocap.position,
            recording.mocap.quaternion, recording.info.imu_to_body, truth.position,
            truth.occluded]


def test_same_seed_same_simulation_other_seed_differs():
    first = simulate("random_reach", seed=11, duration=SHORT)
    again = simulate("random_reach", seed=11, duration=SHORT)
    other = simulate("random_reach", seed=12, duration=SHORT)
    for a, b in zip(_arrays(first), _arrays(again), strict=True):
        np.testing.assert_array_equal(a, b)
    assert not np.array_equal(first.truth.position, other.truth.position)
    assert not np.array_equal(first.recording.imu.accelerometer,
                              other.recording.imu.accelerometer)


def test_sensor_profiles_and_occlusions_do_not_change_the_trajectory():
    base = simulate("circle", seed=4, duration=SHORT)
    other = simulate("circle", seed=4, duration=SHORT, imu="um7",
                     occlusions=OcclusionSpec(placement="mid_motion", gap_range=(0.2, 0.5)))
    np.testing.assert_array_equal(base.truth.position, other.truth.position)
    np.testing.assert_array_equal(base.truth.imu_quaternion, other.truth.imu_quaternion)
    assert not np.array_equal(base.truth.occluded, other.truth.occluded)


def test_recording_metadata_and_clock(realistic):
    recording, truth = realistic.recording, realistic.truth
    info = recording.info
    np.testing.assert_array_equal(info.gravity, GRAVITY)
    np.testing.assert_array_equal(info.lever_arm, np.zeros(3))
    assert info.imu == "mpu9255"
    assert np.linalg.norm(info.imu_to_body) == pytest.approx(1.0)
    mount_angle = 2 * np.degrees(np.arccos(min(1.0, abs(info.imu_to_body[0]))))
    assert 60 < mount_angle < 120  # a real, non-identity mount
    assert recording.mocap.t[0] >= recording.imu.t[0]
    assert truth.t[-1] == pytest.approx(40.0) and recording.imu.t[-1] == pytest.approx(40.0)
    np.testing.assert_allclose(np.diff(recording.imu.t), 1 / 200, atol=1e-12)
    np.testing.assert_allclose(np.diff(recording.mocap.t), 1 / 100, atol=1e-12)
    np.testing.assert_array_equal(truth.t, recording.mocap.t)
    np.testing.assert_array_equal(truth.imu_t, recording.imu.t)
    assert not truth.position.flags.writeable
    with pytest.raises(dataclasses.FrozenInstanceError):
        truth.t = truth.t  # type: ignore[misc]


def test_occluded_rows_are_nan_and_the_rest_visible(realistic):
    mocap, truth = realistic.recording.mocap, realistic.truth
    np.testing.assert_array_equal(~mocap.visible, truth.occluded)
    assert truth.occluded.any()


def test_no_occlusions():
    simulation = simulate("pick_tool", seed=0, duration=SHORT, occlusions=None)
    assert simulation.recording.mocap.visible.all()
    assert not simulation.truth.occluded.any()


# --------------------------------------------------------------------------------------------
# Physics
# --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", SCENARIOS)
def test_error_free_imu_reads_exact_specific_force_and_rate(perfect, name):
    simulation = perfect[name]
    truth, imu = simulation.truth, simulation.recording.imu
    R_imu_global = np.transpose(matrix_from_wxyz(truth.imu_quaternion), (0, 2, 1))
    expected = specific_force(R_imu_global, truth.imu_acceleration, GRAVITY)
    np.testing.assert_allclose(imu.accelerometer, expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(imu.gyroscope, truth.imu_angular_rate, rtol=0, atol=1e-12)
    # and the IMU orientation is the mocap body's composed with the mount
    q_global_body = simulate(name, seed=3, imu=error_free_imu(), mocap=PERFECT_MOCAP,
                             duration=SHORT, mocap_rate=200.0, occlusions=None).truth.quaternion
    np.testing.assert_allclose(
        quaternion_multiply(q_global_body, simulation.recording.info.imu_to_body),
        truth.imu_quaternion, atol=1e-12)


@pytest.mark.parametrize("name", SCENARIOS)
def test_accelerometer_is_rotated_second_difference_of_position_minus_gravity(perfect, name):
    """(p(t+h) - 2 p(t) + p(t-h)) / h^2 = a(t) + e with |e| <= J h / 3 for jerk bounded by J
    (Taylor with integral remainder; the quintic splines are C2 with a piecewise-smooth jerk).

    The error must also shrink with h (at least halve when h halves: O(h) next to a jump of
    jerk, O(h^2) elsewhere); a wrong acceleration would leave an error that does not."""
    truth, imu = perfect[name].truth, perfect[name].recording.imu
    rms = []
    for step in (1, 2):
        position = truth.imu_position[::step]
        h = step * (truth.imu_t[1] - truth.imu_t[0])
        second_difference = (position[2:] - 2 * position[1:-1] + position[:-2]) / h**2
        R_global_imu = matrix_from_wxyz(truth.imu_quaternion[::step][1:-1])
        from_accelerometer = np.einsum("nij,nj->ni", R_global_imu,
                                       imu.accelerometer[::step][1:-1]) + GRAVITY
        acceleration = truth.imu_acceleration[::step]
        jerk = np.max(np.linalg.norm(np.diff(acceleration, axis=0), axis=1)) / h
        tolerance = 1.5 * jerk * h / 3  # 1.5: the sampled jerk underestimates its maximum
        error = np.linalg.norm(from_accelerometer - second_difference, axis=1)
        assert error.max() <= tolerance
        assert tolerance < 0.1 * np.linalg.norm(acceleration, axis=1).max()
        rms.append(np.sqrt(np.mean(error**2)))
    assert rms[0] < 0.5 * rms[1]


@pytest.mark.parametrize("name", SCENARIOS)
def test_gyroscope_is_the_rate_of_the_true_orientation(perfect, name):
    """Rotation vector of q_k^-1 q_{k+1}, divided by h, against the trapezoid mean of the rates.

    Over one step the rotation vector is ∫ω + ½∫∫ ω(s1) × ω(s2) + ... (Magnus), so the error is
    at most h^2/12 (max|ω''| + max|ω| max|ω'|) (trapezoid rule plus the commutator term).
    """
    truth, imu = perfect[name].truth, perfect[name].recording.imu
    h = truth.imu_t[1] - truth.imu_t[0]
    rotation = rotation_from_wxyz(truth.imu_quaternion)
    finite_difference = (rotation[:-1].inv() * rotation[1:]).as_rotvec() / h
    mean_rate = (imu.gyroscope[:-1] + imu.gyroscope[1:]) / 2
    rate = truth.imu_angular_rate
    first = np.linalg.norm(np.diff(rate, axis=0), axis=1).max() / h
    second = np.linalg.norm(np.diff(rate, 2, axis=0), axis=1).max() / h**2
    tolerance = 2 * h**2 / 12 * (second + np.linalg.norm(rate, axis=1).max() * first)
    error = np.linalg.norm(finite_difference - mean_rate, axis=1)
    assert error.max() <= tolerance
    assert np.linalg.norm(rate, axis=1).max() > 0.2  # every scenario rotates at least a little


def test_real_imu_residuals_have_the_datasheet_noise(realistic):
    """accelerometer - (M f + b) is white noise of std noise_density sqrt(rate), plus the
    quantisation's resolution^2 / 12 variance; same for the gyroscope."""
    truth, imu = realistic.truth, realistic.recording.imu
    rate = 1 / (imu.t[1] - imu.t[0])
    for measured, true, matrix, bias, density, resolution in (
        (imu.accelerometer, truth.imu_specific_force, truth.accelerometer_matrix,
         truth.accelerometer_bias, MPU9255.accelerometer_noise_density,
         MPU9255.accelerometer_resolution),
        (imu.gyroscope, truth.imu_angular_rate, truth.gyroscope_matrix, truth.gyroscope_bias,
         MPU9255.gyroscope_noise_density, MPU9255.gyroscope_resolution),
    ):
        residual = measured - (true @ matrix.T + bias)
        expected = np.sqrt((density * np.sqrt(rate)) ** 2 + resolution**2 / 12)
        np.testing.assert_allclose(residual.std(axis=0), expected, rtol=0.04)
        np.testing.assert_allclose(residual.mean(axis=0), 0, atol=4 * expected / np.sqrt(len(imu)))
        # white: lag-1 autocorrelation near 0 (std 1/sqrt(n) ~ 0.011)
        lag = np.mean(residual[1:] * residual[:-1], axis=0) / residual.var(axis=0)
        assert np.all(np.abs(lag) < 0.05)


def test_real_imu_errors_are_drawn_from_the_profile(realistic):
    truth = realistic.truth
    dt = truth.imu_t[1] - truth.imu_t[0]
    steps = np.diff(truth.accelerometer_bias, axis=0)
    np.testing.assert_allclose(steps.std(), MPU9255.accelerometer_bias_random_walk * np.sqrt(dt),
                               rtol=0.03)
    assert not np.allclose(truth.accelerometer_matrix, np.eye(3))
    # turn-on biases are ~20 mg and ~1.7 dps 1-sigma: within 5 sigma
    assert np.all(np.abs(truth.accelerometer_bias[0]) < 5 * MPU9255.accelerometer_turn_on_bias)
    assert np.all(np.abs(truth.gyroscope_bias[0]) < 5 * MPU9255.gyroscope_turn_on_bias)
    assert np.any(truth.gyroscope_bias[0] != 0)


def test_mocap_noise_matches_the_profile(realistic):
    recording, truth = realistic.recording, realistic.truth
    visible = recording.mocap.visible
    error = recording.mocap.position[visible] - truth.position[visible]
    np.testing.assert_allclose(error.std(axis=0), OPTITRACK.position_noise, rtol=0.06)
    relative = (rotation_from_wxyz(truth.quaternion[visible]).inv()
                * rotation_from_wxyz(recording.mocap.quaternion[visible])).as_rotvec()
    np.testing.assert_allclose(relative.std(axis=0), OPTITRACK.orientation_noise, rtol=0.06)


@pytest.mark.parametrize("name", SCENARIOS)
def test_motion_is_a_human_forearm(perfect, name):
    truth = perfect[name].truth
    speed = np.linalg.norm(truth.imu_velocity, axis=1)
    assert 0.5 < speed.max() < 2.6  # m/s
    assert np.linalg.norm(truth.imu_acceleration, axis=1).max() < 20.0  # m/s^2
    assert np.linalg.norm(truth.imu_angular_rate, axis=1).max() < 8.0  # rad/s
    assert speed[:200].max() == 0.0  # starts at rest (first second)
    assert speed[-100:].max() == 0.0  # ends at rest
    assert 0.0 < truth.position[:, 1].min() and truth.position[:, 1].max() < 2.0  # y-up room


def test_arm_lift_moves_up_and_down_along_y(perfect):
    truth = perfect["arm_lift"].truth
    extent = truth.position.max(axis=0) - truth.position.min(axis=0)
    assert 0.70 <= extent[1] <= 0.86  # strokes of 0.70-0.80 m, bottom varies by +-3 cm
    assert extent[0] < 0.1 and extent[2] < 0.1
    # the height turns round only at tops and bottoms a full stroke apart (no overshoot wiggle)
    moving = np.flatnonzero(truth.imu_velocity[:, 1] != 0)
    direction = np.sign(truth.imu_velocity[moving, 1])
    turns = moving[np.flatnonzero(direction[1:] != direction[:-1])]
    assert len(turns) >= 6
    assert np.abs(np.diff(truth.imu_position[turns, 1])).min() > 0.6


def test_circle_stays_near_a_circle_in_x_y(perfect):
    position = perfect["circle"].truth.position
    centre = (position.max(axis=0) + position.min(axis=0)) / 2
    radius = np.linalg.norm((position - centre)[:, :2], axis=1)
    moving = np.linalg.norm(np.gradient(position, axis=0), axis=1) > 0
    assert 0.18 < np.median(radius[moving]) < 0.42
    assert np.ptp(position[:, 2]) < 0.15


def test_pick_tool_reaches_the_floor_in_the_yz_plane(perfect):
    truth = perfect["pick_tool"].truth
    assert truth.position[:, 1].min() < 0.2 and truth.position[:, 1].max() > 0.8
    velocity = truth.imu_velocity
    fast = np.linalg.norm(velocity, axis=1) > 0.8
    assert fast.any()
    sideways = np.abs(velocity[fast, 0]).mean()
    assert sideways < 0.3 * np.linalg.norm(velocity[fast, 1:], axis=1).mean()


def test_random_reach_turns_the_forearm_a_lot(perfect):
    rotation = rotation_from_wxyz(perfect["random_reach"].truth.quaternion)
    turned = (rotation[0].inv() * rotation).magnitude()
    assert np.degrees(turned.max()) > 90


# --------------------------------------------------------------------------------------------
# Occlusions
# --------------------------------------------------------------------------------------------


def _gap_speeds(simulation: Simulation) -> np.ndarray:
    truth = simulation.truth
    frame_speed = np.linalg.norm(np.gradient(truth.position, truth.t, axis=0), axis=1)
    return np.array([frame_speed[start:stop].mean()
                     for start, stop in occlusion_runs(~truth.occluded)])


@pytest.mark.parametrize("name", SCENARIOS)
@pytest.mark.parametrize("placement", ["random", "mid_motion", "direction_change"])
def test_gaps_have_the_requested_length_and_spacing(name, placement):
    spec = OcclusionSpec(gap_range=(0.1, 0.3), placement=placement, spacing=1.5)
    simulation = simulate(name, seed=2, occlusions=spec)
    t, occluded = simulation.truth.t, simulation.truth.occluded
    durations = occlusion_durations(t, ~occluded)
    assert len(durations) >= 3
    assert durations.min() >= 0.1 - 1e-9 and durations.max() <= 0.3 + 1e-9
    previous_end = t[0]
    for start, stop in occlusion_runs(~occluded):
        assert t[start - 1] - previous_end >= 1.5 - 1e-9
        previous_end = t[stop]
    assert t[-1] - previous_end >= 1.5 - 1e-9


def test_gap_lengths_fill_the_range():
    spec = OcclusionSpec(gap_range=(0.3, 1.0), spacing=1.0)
    durations = occlusion_durations(*(lambda tr: (tr.t, ~tr.occluded))(
        simulate("circle", seed=0, duration=60.0, occlusions=spec).truth))
    assert durations.min() < 0.45 and durations.max() > 0.85


def test_type_1_gaps_are_faster_than_type_2_gaps():
    type_1 = simulate("arm_lift", seed=7, occlusions=OcclusionSpec(placement="mid_motion"))
    type_2 = simulate("arm_lift", seed=7, occlusions=OcclusionSpec(placement="direction_change"))
    speeds_1, speeds_2 = _gap_speeds(type_1), _gap_speeds(type_2)
    assert speeds_1.mean() > 3 * speeds_2.mean()
    assert speeds_1.min() > 0.4  # m/s: mid-motion means moving
    # each Type 2 gap straddles a change of direction: vertical velocity flips inside it
    truth = type_2.truth
    vertical = np.gradient(truth.position[:, 1], truth.t)
    for start, stop in occlusion_runs(~truth.occluded):
        assert vertical[start - 1] * vertical[stop] < 0


def test_count_places_exactly_that_many_gaps_or_says_why_not():
    for placement in ("random", "mid_motion"):
        simulation = simulate("arm_lift", seed=1, duration=SHORT,
                              occlusions=OcclusionSpec(placement=placement, count=2))
        assert len(occlusion_runs(~simulation.truth.occluded)) == 2
    with pytest.raises(ValueError, match="500 gaps requested but only"):
        simulate("pick_tool", seed=1, duration=SHORT, occlusions=OcclusionSpec(count=500))


def test_no_room_for_a_gap_is_a_value_error():
    with pytest.raises(ValueError, match="no occlusion fits"):
        simulate("circle", seed=0, duration=6.0, occlusions=OcclusionSpec(spacing=10.0))


# --------------------------------------------------------------------------------------------
# Files and CLI
# --------------------------------------------------------------------------------------------


def test_written_simulation_reads_back(tmp_path, realistic):
    folder = write_simulation(realistic, tmp_path / "sim")
    recording = read_recording(folder)
    np.testing.assert_array_equal(recording.imu.accelerometer,
                                  realistic.recording.imu.accelerometer)
    np.testing.assert_array_equal(recording.mocap.position, realistic.recording.mocap.position)
    np.testing.assert_array_equal(recording.info.imu_to_body,
                                  realistic.recording.info.imu_to_body)
    truth = read_truth(folder)
    np.testing.assert_array_equal(truth.t, realistic.truth.t)
    np.testing.assert_array_equal(truth.position, realistic.truth.position)
    np.testing.assert_array_equal(truth.occluded, realistic.truth.occluded)
    assert truth.imu_t is None and truth.quaternion is None
    header = (folder / "truth.csv").read_text().splitlines()[0]
    assert header == "t,x,y,z,occluded"


def test_read_truth_reports_a_bad_file(tmp_path):
    (tmp_path / "truth.csv").write_text("t,x,y,z,occluded\n0.0,1,2,3,2\n")
    with pytest.raises(ValueError, match=r"truth.csv, row 1 .*column 'occluded': expected 0 or 1"):
        read_truth(tmp_path)
    with pytest.raises(ValueError, match="truth.csv: file not found"):
        read_truth(tmp_path / "missing")


def test_cli_writes_a_recording_and_truth(tmp_path, capsys):
    out = tmp_path / "lift"
    status = main(["simulate", "arm_lift", "--seed", "1", "--out", str(out),
                   "--placement", "direction_change", "--gap-min", "0.15", "--gap-max", "0.25",
                   "--duration", "25"])
    printed = capsys.readouterr().out
    assert status == 0
    assert printed.count("\n") == 1 and printed.startswith(f"wrote {out}")
    recording = read_recording(out)
    truth = read_truth(out)
    assert recording.imu.t[-1] == pytest.approx(25.0)
    durations = occlusion_durations(truth.t, ~truth.occluded)
    assert durations.min() >= 0.15 - 1e-9 and durations.max() <= 0.25 + 1e-9
    np.testing.assert_array_equal(~recording.mocap.visible, truth.occluded)


def test_cli_help_and_unknown_scenario(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["simulate", "--help"])
    assert exit_info.value.code == 0
    assert "arm_lift, circle, pick_tool, random_reach" in " ".join(capsys.readouterr().out.split())
    status = main(["simulate", "arm_raise", "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1
    assert "unknown scenario 'arm_raise'" in err and "random_reach" in err
