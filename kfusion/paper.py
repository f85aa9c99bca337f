"""The paper's reported errors, and our results laid out beside them.

Amorim et al., Robotics and Computer-Integrated Manufacturing 67:102035 (2021): Table 1 (arm
lift, MPU9255, error in mm of five experiments with Type 1 and Type 2 occlusions), the circle
test (about 17.5 mm) and the use case table (MPU9255 and UM7, error along Z, along Y and in
total, mm). The paper reports one error per occlusion experiment and does not define it further;
its text calls it the error "in the worst case", so it is compared here with the largest error
inside a gap (per gap, then the median and the maximum over gaps).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from kfusion.conventions import LOST
from kfusion.recording import occlusion_runs
from kfusion.sweep import ExperimentResult

TABLE_1_TYPE_1_MM = (16.7, 28.4, 25.3, 12.0, 16.1)
"""Paper Table 1, Type 1 (occlusion mid-motion) error of experiments 1-5, mm, MPU9255."""
TABLE_1_TYPE_2_MM = (36.7, 26.5, 12.7, 43.1, 31.6)
"""Paper Table 1, Type 2 (occlusion at a direction change) error of experiments 1-5, mm."""
CIRCLE_MM = 17.5
"""Paper, circle test: "an approximate error of 17.5 millimetres", MPU9255."""
ARM_LIFT_WORST_MM = 15.0
"""Paper, first arm-lift test: "approximate error of 15 millimetres in the worst case"."""
USE_CASE_MM = {"mpu9255": {"z_mm": 11.7, "y_mm": 14.8, "total_mm": 18.9},
               "um7": {"z_mm": 11.4, "y_mm": 5.8, "total_mm": 12.8}}
"""Paper, use case table: error along Z, along Y and in total, mm, per IMU."""


def paper_table_1() -> pd.DataFrame:
    """Paper Table 1 as a DataFrame: experiment 1-5 x (type1_mm, type2_mm)."""
    return pd.DataFrame({"type1_mm": TABLE_1_TYPE_1_MM, "type2_mm": TABLE_1_TYPE_2_MM},
                        index=pd.RangeIndex(1, 6, name="experiment"))


def paper_use_case() -> pd.DataFrame:
    """Paper use-case table: IMU x (z_mm, y_mm, total_mm)."""
    table = pd.DataFrame(USE_CASE_MM).T
    table.index.name = "imu"
    return table


def _per_gap(result: ExperimentResult) -> pd.DataFrame:
    per_gap = result.per_gap()
    if per_gap.empty:
        raise ValueError("expected an experiment with at least one scored gap, got none")
    return per_gap


def table_1_comparison(type1: ExperimentResult, type2: ExperimentResult, *,
                       statistic: str = "median") -> pd.DataFrame:
    """Paper Table 1 beside ours: one row per experiment (our seeds in order), columns
    ``paper type1``, ``<method> type1``, ..., ``paper type2``, ``<method> type2``.

    Ours is the largest error inside each gap (``max_mm`` of
    :func:`kfusion.evaluate.per_gap_errors`), reduced over the gaps of the seed by
    ``statistic`` (``"median"``: a typical occlusion; ``"max"``: the worst one), mm.

    Args:
        type1, type2: results of the Type 1 and Type 2 configs.
    """
    if statistic not in ("median", "max", "mean"):
        raise ValueError(f"statistic: expected 'median', 'max' or 'mean', got {statistic!r}")
    columns = {}
    for label, result, paper in (("type1", type1, TABLE_1_TYPE_1_MM),
                                 ("type2", type2, TABLE_1_TYPE_2_MM)):
        per_gap = _per_gap(result)
        ours = per_gap.groupby(["recording", "method"], sort=False)["max_mm"].agg(statistic)
        wide = ours.unstack("method")
        recordings = list(dict.fromkeys(per_gap["recording"]))
        count = max(len(recordings), len(paper))
        columns[f"paper {label}"] = list(paper) + [np.nan] * (count - len(paper))
        for method in wide.columns:
            values = [float(wide.loc[name, method]) for name in recordings]
            columns[f"{method} {label}"] = values + [np.nan] * (count - len(values))
    table = pd.DataFrame(columns, index=pd.RangeIndex(1, len(next(iter(columns.values()))) + 1,
                                                      name="experiment"))
    means = table.mean(numeric_only=True).rename("mean")
    return pd.concat([table, means.to_frame().T])


def per_gap_axis_errors(result: ExperimentResult) -> pd.DataFrame:
    """Largest absolute error per axis and in total inside each gap, mm.

    One row per (recording, method, gap): ``x_mm``, ``y_mm``, ``z_mm`` = max over the gap's
    samples of ``|e_axis|``, ``total_mm`` = max of ``|e|``; lost samples are left out.
    """
    rows = []
    for name, runs in result.runs.items():
        scored = result.recordings[name]
        gaps = occlusion_runs(~np.asarray(scored.gap_mask, dtype=bool))
        for run in runs:
            error = run.result.position - scored.truth_position
            usable = (np.asarray(run.result.status) != LOST) & np.isfinite(error).all(axis=1)
            for index, (start, stop) in enumerate(gaps):
                inside = error[start:stop][usable[start:stop]]
                if not len(inside):
                    continue
                axis_max = 1000 * np.abs(inside).max(axis=0)
                rows.append({"recording": name, "method": run.method, "gap": index,
                             "x_mm": axis_max[0], "y_mm": axis_max[1], "z_mm": axis_max[2],
                             "total_mm": 1000 * float(np.linalg.norm(inside, axis=1).max())})
    return pd.DataFrame(rows)


def use_case_comparison(results: dict[str, ExperimentResult], *, statistic: str = "median"
                        ) -> pd.DataFrame:
    """The paper's use-case table beside ours.

    Args:
        results: IMU name (``"mpu9255"``, ``"um7"``) -> ExperimentResult of that use case.
        statistic: how our per-gap errors are reduced over gaps (``"median"`` or ``"max"``).

    Returns one row per (imu, source) with source ``paper`` or a method, columns ``z_mm``,
    ``y_mm``, ``total_mm`` and ``gaps`` (the number of our gaps).
    """
    if statistic not in ("median", "max", "mean"):
        raise ValueError(f"statistic: expected 'median', 'max' or 'mean', got {statistic!r}")
    rows = []
    for imu, result in results.items():
        paper = USE_CASE_MM.get(imu)
        if paper is not None:
            rows.append({"imu": imu, "source": "paper", **paper, "gaps": np.nan})
        errors = per_gap_axis_errors(result)
        for method, group in errors.groupby("method", sort=False):
            rows.append({"imu": imu, "source": str(method),
                         **{column: float(group[column].agg(statistic))
                            for column in ("z_mm", "y_mm", "total_mm")},
                         "gaps": len(group)})
    return pd.DataFrame(rows).set_index(["imu", "source"])
