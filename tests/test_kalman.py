"""The Kalman tracker (kfusion.kalman): hand-derived steps, filterpy against plain numpy, the event
policy (NaN, order, gating, re-acquisition, status), save/restore and the lever arm."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from kfusion.conventions import (
    BRIDGED,
    LOST,
    TRACKED,
    integrate_gyroscope,
    matrix_from_wxyz,
    quaternion_multiply,
)
from kfusion.kalman import (
    ACCEPTED,
    GATED,
    INITIALISED,
    OCCLUDED,
    REACQUIRED,
    KalmanFusion,
    KalmanParameters,
    filter_recording,
    model,
    run_filter,
)
from kfusion.kalman.orientation import (
    OrientationTracker,
    conjugate,
    quaternion_log,
    quaternion_product,
)
from kfusion.kalman.reference import reference_filter
from kfusion.methods import track_with_method
from kfusion.profiles import MPU9255, OPTITRACK, UM7
from kfusion.recording import ImuSamples, MocapFrames, Recording, RecordingInfo
from kfusion.simulate import OcclusionSpec, simulate

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
GRAVITY = np.array([0.0, 0.0, -9.81])

# a filter whose only noise is the accelerometer's: orientation terms all vanish
QUIET = dict(
    accelerometer_noise_density=0.01, accelerometer_bias_random_walk=0.002,
    gyroscope_noise_density=0.0, gyroscope_bias_random_walk=0.0, mocap_position_noise=0.001,
    mocap_orientation_noise=0.0, initial_bias_std=0.05, initial_gyroscope_bias_std=0.0,
    initial_velocity_std=0.5,
)


def quiet_fusion(**overrides: object) -> KalmanFusion:
    params = KalmanParameters(**{**QUIET, **overrides})  # type: ignore[arg-type]
    return KalmanFusion(IDENTITY, GRAVITY, params, lever_arm=np.zeros(3))


def sim_recording(seed: int = 3, duration: float = 12.0, gap_range: tuple = (0.1, 0.8)
                  ) -> Recording:
    return simulate("random_reach", seed=seed, imu="mpu9255", duration=duration,
                    occlusions=OcclusionSpec(gap_range=gap_range, spacing=1.0)).recording


def with_mocap(recording: Recording, position: np.ndarray, quaternion: np.ndarray) -> Recording:
    mocap = recording.mocap
    return recording.with_mocap(MocapFrames(mocap.t, position, quaternion))


def test_orientation_tracker_learns_a_gyroscope_bias_from_mocap():
    # turning at 0.5 rad/s about z, gyroscope biased by 0.02 rad/s, exact mocap at 100 Hz
    bias = np.array([0.01, -0.02, 0.015])
    rate = np.array([0.0, 0.0, 0.5])
    tracker = OrientationTracker(1e-4, 1e-5, 0.002, 0.05)
    truth = IDENTITY.copy()
    tracker.initialise(tuple(truth))
    for k in range(2000):
        for _ in range(2):
            tracker.propagate(tuple(rate + bias), tuple(rate + bias), 0.005)
            truth = integrate_gyroscope(truth, rate, 0.005)
        if k < 1999:
            tracker.correct(tuple(truth))
    np.testing.assert_allclose(tracker.state.gyroscope_bias, bias, atol=1e-3)
    # the angle variance grows through a gap by the bias variance, dt^2 P_bb
    before = tracker.angle_variance
    tracker.propagate(tuple(rate), tuple(rate), 0.3)
    angle, cross, bias_variance = tracker.state.covariance
    assert angle > before


def test_a_fix_keeps_the_scale_error_rotation_it_did_not_absorb():
    """A gyroscope scale error S is constant: the angle error it builds, -S r, survives a fix
    but for the fix's gain. By hand: 0.1 s at 1 rad/s about z gives r = (0, 0, 0.1) rad and a
    scale-error variance 0.01^2 |r|^2 = 1e-6 rad^2; a fix of gain K leaves (1 - K) r."""
    tracker = OrientationTracker(0.0, 0.0, 0.004, 0.0, gyroscope_scale_error=0.01)
    tracker.initialise((1.0, 0.0, 0.0, 0.0))
    for _ in range(20):
        tracker.propagate((0.0, 0.0, 1.0), (0.0, 0.0, 1.0), 0.005)
    np.testing.assert_allclose(tracker.state.rotation_since_fix, (0.0, 0.0, 0.1), atol=1e-15)
    np.testing.assert_allclose(tracker.state.scale_variance_peak, 1e-6, rtol=1e-12)
    angle = tracker.angle_variance  # 0.004^2 from the first fix, plus the 1e-6
    np.testing.assert_allclose(angle, 0.004 ** 2 + 1e-6, rtol=1e-12)
    gain = angle / (angle + 0.004 ** 2)
    tracker.correct(tracker.state.quaternion)
    np.testing.assert_allclose(tracker.state.rotation_since_fix, (0.0, 0.0, 0.1 * (1 - gain)),
                               atol=1e-15)
    np.testing.assert_allclose(tracker.state.scale_variance_peak,
                               1e-4 * (0.1 * (1 - gain)) ** 2, rtol=1e-12)
    # turning on, the variance grows again only past what the fix left
    before = tracker.angle_variance
    tracker.propagate((0.0, 0.0, 1.0), (0.0, 0.0, 1.0), 0.005)
    expected = 1e-4 * (0.1 * (1 - gain) + 0.005) ** 2 - 1e-4 * (0.1 * (1 - gain)) ** 2
    np.testing.assert_allclose(tracker.angle_variance - before, expected, rtol=1e-9)


def test_persistent_orientation_innovations_by_hand():
    """The same normalised innovation u = (1, 0, 0) k times: ``m_k = 1 - lambda^k`` on x,
    ``q_k = 3 lambda^k + 1 - lambda^k``, a spread ``(q - m^2) / 3`` below 1 (so 1) and
    ``T = m^2 (1 + lambda) / (1 - lambda)``; the limit is the chi-square(3) 1 - 1e-4 quantile.
    White innovations twice as large as the model says are not persistent: the spread takes
    them out of T."""
    from scipy.stats import chi2

    from kfusion.kalman.orientation import PERSISTENCE_LIMIT, persistent_innovations

    assert PERSISTENCE_LIMIT == pytest.approx(chi2.ppf(0.9999, 3), abs=1e-6)
    mean, square, keep = (0.0, 0.0, 0.0), 3.0, 1.0 - 1.0 / 25
    for k in range(1, 31):
        mean, square, statistic = persistent_innovations(mean, square, (0.002, 0.0, 0.0),
                                                         0.002 ** 2)
        np.testing.assert_allclose(mean, (1 - keep ** k, 0.0, 0.0), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(square, 3 * keep ** k + 1 - keep ** k, rtol=1e-12)
        np.testing.assert_allclose(statistic, (1 - keep ** k) ** 2 * (1 + keep) / (1 - keep),
                                   rtol=1e-12)
    # 30 equal innovations of one sigma: persistent beyond the limit (T = 35.6)
    assert statistic > PERSISTENCE_LIMIT
    # white innovations with twice the model's sigma: T stays chi-square(3)-sized (mean 3, and
    # beyond the limit about as rarely as the model's own: 12 of 20,000 fixes with this seed;
    # without the spread, T would be 4 times larger)
    rng = np.random.default_rng(0)
    mean, square = (0.0, 0.0, 0.0), 3.0
    statistics = []
    for _ in range(20000):
        mean, square, statistic = persistent_innovations(
            mean, square, tuple(rng.normal(0.0, 0.004, 3)), 0.002 ** 2)
        statistics.append(statistic)
    assert np.mean(statistics) == pytest.approx(3.0, rel=0.15)
    assert np.sum(np.array(statistics) > PERSISTENCE_LIMIT) <= 20


def test_a_gyroscope_bias_step_is_seen_in_the_orientation_innovations():
    """Turning at 1 rad/s with 8 mrad orientation fixes (a small marker cluster's fit) at 100
    Hz, the gyroscope's bias steps by 0.06 rad/s on z at 5 s. No single fix's innovation is
    beyond its S, but they keep one sign: without the persistence test the tracker's angle error
    grew to 80 times its claimed sigma; with it the angle variance covers the error within half
    a second, and the bias is learnt again."""
    tracker = OrientationTracker(1e-4, 1e-5, 0.008, 0.01, gyroscope_scale_error=0.0)
    rng = np.random.default_rng(3)
    truth = IDENTITY.copy()
    tracker.initialise(tuple(truth))
    rate = np.array([0.0, 0.0, 1.0])
    nees = []
    for k in range(1500):
        bias = np.array([0.0, 0.0, 0.06]) if k >= 500 else np.zeros(3)
        tracker.propagate(tuple(rate + bias), tuple(rate + bias), 0.01)
        truth = integrate_gyroscope(truth, rate, 0.01)
        noisy = integrate_gyroscope(truth, rng.normal(0.0, 0.008, 3), 1.0)
        tracker.correct(tuple(noisy))
        if k >= 500:
            error = quaternion_log(quaternion_product(conjugate(tracker.state.quaternion),
                                                      tuple(truth)))
            nees.append(float(np.dot(error, error)) / tracker.angle_variance / 3)
    # the first 0.5 s, while the mean builds (39), the next 0.5 s (8.6), then the rest of the 3
    # s after the step (1.6; without the test: 174, 906 and 3226, and the bias learnt to 0.045
    # rad/s in 10 s)
    assert np.mean(nees[:50]) < 50.0
    assert np.mean(nees[50:100]) < 15.0
    assert np.mean(nees[100:300]) < 3.0
    np.testing.assert_allclose(tracker.state.gyroscope_bias[2], 0.06, atol=0.005)


def test_the_orientation_error_times_the_lever_is_in_the_output():
    """The output is ``p - R l``: an orientation error dtheta moves it by ``a x dtheta`` with
    ``a = R l``. By hand, a = (0, 0, L): variance sigma^2 L^2 on x and y, none on z; and the
    filter's estimate carries it with ``a`` from its own orientation and lever."""
    from kfusion.kalman import model
    from kfusion.kalman.batch import make_fusion, process_recording

    np.testing.assert_allclose(model.orientation_error_covariance(np.array([0.0, 0.0, 0.1]),
                                                                  4e-6),
                               np.diag([4e-8, 4e-8, 0.0]), rtol=1e-12, atol=0)
    a = np.array([0.03, -0.05, 0.08])
    cross = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    np.testing.assert_allclose(model.orientation_error_covariance(a, 4e-6),
                               4e-6 * cross @ cross.T, rtol=1e-12, atol=1e-24)
    assert not model.orientation_error_covariance(np.zeros(3), math.inf).any()  # no lever
    lever = np.array([0.02, -0.01, 0.05])
    recording = spinning_recording(lever, gap=(500, 530), swing=1.5)
    for engine in ("filterpy", "compiled"):
        fusion = make_fusion(recording, KalmanParameters.from_profiles("um7"), engine)
        process_recording(recording, fusion, lambda row, outcome: None)
        estimate = fusion.estimate()
        arm = (matrix_from_wxyz(np.asarray(estimate.orientation)) @ lever)
        cross = np.array([[0.0, -arm[2], arm[1]], [arm[2], 0.0, -arm[0]],
                          [-arm[1], arm[0], 0.0]])
        assert fusion.angle_variance > 0
        np.testing.assert_allclose(estimate.orientation_covariance,
                                   fusion.angle_variance * cross @ cross.T, rtol=1e-9,
                                   atol=1e-24)


# ------------------------------------------------------------------------------------------
# the model against hand-derived numbers
# ------------------------------------------------------------------------------------------


def test_model_reduces_to_the_zero_order_hold_form_for_a_constant_rotation():
    R = matrix_from_wxyz([np.cos(0.3), 0.0, np.sin(0.3), 0.0])
    dt = 0.02
    F = model.transition_matrix(R, R, dt)
    B = model.control_matrix(R, R, dt)
    I3 = np.eye(3)
    expected_F = np.block([[I3, dt * I3, -0.5 * dt**2 * R], [0 * I3, I3, -dt * R],
                           [0 * I3, 0 * I3, I3]])
    np.testing.assert_allclose(F, expected_F, atol=1e-15)
    # u = [f; f; g]: B u = [dt^2/2 (R f + g); dt (R f + g); 0]
    f = np.array([0.3, -0.2, 9.7])
    u = model.control_input(f, f, GRAVITY)
    a = R @ f + GRAVITY
    np.testing.assert_allclose(B @ u, np.concatenate([0.5 * dt**2 * a, dt * a, np.zeros(3)]),
                               atol=1e-15)


def test_process_noise_blocks():
    Q = model.process_noise(0.01, 0.2, 0.03, acceleration_variance=4.0, bias_variance=0.5)
    # white: sigma^2 [dt^3, dt^2, dt]; extra held over dt: 4 [dt^4/4, dt^3/2, dt^2]
    assert Q[0, 0] == pytest.approx(0.04 * 1e-6 + 4.0 * 1e-8 / 4)
    assert Q[0, 3] == pytest.approx(0.04 * 1e-4 + 4.0 * 1e-6 / 2)
    assert Q[3, 3] == pytest.approx(0.04 * 1e-2 + 4.0 * 1e-4)
    assert Q[6, 6] == pytest.approx(0.0009 * 0.01 + 0.5)
    assert Q[0, 1] == 0.0 and Q[0, 6] == 0.0 and np.array_equal(Q, Q.T)


def test_one_step_against_hand_derived_numbers():
    fusion = quiet_fusion()
    f0 = np.array([0.1, 0.2, 9.81])
    f1 = np.array([0.3, -0.1, 9.9])
    z0 = np.array([1.0, 2.0, 0.5])
    assert fusion.predict(0.0, f0, np.zeros(3)) == "predicted"
    assert fusion.update(0.0, z0, IDENTITY).kind == INITIALISED
    np.testing.assert_array_equal(fusion.x, [1.0, 2.0, 0.5, 0, 0, 0, 0, 0, 0])
    fusion.predict(0.01, f1, np.zeros(3))
    # a0 = f0 + g = (0.1, 0.2, 0), a1 = f1 + g = (0.3, -0.1, 0.09); linear in between:
    # p1 = p0 + dt^2 (a0/3 + a1/6) = p0 + 1e-4 (0.08333.., 0.05, 0.015)
    # v1 = dt (a0 + a1)/2 = (0.002, 0.0005, 0.00045)
    np.testing.assert_allclose(fusion.x[0:3], z0 + 1e-4 * np.array([0.25 / 3, 0.05, 0.015]),
                               rtol=0, atol=1e-15)
    np.testing.assert_allclose(fusion.x[3:6], [0.002, 0.0005, 0.00045], rtol=0, atol=1e-15)
    # covariance per axis, P0 = diag(sp^2, sv^2, sb^2), F = [[1, dt, -dt^2/2], [0, 1, -dt],
    # [0, 0, 1]], Q = sa^2 [[dt^3, dt^2, 0], [dt^2, dt, 0], [0, 0, 0]] + sbw^2 dt on b
    dt, sp2, sv2, sb2 = 0.01, 1e-6, 0.25, 0.0025
    sa2, sbw2 = 1e-4, 4e-6
    P = fusion.P
    assert P[0, 0] == pytest.approx(sp2 + dt**2 * sv2 + dt**4 / 4 * sb2 + sa2 * dt**3, rel=1e-12)
    assert P[0, 3] == pytest.approx(dt * sv2 + dt**3 / 2 * sb2 + sa2 * dt**2, rel=1e-12)
    assert P[3, 3] == pytest.approx(sv2 + dt**2 * sb2 + sa2 * dt, rel=1e-12)
    assert P[0, 6] == pytest.approx(-dt**2 / 2 * sb2, rel=1e-12)
    assert P[3, 6] == pytest.approx(-dt * sb2, rel=1e-12)
    assert P[6, 6] == pytest.approx(sb2 + sbw2 * dt, rel=1e-12)
    assert P[0, 1] == 0.0

    # update with z1: per axis S = P_pp + sp^2, K = P[:, p] / S (axes are independent here)
    z1 = fusion.x[0:3] + np.array([2e-4, -1e-4, 0.0])
    prior, prior_x = fusion.P, fusion.x
    outcome = fusion.update(0.01, z1, IDENTITY)
    S = prior[0, 0] + sp2
    assert outcome.kind == ACCEPTED
    assert outcome.nis == pytest.approx((4e-8 + 1e-8) / S, rel=1e-12)
    gain = prior[[0, 3, 6], 0] / S
    np.testing.assert_allclose(fusion.x[[0, 3, 6]], prior_x[[0, 3, 6]] + gain * 2e-4,
                               rtol=1e-12)
    # Joseph form equals (I - K H) P for the optimal gain
    assert fusion.P[0, 0] == pytest.approx(prior[0, 0] * sp2 / S, rel=1e-10)
    assert fusion.P[3, 3] == pytest.approx(prior[3, 3] - prior[0, 3] ** 2 / S, rel=1e-10)


def test_rotated_step_uses_the_mocap_orientation():
    fusion = quiet_fusion()
    q = np.array([np.cos(np.pi / 4), 0.0, 0.0, np.sin(np.pi / 4)])  # 90 deg about z
    f = np.array([1.0, 0.0, 9.81])  # 1 m/s^2 along IMU x = global y
    fusion.predict(0.0, f, np.zeros(3))
    fusion.update(0.0, np.zeros(3), q)
    fusion.predict(0.1, f, np.zeros(3))
    np.testing.assert_allclose(fusion.x[0:3], [0.0, 0.005, 0.0], atol=1e-15)
    np.testing.assert_allclose(fusion.x[3:6], [0.0, 0.1, 0.0], atol=1e-15)


# ------------------------------------------------------------------------------------------
# parameters
# ------------------------------------------------------------------------------------------


def test_parameters_from_profiles_and_mappings():
    params = KalmanParameters.from_profiles("mpu9255", "optitrack", max_bridge_s=0.5)
    assert params.accelerometer_noise_density == MPU9255.accelerometer_noise_density
    assert params.accelerometer_bias_random_walk == MPU9255.accelerometer_bias_random_walk
    assert params.mocap_position_noise == OPTITRACK.position_noise
    assert params.initial_bias_std == MPU9255.accelerometer_turn_on_bias
    assert params.accelerometer_scale_error == pytest.approx(
        math.hypot(MPU9255.accelerometer_scale_error, MPU9255.accelerometer_cross_axis))
    assert params.max_bridge_s == 0.5
    assert KalmanParameters.from_profiles(UM7).gyroscope_noise_density == \
        UM7.gyroscope_noise_density
    assert KalmanParameters.from_mapping({"imu": "um7", "gate_probability": None}) == \
        KalmanParameters.from_profiles("um7", gate_probability=None)
    assert KalmanParameters.from_mapping(params.to_mapping()) == params
    with pytest.raises(ValueError, match="unknown key 'max_bridge'; expected one of"):
        KalmanParameters.from_mapping({"max_bridge": 1.0})
    with pytest.raises(ValueError, match="unknown override 'colour'"):
        KalmanParameters.from_profiles("mpu9255", colour=1)
    with pytest.raises(ValueError, match="unknown IMU profile 'mpu6050'"):
        KalmanParameters.from_profiles("mpu6050")


@pytest.mark.parametrize(("field", "value", "message"), [
    ("mocap_position_noise", 0.0, r"mocap_position_noise: expected a number > 0, got 0.0"),
    ("accelerometer_noise_density", -1.0,
     r"accelerometer_noise_density: expected a number > 0, got -1.0"),
    ("max_bridge_s", "1", r"max_bridge_s: expected a number, got '1'"),
    ("initial_velocity_std", math.nan, r"initial_velocity_std: expected a finite number"),
    ("gate_probability", 1.5, r"gate_probability: expected None or a probability in \(0, 1\]"),
])
def test_parameters_are_validated(field, value, message):
    with pytest.raises(ValueError, match=message):
        KalmanParameters.from_profiles("mpu9255", **{field: value})


# ------------------------------------------------------------------------------------------
# filterpy-based filter equals the plain numpy reference
# ------------------------------------------------------------------------------------------


def visible_run_start(visible: np.ndarray, start: int, length: int) -> int:
    """First row >= start beginning ``length`` consecutive visible rows."""
    for row in range(start, len(visible) - length):
        if visible[row:row + length].all():
            return row
    raise AssertionError("no visible run found")


def jumped(recording: Recording) -> tuple[Recording, int, int, int]:
    """A 5 cm marker jump on one frame, and a 1.2 s gap ended by a frame 3 cm off the path.

    Returns the recording and the rows of the jump, of the gap's start and of its first fix."""
    visible = recording.mocap.visible
    jump = visible_run_start(visible, 300, 3) + 1
    start = visible_run_start(visible, jump + 100, 125) + 1
    end = start + 120
    position = recording.mocap.position.copy()
    quaternion = recording.mocap.quaternion.copy()
    position[jump] += [0.05, 0.0, 0.0]
    position[start:end] = np.nan
    quaternion[start:end] = np.nan
    position[end] += [0.0, 0.03, 0.0]
    return with_mocap(recording, position, quaternion), jump, start, end


@pytest.mark.parametrize("variant", ["nine_states", "lever_arm_states_and_latency"])
def test_filterpy_filter_equals_the_numpy_reference(variant):
    recording, _, _, _ = jumped(sim_recording())
    params = KalmanParameters.from_profiles("mpu9255")
    if variant == "lever_arm_states_and_latency":
        recording = dataclasses.replace(
            recording, info=dataclasses.replace(recording.info, lever_arm=None))
        # and a range that some samples reach
        params = dataclasses.replace(params, imu_latency_s=0.0012, accelerometer_range=10.5)
    # the model alone: the consistency monitor is a layer of its own (tests/test_monitor.py)
    run = run_filter(recording, params, monitor=None)
    reference = reference_filter(recording, params)
    assert run.x.shape[1] == (12 if variant != "nine_states" else 9)
    assert (run.counters["accelerometer_saturated"] > 0) == (variant != "nine_states")
    # every kind of update happened, in the same places
    assert {ACCEPTED, GATED, OCCLUDED, REACQUIRED, INITIALISED} <= set(run.outcome)
    np.testing.assert_array_equal(run.outcome, reference.outcome)
    np.testing.assert_allclose(run.x, reference.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(run.P, reference.P, rtol=0, atol=1e-9)
    # the reference keeps its state on lost rows; a TrackResult carries no estimate there
    shown = run.result.status != LOST
    assert np.isnan(run.result.position[~shown]).all()
    np.testing.assert_allclose(run.result.position[shown], reference.position[shown], rtol=0,
                               atol=1e-9)
    np.testing.assert_allclose(run.result.std[shown], reference.std[shown], rtol=0, atol=1e-12)
    np.testing.assert_allclose(run.nis, reference.nis, rtol=1e-9, atol=1e-9)


# ------------------------------------------------------------------------------------------
# streaming API
# ------------------------------------------------------------------------------------------


def stream(fusion: KalmanFusion, recording: Recording, start: int = 0, stop: int | None = None
           ) -> list:
    """Feed mocap rows start..stop (and the IMU samples up to them) with the public API."""
    imu, mocap = recording.imu, recording.mocap
    stop = len(mocap) if stop is None else stop
    i = int(np.searchsorted(imu.t, mocap.t[start - 1], side="right")) if start else 0
    steps = []
    for row in range(start, stop):
        while i < len(imu) and imu.t[i] <= mocap.t[row]:
            fusion.predict(imu.t[i], imu.accelerometer[i], imu.gyroscope[i])
            i += 1
        fusion.update(mocap.t[row], mocap.position[row], mocap.quaternion[row])
        steps.append(fusion.estimate())
    return steps


def test_streaming_equals_the_batch_run():
    recording = sim_recording(duration=8.0)
    params = KalmanParameters.from_profiles("mpu9255")
    # KalmanFusion streams the model alone; the monitor's layer is compared in test_monitor.py
    batch = run_filter(recording, params, monitor=None, engine="filterpy").result
    steps = stream(KalmanFusion(recording.info.imu_to_body, recording.info.gravity, params,
                                lever_arm=recording.info.lever_arm), recording)
    np.testing.assert_array_equal(np.array([s.position for s in steps]), batch.position)
    np.testing.assert_array_equal(np.array([s.std for s in steps]), batch.std)
    assert [s.status for s in steps] == list(batch.status)
    np.testing.assert_array_equal([s.time_since_fix for s in steps], batch.time_since_fix)


def test_snapshot_and_restore_continue_bit_exactly():
    recording = sim_recording(duration=8.0)
    params = KalmanParameters.from_profiles("mpu9255")
    info = recording.info

    def fresh() -> KalmanFusion:
        return KalmanFusion(info.imu_to_body, info.gravity, params, lever_arm=info.lever_arm)

    whole = fresh()
    first = stream(whole, recording, 0, 350)
    snapshot = whole.snapshot()
    rest = stream(whole, recording, 350)
    restored = fresh()
    restored.restore(snapshot)
    again = stream(restored, recording, 350)
    assert len(first) == 350
    for a, b in zip(rest, again, strict=True):
        np.testing.assert_array_equal(a.position, b.position)
        np.testing.assert_array_equal(a.covariance, b.covariance)
        assert a.status == b.status
    np.testing.assert_array_equal(whole.x, restored.x)
    assert whole.counters == restored.counters
    other = KalmanFusion(info.imu_to_body, info.gravity,
                         dataclasses.replace(params, max_bridge_s=2.0), lever_arm=info.lever_arm)
    with pytest.raises(ValueError, match="restore: the snapshot was taken from a filter with "
                                         "other parameters"):
        other.restore(snapshot)


def test_nan_never_reaches_filterpy(monkeypatch):
    calls = []
    original = KalmanFilter.update

    def checked(self, z, R=None, H=None):
        calls.append(np.asarray(z))
        assert np.isfinite(z).all()
        return original(self, z, R=R, H=H)

    monkeypatch.setattr(KalmanFilter, "update", checked)
    fusion = quiet_fusion()
    f = np.array([0.0, 0.0, 9.81])
    fusion.predict(0.0, f, np.zeros(3))
    fusion.update(0.0, np.zeros(3), IDENTITY)
    fusion.predict(0.01, f, np.zeros(3))
    before = (fusion.x, fusion.P, fusion.counters["predictions"])
    assert fusion.predict(0.02, [np.nan, 0.0, 9.81], np.zeros(3)) == "rejected"
    assert fusion.predict(0.02, f, [0.0, np.inf, 0.0]) == "rejected"
    np.testing.assert_array_equal(fusion.x, before[0])
    np.testing.assert_array_equal(fusion.P, before[1])
    assert fusion.counters["imu_rejected"] == 2
    assert fusion.counters["predictions"] == before[2]
    assert fusion.update(0.01, [np.nan, 0.0, 0.0], IDENTITY).kind == OCCLUDED
    assert fusion.update(0.01, None, None).kind == OCCLUDED
    fusion.predict(0.02, f, np.zeros(3))
    assert fusion.update(0.02, np.zeros(3), IDENTITY).kind == ACCEPTED
    assert len(calls) == 1 and np.isfinite(fusion.x).all()


def test_timestamps_out_of_order_are_refused_and_duplicates_skipped():
    fusion = quiet_fusion()
    f = np.array([0.0, 0.0, 9.81])
    fusion.predict(0.0, f, np.zeros(3))
    fusion.update(0.0, np.zeros(3), IDENTITY)
    fusion.predict(0.01, f, np.zeros(3))
    assert fusion.predict(0.01, f, np.zeros(3)) == "duplicate"
    assert fusion.counters["imu_duplicates"] == 1
    with pytest.raises(ValueError, match=r"predict: timestamp 0.01 s is not after the previous "
                                         r"IMU sample \(0.01 s\)"):
        fusion.predict(0.01, f + 1.0, np.zeros(3))
    with pytest.raises(ValueError, match=r"update: timestamp 0.005 s is before the filter's "
                                         r"time \(0.01 s\)"):
        fusion.update(0.005, np.zeros(3), IDENTITY)
    with pytest.raises(ValueError, match=r"accelerometer: expected shape \(3,\), got \(2,\)"):
        fusion.predict(0.02, [0.0, 9.81], np.zeros(3))
    with pytest.raises(ValueError, match=r"estimate: time 0.0 s is before the state's time"):
        fusion.estimate(0.0)
    with pytest.raises(ValueError, match=r"imu_to_body: expected a finite unit quaternion"):
        KalmanFusion([2.0, 0.0, 0.0, 0.0], GRAVITY, KalmanParameters.from_profiles())


def test_a_long_imu_dropout_grows_the_covariance_over_the_real_interval():
    fusion = quiet_fusion()
    f = np.array([0.0, 0.0, 9.81])
    fusion.predict(0.0, f, np.zeros(3))
    fusion.update(0.0, np.zeros(3), IDENTITY)
    fusion.predict(2.0, f, np.zeros(3))
    assert fusion.counters["imu_dropouts"] == 1
    # the velocity variance grew by at least sigma_v^2 + sigma_a^2 * 2 s and position by more
    assert fusion.P[3, 3] >= 0.25 + 1e-4 * 2.0
    assert fusion.P[0, 0] >= 0.25 * 4.0
    step = fusion.estimate()
    assert step.status == LOST and step.time_since_fix == 2.0


def test_implausible_samples_are_rejected_and_overflow_resets_the_state():
    fusion = quiet_fusion()
    f = np.array([0.0, 0.0, 9.81])
    fusion.predict(0.0, f, np.zeros(3))
    fusion.update(0.0, np.zeros(3), IDENTITY)
    assert fusion.predict(0.01, [1e300, -1e300, 9.81], np.zeros(3)) == "rejected"
    assert fusion.counters["imu_rejected"] == 1 and fusion.time == 0.0
    # an interval of 1e200 s overflows the covariance: the state is forgotten (lost) ...
    with np.errstate(over="ignore", invalid="ignore"):
        fusion.predict(1e200, f, np.zeros(3))
    assert fusion.counters["resets"] == 1 and not fusion.initialised
    assert fusion.estimate().status == LOST
    # ... and the next fix initialises it again
    assert fusion.update(1e200, np.ones(3), IDENTITY).kind == INITIALISED
    assert np.isfinite(fusion.P).all() and fusion.estimate().status == TRACKED


@pytest.mark.parametrize("engine", ["filterpy", "compiled"])
def test_a_prediction_looser_than_100_km_is_forgotten_before_the_next_fix(engine: str):
    """Fixes 200 s apart without IMU samples are fused (the no-IMU prediction's position std is
    49 km); fixes 1e15 s apart are not: the prediction passes FORGOTTEN_POSITION_STD, the
    state is forgotten (a reset) and the fix initialises it. Fused instead, the fix landed on a
    prior 1e52 times its own noise and the posterior was rounding: 1-3 mm off the fix with a
    1 mm bound (an adversarial review)."""
    from kfusion.kalman.compiled_fusion import CompiledFusion
    from kfusion.kalman.model import FORGOTTEN_POSITION_STD

    params = KalmanParameters(**QUIET)  # type: ignore[arg-type]
    fusion = (KalmanFusion if engine == "filterpy" else CompiledFusion)(
        IDENTITY, GRAVITY, params, lever_arm=np.zeros(3))
    fusion.predict(0.0, np.array([0.0, 0.0, 9.81]), np.zeros(3))
    fusion.update(0.0, np.zeros(3), IDENTITY)
    near = np.array([0.4, -0.2, 1.1])
    assert fusion.estimate(200.0).position_covariance[0, 0] < FORGOTTEN_POSITION_STD ** 2
    assert fusion.update(200.0, near, IDENTITY).kind == REACQUIRED
    assert fusion.counters["resets"] == 0
    for k, t in enumerate((1e15, 2e15, 3e15)):
        z = near + 0.1 * k
        assert fusion.update(t, z, IDENTITY).kind == INITIALISED
        assert fusion.counters["resets"] == k + 1
        estimate = fusion.estimate()
        assert estimate.status == TRACKED
        np.testing.assert_array_equal(estimate.position, z)
        np.testing.assert_allclose(np.diag(estimate.position_covariance),
                                   params.mocap_position_noise ** 2, rtol=1e-12)


def test_the_plateau_test_by_hand():
    """model.plateau_step on axis x, floor 1.96 rad/s: a level becomes a clip on its 4th exact
    repeat; a value above it clears the evidence (it was a peak). Axis y keeps its own top
    (0.5, below the floor: never a level)."""
    from kfusion.kalman.model import plateau_step

    floor = 1.96
    tops, repeats, previous = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), None
    expected = [  # value on x: (top x, repeats x, level) after it
        (1.0, (1.0, 0, 0.0)),
        (3.0, (3.0, 0, 0.0)),
        (3.0, (3.0, 1, 0.0)),  # an exact repeat at the top
        (3.0, (3.0, 2, 0.0)),
        (3.0, (3.0, 3, 0.0)),
        (3.0, (3.0, 4, 3.0)),  # the 4th: a clipping level
        (2.95, (3.0, 4, 3.0)),  # within 2 % of it (the other side, a bias apart)
        (2.9, (3.0, 4, 0.0)),
        (2.9, (3.0, 4, 0.0)),  # a repeat below the top adds nothing
        (3.1, (3.1, 0, 0.0)),  # above the level: it was a peak, not a clip
    ]
    for value, after in expected:
        sample = (value, 0.5, -0.2)
        tops, repeats, level = plateau_step(sample, previous, tops, repeats, floor)
        assert (tops[0], repeats[0], level) == after, value
        assert (tops[1], repeats[1]) == (0.5, 0.0)
        previous = sample
    # one axis's plateau under another axis's larger values (a bias apart): its own level
    tops, repeats, previous = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), None
    for k in range(8):
        sample = (2.5, 4.0 + 0.1 * k, 0.0)  # x flat at 2.5, y larger and moving
        tops, repeats, level = plateau_step(sample, previous, tops, repeats, floor)
        previous = sample
    assert level == 2.5 and repeats[0] == 7
    # a still sensor's quantised top repeats below the floor: never a range
    tops, repeats, previous = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), None
    for _ in range(50):
        tops, repeats, level = plateau_step((1.5, 0.0, 0.0), previous, tops, repeats, floor)
        previous = (1.5, 0.0, 0.0)
        assert level == 0.0 and repeats == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("engine", ["filterpy", "compiled"])
def test_a_sensor_clipping_below_its_declared_range_is_saturated(engine: str):
    """A gyroscope flat at 3 rad/s while the profile says 1000 dps: from the 4th repeat of the
    level on, its samples are saturated and held with the variance of a range at that level,
    (3/2)^2 (rad/s)^2, as if the level had been declared; a sample off the level is not."""
    from kfusion.kalman import compiled
    from kfusion.kalman.compiled_fusion import CompiledFusion

    params = KalmanParameters(**QUIET)  # type: ignore[arg-type]
    fusion = (KalmanFusion if engine == "filterpy" else CompiledFusion)(
        IDENTITY, GRAVITY, params, lever_arm=np.zeros(3))

    def held_variance() -> float:  # the extra variance of the held gyroscope sample
        if isinstance(fusion, KalmanFusion):
            return fusion._gyroscope_extra_variance
        return float(fusion._scalars[compiled.GYROSCOPE_EXTRA])

    f = np.array([0.0, 0.0, 9.81])
    for k, (rate, variance) in enumerate([(0.5, 0.0), (3.0, 0.0), (3.0, 0.0), (3.0, 0.0),
                                          (3.0, 0.0), (3.0, 2.25), (2.0, 0.0)]):
        fusion.predict(0.01 * k, f, np.array([0.0, -rate, 0.0]))
        assert held_variance() == variance, k
    assert fusion.counters["gyroscope_saturated"] == 1
    assert fusion.counters["accelerometer_saturated"] == 0


def test_saturated_samples_are_flagged_and_inflate_the_noise():
    fusion = quiet_fusion(accelerometer_range=20.0)
    f = np.array([0.0, 0.0, 9.81])
    fusion.predict(0.0, f, np.zeros(3))
    fusion.update(0.0, np.zeros(3), IDENTITY)
    fusion.predict(0.01, [0.0, 20.0, 9.81], np.zeros(3))
    quiet = fusion.P[4, 4]
    fusion.predict(0.02, f, np.zeros(3))
    assert fusion.counters["accelerometer_saturated"] == 1
    # the saturated sample's interval adds (range/2)^2 dt^2 to the velocity variance
    assert fusion.P[4, 4] - quiet >= 100.0 * 0.01**2


# ------------------------------------------------------------------------------------------
# gating, re-acquisition, status
# ------------------------------------------------------------------------------------------


def test_gating_rejects_a_marker_jump_and_reacquires_after_a_long_gap():
    recording, jump, start, end = jumped(sim_recording())
    run = run_filter(recording, gate_probability=0.9999)
    assert run.outcome[jump] == GATED
    assert run.counters["gated"] == int(np.sum(run.outcome == GATED)) >= 1
    assert run.result.status[jump] == BRIDGED
    # the estimate at the jumped frame stayed on the true path (its neighbours)
    truth = recording.mocap.position
    assert np.linalg.norm(run.result.position[jump] - truth[jump - 1]) < 0.02
    # after the 1.2 s gap the first frame is accepted as re-acquisition, not gated, even though
    # it is 3 cm off the prediction
    assert run.outcome[end] == REACQUIRED
    assert run.counters["reacquired"] >= 1
    np.testing.assert_allclose(run.result.position[end], truth[end], atol=0.002)
    # with gating off, the jump is accepted
    assert run_filter(recording, gate_probability=None).outcome[jump] == ACCEPTED


def test_status_is_bridged_then_lost_after_max_bridge():
    recording, _, start, end = jumped(sim_recording())
    # the model's own bound (the monitor's scale steps between horizon bins: test_monitor.py)
    result = filter_recording(recording, max_bridge_s=0.5, monitor=None)
    gap = slice(start, end)
    since = result.t[gap] - result.t[start - 1]
    np.testing.assert_allclose(result.time_since_fix[gap], since, atol=1e-12)
    assert list(result.status[gap]) == list(np.where(since <= 0.5, BRIDGED, LOST))
    assert result.status[start - 1] == TRACKED and result.status[end] == TRACKED
    assert result.time_since_fix[end] == 0.0
    # the uncertainty grows through the gap while bridged; lost rows carry no estimate
    bridged = result.status[gap] == BRIDGED
    assert np.all(np.diff(result.std[gap, 0][bridged]) > 0)
    assert np.isnan(result.std[gap][~bridged]).all()


def test_estimate_extrapolates_without_changing_the_state():
    fusion = quiet_fusion()
    f = np.array([0.5, 0.0, 9.81])
    fusion.predict(0.0, f, np.zeros(3))
    fusion.update(0.0, np.zeros(3), IDENTITY)
    before = fusion.snapshot()
    ahead = fusion.estimate(0.016)
    # the status rule (kfusion.streamhealth.tracking_status, the Tracker's too): tracked while
    # the last frame was fused and is at most fix_timeout_s (0.05 s) old
    assert ahead.status == TRACKED and ahead.time_since_fix == pytest.approx(0.016)
    # held sample: x = 1/2 a t^2 = 6.4e-5 m
    assert ahead.position[0] == pytest.approx(0.5 * 0.5 * 0.016 ** 2, abs=1e-15)
    assert ahead.std[0] > fusion.estimate().std[0]
    # the sample is held for at most 20 ms (kfusion.streamhealth.hold_horizon): later, nothing
    # is dead-reckoned, so past fix_timeout_s the estimate is lost, not bridged
    assert fusion.estimate(0.051).status == LOST
    np.testing.assert_array_equal(fusion.x, before.x)
    np.testing.assert_array_equal(fusion.P, before.P)
    assert fusion.snapshot().orientation == before.orientation
    assert fusion.time == 0.0


def test_lost_before_the_first_fix_and_no_fix_without_orientation():
    fusion = quiet_fusion()
    fusion.predict(0.0, [0.0, 0.0, 9.81], np.zeros(3))
    assert fusion.estimate().status == LOST
    assert np.isnan(fusion.estimate().position).all()
    assert fusion.update(0.0, np.zeros(3), None).kind == OCCLUDED
    assert fusion.counters["no_orientation"] == 1
    assert not fusion.initialised


# ------------------------------------------------------------------------------------------
# lever arm
# ------------------------------------------------------------------------------------------


def spinning_recording(lever: np.ndarray, gap: tuple[int, int], rate: float = 3.0,
                       swing: float = 0.0) -> Recording:
    """A body turning about global z around its fixed origin at ``rate + swing sin(pi t)``
    rad/s; the IMU sits at ``lever`` (body frame) and feels the centripetal acceleration
    ``-omega^2 l`` and, with a swing, the tangential one ``alpha z x l`` (both body frame: a
    constant rate makes them a constant the filter can take for an accelerometer bias). IMU
    200 Hz, mocap 100 Hz."""
    imu_t = np.arange(0.0, 6.0 + 1e-9, 0.005)
    angle = rate * imu_t + swing / np.pi * (1.0 - np.cos(np.pi * imu_t))
    omega = rate + swing * np.sin(np.pi * imu_t)
    alpha = swing * np.pi * np.cos(np.pi * imu_t)
    q = np.column_stack([np.cos(angle / 2), np.zeros_like(angle), np.zeros_like(angle),
                         np.sin(angle / 2)])
    R = matrix_from_wxyz(q)
    in_plane = lever * [1, 1, 0]
    tangential = np.array([-lever[1], lever[0], 0.0])
    body_acceleration = -omega[:, None] ** 2 * in_plane + alpha[:, None] * tangential
    acceleration = np.einsum("nij,nj->ni", R, body_acceleration)
    specific_force = np.einsum("nji,nj->ni", R, acceleration - GRAVITY)
    gyroscope = np.column_stack([np.zeros_like(omega), np.zeros_like(omega), omega])
    rows = np.arange(0, len(imu_t), 2)
    position = np.tile([0.4, -0.2, 1.0], (len(rows), 1))
    quaternion = q[rows].copy()
    position[gap[0]:gap[1]] = np.nan
    quaternion[gap[0]:gap[1]] = np.nan
    return Recording(imu=ImuSamples(imu_t, specific_force, gyroscope),
                     mocap=MocapFrames(imu_t[rows], position, quaternion),
                     info=RecordingInfo(imu_to_body=IDENTITY, gravity=GRAVITY, lever_arm=lever))


def test_a_known_lever_arm_is_used_and_an_unknown_one_is_estimated():
    lever = np.array([0.02, -0.01, 0.0])
    # the rate swings, so the lever's acceleration is no constant (a bias would absorb one)
    recording = spinning_recording(lever, gap=(500, 530), swing=1.5)
    params = KalmanParameters.from_profiles("um7", initial_bias_std=0.001)
    gap = slice(500, 530)
    truth = np.array([0.4, -0.2, 1.0])

    known = filter_recording(recording, params)
    assert np.abs(known.position[gap] - truth).max() < 0.5e-3
    unknown = dataclasses.replace(recording,
                                  info=dataclasses.replace(recording.info, lever_arm=None))
    estimated = run_filter(unknown, params)
    assert estimated.x.shape[1] == 12
    np.testing.assert_allclose(estimated.x[499, 9:11], lever[:2], atol=1e-3)
    assert np.abs(estimated.result.position[gap] - truth).max() < 1e-3
    ignored = run_filter(unknown, params, monitor=None, lever_arm_std=0.0).result
    # ignoring it costs the lever's acceleration (0.05-0.45 m/s^2 here): 10 mm in 0.3 s
    assert np.abs(ignored.position[gap] - truth).max() > 5 * np.abs(
        estimated.result.position[gap] - truth).max()
    # and the consistency monitor (the default) does not bridge with it
    assert (filter_recording(unknown, params, lever_arm_std=0.0).status[gap] == LOST).all()


# ------------------------------------------------------------------------------------------
# recording entry points
# ------------------------------------------------------------------------------------------


def test_filter_recording_takes_the_profile_from_the_recording_and_overrides():
    recording = sim_recording(duration=6.0)
    assert recording.info.imu == "mpu9255"
    default = run_filter(recording)
    assert default.params == KalmanParameters.from_profiles("mpu9255")
    um7 = dataclasses.replace(recording, info=dataclasses.replace(recording.info, imu="um7"))
    assert run_filter(um7).params == KalmanParameters.from_profiles("um7")
    result = track_with_method(recording, "kalman", max_bridge_s=0.25)
    assert result.method == "kalman" and len(result) == len(recording.mocap)
    np.testing.assert_array_equal(result.t, recording.mocap.t)
    with pytest.raises(ValueError, match="unknown override 'bridge'"):
        filter_recording(recording, bridge=1.0)
    with pytest.raises(ValueError, match="params: expected KalmanParameters or None, got dict"):
        filter_recording(recording, {"max_bridge_s": 1.0})  # type: ignore[arg-type]


def test_quaternion_products_compose_like_the_recording_convention():
    # imu_to_body is q_body_imu: the filter's orientation at a fix is q_global_body ⊗ q_body_imu
    q_body_imu = np.array([np.cos(0.4), np.sin(0.4), 0.0, 0.0])
    q_global_body = np.array([np.cos(0.2), 0.0, 0.0, np.sin(0.2)])
    fusion = KalmanFusion(q_body_imu, GRAVITY, KalmanParameters(**QUIET), lever_arm=np.zeros(3))
    fusion.predict(0.0, [0.0, 0.0, 9.81], np.zeros(3))
    fusion.update(0.0, np.zeros(3), q_global_body)
    np.testing.assert_allclose(fusion.estimate().orientation,
                               quaternion_multiply(q_global_body, q_body_imu), atol=1e-15)


def test_an_absurd_fix_after_a_long_gap_is_gated_not_fused():
    # a finite but absurd position (1e200 m) overflows the innovation: fusing it as a
    # re-acquisition would make the state NaN while the status still said tracked
    fusion = quiet_fusion()
    rest = np.array([0.0, 0.0, 9.81])
    fusion.predict(0.0, rest, np.zeros(3))
    fusion.update(0.0, np.zeros(3), IDENTITY)
    fusion.predict(2.0, rest, np.zeros(3))
    outcome = fusion.update(2.0, np.full(3, 1e200), IDENTITY)
    assert outcome.kind == GATED
    step = fusion.estimate()
    assert np.isfinite(step.position).all() and np.isfinite(fusion.P).all()
    # a plausible fix is still accepted as the re-acquisition afterwards
    assert fusion.update(2.01, np.zeros(3), IDENTITY).kind == REACQUIRED


def test_a_non_unit_quaternion_gives_a_position_only_fix():
    fusion = quiet_fusion()
    fusion.predict(0.0, np.array([0.0, 0.0, 9.81]), np.zeros(3))
    fusion.update(0.0, np.zeros(3), IDENTITY)
    fusion.predict(0.01, np.array([0.0, 0.0, 9.81]), np.zeros(3))
    # twice a 90-degree turn about z: not unit, so the orientation must not jump to it
    turned = 2.0 * np.array([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)])
    assert fusion.update(0.01, np.zeros(3), turned).kind == ACCEPTED
    np.testing.assert_allclose(np.abs(fusion.estimate().orientation), IDENTITY, atol=1e-6)
