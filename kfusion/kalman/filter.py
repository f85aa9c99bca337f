"""Streaming Kalman tracker on ``filterpy.kalman.KalmanFilter``: asynchronous IMU and mocap events.

:class:`KalmanFusion` holds the position filter of :mod:`kfusion.kalman.model` in a filterpy
``KalmanFilter`` and the orientation in a :class:`kfusion.kalman.orientation.OrientationTracker`.
Events are fed in time order:

* ``predict(t, accelerometer, gyroscope)``: advance the state from its time to the sample's time
  with the specific force and rate taken as linear between the previous sample and this one
  (first-order hold), then keep this sample;
* ``update(t, position, quaternion)``: advance to t holding the last sample (zero-order hold: the
  next one is not known yet), then fuse the mocap fix or skip it (occluded, gated).

Why a first-order hold, when a zero-order hold of the previous sample is the textbook choice:
IMU samples are values at their instants, and holding the previous one lags the motion by half
a sample. On the simulator that lag is a systematic error of about 1 mm per 0.3 s gap, five
times what a model-matched NEES test must resolve; on the BROAD trials the first-order hold cut
the gap RMS of the two fastest trials by about 30 % (measured, before the latency term below).
The next sample is known when a predict runs, so this costs no latency.

Any dt works (multi-rate, jittered, dropouts: the covariance grows over the real interval, dt is
never clamped). Feed events in the fusion order of :mod:`kfusion.kalman.events` (the batch
driver and the Tracker do): by time, a sample's time being its timestamp minus
``params.imu_latency_s`` (:func:`~kfusion.kalman.events.imu_event_time`), and at equal times
the IMU sample first, then the mocap frame, so that the fix lands on a state that holds that
sample. A sample whose time is not after the state's (a mocap frame was already fused past it)
is kept for the next interval without moving the state, and counted as ``imu_late``.

What reaches filterpy is always finite: a NaN/inf IMU sample is rejected and counted without
touching the state, and a mocap position with any NaN is an occluded frame, which never calls
``KalmanFilter.update`` (filterpy 2.0 would silently poison the state with a NaN z).

filterpy's ``update`` already uses the Joseph form ``P = (I - K H) P (I - K H)^T + K R K^T``
(``filterpy/kalman/kalman_filter.py``, ``KalmanFilter.update``); after every predict and update P is
symmetrised, ``P <- (P + P^T) / 2``. ``predict`` is called with this interval's F, B, Q and
``u = [f0; f1; g]`` (filterpy 2.0: ``x = F x + B u``, ``P = F P F^T + Q``).

Lever arm (m, body frame, the IMU's position relative to the rigid-body origin):

* given (``lever_arm`` argument, e.g. from ``recording.yaml``): the state is the IMU point,
  ``p_imu = p_body + R_global_body lever``; fixes are moved to it and outputs moved back;
* not given and ``params.lever_arm_std > 0``: it is estimated as three more states (12 in all),
  measured through ``z = p - R_global_body l``. Unknown, it would cost the acceleration difference
  between the two points, ``alpha x r + omega x (omega x r)``: 0.5 m/s^2 for r = 1 cm at an
  angular acceleration of 50 rad/s^2, which the BROAD trials reach (measured: estimating it
  more than halved the gap RMS of the fast-rotation trial, 6.3 -> 2.7 mm, and the estimates
  came out at 0.5-1 cm);
* not given and ``lever_arm_std == 0``: ignored (9 states; the IMU point is the rigid-body point).

Outputs are always the rigid-body point (what the mocap measures) and its covariance
``H P H^T`` with the measurement matrix at the estimated orientation.

Gating: a fix is rejected (``gated``, counted) when its NIS ``y^T S^-1 y`` exceeds the
chi-square(3) quantile of ``gate_probability`` *and* it lies more than ``gate_min_innovation``
(1 cm) from the prediction: a marker swap or jump moves the rigid body by centimetres, while an
impact the IMU cannot sample can make the filter briefly over-confident by a few millimetres, and
rejecting good fixes then makes it drift away from them. While the prediction is valid (at most
``max_bridge_s`` after the last accepted fix) a fix that fails the gate is rejected however long
the gap: time alone never makes a disagreeing fix a re-acquisition (a marker swap lasting longer
than ``reacquire_after_s`` stays rejected, and the output is ``bridged`` with the honest bound
of the prediction, then ``lost``). Past ``max_bridge_s`` the state is lost and the next fix is
taken (re-acquisition): if it would have failed the gate, the position and velocity covariance is
inflated first (:func:`kfusion.kalman.model.reacquisition_inflation`) so that the fix
re-initialises the position. A fix passing the gate ``reacquire_after_s`` or more after the last
one is labelled ``reacquired``.

Orientation fixes are gated too, against the gyroscope-propagated orientation
(:func:`kfusion.streamhealth.orientation_gated`): a flipped rigid body is used as a position-only
fix (counted ``orientation_gated``) while an accepted orientation is at most ``max_bridge_s``
old.

IMU stream health (:mod:`kfusion.streamhealth`): the last IMU sample is held for at most
``imu_dropout_s``; an interval not covered by the IMU (none received, a stalled stream, a dropout)
follows a no-IMU constant-velocity model with an honest acceleration noise, so fixes still pass
the gate and give the position, and the gap after it is ``lost``, never dead-reckoned
(:meth:`KalmanFusion.dead_reckoning_until`).

Honest covariance on real sensors (each term derived in :mod:`kfusion.kalman.model`): besides the
profile's white noise and bias walk, the bias state absorbs the orientation error grown through a
gap (:func:`~kfusion.kalman.model.orientation_leak_variance`) and the accelerometer's scale and
cross-axis error (:func:`~kfusion.kalman.model.scale_error_variance`); the fast part of that
error, which the bias cannot follow, and sample-to-sample jumps beyond the noise (impacts) count
as acceleration noise (:func:`~kfusion.kalman.model.motion_acceleration_variance`,
:func:`~kfusion.kalman.model.interpolation_variance`). A propagation that overflows (an
absurd interval) or leaves the position std beyond 100 km (minutes without a fix,
:data:`~kfusion.kalman.model.FORGOTTEN_POSITION_STD`) forgets the state (``resets``): the output
is ``lost`` until the next fix with an orientation.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any, Final

import numpy as np
from filterpy.kalman import KalmanFilter
from numpy.typing import ArrayLike, NDArray

from kfusion import streamhealth
from kfusion.conventions import (  # the update outcomes: kfusion.kalman.filter's vocabulary
    ACCEPTED,
    GATED,
    INITIALISED,
    LOST,
    OCCLUDED,
    QUATERNION_NORM_TOLERANCE,
    REACQUIRED,
    USED_OUTCOMES,
)
from kfusion.guards import refuse_masked
from kfusion.kalman import model
from kfusion.kalman.events import imu_event_time
from kfusion.kalman.marker_layout import LayoutResiduals, corrected_markers, origin_variance
from kfusion.kalman.markers import (
    common_error_variance,
    consistent_markers,
    fit_angle_variance,
    labels_ambiguous,
    marker_arms,
    marker_gate,
    marker_nis,
    marker_noise,
    marker_pose,
    origin_covariance,
    pooled_innovation,
    stacked_measurement,
)
from kfusion.kalman.orientation import (
    OrientationState,
    OrientationTracker,
    Quaternion,
    conjugate,
    matrix_from_quaternion,
    normalise,
    quaternion_log,
    quaternion_product,
)
from kfusion.kalman.parameters import KalmanParameters

# predict outcomes
PREDICTED: Final = "predicted"
"""The state was advanced to the sample's time (or the sample kept, if late)."""
DUPLICATE: Final = "duplicate"
"""Same timestamp and values as the previous IMU sample: skipped."""
REJECTED: Final = "rejected"
"""NaN or inf in the sample: skipped, state untouched."""

COUNTER_NAMES: Final = (
    "predictions", "imu_rejected", "imu_duplicates", "imu_dropouts", "imu_late",
    "accelerometer_saturated", "gyroscope_saturated",
    "updates", "occluded", "gated", "reacquired", "initialised", "no_orientation", "resets",
    "imu_outages", "orientation_gated", "markers_used", "markers_gated",
)
"""Keys of :attr:`KalmanFusion.counters`. ``updates`` counts every fix fused (accepted,
reacquired and initialised); ``no_orientation`` counts fixes without a quaternion before the
orientation was known (treated as occluded); ``imu_dropouts`` intervals longer than
``imu_dropout_s``; ``imu_late`` samples not after the state's time; ``resets`` propagations that
overflowed or left the position std beyond 100 km (the state is then forgotten and re-initialised
by the next fix); ``imu_rejected``
samples with NaN, inf or a value beyond :data:`kfusion.kalman.model.IMPLAUSIBLE_SAMPLE`;
``imu_outages`` intervals propagated without IMU (:mod:`kfusion.streamhealth`);
``orientation_gated`` fixes whose orientation failed the gyroscope gate (position still used);
``markers_used`` and ``markers_gated`` markers fused and rejected one by one by
:meth:`KalmanFusion.update_markers` (a frame counts in ``updates`` when one of its markers was
fused, in ``gated`` when all its visible markers were rejected)."""

Vector3 = tuple[float, float, float]


@dataclass(frozen=True)
class UpdateOutcome:
    """What :meth:`KalmanFusion.update` did with a mocap frame.

    Attributes:
        t: frame time, s.
        kind: one of accepted, occluded, gated, reacquired, initialised.
        nis: normalised innovation squared ``y^T S^-1 y`` (3 dof) before fusing; NaN when there
            was nothing to compare (occluded, initialised). For k markers fused together
            (:meth:`KalmanFusion.update_markers`) the stacked NIS (3k dof) divided by k, so that
            its expectation is 3 as for a rigid-body fix.
        markers_used: markers fused from this frame (marker-level fusion; 0 otherwise).
        markers_gated: visible markers of this frame rejected by their own gate.
        marker_origin: the rigid-body origin (m, global frame) solved from this frame's markers
            when 3 or more fitted (Kabsch), else None: the fix a rigid-body consumer (the
            consistency monitor) compares with.
        y, S: the innovation ``y = z - c - H x-`` (3,) m and its covariance ``S = H P- H^T +
            R`` (3, 3) m^2 of a fix fused into the prediction (accepted, reacquired; before
            any re-acquisition inflation; for marker-level fusion the stacked innovation's
            position part, :func:`kfusion.kalman.markers.pooled_innovation`), else None: the
            consistency monitor's block test (:func:`kfusion.monitor.block_nis`) sums them.
            Not compared by ``==`` (the engines agree to rounding, not bit for bit).
    """

    t: float
    kind: str
    nis: float
    markers_used: int = 0
    markers_gated: int = 0
    marker_origin: tuple[float, float, float] | None = None
    y: NDArray[np.float64] | None = field(default=None, compare=False)
    S: NDArray[np.float64] | None = field(default=None, compare=False)

    @property
    def accepted(self) -> bool:
        """True when the fix was fused (accepted, reacquired or initialised)."""
        return self.kind in USED_OUTCOMES


@dataclass(frozen=True)
class FilterEstimate:
    """The estimate at one time.

    Attributes:
        t: time, s.
        position: (3,) rigid-body point, m, global frame; NaN before the first fix.
        position_covariance: (3, 3) the state's part of its covariance ``H P H^T``, m^2
            (:func:`kfusion.kalman.model.output_covariance`).
        std: (3,) 1-sigma per axis of ``position_covariance``, m.
        velocity: (3,) of the IMU point, m/s, global frame.
        bias: (3,) accelerometer bias, m/s^2, IMU frame.
        lever_arm: (3,) lever arm in use (estimated, given, or zeros), m, body frame.
        orientation: (4,) ``q_global_imu`` [w, x, y, z].
        covariance: (n, n) covariance of the state (n = 9, or 12 with the lever-arm states).
        status: ``tracked``, ``bridged`` or ``lost``
            (:func:`kfusion.streamhealth.tracking_status` with its default ``fix_timeout_s``).
        time_since_fix: s since the last accepted fix (inf before the first).
        nis: NIS of the last mocap frame compared (NaN if none).
        orientation_covariance: (3, 3) the orientation's part of the point's covariance, m^2:
            its error times the lever arm (:func:`kfusion.kalman.model.
            orientation_error_covariance`; zero without a lever arm). The point's whole
            covariance is ``position_covariance + orientation_covariance``: the Tracker and the
            batch outputs report that sum.
    """

    t: float
    position: NDArray[np.float64]
    position_covariance: NDArray[np.float64]
    std: NDArray[np.float64]
    velocity: NDArray[np.float64]
    bias: NDArray[np.float64]
    lever_arm: NDArray[np.float64]
    orientation: NDArray[np.float64]
    covariance: NDArray[np.float64]
    status: str
    time_since_fix: float
    nis: float
    orientation_covariance: NDArray[np.float64]


@dataclass(frozen=True)
class KalmanSnapshot:
    """Everything :meth:`KalmanFusion.restore` needs to continue a run bit-exactly."""

    configuration: tuple[Any, ...]
    x: NDArray[np.float64]
    P: NDArray[np.float64]
    orientation: OrientationState
    time: float | None
    imu_stamp: float | None
    imu_time: float | None
    accelerometer: Vector3 | None
    gyroscope: Vector3 | None
    accelerometer_extra_variance: float
    gyroscope_extra_variance: float
    accelerometer_low_pass: Vector3 | None
    initialised: bool
    last_fix: float | None
    last_nis: float
    counters: dict[str, int] = field(default_factory=dict)
    outage_since_fix: bool = False
    last_orientation_fix: float | None = None
    imu_interval: float | None = None
    last_frame_fused: bool = False
    frames_on_gyroscope: int = 0
    layout: LayoutResiduals | None = None
    last_impact_t: float = -math.inf
    accelerometer_plateau: tuple[model.Triple, model.Triple] = ((0.0,) * 3, (0.0,) * 3)
    gyroscope_plateau: tuple[model.Triple, model.Triple] = ((0.0,) * 3, (0.0,) * 3)


def _vector(value: ArrayLike, size: int, name: str) -> NDArray[np.float64]:
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == (size,):
        return value  # the common case, cheaply
    refuse_masked(name, value)
    array = np.asarray(value, dtype=float)
    if array.shape != (size,):
        raise ValueError(f"{name}: expected shape ({size},), got {array.shape}")
    return array


def checked_sample(t: float, accelerometer: ArrayLike, gyroscope: ArrayLike
                   ) -> tuple[float, NDArray[np.float64], NDArray[np.float64], bool]:
    """An IMU sample checked for ``predict`` (every engine's): ``(t, accelerometer (3,),
    gyroscope (3,), finite)``, finite False when a value is NaN or inf (rejected, counted).
    ValueError for wrong shapes or a non-finite t."""
    t = float(t)
    accelerometer_array = _vector(accelerometer, 3, "accelerometer")
    gyroscope_array = _vector(gyroscope, 3, "gyroscope")
    if not math.isfinite(t):
        raise ValueError(f"predict: expected a finite time in s, got {t!r}")
    # math.isfinite over the six values: a tenth of np.isfinite(...).all()'s cost at IMU rate
    finite = all(map(math.isfinite, accelerometer_array.tolist() + gyroscope_array.tolist()))
    return t, accelerometer_array, gyroscope_array, finite


def frame_time(t: float, state_time: float | None, where: str) -> float:
    """A mocap frame's time as a float: ValueError (naming ``where``) unless finite and not
    before ``state_time`` (s, the filter's; None before any event)."""
    t = float(t)
    if not math.isfinite(t):
        raise ValueError(f"{where}: expected a finite time in s, got {t!r}")
    if state_time is not None and t < state_time:
        raise ValueError(f"{where}: timestamp {t!r} s is before the filter's time "
                         f"({state_time!r} s); expected events in time order")
    return t


def checked_frame(t: float, state_time: float | None, position: ArrayLike | None,
                  quaternion: ArrayLike | None
                  ) -> tuple[float, NDArray[np.float64] | None, NDArray[np.float64] | None]:
    """A mocap frame checked for ``update`` (every engine's): ``(t, z, q_global_body)`` with z
    None when occluded (None or any NaN) and the quaternion None when it is not a unit one (a
    position-only fix). ValueError for a non-finite t, t before ``state_time`` or wrong
    shapes."""
    t = frame_time(t, state_time, "update")
    z = None if position is None else _vector(position, 3, "position")
    q_global_body = None if quaternion is None else _vector(quaternion, 4, "quaternion")
    if z is not None and not np.isfinite(z).all():
        z = None
    if q_global_body is not None:
        norm = float(np.linalg.norm(q_global_body))
        if not math.isfinite(norm) or abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
            q_global_body = None  # not a unit quaternion: a position-only fix
    return t, z, q_global_body


def _clipped(sample: Vector3, sensor_range: float) -> Vector3:
    """Each axis limited to ``[-range, range]``: what a saturated sensor reports."""
    return (min(max(sample[0], -sensor_range), sensor_range),
            min(max(sample[1], -sensor_range), sensor_range),
            min(max(sample[2], -sensor_range), sensor_range))


def _squared_distance(a: Vector3, b: Vector3) -> float:
    dx, dy, dz = a[0] - b[0], a[1] - b[1], a[2] - b[2]
    return dx * dx + dy * dy + dz * dz


class KalmanFusion:
    """Streaming IMU + mocap position filter (see the module docstring).

    Args:
        imu_to_body: (4,) ``q_body_imu`` [w, x, y, z] (``recording.yaml``'s ``imu_to_body``).
        gravity: (3,) gravity in the global frame, m/s^2.
        params: noise model and behaviour.
        lever_arm: optional (3,) IMU position in the body frame relative to the rigid-body
            origin, m. None: estimated when ``params.lever_arm_std > 0``, else ignored.
    """

    def __init__(self, imu_to_body: ArrayLike, gravity: ArrayLike, params: KalmanParameters,
                 lever_arm: ArrayLike | None = None) -> None:
        if not isinstance(params, KalmanParameters):
            raise ValueError(f"params: expected KalmanParameters, got {type(params).__name__}")
        q_body_imu = _vector(imu_to_body, 4, "imu_to_body")
        if not np.isfinite(q_body_imu).all() or abs(np.linalg.norm(q_body_imu) - 1.0) > 1e-3:
            raise ValueError(f"imu_to_body: expected a finite unit quaternion [w, x, y, z], got "
                             f"{q_body_imu.tolist()}")
        self._gravity = _vector(gravity, 3, "gravity")
        if not np.isfinite(self._gravity).all():
            raise ValueError(f"gravity: expected 3 finite numbers (m/s^2), got "
                             f"{self._gravity.tolist()}")
        self._lever_arm: NDArray[np.float64] | None = None
        if lever_arm is not None:
            self._lever_arm = _vector(lever_arm, 3, "lever_arm")
            if not np.isfinite(self._lever_arm).all():
                raise ValueError(f"lever_arm: expected 3 finite numbers (m), got "
                                 f"{self._lever_arm.tolist()}")
        self.params = params
        self.size = model.state_size(lever_arm is None and params.lever_arm_std > 0)
        self._q_body_imu: Quaternion = normalise(
            (float(q_body_imu[0]), float(q_body_imu[1]), float(q_body_imu[2]),
             float(q_body_imu[3])))
        self._R_imu_body = matrix_from_quaternion(self._q_body_imu).T
        self._gate = model.gate_threshold(params.gate_probability)

        self._kf = KalmanFilter(dim_x=self.size, dim_z=model.MEASUREMENT_SIZE,
                                dim_u=model.CONTROL_SIZE)
        self._kf.x = np.zeros(self.size)
        self._kf.P = np.eye(self.size)
        self._kf.R = model.measurement_noise(params.mocap_position_noise)
        self._H = model.measurement_matrix(self.size, np.eye(3))
        self._F = np.eye(self.size)
        self._B = np.zeros((self.size, model.CONTROL_SIZE))
        self._Q = np.zeros((self.size, self.size))
        self._u = model.control_input(np.zeros(3), np.zeros(3), self._gravity)

        self._orientation = OrientationTracker(
            params.gyroscope_noise_density, params.gyroscope_bias_random_walk,
            params.mocap_orientation_noise, params.initial_gyroscope_bias_std,
            params.gyroscope_scale_error)
        self._R_current: NDArray[np.float64] | None = None  # cache of the orientation's matrix
        self._time: float | None = None
        self._imu_stamp: float | None = None  # raw timestamp of the held sample
        self._imu_time: float | None = None  # its time on the mocap clock
        self._accelerometer: Vector3 | None = None
        self._gyroscope: Vector3 | None = None
        self._accelerometer_extra_variance = 0.0
        self._gyroscope_extra_variance = 0.0
        # (tops, repeats) of each sensor's plateau test (model.plateau_step)
        self._accelerometer_plateau: tuple[model.Triple, model.Triple] = ((0.0,) * 3,
                                                                          (0.0,) * 3)
        self._gyroscope_plateau: tuple[model.Triple, model.Triple] = ((0.0,) * 3, (0.0,) * 3)
        self._accelerometer_low_pass: Vector3 | None = None
        self._initialised = False
        self._last_fix: float | None = None
        self._last_frame_fused = False  # the last mocap frame's fix was fused
        self._last_nis = math.nan
        self._outage_since_fix = False  # an interval without IMU since the last fix
        self._imu_interval: float | None = None  # the last interval between IMU samples, s
        self._last_orientation_fix: float | None = None
        # marker frames fused with the gyroscope's orientation since the last orientation fix
        # (:meth:`update_markers`: their orientation errors are one and the same)
        self._frames_on_gyroscope = 0
        # the marker layout's residuals so far (kfusion.kalman.marker_layout; None before a
        # marker frame)
        self._layout: LayoutResiduals | None = None
        self._last_impact = -math.inf  # last_impact_t
        self._counters = dict.fromkeys(COUNTER_NAMES, 0)
        # smoother support (see kfusion.kalman.smoother): product of the transitions since the
        # smoother last reset it, and the prior of the last fused fix
        self._interval: NDArray[np.float64] | None = None
        self._prior: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None

    # ------------------------------------------------------------------ public state

    @property
    def x(self) -> NDArray[np.float64]:
        """(n,) copy of the state ``[p, v, b]`` or ``[p, v, b, l]`` (p, v of the IMU point)."""
        return np.array(self._kf.x, dtype=float)

    @property
    def P(self) -> NDArray[np.float64]:  # noqa: N802 (the standard Kalman symbol)
        """(n, n) copy of the state covariance."""
        return np.array(self._kf.P, dtype=float)

    @property
    def counters(self) -> dict[str, int]:
        """Copy of the event counts (keys :data:`COUNTER_NAMES`)."""
        return dict(self._counters)

    @property
    def time(self) -> float | None:
        """Time of the state, s (None before the first event)."""
        return self._time

    @property
    def initialised(self) -> bool:
        """True once a fix has initialised the position."""
        return self._initialised

    def dead_reckoning_until(self) -> float:
        """Time (s) up to which the state is IMU-propagated since the last fix
        (:func:`kfusion.streamhealth.dead_reckoning_until`): later, a gap is ``lost``."""
        return streamhealth.dead_reckoning_until(self._imu_time, self._hold_s(),
                                                 self._outage_since_fix)

    def _hold_s(self) -> float:
        """How long the last IMU sample may be held (:func:`kfusion.streamhealth.
        hold_horizon`)."""
        return streamhealth.hold_horizon(self._imu_interval, self.params.imu_dropout_s)

    @property
    def estimates_lever_arm(self) -> bool:
        """True when the lever arm is part of the state (12 states)."""
        return self.size == model.LEVER_SIZE

    # ------------------------------------------------------------------ events

    def predict(self, t: float, accelerometer: ArrayLike, gyroscope: ArrayLike) -> str:
        """Advance to the sample's time, then keep the sample for the next interval.

        Args:
            t: sample timestamp, s; must be after the previous sample's.
            accelerometer: (3,) specific force, m/s^2, IMU frame.
            gyroscope: (3,) angular rate, rad/s, IMU frame.

        Returns:
            ``predicted``; ``duplicate`` for a repeat of the previous sample (same t and values);
            ``rejected`` for a sample with NaN/inf (counted, state untouched).

        Raises:
            ValueError: wrong shapes, non-finite t, or t not after the previous sample.
        """
        t, accelerometer_array, gyroscope_array, finite = checked_sample(t, accelerometer,
                                                                         gyroscope)
        if not finite:
            self._counters["imu_rejected"] += 1
            return REJECTED
        f = (float(accelerometer_array[0]), float(accelerometer_array[1]),
             float(accelerometer_array[2]))
        omega = (float(gyroscope_array[0]), float(gyroscope_array[1]), float(gyroscope_array[2]))
        if self._imu_stamp is not None and t <= self._imu_stamp:
            if (t == self._imu_stamp
                    and _clipped(f, self.params.accelerometer_range) == self._accelerometer
                    and _clipped(omega, self.params.gyroscope_range) == self._gyroscope):
                self._counters["imu_duplicates"] += 1
                return DUPLICATE
            raise ValueError(f"predict: timestamp {t!r} s is not after the previous IMU sample "
                             f"({self._imu_stamp!r} s); expected strictly increasing times")
        return self._predict_valid(t, f, omega)

    def update(self, t: float, position: ArrayLike | None,
               quaternion: ArrayLike | None = None) -> UpdateOutcome:
        """Advance to t (s) holding the last IMU sample, then fuse a mocap frame.

        Args:
            t: frame time, s; not before the state's time.
            position: (3,) rigid-body position, m, global frame; None or any NaN: occluded.
            quaternion: (4,) ``q_global_body`` [w, x, y, z]; None or NaN: no orientation (the
                position is still used once the orientation is known).

        Returns:
            :class:`UpdateOutcome`. A fix is gated when its NIS exceeds the chi-square quantile
            of ``gate_probability`` and its innovation is longer than ``gate_min_innovation``,
            unless it comes more than ``max_bridge_s`` after the last accepted fix (the state is
            lost): then it is accepted as a re-acquisition (after inflating the position
            and velocity covariance if it would have failed the gate).
        """
        t, z, q_global_body = checked_frame(t, self._time, position, quaternion)
        return self._update_valid(t, z, q_global_body)

    def update_markers(self, t: float, observed: ArrayLike, body_positions: ArrayLike, *,
                       shared_frames: int | None = None) -> UpdateOutcome:
        """Advance to t (s) holding the last IMU sample, then fuse a frame of individual markers
        (marker-level fusion, :mod:`kfusion.kalman.markers`).

        Each visible marker is a measurement ``z_i = p_body + R_global_body m_i``. With 3 or
        more visible (and not collinear, and fitting the cluster within
        :data:`kfusion.rigid_body.DEFAULT_MAX_RESIDUAL`) their Kabsch pose gives the
        orientation, gated against the gyroscope as a rigid body's is; otherwise the orientation
        is the gyroscope-propagated one, and its angle variance enters each marker's noise.
        Each marker is gated alone (chi-square(3) at ``gate_probability`` and beyond
        ``gate_min_innovation``, while the prediction is valid), and must agree among
        themselves (the unique largest pairwise-consistent set of 2 or more,
        :func:`kfusion.kalman.markers.consistent_markers`); one or two markers ending a gap
        (``reacquire_after_s`` after the last fix) only when the prediction tells their labels
        from any other labelling by the cluster's markers (:func:`kfusion.kalman.markers.
        labels_ambiguous`), and a lone one never after ``max_bridge_s``. The markers that pass
        are fused together with their correlated noise (:func:`kfusion.kalman.markers.
        marker_noise`), or, where all of them passed and their pose is the orientation fix, as
        that pose's origin with its covariance (:func:`kfusion.kalman.markers.
        origin_covariance`). The layout is checked against the data as frames come
        (:mod:`kfusion.kalman.marker_layout`): markers whose mean residual is significant are
        placed where the data put them, and :attr:`layout_variance` is what stays unknown.
        The first fix needs 3 markers (the orientation and position are
        initialised from their pose).

        Args:
            t: frame time, s; not before the state's time.
            observed: (k, 3) global marker positions, m; a row with any NaN or inf is occluded.
            body_positions: (k, 3) the same markers in the body frame, m (finite).
            shared_frames: offline only: how many frames share this frame's gyroscope
                orientation error (the run of frames with fewer than 3 markers it belongs to),
                so that each counts it ``shared_frames`` times and any combination of them (a
                smoother's) stays covered; None (online): the frames fused with it so far
                (:func:`kfusion.kalman.markers.common_error_variance`).

        Returns:
            :class:`UpdateOutcome` with ``markers_used`` and ``markers_gated``: ``occluded``
            (no marker, or fewer than 3 before the orientation is known), ``gated`` (every
            visible marker rejected), else ``accepted``, ``reacquired`` or ``initialised``.

        Raises:
            ValueError: shapes other than (k, 3), non-finite body positions, a non-finite t or
                a t before the state's time.
        """
        t = self._frame_time(t, "update_markers")
        refuse_masked("observed", observed)
        refuse_masked("body_positions", body_positions)
        seen = np.asarray(observed, dtype=float)
        body = np.asarray(body_positions, dtype=float)
        if seen.ndim != 2 or seen.shape[1:] != (3,) or body.shape != seen.shape:
            raise ValueError(f"update_markers: expected observed and body_positions of one "
                             f"shape (k, 3), got {seen.shape} and {body.shape}")
        if not np.isfinite(body).all():
            raise ValueError("update_markers: body_positions: expected finite numbers (m)")
        visible = np.isfinite(seen).all(axis=1)
        if self._layout is None or not self._layout.matches(body):
            self._layout = LayoutResiduals.start(body)
        layout = self._layout
        placed = body + np.where(self._layout_corrected()[:, None], layout.long_mean, 0.0)
        outcome = self._update_markers_valid(t, seen[visible], placed[visible], shared_frames,
                                             placed[~visible])
        if visible.all() and outcome.accepted and outcome.markers_used == len(body) \
                and outcome.marker_origin is not None and self._last_orientation_fix == t:
            # every marker fused, their pose taken as the orientation fix: the layout's
            # residuals (kfusion.kalman.marker_layout), always against the declared layout
            self._layout = layout.with_frame(seen, self.params.marker_position_noise ** 2)
        return outcome

    def _layout_corrected(self) -> NDArray[np.bool_]:
        """(n,) the markers placed at their layout plus their mean residual
        (:func:`kfusion.kalman.marker_layout.corrected_markers`)."""
        layout = self._layout
        assert layout is not None
        return corrected_markers(layout, self.params.marker_position_noise ** 2)

    @property
    def layout_variance(self) -> float:
        """Per-axis variance (m^2) of the rigid-body point's error that the marker layout
        leaves, common to every frame (:func:`kfusion.kalman.marker_layout.origin_variance`):
        added to the bound, never fused. 0 before a frame with every marker fused, and without
        marker frames."""
        layout = self._layout
        if layout is None or layout.frames == 0:
            return 0.0
        return origin_variance(layout, self.params.marker_position_noise ** 2)

    def _frame_time(self, t: float, where: str) -> float:
        """A mocap frame's time (:func:`frame_time` against the state's time)."""
        return frame_time(t, self._time, where)

    def estimate(self, t: float | None = None) -> FilterEstimate:
        """The estimate at t (s; default: the state's time). A later t extrapolates holding the
        last IMU sample, without changing the state; an earlier t is a ValueError."""
        if self._time is None:
            raise ValueError("estimate: no event yet; feed predict() or update() first")
        t = self._time if t is None else float(t)
        if not t >= self._time:
            raise ValueError(f"estimate: time {t!r} s is before the state's time "
                             f"({self._time!r} s); expected t >= {self._time!r}")
        x, P, quaternion, angle_variance = self._extrapolate(t)
        nan3 = np.full(3, np.nan)
        if not self._initialised:
            return FilterEstimate(t, nan3, np.full((3, 3), np.nan), nan3, nan3, nan3, nan3,
                              np.asarray(quaternion), np.full(P.shape, np.nan), LOST, math.inf,
                              self._last_nis, np.full((3, 3), np.nan))
        H, offset = self._output_map(quaternion)
        position = model.output_point(H, x, offset)
        position_covariance = model.output_covariance(H, P)
        orientation_covariance = model.orientation_error_covariance(
            model.output_arm(x, position), angle_variance)
        since = t - self._last_fix if self._last_fix is not None else math.inf
        status = streamhealth.tracking_status(
            since, self._last_frame_fused, fix_timeout_s=streamhealth.FIX_TIMEOUT_S,
            max_bridge_s=self.params.max_bridge_s,
            beyond_dead_reckoning=t > self.dead_reckoning_until())
        return FilterEstimate(
            t, position, position_covariance, np.sqrt(np.diag(position_covariance)),
            x[model.VELOCITY].copy(), x[model.BIAS].copy(), self._lever_in_use(x),
            np.asarray(quaternion), P, status, since, self._last_nis, orientation_covariance)

    @property
    def last_impact_t(self) -> float:
        """Time (s, mocap clock) of the end of the last IMU interval that was an impact
        (:func:`kfusion.kalman.model.is_impact` with ``params.impact_jerk``), -inf before one.
        It describes the IMU stream, so a reset keeps it."""
        return self._last_impact

    @property
    def angle_variance(self) -> float:
        """The orientation tracker's per-axis angle variance now, rad^2 (the orientation's part
        of the output: :attr:`FilterEstimate.orientation_covariance`)."""
        return self._orientation.angle_variance

    def output_map(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(H (3, n), c (3,)): the rigid-body point is ``H x + c`` at the current orientation."""
        return self._output_map(self._orientation.state.quaternion)

    def kernel_config(self) -> NDArray[np.float64]:
        """This filter's configuration packed for the compiled engine
        (:func:`kfusion.kalman.compiled.pack_config`; imports numba)."""
        from kfusion.kalman.compiled import pack_config

        return pack_config(self.params, self._q_body_imu, self._R_imu_body, self._gravity,
                           self._lever_arm, self.size)

    # ------------------------------------------------------------------ save / restore

    def _configuration(self) -> tuple[Any, ...]:
        lever = None if self._lever_arm is None else tuple(self._lever_arm.tolist())
        return (self.params, self._q_body_imu, tuple(self._gravity.tolist()), lever)

    def snapshot(self) -> KalmanSnapshot:
        """A copy of the whole state; :meth:`restore` continues from it bit-exactly."""
        return KalmanSnapshot(
            configuration=self._configuration(),
            x=np.array(self._kf.x, dtype=float),
            P=np.array(self._kf.P, dtype=float),
            orientation=self._orientation.state.copy(),
            time=self._time,
            imu_stamp=self._imu_stamp,
            imu_time=self._imu_time,
            accelerometer=self._accelerometer,
            gyroscope=self._gyroscope,
            accelerometer_extra_variance=self._accelerometer_extra_variance,
            gyroscope_extra_variance=self._gyroscope_extra_variance,
            accelerometer_plateau=self._accelerometer_plateau,
            gyroscope_plateau=self._gyroscope_plateau,
            accelerometer_low_pass=self._accelerometer_low_pass,
            initialised=self._initialised,
            last_fix=self._last_fix,
            last_nis=self._last_nis,
            counters=dict(self._counters),
            outage_since_fix=self._outage_since_fix,
            last_orientation_fix=self._last_orientation_fix,
            imu_interval=self._imu_interval,
            last_frame_fused=self._last_frame_fused,
            frames_on_gyroscope=self._frames_on_gyroscope,
            layout=self._layout,
            last_impact_t=self._last_impact,
        )

    def restore(self, snapshot: KalmanSnapshot) -> None:
        """Continue from ``snapshot`` (taken from a filter with the same configuration)."""
        if not isinstance(snapshot, KalmanSnapshot):
            raise ValueError(f"restore: expected a KalmanSnapshot, got "
                             f"{type(snapshot).__name__}")
        if snapshot.configuration != self._configuration():
            raise ValueError("restore: the snapshot was taken from a filter with other "
                             "parameters, imu_to_body, gravity or lever_arm; expected the same")
        self._kf.x = snapshot.x.copy()
        self._kf.P = snapshot.P.copy()
        self._orientation.state = snapshot.orientation.copy()
        self._R_current = None
        self._time = snapshot.time
        self._imu_stamp = snapshot.imu_stamp
        self._imu_time = snapshot.imu_time
        self._accelerometer = snapshot.accelerometer
        self._gyroscope = snapshot.gyroscope
        self._accelerometer_extra_variance = snapshot.accelerometer_extra_variance
        self._gyroscope_extra_variance = snapshot.gyroscope_extra_variance
        self._accelerometer_plateau = snapshot.accelerometer_plateau
        self._gyroscope_plateau = snapshot.gyroscope_plateau
        self._accelerometer_low_pass = snapshot.accelerometer_low_pass
        self._initialised = snapshot.initialised
        self._last_fix = snapshot.last_fix
        self._last_nis = snapshot.last_nis
        self._counters = dict(snapshot.counters)
        self._outage_since_fix = snapshot.outage_since_fix
        self._last_orientation_fix = snapshot.last_orientation_fix
        self._imu_interval = snapshot.imu_interval
        self._last_frame_fused = snapshot.last_frame_fused
        self._frames_on_gyroscope = snapshot.frames_on_gyroscope
        self._layout = snapshot.layout
        self._last_impact = snapshot.last_impact_t

    # ------------------------------------------------------------------ internals

    def _predict_valid(self, stamp: float, f: Vector3, omega: Vector3) -> str:
        """predict() after validation: finite sample, stamp after the previous sample's."""
        params = self.params
        if max(abs(f[0]), abs(f[1]), abs(f[2]), abs(omega[0]), abs(omega[1]),
               abs(omega[2])) > model.IMPLAUSIBLE_SAMPLE:
            self._counters["imu_rejected"] += 1
            return REJECTED
        tops, repeats, level = model.plateau_step(f, self._accelerometer,
                                                  *self._accelerometer_plateau,
                                                  model.PLATEAU_FLOOR_ACCELEROMETER)
        self._accelerometer_plateau = (tops, repeats)
        f, accelerometer_extra = self._limit(f, params.accelerometer_range,
                                             "accelerometer_saturated", level or None)
        tops, repeats, level = model.plateau_step(omega, self._gyroscope,
                                                  *self._gyroscope_plateau,
                                                  model.PLATEAU_FLOOR_GYROSCOPE)
        self._gyroscope_plateau = (tops, repeats)
        omega, gyroscope_extra = self._limit(omega, params.gyroscope_range, "gyroscope_saturated",
                                             level or None)
        t = imu_event_time(stamp, params.imu_latency_s)
        if self._imu_time is not None and t - self._imu_time > params.imu_dropout_s:
            self._counters["imu_dropouts"] += 1
        if self._time is not None and t <= self._time and self._imu_time is not None:
            if t < self._time:
                self._counters["imu_late"] += 1
        else:
            self._advance(t, f, omega)
        self._accelerometer = f
        self._gyroscope = omega
        self._accelerometer_extra_variance = accelerometer_extra
        self._gyroscope_extra_variance = gyroscope_extra
        if self._imu_time is not None:
            self._imu_interval = t - self._imu_time
        self._imu_stamp = stamp
        self._imu_time = t
        self._counters["predictions"] += 1
        return PREDICTED

    def _limit(self, sample: Vector3, sensor_range: float, counter: str,
               plateau: float | None = None) -> tuple[Vector3, float]:
        """A saturated sample (an axis at 99.9 % of the range or beyond) is counted, clipped to
        the range (what the sensor can report) and given :func:`model.saturation_variance`.
        So is a sample on a plateau below the range (``plateau``: its level, from
        :func:`model.plateau_step`), with the plateau's level as the range.

        The variance is held over the interval after the sample only: under the first-order hold
        the sample's error ramps in over the interval before it and out over the one after,
        moving the velocity by the same ``dt e`` as one interval of a held error."""
        if max(abs(sample[0]), abs(sample[1]), abs(sample[2])) < (model.SATURATION_FRACTION
                                                                   * sensor_range):
            if plateau is None:
                return sample, 0.0
            self._counters[counter] += 1
            return sample, model.saturation_variance(plateau)
        self._counters[counter] += 1
        return _clipped(sample, sensor_range), model.saturation_variance(sensor_range)

    def _interval_ends(self, t: float, f_end: Vector3 | None, omega_end: Vector3 | None
                       ) -> tuple[Vector3, Vector3, Vector3, Vector3]:
        """Specific force and rate at the start (state time) and end (t) of the interval:
        linear between the held sample and the new one, or the held sample throughout."""
        assert self._accelerometer is not None and self._gyroscope is not None
        f0, omega0 = self._accelerometer, self._gyroscope
        if f_end is None or omega_end is None:
            return f0, f0, omega0, omega0
        assert self._time is not None and self._imu_time is not None
        if self._time > self._imu_time:  # part of the interval was already covered by a hold
            weight = (self._time - self._imu_time) / (t - self._imu_time)
            f0 = (f0[0] + weight * (f_end[0] - f0[0]), f0[1] + weight * (f_end[1] - f0[1]),
                  f0[2] + weight * (f_end[2] - f0[2]))
            omega0 = (omega0[0] + weight * (omega_end[0] - omega0[0]),
                      omega0[1] + weight * (omega_end[1] - omega0[1]),
                      omega0[2] + weight * (omega_end[2] - omega0[2]))
        return f0, f_end, omega0, omega_end

    def _advance(self, t: float, f_end: Vector3 | None = None,
                 omega_end: Vector3 | None = None) -> None:
        """Propagate orientation and state from the state's time to t (s). With ``f_end``,
        ``omega_end`` (a new sample at t) the signals are linear over the interval; without,
        the held sample is held, for at most ``imu_dropout_s`` after its time. The part of the
        interval the IMU does not cover (nothing received, a stalled stream, a dropout) follows
        the no-IMU model (:meth:`_advance_without_imu`)."""
        if self._time is None:
            self._time = t
            return
        if t - self._time <= 0.0:
            return
        covered = streamhealth.imu_interval_split(self._time, t, self._imu_time,
                                                  self.params.imu_dropout_s, self._hold_s(),
                                                  f_end is not None)
        if covered < t:
            if covered > self._time:
                self._advance_with_imu(covered, None, None)
            self._advance_without_imu(t)
            return
        self._advance_with_imu(t, f_end, omega_end)

    def _advance_without_imu(self, t: float) -> None:
        """No IMU over [state time, t]: constant velocity with white acceleration
        (:func:`kfusion.streamhealth.no_imu_transition`, :func:`~kfusion.streamhealth.
        no_imu_process_noise`); the orientation becomes unknown (the next mocap orientation is
        taken as it is) and the gap is not dead-reckoned (``lost`` until the next fix)."""
        assert self._time is not None
        dt = t - self._time
        if self._initialised:
            F = streamhealth.no_imu_transition(dt, self.size)
            Q = streamhealth.no_imu_process_noise(dt, self.size,
                                                  self.params.accelerometer_bias_random_walk)
            with np.errstate(over="ignore", invalid="ignore"):
                self._kf.x = F @ self._kf.x
                self._kf.P = F @ self._kf.P @ F.T + Q
                self._symmetrise()
            if self._interval is not None:
                self._interval = F @ self._interval
            if not self._outage_since_fix:
                self._counters["imu_outages"] += 1
            self._outage_since_fix = True
            if not self._usable():
                self._reset()
        state = self._orientation.state
        if state.initialised:
            state.covariance = (streamhealth.ORIENTATION_UNKNOWN_VARIANCE, 0.0,
                                state.covariance[2])
            self._R_current = None
        self._time = t

    def _advance_with_imu(self, t: float, f_end: Vector3 | None,
                          omega_end: Vector3 | None) -> None:
        """:meth:`_advance` over an interval the IMU covers."""
        assert self._time is not None
        dt = t - self._time
        orientation = self._orientation
        if self._accelerometer is not None and orientation.state.initialised:
            f0, f1, omega0, omega1 = self._interval_ends(t, f_end, omega_end)
            noise_variance = self.params.accelerometer_noise_density ** 2 / dt
            impact = model.is_impact(_squared_distance(f0, f1), dt, self.params.impact_jerk,
                                     noise_variance)
            if impact:
                self._last_impact = t
            R0 = self._R_current if self._R_current is not None else orientation.matrix()
            angle_variance = orientation.angle_variance
            orientation.propagate(omega0, omega1, dt, self._gyroscope_extra_variance * dt * dt)
            R1 = orientation.matrix()
            self._R_current = R1
            previous_low_pass = self._accelerometer_low_pass
            low_pass = self._low_pass(f1, dt)
            if self._initialised:
                params = self.params
                force_squared = 0.5 * (f0[0] * f0[0] + f0[1] * f0[1] + f0[2] * f0[2]
                                       + f1[0] * f1[0] + f1[1] * f1[1] + f1[2] * f1[2])
                bias_variance = model.orientation_leak_variance(
                    force_squared, orientation.angle_variance - angle_variance,
                    params.tilt_error_inflation)
                if params.accelerometer_scale_error > 0.0 and previous_low_pass is not None:
                    bias_variance += model.scale_error_variance(
                        params.accelerometer_scale_error,
                        _squared_distance(low_pass, previous_low_pass), dt)
                acceleration_variance = (self._accelerometer_extra_variance
                                         + model.interpolation_variance(
                                             _squared_distance(f0, f1), noise_variance, impact)
                                         + model.motion_acceleration_variance(
                                             _squared_distance(f1, low_pass), dt,
                                             params.accelerometer_scale_error,
                                             model.LOW_PASS_TIME_CONSTANT)
                                         + model.stamp_jitter_variance(
                                             _squared_distance(f0, f1), dt,
                                             params.timestamp_jitter))
                F, B = self._F, self._B
                model.fill_interval(F, B, R0, R1, dt)
                model.control_input(f0, f1, self._gravity, out=self._u)
                Q = model.process_noise(
                    dt, params.accelerometer_noise_density, params.accelerometer_bias_random_walk,
                    acceleration_variance=acceleration_variance,
                    bias_variance=bias_variance, size=self.size, out=self._Q)
                self._kf.predict(u=self._u, B=B, F=F, Q=Q)
                self._symmetrise()
                if self._interval is not None:
                    self._interval = F @ self._interval
            if not self._usable():
                self._reset()
        self._time = t

    def _update_valid(self, t: float, z: NDArray[np.float64] | None,
                      q_global_body: NDArray[np.float64] | None) -> UpdateOutcome:
        self._advance(t)
        self._prior = None
        self._last_frame_fused = False  # until this frame's fix is fused (_mark_fix)
        if z is None:
            self._counters["occluded"] += 1
            return UpdateOutcome(t, OCCLUDED, math.nan)
        q_global_imu: Quaternion | None = None
        if q_global_body is not None:
            q_global_imu = normalise(quaternion_product(
                (float(q_global_body[0]), float(q_global_body[1]), float(q_global_body[2]),
                 float(q_global_body[3])), self._q_body_imu))
            if self._orientation_disagrees(t, q_global_imu):
                self._counters["orientation_gated"] += 1
                q_global_imu = None  # a position-only fix: the orientation stays the gyro's
        if not self._orientation.state.initialised:
            if q_global_imu is None:
                self._counters["no_orientation"] += 1
                self._counters["occluded"] += 1
                return UpdateOutcome(t, OCCLUDED, math.nan)
            self._orientation.initialise(q_global_imu)
            self._R_current = None
            self._last_orientation_fix = t
        H, offset = self._output_map(q_global_imu if q_global_imu is not None
                                     else self._orientation.state.quaternion)
        if not self._initialised:  # the orientation was initialised from this frame above
            self._initialise(t, z, H, offset)
            return UpdateOutcome(t, INITIALISED, math.nan)

        P = self._kf.P
        y = z - offset - H @ self._kf.x
        S = H @ P @ H.T + self._kf.R
        nis = model.normalised_innovation_squared(y, S)
        self._last_nis = nis
        if not (math.isfinite(nis) and math.isfinite(float(y @ y))):
            # an absurd (finite but huge) fix overflows the innovation: never fuse it
            self._counters["gated"] += 1
            return UpdateOutcome(t, GATED, nis)
        since = t - self._last_fix if self._last_fix is not None else math.inf
        kind = ACCEPTED
        failed = nis > self._gate and float(y @ y) > self.params.gate_min_innovation ** 2
        if failed and since <= self.params.max_bridge_s:
            # the prediction is still valid: a fix that disagrees with it is a jump or a marker
            # swap, however long ago the last fix was (never a re-acquisition by time alone)
            self._counters["gated"] += 1
            return UpdateOutcome(t, GATED, nis)
        if since >= self.params.reacquire_after_s:
            kind = REACQUIRED
            if nis > self._gate:
                self._inflate_for_reacquisition(y, since)
        if self._interval is not None:
            self._prior = (np.array(self._kf.x, dtype=float), np.array(self._kf.P, dtype=float))
        self._kf.update(z - offset, H=H)
        self._symmetrise()
        if q_global_imu is not None:
            self._orientation.correct(q_global_imu)
            self._R_current = None
            self._last_orientation_fix = t
            self._frames_on_gyroscope = 0
        self._mark_fix(t)
        if kind == REACQUIRED:
            self._counters["reacquired"] += 1
        return UpdateOutcome(t, kind, nis, y=y, S=S)

    def _update_markers_valid(self, t: float, points: NDArray[np.float64],
                              body: NDArray[np.float64], shared_frames: int | None,
                              hidden: NDArray[np.float64]) -> UpdateOutcome:
        """update_markers() after validation: ``points`` (k, 3) the visible markers (finite),
        ``body`` (k, 3) their body-frame positions, ``hidden`` (h, 3) the cluster's other
        markers' (the labels a lone marker could carry instead)."""
        self._advance(t)
        self._prior = None
        self._last_frame_fused = False  # until this frame's fix is fused (_mark_fix)
        if len(points) == 0:
            self._counters["occluded"] += 1
            return UpdateOutcome(t, OCCLUDED, math.nan)
        marker_variance = self.params.marker_position_noise ** 2
        # the cluster's pose only when every marker fits it within its noise (chi-square(3) at
        # the gate): one marker 6-8 mm off tilts a Kabsch fit by degrees, within the
        # converter's 10 mm, and the orientation it gives would then misplace every marker
        pose = marker_pose(points, body, max_residual=math.sqrt(self._gate * marker_variance))
        origin = None if pose is None else (float(pose[0][0]), float(pose[0][1]),
                                             float(pose[0][2]))
        orientation = self._orientation
        q_global_imu: Quaternion | None = None
        fit_variance = math.inf  # of the markers' own orientation (Kabsch), rad^2
        if pose is not None:
            q = pose[1]
            q_global_imu = normalise(quaternion_product(
                (float(q[0]), float(q[1]), float(q[2]), float(q[3])), self._q_body_imu))
            fit_variance = max(orientation.measurement_variance,
                               fit_angle_variance(body, marker_variance))
            # a marker cluster's pose with labels swapped or cycled can fit within
            # DEFAULT_MAX_RESIDUAL, rotated: gated against the gyroscope for as long as the
            # gyroscope's orientation holds, not only max_bridge_s
            if self._orientation_disagrees(t, q_global_imu, fit_variance,
                                           gyroscope_unbroken=True):
                self._counters["orientation_gated"] += 1
                q_global_imu = None  # positions only: the orientation stays the gyro's
        if not orientation.state.initialised:
            if q_global_imu is None:
                self._counters["no_orientation"] += 1
                self._counters["occluded"] += 1
                return UpdateOutcome(t, OCCLUDED, math.nan)
            orientation.initialise(q_global_imu)
            state = orientation.state
            state.covariance = (fit_variance, 0.0, state.covariance[2])
            self._R_current = None
            self._last_orientation_fix = t
        if q_global_imu is not None:
            quaternion, angle_variance = q_global_imu, fit_variance
        else:
            # the gyroscope's orientation error is the same in this frame as in the previous
            # frames fused with it: counted once in all (module docstring of kfusion.kalman.
            # markers, "Correlated orientation error")
            quaternion = orientation.state.quaternion
            frames = self._frames_on_gyroscope + 1
            angle_variance = common_error_variance(orientation.angle_variance, frames
                                                   if shared_frames is None
                                                   else max(frames, shared_frames))
        H, offset = self._output_map(quaternion)
        if not self._initialised:
            if pose is None or q_global_imu is None:
                self._counters["occluded"] += 1
                return UpdateOutcome(t, OCCLUDED, math.nan)
            self._initialise(t, pose[0], H, offset)
            self._counters["markers_used"] += len(points)
            return UpdateOutcome(t, INITIALISED, math.nan, markers_used=len(points),
                                 marker_origin=origin)

        R_global_body = matrix_from_quaternion(quaternion) @ self._R_imu_body
        H_all, offset_all = stacked_measurement(H, offset, R_global_body, body)
        lever = self._lever_in_use(self._kf.x)
        arms = marker_arms(R_global_body, body, lever)
        R_all = marker_noise(arms, marker_variance, angle_variance)
        P = self._kf.P
        with np.errstate(over="ignore", invalid="ignore"):
            innovations = (points.ravel() - offset_all - H_all @ self._kf.x).reshape(-1, 3)
        point_covariance = H @ P @ H.T
        nis_each = [marker_nis(innovations[i], point_covariance
                               + R_all[3 * i:3 * i + 3, 3 * i:3 * i + 3])
                    for i in range(len(points))]
        since = t - self._last_fix if self._last_fix is not None else math.inf
        prediction_valid = since <= self.params.max_bridge_s
        keep = marker_gate(nis_each, innovations, self._gate, self.params.gate_min_innovation,
                           prediction_valid)
        if len(points) >= 2:
            # the markers must also agree among themselves: a swap or cycled labels make them
            # disagree by centimetres, and a prediction grown loose (or none, after
            # max_bridge_s) could let a wrong one through its own gate
            # no gate_min_innovation escape here: the pairwise test does not depend on the
            # state's covariance, so an overconfident P cannot make it reject good markers,
            # while the escape let a marker 6-10 mm off be fused at 0.5 mm noise
            keep &= consistent_markers(innovations, R_all, self._gate, 0.0)
        if len(points) == 1 and not prediction_valid:
            keep[:] = False  # a lone marker after max_bridge_s: nothing can check its label
        if 0 < keep.sum() <= 2 and since >= self.params.reacquire_after_s and labels_ambiguous(
                    innovations[keep], point_covariance, arms[keep],
                    np.vstack([marker_arms(R_global_body, hidden, lever), arms[~keep]]),
                    marker_variance, angle_variance, self._gate):
            # one or two markers ending a gap whose labels nothing can check: another
            # labelling by the cluster's markers fits the prediction (and each other) as well.
            # A labeller guesses the labels of markers reappearing alone or in a pair; with a
            # neighbour's label a lone marker re-acquired the track 70 mm off, tracked with a
            # 4-8 mm bound (up to 18x), and a rectangle's pair under the other pair's labels
            # 4 cm off (34.5x). The track waits for a pose (3 markers) or a prediction that
            # tells the labels apart. Only at a re-acquisition: while frames keep coming, the
            # labels carry over and a relabelling is a jump the gate sees (tested on every
            # frame, a small rectangle's correctly labelled pair was refused until the
            # prediction had grown loose, and lost for good: 38-54 % of the rows)
            keep[:] = False
        rejected = int(len(points) - keep.sum())
        self._counters["markers_gated"] += rejected
        if not keep.any():
            self._counters["gated"] += 1
            self._last_nis = float(min(nis_each))
            return UpdateOutcome(t, GATED, self._last_nis, markers_gated=rejected,
                                 marker_origin=origin)
        rows = np.repeat(keep, 3)
        H_used, R_used = H_all[rows], R_all[np.ix_(rows, rows)]
        y = innovations[keep].ravel()
        used = int(keep.sum())
        S_used = H_used @ P @ H_used.T + R_used
        nis = model.normalised_innovation_squared(y, S_used) / used
        self._last_nis = nis
        kind = ACCEPTED
        if since >= self.params.reacquire_after_s:
            kind = REACQUIRED
            if max(nis_each[i] for i in np.flatnonzero(keep)) > self._gate:
                self._inflate_for_reacquisition(innovations[keep].mean(axis=0), since)
        if self._interval is not None:
            self._prior = (np.array(self._kf.x, dtype=float), np.array(self._kf.P, dtype=float))
        if q_global_imu is not None and pose is not None and keep.all():
            # the orientation is these markers' own fit: their information is the fit's
            # origin, with its own covariance (the orientation error it carries is the
            # markers' noise, not independent of it, as the stacked rows would take it: they
            # left the lever's part of the bound at 0.5-0.7 of its size), fused once
            covariance = R_global_body @ origin_covariance(body - lever, marker_variance) \
                @ R_global_body.T
            self._kf.update(np.asarray(pose[0], dtype=float) - offset,
                            R=0.5 * (covariance + covariance.T), H=H)
        else:
            # z - c = H x + r, fused as one stacked measurement (filterpy's Joseph-form update)
            self._kf.update(points[keep].ravel() - offset_all[rows], R=R_used, H=H_used)
        self._symmetrise()
        if q_global_imu is not None:
            orientation.correct(q_global_imu, fit_variance)
            self._R_current = None
            self._last_orientation_fix = t
            self._frames_on_gyroscope = 0
        else:
            self._frames_on_gyroscope += 1
        self._mark_fix(t)
        self._counters["markers_used"] += used
        if kind == REACQUIRED:
            self._counters["reacquired"] += 1
        # the stacked innovation's position part: what the monitor's block test sums
        y_origin, S_origin = pooled_innovation(y, S_used) if math.isfinite(nis) else (None, None)
        return UpdateOutcome(t, kind, nis, markers_used=used, markers_gated=rejected,
                             marker_origin=origin, y=y_origin, S=S_origin)

    def _inflate_for_reacquisition(self, innovation: NDArray[np.float64], since: float
                                   ) -> None:
        """Add :func:`kfusion.kalman.model.reacquisition_inflation` of the innovation (3,) m
        after ``since`` s without a fix to the position and velocity covariance."""
        position_variance, velocity_variance = model.reacquisition_inflation(innovation, since)
        P = self._kf.P.copy()
        P[model.POSITION, model.POSITION] += position_variance * np.eye(3)
        P[model.VELOCITY, model.VELOCITY] += velocity_variance * np.eye(3)
        self._kf.P = P

    def _usable(self) -> bool:
        """False when a propagation overflowed (an interval of 1e200 s, say) or left the
        position std beyond :data:`~kfusion.kalman.model.FORGOTTEN_POSITION_STD` (a pause of
        minutes without fixes): :func:`kfusion.kalman.model.state_usable`."""
        state = self._orientation.state
        return bool(math.isfinite(sum(state.covariance) + sum(state.quaternion))
                    and model.state_usable(self._kf.x, self._kf.P, model.POSITION))

    def _reset(self) -> None:
        """Forget position and orientation: the state is unknown (``lost``) until a fix with an
        orientation initialises it again. Counted as ``resets``."""
        self._initialised = False
        self._orientation.state = OrientationState()
        self._R_current = None
        self._kf.x = np.zeros(self.size)
        self._kf.P = np.eye(self.size)
        self._last_fix = None
        self._last_orientation_fix = None
        self._counters["resets"] += 1

    def _orientation_disagrees(self, t: float, q_global_imu: Quaternion,
                               measurement_variance: float | None = None, *,
                               gyroscope_unbroken: bool = False) -> bool:
        """The mocap orientation fails the gate against the gyroscope-propagated one
        (:func:`kfusion.streamhealth.orientation_gated`), while that one is still valid (an
        accepted orientation at most ``max_bridge_s`` ago, or with ``gyroscope_unbroken``
        any time the gyroscope has had no outage since the last fix: its covariance grows
        with the time it has integrated alone). ``measurement_variance``: the orientation's
        noise (rad^2) when not the configured one."""
        state = self._orientation.state
        recent = (self._last_orientation_fix is not None
                  and t - self._last_orientation_fix <= self.params.max_bridge_s)
        if not (state.initialised and self.params.gating and (
                recent or (gyroscope_unbroken and not self._outage_since_fix))):
            return False
        innovation = quaternion_log(quaternion_product(conjugate(state.quaternion),
                                                       q_global_imu))
        return streamhealth.orientation_gated(
            innovation, state.covariance[0], self._orientation.measurement_variance
            if measurement_variance is None else measurement_variance, self._gate)

    def _mark_fix(self, t: float) -> None:
        self._outage_since_fix = False
        self._last_fix = t
        self._last_frame_fused = True
        self._counters["updates"] += 1

    def _initialise(self, t: float, z: NDArray[np.float64], H: NDArray[np.float64],
                    offset: NDArray[np.float64]) -> None:
        params = self.params
        R_global_body = -H[:, model.LEVER] if self.estimates_lever_arm else None
        self._kf.x = model.initial_state(z - offset, self.size)
        self._kf.P = model.initial_covariance(
            params.mocap_position_noise, params.initial_velocity_std, params.initial_bias_std,
            params.lever_arm_std, self.size, R_global_body)
        self._initialised = True
        self._mark_fix(t)
        self._counters["initialised"] += 1

    def _low_pass(self, f: Vector3, dt: float) -> Vector3:
        """Advance the low-passed specific force (scale-error term) by dt with the value f."""
        previous = self._accelerometer_low_pass
        if previous is None:
            self._accelerometer_low_pass = f
            return f
        weight = model.low_pass_weight(dt)
        low_pass = (previous[0] + weight * (f[0] - previous[0]),
                    previous[1] + weight * (f[1] - previous[1]),
                    previous[2] + weight * (f[2] - previous[2]))
        self._accelerometer_low_pass = low_pass
        return low_pass

    def _symmetrise(self) -> None:
        P = self._kf.P
        self._kf.P = 0.5 * (P + P.T)

    def _output_map(self, q_global_imu: Quaternion
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(H, c) with rigid-body point ``= H x + c`` at orientation ``q_global_imu``:
        c = ``-R_global_body lever`` for a given lever arm, else 0."""
        if self._lever_arm is None and not self.estimates_lever_arm:
            return self._H, np.zeros(3)
        R_global_body = matrix_from_quaternion(q_global_imu) @ self._R_imu_body
        if self.estimates_lever_arm:
            return model.measurement_matrix(self.size, R_global_body), np.zeros(3)
        assert self._lever_arm is not None
        return self._H, -(R_global_body @ self._lever_arm)

    def _lever_in_use(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        if self.estimates_lever_arm:
            return np.array(x[model.LEVER], dtype=float)
        if self._lever_arm is not None:
            return self._lever_arm.copy()
        return np.zeros(3)

    def _extrapolate(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64],
                                              Quaternion, float]:
        """State, covariance, orientation and its angle variance (rad^2) at t >= the state's
        time, without changing them."""
        assert self._time is not None
        dt = t - self._time
        orientation = self._orientation
        if (dt <= 0.0 or self._accelerometer is None or self._gyroscope is None
                or not orientation.state.initialised or not self._initialised):
            return (np.array(self._kf.x, dtype=float), np.array(self._kf.P, dtype=float),
                    orientation.state.quaternion, orientation.angle_variance)
        scratch = copy.copy(orientation)  # propagate a copy: estimate() never changes the state
        scratch.state = orientation.state.copy()
        f, omega = self._accelerometer, self._gyroscope
        R0 = scratch.matrix()
        angle_variance = scratch.angle_variance
        scratch.propagate(omega, omega, dt, self._gyroscope_extra_variance * dt * dt)
        quaternion = scratch.state.quaternion
        R1 = scratch.matrix()
        bias_variance = model.orientation_leak_variance(
            f[0] * f[0] + f[1] * f[1] + f[2] * f[2], scratch.angle_variance - angle_variance,
            self.params.tilt_error_inflation)
        u = model.control_input(f, f, self._gravity)
        Q = model.process_noise(dt, self.params.accelerometer_noise_density,
                                self.params.accelerometer_bias_random_walk,
                                acceleration_variance=self._accelerometer_extra_variance,
                                bias_variance=bias_variance, size=self.size)
        x, P = self._kf.get_prediction(u=u, B=model.control_matrix(R0, R1, dt, self.size),
                                       F=model.transition_matrix(R0, R1, dt, self.size), Q=Q)
        return np.asarray(x, dtype=float), 0.5 * (P + P.T), quaternion, scratch.angle_variance
