"""Stream health: is the IMU alive, are the stamps plausible, do the fixes agree with the IMU?

Every estimate kfusion gives must be ``lost`` or carry a bound that holds the truth at its stated
confidence, even when an assumption breaks (GUIDE §10). This module holds the rules that decide
it when the *streams* misbehave, in small pure functions and two thin classes, shared by the
streaming filter (:mod:`kfusion.kalman.filter`), the batch driver and smoother
(:mod:`kfusion.kalman.batch`, :mod:`kfusion.kalman.smoother`) and the
:class:`kfusion.tracker.Tracker`:

* **IMU alive.** Dead reckoning needs IMU samples. The last sample is held for at most
  ``imu_dropout_s`` after its time; past that there is no IMU (nothing or a stalled stream). Over
  an interval without IMU the position filter moves by :func:`no_imu_transition` and
  :func:`no_imu_process_noise`: constant velocity driven by white acceleration of density
  :data:`NO_IMU_ACCELERATION_DENSITY`, an honest model of a limb's motion between fixes, so good
  fixes pass the gate and the position comes from them. A gap in which the IMU was missing is
  never bridged: :func:`dead_reckoning_until` and :func:`tracking_status` make it ``lost``.
* **Stamps plausible.** :class:`TimeGuard` rejects a stamp implausibly far ahead of the newest
  time of both streams and recovers by itself when the streams really jumped (several consistent
  samples) or when the present was itself a glitch (samples of every stream far behind it).
* **Orientation fixes.** :func:`orientation_gated` gates a mocap orientation against the
  gyroscope-propagated one.
* **Held poses.** A frame repeating a recent frame's pose bit for bit (:func:`repeats_pose`)
  is not a measurement: a pose held through an occlusion by a client repeating the last value,
  read as occluded.
* **Outages counted.** :class:`ImuWatch` counts IMU outages once each, whether they end with a
  late sample or are seen from the mocap stream while the IMU is silent.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import NDArray

from kfusion.conventions import BRIDGED, LOST, TRACKED

NO_IMU_ACCELERATION_DENSITY: Final = 30.0
"""White acceleration density (m/s^2/sqrt(Hz)) of the no-IMU motion model.

Between two fixes dt apart, a constant-velocity model with white acceleration of density q gives
the position a variance ``q^2 dt^3 / 3``: 1.7 mm (1 sigma) at dt = 10 ms for q = 30, the distance
a constant 35 m/s^2 moves a limb in 10 ms. Fast arm motion peaks at about 30-50 m/s^2 (BROAD's
fastest trials), so a fix after such motion lies inside the 0.9999 gate; the model is only used
while fixes arrive (without IMU a gap is ``lost``), so its looseness costs nothing in a gap."""

ORIENTATION_GATE_MIN_ANGLE: Final = math.radians(10.0)
"""rad. An orientation fix that differs from the gyroscope-propagated orientation by at most this
is never gated (the analogue of ``gate_min_innovation``): a flipped or mis-solved rigid body is
off by tens of degrees, while a briefly over-confident orientation is off by a few."""

HOLD_INTERVALS: Final = 3.0
HOLD_MIN_S: Final = 0.02
"""How long the last IMU sample may be held without a newer one: ``HOLD_INTERVALS`` of the last
interval between samples, at least ``HOLD_MIN_S`` s, at most ``imu_dropout_s``
(:func:`hold_horizon`). Holding it longer is dead reckoning on a stale acceleration: on the
simulator a sample held for 0.1 s in fast motion gave errors of 3-8 mm against a 99 % bound
of 0.4-0.8 mm. 20 ms leaves room for the few ms one stream lags the other."""

FIX_TIMEOUT_S: Final = 0.05
"""s. Default ``fix_timeout_s`` of :func:`tracking_status`: after a fused fix the status stays
``tracked`` this long (five frames at 100 Hz) while no newer frame arrives; the Tracker's
``TrackerOptions.fix_timeout_s`` may change it."""

DEFAULT_MAX_TIME_JUMP_S: Final = 0.25
"""s. Default :class:`TimeGuard` threshold: a stamp this far beyond the newest time of both
streams is implausible. The streams sample at 100-1000 Hz and one stream's outage leaves the
other's time as the present, so only a pause of both exceeds it; that is confirmed by
:data:`DEFAULT_CONFIRM_SAMPLES` consistent samples (the first two are dropped). A glitch
*below* it is accepted and can hold the streams back by up to that long."""

DEFAULT_CONFIRM_SAMPLES: Final = 3
"""Consistent samples that confirm a time jump as real (:class:`TimeGuard`)."""


# ---------------------------------------------------------------------------------------------
# IMU alive: the dead-reckoning horizon and the status rule
# ---------------------------------------------------------------------------------------------


def hold_horizon(imu_interval: float | None, imu_dropout_s: float) -> float:
    """How long (s) the last IMU sample may be held:
    ``min(imu_dropout_s, max(HOLD_MIN_S, HOLD_INTERVALS * imu_interval))`` (``HOLD_MIN_S``
    while the interval is unknown)."""
    if imu_interval is None or not math.isfinite(imu_interval):
        return min(imu_dropout_s, HOLD_MIN_S)
    return min(imu_dropout_s, max(HOLD_MIN_S, HOLD_INTERVALS * imu_interval))


def dead_reckoning_until(imu_time: float | None, hold_s: float,
                         outage_since_fix: bool) -> float:
    """The time (s) up to which the state may be dead-reckoned from the IMU.

        -inf               no IMU sample yet, or an interval without IMU since the last fix
                           (the gap's state is not IMU-propagated)
        imu_time + hold_s  otherwise: the last sample is held for at most that long
                           (:func:`hold_horizon`)
    """
    if imu_time is None or outage_since_fix:
        return -math.inf
    return imu_time + hold_s


def tracking_status(time_since_fix: float, last_frame_fused: bool, *, fix_timeout_s: float,
                    max_bridge_s: float, beyond_dead_reckoning: bool = False) -> str:
    """The status rule, the one place it is written. Every estimator uses it: the filter's
    :meth:`~kfusion.kalman.KalmanFusion.estimate`, the batch driver and the smoother
    (:func:`kfusion.kalman.batch.status_from_fixes`, :func:`kfusion.kalman.smoother.
    smoother_status`), the :class:`kfusion.tracker.Tracker` and the paper's baseline.

        tracked  if the last frame was fused and time_since_fix <= fix_timeout_s
        lost     if time_since_fix > max_bridge_s, or the time is beyond the dead-reckoning
                 horizon (:func:`dead_reckoning_until`: no IMU to bridge with)
        bridged  otherwise

    ``time_since_fix`` (s) runs from the last fused fix; it is inf before the first fix and
    whenever the estimator has no state to go from (a reset), so those times are lost. The
    smoother, which also sees the fixes after a row, measures from the last fix as well
    (:func:`kfusion.kalman.smoother.smoother_status`). At a row of ``kfusion track`` the last
    frame is the row's own, so a row is tracked exactly when its fix was used.
    ``fix_timeout_s`` is :data:`FIX_TIMEOUT_S` unless the Tracker's options change it;
    ``fix_timeout_s <= max_bridge_s``, so the order of the first two lines only matters for the
    IMU: a fused fix is tracked whether or not the IMU is alive. Beyond this rule, the
    consistency monitor (:mod:`kfusion.monitor`) may turn a bridged estimate lost when it finds
    the IMU model broken.
    """
    if last_frame_fused and time_since_fix <= fix_timeout_s:
        return TRACKED
    if not time_since_fix <= max_bridge_s or beyond_dead_reckoning:
        return LOST
    return BRIDGED


def status_durations(start: float, end: float, fix_time: float, last_frame_fused: bool, *,
                     fix_timeout_s: float, max_bridge_s: float,
                     reckoning_until: float = math.inf) -> tuple[float, float, float]:
    """Time (s) spent tracked, bridged and lost over [start, end] with no new fix inside.

    With f = fix_time (``-inf`` before any fix), :func:`tracking_status` is tracked on
    [f, f + fix_timeout_s] (only if the last frame was fused), bridged up to
    ``min(f + max_bridge_s, reckoning_until)``, and lost after; the result is the length of each
    of those intervals within [start, end].
    """
    tracked_end = fix_time + (fix_timeout_s if last_frame_fused else 0.0)
    bridged_end = min(fix_time + max_bridge_s, reckoning_until)

    def overlap(low: float, high: float) -> float:
        return max(0.0, min(end, high) - max(start, low))

    tracked = overlap(fix_time, tracked_end) if last_frame_fused else 0.0
    bridged = overlap(tracked_end, bridged_end)
    lost = (end - start) - tracked - bridged
    return tracked, bridged, max(lost, 0.0)


# ---------------------------------------------------------------------------------------------
# The no-IMU motion model (position filter, states [p, v, b, (l)])
# ---------------------------------------------------------------------------------------------


def no_imu_transition(dt: float, size: int) -> NDArray[np.float64]:
    """F (size, size) of the no-IMU model over dt (s): ``p' = p + v dt``, ``v' = v``, ``b' = b``
    (the accelerometer bias does not enter: no accelerometer is used)."""
    F = np.eye(size)
    F[0, 3] = F[1, 4] = F[2, 5] = dt
    return F


def no_imu_process_noise(dt: float, size: int, bias_random_walk: float,
                         density: float = NO_IMU_ACCELERATION_DENSITY) -> NDArray[np.float64]:
    """Q (size, size) of the no-IMU model over dt (s): continuous white acceleration of
    ``density`` q (m/s^2/sqrt(Hz)) per axis, and the bias random walk sigma_b::

        Q_pp = q^2 dt^3 / 3,  Q_pv = q^2 dt^2 / 2,  Q_vv = q^2 dt,  Q_bb = sigma_b^2 dt
    """
    Q = np.zeros((size, size))
    q2 = density * density
    eye = np.eye(3)
    interval = np.float64(dt)  # an absurd dt overflows to inf (the caller resets), never raises
    with np.errstate(over="ignore", invalid="ignore"):
        Q[0:3, 0:3] = q2 * interval ** 3 / 3.0 * eye
        Q[0:3, 3:6] = Q[3:6, 0:3] = q2 * interval ** 2 / 2.0 * eye
        Q[3:6, 3:6] = q2 * interval * eye
        Q[6:9, 6:9] = bias_random_walk * bias_random_walk * interval * eye
    return Q


def imu_interval_split(state_time: float, t: float, imu_time: float | None,
                       imu_dropout_s: float, hold_s: float, new_sample: bool) -> float:
    """Where an interval [state_time, t] stops being covered by the IMU (s).

    A new sample at t after a dropout (``t - imu_time > imu_dropout_s``) covers nothing (no
    interpolation across the dropout): returns ``state_time``; after a shorter interval the
    two samples cover it all (first-order hold between them). Without a new sample the held
    sample covers up to ``imu_time + hold_s``. Without any sample: ``state_time``. The result
    is clipped to [state_time, t].
    """
    if imu_time is None:
        return state_time
    if new_sample:
        return t if t - imu_time <= imu_dropout_s else state_time
    return min(max(imu_time + hold_s, state_time), t)


# ---------------------------------------------------------------------------------------------
# Orientation fixes against the gyroscope
# ---------------------------------------------------------------------------------------------


ORIENTATION_UNKNOWN_VARIANCE: Final = math.pi ** 2 / 3.0
"""rad^2 per axis: the variance of an angle uniform on [-pi, pi], the orientation's variance
after an interval without gyroscope (the next mocap orientation is then taken as it is)."""


def orientation_gated(innovation: tuple[float, float, float], angle_variance: float,
                      measurement_variance: float, threshold: float,
                      min_angle: float = ORIENTATION_GATE_MIN_ANGLE) -> bool:
    """True when a mocap orientation disagrees with the gyroscope-propagated one.

    ``innovation`` is ``Log(q_est^-1 ⊗ q_mocap)`` (rad, 3). Per axis its variance is
    ``S = P_tt + sigma_m^2`` (angle variance of the estimate plus the mocap's), so

        NIS = |innovation|^2 / S  ~  chi-square(3)

    and the fix is gated when NIS > ``threshold`` (the position gate's quantile) *and* the angle
    exceeds ``min_angle``.
    """
    angle_squared = innovation[0] ** 2 + innovation[1] ** 2 + innovation[2] ** 2
    if angle_squared <= min_angle * min_angle:
        return False
    S = angle_variance + measurement_variance
    return not (S > 0.0 and angle_squared / S <= threshold)


RECENT_POSES: Final = 10
"""How many of the latest visible frames a new frame's pose is compared with
(:class:`RecentPoses`): a client repeating the last value, cycling through its last few, or
alternating a held value with NaN frames, repeats one of them."""


Pose = tuple[float, ...]
"""A frame's pose as a key compared bit for bit: ``(x, y, z, w, qx, qy, qz)``, or ``(x, y, z)``
without a quaternion (:func:`pose_key`)."""


def pose_key(position: Sequence[float] | NDArray[np.float64],
             quaternion: Sequence[float] | NDArray[np.float64]) -> Pose:
    """The :data:`Pose` of a frame: ``position`` (3,) m and ``quaternion`` (4,) (any NaN:
    none), arrays or lists, as Python floats, so that two keys are equal exactly when the
    frames repeat."""
    values = [float(value) for value in position]
    rotation = [float(value) for value in quaternion]
    return tuple(values if any(math.isnan(value) for value in rotation) else values + rotation)


def repeats_pose(pose: Pose, recent: Sequence[Pose]) -> bool:
    """True when a frame's ``pose`` (:func:`pose_key`) equals one of the ``recent`` poses
    (those of the latest visible frames, :class:`RecentPoses`) bit for bit, a missing
    quaternion matching a missing one.

    Such a frame is not a measurement. A sensor with noise never gives the same pose twice:
    the repeat is a pose held through an occlusion (a streaming client repeating the last
    value, NatNet's untracked rigid body read without its valid flag, NaN filled forward, a
    client cycling through its last frames), or a still body in a noise-free stream, and in
    every case it carries no information the first frame did not. Fused as a fix, a held pose
    pulls the state towards where the body was (the fail-safe finding F11: 4.3 % of rows
    beyond the 99 % bound, up to 64x); the IMU cannot always tell a held pose from a still
    body (a slow slide without turning, a hold at the start of a run before the velocity is
    known, an IMU arriving late: an adversarial review of a rule that fused the repeats the
    IMU showed still found 16-207x). So every repeat is read as occluded (``held_poses``): a
    still noise-free stream is dead-reckoned from its last distinct frame and goes ``lost``
    after ``max_bridge_s``. The position alone is not enough: a noise-free body turning about
    its origin keeps its position (so a client holding the position while the quaternion
    comes fresh is not caught)."""
    return pose in recent


@dataclass
class RecentPoses:
    """The poses of a mocap stream's :data:`RECENT_POSES` latest visible frames, held ones
    included, in time order (:func:`repeats_pose`; the batch form is
    :func:`kfusion.recording.held_frames`)."""

    poses: deque[Pose] = field(default_factory=lambda: deque(maxlen=RECENT_POSES))

    def repeats(self, pose: Pose) -> bool:
        """Whether a visible frame's ``pose`` (:func:`pose_key`) repeats a recent one."""
        return repeats_pose(pose, self.poses)

    def add(self, pose: Pose) -> None:
        """Keep a visible frame's ``pose`` as the newest (a held one too)."""
        self.poses.append(pose)


# ---------------------------------------------------------------------------------------------
# IMU outages, counted once
# ---------------------------------------------------------------------------------------------


@dataclass
class ImuWatch:
    """Counts IMU outages: intervals of more than ``dropout_s`` without an IMU sample.

    An outage is counted when a mocap frame sees the IMU silent for longer than ``dropout_s``
    (including an IMU that never delivered), or when a sample ends an interval longer than that
    which no frame had seen; each outage once.
    """

    dropout_s: float
    last_imu: float = -math.inf
    started: float = -math.inf
    in_outage: bool = False
    outages: int = 0

    def imu(self, t: float) -> None:
        """An IMU sample at t (s) was accepted."""
        if not self.in_outage and self.last_imu != -math.inf and t - self.last_imu > \
                self.dropout_s:
            self.outages += 1
        self.in_outage = False
        self.last_imu = t

    def mocap(self, t: float) -> None:
        """A mocap frame at t (s) was accepted."""
        if self.started == -math.inf:
            self.started = t
        reference = self.last_imu if self.last_imu != -math.inf else self.started
        if not self.in_outage and t - reference > self.dropout_s:
            self.outages += 1
            self.in_outage = True

    def forget(self) -> None:
        """The streams restarted (reset): the next samples start afresh (count kept)."""
        self.last_imu = self.started = -math.inf
        self.in_outage = False


# ---------------------------------------------------------------------------------------------
# Plausible stamps
# ---------------------------------------------------------------------------------------------

ACCEPT: Final = "accept"
"""The stamp is plausible."""
IMPLAUSIBLE: Final = "implausible"
"""The stamp is implausibly far ahead: reject and count."""
REBASE: Final = "rebase"
"""Consistent samples show the clock really jumped (or the present was a glitch): restart the
streams and take this sample."""


@dataclass
class TimeGuard:
    """Plausibility of stamps against the present (the newest accepted time of both streams).

    * A stamp more than ``max_jump_s`` ahead of the present is ``implausible`` (rejected): one
      glitch never becomes the new present, so it cannot freeze the tracker.
    * ``confirm`` consecutive implausible stamps, each later than the previous and within
      ``max_jump_s`` of it, with no plausible sample in between, confirm the jump: ``rebase``.
    * ``confirm`` consecutive stamps more than ``max_jump_s`` *behind* the present, from every
      stream seen so far, with no plausible sample in between, show that the present itself was
      a glitch (the first sample ever, say): ``rebase`` too.
    """

    max_jump_s: float = DEFAULT_MAX_TIME_JUMP_S
    confirm: int = DEFAULT_CONFIRM_SAMPLES
    ahead: list[float] = field(default_factory=list)
    behind: list[tuple[float, int]] = field(default_factory=list)
    rejected: int = 0
    rebases: int = 0

    def settled(self, t: float, present: float) -> bool:
        """True when :meth:`check` of a finite stamp t (s) against ``present`` (s) would
        accept it and change nothing: t within ``max_jump_s`` of the present, no suspect
        stamps waiting (the common case, one comparison at IMU rate)."""
        return present - self.max_jump_s <= t <= present + self.max_jump_s \
            and not self.ahead and not self.behind

    def check(self, t: float, stream: int, present: float, streams_seen: set[int]) -> str:
        """Judge a finite stamp t (s) of ``stream`` against ``present`` (s, -inf if none)."""
        if t > present + self.max_jump_s and present != -math.inf:
            self.behind.clear()
            ahead = self.ahead
            if ahead and not (t != ahead[-1] and abs(t - ahead[-1]) <= self.max_jump_s):
                ahead.clear()
            ahead.append(t)
            if len(ahead) >= self.confirm:
                return self._rebase()
            self.rejected += 1
            return IMPLAUSIBLE
        self.ahead.clear()
        if t < present - self.max_jump_s:
            behind = self.behind
            if behind and not abs(t - behind[-1][0]) <= self.max_jump_s:
                behind.clear()
            behind.append((t, stream))
            if len(behind) >= self.confirm and {s for _, s in behind} >= streams_seen:
                return self._rebase()
            return ACCEPT  # the stream's own order check rejects it (out of order, too late)
        self.behind.clear()
        return ACCEPT

    def _rebase(self) -> str:
        self.ahead.clear()
        self.behind.clear()
        self.rebases += 1
        return REBASE
