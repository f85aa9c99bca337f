"""The paper's baseline tracker (kfusion.baseline) against hand-derived values."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd
import pytest

from kfusion.baseline import (
    OFFSET_ADAPTED,
    OFFSET_HELD_ACCELERATION,
    OFFSET_HELD_OCCLUSION,
    OFFSET_INITIALISED,
    BaselineParameters,
    BaselineTracker,
    adapt_offset,
    dead_reckon,
    design_matrix,
    expected_acceleration,
    fit_cubic,
    fit_velocity,
    imu_acceleration,
    measured_offset,
    offset_action,
    track_recording,
)
from kfusion.cli import main
from kfusion.conventions import (
    BRIDGED,
    LOST,
    TRACKED,
    matrix_from_wxyz,
    quaternion_multiply,
    specific_force,
)
from kfusion.methods import track_with_method
from kfusion.recording import ImuSamples, MocapFrames, Recording, RecordingInfo

GRAVITY = np.array([0.0, -9.81, 0.0])
MOCAP_RATE = 100.0
IMU_RATE = 200.0

Vector = Callable[[np.ndarray], np.ndarray]


def unit(quaternion: list[float]) -> np.ndarray:
    array = np.asarray(quaternion, dtype=float)
    return array / np.linalg.norm(array)


Q_BODY_IMU = unit([0.9, 0.1, -0.3, 0.2])
Q_GLOBAL_BODY = unit([0.8, -0.2, 0.1, 0.4])


def synthetic_recording(position: Vector, acceleration: Vector, *, duration: float = 4.0,
                        bias: np.ndarray | None = None, hidden: tuple[float, float] | None = None,
                        rate_body: np.ndarray | None = None) -> Recording:
    """Noise-free recording: mocap at 100 Hz and IMU at 200 Hz on one clock (every mocap time is
    also an IMU time). The body turns at the constant body-frame rate ``rate_body`` (rad/s) from
    ``Q_GLOBAL_BODY``; the IMU reads exact specific force plus ``bias`` (IMU frame)."""
    imu_t = np.arange(round(duration * IMU_RATE)) / IMU_RATE
    mocap_t = imu_t[::2]
    rate_body = np.zeros(3) if rate_body is None else np.asarray(rate_body, dtype=float)

    def q_global_body(t: np.ndarray) -> np.ndarray:
        angle = np.linalg.norm(rate_body) * t
        axis = rate_body / max(np.linalg.norm(rate_body), 1e-300)
        increment = np.column_stack([np.cos(angle / 2), np.sin(angle / 2)[:, None] * axis])
        return quaternion_multiply(Q_GLOBAL_BODY, increment)

    R_global_imu = matrix_from_wxyz(q_global_body(imu_t)) @ matrix_from_wxyz(Q_BODY_IMU)
    accelerometer = specific_force(np.transpose(R_global_imu, (0, 2, 1)),
                                   acceleration(imu_t), GRAVITY)
    if bias is not None:
        accelerometer = accelerometer + bias
    gyroscope = np.tile(matrix_from_wxyz(Q_BODY_IMU).T @ rate_body, (len(imu_t), 1))
    mocap_position = position(mocap_t)
    quaternion = q_global_body(mocap_t)
    if hidden is not None:
        inside = (mocap_t > hidden[0]) & (mocap_t < hidden[1])
        mocap_position[inside] = np.nan
        quaternion[inside] = np.nan
    return Recording(imu=ImuSamples(imu_t, accelerometer, gyroscope),
                     mocap=MocapFrames(mocap_t, mocap_position, quaternion),
                     info=RecordingInfo(imu_to_body=Q_BODY_IMU, gravity=GRAVITY))


def constant_acceleration(p0: list[float], v0: list[float], a: list[float]
                          ) -> tuple[Vector, Vector]:
    p0_, v0_, a_ = (np.asarray(x, dtype=float) for x in (p0, v0, a))
    return (lambda t: p0_ + np.outer(t, v0_) + 0.5 * np.outer(t**2, a_),
            lambda t: np.tile(a_, (len(t), 1)))


def stationary(p0: list[float]) -> tuple[Vector, Vector]:
    return constant_acceleration(p0, [0, 0, 0], [0, 0, 0])


# ---- eqs. 1-5: the fits -----------------------------------------------------------------------


def test_cubic_fit_returns_velocity_acceleration_and_jerk_exactly():
    period, n = 0.01, 20
    v0, a0, jerk = np.array([0.3, -0.2, 0.1]), np.array([1.5, 0.4, -2.0]), np.array([-8, 3, 5.0])
    elapsed = np.arange(n + 1) * period
    positions = (np.array([0.1, 1.2, -0.4]) + np.outer(elapsed, v0) + np.outer(elapsed**2, a0) / 2
                 + np.outer(elapsed**3, jerk) / 6)
    pseudo_inverse = np.linalg.pinv(design_matrix(n, period))
    fitted = fit_cubic(positions, pseudo_inverse)
    for value, expected in zip(fitted, (v0, a0, jerk), strict=True):
        np.testing.assert_allclose(value, expected, rtol=1e-7, atol=1e-9)
    # eq. 2 at the end of the buffer: a(t) = a0 + jerk N Ta
    np.testing.assert_allclose(expected_acceleration(fitted[1], fitted[2], n * period),
                               a0 + jerk * 0.2, rtol=1e-7)


def test_design_matrix_rows_follow_eq_4():
    X = design_matrix(3, 0.5)
    np.testing.assert_allclose(X, [[0.5, 0.125, 0.125 / 6], [1.0, 0.5, 1 / 6],
                                   [1.5, 1.125, 3.375 / 6]])
    with pytest.raises(ValueError, match="expected points >= 1 and period > 0"):
        design_matrix(3, 0.0)


def test_velocity_fit_is_exact_at_constant_velocity_and_lags_under_acceleration():
    period, nv = 0.01, 5
    elapsed = np.arange(nv + 1) * period
    v = np.array([0.4, -1.0, 0.2])
    np.testing.assert_allclose(fit_velocity(np.outer(elapsed, v) + 3.0, period), v, rtol=1e-12)
    # under acceleration a, slope = v_k + a Ta sum(i^3) / (2 sum(i^2)) = v_k + a Ta 225 / 110
    a = np.array([2.0, 0.0, -1.0])
    positions = np.outer(elapsed, v) + 0.5 * np.outer(elapsed**2, a)
    np.testing.assert_allclose(fit_velocity(positions, period), v + a * period * 225 / 110,
                               rtol=1e-12)


# ---- eqs. 6-9 as pure functions -------------------------------------------------------------


def test_offset_equations_6_and_7():
    R = matrix_from_wxyz(Q_GLOBAL_BODY).T
    reading, acceleration = np.array([0.5, 9.0, 1.0]), np.array([1.0, 2.0, 3.0])
    np.testing.assert_allclose(measured_offset(reading, R, acceleration),
                               reading - R @ acceleration)
    np.testing.assert_allclose(adapt_offset([1.0, 0.0, 0.0], [2.0, 1.0, -1.0], 0.01),
                               [1.01, 0.01, -0.01])


def test_imu_acceleration_and_dead_reckoning_equations_8_and_9():
    R = matrix_from_wxyz(Q_GLOBAL_BODY)
    np.testing.assert_allclose(imu_acceleration(0.9, R, [1.0, 2.0, 3.0], [0.5, 0.5, 0.5]),
                               0.9 * R @ np.array([0.5, 1.5, 2.5]))
    # constant acceleration over irregular steps is exact: p0 + v0 T + a T^2 / 2
    rng = np.random.default_rng(4)
    p0, v0, a = np.array([1.0, 2.0, 3.0]), np.array([0.5, -0.2, 0.1]), np.array([0.3, -9.0, 2.0])
    position, velocity = p0.copy(), v0.copy()
    steps = rng.uniform(0.001, 0.02, size=50)
    for dt in steps:
        position, velocity = dead_reckon(position, velocity, a, dt)
    total = steps.sum()
    np.testing.assert_allclose(position, p0 + v0 * total + 0.5 * a * total**2, rtol=1e-12)
    np.testing.assert_allclose(velocity, v0 + a * total, rtol=1e-12)


def test_offset_branches_of_algorithm_1():
    kwargs = {"expected_magnitude": 5.0, "threshold": 2.0}
    assert offset_action(first=True, buffer_occluded=True, **kwargs) == OFFSET_HELD_OCCLUSION
    assert offset_action(first=True, buffer_occluded=False, **kwargs) == OFFSET_INITIALISED
    assert offset_action(first=False, buffer_occluded=False, **kwargs) == OFFSET_HELD_ACCELERATION
    assert offset_action(first=False, buffer_occluded=False, expected_magnitude=1.0,
                         threshold=2.0) == OFFSET_ADAPTED


def test_folded_gravity_error_after_a_rotation_is_2g_sin_half_angle():
    """Documented behaviour: the gravity held in the IMU-frame offset does not rotate, so a turn
    by theta about a horizontal axis leaves 2 |g| sin(theta / 2); about the vertical, nothing."""
    theta = np.deg2rad(10.0)
    R_before = matrix_from_wxyz(Q_GLOBAL_BODY) @ matrix_from_wxyz(Q_BODY_IMU)  # R_global_imu
    offset = measured_offset(specific_force(R_before.T, np.zeros(3), GRAVITY), R_before.T,
                             np.zeros(3))
    for axis, expected in (([1.0, 0.0, 0.0], 2 * 9.81 * np.sin(theta / 2)),
                           ([0.0, 1.0, 0.0], 0.0)):
        turn = matrix_from_wxyz([np.cos(theta / 2), *(np.sin(theta / 2) * np.array(axis))])
        R_after = turn @ R_before  # turned about a global axis
        at_rest_after = specific_force(R_after.T, np.zeros(3), GRAVITY)
        error = imu_acceleration(1.0, R_after, at_rest_after, offset)
        assert np.linalg.norm(error) == pytest.approx(expected, rel=1e-12, abs=1e-12)


# ---- the tracker ------------------------------------------------------------------------------


def test_stationary_imu_with_constant_offset_learns_that_offset():
    bias = np.array([0.15, -0.1, 0.25])
    recording = synthetic_recording(*stationary([0.2, 1.0, -0.5]), bias=bias, duration=2.0)
    tracker = BaselineTracker.from_recording(recording)
    for t, accelerometer, gyroscope in zip(recording.imu.t, recording.imu.accelerometer,
                                           recording.imu.gyroscope, strict=True):
        tracker.push_imu(t, accelerometer, gyroscope)
        if round(t * IMU_RATE) % 2 == 0:
            index = round(t * MOCAP_RATE)
            tracker.push_mocap(t, recording.mocap.position[index],
                               recording.mocap.quaternion[index])
    # at rest: offset = a_read = bias - R_imu_global g  (eq. 6 with a(t) = 0)
    R_imu_global = (matrix_from_wxyz(Q_GLOBAL_BODY) @ matrix_from_wxyz(Q_BODY_IMU)).T
    np.testing.assert_allclose(tracker.offset, bias - R_imu_global @ GRAVITY, atol=1e-9)
    frames = 2.0 * MOCAP_RATE
    actions = tracker.offset_actions
    assert actions[OFFSET_INITIALISED] == 1
    assert actions[OFFSET_ADAPTED] == frames - 21  # every frame after the first full buffer


def run_stream(recording: Recording, params: BaselineParameters | None = None,
               mocap_first: bool = False) -> tuple[BaselineTracker, np.ndarray, list[str]]:
    """Manual streaming loop; ``mocap_first`` feeds a mocap frame before the IMU sample with the
    same time (the batch runner does the opposite)."""
    tracker = BaselineTracker.from_recording(recording, params)
    imu, mocap = recording.imu, recording.mocap
    positions, statuses = [], []
    j = 0
    for i in range(len(imu)):
        while j < len(mocap) and (mocap.t[j] < imu.t[i]
                                  or (mocap_first and mocap.t[j] == imu.t[i])):
            output = tracker.push_mocap(mocap.t[j], mocap.position[j], mocap.quaternion[j])
            positions.append(output.position)
            statuses.append(output.status)
            j += 1
        tracker.push_imu(imu.t[i], imu.accelerometer[i], imu.gyroscope[i])
    while j < len(mocap):
        output = tracker.push_mocap(mocap.t[j], mocap.position[j], mocap.quaternion[j])
        positions.append(output.position)
        statuses.append(output.status)
        j += 1
    return tracker, np.array(positions), statuses


def test_offset_adapts_at_rate_0_01_then_holds_during_high_acceleration():
    """A step in the accelerometer reading is followed as offset_k = old + step (1 - 0.99^k)."""
    step = np.array([0.0, 0.2, 0.0])
    base = synthetic_recording(*stationary([0.0, 1.0, 0.0]), duration=2.0)
    accelerometer = base.imu.accelerometer.copy()
    accelerometer[base.imu.t >= 1.0] += step
    recording = Recording(ImuSamples(base.imu.t, accelerometer, base.imu.gyroscope), base.mocap,
                          base.info)
    tracker, _, _ = run_stream(recording)
    k = round((recording.mocap.t[-1] - 1.0) * MOCAP_RATE) + 1  # fits using the new reading
    np.testing.assert_allclose(tracker.offset, accelerometer[0] + step * (1 - 0.99**k),
                               atol=1e-9)

    # the same step while accelerating at 3 m/s^2 > threshold: the first offset stays
    hard = synthetic_recording(*constant_acceleration([0, 1, 0], [0, 0, 0], [3.0, 0, 0]),
                               duration=2.0)
    accelerometer = hard.imu.accelerometer.copy()
    accelerometer[hard.imu.t >= 1.0] += step
    hard = Recording(ImuSamples(hard.imu.t, accelerometer, hard.imu.gyroscope), hard.mocap,
                     hard.info)
    tracker, _, _ = run_stream(hard)
    R_imu_global = (matrix_from_wxyz(Q_GLOBAL_BODY) @ matrix_from_wxyz(Q_BODY_IMU)).T
    # first fit at t = 0.2 s: offset = a_read - R_imu_global a (eq. 6) = -R_imu_global g
    np.testing.assert_allclose(tracker.offset, -R_imu_global @ GRAVITY, atol=1e-8)
    assert tracker.offset_actions[OFFSET_HELD_ACCELERATION] == 200 - 21
    assert tracker.offset_actions[OFFSET_ADAPTED] == 0
    # a lower threshold-free setting adapts instead
    relaxed = BaselineParameters(acceleration_threshold=10.0)
    tracker, _, _ = run_stream(hard, relaxed)
    assert tracker.offset_actions[OFFSET_ADAPTED] == 200 - 21


def test_offset_is_held_while_occlusions_are_in_the_last_n_measures():
    recording = synthetic_recording(*stationary([0.0, 1.0, 0.0]), duration=2.0,
                                    hidden=(0.995, 1.095))  # frames 100..109 hidden
    tracker, _, _ = run_stream(recording)
    actions = tracker.offset_actions
    hidden = int((~recording.mocap.visible).sum())
    assert hidden == 10
    # occluded frames + the N = 20 visible frames whose buffer still holds one
    assert actions[OFFSET_HELD_OCCLUSION] == hidden + 20
    # fits are possible from frame 20 (the first full buffer of 21) to frame 199
    assert actions[OFFSET_INITIALISED] + actions[OFFSET_ADAPTED] == 180 - hidden - 20


def test_bridging_is_exact_under_constant_acceleration():
    """Gap from 1.0 s: p = p_fix + v5 tau + a tau^2 / 2, with eq. 5's (lagging) velocity v5."""
    a = np.array([0.6, -1.2, 0.4])  # |a| < threshold, so the offset also adapts
    v0 = np.array([0.2, 0.1, -0.3])
    position, acceleration = constant_acceleration([0.1, 1.0, 0.3], list(v0), list(a))
    recording = synthetic_recording(position, acceleration, duration=1.5,
                                    bias=np.array([0.05, 0.1, -0.2]), hidden=(1.0, 1.3))
    result = track_recording(recording)
    t = recording.mocap.t
    fix = int(np.flatnonzero(recording.mocap.visible & (t <= 1.0))[-1])
    nv, period = 5, 0.01
    v5 = v0 + a * (t[fix] - nv * period) + a * period * 225 / 110
    gap = ~recording.mocap.visible
    tau = t[gap] - t[fix]
    expected = position(t[[fix]]) + np.outer(tau, v5) + 0.5 * np.outer(tau**2, a)
    np.testing.assert_allclose(result.position[gap], expected, atol=1e-9)
    assert set(result.status[gap]) == {BRIDGED}
    np.testing.assert_allclose(result.time_since_fix[gap], tau, atol=1e-12)


def test_streaming_equals_batch_for_either_order_of_simultaneous_events():
    def position(t: np.ndarray) -> np.ndarray:
        return np.column_stack([0.2 * np.sin(3 * t), 1 + 0.3 * np.sin(2 * t), 0.1 * t])

    def acceleration(t: np.ndarray) -> np.ndarray:
        return np.column_stack([-1.8 * np.sin(3 * t), -1.2 * np.sin(2 * t), 0 * t])

    base = synthetic_recording(position, acceleration, duration=3.0, hidden=(1.0, 1.25),
                               bias=np.array([0.1, 0.0, -0.1]),
                               rate_body=np.array([0.3, -0.5, 0.8]))
    rng = np.random.default_rng(7)
    noisy = Recording(
        ImuSamples(base.imu.t, base.imu.accelerometer + rng.normal(0, 0.05, (len(base.imu), 3)),
                   base.imu.gyroscope + rng.normal(0, 0.01, (len(base.imu), 3))),
        MocapFrames(base.mocap.t, base.mocap.position + rng.normal(0, 3e-4, (len(base.mocap), 3)),
                    base.mocap.quaternion),
        base.info)
    batch = track_recording(noisy)
    _, stream_positions, stream_statuses = run_stream(noisy, mocap_first=True)
    np.testing.assert_array_equal(batch.status, stream_statuses)
    np.testing.assert_allclose(batch.position, stream_positions, rtol=0, atol=1e-12)
    gap = ~noisy.mocap.visible
    assert set(batch.status[gap]) == {BRIDGED}
    # and the gyroscope is used: without it the rotating body's gap estimate changes
    still = Recording(ImuSamples(noisy.imu.t, noisy.imu.accelerometer,
                                 np.zeros_like(noisy.imu.gyroscope)), noisy.mocap, noisy.info)
    assert np.abs(track_recording(still).position[gap] - batch.position[gap]).max() > 1e-4


def test_status_lost_before_first_fit_and_past_the_bridging_horizon():
    recording = synthetic_recording(*stationary([0.0, 1.0, 0.0]), duration=3.0,
                                    hidden=(0.1, 0.2))  # before the first full buffer
    hidden_late = recording.mocap.visible & (recording.mocap.t > 1.0) & (recording.mocap.t < 1.8)
    mocap = recording.mocap
    position = np.where(hidden_late[:, None], np.nan, mocap.position)
    quaternion = np.where(hidden_late[:, None], np.nan, mocap.quaternion)
    recording = recording.with_mocap(MocapFrames(mocap.t, position, quaternion))
    result = track_recording(recording, max_bridge_s=0.5)
    t = result.t
    early = (t > 0.1) & (t < 0.2)
    assert set(result.status[early]) == {LOST}
    assert np.isnan(result.position[early]).all()
    assert set(result.status[(t > 1.0) & (t <= 1.5 + 1e-9)]) == {BRIDGED}
    assert set(result.status[(t > 1.5 + 1e-9) & (t < 1.8)]) == {LOST}
    assert set(result.status[recording.mocap.visible]) == {TRACKED}
    np.testing.assert_array_equal(result.position[recording.mocap.visible],
                                  recording.mocap.position[recording.mocap.visible])
    assert np.isnan(result.std).all()
    assert result.method == "baseline"
    assert result.time_since_fix[0] == 0.0


def test_registry_and_parameter_overrides():
    recording = synthetic_recording(*stationary([0.0, 1.0, 0.0]), duration=1.0, hidden=(0.5, 0.6))
    default = track_with_method(recording, "baseline")
    assert len(default) == len(recording.mocap)
    np.testing.assert_array_equal(default.t, recording.mocap.t)
    # a buffer longer than the recording never fits: every gap row is lost
    long = track_with_method(recording, "baseline", buffer_size=200)
    assert set(long.status[~recording.mocap.visible]) == {LOST}
    with pytest.raises(ValueError, match="unknown parameter"):
        track_recording(recording, buffer_length=3)


def test_parameters_defaults_and_validation():
    params = BaselineParameters()
    assert (params.buffer_size, params.velocity_points, params.adaptation_rate) == (20, 5, 0.01)
    assert BaselineParameters(buffer_size=30).velocity_points == 8  # round(30 / 4) = round(7.5)
    assert params.replace(buffer_size=12).velocity_points == 3
    assert params.replace(velocity_points=2).buffer_size == 20
    with pytest.raises(ValueError, match=r"buffer_size: expected an integer >= 3, got 2"):
        BaselineParameters(buffer_size=2)
    with pytest.raises(ValueError, match=r"velocity_points: expected at most buffer_size"):
        BaselineParameters(buffer_size=10, velocity_points=11)
    with pytest.raises(ValueError, match=r"adaptation_rate: expected a number in \(0, 1\]"):
        BaselineParameters(adaptation_rate=0.0)
    with pytest.raises(ValueError, match=r"gain: expected a positive number, got nan"):
        BaselineParameters(gain=float("nan"))
    with pytest.raises(ValueError, match=r"max_bridge_s: expected a positive number of seconds"):
        BaselineParameters(max_bridge_s=-1)
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) \['N'\]"):
        BaselineParameters.from_mapping({"N": 20})
    assert BaselineParameters.from_mapping({"gain": 0.95}).gain == 0.95


def test_bad_samples_are_rejected_and_leave_the_state_untouched():
    recording = synthetic_recording(*stationary([0.0, 1.0, 0.0]), duration=0.5)
    tracker, _, _ = run_stream(recording)
    offset = tracker.offset.copy()
    last = recording.imu.t[-1]
    assert not tracker.push_imu(last + 0.005, [np.nan, 0, 9.81], [0, 0, 0])
    assert not tracker.push_imu(last, recording.imu.accelerometer[-1], recording.imu.gyroscope[-1])
    assert not tracker.push_imu(last - 0.1, [0, 9.81, 0], [0, 0, 0])
    assert tracker.rejected == {"non-finite IMU sample": 1, "duplicate IMU sample": 1,
                                "IMU timestamp earlier than the last event": 1}
    np.testing.assert_array_equal(tracker.offset, offset)
    output = tracker.push_mocap(last - 0.5, [0, 1, 0], [1, 0, 0, 0])
    assert tracker.rejected["mocap timestamp not after the last event"] == 1
    assert output.t == last
    tracker.push_mocap(recording.mocap.t[-1], [0, 1, 0], [1, 0, 0, 0])
    assert tracker.rejected["duplicate mocap timestamp"] == 1
    with pytest.raises(ValueError, match=r"estimate: expected a time at or after the last event"):
        tracker.estimate(last - 1.0)
    with pytest.raises(ValueError, match=r"accelerometer: expected shape \(3,\), got \(2,\)"):
        tracker.push_imu(last + 0.01, [0, 9.81], [0, 0, 0])
    with pytest.raises(ValueError, match=r"quaternion: expected shape \(4,\)"):
        tracker.push_mocap(last + 0.01, [0, 1, 0], [1, 0, 0])
    with pytest.raises(ValueError, match=r"imu_to_body: expected a finite quaternion"):
        BaselineTracker([1, 0, 0])


def test_paper_command_smoke(tmp_path, capsys):
    out = tmp_path / "paper"
    assert main(["paper", "--seeds", "1", "--duration", "15", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "Table 1" in printed and "Where and why the numbers differ" in printed
    table1 = pd.read_csv(out / "table1.csv")
    assert list(table1["experiment"]) == [1]
    assert table1.loc[0, "Type 1 paper (mm)"] == 16.7
    use_case = pd.read_csv(out / "use_case.csv")
    assert list(use_case["IMU"]) == ["MPU9255", "UM7"]
    assert list(use_case["paper total (mm)"]) == [18.9, 12.8]
    per_gap = pd.read_csv(out / "per_gap.csv")
    assert (per_gap["max_mm"] >= per_gap["rms_mm"]).all()
    assert (out / "report.md").read_text().startswith("# The paper's tables")


def test_a_non_unit_quaternion_is_not_a_fix_and_cannot_poison_the_offset():
    tracker = BaselineTracker([1.0, 0.0, 0.0, 0.0])
    rest = np.array([0.0, 0.0, 9.81])
    for k in range(60):
        t = k * 0.01
        tracker.push_imu(t, rest, np.zeros(3))
        quaternion = [0.0, 0.0, 0.0, 0.0] if k == 40 else [1.0, 0.0, 0.0, 0.0]
        tracker.push_mocap(t, np.zeros(3), quaternion)
    assert np.isfinite(tracker.offset).all()
    tracker.push_imu(0.6, rest, np.zeros(3))
    bridged = tracker.push_mocap(0.6, None, None)
    assert bridged.status == "bridged" and np.isfinite(bridged.position).all()
