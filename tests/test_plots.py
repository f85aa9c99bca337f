"""The figures keep their promises: legends off the data, gaps shaded, the worst gaps zoomed,
log or diverging colour scales where they are needed, units on axes, coverage bands in [0, 1]."""

from __future__ import annotations

from dataclasses import replace

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
from matplotlib.colors import LogNorm, Normalize, TwoSlopeNorm

from kfusion.conventions import BRIDGED, TRACKED
from kfusion.plots import (
    NOMINAL_COVERAGE_3SIGMA,
    binned_median,
    busiest_window,
    cell_text,
    clipped_band,
    colour_scale,
    error_by_gap_length_figure,
    gap_duration,
    gap_markers,
    gap_zoom_figure,
    heatmap_figure,
    in_gaps,
    plain_log_ticks,
    quantity_label,
    sweep_lines_figure,
    symlog_threshold,
    text_colour,
    tick_text,
    trajectory_figure,
    worst_gaps,
)
from kfusion.track_file import TrackResult

RATE_HZ = 100
GAPS = [(100, 120), (300, 330), (500, 515), (700, 740)]
"""Rows [start, stop) hidden in the synthetic recording."""
ERRORS_MM = {"baseline": [4.0, 20.0, 1.0, 9.0], "kalman": [1.0, 2.0, 6.0, 0.5]}
"""Largest error per gap (along y, growing linearly through the gap) of each method."""


def synthetic():
    """10 s at 100 Hz, a 0.3 m sine on y, four gaps; each method's y error ramps to
    ERRORS_MM inside each gap, 1 mm sigma."""
    t = np.arange(1000) / RATE_HZ
    truth = np.zeros((len(t), 3))
    truth[:, 1] = 0.3 * np.sin(t)
    gap = np.zeros(len(t), dtype=bool)
    for start, stop in GAPS:
        gap[start:stop] = True
    measured = np.where(gap[:, None], np.nan, truth)
    results = {}
    for name, peaks in ERRORS_MM.items():
        position = truth.copy()
        for (start, stop), peak in zip(GAPS, peaks, strict=True):
            position[start:stop, 1] += 1e-3 * peak * np.linspace(0.1, 1.0, stop - start)
        results[name] = TrackResult(t=t, position=position, std=np.full((len(t), 3), 1e-3),
                                    status=np.where(gap, BRIDGED, TRACKED),
                                    time_since_fix=np.zeros(len(t)), method=name)
    return t, truth, measured, gap, results


def legend_overlaps_any_axes(figure) -> bool:
    figure.canvas.draw()
    renderer = figure.canvas.get_renderer()
    legends = list(figure.legends) + [ax.get_legend() for ax in figure.axes if ax.get_legend()]
    assert legends, "expected a legend"
    return any(legend.get_window_extent(renderer).overlaps(ax.get_window_extent(renderer))
               for legend in legends for ax in figure.axes if ax.get_label() != "<colorbar>")


@pytest.fixture(autouse=True)
def close_figures():
    yield
    plt.close("all")


def sweep_table() -> pd.DataFrame:
    """Two gap ranges x three methods x two seeds; the baseline's errors reach 932 mm."""
    rows = []
    for gap_range, scale in (("[0.1, 0.3]", 1.0), ("[0.6, 1.0]", 10.0)):
        for method, rms, coverage in (("baseline", 93.2, np.nan), ("kalman", 1.5, 0.97),
                                      ("smoother", 0.2, 0.999)):
            for seed, spread in ((0, -1), (1, 1)):
                rows.append({"data.occlusions.gap_range": gap_range, "method": method,
                             "seed": seed, "rms_mm": rms * scale * (1 + 0.1 * spread),
                             "coverage_3sigma": coverage + 0.02 * spread * (coverage > 0.98)})
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------------------------
# pure helpers


def test_worst_gaps_are_the_largest_errors_in_time_order_with_their_axis():
    t, truth, _, gap, results = synthetic()
    runs = [(start, stop) for start, stop in GAPS]
    # worst per gap over methods: 4, 20, 6, 9 mm -> gaps 2, 4, 3; shown in time order
    assert worst_gaps(runs, results, truth, count=3) == [(300, 330, 1), (500, 515, 1),
                                                         (700, 740, 1)]
    assert worst_gaps(runs, {"kalman": results["kalman"]}, truth, count=1) == [(500, 515, 1)]
    assert worst_gaps(runs, results, truth, axes=(0,), count=2) == [(100, 120, 0),
                                                                    (300, 330, 0)]


def test_busiest_window_finds_the_fast_stretch_and_prefers_windows_holding_a_gap():
    t = np.arange(0, 60, 0.01)
    rate = np.where((t >= 40) & (t < 46), 8.0, 0.01)
    start, stop = busiest_window(t, rate, 6.0)
    assert start == pytest.approx(40.0) and stop == pytest.approx(46.0)
    # a gap only at 10 s: the fast stretch holds none, so the window moves to the gap
    start, _ = busiest_window(t, rate, 6.0, containing=np.array([10.0]))
    assert start <= 10.0 - 0.6 and start + 6.0 >= 10.0 + 0.6
    # a recording shorter than the window is shown whole
    assert busiest_window(t[:100], rate[:100], 6.0) == (0.0, 6.0)


def test_colour_scale_is_log_across_decades_diverging_for_coverage_linear_otherwise():
    norm, _ = colour_scale(np.array([0.19, 1.3, 87.0, 932.0]), "rms_mm")
    assert isinstance(norm, LogNorm) and norm.vmin == 0.19 and norm.vmax == 932.0
    norm, cmap = colour_scale(np.array([0.965, 0.99, 1.0, np.nan]), "coverage_3sigma")
    assert isinstance(norm, TwoSlopeNorm) and cmap == "RdBu"
    assert norm.vcenter == pytest.approx(0.9973 ** 3) and norm.vmax == 1.0
    assert norm.vmin == pytest.approx(0.965)
    norm, _ = colour_scale(np.array([2.0, 5.0, 9.0]), "rms_mm")
    assert type(norm) is Normalize and (norm.vmin, norm.vmax) == (2.0, 9.0)
    norm, _ = colour_scale(np.array([-1.0, 50.0]), "rms_mm")  # not all positive: linear
    assert type(norm) is Normalize


def test_coverage_bands_stay_inside_zero_and_one_and_log_bands_above_zero():
    mean = np.array([0.99, 0.5, 0.02])
    lower, upper = clipped_band(mean, np.array([0.05, 0.1, 0.05]), fraction=True, log=False)
    np.testing.assert_allclose(upper, [1.0, 0.6, 0.07])
    np.testing.assert_allclose(lower, [0.94, 0.4, 0.0])
    lower, upper = clipped_band(np.array([2.0, 20.0]), np.array([3.0, 1.0]), fraction=False,
                                log=True)
    np.testing.assert_allclose(lower, [0.2, 19.0])
    np.testing.assert_allclose(upper, [5.0, 21.0])


def test_labels_carry_units():
    assert quantity_label("methods.kalman.accelerometer_noise_density") == \
        "kalman accelerometer noise density (m/s²/√Hz)"
    assert quantity_label("data.occlusions.gap_range") == "gap length (s)"
    assert quantity_label("rms_mm") == "RMS gap error (mm)"
    assert quantity_label("something_s") == "something (s)"
    assert tick_text("[0.1, 0.3]") == "0.1–0.3"
    assert tick_text([0.6, 1.0]) == "0.6–1"
    assert tick_text(0.0030000000000000001) == "0.003"
    assert tick_text("mpu9255") == "mpu9255"


def visible_tick_labels(axis) -> list[str]:
    low, high = sorted(axis.get_view_interval())
    return [tick.label1.get_text() for tick in axis.get_major_ticks() + axis.get_minor_ticks()
            if tick.label1.get_text() and low * 0.999 <= tick.get_loc() <= high * 1.001]


def test_log_axes_read_as_plain_numbers_and_short_ones_label_2_and_5():
    figure, ax = plt.subplots()
    ax.set_yscale("log")
    plain_log_ticks(ax.yaxis)
    ax.set_ylim(1.0, 20.0)  # 1.3 decades: 1, 2, 5, 10, 20
    figure.canvas.draw()
    labels = visible_tick_labels(ax.yaxis)
    assert sorted(labels, key=float) == ["1", "2", "5", "10", "20"]
    ax.set_ylim(0.1, 1000.0)  # four decades: the decades alone
    figure.canvas.draw()
    labels = visible_tick_labels(ax.yaxis)
    assert sorted(labels, key=float) == ["0.1", "1", "10", "100", "1000"]
    assert cell_text(0.99962, fraction=True) == "1.000" and cell_text(932.04, fraction=False) == \
        "932" and cell_text(1234.5, fraction=False) == "1,234"


def test_small_helpers_by_hand():
    centres, medians = binned_median(np.array([0.0, 0.1, 0.2, 1.0]),
                                     np.array([1.0, 3.0, 2.0, 7.0]), bins=2)
    np.testing.assert_allclose(centres, [0.25, 0.75])
    np.testing.assert_allclose(medians, [2.0, 7.0])
    t = np.arange(10) * 0.1
    assert gap_duration(t, 3, 6) == pytest.approx(0.4)  # last fix 0.2 s, first after 0.6 s
    mask = np.zeros(10, dtype=bool)
    mask[3:6] = True
    kept = in_gaps(np.arange(10.0), [(3, 6)], mask)
    np.testing.assert_array_equal(np.isfinite(kept), [0, 0, 1, 1, 1, 1, 1, 0, 0, 0])
    np.testing.assert_array_equal(np.flatnonzero(gap_markers([(0, 10)], 10)), [2, 4, 7])
    assert text_colour((1.0, 1.0, 0.8, 1.0)) == "k" and text_colour((0.2, 0.0, 0.3, 1)) == "w"


# --------------------------------------------------------------------------------------------
# figures


def test_trajectory_figure_shades_every_gap_zooms_on_the_worst_and_keeps_its_legend_off():
    t, truth, measured, gap, results = synthetic()
    figure = trajectory_figure(t, measured, results, gap, truth=truth, axes=(1,))
    full, *zoom = figure.axes
    spans = sorted((round(patch.get_x(), 6), round(patch.get_x() + patch.get_width(), 6))
                   for patch in full.patches)
    assert spans == [(round(t[start - 1], 6), round(t[stop], 6)) for start, stop in GAPS]
    assert [ax.get_title()[:1] for ax in zoom] == ["A", "B", "C"]
    assert [ax.get_title() for ax in zoom][0] == "A: gap at 3.00 s, 0.31 s long"
    assert not legend_overlaps_any_axes(figure)
    # every method is drawn in the full-scale panel with its own style
    styles = {line.get_label(): (line.get_linestyle(), line.get_marker())
              for line in full.lines if line.get_label() in results}
    assert len(set(styles.values())) == len(results)


def test_trajectory_window_keeps_only_gaps_inside_it_for_the_zoom():
    t, truth, measured, gap, results = synthetic()
    figure = trajectory_figure(t, measured, results, gap, truth=truth, axes=(0, 1),
                               window=(0.0, 4.0))
    titles = [ax.get_title() for ax in figure.axes if ax.get_title()]
    assert titles == ["A: gap at 1.00 s, 0.21 s long", "B: gap at 3.00 s, 0.31 s long"]
    assert figure.axes[0].get_xlim() == (0.0, 4.0)  # the window, not the gaps' shading


def test_symlog_threshold_only_when_one_method_dwarfs_the_rest():
    # baseline 932 mm against kalman 0.45 mm: linear on [-1, 1] mm, log beyond
    assert symlog_threshold([932.0, 0.45, 0.1]) == pytest.approx(1.0)
    assert symlog_threshold([250.0, 2.5]) == pytest.approx(10.0)
    assert symlog_threshold([31.0, 2.5, 0.3]) is None  # 31 mm is inside a decade of 10 mm
    assert symlog_threshold([9.0, 1.0]) is None
    assert symlog_threshold([40.0]) is None  # a single method
    assert symlog_threshold([40.0, 0.0, np.nan]) is None  # nothing to read beside it


def test_gap_zoom_turns_log_where_the_baseline_dwarfs_the_kalman_filter():
    t, truth, measured, gap, results = synthetic()
    baseline = results["baseline"]
    results["baseline"] = replace(baseline, position=truth + 10 * (baseline.position - truth))
    figure = gap_zoom_figure(t, measured, results, gap, truth=truth, axis=1, gaps=4)
    # peaks (baseline, kalman) per gap, mm: 40/1, 200/2, 10/6, 90/0.5
    scales = [(ax.get_yscale(), getattr(ax.yaxis.get_transform(), "linthresh", None))
              for ax in figure.axes if ax.get_title()]
    assert scales == [("symlog", 1.0), ("symlog", 10.0), ("linear", None), ("symlog", 1.0)]
    assert all("log beyond ±" in ax.get_ylabel() for ax in figure.axes
               if ax.get_yscale() == "symlog")
    # a 40 mm peak reads between labelled ticks at 30 and the top, not in an unlabelled decade
    first = figure.axes[0].yaxis.get_major_locator().tick_values(-1.0, 40.0)
    assert {0.0, 1.0, 3.0, 10.0, 30.0} <= set(np.round(first, 9))


def test_gap_zoom_figure_shows_the_worst_gaps_with_the_legend_outside():
    t, truth, measured, gap, results = synthetic()
    figure = gap_zoom_figure(t, measured, results, gap, truth=truth, axis=1, gaps=2)
    titles = [ax.get_title() for ax in figure.axes if ax.get_title()]
    assert titles == ["gap at 3.00 s, 0.31 s long", "gap at 7.00 s, 0.41 s long"]
    assert not legend_overlaps_any_axes(figure)


def test_error_by_gap_figure_has_its_legend_outside_and_a_median_line_per_method():
    per_gap = pd.DataFrame({"method": ["baseline"] * 4 + ["kalman"] * 4,
                            "duration_s": [0.1, 0.2, 0.3, 0.4] * 2,
                            "max_mm": [10.0, 20.0, 30.0, 40.0, 1.0, 2.0, 3.0, 4.0]})
    figure = error_by_gap_length_figure(per_gap)
    ax = figure.axes[0]
    assert ax.get_yscale() == "log" and ax.get_xlabel() == "gap duration (s)"
    assert len(ax.lines) == 4  # points and median per method
    assert not legend_overlaps_any_axes(figure)


def test_heatmap_uses_a_log_scale_when_the_baseline_swamps_the_others():
    figure = heatmap_figure(sweep_table(), rows="data.occlusions.gap_range", columns="method",
                            value="rms_mm")
    image = figure.axes[0].images[0]
    assert isinstance(image.norm, LogNorm)
    assert figure.axes[-1].get_ylabel() == "RMS gap error (mm), log scale"  # the colour bar
    assert figure.axes[0].get_ylabel() == "gap length (s)"
    assert [label.get_text() for label in figure.axes[0].get_yticklabels()] == ["0.1–0.3",
                                                                                "0.6–1"]
    figure = heatmap_figure(sweep_table(), rows="data.occlusions.gap_range", columns="method",
                            value="coverage_3sigma")
    assert isinstance(figure.axes[0].images[0].norm, TwoSlopeNorm)
    # the baseline gives no bound: its column stays, marked, beside the others
    ax = figure.axes[0]
    assert [label.get_text() for label in ax.get_xticklabels()] == ["baseline", "kalman",
                                                                    "smoother"]
    assert [text.get_text() for text in ax.texts].count("no bound") == 2


def test_sweep_lines_keep_coverage_bands_below_one_and_the_legend_outside():
    figure = sweep_lines_figure(sweep_table(), x="data.occlusions.gap_range",
                                value="coverage_3sigma", log=False)
    ax = figure.axes[0]
    tops = [collection.get_paths()[0].vertices[:, 1].max() for collection in ax.collections]
    assert tops and max(tops) <= 1.0
    assert ax.get_ylim()[1] <= 1.01
    assert any(line.get_ydata()[0] == pytest.approx(NOMINAL_COVERAGE_3SIGMA)
               for line in ax.lines)
    assert ax.get_ylabel() == "fraction of gap samples inside 3σ"
    assert not legend_overlaps_any_axes(figure)
    figure = sweep_lines_figure(sweep_table(), x="data.occlusions.gap_range", value="rms_mm")
    assert figure.axes[0].get_yscale() == "log"
    assert not legend_overlaps_any_axes(figure)


def test_sweep_line_panels_share_limits_that_hold_every_panels_band():
    table = sweep_table()
    table["data.imu"] = "mpu9255"
    wide = table[table["method"] == "kalman"].assign(**{"data.imu": "um7"})
    wide["coverage_3sigma"] = [0.90, 0.96, 0.90, 0.96]  # mean 0.93, std 0.042 per gap range
    figure = sweep_lines_figure(pd.concat([table, wide]), x="data.occlusions.gap_range",
                                value="coverage_3sigma", facet="data.imu", log=False)
    bottoms = [collection.get_paths()[0].vertices[:, 1].min() for ax in figure.axes
               for collection in ax.collections]
    low, high = figure.axes[0].get_ylim()
    assert min(bottoms) == pytest.approx(0.93 - 0.06 / np.sqrt(2))
    assert low <= min(bottoms) and high == pytest.approx(1.01)
    assert figure.axes[1].get_ylim() == (low, high)
    assert not legend_overlaps_any_axes(figure)
