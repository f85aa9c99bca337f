"""Mount and clock from paired angular rates: Kabsch, then one joint least-squares fit.

Model for a mocap rate interval k (see :mod:`kfusion.calibration.clock`):

    w_mocap(k) = R_body_imu (w_gyro(k; offset, drift) - b_gyro) + noise

with ``R_body_imu`` the mount (``recording.yaml``'s ``imu_to_body``) and ``b_gyro`` the
gyroscope bias (IMU frame). A first mount comes from Kabsch on the pairs
(:func:`mount_from_rates`); offsets fitted in windows give the drift
(:func:`kfusion.calibration.clock.drift_from_window_offsets`); then every unknown is refined
together by robust least squares (:func:`fit_rates`, scipy ``least_squares``), and the
uncertainties come from its Jacobian.

The rotation about an axis is seen only if the limb turns about another axis too: the second
moment of the body rates, ``M = mean(w w^T)``, tells (:func:`rate_spread`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from kfusion.calibration.clock import (
    IntervalRates,
    drift_from_window_offsets,
    frames_per_interval,
    gyroscope_integral,
    gyroscope_interval_rates,
    inside_imu,
    mocap_interval_rates,
)
from kfusion.calibration.mount import marginal_information
from kfusion.calibration.paper import kabsch
from kfusion.conventions import rotation_from_wxyz, wxyz_from_rotation
from kfusion.recording import Recording

Array = NDArray[np.float64]

MIN_ROTATION_RATE: Final = 0.05
"""rad/s: RMS body rate below which the recording has too little rotation to fit clock or
mount (the gyroscope's turn-on bias is up to ~0.1 rad/s)."""
MIN_SECOND_AXIS: Final = 0.1
"""The second-largest RMS rate about a principal axis must be at least this fraction of the
largest, or the mount is undetermined about the main rotation axis."""
MAX_DRIFT_STD_PPM: Final = 10.0
"""ppm: a drift fitted less precisely than this is not written (left at 0)."""
MAX_OFFSET_STD_S: Final = 0.002
"""s: an offset fitted less precisely than this is reported undetermined."""
MAX_MOUNT_STD_DEG: Final = 1.0
"""deg: a mount axis whose 1-sigma exceeds this is reported undetermined."""


def mount_from_rates(rate_body: ArrayLike, rate_imu: ArrayLike) -> Array:
    """``R_body_imu`` (3, 3) minimising ``sum |w_body - R w_imu|^2`` (Kabsch)."""
    return kabsch(rate_body, rate_imu)


def rate_spread(rate_body: ArrayLike) -> tuple[Array, Array]:
    """Principal RMS rates and axes of the body rates: the eigen-decomposition of
    ``M = mean(w w^T)``. Returns (sqrt of eigenvalues (3,) descending, rad/s; axes (3, 3) as
    columns)."""
    rates = np.asarray(rate_body, dtype=float)
    moment = rates.T @ rates / max(len(rates), 1)
    values, vectors = np.linalg.eigh(moment)
    order = np.argsort(values)[::-1]
    return np.sqrt(np.maximum(values[order], 0.0)), vectors[:, order]


@dataclass(frozen=True)
class RatePairs:
    """Mocap interval rates with the IMU's data needed to compute the matching gyro rates."""

    mocap: IntervalRates
    imu_t: Array
    integral: Array
    overlap: int = 1
    """Intervals sharing each frame (they overlap: their noise is correlated)."""

    def gyroscope(self, offset: float, drift_ppm: float) -> Array:
        return gyroscope_interval_rates(self.imu_t, self.integral, self.mocap.start,
                                        self.mocap.end, offset, drift_ppm)


def rate_pairs(recording: Recording, offset: float, drift_ppm: float = 0.0, *,
               margin: float = 0.1) -> RatePairs:
    """Mocap interval rates starting at every visible frame (overlapping: all the data is
    used) and lying inside the IMU's span (plus ``margin`` s, room for the fit to move the
    offset) under the given clock."""
    mocap, imu = recording.mocap, recording.imu
    frames = frames_per_interval(mocap.t)
    rates = mocap_interval_rates(mocap.t, mocap.quaternion, frames, stride=1)
    keep = inside_imu(rates, imu.t, offset, drift_ppm, margin) if len(rates.start) else \
        np.zeros(0, dtype=bool)
    return RatePairs(rates.subset(keep), imu.t, gyroscope_integral(imu), frames)


@dataclass(frozen=True)
class RateFit:
    """Result of :func:`fit_rates`.

    Attributes:
        offset, offset_std: s. drift_ppm, drift_std_ppm: ppm (std 0 when drift was fixed).
        imu_to_body: (4,) [w, x, y, z]. mount_std_deg: (3,) 1-sigma of the mount's rotation
            error about the body x, y, z axes, degrees.
        gyroscope_bias, gyroscope_bias_std: (3,) rad/s, IMU frame.
        residual_rms: RMS of ``w_mocap - R (w_gyro - b)`` per axis, rad/s (mocap orientation
            noise and gyro noise).
        rate_before_rms: the same with the identity mount, no bias and the starting clock, rad/s.
        pairs: number of rate intervals used.
        mount_information: (3, 3) information on the mount rotation theta (rad^-2, body frame,
            ``R = exp([theta]x) R_fit``) with offset, drift and bias marginalised
            (:func:`kfusion.calibration.mount.marginal_information`); zero when the mount was
            held.
    """

    offset: float
    offset_std: float
    drift_ppm: float
    drift_std_ppm: float
    imu_to_body: Array
    mount_std_deg: Array
    gyroscope_bias: Array
    gyroscope_bias_std: Array
    residual_rms: float
    pairs: int
    mount_information: Array = field(default_factory=lambda: np.zeros((3, 3)))


def rate_residuals(pairs: RatePairs, offset: float, drift_ppm: float, R_body_imu: ArrayLike,
                   gyroscope_bias: ArrayLike) -> Array:
    """``w_mocap - R_body_imu (w_gyro - b)`` per interval, (k, 3) rad/s."""
    gyro = pairs.gyroscope(offset, drift_ppm) - np.asarray(gyroscope_bias, dtype=float)
    return np.asarray(pairs.mocap.rate - gyro @ np.asarray(R_body_imu, dtype=float).T)


def fit_rates(pairs: RatePairs, offset: float, drift_ppm: float, imu_to_body: ArrayLike, *,
              fit_drift: bool = True, fit_mount: bool = True,
              gyroscope_bias: ArrayLike = (0.0, 0.0, 0.0)) -> RateFit:
    """Robust least squares of :func:`rate_residuals` over offset (and drift, mount, bias).

    Parameters: ``[offset (ms), drift (ppm), theta (3, rad), b (3, rad/s)]`` with the mount
    ``R = R0 exp([theta]x)`` (theta in the body frame). Loss soft-L1 with a scale of 3 robust
    sigmas of the starting residual, so a glitched mocap frame cannot pull the fit. The
    covariance is ``sigma^2 (J^T J)^-1`` at the solution, sigma from the inlier residuals.
    """
    R0 = rotation_from_wxyz(imu_to_body)
    free = np.array([True, fit_drift, fit_mount, fit_mount, fit_mount, True, True, True])
    start = np.array([offset * 1e3, drift_ppm, 0.0, 0.0, 0.0, *np.asarray(gyroscope_bias)])

    def unpack(values: Array) -> tuple[float, float, Array, Array]:
        full = start.copy()
        full[free] = values
        R = (Rotation.from_rotvec(full[2:5]) * R0).as_matrix()
        return full[0] * 1e-3, float(full[1]), R, full[5:8]

    def residuals(values: Array) -> Array:
        offset_s, drift, R, bias = unpack(values)
        return rate_residuals(pairs, offset_s, drift, R, bias).ravel()

    initial = residuals(start[free])
    scale = 3.0 * 1.4826 * float(np.median(np.abs(initial - np.median(initial)))) + 1e-9
    solution = least_squares(residuals, start[free], loss="soft_l1", f_scale=scale,
                             x_scale="jac", method="trf")
    offset_s, drift, R, bias = unpack(solution.x)
    final = solution.fun.reshape(-1, 3)
    inliers = np.abs(solution.fun) < 3 * scale
    sigma2 = float(np.sum(solution.fun[inliers] ** 2) / max(inliers.sum() - free.sum(), 1))
    jacobian = solution.jac[inliers]
    # overlapping intervals share their noise: each frame's noise enters `overlap` residuals,
    # so the information is `overlap` times less than the count suggests
    normal = jacobian.T @ jacobian / (sigma2 * pairs.overlap)
    covariance_free = np.linalg.pinv(normal)
    std = np.zeros(8)
    std[free] = np.sqrt(np.maximum(np.diag(covariance_free), 0.0))
    information = np.zeros((3, 3))
    if fit_mount:
        target = np.searchsorted(np.flatnonzero(free), [2, 3, 4])  # theta among the free
        information, _ = marginal_information(normal, np.zeros(len(normal)), target)
    return RateFit(offset=offset_s, offset_std=float(std[0] * 1e-3), drift_ppm=drift,
                   drift_std_ppm=float(std[1]),
                   imu_to_body=wxyz_from_rotation(Rotation.from_matrix(R)),
                   mount_std_deg=np.degrees(std[2:5]), gyroscope_bias=bias,
                   gyroscope_bias_std=std[5:8],
                   residual_rms=float(np.sqrt(np.mean(final[np.abs(final) < 3 * scale] ** 2))),
                   pairs=len(final), mount_information=information)


@dataclass(frozen=True)
class WindowOffsets:
    """Offsets fitted in windows (the mount and bias held), for the drift and for plots.

    Attributes:
        imu_time: (w,) window centres, IMU clock, s. offset, offset_std: (w,) s.
    """

    imu_time: Array
    offset: Array
    offset_std: Array


def window_offsets(pairs: RatePairs, fit: RateFit, window_s: float, min_pairs: int = 100
                   ) -> WindowOffsets:
    """Offset alone fitted in consecutive windows of ``window_s`` s (mocap clock), starting from
    ``fit``'s clock, mount and bias; windows with fewer than ``min_pairs`` intervals or too
    little rotation (:data:`MIN_ROTATION_RATE`) are skipped."""
    middle = pairs.mocap.middle
    edges = np.arange(middle[0], middle[-1] + window_s, window_s)
    times, offsets, stds = [], [], []
    for low, high in zip(edges[:-1], edges[1:], strict=True):
        keep = (middle >= low) & (middle < high)
        if keep.sum() < min_pairs:
            continue
        if rate_spread(pairs.mocap.rate[keep])[0][0] < MIN_ROTATION_RATE:
            continue
        subset = RatePairs(pairs.mocap.subset(keep), pairs.imu_t, pairs.integral, pairs.overlap)
        # a window's offset is t_mocap - t_imu there: the drift's contribution is included
        local_offset = fit.offset + fit.drift_ppm * 1e-6 * float(np.mean(middle[keep]))
        window = fit_rates(subset, local_offset, 0.0, fit.imu_to_body, fit_drift=False,
                           fit_mount=False, gyroscope_bias=fit.gyroscope_bias)
        times.append(float(np.mean(middle[keep])) - window.offset)
        offsets.append(window.offset)
        stds.append(window.offset_std)
    return WindowOffsets(np.asarray(times), np.asarray(offsets), np.asarray(stds))


@dataclass(frozen=True)
class ClockAndMount:
    """Result of :func:`calibrate_clock_and_mount`: the joint fit, the windows it started
    from, and what the motion leaves undetermined (empty when everything is)."""

    fit: RateFit
    windows: WindowOffsets
    coarse_offset: float
    principal_rates: Array
    principal_axes: Array
    undetermined: dict[str, str]


def calibrate_clock_and_mount(recording: Recording, coarse_offset: float, *,
                              window_s: float | None = None) -> ClockAndMount:
    """Clock offset, drift, mount and gyroscope bias from the rates, starting at the
    cross-correlation's ``coarse_offset`` (s).

    Steps: Kabsch mount at the coarse offset; joint fit without drift; offsets in windows
    (default ``window_s``: a tenth of the recording, 5-30 s) and a line through them
    (:func:`drift_from_window_offsets`); joint fit of everything from there. When the
    recording is shorter than three windows the drift is not fitted and reported undetermined.
    """
    undetermined: dict[str, str] = {}
    pairs = rate_pairs(recording, coarse_offset)
    if len(pairs.mocap.start) < 20:
        raise ValueError(f"cannot fit the clock and mount: only {len(pairs.mocap.start)} "
                         "visible mocap intervals overlap the IMU")
    principal, axes = rate_spread(pairs.mocap.rate)
    if principal[0] < MIN_ROTATION_RATE:
        raise ValueError(f"cannot fit the clock and mount: too little rotation (RMS body rate "
                         f"{principal[0]:.3f} rad/s, expected at least {MIN_ROTATION_RATE})")
    gyro = pairs.gyroscope(coarse_offset, 0.0)
    R_body_imu = mount_from_rates(pairs.mocap.rate, gyro)
    mount = wxyz_from_rotation(Rotation.from_matrix(R_body_imu))
    first = fit_rates(pairs, coarse_offset, 0.0, mount, fit_drift=False)
    duration = float(pairs.mocap.end[-1] - pairs.mocap.start[0])
    window = window_s if window_s is not None else float(np.clip(duration / 10, 5.0, 30.0))
    windows = window_offsets(pairs, first, window)
    fit = first
    if len(windows.offset) >= 3:
        line = drift_from_window_offsets(windows.imu_time, windows.offset, windows.offset_std)
        drifting = fit_rates(pairs, line.offset, line.drift_ppm, first.imu_to_body,
                             gyroscope_bias=first.gyroscope_bias)
        if drifting.drift_std_ppm <= MAX_DRIFT_STD_PPM:
            fit = drifting
        else:
            undetermined["imu_clock_drift_ppm"] = (
                f"drift {drifting.drift_ppm:+.0f} +- {drifting.drift_std_ppm:.0f} ppm over "
                f"{duration:.0f} s is not determined within {MAX_DRIFT_STD_PPM:g} ppm: left at "
                "0 (a longer recording with more rotation measures it)")
    else:
        undetermined["imu_clock_drift_ppm"] = (
            f"only {len(windows.offset)} window(s) of {window:.0f} s with enough rotation: "
            "record at least three to measure the drift (left at 0)")
    if fit.offset_std > MAX_OFFSET_STD_S:
        undetermined["imu_time_offset"] = (
            f"offset uncertainty {fit.offset_std * 1e3:.1f} ms: too little rotation (RMS body "
            f"rate {principal[0]:.2f} rad/s) to time the IMU against the mocap")
    if "imu_time_offset" in undetermined:
        undetermined["imu_to_body"] = CLOCK_UNDETERMINED
    else:
        reason = mount_undetermined(principal, axes, fit)
        if reason is not None:
            undetermined["imu_to_body"] = reason
    return ClockAndMount(fit=fit, windows=windows, coarse_offset=coarse_offset,
                         principal_rates=principal, principal_axes=axes,
                         undetermined=undetermined)


CLOCK_UNDETERMINED: Final = ("not fitted: the clock is undetermined, so gyroscope and mocap "
                             "rates cannot be paired")


def mount_undetermined(principal: Array, axes: Array, fit: RateFit) -> str | None:
    """Why the rates do not determine the mount (None when they do): rotation about one axis
    only (the second principal RMS rate below :data:`MIN_SECOND_AXIS` of the first), or a
    mount 1-sigma above :data:`MAX_MOUNT_STD_DEG` about some body axis."""
    if principal[1] < MIN_SECOND_AXIS * principal[0]:
        axis = np.round(axes[:, 0], 2).tolist()
        return (f"rotation about one axis only (body axis {axis}, RMS {principal[0]:.2f} rad/s; "
                f"the next axis {principal[1]:.3f} rad/s): the mount is undetermined about it")
    if np.max(fit.mount_std_deg) > MAX_MOUNT_STD_DEG:
        return (f"mount uncertainty {np.max(fit.mount_std_deg):.2f} deg exceeds "
                f"{MAX_MOUNT_STD_DEG:g} deg: rotate the limb about more than one axis")
    return None
