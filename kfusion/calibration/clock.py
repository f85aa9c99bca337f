"""The IMU's clock against the mocap's: offset and drift from angular rates.

Model (:func:`kfusion.conventions.imu_time_to_mocap`, the one place it is written):

    t_mocap = (1 + drift_ppm * 1e-6) * t_imu + offset

Signals compared (both are mean body rates over the same short interval, so neither is
differentiated more than the other):

* mocap: ``w_mocap(k) = rotvec(q_k^-1 q_k+s) / (t_k+s - t_k)``, body frame, between two visible
  frames ``s`` apart (:func:`mocap_interval_rates`);
* gyroscope: ``w_gyro(k) = (C(tau_k+s) - C(tau_k)) / (t_k+s - t_k)`` with ``C`` the running
  trapezoid integral of the gyroscope (IMU frame) and ``tau`` the IMU-clock time of a mocap
  time (:func:`gyroscope_interval_rates`).

Their magnitudes do not depend on the mount, so the coarse offset is the lag that maximises the
normalised cross-correlation of ``|w_gyro|`` and ``|w_mocap|`` (:func:`coarse_clock_offset`).
Offsets measured in windows give the drift (:func:`drift_from_window_offsets`); the final values
come from a joint least-squares fit with the mount (:mod:`kfusion.calibration.mount`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal

from kfusion.conventions import median_interval, rotation_from_wxyz
from kfusion.recording import ImuSamples, Recording

Array = NDArray[np.float64]

RATE_INTERVAL_S: Final = 0.1
"""s: interval over which mean rates are compared (4 frames at 100 Hz): long enough to average
the mocap's orientation noise, short enough that the rate hardly changes within it."""
CORRELATION_STEP_S: Final = 0.005
"""s: grid of the coarse cross-correlation (sub-step accuracy comes from the refinement)."""
DEFAULT_MAX_OFFSET_S: Final = 5.0
"""s: coarse search range of the clock offset, either sign."""
LARGEST_MAX_OFFSET_S: Final = 3600.0
"""s: the largest search range accepted (its grid at :data:`CORRELATION_STEP_S` holds about
1.4 million points; ``--max-offset 1e9`` asked numpy for 2.9 TiB). An offset beyond an hour is
a clock set to another day, not something to search for."""


@dataclass(frozen=True)
class IntervalRates:
    """Mean body rates between visible mocap frames ``s`` apart.

    Attributes:
        start, end: (k,) mocap times of the two frames, s.
        rate: (k, 3) mean angular rate, rad/s, body frame.
    """

    start: Array
    end: Array
    rate: Array

    @property
    def middle(self) -> Array:
        return 0.5 * (self.start + self.end)

    def subset(self, keep: NDArray[np.bool_]) -> IntervalRates:
        return IntervalRates(self.start[keep], self.end[keep], self.rate[keep])


def frames_per_interval(mocap_t: ArrayLike, interval_s: float = RATE_INTERVAL_S) -> int:
    """Frames ``s`` between the two ends of a rate interval: ``max(1, round(interval / dt))``
    with dt the median frame step."""
    step = median_interval(mocap_t)
    return max(1, int(round(interval_s / step)))


def mocap_interval_rates(t: ArrayLike, quaternion: ArrayLike, frames: int, *,
                         stride: int | None = None) -> IntervalRates:
    """``rotvec(q_k^-1 q_k+s) / (t_k+s - t_k)`` (body frame, rad/s) for visible frame pairs
    ``s = frames`` apart with no gap between them, every ``stride`` frames (default ``s``:
    non-overlapping intervals, so that their noise is independent).

    Args:
        t: (m,) mocap times, s. quaternion: (m, 4) body -> global [w, x, y, z], NaN occluded.
    """
    t = np.asarray(t, dtype=float)
    quaternion = np.asarray(quaternion, dtype=float)
    visible = np.isfinite(quaternion).all(axis=1)
    stride = frames if stride is None else stride
    step = median_interval(t, default=1.0)
    first = np.arange(0, len(t) - frames, stride)
    last = first + frames
    # every frame of the interval visible: count occluded frames with a running sum
    hidden = np.concatenate([[0], np.cumsum(~visible)])
    keep = (hidden[last + 1] - hidden[first] == 0) & (t[last] - t[first] < (frames + 0.5) * step)
    first, last = first[keep], last[keep]
    if len(first) == 0:
        return IntervalRates(np.empty(0), np.empty(0), np.empty((0, 3)))
    increment = rotation_from_wxyz(quaternion[first]).inv() * rotation_from_wxyz(
        quaternion[last])
    duration = t[last] - t[first]
    return IntervalRates(t[first], t[last], increment.as_rotvec() / duration[:, None])


def gyroscope_integral(imu: ImuSamples) -> Array:
    """``C(t_i) = integral_t0^t_i gyroscope dt`` (trapezoid, IMU clock), (n, 3) rad."""
    steps = 0.5 * (imu.gyroscope[1:] + imu.gyroscope[:-1]) * np.diff(imu.t)[:, None]
    return np.vstack([np.zeros((1, 3)), np.cumsum(steps, axis=0)])


def mocap_to_imu_time(t_mocap: ArrayLike, offset: float, drift_ppm: float) -> Array:
    """Inverse of :func:`kfusion.conventions.imu_time_to_mocap`:
    ``t_imu = (t_mocap - offset) / (1 + drift_ppm 1e-6)``."""
    return np.asarray((np.asarray(t_mocap, dtype=float) - offset) / (1.0 + drift_ppm * 1e-6))


def gyroscope_interval_rates(imu_t: Array, integral: Array, start: Array, end: Array,
                             offset: float, drift_ppm: float) -> Array:
    """Mean gyroscope rate (IMU frame, rad/s) over the mocap-clock intervals ``[start, end]``:
    ``(C(tau(end)) - C(tau(start))) / (end - start)``, ``tau`` the IMU-clock time; (k, 3).
    Intervals outside the IMU's span read the end values (callers keep only inside ones)."""
    low = mocap_to_imu_time(start, offset, drift_ppm)
    high = mocap_to_imu_time(end, offset, drift_ppm)
    change = np.column_stack([np.interp(high, imu_t, integral[:, axis])
                              - np.interp(low, imu_t, integral[:, axis]) for axis in range(3)])
    return np.asarray(change / (end - start)[:, None])


def inside_imu(rates: IntervalRates, imu_t: Array, offset: float, drift_ppm: float,
               margin: float = 0.0) -> NDArray[np.bool_]:
    """(k,) True where the whole interval (plus ``margin`` s) lies within the IMU's span."""
    low = mocap_to_imu_time(rates.start - margin, offset, drift_ppm)
    high = mocap_to_imu_time(rates.end + margin, offset, drift_ppm)
    return np.asarray((low >= imu_t[0]) & (high <= imu_t[-1]))


# --------------------------------------------------------------------------------------------
# Coarse offset: cross-correlation of magnitudes
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Correlation:
    """Normalised cross-correlation of gyroscope and mocap rate magnitudes.

    Attributes:
        lag: (L,) candidate offsets, s (``t_mocap = t_imu + lag``).
        value: (L,) Pearson correlation at each lag (NaN where the overlap is too short).
        offset: the lag of the peak, s, refined by a parabola through the peak and its
            neighbours.
        peak: the correlation at the peak (1 = perfect match).
        runner_up: the highest correlation more than 0.25 s away from the peak (how unique the
            peak is).
    """

    lag: Array
    value: Array
    offset: float
    peak: float
    runner_up: float


def _masked_grid(times: Array, values: Array, grid: Array, max_distance: float
                 ) -> tuple[Array, Array]:
    """``values`` interpolated onto ``grid``, and a 0/1 mask that is 1 where a sample lies
    within ``max_distance`` s of the grid point."""
    resampled = np.interp(grid, times, values)
    index = np.clip(np.searchsorted(times, grid), 1, len(times) - 1)
    distance = np.minimum(np.abs(grid - times[index - 1]), np.abs(times[index] - grid))
    mask = (distance <= max_distance) & (grid >= times[0]) & (grid <= times[-1])
    return np.where(mask, resampled, 0.0), mask.astype(float)


def normalised_cross_correlation(x: ArrayLike, x_mask: ArrayLike, y: ArrayLike,
                                 y_mask: ArrayLike, min_overlap: int
                                 ) -> tuple[NDArray[np.int_], Array]:
    """Masked Pearson correlation of ``y[n]`` with ``x[n - k]`` for every integer lag k.

    Over the samples where both masks are 1 (N of them) at lag k:

        r(k) = (N Sxy - Sx Sy) / sqrt((N Sxx - Sx^2) (N Syy - Sy^2))

    with every sum computed for all lags at once by FFT correlation. NaN where N < min_overlap
    or a variance vanishes. A signal ``y[n] = x[n - k0]`` peaks at ``k0``.

    Returns:
        (lags (L,), r (L,)).
    """
    mask_x = np.asarray(x_mask, dtype=float)
    mask_y = np.asarray(y_mask, dtype=float)
    first = np.asarray(x, dtype=float) * mask_x
    second = np.asarray(y, dtype=float) * mask_y
    # centre on the masked means: the formula is shift-invariant, this only helps round-off
    xs = (first - np.sum(first) / max(np.sum(mask_x), 1)) * mask_x
    ys = (second - np.sum(second) / max(np.sum(mask_y), 1)) * mask_y

    def correlate(a: Array, b: Array) -> Array:
        return np.asarray(signal.correlate(a, b, mode="full", method="fft"))

    count = correlate(mask_y, mask_x)
    sum_x = correlate(mask_y, xs)
    sum_y = correlate(ys, mask_x)
    sum_xx = correlate(mask_y, xs * xs)
    sum_yy = correlate(ys * ys, mask_x)
    sum_xy = correlate(ys, xs)
    lags = signal.correlation_lags(len(ys), len(xs), mode="full")
    variance = (count * sum_xx - sum_x**2) * (count * sum_yy - sum_y**2)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = (count * sum_xy - sum_x * sum_y) / np.sqrt(variance)
    valid = (np.round(count) >= min_overlap) & (variance > 1e-12 * np.maximum(count, 1) ** 4)
    return lags, np.where(valid, r, np.nan)


def parabola_peak(values: ArrayLike) -> float:
    """Sub-sample position (-0.5..0.5) of the maximum of a parabola through three values
    ``[y(-1), y(0), y(1)]`` with y(0) the largest: ``(y(-1) - y(1)) / (2 (y(-1) - 2 y(0) +
    y(1)))``; 0 when they are collinear."""
    before, peak, after = (float(v) for v in np.asarray(values, dtype=float))
    curvature = before - 2.0 * peak + after
    if not curvature < 0:
        return 0.0
    return float(np.clip(0.5 * (before - after) / curvature, -0.5, 0.5))


def coarse_clock_offset(recording: Recording, *, max_offset: float = DEFAULT_MAX_OFFSET_S,
                        centre: float = 0.0, step: float = CORRELATION_STEP_S,
                        clipped: NDArray[np.bool_] | None = None) -> Correlation:
    """The lag maximising the correlation of ``|w_gyro|`` and ``|w_mocap|``, searched over
    ``centre +- max_offset`` s. Independent of the mount. The recording's own clock fields are
    ignored: the lag is measured on the raw IMU stamps. ``clipped`` (n,) bool marks IMU samples
    on a plateau (:func:`kfusion.calibration.diagnosis.clipped_samples`): the gyroscope's mean
    rate is not compared where its interval touches one (a flat-topped rate would shift the
    peak: 25 ms on a BROAD trial clipped at 250 dps).

    Raises ValueError when no lag has enough overlap (at least 5 s or a quarter of the mocap),
    or when ``max_offset`` is not a number in (0, :data:`LARGEST_MAX_OFFSET_S`].
    """
    if not (isinstance(max_offset, (int, float)) and 0 < max_offset <= LARGEST_MAX_OFFSET_S):
        raise ValueError(f"max offset: expected a number of seconds in (0, "
                         f"{LARGEST_MAX_OFFSET_S:g}], got {max_offset!r}")
    imu, mocap = recording.imu, recording.mocap
    frames = frames_per_interval(mocap.t)
    rates = mocap_interval_rates(mocap.t, mocap.quaternion, frames, stride=1)
    if len(rates.start) < 10:
        raise ValueError("cannot correlate the clocks: fewer than 10 visible mocap frame pairs")
    width = float(np.median(rates.end - rates.start))
    integral = gyroscope_integral(imu)
    # the gyro's mean rate over the same interval length, centred on each grid point
    start = min(imu.t[0] + centre, mocap.t[0]) - max_offset
    stop = max(imu.t[-1] + centre, mocap.t[-1]) + max_offset
    grid = np.arange(start, stop + step, step)
    shifted = grid - centre  # IMU clock
    gyro = np.column_stack([np.interp(shifted + width / 2, imu.t, integral[:, axis])
                            - np.interp(shifted - width / 2, imu.t, integral[:, axis])
                            for axis in range(3)]) / width
    gyro_mask = ((shifted - width / 2 >= imu.t[0]) & (shifted + width / 2 <= imu.t[-1]))
    if clipped is not None and clipped.any():
        # clipped samples inside the interval or next to its ends (the interpolation's)
        count = np.concatenate([[0], np.cumsum(clipped)])
        first = np.maximum(np.searchsorted(imu.t, shifted - width / 2, side="left") - 1, 0)
        last = np.minimum(np.searchsorted(imu.t, shifted + width / 2, side="right") + 1,
                          len(imu.t))
        gyro_mask &= count[last] - count[first] == 0
    gyro_magnitude = np.linalg.norm(gyro, axis=1)
    mocap_magnitude, mocap_mask = _masked_grid(rates.middle, np.linalg.norm(rates.rate, axis=1),
                                               grid, 0.75 * width)
    covered = float(np.sum(mocap_mask) * step)
    min_overlap = int(min(5.0, 0.25 * covered) / step)
    lags, r = normalised_cross_correlation(gyro_magnitude, gyro_mask.astype(float),
                                           mocap_magnitude, mocap_mask, max(min_overlap, 10))
    lag_s = lags * step + centre
    window = np.abs(lags * step) <= max_offset
    lag_s, r = lag_s[window], r[window]
    if not np.isfinite(r).any():
        raise ValueError(f"cannot correlate the clocks: the IMU ({imu.t[0]:.3f}-{imu.t[-1]:.3f} "
                         f"s) and the visible mocap ({mocap.t[0]:.3f}-{mocap.t[-1]:.3f} s) "
                         f"overlap by less than {min_overlap * step:.1f} s at any offset within "
                         f"{centre:+.1f} +- {max_offset:g} s"
                         + (" once the clipped samples are left out"
                            if clipped is not None and clipped.any() else ""))
    best = int(np.nanargmax(r))
    fraction = 0.0
    if 0 < best < len(r) - 1 and np.isfinite(r[best - 1:best + 2]).all():
        fraction = parabola_peak(r[best - 1:best + 2])
    far = np.abs(lag_s - lag_s[best]) > 0.25
    runner_up = float(np.nanmax(r[far])) if np.isfinite(r[far]).any() else float("nan")
    return Correlation(lag=lag_s, value=r, offset=float(lag_s[best] + fraction * step),
                       peak=float(r[best]), runner_up=runner_up)


# --------------------------------------------------------------------------------------------
# Drift from windows
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ClockFit:
    """Offset and drift with 1-sigma uncertainties.

    Attributes:
        offset: s. drift_ppm: ppm. offset_std: s. drift_std_ppm: ppm.
        residual: RMS misfit of what was fitted (s for window offsets, rad/s for rates).
    """

    offset: float
    drift_ppm: float
    offset_std: float
    drift_std_ppm: float
    residual: float


def drift_from_window_offsets(imu_times: ArrayLike, offsets: ArrayLike,
                              offset_std: ArrayLike | None = None) -> ClockFit:
    """Weighted line through offsets measured in windows.

    In a window centred at IMU time tau the measured offset is ``t_mocap - t_imu =
    drift * 1e-6 * tau + offset``, so a least-squares line ``offsets = a + b tau`` gives
    ``offset = a`` and ``drift_ppm = b * 1e6``. Weights ``1 / std^2`` (equal when None).
    Uncertainties from the weighted normal equations, scaled by the reduced chi-square when
    it exceeds 1.

    Args:
        imu_times: (w,) window centres on the IMU clock, s. offsets: (w,) s.
        offset_std: (w,) 1-sigma of each window's offset, s.
    """
    tau = np.asarray(imu_times, dtype=float)
    measured = np.asarray(offsets, dtype=float)
    if tau.shape != measured.shape or tau.ndim != 1 or len(tau) < 2:
        raise ValueError(f"drift_from_window_offsets: expected two (w,) arrays with w >= 2, "
                         f"got {tau.shape} and {measured.shape}")
    std = np.ones_like(tau) if offset_std is None else np.asarray(offset_std, dtype=float)
    weights = 1.0 / np.maximum(std, 1e-12) ** 2
    basis = np.column_stack([np.ones_like(tau), tau])
    normal = basis.T @ (basis * weights[:, None])
    coefficients = np.linalg.solve(normal, basis.T @ (weights * measured))
    residual = measured - basis @ coefficients
    covariance = np.linalg.inv(normal)
    if len(tau) > 2:
        chi2 = float(np.sum(weights * residual**2) / (len(tau) - 2))
        covariance = covariance * (max(chi2, 1.0) if offset_std is not None else chi2)
    return ClockFit(offset=float(coefficients[0]), drift_ppm=float(coefficients[1] * 1e6),
                    offset_std=float(np.sqrt(covariance[0, 0])),
                    drift_std_ppm=float(np.sqrt(covariance[1, 1]) * 1e6),
                    residual=float(np.sqrt(np.mean(residual**2))))
