"""Late arrival (issue 11 §3): whatever order the two streams arrive in (within ``max_delay_s``),
the Tracker gives the in-order result bit for bit, and a late sample costs a bounded amount of
work: IMU samples behind mocap frames wait until a frame arrives or the state is read, then
the checkpoint just before them is restored once, each sample is fused once, and each such frame
is fused again once, however many IMU samples arrive behind it.

The reference is the same Tracker fed the fusion order (:func:`kfusion.kalman.events.event_key`).
A run in another order is compared with it whenever the samples that have arrived are exactly
a prefix of the fusion order (every event up to some point, none after): the estimate at the
newest time must be the one the in-order run gave after that prefix, ``==`` on every array.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kfusion.kalman.events import IMU_STREAM, MOCAP_STREAM, merge_events
from kfusion.recording import ImuSamples, MocapFrames, Recording
from kfusion.simulate import OcclusionSpec, simulate
from kfusion.tracker import Estimate, Tracker

Order = list[tuple[int, int]]


def excerpt(recording: Recording, stop: float) -> Recording:
    """The samples before ``stop`` s."""
    imu, mocap = recording.imu, recording.mocap
    keep_imu, keep_mocap = imu.t < stop, mocap.t < stop
    return dataclasses.replace(
        recording,
        imu=ImuSamples(t=imu.t[keep_imu], accelerometer=imu.accelerometer[keep_imu],
                       gyroscope=imu.gyroscope[keep_imu]),
        mocap=MocapFrames(t=mocap.t[keep_mocap], position=mocap.position[keep_mocap],
                          quaternion=mocap.quaternion[keep_mocap]))


@pytest.fixture(scope="module")
def recording():
    """3 s of arm_lift, IMU at 1 kHz and mocap at 100 Hz (every 10th IMU stamp equals a frame
    time), with occlusions."""
    return excerpt(simulate("arm_lift", seed=5, duration=5.0, imu_rate=1000.0,
                            mocap_rate=100.0,
                            occlusions=OcclusionSpec(gap_range=(0.1, 0.3), spacing=0.8)
                            ).recording, 3.0)


def fusion_order(recording) -> Order:
    return [(stream, index) for _, stream, index in
            merge_events(recording.imu.t.tolist(), recording.mocap.t.tolist())]


def arrival_order(recording, imu_delay: np.ndarray, mocap_delay: np.ndarray) -> Order:
    """Samples arriving at stamp + delay (each stream kept in its own order; at equal arrival
    times the mocap frame first, the harder case)."""
    imu_arrival = np.maximum.accumulate(recording.imu.t + imu_delay)
    mocap_arrival = np.maximum.accumulate(recording.mocap.t + mocap_delay)
    arrivals = sorted([(float(t), 1, IMU_STREAM, i) for i, t in enumerate(imu_arrival)]
                      + [(float(t), 0, MOCAP_STREAM, j) for j, t in enumerate(mocap_arrival)])
    return [(stream, index) for _, _, stream, index in arrivals]


def push(tracker: Tracker, recording, stream: int, index: int) -> None:
    if stream == IMU_STREAM:
        tracker.push_imu(recording.imu.t[index], recording.imu.accelerometer[index],
                         recording.imu.gyroscope[index])
        return
    mocap = recording.mocap
    visible = bool(mocap.visible[index])
    tracker.push_mocap(mocap.t[index], mocap.position[index] if visible else None,
                       mocap.quaternion[index] if visible else None)


def assert_same(actual: Estimate, expected: Estimate) -> None:
    assert actual.t == expected.t and actual.status == expected.status
    assert actual.time_since_fix == expected.time_since_fix
    for name in ("position", "velocity", "covariance", "std"):
        np.testing.assert_array_equal(getattr(actual, name), getattr(expected, name),
                                      err_msg=name)


def in_order_run(recording) -> tuple[Tracker, list[Estimate]]:
    """The reference: the fusion order; the estimate after each prefix."""
    tracker = Tracker.from_recording_info(recording.info)
    after = []
    for stream, index in fusion_order(recording):
        push(tracker, recording, stream, index)
        after.append(tracker.estimate(tracker.newest_time))
    return tracker, after


@pytest.fixture(scope="module")
def reference(recording):
    return in_order_run(recording)


def compare_run(recording, reference, order: Order, tracker: Tracker | None = None,
                reads: np.ndarray | None = None) -> int:
    """Push ``order``; compare with the in-order run at every complete prefix; the number of
    comparisons. The final health counters must equal the in-order run's (replays aside).
    ``reads`` (bool per push): also read the estimate at the newest time after that push
    (a read fuses deferred samples, whether or not the prefix is complete)."""
    in_order, after = reference
    rank = {event: position for position, event in enumerate(fusion_order(recording))}
    tracker = tracker or Tracker.from_recording_info(recording.info)
    arrived = np.zeros(len(rank), dtype=bool)
    complete, highest, compared = 0, -1, 0
    for number, (stream, index) in enumerate(order):
        push(tracker, recording, stream, index)
        if reads is not None and reads[number]:
            tracker.estimate(tracker.newest_time)
        position = rank[(stream, index)]
        arrived[position] = True
        highest = max(highest, position)
        while complete < len(arrived) and arrived[complete]:
            complete += 1
        if highest == complete - 1:
            assert_same(tracker.estimate(tracker.newest_time), after[highest])
            compared += 1
    assert_same(tracker.estimate(tracker.newest_time), after[-1])
    expected = in_order.health.as_dict()
    health = tracker.health.as_dict()
    for counts in (expected, health):
        counts.pop("replays")
    assert health == expected
    return compared


def test_mocap_first_at_the_same_stamp_gives_the_in_order_result(recording, reference):
    """Every frame arrives before the IMU sample with its stamp (and, 4.5 ms early, before the
    four samples before it): bit for bit the in-order result."""
    for early in (0.0, 0.0045):
        order = arrival_order(recording, np.zeros(len(recording.imu)),
                              np.full(len(recording.mocap), -early))
        assert order != fusion_order(recording)
        assert compare_run(recording, reference, order) > len(recording.mocap) // 2


def test_imu_first_mocap_lagging_gives_the_in_order_result(recording, reference):
    """Every frame arrives 7 ms late, behind the IMU samples after it."""
    order = arrival_order(recording, np.zeros(len(recording.imu)),
                          np.full(len(recording.mocap), 0.007))
    assert compare_run(recording, reference, order) > len(recording.imu) // 4


def test_random_interleavings_within_max_delay_give_the_in_order_result(recording, reference):
    rng = np.random.default_rng(4)
    for jitter in (0.005, 0.04):
        order = arrival_order(recording, rng.uniform(0.0, jitter, len(recording.imu)),
                              rng.uniform(0.0, jitter, len(recording.mocap)))
        compare_run(recording, reference, order)


class CountingEstimator:
    """Wraps a Tracker's estimator and counts its predict and update calls."""

    def __init__(self, estimator) -> None:
        self._estimator = estimator
        self.predicts = 0
        self.updates = 0

    def predict(self, *args):
        self.predicts += 1
        return self._estimator.predict(*args)

    def update(self, *args):
        self.updates += 1
        return self._estimator.update(*args)

    def __getattr__(self, name):
        return getattr(self._estimator, name)


def counting_tracker(recording) -> tuple[Tracker, CountingEstimator]:
    tracker = Tracker.from_recording_info(recording.info)
    counter = CountingEstimator(tracker._estimator)
    tracker._estimator = counter
    return tracker, counter


@pytest.mark.parametrize("early", [0.0, 0.0045, 0.0095])
def test_frames_ahead_of_the_imu_cost_one_restore_and_one_refusion(recording, early):
    """Frames ``early`` s ahead of the IMU (0, 4 or 9 IMU samples behind each): no IMU sample
    is fused twice, each frame with a sample behind it is fused at most twice (once when it
    arrives, for its outcome, once when the IMU passes it) and causes one restore, however many
    samples arrive behind it."""
    imu, mocap = recording.imu, recording.mocap
    order = arrival_order(recording, np.zeros(len(imu)), np.full(len(mocap), -early))
    tracker, counter = counting_tracker(recording)
    for stream, index in order:
        push(tracker, recording, stream, index)
        if stream == MOCAP_STREAM:
            tracker.estimate(tracker.newest_time)  # a reader at frame rate
    tracker.estimate(tracker.newest_time)
    assert counter.predicts == len(imu)
    # a frame has an IMU sample behind it when one has a stamp in [t - early, t]
    behind = np.searchsorted(imu.t, mocap.t, side="right") \
        - np.searchsorted(imu.t, mocap.t - early - 1e-12, side="left")
    frames_undone = int((behind > 0).sum())
    assert frames_undone > len(mocap) - 5
    assert tracker.health.replays == frames_undone
    assert counter.updates == len(mocap) + frames_undone


def test_a_late_frame_finds_the_imu_samples_after_it_waiting(recording):
    """Frames 7 ms late (IMU at 1 kHz): the IMU samples past the time the next frame is
    expected wait for it (up to ``checkpoint_interval_s``, 20 ms), so the frame lands in
    order: no restore (but for the first frames, before the frame period is known), no IMU
    sample fused twice, no frame fused twice."""
    imu, mocap = recording.imu, recording.mocap
    order = arrival_order(recording, np.zeros(len(imu)), np.full(len(mocap), 0.007))
    tracker, counter = counting_tracker(recording)
    for stream, index in order:
        push(tracker, recording, stream, index)
    tracker.estimate(tracker.newest_time)
    assert tracker.health.replays <= 2
    assert counter.predicts - len(imu) <= 2 * (7 + 10)  # each: its lag and a frame period
    assert counter.updates == len(mocap)


def test_a_frame_later_than_the_wait_replays_only_the_samples_of_its_lag(recording):
    """Frames 7 ms late with samples waiting only 3 ms (``checkpoint_interval_s``): the
    checkpoint taken just before the first IMU sample past the frame's expected time is
    restored and only the samples of its lag are fused again, at most 7 per frame (never the
    whole buffer); no frame is fused twice."""
    imu, mocap = recording.imu, recording.mocap
    order = arrival_order(recording, np.zeros(len(imu)), np.full(len(mocap), 0.007))
    tracker = Tracker.from_recording_info(recording.info,
                                          options={"checkpoint_interval_s": 0.003})
    counter = CountingEstimator(tracker._estimator)
    tracker._estimator = counter
    for stream, index in order:
        push(tracker, recording, stream, index)
    tracker.estimate(tracker.newest_time)
    replayed = counter.predicts - len(imu)
    assert tracker.health.replays == len(mocap)
    assert replayed <= len(mocap) * 7
    assert counter.updates == len(mocap)


def test_an_imu_that_stops_behind_a_frame_leaves_an_honest_status(recording, reference):
    """An IMU sample arrives behind a frame (it waits, and the frame is fused again) and then
    the IMU stops while frames go on: every estimate equals the in-order run's (the waiting
    sample is fused when the state is read or the next frame arrives), tracked while the fixes
    come, and a gap after the IMU stopped is lost, not bridged."""
    imu, mocap = recording.imu, recording.mocap
    stop = 1.2
    imu_rows = np.flatnonzero(imu.t <= stop)
    frame_rows = np.flatnonzero(mocap.t <= stop + 0.3)
    events = [(t, stream, index) for t, stream, index in merge_events(
        imu.t[imu_rows].tolist(), mocap.t[frame_rows].tolist())]
    in_order = Tracker.from_recording_info(recording.info)
    late = Tracker.from_recording_info(recording.info)
    for _, stream, index in events:
        push(in_order, recording, stream, index)
    frame_at_stop = int(np.flatnonzero(mocap.t == stop)[0])
    assert mocap.visible[frame_at_stop]
    for _, stream, index in events:
        if (stream, index) == (IMU_STREAM, int(imu_rows[-1])):
            continue  # the last IMU sample arrives after the frame with its stamp
        push(late, recording, stream, index)
        if (stream, index) == (MOCAP_STREAM, frame_at_stop):
            push(late, recording, IMU_STREAM, int(imu_rows[-1]))
            assert len(late._pending) == 1  # the sample waits; the frame is fused again
    for now in (stop + 0.3, stop + 0.31, stop + 0.6, stop + 2.0):
        expected, actual = in_order.estimate(now), late.estimate(now)
        assert_same(actual, expected)
    assert late.estimate(stop + 0.3).status == "tracked"  # fixes without IMU still track
    assert late.estimate(stop + 0.6).status == "lost"  # the gap after them is not bridged
    assert late.estimate(stop + 2.0).bound() == math.inf
    expected, health = in_order.health.as_dict(), late.health.as_dict()
    assert (expected.pop("replays"), health.pop("replays")) == (0, 1)
    assert health == expected


def test_the_frame_pending_after_a_late_sample_counts_in_health_and_snapshots(recording):
    """Reads fuse a pending frame first: health counts it and a snapshot holds it."""
    imu, mocap = recording.imu, recording.mocap
    tracker = Tracker.from_recording_info(recording.info)
    frame = 20  # 0.2 s
    for _, stream, index in merge_events(imu.t[imu.t < mocap.t[frame]].tolist(),
                                         mocap.t[:frame + 1].tolist()):
        push(tracker, recording, stream, index)
    push(tracker, recording, IMU_STREAM, int(np.flatnonzero(imu.t == mocap.t[frame])[0]))
    assert len(tracker._pending) == 1
    health = tracker.health
    assert health.mocap_fused + health.mocap_occluded + sum(health.mocap_rejected.values()) \
        == health.mocap_pushed == frame + 1
    copy = Tracker.from_recording_info(recording.info)
    copy.restore(tracker.snapshot())
    assert_same(copy.estimate(1.0), tracker.estimate(1.0))


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(imu_lag=st.floats(0.0, 0.03), mocap_lag=st.floats(0.0, 0.03),
       jitter=st.floats(0.0, 0.04), seed=st.integers(0, 2**16),
       read_probability=st.sampled_from([0.0, 0.1, 1.0]),
       checkpoint_interval=st.sampled_from([0.02, 0.002]))
def test_any_arrival_order_within_max_delay_gives_the_in_order_result(
        short_recording, short_reference, imu_lag, mocap_lag, jitter, seed, read_probability,
        checkpoint_interval):
    """Hypothesis: constant lags of either stream plus random jitter (all within the default
    ``max_delay_s`` of 0.1 s), reads at random moments (each fuses the deferred samples) and
    checkpoint intervals of 20 or 2 ms (the span after which deferred samples are fused even
    without a read): bit for bit the in-order result at every complete prefix."""
    rng = np.random.default_rng(seed)
    imu, mocap = short_recording.imu, short_recording.mocap
    order = arrival_order(short_recording, imu_lag + rng.uniform(0.0, jitter, len(imu)),
                          mocap_lag + rng.uniform(0.0, jitter, len(mocap)))
    tracker = Tracker.from_recording_info(short_recording.info,
                                          options={"checkpoint_interval_s": checkpoint_interval})
    compare_run(short_recording, short_reference, order, tracker,
                reads=rng.uniform(size=len(order)) < read_probability)


@pytest.fixture(scope="module")
def short_recording():
    """1.2 s of arm_lift at 200 Hz / 100 Hz with a gap (for the hypothesis test)."""
    return excerpt(simulate("arm_lift", seed=8, duration=5.0, imu_rate=200.0, mocap_rate=100.0,
                            occlusions=OcclusionSpec(gap_range=(0.1, 0.2), spacing=0.5)
                            ).recording, 1.2)


@pytest.fixture(scope="module")
def short_reference(short_recording):
    return in_order_run(short_recording)


@pytest.mark.parametrize("arrival", ["mocap first", "4.5 ms early", "jitter"])
def test_deferred_imu_samples_give_the_in_order_result_with_a_reader_at_every_frame(
        recording, reference, arrival):
    """IMU samples arriving behind frames wait (deferred) and the frames are fused again
    once the samples before them are in: with a reader after every frame (safety software),
    bit for bit the in-order estimates at every complete prefix and the same health; the
    samples really were deferred; each read right after a fused frame includes that frame
    (``time_since_fix`` 0)."""
    imu, mocap = recording.imu, recording.mocap
    rng = np.random.default_rng(11)
    if arrival == "jitter":
        order = arrival_order(recording, rng.uniform(0.0, 0.01, len(imu)),
                              rng.uniform(0.0, 0.01, len(mocap)))
    else:
        early = 0.0 if arrival == "mocap first" else 0.0045
        order = arrival_order(recording, np.zeros(len(imu)), np.full(len(mocap), -early))
    reads = np.array([stream == MOCAP_STREAM for stream, _ in order])
    tracker = Tracker.from_recording_info(recording.info)
    deferred = 0
    original_push = tracker.push_imu

    def push_imu(*args):
        nonlocal deferred
        outcome = original_push(*args)
        deferred += bool(tracker._pending)
        return outcome

    tracker.push_imu = push_imu
    assert compare_run(recording, reference, order, tracker, reads) > len(mocap) // 2
    assert deferred > len(mocap) // 2
    tracker = Tracker.from_recording_info(recording.info)
    fused = 0
    for stream, index in order:
        if stream == IMU_STREAM:
            push(tracker, recording, stream, index)
            continue
        t = mocap.t[index]
        visible = bool(mocap.visible[index])
        outcome = tracker.push_mocap(t, mocap.position[index] if visible else None,
                                     mocap.quaternion[index] if visible else None)
        if outcome.accepted:
            fused += 1
            now = tracker.newest_time
            assert tracker.estimate(now).time_since_fix == now - t
    assert fused > len(mocap) // 2


def test_a_read_fuses_the_frame_again_after_the_imu_sample_behind_it(recording, reference):
    """A frame, then the IMU sample with its stamp (behind it: deferred): the read at that
    time is the in-order one (the frame undone and fused again after the sample), not the
    frame fused on the held sample."""
    imu, mocap = recording.imu, recording.mocap
    in_order, after = reference
    events = fusion_order(recording)
    frame = 50
    sample = int(np.flatnonzero(imu.t == mocap.t[frame])[0])
    position = events.index((MOCAP_STREAM, frame))
    assert events[position - 1] == (IMU_STREAM, sample)
    tracker = Tracker.from_recording_info(recording.info)
    for stream, index in events[:position - 1]:
        push(tracker, recording, stream, index)
    push(tracker, recording, MOCAP_STREAM, frame)
    early = tracker.estimate(mocap.t[frame])  # the frame on the held sample
    push(tracker, recording, IMU_STREAM, sample)
    assert len(tracker._pending) == 1 and tracker._rollback is not None  # deferred
    assert_same(tracker.estimate(mocap.t[frame]), after[position])
    assert not np.array_equal(early.position, after[position].position)


def test_a_reset_counts_the_deferred_samples_first(recording):
    """reset() while IMU samples wait behind a frame: the health counters (time tracked,
    fixes, ...) are the in-order run's, as if every sample had been fused before the reset."""
    imu, mocap = recording.imu, recording.mocap
    events = fusion_order(recording)
    frame = 30
    sample = int(np.flatnonzero(imu.t == mocap.t[frame])[0])
    position = events.index((MOCAP_STREAM, frame))
    in_order, late = (Tracker.from_recording_info(recording.info) for _ in range(2))
    for stream, index in events[:position + 1]:
        push(in_order, recording, stream, index)
    for stream, index in events[:position - 1]:
        push(late, recording, stream, index)
    push(late, recording, MOCAP_STREAM, frame)
    push(late, recording, IMU_STREAM, sample)
    assert late._pending  # deferred
    in_order.reset()
    late.reset()
    expected, health = in_order.health.as_dict(), late.health.as_dict()
    assert (expected.pop("replays"), health.pop("replays")) == (0, 1)
    assert health == expected and health["time_tracked_s"] > 0.0
