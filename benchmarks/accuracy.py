"""Accuracy and speed benchmark of every method (issue 4 §9). Prints markdown tables.

Data sets:

* simulated: the paper's scenarios (arm_lift with Type 1 and Type 2 gaps, circle, pick_tool)
  with the ``mpu9255`` profile, gaps of 0.1-0.3 s and of 0.3-1.0 s, several seeds each;
* BROAD: the seven real trials, mocap taken every 3rd sample (~95 Hz), artificial gaps of
  0.1-0.3 s (and 0.3-1.0 s) cut where the mocap is valid, scored against the hidden mocap.

For each method: RMS and maximum gap error (mm), the ratio baseline RMS / method RMS, the
fraction of gap samples inside 3 sigma on every axis, IMU samples processed per second, and the
slowest single-trial tracking time. Run: ``python benchmarks/accuracy.py [--seeds 5] [--quick]``.

The data sets are the configs ``configs/accuracy_*.yaml`` (one per table), built by
:mod:`kfusion.config` as for ``kfusion run``; ``kfusion run configs/accuracy_<...>.yaml``
reproduces a table's accuracy columns.
"""

from __future__ import annotations

import argparse
import time

import pandas as pd

from kfusion.config import BroadData, RunConfig, find_config, load_run_config
from kfusion.experiment import format_table
from kfusion.sweep import run_experiment

TABLES = {
    "0.1-0.3 s": ("accuracy_simulated_short_gaps", "accuracy_broad_short_gaps"),
    "0.3-1.0 s": ("accuracy_simulated_long_gaps", "accuracy_broad_long_gaps"),
}
"""Gap lengths -> the configs (``configs/<name>.yaml``) of the simulated and BROAD tables; each
table is also ``kfusion run configs/<name>.yaml``."""


def limited(config: RunConfig, seeds: int, trials: int | None) -> RunConfig:
    """``config`` with ``seeds`` simulation seeds (0..seeds-1; BROAD configs keep theirs, one
    gap pattern) and, on BROAD, its first ``trials`` trials (None: all)."""
    if isinstance(config.data, BroadData):
        if trials is None:
            return config
        keys = [path.stem for path in config.data.trial_paths()[:trials]]
        return config.model_copy(update={"data": config.data.model_copy(
            update={"trials": keys})})
    return config.model_copy(update={"seeds": list(range(seeds))})


def evaluate(config: RunConfig) -> tuple[pd.DataFrame, int]:
    """Summary table of ``config`` (:func:`kfusion.sweep.run_experiment`, as ``kfusion run``)
    plus the slowest single run per method; and the number of recordings."""
    result = run_experiment(config, progress=True)
    table = result.summary()
    table["slowest_run_s"] = pd.Series({
        method: max(run.seconds for run in result.all_runs if run.method == method)
        for method in table.index})
    return table, len(result.recordings)


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
    for gap_label, (simulated, broad) in TABLES.items():
        data = {
            f"simulated paper scenarios, mpu9255, {seeds} seeds": simulated,
            "BROAD trials, mocap every 3rd sample": broad,
        }
        for data_label, name in data.items():
            config = limited(load_run_config(find_config(name)), seeds, trials)
            table, count = evaluate(config)
            print(f"\n### {data_label}, gaps {gap_label} ({count} recordings)\n")
            print("```")
            print(format_table(table[[c for c in columns if c in table.columns]]))
            print("```")
    print(f"\n(total benchmark time {time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
