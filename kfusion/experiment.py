"""Run several methods over one scored recording and tabulate their gap errors.

Used by ``kfusion demo``, ``kfusion run``, ``kfusion sweep`` and the benchmarks, so every table
is computed the same way (definitions in :mod:`kfusion.evaluate`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from kfusion.evaluate import GapErrors, gap_errors, metrics_from_errors, per_gap_errors
from kfusion.methods import track_recording
from kfusion.recording import Recording
from kfusion.track import TrackResult


@dataclass(frozen=True)
class ScoredRecording:
    """A recording plus what is needed to score it.

    Attributes:
        name: label for tables.
        recording: what the estimators see (occluded rows NaN).
        truth_position: (m, 3) true position at the mocap rows, m.
        gap_mask: (m,) True on rows to score.
    """

    name: str
    recording: Recording
    truth_position: NDArray[np.float64]
    gap_mask: NDArray[np.bool_]


@dataclass(frozen=True)
class MethodRun:
    """One method's output on one scored recording."""

    method: str
    result: TrackResult
    errors: GapErrors
    seconds: float
    imu_samples: int
    per_gap: pd.DataFrame = field(repr=False)

    @property
    def metrics(self) -> dict[str, float]:
        """Gap metrics plus speed (IMU samples processed per second)."""
        return {**metrics_from_errors(self.errors), "seconds": self.seconds,
                "imu_per_second": self.imu_samples / self.seconds if self.seconds else np.nan}


def run_method(scored: ScoredRecording, method: str, options: Mapping[str, Any] | None = None
               ) -> MethodRun:
    """Track ``scored.recording`` with ``method`` and score its gap samples."""
    start = time.perf_counter()
    result = track_recording(scored.recording, method, **dict(options or {}))
    seconds = time.perf_counter() - start
    per_gap = per_gap_errors(result, scored.truth_position, scored.gap_mask)
    per_gap.insert(0, "method", method)
    per_gap.insert(0, "recording", scored.name)
    return MethodRun(method=method, result=result,
                     errors=gap_errors(result, scored.truth_position, scored.gap_mask),
                     seconds=seconds, imu_samples=len(scored.recording.imu), per_gap=per_gap)


def summary_table(runs: Sequence[MethodRun], *, reference: str = "baseline",
                  versus: str = "kalman") -> pd.DataFrame:
    """One row per method, pooling all its runs: samples, rms/max/mean mm, coverage, lost
    fraction, IMU samples per second; and the ratio ``rms(reference) / rms(method)``."""
    rows = []
    for method in dict.fromkeys(run.method for run in runs):
        mine = [run for run in runs if run.method == method]
        metrics = metrics_from_errors(GapErrors.concatenate(run.errors for run in mine))
        seconds = sum(run.seconds for run in mine)
        samples = sum(run.imu_samples for run in mine)
        rows.append({"method": method, **metrics,
                     "imu_per_second": samples / seconds if seconds else np.nan})
    table = pd.DataFrame(rows).set_index("method")
    if reference in table.index:
        table[f"{reference}_over_method"] = table.loc[reference, "rms_mm"] / table["rms_mm"]
    return table


def format_table(table: pd.DataFrame) -> str:
    """Fixed-width text of a summary table, for terminals and reports."""
    shown = table.copy()
    formats = {"samples": "{:.0f}", "rms_mm": "{:.2f}", "max_mm": "{:.2f}", "mean_mm": "{:.2f}",
               "coverage_3sigma": "{:.3f}", "lost_fraction": "{:.3f}",
               "imu_per_second": "{:,.0f}", "seconds": "{:.2f}"}
    for column in shown.columns:
        fmt = formats.get(column, "{:.2f}")
        shown[column] = [("-" if pd.isna(v) else fmt.format(v)) if isinstance(v, (int, float,
                         np.floating)) else str(v) for v in shown[column]]
    return shown.to_string()
