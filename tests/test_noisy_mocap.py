"""A mocap noisier than configured (recording.yaml cannot say it): the windowed NIS fails high,
and the fused fixes, the fixes shown alone and the smoothed rows at fixes take its factor
(kfusion.monitor: at_fix, fix_only), so no path presents a fix as surer than the data say."""

from __future__ import annotations

import math

import numpy as np
import pytest

from kfusion.kalman import run_filter, run_smoother
from kfusion.monitor import chi2_quantile
from kfusion.profiles import DEGREE, MocapProfile
from kfusion.simulate import OcclusionSpec, simulate

R99 = math.sqrt(chi2_quantile(0.99, 3))


def _wrong_fraction(result, truth: np.ndarray) -> float:
    status = np.asarray(result.status).astype(str)
    live = status != "lost"
    error = np.linalg.norm(np.asarray(result.position) - truth, axis=1)
    std = np.asarray(result.std)
    bound = R99 * np.where(np.isfinite(std), std, 0.0).max(axis=1)  # lost rows: NaN std
    return float(np.mean(live & (error > bound)))


@pytest.mark.parametrize("noise_mm", [0.6, 1.0])
def test_a_noisier_mocap_is_covered(noise_mm):
    # configured 0.3 mm (the optitrack profile). Before: kalman 19.5 % / 71 % of rows beyond
    # the 99 % bound, smoother 37 % / 71 % (60 s; tracked rows reported 0.30 mm against a
    # median error of 1.5 mm at 1 mm)
    mocap = MocapProfile(name="noisy", position_noise=noise_mm * 1e-3,
                         orientation_noise=0.2 * DEGREE, rate=100.0)
    simulation = simulate("random_reach", seed=0, duration=30.0, mocap=mocap,
                          occlusions=OcclusionSpec(spacing=1.5))
    truth = np.asarray(simulation.truth.position)
    kalman = run_filter(simulation.recording)
    smoother = run_smoother(simulation.recording)
    assert kalman.monitor is not None and kalman.monitor.nis.mean > kalman.monitor.nis.upper
    assert _wrong_fraction(kalman.result, truth) <= 0.01
    assert _wrong_fraction(smoother.result, truth) <= 0.015
