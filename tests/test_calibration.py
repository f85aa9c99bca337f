"""Offline calibrations (kfusion.calibration): Kabsch, IMU -> body rotation, gain K."""

from __future__ import annotations

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation, Slerp

from kfusion.baseline import BaselineParameters
from kfusion.calibration import (
    angles_between,
    calibrate_gain,
    calibrate_imu_to_body,
    kabsch,
    still_periods,
)
from kfusion.cli import main
from kfusion.conventions import matrix_from_wxyz, rotation_from_wxyz, specific_force
from kfusion.recording import (
    ImuSamples,
    MocapFrames,
    Recording,
    RecordingInfo,
    read_info,
    write_recording,
)
from kfusion.simulate import simulate

GRAVITY = np.array([0.0, -9.81, 0.0])
Q_BODY_IMU = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm([0.9, 0.1, -0.3, 0.2])


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(R_a.T @ R_b).magnitude()))


def test_kabsch_recovers_a_known_rotation_from_noisy_pairs():
    rng = np.random.default_rng(11)
    R_true = Rotation.from_rotvec([0.4, -1.1, 0.7]).as_matrix()
    b = rng.normal(size=(200, 3))
    a = b @ R_true.T + rng.normal(0, 0.01, size=(200, 3))
    R = kabsch(a, b)
    assert np.linalg.det(R) == pytest.approx(1.0)
    # 0.01 noise on unit-size vectors: the angle error is about 0.01 / sqrt(200) rad ~ 0.04 deg
    assert rotation_angle_deg(R, R_true) < 0.2
    # exact pairs give the rotation to rounding
    np.testing.assert_allclose(kabsch(b @ R_true.T, b), R_true, atol=1e-12)


def test_kabsch_never_returns_a_reflection_and_honours_weights():
    b = np.eye(3)
    reflected = b @ np.diag([1.0, 1.0, -1.0])  # best orthogonal fit is a reflection
    R = kabsch(reflected, b)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    # an outlier with zero weight has no influence
    rng = np.random.default_rng(2)
    R_true = Rotation.from_rotvec([0.0, 0.3, 0.0]).as_matrix()
    b = rng.normal(size=(10, 3))
    a = b @ R_true.T
    a[0] = [5.0, -5.0, 5.0]
    weights = np.ones(10)
    weights[0] = 0.0
    np.testing.assert_allclose(kabsch(a, b, weights), R_true, atol=1e-12)
    assert rotation_angle_deg(kabsch(a, b), R_true) > 1.0


def test_kabsch_rejects_bad_input():
    with pytest.raises(ValueError, match=r"expected two arrays of shape \(n, 3\), got \(4, 3\) "
                                         r"and \(4, 2\)"):
        kabsch(np.ones((4, 3)), np.ones((4, 2)))
    with pytest.raises(ValueError, match="expected at least 2 vector pairs, got 1"):
        kabsch(np.ones((1, 3)), np.ones((1, 3)))
    with pytest.raises(ValueError, match="non-negative finite weights"):
        kabsch(np.eye(3), np.eye(3), [1.0, -1.0, 1.0])


def posed_recording(keys: list[tuple[float, np.ndarray]], *, bias: np.ndarray | None = None,
                    noise: float = 0.0, seed: int = 0) -> Recording:
    """Limb at a fixed position, turning between key orientations q_global_body (slerp, constant
    rate) and resting at each; IMU (200 Hz) reads exact specific force and rate (+ bias, noise),
    mocap at 100 Hz."""
    times = np.array([k[0] for k in keys])
    slerp = Slerp(times, rotation_from_wxyz(np.array([k[1] for k in keys])))
    imu_t = np.arange(round(times[-1] * 200) + 1) / 200
    R_body_imu = matrix_from_wxyz(Q_BODY_IMU)
    R_global_imu = slerp(imu_t).as_matrix() @ R_body_imu
    accelerometer = specific_force(np.transpose(R_global_imu, (0, 2, 1)), np.zeros(3), GRAVITY)
    h = 1e-6
    later = slerp(np.minimum(imu_t + h, times[-1]))
    rate_body = (slerp(imu_t).inv() * later).as_rotvec() / h
    gyroscope = rate_body @ R_body_imu  # R_imu_body @ w_body, row-wise
    rng = np.random.default_rng(seed)
    if bias is not None:
        accelerometer = accelerometer + bias
    accelerometer = accelerometer + rng.normal(0, noise, accelerometer.shape)
    mocap_t = imu_t[::2]
    quaternion = slerp(mocap_t).as_quat(scalar_first=True)
    position = np.tile([0.3, 1.1, -0.2], (len(mocap_t), 1))
    return Recording(ImuSamples(imu_t, accelerometer, gyroscope),
                     MocapFrames(mocap_t, position, quaternion),
                     RecordingInfo(imu_to_body=[1, 0, 0, 0], gravity=GRAVITY))


def quaternion_about(axis: list[float], degrees: float) -> np.ndarray:
    return Rotation.from_rotvec(np.radians(degrees) * np.asarray(axis, float)).as_quat(
        scalar_first=True)


POSES = [quaternion_about([1, 0, 0], 0), quaternion_about([1, 0, 0], 90),
         quaternion_about([0, 0, 1], 90), quaternion_about([0, 1, 0], 60)]


def keys_for(poses: list[np.ndarray], rest: float = 1.0, turn: float = 0.6
             ) -> list[tuple[float, np.ndarray]]:
    keys, t = [], 0.0
    for pose in poses:
        keys.append((t, pose))
        t += rest
        keys.append((t, pose))
        t += turn
    return keys


def test_imu_to_body_from_exact_still_poses():
    recording = posed_recording(keys_for(POSES))
    assert len(still_periods(recording)) == 4
    result = calibrate_imu_to_body(recording)
    assert result.poses == 4
    assert result.residual_deg < 1e-6
    assert rotation_angle_deg(matrix_from_wxyz(result.imu_to_body),
                              matrix_from_wxyz(Q_BODY_IMU)) < 1e-6
    assert result.spread_deg == pytest.approx(90.0, abs=1e-6)


def test_imu_to_body_with_offset_and_noise_is_within_the_offset_angle():
    bias = np.array([0.15, -0.1, 0.2])  # 0.27 m/s^2: at most 1.6 deg on one gravity pair
    recording = posed_recording(keys_for(POSES), bias=bias, noise=0.03, seed=5)
    result = calibrate_imu_to_body(recording)
    bound = np.degrees(np.arcsin(np.linalg.norm(bias) / 9.81))
    error = rotation_angle_deg(matrix_from_wxyz(result.imu_to_body), matrix_from_wxyz(Q_BODY_IMU))
    assert error < bound
    assert 0.1 < result.residual_deg < bound


def test_imu_to_body_needs_distinct_poses_unless_rates_are_used():
    # every rest has the same gravity direction in the body: turns about the vertical (global
    # y), and a 45 deg nod about the horizontal x axis without a rest
    identity, nod = POSES[0], quaternion_about([1, 0, 0], 45)
    turned = quaternion_about([0, 1, 0], 90)
    keys = [(0.0, identity), (1.0, identity), (1.4, nod), (1.8, identity), (2.8, identity),
            (3.4, turned), (4.4, turned)]
    recording = posed_recording(keys)
    with pytest.raises(ValueError, match=r"span at least 20 deg, found 3 pose\(s\) spanning "):
        calibrate_imu_to_body(recording)
    result = calibrate_imu_to_body(recording, use_angular_rate=True)
    assert result.rate_pairs > 50
    assert rotation_angle_deg(matrix_from_wxyz(result.imu_to_body),
                              matrix_from_wxyz(Q_BODY_IMU)) < 0.1


def test_gain_is_the_inverse_of_the_accelerometer_scale():
    """f = 1.05 R_imu_global (a - g) + bias: K = 1 / 1.05, hand-derived."""
    t = np.arange(0, 6.0, 0.005)
    omega = 2 * np.pi * 0.7
    amplitude = np.array([0.1, 0.25, 0.05])
    acceleration = -omega**2 * np.outer(np.sin(omega * t), amplitude)
    R_global_body = Rotation.from_rotvec([0.2, 0.5, -0.1]).as_matrix()
    R_imu_global = (R_global_body @ matrix_from_wxyz(Q_BODY_IMU)).T
    accelerometer = 1.05 * specific_force(R_imu_global, acceleration, GRAVITY) + [0.1, 0.2, -0.1]
    mocap_t = t[::2]
    position = np.outer(np.sin(omega * mocap_t), amplitude) + [0, 1, 0]
    quaternion = np.tile(Rotation.from_matrix(R_global_body).as_quat(scalar_first=True),
                         (len(mocap_t), 1))
    position[300:320] = np.nan  # an occlusion splits the visible stretches
    quaternion[300:320] = np.nan
    recording = Recording(ImuSamples(t, accelerometer, np.zeros_like(accelerometer)),
                          MocapFrames(mocap_t, position, quaternion),
                          RecordingInfo(imu_to_body=Q_BODY_IMU, gravity=GRAVITY))
    result = calibrate_gain(recording, window_s=1.0)
    assert result.gain == pytest.approx(1 / 1.05, rel=2e-3)
    assert result.windows == 4  # stretches of 3.0 s and 2.8 s
    with pytest.raises(ValueError, match="expected visible mocap stretches of at least 10 s"):
        calibrate_gain(recording, window_s=10.0)


def test_angles_between():
    np.testing.assert_allclose(angles_between([[1, 0, 0], [1, 1, 0]], [[0, 2, 0], [1, 0, 0]]),
                               [90.0, 45.0])


def test_imu_to_body_on_a_simulated_recording():
    """The simulated pick-tool scenario holds still poses at the bench and at the floor. The
    MPU9255's accelerometer offset (20 mg = 0.2 m/s^2 per axis, 1 sigma) tilts each gravity pair
    by about 1-2 deg, so the mount is recovered to within 3 deg, not exactly."""
    simulation = simulate("pick_tool", seed=1, imu="mpu9255", occlusions=None, duration=20.0)
    result = calibrate_imu_to_body(simulation.recording)
    truth = matrix_from_wxyz(simulation.recording.info.imu_to_body)
    error = rotation_angle_deg(matrix_from_wxyz(result.imu_to_body), truth)
    assert result.poses >= 3
    assert error < 3.0
    # the nominal mount is -90 deg about the forearm: an identity guess would be far off
    assert rotation_angle_deg(np.eye(3), truth) > 60


def test_calibrate_command_writes_recording_yaml_and_gain(tmp_path, capsys):
    simulation = simulate("pick_tool", seed=1, imu="mpu9255", occlusions=None, duration=20.0)
    folder = write_recording(simulation.recording, tmp_path / "recording")
    out, gain_out = tmp_path / "calibrated.yaml", tmp_path / "gain.yaml"
    assert main(["calibrate", str(folder), "--paper", "--out", str(out), "--gain-out",
                 str(gain_out)]) == 0
    assert "baseline gain K" in capsys.readouterr().out
    info = read_info(out)
    expected = calibrate_imu_to_body(simulation.recording).imu_to_body
    np.testing.assert_allclose(info.imu_to_body, expected)
    np.testing.assert_array_equal(info.gravity, simulation.recording.info.gravity)

    params = BaselineParameters.from_mapping(yaml.safe_load(gain_out.read_text()))
    assert params.gain == pytest.approx(calibrate_gain(simulation.recording, expected).gain,
                                        abs=1e-6)
    # existing output is not overwritten without --force
    assert main(["calibrate", str(folder), "--out", str(out)]) == 2
    assert "pass --force" in capsys.readouterr().err
    # without recording.yaml, gravity comes from --gravity
    (folder / "recording.yaml").unlink()
    assert main(["calibrate", str(folder), "--paper", "--gravity", "0", "-9.81", "0"]) == 0
