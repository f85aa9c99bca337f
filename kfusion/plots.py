"""Figures: trajectories with gaps (like the paper's), error against gap length, sweep heat maps.

Every function returns a matplotlib Figure and, given ``path``, also saves it as PNG. The Agg
backend is selected on import when no display is configured, so the functions work headless.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

if not os.environ.get("DISPLAY") and not os.environ.get("MPLBACKEND"):
    matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from kfusion.conventions import LOST  # noqa: E402
from kfusion.recording import occlusion_runs  # noqa: E402
from kfusion.track import TrackResult  # noqa: E402

METHOD_COLOURS = {"baseline": "tab:red", "kalman": "tab:green", "smoother": "tab:purple"}
AXIS_NAMES = ("x", "y", "z")


def _save(figure: Figure, path: str | Path | None) -> Figure:
    if path is not None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        figure.savefig(path, dpi=120, bbox_inches="tight")
    return figure


def trajectory_figure(
    t: NDArray[np.float64],
    measured: NDArray[np.float64],
    results: Mapping[str, TrackResult],
    gap_mask: NDArray[np.bool_],
    *,
    truth: NDArray[np.float64] | None = None,
    axes: Sequence[int] = (0, 1, 2),
    window: tuple[float, float] | None = None,
    title: str = "",
    path: str | Path | None = None,
) -> Figure:
    """Position against time per axis: measured mocap (blue), each method's estimate, truth.

    Like the paper's figures: gaps are shaded, and each method's estimate is drawn inside gaps
    (with a 3-sigma band where the method gives one). Shapes: ``t`` (m,), ``measured`` (m, 3) with
    NaN where occluded, ``gap_mask`` (m,), ``truth`` (m, 3) or None; positions in m, plotted in mm.
    """
    t = np.asarray(t, dtype=float)
    shown = np.ones(len(t), dtype=bool)
    if window is not None:
        shown = (t >= window[0]) & (t <= window[1])
    figure, plot_axes = plt.subplots(len(axes), 1, figsize=(10, 2.6 * len(axes)), sharex=True,
                                     squeeze=False)
    runs = occlusion_runs(~np.asarray(gap_mask, dtype=bool))
    for row, axis in enumerate(axes):
        ax = plot_axes[row, 0]
        for start, stop in runs:
            if shown[start:stop].any():
                ax.axvspan(t[max(start - 1, 0)], t[min(stop, len(t) - 1)], color="0.9", lw=0)
        if truth is not None:
            ax.plot(t[shown], 1000 * truth[shown, axis], color="k", lw=0.8, ls="--", label="truth")
        ax.plot(t[shown], 1000 * measured[shown, axis], ".", color="tab:blue", ms=2,
                label="mocap")
        for name, result in results.items():
            colour = METHOD_COLOURS.get(name)
            estimate = np.where((np.asarray(result.status) == LOST)[:, None], np.nan,
                                result.position)
            in_gap = np.asarray(gap_mask, dtype=bool) & shown
            # draw each gap's estimate joined to the last fix before it
            values = np.where(in_gap, estimate[:, axis], np.nan)
            for start, stop in runs:
                if start > 0:
                    values[start - 1] = estimate[start - 1, axis]
                if stop < len(t):
                    values[stop] = estimate[stop, axis]
            ax.plot(t[shown], 1000 * values[shown], color=colour, lw=1.4, label=name)
            std = np.asarray(result.std, dtype=float)[:, axis]
            if np.isfinite(std[in_gap]).any():
                ax.fill_between(t[shown], 1000 * (values - 3 * std)[shown],
                                1000 * (values + 3 * std)[shown], color=colour, alpha=0.15, lw=0)
        ax.set_ylabel(f"{AXIS_NAMES[axis]} (mm)")
        ax.grid(alpha=0.3)
    plot_axes[0, 0].legend(loc="upper right", fontsize=8, ncol=4)
    plot_axes[-1, 0].set_xlabel("t (s)")
    if title:
        plot_axes[0, 0].set_title(title)
    figure.tight_layout()
    return _save(figure, path)


def error_by_gap_length_figure(per_gap: pd.DataFrame, *, metric: str = "max_mm",
                               title: str = "", path: str | Path | None = None) -> Figure:
    """Scatter of a per-gap error metric against gap duration, one colour per method.

    ``per_gap`` has columns ``method``, ``duration_s`` and ``metric`` (as made by
    :func:`kfusion.evaluate.per_gap_errors` plus a method column).
    """
    figure, ax = plt.subplots(figsize=(6, 4))
    for method, rows in per_gap.groupby("method", sort=False):
        ax.plot(rows["duration_s"], rows[metric], "o", ms=4, alpha=0.7,
                color=METHOD_COLOURS.get(str(method)), label=str(method))
    ax.set_xlabel("gap duration (s)")
    ax.set_ylabel(metric.replace("_mm", " error (mm)").replace("_", " "))
    ax.set_yscale("log")
    ax.grid(alpha=0.3, which="both")
    ax.legend()
    if title:
        ax.set_title(title)
    figure.tight_layout()
    return _save(figure, path)


def heatmap_figure(table: pd.DataFrame, *, rows: str, columns: str, value: str,
                   title: str = "", path: str | Path | None = None) -> Figure:
    """Heat map of ``value`` (mean over repeats) on a ``rows`` x ``columns`` grid of a sweep."""
    grid = table.pivot_table(index=rows, columns=columns, values=value, aggfunc="mean")
    figure, ax = plt.subplots(figsize=(1.2 + 1.1 * grid.shape[1], 1.0 + 0.6 * grid.shape[0]))
    image = ax.imshow(grid.to_numpy(dtype=float), cmap="viridis", aspect="auto")
    ax.set_xticks(range(grid.shape[1]), [str(c) for c in grid.columns], rotation=30)
    ax.set_yticks(range(grid.shape[0]), [str(i) for i in grid.index])
    ax.set_xlabel(columns)
    ax.set_ylabel(rows)
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            ax.text(j, i, f"{grid.iat[i, j]:.3g}", ha="center", va="center", color="w", fontsize=8)
    figure.colorbar(image, ax=ax, label=value)
    if title:
        ax.set_title(title)
    figure.tight_layout()
    return _save(figure, path)
