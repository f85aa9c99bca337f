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
from matplotlib.ticker import FuncFormatter  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from kfusion.conventions import LOST  # noqa: E402
from kfusion.guards import atomic_write  # noqa: E402
from kfusion.recording import occlusion_runs  # noqa: E402
from kfusion.track import TrackResult  # noqa: E402

METHOD_COLOURS = {"baseline": "tab:red", "kalman": "tab:green", "smoother": "tab:purple"}
AXIS_NAMES = ("x", "y", "z")


def _save(figure: Figure, path: str | Path | None) -> Figure:
    if path is not None:
        path = Path(path)
        image_format = path.suffix.lstrip(".") or "png"
        atomic_write(path, lambda temporary: figure.savefig(temporary, format=image_format,
                                                            dpi=120, bbox_inches="tight"))
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
                   title: str = "", path: str | Path | None = None,
                   facet: str | None = None) -> Figure:
    """Heat map of ``value`` (mean over repeats and any other column) on a ``rows`` x ``columns``
    grid of a sweep; with ``facet``, one panel per value of that column on a shared colour
    scale. ``table`` is a sweep's results table (one row per run)."""
    panels = [(None, table)] if facet is None else list(table.groupby(facet, sort=True))
    grids = [(label, frame.pivot_table(index=rows, columns=columns, values=value,
                                       aggfunc="mean")) for label, frame in panels]
    values = np.concatenate([grid.to_numpy(dtype=float).ravel() for _, grid in grids])
    finite = values[np.isfinite(values)]
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    n_rows = max(grid.shape[0] for _, grid in grids)
    n_columns = max(grid.shape[1] for _, grid in grids)
    figure, plot_axes = plt.subplots(
        1, len(grids), squeeze=False, sharey=True, layout="constrained",
        figsize=(1.6 + (1.1 * n_columns + 0.6) * len(grids), 1.4 + 0.6 * n_rows))
    image = None
    for ax, (label, grid) in zip(plot_axes[0], grids, strict=True):
        data = grid.to_numpy(dtype=float)
        image = ax.imshow(data, cmap="viridis", aspect="auto", vmin=low, vmax=high)
        ax.set_xticks(range(grid.shape[1]), [str(c) for c in grid.columns], rotation=30,
                      ha="right")
        ax.set_yticks(range(grid.shape[0]), [str(i) for i in grid.index])
        ax.set_xlabel(columns)
        middle = (low + high) / 2
        for i in range(grid.shape[0]):
            for j in range(grid.shape[1]):
                cell = data[i, j]
                ax.text(j, i, "-" if np.isnan(cell) else f"{cell:.3g}", ha="center",
                        va="center", fontsize=8, color="k" if cell > middle else "w")
        if label is not None:
            ax.set_title(f"{facet} = {label}", fontsize=9)
    plot_axes[0, 0].set_ylabel(rows)
    if image is not None:
        figure.colorbar(image, ax=list(plot_axes[0]), label=value)
    if title:
        figure.suptitle(title)
    return _save(figure, path)


def sweep_lines_figure(table: pd.DataFrame, *, x: str, value: str, hue: str = "method",
                       facet: str | None = None, log: bool = True, title: str = "",
                       path: str | Path | None = None) -> Figure:
    """``value`` against the sweep axis ``x``, one line per value of ``hue`` (mean over seeds
    and other columns, with a band of +-1 standard deviation across seeds), one panel per value
    of ``facet``. ``x`` is treated as categorical, in sorted order. ``table`` is a sweep's
    results table (one row per run)."""
    panels = [(None, table)] if facet is None else list(table.groupby(facet, sort=True))
    figure, plot_axes = plt.subplots(1, len(panels), squeeze=False, sharey=True,
                                     layout="constrained", figsize=(1.0 + 4.2 * len(panels), 3.6))
    for ax, (label, frame) in zip(plot_axes[0], panels, strict=True):
        positions = {key: index for index, key in enumerate(sorted(frame[x].unique()))}
        for name, rows in frame.groupby(hue, sort=False):
            statistics = rows.groupby(x)[value].agg(["mean", "std"]).sort_index()
            where = [positions[key] for key in statistics.index]
            colour = METHOD_COLOURS.get(str(name))
            ax.plot(where, statistics["mean"], "o-", color=colour, label=str(name))
            spread = statistics["std"].fillna(0.0)
            ax.fill_between(where, statistics["mean"] - spread, statistics["mean"] + spread,
                            color=colour, alpha=0.15, lw=0)
        ax.set_xticks(list(positions.values()), [str(key) for key in positions], rotation=20)
        ax.set_xlabel(x)
        if log:
            ax.set_yscale("log")
            ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
            ax.yaxis.set_minor_formatter(FuncFormatter(lambda v, _: ""))
        ax.grid(alpha=0.3, which="both")
        if label is not None:
            ax.set_title(f"{facet} = {label}", fontsize=9)
    plot_axes[0, 0].set_ylabel(value)
    plot_axes[0, 0].legend(fontsize=8)
    if title:
        figure.suptitle(title)
    return _save(figure, path)


def gap_zoom_figure(
    t: NDArray[np.float64],
    measured: NDArray[np.float64],
    results: Mapping[str, TrackResult],
    gap_mask: NDArray[np.bool_],
    *,
    truth: NDArray[np.float64] | None = None,
    axis: int = 1,
    gaps: int = 6,
    margin_s: float = 0.15,
    title: str = "",
    path: str | Path | None = None,
) -> Figure:
    """Small multiples of the first ``gaps`` gaps: error against the truth (or the measured
    mocap) in mm along ``axis``, per method, with the 3-sigma band where the method gives one.

    Millimetre errors are invisible on a trajectory spanning 0.8 m; this zooms in on them.
    Shapes as in :func:`trajectory_figure`.
    """
    t = np.asarray(t, dtype=float)
    reference = np.asarray(truth if truth is not None else measured, dtype=float)[:, axis]
    runs = occlusion_runs(~np.asarray(gap_mask, dtype=bool))[:gaps]
    columns = min(3, max(len(runs), 1))
    rows = max(1, -(-len(runs) // columns))
    figure, plot_axes = plt.subplots(rows, columns, figsize=(4 * columns, 2.8 * rows),
                                     squeeze=False)
    for index, (start, stop) in enumerate(runs):
        ax = plot_axes[index // columns, index % columns]
        shown = (t >= t[start] - margin_s) & (t <= t[stop - 1] + margin_s)
        ax.axvspan(t[max(start - 1, 0)], t[min(stop, len(t) - 1)], color="0.9", lw=0)
        for name, result in results.items():
            colour = METHOD_COLOURS.get(name)
            error = 1000 * (np.asarray(result.position)[:, axis] - reference)
            ax.plot(t[shown], error[shown], color=colour, lw=1.3, label=name)
            sigma = 1000 * np.asarray(result.std, dtype=float)[:, axis]
            if np.isfinite(sigma[shown]).any():
                ax.fill_between(t[shown], -3 * sigma[shown], 3 * sigma[shown], color=colour,
                                alpha=0.12, lw=0)
        ax.axhline(0, color="k", lw=0.6)
        ax.set_title(f"gap {index + 1}: {t[stop - 1] - t[start] + (t[1] - t[0]):.2f} s",
                     fontsize=9)
        ax.set_xlabel("t (s)", fontsize=8)
        ax.set_ylabel(f"{AXIS_NAMES[axis]} error (mm)", fontsize=8)
        ax.grid(alpha=0.3)
    for index in range(len(runs), rows * columns):
        plot_axes[index // columns, index % columns].axis("off")
    plot_axes[0, 0].legend(fontsize=7)
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    return _save(figure, path)
