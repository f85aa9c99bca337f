"""IMU timestamp jitter: measured from the recording's own sample intervals
(:func:`kfusion.kalman.model.timestamp_jitter`) and carried as acceleration noise
(:func:`kfusion.kalman.model.stamp_jitter_variance`) by all three engines."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from kfusion.datasets import broad_trials
from kfusion.kalman import model
from kfusion.kalman.batch import resolve_parameters, run_filter
from kfusion.kalman.parameters import KalmanParameters
from kfusion.kalman.reference import reference_filter
from kfusion.simulate import OcclusionSpec, UnmodelledErrors, simulate


def test_stamp_jitter_variance_by_hand() -> None:
    # jitter 0.5 ms, acceleration change 0.5 m/s^2 over a 5 ms step:
    # 0.0005^2 * 0.25 / 0.005^2 = 0.0025 (m/s^2)^2, i.e. a velocity step of
    # 0.0025 * dt^2 = 6.25e-8 (m/s)^2 = (0.5 ms * 0.5 m/s^2)^2
    assert model.stamp_jitter_variance(0.25, 0.005, 0.0005) == pytest.approx(0.0025)
    assert model.stamp_jitter_variance(0.25, 0.005, 0.0005) * 0.005 ** 2 == pytest.approx(
        (0.0005 * 0.5) ** 2)
    assert model.stamp_jitter_variance(0.0, 0.005, 0.0005) == 0.0  # at rest or steady
    assert model.stamp_jitter_variance(0.25, 0.005, 0.0) == 0.0  # a clean clock
    assert model.stamp_jitter_variance(0.25, 0.0, 0.0005) == 0.0


def test_stamp_jitter_variance_matches_a_monte_carlo_integration() -> None:
    # a(t) = j t sampled at tau_k = k dt, stamped tau_k + d_k; the velocity integrated
    # trapezoidally over the stamped intervals, against the true velocity at the last stamp:
    # the error is the random walk of the docstring, n steps of jitter^2 (j dt)^2
    rng = np.random.default_rng(1)
    dt, jitter, steps, jerk = 0.005, 0.5e-3, 60, 40.0
    tau = np.arange(steps + 1) * dt
    acceleration = jerk * tau
    stamps = tau + jitter * rng.standard_normal((20000, steps + 1))
    integrated = jerk * stamps[:, 0] ** 2 / 2 + (
        (acceleration[:-1] + acceleration[1:]) / 2 * np.diff(stamps, axis=1)).sum(axis=1)
    error = integrated - jerk * stamps[:, -1] ** 2 / 2
    predicted = steps * model.stamp_jitter_variance((jerk * dt) ** 2, dt, jitter) * dt ** 2
    assert error.var() == pytest.approx(predicted, rel=0.05)


def test_timestamp_jitter_is_measured_from_the_intervals() -> None:
    rng = np.random.default_rng(3)
    regular = np.arange(4000) * 0.005
    assert model.timestamp_jitter(regular) == pytest.approx(0.0, abs=1e-12)
    jittered = regular + 0.4e-3 * rng.standard_normal(len(regular))
    assert model.timestamp_jitter(jittered) == pytest.approx(0.4e-3, rel=0.08)
    # a few dropouts (missing samples) do not count as jitter
    dropped = np.delete(jittered, np.arange(100, 4000, 400))
    assert model.timestamp_jitter(dropped) == pytest.approx(0.4e-3, rel=0.08)
    assert model.timestamp_jitter(np.array([0.0, 0.01])) == 0.0


def jittered_recording(jitter: float):
    return simulate("arm_lift", seed=0, imu="mpu9255",
                    unmodelled=UnmodelledErrors(timestamp_jitter=jitter),
                    occlusions=OcclusionSpec(gap_range=(0.1, 0.3))).recording


def test_batch_runs_measure_the_recordings_jitter() -> None:
    assert resolve_parameters(jittered_recording(0.5e-3), None, {}).timestamp_jitter == (
        pytest.approx(0.5e-3, rel=0.1))
    clean = simulate("arm_lift", seed=0, imu="mpu9255").recording
    assert resolve_parameters(clean, None, {}).timestamp_jitter == pytest.approx(0.0, abs=1e-9)
    # the caller's value wins
    assert resolve_parameters(clean, None, {"timestamp_jitter": 1e-3}).timestamp_jitter == 1e-3


@pytest.mark.broad
def test_broad_clocks_have_no_jitter() -> None:
    trials = broad_trials()
    from kfusion.readers.broad import read_broad

    recording = read_broad(trials[0], mocap_step=3)
    assert resolve_parameters(recording, None, {}).timestamp_jitter < 1e-6


def test_engines_agree_on_the_jitter_term() -> None:
    recording = jittered_recording(0.5e-3)
    params = dataclasses.replace(KalmanParameters.from_profiles("mpu9255"),
                                 timestamp_jitter=2e-3)
    filterpy = run_filter(recording, params, monitor=None, engine="filterpy")
    compiled = run_filter(recording, params, monitor=None, engine="compiled")
    reference = reference_filter(recording, params)
    np.testing.assert_allclose(filterpy.P, reference.P, rtol=0, atol=1e-9)
    np.testing.assert_allclose(filterpy.x, reference.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(compiled.result.std, filterpy.result.std, rtol=1e-9, atol=1e-12)
    # and the term is there: the bound in the gaps is wider than without it
    without = run_filter(recording, dataclasses.replace(params, timestamp_jitter=0.0),
                         monitor=None, engine="filterpy")
    gaps = np.isfinite(filterpy.result.std).all(axis=1) & (filterpy.result.time_since_fix > 0)
    assert (filterpy.result.std[gaps] >= without.result.std[gaps] - 1e-15).all()
    assert (filterpy.result.std[gaps] > without.result.std[gaps] * 1.001).any()
