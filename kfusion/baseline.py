"""The baseline: the paper's IMU-compensated tracking (Amorim et al. 2021, eqs. 1-9, Algorithm 1).

Every other kfusion estimator is compared with this one, so it implements the paper's method and
nothing better: no gravity model, no gyroscope bias, no uncertainty. Where the paper leaves a
choice open, the choice made here is written down below and next to the code.

While the mocap is seen (at each visible mocap frame, time t):

* the last N + 1 positions ``y[t-N] .. y[t]`` form the buffer. When none of them is occluded, a
  cubic is fitted by least squares (eqs. 1, 3, 4) with the constant design matrix's
  pseudo-inverse, computed once. The fit gives ``v0, a0, jerk`` at the START of the buffer
  (time ``t0 = t - N Ta``); the expected acceleration is taken at the END of the buffer, the
  current time: ``a(t) = a0 + jerk (t - t0)`` (eq. 2). It is kinematic (no gravity), global frame;
* the velocity ("last velocity") is the least-squares slope through the last Nv + 1 positions,
  anchored at ``y[t-Nv]`` (eq. 5), when none of them is occluded. It is the paper's estimator:
  exact at constant velocity, and under acceleration a it equals the velocity about
  ``0.4 Nv Ta`` after ``t - Nv Ta`` (it lags the current velocity by roughly ``0.6 Nv Ta``);
* the expected acceleration is rotated into the IMU frame with the mocap orientation at t and
  compared with the accelerometer reading: ``offset = a_read - R_imu_global a(t)`` (eq. 6) on
  the first fit, afterwards ``offset += rate (a_read - R_imu_global a(t) - offset)`` (eq. 7),
  held when ``|a(t)|`` exceeds the acceleration threshold or when the buffer holds an occlusion.
  ``a_read`` is the IMU reading at t, or the most recent one before t (an IMU sample stamped
  exactly t is used whether it arrives before or after the mocap frame).

During an occlusion, at IMU rate, from the last fix (position measured, velocity from eq. 5):

* ``a_IMU = K R_global_body R_body_imu (a_read - offset)`` (eq. 8);
* ``p += v dt + a_IMU dt^2 / 2`` (eq. 9), and "update last velocity" is ``v += a_IMU dt``;
* the orientation ``R_global_body`` starts from the last seen mocap quaternion and is propagated
  with the gyroscope (:func:`kfusion.conventions.integrate_gyroscope`), without any bias estimate.

"Constant acceleration between two successive readings" is implemented as sample-and-hold: the
reading at ``t_i`` (accelerometer and gyroscope) drives the step from ``t_i`` to the next sample.
The estimate at any time is therefore a function of the readings strictly before it, which makes
the result independent of the order in which simultaneous IMU and mocap events are fed. An output
at a mocap time that falls between IMU samples is the same constant-acceleration step taken from
the last IMU sample to that time.

Gravity. The paper folds gravity into the IMU-frame offset: at rest ``a_read = -R_imu_global g +
bias``, so the offset holds ``-R_imu_global g`` as seen at the time it was learned. While the limb
keeps its orientation this cancels gravity exactly. When the limb rotates by an angle theta
during a gap (or between the fits that set the offset and the gap), the gravity part of the offset
stays fixed in the IMU frame while true gravity rotates in it, so eq. 8 leaves an acceleration
error of ``|g| 2 sin(theta / 2)`` m/s^2 for a turn about a horizontal axis (in general times the
sine of the angle between the axis and the vertical; nothing for a turn about the vertical):
1.7 m/s^2 for 10 degrees, which is 9 mm after 0.1 s and 77 mm after 0.3 s. The slow adaptation
(rate 0.01 per frame, about 1 s at 100 Hz) also means that after a rotation while tracked, the
offset lags the new orientation's gravity for about a second. This is the paper's behaviour and
is kept.

Other choices the paper leaves open:

* Ta (the mocap period in the design matrix, eq. 4) is the median time step of the first full
  buffer; the pseudo-inverse is computed then and recomputed only if a later buffer's median step
  differs from it by more than 1 % (the mocap rate changed). Eq. 5 uses the median step of its
  own Nv + 1 points. Frames are assumed evenly spaced, as in the paper.
* The lever arm (``recording.yaml``'s ``lever_arm``) is ignored, as in the paper.
* The output is ``lost`` before the first fit (no offset and velocity yet) and once the time since
  the last fix exceeds ``max_bridge_s``. There is no uncertainty: ``std`` is NaN.

Bad input (see the guide's table): a non-finite IMU sample is rejected and counted, the state is
untouched; a timestamp earlier than the last event is rejected and counted; an identical duplicate
is skipped; malformed shapes raise ValueError.
"""

from __future__ import annotations

import dataclasses
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kfusion.conventions import (
    LOST,
    MAX_BRIDGE_LIMIT_S,
    QUATERNION_NORM_TOLERANCE,
    integrate_gyroscope,
    matrix_from_wxyz,
    median_interval,
    quaternion_multiply,
)
from kfusion.guards import real_number, refuse_masked, short_repr
from kfusion.recording import Recording, on_mocap_clock
from kfusion.streamhealth import FIX_TIMEOUT_S, tracking_status
from kfusion.track_file import TrackResult

METHOD_NAME: Final = "baseline"
PERIOD_TOLERANCE: Final = 0.01
"""Relative change of the mocap period (median buffer step) that triggers a new pseudo-inverse."""

# Offset actions of Algorithm 1 (see BaselineTracker.offset_actions).
OFFSET_INITIALISED: Final = "initialised"  # first fit: eq. 6
OFFSET_ADAPTED: Final = "adapted"  # eq. 7
OFFSET_HELD_ACCELERATION: Final = "held_high_acceleration"  # |a(t)| above the threshold
OFFSET_HELD_OCCLUSION: Final = "held_occlusion"  # an occlusion in the last N measures
OFFSET_NO_READING: Final = "no_imu_reading"  # no IMU sample at or before the fit time
OFFSET_ACTIONS: Final = (OFFSET_INITIALISED, OFFSET_ADAPTED, OFFSET_HELD_ACCELERATION,
                         OFFSET_HELD_OCCLUSION, OFFSET_NO_READING)


# --------------------------------------------------------------------------------------------
# Parameters
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BaselineParameters:
    """Tunable parameters of the paper's tracker.

    Attributes:
        buffer_size: N, number of position differences in the cubic fit (the buffer holds the
            last N + 1 mocap positions). The paper found it "through experimentation" and does
            not print it. Default 20: at 100 Hz a 0.2 s window, where the end-point acceleration
            of the fit has a noise of 0.25 m/s^2 for 0.3 mm mocap noise (averaged down to
            ~0.03 m/s^2 by the 0.01 adaptation rate), while a 1 Hz, 0.3 m arm motion is still
            followed to within ~1 m/s^2 at its acceleration peaks (which the threshold skips).
            Longer windows cut the noise but follow human motion worse; shorter ones are
            dominated by noise (1.2 m/s^2 at N = 10).
        velocity_points: Nv, number of position differences in the velocity fit (eq. 5).
            Default ``round(N / 4)`` ("Nv ~ N/4" in the paper), at least 1.
        adaptation_rate: rate of the offset update (eq. 7), per mocap frame; 0.01 in the paper.
        acceleration_threshold: m/s^2; the offset is held when the expected acceleration's
            magnitude exceeds it. The paper says only "too high". Default 2.0 m/s^2: the cubic
            fit misses roughly 10 % of the acceleration at the peaks of human motion, and the
            offset it corrects is about 0.2 m/s^2 (the MPU9255's 1-sigma turn-on bias of
            20 mg), so above ~10 x 0.2 m/s^2 the fit's error would exceed the offset itself.
        gain: K, the scalar gain of eq. 8, found offline (:func:`kfusion.calibration.
            calibrate_gain`). Default 1.0: uncalibrated.
        max_bridge_s: s; past this time since the last fix the output is ``lost``. The paper
            bridged gaps of at most 0.3 s; 1.0 s covers the 0.1-1 s occlusions kfusion targets
            while the error (tens of mm at 0.3 s, growing as t^2) is still of arm-length order.
    """

    buffer_size: int = 20
    velocity_points: int | None = None
    adaptation_rate: float = 0.01
    acceleration_threshold: float = 2.0
    gain: float = 1.0
    max_bridge_s: float = 1.0

    def __post_init__(self) -> None:
        _check_integer("buffer_size", self.buffer_size, minimum=3)
        if self.velocity_points is None:
            object.__setattr__(self, "velocity_points", max(1, round(self.buffer_size / 4)))
        _check_integer("velocity_points", self.velocity_points, minimum=1)
        assert self.velocity_points is not None  # for mypy; set just above
        if self.velocity_points > self.buffer_size:
            raise ValueError(f"BaselineParameters.velocity_points: expected at most buffer_size "
                             f"({self.buffer_size}), got {self.velocity_points}")
        _check_number("adaptation_rate", self.adaptation_rate, low=0.0, high=1.0,
                      expected="a number in (0, 1]", low_open=True)
        _check_number("acceleration_threshold", self.acceleration_threshold, low=0.0,
                      expected="a positive number of m/s^2", low_open=True)
        _check_number("gain", self.gain, low=0.0, expected="a positive number", low_open=True)
        _check_number("max_bridge_s", self.max_bridge_s, low=0.0, high=MAX_BRIDGE_LIMIT_S,
                      expected=f"a positive number of seconds, at most {MAX_BRIDGE_LIMIT_S:g}",
                      low_open=True)

    @property
    def nv(self) -> int:
        """Nv as an int (``velocity_points`` after defaulting)."""
        return int(self.velocity_points or 1)

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any]) -> BaselineParameters:
        """Build from a mapping (e.g. loaded from YAML); ValueError on unknown keys."""
        if not isinstance(mapping, Mapping):
            raise ValueError(f"BaselineParameters: expected a mapping of parameter names, got "
                             f"{type(mapping).__name__}")
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(map(str, mapping)) - set(names))
        if unknown:
            raise ValueError(f"BaselineParameters: unknown parameter(s) {unknown}; expected "
                             f"some of {names}")
        return cls(**dict(mapping))

    def replace(self, **overrides: Any) -> BaselineParameters:
        """A copy with some fields changed (unknown names raise ValueError).

        ``velocity_points`` is re-derived from a new ``buffer_size`` unless given explicitly.
        """
        current = dataclasses.asdict(self)
        if "buffer_size" in overrides and "velocity_points" not in overrides:
            current["velocity_points"] = None
        return BaselineParameters.from_mapping({**current, **overrides})


MAX_BUFFER_SIZE: Final = 10_000
"""Largest ``buffer_size`` (mocap frames: 100 s at 100 Hz)."""


def _check_integer(name: str, value: object, *, minimum: int,
                   maximum: int = MAX_BUFFER_SIZE) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValueError(f"BaselineParameters.{name}: expected an integer >= {minimum}, "
                         f"got {short_repr(value)}")
    if value > maximum:
        raise ValueError(f"BaselineParameters.{name}: expected an integer <= {maximum}, "
                         f"got {short_repr(value)}")


def _check_number(name: str, value: object, *, low: float, expected: str,
                  high: float = np.inf, low_open: bool = False) -> None:
    number = real_number(value)
    ok = number is not None and bool(np.isfinite(number)
                                     and (number > low if low_open else number >= low)
                                     and number <= high)
    if not ok:
        raise ValueError(f"BaselineParameters.{name}: expected {expected}, "
                         f"got {short_repr(value)}")


# --------------------------------------------------------------------------------------------
# The equations, as pure functions
# --------------------------------------------------------------------------------------------


def design_matrix(points: int, period: float) -> NDArray[np.float64]:
    """Eq. 4: X, shape (points, 3), row i (1-based) = [i Ta, (i Ta)^2 / 2, (i Ta)^3 / 6].

    ``period`` is Ta, the mocap sampling time, s.
    """
    if points < 1 or not period > 0:
        raise ValueError(f"design_matrix: expected points >= 1 and period > 0 s, got {points} "
                         f"and {period}")
    elapsed = np.arange(1, points + 1) * period
    return np.column_stack([elapsed, elapsed**2 / 2, elapsed**3 / 6])


def position_differences(positions: NDArray[np.float64]) -> NDArray[np.float64]:
    """Eq. 3: Y, shape (n, 3), row i = y[k + i] - y[k], from positions (n + 1, 3) in m."""
    return positions[1:] - positions[0]


def fit_cubic(positions: ArrayLike, pseudo_inverse: NDArray[np.float64]
              ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Eqs. 1, 3, 4: least-squares cubic through N + 1 evenly spaced positions.

        [v0, a0, jerk] = pinv(X) Y,   y(t) - y0 = v0 t + a0 t^2/2 + jerk t^3/6

    Args:
        positions: (N + 1, 3) positions y[t-N] .. y[t], m, global frame.
        pseudo_inverse: (3, N) ``pinv(design_matrix(N, Ta))``.

    Returns:
        v0 (3,) m/s, a0 (3,) m/s^2 and jerk (3,) m/s^3, all at the START of the buffer, t - N Ta.
    """
    coefficients = pseudo_inverse @ position_differences(np.asarray(positions, dtype=float))
    return coefficients[0], coefficients[1], coefficients[2]


def expected_acceleration(a0: ArrayLike, jerk: ArrayLike, elapsed: float
                          ) -> NDArray[np.float64]:
    """Eq. 2: a(t) = a0 + jerk (t - t0), m/s^2; ``elapsed`` = t - t0 in s."""
    return np.asarray(a0, dtype=float) + np.asarray(jerk, dtype=float) * elapsed


def fit_velocity(positions: ArrayLike, period: float) -> NDArray[np.float64]:
    """Eq. 5: v = (X1' X1)^-1 X1' Y, the slope through the last Nv + 1 positions.

    X1 = [Ta, 2 Ta, ..., Nv Ta]' (first column of eq. 4 with N = Nv), Y = eq. 3 with N = Nv.

    Args:
        positions: (Nv + 1, 3) positions y[t-Nv] .. y[t], m.
        period: Ta, s.

    Returns:
        (3,) velocity, m/s (see the module docstring for the time it refers to).
    """
    differences = position_differences(np.asarray(positions, dtype=float))
    column = np.arange(1, differences.shape[0] + 1) * period
    velocity: NDArray[np.float64] = column @ differences / (column @ column)
    return velocity


def measured_offset(reading: ArrayLike, R_imu_global: ArrayLike, acceleration: ArrayLike
                    ) -> NDArray[np.float64]:
    """Eq. 6: offset = a_read - R_imu_global a(t), m/s^2, IMU frame (gravity included)."""
    rotated = np.asarray(R_imu_global, dtype=float) @ np.asarray(acceleration, dtype=float)
    return np.asarray(reading, dtype=float) - rotated


def adapt_offset(previous: ArrayLike, measured: ArrayLike, rate: float) -> NDArray[np.float64]:
    """Eq. 7: offset = offset_prev + rate (a_read - a(t) - offset_prev), m/s^2.

    ``measured`` is ``a_read - a(t)`` (eq. 6) in the IMU frame.
    """
    previous = np.asarray(previous, dtype=float)
    return previous + rate * (np.asarray(measured, dtype=float) - previous)


def offset_action(*, first: bool, buffer_occluded: bool, expected_magnitude: float,
                  threshold: float) -> str:
    """Algorithm 1's offset branch: which of ``OFFSET_*`` applies at a mocap frame.

    Occlusion in the last N measures -> hold; else first fit -> initialise (eq. 6, whatever the
    acceleration); else |a(t)| above ``threshold`` -> hold; else adapt (eq. 7).
    """
    if buffer_occluded:
        return OFFSET_HELD_OCCLUSION
    if first:
        return OFFSET_INITIALISED
    if expected_magnitude > threshold:
        return OFFSET_HELD_ACCELERATION
    return OFFSET_ADAPTED


def imu_acceleration(gain: float, R_global_imu: ArrayLike, reading: ArrayLike,
                     offset: ArrayLike) -> NDArray[np.float64]:
    """Eq. 8: a_IMU = K R_global_body R_body_imu (a_read - offset), m/s^2, global frame.

    ``R_global_imu`` = R_global_body @ R_body_imu, shape (3, 3).
    """
    return gain * (np.asarray(R_global_imu, dtype=float)
                   @ (np.asarray(reading, dtype=float) - np.asarray(offset, dtype=float)))


def dead_reckon(position: NDArray[np.float64], velocity: NDArray[np.float64],
                acceleration: NDArray[np.float64], dt: float
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Eq. 9 and "update last velocity", constant acceleration over dt (s):

        p' = p + v dt + a dt^2 / 2,   v' = v + a dt
    """
    return position + velocity * dt + acceleration * (0.5 * dt * dt), velocity + acceleration * dt


# --------------------------------------------------------------------------------------------
# Streaming tracker
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class BaselineEstimate:
    """The tracker's output at one time.

    Attributes:
        t: time, s.
        position: (3,) m, global frame; NaN when lost.
        status: ``tracked``, ``bridged`` or ``lost`` (:func:`kfusion.streamhealth.tracking_status`).
        time_since_fix: s since the last visible mocap frame (inf before the first).
    """

    t: float
    position: NDArray[np.float64]
    status: str
    time_since_fix: float


@dataclass
class _ImuReading:
    time: float
    accelerometer: NDArray[np.float64]
    gyroscope: NDArray[np.float64]


@dataclass
class _DeadReckoning:
    """Mutable dead-reckoning state at ``time``: position (3,) m and velocity (3,) m/s, global
    frame; orientation ``q_global_imu`` [w, x, y, z] and its matrix; ``reading``, the IMU sample
    held over the next step (the latest at or before ``time``; None if there is none yet)."""

    time: float
    position: NDArray[np.float64]
    velocity: NDArray[np.float64]
    q_global_imu: NDArray[np.float64]
    R_global_imu: NDArray[np.float64]
    reading: _ImuReading | None


@dataclass
class _PendingFit:
    """A fit at ``time`` whose offset update waits for the IMU reading at that time."""

    time: float
    R_imu_global: NDArray[np.float64]  # (3, 3) from the mocap orientation at ``time``
    acceleration: NDArray[np.float64]  # a(t), eq. 2, global frame, m/s^2


class BaselineTracker:
    """Streaming form of Algorithm 1: feed IMU samples and mocap frames in time order.

    Events must come in non-decreasing time across both streams; on equal times either order
    gives the same result. :meth:`push_mocap` returns the output at the frame's time, which is
    also what :func:`track_recording` reports per mocap row.

    The dead-reckoning steps (eq. 9, one per IMU sample since the last fix) are taken when an
    output needs them (an occluded frame, :meth:`estimate`, or a fix without a fresh eq. 5
    velocity); the numbers are the same as stepping at every sample, and steps that a fresh fix
    discards are never computed.

    Args:
        imu_to_body: (4,) rotation IMU -> body, [w, x, y, z] (``recording.yaml``'s
            ``imu_to_body``).
        params: parameters (defaults if None).
    """

    def __init__(self, imu_to_body: ArrayLike, params: BaselineParameters | None = None) -> None:
        q_body_imu = np.asarray(imu_to_body, dtype=float)
        if q_body_imu.shape != (4,) or not np.isfinite(q_body_imu).all():
            raise ValueError(f"imu_to_body: expected a finite quaternion [w, x, y, z] of shape "
                             f"(4,), got {q_body_imu.shape}")
        self.params = params if params is not None else BaselineParameters()
        self._q_body_imu = q_body_imu / np.linalg.norm(q_body_imu)
        self._R_body_imu = matrix_from_wxyz(self._q_body_imu)
        n = self.params.buffer_size
        self._buffer_t: deque[float] = deque(maxlen=n + 1)
        self._buffer_position: deque[NDArray[np.float64]] = deque(maxlen=n + 1)
        self._period: float | None = None
        self._pseudo_inverse: NDArray[np.float64] | None = None
        self.offset: NDArray[np.float64] | None = None
        """Current IMU-frame offset (gravity included), m/s^2; None before the first fit."""
        self.velocity: NDArray[np.float64] | None = None
        """Last velocity from eq. 5 (global, m/s); None before Nv + 1 visible frames."""
        self._pending: _PendingFit | None = None
        self._latest: _ImuReading | None = None
        self._state: _DeadReckoning | None = None
        self._queue: list[_ImuReading] = []  # readings after the state's, not yet stepped
        self._last_fix: float = -np.inf
        self._fix_position: NDArray[np.float64] | None = None
        self._last_mocap_t: float = -np.inf
        self._time: float = -np.inf
        self._rejected: dict[str, int] = {}
        self._offset_actions: dict[str, int] = dict.fromkeys(OFFSET_ACTIONS, 0)

    @classmethod
    def from_recording(cls, recording: Recording, params: BaselineParameters | None = None
                       ) -> BaselineTracker:
        """A tracker for ``recording``'s IMU mounting (its ``info.imu_to_body``)."""
        return cls(recording.info.imu_to_body, params)

    # ---- read-only views -------------------------------------------------------------------

    @property
    def rejected(self) -> dict[str, int]:
        """Count of rejected or skipped events by reason."""
        return dict(self._rejected)

    @property
    def offset_actions(self) -> dict[str, int]:
        """How often each of Algorithm 1's offset branches fired (keys ``OFFSET_ACTIONS``)."""
        return dict(self._offset_actions)

    @property
    def period(self) -> float | None:
        """Ta used in the design matrix, s (None before the first fit)."""
        return self._period

    # ---- events ----------------------------------------------------------------------------

    def push_imu(self, t: float, accelerometer: ArrayLike, gyroscope: ArrayLike) -> bool:
        """Feed one IMU sample; returns False if it was rejected or skipped (see ``rejected``).

        Args:
            t: time, s.
            accelerometer: (3,) specific force, m/s^2, IMU frame.
            gyroscope: (3,) angular rate, rad/s, IMU frame.
        """
        accelerometer = _vector3("accelerometer", accelerometer)
        gyroscope = _vector3("gyroscope", gyroscope)
        t = float(t)
        if not (np.isfinite(t) and np.isfinite(accelerometer).all()
                and np.isfinite(gyroscope).all()):
            return self._reject("non-finite IMU sample")
        latest = self._latest
        if latest is not None and t == latest.time:
            same = (np.array_equal(accelerometer, latest.accelerometer)
                    and np.array_equal(gyroscope, latest.gyroscope))
            return self._reject("duplicate IMU sample" if same else "IMU timestamp repeated")
        if t < self._time:
            return self._reject("IMU timestamp earlier than the last event")
        reading = _ImuReading(t, accelerometer, gyroscope)
        if self._pending is not None:
            self._resolve_pending(reading if t == self._pending.time else None)
        if self._state is not None:
            self._queue.append(reading)
        self._latest = reading
        self._time = t
        return True

    def push_mocap(self, t: float, position: ArrayLike | None,
                   quaternion: ArrayLike | None) -> BaselineEstimate:
        """Feed one mocap frame and return the output at its time.

        Args:
            t: time, s.
            position: (3,) m, global frame; None or any NaN means occluded.
            quaternion: (4,) body -> global, [w, x, y, z]; None or any NaN means occluded.
        """
        t = float(t)
        position_array = None if position is None else _vector3("position", position)
        quaternion_array = None
        if quaternion is not None:
            refuse_masked("quaternion", quaternion)
            quaternion_array = np.asarray(quaternion, dtype=float)
            if quaternion_array.shape != (4,):
                raise ValueError(f"quaternion: expected shape (4,) [w, x, y, z], got "
                                 f"{quaternion_array.shape}")
        if not np.isfinite(t) or t <= self._last_mocap_t or t < self._time:
            self._reject("duplicate mocap timestamp" if t == self._last_mocap_t
                         else "mocap timestamp not after the last event")
            return self.estimate(self._time)
        self._last_mocap_t = t
        self._time = t
        if self._pending is not None:
            self._resolve_pending(None)
        if (position_array is None or quaternion_array is None
                or not np.isfinite(position_array).all()
                or not np.isfinite(quaternion_array).all()
                or abs(float(np.linalg.norm(quaternion_array)) - 1.0)
                > QUATERNION_NORM_TOLERANCE):
            # no usable fix: the paper's method needs position and a unit orientation; a
            # non-unit quaternion would poison the IMU-frame offset for good
            self._buffer_t.append(t)
            self._buffer_position.append(np.full(3, np.nan))
            self._count(OFFSET_HELD_OCCLUSION)
        else:
            self._fix(t, position_array, quaternion_array)
        return self.estimate(t)

    def estimate(self, t: float) -> BaselineEstimate:
        """Output at time ``t`` (s, not before the last event) from the data fed so far.

        Between IMU samples, the last constant-acceleration step (eq. 9) is extrapolated to t.
        Querying does not change what later events produce (pending dead-reckoning steps are
        taken, exactly as they would be later).
        """
        t = float(t)
        if not t >= self._time:
            raise ValueError(f"estimate: expected a time at or after the last event "
                             f"({self._time} s), got {t}")
        since = t - self._last_fix
        # the status rule shared by every estimator; the paper's method dead-reckons whatever
        # the IMU does, so no dead-reckoning horizon
        status = tracking_status(since, self._last_fix == self._last_mocap_t,
                                 fix_timeout_s=FIX_TIMEOUT_S,
                                 max_bridge_s=self.params.max_bridge_s)
        if status != LOST and since == 0.0 and self._fix_position is not None:
            return BaselineEstimate(t, self._fix_position.copy(), status, 0.0)
        if status == LOST or self._state is None or self.offset is None:
            return BaselineEstimate(t, np.full(3, np.nan), LOST, float(since))
        self._catch_up()
        position, _ = self._step(self._state, t)
        return BaselineEstimate(t, position, status, float(since))

    # ---- internals -------------------------------------------------------------------------

    def _reject(self, reason: str) -> bool:
        self._rejected[reason] = self._rejected.get(reason, 0) + 1
        return False

    def _step(self, state: _DeadReckoning, t: float
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Position and velocity at ``t`` from ``state`` with its held reading (eqs. 8-9)."""
        if state.reading is None or self.offset is None:
            acceleration = np.zeros(3)
        else:
            acceleration = imu_acceleration(self.params.gain, state.R_global_imu,
                                            state.reading.accelerometer, self.offset)
        return dead_reckon(state.position, state.velocity, acceleration, t - state.time)

    def _catch_up(self) -> None:
        """Take the queued dead-reckoning steps, one per IMU sample; the gyroscope reading held
        over each step propagates the orientation (no bias estimate, as in the paper)."""
        state = self._state
        assert state is not None
        for reading in self._queue:
            dt = reading.time - state.time
            if dt > 0:
                state.position, state.velocity = self._step(state, reading.time)
                if state.reading is not None:
                    state.q_global_imu = integrate_gyroscope(state.q_global_imu,
                                                             state.reading.gyroscope, dt)
                    state.R_global_imu = matrix_from_wxyz(state.q_global_imu)
                state.time = reading.time
            state.reading = reading
        self._queue.clear()

    def _fix(self, t: float, position: NDArray[np.float64], quaternion: NDArray[np.float64]
             ) -> None:
        """A visible frame: buffer, fit (eqs. 1-5), offset (eqs. 6-7), restart dead reckoning."""
        self._buffer_t.append(t)
        self._buffer_position.append(position.copy())
        n, nv = self.params.buffer_size, self.params.nv
        times = np.asarray(self._buffer_t)
        positions = np.asarray(self._buffer_position)
        visible = np.asarray(~np.isnan(positions).any(axis=1), dtype=bool)
        R_global_imu = matrix_from_wxyz(quaternion) @ self._R_body_imu
        # velocity first (eq. 5, or the dead-reckoned "last velocity"), with the offset so far
        if len(times) >= nv + 1 and visible[-(nv + 1):].all():
            step = median_interval(times[-(nv + 1):])
            self.velocity = fit_velocity(positions[-(nv + 1):], step)
            velocity = self.velocity
        elif self._state is not None:
            self._catch_up()
            velocity = self._step(self._state, t)[1]  # "last velocity", dead-reckoned to t
        else:
            velocity = self.velocity if self.velocity is not None else np.zeros(3)
        if len(times) == n + 1 and visible.all():
            period = self._design(times)
            _, a0, jerk = fit_cubic(positions, self._pseudo_inverse_checked())
            pending = _PendingFit(t, R_global_imu.T, expected_acceleration(a0, jerk, n * period))
            if self._latest is not None and self._latest.time == t:
                self._apply_offset(pending, self._latest)
            else:
                self._pending = pending
        elif not visible.all():
            self._count(OFFSET_HELD_OCCLUSION)
        self._queue.clear()
        if self.offset is not None or self._pending is not None:
            q_global_imu = quaternion_multiply(quaternion / np.linalg.norm(quaternion),
                                               self._q_body_imu)
            self._state = _DeadReckoning(t, position.copy(), velocity, q_global_imu,
                                         R_global_imu, self._latest)
        self._last_fix = t
        self._fix_position = position.copy()

    def _design(self, times: NDArray[np.float64]) -> float:
        """Ta for this buffer; (re)compute the pseudo-inverse when the period changes."""
        step = median_interval(times)
        if self._period is None or abs(step - self._period) > PERIOD_TOLERANCE * self._period:
            self._period = step
            design = design_matrix(self.params.buffer_size, step)
            self._pseudo_inverse = np.asarray(np.linalg.pinv(design), dtype=float)
        return self._period

    def _pseudo_inverse_checked(self) -> NDArray[np.float64]:
        assert self._pseudo_inverse is not None
        return self._pseudo_inverse

    def _resolve_pending(self, reading_at_fit: _ImuReading | None) -> None:
        """Apply the waiting offset update with the reading at the fit time, or else the latest
        one before it."""
        pending = self._pending
        assert pending is not None
        self._pending = None
        reading = reading_at_fit
        if reading is None and self._latest is not None and self._latest.time <= pending.time:
            reading = self._latest
        if reading is None:
            self._count(OFFSET_NO_READING)
            return
        self._apply_offset(pending, reading)

    def _apply_offset(self, pending: _PendingFit, reading: _ImuReading) -> None:
        """Algorithm 1's offset branch with a fit and its reading (eqs. 6-7)."""
        action = offset_action(first=self.offset is None, buffer_occluded=False,
                               expected_magnitude=float(np.linalg.norm(pending.acceleration)),
                               threshold=self.params.acceleration_threshold)
        measured = measured_offset(reading.accelerometer, pending.R_imu_global,
                                   pending.acceleration)
        if action == OFFSET_INITIALISED:
            self.offset = measured
        elif action == OFFSET_ADAPTED:
            assert self.offset is not None
            self.offset = adapt_offset(self.offset, measured, self.params.adaptation_rate)
        self._count(action)

    def _count(self, action: str) -> None:
        self._offset_actions[action] += 1


def _vector3(name: str, value: ArrayLike) -> NDArray[np.float64]:
    refuse_masked(name, value)
    array = np.asarray(value, dtype=float)
    if array.shape != (3,):
        raise ValueError(f"{name}: expected shape (3,), got {array.shape}")
    return array


# --------------------------------------------------------------------------------------------
# Batch
# --------------------------------------------------------------------------------------------


def track_recording(recording: Recording, params: BaselineParameters | None = None,
                    **overrides: Any) -> TrackResult:
    """Run the paper's tracker over a recording: one output row per mocap row (same t).

    IMU samples and mocap frames are merged in time order (an IMU sample before a mocap frame
    with the same time) and fed to one :class:`BaselineTracker`.

    Args:
        recording: the recording (its ``info.imu_to_body`` is used; gravity is not: the paper
            folds it into the offset).
        params: parameters (defaults if None).
        **overrides: :class:`BaselineParameters` field names, e.g. ``buffer_size=30``.

    Returns:
        TrackResult with ``std`` all NaN (the paper has no uncertainty), ``method="baseline"``.
    """
    params = (params or BaselineParameters()).replace(**overrides) if overrides else (
        params or BaselineParameters())
    recording = on_mocap_clock(recording)  # the recording's IMU clock model, once
    tracker = BaselineTracker.from_recording(recording, params)
    imu, mocap = recording.imu, recording.mocap
    m = len(mocap)
    position = np.full((m, 3), np.nan)
    status = np.empty(m, dtype=object)
    since = np.full(m, np.inf)
    # merge: sort by time, IMU (kind 0) before mocap (kind 1) at equal times
    times = np.concatenate([imu.t, mocap.t])
    kinds = np.concatenate([np.zeros(len(imu), dtype=np.int8), np.ones(m, dtype=np.int8)])
    indices = np.concatenate([np.arange(len(imu)), np.arange(m)])
    order = np.lexsort((kinds, times))
    accelerometer, gyroscope = imu.accelerometer, imu.gyroscope
    mocap_position, mocap_quaternion = mocap.position, mocap.quaternion
    for event in order:
        index = int(indices[event])
        if kinds[event] == 0:
            tracker.push_imu(float(imu.t[index]), accelerometer[index], gyroscope[index])
        else:
            output = tracker.push_mocap(float(mocap.t[index]), mocap_position[index],
                                        mocap_quaternion[index])
            position[index] = output.position
            status[index] = output.status
            since[index] = output.time_since_fix
    return TrackResult(t=np.array(mocap.t, dtype=float), position=position,
                       std=np.full((m, 3), np.nan), status=status.astype(str),
                       time_since_fix=since, method=METHOD_NAME)
