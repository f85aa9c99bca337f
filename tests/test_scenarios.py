"""Scenario tests: every method on the paper's simulated experiments and on real BROAD trials.

The thresholds are the targets of the Kalman issue (kalman <= 5 mm RMS on simulated 0.1-0.3 s
gaps, smoother <= 2 mm, kalman at least 5x better than the baseline, <= 8 mm on BROAD, >= 95 % of
gap samples inside 3 sigma), checked here on shorter data than the benchmark
(``benchmarks/accuracy.py``) so the suite stays fast. Nothing is tuned to these runs: the
parameters are the defaults from the sensor profiles.
"""

from __future__ import annotations

import pytest

from kfusion.config import (
    GapsConfig,
    OcclusionsConfig,
    first_seconds,
    recording_with_gaps,
    simulated_recording,
)
from kfusion.datasets import broad_excerpt, broad_trial
from kfusion.experiment import ScoredRecording, run_method, summary_table
from kfusion.readers.broad import read_broad
from kfusion.recording import Recording, read_recording

METHODS = ("baseline", "kalman", "smoother")


def score(scored: list[ScoredRecording]):
    runs = [run_method(one, method) for one in scored for method in METHODS]
    return summary_table(runs)


@pytest.mark.parametrize(("scenario", "placement"), [("arm_lift", "mid_motion"),
                                                     ("arm_lift", "direction_change"),
                                                     ("pick_tool", "random")])
def test_simulated_paper_experiment_meets_the_targets(scenario, placement):
    occlusions = OcclusionsConfig(gap_range=(0.1, 0.3), placement=placement)
    table = score([simulated_recording(scenario, seed, imu="mpu9255", occlusions=occlusions)
                   for seed in (11, 12)])
    assert table.loc["kalman", "samples"] > 100
    assert table.loc["kalman", "rms_mm"] <= 5.0
    assert table.loc["smoother", "rms_mm"] <= 2.0
    assert table.loc["smoother", "rms_mm"] < table.loc["kalman", "rms_mm"]
    assert table.loc["kalman", "baseline_over_method"] >= 5.0
    assert table.loc["kalman", "coverage_3sigma"] >= 0.95
    assert table.loc["kalman", "lost_fraction"] == 0.0


def assert_real_targets(name: str, recording: Recording) -> None:
    gaps = GapsConfig(gap_range=(0.1, 0.3), seeding="shared")
    table = score([recording_with_gaps(name, recording, gaps, seed=7)])
    assert table.loc["kalman", "samples"] > 200
    assert table.loc["kalman", "rms_mm"] <= 8.0
    assert table.loc["kalman", "baseline_over_method"] >= 5.0
    assert table.loc["kalman", "coverage_3sigma"] >= 0.95
    assert table.loc["smoother", "rms_mm"] < table.loc["kalman", "rms_mm"]


def test_bundled_broad_excerpt_with_cut_gaps_meets_the_targets():
    """Always runs: 36 s of real fast combined motion shipped with kfusion."""
    assert_real_targets("21_excerpt", read_recording(broad_excerpt()))


@pytest.mark.broad
@pytest.mark.parametrize("trial", ["10", "21"])
def test_real_broad_trial_with_cut_gaps_meets_the_targets(trial):
    assert_real_targets(trial, first_seconds(read_broad(broad_trial(trial), mocap_step=3), 90.0))
