"""Broken model assumptions through the streaming Tracker: never confidently wrong.

A user who gets the recording's metadata or clock wrong (gravity with the wrong sign, the mount
given as identity, quaternion columns in x, y, z, w order, the IMU clock off by tens of ms) gives
the Tracker a model the data contradicts. ``kfusion track`` refuses such a recording after its
diagnosis (tests/test_self_calibration.py, tests/test_check_command.py); the Tracker has no
whole recording to diagnose, so its consistency monitor must notice. The invariant of the
fail-safe issue, checked here on a simulated recording with ground truth (the caller's clock at
each mocap frame's arrival):

* each estimate is ``lost``, or its error is within bound(0.99);
* allowed: at most 3 % of the rows shown beyond 1x bound(0.99) (a calibrated bound is beyond it
  on about 1 % of them; the rows of one run are correlated), none beyond 3x (the issue's target).

Hypothesis mixes a model fault with its size and the stream's seed; a marker swap lasting
1 s (which can pass the gate once the prediction has grown loose) joins them. Before the monitor's
fix-only fallback (a monitor that refuses to bridge also stops trusting the IMU-driven
posterior at the fixes) the gravity, mount and quaternion-order faults showed tracked rows with
errors 5-18x their bound on 12-22 % of the rows; before the rival hypotheses were covered, a
swapped marker that passed the gate was tracked 200 mm off with a 1 mm bound.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from kfusion.conventions import LOST, TRACKED
from kfusion.kalman import run_filter, run_smoother
from kfusion.kalman.smoother import contested_fixes
from kfusion.simulate import OcclusionSpec, faults, simulate
from kfusion.simulate.faults import Streams
from kfusion.tracker import Tracker, position_bound

DURATION = 8.0  # s
CONFIDENCE = 0.99
MAX_BEYOND = 0.03  # fraction of rows shown beyond 1x bound(0.99)
MAX_RATIO = 3.0  # no error beyond this multiple of bound(0.99)


@pytest.fixture(scope="module")
def simulations():
    return {seed: simulate("random_reach", seed=seed, imu="mpu9255", duration=DURATION,
                           occlusions=OcclusionSpec(gap_range=(0.1, 0.3), spacing=1.5))
            for seed in (3, 4)}


def apply_fault(streams: Streams, name: str, size: float) -> Streams:
    """One broken assumption; ``size`` is the clock offset in s for ``clock``."""
    if name == "gravity":
        return faults.gravity_sign_flipped(streams)
    if name == "mount":
        return faults.mount_identity(streams)
    if name == "quaternion":
        return faults.quaternion_columns_xyzw(streams)
    if name == "clock":
        return faults.imu_clock_offset(streams, size)
    if name == "swap":  # a marker swap lasting 1 s, starting where size (as a fraction) says
        return faults.marker_swap(streams, fraction=0.3 + abs(size), duration_s=1.0)
    return streams


def shown_rows(streams: Streams, truth: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, Tracker]:
    """Push in arrival order; after each mocap frame ask ``estimate(now)``, now = the frame's
    arrival (a ValueError, for samples stamped after now, gives no position: shown as lost).
    Status (m,), error (m,) m, bound(0.99) (m,) m per mocap frame, and the tracker at the
    end."""
    recording = streams.recording
    tracker = Tracker.from_recording_info(recording.info)
    imu, mocap = recording.imu, recording.mocap
    status, error, bound = [], [], []
    for arrival, stream, index in streams.events():
        if stream == 0:
            tracker.push_imu(imu.t[index], imu.accelerometer[index], imu.gyroscope[index])
            continue
        tracker.push_mocap(mocap.t[index], mocap.position[index], mocap.quaternion[index])
        try:
            estimate = tracker.estimate(arrival)
        except ValueError:  # samples stamped after now (an IMU clock ahead): no position given
            estimate = None
        status.append(LOST if estimate is None else estimate.status)
        if estimate is None or estimate.status == LOST:
            error.append(np.nan)
            bound.append(np.inf)
        else:
            assert np.isfinite(estimate.position).all()
            error.append(float(np.linalg.norm(estimate.position - truth[index])))
            bound.append(estimate.bound(CONFIDENCE))
    return np.array(status), np.array(error), np.array(bound), tracker


def assert_never_confidently_wrong(status, error, bound, what: str) -> None:
    shown = status != LOST
    if not shown.any():
        return
    ratio = error[shown] / bound[shown]
    beyond = float(np.mean(ratio > 1.0))
    assert beyond <= MAX_BEYOND, f"{what}: {beyond:.1%} of the rows shown beyond bound(0.99)"
    assert ratio.max() <= MAX_RATIO, f"{what}: error up to {ratio.max():.1f}x bound(0.99)"


@settings(max_examples=16, deadline=None, derandomize=True,
          phases=[Phase.explicit, Phase.generate],  # shrinking a whole run takes minutes
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(name=st.sampled_from(["gravity", "mount", "quaternion", "clock", "swap"]),
       size=st.sampled_from([-0.137, -0.05, 0.05, 0.1]), seed=st.sampled_from([3, 4]))
def test_a_broken_model_never_leaves_the_tracker_confidently_wrong(simulations, name, size,
                                                                    seed):
    simulation = simulations[seed]
    streams = apply_fault(Streams.of(simulation.recording), name, size)
    status, error, bound, _ = shown_rows(streams, np.asarray(simulation.truth.position))
    assert_never_confidently_wrong(status, error, bound, f"{name} (size {size}, seed {seed})")


@pytest.mark.parametrize("name", ["gravity", "mount", "quaternion"])
def test_the_monitor_names_a_broken_model_and_keeps_the_fixes(simulations, name):
    """The consistency report says the IMU model is not trusted and names a cause; fixes the
    filter still fuses are shown (the fix itself, within the mocap noise), the rest is lost."""
    simulation = simulations[3]
    streams = apply_fault(Streams.of(simulation.recording), name, 0.0)
    status, _, _, tracker = shown_rows(streams, np.asarray(simulation.truth.position))
    assert np.any(status == TRACKED)
    report = tracker.consistency
    assert report is not None and not report.bridging_allowed
    assert report.suspected_cause != "consistent"


def test_a_correct_model_keeps_its_sharp_bound(simulations):
    """The same check on the unbroken recording: bridged rows exist and are within their bound
    (the fallback must not turn on without cause)."""
    simulation = simulations[4]
    streams = Streams.of(simulation.recording)
    status, error, bound, _ = shown_rows(streams, np.asarray(simulation.truth.position))
    assert_never_confidently_wrong(status, error, bound, "no fault")
    assert np.mean(status == "bridged") > 0.05
    assert np.median(bound[status == TRACKED]) < 1e-3  # m: the filtered fix, sub-millimetre


@pytest.mark.parametrize("fraction", [0.3, 0.35, 0.4, 0.45, 0.5])
def test_a_marker_swap_that_passes_the_gate_stays_covered(simulations, fraction):
    """A swapped marker 1 s long, at several places: whether it is gated throughout or passes
    the gate once the prediction is loose, the rows shown are within their bound."""
    simulation = simulations[3]
    streams = faults.marker_swap(Streams.of(simulation.recording), fraction=fraction,
                                 duration_s=1.0)
    status, error, bound, _ = shown_rows(streams, np.asarray(simulation.truth.position))
    assert_never_confidently_wrong(status, error, bound, f"swap at {fraction}")


def test_contested_fixes_are_the_fixes_fused_after_gated_ones():
    outcome = np.array(["initialised", "accepted", "gated", "occluded", "gated", "reacquired",
                        "accepted", "occluded", "accepted", "gated", "accepted"])
    expected = [False, False, False, False, False, True, False, False, False, False, True]
    assert contested_fixes(outcome).tolist() == expected


@pytest.mark.parametrize("fraction", [0.35, 0.5])
@pytest.mark.parametrize("method", ["kalman", "smoother"])
def test_batch_paths_cover_a_marker_swap(simulations, method, fraction):
    """``kfusion track``'s filter and smoother on the same swaps: every row not lost is within
    its bound (the batch bound is the axis-aligned one kfusion's CSV carries)."""
    simulation = simulations[3]
    streams = faults.marker_swap(Streams.of(simulation.recording), fraction=fraction,
                                 duration_s=1.0)
    runner = run_filter if method == "kalman" else run_smoother
    result = runner(streams.recording).result
    error = np.linalg.norm(result.position - np.asarray(simulation.truth.position), axis=1)
    bound = np.array([position_bound(np.diag(std ** 2), CONFIDENCE) for std in result.std])
    status = np.asarray(result.status)
    assert_never_confidently_wrong(status, np.where(status == LOST, np.nan, error),
                                   np.where(status == LOST, np.inf, bound),
                                   f"{method}, swap at {fraction}")


def test_a_gyroscope_clipping_below_its_declared_range_is_not_dead_reckoned_as_true():
    """A gyroscope flat at 150 dps (the reach turns 1.9x faster) while the profile says
    1000 dps, with the occlusions at speed peaks: the plateau test saturates the clipped
    samples, and the rows shown stay within bound(0.99) as this file allows (1.6 % beyond, as
    with the range declared). Before it, the clipped rate was integrated as the true one: 3.8 %
    of this recording's rows were beyond the bound, up to 4.7x (130 mm against 28 mm; an
    adversarial review)."""
    simulation = simulate("random_reach", seed=2, imu="mpu9255", duration=30.0,
                          occlusions=OcclusionSpec(gap_range=(0.1, 0.5), spacing=1.5,
                                                   placement="mid_motion"))
    streams = faults.imu_clips(Streams.of(simulation.recording), None, np.radians(150.0))
    run = run_filter(streams.recording)
    result = run.result
    truth = np.asarray(simulation.truth.position)
    shown = result.status != LOST
    error = np.linalg.norm(result.position[shown] - truth[shown], axis=1)
    bound = np.sqrt(chi2.ppf(CONFIDENCE, 3)) * result.std[shown].max(axis=1)
    assert np.mean(error > bound) <= MAX_BEYOND
    assert np.max(error / bound) <= MAX_RATIO
    assert run.counters["gyroscope_saturated"] > 50


def test_the_first_fixes_after_a_reset_are_a_recording_s_first():
    """Both streams paused for 400 s (the prediction passes FORGOTTEN_POSITION_STD: a reset),
    and at re-entry the body's first 10 frames solved 3 mm off (a cluster re-appearing): the
    filter and the smoother show those rows as at a recording's start, with the cover of
    a first fix (monitor.step_offset_variance), not with the posterior's. Before the monitor
    was told of the reset (its first fixes counted as tested) the filter was 4.1-4.4x beyond
    the bound and the smoother 4.5-6.2x there (an adversarial review); the smoother was 3.7x
    at a recording's own start."""
    from kfusion.recording import ImuSamples, MocapFrames

    simulation = simulate("random_reach", seed=1, imu="mpu9255", duration=16.0,
                          occlusions=OcclusionSpec(gap_range=(0.1, 0.4), spacing=1.0))
    recording, truth = simulation.recording, np.asarray(simulation.truth.position)
    mocap, imu = recording.mocap, recording.imu
    resume = 8.0
    position = np.array(mocap.position)
    late = mocap.t >= resume
    first = np.flatnonzero(late & mocap.visible)[:10]
    position[first, 0] += 0.003
    shifted = 400.0
    paused = recording.with_mocap(MocapFrames(np.where(late, mocap.t + shifted, mocap.t),
                                              position, mocap.quaternion))
    paused = paused.__class__(imu=ImuSamples(np.where(imu.t >= resume, imu.t + shifted, imu.t),
                                             imu.accelerometer, imu.gyroscope),
                              mocap=paused.mocap, info=paused.info)
    runs = {"filter": run_filter(paused), "smoother": run_smoother(paused)}
    assert runs["filter"].counters["resets"] == 1
    window = late & np.isfinite(truth).all(axis=1) & (mocap.t < resume + 0.5)
    for name, run in runs.items():
        result = run.result
        shown = window & (result.status != LOST)
        assert shown[first].all(), name
        error = np.linalg.norm(result.position[shown] - truth[shown], axis=1)
        bound = np.sqrt(chi2.ppf(CONFIDENCE, 3)) * result.std[shown].max(axis=1)
        assert np.max(error / bound) <= MAX_RATIO, (name, np.max(error / bound))
