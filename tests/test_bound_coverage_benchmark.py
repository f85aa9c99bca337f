"""The coverage benchmark's oracle sharpness (``bound_coverage.py --oracle``) and its count of rows
beyond the 99 % radius, by hand."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from benchmark_module import load_benchmark as load_module
from scipy.stats import chi2

from kfusion.evaluate import GapErrors


def load_benchmark():
    return load_module("bound_coverage")


def test_oracle_sharpness_by_hand():
    # 100 rows, unit sigma on every axis, errors 0.1 k along x (k = 1..100).
    size = 0.1 * np.arange(1, 101)
    errors = GapErrors(np.column_stack([size, np.zeros(100), np.zeros(100)]),
                       np.ones((100, 3)), 0)
    r99 = math.sqrt(chi2.ppf(0.99, 3))
    # median of r99 / (0.1 k): the mean of its 50th and 51st values
    sharpness = r99 * (10 / 50 + 10 / 51) / 2
    # numpy's linear quantile at 0.99 of z = 0.1 k / r99: index 98.01 -> (9.9 + 0.01 * 0.1) / r99
    c99 = 9.901 / r99
    # at 0.97 of w = 0.1 k / 3: index 96.03 -> (9.7 + 0.03 * 0.1) / 3
    c97 = 9.703 / 3
    oracle = load_benchmark().oracle_sharpness(errors)
    assert oracle["o99"] == pytest.approx(c99 * sharpness, rel=1e-12)
    assert oracle["o97"] == pytest.approx(c97 * sharpness, rel=1e-12)
    assert oracle["o99"] == pytest.approx(9.901 * (10 / 50 + 10 / 51) / 2, rel=1e-12)


def test_oracle_sharpness_of_a_calibrated_gaussian():
    # Isotropic N(0, I): 99 % inside r99 already, so o99 is the sharpness itself, about
    # r99 / median |e| = 3.368 / 1.538 = 2.19 (median of a chi with 3 degrees of freedom).
    rng = np.random.default_rng(3)
    error = rng.standard_normal((200_000, 3))
    oracle = load_benchmark().oracle_sharpness(GapErrors(error, np.ones_like(error), 0))
    expected = math.sqrt(chi2.ppf(0.99, 3)) / math.sqrt(chi2.ppf(0.5, 3))
    assert oracle["o99"] == pytest.approx(expected, rel=0.02)
    empty = load_benchmark().oracle_sharpness(GapErrors(np.empty((0, 3)), np.empty((0, 3)), 0))
    assert math.isnan(empty["o99"]) and math.isnan(empty["o97"])


def test_beyond_r99_counts_the_rows_outside_the_99_percent_radius():
    # unit sigma; errors along x of 1, 3.3 and 3.4 (r99 = 3.368): one row beyond the radius,
    # two beyond 3 sigma on x, so the 3-sigma coverage is 1/3
    errors = GapErrors(np.array([[1.0, 0, 0], [3.3, 0, 0], [3.4, 0, 0]]), np.ones((3, 3)), 0)
    row = load_benchmark().row(errors)
    assert row["beyond99"] == pytest.approx(1 / 3)
    assert row["coverage"] == pytest.approx(1 / 3)
    # a row inside 3 sigma on every axis can be beyond the radius: (2.9, 2.9, 0) has |e| 4.1
    diagonal = GapErrors(np.array([[2.9, 2.9, 0.0]]), np.ones((1, 3)), 0)
    assert load_benchmark().row(diagonal)["beyond99"] == 1.0
    assert load_benchmark().row(diagonal)["coverage"] == 1.0


def test_violent_placement_starts_gaps_just_before_the_largest_jolts():
    """``--placement violent``: a gap starts ``VIOLENT_LEAD_S`` before the most violent frame,
    the next ones at the next peaks at least ``spacing + 0.6`` s apart, and none where the mocap
    was not visible for ``spacing`` s before it."""
    from kfusion.evaluate import hide_frames
    from kfusion.recording import ImuSamples
    from kfusion.simulate import OcclusionSpec, simulate

    benchmark = load_benchmark()
    recording = simulate("arm_lift", seed=1, duration=20.0,
                         occlusions=OcclusionSpec(gap_range=(0.1, 0.3), spacing=3.0)).recording
    imu = recording.imu
    accelerometer = np.array(imu.accelerometer)
    for jolt_t, size in ((12.0, 300.0), (6.0, 200.0), (6.5, 150.0)):
        accelerometer[np.argmin(np.abs(imu.t - jolt_t))] += size  # one sample, a jump and back
    jolted = dataclasses.replace(recording,
                                 imu=ImuSamples(imu.t, accelerometer, imu.gyroscope))
    t = jolted.mocap.t
    mask = benchmark.violent_gap_mask(jolted, np.random.default_rng(0), (0.1, 0.3), 3)
    starts = t[np.flatnonzero(np.diff(np.r_[False, mask].astype(int)) == 1)]
    assert len(starts) == 3 and np.diff(np.sort(starts)).min() >= 1.6
    # a gap starts at most a frame or two before each of the two largest jolts (the violence is
    # averaged over 30 ms) and hides the frame at it; 6.5 s is too close to 6.0 for a third
    for jolt_t in (12.0, 6.0):
        assert np.any((starts >= jolt_t - 0.035) & (starts <= jolt_t))
        assert mask[np.argmin(np.abs(t - jolt_t))]
    assert np.min(np.abs(starts - 6.5)) > 0.4
    visible = jolted.mocap.visible
    for start in starts:
        before = (t >= start - 1.0) & (t < start)
        assert visible[before].all()
    assert np.isnan(hide_frames(jolted, mask).recording.mocap.position[mask]).all()
