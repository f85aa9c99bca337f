"""The motion-dependent acceleration noise (fast part of the accelerometer's scale error,
:func:`kfusion.kalman.model.motion_acceleration_variance`): hand-derived values, and the bound it
buys on a fast simulated recording with IMU errors outside the model."""

from __future__ import annotations

import numpy as np
import pytest

from kfusion.evaluate import gap_errors
from kfusion.kalman import model, run_smoother
from kfusion.simulate import TYPICAL_UNMODELLED, OcclusionSpec, simulate


def test_motion_acceleration_variance_by_hand() -> None:
    # scale error 1.2 %, |f - f_lp| = 5 m/s^2, tau 0.1 s, dt 5 ms:
    # 0.012^2 * 25 * 0.1 / 0.005 = 0.072 (m/s^2)^2
    assert model.motion_acceleration_variance(25.0, 0.005, 0.012, 0.1) == pytest.approx(0.072)
    # held over the interval it moves the velocity by 0.072 * dt^2 per axis
    Q = model.process_noise(0.005, 0.0, 1e-4, acceleration_variance=0.072)
    assert Q[3, 3] == pytest.approx(0.072 * 0.005 ** 2)
    assert Q[0, 0] == pytest.approx(0.072 * 0.005 ** 4 / 4)


def test_motion_acceleration_variance_vanishes_without_motion_or_error() -> None:
    assert model.motion_acceleration_variance(0.0, 0.005, 0.012, 0.1) == 0.0
    assert model.motion_acceleration_variance(25.0, 0.005, 0.0, 0.1) == 0.0
    assert model.motion_acceleration_variance(25.0, 0.0, 0.012, 0.1) == 0.0


def test_variance_density_does_not_depend_on_the_imu_rate() -> None:
    # white noise: variance per interval times dt (the velocity variance per second) is the
    # same at 100 Hz and 1 kHz
    slow = model.motion_acceleration_variance(9.0, 0.01, 0.01, 0.1) * 0.01
    fast = model.motion_acceleration_variance(9.0, 0.001, 0.01, 0.1) * 0.001
    assert slow == pytest.approx(fast)


def three_sigma_coverage(result, truth, gaps) -> float:
    errors = gap_errors(result, truth, gaps)
    return float(np.mean((np.abs(errors.error) <= 3 * errors.std).all(axis=1)))


def test_the_bound_holds_in_fast_lifts_with_unmodelled_imu_errors() -> None:
    # Fast vertical lifts (|a| up to 8 m/s^2) with the accelerometer's drawn z scale error at
    # -3.5 % and every unmodelled error source on: without the motion term the filter's 3-sigma
    # coverage in the gaps was 0.945 and the smoother's 0.918 (the velocity covariance at the
    # fix before a gap ignored the error S (f - f_lp) the bias cannot follow).
    simulation = simulate("arm_lift", seed=0, imu="mpu9255", unmodelled=TYPICAL_UNMODELLED,
                          occlusions=OcclusionSpec(gap_range=(0.1, 0.3)))
    run = run_smoother(simulation.recording)
    truth, gaps = simulation.truth.position, simulation.truth.occluded
    assert three_sigma_coverage(run.filtered, truth, gaps) >= 0.955
    assert three_sigma_coverage(run.result, truth, gaps) >= 0.955
