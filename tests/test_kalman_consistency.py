"""Monte Carlo consistency of the Kalman filter and smoother (NEES and NIS in chi-square bounds).

A model-matched simulation: the simulator (kfusion.simulate) with an IMU and a mocap whose errors
are exactly what the filter assumes: accelerometer white noise, bias random walk and turn-on bias
from the MPU9255 profile; no scale or cross-axis error, no quantisation, no saturation; an exact
gyroscope and an exact mocap orientation; mocap position noise from the OptiTrack profile. The
simulator's trajectory is smooth and its IMU samples are instantaneous values, as the filter's
first-order hold assumes.

Each run contributes one value per check, at one row chosen by the run's own occlusions, so the
runs are independent and the mean of N values of a chi-square(d) variable has the two-sided 95 %
interval ``chi2.ppf([0.025, 0.975], d N) / N``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

from kfusion.kalman import KalmanParameters, run_filter, run_smoother
from kfusion.profiles import MPU9255, OPTITRACK
from kfusion.simulate import OcclusionSpec, simulate

RUNS = 100
MATCHED_IMU = dataclasses.replace(
    MPU9255, accelerometer_scale_error=0.0, accelerometer_cross_axis=0.0,
    accelerometer_resolution=0.0, accelerometer_range=1e6,
    gyroscope_noise_density=0.0, gyroscope_bias_random_walk=0.0, gyroscope_turn_on_bias=0.0,
    gyroscope_scale_error=0.0, gyroscope_cross_axis=0.0, gyroscope_resolution=0.0,
    gyroscope_range=1e6)
MATCHED_MOCAP = dataclasses.replace(OPTITRACK, orientation_noise=0.0)


def nees(error: np.ndarray, covariance: np.ndarray) -> float:
    """e^T P^-1 e."""
    return float(error @ np.linalg.solve(covariance, error))


def interval(dof: int, runs: int) -> np.ndarray:
    """Two-sided 95 % interval of the mean of ``runs`` chi-square(dof) values."""
    return chi2.ppf([0.025, 0.975], dof * runs) / runs


def monte_carlo(params: KalmanParameters, runs: int = RUNS) -> dict[str, np.ndarray]:
    values: dict[str, list[float]] = {key: [] for key in (
        "filter_before_gap", "filter_gap_end", "smoother_before_gap", "smoother_gap_middle",
        "nis_after_gap")}
    for seed in range(runs):
        sim = simulate("random_reach", seed=seed, imu=MATCHED_IMU, mocap=MATCHED_MOCAP,
                       duration=8.0, occlusions=OcclusionSpec(gap_range=(0.2, 0.3), spacing=1.0))
        run = run_smoother(sim.recording, params)
        # the forward filter's states (the smoother keeps its point estimates only)
        forward = run_filter(sim.recording, params, monitor=None)
        truth = sim.truth
        dense = np.searchsorted(truth.imu_t, truth.t)
        state = np.column_stack([truth.imu_position[dense], truth.imu_velocity[dense],
                                 truth.accelerometer_bias[dense]])
        occluded = np.flatnonzero(truth.occluded)
        start = int(occluded[0])
        end = start
        while truth.occluded[end + 1]:
            end += 1
        middle = (start + end) // 2
        before = start - 1
        values["filter_before_gap"].append(
            nees(forward.x[before] - state[before], forward.P[before]))
        values["filter_gap_end"].append(
            nees(forward.x[end, :3] - state[end, :3], forward.P[end, :3, :3]))
        values["smoother_before_gap"].append(nees(run.x[before] - state[before], run.P[before]))
        values["smoother_gap_middle"].append(
            nees(run.x[middle, :3] - state[middle, :3], run.P[middle, :3, :3]))
        # the first fix after the gap, against the filter's prediction
        values["nis_after_gap"].append(float(run.nis[end + 1]))
    return {key: np.array(value) for key, value in values.items()}


@pytest.fixture(scope="module")
def matched() -> dict[str, np.ndarray]:
    return monte_carlo(KalmanParameters.from_profiles(MATCHED_IMU, MATCHED_MOCAP))


@pytest.mark.slow
@pytest.mark.parametrize(("key", "dof"), [
    ("filter_before_gap", 9), ("filter_gap_end", 3), ("smoother_before_gap", 9),
    ("smoother_gap_middle", 3), ("nis_after_gap", 3)])
def test_average_nees_and_nis_lie_in_the_chi_square_interval(matched, key, dof):
    values = matched[key]
    assert len(values) == RUNS and np.isfinite(values).all()
    low, high = interval(dof, RUNS)
    assert low <= values.mean() <= high, f"{key}: mean {values.mean():.3f} not in " \
                                         f"[{low:.3f}, {high:.3f}]"


@pytest.mark.slow
def test_the_check_detects_a_wrong_noise_model():
    # the filter told the accelerometer is 3 times noisier than it is: NEES far too small
    params = KalmanParameters.from_profiles(
        MATCHED_IMU, MATCHED_MOCAP,
        accelerometer_noise_density=3 * MATCHED_IMU.accelerometer_noise_density)
    values = monte_carlo(params, runs=30)
    assert values["filter_gap_end"].mean() < interval(3, 30)[0]
