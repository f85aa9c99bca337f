"""Run several methods over one scored recording and tabulate their gap errors.

Used by ``kfusion demo``, ``kfusion run``, ``kfusion sweep`` and the benchmarks, so every table
is computed the same way (definitions in :mod:`kfusion.evaluate`).
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from kfusion.evaluate import GapErrors, gap_errors, metrics_from_errors, per_gap_errors
from kfusion.guards import atomic_write
from kfusion.methods import track_with_method
from kfusion.recording import Recording
from kfusion.track_file import TrackResult


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


ENGINE_METHODS = ("kalman", "smoother")
"""Methods that take an ``engine`` (:mod:`kfusion.kalman.engines`)."""


def engine_options(method: str, engine: str | None) -> dict[str, Any]:
    """``{"engine": engine}`` for a method that has engines (:data:`ENGINE_METHODS`), else {}."""
    return {"engine": engine} if engine is not None and method in ENGINE_METHODS else {}


def run_method(scored: ScoredRecording, method: str, options: Mapping[str, Any] | None = None
               ) -> MethodRun:
    """Track ``scored.recording`` with ``method`` and score its gap samples (``options`` may
    hold an ``engine``: :func:`engine_options`)."""
    start = time.perf_counter()
    result = track_with_method(scored.recording, method, **dict(options or {}))
    seconds = time.perf_counter() - start
    per_gap = per_gap_errors(result, scored.truth_position, scored.gap_mask)
    per_gap.insert(0, "method", method)
    per_gap.insert(0, "recording", scored.name)
    return MethodRun(method=method, result=result,
                     errors=gap_errors(result, scored.truth_position, scored.gap_mask),
                     seconds=seconds, imu_samples=len(scored.recording.imu), per_gap=per_gap)


def summary_table(runs: Sequence[MethodRun], *, reference: str = "baseline") -> pd.DataFrame:
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


TABLE_SIGNIFICANT_DIGITS = 10
"""Significant digits of the numbers in written result tables (recordings keep every bit)."""
COUNT_COLUMNS = ("samples", "gaps", "seeds")
"""Result-table columns that count things: written as integers."""


def write_table_csv(table: pd.DataFrame, path: str | Path, *, index: bool = True) -> Path:
    """Write a result table as CSV for people to read: counts as integers (``416``, not
    ``416.0``), other numbers to :data:`TABLE_SIGNIFICANT_DIGITS` significant digits (``0.12``,
    not ``0.1200000000000001``), NaN as an empty cell. Written atomically
    (:func:`kfusion.guards.atomic_write`). Returns the path."""
    path = Path(path)
    table = table.copy()
    for column in table.columns:
        values = table[column]
        if str(column) in COUNT_COLUMNS and pd.api.types.is_float_dtype(values) \
                and bool((values.dropna() % 1 == 0).all()):
            table[column] = values.astype("Int64")
    return atomic_write(path, lambda temporary: table.to_csv(
        temporary, index=index, float_format=f"%.{TABLE_SIGNIFICANT_DIGITS}g"))
