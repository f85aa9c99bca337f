"""Property test: random sequences of good and bad calls never break the Tracker's promises.

Hypothesis draws call sequences mixing good samples with NaN/inf values and times, out-of-order
and duplicate times, huge and overflowing intervals, saturated and out-of-range accelerometer
values, occlusions, jumps and marker swaps, bad quaternions, wrong shapes and types, late samples
(replayed), extrapolated estimates, snapshots restored into fresh trackers, and resets.

After every call:

* only ValueError escapes, and only for a wrong shape or type (or an estimate time earlier than
  the newest sample, or missing: the tracker has no clock);
* ``estimate()`` is finite whenever its status is not ``lost``, its covariance symmetric and
  positive semi-definite, and its bound finite (Kalman) or ``inf`` (baseline); when lost the
  position is NaN and the bound ``inf``;
* the health counters add up: accepted + rejected == pushed for each stream, and the pushed
  counts equal the well-formed calls made.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from kfusion.conventions import STATUSES
from kfusion.profiles import MPU9255
from kfusion.tracker import IMU_REJECTIONS, MOCAP_REJECTIONS, WAITING, Tracker

GRAVITY = np.array([0.0, -9.81, 0.0])
IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
HOME = np.array([0.2, 1.0, 0.3])
RANGE = MPU9255.accelerometer_range
REASONS = {"accepted", "initialised", "saturated", "reacquired", "occluded", "gated", WAITING,
           *IMU_REJECTIONS, *MOCAP_REJECTIONS}  # WAITING: a frame ahead of the cadence

TIMES = ["step"] * 8 + ["lag"] * 6 + ["zero", "back", "dropout", "long", "huge", "overflow", "nan",
                        "inf"]
ACCELEROMETER = ["good"] * 8 + ["nan", "inf", "saturated", "beyond", "short", "text", "matrix"]
GYROSCOPE = ["good"] * 8 + ["nan", "inf", "fast", "short", "none"]
POSITION = ["good"] * 6 + ["none", "nan", "partial_nan", "inf", "jump", "swap", "drift", "short",
                          "text"]
QUATERNION = ["good"] * 6 + ["none", "nan", "non_unit", "zero", "flipped", "short"]

imu_call = st.tuples(st.just("imu"), st.sampled_from(TIMES), st.sampled_from(ACCELEROMETER),
                     st.sampled_from(GYROSCOPE), st.floats(-1, 1))
mocap_call = st.tuples(st.just("mocap"), st.sampled_from(TIMES), st.sampled_from(POSITION),
                       st.sampled_from(QUATERNION), st.floats(-1, 1))
estimate_call = st.tuples(st.just("estimate"),
                          st.sampled_from(["none", "later", "far", "earlier", "text"]),
                          st.just(""), st.just(""), st.floats(0, 1))
control_call = st.tuples(st.sampled_from(["snapshot_restore", "reset"]), st.just(""),
                         st.just(""), st.just(""), st.just(0.0))
steady_call = st.tuples(st.just("steady"), st.integers(5, 150), st.just(""), st.just(""),
                        st.floats(-1, 1))
"""A burst of good samples (1 kHz IMU, a mocap frame every 10 ms), to reach tracked states."""
calls = st.lists(st.one_of(steady_call, imu_call, imu_call, mocap_call, mocap_call,
                           estimate_call, control_call), min_size=3, max_size=60)


class Clock:
    """Draws sample times: mostly steady, sometimes broken in the ways the issue lists."""

    def __init__(self) -> None:
        self.now = 0.0
        self.last = {"imu": -math.inf, "mocap": -math.inf}

    def time(self, stream: str, kind: str, jitter: float) -> float:
        if kind == "nan":
            return math.nan
        if kind == "inf":
            return math.inf
        last = self.last[stream]
        if kind == "zero" and math.isfinite(last):
            return last
        if kind == "back" and math.isfinite(last):
            return last - 0.005
        step = {"step": 0.001 if stream == "imu" else 0.004, "dropout": 0.3 + 0.5 * abs(jitter),
                "long": 2.0, "huge": 1e6, "overflow": 1e200, "same": 0.0}.get(kind, 0.001)
        self.now += step
        t = self.now - (0.003 * abs(jitter) if kind == "lag" else 0.0)
        self.last[stream] = max(t, last) if math.isfinite(last) else t
        return t


def imu_arguments(acc_kind: str, gyro_kind: str, jitter: float):
    """(acc, gyro, well_formed)."""
    acc: object = GRAVITY * -1 + 0.05 * jitter
    gyro: object = np.array([0.01, -0.02, 0.005]) * jitter
    well_formed = True
    if acc_kind == "nan":
        acc = [math.nan, 9.81, 0.0]
    elif acc_kind == "inf":
        acc = [0.0, math.inf, 0.0]
    elif acc_kind == "saturated":
        acc = [RANGE, 9.81, 0.0]
    elif acc_kind == "beyond":
        acc = [1e300, -1e300, 9.81]
    elif acc_kind == "short":
        acc, well_formed = [0.0, 9.81], False
    elif acc_kind == "text":
        acc, well_formed = "0 9.81 0", False
    elif acc_kind == "matrix":
        acc, well_formed = np.eye(3), False
    if gyro_kind == "nan":
        gyro = [0.0, math.nan, 0.0]
    elif gyro_kind == "inf":
        gyro = [-math.inf, 0.0, 0.0]
    elif gyro_kind == "fast":
        gyro = [300.0, -200.0, 1e5]
    elif gyro_kind == "short":
        gyro, well_formed = [0.0], False
    elif gyro_kind == "none":
        gyro, well_formed = None, False
    return acc, gyro, well_formed


def mocap_arguments(position_kind: str, quaternion_kind: str, jitter: float):
    """(position, quaternion, well_formed)."""
    position: object = HOME + 3e-4 * jitter
    quaternion: object = IDENTITY
    well_formed = True
    position = {
        "none": None, "nan": [math.nan] * 3, "partial_nan": [0.1, math.nan, 0.2],
        "inf": [math.inf, 0.0, 0.0], "jump": HOME + [0.5, 0.0, 0.0],
        "swap": HOME + [-0.3, 0.2, 0.1], "drift": HOME + 0.05 * jitter,
    }.get(position_kind, position)
    if position_kind in ("short", "text"):
        position, well_formed = ([1.0, 2.0] if position_kind == "short" else "here"), False
    quaternion = {
        "none": None, "nan": [math.nan] * 4, "non_unit": [1.0, 0.5, 0.0, 0.0],
        "zero": [0.0] * 4, "flipped": -IDENTITY,
    }.get(quaternion_kind, quaternion)
    if quaternion_kind == "short":
        quaternion, well_formed = [1.0, 0.0, 0.0], False
    return position, quaternion, well_formed


def check_invariants(tracker: Tracker, pushed: dict[str, int], method: str) -> None:
    estimate = tracker.estimate(tracker.newest_time)
    assert estimate.status in STATUSES
    if estimate.status == "lost":
        assert np.isnan(estimate.position).all()
        assert estimate.bound() == math.inf
    else:
        assert math.isfinite(estimate.t)
        assert np.isfinite(estimate.position).all()
        assert math.isfinite(estimate.time_since_fix) and estimate.time_since_fix >= 0
        if method == "kalman":
            covariance = estimate.covariance
            assert np.isfinite(covariance).all() and np.isfinite(estimate.std).all()
            assert np.array_equal(covariance, covariance.T)
            eigenvalues = np.linalg.eigvalsh(covariance)
            assert eigenvalues[0] >= -1e-12 * max(1.0, eigenvalues[-1])
            bound = estimate.bound(0.99)
            assert math.isfinite(bound) and bound >= 0
        else:
            assert estimate.bound(0.99) == math.inf
    health = tracker.health
    assert health.imu_pushed == pushed["imu"]
    assert health.mocap_pushed == pushed["mocap"]
    assert health.imu_pushed == health.imu_accepted + sum(health.imu_rejected.values())
    assert health.mocap_pushed == (health.mocap_fused + health.mocap_occluded
                                   + sum(health.mocap_rejected.values()))
    assert health.gate_rejections == health.mocap_rejected["gated"]
    assert min(health.time_tracked_s, health.time_bridged_s, health.time_lost_s) >= 0


def run_calls(method: str, sequence) -> None:
    tracker = Tracker(IDENTITY, GRAVITY, method=method)
    clock = Clock()
    pushed = {"imu": 0, "mocap": 0}
    for name, first, second, third, jitter in sequence:
        expect_error = False
        try:
            if name == "imu":
                acc, gyro, well_formed = imu_arguments(second, third, jitter)
                expect_error = not well_formed
                t = clock.time("imu", first, jitter)
                outcome = tracker.push_imu(t, acc, gyro)
                pushed["imu"] += 1
                assert outcome.reason in REASONS
            elif name == "mocap":
                position, quaternion, well_formed = mocap_arguments(second, third, jitter)
                expect_error = not well_formed
                t = clock.time("mocap", first, jitter)
                outcome = tracker.push_mocap(t, position, quaternion)
                pushed["mocap"] += 1
                assert outcome.reason in REASONS
                assert outcome.accepted == (outcome.reason in ("accepted", "reacquired",
                                                               "initialised"))
            elif name == "estimate":
                newest = tracker.estimate(tracker.newest_time).t
                base = newest if math.isfinite(newest) else 0.0
                argument: object = {"none": None, "later": base + jitter, "far": base + 1e9,
                                    "earlier": base - 1.0 - jitter, "text": "soon"}[first]
                expect_error = first in ("text", "none") or (  # no clock: t is required
                    first == "earlier" and argument < newest)  # type: ignore[operator]
                estimate = tracker.estimate(argument)  # type: ignore[arg-type]
                if estimate.status != "lost":
                    assert np.isfinite(estimate.position).all()
            elif name == "steady":
                for k in range(first):
                    acc, gyro, _ = imu_arguments("good", "good", jitter * math.cos(k))
                    tracker.push_imu(clock.time("imu", "step", 0.0), acc, gyro)
                    pushed["imu"] += 1
                    if k % 10 == 0:
                        position, quaternion, _ = mocap_arguments("good", "good", math.sin(k))
                        tracker.push_mocap(clock.time("mocap", "same", 0.0), position,
                                           quaternion)
                        pushed["mocap"] += 1
            elif name == "snapshot_restore":
                snapshot = tracker.snapshot()
                tracker = Tracker(IDENTITY, GRAVITY, method=method)
                tracker.restore(snapshot)
            else:
                tracker.reset()
                clock = Clock()
        except ValueError:
            assert expect_error, f"unexpected ValueError in {name} {first} {second} {third}"
        else:
            assert not expect_error, f"expected a ValueError in {name} {first} {second} {third}"
        check_invariants(tracker, pushed, method)


@pytest.mark.parametrize("method", ["kalman", "baseline"])
@settings(max_examples=250, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(sequence=calls)
def test_random_call_sequences_keep_the_promises(method, sequence):
    with np.errstate(all="ignore"):  # overflowing inputs are the point; warnings are noise
        run_calls(method, sequence)


def test_a_long_good_run_with_every_kind_of_fault_once():
    """A fixed, long sequence (no hypothesis) as a smoke test of the same invariants."""
    sequence = []
    kinds = [("imu", "step", "good", "good")] * 30 + [("mocap", "step", "good", "good")] * 10
    for fault in (("imu", "nan", "good", "good"), ("imu", "step", "saturated", "good"),
                  ("mocap", "step", "jump", "good"), ("imu", "dropout", "good", "good"),
                  ("mocap", "lag", "good", "good"), ("imu", "long", "good", "good"),
                  ("mocap", "step", "swap", "flipped"), ("imu", "overflow", "beyond", "fast")):
        sequence += [(*kind, 0.1) for kind in kinds] + [(*fault, 0.5)]
    with np.errstate(all="ignore"):
        run_calls("kalman", sequence)
