"""One status rule (:func:`kfusion.streamhealth.tracking_status`) for every estimator.

The streaming filter (:meth:`KalmanFusion.estimate`), the batch driver (``kfusion track
--method kalman``), the smoother, the :class:`Tracker` (Kalman and baseline) and the paper's
baseline (streaming and batch) are asked at the same hand-picked instants of one simulated
recording and must agree with each other and with the values the rule gives by hand.

The batch driver, the smoother and the baseline's batch run give one row per mocap row, so they
are compared at the instants that are rows; "5 ms after a fix" falls between two frames (no new
frame has arrived) and is compared among the streaming estimators, where the filter used to say
``bridged`` and the Tracker ``tracked``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from kfusion.baseline import BaselineParameters, BaselineTracker
from kfusion.baseline import track_recording as baseline_recording
from kfusion.conventions import BRIDGED, LOST, TRACKED
from kfusion.kalman import KalmanFusion, run_filter, run_smoother
from kfusion.kalman.batch import resolve_parameters
from kfusion.kalman.events import IMU_STREAM, merge_events
from kfusion.recording import MocapFrames, Recording
from kfusion.simulate import simulate
from kfusion.streamhealth import FIX_TIMEOUT_S, tracking_status
from kfusion.track_file import bounded_rows
from kfusion.tracker import Tracker

MAX_BRIDGE_S = 0.2
# mocap rows (100 Hz) hidden: before the first fix, a 0.3 s gap, a 0.6 s gap
HIDDEN = ((0, 20), (200, 230), (350, 410))
# instant -> (mocap row or None, expected status by the rule); "5 ms after a fix" is no row
INSTANTS = {
    "before the first fix": (10, LOST),
    "at a fix": (100, TRACKED),
    "5 ms after a fix": (None, TRACKED),
    "inside a gap": (215, BRIDGED),  # 0.16 s after the fix at row 199, 0.15 s before row 230
    "past max_bridge_s": (380, LOST),  # 0.31 s after row 349, 0.30 s before row 410
}


@pytest.fixture(scope="module")
def recording() -> Recording:
    simulation = simulate("arm_lift", seed=5, duration=6.0, imu_rate=200.0, mocap_rate=100.0,
                          occlusions=None)
    mocap = simulation.recording.mocap
    position, quaternion = mocap.position.copy(), mocap.quaternion.copy()
    for start, stop in HIDDEN:
        position[start:stop] = np.nan
        quaternion[start:stop] = np.nan
    return dataclasses.replace(simulation.recording,
                               mocap=MocapFrames(t=mocap.t, position=position,
                                                 quaternion=quaternion))


def instant_times(recording: Recording) -> dict[str, float]:
    t = recording.mocap.t
    return {name: float(t[row]) if row is not None else float(t[100]) + 0.005
            for name, (row, _) in INSTANTS.items()}


def streamed_statuses(recording: Recording, push_imu, push_mocap, estimate, latency: float = 0.0
                      ) -> dict[str, str]:
    """Feed the events in fusion order; at each instant, the status after every event up to
    it."""
    imu, mocap = recording.imu, recording.mocap
    events = merge_events(imu.t.tolist(), mocap.t.tolist(), latency)
    statuses = {}
    position = 0
    for name, instant in sorted(instant_times(recording).items(), key=lambda item: item[1]):
        while position < len(events) and events[position][0] <= instant:
            _, stream, index = events[position]
            if stream == IMU_STREAM:
                push_imu(imu.t[index], imu.accelerometer[index], imu.gyroscope[index])
            else:
                visible = bool(mocap.visible[index])
                push_mocap(mocap.t[index], mocap.position[index] if visible else None,
                           mocap.quaternion[index] if visible else None)
            position += 1
        statuses[name] = estimate(instant).status
    return statuses


def test_the_rule_by_hand():
    rule = dict(fix_timeout_s=FIX_TIMEOUT_S, max_bridge_s=MAX_BRIDGE_S)
    assert tracking_status(0.0, True, **rule) == TRACKED
    assert tracking_status(0.005, True, **rule) == TRACKED
    assert tracking_status(0.005, False, **rule) == BRIDGED  # an occluded frame came since
    assert tracking_status(0.16, False, **rule) == BRIDGED
    assert tracking_status(0.16, False, beyond_dead_reckoning=True, **rule) == LOST
    assert tracking_status(0.31, False, **rule) == LOST
    assert tracking_status(np.inf, False, **rule) == LOST


def test_a_row_without_a_usable_variance_is_lost():
    """A bound is a promise: a variance rounded below zero, overflowed or NaN is none, so the
    row is lost (before, the smoother reported a frame stamped 1000 s ahead ``tracked`` with
    a NaN std: its smoothed variance was -7e-8 m^2)."""
    status = np.array([TRACKED, BRIDGED, TRACKED, BRIDGED, TRACKED, LOST])
    variance = np.array([[4e-6, 9e-8, 0.0], [1e-4, 1e-4, 1e-4], [9e-8, -7e-8, 9e-8],
                         [np.inf, 1e-4, 1e-4], [np.nan, 9e-8, 9e-8], [1e-6, 1e-6, 1e-6]])
    kept, std = bounded_rows(status, variance)
    assert kept.tolist() == [TRACKED, BRIDGED, LOST, LOST, LOST, LOST]
    np.testing.assert_array_equal(std[:2], [[2e-3, 3e-4, 0.0], [1e-2, 1e-2, 1e-2]])
    assert np.isnan(std[2:]).all()


def test_every_estimator_gives_the_same_status(recording):
    info = recording.info
    params = resolve_parameters(recording, None, {"max_bridge_s": MAX_BRIDGE_S})
    baseline_params = BaselineParameters(max_bridge_s=MAX_BRIDGE_S)
    expected = {name: status for name, (_, status) in INSTANTS.items()}
    streaming = {}

    fusion = KalmanFusion(info.imu_to_body, info.gravity, params, lever_arm=info.lever_arm)
    streaming["filter"] = streamed_statuses(recording, fusion.predict, fusion.update,
                                            fusion.estimate)
    for method, method_params in (("kalman", params), ("baseline", baseline_params)):
        tracker = Tracker.from_recording_info(info, method=method, params=method_params)
        streaming[f"Tracker ({method})"] = streamed_statuses(
            recording, tracker.push_imu, tracker.push_mocap, tracker.estimate)
    baseline = BaselineTracker(info.imu_to_body, baseline_params)
    streaming["baseline"] = streamed_statuses(recording, baseline.push_imu, baseline.push_mocap,
                                              baseline.estimate)
    for name, statuses in streaming.items():
        assert statuses == expected, name

    rows = {name: row for name, (row, _) in INSTANTS.items() if row is not None}
    batch = {
        "kfusion track --method kalman": run_filter(recording, params).result,
        "smoother": run_smoother(recording, params).result,
        "baseline batch": baseline_recording(recording, baseline_params),
    }
    for name, result in batch.items():
        assert {instant: result.status[row] for instant, row in rows.items()} == {
            instant: expected[instant] for instant in rows}, name
