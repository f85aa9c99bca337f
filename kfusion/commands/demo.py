"""``kfusion demo``: the main job on built-in data.

Simulates the paper's arm-lift experiment (MPU9255 IMU, 0.1-0.3 s occlusions), runs every
registered estimator, prints the gap-error table and writes the recording, the tracks, the table
and a plot to ``--out``.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd

from kfusion.commands.stream import stream_lines
from kfusion.experiment import format_table, run_method, summary_table, write_table_csv
from kfusion.methods import METHODS
from kfusion.plots import (
    error_by_gap_length_figure,
    gap_zoom_figure,
    motion_window,
    trajectory_figure,
)
from kfusion.recording import write_recording
from kfusion.track_file import write_track_csv

NAME = "demo"
HELP = "Run every estimator on the simulated arm-lift experiment; print and plot gap errors."
ORDER = 1


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="demo-output", metavar="DIR",
                        help="output folder (default: demo-output)")
    parser.add_argument("--seed", type=int, default=0, help="simulation seed (default: 0)")
    parser.add_argument("--imu", default="mpu9255", help="IMU profile (default: mpu9255)")


def run(args: argparse.Namespace) -> int:
    from kfusion.config import OcclusionsConfig, simulated_recording

    out = Path(args.out)
    scored = dataclasses.replace(
        simulated_recording("arm_lift", args.seed, imu=args.imu,
                            occlusions=OcclusionsConfig(gap_range=(0.1, 0.3))), name="arm_lift")
    recording, truth = scored.recording, scored.truth_position
    write_recording(recording, out / "arm_lift")
    gaps = int(np.count_nonzero(np.diff(scored.gap_mask.astype(int)) == 1))
    print(f"simulated arm_lift (seed {args.seed}, {args.imu}): {len(recording.imu)} "
          f"IMU samples, {len(recording.mocap)} mocap frames, {gaps} gaps of 0.1-0.3 s")
    runs = [run_method(scored, method) for method in METHODS]
    for method_run in runs:
        write_track_csv(method_run.result, out / f"track_{method_run.method}.csv")
    table = summary_table(runs)
    write_table_csv(table, out / "gap_errors.csv")
    print()
    print("Gap errors (all gap samples pooled; coverage = fraction inside 3 sigma):")
    print(format_table(table))
    per_gap = pd.concat([method_run.per_gap for method_run in runs], ignore_index=True)
    write_table_csv(per_gap, out / "per_gap_errors.csv", index=False)
    results = {method_run.method: method_run.result for method_run in runs}
    first_gap = float(recording.mocap.t[np.argmax(scored.gap_mask)])
    trajectory_figure(recording.mocap.t, recording.mocap.position, results,
                      scored.gap_mask, truth=truth, axes=(1,),
                      window=motion_window(recording, scored.gap_mask, 8.0),
                      title="arm lift, MPU9255: estimates inside gaps (below: the worst gaps)",
                      path=out / "arm_lift_trajectory.png")
    gap_zoom_figure(recording.mocap.t, recording.mocap.position, results,
                    scored.gap_mask, truth=truth, axis=1,
                    title="error along y inside the six worst gaps (band: 3 sigma)",
                    path=out / "gap_errors_zoom.png")
    error_by_gap_length_figure(per_gap, title="max error per gap", path=out / "error_by_gap.png")
    print()
    print("Streaming the same recording through kfusion.Tracker (what safety software sees), "
          "around the first gap:")
    for line in stream_lines(recording, count=8, every=5, start=first_gap - 0.05):
        print("  " + line)
    print()
    print(f"wrote {out}/: arm_lift/ (recording), track_*.csv, gap_errors.csv, "
          "per_gap_errors.csv, arm_lift_trajectory.png, gap_errors_zoom.png, error_by_gap.png")
    return 0
