"""Impacts (knocks the IMU cannot resolve): the filter's time of the last one, in both engines
and through snapshots, and the consistency monitor's scales for gaps near them
(``MonitorParameters.impact_memory_s``), which are matched apart from the others.

The two-pass and event-by-event monitor runs with knocks are compared bit for bit in
``tests/test_compiled_engine.py`` (cases ``knocks`` and ``knocks_shrinking``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kfusion.evaluate import cut_gaps
from kfusion.kalman import model, run_filter, run_smoother
from kfusion.kalman.batch import make_fusion, process_recording, resolve_parameters
from kfusion.kalman.smoother import near_impact_rows
from kfusion.monitor import chi2_quantile
from kfusion.recording import Recording
from kfusion.simulate import OcclusionSpec, faults, simulate

R99 = math.sqrt(chi2_quantile(0.99, 3))


def test_is_impact_by_hand() -> None:
    # 1000 m/s^3 over a 5 ms interval: the specific force may change by 5 m/s^2
    assert model.is_impact(5.01 ** 2, 0.005, 1000.0, 0.0)
    assert not model.is_impact(4.99 ** 2, 0.005, 1000.0, 0.0)
    assert not model.is_impact(25.0, 0.005, 1000.0, 0.0)  # exactly at the limit: not beyond
    assert not model.is_impact(1e6, 0.0, 1000.0, 0.0)  # no interval
    assert not model.is_impact(1e300, 0.005, math.inf, 0.0)  # switched off
    # noise of 0.01 (m/s^2)^2 per sample explains 2 * 11.34 * 0.01 = 0.2269 of the change^2
    noise = 0.01
    allowance = 2.0 * model.NOISE_CHANGE_QUANTILE * noise
    assert model.is_impact(25.0 + allowance + 1e-9, 0.005, 1000.0, noise)
    assert not model.is_impact(25.0 + allowance - 1e-9, 0.005, 1000.0, noise)


def test_impact_times_by_hand() -> None:
    t = np.array([0.0, 0.01, 0.02, 0.03, 0.03, 0.05])
    force = np.zeros((6, 3))
    force[2] = [0.0, 6.0, 8.0]  # 10 m/s^2 in 10 ms: 1000 m/s^3, not beyond
    force[3] = [0.0, -6.0, -8.0]  # 20 m/s^2 in 10 ms: beyond; then a repeated stamp
    force[5] = [np.nan, 0.0, 0.0]
    np.testing.assert_array_equal(model.impact_times(t, force, 1000.0, 0.0), [0.03])
    np.testing.assert_array_equal(model.impact_times(t, force, 900.0, 0.0), [0.02, 0.03])
    # a density whose noise explains 2 * 11.34 * density^2 / 0.01 = 50 (m/s^2)^2 of each
    # interval's change^2: 100 - 50 > 81 no longer holds for the first
    density = math.sqrt(50.0 * 0.01 / (2.0 * model.NOISE_CHANGE_QUANTILE))
    np.testing.assert_array_equal(model.impact_times(t, force, 900.0, density), [0.03])
    assert model.impact_times(t, force, math.inf, 0.0).size == 0
    assert model.impact_times(t[:1], force[:1], 1000.0, 0.0).size == 0


def test_near_impact_rows_by_hand() -> None:
    # fixes at 0.0, 0.1 and 0.6 s; rows between them at 0.05 and 0.3, 0.4, 0.5 s
    t = np.array([0.0, 0.05, 0.1, 0.3, 0.4, 0.5, 0.6, 0.7])
    fixed = np.array([True, False, True, False, False, False, True, False])
    # an impact 0.25 s after the gap (0.1, 0.6) ends: within 0.3 s of its fix after
    near = near_impact_rows(t, fixed, np.array([0.85]), 0.3)
    np.testing.assert_array_equal(near, [False, False, False, True, True, True, False, True])
    # one in the first gap only
    near = near_impact_rows(t, fixed, np.array([0.07]), 0.0)
    np.testing.assert_array_equal(near, [False, True, False, False, False, False, False, False])
    # 0.21 s before the first gap's fix: within the memory; 0.31 s before: beyond it
    near = near_impact_rows(t, fixed, np.array([-0.21]), 0.3)
    np.testing.assert_array_equal(near, [False, True, False, False, False, False, False, False])
    assert not near_impact_rows(t, fixed, np.array([-0.31]), 0.3).any()
    assert not near_impact_rows(t, fixed, np.empty(0), 0.3).any()


def knocked(seed: int = 5) -> tuple[Recording, faults.Streams]:
    """A 6 s simulated arm lift with gaps, knocked about every 0.35 s."""
    simulation = simulate("arm_lift", seed=seed, duration=6.0,
                          occlusions=OcclusionSpec(gap_range=(0.15, 0.6), spacing=1.0))
    streams = faults.imu_knocks(faults.Streams.of(simulation.recording), every_s=0.35,
                                amplitude=150.0, frequency=120.0)
    return simulation.recording, streams


def test_the_knocks_fault_rings_without_moving_the_imu() -> None:
    """The fault's ringing integrates to no velocity and no displacement (the housing ends
    where it started), so what the samples make of it is the only error; the arm's samples
    are untouched between knocks."""
    clean, streams = knocked()
    added = streams.recording.imu.accelerometer - clean.imu.accelerometer
    assert np.abs(added).max() > 100.0  # knocks of about the amplitude
    assert (np.abs(added).max(axis=1) == 0.0).mean() > 0.7  # untouched between them
    fine = np.linspace(0.0, 0.04, 40001)  # one knock, sampled finely
    omega, window = 2 * np.pi * 120.0, np.pi / 0.04
    size = 150.0 / omega ** 2
    displacement = size * np.sin(omega * fine) * np.sin(window * fine) ** 2
    acceleration = np.gradient(np.gradient(displacement, fine), fine)
    velocity = np.concatenate([[0.0], np.cumsum(0.5 * (acceleration[1:] + acceleration[:-1])
                                                 * np.diff(fine))])
    assert abs(velocity[-1]) < 1e-3 and abs(displacement[-1]) < 1e-12


@pytest.mark.parametrize("impact_jerk", [1000.0, math.inf])
def test_both_engines_keep_the_same_last_impact_time(impact_jerk: float) -> None:
    """The filterpy and compiled engines mark the same intervals as impacts, and a snapshot
    carries the time: after every mocap frame both give the same ``last_impact_t``; every
    knock is marked (the intervals end within it), nothing else; none with impacts off."""
    _, streams = knocked()
    recording = streams.recording
    params = resolve_parameters(recording, None, {"impact_jerk": impact_jerk})
    seen: dict[str, list[float]] = {}
    for engine in ("filterpy", "compiled"):
        fusion = make_fusion(recording, params, engine)
        times: list[float] = []
        process_recording(recording, fusion,
                          lambda row, outcome, f=fusion, out=times: out.append(f.last_impact_t))
        seen[engine] = times
        restored = make_fusion(recording, params, engine)
        restored.restore(fusion.snapshot())
        assert restored.last_impact_t == fusion.last_impact_t
    assert seen["filterpy"] == seen["compiled"]
    marked = sorted({t for t in seen["compiled"] if t > -math.inf})
    if impact_jerk == math.inf:
        assert marked == []
        return
    clean = knocked()[0]
    added = np.abs(recording.imu.accelerometer - clean.imu.accelerometer).max(axis=1) > 0
    knock_times = recording.imu.t[added]
    period = float(np.median(np.diff(recording.imu.t)))
    assert marked and all(np.min(np.abs(knock_times - t)) <= 1.5 * period for t in marked)
    starts = knock_times[np.r_[True, np.diff(knock_times) > 0.1]]
    assert all(any(0 <= t - start <= 0.05 for t in marked) for start in starts[:-1])


def test_knocks_on_the_tapping_trial_keep_the_other_gaps_sharp() -> None:
    """BROAD trial 24 (tapping on a table). With one scale for every gap, the knocks set the
    scale of all the gaps after them: the median bound / error of the gap rows was 5.5 on
    these gaps (``benchmarks/bound_coverage.py``), the worst row 2.6x its bound in a gap
    through a knock. With the gaps near impacts matched apart, the others keep their own
    scale and the knocks' gaps theirs."""
    from kfusion.datasets import broad_trial
    from kfusion.readers.broad import read_broad

    try:
        path = broad_trial("24")
    except ValueError:
        pytest.skip("BROAD trials not found (../shared/data/broad): real-data test skipped")
    gapped = cut_gaps(read_broad(path, mocap_step=3), rng=np.random.default_rng(1),
                      gap_range=(0.1, 0.3))
    scores = {}
    for name, impact_jerk in (("apart", 1000.0), ("pooled", math.inf)):
        result = run_filter(gapped.recording, impact_jerk=impact_jerk).result
        gaps = gapped.gap_mask & (result.status != "lost")
        error = np.linalg.norm(result.position - gapped.truth_position, axis=1)[gaps]
        bound = R99 * result.std.max(axis=1)[gaps]
        inside = (np.abs(result.position - gapped.truth_position)
                  <= 3 * result.std).all(axis=1)[gaps]
        scores[name] = (float(np.median(bound / error)), float(np.max(error / bound)),
                        float(np.mean(error > bound)), float(np.mean(inside)),
                        int(gaps.sum()), int(gapped.gap_mask.sum()))
    apart, pooled = scores["apart"], scores["pooled"]
    assert apart[4] == apart[5] and pooled[4] == pooled[5], scores  # nothing lost
    assert apart[3] >= 0.97 and apart[2] <= 0.015 and apart[1] < 2.0, scores
    assert apart[0] <= 0.8 * pooled[0], scores
    # the smoother's hold-out, the same way
    smoothed = {}
    for name, impact_jerk in (("apart", 1000.0), ("pooled", math.inf)):
        result = run_smoother(gapped.recording, impact_jerk=impact_jerk).result
        gaps = gapped.gap_mask & (result.status != "lost")
        error = np.linalg.norm(result.position - gapped.truth_position, axis=1)[gaps]
        bound = R99 * result.std.max(axis=1)[gaps]
        inside = (np.abs(result.position - gapped.truth_position)
                  <= 3 * result.std).all(axis=1)[gaps]
        smoothed[name] = (float(np.median(bound / error)), float(np.mean(inside)),
                          int(gaps.sum()))
    assert smoothed["apart"][2] == smoothed["pooled"][2] == apart[5], smoothed
    assert smoothed["apart"][1] >= 0.95, smoothed
    assert smoothed["apart"][0] <= 0.9 * smoothed["pooled"][0], smoothed
