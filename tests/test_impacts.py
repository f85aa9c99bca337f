"""Impacts (knocks the IMU cannot resolve): the filter's time of the last one, in both engines
and through snapshots, and the consistency monitor's scales for gaps near them
(``MonitorParameters.impact_memory_s``), which are matched apart from the others.

The two-pass and event-by-event monitor runs with knocks are compared bit for bit in
``tests/test_compiled_engine.py`` (cases ``knocks`` and ``knocks_shrinking``)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from kfusion.evaluate import cut_gaps
from kfusion.kalman import model, run_filter
from kfusion.kalman.batch import make_fusion, process_recording, resolve_parameters
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


def test_interpolation_variance_by_hand() -> None:
    # noise of 0.01 (m/s^2)^2 per sample explains 2 * 11.34 * 0.01 of the change^2; the rest,
    # 36 (m/s^2)^2, is spread as |df|^2 / 36 = 1 per axis, or on an impact |df|^2 / 8 = 4.5
    noise = 0.01
    change_squared = 36.0 + 2.0 * model.NOISE_CHANGE_QUANTILE * noise
    assert model.interpolation_variance(change_squared, noise) == pytest.approx(1.0, abs=1e-12)
    assert model.interpolation_variance(change_squared, noise, True) == pytest.approx(
        4.5, abs=1e-12)
    assert model.interpolation_variance(0.1, noise, True) == 0.0  # within the noise


def test_the_numpy_reference_treats_impacts_as_the_filter_does() -> None:
    """The reference writes the impact rule out itself (|df|^2 / 8 beyond impact_jerk): over a
    knocked recording it equals the filterpy filter, and the knocks widen the bound."""
    from kfusion.kalman.reference import reference_filter

    _, streams = knocked()
    recording = streams.recording
    params = resolve_parameters(recording, None, {})
    run = run_filter(recording, params, monitor=None, engine="filterpy")
    reference = reference_filter(recording, params)
    np.testing.assert_allclose(run.x, reference.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(run.P, reference.P, rtol=0, atol=1e-9)
    # with the impact rule off the knocks' intervals get |df|^2 / 36: a smaller bound
    off = run_filter(recording, dataclasses.replace(params, impact_jerk=math.inf), monitor=None,
                     engine="filterpy")
    bridged = run.result.status == "bridged"
    assert (run.result.std[bridged] >= off.result.std[bridged] - 1e-15).all()
    assert (run.result.std[bridged] > 1.5 * off.result.std[bridged]).any()


def knocked(seed: int = 5) -> tuple[Recording, faults.Streams]:
    """A 6 s simulated arm lift with gaps, knocked about every 0.35 s."""
    simulation = simulate("arm_lift", seed=seed, duration=6.0,
                          occlusions=OcclusionSpec(gap_range=(0.15, 0.6), spacing=1.0))
    streams = faults.imu_knocks(faults.Streams.of(simulation.recording), every_s=0.35,
                                amplitude=150.0, frequency=120.0)
    return simulation.recording, streams


def test_the_knocks_fault_rings_without_moving_the_imu() -> None:
    """The fault's ringing integrates to no velocity (the housing ends where it started, at
    rest), so what the samples make of it is the only error: sampled at 20 kHz, the knocks'
    added acceleration integrates to below 1 mm/s (a damped sine of the same size would leave
    A w / (w^2 + 1/tau^2), about 0.1 m/s per knock); at 200 Hz the knocks are their
    amplitude's size and the samples between them untouched."""
    clean, streams = knocked()
    added = streams.recording.imu.accelerometer - clean.imu.accelerometer
    assert np.abs(added).max() > 100.0  # knocks of about the amplitude
    assert (np.abs(added).max(axis=1) == 0.0).mean() > 0.7  # untouched between them
    fine = simulate("arm_lift", seed=1, duration=5.0, imu_rate=20000.0).recording
    ringing = faults.imu_knocks(faults.Streams.of(fine), every_s=2.0, seed=3).recording.imu
    t = fine.imu.t
    added = ringing.accelerometer - fine.imu.accelerometer
    assert np.abs(added).max() > 50.0
    velocity = np.concatenate([np.zeros((1, 3)), np.cumsum(
        0.5 * (added[1:] + added[:-1]) * np.diff(t)[:, None], axis=0)])
    assert np.abs(velocity).max() > 0.01  # it does ring
    assert np.abs(velocity[-1]).max() < 1e-3  # and leaves no velocity (within the rule's error)


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


@pytest.mark.broad
def test_knocks_on_the_tapping_trial_keep_the_other_gaps_sharp() -> None:
    """BROAD trial 24 (tapping on a table), gaps cut with seed 1. With one scale for every
    gap, the knocks set the scale of all the gaps after them: median bound / error 6.5, 1.13 %
    of the gap rows beyond their 99 % bound, the worst 2.6x, in a gap through a knock. With the
    gaps near impacts matched apart, 4.8, 0.98 % and 2.1x."""
    from kfusion.datasets import broad_trial
    from kfusion.readers.broad import read_broad

    gapped = cut_gaps(read_broad(broad_trial("24"), mocap_step=3),
                      rng=np.random.default_rng(1), gap_range=(0.1, 0.3))
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
    # no fewer rows inside the bound, no worse worst row, and sharper
    assert apart[3] >= 0.97 and apart[2] <= pooled[2] and apart[1] <= pooled[1], scores
    assert apart[0] <= 0.8 * pooled[0], scores
