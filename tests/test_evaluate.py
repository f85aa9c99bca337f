"""Gap cutting and gap metrics, against hand-computed values."""

from __future__ import annotations

import numpy as np
import pytest

from kfusion.conventions import BRIDGED, LOST, TRACKED
from kfusion.evaluate import GapErrors, cut_gaps, gap_metrics, metrics_from_errors, per_gap_errors
from kfusion.recording import ImuSamples, MocapFrames, Recording, RecordingInfo, occlusion_runs
from kfusion.track_file import TrackResult


def make_recording(duration: float = 30.0, rate: float = 100.0,
                   hidden: tuple[int, int] | None = None) -> Recording:
    t = np.arange(0.0, duration, 1.0 / rate)
    position = np.column_stack([np.sin(t), np.cos(t), 0.1 * t])
    quaternion = np.tile([1.0, 0.0, 0.0, 0.0], (len(t), 1))
    if hidden is not None:
        position[hidden[0]:hidden[1]] = np.nan
        quaternion[hidden[0]:hidden[1]] = np.nan
    imu_t = np.arange(0.0, duration, 0.005)
    accelerometer = np.tile([0.0, 0.0, 9.81], (len(imu_t), 1))
    return Recording(
        imu=ImuSamples(imu_t, accelerometer, np.zeros_like(accelerometer)),
        mocap=MocapFrames(t, position, quaternion),
        info=RecordingInfo(imu_to_body=[1, 0, 0, 0], gravity=[0, 0, -9.81]),
    )


def test_cut_gaps_respects_length_spacing_and_existing_occlusions():
    recording = make_recording(hidden=(1000, 1030))
    gapped = cut_gaps(recording, rng=np.random.default_rng(3), gap_range=(0.1, 0.3), spacing=1.0)
    t = recording.mocap.t
    original_hidden = ~recording.mocap.visible
    runs = occlusion_runs(~gapped.gap_mask)
    assert len(runs) >= 10
    for start, stop in runs:
        length = t[stop - 1] - t[start]
        assert 0.1 - 0.011 <= length <= 0.3
        # visible for spacing seconds before, and the frame after the gap is visible
        before = (t >= t[start] - 1.0) & (t < t[start])
        assert not original_hidden[before].any()
        assert not original_hidden[stop]
    # the estimator sees every cut row and the original occlusion as occluded
    assert np.array_equal(~gapped.recording.mocap.visible, gapped.gap_mask | original_hidden)
    # the truth is the hidden mocap, NaN where the original was occluded
    np.testing.assert_array_equal(gapped.truth_position[gapped.gap_mask],
                                  recording.mocap.position[gapped.gap_mask])
    assert np.isnan(gapped.truth_position[original_hidden]).all()


def test_cut_gaps_is_seeded_and_counts():
    recording = make_recording()
    first = cut_gaps(recording, rng=np.random.default_rng(1), count=3)
    second = cut_gaps(recording, rng=np.random.default_rng(1), count=3)
    assert np.array_equal(first.gap_mask, second.gap_mask)
    assert len(occlusion_runs(~first.gap_mask)) == 3


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"gap_range": (0.3, 0.1)}, r"gap_range: expected 0 < min <= max, got \(0.3, 0.1\)"),
    ({"gap_range": (0.0, 0.1)}, "gap_range"),
    ({"spacing": 0.0}, "spacing: expected a positive number of seconds, got 0.0"),
])
def test_cut_gaps_rejects_bad_arguments(kwargs, message):
    with pytest.raises(ValueError, match=message):
        cut_gaps(make_recording(duration=5.0), rng=np.random.default_rng(0), **kwargs)


def make_result(position, std, status):
    count = len(status)
    return TrackResult(t=np.arange(count) * 0.01, position=np.asarray(position, float),
                       std=np.asarray(std, float), status=np.asarray(status),
                       time_since_fix=np.zeros(count))


def test_gap_metrics_hand_computed():
    truth = np.zeros((5, 3))
    # errors of size 3 mm (3-4-0 triangle: 5 mm) and 0
    position = [[0, 0, 0], [0.003, 0.004, 0], [0.0, 0.0, 0.002], [1, 1, 1], [0, 0, 0]]
    std = np.full((5, 3), 0.001)
    status = [TRACKED, BRIDGED, BRIDGED, LOST, TRACKED]
    gap = np.array([False, True, True, True, False])
    metrics = gap_metrics(make_result(position, std, status), truth, gap)
    assert metrics["samples"] == 2
    assert metrics["rms_mm"] == pytest.approx(np.sqrt((25 + 4) / 2))
    assert metrics["max_mm"] == pytest.approx(5.0)
    assert metrics["mean_mm"] == pytest.approx(3.5)
    # 5 mm sample: |e_y| = 4 mm > 3 sigma = 3 mm -> outside; 2 mm sample inside
    assert metrics["coverage_3sigma"] == pytest.approx(0.5)
    assert metrics["lost_fraction"] == pytest.approx(1 / 3)


def test_gap_metrics_without_uncertainty_and_empty():
    truth = np.zeros((3, 3))
    result = make_result(np.zeros((3, 3)), np.full((3, 3), np.nan), [TRACKED, BRIDGED, TRACKED])
    metrics = gap_metrics(result, truth, np.array([False, True, False]))
    assert metrics["rms_mm"] == 0.0
    assert np.isnan(metrics["coverage_3sigma"])
    empty = metrics_from_errors(GapErrors(np.empty((0, 3)), np.empty((0, 3)), 0))
    assert empty["samples"] == 0 and np.isnan(empty["rms_mm"])


def test_gap_metrics_rejects_wrong_shapes():
    result = make_result(np.zeros((3, 3)), np.zeros((3, 3)), [TRACKED] * 3)
    with pytest.raises(ValueError, match=r"expected truth_position \(3, 3\) and gap_mask \(3,\)"):
        gap_metrics(result, np.zeros((2, 3)), np.zeros(3, bool))


def test_per_gap_errors_one_row_per_gap():
    truth = np.zeros((8, 3))
    position = np.zeros((8, 3))
    position[2] = [0.001, 0, 0]
    position[5] = [0, 0.002, 0]
    status = [TRACKED, TRACKED, BRIDGED, TRACKED, TRACKED, BRIDGED, BRIDGED, TRACKED]
    gap = np.array([0, 0, 1, 0, 0, 1, 1, 0], dtype=bool)
    table = per_gap_errors(make_result(position, np.full((8, 3), 1e-3), status), truth, gap)
    assert list(table["gap_start_s"]) == pytest.approx([0.02, 0.05])
    assert list(table["duration_s"]) == pytest.approx([0.02, 0.03])
    assert list(table["max_mm"]) == pytest.approx([1.0, 2.0])
