"""kfusion.Tracker: validation, bad-input behaviour, status rules, health counters, snapshots,
out-of-step streams, streaming == batch, the position bound and the ``stream`` command."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

from kfusion.cli import main
from kfusion.commands.stream import format_estimate, stream_lines, stream_recording
from kfusion.kalman import KalmanFusion, KalmanParameters, run_filter
from kfusion.profiles import MPU9255
from kfusion.recording import write_recording
from kfusion.safety import protective_separation_distance
from kfusion.simulate import OcclusionSpec, simulate
from kfusion.streamhealth import NO_IMU_ACCELERATION_DENSITY
from kfusion.tracker import (
    Estimate,
    Tracker,
    TrackerOptions,
    TrackerSnapshot,
    position_bound,
    status_durations,
    tracking_status,
)

GRAVITY = np.array([0.0, -9.81, 0.0])
REST_FORCE = -GRAVITY  # identity orientation, at rest: f = R^T (0 - g)
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
HOME = np.array([0.2, 1.0, 0.3])


def make_tracker(**kwargs) -> Tracker:
    return Tracker(imu_to_body=IDENTITY, gravity=GRAVITY, **kwargs)


def rest_events(start: float, stop: float, *, rng: np.random.Generator, mocap: bool = True,
                imu: bool = True, imu_rate: int = 1000, mocap_rate: int = 100) -> list[tuple]:
    """A still limb at HOME from ``start`` to ``stop`` (s): ("imu", t, acc, gyro) and
    ("mocap", t, position, quaternion) in time order, IMU first."""
    steps = round((stop - start) * imu_rate)
    every = imu_rate // mocap_rate
    events: list[tuple] = []
    for k in range(steps + 1):
        t = start + k / imu_rate
        if imu:
            events.append(("imu", t, REST_FORCE + 0.003 * rng.standard_normal(3),
                           1e-4 * rng.standard_normal(3)))
        if mocap and k % every == 0:
            events.append(("mocap", t, HOME + 3e-4 * rng.standard_normal(3), IDENTITY))
    return events


def feed_rest(tracker: Tracker, start: float, stop: float, *, rng: np.random.Generator,
              **kwargs) -> None:
    """Push :func:`rest_events` to ``tracker``."""
    for kind, t, first, second in rest_events(start, stop, rng=rng, **kwargs):
        if kind == "imu":
            tracker.push_imu(t, first, second)
        else:
            tracker.push_mocap(t, first, second)


@pytest.fixture(scope="module")
def recording():
    return simulate("arm_lift", seed=3, duration=8.0, imu_rate=500,
                    occlusions=OcclusionSpec(gap_range=(0.2, 0.6), spacing=1.0)).recording


def run_stream(tracker: Tracker, recording) -> list[Estimate]:
    return [estimate for _, estimate in stream_recording(recording, tracker)]


# ------------------------------------------------------------------------------------------
# Wrong shapes and types: ValueError naming expected and received
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("call", "match"), [
    (lambda tr: tr.push_imu(0.0, [1.0, 2.0], [0, 0, 0]),
     r"push_imu: acc: expected 3 finite numbers \(m/s\^2\), got shape \(2,\)"),
    (lambda tr: tr.push_imu(0.0, [0, 0, 9.8], np.zeros((3, 1))),
     r"push_imu: gyro: expected 3 finite numbers \(rad/s\), got shape \(3, 1\)"),
    (lambda tr: tr.push_imu(0.0, "abc", [0, 0, 0]),
     r"push_imu: acc: expected 3 finite numbers \(m/s\^2\), got str of dtype <U3"),
    (lambda tr: tr.push_imu(0.0, [0, None, 1], [0, 0, 0]),
     r"push_imu: acc: expected 3 finite numbers \(m/s\^2\), got list"),
    (lambda tr: tr.push_imu(0.0, [1 + 1j, 0, 0], [0, 0, 0]),
     r"push_imu: acc: expected 3 finite numbers .* got list of dtype complex128"),
    (lambda tr: tr.push_imu("0.1", [0, 0, 9.8], [0, 0, 0]),
     r"push_imu: t: expected a time in s \(a real number\), got str"),
    (lambda tr: tr.push_imu(True, [0, 0, 9.8], [0, 0, 0]),
     r"push_imu: t: expected a time in s \(a real number\), got bool"),
    (lambda tr: tr.push_mocap(0.0, [1.0, 2.0, 3.0, 4.0], IDENTITY),
     r"push_mocap: position: expected 3 finite numbers \(m\), got shape \(4,\)"),
    (lambda tr: tr.push_mocap(0.0, HOME, [1.0, 0.0, 0.0]),
     r"push_mocap: quaternion: expected 4 finite numbers \(\[w, x, y, z\]\), got shape \(3,\)"),
    (lambda tr: tr.push_mocap(None, HOME, IDENTITY),
     r"push_mocap: t: expected a time in s \(a real number\), got NoneType"),
    (lambda tr: tr.estimate("now"),
     r"estimate: t: expected a time in s \(a real number\), got str"),
    (lambda tr: tr.restore({"state": 1}),
     r"restore: expected a TrackerSnapshot, got dict"),
])
def test_wrong_shapes_and_types_raise_value_error(call, match):
    tracker = make_tracker()
    with pytest.raises(ValueError, match=match):
        call(tracker)
    health = tracker.health
    assert health.imu_pushed == 0 and health.mocap_pushed == 0  # nothing was counted as pushed


@pytest.mark.parametrize(("kwargs", "match"), [
    (dict(imu_to_body=[1, 0, 0], gravity=GRAVITY),
     r"Tracker: imu_to_body: expected 4 finite numbers \(\[w, x, y, z\]\), got shape \(3,\)"),
    (dict(imu_to_body=[2, 0, 0, 0], gravity=GRAVITY),
     r"Tracker: imu_to_body: expected a unit quaternion \[w, x, y, z\], got norm 2"),
    (dict(imu_to_body=IDENTITY, gravity=[0, -9810, 0]),
     r"Tracker: gravity: expected a length of about 9.81 m/s\^2 \(between 9.7 and 9.9\), "
     r"got 9810"),
    (dict(imu_to_body=IDENTITY, gravity=GRAVITY, method="ukf"),
     r"Tracker: method: expected one of \['kalman', 'baseline'\], got 'ukf'"),
    (dict(imu_to_body=IDENTITY, gravity=GRAVITY, imu="bmi088"),
     r"unknown IMU profile 'bmi088'"),
    (dict(imu_to_body=IDENTITY, gravity=GRAVITY, params=3),
     r"Tracker: params: expected KalmanParameters or a mapping for method 'kalman', got int"),
    (dict(imu_to_body=IDENTITY, gravity=GRAVITY, options={"max_delay": 1}),
     r"TrackerOptions: unknown key 'max_delay'"),
    (dict(imu_to_body=IDENTITY, gravity=GRAVITY, options={"fix_timeout_s": -1}),
     r"TrackerOptions.fix_timeout_s: expected a finite number > 0, got -1"),
])
def test_bad_constructor_arguments(kwargs, match):
    with pytest.raises(ValueError, match=match):
        Tracker(**kwargs)


# ------------------------------------------------------------------------------------------
# Bad values: rejected with a reason and counted; state untouched
# ------------------------------------------------------------------------------------------


def tracked_tracker(seconds: float = 1.0, **kwargs) -> Tracker:
    tracker = make_tracker(**kwargs)
    feed_rest(tracker, 0.0, seconds, rng=np.random.default_rng(0))
    assert tracker.estimate(tracker.newest_time).status == "tracked"
    return tracker


def assert_same_estimate(first: Estimate, second: Estimate) -> None:
    assert first.t == second.t and first.status == second.status
    for name in ("position", "velocity", "covariance", "std"):
        assert np.array_equal(getattr(first, name), getattr(second, name), equal_nan=True), name


@pytest.mark.parametrize(("acc", "gyro"), [
    ([np.nan, 0, 9.81], [0, 0, 0]), ([0, np.inf, 9.81], [0, 0, 0]),
    ([0, 9.81, 0], [0, -np.inf, 0]), ([0, 9.81, 0], [np.nan, np.nan, np.nan]),
])
def test_non_finite_imu_sample_is_rejected_and_state_untouched(acc, gyro):
    tracker = tracked_tracker()
    before = tracker.estimate(tracker.newest_time)
    snapshot = tracker.snapshot()
    outcome = tracker.push_imu(1.0005, acc, gyro)
    assert (outcome.accepted, outcome.reason) == (False, "non_finite")
    assert_same_estimate(tracker.estimate(tracker.newest_time), before)
    assert tracker.health.imu_rejected["non_finite"] == 1
    # the next good sample continues exactly as if the bad one never came
    other = make_tracker()
    other.restore(snapshot)
    sample = (1.001, REST_FORCE, np.zeros(3))
    tracker.push_imu(*sample)
    other.push_imu(*sample)
    assert_same_estimate(tracker.estimate(tracker.newest_time), other.estimate(other.newest_time))


def test_non_finite_time_is_rejected():
    tracker = tracked_tracker()
    assert tracker.push_imu(math.nan, REST_FORCE, np.zeros(3)).reason == "non_finite"
    assert tracker.push_mocap(math.inf, HOME, IDENTITY).reason == "non_finite"
    assert tracker.health.mocap_rejected["non_finite"] == 1


def test_time_order_duplicates_and_conflicts():
    tracker = tracked_tracker()
    t_last = 1.0
    # IMU: last sample was at t = 1.0
    assert tracker.push_imu(0.5, REST_FORCE, np.zeros(3)).reason == "out_of_order"
    assert tracker.push_imu(t_last, REST_FORCE, np.zeros(3)).reason == "conflicting_duplicate"
    good = (1.001, REST_FORCE + 0.01, np.full(3, 1e-3))
    assert tracker.push_imu(*good).reason == "accepted"
    assert tracker.push_imu(*good).reason == "duplicate"
    # mocap: last frame at t = 1.0
    assert tracker.push_mocap(0.99, HOME, IDENTITY).reason == "out_of_order"
    assert tracker.push_mocap(t_last, HOME + 1e-3, IDENTITY).reason == "conflicting_duplicate"
    health = tracker.health
    assert health.imu_rejected["out_of_order"] == 1
    assert health.imu_rejected["conflicting_duplicate"] == 1
    assert health.imu_rejected["duplicate"] == 1
    assert health.mocap_rejected["out_of_order"] == 1
    assert health.mocap_rejected["conflicting_duplicate"] == 1


def test_identical_mocap_duplicate_is_skipped():
    tracker = make_tracker()
    rng = np.random.default_rng(1)
    feed_rest(tracker, 0.0, 0.5, rng=rng)
    position = HOME + 1e-4
    tracker.push_mocap(0.505, position, IDENTITY)
    before = tracker.estimate(tracker.newest_time)
    outcome = tracker.push_mocap(0.505, position.copy(), IDENTITY.copy())
    assert (outcome.accepted, outcome.reason) == (False, "duplicate")
    assert_same_estimate(tracker.estimate(tracker.newest_time), before)
    # an occluded duplicate too
    tracker.push_mocap(0.515, None, None)
    assert tracker.push_mocap(0.515, [np.nan] * 3, None).reason == "duplicate"


def test_occluded_frames_bridge_and_nan_means_occluded():
    tracker = tracked_tracker()
    assert tracker.push_mocap(1.01, None, None).reason == "occluded"
    assert tracker.push_mocap(1.02, [np.nan, 1.0, 2.0], IDENTITY).reason == "occluded"
    tracker.push_imu(1.025, REST_FORCE, np.zeros(3))
    estimate = tracker.estimate(tracker.newest_time)
    assert estimate.status == "bridged"
    assert estimate.time_since_fix == pytest.approx(0.025)
    assert np.isfinite(estimate.position).all() and math.isfinite(estimate.bound())
    assert tracker.health.mocap_occluded == 2


def test_infinite_position_and_bad_quaternion_are_rejected():
    tracker = tracked_tracker()
    assert tracker.push_mocap(1.01, [np.inf, 0, 0], IDENTITY).reason == "non_finite"
    assert tracker.push_mocap(1.02, HOME, [1.0, 0.1, 0.0, 0.0]).reason == "bad_quaternion"
    # a missing orientation is a position-only fix
    outcome = tracker.push_mocap(1.03, HOME, None)
    assert (outcome.accepted, outcome.reason) == (True, "accepted")


def test_long_imu_dropout_is_lost_and_grows_covariance_over_the_whole_gap():
    stds = {}
    for gap in (0.2, 0.4, 0.8):
        events = rest_events(0.0, 1.0, rng=np.random.default_rng(0))
        events.append(("imu", 1.0 + gap, REST_FORCE, np.zeros(3)))
        tracker = make_tracker(options={"max_time_jump_s": 10.0})  # a pause, not a glitch
        fusion = KalmanFusion(IDENTITY, GRAVITY, KalmanParameters.from_profiles("mpu9255"))
        for kind, t, first, second in events:
            if kind == "imu":
                assert tracker.push_imu(t, first, second).accepted
                fusion.predict(t, first, second)
            else:
                tracker.push_mocap(t, first, second)
                fusion.update(t, first, second)
        # the gap was not covered by the IMU: nothing is dead-reckoned, the output is lost
        estimate = tracker.estimate(tracker.newest_time)
        assert estimate.status == "lost" and estimate.bound() == math.inf
        assert estimate.time_since_fix == pytest.approx(gap)
        health = tracker.health
        assert health.imu_dropouts == 1
        assert health.longest_imu_interval_s == pytest.approx(gap)
        # the filter's covariance grew over the real dt by the no-IMU model (nothing clamped):
        # position variance >= q^2 dt^3 / 3
        variance = float(fusion.P[0, 0])
        assert variance >= NO_IMU_ACCELERATION_DENSITY ** 2 * gap ** 3 / 3
        stds[gap] = math.sqrt(variance)
    assert stds[0.2] < stds[0.4] < stds[0.8]


def test_dropout_past_max_bridge_is_lost_then_reacquired():
    tracker = tracked_tracker(options={"max_time_jump_s": 10.0})
    tracker.push_imu(2.5, REST_FORCE, np.zeros(3))  # 1.5 s without IMU and mocap
    estimate = tracker.estimate(tracker.newest_time)
    assert estimate.status == "lost"
    assert np.isnan(estimate.position).all() and estimate.bound() == math.inf
    health = tracker.health
    assert health.lost_transitions == 1
    # the last fix and IMU sample are at 1.0 s: tracked for fix_timeout_s = 0.05 s, and the
    # IMU sample is held only 20 ms (kfusion.streamhealth.hold_horizon), so never bridged:
    # lost from 1.05 s (no IMU: nothing is dead-reckoned)
    assert health.time_lost_s == pytest.approx(1.45)
    assert health.time_bridged_s == 0.0
    outcome = tracker.push_mocap(2.5, HOME, IDENTITY)
    assert (outcome.accepted, outcome.reason) == (True, "reacquired")
    assert tracker.estimate(tracker.newest_time).status == "tracked"
    assert tracker.health.reacquisitions == 1


def test_saturated_accelerometer_is_flagged_and_its_noise_inflated():
    limit = MPU9255.accelerometer_range
    variances = {}
    for label, value in (("saturated", 0.9995 * limit), ("inside", 0.998 * limit)):
        tracker = tracked_tracker()
        outcome = tracker.push_imu(1.001, [value, 9.81, 0.0], np.zeros(3))
        assert outcome.accepted and outcome.reason == ("saturated" if label == "saturated"
                                                       else "accepted")
        tracker.push_imu(1.002, REST_FORCE, np.zeros(3))  # the held sample is propagated here
        variances[label] = float(np.trace(tracker.estimate(tracker.newest_time).covariance))
        assert tracker.health.imu_saturated == (1 if label == "saturated" else 0)
    # (range/2)^2 extra variance held for 1 ms: 1/4 dt^4 (range/2)^2 per axis
    extra = 0.25 * 1e-3**4 * (limit / 2) ** 2
    assert variances["saturated"] - variances["inside"] == pytest.approx(3 * extra, rel=0.05)


def test_mocap_jump_is_gated_and_counted():
    tracker = tracked_tracker()
    tracker.push_imu(1.001, REST_FORCE, np.zeros(3))
    outcome = tracker.push_mocap(1.01, HOME + [0.3, 0.0, 0.0], IDENTITY)
    assert (outcome.accepted, outcome.reason) == (False, "gated")
    estimate = tracker.estimate(tracker.newest_time)
    assert estimate.status == "bridged"
    assert abs(estimate.position[0] - HOME[0]) < 0.005  # the jump did not move it
    health = tracker.health
    assert health.gate_rejections == 1 == health.mocap_rejected["gated"]
    assert tracker.push_mocap(1.02, HOME, IDENTITY).reason == "accepted"
    assert tracker.estimate(tracker.newest_time).status == "tracked"


def test_status_rules_and_time_accounting():
    tracker = make_tracker()
    assert tracker.estimate(tracker.newest_time).status == "lost"  # nothing yet
    rng = np.random.default_rng(2)
    feed_rest(tracker, 0.0, 1.0, rng=rng)
    feed_rest(tracker, 1.001, 2.3, rng=rng, mocap=False)  # IMU only: 1.3 s without a fix
    health = tracker.health
    assert tracker.estimate(tracker.newest_time).status == "lost"
    assert health.time_tracked_s == pytest.approx(1.0 + 0.05)
    assert health.time_bridged_s == pytest.approx(1.0 - 0.05)
    assert health.time_lost_s == pytest.approx(0.3)
    total = health.time_tracked_s + health.time_bridged_s + health.time_lost_s
    assert total == pytest.approx(2.3)
    assert health.lost_transitions == 1
    assert health.longest_gap_s == pytest.approx(1.3)
    # extrapolation ages the estimate; earlier times are refused
    later = tracker.estimate(5.0)
    assert later.status == "lost" and later.time_since_fix == pytest.approx(4.0)
    with pytest.raises(ValueError, match=r"estimate: t: expected a time >= 2.3"):
        tracker.estimate(2.0)


def test_pure_status_functions():
    assert tracking_status(math.inf, False, fix_timeout_s=0.05, max_bridge_s=1.0) == "lost"
    assert tracking_status(0.02, True, fix_timeout_s=0.05, max_bridge_s=1.0) == "tracked"
    assert tracking_status(0.02, False, fix_timeout_s=0.05, max_bridge_s=1.0) == "bridged"
    assert tracking_status(0.06, True, fix_timeout_s=0.05, max_bridge_s=1.0) == "bridged"
    assert tracking_status(1.01, True, fix_timeout_s=0.05, max_bridge_s=1.0) == "lost"
    # fix at 10 s, fused; [9.9, 11.2]: tracked 10-10.05, bridged 10.05-11, lost 9.9-10, 11-11.2
    tracked, bridged, lost = status_durations(9.9, 11.2, 10.0, True, fix_timeout_s=0.05,
                                              max_bridge_s=1.0)
    assert (tracked, bridged, lost) == pytest.approx((0.05, 0.95, 0.3))
    assert status_durations(0, 2, -math.inf, False, fix_timeout_s=0.05,
                            max_bridge_s=1.0) == (0.0, 0.0, 2.0)


# ------------------------------------------------------------------------------------------
# Counters are consistent; estimates are never NaN with a valid status
# ------------------------------------------------------------------------------------------


def test_counters_add_up_on_a_simulated_recording(recording):
    tracker = Tracker.from_recording_info(recording.info)
    estimates = run_stream(tracker, recording)
    health = tracker.health
    assert health.imu_pushed == len(recording.imu) == health.imu_accepted
    assert health.mocap_pushed == len(recording.mocap)
    assert health.mocap_pushed == (health.mocap_fused + health.mocap_occluded
                                   + sum(health.mocap_rejected.values()))
    assert health.mocap_occluded == int((~recording.mocap.visible).sum())
    for estimate in estimates:
        if estimate.status != "lost":
            assert np.isfinite(estimate.position).all()
            assert np.isfinite(estimate.covariance).all()
            assert 0 < estimate.bound() < 0.1


# ------------------------------------------------------------------------------------------
# Cross-checks: streaming == batch, snapshot/restore, out-of-step streams
# ------------------------------------------------------------------------------------------


def test_streaming_equals_the_batch_kalman_filter_exactly(recording):
    tracker = Tracker.from_recording_info(recording.info)
    estimates = run_stream(tracker, recording)
    batch = run_filter(recording).result
    position = np.array([e.position for e in estimates])
    std = np.array([e.std for e in estimates])
    status = np.array([e.status for e in estimates])
    assert np.array_equal(status, batch.status)
    live = status != "lost"
    assert np.array_equal(position[live], batch.position[live])
    assert np.array_equal(std[live], batch.std[live])


def events(recording):
    """The recording's samples in time order (IMU first at equal times)."""
    imu, mocap = recording.imu, recording.mocap
    merged = [(float(t), 0, i) for i, t in enumerate(imu.t)]
    merged += [(float(t), 1, i) for i, t in enumerate(mocap.t)]
    return sorted(merged)


def push(tracker: Tracker, recording, event) -> None:
    t, kind, index = event
    if kind == 0:
        tracker.push_imu(t, recording.imu.accelerometer[index], recording.imu.gyroscope[index])
    else:
        visible = recording.mocap.visible[index]
        tracker.push_mocap(t, recording.mocap.position[index] if visible else None,
                           recording.mocap.quaternion[index] if visible else None)


@pytest.mark.parametrize("method", ["kalman", "baseline"])
def test_snapshot_restore_continues_bit_exactly(recording, method):
    merged = events(recording)
    half = len(merged) // 2
    uninterrupted = Tracker.from_recording_info(recording.info, method=method)
    first = Tracker.from_recording_info(recording.info, method=method)
    expected = []
    for event in merged:
        push(uninterrupted, recording, event)
        expected.append(uninterrupted.estimate(uninterrupted.newest_time))
    for event in merged[:half]:
        push(first, recording, event)
    snapshot = first.snapshot()
    assert isinstance(snapshot, TrackerSnapshot) and snapshot.method == method
    for event in merged[half:half + 50]:  # keep using the original: the snapshot must not move
        push(first, recording, event)
    second = Tracker.from_recording_info(recording.info, method=method)
    second.restore(snapshot)
    for index, event in enumerate(merged[half:], start=half):
        push(second, recording, event)
        assert_same_estimate(second.estimate(second.newest_time), expected[index])
    assert second.health == uninterrupted.health


def test_restore_refuses_a_snapshot_from_another_configuration(recording):
    tracker = Tracker.from_recording_info(recording.info)
    other = Tracker.from_recording_info(recording.info, options={"fix_timeout_s": 0.1})
    with pytest.raises(ValueError, match=r"restore: expected a snapshot from a tracker with the"):
        other.restore(tracker.snapshot())


def test_mocap_lagging_the_imu_gives_the_in_order_result(recording):
    """Each mocap frame pushed 6 ms late (after later IMU samples) is fused in time order by
    replay: the estimates match the in-order run bit for bit."""
    lag = 0.006
    merged = events(recording)
    in_order = Tracker.from_recording_info(recording.info)
    expected = {}
    for event in merged:
        push(in_order, recording, event)
        if event[1] == 0:
            expected[event[0]] = in_order.estimate(in_order.newest_time)
    delayed = sorted(merged, key=lambda e: (e[0] + (lag if e[1] == 1 else 0.0), e[1]))
    late = Tracker.from_recording_info(recording.info)
    frames_pushed = 0
    compared = 0
    for event in delayed:
        push(late, recording, event)
        frames_pushed += event[1] == 1
        # compare after an IMU sample at t once the late run holds the same samples as the
        # in-order run did then: every frame at or before t, none after
        if event[1] == 0 and frames_pushed == int(np.sum(recording.mocap.t <= event[0])):
            assert_same_estimate(late.estimate(late.newest_time), expected[event[0]])
            compared += 1
    assert compared > len(recording.imu) // 6
    assert late.health.replays > 0
    assert late.health.mocap_rejected["too_late"] == 0


def test_samples_older_than_max_delay_are_too_late():
    tracker = tracked_tracker(options={"max_delay_s": 0.05})
    feed_rest(tracker, 1.001, 1.2, rng=np.random.default_rng(3), mocap=False)
    assert tracker.push_mocap(1.1, HOME, IDENTITY).reason == "too_late"
    assert tracker.push_mocap(1.16, HOME, IDENTITY).reason == "accepted"
    no_replay = tracked_tracker(options={"max_delay_s": 0.0})
    no_replay.push_imu(1.005, REST_FORCE, np.zeros(3))
    assert no_replay.push_mocap(1.004, HOME, IDENTITY).reason == "too_late"
    assert no_replay.health.mocap_rejected["too_late"] == 1


def test_reset_clears_the_state_and_keeps_the_counters():
    tracker = tracked_tracker()
    pushed = tracker.health.imu_pushed
    tracker.reset()
    assert tracker.estimate(tracker.newest_time).status == "lost"
    assert tracker.push_imu(0.0, REST_FORCE, np.zeros(3)).accepted  # earlier time is fine now
    assert tracker.push_mocap(0.0, HOME, IDENTITY).accepted
    health = tracker.health
    assert health.resets == 1 and health.imu_pushed == pushed + 1


def test_non_finite_state_restarts_the_estimator():
    tracker = tracked_tracker(options={"max_time_jump_s": 1e300})  # let the stamp through
    with np.errstate(all="ignore"):
        outcome = tracker.push_imu(1e200, REST_FORCE, np.zeros(3))  # dt overflows the model
    assert outcome.accepted
    estimate = tracker.estimate(tracker.newest_time)
    assert estimate.status == "lost" and np.isnan(estimate.position).all()
    assert tracker.health.state_resets == 1
    assert tracker.push_mocap(1e200, HOME, IDENTITY).accepted
    tracker.push_imu(1e200 + 2**600, REST_FORCE, np.zeros(3))
    assert tracker.estimate(tracker.newest_time).status in ("tracked", "bridged", "lost")


# ------------------------------------------------------------------------------------------
# Construction from YAML, recording info and parameter objects; the baseline
# ------------------------------------------------------------------------------------------


def test_from_yaml(tmp_path: Path):
    path = tmp_path / "tracker.yaml"
    path.write_text("imu_to_body: [1, 0, 0, 0]\ngravity: [0, -9.81, 0]\nmethod: kalman\n"
                    "imu: um7\nparameters:\n  max_bridge_s: 0.5\n  gate_probability: 0.999\n"
                    "tracker:\n  fix_timeout_s: 0.03\n")
    tracker = Tracker.from_yaml(path)
    assert tracker.params.max_bridge_s == 0.5 and tracker.params.gate_probability == 0.999
    assert tracker.params.accelerometer_noise_density == pytest.approx(
        400e-6 * 9.80665)  # from the um7 profile
    assert tracker.options.fix_timeout_s == 0.03
    assert tracker.max_bridge_s == 0.5


def test_from_yaml_reads_a_recordings_own_metadata_file():
    # recording.yaml as every command writes it, including its name: nothing to edit first
    from kfusion.datasets import broad_excerpt

    tracker = Tracker.from_yaml(broad_excerpt() / "recording.yaml")
    assert tracker.imu_profile.name == "broad" and tracker.method == "kalman"
    assert tracker.imu_clock == (-0.003, 0.0)  # BROAD's IMU lag, from the file


def test_from_yaml_takes_a_calibrated_files_clock_and_noise(tmp_path: Path):
    # what kfusion calibrate writes: the clock model and measured noise, read as the recording
    # readers read them (from_recording_info), never refused as unknown keys
    from kfusion.recording import read_info

    path = tmp_path / "recording.yaml"
    path.write_text("imu_to_body: [1, 0, 0, 0]\ngravity: [0, -9.81, 0]\nname: take 3\n"
                    "imu: mpu9255\nimu_time_offset: 1.25\nimu_clock_drift_ppm: -40.0\n"
                    "imu_noise: {accelerometer_noise_density: 0.004}\nmarkers: {A: [0, 0, 0.1]}\n")
    tracker = Tracker.from_yaml(path)
    reference = Tracker.from_recording_info(read_info(path))
    assert tracker.imu_clock == reference.imu_clock == (1.25, -40.0)
    assert tracker.imu_profile == reference.imu_profile
    assert tracker.imu_profile.accelerometer_noise_density == 0.004
    assert tracker.params == reference.params
    path.write_text("imu_to_body: [1, 0, 0, 0]\ngravity: [0, -9.81, 0]\n"
                    "imu_noise: {accelerometer_noise_density: -1}\n")
    with pytest.raises(ValueError, match=r"recording.yaml.*imu_noise.accelerometer_noise_density"):
        Tracker.from_yaml(path)


@pytest.mark.parametrize(("text", "match"), [
    ("imu_to_body: [1, 0, 0, 0]\ngravity: [0, -9.81, 0]\nmax_bridge: 1\n",
     r"tracker.yaml: unknown key 'max_bridge'; expected some of \['imu_to_body'"),
    ("imu_to_body: [1, 0, 0, 0]\n", r"tracker.yaml: missing key 'gravity'"),
    ("imu_to_body: [1, 0, 0, 0]\ngravity: [0, -9.81, 0]\nparameters: {gate: 0.9}\n",
     r"tracker.yaml: parameters: KalmanParameters: unknown key 'gate'"),
    ("imu_to_body: [1, 0, 0, 0]\ngravity: [0, -9.81, 0]\ntracker: {max_delay_s: -1}\n",
     r"tracker.yaml: tracker: TrackerOptions.max_delay_s: expected a finite number >= 0"),
    ("imu_to_body: [1, 0, 0, 0]\ngravity: [0, -9.81, 0]\nimu: bmi088\n",
     r"tracker.yaml: imu: unknown IMU profile 'bmi088'"),
    ("imu_to_body: [1, 0, 0]\ngravity: [0, -9.81, 0]\n",
     r"tracker.yaml: Tracker: imu_to_body: expected 4 finite numbers"),
    ("[1, 2]\n", r"tracker.yaml: expected a mapping with keys"),
])
def test_from_yaml_errors_name_the_file_and_key(tmp_path: Path, text, match):
    path = tmp_path / "tracker.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        Tracker.from_yaml(path)


def test_parameter_objects_and_recording_info(recording):
    params = KalmanParameters.from_profiles("mpu9255", max_bridge_s=0.4)
    tracker = Tracker.from_recording_info(recording.info, params=params)
    assert tracker.params is params and tracker.max_bridge_s == 0.4
    options = TrackerOptions(max_delay_s=0.0)
    assert Tracker(IDENTITY, GRAVITY, options=options).options is options


def test_baseline_has_no_bound_and_its_distance_is_unknown(recording):
    tracker = Tracker.from_recording_info(recording.info, method="baseline")
    estimates = run_stream(tracker, recording)
    live = [e for e in estimates if e.status != "lost"]
    assert live, "the baseline should track part of the recording"
    for estimate in live:
        assert np.isfinite(estimate.position).all()
        assert np.isnan(estimate.covariance).all() and estimate.bound(0.99) == math.inf
    distance = protective_separation_distance(
        live[-1], robot_speed=1.0, reaction_time=0.1, stopping_time=0.2, stopping_distance=0.1,
        robot_position_uncertainty=0.0)
    assert not distance.known and distance.value == math.inf
    assert "no usable position uncertainty" in distance.reason


# ------------------------------------------------------------------------------------------
# The bound
# ------------------------------------------------------------------------------------------


def test_position_bound_hand_value_and_unknown():
    covariance = np.diag([4e-6, 1e-6, 1e-6])  # lambda_max = 4e-6 m^2
    expected = 2e-3 * math.sqrt(chi2.ppf(0.99, 3))  # 6.736 mm
    assert position_bound(covariance, 0.99) == pytest.approx(expected, rel=1e-12)
    assert expected == pytest.approx(6.736e-3, abs=1e-6)
    assert position_bound(np.full((3, 3), np.nan)) == math.inf
    with pytest.raises(ValueError, match=r"confidence: expected a probability in \(0, 1\)"):
        position_bound(covariance, 1.5)
    with pytest.raises(ValueError, match=r"covariance: expected shape \(3, 3\), got \(2, 2\)"):
        position_bound(np.eye(2))


@pytest.mark.parametrize("confidence", [0.9, 0.99])
def test_position_bound_coverage_by_sampling(confidence):
    rng = np.random.default_rng(11)
    n = 200_000
    isotropic = np.eye(3) * 1e-6
    a = rng.standard_normal((3, 3))
    anisotropic = a @ a.T * 1e-6 + np.eye(3) * 1e-8
    for covariance, exact in ((isotropic, True), (anisotropic, False)):
        samples = rng.multivariate_normal(np.zeros(3), covariance, size=n)
        radius = position_bound(covariance, confidence)
        coverage = float(np.mean(np.linalg.norm(samples, axis=1) <= radius))
        tolerance = 4 * math.sqrt(confidence * (1 - confidence) / n)
        if exact:
            assert coverage == pytest.approx(confidence, abs=tolerance)
        else:
            assert coverage >= confidence - tolerance  # conservative


# ------------------------------------------------------------------------------------------
# The stream command
# ------------------------------------------------------------------------------------------


def test_stream_lines_and_format(recording):
    lines = stream_lines(recording, count=4, every=25)
    assert len(lines) == 4
    assert lines[0].startswith("t=0.000 s  status=tracked")
    assert all("bound99=" in line and "since_fix=" in line for line in lines)
    lost = Estimate(t=1.0, position=np.full(3, np.nan), velocity=np.full(3, np.nan),
                    covariance=np.full((3, 3), np.nan), std=np.full(3, np.nan), status="lost",
                    time_since_fix=math.inf, method="kalman")
    text = format_estimate(lost, 0.999)
    assert "pos=unknown" in text and "bound99_9=unknown" in text and "since_fix=never" in text
    with pytest.raises(ValueError, match=r"every: expected a positive integer, got 0"):
        stream_lines(recording, every=0)


def test_stream_command_prints_lines(recording, tmp_path, capsys):
    folder = write_recording(recording, tmp_path / "rec")
    assert main(["stream", str(folder), "--count", "3", "--every", "10", "--health"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert sum(line.startswith("t=") for line in out) == 3
    assert any(line.startswith("imu_accepted:") for line in out)
    assert main(["stream", str(folder), "--every", "0"]) == 2
