"""Figures of a self-calibration (notebook ``04_calibrate_a_recording``).

Each function returns a matplotlib Figure and, given ``path``, also saves it (PNG), following
:mod:`kfusion.plots`' rules: legends outside the data, units on every axis.

* :func:`correlation_figure`: the clock's cross-correlation curve, whole range and a zoom on
  its peak;
* :func:`residual_figure`: the distribution of the rate and specific-force misfits before
  calibration (clock 0, identity mount, gravity alone fitted) and after;
* :func:`gap_error_figure`: RMS gap error and lost gap samples, before and after.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from numpy.typing import NDArray

from kfusion.calibration.clock import Correlation
from kfusion.calibration.rates import rate_pairs, rate_residuals
from kfusion.calibration.recording import SelfCalibration
from kfusion.calibration.specific_force import solve_specific_force, specific_force_system
from kfusion.conventions import matrix_from_wxyz
from kfusion.plots import OTHER_STYLES, _save, legend_outside, plt
from kfusion.recording import Recording

Array = NDArray[np.float64]

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
BEFORE_STYLE = {"color": "tab:red", "ls": "--", "lw": 2.0}
AFTER_STYLE = {"color": "tab:green", "ls": "-", "lw": 1.5}


def correlation_figure(correlations: Mapping[str, Correlation], *,
                       true_offsets: Mapping[str, float] | None = None,
                       zoom_s: float = 0.05, path: str | Path | None = None) -> Figure:
    """One row per recording: the correlation of the rate magnitudes against the clock
    offset over the whole search range (left) and within ``zoom_s`` s of its peak (right, in
    ms), with the peak found and, when given, the true offset."""
    rows = len(correlations)
    figure, axes = plt.subplots(rows, 2, figsize=(10, 2.6 * rows), layout="constrained",
                                squeeze=False)
    for (name, correlation), (whole, zoom) in zip(correlations.items(), axes, strict=True):
        truth = (true_offsets or {}).get(name)
        near = np.abs(correlation.lag - correlation.offset) <= zoom_s
        for ax, scale, keep in ((whole, 1.0, np.ones_like(near)), (zoom, 1e3, near)):
            ax.plot(correlation.lag[keep] * scale, correlation.value[keep], color="tab:blue",
                    lw=1.2, label="correlation of |ω| (gyroscope vs mocap)")
            ax.axvline(correlation.offset * scale, color="tab:green", ls="-", lw=1.0,
                       label="peak found")
            if truth is not None:
                ax.axvline(truth * scale, color="black", ls=":", lw=1.5,
                           label="expected offset (from the truth)")
            ax.set_ylabel("Pearson r")
            ax.grid(alpha=0.3)
        whole.set_xlabel("IMU clock offset (s)")
        zoom.set_xlabel("IMU clock offset (ms)")
        whole.set_title(f"{name}: whole search range", fontsize=9)
        zoom.set_title(f"{name}: peak {correlation.offset * 1e3:+.1f} ms "
                       f"(r = {correlation.peak:.3f}; next best {correlation.runner_up:.2f})",
                       fontsize=9)
    handles, labels = axes[0, 1].get_legend_handles_labels()
    legend_outside(figure, handles, labels, where="top")
    return _save(figure, path)


def rate_misfit(recording: Recording, offset: float, drift_ppm: float,
                imu_to_body: Array, gyroscope_bias: Array) -> Array:
    """``|w_mocap - R_body_imu (w_gyro - b)|`` per rate interval under the given clock,
    mount and bias, rad/s."""
    pairs = rate_pairs(recording, offset, drift_ppm, margin=0.0)
    residual = rate_residuals(pairs, offset, drift_ppm, matrix_from_wxyz(imu_to_body),
                              gyroscope_bias)
    return np.asarray(np.linalg.norm(residual, axis=1))


def specific_force_misfit(recording: Recording, offset: float, drift_ppm: float,
                          imu_to_body: Array, *, full_model: bool) -> Array:
    """``|y - A x|`` per filtered sample (m/s^2) of the specific-force system
    (:mod:`kfusion.calibration.specific_force`) under the given clock and mount: gravity alone
    fitted, or (``full_model``) gravity, lever arm, bias and scale errors."""
    y, design = specific_force_system(recording, offset, drift_ppm, imu_to_body)
    if full_model:
        _, _, residual = solve_specific_force(y, design)
        return np.asarray(np.linalg.norm(residual, axis=1))
    columns = design[:, :, :3].reshape(-1, 3)
    gravity, *_ = np.linalg.lstsq(columns, y.reshape(-1), rcond=None)
    return np.asarray(np.linalg.norm((y.reshape(-1) - columns @ gravity).reshape(-1, 3),
                                     axis=1))


def _cumulative(ax: Axes, values: Array, label: str, style: dict) -> None:
    ordered = np.sort(values[np.isfinite(values) & (values > 0)])
    ax.plot(ordered, np.arange(1, len(ordered) + 1) / len(ordered), label=label, **style)


def residual_figure(cases: Mapping[str, tuple[Recording, SelfCalibration]], *,
                    path: str | Path | None = None) -> Figure:
    """One row per recording: cumulative distributions of the rate misfit (left) and of the
    specific-force misfit (right), before calibration (clock offset and drift 0, identity
    mount, no bias; gravity alone fitted) and after (every calibrated value)."""
    rows = len(cases)
    figure, axes = plt.subplots(rows, 2, figsize=(10, 2.8 * rows), layout="constrained",
                                squeeze=False)
    for (name, (recording, calibration)), (rates, force) in zip(cases.items(), axes,
                                                                 strict=True):
        fit = calibration.clock_and_mount.fit
        _cumulative(rates, rate_misfit(recording, 0.0, 0.0, IDENTITY, np.zeros(3)),
                    "before: clock 0, identity mount, no bias", BEFORE_STYLE)
        _cumulative(rates, rate_misfit(recording, fit.offset, fit.drift_ppm, fit.imu_to_body,
                                       fit.gyroscope_bias), "after calibration", AFTER_STYLE)
        try:
            _cumulative(force, specific_force_misfit(recording, 0.0, 0.0, IDENTITY,
                                                     full_model=False),
                        "before: clock 0, identity mount, no bias", BEFORE_STYLE)
        except ValueError:  # no visible run inside the IMU's span on the wrong clock
            force.text(0.02, 0.9, "before: no overlap on the uncorrected clock",
                       transform=force.transAxes, fontsize=8)
        _cumulative(force, specific_force_misfit(recording, fit.offset, fit.drift_ppm,
                                                 fit.imu_to_body, full_model=True),
                    "after calibration", AFTER_STYLE)
        rates.set_xlabel("angular-rate misfit |ω_mocap − R(ω_gyro − b)| (rad/s)")
        force.set_xlabel("specific-force misfit (m/s²)")
        for ax in (rates, force):
            ax.set_xscale("log")
            ax.set_ylabel("fraction of samples below")
            ax.set_ylim(0, 1)
            ax.grid(alpha=0.3, which="both")
        rates.set_title(f"{name}: angular rates", fontsize=9)
        force.set_title(f"{name}: specific force (filtered below 4 Hz)", fontsize=9)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    legend_outside(figure, handles, labels, where="top")
    return _save(figure, path)


def gap_error_figure(table: Mapping[str, Mapping[str, tuple[float, float]]], *,
                     path: str | Path | None = None) -> Figure:
    """Grouped bars: ``table[recording][condition] = (RMS gap error mm, lost gap samples
    %)``; RMS (log scale) on the left, the lost share on the right. A gap sample the tracker
    calls lost is not scored in the RMS, so both are needed."""
    recordings = list(table)
    conditions = list(dict.fromkeys(c for row in table.values() for c in row))
    figure, (rms_ax, lost_ax) = plt.subplots(1, 2, figsize=(10, 3.4), layout="constrained")
    width = 0.8 / max(len(conditions), 1)
    positions = np.arange(len(recordings))
    for index, condition in enumerate(conditions):
        values = np.array([table[r].get(condition, (np.nan, np.nan)) for r in recordings],
                          dtype=float)
        colour = OTHER_STYLES[index % len(OTHER_STYLES)]["color"]
        shift = (index - (len(conditions) - 1) / 2) * width
        rms_ax.bar(positions + shift, values[:, 0], width, color=colour, label=condition)
        lost_ax.bar(positions + shift, values[:, 1], width, color=colour, label=condition)
        for x, (rms, lost) in zip(positions + shift, values, strict=True):
            text = ("all lost" if not np.isfinite(rms) else
                    f"{rms:.3g}" if rms < 1000 else f"{rms:.0f}")
            rms_ax.annotate(text, (x, rms if np.isfinite(rms) else 1.0), ha="center", va="bottom",
                            fontsize=7, xytext=(0, 2), textcoords="offset points")
            lost_ax.annotate(f"{lost:.0f} %", (x, lost), ha="center", va="bottom", fontsize=7,
                             xytext=(0, 2), textcoords="offset points")
    rms_ax.set_yscale("log")
    rms_ax.set_ylim(bottom=0.5)
    rms_ax.set_ylabel("RMS gap error over bridged samples (mm)")
    lost_ax.set_ylabel("gap samples lost (%)")
    lost_ax.set_ylim(0, 110)
    for ax in (rms_ax, lost_ax):
        ax.set_xticks(positions, recordings, fontsize=8)
        ax.grid(alpha=0.3, axis="y", which="both")
    handles, labels = rms_ax.get_legend_handles_labels()
    legend_outside(figure, handles, labels, where="top")
    return _save(figure, path)
