"""A streaming tracker for in-process use at IMU rate, built for safety software.

:class:`Tracker` wraps the Kalman filter (:mod:`kfusion.kalman`) or, on request, the paper's
baseline (:mod:`kfusion.baseline`). It validates every call before the estimator sees it, keeps
health counters, and reports every output with its time, a status, the time since the last mocap
fix and a position bound usable as ISO/TS 15066's Z_d (:mod:`kfusion.safety`).

Usage::

    tracker = Tracker(imu_to_body=[1, 0, 0, 0], gravity=[0, -9.81, 0],
                      clock=time.monotonic)       # the clock the samples are stamped with
    tracker.push_imu(t, accelerometer, gyroscope)     # m/s^2, rad/s, IMU frame
    tracker.push_mocap(t, position, quaternion)       # m, [w, x, y, z]; None/NaN: occluded
    estimate = tracker.estimate()                     # now (without a clock: estimate(now))
    estimate.status, estimate.bound(0.99)             # 'tracked' | 'bridged' | 'lost', m

Status (at time t, the caller's now, with t_fix the time of the last fused mocap fix):

* ``tracked``: the last mocap frame pushed was fused and ``t - t_fix <= fix_timeout_s``.
* ``lost``: otherwise, when there is no fix yet, ``t - t_fix > max_bridge_s``, the IMU did not
  cover the time since the fix (no sample, a stalled stream, an outage, or t more than the hold
  horizon after the last sample: :mod:`kfusion.streamhealth`), the estimator has no estimate, or
  the state is not finite. The position is NaN and ``bound()`` is ``math.inf``.
* ``bridged``: otherwise (the last frame was occluded or gated, or frames stopped arriving, and
  the IMU dead-reckons).

Bad input (each case is counted in :attr:`Tracker.health`). Bad values never raise; the only
exception any call raises is ValueError, for a wrong shape or type (or an ``estimate(t)`` earlier
than the newest sample, a ``restore`` of a foreign snapshot, a bad constructor argument):

=====================================  ==========================================================
input                                  behaviour
=====================================  ==========================================================
wrong shape or type                    ValueError naming what was expected and what was received
NaN/inf IMU value or time              rejected ``non_finite``; state untouched
time <= the stream's last time         rejected ``out_of_order``; same time and values:
                                       ``duplicate`` (skipped); same time, other values:
                                       ``conflicting_duplicate``
one stream behind the other            fused in time order from the checkpoint before it (up to
                                       ``max_delay_s``, see the policy below); older:
                                       ``too_late``
long IMU dropout (large dt), IMU      dt is never clamped: the interval the IMU does not cover
stalled or never delivering            follows the no-IMU model (the covariance grows over all of
                                       it); counted once in ``imu_dropouts``; fixes still give
                                       the position (tracked); a gap is lost, never bridged
stamp > ``max_time_jump_s`` ahead of   rejected ``implausible_time``; three consistent such
both streams (a glitch)                stamps confirm a real jump (``time_rebases``), as do
                                       stamps of every stream far behind a glitched present
mocap stamp ahead of the cadence       more than 2.5 frame periods after the previous frame and
and of the IMU (a frame counter or     as far ahead of the newest IMU sample: ``waiting`` until the
host clock glitching a few frames)     next frame; one stamped before it rejects it
                                       ``implausible_time``, one stamped after it confirms lost
                                       frames (the waiting one is fused first), as does an IMU
                                       sample past its time (``health.mocap_waiting``)
huge int time (beyond float)           rejected ``non_finite``; ``estimate`` of it is lost
IMU axis beyond any sensor's range     rejected ``implausible_value``: corrupt like a non-finite
(1e4 m/s^2, 1e3 rad/s)                 sample, not saturated
accelerometer at its range limit       accepted, flagged ``saturated``; the Kalman filter adds
(an axis at >= 99.9 % of the range)    (range/2)^2 acceleration variance over the interval the
                                       sample is held, so the clipped part becomes position and
                                       velocity uncertainty rather than bias (the bias update is
                                       not frozen outright)
mocap position None / NaN              occluded: no update, bridging
mocap pose repeated bit for bit (one   not a measurement (a client holding the last value):
of the 10 latest visible frames')      occluded, counted ``held_poses`` (kept across reset)
mocap position inf                     rejected ``non_finite``
mocap coordinate beyond 10 m           rejected ``implausible_value`` (mm, or corrupt)
mocap quaternion None / NaN            kalman: position-only update (orientation from the
                                       gyroscope); baseline: occluded
mocap quaternion not unit (> 1e-3)     rejected ``bad_quaternion``
mocap jump / marker swap               chi-square gate: rejected ``gated`` and counted, however
                                       long the gap, while the prediction is valid (bridged
                                       with its bound); once lost, the next fix re-acquires
mocap orientation flipped              gated against the gyroscope orientation: the fix is used
                                       position-only, counted ``orientation_gated``
non-finite estimator state             status lost, the estimator restarts at the next fix,
                                       counted in ``state_resets``
=====================================  ==========================================================

Out-of-step streams: each stream must be in time order, but the two may arrive out of step (the
mocap typically lags the IMU by a few ms; with an IMU latency the IMU lags the mocap). The order
is the batch driver's (:mod:`kfusion.kalman.events`): an IMU sample counts at the time it
describes, its stamp mapped onto the mocap clock (``imu_time_offset``, ``imu_clock_drift_ppm``)
minus the Kalman parameters' ``imu_latency_s``, and at equal times the IMU sample goes first.
Whatever the arrival order within ``max_delay_s``, the result is bit-identical to pushing
everything in that order, and to ``kfusion track`` on the same recording
(tests/test_batch_streaming.py, tests/test_tracker_late_arrival.py).

Late arrival at bounded cost (the policy). A frame is fused when it arrives, so that
``push_mocap`` returns the fix's outcome (accepted, gated, ...) and ``estimate(t)`` at a frame's
time includes that frame: an estimate is never older than the data that has arrived. An IMU
sample in order is fused when it arrives too. The tracker logs the fused events of the last
``max_delay_s`` and keeps state checkpoints where the next insertion will land
(:meth:`Tracker._fuse_next`), and one after an IMU sample when the newest is
``checkpoint_interval_s`` old. A sample behind the newest fused event undoes only what follows
it:

* an IMU sample behind fused frames (frames first: same stamps with the mocap delivered first,
  or an IMU latency) is *deferred*: it waits (pending), with every IMU sample after it, until a
  frame arrives, the state is read (``estimate``, ``health``, ``snapshot``, ...) or the waiting
  samples span more than ``checkpoint_interval_s``. Then, once, the checkpoint just before it
  is restored and the frames after it are fused again among the waiting samples. ``push_imu``
  then costs its validation and an append (its outcome does not depend on the fusion), and a
  reader at frame rate pays one restore and one extra update per frame, however many samples
  arrived behind it; no IMU sample is fused twice.
* an IMU sample past the time the next frame is expected at (the newest frame's time plus
  the last frame period), by at most ``checkpoint_interval_s``, is deferred the same way, with
  no rollback: a frame that arrives late (the mocap typically lags the IMU by a few ms) then
  lands in order, with no restore and no IMU sample fused twice. Past that wait the IMU
  samples are fused as they arrive again (a mocap that stopped does not hold the IMU back).
* a frame behind fused IMU samples (the mocap later than that wait): the deferred samples
  before it are fused; the checkpoint before it is restored (while frames come late, one is
  taken just before the first IMU sample past the time the next frame is expected at; else
  the one just after the previous late frame, or an interval checkpoint), the frame fused in
  its place (its outcome returned), a checkpoint taken after it, and the IMU samples after it
  fused again. Cost: one restore, one update and lag x IMU rate predictions for frames at a
  steady rate (at most (lag + the frame period or ``checkpoint_interval_s``) x IMU rate).
* older than ``max_delay_s`` behind the newest sample: rejected ``too_late``.

Anchors, and why not as they are. PX4 EKF2 fuses on a delayed horizon from an IMU buffer and an
output predictor carries the state to now with the IMU alone; its output at now is a
complementary correction, not the in-order posterior, so batch and stream would differ. A pure
hold of frames (a frame ahead of the IMU kept out of the state until the IMU passes it) cannot
return the fix's outcome at push time and leaves ``estimate(t)`` at the frame's time without
that frame. Here the frame is fused at once and the IMU samples behind it are held instead
(their outcome is known at push time), and the hold ends at every read and every frame. This is
optimistic execution with rollback and lazy re-execution (Jefferson's Time Warp): the common
cases cost a restore and one extra update per frame rather than a replay of the buffer.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
import threading
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from numbers import Real
from pathlib import Path
from types import MappingProxyType
from typing import Any, Final, Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kfusion.conventions import (
    BRIDGED,
    GRAVITY_MAGNITUDE_RANGE,
    LOST,
    MAX_ACCELEROMETER_VALUE,
    MAX_GYROSCOPE_VALUE,
    MAX_LEVER_ARM_M,
    QUATERNION_NORM_TOLERANCE,
    imu_time_to_mocap,
    vector_length,
)
from kfusion.guards import YamlError, load_yaml, real_number, refuse_masked, short_repr
from kfusion.kalman.batch import marker_fix_parameters
from kfusion.kalman.events import IMU_STREAM, MOCAP_STREAM, event_key
from kfusion.kalman.filter import ACCEPTED, GATED, INITIALISED, OCCLUDED, REACQUIRED
from kfusion.kalman.model import VELOCITY
from kfusion.kalman.parameters import KalmanParameters
from kfusion.monitor import CLOCK, IMU_MOTION, MonitorReport, held_at_frame
from kfusion.online_clock import (
    DEFAULT_WINDOW_S,
    OnlineClockCheck,
    suspected_clock_fix_covariance,
    timing_error_covariance,
)
from kfusion.profiles import ImuProfile, imu_profile
from kfusion.recording import (
    MAX_PLAUSIBLE_POSITION,
    RecordingInfo,
    check_clock,
    marker_offset_problem,
    parse_info,
)
from kfusion.streamhealth import (
    DEFAULT_MAX_TIME_JUMP_S,
    FIX_TIMEOUT_S,
    IMPLAUSIBLE,
    REBASE,
    ImuWatch,
    RecentPoses,
    TimeGuard,
    dead_reckoning_until,
    hold_horizon,
    pose_key,
    status_durations,
    tracking_status,
)

__all__ = ["Estimate", "Health", "PushOutcome", "Tracker", "TrackerOptions",
           "TrackerSnapshot", "position_bound", "status_durations", "tracking_status"]

# ---------------------------------------------------------------------------------------------
# Reasons (the strings of PushOutcome.reason and the keys of the health counters)
# ---------------------------------------------------------------------------------------------

# ACCEPTED (IMU sample fused, or mocap fix fused through the gate), REACQUIRED (fix fused as a
# re-acquisition after a long gap), OCCLUDED (frame without a position) and GATED (fix rejected by
# the chi-square gate) are the Kalman filter's own outcome strings, imported so they cannot drift.
SATURATED: Final = "saturated"
"""IMU sample fused with an accelerometer axis at its range limit (flag, not a rejection)."""
NON_FINITE: Final = "non_finite"
OUT_OF_ORDER: Final = "out_of_order"
DUPLICATE: Final = "duplicate"
CONFLICTING_DUPLICATE: Final = "conflicting_duplicate"
TOO_LATE: Final = "too_late"
BAD_QUATERNION: Final = "bad_quaternion"
IMPLAUSIBLE_VALUE: Final = "implausible_value"
"""An IMU sample with an axis beyond what any body-worn sensor reports (``MAX_ACCELEROMETER_VALUE``
and ``MAX_GYROSCOPE_VALUE`` of :mod:`kfusion.conventions`): corrupt like a non-finite one, not
saturated; or a mocap coordinate (a marker's too) beyond
:data:`kfusion.recording.MAX_PLAUSIBLE_POSITION`, which ``kfusion check`` refuses in a file."""
IMPLAUSIBLE_TIME: Final = "implausible_time"
"""A stamp implausibly far ahead of both streams (:class:`kfusion.streamhealth.TimeGuard`), or
a frame waiting for jumping ahead of the mocap's cadence that the next frame contradicted."""
WAITING: Final = "waiting"
"""A mocap frame stamped ahead of the stream's cadence and of the IMU, waiting until the next
frame (or the IMU) shows whether its stamp is real (:meth:`Tracker._admit_frame`)."""
CADENCE_JUMP: Final = 2.5
"""A frame stamped more than this many frame periods after the previous one, and as far ahead
of the newest IMU sample, waits (:data:`WAITING`). 1.5 made frames of hand-built streams wait with
uneven steps (a 5 ms step, then 10 ms: the period is the last step); 2.5 still stops a frame
stamped 3 periods ahead (at 100 Hz a stale fix 30 ms ahead was shown `tracked` at its stamp
up to 46x beyond its bound, to a reader at the newest time)."""

FIXED: Final = (ACCEPTED, REACQUIRED, INITIALISED)
"""Mocap outcomes whose fix was fused: the filter's own vocabulary
(:data:`kfusion.kalman.filter.USED_OUTCOMES`), the first fix ``initialised`` as in ``kfusion
track``'s outcome column."""
IMU_REJECTIONS: Final = (NON_FINITE, IMPLAUSIBLE_VALUE, OUT_OF_ORDER, DUPLICATE,
                         CONFLICTING_DUPLICATE, TOO_LATE, IMPLAUSIBLE_TIME)
MOCAP_REJECTIONS: Final = (GATED, NON_FINITE, IMPLAUSIBLE_VALUE, BAD_QUATERNION, OUT_OF_ORDER,
                           DUPLICATE, CONFLICTING_DUPLICATE, TOO_LATE, IMPLAUSIBLE_TIME)
METHODS: Final = ("kalman", "baseline")
DEFAULT_CONFIDENCE: Final = 0.99


# ---------------------------------------------------------------------------------------------
# Results
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PushOutcome:
    """What happened to one pushed sample.

    Attributes:
        accepted: True when the sample was fused (an IMU sample propagated the state, a mocap fix
            updated it). False for rejections, skipped duplicates and occluded frames.
        reason: one of ``accepted``, ``initialised`` (the Kalman filter's first fix),
            ``saturated`` (IMU, fused but flagged), ``reacquired``,
            ``occluded``, ``gated``, ``non_finite``, ``out_of_order``, ``duplicate``,
            ``conflicting_duplicate``, ``too_late``, ``bad_quaternion``, ``implausible_time``,
            ``waiting`` (a mocap frame stamped ahead of the stream's cadence, waiting for the
            next frame: fused then if that one is stamped later, else rejected
            ``implausible_time``).
    """

    accepted: bool
    reason: str


@dataclass(frozen=True)
class Estimate:
    """The tracker's output at one time; arrays are read-only.

    Attributes:
        t: time of the estimate, s.
        position: (3,) m, global frame; NaN when lost.
        velocity: (3,) m/s, global frame; NaN when lost or not estimated.
        covariance: (3, 3) position covariance, m^2; NaN when lost or when the method has no
            uncertainty (baseline).
        std: (3,) per-axis 1-sigma, m (square roots of the covariance diagonal).
        status: ``tracked``, ``bridged`` or ``lost``.
        time_since_fix: s since the last fused mocap fix (inf before the first).
        method: ``kalman`` or ``baseline``.
    """

    t: float
    position: NDArray[np.float64]
    velocity: NDArray[np.float64]
    covariance: NDArray[np.float64]
    std: NDArray[np.float64]
    status: str
    time_since_fix: float
    method: str

    def bound(self, confidence: float = DEFAULT_CONFIDENCE) -> float:
        """Radius r (m) with P(|p_true - position| <= r) >= confidence under the filter's model.

        ``math.inf`` (explicitly unknown) when lost or when the method gives no covariance (the
        baseline), never a small number. See :func:`position_bound` for the formula; it is
        conservative (exact for an isotropic covariance).
        """
        if self.status == LOST:
            checked_confidence(confidence)  # a bad confidence is an error, lost or not
            return math.inf
        return position_bound(self.covariance, confidence)


@dataclass(frozen=True)
class Health:
    """Health counters, cumulative over the tracker's life (kept by :meth:`Tracker.reset`).

    Attributes:
        imu_pushed: push_imu calls that passed the shape/type check.
        imu_accepted: IMU samples fused (saturated ones included).
        imu_rejected: reason -> count (``IMU_REJECTIONS``); accepted + rejected == pushed.
        imu_saturated: fused samples with an accelerometer axis at its range limit.
        imu_dropouts: IMU outages: intervals of more than ``imu_dropout_s`` without an IMU
            sample, each counted once, whether a later sample ends it or mocap frames arrive
            while the IMU is silent (an IMU that never delivers counts once)
            (:class:`kfusion.streamhealth.ImuWatch`).
        longest_imu_interval_s: longest interval between fused IMU samples, s.
        mocap_pushed: push_mocap calls that passed the shape/type check.
        mocap_fused: fixes fused (re-acquisitions included).
        mocap_occluded: occluded frames.
        mocap_rejected: reason -> count (``MOCAP_REJECTIONS``, ``gated`` included);
            fused + occluded + rejected + waiting == pushed.
        gate_rejections: fixes rejected by the innovation gate (= ``mocap_rejected['gated']``).
        reacquisitions: fixes accepted as re-acquisitions after a long gap.
        time_tracked_s, time_bridged_s, time_lost_s: time spent in each status, s, from the first
            sample to the newest.
        longest_gap_s: longest time without a fused fix, s (the current gap included).
        lost_transitions: times the status went from tracked or bridged to lost.
        state_resets: times a non-finite estimator state forced a restart.
        replays: checkpoint restores: a frame that arrived behind fused IMU samples, or IMU
            samples deferred behind fused frames (one restore when they are fused); a frame
            that finds the IMU samples after it waiting costs none.
        resets: calls to :meth:`Tracker.reset`.
        orientation_gated: mocap orientations rejected by the gate against the gyroscope (the
            fix's position was still used; Kalman only).
        held_poses: frames whose pose repeated bit for bit one of the latest visible
            frames': a pose held through an occlusion (or a still body in a noise-free
            stream), not a measurement, read as occluded (counted in ``mocap_occluded`` too;
            :func:`kfusion.streamhealth.repeats_pose`).
        time_rebases: times consistent samples showed the clock really jumped (or the newest
            time was itself a glitch) and the streams restarted from the new time
            (:class:`kfusion.streamhealth.TimeGuard`).
        markers_used: markers fused from :meth:`Tracker.push_markers` frames.
        markers_rejected: visible markers rejected one by one by their own gate (a frame
            whose every visible marker was rejected also counts in ``gate_rejections``).
        clock_offset_s, clock_offset_std_s: the IMU clock offset against the mocap (positive:
            the IMU clock behind) and its 1-sigma, s, from the newest online timing
            (:mod:`kfusion.online_clock`); NaN before one.
        clock_problem: that timing's finding when it refused the clock (the tracker then
            bridges nothing), else "".
        clock_suspected: True while the timing is within the rule but beyond 2 sigma of zero
            (:attr:`kfusion.online_clock.OnlineClockCheck.suspected`): the bounds are widened
            by the timing error it implies.
        mocap_waiting: 1 while a frame stamped ahead of the mocap's cadence and of the IMU waits
            for the next frame (``waiting``), else 0; it counts as fused, occluded or rejected
            once decided.
    """

    imu_pushed: int
    imu_accepted: int
    imu_rejected: Mapping[str, int]
    imu_saturated: int
    imu_dropouts: int
    longest_imu_interval_s: float
    mocap_pushed: int
    mocap_fused: int
    mocap_occluded: int
    mocap_rejected: Mapping[str, int]
    gate_rejections: int
    reacquisitions: int
    time_tracked_s: float
    time_bridged_s: float
    time_lost_s: float
    longest_gap_s: float
    lost_transitions: int
    state_resets: int
    replays: int
    resets: int
    orientation_gated: int = 0
    held_poses: int = 0
    time_rebases: int = 0
    markers_used: int = 0
    markers_rejected: int = 0
    clock_offset_s: float = math.nan
    clock_offset_std_s: float = math.nan
    clock_problem: str = ""
    clock_suspected: bool = False
    mocap_waiting: int = 0

    def as_dict(self) -> dict[str, Any]:
        """Plain nested dict (for logging or YAML/JSON)."""
        result = {item.name: getattr(self, item.name) for item in dataclasses.fields(self)}
        result["imu_rejected"] = dict(self.imu_rejected)
        result["mocap_rejected"] = dict(self.mocap_rejected)
        return result


@dataclass(frozen=True)
class TrackerOptions:
    """Tracker-level settings (the estimator's own are in its parameters object).

    Attributes:
        fix_timeout_s: s; the status is ``tracked`` only while the last fix is at most this old
            (and the last frame was fused). Default 0.05 s: five frames at 100 Hz.
        max_delay_s: s; how far one stream may lag the other and still be fused in time order
            (from a checkpoint: the module docstring's late-arrival policy). 0 disables it: a
            sample behind the other stream is ``too_late``.
        checkpoint_interval_s: s; spacing of state checkpoints between mocap frames (a
            checkpoint is also taken around mocap frames: the module docstring's policy). > 0.
        accelerometer_range: m/s^2; a sample with an axis at 99.9 % of it or beyond is flagged
            ``saturated``. None: the estimator's (Kalman parameters) or the IMU profile's range.
        max_time_jump_s: s; a stamp more than this ahead of the newest time of both streams is
            rejected ``implausible_time`` unless consistent samples confirm the jump
            (:class:`kfusion.streamhealth.TimeGuard`). > 0.
        clock_window_s: s of data in each online timing of the IMU clock against the mocap
            (:mod:`kfusion.online_clock`: one every 2.5 s of mocap time; an offset beyond
            ``kfusion check``'s rule stops the bridging). Default 5 s; 0 turns the watch off
            (Kalman only; the baseline has no bound to keep).
    """

    fix_timeout_s: float = FIX_TIMEOUT_S
    max_delay_s: float = 0.1
    checkpoint_interval_s: float = 0.02
    accelerometer_range: float | None = None
    max_time_jump_s: float = DEFAULT_MAX_TIME_JUMP_S
    clock_window_s: float = DEFAULT_WINDOW_S

    def __post_init__(self) -> None:
        for name, positive in (("fix_timeout_s", True), ("max_delay_s", False),
                               ("checkpoint_interval_s", True), ("accelerometer_range", True),
                               ("max_time_jump_s", True), ("clock_window_s", False)):
            value = getattr(self, name)
            if value is None and name == "accelerometer_range":
                continue
            number = real_number(value)
            if number is None or math.isnan(number) \
                    or number < 0 or (positive and number == 0) \
                    or (math.isinf(number) and name != "accelerometer_range"):
                need = "> 0" if positive else ">= 0"
                raise ValueError(f"TrackerOptions.{name}: expected a finite number {need}, "
                                 f"got {short_repr(value)}")
            object.__setattr__(self, name, number)

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any]) -> TrackerOptions:
        """From a plain mapping; ValueError naming an unknown key."""
        if not isinstance(mapping, Mapping):
            raise ValueError(f"TrackerOptions: expected a mapping, got {type(mapping).__name__}")
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(map(str, mapping)) - set(names))
        if unknown:
            raise ValueError(f"TrackerOptions: unknown key {short_repr(unknown[0])}; expected "
                             f"some of {names}")
        return cls(**dict(mapping))


@dataclass(frozen=True)
class TrackerSnapshot:
    """Opaque, deep-copied state of a :class:`Tracker` (see :meth:`Tracker.snapshot`)."""

    method: str
    t: float
    _configuration: tuple = field(repr=False)
    _state: Any = field(repr=False, compare=False)


SNAPSHOT_FORMAT: Final = 10
"""Version of the state a :class:`TrackerSnapshot` holds (part of its configuration): raised
whenever the estimator's or the monitor's state changes shape, so that a snapshot pickled by
another version of kfusion is refused by :meth:`Tracker.restore` with a ValueError rather than
restored and failing later (2: the monitor's sorted horizon rows and per-fix caches; 3: the
time of the first fused frame, from which fixes test the model; 4: the running gap's peak
variance and last frames; 5: the implausible_value rejection counter; 6: the test of the
fixes before each occlusion; 7: the marker layout's residuals, ``KalmanSnapshot.layout``; 8:
the orientation innovations' mean, ``OrientationState.innovation_mean``, and the compiled
engine's orientation array of ``ORIENTATION_SIZE``; 9: the time of the last impact,
``KalmanSnapshot.last_impact_t`` and the compiled scalar ``LAST_IMPACT``, and the monitor's
scales for gaps near impacts; 10: the test of the fixes before each occlusion per span,
``MonitorParameters.longer_edges_s``)."""

_NUMERICAL_ERRORS: Final = (ArithmeticError, ValueError, np.linalg.LinAlgError)
"""What the estimator's maths may raise on overflowing numbers (math.sin(inf), singular S)."""

_STREAMS_SEEN: Final[dict[tuple[bool, bool], set[int]]] = {
    (False, False): set(), (True, False): {IMU_STREAM}, (False, True): {MOCAP_STREAM},
    (True, True): {IMU_STREAM, MOCAP_STREAM}}
"""The streams that delivered a sample, by (IMU seen, mocap seen); read only."""

_FUSED: Final = PushOutcome(True, ACCEPTED)
_FUSED_SATURATED: Final = PushOutcome(True, SATURATED)

# ---------------------------------------------------------------------------------------------
# Pure functions
# ---------------------------------------------------------------------------------------------


@lru_cache(maxsize=64)
def _chi2_3_quantile(confidence: float) -> float:
    """F^-1 of the chi-square distribution with 3 degrees of freedom (scipy, cached)."""
    from scipy.stats import chi2  # imported on first use: it costs ~0.3 s at start-up

    return float(chi2.ppf(confidence, 3))


def position_bound(covariance: ArrayLike, confidence: float = DEFAULT_CONFIDENCE) -> float:
    """Radius holding a Gaussian position error with probability >= ``confidence``, m.

    For e ~ N(0, Σ) (3-D), |e|^2 = Σ_i λ_i z_i^2 <= λ_max χ²_3 with z ~ N(0, I), so

        r = sqrt(λ_max(Σ) · F⁻¹_χ²(3)(confidence))

    gives P(|e| <= r) >= confidence: exact when Σ is isotropic, conservative otherwise (the
    right choice for a safety margin). ``math.inf`` when Σ is not finite (no uncertainty).

    Args:
        covariance: (3, 3) symmetric position covariance, m^2; ValueError when its largest
            eigenvalue is negative (not a covariance: a zero bound would be the unsafe answer).
        confidence: probability in (0, 1).
    """
    probability = checked_confidence(confidence)
    sigma = np.asarray(covariance, dtype=float)
    if sigma.shape != (3, 3):
        raise ValueError(f"covariance: expected shape (3, 3), got {sigma.shape}")
    if not np.isfinite(sigma).all():
        return math.inf
    largest = float(np.linalg.eigvalsh(0.5 * (sigma + sigma.T))[-1])
    if largest < 0.0:
        raise ValueError(f"covariance: its largest eigenvalue is {largest:.3g} < 0; expected a "
                         "positive semi-definite covariance")
    return math.sqrt(largest * _chi2_3_quantile(probability))


def checked_confidence(confidence: object) -> float:
    """``confidence`` as a float when it is a probability in (0, 1), else ValueError (also for
    a bool, and for an integer too large for a float)."""
    if isinstance(confidence, bool) or not isinstance(confidence, Real):
        raise ValueError(f"confidence: expected a probability in (0, 1), got "
                         f"{short_repr(confidence)}")
    try:
        probability = float(confidence)
    except OverflowError:
        probability = math.inf
    if not 0.0 < probability < 1.0:
        raise ValueError(f"confidence: expected a probability in (0, 1), got "
                         f"{short_repr(confidence)}")
    return probability


def _read_only(array: NDArray[np.float64]) -> NDArray[np.float64]:
    array.flags.writeable = False
    return array


def _describe(value: object, array: NDArray | None) -> str:
    if array is None or array.dtype.kind == "O":
        return f"{type(value).__name__}"
    if array.dtype.kind not in "fiu":
        return f"{type(value).__name__} of dtype {array.dtype} with shape {array.shape}"
    return f"shape {array.shape}"


def _vector(where: str, name: str, value: object, size: int, unit: str) -> NDArray[np.float64]:
    """``value`` as a new float array of shape (size,); ValueError for a wrong shape or type.

    Non-finite values pass (the caller rejects or interprets them).
    """
    if type(value) is np.ndarray and value.shape == (size,) and value.dtype is _FLOAT64:
        return value.copy()  # the common case, at IMU rate: a plain float64 array
    refuse_masked(f"{where}: {name}", value)
    try:
        array = np.asarray(value)
    except (TypeError, ValueError):
        array = None
    if array is None or array.shape != (size,) or array.dtype.kind not in "fiu":
        raise ValueError(f"{where}: {name}: expected {size} finite numbers ({unit}), got "
                         f"{_describe(value, array)}")
    return np.array(array, dtype=np.float64)


_FLOAT64: Final = np.dtype(np.float64)


_Three = tuple[float, float, float]
"""An IMU vector: specific force in m/s^2 or rate in rad/s, IMU frame."""


def _three(where: str, name: str, value: object, unit: str) -> _Three:
    """``value`` as 3 floats; ValueError as :func:`_vector` for a wrong shape or type (non-finite
    values pass). A plain float64 array (the common case, at IMU rate) is read without a copy:
    the floats are new objects the caller cannot change."""
    if type(value) is np.ndarray and value.shape == (3,) and value.dtype is _FLOAT64:
        x, y, z = value.tolist()
    else:
        x, y, z = _vector(where, name, value, 3, unit).tolist()
    return x, y, z


def _clock_time(reading: object, newest: float | None, tolerance_s: float) -> float:
    """The time ``estimate()`` reads from the Tracker's ``clock`` (s): ``reading``, or the
    ``newest`` fused sample's time when the reading is at most ``tolerance_s`` (s) behind it
    (stamps a little ahead of the caller's clock). ValueError when the reading is not a finite
    time, or further behind: a clock on another time base (``time.monotonic`` against stamps
    in Unix time) would otherwise read "now" as the newest sample forever, and an estimate
    would look current after the streams stopped."""
    t = _time("estimate", reading)
    if math.isnan(t) or t == -math.inf:
        raise ValueError(f"estimate: clock() returned {t!r}: expected the current time in s on "
                         f"the stamps' clock")
    if newest is not None and not t >= newest:
        if newest - t > tolerance_s:
            raise ValueError(f"estimate: clock() reads {t!r} s, {newest - t:.6g} s behind the "
                             f"newest sample ({newest!r} s), more than the larger of "
                             f"max_delay_s and fix_timeout_s ({tolerance_s:g} s): the clock "
                             f"must give the time on the stamps' clock")
        return newest
    return t


def _time(where: str, t: object) -> float:
    """``t`` as a float; ValueError when it is not a real number (NaN/inf pass)."""
    if type(t) is float:
        return t
    if isinstance(t, (bool, np.bool_)) or not isinstance(t, (Real, np.integer, np.floating)):
        if isinstance(t, np.ndarray) and t.shape == () and t.dtype.kind in "fiu":
            return float(t)
        raise ValueError(f"{where}: t: expected a time in s (a real number), got "
                         f"{type(t).__name__}")
    try:
        return float(t)  # type: ignore[arg-type]
    except OverflowError:  # an int (or Fraction) beyond the float range: an infinite time
        return math.inf if t > 0 else -math.inf  # type: ignore[operator]


# ---------------------------------------------------------------------------------------------
# Estimators behind one small interface
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Reading:
    """An estimator's state at one time, in new arrays: position (3,) m, velocity (3,) m/s,
    position covariance (3, 3) m^2 (symmetric) and its diagonal's square roots (3,) m; NaN
    where the method has none."""

    position: NDArray[np.float64]
    velocity: NDArray[np.float64]
    covariance: NDArray[np.float64]
    std: NDArray[np.float64]


class _Estimator(Protocol):
    method: str
    has_covariance: bool
    imu_latency_s: float
    max_bridge_s: float
    imu_dropout_s: float
    accelerometer_range: float

    def predict(self, t: float, accelerometer: _Three, gyroscope: _Three) -> None: ...

    def update(self, t: float, position: NDArray | None, quaternion: NDArray | None) -> str: ...

    def read(self, t: float, trust_model: bool = True,
             suspected_clock: tuple[float, float] | None = None) -> _Reading | None: ...

    def note_gap_frame(self, t: float,
                       suspected_clock: tuple[float, float] | None = None) -> None:
        """A frame at t (s) just processed, reported ``bridged``: its bound (with the timing
        term of a suspected clock offset, as :meth:`read`) joins the gap's peak, below which
        no later reading of the gap falls."""

    def finite(self) -> bool: ...

    def resets(self) -> int: ...

    def dead_reckoning_until(self) -> float: ...

    def orientation_gated(self) -> int: ...

    def snapshot(self) -> object:
        """The whole state, taken at mocap rate for the Tracker's checkpoints: keep it cheap."""

    def restore(self, snapshot: object) -> None:
        """Continue from ``snapshot``, sharing nothing mutable with it: the Tracker restores
        one checkpoint again and again and does not copy it first."""


class _BaselineEstimator:
    """:class:`kfusion.baseline.BaselineTracker` behind the tracker's interface (no covariance,
    no gate; its saturated samples are flagged but not treated differently)."""

    method = "baseline"
    has_covariance = False
    imu_latency_s = 0.0  # the paper's method has none

    def __init__(self, imu_to_body: NDArray, params: Any, accelerometer_range: float) -> None:
        from kfusion.baseline import BaselineTracker

        self._tracker = BaselineTracker(imu_to_body, params)
        self.max_bridge_s = float(params.max_bridge_s)
        self.imu_dropout_s = 0.1
        self.accelerometer_range = accelerometer_range
        self._imu_time: float | None = None
        self._imu_interval: float | None = None
        self._outage_since_fix = False

    def predict(self, t: float, accelerometer: _Three, gyroscope: _Three) -> None:
        if self._imu_time is not None:
            self._imu_interval = t - self._imu_time
            if self._imu_interval > self.imu_dropout_s:
                self._outage_since_fix = True  # the paper's method dead-reckons across it
        self._imu_time = t
        self._tracker.push_imu(t, accelerometer, gyroscope)

    def update(self, t: float, position: NDArray | None, quaternion: NDArray | None) -> str:
        if t > self.dead_reckoning_until():
            self._outage_since_fix = True
        if position is None or quaternion is None:
            # the paper's method needs the orientation at every fix
            self._tracker.push_mocap(t, None, None)
            return OCCLUDED
        self._tracker.push_mocap(t, position, quaternion)
        self._outage_since_fix = False
        return ACCEPTED

    def dead_reckoning_until(self) -> float:
        """As :func:`kfusion.streamhealth.dead_reckoning_until`, kept around the paper's
        method (which itself dead-reckons whatever the IMU does)."""
        return dead_reckoning_until(self._imu_time, hold_horizon(self._imu_interval,
                                                                 self.imu_dropout_s),
                                    self._outage_since_fix)

    def orientation_gated(self) -> int:
        return 0

    def read(self, t: float, trust_model: bool = True,
             suspected_clock: tuple[float, float] | None = None) -> _Reading | None:
        output = self._tracker.estimate(t)
        if output.status == LOST:
            return None
        nan3 = np.full(3, np.nan)
        return _Reading(np.array(output.position, dtype=float), nan3, np.full((3, 3), np.nan),
                        nan3)

    def note_gap_frame(self, t: float,
                       suspected_clock: tuple[float, float] | None = None) -> None:
        pass  # no bound

    def finite(self) -> bool:
        return True  # its state is rebuilt at every fix; the tracker checks every reading

    def resets(self) -> int:
        return 0

    def snapshot(self) -> object:
        return copy.deepcopy((self._tracker, self._imu_time, self._imu_interval,
                              self._outage_since_fix))

    def restore(self, snapshot: object) -> None:
        (self._tracker, self._imu_time, self._imu_interval,
         self._outage_since_fix) = copy.deepcopy(snapshot)  # type: ignore[misc]


class _KalmanEstimator:
    """:class:`kfusion.kalman.KalmanFusion` behind the tracker's interface.

    The tracker has already validated each event (finite, shapes, time order), so the fusion's
    own checks pass; its first fix (``initialised``) counts as fused.
    """

    method = "kalman"
    has_covariance = True

    def __init__(self, imu_to_body: NDArray, gravity: NDArray, params: Any,
                 lever_arm: NDArray | None, engine: str = "filterpy") -> None:
        from kfusion.kalman import KalmanFusion
        from kfusion.monitor import ConsistencyMonitor

        fusion_class: Any = KalmanFusion
        if engine == "compiled":  # numba loads here, on first use
            from kfusion.kalman.compiled_fusion import CompiledFusion

            fusion_class = CompiledFusion
        self._fusion = fusion_class(imu_to_body, gravity, params, lever_arm=lever_arm)
        # the compiled engine's predict without its second validation of a checked sample
        self._predict_valid_with = getattr(self._fusion, "predict_valid_with", None)
        # the consistency monitor (kfusion.monitor) with its shadow filter: scales the bound in
        # gaps as the shadow gaps showed it must, or refuses to bridge (read() gives None)
        self.monitor = ConsistencyMonitor(
            fusion_class(imu_to_body, gravity, params, lever_arm=lever_arm), gravity=gravity)
        self.max_bridge_s = float(params.max_bridge_s)
        self.imu_dropout_s = float(params.imu_dropout_s)
        self.accelerometer_range = float(params.accelerometer_range)
        self.imu_latency_s = float(params.imu_latency_s)
        # the monitor's state besides its shadow (ConsistencyMonitor.state_snapshot) changes
        # only at frames and restores: one copy serves the checkpoints in between
        self._monitor_state: object | None = None
        self._reckoning: float | None = None  # dead_reckoning_until() until the next event
        # the dead-reckoned velocity (3,) m/s right after the last fused fix (None before one):
        # a suspected clock offset's error in a gap grows with its change (read)
        self._fix_velocity: NDArray[np.float64] | None = None
        self._mocap_noise_variance = float(params.mocap_position_noise) ** 2  # R = this I, m^2
        # the largest per-axis variance (m^2) the frames of the running gap reported, 0 at a
        # fix (kfusion.kalman.batch.held_in_gaps): no reading of the gap falls below it; and
        # the horizons (s) of its last two bridged frames with the last one's time (s), for
        # the scale of the bin a reading after a frame has crossed from (batch.apply_monitor)
        self._gap_peak = 0.0
        self._gap_frames = _NO_GAP_FRAMES

    def predict(self, t: float, accelerometer: _Three, gyroscope: _Three) -> None:
        """A sample the tracker validated: t a finite float after the previous sample's stamp,
        accelerometer and gyroscope 3 finite floats each."""
        if self._predict_valid_with is not None:
            a0, a1, a2 = accelerometer
            g0, g1, g2 = gyroscope
            # the filter and, in a shadow gap, the monitor's shadow (compiled too) in one call
            self._reckoning = self._predict_valid_with(self.monitor.gap_shadow, t, a0, a1, a2,
                                                       g0, g1, g2)
            return
        self._reckoning = None
        self._fusion.predict(t, accelerometer, gyroscope)
        self.monitor.imu(t, accelerometer, gyroscope)

    def update(self, t: float, position: NDArray | None, quaternion: NDArray | None) -> str:
        self._reckoning = self._monitor_state = None
        prior = self._fusion.estimate(t) if self.monitor.wants_prior(t, position is not None) \
            else None
        outcome = self._fusion.update(t, position, quaternion)
        self.monitor.mocap(t, position, outcome, self._fusion, prior)
        if outcome.accepted:
            self._fix_velocity = self._fusion.x[VELOCITY].copy()
            self._gap_peak, self._gap_frames = 0.0, _NO_GAP_FRAMES
        return _KALMAN_OUTCOMES[outcome.kind]

    def update_markers(self, t: float, observed: NDArray, body: NDArray
                       ) -> tuple[str, int, int]:
        """Fuse a marker frame (:meth:`KalmanFusion.update_markers`); (reason, markers used,
        markers rejected). The monitor sees the markers' Kabsch origin as the frame's fix."""
        self._reckoning = self._monitor_state = None
        seen = bool(np.isfinite(observed).any())
        prior = self._fusion.estimate(t) if self.monitor.wants_prior(t, seen) else None
        outcome = self._fusion.update_markers(t, observed, body)
        origin = outcome.marker_origin
        self.monitor.mocap(t, None if origin is None else np.array(origin), outcome,
                           self._fusion, prior)
        if outcome.accepted:
            self._fix_velocity = self._fusion.x[VELOCITY].copy()
            self._gap_peak, self._gap_frames = 0.0, _NO_GAP_FRAMES
        return _KALMAN_OUTCOMES[outcome.kind], outcome.markers_used, outcome.markers_gated

    def read(self, t: float, trust_model: bool = True,
             suspected_clock: tuple[float, float] | None = None) -> _Reading | None:
        """The reading at t (s); ``trust_model`` False (the IMU clock refused,
        :mod:`kfusion.online_clock`) reads as when the monitor refuses the model;
        ``suspected_clock`` (offset s, 1-sigma s: a suspected clock offset,
        :attr:`kfusion.online_clock.OnlineClockCheck.suspected`) widens a gap's covariance by
        the timing error it implies (:func:`kfusion.online_clock.timing_error_covariance`) and
        a fix's to at least the fix's own
        (:func:`kfusion.online_clock.suspected_clock_fix_covariance`)."""
        if not self._fusion.initialised:
            return None
        step = self._fusion.estimate(t)  # new arrays
        covariance = step.position_covariance
        std = step.std
        if not (trust_model and self.monitor.bridging_allowed):
            # the monitor found the IMU model broken (NIS or shadow gaps far out of bounds),
            # or the clock watch the IMU clock: its predictions, and the fused posterior built
            # on them, are not trusted; at a fix the position is that fix alone (covariance
            # R), elsewhere it is unknown
            fix = self.monitor.fix_only(t)
            if fix is None:
                return None
            position, covariance = fix
            covariance = self._with_layout(self.monitor.cover_rivals(t, position, covariance))
            return _Reading(position, step.velocity, 0.5 * (covariance + covariance.T),
                            np.sqrt(np.diag(covariance)))
        if step.time_since_fix > 0.0:  # in a gap: the monitor's scale, never below the peak
            previous, latest_t, latest = self._gap_frames
            covariance = self._gap_covariance(t, step, previous if t == latest_t else latest,
                                              suspected_clock)
            factor, _ = held_at_frame(self._gap_peak, np.diag(covariance))
            if factor > 1.0:
                covariance = covariance * factor
        else:  # at a fix: fused with a prediction the shadow gaps may have found worse
            covariance = self.monitor.at_fix(t, covariance)
            if suspected_clock is not None:  # and whose timing error is unknown
                covariance = suspected_clock_fix_covariance(covariance,
                                                            self._mocap_noise_variance)
            covariance = covariance + self.monitor.cover_rivals(t, step.position, _ZERO_3X3)
            # the orientation's error times the lever (batch.monitored_output's order)
            covariance = covariance + step.orientation_covariance
        covariance = self._with_layout(covariance)
        std = np.sqrt(np.diag(covariance))
        return _Reading(step.position, step.velocity, 0.5 * (covariance + covariance.T), std)

    def _with_layout(self, covariance: NDArray[np.float64]) -> NDArray[np.float64]:
        """``covariance`` (3, 3) m^2 plus the marker layout's common error, last, as the batch
        filter adds it (:attr:`kfusion.kalman.filter.KalmanFusion.layout_variance`)."""
        variance = getattr(self._fusion, "layout_variance", 0.0)
        return covariance + variance * np.eye(3) if variance > 0.0 else covariance

    def _gap_covariance(self, t: float, step: Any, frame_horizon: float,
                        suspected_clock: tuple[float, float] | None
                        ) -> NDArray[np.float64]:
        """The position covariance (3, 3) m^2 at t (s) in a gap, before the gap's peak is held,
        from the filter's estimate ``step`` there: scaled by the monitor at its horizon or at
        ``frame_horizon`` (s, the gap's last bridged frame before t; 0 if none), whichever
        scale is larger, plus its rivals' part, formed alone and added in the batch recorder's
        order of operations (P + (d d^T + R), not (P + d d^T) + R), plus the orientation's
        part (:attr:`~kfusion.kalman.filter.FilterEstimate.orientation_covariance`): the two
        agree to the bit (:func:`kfusion.kalman.batch.monitored_output`); plus, with a
        suspected clock offset,
        the timing error it implies (the Tracker's alone: the batch filter has no clock
        watch)."""
        monitor = self.monitor
        scale = max(monitor.variance_scale(step.time_since_fix),
                    monitor.variance_scale(frame_horizon))
        covariance = step.position_covariance * scale
        covariance = covariance + monitor.cover_rivals(t, step.position, _ZERO_3X3)
        # the orientation's error times the lever, which no scale of the position filter's
        # covariance stands for, held with the rest
        covariance = covariance + step.orientation_covariance
        if suspected_clock is not None and self._fix_velocity is not None:
            change = self._fusion.x[VELOCITY] - self._fix_velocity
            covariance = covariance + timing_error_covariance(*suspected_clock, change)
        return covariance

    def note_gap_frame(self, t: float,
                       suspected_clock: tuple[float, float] | None = None) -> None:
        """A frame at t (s) reported ``bridged``: the largest per-axis variance of its
        covariance (with the timing term of ``suspected_clock``, as :meth:`read` adds it)
        joins the gap's peak (:func:`kfusion.monitor.held_at_frame`)."""
        if not self.monitor.bridging_allowed:
            return  # read() shows no bridged position
        step = self._fusion.estimate(t)
        if step.time_since_fix > 0.0:
            latest = self._gap_frames[2]
            _, self._gap_peak = held_at_frame(
                self._gap_peak,
                np.diag(self._gap_covariance(t, step, latest, suspected_clock)))
            self._gap_frames = (latest, t, step.time_since_fix)

    def finite(self) -> bool:
        kf = self._fusion._kf  # read only, without the public properties' copies
        return bool(np.isfinite(kf.x).all() and np.isfinite(kf.P).all())

    def resets(self) -> int:
        """Times the fusion forgot an overflowing state by itself (its ``resets`` counter)."""
        counter = getattr(self._fusion, "counter", None)  # the compiled engine's, no copies
        return int(self._fusion.counters["resets"] if counter is None else counter("resets"))

    def dead_reckoning_until(self) -> float:
        if self._reckoning is None:
            self._reckoning = self._fusion.dead_reckoning_until()
        return self._reckoning

    def orientation_gated(self) -> int:
        return int(self._fusion.counters["orientation_gated"])

    def snapshot(self) -> object:
        monitor = self.monitor
        if self._monitor_state is None:
            self._monitor_state = monitor.state_snapshot()
        # the shared state is never changed: ConsistencyMonitor.restore copies it
        # (the velocity array and the gap's tuple are never changed in place: shared safely)
        return (self._fusion.snapshot(), (self._monitor_state, monitor.shadow_snapshot()),
                self._fix_velocity, self._gap_peak, self._gap_frames)

    def restore(self, snapshot: object) -> None:
        self._reckoning = self._monitor_state = None
        self._fusion.restore(snapshot[0])  # type: ignore[index]
        self.monitor.restore(snapshot[1])  # type: ignore[index]
        self._fix_velocity = snapshot[2]  # type: ignore[index]
        self._gap_peak = snapshot[3]  # type: ignore[index]
        self._gap_frames = snapshot[4]  # type: ignore[index]


_NO_POSE: Final[tuple[NDArray[np.float64], NDArray[np.float64]]] = (np.full(3, np.nan),
                                                                     np.full(4, np.nan))
"""(origin, quaternion) of a frame with no rigid-body pose (read only)."""
for _array in _NO_POSE:
    _array.flags.writeable = False

_NO_GAP_FRAMES: Final = (0.0, -math.inf, 0.0)
"""(previous frame's horizon s, last frame's time s, its horizon s) of a gap with no bridged
frame yet: both horizons its fix's, 0."""

_ZERO_3X3: Final = np.zeros((3, 3))
"""Read-only zeros for :meth:`kfusion.monitor.ConsistencyMonitor.cover_rivals` (it returns a
new array)."""
_ZERO_3X3.flags.writeable = False

_KALMAN_OUTCOMES: Final = {"accepted": ACCEPTED, "initialised": INITIALISED,
                           "reacquired": REACQUIRED, "gated": GATED, "occluded": OCCLUDED}
"""kfusion.kalman's update outcomes -> the tracker's reasons."""


# ---------------------------------------------------------------------------------------------
# Bookkeeping that follows the fused event order (checkpointed with the estimator)
# ---------------------------------------------------------------------------------------------


@dataclass
class _Counts:
    """Counters decided by fusing, in event order (restored with checkpoints on replay)."""

    mocap_fused: int = 0
    mocap_occluded: int = 0
    gated: int = 0
    reacquisitions: int = 0
    time_tracked_s: float = 0.0
    time_bridged_s: float = 0.0
    time_lost_s: float = 0.0
    longest_gap_s: float = 0.0
    lost_transitions: int = 0
    state_resets: int = 0
    markers_used: int = 0
    markers_rejected: int = 0


@dataclass
class _Book:
    """Fix bookkeeping at the newest fused event."""

    key: tuple[float, int] | None = None  # (t, stream) of the newest fused event
    fix_time: float = -math.inf
    last_frame_fused: bool = False
    status: str = LOST
    counts: _Counts = field(default_factory=_Counts)

    def copy(self) -> _Book:
        counts = _Counts.__new__(_Counts)  # a plain field copy: this runs at mocap rate
        counts.__dict__.update(self.counts.__dict__)
        return _Book(self.key, self.fix_time, self.last_frame_fused, self.status, counts)


@dataclass
class _Checkpoint:
    key: tuple[float, int]
    estimator: object
    book: _Book


@dataclass
class _Stream:
    """Arrival-side state and counters of one input stream."""

    last_t: float = -math.inf
    last_values: tuple[ArrayLike, ArrayLike] | None = None  # IMU: 3-tuples; mocap: arrays
    pushed: int = 0
    accepted: int = 0
    rejected: dict[str, int] = field(default_factory=dict)
    saturated: int = 0
    longest_interval_s: float = 0.0
    # mocap only: the newest stamp of a frame that arrived in order (fused, or rejected for
    # its values), the last frame interval in cadence (s), and a frame waiting for jumping ahead
    # of it, waiting (its event and (position, quaternion) values), see Tracker._admit_frame
    cadence_t: float = -math.inf
    interval: float = math.inf
    waiting: tuple[tuple, tuple[ArrayLike, ArrayLike]] | None = None
    # mocap only: the latest visible poses (kept by a reset: a repeat is no measurement
    # whatever the estimator) and the frames that repeated one of them (read as occluded)
    recent: RecentPoses = field(default_factory=RecentPoses)
    held_poses: int = 0


def _locked(method: Any) -> Any:
    """Run a :class:`Tracker` method holding the tracker's lock (calls from several threads
    are serialised: each sees the state before or after another, never half-way)."""

    @functools.wraps(method)
    def wrapper(self: Tracker, *args: Any, **kwargs: Any) -> Any:
        with self._lock:
            return method(self, *args, **kwargs)

    return wrapper


# ---------------------------------------------------------------------------------------------
# The tracker
# ---------------------------------------------------------------------------------------------


class Tracker:
    """Streaming position tracker for one limb: IMU at its rate, mocap when seen.

    Args:
        imu_to_body: (4,) rotation IMU -> body, [w, x, y, z].
        gravity: (3,) gravity in the global (mocap) frame, m/s^2.
        method: ``"kalman"`` (default) or ``"baseline"`` (the paper's method; no uncertainty,
            so its bound is ``math.inf`` = unknown).
        imu: IMU profile name or :class:`kfusion.profiles.ImuProfile` (default ``mpu9255``);
            it sets the Kalman noise model and the accelerometer range.
        params: :class:`kfusion.kalman.KalmanParameters` or
            :class:`kfusion.baseline.BaselineParameters` matching ``method``, or a mapping of
            their fields (None: defaults from ``imu``).
        lever_arm: (3,) IMU position in the body frame, m (Kalman only), or None.
        options: :class:`TrackerOptions` or a mapping of its fields.
        imu_time_offset: s, and imu_clock_drift_ppm: the IMU's clock; :meth:`push_imu` maps
            its ``t`` onto the mocap clock with :func:`kfusion.conventions.imu_time_to_mocap`.
        clock: a function returning the current time in s *on the mocap clock* (the clock
            of :meth:`push_mocap`'s ``t`` and :meth:`estimate`'s; e.g. ``time.monotonic`` when
            the mocap frames are stamped with it). With an IMU on a clock of its own, do not
            pass the IMU's "now": it is ``imu_time_offset`` away from the mocap's. With it,
            :meth:`estimate` without ``t`` is the estimate now; without it, :meth:`estimate`
            needs ``t`` (an estimate is never presented as current when it is old).
        markers: ``{NAME: [bx, by, bz]}``, each marker's position in the body frame, m
            (``recording.yaml``'s ``markers``): needed by :meth:`push_markers` (Kalman only).
        engine: the Kalman filter's engine: ``compiled`` (default: :class:`kfusion.kalman.
            compiled_fusion.CompiledFusion`, numba step functions; numba loads on the first
            Tracker, and compiles once if its on-disk cache is empty) or ``filterpy``
            (:class:`kfusion.kalman.KalmanFusion`, the reference; the same results within
            rounding, tests/test_compiled_engine.py). Marker-level fusion (``markers``) has
            no compiled path yet: with ``markers`` the default is ``filterpy`` and
            ``compiled`` is refused.

    Thread safety: every public method holds the tracker's lock, and :meth:`estimate` and
    :attr:`health` do not change the state, so one thread may push while others read.

    Raises:
        ValueError: for any malformed argument, naming what was expected and what was given.
    """

    def __init__(
        self,
        imu_to_body: ArrayLike,
        gravity: ArrayLike,
        *,
        method: str = "kalman",
        imu: str | ImuProfile | None = None,
        params: Any = None,
        lever_arm: ArrayLike | None = None,
        options: TrackerOptions | Mapping[str, Any] | None = None,
        imu_time_offset: float = 0.0,
        imu_clock_drift_ppm: float = 0.0,
        clock: Callable[[], float] | None = None,
        markers: Mapping[str, ArrayLike] | None = None,
        engine: str | None = None,
    ) -> None:
        self.imu_clock = check_clock(imu_time_offset, imu_clock_drift_ppm, "Tracker")
        self._imu_clock_mapped = self.imu_clock != (0.0, 0.0)
        if clock is not None and not callable(clock):
            raise ValueError(f"Tracker: clock: expected a function returning the time in s, "
                             f"got {type(clock).__name__}")
        self._lock = threading.RLock()
        self._clock = clock
        q_body_imu = _vector("Tracker", "imu_to_body", imu_to_body, 4, "[w, x, y, z]")
        norm = float(vector_length(q_body_imu))
        if not np.isfinite(q_body_imu).all() or abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
            raise ValueError(f"Tracker: imu_to_body: expected a unit quaternion [w, x, y, z], "
                             f"got norm {norm:.6g}")
        gravity_vector = _vector("Tracker", "gravity", gravity, 3, "m/s^2")
        low, high = GRAVITY_MAGNITUDE_RANGE
        if not (np.isfinite(gravity_vector).all()
                and low <= vector_length(gravity_vector) <= high):
            raise ValueError(f"Tracker: gravity: expected a length of about 9.81 m/s^2 (between "
                             f"{low} and {high}), got {vector_length(gravity_vector):.4g}")
        lever = None if lever_arm is None else _vector("Tracker", "lever_arm", lever_arm, 3, "m")
        if lever is not None and not np.isfinite(lever).all():
            raise ValueError("Tracker: lever_arm: expected 3 finite numbers (m), got non-finite")
        if lever is not None and (length := vector_length(lever)) > MAX_LEVER_ARM_M:
            raise ValueError(f"Tracker: lever_arm: expected at most {MAX_LEVER_ARM_M:g} m long "
                             f"(m, not mm), got {length:.4g}")
        if engine is None:  # marker-level fusion has no compiled path yet
            engine = "filterpy" if markers else "compiled"
        if engine not in ("compiled", "filterpy"):  # kfusion.kalman.engines.ENGINES
            raise ValueError(f"Tracker: engine: expected 'compiled' or 'filterpy', got "
                             f"{short_repr(engine)}")
        if markers and engine == "compiled":
            raise ValueError("Tracker: engine 'compiled' has no marker-level fusion yet: leave "
                             "engine out or pass engine='filterpy' with markers")
        self.engine = engine
        if not isinstance(method, str) or method not in METHODS:
            raise ValueError(f"Tracker: method: expected one of {list(METHODS)}, got "
                             f"{short_repr(method)}")
        profile = imu if isinstance(imu, ImuProfile) else imu_profile(imu or "mpu9255")
        if isinstance(options, Mapping):
            options = TrackerOptions.from_mapping(options)
        elif options is None:
            options = TrackerOptions()
        elif not isinstance(options, TrackerOptions):
            raise ValueError(f"Tracker: options: expected TrackerOptions or a mapping, got "
                             f"{type(options).__name__}")
        self.method = method
        self.options = options
        self.params = _parameters(method, params, profile)
        self.imu_profile = profile
        self._imu_to_body = q_body_imu / norm
        self._gravity = gravity_vector
        self._lever_arm = lever
        self._marker_names, self._marker_body = _marker_body(markers)
        if self._marker_body is not None and isinstance(self.params, KalmanParameters):
            # a marker-level fix is the cluster's fitted origin: the monitor and a fix shown
            # alone take its noise, as in the batch filter
            self.params = marker_fix_parameters(self.params, self._marker_body)
        self._estimator = self._new_estimator()
        self.max_bridge_s = self._estimator.max_bridge_s
        if options.fix_timeout_s > self.max_bridge_s:
            raise ValueError(f"Tracker: options.fix_timeout_s: expected at most max_bridge_s "
                             f"({self.max_bridge_s} s), got {options.fix_timeout_s}")
        range_ = options.accelerometer_range
        if range_ is None:
            range_ = self._estimator.accelerometer_range
        self._saturation_level = 0.999 * range_
        self._watch = ImuWatch(self._estimator.imu_dropout_s)
        self._guard = TimeGuard(options.max_time_jump_s)
        self._resets = 0
        self._replays = 0
        self._log: deque[tuple] = deque()
        self._checkpoints: deque[_Checkpoint] = deque()
        self._pending: deque[tuple] = deque()  # deferred IMU samples, in time order
        self._rollback: tuple[float, int] | None = None  # key of the first behind fused frames
        self._newest: tuple[float, int] | None = None
        self._imu_newest = -math.inf  # time of the newest IMU event that arrived to be fused
        self._mocap_newest = -math.inf  # the same for frames, and the last frame period, s
        self._frame_period = math.inf
        # IMU samples up to this long past the next frame's expected time wait for it (s)
        self._hold_s = options.checkpoint_interval_s if options.max_delay_s > 0 else -math.inf
        self._clock_watch: OnlineClockCheck  # the online clock check (kfusion.online_clock)
        self._start_streams(keep_counters=False)

    # ---- construction helpers ---------------------------------------------------------------

    @classmethod
    def from_recording_info(cls, info: RecordingInfo, **kwargs: Any) -> Tracker:
        """A tracker for a recording's mounting (``imu_to_body``, ``gravity``, ``imu`` with its
        measured ``imu_noise``, ``lever_arm``, the IMU clock); ``kwargs`` as for the
        constructor and take precedence."""
        if not isinstance(info, RecordingInfo):
            raise ValueError(f"Tracker.from_recording_info: expected a RecordingInfo, got "
                             f"{type(info).__name__}")
        measured: dict[str, Any] = info.imu_noise.overrides() if info.imu_noise else {}
        kwargs.setdefault("imu", dataclasses.replace(imu_profile(info.imu or "mpu9255"),
                                                     **measured))
        kwargs.setdefault("imu_time_offset", info.imu_time_offset)
        kwargs.setdefault("imu_clock_drift_ppm", info.imu_clock_drift_ppm)
        if kwargs.get("method", "kalman") == "kalman":
            kwargs.setdefault("lever_arm", info.lever_arm)
            kwargs.setdefault("markers", info.markers)
        return cls(info.imu_to_body, info.gravity, **kwargs)

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any], *, source: str = "mapping") -> Tracker:
        """A tracker from a plain mapping with keys ``imu_to_body``, ``gravity`` (required),
        ``method``, ``imu``, ``lever_arm``, ``parameters`` (the method's fields),
        ``tracker`` (:class:`TrackerOptions` fields) and ``recording.yaml``'s clock model and
        measured noise (``imu_time_offset``, ``imu_clock_drift_ppm``, ``imu_noise``: they
        mean what they mean there) and its ``markers`` (for :meth:`push_markers`). ValueError
        names ``source`` and any unknown key."""
        if not isinstance(mapping, Mapping):
            raise ValueError(f"{source}: expected a mapping with keys {list(CONFIG_KEYS)}, got "
                             f"{type(mapping).__name__}")
        unknown = sorted(set(map(str, mapping)) - set(CONFIG_KEYS))
        if unknown:
            raise ValueError(f"{source}: unknown key {short_repr(unknown[0])}; expected some of "
                             f"{list(CONFIG_KEYS)}")
        for key in ("imu_to_body", "gravity"):
            if key not in mapping:
                raise ValueError(f"{source}: missing key {key!r}")

        def section(key: str, build: Any) -> Any:
            try:
                return build()
            except ValueError as error:
                raise ValueError(f"{source}: {key}: {error}") from None

        method = mapping.get("method", "kalman")
        if not isinstance(method, str) or method not in METHODS:
            raise ValueError(f"{source}: method: expected one of {list(METHODS)}, got "
                             f"{short_repr(method)}")
        imu = mapping.get("imu")
        profile = section("imu", lambda: imu_profile(imu or "mpu9255")) if not isinstance(
            imu, ImuProfile) else imu
        # the clock and noise keys as recording.yaml defines them, read by its own parser
        info = parse_info({key: mapping[key] for key in
                           ("imu_time_offset", "imu_clock_drift_ppm", "imu_noise", "markers")
                           if key in mapping}, source, require_mount=False)
        if info.imu_noise is not None:
            profile = dataclasses.replace(profile, **info.imu_noise.overrides())
        params = section("parameters",
                         lambda: _parameters(method, mapping.get("parameters"), profile))
        options = section("tracker", lambda: TrackerOptions.from_mapping(
            mapping.get("tracker") or {}))
        try:
            return cls(mapping["imu_to_body"], mapping["gravity"], method=method, imu=profile,
                       params=params, lever_arm=mapping.get("lever_arm"), options=options,
                       imu_time_offset=info.imu_time_offset,
                       imu_clock_drift_ppm=info.imu_clock_drift_ppm,
                       markers=info.markers if method == "kalman" else None)
        except ValueError as error:
            raise ValueError(f"{source}: {error}") from None

    @classmethod
    def from_yaml(cls, path: str | Path) -> Tracker:
        """A tracker from a YAML file (schema of :meth:`from_mapping`), such as a recording's
        ``recording.yaml``: its ``name`` (a label) is ignored, its ``markers`` (body-frame
        positions) serve :meth:`push_markers`."""
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"{path}: file not found")
        try:
            data = load_yaml(path)
        except YamlError as error:
            reason = f"not valid YAML ({error.reason})" if error.syntax else error.reason
            raise ValueError(f"{path}: {reason}") from None
        if isinstance(data, dict):
            data = {key: value for key, value in data.items() if key != "name"}
        return cls.from_mapping(data, source=str(path))

    def _new_estimator(self) -> _Estimator:
        if self.method == "kalman":
            return _KalmanEstimator(self._imu_to_body, self._gravity, self.params,
                                    self._lever_arm, self.engine)
        return _BaselineEstimator(self._imu_to_body, self.params,
                                  self.imu_profile.accelerometer_range)

    # ---- public API -------------------------------------------------------------------------

    @_locked
    def push_imu(self, t: float, acc: ArrayLike, gyro: ArrayLike) -> PushOutcome:
        """Feed one IMU sample.

        Args:
            t: sample time, s, on the IMU's own clock (mapped onto the mocap clock with
                ``imu_time_offset`` and ``imu_clock_drift_ppm``; with neither given the two
                clocks are one).
            acc: (3,) specific force, m/s^2, IMU frame.
            gyro: (3,) angular rate, rad/s, IMU frame.

        Returns:
            :class:`PushOutcome`; bad values are rejected and counted, never raised.

        Raises:
            ValueError: ``t`` not a real number, or ``acc``/``gyro`` not 3 numbers.
        """
        t = _time("push_imu", t)
        if self._imu_clock_mapped:  # onto the mocap clock (the one clock model)
            t = float(imu_time_to_mocap(t, *self.imu_clock))
        accelerometer = _three("push_imu", "acc", acc, "m/s^2")
        gyroscope = _three("push_imu", "gyro", gyro, "rad/s")
        stream = self._imu
        stream.pushed += 1
        a0, a1, a2 = accelerometer
        g0, g1, g2 = gyroscope
        isfinite = math.isfinite
        if not (isfinite(t) and isfinite(a0) and isfinite(a1) and isfinite(a2)
                and isfinite(g0) and isfinite(g1) and isfinite(g2)):
            return self._reject(stream, NON_FINITE)
        largest_force = max(abs(a0), abs(a1), abs(a2))  # m/s^2, also the saturation test
        if largest_force > MAX_ACCELEROMETER_VALUE \
                or max(abs(g0), abs(g1), abs(g2)) > MAX_GYROSCOPE_VALUE:
            return self._reject(stream, IMPLAUSIBLE_VALUE)
        if self._implausible(t, IMU_STREAM):
            return self._reject(stream, IMPLAUSIBLE_TIME)
        if t <= stream.last_t:
            return self._order_rejection(stream, t, (accelerometer, gyroscope))
        saturated = largest_force >= self._saturation_level
        # fused at the time the sample describes (kfusion.kalman.events: stamp - latency)
        time, _ = event_key(t, IMU_STREAM, self._estimator.imu_latency_s)
        if self._mocap.waiting is not None:
            self._release_waiting(time)
        if self._fuse((time, IMU_STREAM, accelerometer, gyroscope, saturated, t)) is None:
            return self._reject(stream, TOO_LATE)
        interval = t - stream.last_t  # inf for the first sample (after a reset too)
        if interval != math.inf and interval > stream.longest_interval_s:
            stream.longest_interval_s = interval
        self._watch.imu(time)
        self._clock_watch.imu((time, a0, a1, a2, g0, g1, g2))
        stream.last_t = t
        stream.last_values = (accelerometer, gyroscope)
        stream.accepted += 1
        if saturated:
            stream.saturated += 1
            return _FUSED_SATURATED
        return _FUSED

    @_locked
    def push_mocap(self, t: float, position: ArrayLike | None,
                   quaternion: ArrayLike | None) -> PushOutcome:
        """Feed one mocap frame.

        Args:
            t: frame time, s.
            position: (3,) rigid-body position, m, global frame; None or any NaN: occluded.
            quaternion: (4,) body -> global [w, x, y, z], or None / NaN (position-only fix).

        Returns:
            :class:`PushOutcome` (``accepted``, ``reacquired``, ``occluded``, ``gated`` or a
            rejection reason).

        Raises:
            ValueError: ``t`` not a real number, position not 3 numbers, quaternion not 4.
        """
        t = _time("push_mocap", t)
        nan_position = np.full(3, np.nan)
        point = nan_position if position is None else _vector(
            "push_mocap", "position", position, 3, "m")
        rotation = np.full(4, np.nan) if quaternion is None else _vector(
            "push_mocap", "quaternion", quaternion, 4, "[w, x, y, z]")
        stream = self._mocap
        stream.pushed += 1
        values = point.tolist()
        components = rotation.tolist()
        if not math.isfinite(t) or any(map(math.isinf, values + components)):
            self._frame_arrived(t)
            return self._reject(stream, NON_FINITE)
        if any(abs(value) > MAX_PLAUSIBLE_POSITION for value in values):  # (NaN compares False)
            self._frame_arrived(t)
            return self._reject(stream, IMPLAUSIBLE_VALUE)
        if self._implausible(t, MOCAP_STREAM):
            return self._reject(stream, IMPLAUSIBLE_TIME)
        if any(map(math.isnan, values)):
            point, rotation = nan_position, np.full(4, np.nan)
        elif any(map(math.isnan, components)):
            rotation = np.full(4, np.nan)
        else:
            norm = math.sqrt(sum(value * value for value in components))
            if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
                self._frame_arrived(t)
                return self._reject(stream, BAD_QUATERNION)
        if t <= stream.last_t:
            return self._order_rejection(stream, t, (point, rotation))
        pushed = (point, rotation)
        pose = None if math.isnan(values[0]) else pose_key(values, components)
        held = pose is not None and stream.recent.repeats(pose)
        if held:  # a recent frame's pose again: not a measurement, an occluded frame
            point, rotation = nan_position, np.full(4, np.nan)
        outcome = self._admit_frame((t, MOCAP_STREAM, point, rotation, False, t), pushed)
        if pose is not None and outcome.reason != TOO_LATE:
            stream.recent.add(pose)
        if held and outcome.reason == OCCLUDED:
            stream.held_poses += 1
        return outcome

    @_locked
    def push_markers(self, t: float, markers: Mapping[str, ArrayLike | None]) -> PushOutcome:
        """Feed one frame of individual markers (marker-level fusion, Kalman only).

        Each visible marker is a measurement of the body (``z_i = p + R m_i`` with m_i from the
        ``markers`` given to the constructor), so 1 or 2 visible markers still fix the
        position; 3 or more also give the orientation. Each marker is gated alone: a swapped
        marker is rejected (``health.markers_rejected``) while the others are fused. The frame
        takes a mocap frame's place in the fusion order (the mocap stream: push either
        ``push_mocap`` or ``push_markers`` at a time t, not both).

        Args:
            t: frame time, s (mocap clock).
            markers: ``{NAME: (3,) global position in m, or None}``; None, a NaN, or a name
                left out: that marker is occluded.

        Returns:
            :class:`PushOutcome`: ``accepted``/``reacquired`` when a marker was fused,
            ``occluded`` (no marker seen, or fewer than 3 before the first fix), ``gated``
            (every visible marker rejected), or a rejection (``non_finite`` for an inf,
            ``out_of_order``, ``duplicate``, ``too_late``, ``implausible_time``).

        Raises:
            ValueError: method ``baseline``, a tracker built without ``markers``, ``markers``
                not a mapping, an unknown marker name, or a value that is not None or 3 numbers
                (naming the marker).
        """
        t = _time("push_markers", t)
        if self.method != "kalman" or self._marker_body is None:
            raise ValueError("push_markers: expected a Kalman tracker built with markers={NAME: "
                             "[bx, by, bz]} (or from a recording.yaml with markers:), got "
                             + (f"method {self.method!r}" if self.method != "kalman"
                                else "no markers"))
        observed = _marker_frame(markers, self._marker_names)
        stream = self._mocap
        stream.pushed += 1
        if not math.isfinite(t) or np.isinf(observed).any():
            self._frame_arrived(t)
            return self._reject(stream, NON_FINITE)
        if (np.abs(observed) > MAX_PLAUSIBLE_POSITION).any():  # (NaN compares False)
            self._frame_arrived(t)
            return self._reject(stream, IMPLAUSIBLE_VALUE)
        if self._implausible(t, MOCAP_STREAM):
            return self._reject(stream, IMPLAUSIBLE_TIME)
        values = (observed, np.full(4, np.nan))  # no rigid-body orientation
        if t <= stream.last_t:
            return self._order_rejection(stream, t, values)
        return self._admit_frame((t, MOCAP_STREAM, observed, None, False, t, _MARKER_FRAME),
                                 values)

    def _admit_frame(self, event: tuple, values: tuple[ArrayLike, ArrayLike]) -> PushOutcome:
        """Fuse a validated frame in order after the stream's last one, unless it jumps ahead.

        A frame stamped more than :data:`CADENCE_JUMP` frame periods after the previous frame
        (the newest that arrived in order, whether fused or rejected for its values) and as far
        ahead of the newest IMU sample (the stamp of a frame whose counter or host
        clock glitched a few frames ahead: under ``max_time_jump_s``, so plausible) waits:
        fused at once, its stale pose would stand at a time the IMU has not reached, push the
        IMU samples behind it out as ``too_late`` and reject every true frame before its stamp
        ``out_of_order``. The next frame decides: stamped after it, the frames between were
        lost (the waiting frame is fused first, in its place); stamped before it, the waiting frame
        was the glitch (rejected ``implausible_time``) and the new one goes on in the cadence;
        at its stamp, the same values are a ``duplicate`` (the frame stays waiting), others a
        ``conflicting_duplicate`` (both rejected). An IMU sample past the waiting frame's time
        fuses it too (the mocap stopped after it). Frames in cadence, the first ones, and
        frames the IMU already covers (a client that leaves out occluded frames, an IMU
        latency) never wait. A frame 2 periods ahead (the stamp of the frame after next)
        is not caught: it is fused, the true frames up to its stamp rejected as before."""
        stream = self._mocap
        t = event[0]
        waiting = stream.waiting
        if waiting is not None:
            if t == waiting[0][0]:  # the waiting frame again: skipped, or both rejected
                if _same_values(values, waiting[1]):
                    return self._reject(stream, DUPLICATE)
                stream.waiting = None
                stream.rejected[IMPLAUSIBLE_TIME] += 1
                return self._reject(stream, CONFLICTING_DUPLICATE)
            stream.waiting = None
            if t < waiting[0][0]:
                stream.rejected[IMPLAUSIBLE_TIME] += 1
            elif self._fuse_frame(*waiting) is None:  # its outcome was reported as waiting
                stream.rejected[TOO_LATE] += 1
        step = t - stream.cadence_t  # after the newest frame that arrived in order
        jump = CADENCE_JUMP * stream.interval
        if step > jump and t - self._imu_newest > jump:
            stream.waiting = (event, values)
            return PushOutcome(False, WAITING)
        reason = self._fuse_frame(event, values)
        if reason is None:
            return self._reject(stream, TOO_LATE)
        if step > 0:
            stream.interval = step
        return PushOutcome(reason in FIXED, reason)

    def _frame_arrived(self, t: float) -> None:
        """A frame rejected for its values (not its stamp) still shows the mocap's cadence:
        its stamp, when finite and within ``max_time_jump_s`` after the newest one, is the
        newest that arrived (``_Stream.cadence_t``)."""
        stream = self._mocap
        if math.isfinite(t) and (stream.cadence_t == -math.inf or stream.cadence_t < t
                                 <= stream.cadence_t + self.options.max_time_jump_s):
            stream.cadence_t = t

    def _release_waiting(self, before: float) -> None:
        """Fuse the waiting frame when an IMU sample at ``before`` (s, its event time) passes it
        (``math.inf``: before a reset or a rebase forgets the streams, so that it is
        counted)."""
        stream = self._mocap
        waiting = stream.waiting
        if waiting is not None and waiting[0][0] < before:
            stream.waiting = None
            if self._fuse_frame(*waiting) is None:
                stream.rejected[TOO_LATE] += 1

    def _fuse_frame(self, event: tuple, values: tuple[ArrayLike, ArrayLike]) -> str | None:
        """Fuse a frame after the stream's last one and keep the stream's books; its outcome,
        or None (nothing changed) when too late to insert."""
        stream = self._mocap
        t = event[0]
        reason = self._fuse(event)
        if reason is None:
            return None
        stream.last_t, stream.last_values = t, values
        stream.cadence_t = max(stream.cadence_t, t)
        stream.accepted += 1
        self._watch.mocap(t)
        if event[-1] is not _MARKER_FRAME:
            self._clock_watch.mocap(t, event[2], event[3], reason in FIXED)
        elif self._clock_watch.enabled:  # timed on a fused frame's Kabsch pose
            fused = reason in FIXED
            origin, quaternion = self._marker_frame_pose(event[2]) if fused else _NO_POSE
            self._clock_watch.mocap(t, origin, quaternion, fused)
        return reason

    def _marker_frame_pose(self, observed: NDArray[np.float64]
                           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The rigid-body pose (origin (3,) m, quaternion (4,) [w, x, y, z]) of a marker frame
        (:func:`kfusion.kalman.markers.marker_pose`: 3 or more visible markers that fit the
        cluster), NaN when it has none."""
        from kfusion.kalman.markers import marker_pose

        assert self._marker_body is not None
        seen = np.isfinite(observed).all(axis=1)
        pose = marker_pose(observed[seen], self._marker_body[seen]) if seen.sum() >= 3 else None
        return _NO_POSE if pose is None else pose

    @_locked
    def estimate(self, t: float | None = None) -> Estimate:
        """The estimate at ``t``, the caller's current time in s on the stamps' clock.

        ``t`` may be omitted only for a tracker built with a ``clock``: the estimate is then at
        ``clock()`` (or at the newest fused sample, if that is later by at most the larger of
        ``max_delay_s`` and ``fix_timeout_s``). Without either there is
        no "now", and an estimate at the newest sample's time would look current after the
        streams stopped: ValueError. A later ``t`` than the newest sample extrapolates with the
        last IMU sample held (for at most ``imu_dropout_s``; later a gap is ``lost``) and ages
        ``time_since_fix``; the fused result is not changed (IMU samples waiting behind
        frames are fused first: :meth:`_flush`). NaN position before any fix.

        Raises:
            ValueError: ``t`` missing without a clock, not a real number, or earlier than the
                newest fused sample; a ``clock()`` reading that is NaN or more than the larger
                of ``max_delay_s`` and ``fix_timeout_s`` behind the newest fused sample (a
                clock on another time base).
        """
        if self._pending:
            self._flush()
        book = self._book
        if t is None:
            if self._clock is None:
                raise ValueError("estimate: t: expected the current time in s (the stamps' "
                                 "clock), got none; pass estimate(now) or build the Tracker "
                                 "with clock=")
            t = _clock_time(self._clock(), book.key[0] if book.key is not None else None,
                            max(self.options.max_delay_s, self.options.fix_timeout_s))
        else:
            t = _time("estimate", t)
            if book.key is not None and not t >= book.key[0]:
                raise ValueError(f"estimate: t: expected a time >= {book.key[0]!r} s (the "
                                 f"newest fused sample), got {t!r}")
        since = t - book.fix_time
        status = self._status_at(t)
        reading = None
        if status != LOST and math.isfinite(t):
            try:
                watch = self._clock_watch
                reading = self._estimator.read(t, not watch.refused, watch.suspected)
            except _NUMERICAL_ERRORS:
                reading = None
            if reading is not None and not _finite_reading(reading,
                                                            self._estimator.has_covariance):
                reading = None
        if reading is None:
            nan3 = _read_only(np.full(3, np.nan))
            return Estimate(t=t, position=nan3, velocity=nan3,
                            covariance=_read_only(np.full((3, 3), np.nan)), std=nan3,
                            status=LOST, time_since_fix=since, method=self.method)
        return Estimate(t=t, position=_read_only(reading.position),
                        velocity=_read_only(reading.velocity),
                        covariance=_read_only(reading.covariance), std=_read_only(reading.std),
                        status=status, time_since_fix=since, method=self.method)

    @property
    def imu_latency_s(self) -> float:
        """s subtracted from an IMU sample's stamp (on the mocap clock) to get the time it
        describes (:func:`kfusion.kalman.events.imu_event_time`): the Kalman parameters'
        ``imu_latency_s``, 0 for the baseline."""
        return self._estimator.imu_latency_s

    @property
    @_locked
    def newest_time(self) -> float:
        """Time (s) of the newest fused sample; NaN before any. Not "now": after the streams
        stop it stays put, so pass the caller's current time to :meth:`estimate`."""
        return math.nan if self._newest is None else self._newest[0]

    @property
    @_locked
    def consistency(self) -> MonitorReport | None:
        """What the consistency monitor found (:mod:`kfusion.monitor`: windowed NIS, shadow
        gaps, the bound's scale, whether it bridges, the suspected cause); None for the
        baseline."""
        self._flush()
        monitor = getattr(self._estimator, "monitor", None)
        if monitor is None:
            return None
        report = monitor.report()
        latest = self._clock_watch.latest
        if latest is not None and latest.problem:  # the online timing refused the IMU clock
            # or, timed again with the gyroscope's mount, found the mount off instead
            cause = IMU_MOTION if latest.mount_suspected else CLOCK
            return dataclasses.replace(report, bridging_allowed=False, suspected_cause=cause)
        return report

    @property
    @_locked
    def health(self) -> Health:
        """The health counters now (a frozen copy)."""
        self._flush()
        imu, mocap, book = self._imu, self._mocap, self._book
        counts = book.counts
        gap = counts.longest_gap_s
        if book.key is not None and math.isfinite(book.fix_time):
            gap = max(gap, book.key[0] - book.fix_time)
        mocap_rejected = dict(mocap.rejected)
        mocap_rejected[GATED] = counts.gated
        clock = self._clock_watch.latest
        return Health(
            imu_pushed=imu.pushed, imu_accepted=imu.accepted,
            imu_rejected=MappingProxyType(dict(imu.rejected)), imu_saturated=imu.saturated,
            imu_dropouts=self._watch.outages, longest_imu_interval_s=imu.longest_interval_s,
            mocap_pushed=mocap.pushed, mocap_fused=counts.mocap_fused,
            mocap_occluded=counts.mocap_occluded,
            mocap_rejected=MappingProxyType(mocap_rejected), gate_rejections=counts.gated,
            reacquisitions=counts.reacquisitions, time_tracked_s=counts.time_tracked_s,
            time_bridged_s=counts.time_bridged_s, time_lost_s=counts.time_lost_s,
            longest_gap_s=gap, lost_transitions=counts.lost_transitions,
            state_resets=counts.state_resets, replays=self._replays, resets=self._resets,
            orientation_gated=self._estimator.orientation_gated(),
            held_poses=mocap.held_poses,
            time_rebases=self._guard.rebases, markers_used=counts.markers_used,
            markers_rejected=counts.markers_rejected,
            clock_offset_s=math.nan if clock is None else clock.offset_s,
            clock_offset_std_s=math.nan if clock is None else clock.std_s,
            clock_problem="" if clock is None else clock.problem,
            clock_suspected=self._clock_watch.suspected is not None,
            mocap_waiting=int(mocap.waiting is not None),
        )

    @_locked
    def reset(self) -> None:
        """Forget the state and the stream history, as if newly constructed; the health
        counters keep counting (``health.resets`` counts the calls). The consistency monitor
        starts afresh too: nothing is bridged until 5 fixes have tested the model again and
        0.2 s have passed since the first fix after the reset
        (:attr:`kfusion.monitor.ConsistencyMonitor.model_tested`), so a gross configuration
        error is refused again at once, and a transient fault's evidence does not outlive the
        reset."""
        self._resets += 1
        self._release_waiting(math.inf)  # a waiting frame and the deferred samples count before
        self._flush()  # the state is forgotten
        self._estimator = self._new_estimator()
        self._start_streams(keep_counters=True)

    @_locked
    def snapshot(self) -> TrackerSnapshot:
        """A deep copy of the whole state (estimator, stream history, buffers, counters).

        :meth:`restore` into a tracker built with the same arguments continues bit-exactly.
        """
        self._flush()
        state = copy.deepcopy({
            "estimator": self._estimator.snapshot(), "book": self._book, "imu": self._imu,
            "mocap": self._mocap, "log": self._log, "checkpoints": self._checkpoints,
            "resets": self._resets, "replays": self._replays, "watch": self._watch,
            "guard": self._guard, "newest": self._newest,
            "horizons": (self._imu_newest, self._mocap_newest, self._frame_period),
            "clock_watch": self._clock_watch.state(),
        })
        newest = math.nan if self._book.key is None else self._book.key[0]
        return TrackerSnapshot(method=self.method, t=newest,
                               _configuration=self._configuration(), _state=state)

    @_locked
    def restore(self, snapshot: TrackerSnapshot) -> None:
        """Continue from ``snapshot`` (taken from a tracker built with the same arguments).

        Raises:
            ValueError: not a :class:`TrackerSnapshot`, or taken with other arguments or by a
                version of kfusion with another :data:`SNAPSHOT_FORMAT`.
        """
        if not isinstance(snapshot, TrackerSnapshot):
            raise ValueError(f"restore: expected a TrackerSnapshot, got "
                             f"{type(snapshot).__name__}")
        if snapshot._configuration != self._configuration():
            raise ValueError("restore: expected a snapshot from a tracker with the same method, "
                             "parameters, mounting and options (and this version of kfusion's "
                             "state format); got one from another")
        state = copy.deepcopy(snapshot._state)
        self._estimator.restore(state["estimator"])
        self._book = state["book"]
        self._imu, self._mocap = state["imu"], state["mocap"]
        self._log, self._checkpoints = state["log"], state["checkpoints"]
        self._resets, self._replays = state["resets"], state["replays"]
        self._watch, self._guard = state["watch"], state["guard"]
        self._newest, self._pending, self._rollback = state["newest"], deque(), None
        self._imu_newest, self._mocap_newest, self._frame_period = state["horizons"]
        self._clock_watch.restore(state["clock_watch"])

    @_locked
    def __repr__(self) -> str:
        self._flush()
        newest = None if self._book.key is None else self._book.key[0]
        return f"Tracker(method={self.method!r}, t={newest!r}, status={self._book.status!r})"

    # ---- internals ---------------------------------------------------------------------------

    def _configuration(self) -> tuple:
        return (SNAPSHOT_FORMAT, self.method, repr(self.params), self.imu_profile, self.options,
                tuple(self._imu_to_body), tuple(self._gravity),
                None if self._lever_arm is None else tuple(self._lever_arm),
                self._marker_names, None if self._marker_body is None
                else tuple(self._marker_body.ravel().tolist()))

    def _start_streams(self, *, keep_counters: bool) -> None:
        """Empty stream history, bookkeeping, event log and checkpoints (counters optional)."""
        if keep_counters:
            for stream in (self._imu, self._mocap):
                stream.last_t, stream.last_values = -math.inf, None
                stream.cadence_t, stream.interval, stream.waiting = -math.inf, math.inf, None
            self._book = _Book(counts=self._book.counts)
            self._watch.forget()
        else:
            self._imu = _Stream(rejected=dict.fromkeys(IMU_REJECTIONS, 0))
            self._mocap = _Stream(rejected=dict.fromkeys(MOCAP_REJECTIONS, 0))
            self._book = _Book()
        self._log = deque()
        self._checkpoints = deque()
        self._pending = deque()
        self._rollback = None
        self._newest = None
        self._imu_newest = self._mocap_newest = -math.inf
        self._frame_period = math.inf
        if keep_counters:  # a reset or a rebase: the clock's verdict stays
            self._clock_watch.forget_data()
        else:
            self._clock_watch = OnlineClockCheck(self._imu_to_body, self.options.clock_window_s
                                                 if self.method == "kalman" else 0.0)
        if self.options.max_delay_s > 0:
            self._checkpoints.append(_Checkpoint((-math.inf, -1), self._estimator.snapshot(),
                                                 self._book.copy()))

    def _implausible(self, t: float, stream: int) -> bool:
        """Judge a finite stamp against the newest time of both streams
        (:class:`kfusion.streamhealth.TimeGuard`): True to reject it. A confirmed jump restarts
        the streams from the new time (counted in ``health.time_rebases``)."""
        imu, mocap = self._imu.last_t, self._mocap.last_t
        present = imu if imu > mocap else mocap
        if self._guard.settled(t, present):
            return False
        seen = _STREAMS_SEEN[imu != -math.inf, mocap != -math.inf]
        verdict = self._guard.check(t, stream, present, seen)
        if verdict == REBASE:
            self._release_waiting(math.inf)  # a waiting frame and the deferred samples count
            self._flush()  # before the restart
            self._estimator = self._new_estimator()
            self._start_streams(keep_counters=True)
        return verdict == IMPLAUSIBLE

    def _reject(self, stream: _Stream, reason: str) -> PushOutcome:
        stream.rejected[reason] += 1
        return PushOutcome(False, reason)

    def _order_rejection(self, stream: _Stream, t: float,
                         values: tuple[ArrayLike, ArrayLike]) -> PushOutcome:
        """The rejection of a time not after the stream's last one (``t <= stream.last_t``)."""
        if t < stream.last_t or stream.last_values is None:
            return self._reject(stream, OUT_OF_ORDER)
        return self._reject(stream, DUPLICATE if _same_values(values, stream.last_values)
                            else CONFLICTING_DUPLICATE)

    def _fuse(self, event: tuple) -> str | None:
        """Fuse a validated event in time order; its outcome, or None if too late to insert.

        After the newest fused event (the common case): fused now. An IMU sample behind fused
        frames, after deferred samples, or up to ``checkpoint_interval_s`` past the time the
        next frame is expected at, is deferred (:meth:`_defer`). A frame fuses the
        deferred samples before it first (:meth:`_flush`), then is fused now, or inserted by
        :meth:`_insert` behind fused IMU samples (the late-arrival policy in the module
        docstring).
        """
        key = (event[0], event[1])
        if key[1] == IMU_STREAM:
            t = key[0]
            if t > self._imu_newest:
                self._imu_newest = t
            fused = self._book.key
            expected = self._mocap_newest + self._frame_period  # the next frame's time
            if self._pending or (fused is not None and key < fused) \
                    or expected < t <= expected + self._hold_s:
                return self._defer(event, key)
        elif key[0] > self._mocap_newest:
            self._frame_period = key[0] - self._mocap_newest  # inf after the first frame
            self._mocap_newest = key[0]
        if self._pending:
            self._flush(key)
        newest = self._newest
        if newest is None or key > newest:
            self._newest = key
            return self._fuse_next(event)
        if event[0] < newest[0] - self.options.max_delay_s:
            return None
        fused = self._book.key
        if fused is None or key > fused:  # behind deferred samples only: no state to undo
            return self._fuse_next(event)
        return self._insert(event, key)

    def _defer(self, event: tuple, key: tuple[float, int]) -> str | None:
        """Defer an IMU sample that arrived behind fused frames, after deferred samples or
        ahead of an expected frame: it waits (pending) until a frame arrives, the state is
        read (:meth:`_flush`), or the deferred samples span more than
        ``checkpoint_interval_s``. Behind fused frames, the
        checkpoint before it will be restored then (``_rollback``, its key), once for all
        the samples deferred. ``accepted``, or None when too late (older than ``max_delay_s``
        behind the newest event, or no checkpoint before it)."""
        newest = self._newest
        assert newest is not None  # a fused or pending event came before
        if event[0] < newest[0] - self.options.max_delay_s:
            return None
        fused = self._book.key
        if self._rollback is None and fused is not None and key < fused:  # behind frames
            if self._checkpoint_before(key) < 0:
                return None
            self._rollback = key
        pending = self._pending
        if key > newest:
            self._newest = key
        pending.append(event)  # the IMU stream is in order: pending stays sorted
        if event[0] - pending[0][0] > self.options.checkpoint_interval_s:
            self._flush()
        return ACCEPTED

    def _insert(self, event: tuple, key: tuple[float, int]) -> str | None:
        """Fuse a frame ``event`` (key ``key``) behind fused IMU samples: restore the newest
        checkpoint before it and fuse the logged events after that checkpoint again, with
        ``event`` in its place."""
        index = self._checkpoint_before(key)
        if index < 0:
            return None
        later = self._rewind(index)
        split = 0
        while split < len(later) and (later[split][0], later[split][1]) < key:
            self._fuse_next(later[split])
            split += 1
        outcome = self._fuse_next(event, late_frame=True)
        for logged in later[split:]:
            self._fuse_next(logged)
        return outcome

    def _checkpoint_before(self, key: tuple[float, int]) -> int:
        """Index of the newest checkpoint before ``key``; -1 when there is none."""
        checkpoints = self._checkpoints
        index = len(checkpoints) - 1
        while index >= 0 and not checkpoints[index].key < key:
            index -= 1
        return index

    def _rewind(self, index: int) -> list[tuple]:
        """Restore checkpoint ``index`` (dropping the newer ones) and take the logged events
        after it off the log: they are returned, in time order, to be fused again."""
        checkpoints = self._checkpoints
        checkpoint = checkpoints[index]
        while len(checkpoints) > index + 1:
            checkpoints.pop()
        self._estimator.restore(checkpoint.estimator)  # restore copies: the checkpoint stays
        self._book = checkpoint.book.copy()
        log = self._log
        later: list[tuple] = []
        while log and (log[-1][0], log[-1][1]) > checkpoint.key:
            later.append(log.pop())
        later.reverse()
        self._replays += 1
        return later

    def _flush(self, before: tuple[float, int] | None = None) -> None:
        """Fuse the deferred IMU samples (those with a key before ``before``; None: all),
        first restoring the checkpoint before the oldest when it arrived behind fused frames
        and fusing the frames again in their place."""
        pending = self._pending
        rollback = self._rollback
        if rollback is not None and (before is None or rollback < before):
            self._rollback = None
            index = self._checkpoint_before(rollback)  # one exists (_defer)
            taken = []
            while pending and (before is None or _event_key(pending[0]) < before):
                taken.append(pending.popleft())
            for event in sorted(self._rewind(index) + taken, key=_event_key):
                self._fuse_next(event)
            return
        while pending and (before is None or _event_key(pending[0]) < before):
            self._fuse_next(pending.popleft())

    def _fuse_next(self, event: tuple, *, late_frame: bool = False) -> str:
        """Fuse an event that comes after every fused one, log it and checkpoint around it.

        Checkpoints go where the next insertion will land: just before a frame while the IMU
        has not reached its time (an IMU sample may still arrive behind it); just after a frame
        that arrived late itself (``late_frame``: the next frame will too, and lands after it);
        and, while the frames are late, just before the first IMU sample past the time the
        next frame is expected at (the newest frame's time plus the last frame period), so a
        late frame re-predicts only the samples of its own lag."""
        if self.options.max_delay_s <= 0:
            return self._process(event)
        checkpoints = self._checkpoints
        book = self._book
        if book.key is not None and checkpoints[-1].key != book.key:
            t = event[0]
            if event[1] == MOCAP_STREAM:
                ahead = self._imu_newest < t
            else:
                expected = self._mocap_newest + self._frame_period
                ahead = book.key[0] <= expected < t
            if ahead:
                checkpoints.append(_Checkpoint(book.key, self._estimator.snapshot(),
                                               book.copy()))
        outcome = self._process(event)
        if late_frame:
            checkpoints.append(_Checkpoint(self._book.key, self._estimator.snapshot(),
                                           self._book.copy()))
        self._log_and_checkpoint(event)
        return outcome

    def _process(self, event: tuple) -> str:
        """Run one event (in time order) through the estimator and the bookkeeping.

        ``event`` is ``(t, stream, first, second, saturated, stamp)``: ``(t, stream)`` is the
        event's :func:`kfusion.kalman.events.event_key` (t: the time the event describes on the
        mocap clock, an IMU sample's stamp minus the latency), then accelerometer and gyroscope
        (3-tuples of floats) for the IMU, position (3,) and quaternion (4,) arrays (NaN when
        absent) for the mocap, and the stamp on the mocap clock (what the estimator is given).

        Inputs are validated, so over a normal interval a finite state stays finite. After a
        long interval (a dropout) or a saturated sample the model may overflow; the state is
        then checked (and after every mocap frame), and a non-finite state or a numerical error
        restarts the estimator, which takes this event as its first.
        """
        t, stream = event[0], event[1]
        book = self._book
        previous = t if book.key is None else book.key[0]
        if t > previous:
            self._account(previous, t)
            if book.status != LOST and self._status_at(t) == LOST:
                book.counts.lost_transitions += 1
                book.status = LOST
        estimator = self._estimator
        large = event[4] or t - previous > estimator.imu_dropout_s
        # only after a large interval, a saturated sample or a frame can the state overflow
        # (the inputs are validated): only then is it checked
        checked = large or stream == MOCAP_STREAM
        resets_before = estimator.resets() if checked else 0
        try:
            if large:
                with np.errstate(all="ignore"):
                    outcome = self._apply(event)
            else:
                outcome = self._apply(event)
            failed = checked and not estimator.finite()
        except _NUMERICAL_ERRORS:
            failed = True
        if failed:
            self._estimator = self._new_estimator()
            book.counts.state_resets += 1
            book.fix_time = -math.inf
            book.last_frame_fused = False
            outcome = self._apply(event)  # a fresh estimator: holds the sample or initialises
        elif checked and estimator.resets() > resets_before:
            # the estimator forgot an overflowing state itself: the same restart for the books
            book.counts.state_resets += 1
            book.fix_time = -math.inf
            book.last_frame_fused = False
        if stream == MOCAP_STREAM:
            self._count_fix(t, outcome)
        book.key = (t, stream)
        status = self._status_at(t)
        if status == LOST and book.status != LOST:
            book.counts.lost_transitions += 1
        book.status = status
        if stream == MOCAP_STREAM and status == BRIDGED:
            try:
                self._estimator.note_gap_frame(t, self._clock_watch.suspected)
            except _NUMERICAL_ERRORS:
                pass  # estimate() finds the same reading unusable (lost)
        return outcome

    def _apply(self, event: tuple) -> str:
        """The estimator's step for one event; its outcome (``accepted`` for an IMU sample)."""
        if event[1] == IMU_STREAM:
            self._estimator.predict(event[5], event[2], event[3])  # its stamp
            return ACCEPTED
        if event[-1] is _MARKER_FRAME:  # push_markers (a Kalman tracker with markers)
            assert isinstance(self._estimator, _KalmanEstimator)
            assert self._marker_body is not None
            reason, used, rejected = self._estimator.update_markers(event[0], event[2],
                                                                    self._marker_body)
            self._book.counts.markers_used += used
            self._book.counts.markers_rejected += rejected
            return reason
        position, quaternion = event[2], event[3]
        return self._estimator.update(event[0], None if math.isnan(position[0]) else position,
                                      None if math.isnan(quaternion[0]) else quaternion)

    def _count_fix(self, t: float, outcome: str) -> None:
        """Fix bookkeeping after a mocap frame's outcome."""
        book = self._book
        counts = book.counts
        if outcome in FIXED:
            counts.mocap_fused += 1
            counts.reacquisitions += outcome == REACQUIRED
            if book.fix_time != -math.inf:
                counts.longest_gap_s = max(counts.longest_gap_s, t - book.fix_time)
            book.fix_time = t
            book.last_frame_fused = True
        else:
            if outcome == OCCLUDED:
                counts.mocap_occluded += 1
            else:
                counts.gated += 1
            book.last_frame_fused = False

    def _status_at(self, t: float) -> str:
        book = self._book
        return tracking_status(t - book.fix_time, book.last_frame_fused,
                               fix_timeout_s=self.options.fix_timeout_s,
                               max_bridge_s=self.max_bridge_s,
                               beyond_dead_reckoning=t > self._estimator.dead_reckoning_until())

    def _account(self, start: float, end: float) -> None:
        """Add the time from ``start`` to ``end`` (no fix inside) to the status durations."""
        book = self._book
        if book.last_frame_fused and end - book.fix_time <= self.options.fix_timeout_s:
            book.counts.time_tracked_s += end - start  # fast path of status_durations
            return
        tracked, bridged, lost = status_durations(
            start, end, book.fix_time, book.last_frame_fused,
            fix_timeout_s=self.options.fix_timeout_s, max_bridge_s=self.max_bridge_s,
            reckoning_until=self._estimator.dead_reckoning_until())
        book.counts.time_tracked_s += tracked
        book.counts.time_bridged_s += bridged
        book.counts.time_lost_s += lost

    def _log_and_checkpoint(self, event: tuple) -> None:
        """Keep the fused event and checkpoints for insertions within ``max_delay_s``; prune.

        Checkpoints: around mocap frames (:meth:`_fuse_next`), and after an IMU sample when
        the newest checkpoint is ``checkpoint_interval_s`` old. The newest
        checkpoint at or before ``t - max_delay_s`` and everything after it are kept; the log
        holds the events after the oldest one.
        """
        t = event[0]
        log = self._log
        log.append(event)
        checkpoints = self._checkpoints
        if event[1] == IMU_STREAM and t - checkpoints[-1].key[0] >= \
                self.options.checkpoint_interval_s:
            checkpoints.append(_Checkpoint((t, IMU_STREAM), self._estimator.snapshot(),
                                           self._book.copy()))
        horizon = t - self.options.max_delay_s
        if len(checkpoints) > 1 and checkpoints[1].key[0] <= horizon:
            while len(checkpoints) > 1 and checkpoints[1].key[0] <= horizon:
                checkpoints.popleft()
            oldest = checkpoints[0].key
            while log and (log[0][0], log[0][1]) <= oldest:
                log.popleft()


CONFIG_KEYS: Final = ("imu_to_body", "gravity", "method", "imu", "lever_arm", "parameters",
                      "tracker", "imu_time_offset", "imu_clock_drift_ppm", "imu_noise", "markers")
"""Keys of a tracker YAML file (:meth:`Tracker.from_yaml`)."""


def _parameters(method: str, params: Any, profile: ImuProfile) -> Any:
    """The estimator's parameter object from an object, a mapping or None."""
    if method == "kalman":
        from kfusion.kalman import KalmanParameters

        if params is None:
            return KalmanParameters.from_profiles(profile)
        if isinstance(params, KalmanParameters):
            return params
        if isinstance(params, Mapping):
            values = dict(params)
            values.setdefault("imu", profile)
            return KalmanParameters.from_mapping(values)
        raise ValueError(f"Tracker: params: expected KalmanParameters or a mapping for method "
                         f"'kalman', got {type(params).__name__}")
    from kfusion.baseline import BaselineParameters

    if params is None:
        return BaselineParameters()
    if isinstance(params, BaselineParameters):
        return params
    if isinstance(params, Mapping):
        return BaselineParameters.from_mapping(params)
    raise ValueError(f"Tracker: params: expected BaselineParameters or a mapping for method "
                     f"'baseline', got {type(params).__name__}")


def _event_key(event: tuple) -> tuple[float, int]:
    """An event's (t, stream): its place in the fusion order."""
    return event[0], event[1]


def _same_values(new: tuple[ArrayLike, ...], old: tuple[ArrayLike, ...]) -> bool:
    """Two pushes' values (the same shapes) equal element for element, NaN matching NaN: an
    identical duplicate."""
    return all(np.array_equal(a, b, equal_nan=True) for a, b in zip(new, old, strict=True))


def _finite_reading(reading: _Reading, has_covariance: bool) -> bool:
    """Position finite, and the covariance too if the method has one, with every variance
    >= 0 (the rule of :func:`kfusion.track_file.bounded_rows`: a covariance rounded below
    zero is no bound)."""
    if not np.isfinite(reading.position).all():
        return False
    covariance = reading.covariance
    return not has_covariance or bool(np.isfinite(covariance).all()
                                      and (np.diag(covariance) >= 0.0).all())



_MARKER_FRAME: Final = "markers"
"""Last item of a :meth:`Tracker.push_markers` event (a mocap-stream event of its own kind)."""


def _marker_body(markers: Mapping[str, ArrayLike] | None
                 ) -> tuple[tuple[str, ...], NDArray[np.float64] | None]:
    """Names and body-frame positions (n, 3) m of the constructor's ``markers``; ValueError
    naming a bad entry."""
    if markers is None:
        return (), None
    if not isinstance(markers, Mapping) or not markers:
        raise ValueError(f"Tracker: markers: expected a mapping NAME -> [bx, by, bz] (m), got "
                         f"{short_repr(markers)}")
    names = tuple(str(name) for name in markers)
    body = np.array([_vector("Tracker", f"markers[{name!r}]", markers[name], 3, "m")
                     for name in markers])
    if not np.isfinite(body).all():
        bad = names[int(np.flatnonzero(~np.isfinite(body).all(axis=1))[0])]
        raise ValueError(f"Tracker: markers[{bad!r}]: expected 3 finite numbers (m)")
    for name, position in zip(names, body, strict=True):
        problem = marker_offset_problem(position)
        if problem is not None:
            raise ValueError(f"Tracker: markers[{name!r}]: {problem}")
    body.flags.writeable = False
    return names, body


def _marker_frame(markers: object, names: tuple[str, ...]) -> NDArray[np.float64]:
    """A push_markers frame as (n, 3) m in the constructor's marker order, NaN where a marker
    is None, NaN or left out; ValueError naming an unknown marker or a malformed value."""
    if not isinstance(markers, Mapping):
        raise ValueError(f"push_markers: markers: expected a mapping NAME -> (3,) position in m "
                         f"or None, got {type(markers).__name__}")
    observed = np.full((len(names), 3), np.nan)
    index = {name: i for i, name in enumerate(names)}
    for name, value in markers.items():
        if name not in index:
            raise ValueError(f"push_markers: unknown marker {short_repr(name)}; expected names "
                             f"from {list(names)}")
        if value is not None:
            observed[index[name]] = _vector("push_markers", f"markers[{name!r}]", value, 3, "m")
    return observed
