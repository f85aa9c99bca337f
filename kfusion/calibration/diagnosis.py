"""Does a recording agree with itself? The consistency diagnosis of ``kfusion check``.

Run on the recording as its ``recording.yaml`` describes it (clock model applied), with the
self-calibration's estimators (:mod:`kfusion.calibration`), in this order, stopping at the first
mistake found (later tests assume the earlier ones passed):

0. markers: with ``markers.csv`` and ``markers:``, each marker where ``recording.yaml`` puts it
   on ``mocap.csv``'s rigid body (:func:`kfusion.calibration.marker_fit.marker_problem`);
1. time units: one stream's time span about 1000 times the other's (ms instead of s);
2. time overlap of the IMU and the mocap;
   then a note for each IMU sensor that clips below its profile's range (a flat top,
   :func:`kfusion.kalman.model.clipping_levels`); the frames within :data:`CLIPPED_MARGIN_S` of a
   clipped sample are left out of the tests below, whose rates and accelerations the clipped
   samples would bend (a gyroscope flat at 250 dps on a fast trial read as a 25 ms clock
   offset);
3. quaternion order: the rate-magnitude correlation is much better with the mocap quaternion
   columns read as x, y, z, w;
4. clock: the correlation's peak more than :data:`CLOCK_TOLERANCE_S` from zero;
5. mount: the Kabsch mount from paired rates more than :data:`MOUNT_TOLERANCE_DEG` from
   ``imu_to_body``;
6. gravity: the least-squares gravity more than :data:`GRAVITY_TOLERANCE_DEG` from ``gravity``
   (a flipped sign, a wrong axis), or its length far from 9.81 (units);
7. fine clock, by the accelerometer (the sensor the filter dead-reckons with, and the one that
   times a slow rotation the gyroscope cannot): its offset against the mocap's acceleration
   (:func:`kfusion.calibration.specific_force.fit_accelerometer_offset`) more than
   :data:`FINE_CLOCK_TOLERANCE_S` (plus :data:`OFFSET_SIGMAS` sigma) from zero;
8. drift: fitted with that offset, a drift the recording does not describe that moves the
   clock by more than :data:`FINE_CLOCK_TOLERANCE_S` across the motion that times it
   (:func:`informative_time_spread`: a drift matters where the limb moves, and is only
   measured there), beyond :data:`DRIFT_SIGMAS` sigma with the accelerometer's systematic
   timing error included (:func:`drift_std_with_timing_floor`), or beyond that many of the
   fit's own sigma and confirmed by the motion's two halves timed apart
   (:func:`confirming_halves`).

The IMU stamps are mapped by the recording's clock model and, when given, shifted by the
filter's ``imu_latency_s`` (``kfusion track`` passes it), so the clock tested is the one the
estimators will use.

Each finding is one line naming the likely mistake and the fix. A test the motion cannot decide
(too little rotation, say) is a note, not a finding.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Final

import numpy as np
from scipy.spatial.transform import Rotation

from kfusion.calibration.clock import Correlation, coarse_clock_offset
from kfusion.calibration.marker_fit import marker_problem
from kfusion.calibration.rates import (
    MAX_OFFSET_STD_S,
    MIN_ROTATION_RATE,
    MIN_SECOND_AXIS,
    mount_from_rates,
    rate_pairs,
    rate_spread,
)
from kfusion.calibration.recording import GRAVITY_TOLERANCE_DEG, angle_between_deg
from kfusion.calibration.specific_force import (
    CUTOFF_HZ,
    MAX_BIAS_STD,
    UNKNOWNS,
    fit_accelerometer_offset,
    fit_specific_force,
    residual_correlation,
    solve_specific_force,
    specific_force_system,
)
from kfusion.conventions import (
    STANDARD_GRAVITY,
    matrix_from_wxyz,
    median_interval,
    rotation_from_wxyz,
)
from kfusion.kalman import model
from kfusion.recording import (
    ImuSamples,
    MocapFrames,
    Recording,
    on_mocap_clock,
    without_held_frames,
)

CLIPPED_MARGIN_S: Final = 0.1
"""s: mocap frames this close to a clipped IMU sample are left out of the consistency tests (the
rate and acceleration estimators span a few frames, and the clock may be off by tens of ms)."""
CLOCK_TOLERANCE_S: Final = 0.010
"""s: a coarse (rate-correlation) clock offset beyond this is reported (1 m/s of arm speed
turns 10 ms into 10 mm)."""
FINE_CLOCK_TOLERANCE_S: Final = 0.002
"""s: an accelerometer-timed offset (or its change over the recording) beyond this is reported.
A residual offset of 3 ms already puts about 3 % of a simulated reach's gap rows outside the
Tracker's 99 % bound (5 ms: 6 %), against 1 % when the clock is right; BROAD's accelerometer
times within 1.2 ms of the reader's -3 ms on every trial."""
MOUNT_TOLERANCE_DEG: Final = 5.0
"""deg: a mount error beyond this is reported (5 deg of tilt leaks 0.85 m/s^2 of gravity)."""
MIN_CORRELATION: Final = 0.8
"""Peak correlation below which the clock test is not decided (2 s of a still IMU's noise
correlate up to about 0.55 somewhere)."""
MIN_PEAK_MARGIN: Final = 0.15
"""The peak must beat the best correlation more than 0.25 s away by this much (a unique
match), unless it reaches :data:`CLEAR_CORRELATION` (periodic motion repeats its pattern)."""
CLEAR_CORRELATION: Final = 0.95
MAX_RATE_MISFIT: Final = 0.3
MIN_MOUNT_MISFIT_EXCESS: Final = 0.1
"""How much worse (as a fraction of the RMS body rate) the stated mount must fit the rates than
the best fit before check calls it wrong: a 10 deg mount error gives about 0.17."""
"""Relative RMS misfit of the rates under the best mount above which the mocap orientations
do not match the gyroscope at all (the quaternion order test)."""
MIN_GRAVITY_SECONDS: Final = 5.0
"""s: visible mocap needed (after trimming run ends) to test gravity."""
UNITS_RATIO: Final = (300.0, 3000.0)
"""A stream whose time span is this many times the other's was written in ms."""
MS_MEDIAN_STEP: Final = 0.5
"""Median step (in the file's unit) from which a stream's times read as ms: a stream of 2 Hz or
more has a step below it in seconds, one of 2 kHz or less a step above it in ms."""
OFFSET_SIGMAS: Final = 2.0
"""The accelerometer's offset is reported only beyond the tolerance plus this many sigma (a
short or slow recording times it loosely: 2.5 +- 1.3 ms on a 20 s simulated reach)."""
SYSTEMATIC_TIMING_S: Final = 1e-3
"""s, 1-sigma: how much the accelerometer's timing against the mocap's acceleration wanders
with the motion. Timed in 10 s windows on the same clock, BROAD's trials scatter by 0.14-0.63 ms
(standard deviation per trial; single windows up to 2.4 ms off) against the fit's 1-sigmas of
0.1-0.4 ms. It limits the drift :func:`fine_clock_problem` can find to about
``4e6 sigma_sys / T`` ppm: 900 ppm on a 15 s simulated reach, 250 ppm on 60 s (a drift of 600
ppm over 20 s, missed, leaves 2-3 % of rows beyond the 99 % bound, up to 1.8x)."""
DRIFT_SIGMAS: Final = 4.0
"""A drift is reported only beyond this many sigma (and when it moves the clock by more than
:data:`FINE_CLOCK_TOLERANCE_S` across the motion, :func:`drift_clock_change`)."""
CALIBRATE_FIX: Final = "run kfusion calibrate DIR --out DIR/recording.yaml --force"


@dataclass(frozen=True)
class Diagnosis:
    """Result of :func:`diagnose`.

    Attributes:
        problems: one line per mistake found (empty: the recording agrees with itself).
        notes: tests that were passed, or that the motion could not decide.
        correlation: the clock correlation (None if not reached).
    """

    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    correlation: Correlation | None = None

    @property
    def ok(self) -> bool:
        return not self.problems


def clipped_samples(imu: ImuSamples) -> tuple[np.ndarray, list[str]]:
    """IMU samples (n,) bool on a plateau of either sensor (an axis at
    :data:`~kfusion.kalman.model.PLATEAU_TOLERANCE` of the level :func:`kfusion.kalman.model.
    clipping_levels` finds for it, or beyond), and one note per clipping sensor naming its
    largest level."""
    clipped = np.zeros(len(imu.t), dtype=bool)
    notes = []
    for name, values, floor, unit, other, scale in (
            ("accelerometer", imu.accelerometer, model.PLATEAU_FLOOR_ACCELEROMETER, "m/s^2",
             "g", 1.0 / STANDARD_GRAVITY),
            ("gyroscope", imu.gyroscope, model.PLATEAU_FLOOR_GYROSCOPE, "rad/s", "dps",
             180.0 / np.pi)):
        levels = model.clipping_levels(values, floor)
        if not levels.any():
            continue
        level = float(levels.max())
        flat = ((np.abs(values) >= model.PLATEAU_TOLERANCE * levels) & (levels > 0)).any(axis=1)
        clipped |= flat
        notes.append(f"{name} clips at {level:.3g} {unit} ({level * scale:.3g} {other}) on "
                     f"{int(flat.sum())} samples ({flat.mean():.1%}): a flat top below the "
                     "profile's range; kfusion track saturates those samples, as if that "
                     "range were declared")
    return clipped, notes


def without_frames_near(recording: Recording, times: np.ndarray, margin: float) -> Recording:
    """``recording`` with its mocap frames within ``margin`` s of any of ``times`` (s, sorted)
    occluded (position and quaternion NaN)."""
    mocap = recording.mocap
    after = np.searchsorted(times, mocap.t - margin, side="left")
    near = (after < len(times)) & (times[np.minimum(after, len(times) - 1)] <= mocap.t + margin)
    position, quaternion = np.array(mocap.position), np.array(mocap.quaternion)
    position[near], quaternion[near] = np.nan, np.nan
    return recording.with_mocap(dataclasses.replace(mocap, position=position,
                                                    quaternion=quaternion))


def _span(t: np.ndarray) -> float:
    return float(t[-1] - t[0]) if len(t) > 1 else 0.0


def time_unit_problem(recording: Recording) -> str | None:
    """A message when one stream's time span is ~1000 times the other's and its median step,
    read as seconds, is at least :data:`MS_MEDIAN_STEP` (a stream stopping early, e.g. an
    imu.csv of 2 rows, has a short span but a step in seconds), else None."""
    imu, mocap = _span(recording.imu.t), _span(recording.mocap.t)
    low, high = UNITS_RATIO
    if mocap > 0 and low <= imu / mocap <= high \
            and median_interval(recording.imu.t) >= MS_MEDIAN_STEP:
        return (f"IMU time looks like ms: imu.csv spans {imu:.6g} against the mocap's "
                f"{mocap:.6g} s: divide imu.csv's t by 1000")
    if imu > 0 and low <= mocap / imu <= high \
            and median_interval(recording.mocap.t) >= MS_MEDIAN_STEP:
        return (f"mocap time looks like ms: mocap.csv spans {mocap:.6g} against the IMU's "
                f"{imu:.6g} s: divide mocap.csv's t by 1000")
    return None


def _seconds(value: float) -> str:
    """A time for a message: 3 decimals, or 6 significant digits when that would be long (a
    time of 1e300 printed 300 digits)."""
    return f"{value:.3f}" if abs(value) < 1e9 else f"{value:.6g}"


def overlap_seconds(recording: Recording) -> float:
    """Length of the common time span of the IMU and the visible mocap, s (<= 0: none)."""
    visible = recording.mocap.t[recording.mocap.visible]
    if len(visible) == 0:
        return 0.0
    return float(min(recording.imu.t[-1], visible[-1]) - max(recording.imu.t[0], visible[0]))


def relative_rate_misfit(rate_body: np.ndarray, rate_imu: np.ndarray,
                         R: np.ndarray | None = None) -> float:
    """``RMS|w_body - R w_imu| / RMS|w_body|`` under the mount R (default: the Kabsch fit);
    0 is a perfect match. Shapes: rates (n, 3) rad/s, R (3, 3)."""
    if R is None:
        R = mount_from_rates(rate_body, rate_imu)
    misfit = rate_body - rate_imu @ R.T
    return float(np.sqrt(np.mean(np.sum(misfit**2, axis=1)) / np.mean(np.sum(rate_body**2,
                                                                            axis=1))))


def _reordered(recording: Recording) -> Recording:
    """The recording with the mocap quaternion columns read as x, y, z, w."""
    mocap = recording.mocap
    quaternion = mocap.quaternion[:, [3, 0, 1, 2]]
    return recording.with_mocap(MocapFrames(t=mocap.t, position=mocap.position,
                                            quaternion=quaternion))


def _side(offset: float) -> str:
    return "behind" if offset > 0 else "ahead of"


def timing_rows(design: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row of :func:`specific_force_system`'s design (built with ``drift_shift``): how much
    it times the clock, ``w_i = |s_i|^2`` ((m/s^2 per s)^2), and its IMU time from the
    reference, ``tau_i - tau_m = 1e6 s_i . d_i / |s_i|^2`` (s), with ``s_i = A[i, :, c]`` the
    time-shift column and ``d_i = A[i, :, c + 1] = s_i (tau_i - tau_m) 1e-6`` the drift
    column (per ppm). Shapes: design (k, 3, >= c + 2); both results (k,)."""
    shift, drift = design[:, :, UNKNOWNS], design[:, :, UNKNOWNS + 1]
    weight = np.sum(shift * shift, axis=1)
    time = 1e6 * np.sum(shift * drift, axis=1) / np.where(weight > 0, weight, 1.0)
    return weight, time


def informative_time_spread(design: np.ndarray) -> float:
    """Spread (s) of the times that time the accelerometer, each weighted by how much it times
    it (:func:`timing_rows`): ``T^2 = sum w_i (tau_i - tau_w)^2 / sum w_i``, ``tau_w`` the
    weighted mean. A motion spread evenly over L seconds gives L / sqrt(12); a recording still
    for 20 s and moving for 10 s gives about 3 s, not 9. 0 when nothing times the clock."""
    weight, time = timing_rows(design)
    if not float(np.sum(weight)) > 0:
        return 0.0
    mean = float(np.average(time, weights=weight))
    return float(np.sqrt(np.average((time - mean) ** 2, weights=weight)))


def drift_clock_change(drift_ppm: float, spread_s: float) -> float:
    """How far (s) a drift moves the clock across the motion that times it: ``d 1e-6 2 T``,
    ``T`` the weighted spread of :func:`informative_time_spread` (the clock's change between
    one sigma before and one sigma after the motion's weighted middle)."""
    return drift_ppm * 1e-6 * 2.0 * spread_s


def drift_std_with_timing_floor(drift_std_ppm: float, spread_s: float) -> float:
    """The drift's 1-sigma (ppm) with the accelerometer's systematic timing error included:
    ``sqrt(sigma_d^2 + (1e6 sigma_sys / T)^2)``, ``sigma_sys`` =
    :data:`SYSTEMATIC_TIMING_S`, ``T`` the weighted spread of the times that time the clock
    (:func:`informative_time_spread`; inf when it is 0). A timing error that wanders with the
    motion by ``sigma_sys`` tilts a line fitted through times spread by ``T`` by about
    ``sigma_sys / T``; the fit's own 1-sigma, which treats the residuals as noise, does not
    see it."""
    if not spread_s > 0:
        return float("inf")
    return float(np.hypot(drift_std_ppm, 1e6 * SYSTEMATIC_TIMING_S / spread_s))


@dataclass(frozen=True)
class HalfOffsets:
    """The accelerometer's clock offset (s) timed separately on the earlier and the later half
    of the motion (:func:`half_offsets`), with 1-sigmas (s)."""

    first: float
    first_std: float
    second: float
    second_std: float

    @property
    def change(self) -> float:
        """``second - first``, s."""
        return self.second - self.first

    @property
    def change_std(self) -> float:
        return float(np.hypot(self.first_std, self.second_std))


def half_offsets(y: np.ndarray, design: np.ndarray, correlation: float) -> HalfOffsets | None:
    """One Gauss-Newton step of the offset alone on each half of the rows, split at the
    weighted median time (:func:`timing_rows`), on a system built without drift: a drift
    shows as ``change = second - first ~ d 1e-6 (tau_2 - tau_1)``. Each half has its own
    gravity, lever arm and bias, so model error that the drift column of one joint fit can
    absorb (error correlated with ``(tau - tau_m) f'``) does not pass for a drift here. None
    when a half does not determine its accelerometer bias (1-sigma above ``MAX_BIAS_STD``):
    without it, a half's offset absorbs the bias. Shapes: y (k, 3), design (k, 3, >= c + 2).
    Linear in the offset: a drift that moves the clock by tens of ms within a half is the
    joint fit's to find."""
    weight, time = timing_rows(design)
    order = np.argsort(time)
    cumulative = np.cumsum(weight[order])
    split = time[order][min(int(np.searchsorted(cumulative, 0.5 * cumulative[-1])),
                            len(order) - 1)]
    found = []
    for rows in (time < split, time >= split):
        system = design[rows][:, :, :UNKNOWNS + 1]
        x, covariance, _ = solve_specific_force(y[rows], system, correlation=correlation)
        if not np.max(np.sqrt(np.diag(covariance)[6:9])) <= MAX_BIAS_STD:
            return None
        found += [float(x[UNKNOWNS]), float(np.sqrt(max(covariance[UNKNOWNS, UNKNOWNS], 0.0)))]
    return HalfOffsets(*found)


def confirming_halves(y: np.ndarray, design: np.ndarray, drift_ppm: float,
                      correlation: float) -> HalfOffsets | None:
    """The motion's two halves timed apart without a drift (:func:`half_offsets` on ``y``,
    ``design``, built without drift) when they move the clock the way ``drift_ppm`` does by
    more than :data:`OFFSET_SIGMAS` sigma; None when they do not confirm it."""
    halves = half_offsets(y, design, correlation)
    if halves is not None and np.sign(halves.change) == np.sign(drift_ppm) and (
            abs(halves.change) > OFFSET_SIGMAS * halves.change_std):
        return halves
    return None


def accelerometer_clock_finding(offset: float, std: float, over: str = "") -> str | None:
    """Test 7's rule on an accelerometer timing of ``offset`` +- ``std`` s (positive: the IMU
    clock behind the mocap): beyond :data:`FINE_CLOCK_TOLERANCE_S` plus :data:`OFFSET_SIGMAS`
    sigma, the finding's words ("IMU clock about 9.9 ms behind the mocap (timed ...)"), else
    None. ``over`` names the data timed (e.g. " over the last 5 s"). Shared by ``kfusion
    check`` and the Tracker's online watch (:mod:`kfusion.clockwatch`)."""
    if abs(offset) <= FINE_CLOCK_TOLERANCE_S + OFFSET_SIGMAS * std:
        return None
    return (f"IMU clock about {abs(offset) * 1e3:.1f} ms {_side(offset)} the mocap (timed by "
            f"the accelerometer against the mocap's acceleration{over}, +- {std * 1e3:.1f} ms)")


def fine_clock_problem(recording: Recording, start: float, notes: list[str]) -> str | None:
    """Tests 7 and 8 of the module docstring on a recording on the mocap clock whose mount and
    gravity passed: the finding, or None (with a note of what was measured or why not).

    One Gauss-Newton fit of the accelerometer's offset and drift from ``start`` (s)
    (:func:`kfusion.calibration.specific_force.fit_accelerometer_offset`): the offset at the
    recording's middle must be within :data:`FINE_CLOCK_TOLERANCE_S` of zero, and a drift
    beyond :data:`DRIFT_SIGMAS` sigma must not move the clock by more than that across the
    motion that times it (:func:`drift_clock_change`), with a 1-sigma that includes the
    accelerometer's systematic timing error (:func:`drift_std_with_timing_floor`). Without
    those two, the first 30 s of BROAD trials 01 and 21 (still, then moving) were refused for
    a drift of 150-310 +- 24-38 ppm, "8 ms over the recording", that the full trials do not
    have (within 3 ppm)."""
    try:
        found = fit_accelerometer_offset(recording, start, 0.0, recording.info.imu_to_body,
                                         fit_drift=True, max_iterations=8)
    except ValueError:
        found = None
    if found is None or not (found.converged and found.middle_offset_std <= MAX_OFFSET_STD_S):
        notes.append("clock not timed by the accelerometer: too little acceleration, or no "
                     "visible mocap run long enough")
        return None
    offset, std = found.middle_offset, found.middle_offset_std
    finding = accelerometer_clock_finding(offset, std)
    if finding is not None:
        return f"{finding}: {CALIBRATE_FIX}"
    # one system, linearised at the middle offset without drift: the halves are timed on it,
    # and its rows' weights and times give the spread (they hardly depend on the drift)
    middle = 0.5 * float(recording.imu.t[0] + recording.imu.t[-1])
    y, design = specific_force_system(recording, found.middle_offset, 0.0,
                                      recording.info.imu_to_body, time_shift=True,
                                      drift_shift=True, reference_time=middle)
    spread = informative_time_spread(design)
    drift = found.drift_ppm
    drift_std = drift_std_with_timing_floor(found.drift_std_ppm, spread)
    change = drift_clock_change(drift, spread)
    if abs(change) > FINE_CLOCK_TOLERANCE_S:
        stated = f"{change * 1e3:+.1f} ms across the motion"
        if abs(drift) > DRIFT_SIGMAS * drift_std:
            return (f"IMU clock drifts about {drift:+.0f} +- {drift_std:.0f} ppm against the "
                    f"mocap ({stated}; recording.yaml says 0): {CALIBRATE_FIX}")
        halves = (confirming_halves(y, design, drift,
                                    residual_correlation(recording.mocap.t, CUTOFF_HZ))
                  if abs(drift) > DRIFT_SIGMAS * found.drift_std_ppm else None)
        if halves is not None:
            return (f"IMU clock drifts about {drift:+.0f} +- {found.drift_std_ppm:.0f} ppm "
                    f"against the mocap ({stated}; the motion's two halves are timed "
                    f"{halves.change * 1e3:+.1f} +- {halves.change_std * 1e3:.1f} ms apart; "
                    f"recording.yaml says 0): {CALIBRATE_FIX}")
    notes.append(f"clock (accelerometer): offset {offset * 1e3:+.2f} ms +- {std * 1e3:.2f} ms, "
                 f"drift {drift:+.0f} +- {drift_std:.0f} ppm")
    return None


def diagnose(recording: Recording, *, imu_latency_s: float = 0.0) -> Diagnosis:
    """The consistency tests of the module docstring on ``recording`` (as described by its
    info), with the IMU's events ``imu_latency_s`` (s) earlier than its mapped stamps, as the
    filter takes them (:func:`kfusion.kalman.events.imu_event_time`).

    Frames that repeat a recent frame's pose bit for bit are read as occluded first, as every
    path reads them (:func:`kfusion.recording.held_frames`: their steps would be read as
    motion); the diagnosis says so in a note, and after its first problem when it finds one
    (with most frames held, what is left may not be enough)."""
    visible = int(recording.mocap.visible.sum())
    recording, held = without_held_frames(recording)
    diagnosis = _diagnose(recording, imu_latency_s)
    if not held:
        return diagnosis
    text = (f"{held} of {visible} visible mocap frames repeat a recent frame's pose bit for "
            "bit (a client holding the last value through occlusions, or a noise-free "
            "stream) and were read as occluded")
    problems = list(diagnosis.problems)
    if problems:
        problems[0] = f"{problems[0]} ({text}: export occluded frames as empty)"
    return dataclasses.replace(diagnosis, problems=problems, notes=[text, *diagnosis.notes])


def _diagnose(recording: Recording, imu_latency_s: float) -> Diagnosis:
    """:func:`diagnose` on a recording without held frames."""
    notes: list[str] = []
    markers = marker_problem(recording)
    if markers:
        return Diagnosis([markers])
    unit = time_unit_problem(recording)
    if unit:
        return Diagnosis([unit])
    recording = on_mocap_clock(recording)
    if imu_latency_s:
        samples = recording.imu
        recording = dataclasses.replace(recording, imu=ImuSamples(
            samples.t - imu_latency_s, samples.accelerometer, samples.gyroscope))
    if not recording.mocap.visible.any():
        return Diagnosis(["mocap.csv has no visible (solved) frame: every row is empty or "
                          "occluded, so nothing can be tracked or checked"])
    overlap = overlap_seconds(recording)
    if overlap <= 1.0:
        imu, mocap = recording.imu.t, recording.mocap.t[recording.mocap.visible]
        return Diagnosis([f"no time overlap: the IMU spans {_seconds(imu[0])}-{_seconds(imu[-1])}"
                          f" s and the visible mocap {_seconds(mocap[0])}-{_seconds(mocap[-1])} "
                          f"s ({len(mocap)} frames; overlap {max(overlap, 0.0):.3f} s): check "
                          f"both files' t column (same clock, seconds) or {CALIBRATE_FIX}"])
    clipped, clipping = clipped_samples(recording.imu)
    notes += clipping
    try:  # the whole mocap: the clipped samples are masked on the gyroscope's side
        correlation = coarse_clock_offset(recording, clipped=clipped)
    except ValueError as error:
        return Diagnosis(notes=[*notes, f"clock and mount not checked: {error}"])
    try:
        swapped = coarse_clock_offset(_reordered(recording), clipped=clipped)
        if swapped.peak > max(correlation.peak + 0.2, 0.8):
            return Diagnosis([f"quaternion columns look like x, y, z, w: the mocap rates match "
                              f"the gyroscope with qw read from the last column (correlation "
                              f"{swapped.peak:.2f} against {correlation.peak:.2f}): write "
                              "mocap.csv's quaternion as qw, qx, qy, qz"], correlation=swapped)
    except ValueError:
        pass
    if clipped.any():  # the tests below pair the mocap with the IMU at the offset found
        recording = without_frames_near(recording, recording.imu.t[clipped], CLIPPED_MARGIN_S)
    offset = correlation.offset
    unique = correlation.peak >= CLEAR_CORRELATION or (
        correlation.peak - correlation.runner_up >= MIN_PEAK_MARGIN)
    if correlation.peak < MIN_CORRELATION or not unique:
        notes.append(f"clock not checked: too little rotation (correlation peak "
                     f"{correlation.peak:.2f}, next best {correlation.runner_up:.2f})")
        offset = 0.0
    elif abs(offset) > CLOCK_TOLERANCE_S:
        side = "behind" if offset > 0 else "ahead of"
        return Diagnosis([f"IMU clock about {abs(offset) * 1e3:.0f} ms {side} the mocap: "
                          f"{CALIBRATE_FIX}"], correlation=correlation)
    else:
        notes.append(f"clock: offset {offset * 1e3:+.1f} ms (correlation {correlation.peak:.3f})")
    pairs = rate_pairs(recording, offset)
    principal, _ = rate_spread(pairs.mocap.rate) if len(pairs.mocap.start) else (np.zeros(3), 0)
    if principal[0] < MIN_ROTATION_RATE or principal[1] < MIN_SECOND_AXIS * principal[0]:
        notes.append("mount not checked: the limb rotates about one axis only or too little")
    else:
        gyroscope = pairs.gyroscope(offset, 0.0)
        best = Rotation.from_matrix(mount_from_rates(pairs.mocap.rate, gyroscope))
        misfit = relative_rate_misfit(pairs.mocap.rate, gyroscope)
        if misfit > MAX_RATE_MISFIT:
            swapped_pairs = rate_pairs(_reordered(recording), offset)
            swapped_misfit = relative_rate_misfit(swapped_pairs.mocap.rate,
                                                  swapped_pairs.gyroscope(offset, 0.0))
            if swapped_misfit < 0.5 * misfit:
                return Diagnosis([f"quaternion columns look like x, y, z, w: no mount matches "
                                  f"the gyroscope to the mocap rates (misfit {misfit:.0%}), but "
                                  "with qw read from the last column one does "
                                  f"({swapped_misfit:.0%}): write mocap.csv's quaternion as "
                                  "qw, qx, qy, qz"],
                                 correlation=correlation)
        angle = float(np.degrees((best.inv() * rotation_from_wxyz(
            recording.info.imu_to_body)).magnitude()))
        stated_misfit = relative_rate_misfit(
            pairs.mocap.rate, gyroscope, matrix_from_wxyz(recording.info.imu_to_body))
        # a short or one-axis recording leaves the best fit loose: the stated mount is wrong
        # only when it explains the rates clearly worse than the best fit does
        if angle > MOUNT_TOLERANCE_DEG and stated_misfit > misfit + MIN_MOUNT_MISFIT_EXCESS:
            quaternion = np.round(best.as_quat(scalar_first=True), 3).tolist()
            return Diagnosis([f"mount wrong: the gyroscope matches the mocap rates with "
                              f"imu_to_body about {quaternion}, {angle:.0f} deg from "
                              f"recording.yaml's: {CALIBRATE_FIX}"], correlation=correlation)
        notes.append(f"mount: within {angle:.1f} deg of the rates' best fit, or as good a fit "
                     f"(rate misfit {stated_misfit:.0%} against {misfit:.0%})")
    try:
        force = fit_specific_force(recording, offset, 0.0, recording.info.imu_to_body)
    except ValueError as error:
        notes.append(f"gravity not checked: {error}")
        return Diagnosis(notes=notes, correlation=correlation)
    seconds = force.samples * median_interval(recording.mocap.t)
    if seconds < MIN_GRAVITY_SECONDS:
        notes.append(f"gravity not checked: {seconds:.1f} s of usable visible mocap (expected "
                     f"at least {MIN_GRAVITY_SECONDS:g} s)")
        return Diagnosis(notes=notes, correlation=correlation)
    given, fitted = recording.info.gravity, force.gravity
    angle = angle_between_deg(given, fitted)
    magnitude = float(np.linalg.norm(fitted))
    if angle > GRAVITY_TOLERANCE_DEG:
        kind = "sign flipped" if angle > 150 else "wrong axis"
        return Diagnosis([f"gravity {kind}: the accelerometer says gravity is about "
                          f"{np.round(fitted, 1).tolist()} m/s^2, recording.yaml says "
                          f"{np.round(given, 2).tolist()} ({angle:.0f} deg apart): fix gravity "
                          f"in recording.yaml or {CALIBRATE_FIX}"], correlation=correlation)
    if not 7.0 <= magnitude <= 12.5:
        return Diagnosis([f"accelerometer scale: gravity measures {magnitude:.3g} m/s^2 "
                          "(expected about 9.81): check the accelerometer's unit (m/s^2)"],
                         correlation=correlation)
    notes.append(f"gravity: within {angle:.1f} deg of the accelerometer's ({magnitude:.2f} m/s^2)")
    problem = fine_clock_problem(recording, offset, notes)
    if problem:
        return Diagnosis([problem], notes=notes, correlation=correlation)
    return Diagnosis(notes=notes, correlation=correlation)
