"""Figures: trajectories with gaps (like the paper's), error against gap length, sweep heat maps.

Every function returns a matplotlib Figure and, given ``path``, also saves it as PNG. The Agg
backend is selected on import when no display is configured, so the functions work headless.

Rules every figure follows, so that a reader sees at a glance what matters:

* legends sit outside the data (beside or above the axes, never on them);
* gaps are shaded, and figures with a trajectory add a row that zooms on the worst gaps, where
  millimetre errors are visible (a trajectory spans up to a metre);
* no estimate hides another: each method has its own colour, line style and marker, the widest
  line is drawn lowest;
* colour scales are logarithmic where values span a decade or more, diverging around the
  calibrated value for 3-sigma coverage, linear otherwise; a gap zoom's error axis is linear
  near zero and logarithmic beyond where one method's error dwarfs the others'
  (:func:`symlog_threshold`), and log axes read as plain numbers (:func:`plain_log_ticks`);
* every axis says its unit (:func:`quantity_label`); a coverage band never leaves [0, 1].
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

if not os.environ.get("DISPLAY") and not os.environ.get("MPLBACKEND"):
    matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.axis import Axis  # noqa: E402
from matplotlib.colors import LogNorm, Normalize, TwoSlopeNorm  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.ticker import FuncFormatter, SymmetricalLogLocator  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from kfusion.conventions import LOST, median_interval  # noqa: E402
from kfusion.guards import atomic_write  # noqa: E402
from kfusion.recording import Recording, occlusion_runs  # noqa: E402
from kfusion.safety import BindingMargins  # noqa: E402
from kfusion.track_file import TrackResult  # noqa: E402

AXIS_NAMES = ("x", "y", "z")
METHOD_STYLES: dict[str, dict[str, Any]] = {
    "baseline": {"color": "tab:red", "ls": "-", "lw": 2.4, "marker": "o", "ms": 8},
    "kalman": {"color": "tab:green", "ls": "--", "lw": 1.8, "marker": "s", "ms": 5.5},
    "smoother": {"color": "tab:purple", "ls": "-", "lw": 1.0, "marker": "^", "ms": 3.5},
}
"""Colour, line style, width, marker and marker size per method: widths and marker sizes fall
from baseline to smoother, so drawing in this order leaves each line visible around the thinner
one on top of it, and coincident markers nest instead of covering each other."""
OTHER_STYLES = [{"color": colour, "ls": ls, "lw": 1.5, "marker": marker, "ms": 5}
                for colour, ls, marker in (("tab:blue", "-", "D"), ("tab:orange", "--", "v"),
                                           ("tab:brown", "-.", "P"), ("tab:pink", ":", "X"),
                                           ("tab:olive", "-", "*"), ("tab:cyan", "--", "h"))]
NOMINAL_COVERAGE_3SIGMA = 0.9973 ** 3
"""Fraction of gap samples inside 3 sigma on all three axes for a calibrated Gaussian estimate
(:mod:`kfusion.evaluate`); the centre of coverage colour scales and a reference line."""
QUANTITY_LABELS = {
    "rms_mm": "RMS gap error (mm)", "max_mm": "max gap error (mm)",
    "mean_mm": "mean gap error (mm)", "rms_mm_mean": "RMS gap error (mm)",
    "coverage_3sigma": "fraction of gap samples inside 3σ",
    "lost_fraction": "fraction of gap samples lost", "samples": "gap samples",
    "imu_per_second": "IMU samples processed per second (1/s)",
    "runtime_s": "run time (s)", "tracking_s": "tracking time (s)",
    "duration_s": "gap duration (s)",
    "method": "method", "data.imu": "IMU profile", "data.scenario": "scenario",
    "data.occlusions.gap_range": "gap length (s)", "data.gaps.gap_range": "gap length (s)",
    "data.occlusions.placement": "gap placement", "data.mocap_step": "mocap step (samples)",
}
"""Axis label, with its unit, of sweep columns and metrics (:mod:`kfusion.evaluate`)."""
PARAMETER_UNITS = {
    "accelerometer_noise_density": "m/s²/√Hz", "accelerometer_bias_random_walk": "m/s³/√Hz",
    "gyroscope_noise_density": "rad/s/√Hz", "gyroscope_bias_random_walk": "rad/s²/√Hz",
    "mocap_position_noise": "m", "mocap_orientation_noise": "rad", "initial_bias_std": "m/s²",
    "initial_gyroscope_bias_std": "rad/s", "initial_velocity_std": "m/s", "lever_arm_std": "m",
    "imu_latency_s": "s", "accelerometer_range": "m/s²", "gyroscope_range": "rad/s",
    "gate_probability": "probability", "buffer_size": "position differences",
    "velocity_points": "position differences", "adaptation_rate": "per mocap frame",
    "accelerometer_scale_error": "fraction", "gyroscope_scale_error": "fraction",
}
"""Units of method parameters (:class:`kfusion.kalman.KalmanParameters`,
:class:`kfusion.baseline.BaselineParameters`) for sweep axes ``methods.NAME.PARAMETER``."""
FRACTION_PREFIXES = ("coverage", "lost_fraction")
ZOOM_GAPS = 3
"""Gaps zoomed on below a trajectory."""


# --------------------------------------------------------------------------------------------
# small helpers: labels, styles, colour scales, legends


def quantity_label(name: str) -> str:
    """Axis label with its unit for a sweep column or metric: ``rms_mm`` -> "RMS gap error
    (mm)", ``methods.kalman.accelerometer_noise_density`` -> "kalman accelerometer noise density
    (m/s²/√Hz)"; unknown names are returned with underscores as spaces, plus a unit read from a
    ``_s``/``_mm``/``_m`` suffix."""
    if name in QUANTITY_LABELS:
        return QUANTITY_LABELS[name]
    parts = name.split(".")
    if len(parts) == 3 and parts[0] == "methods":
        unit = PARAMETER_UNITS.get(parts[2])
        words = f"{parts[1]} {parts[2].replace('_', ' ')}"
        return f"{words} ({unit})" if unit else words
    for suffix, unit in (("_mm", "mm"), ("_s", "s"), ("_m", "m")):
        if name.endswith(suffix):
            return f"{name[: -len(suffix)].replace('_', ' ')} ({unit})"
    return name.replace("_", " ")


def per_gap_label(metric: str) -> str:
    """Label of a per-gap metric with its unit: ``max_mm`` -> "max error per gap (mm)"."""
    return quantity_label(metric).replace("gap error", "error per gap")


def tick_text(value: object) -> str:
    """A grid value as a tick label: a range ``[0.1, 0.3]`` (list or its JSON text) as
    ``0.1-0.3``, numbers with ``:g``."""
    if isinstance(value, str):
        match = re.fullmatch(r"\[\s*([-+0-9.eE]+)\s*,\s*([-+0-9.eE]+)\s*\]", value)
        return f"{float(match[1]):g}–{float(match[2]):g}" if match else value
    if isinstance(value, (list, tuple, np.ndarray)) and len(value) == 2:
        return f"{float(value[0]):g}–{float(value[1]):g}"
    if isinstance(value, (float, np.floating)):
        return f"{float(value):g}"
    return str(value)


def method_style(name: str, index: int = 0) -> dict[str, Any]:
    """Colour, ls, lw and marker of method (or series) ``name``; unknown names get the
    ``index``-th of :data:`OTHER_STYLES`."""
    return dict(METHOD_STYLES.get(name, OTHER_STYLES[index % len(OTHER_STYLES)]))


def is_fraction(value: str) -> bool:
    """True for metrics that are fractions in [0, 1] (coverage, lost fraction)."""
    return value.startswith(FRACTION_PREFIXES)


def spans_decades(values: NDArray[np.float64], decades: float = 1.0) -> bool:
    """True when the finite values are all positive and max/min >= 10**decades."""
    finite = values[np.isfinite(values)]
    return bool(finite.size) and finite.min() > 0 and finite.max() / finite.min() >= 10 ** decades


def colour_scale(values: NDArray[np.float64], value: str) -> tuple[Normalize, str]:
    """Norm and colour map for a heat map of ``value``: coverage diverges (RdBu) around
    :data:`NOMINAL_COVERAGE_3SIGMA` (red: overconfident, blue: conservative); positive values
    spanning a decade or more get a LogNorm (viridis); others a linear scale."""
    finite = values[np.isfinite(values)]
    low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    if value.startswith("coverage"):
        centre = NOMINAL_COVERAGE_3SIGMA
        return TwoSlopeNorm(vcenter=centre, vmin=min(low, 2 * centre - 1.0), vmax=1.0), "RdBu"
    if spans_decades(values):
        return LogNorm(vmin=low, vmax=high), "viridis"
    return Normalize(vmin=low, vmax=high if high > low else low + 1.0), "viridis"


def cell_text(value: float, *, fraction: bool) -> str:
    """A heat-map cell's value: fractions with three decimals (0.9996 reads "1.000", not a
    perfect "1"), others with three significant digits, thousands in full ("1,234")."""
    if fraction:
        return f"{value:.3f}"
    return f"{value:,.0f}" if abs(value) >= 1000 else f"{value:.3g}"


def text_colour(rgba: Sequence[float]) -> str:
    """Black or white, whichever reads better on a cell of colour ``rgba`` (luma 0.299 R +
    0.587 G + 0.114 B against 0.5)."""
    return "k" if 0.299 * rgba[0] + 0.587 * rgba[1] + 0.114 * rgba[2] > 0.5 else "w"


def clipped_band(mean: NDArray[np.float64], spread: NDArray[np.float64], *, fraction: bool,
                 log: bool) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``mean -+ spread``, clipped to what the axis can show: [0, 1] for a fraction; on a log
    axis the lower edge is kept above zero (at a tenth of the smallest positive mean)."""
    lower, upper = mean - spread, mean + spread
    if fraction:
        lower, upper = np.clip(lower, 0.0, 1.0), np.clip(upper, 0.0, 1.0)
    if log:
        positive = mean[np.isfinite(mean) & (mean > 0)]
        floor = positive.min() / 10 if positive.size else 1e-12
        lower = np.maximum(lower, floor)
    return lower, upper


def legend_outside(figure: Figure, handles: Sequence[Any], labels: Sequence[str], *,
                   where: str = "right", title: str | None = None) -> None:
    """One legend for the figure, outside every axes (the figure must use the constrained
    layout): ``where`` is "right" (a column) or "top" (a row)."""
    if not handles:
        return
    if where == "top":
        figure.legend(handles, labels, loc="outside upper center", ncol=min(len(labels), 6),
                      fontsize=8, title=title, frameon=False)
    else:
        figure.legend(handles, labels, loc="outside right center", fontsize=8, title=title,
                      title_fontsize=8, frameon=False)


def plain_log_ticks(axis: Axis) -> None:
    """Label a log ``axis`` with plain numbers (0.1, 1, 10 rather than 10^-1, 10^0, 10^1); when
    its view spans less than 3.5 decades, label the minor ticks at 2 and 5 times a power of ten
    too (at most about ten labels), so that an axis never shows only two or three numbers."""
    axis.set_major_formatter(FuncFormatter(lambda value, _: f"{value:g}"))

    def minor(value: float, _: int) -> str:
        low, high = sorted(axis.get_view_interval())
        if value <= 0 or low <= 0 or high / low >= 10 ** 3.5:
            return ""
        mantissa = value / 10 ** np.floor(np.log10(value) + 1e-9)
        return f"{value:g}" if min(abs(mantissa - 2), abs(mantissa - 5)) < 1e-6 else ""

    axis.set_minor_formatter(FuncFormatter(minor))


def _unique_handles(axes: Sequence[Axes]) -> tuple[list[Any], list[str]]:
    handles: dict[str, Any] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels(), strict=True):
            handles.setdefault(label, handle)
    return list(handles.values()), list(handles)


def _save(figure: Figure, path: str | Path | None) -> Figure:
    if path is not None:
        path = Path(path)
        image_format = path.suffix.lstrip(".") or "png"
        atomic_write(path, lambda temporary: figure.savefig(temporary, format=image_format,
                                                            dpi=120, bbox_inches="tight"))
    return figure


# --------------------------------------------------------------------------------------------
# choosing what to show


def busiest_window(t: NDArray[np.float64], rate: NDArray[np.float64], window_s: float, *,
                   containing: NDArray[np.float64] | None = None) -> tuple[float, float]:
    """The window ``[start, start + window_s]`` (s) of highest mean ``rate``, starting at a
    sample of ``t``; with ``containing`` (times, s), only windows holding one of them (with a
    tenth of the window to spare on each side) compete, when any does. Shapes: ``t`` and
    ``rate`` (n,), ``t`` increasing. A recording shorter than the window is shown whole.

    mean over [t_i, t_i + w) = (C[j] - C[i]) / (j - i), C the cumulative sum of rate
    (C[0] = 0), j the first sample at or after t_i + w.
    """
    t, rate = np.asarray(t, dtype=float), np.nan_to_num(np.asarray(rate, dtype=float))
    if len(t) == 0 or t[-1] - t[0] <= window_s:
        return (float(t[0]), float(t[0]) + window_s) if len(t) else (0.0, window_s)
    starts = np.arange(len(t))
    stops = np.searchsorted(t, t + window_s, side="left")
    cumulative = np.concatenate([[0.0], np.cumsum(rate)])
    means = (cumulative[stops] - cumulative[starts]) / (stops - starts)
    valid = t + window_s <= t[-1]
    if containing is not None and len(containing):
        spare = window_s / 10
        inside = np.searchsorted(np.sort(containing), t + spare, side="left")
        holds = (inside < len(containing)) & \
            (np.sort(containing)[np.minimum(inside, len(containing) - 1)] <= t + window_s - spare)
        valid = valid & holds if (valid & holds).any() else valid
    best = int(np.argmax(np.where(valid, means, -np.inf)))
    return float(t[best]), float(t[best]) + window_s


def motion_window(recording: Recording, gap_mask: NDArray[np.bool_], window_s: float
                  ) -> tuple[float, float]:
    """The ``window_s`` seconds where the IMU turns fastest (highest mean gyroscope rate
    magnitude, rad/s) among windows holding a gap start: where the motion is fast, so a
    trajectory figure shows the estimators at work rather than a limb standing still."""
    rate = np.linalg.norm(np.asarray(recording.imu.gyroscope, dtype=float), axis=1)
    runs = occlusion_runs(~np.asarray(gap_mask, dtype=bool))
    gap_starts = np.asarray([recording.mocap.t[start] for start, _ in runs], dtype=float)
    return busiest_window(recording.imu.t, rate, window_s, containing=gap_starts)


def worst_gaps(runs: Sequence[tuple[int, int]], results: Mapping[str, TrackResult],
               reference: NDArray[np.float64], *, axes: Sequence[int] = (0, 1, 2),
               count: int = ZOOM_GAPS) -> list[tuple[int, int, int]]:
    """The ``count`` gaps (index ranges of :func:`kfusion.recording.occlusion_runs`) with the
    largest absolute error of any method on any of ``axes``, in time order, each with the axis
    of that error: ``(start, stop, axis)``. ``reference`` (m, 3) is the truth, m."""
    scored = []
    for start, stop in runs:
        worst, worst_axis = -1.0, axes[0]
        for result in results.values():
            error = np.abs(np.asarray(result.position)[start:stop] - reference[start:stop])
            for axis in axes:
                column = error[:, axis]
                if np.isfinite(column).any() and np.nanmax(column) > worst:
                    worst, worst_axis = float(np.nanmax(column)), axis
        scored.append((worst, start, stop, worst_axis))
    chosen = sorted(scored, key=lambda item: -item[0])[:count]
    return [(start, stop, axis) for _, start, stop, axis in sorted(chosen, key=lambda i: i[1])]


def binned_median(x: NDArray[np.float64], y: NDArray[np.float64], bins: int = 8
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Median of ``y`` in ``bins`` equal-width bins of ``x``: (bin centres, medians), empty
    bins left out."""
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    keep = np.isfinite(x) & np.isfinite(y)
    x, y = x[keep], y[keep]
    if x.size == 0:
        return np.empty(0), np.empty(0)
    edges = np.linspace(x.min(), x.max() if x.max() > x.min() else x.min() + 1e-9, bins + 1)
    index = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, bins - 1)
    filled = [i for i in range(bins) if (index == i).any()]
    centres = np.array([(edges[i] + edges[i + 1]) / 2 for i in filled])
    return centres, np.array([np.median(y[index == i]) for i in filled])


# --------------------------------------------------------------------------------------------
# trajectories and gaps


def _shade_gaps(ax: Axes, t: NDArray[np.float64], runs: Sequence[tuple[int, int]],
                shown: NDArray[np.bool_]) -> None:
    """Grey span from the last fix before each gap to the first fix after it."""
    for start, stop in runs:
        if shown[start:stop].any():
            ax.axvspan(t[max(start - 1, 0)], t[min(stop, len(t) - 1)], color="0.88", lw=0,
                       zorder=0, label="gap (mocap hidden)")


def in_gaps(values: NDArray[np.float64], runs: Sequence[tuple[int, int]],
            gap_mask: NDArray[np.bool_]) -> NDArray[np.float64]:
    """``values`` (m,) on gap rows and on the fixes just before and after each gap (so a line
    joins the gap to the track), NaN elsewhere."""
    keep = np.asarray(gap_mask, dtype=bool).copy()
    for start, stop in runs:
        keep[max(start - 1, 0)] = True
        keep[min(stop, len(keep) - 1)] = True
    return np.where(keep, np.asarray(values, dtype=float), np.nan)


def _draw_gap_errors(ax: Axes, t: NDArray[np.float64], reference: NDArray[np.float64],
                     results: Mapping[str, TrackResult], start: int, stop: int, axis: int,
                     margin_s: float) -> None:
    """Error (mm) along ``axis`` of each method around one gap, with its 3-sigma band; the gap
    shaded and zero marked. ``reference`` (m, 3), m."""
    shown = (t >= t[start] - margin_s) & (t <= t[stop - 1] + margin_s)
    ax.axvspan(t[max(start - 1, 0)], t[min(stop, len(t) - 1)], color="0.88", lw=0, zorder=0,
               label="gap (mocap hidden)")
    for index, (name, result) in enumerate(results.items()):
        style = method_style(name, index)
        error = 1000 * (np.asarray(result.position)[:, axis] - reference[:, axis])
        sigma = 1000 * np.asarray(result.std, dtype=float)[:, axis]
        if np.isfinite(sigma[shown]).any():
            ax.fill_between(t[shown], -3 * sigma[shown], 3 * sigma[shown], color=style["color"],
                            alpha=0.12, lw=0, zorder=1, label=f"{name} ±3σ")
        ax.plot(t[shown], error[shown], color=style["color"], ls=style["ls"],
                lw=min(style["lw"], 2.0), zorder=2 + index, label=name)
    ax.axhline(0, color="k", lw=0.6, zorder=1)
    ax.set_xlabel("t (s)", fontsize=8)
    inside = slice(max(start - 1, 0), min(stop + 1, len(t)))
    threshold = symlog_threshold([
        float(np.nanmax(np.abs(1000 * (np.asarray(result.position)[inside, axis]
                                       - reference[inside, axis])), initial=0.0))
        for result in results.values()])
    if threshold is None:
        ax.set_ylabel(f"{AXIS_NAMES[axis]} error (mm)", fontsize=8)
    else:
        ax.set_yscale("symlog", linthresh=threshold, linscale=1.0)
        # ticks at 1 and 3 times each power of ten: a peak between decades stays readable
        ax.yaxis.set_major_locator(SymmetricalLogLocator(linthresh=threshold, base=10,
                                                         subs=[1.0, 3.0]))
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.set_ylabel(f"{AXIS_NAMES[axis]} error (mm),\nlog beyond ±{threshold:g}", fontsize=8)
    ax.tick_params(labelsize=8)
    ax.grid(alpha=0.3)


def symlog_threshold(peaks: Sequence[float]) -> float | None:
    """Linear range (mm) of a symmetric-log error axis, or None for a linear axis.

    ``peaks`` are the methods' largest absolute errors (mm) in a panel. The second largest,
    rounded up to a power of ten, ``L = 10 ** ceil(log10(second))``, bounds every method but
    the worst. When the worst reaches ``10 L`` or more (the baseline's tens or hundreds of
    millimetres against the Kalman filter's one), a linear axis would draw the others as a flat
    line at zero; then the axis is linear on [-L, L] and logarithmic beyond, so that both are
    readable and the mocap noise outside the gap looks as small as it is.
    """
    finite = sorted((p for p in peaks if np.isfinite(p) and p > 0), reverse=True)
    if len(finite) < 2:
        return None
    linear = float(10 ** np.ceil(np.log10(finite[1]) - 1e-9))  # 1.0000001 mm: 1 mm
    return linear if finite[0] >= 10 * linear else None


def gap_duration(t: NDArray[np.float64], start: int, stop: int) -> float:
    """Duration (s) of the gap on rows ``[start, stop)``: from the last fix before it to the
    first fix after it, as in :func:`kfusion.evaluate.per_gap_errors`."""
    return float(t[min(stop, len(t) - 1)] - t[max(start - 1, 0)])


def _gap_title(letter: str, t: NDArray[np.float64], start: int, stop: int) -> str:
    return f"{letter}gap at {t[start]:.2f} s, {gap_duration(t, start, stop):.2f} s long"


def trajectory_figure(
    t: NDArray[np.float64],
    measured: NDArray[np.float64],
    results: Mapping[str, TrackResult],
    gap_mask: NDArray[np.bool_],
    *,
    truth: NDArray[np.float64] | None = None,
    axes: Sequence[int] = (0, 1, 2),
    window: tuple[float, float] | None = None,
    zoom_gaps: int = ZOOM_GAPS,
    margin_s: float = 0.15,
    title: str = "",
    path: str | Path | None = None,
) -> Figure:
    """Position against time per axis, like the paper's figures, and a row zooming on the
    worst gaps.

    Top panels (one per axis, full scale, in mm): measured mocap (dots), truth (thin black
    line on top), gaps shaded, each method's estimate inside the gaps with its 3-sigma band.
    Bottom row: the ``zoom_gaps`` gaps in the window with the largest error of any method, as
    error against the truth (or the measured mocap) in mm along the axis of that error; letters
    link them to the gaps above. Shapes: ``t`` (m,), ``measured`` (m, 3) with NaN where
    occluded, ``gap_mask`` (m,), ``truth`` (m, 3) or None; positions in m.
    """
    t = np.asarray(t, dtype=float)
    gap_mask = np.asarray(gap_mask, dtype=bool)
    shown = np.ones(len(t), dtype=bool) if window is None else \
        (t >= window[0]) & (t <= window[1])
    runs = occlusion_runs(~gap_mask)
    reference = np.asarray(truth if truth is not None else measured, dtype=float)
    zoomed = worst_gaps([run for run in runs if shown[run[0]:run[1]].all()], results, reference,
                        axes=axes, count=zoom_gaps) if zoom_gaps else []
    columns = max(len(zoomed), 1)
    figure = plt.figure(figsize=(11, 2.3 * len(axes) + (2.6 if zoomed else 0)),
                        layout="constrained")
    grid = figure.add_gridspec(len(axes) + bool(zoomed), columns)
    full: list[Axes] = []
    for row, axis in enumerate(axes):
        ax = figure.add_subplot(grid[row, :], sharex=full[0] if full else None)
        _draw_full_scale(ax, t, measured, results, gap_mask, runs, shown, truth, axis)
        for letter, (start, stop, _) in zip("ABCDEFGH", zoomed, strict=False):
            ax.annotate(letter, ((t[start] + t[stop - 1]) / 2, 1.0), xycoords=("data",
                        "axes fraction"), ha="center", va="bottom", fontsize=8, weight="bold")
        full.append(ax)
    full[-1].set_xlabel("t (s)")
    if window is not None:
        full[0].set_xlim(max(window[0], t[0]), min(window[1], t[-1]))
    zoom_axes = []
    for column, (start, stop, axis) in enumerate(zoomed):
        ax = figure.add_subplot(grid[len(axes), column])
        _draw_gap_errors(ax, t, reference, results, start, stop, axis, margin_s)
        ax.set_title(_gap_title(f"{'ABCDEFGH'[column]}: ", t, start, stop), fontsize=8)
        zoom_axes.append(ax)
    legend_outside(figure, *_unique_handles(full + zoom_axes))
    if title:
        figure.suptitle(title)
    return _save(figure, path)


def _draw_full_scale(ax: Axes, t: NDArray[np.float64], measured: NDArray[np.float64],
                     results: Mapping[str, TrackResult], gap_mask: NDArray[np.bool_],
                     runs: Sequence[tuple[int, int]], shown: NDArray[np.bool_],
                     truth: NDArray[np.float64] | None, axis: int) -> None:
    """One full-scale panel of :func:`trajectory_figure` (positions in mm). Estimates and truth
    are drawn inside the gaps only (outside, the mocap dots are the measurement); a few nested
    markers per gap keep methods apart where their lines coincide at this scale."""
    _shade_gaps(ax, t, runs, shown)
    ax.plot(t[shown], 1000 * np.asarray(measured)[shown, axis], ".", color="tab:blue", ms=2.5,
            zorder=2, label="mocap (seen)")
    marked = gap_markers(runs, len(t)) & shown
    for index, (name, result) in enumerate(results.items()):
        style = method_style(name, index)
        estimate = np.where(np.asarray(result.status) == LOST, np.nan,
                            np.asarray(result.position)[:, axis])
        values = in_gaps(estimate, runs, gap_mask)
        std = in_gaps(np.asarray(result.std, dtype=float)[:, axis], runs, gap_mask)
        if np.isfinite(std[shown & gap_mask]).any():
            ax.fill_between(t[shown], 1000 * (values - 3 * std)[shown],
                            1000 * (values + 3 * std)[shown], color=style["color"], alpha=0.15,
                            lw=0, zorder=1, label=f"{name} ±3σ")
        ax.plot(t[shown], 1000 * values[shown], color=style["color"], ls=style["ls"],
                lw=style["lw"], marker=style["marker"], ms=style["ms"], mfc="none",
                markevery=list(np.flatnonzero(marked[shown])), zorder=3 + index, label=name)
    if truth is not None:
        inside = in_gaps(np.asarray(truth, dtype=float)[:, axis], runs, gap_mask)
        ax.plot(t[shown], 1000 * inside[shown], color="k", lw=0.8, zorder=10,
                label="truth (in gaps)")
    ax.set_ylabel(f"{AXIS_NAMES[axis]} (mm)")
    ax.grid(alpha=0.3)


def gap_markers(runs: Sequence[tuple[int, int]], rows: int, per_gap: int = 3
                ) -> NDArray[np.bool_]:
    """(rows,) True on ``per_gap`` evenly spread rows inside each gap (where the full-scale
    trajectory puts its method markers)."""
    marked = np.zeros(rows, dtype=bool)
    for start, stop in runs:
        inside = np.linspace(start, stop - 1, per_gap + 2)[1:-1].round().astype(int)
        marked[inside] = True
    return marked


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
    """Small multiples of the ``gaps`` worst gaps (largest error of any method along ``axis``),
    in time order: error against the truth (or the measured mocap) in mm along ``axis``, per
    method, with the 3-sigma band where the method gives one.

    Millimetre errors are invisible on a trajectory spanning 0.8 m; this zooms in on them.
    Shapes as in :func:`trajectory_figure`.
    """
    t = np.asarray(t, dtype=float)
    reference = np.asarray(truth if truth is not None else measured, dtype=float)
    chosen = worst_gaps(occlusion_runs(~np.asarray(gap_mask, dtype=bool)), results, reference,
                        axes=(axis,), count=gaps)
    columns = min(3, max(len(chosen), 1))
    rows = max(1, -(-len(chosen) // columns))
    figure, plot_axes = plt.subplots(rows, columns, figsize=(4 * columns + 1.5, 2.8 * rows),
                                     squeeze=False, layout="constrained")
    for index, (start, stop, _) in enumerate(chosen):
        ax = plot_axes[index // columns, index % columns]
        _draw_gap_errors(ax, t, reference, results, start, stop, axis, margin_s)
        ax.set_title(_gap_title("", t, start, stop), fontsize=9)
    for index in range(len(chosen), rows * columns):
        plot_axes[index // columns, index % columns].axis("off")
    legend_outside(figure, *_unique_handles(list(plot_axes.ravel())))
    if title:
        figure.suptitle(title)
    return _save(figure, path)


# --------------------------------------------------------------------------------------------
# errors per gap and sweeps


def error_by_gap_length_figure(per_gap: pd.DataFrame, *, metric: str = "max_mm",
                               title: str = "", path: str | Path | None = None) -> Figure:
    """Per-gap error metric (log scale) against gap duration: one marker shape and colour per
    method, and each method's median in duration bins as a line (readable even when thousands
    of gaps overlap), drawn under the points.

    ``per_gap`` has columns ``method``, ``duration_s`` and ``metric`` (as made by
    :func:`kfusion.evaluate.per_gap_errors` plus a method column).
    """
    figure, ax = plt.subplots(figsize=(7.5, 4), layout="constrained")
    for index, (method, rows) in enumerate(per_gap.groupby("method", sort=False)):
        style = method_style(str(method), index)
        alpha = float(np.clip(40 / np.sqrt(len(rows)), 0.15, 0.8))
        ax.plot(rows["duration_s"], rows[metric], style["marker"], ms=4, alpha=alpha,
                color=style["color"], mew=0, zorder=2 + index, label=str(method))
        centres, medians = binned_median(rows["duration_s"].to_numpy(), rows[metric].to_numpy())
        ax.plot(centres, medians, color=style["color"], ls=style["ls"], lw=1.6, alpha=0.8,
                zorder=1)
    ax.set_xlabel(quantity_label("duration_s"))
    ax.set_ylabel(per_gap_label(metric))
    ax.set_yscale("log")
    plain_log_ticks(ax.yaxis)
    ax.grid(alpha=0.3, which="both")
    methods = [str(method) for method in per_gap["method"].unique()] if len(per_gap) else []
    handles = [Line2D([], [], ls="none", marker=method_style(m, i)["marker"],
                      color=method_style(m, i)["color"]) for i, m in enumerate(methods)]
    legend_outside(figure, [*handles, Line2D([], [], color="0.3", lw=2.0)],
                   [*methods, "median per duration bin"])
    if title:
        ax.set_title(title)
    return _save(figure, path)


def heatmap_figure(table: pd.DataFrame, *, rows: str, columns: str, value: str,
                   title: str = "", path: str | Path | None = None,
                   facet: str | None = None) -> Figure:
    """Heat map of ``value`` (mean over repeats and any other column) on a ``rows`` x ``columns``
    grid of a sweep; with ``facet``, one panel per value of that column on a shared colour
    scale (:func:`colour_scale`: log where values span decades, diverging for coverage). A
    column without values stays, its cells marked "–" ("no bound" for the baseline's coverage),
    so that every map of a sweep shows the same methods. ``table`` is a sweep's results
    table (one row per run)."""
    panels = [(None, table)] if facet is None else list(table.groupby(facet, sort=True))
    grids = [(label, frame.pivot_table(index=rows, columns=columns, values=value,
                                       aggfunc="mean", dropna=False))
             for label, frame in panels]
    values = np.concatenate([grid.to_numpy(dtype=float).ravel() for _, grid in grids])
    norm, cmap = colour_scale(values, value)
    n_rows = max(grid.shape[0] for _, grid in grids)
    n_columns = max(grid.shape[1] for _, grid in grids)
    figure, plot_axes = plt.subplots(
        1, len(grids), squeeze=False, sharey=True, layout="constrained",
        figsize=(2.4 + (1.1 * n_columns + 0.6) * len(grids), 1.6 + 0.6 * n_rows))
    image = None
    for ax, (label, grid) in zip(plot_axes[0], grids, strict=True):
        image = _draw_heatmap_panel(ax, grid, norm, cmap, fraction=is_fraction(value),
                                    missing="no bound" if value.startswith("coverage") else "–")
        ax.set_xlabel(quantity_label(columns))
        if label is not None:
            ax.set_title(f"{quantity_label(str(facet))}: {tick_text(label)}", fontsize=9)
    plot_axes[0, 0].set_ylabel(quantity_label(rows))
    if image is not None:
        log = isinstance(norm, LogNorm)  # say so: whether it is depends on the values
        bar = figure.colorbar(image, ax=list(plot_axes[0]),
                              label=quantity_label(value) + (", log scale" if log else ""))
        if log:
            plain_log_ticks(bar.ax.yaxis)
        else:
            bar.ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        if value.startswith("coverage"):
            bar.ax.axhline(NOMINAL_COVERAGE_3SIGMA, color="k", lw=1.0)
    if title:
        figure.suptitle(title)
    return _save(figure, path)


def _draw_heatmap_panel(ax: Axes, grid: pd.DataFrame, norm: Normalize, cmap: str, *,
                        fraction: bool, missing: str) -> Any:
    """One heat-map panel with each cell's value written in it (:func:`cell_text`), ``missing``
    in cells without one."""
    data = grid.to_numpy(dtype=float)
    image = ax.imshow(data, cmap=cmap, norm=norm, aspect="auto")
    ax.set_xticks(range(grid.shape[1]), [tick_text(c) for c in grid.columns], rotation=30,
                  ha="right")
    ax.set_yticks(range(grid.shape[0]), [tick_text(i) for i in grid.index])
    colours = plt.get_cmap(cmap)
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            cell = data[i, j]
            colour = "k" if np.isnan(cell) else text_colour(colours(norm(cell)))
            ax.text(j, i, missing if np.isnan(cell) else cell_text(cell, fraction=fraction),
                    ha="center", va="center", fontsize=8, color=colour)
    return image


def sweep_lines_figure(table: pd.DataFrame, *, x: str, value: str, hue: str = "method",
                       facet: str | None = None, log: bool = True, title: str = "",
                       path: str | Path | None = None) -> Figure:
    """``value`` against the sweep axis ``x``, one line per value of ``hue`` (mean over seeds
    and other columns, with a band of +-1 standard deviation across seeds, clipped to [0, 1]
    for fractions), one panel per value of ``facet``. ``x`` is treated as categorical, in sorted
    order; each hue is shifted a little sideways and has its own marker, so equal values stay
    visible. Fractions get a linear axis ending at 1 and, for coverage, the calibrated value
    as a reference line. ``table`` is a sweep's results table (one row per run)."""
    fraction = is_fraction(value)
    log = log and not fraction
    panels = [(None, table)] if facet is None else list(table.groupby(facet, sort=True))
    figure, plot_axes = plt.subplots(1, len(panels), squeeze=False, sharey=True,
                                     layout="constrained", figsize=(2.6 + 4.2 * len(panels), 3.8))
    for ax, (label, frame) in zip(plot_axes[0], panels, strict=True):
        _draw_lines_panel(ax, frame, x=x, value=value, hue=hue, fraction=fraction, log=log)
        if label is not None:
            ax.set_title(f"{quantity_label(str(facet))}: {tick_text(label)}", fontsize=9)
    plot_axes[0, 0].set_ylabel(quantity_label(value))
    if fraction:  # after every panel is drawn: the shared limits then hold all their bands
        plot_axes[0, 0].autoscale_view()
        plot_axes[0, 0].set_ylim(max(plot_axes[0, 0].get_ylim()[0], 0.0), 1.01)
    legend_outside(figure, *_unique_handles(list(plot_axes[0])), title=quantity_label(hue))
    if title:
        figure.suptitle(title)
    return _save(figure, path)


def _draw_lines_panel(ax: Axes, frame: pd.DataFrame, *, x: str, value: str, hue: str,
                      fraction: bool, log: bool) -> None:
    """One panel of :func:`sweep_lines_figure`."""
    positions = {key: index for index, key in enumerate(sorted(frame[x].unique()))}
    groups = list(frame.groupby(hue, sort=False))
    for index, (name, rows) in enumerate(groups):
        statistics = rows.groupby(x)[value].agg(["mean", "std"]).sort_index()
        shift = 0.06 * (index - (len(groups) - 1) / 2)
        where = np.array([positions[key] for key in statistics.index], dtype=float) + shift
        style = method_style(str(name), index)
        mean = statistics["mean"].to_numpy(dtype=float)
        if not np.isfinite(mean).any():  # e.g. coverage of a method without a bound
            continue
        lower, upper = clipped_band(mean, statistics["std"].fillna(0.0).to_numpy(dtype=float),
                                    fraction=fraction, log=log)
        ax.fill_between(where, lower, upper, color=style["color"], alpha=0.15, lw=0)
        ax.plot(where, mean, color=style["color"], ls=style["ls"], marker=style["marker"],
                lw=1.5, ms=6 - index % 3, label=tick_text(name))
    if value.startswith("coverage"):
        ax.axhline(NOMINAL_COVERAGE_3SIGMA, color="k", lw=0.8, ls=":",
                   label=f"calibrated 3σ: {NOMINAL_COVERAGE_3SIGMA:.3f}")
    ax.set_xticks(list(positions.values()), [tick_text(key) for key in positions], rotation=20)
    ax.set_xlabel(quantity_label(x))
    if log:
        ax.set_yscale("log")
        plain_log_ticks(ax.yaxis)
    ax.grid(alpha=0.3, which="both")


# --------------------------------------------------------------------------------------------
# several bodies


def binding_margin_figure(margins: BindingMargins, *, path: str | Path | None = None,
                          title: str | None = None) -> Figure:
    """The binding body's margin |robot - body| - S_p (m) over time
    (:func:`kfusion.safety.binding_margins`): one colour per body where it binds, a dashed line
    at 0 m (below it the robot must slow or stop), and red spans where the margin is unknown
    (a body lost), which never read as a margin."""
    figure, ax = plt.subplots(figsize=(9, 3.2), layout="constrained")
    t = np.asarray(margins.t, dtype=float)
    for index, name in enumerate(margins.names):
        binds = (margins.body == name) & margins.known
        if binds.any():
            style = method_style(name, index)
            ax.plot(t, np.where(binds, margins.margin, np.nan), color=style["color"],
                    ls=style["ls"], lw=1.5, label=f"{name} binds")
    step = median_interval(t)
    for start, stop in occlusion_runs(margins.known):  # each unknown row to the next row
        ax.axvspan(t[start], t[stop] if stop < len(t) else t[-1] + step, color="tab:red",
                   alpha=0.2, lw=0, zorder=0, label="unknown (a body lost)")
    ax.axhline(0.0, color="k", lw=0.8, ls="--", label="margin 0 m")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("binding margin |robot − body| − S_p (m)")
    ax.grid(alpha=0.3)
    legend_outside(figure, *_unique_handles([ax]))
    if title:
        ax.set_title(title)
    return _save(figure, path)
