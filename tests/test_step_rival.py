"""Steps in the fixes below the gate (:meth:`kfusion.monitor.ConsistencyMonitor._step`): a marker
of the cluster drops out and the solved rigid body shifts by a few mm for some frames. The filter
follows the shifted fixes and its innovations shrink, so the prediction the first shifted fix was
fused with stays a rival hypothesis, and the bound covers both."""

from __future__ import annotations

import dataclasses
import math
from types import SimpleNamespace

import numpy as np
import pytest
from test_batch_streaming import arrival_orders, stream_rows
from test_broken_prediction import _monitor_with_fixes

from kfusion.kalman import KalmanParameters, run_filter
from kfusion.kalman.batch import resolve_parameters
from kfusion.kalman.filter import ACCEPTED, UpdateOutcome
from kfusion.monitor import (
    MonitorParameters,
    chi2_quantile,
    innovation_from_posterior,
    step_offset_variance,
)
from kfusion.recording import MocapFrames, Recording
from kfusion.simulate import OcclusionSpec, faults, simulate
from kfusion.tracker import Tracker

K99 = math.sqrt(chi2_quantile(0.99, 3))
GLITCH_M = 0.004
GLITCH_FRAMES = 10


def kalman_update(x, P, z, r):
    """A textbook Kalman update of a 3-D position with H = I, R = r I (numpy, not kfusion)."""
    S = P + r * np.eye(3)
    K = P @ np.linalg.inv(S)
    return x + K @ (z - x), (np.eye(3) - K) @ P, z - x, S


def test_innovation_from_posterior_by_hand():
    # scalar: p- = r, the fix halfway: P+ = r / 2, z - p+ = y / 2, so y = 2 (z - p+), S = 2 r
    r = 9e-8
    found = innovation_from_posterior([0.002, 0.0, 0.0], [0.001, 0.0, 0.0], r / 2 * np.eye(3), r)
    assert found is not None
    np.testing.assert_allclose(found[0], [0.002, 0.0, 0.0], rtol=1e-12)
    np.testing.assert_allclose(found[1], 2 * r * np.eye(3), rtol=1e-12)


def test_innovation_from_posterior_recovers_a_correlated_update():
    rng = np.random.default_rng(3)
    r = 9e-8
    for _ in range(20):
        A = rng.standard_normal((3, 3))
        P = 3e-8 * (A @ A.T) / 3 + 1e-9 * np.eye(3)  # a prediction tighter than 9 R
        x, z = rng.standard_normal(3) * 0.1, rng.standard_normal(3) * 0.1
        x_post, P_post, y, S = kalman_update(x, P, z, r)
        found = innovation_from_posterior(z, x_post, P_post, r)
        assert found is not None
        np.testing.assert_allclose(found[0], y, rtol=1e-8, atol=1e-15)
        np.testing.assert_allclose(found[1], S, rtol=1e-8, atol=1e-22)


def test_innovation_from_posterior_refuses_a_loose_prediction_and_bad_numbers():
    r = 9e-8
    # P- = 10 R: gain 10/11 > 0.9, (R - P+)^-1 would amplify by 11
    _, P_post, _, _ = kalman_update(np.zeros(3), 10 * r * np.eye(3), np.ones(3) * 1e-3, r)
    assert innovation_from_posterior(np.ones(3) * 1e-3, np.zeros(3), P_post, r) is None
    assert innovation_from_posterior([np.nan, 0, 0], np.zeros(3), r / 2 * np.eye(3), r) is None
    assert innovation_from_posterior(np.zeros(3), np.zeros(3), r / 2 * np.eye(3), 0.0) is None


class _Posterior:
    """The main filter as the monitor reads it: a real fusion's snapshots (the shadow gaps) and
    a given fused point and covariance (its estimate after the frame)."""

    last_impact_t = -math.inf  # no knocks

    def __init__(self, fusion, position, covariance):
        self.fusion, self.position, self.covariance = fusion, position, covariance

    def snapshot(self):
        return self.fusion.snapshot()

    def estimate(self, t):
        return SimpleNamespace(position=np.array(self.position),
                               position_covariance=np.array(self.covariance))


def test_a_step_keeps_its_prediction_as_a_rival_by_hand():
    monitor, fusion, r = _monitor_with_fixes()
    limit = KalmanParameters.from_profiles("mpu9255").max_bridge_s  # the fixture's profile
    zeros = np.zeros((3, 3))

    def fix(t, z, nis, fused_point=None, covariance=None):
        main = _Posterior(fusion, z if fused_point is None else fused_point,
                          r / 2 * np.eye(3) if covariance is None else covariance)
        monitor.mocap(t, np.array(z, dtype=float), UpdateOutcome(t, ACCEPTED, nis), main)

    threshold = chi2_quantile(MonitorParameters().step_probability, 3)
    assert threshold == pytest.approx(30.66, abs=0.01)
    t = 0.0
    for _ in range(5):
        t += 0.01
        fix(t, [0.0, 0.0, 0.0], 3.0)
    assert not monitor.has_rivals(t)
    t += 0.01
    fix(t, [0.004, 0.0, 0.0], threshold * 0.99)  # below the step quantile: nothing
    assert not monitor.has_rivals(t)
    # a 4 mm step with P- = R: P+ = R / 2, the fused point halfway; y = 4 mm, S = 2 R
    t += 0.01
    step_t = t
    fix(t, [0.004, 0.0, 0.0], 80.0, fused_point=[0.002, 0.0, 0.0])
    assert monitor.has_rivals(t)
    expected = np.diag([0.004 ** 2, 0.0, 0.0]) + 2 * r * np.eye(3)
    np.testing.assert_allclose(monitor.cover_rivals(t, np.zeros(3), zeros), expected,
                               rtol=1e-9)
    assert K99 * math.sqrt(monitor.cover_rivals(t, np.zeros(3), zeros)[0, 0]) > 3 * 0.004
    # a smaller step later (the filter's overshoot) leaves the larger rival in place
    t += 0.01
    fix(t, [0.004, 0.0, 0.0], 40.0, fused_point=[0.0035, 0.0, 0.0])
    np.testing.assert_allclose(monitor.cover_rivals(t, np.zeros(3), zeros), expected,
                               rtol=1e-9)
    small = np.diag([0.001 ** 2, 0.0, 0.0]) + 2 * r * np.eye(3)
    # ... until the larger one ends (max_bridge_s after its fix), then the smaller one holds
    np.testing.assert_allclose(monitor.cover_rivals(step_t + limit - 1e-9, np.zeros(3), zeros),
                               expected, rtol=1e-9)
    np.testing.assert_allclose(monitor.cover_rivals(step_t + limit + 0.005, np.zeros(3), zeros),
                               small, rtol=1e-9)
    assert not monitor.has_rivals(t + limit + 0.001)
    # a marker-level update is no rigid-body step
    monitor2, fusion2, _ = _monitor_with_fixes()
    monitor2.mocap(0.01, np.array([0.004, 0.0, 0.0]),
                   UpdateOutcome(0.01, ACCEPTED, 80.0, markers_used=4),
                   _Posterior(fusion2, [0.002, 0.0, 0.0], r / 2 * np.eye(3)))
    assert not monitor2.has_rivals(0.01)


def glitched_recording() -> tuple[Recording, np.ndarray, np.ndarray]:
    """20 s of simulated random_reach with 12 glitches: the fixes shifted 4 mm in a random
    direction for 10 frames, each where the frame before and the 25 after are visible (a
    glitch that begins inside an occlusion shows in no innovation: the first fix after it is
    already shifted and agrees with the loose prediction). (recording, truth (m, 3), rows in a
    glitch (m,) bool)."""
    simulation = simulate("random_reach", seed=3, duration=20.0,
                          occlusions=OcclusionSpec(spacing=1.5))
    recording = simulation.recording
    mocap = recording.mocap
    visible = mocap.visible
    rng = np.random.default_rng(5)
    position = mocap.position.copy()
    inside = np.zeros(len(position), dtype=bool)
    starts: list[int] = []
    for start in rng.permutation(np.arange(50, len(position) - 30)).tolist():
        if visible[start - 1:start + 25].all() and not inside[max(0, start - 40):start + 40].any():
            starts.append(start)
            inside[start:start + GLITCH_FRAMES] = True
        if len(starts) == 12:
            break
    for start in starts:
        direction = rng.standard_normal(3)
        position[start:start + GLITCH_FRAMES] += GLITCH_M * direction / np.linalg.norm(direction)
    glitched = dataclasses.replace(recording,
                                   mocap=MocapFrames(mocap.t, position, mocap.quaternion))
    return glitched, np.asarray(simulation.truth.position), inside


def test_multi_frame_sub_gate_glitches_stay_inside_the_bound():
    """Before the step rival: 28 of the 120 glitched rows beyond the 99 % bound (1.85 % of all
    rows wrong, the filter's bound at a fused fix about P+, far below the 4 mm shift); now none,
    and the run's wrong rows are those of a clean run's tail (<= 1 %)."""
    recording, truth, inside = glitched_recording()
    run = run_filter(recording)
    result = run.result
    error = np.linalg.norm(result.position - truth, axis=1)
    live = result.status != "lost"
    bound = K99 * np.where(live[:, None], result.std, 0.0).max(axis=1)
    wrong = live & (error > bound)
    assert inside.sum() == 120 and live[inside].all()
    assert not wrong[inside].any(), np.flatnonzero(wrong & inside)
    assert wrong.sum() <= 0.01 * len(wrong)
    # the glitches show in the NIS (every first shifted fix beyond the step quantile)
    starts = np.flatnonzero(inside & ~np.roll(inside, 1))
    assert (run.nis[starts] > chi2_quantile(MonitorParameters().step_probability, 3)).all()
    assert run.monitor is not None and run.monitor.steps >= len(starts)
    # the clean recording has no false step (the rival would widen its tracked rows)
    clean = run_filter(simulate("random_reach", seed=3, duration=20.0,
                                occlusions=OcclusionSpec(spacing=1.5)).recording)
    assert clean.monitor is not None and clean.monitor.steps == 0


def test_the_step_rival_is_the_same_in_batch_tracker_and_engines():
    """The Tracker and the batch filter give the same bits with step rivals in play; the
    compiled engine's two passes (the filter after a step read from its checkpoints) equal its
    event-by-event run, and filterpy agrees."""
    recording, _, inside = glitched_recording()
    params = resolve_parameters(recording, None, {})
    run = run_filter(recording, params)
    tracker = Tracker.from_recording_info(recording.info, params=params)
    rows = stream_rows(recording, tracker, arrival_orders(recording, 0.0)["natural"], 0.0)
    np.testing.assert_array_equal(rows["position"], run.result.position)
    np.testing.assert_array_equal(rows["std"], run.result.std)
    stepwise = run_filter(recording, params, stepwise=True)
    np.testing.assert_array_equal(stepwise.result.std, run.result.std)
    np.testing.assert_array_equal(stepwise.result.position, run.result.position)
    reference = run_filter(recording, params, engine="filterpy")
    np.testing.assert_allclose(reference.result.std[inside], run.result.std[inside],
                               rtol=1e-6)
    # the bound at every glitched row reaches past the shift (before the step rival: 2.4-3.7
    # mm at many, the innovations' factor alone)
    assert (K99 * run.result.std[inside].max(axis=1) > GLITCH_M).all()


def test_the_sub_gate_glitch_fault_shifts_runs_of_frames_and_nothing_else():
    simulation = simulate("random_reach", seed=2, duration=10.0,
                          occlusions=OcclusionSpec(spacing=1.5))
    streams = faults.Streams.of(simulation.recording)
    glitched = faults.sub_gate_glitches(streams, size_m=0.003, frames=7, rate=0.004, seed=1)
    before, after = streams.recording.mocap, glitched.recording.mocap
    shift = after.position - before.position
    moved = np.isfinite(shift).all(axis=1) & (np.abs(shift) > 0).any(axis=1)
    np.testing.assert_allclose(np.linalg.norm(shift[moved], axis=1), 0.003, rtol=1e-9)
    # runs of 7 frames (4 runs in 1001 frames; their occluded frames stay occluded)
    starts = np.sort(np.random.default_rng(1).choice(len(before), size=4, replace=False))
    expected = np.zeros(len(before), dtype=bool)
    for start in starts:
        expected[start:start + 7] = True
    np.testing.assert_array_equal(moved, expected & before.visible)
    np.testing.assert_array_equal(after.quaternion, before.quaternion)
    np.testing.assert_array_equal(after.visible, before.visible)
    assert glitched.recording.imu is streams.recording.imu
    again = faults.sub_gate_glitches(streams, size_m=0.003, frames=7, rate=0.004, seed=1)
    np.testing.assert_array_equal(again.recording.mocap.position, after.position)


# ------------------------------------------------------------------------------------------
# A fix ending a gap (ConsistencyMonitor._reacquisition_rival)
# ------------------------------------------------------------------------------------------


def test_a_fix_ending_a_gap_keeps_its_prediction_as_a_rival_by_hand():
    monitor, fusion, r = _monitor_with_fixes()
    life = MonitorParameters().reacquisition_rival_s
    zeros = np.zeros((3, 3))

    def fix(t, z, prior=None):
        main = _Posterior(fusion, z, r / 2 * np.eye(3))
        monitor.mocap(t, np.array(z, dtype=float), UpdateOutcome(t, ACCEPTED, 3.0), main, prior)

    t = 0.0
    for _ in range(5):
        t += 0.01
        assert not monitor.wants_prior(t, True)
        fix(t, [0.0, 0.0, 0.0])
    # one missing frame (20 ms) is no gap: no prior wanted, no rival
    t += 0.02
    assert not monitor.wants_prior(t, True)
    fix(t, [0.0, 0.0, 0.0])
    assert not monitor.has_rivals(t)
    # a 0.3 s gap: the prediction, 3 mm from the fix with P- = 4 R, stays a rival:
    # P' = P + d d^T + (P- + R)
    t += 0.3
    assert monitor.wants_prior(t, True) and not monitor.wants_prior(t, False)
    prior = SimpleNamespace(position=np.array([0.003, 0.0, 0.0]),
                            position_covariance=4 * r * np.eye(3))
    fix(t, [0.0, 0.0, 0.0], prior)
    expected = np.diag([0.003 ** 2, 0.0, 0.0]) + 5 * r * np.eye(3)

    # The fix ending the gap has an NIS of 20 (beyond the edge test's 17.7 for one gap end):
    # from then on the bound also holds an offset on the fixes before a gap (its own tests:
    # test_edge_offsets), at the last fix and h s after it
    def edge(at):
        return monitor.edge_offset_variance(at) * np.eye(3)

    assert edge(t)[0, 0] > 0
    # at the fix, the offset whole, sigma^2 capped by the largest offset below the step rule
    # (2.7 R); h s later sigma^2 (a + b h)^2, never below the fix's
    at_fix = min(monitor._edge_variance(), step_offset_variance(r, monitor.params))
    assert edge(t)[0, 0] == pytest.approx(at_fix)
    assert edge(t + 1e-4)[0, 0] == pytest.approx(at_fix)  # it fell 6x here (a review's finding)
    assert edge(t + life)[0, 0] == pytest.approx(
        max(at_fix, monitor._edge_variance() * monitor._edge_shape(life)))
    np.testing.assert_allclose(monitor.cover_rivals(t, np.zeros(3), zeros),
                               expected + edge(t), rtol=1e-12)
    # for reacquisition_rival_s, its end included, then no more; not counted as a step
    np.testing.assert_allclose(monitor.cover_rivals(t + life, np.zeros(3), zeros),
                               expected + edge(t + life), rtol=1e-12)
    np.testing.assert_allclose(monitor.cover_rivals(t + life + 1e-6, np.zeros(3), zeros),
                               edge(t + life + 1e-6), rtol=1e-12)
    assert monitor.report().steps == 0
    # a fix ending a gap with an NIS beyond the step quantile is a step: its rival lasts
    # max_bridge_s, and it is counted
    limit = KalmanParameters.from_profiles("mpu9255").max_bridge_s
    t += 0.3
    monitor.mocap(t, np.zeros(3), UpdateOutcome(t, ACCEPTED, 80.0),
                  _Posterior(fusion, np.zeros(3), r / 2 * np.eye(3)), prior)
    np.testing.assert_allclose(monitor.cover_rivals(t + limit, np.zeros(3), zeros),
                               expected + edge(t + limit), rtol=1e-12)
    assert monitor.report().steps == 1
    # turned off: neither prior nor rival
    off, fusion_off, _ = _monitor_with_fixes()
    off.params = MonitorParameters(reacquisition_rival_s=0.0)
    off.mocap(0.01, np.zeros(3), UpdateOutcome(0.01, ACCEPTED, 3.0),
              _Posterior(fusion_off, np.zeros(3), r / 2 * np.eye(3)))
    assert not off.wants_prior(0.5, True)
    off.mocap(0.5, np.zeros(3), UpdateOutcome(0.5, ACCEPTED, 3.0),
              _Posterior(fusion_off, np.zeros(3), r / 2 * np.eye(3)), prior)
    assert not off.has_rivals(0.5)


def test_a_short_rival_does_not_end_a_longer_smaller_step():
    """A step rival (max_bridge_s) stays when a larger re-acquisition rival (0.2 s) comes and
    goes, and the larger one covers while both are in time."""
    monitor, fusion, r = _monitor_with_fixes()
    zeros = np.zeros((3, 3))
    t = 0.0
    for _ in range(5):
        t += 0.01
        monitor.mocap(t, np.zeros(3), UpdateOutcome(t, ACCEPTED, 3.0),
                      _Posterior(fusion, np.zeros(3), r / 2 * np.eye(3)))
    t += 0.01  # a 2 mm step: y = 2 mm, S = 2 R
    monitor.mocap(t, np.array([0.002, 0.0, 0.0]), UpdateOutcome(t, ACCEPTED, 80.0),
                  _Posterior(fusion, [0.001, 0.0, 0.0], r / 2 * np.eye(3)))
    step = np.diag([0.002 ** 2, 0.0, 0.0]) + 2 * r * np.eye(3)
    t += 0.1  # a gap, then a fix 5 mm from its prediction
    prior = SimpleNamespace(position=np.array([0.0, 0.005, 0.0]),
                            position_covariance=r * np.eye(3))
    monitor.mocap(t, np.zeros(3), UpdateOutcome(t, ACCEPTED, 3.0),
                  _Posterior(fusion, np.zeros(3), r / 2 * np.eye(3)), prior)
    larger = np.diag([0.0, 0.005 ** 2, 0.0]) + 2 * r * np.eye(3)
    # (the gap's end, 5 mm off, also starts the edge term, at the fix and after it:
    # test_edge_offsets)
    np.testing.assert_allclose(monitor.cover_rivals(t, np.zeros(3), zeros),
                               larger + monitor.edge_offset_variance(t) * np.eye(3),
                               rtol=1e-12)
    edge = monitor.edge_offset_variance(t + 0.25) * np.eye(3)
    np.testing.assert_allclose(monitor.cover_rivals(t + 0.25, np.zeros(3), zeros), step + edge,
                               rtol=1e-12)


@pytest.mark.parametrize("seed, duration, gaps", [(3, 20.0, (0.1, 0.3)), (2, 30.0, (0.1, 0.5))])
def test_bodies_re_solved_off_after_gaps_stay_inside_the_bound(seed, duration, gaps):
    """The first 10 frames after every gap 4 mm off (a body re-solved on part of its cluster):
    without the rival many of them are beyond the 99 % bound (the fix agrees with the loose
    prediction, no NIS shows it); with it, none. Seed 2 has a 0.5 s gap whose ending fix the
    filter takes as a re-acquisition (``reacquired``): its prediction is a rival too. Batch and
    Tracker agree bit for bit."""
    simulation = simulate("random_reach", seed=seed, duration=duration,
                          occlusions=OcclusionSpec(gap_range=gaps, spacing=1.5))
    streams = faults.occlusion_edge_offsets(faults.Streams.of(simulation.recording), 0.004, 10,
                                            "after")
    recording, truth = streams.recording, np.asarray(simulation.truth.position)
    shifted = np.any(recording.mocap.position != simulation.recording.mocap.position, axis=1)
    shifted &= recording.mocap.visible
    assert shifted.sum() >= 50

    def wrong_rows(monitor):
        result = run_filter(recording, monitor=monitor).result
        live = result.status != "lost"
        bound = K99 * np.where(live[:, None], result.std, 0.0).max(axis=1)
        return live & (np.linalg.norm(result.position - truth, axis=1) > bound), result

    without, _ = wrong_rows(MonitorParameters(reacquisition_rival_s=0.0))
    assert without[shifted].sum() >= 20
    wrong, result = wrong_rows(MonitorParameters())
    assert not wrong[shifted].any(), np.flatnonzero(wrong & shifted)
    params = resolve_parameters(recording, None, {})
    tracker = Tracker.from_recording_info(recording.info, params=params)
    rows = stream_rows(recording, tracker, arrival_orders(recording, 0.0)["natural"], 0.0)
    np.testing.assert_array_equal(rows["std"], result.std)
    np.testing.assert_array_equal(rows["position"], result.position)
