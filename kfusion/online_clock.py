"""The Tracker's online IMU clock check: the accelerometer timed against the mocap as it runs.

``kfusion check`` times a recording's IMU clock before ``kfusion track`` runs (test 7 of
:mod:`kfusion.calibration.diagnosis`); the streaming :class:`kfusion.tracker.Tracker` runs no
check, and its consistency monitor refuses a model only from twice its bound. An undeclared IMU
clock offset of 10 ms (20 ms) therefore left 6.0 % (5.8 %) of the Tracker's rows beyond the 99 %
bound, up to 2.35x (2.78x) (``benchmarks/failsafe.py --quick``): a clock offset ``d`` shifts the
dead-reckoned velocity by about ``d`` times its change, a systematic error that no noise scale
covers.

The watch applies ``check``'s own test to the stream, window by window. Every
:data:`PERIOD_S` of mocap time, the last ``window_s`` of frames (the fused ones; occluded and
gated frames count as not seen) and of IMU samples (at the times the filter uses them: on the
mocap clock, minus ``imu_latency_s``) are timed by
:func:`kfusion.calibration.specific_force.fit_accelerometer_offset` (Gauss-Newton on the
accelerometer against the mocap's second derivative, 4 Hz low-passed alike, with gravity,
lever arm, bias and scale errors fitted beside the offset). A timing whose offset is beyond
``check``'s rule (:func:`kfusion.calibration.diagnosis.accelerometer_clock_finding`: 2 ms plus 2
sigma) makes the clock *refused*: the Tracker then bridges nothing (a gap is ``lost``; at a fix
the position is the fix alone), exactly as when the consistency monitor refuses the model, and
health names the offset. A window the motion cannot time (too still, too occluded, the fit not
converged or its 1-sigma above :data:`kfusion.calibration.rates.MAX_OFFSET_STD_S`) leaves the
previous verdict in place.

Each window's 1-sigma is the fit's own combined with ``check``'s systematic timing error (1 ms:
how the timing wanders with the motion), and the verdict pools the newest
:data:`POOLED_TIMINGS` windows (:func:`pooled_timing`). Measured with 5 s windows (the
default): on 20 s simulated reaches the pooled timing reads 9.0-10.5 ms for a 10 ms offset and
17.8-20.3 ms for 20 ms, refused from 5.5-8 s on, and -1.3 to +4.4 ms on clean clocks (single
windows up to 7.5 ms in an adversarial review's clean runs); on the seven BROAD trials (first
120 s each) single windows read up to 6.9 ms (trial 24: +6.9 +- 0.1 ms by the fit's sigma alone,
which refused a right clock before the systematic term) and no pooled verdict refuses. Frames
within :data:`EDGE_MARGIN_S` of a window's IMU span are not timed (otherwise an offset of one
IMU period made the fit alternate without converging, and an undeclared 5 ms stayed undecided
until 8 s instead of 5.5 s).

Suspected clock. An offset within the rule can still break the bound: an undeclared 5 ms, timed
4.4 +- 1.5 ms, is refused only after 8-20 s, and meanwhile its gaps were up to 1.7x their bound
(1.4 % of the Tracker's rows beyond it, ``benchmarks/failsafe.py --seeds 5 --duration 30``). A
verdict beyond :data:`SUSPECT_SIGMAS` sigma of zero but within the rule is *suspected*
(:attr:`OnlineClockCheck.suspected`): the Tracker keeps bridging, with a gap's covariance
widened by the timing error the offset implies (:func:`timing_error_covariance`) and a fused
fix's raised to at least the fix's own (:func:`suspected_clock_fix_covariance`). On clean
simulated clocks 1.7 % of the rows were read while suspected (a first window reading 3.5-4.8
ms), on the first 40 s of the seven BROAD trials 9 % (bounds up to 1.05x wider in gaps).

Mount or clock. A mount error turns the accelerometer's axes, which on a steadily turning
acceleration looks like a time shift: 3 deg inside ``check``'s 5 deg tolerance read as 6-12 ms
on simulated circles. A window beyond :data:`SUSPECT_SIGMAS` sigma is timed again with the
mount the gyroscope fits on it (:func:`gyroscope_mount_timing`); when the pooled timing is
beyond the rule with the declared mount but within it with the gyroscope's
(:attr:`ClockTiming.mount_suspected`), the finding names the mount and the Tracker's suspected
cause is the IMU disagreeing with the motion, not the clock. The clock is refused all the same
(the model is wrong either way). A real 10 ms offset still reads 6.6-10.7 ms with the
gyroscope's mount (0.7-0.8 deg from the right one), and stays a clock finding.

Known limits: marker frames
(:meth:`kfusion.tracker.Tracker.push_markers`) are timed on their Kabsch pose
(:func:`kfusion.kalman.markers.marker_pose`; a frame with fewer than 3 fitting markers counts
as not seen); one worker thread serves every tracker of a process (a fit costs 15-130 ms of CPU per
5 s window, more for a window timed again with the gyroscope's mount; about 30 live trackers at
500 Hz saturate it). A tracker whose timing the busy worker has not started when it is due takes
it back and computes it itself, so its wait is one timing, not the queue.

Determinism. A fit costs tens of ms, so it runs in a worker thread, off the push path. Its
result is applied at the first frame at least :data:`APPLY_AFTER_S` of mocap time after the
window's end (the Tracker waits for the worker there if it is not done), so what the Tracker
reports depends only on the data pushed, never on the thread's timing: a replay faster than
real time gives the same outputs as the live run. Where the worker cannot run the timing (after
interpreter shutdown, or in a forked child, which inherits the executor but not its thread) the
caller computes it when due, with the same result; a timing that fails unexpectedly is
undecided. A reset keeps the verdict (it is about the sensors' clocks) and drops the data.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING, Final

import numpy as np
from numpy.typing import NDArray

from kfusion.monitor import fix_covariance_under_innovation_factor

if TYPE_CHECKING:
    from kfusion.recording import Recording

PERIOD_S: Final = 2.5
"""s of mocap time between the starts of two timings (windows overlap by half by default)."""
APPLY_AFTER_S: Final = 0.5
"""s of mocap time after a window's end at which its timing takes effect."""
DEFAULT_WINDOW_S: Final = 5.0
"""s of data each timing uses (``TrackerOptions.clock_window_s``)."""
POOLED_TIMINGS: Final = 4
"""The verdict pools this many newest decided timings (:func:`pooled_timing`)."""
SUSPECT_SIGMAS: Final = 2.0
"""A verdict within ``check``'s rule but beyond this many sigma of zero is *suspected*
(:attr:`OnlineClockCheck.suspected`): the Tracker widens its gap bounds by the timing error it
implies (:func:`timing_error_covariance`)."""
EDGE_MARGIN_S: Final = 0.05
"""s: frames this close to either end of a window's IMU samples are left out of its timing
(:func:`time_window`), so that no offset up to this moves a frame out of the IMU's span."""


@dataclass(frozen=True)
class ClockTiming:
    """One window's accelerometer timing.

    Attributes:
        end: s, mocap time of the window's last frame.
        offset_s, std_s: the IMU clock offset (positive: the IMU clock behind the mocap) and its
            1-sigma, s.
        problem: the finding (``check``'s words) when the offset is beyond the rule, else "".
        mount_offset_s, mount_std_s: the same timing with the mount the gyroscope fits on
            the window (:func:`gyroscope_mount_timing`), s; NaN when not timed so (the
            offset within :data:`SUSPECT_SIGMAS` sigma of zero, or the gyroscope's fit
            failing).
        mount_error_deg: the angle between that mount and the declared one, deg (NaN: not
            fitted).
    """

    end: float
    offset_s: float
    std_s: float
    problem: str
    mount_offset_s: float = math.nan
    mount_std_s: float = math.nan
    mount_error_deg: float = math.nan

    @property
    def mount_suspected(self) -> bool:
        """True when the problem is a mount error rather than the clock: the offset is
        beyond ``check``'s rule with the declared mount and within it with the gyroscope's
        (:func:`gyroscope_mount_timing`)."""
        from kfusion.calibration.diagnosis import accelerometer_clock_finding

        return bool(self.problem) and math.isfinite(self.mount_offset_s) and (
            accelerometer_clock_finding(self.mount_offset_s, self.mount_std_s) is None)


def time_window(imu: NDArray[np.float64], frames: NDArray[np.float64],
                imu_to_body: NDArray[np.float64], window_s: float) -> ClockTiming | None:
    """Time the accelerometer over one window; None when the motion cannot time it.

    Args:
        imu: (n, 7) rows ``[t, ax, ay, az, gx, gy, gz]`` (s on the mocap clock, m/s^2, rad/s,
            IMU frame), any order.
        frames: (m, 8) rows ``[t, px, py, pz, qw, qx, qy, qz]`` (s, m, body -> global
            [w, x, y, z]; NaN position: not seen), any order.
        imu_to_body: (4,) rotation IMU -> body, [w, x, y, z].
        window_s: s, for the finding's words.
    """
    from kfusion.calibration.diagnosis import SYSTEMATIC_TIMING_S, accelerometer_clock_finding
    from kfusion.calibration.rates import MAX_OFFSET_STD_S
    from kfusion.calibration.specific_force import fit_accelerometer_offset
    from kfusion.recording import ImuSamples, MocapFrames, Recording, RecordingInfo

    imu = imu[np.argsort(imu[:, 0], kind="stable")]
    frames = frames[np.argsort(frames[:, 0], kind="stable")]
    if len(imu) < 20 or len(frames) < 20:
        return None
    # frames whose IMU time (t - offset) leaves the IMU's span for some offset within
    # EDGE_MARGIN_S are not timed: a run with such a frame is dropped whole by
    # specific_force_system, so the system would change as an iterate crosses the edge (an
    # undeclared 5 ms offset, one IMU period at 200 Hz, made Gauss-Newton alternate between
    # 4.55 and 5.09 ms, never converging: the first 5 s undecided)
    frames = frames[(frames[:, 0] >= imu[0, 0] + EDGE_MARGIN_S)
                    & (frames[:, 0] <= imu[-1, 0] - EDGE_MARGIN_S)]
    if len(frames) < 20:
        return None
    seen = np.isfinite(frames[:, 1:4]).all(axis=1)
    frames = frames.copy()
    frames[~seen, 1:] = np.nan
    try:
        recording = Recording(
            imu=ImuSamples(imu[:, 0], imu[:, 1:4], imu[:, 4:7]),
            mocap=MocapFrames(frames[:, 0], frames[:, 1:4], frames[:, 4:8]),
            info=RecordingInfo(imu_to_body=imu_to_body, gravity=np.full(3, np.nan)))
        with np.errstate(all="ignore"):
            found = fit_accelerometer_offset(recording, 0.0, 0.0, imu_to_body,
                                             max_iterations=8)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None  # no visible run long enough, a singular system: the motion cannot time it
    offset, std = found.middle_offset, found.middle_offset_std
    if not (found.converged and math.isfinite(offset) and std <= MAX_OFFSET_STD_S):
        return None
    # the fit's own 1-sigma leaves out how the timing wanders with the motion (check's
    # SYSTEMATIC_TIMING_S): a 5 s window of BROAD 24 read +6.9 +- 0.1 ms where the whole trial
    # reads +0.3 +- 0.05 ms, and pooled by the fit's sigma alone it refused a right clock
    std = math.hypot(std, SYSTEMATIC_TIMING_S)
    mount_timing = (math.nan, math.nan, math.nan)
    if abs(offset) > SUSPECT_SIGMAS * std:
        mount_timing = gyroscope_mount_timing(recording, imu_to_body)
    problem = accelerometer_clock_finding(offset, std, f" over {window_s:g} s of the stream")
    timing = ClockTiming(float(frames[-1, 0]), offset, std, problem or "", *mount_timing)
    return _with_mount_words(timing)


def gyroscope_mount_timing(recording: Recording, imu_to_body: NDArray[np.float64]
                           ) -> tuple[float, float, float]:
    """(offset s, 1-sigma s, mount error deg): the accelerometer timed again with the mount
    the gyroscope fits on the same data, and that mount's angle from ``imu_to_body``; NaNs
    when either fit fails.

    A mount error turns the accelerometer's axes, and on a motion whose acceleration turns
    steadily (a circle) a turn of the axes looks like a time shift: a 3 deg mount error on
    simulated circles read as 6-12 ms. The gyroscope's rates fix the mount apart from the
    clock (:func:`kfusion.calibration.rates.fit_rates` fits the offset, the mount and the
    gyro bias together; on those circles it found the 3 deg within 0.5 deg, and within 0.8 deg
    of the right mount with a 10 ms offset), so with its mount a clock offset still reads as
    one (10 ms: 7.9-9.8 ms) and a mount error no longer does (within the rule)."""
    from kfusion.calibration.diagnosis import SYSTEMATIC_TIMING_S
    from kfusion.calibration.rates import MAX_OFFSET_STD_S, fit_rates, rate_pairs
    from kfusion.calibration.specific_force import fit_accelerometer_offset
    from kfusion.conventions import rotation_angle

    try:
        with np.errstate(all="ignore"):
            rates = fit_rates(rate_pairs(recording, 0.0), 0.0, 0.0, imu_to_body,
                              fit_drift=False, fit_mount=True)
            mount = np.asarray(rates.imu_to_body, dtype=float)
            found = fit_accelerometer_offset(recording, 0.0, 0.0, mount, max_iterations=8)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError):
        return math.nan, math.nan, math.nan
    offset, std = found.middle_offset, found.middle_offset_std
    if not (found.converged and math.isfinite(offset) and std <= MAX_OFFSET_STD_S
            and np.isfinite(mount).all()):
        return math.nan, math.nan, math.nan
    return (offset, math.hypot(std, SYSTEMATIC_TIMING_S),
            math.degrees(rotation_angle(imu_to_body, mount)))


def _with_mount_words(timing: ClockTiming) -> ClockTiming:
    """``timing`` with its problem in a mount error's words when that is the cause
    (:attr:`ClockTiming.mount_suspected`)."""
    if not timing.mount_suspected:
        return timing
    words = (f"IMU mount about {timing.mount_error_deg:.1f} deg off imu_to_body (the "
             f"gyroscope's fit): with it the accelerometer times the IMU clock at "
             f"{timing.mount_offset_s * 1e3:+.1f} +- {timing.mount_std_s * 1e3:.1f} ms, with "
             f"imu_to_body at {timing.offset_s * 1e3:+.1f} +- {timing.std_s * 1e3:.1f} ms; "
             "run kfusion calibrate")
    return dataclasses.replace(timing, problem=words)


def _pooled_mean(offsets_s: list[float], stds_s: list[float], overlap: float
                 ) -> tuple[float, float]:
    """(mean s, 1-sigma s) of :func:`pooled_timing`'s rule: the inverse-variance mean of the
    offsets, its variance inflated by ``min(n, overlap)`` for windows sharing data."""
    weights = np.array([1.0 / std ** 2 for std in stds_s])
    mean = float(weights @ np.array(offsets_s) / weights.sum())
    return mean, math.sqrt(min(len(offsets_s), max(overlap, 1.0)) / float(weights.sum()))


def pooled_timing(timings: tuple[ClockTiming, ...], overlap: float) -> ClockTiming:
    """The inverse-variance mean of window timings, judged by ``check``'s rule.

    ``offset = sum(w_i d_i) / sum(w_i)`` with ``w_i = 1 / sigma_i^2``, and ``sigma^2 = min(n,
    overlap) / sum(w_i)``: windows that share data (``overlap`` = window / period: each sample
    is in that many windows) are not independent, so the variance of the mean is inflated by
    up to that factor. One window's timing is its own. Pooling keeps an offset near the rule's
    edge from being refused and accepted window by window (an undeclared 5 ms offset timed
    8.3 +- 1.4 ms in one window and 4.5 ms in the next)."""
    from kfusion.calibration.diagnosis import accelerometer_clock_finding

    if len(timings) == 1:
        return timings[0]
    offset, std = _pooled_mean([timing.offset_s for timing in timings],
                               [timing.std_s for timing in timings], overlap)
    problem = accelerometer_clock_finding(
        offset, std, f" over the stream's last {len(timings)} windows")
    # with the gyroscope's mount: a window not timed so (its offset within SUSPECT_SIGMAS
    # sigma of zero with the declared mount) counts with its own timing
    fitted = [timing.mount_error_deg for timing in timings
              if not math.isnan(timing.mount_error_deg)]
    mount_timing = (math.nan, math.nan, math.nan)
    if fitted:
        mount_timing = (*_pooled_mean(
            [timing.offset_s if math.isnan(timing.mount_offset_s) else timing.mount_offset_s
             for timing in timings],
            [timing.std_s if math.isnan(timing.mount_std_s) else timing.mount_std_s
             for timing in timings], overlap), float(np.mean(fitted)))
    return _with_mount_words(ClockTiming(timings[-1].end, offset, std, problem or "",
                                         *mount_timing))


def timing_error_covariance(offset_s: float, std_s: float,
                            velocity_change: NDArray[np.float64]) -> NDArray[np.float64]:
    """The position covariance (3, 3) m^2 a suspected IMU clock offset adds in a gap.

    IMU samples stamped ``d`` off the mocap clock make the dead-reckoned velocity follow
    ``v(t + d)``: from a fix at ``t_0`` the velocity has changed by ``v(t + d) - v(t_0 + d)``
    where the truth changed by ``v(t) - v(t_0)``, so the position is off by about ``d (v(t) -
    v(t_0)) = d dv`` (the velocity state, fused with such predictions, already follows ``v(t +
    d)`` at the fix). With the offset known only as ``d ~ N(offset, std^2)``, the error's
    second moment is

        E[d^2] dv dv^T = (offset^2 + std^2) dv dv^T,

    added to the filter's covariance as the bias a rival hypothesis adds
    (:meth:`kfusion.monitor.ConsistencyMonitor.cover_rivals`). Args: offset_s, std_s in s;
    velocity_change (3,) m/s, the dead-reckoned velocity's change since the last fix."""
    change = np.asarray(velocity_change, dtype=float)
    return (offset_s ** 2 + std_s ** 2) * np.outer(change, change)


SUSPECTED_FIX_FACTOR: Final = 2.0
"""Innovation factor a fused fix is given while the clock is suspected
(:func:`suspected_clock_fix_covariance`)."""


def suspected_clock_fix_covariance(covariance: NDArray[np.float64], noise_variance: float
                                   ) -> NDArray[np.float64]:
    """The covariance (3, 3) m^2 of a fused fix's position while the IMU clock is suspected:
    ``P+ + (R - P+)`` with its negative directions dropped, i.e. at least the fix's own R
    (:func:`kfusion.monitor.fix_covariance_under_innovation_factor` with factor
    :data:`SUSPECTED_FIX_FACTOR`, the least the monitor gives a fix fused with predictions
    shown wrong).

    Why: the timing error of the prediction the fix is fused with is not ``d dv`` over one
    frame (0.05 mm for 5 ms at a fix) but mostly the velocity state's timing error carried
    along, which the tracker cannot observe: with an undeclared 5 ms offset the fused
    position was off by 0.10 mm RMS (0.32 mm at the 99th percentile) more than with the right
    clock, against a 1-sigma of 0.16 mm, and 1.65 % of the fixes read while the clock was
    suspected lay beyond the 99 % bound (0.77 % with the right clock). The fix itself does not
    depend on the IMU clock. ``covariance``: ``P+`` (3, 3) m^2; ``noise_variance``: the mocap's
    R = noise_variance I, m^2."""
    return fix_covariance_under_innovation_factor(covariance, noise_variance,
                                                  SUSPECTED_FIX_FACTOR)


@lru_cache(maxsize=1)
def _worker() -> ThreadPoolExecutor:
    """One worker thread for every tracker's timings (created on first use; a forked child
    makes its own: it inherits the executor but not its thread)."""
    return ThreadPoolExecutor(max_workers=1, thread_name_prefix="kfusion-clock-watch")


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_worker.cache_clear)


def _timed(arguments: tuple) -> ClockTiming | None:
    """:func:`time_window` of ``arguments``; None (undecided) when it fails in a way the
    motion does not explain (a timing is a check: its failure must not stop the tracker)."""
    try:
        return time_window(*arguments)
    except Exception:  # noqa: BLE001 - see the docstring
        return None


@dataclass
class _Job:
    """A timing under way: its arguments, the worker's Future (None: not submitted, e.g.
    after interpreter shutdown) and the process that submitted it."""

    arguments: tuple
    future: Future | None
    process: int

    def result(self) -> ClockTiming | None:
        """The timing, waiting for the worker; computed here when the worker cannot give it
        (not submitted, or submitted by the parent of this forked process) or has not started
        it (the worker is busy with other trackers' timings: taking the job back bounds the
        wait by one timing's cost, not by the queue's; the same function on the same data,
        so the outputs do not change)."""
        if self.future is None or self.process != os.getpid() or self.future.cancel():
            return _timed(self.arguments)
        return self.future.result()


class OnlineClockCheck:
    """The watch's state for one tracker (module docstring).

    Feed it every IMU sample the tracker accepts (:meth:`imu`) and every frame with whether it
    was fused (:meth:`mocap`); read :attr:`refused` and :attr:`latest`.
    """

    def __init__(self, imu_to_body: NDArray[np.float64], window_s: float) -> None:
        self._imu_to_body = np.array(imu_to_body, dtype=float)
        self.window_s = float(window_s)
        self._imu: deque[tuple[float, ...]] = deque()
        self._frames: deque[tuple[float, ...]] = deque()
        self._next_start = math.inf  # mocap time the next timing starts at, s (inf: no frame yet)
        # (mocap time it takes effect, s; the job, or its result once known)
        self._pending: deque[tuple[float, _Job | ClockTiming | None]] = deque()
        self._timings: tuple[ClockTiming, ...] = ()  # the newest decided window timings
        self.latest: ClockTiming | None = None  # their pooled_timing: the verdict

    @property
    def enabled(self) -> bool:
        return self.window_s > 0.0

    @property
    def refused(self) -> bool:
        """True while the verdict (the newest decided timings, pooled) is beyond ``check``'s
        rule."""
        return self.latest is not None and bool(self.latest.problem)

    @property
    def suspected(self) -> tuple[float, float] | None:
        """(offset s, 1-sigma s) of the verdict while it is within ``check``'s rule but beyond
        :data:`SUSPECT_SIGMAS` sigma of zero (an offset under 2 ms plus 2 sigma, such as an
        undeclared 5 ms timed 4.4 +- 1.5 ms, is not refused until the windows pin it down,
        after 8-20 s, and meanwhile makes gaps about 1.5x their bound); None otherwise."""
        latest = self.latest
        if latest is None or latest.problem or not (
                abs(latest.offset_s) > SUSPECT_SIGMAS * latest.std_s):
            return None
        return latest.offset_s, latest.std_s

    def imu(self, row: tuple[float, float, float, float, float, float, float]) -> None:
        """An accepted IMU sample ``(t, ax, ay, az, gx, gy, gz)``: event time (s, mocap clock
        minus the latency), m/s^2 and rad/s, IMU frame."""
        if self.enabled:
            rows = self._imu
            rows.append(row)
            if row[0] - rows[0][0] > self.window_s + 2.0 * PERIOD_S:  # the mocap may be away
                self._trim(row[0])

    def mocap(self, t: float, position: NDArray[np.float64], quaternion: NDArray[np.float64],
              fused: bool) -> None:
        """A frame at t (s) that the filter fused (``fused``) or not (occluded, gated, a
        position-only fix: the orientation is needed); applies due timings and starts one
        when its period has passed."""
        if not self.enabled:
            return
        seen = fused and not math.isnan(quaternion[0])
        values = (*position.tolist(), *quaternion.tolist()) if seen else (math.nan,) * 7
        self._frames.append((t, *values))
        if self._next_start == math.inf:  # the first frame
            self._next_start = t + min(self.window_s, PERIOD_S)
        while self._pending and self._pending[0][0] <= t:
            _, job = self._pending.popleft()
            timing = job.result() if isinstance(job, _Job) else job
            if timing is not None:
                self._timings = (self._timings + (timing,))[-POOLED_TIMINGS:]
                self.latest = pooled_timing(self._timings, self.window_s / PERIOD_S)
        if t >= self._next_start:
            self._next_start = t + PERIOD_S
            self._start(t)
        self._trim(t)

    def _start(self, t: float) -> None:
        """Submit the timing of the window ending at t (s)."""
        begin = t - self.window_s
        imu = np.array([row for row in self._imu if row[0] >= begin], dtype=float)
        frames = np.array([row for row in self._frames if begin <= row[0] <= t], dtype=float)
        if imu.ndim != 2 or frames.ndim != 2:
            return
        arguments = (imu.reshape(-1, 7), frames.reshape(-1, 8), self._imu_to_body,
                     self.window_s)
        try:
            future: Future | None = _worker().submit(_timed, arguments)
        except RuntimeError:  # interpreter shutdown: computed when due, in the caller
            future = None
        self._pending.append((t + APPLY_AFTER_S, _Job(arguments, future, os.getpid())))

    def _trim(self, t: float) -> None:
        """Forget data older than the next window can use (out-of-order rows a little later)."""
        horizon = t - self.window_s - PERIOD_S
        for rows in (self._imu, self._frames):
            while rows and rows[0][0] < horizon:
                rows.popleft()

    def forget_data(self) -> None:
        """Drop the buffered samples and the timings under way (a reset, or the streams
        restarted after a clock jump), keeping the verdict: it is about the sensors' clocks,
        which a reset does not change (a refused clock stayed refused for at most the next
        timing after it)."""
        self._imu.clear()
        self._frames.clear()
        self._pending.clear()
        self._next_start = math.inf

    def state(self) -> tuple:
        """A copy of the state (pending timings waited for): :meth:`restore` continues
        exactly from it."""
        pending = tuple((due, job.result() if isinstance(job, _Job) else job)
                        for due, job in self._pending)
        return (tuple(self._imu), tuple(self._frames), self._next_start, pending,
                self._timings, self.latest)

    def restore(self, state: tuple) -> None:
        """Continue from :meth:`state`."""
        imu, frames, self._next_start, pending, self._timings, self.latest = state
        self._imu, self._frames = deque(imu), deque(frames)
        self._pending = deque(pending)
