"""Accuracy and speed benchmark of every method (issue 4 §9). Prints markdown tables.

Data sets:

* simulated: the paper's scenarios (arm_lift with Type 1 and Type 2 gaps, circle, pick_tool)
  with the ``mpu9255`` profile, gaps of 0.1-0.3 s and of 0.3-1.0 s, several seeds each;
* BROAD: the seven real trials, mocap taken every 3rd sample (~95 Hz), artificial gaps of
  0.1-0.3 s (and 0.3-1.0 s) cut where the mocap is valid, scored against the hidden mocap.

For each method: RMS and maximum gap error (mm), the ratio baseline RMS / method RMS, the
fraction of gap samples inside 3 sigma on every axis, IMU samples processed per second, and the
slowest single-trial tracking time. Run: ``python benchmarks/accuracy.py [--seeds 5] [--quick]``.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np
import pandas as pd
from tqdm import tqdm

from kfusion.datasets import broad_trials
from kfusion.evaluate import cut_gaps
from kfusion.experiment import MethodRun, ScoredRecording, format_table, run_method, summary_table
from kfusion.methods import METHODS
from kfusion.readers.broad import read_broad
from kfusion.simulate import OcclusionSpec, simulate

GAP_RANGES = {"0.1-0.3 s": (0.1, 0.3), "0.3-1.0 s": (0.3, 1.0)}
SIMULATED = (("arm_lift", "mid_motion"), ("arm_lift", "direction_change"),
             ("circle", "random"), ("pick_tool", "random"))


def simulated_sets(seeds: int, gap_range: tuple[float, float]) -> list[ScoredRecording]:
    sets = []
    for scenario, placement in SIMULATED:
        for seed in range(seeds):
            simulation = simulate(scenario, seed=seed, imu="mpu9255",
                                  occlusions=OcclusionSpec(gap_range=gap_range,
                                                           placement=placement))
            sets.append(ScoredRecording(f"{scenario}/{placement}/{seed}", simulation.recording,
                                        simulation.truth.position, simulation.truth.occluded))
    return sets


def broad_sets(gap_range: tuple[float, float], trials: int | None) -> list[ScoredRecording]:
    sets = []
    for path in broad_trials()[:trials]:
        recording = read_broad(path, mocap_step=3)
        gapped = cut_gaps(recording, rng=np.random.default_rng(0), gap_range=gap_range)
        sets.append(ScoredRecording(path.stem, gapped.recording, gapped.truth_position,
                                    gapped.gap_mask))
    return sets


def evaluate(sets: list[ScoredRecording], label: str) -> tuple[pd.DataFrame, list[MethodRun]]:
    runs = [run_method(scored, method)
            for scored in tqdm(sets, desc=label, leave=False, file=sys.stderr)
            for method in METHODS]
    table = summary_table(runs)
    slowest = {m: max(r.seconds for r in runs if r.method == m) for m in METHODS}
    table["slowest_run_s"] = pd.Series(slowest)
    return table, runs


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5, help="simulation seeds per scenario")
    parser.add_argument("--quick", action="store_true", help="2 seeds, 2 BROAD trials")
    args = parser.parse_args()
    seeds = 2 if args.quick else args.seeds
    trials = 2 if args.quick else None
    start = time.perf_counter()
    columns = ["samples", "rms_mm", "max_mm", "baseline_over_method", "coverage_3sigma",
               "lost_fraction", "imu_per_second", "slowest_run_s"]
    for gap_label, gap_range in GAP_RANGES.items():
        data = {
            f"simulated paper scenarios, mpu9255, {seeds} seeds": simulated_sets(seeds, gap_range),
            "BROAD trials, mocap every 3rd sample": broad_sets(gap_range, trials),
        }
        for data_label, sets in data.items():
            table, _ = evaluate(sets, f"{data_label}, {gap_label}")
            print(f"\n### {data_label}, gaps {gap_label} ({len(sets)} recordings)\n")
            print("```")
            print(format_table(table[[c for c in columns if c in table.columns]]))
            print("```")
    print(f"\n(total benchmark time {time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
