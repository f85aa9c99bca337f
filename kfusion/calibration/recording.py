"""Self-calibration of a recording: clock, mount, gravity, lever arm and noise, from the data.

:func:`calibrate_recording` chains the estimators (each in its own module) and collects, for
every quantity, its value, its 1-sigma uncertainty, a fit residual, or the reason the motion does
not determine it. ``kfusion calibrate`` prints and writes its result; ``kfusion check`` runs the
same estimators (:mod:`kfusion.calibration.diagnosis`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kfusion.calibration.clock import Correlation, coarse_clock_offset
from kfusion.calibration.mount import JointMount, joint_mount
from kfusion.calibration.noise import NoiseEstimate, estimate_noise
from kfusion.calibration.rates import (
    CLOCK_UNDETERMINED,
    MAX_DRIFT_STD_PPM,
    MAX_MOUNT_STD_DEG,
    MAX_OFFSET_STD_S,
    MIN_SECOND_AXIS,
    ClockAndMount,
    calibrate_clock_and_mount,
    mount_undetermined,
)
from kfusion.calibration.specific_force import (
    MAX_LEVER_ARM_STD,
    AccelerometerClock,
    SpecificForceFit,
    fit_accelerometer_offset,
    fit_specific_force,
)
from kfusion.conventions import GRAVITY_MAGNITUDE_RANGE, rotation_from_wxyz
from kfusion.profiles import IMU_PROFILES
from kfusion.recording import (
    ImuNoise,
    ImuSamples,
    Recording,
    RecordingInfo,
    without_held_frames,
)

Array = NDArray[np.float64]

GRAVITY_TOLERANCE_DEG = 10.0
"""deg: a given gravity further than this from the fitted one is wrong."""
NOMINAL_GRAVITY = 9.81
"""m/s^2: length written for an estimated gravity (the accelerometer's scale error makes the
fitted length uncertain by about 1 %)."""
MAX_GRAVITY_STD = 0.2
"""m/s^2: a gravity fitted less precisely than this is undetermined."""
ACCELEROMETER_OFFSET_RANGE_S = 0.005
"""s: the accelerometer's offset is used when it lies within this (or 3 sigma of the
gyroscope's offset, if larger) of the gyroscope's: Gauss-Newton from there is only trusted
near its start."""


def angle_between_deg(first: Array, second: Array) -> float:
    """Angle between two vectors, degrees."""
    cosine = float(np.dot(first, second) / (np.linalg.norm(first) * np.linalg.norm(second)))
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


@dataclass(frozen=True)
class SelfCalibration:
    """Result of :func:`calibrate_recording`.

    Attributes:
        correlation: the coarse cross-correlation of rate magnitudes.
        clock_and_mount: the joint rate fit (offset, drift, mount, gyro bias).
        specific_force: gravity, lever arm and accelerometer bias fit (None if impossible).
        noise: noise densities.
        accelerometer_clock: the accelerometer's own timing (None when it could not be fitted
            or was not used; see :func:`accelerometer_timing`).
        mount: the joint mount from rates and specific force (:func:`joint_mount_or_none`;
            None when no specific-force system could be built: the rates' mount is used).
        info: the calibrated ``recording.yaml`` content; ``imu_to_body`` or ``gravity`` are NaN
            when undetermined (then it must not be written).
        undetermined: quantity -> why the motion does not determine it.
    """

    correlation: Correlation
    clock_and_mount: ClockAndMount
    specific_force: SpecificForceFit | None
    noise: NoiseEstimate
    info: RecordingInfo
    undetermined: dict[str, str] = field(default_factory=dict)
    accelerometer_clock: AccelerometerClock | None = None
    mount: JointMount | None = None

    @property
    def imu_time_offset_std(self) -> float:
        """s, 1-sigma of the offset written: the accelerometer's when it was used, else the
        gyroscope's."""
        if self.accelerometer_clock is not None:
            return self.accelerometer_clock.offset_std
        return self.clock_and_mount.fit.offset_std

    @property
    def complete(self) -> bool:
        """True when both required keys (mount and gravity) are determined."""
        return bool(np.isfinite(self.info.imu_to_body).all()
                    and np.isfinite(self.info.gravity).all())

    def report(self) -> list[str]:
        """One line per quantity: value, 1-sigma and fit residual, or why it is undetermined."""
        fit = self.clock_and_mount.fit
        correlation = self.correlation
        lines = [f"clock correlation: peak {correlation.peak:.3f} at "
                 f"{correlation.offset * 1e3:+.1f} ms (next best {correlation.runner_up:.3f} "
                 "more than 0.25 s away)"]

        def line(key: str, text: str) -> None:
            lines.append(f"{key}: " + (f"undetermined: {self.undetermined[key]}"
                                       if key in self.undetermined else text))

        gyroscope = (f"{fit.offset * 1e3:+.3f} ms +- {fit.offset_std * 1e3:.3f} ms (rate "
                     f"residual {fit.residual_rms:.3f} rad/s RMS over {fit.pairs} intervals)")
        accelerometer = self.accelerometer_clock
        if accelerometer is None:
            line("imu_time_offset", gyroscope + ", from the gyroscope")
        else:
            lag = accelerometer.offset - fit.offset
            lag_std = float(np.hypot(accelerometer.offset_std, fit.offset_std))
            relation = (f"the accelerometer is timed {abs(lag) * 1e3:.2f} ms "
                        f"{'earlier' if lag > 0 else 'later'} than the gyroscope"
                        if abs(lag) > 3.0 * lag_std else "the two agree within 3 sigma")
            line("imu_time_offset",
                 f"{accelerometer.offset * 1e3:+.3f} ms +- {accelerometer.offset_std * 1e3:.3f} "
                 f"ms from the accelerometer against the mocap acceleration (specific-force "
                 f"residual {accelerometer.residual_rms:.3f} m/s^2 RMS); the gyroscope gives "
                 f"{gyroscope}: {relation}")
        if accelerometer is not None and np.isfinite(accelerometer.drift_std_ppm):
            line("imu_clock_drift_ppm", f"{accelerometer.drift_ppm:+.1f} +- "
                 f"{accelerometer.drift_std_ppm:.1f} ppm from the accelerometer (the gyroscope's "
                 f"windows did not determine it)")
        else:
            line("imu_clock_drift_ppm", f"{fit.drift_ppm:+.1f} +- {fit.drift_std_ppm:.1f} ppm "
                 f"({len(self.clock_and_mount.windows.offset)} windows)")
        mount = self.mount
        if mount is None:
            std = np.round(fit.mount_std_deg, 3).tolist()
            line("imu_to_body", f"{np.round(fit.imu_to_body, 6).tolist()} +- {std} deg about "
                 f"body x, y, z, from the rates (rate residual {fit.residual_rms:.3f} rad/s "
                 "RMS)")
        else:
            line("imu_to_body", mount_text(mount, fit.imu_to_body, fit.residual_rms))
        lines.append(f"gyroscope bias: {np.round(fit.gyroscope_bias, 4).tolist()} +- "
                     f"{np.round(fit.gyroscope_bias_std, 4).tolist()} rad/s")
        force = self.specific_force
        if force is not None:
            line("gravity", f"{np.round(self.info.gravity, 4).tolist()} m/s^2 (fitted "
                 f"{np.round(force.gravity, 3).tolist()} +- "
                 f"{np.round(force.gravity_std, 3).tolist()}; specific-force residual "
                 f"{force.residual_rms:.3f} m/s^2 RMS, {force.residual_before_rms:.3f} "
                 "without lever arm, bias and scale errors)")
            line("lever_arm", f"{np.round(force.lever_arm * 1e3, 1).tolist()} mm +- "
                 f"{np.round(force.lever_arm_std * 1e3, 1).tolist()} mm")
            lines.append("accelerometer bias: " + (
                f"{np.round(force.accelerometer_bias, 3).tolist()} +- "
                f"{np.round(force.accelerometer_bias_std, 3).tolist()} m/s^2"
                if np.isfinite(force.accelerometer_bias_std).all() else
                "not separable from gravity (too little change of orientation): not fitted"))
            if np.isfinite(force.accelerometer_bias_std).all():
                lines.append("accelerometer scale and misalignment: largest term "
                             f"{100 * np.max(np.abs(force.accelerometer_scale_error)):.2f} % "
                             "(fitted with the bias; not written)")
        else:
            line("gravity", f"{np.round(self.info.gravity, 4).tolist()} m/s^2 as given, not "
                 "checked (no specific-force fit)")
            line("lever_arm", "")
        noise = self.noise
        source = (f"{noise.still_seconds:.1f} s still" if noise.source == "still"
                  else "third differences: no still stretch")
        lines.append(f"imu_noise: accelerometer {noise.accelerometer_noise_density:.3g} "
                     f"m/s^2/sqrt(Hz), gyroscope {noise.gyroscope_noise_density:.3g} "
                     f"rad/s/sqrt(Hz) (from {source})")
        return lines


def _gravity(given: Array, force: SpecificForceFit | None, undetermined: dict[str, str],
             prerequisite: str | None = None) -> Array:
    """The gravity to write: the given one checked against the fit, else the fit's direction
    at :data:`NOMINAL_GRAVITY`. ValueError when a given gravity contradicts the data. Without a
    fit (``prerequisite``: the undetermined quantity it needs) a given gravity is kept
    unchecked and an absent one is undetermined."""
    if force is None:
        if not np.isfinite(given).all():
            undetermined["gravity"] = (f"not fitted: {prerequisite} is undetermined"
                                       if prerequisite else
                                       "no visible mocap run long enough to fit it")
        return given
    fitted = force.gravity
    low, high = GRAVITY_MAGNITUDE_RANGE
    magnitude = float(np.linalg.norm(fitted))
    if np.isfinite(given).all():
        angle = angle_between_deg(given, fitted)
        if angle > GRAVITY_TOLERANCE_DEG:
            raise ValueError(f"gravity {np.round(given, 3).tolist()} from recording.yaml is "
                             f"{angle:.0f} deg from the data's {np.round(fitted, 2).tolist()}: "
                             "fix it or remove it to estimate it")
        return given
    if np.max(force.gravity_std) > MAX_GRAVITY_STD or not 0.8 * low <= magnitude <= 1.2 * high:
        undetermined["gravity"] = (f"fitted {np.round(fitted, 2).tolist()} +- "
                                   f"{np.round(force.gravity_std, 2).tolist()} m/s^2 is not "
                                   "credible: give gravity in recording.yaml or --gravity")
        return np.full(3, np.nan)
    return np.asarray(fitted / magnitude * NOMINAL_GRAVITY)


def calibrate_recording(recording: Recording, *, max_offset: float = 5.0) -> SelfCalibration:
    """Every quantity kfusion can observe in ``recording`` (its info's mount is ignored; a
    finite ``info.gravity`` is checked, a NaN one estimated; the clock fields are ignored).

    Order: coarse clock (rate magnitudes); clock, drift, rates' mount and gyroscope bias
    (:func:`calibrate_clock_and_mount`); the mount from rates and specific force at the
    gyroscope's clock (:func:`joint_mount_or_none`); the accelerometer's clock at that mount
    (:func:`accelerometer_timing`) and the joint mount again at it; gravity, lever arm and
    accelerometer bias at the final mount and clock; noise. The mount is undetermined when the
    clock is, or when its weakest axis's 1-sigma exceeds ``MAX_MOUNT_STD_DEG``
    (:func:`joint_mount_undetermined` says which axis and why).

    Raises ValueError when the clocks cannot be correlated (no overlap, no rotation) or a
    given gravity contradicts the data.
    """
    recording, _ = without_held_frames(recording)  # poses held through occlusions
    correlation = coarse_clock_offset(recording, max_offset=max_offset)
    clock_and_mount = calibrate_clock_and_mount(recording, correlation.offset)
    fit = clock_and_mount.fit
    undetermined = dict(clock_and_mount.undetermined)
    # the accelerometer is timed at the rates' mount when the rates determine it, else at the
    # mount from rates and specific force at the gyroscope's clock; the mount written is the
    # joint one at the accelerometer's clock
    systematic = triad_misalignment_deg(recording.info.imu)
    mount: JointMount | None = None
    if clock_and_mount.undetermined.get("imu_to_body",
                                        CLOCK_UNDETERMINED) == CLOCK_UNDETERMINED:
        accelerometer = accelerometer_timing(recording, clock_and_mount)
    else:
        mount = joint_mount_or_none(recording, fit.offset, fit.drift_ppm, clock_and_mount,
                                    systematic_deg=systematic)
        known = mount is not None and mount.weakest_std_deg <= MAX_MOUNT_STD_DEG
        accelerometer = accelerometer_timing(
            recording, clock_and_mount, mount.imu_to_body if mount is not None and known
            else None)
    offset, drift = fit.offset, fit.drift_ppm
    if accelerometer is not None:
        offset, drift = accelerometer.offset, accelerometer.drift_ppm
        undetermined.pop("imu_time_offset", None)
        if np.isfinite(accelerometer.drift_std_ppm):
            undetermined.pop("imu_clock_drift_ppm", None)
    if "imu_time_offset" not in undetermined and (accelerometer is not None or mount is None):
        mount = joint_mount_or_none(recording, offset, drift, clock_and_mount,
                                    start=None if mount is None else mount.imu_to_body,
                                    systematic_deg=systematic)
    if "imu_time_offset" in undetermined:
        undetermined["imu_to_body"] = CLOCK_UNDETERMINED
    else:
        undetermined.pop("imu_to_body", None)
        reason = (mount_undetermined(clock_and_mount.principal_rates,
                                     clock_and_mount.principal_axes, fit) if mount is None
                  else joint_mount_undetermined(mount, clock_and_mount))
        if reason is not None:
            undetermined["imu_to_body"] = reason
    imu_to_body = fit.imu_to_body if mount is None else mount.imu_to_body
    # the specific force is rotated through the mount at the fitted clock: with either
    # undetermined, the fitted gravity would be an artefact of a wrong mount (a still limb's
    # Kabsch "mount" is noise), so neither check nor estimate it
    prerequisite = next((key for key in ("imu_time_offset", "imu_to_body")
                         if key in undetermined), None)
    force: SpecificForceFit | None = None
    if prerequisite is None:
        try:
            force = fit_specific_force(recording, offset, drift, imu_to_body)
        except ValueError:
            force = None
    gravity = _gravity(np.asarray(recording.info.gravity, dtype=float), force, undetermined,
                       prerequisite)
    lever_arm = None
    if force is not None and np.max(force.lever_arm_std) <= MAX_LEVER_ARM_STD:
        lever_arm = force.lever_arm
    elif force is not None:
        undetermined["lever_arm"] = (
            f"fitted {np.round(force.lever_arm * 1e3, 1).tolist()} +- "
            f"{np.round(force.lever_arm_std * 1e3, 1).tolist()} mm: too little angular "
            f"acceleration to pin it within {MAX_LEVER_ARM_STD * 1e3:g} mm (not written)")
    elif prerequisite is not None:
        undetermined["lever_arm"] = f"not fitted: {prerequisite} is undetermined"
    else:
        undetermined["lever_arm"] = "no visible mocap run long enough to fit it"
    noise = estimate_noise(recording.imu)
    info = RecordingInfo(
        imu_to_body=np.full(4, np.nan) if "imu_to_body" in undetermined else imu_to_body,
        gravity=gravity, name=recording.info.name, imu=recording.info.imu,
        lever_arm=lever_arm,
        imu_time_offset=0.0 if "imu_time_offset" in undetermined else offset,
        imu_clock_drift_ppm=0.0 if "imu_clock_drift_ppm" in undetermined else drift,
        imu_noise=ImuNoise(accelerometer_noise_density=noise.accelerometer_noise_density,
                           gyroscope_noise_density=noise.gyroscope_noise_density),
        markers=recording.info.markers)
    return SelfCalibration(correlation=correlation, clock_and_mount=clock_and_mount,
                           specific_force=force, noise=noise, info=info,
                           undetermined=undetermined, accelerometer_clock=accelerometer,
                           mount=mount)


def accelerometer_timing(recording: Recording, clock_and_mount: ClockAndMount,
                         imu_to_body: Array | None = None) -> AccelerometerClock | None:
    """The accelerometer's clock offset (:func:`fit_accelerometer_offset`), started at the
    gyroscope's, when it is usable, else None.

    Usable: the mount is known well enough to rotate the specific force (``imu_to_body``, the
    joint mount, when given; else the rates' mount, undetermined, if at all, only because the
    gyroscope could not time the clock), the fit converges to within
    :data:`MAX_OFFSET_STD_S` (1-sigma) and stays within :data:`ACCELEROMETER_OFFSET_RANGE_S`
    (or 3 sigma of the gyroscope's offset) of where it started. The filter dead-reckons the
    position with the accelerometer, so its timing is the one written: it is also the better
    determined one on slow rotations (simulated arm lift: +-0.2-0.3 ms against +-7-9 ms from
    the gyroscope).

    The drift: the gyroscope's when it determined it (kept fixed; ``drift_std_ppm`` NaN);
    else fitted with the offset, and when that is not within :data:`MAX_DRIFT_STD_PPM` either,
    the offset is refitted at the gyroscope's drift (0 then: the recording's mean offset)."""
    fit = clock_and_mount.fit
    if imu_to_body is None:
        if clock_and_mount.undetermined.get("imu_to_body",
                                            CLOCK_UNDETERMINED) != CLOCK_UNDETERMINED:
            return None
        imu_to_body = fit.imu_to_body
    fit_drift = "imu_clock_drift_ppm" in clock_and_mount.undetermined
    try:
        accelerometer = fit_accelerometer_offset(recording, fit.offset, fit.drift_ppm,
                                                 imu_to_body, fit_drift=fit_drift)
        if fit_drift and not accelerometer.drift_std_ppm <= MAX_DRIFT_STD_PPM:
            accelerometer = fit_accelerometer_offset(recording, fit.offset, fit.drift_ppm,
                                                     imu_to_body)
    except ValueError:
        return None
    reach = max(ACCELEROMETER_OFFSET_RANGE_S, 3.0 * fit.offset_std)
    if not (accelerometer.converged and np.isfinite(accelerometer.offset_std)
            and accelerometer.offset_std <= MAX_OFFSET_STD_S
            and abs(accelerometer.offset - fit.offset) <= reach):
        return None
    return accelerometer


def triad_misalignment_deg(profile_name: str | None) -> float:
    """deg, 1-sigma per axis of the rotation between the accelerometer's axes and the IMU's
    nominal frame that no fit can separate from the mount: the antisymmetric part of a
    cross-axis matrix with entries of 1-sigma ``c`` (the named profile's
    ``accelerometer_cross_axis``), ``(C_ij - C_ji) / 2``, has 1-sigma ``c / sqrt(2)`` rad. 0
    without a known profile."""
    profile = IMU_PROFILES.get(profile_name or "")
    if profile is None:
        return 0.0
    return float(np.degrees(profile.accelerometer_cross_axis / np.sqrt(2.0)))


def joint_mount_or_none(recording: Recording, offset: float, drift_ppm: float,
                        clock_and_mount: ClockAndMount, *, start: Array | None = None,
                        systematic_deg: float = 0.0) -> JointMount | None:
    """:func:`kfusion.calibration.mount.joint_mount` from the rate fit's mount and information,
    or None when the specific force gives no system (no visible run long enough)."""
    fit = clock_and_mount.fit
    try:
        return joint_mount(recording, offset, drift_ppm, fit.imu_to_body,
                           fit.mount_information, start=start, systematic_deg=systematic_deg)
    except ValueError:
        return None


def joint_mount_undetermined(mount: JointMount, clock_and_mount: ClockAndMount) -> str | None:
    """Why rates and specific force together leave the mount undetermined (None when they
    do not): the weakest axis's 1-sigma above :data:`MAX_MOUNT_STD_DEG`, with what each source
    saw about that axis (the rates: whether the limb turned about one axis only; the specific
    force: how far its direction moved in the body frame)."""
    if mount.weakest_std_deg <= MAX_MOUNT_STD_DEG:
        return None
    principal = clock_and_mount.principal_rates
    axis = np.round(mount.weakest_axis, 2).tolist()
    if principal[1] < MIN_SECOND_AXIS * principal[0]:
        turned = np.round(clock_and_mount.principal_axes[:, 0], 2).tolist()
        rates = (f"the limb turned about one axis only (body axis {turned}, RMS "
                 f"{principal[0]:.2f} rad/s; the next axis {principal[1]:.3f} rad/s)")
    else:
        rates = f"the rates alone pin it to {mount.rate_only_deg[0]:.2f} deg"
    force = mount.force
    direction = np.round(force.force_body, 2).tolist()
    forces = (f"the specific force stayed near body direction {direction} (RMS "
              f"{force.spread_deg:.1f} deg of change), which pins it to "
              f"{mount.force_only_deg[0]:.2f} deg")
    return (f"the mount is undetermined about body axis {axis} (1-sigma "
            f"{mount.weakest_std_deg:.2f} deg, above {MAX_MOUNT_STD_DEG:g} deg): {rates}; "
            f"{forces}")


def mount_text(mount: JointMount, rate_mount: Array, rate_residual: float) -> str:
    """The report's mount line: value, 1-sigma about body x, y, z, and how the rates' and the
    specific force's own estimates compare."""
    rate_angle = float(np.degrees((rotation_from_wxyz(rate_mount).inv()
                                   * rotation_from_wxyz(mount.imu_to_body)).magnitude()))
    agreement = (f"they disagree beyond their noise (chi2 {mount.chi2:.0f} for {mount.dof} "
                 f"dof): 1-sigma scaled by {mount.birge:.1f}" if mount.birge > 1.0 else
                 f"they agree (chi2 {mount.chi2:.1f} for {mount.dof} dof)")
    systematic = (f", including {mount.systematic_deg:.2f} deg for the accelerometer's own "
                  "axis misalignment (its profile's cross-axis figure)"
                  if mount.systematic_deg > 0 else "")
    return (f"{np.round(mount.imu_to_body, 6).tolist()} +- "
            f"{np.round(mount.std_deg, 3).tolist()} deg about body x, y, z{systematic}, from "
            f"rates and specific force together (rates alone: {rate_angle:.2f} deg away, rate "
            "residual "
            f"{rate_residual:.3f} rad/s RMS; specific-force residual "
            f"{mount.force.residual_rms:.3f} m/s^2 RMS); {agreement}")


def without_calibration(recording: Recording) -> Recording:
    """The recording as ``imu.csv`` and ``mocap.csv`` alone describe it: mount and gravity
    unknown (NaN), no lever arm, clock fields 0, no measured noise (benchmarks and the notebook
    calibrate from this)."""
    return dataclasses.replace(recording, info=dataclasses.replace(
        recording.info, imu_to_body=np.full(4, np.nan), gravity=np.full(3, np.nan),
        lever_arm=None, imu_time_offset=0.0, imu_clock_drift_ppm=0.0, imu_noise=None))


def restamped(recording: Recording, offset: float, drift_ppm: float) -> Recording:
    """The IMU stamps re-expressed on a clock with ``t_mocap = (1 + drift_ppm 1e-6) t' +
    offset``: ``t' = (t - offset) / (1 + drift_ppm 1e-6)`` (an artificial clock error put on
    a recording whose clocks agree)."""
    imu = recording.imu
    stamps = (imu.t - offset) / (1.0 + drift_ppm * 1e-6)
    return dataclasses.replace(recording, imu=ImuSamples(stamps, imu.accelerometer,
                                                         imu.gyroscope))
