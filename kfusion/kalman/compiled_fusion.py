""":class:`CompiledFusion`: the streaming filter with the interface of
:class:`kfusion.kalman.KalmanFusion`, backed by the compiled step functions of
:mod:`kfusion.kalman.compiled` (``predict_step``, ``update_step``, ``extrapolate``).

Inputs are validated here exactly as :class:`KalmanFusion` validates them (same checks, same
messages, same outcomes), so no NaN reaches a kernel; the state lives in flat arrays that the
kernels update in place. Kept apart from the kernels' module so that editing this class does not
invalidate numba's on-disk cache of the kernels.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any, Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kfusion import streamhealth
from kfusion.conventions import LOST
from kfusion.kalman import compiled, model
from kfusion.kalman.filter import (
    DUPLICATE,
    PREDICTED,
    REJECTED,
    FilterEstimate,
    KalmanFusion,
    UpdateOutcome,
    checked_frame,
    checked_sample,
)
from kfusion.kalman.parameters import KalmanParameters


@dataclass(frozen=True, slots=True)
class CompiledSnapshot:
    """Everything :meth:`CompiledFusion.restore` needs to continue a run bit-exactly (slots:
    the Tracker takes two at every checkpoint, and a frozen dataclass without them takes
    twice as long to build)."""

    configuration: tuple[float, ...]
    state: NDArray[np.float64]  # packed (kfusion.kalman.compiled.state_views)
    counters: NDArray[np.int64] = field(default_factory=lambda: np.zeros(0, dtype=np.int64))


class CompiledFusion:
    """Streaming IMU + mocap position filter on the compiled engine; the same arguments,
    methods and properties as :class:`kfusion.kalman.KalmanFusion` (whose docstring explains
    the model). Snapshots are :class:`CompiledSnapshot` (restore them into a CompiledFusion)."""

    def __init__(self, imu_to_body: ArrayLike, gravity: ArrayLike, params: KalmanParameters,
                 lever_arm: ArrayLike | None = None) -> None:
        # the reference validates the arguments and builds the configuration (one place)
        reference = KalmanFusion(imu_to_body, gravity, params, lever_arm=lever_arm)
        self.params = params
        self.size = reference.size
        self._config = reference.kernel_config()
        self._configuration = tuple(self._config.tolist())
        # the whole state in one array (one kernel argument, one copy per snapshot); the
        # attributes below are views into it
        self._state = np.zeros(compiled.packed_size(self.size))
        (self._x, self._P, self._orientation, self._scalars, self._prior_x,
         self._prior_P) = compiled.state_views(self._state, self.size)
        self._P[:, :] = np.eye(self.size)
        self._orientation[:] = compiled.initial_orientation()
        self._scalars[:] = compiled.initial_scalars()
        self._counters = np.zeros(len(compiled.COUNTER_INDEX), dtype=np.int64)
        self._no_quaternion = np.zeros(4)
        self._accelerometer_range = float(params.accelerometer_range)
        self._gyroscope_range = float(params.gyroscope_range)
        # read-only view for the Tracker's finiteness check (the kernels write in place)
        self._kf = SimpleNamespace(x=self._x, P=self._P)
        self._checked_shadow: CompiledFusion | None = None  # see predict_valid_with

    # ------------------------------------------------------------------ public state

    @property
    def x(self) -> NDArray[np.float64]:
        """(n,) copy of the state."""
        return self._x.copy()

    @property
    def P(self) -> NDArray[np.float64]:  # noqa: N802 (the standard Kalman symbol)
        """(n, n) copy of the state covariance."""
        return self._P.copy()

    @property
    def counters(self) -> dict[str, int]:
        """Copy of the event counts (keys :data:`kfusion.kalman.filter.COUNTER_NAMES`)."""
        return dict(zip(compiled.COUNTER_INDEX, self._counters.tolist(), strict=True))

    def counter(self, name: str) -> int:
        """One of :attr:`counters` (a key of :data:`kfusion.kalman.filter.COUNTER_NAMES`),
        without copying them all (the Tracker reads ``resets`` around every frame)."""
        return int(self._counters[compiled.COUNTER_INDEX[name]])

    @property
    def time(self) -> float | None:
        """Time of the state, s (None before the first event)."""
        return _optional(self._scalars[compiled.TIME])

    @property
    def initialised(self) -> bool:
        """True once a fix has initialised the position."""
        return bool(self._scalars[compiled.INITIALISED_FLAG] != 0.0)

    @property
    def estimates_lever_arm(self) -> bool:
        """True when the lever arm is part of the state (12 states)."""
        return self.size == model.LEVER_SIZE

    def dead_reckoning_until(self) -> float:
        """Time (s) up to which the state is IMU-propagated since the last fix."""
        return float(compiled.dead_reckoning_until(self._scalars, self._config))

    # ------------------------------------------------------------------ events

    def predict(self, t: float, accelerometer: ArrayLike, gyroscope: ArrayLike) -> str:
        """:meth:`KalmanFusion.predict` (same checks, outcomes and errors)."""
        f_values, omega_values = _three_floats(accelerometer), _three_floats(gyroscope)
        if type(t) is float and math.isfinite(t) and f_values is not None \
                and omega_values is not None:  # the common types, checked cheaply
            values = f_values + omega_values
            finite = all(map(math.isfinite, values))
        else:  # every other input: the full checks and their messages
            t, f, omega, finite = checked_sample(t, accelerometer, gyroscope)
            values = f.tolist() + omega.tolist()
        if not finite:
            self._counters[_IMU_REJECTED] += 1
            return REJECTED
        a0, a1, a2, g0, g1, g2 = values
        stamp = float(self._scalars[compiled.IMU_STAMP])
        if not math.isnan(stamp) and t <= stamp:
            held = self._scalars
            f, omega = np.array(values[:3]), np.array(values[3:])
            if (t == stamp and np.array_equal(
                    np.clip(f, -self._accelerometer_range, self._accelerometer_range),
                    held[compiled.ACCELEROMETER:compiled.ACCELEROMETER + 3])
                    and np.array_equal(np.clip(omega, -self._gyroscope_range,
                                               self._gyroscope_range),
                                       held[compiled.GYROSCOPE:compiled.GYROSCOPE + 3])):
                self._counters[_IMU_DUPLICATES] += 1
                return DUPLICATE
            raise ValueError(f"predict: timestamp {t!r} s is not after the previous IMU sample "
                             f"({stamp!r} s); expected strictly increasing times")
        return self.predict_valid(t, a0, a1, a2, g0, g1, g2)

    def predict_valid(self, t: float, a0: float, a1: float, a2: float, g0: float, g1: float,
                      g2: float) -> str:
        """:meth:`predict` of a sample its caller has checked (the checks of :meth:`predict`:
        t a finite float after the previous sample's stamp; specific force a0..a2 m/s^2 and
        rate g0..g2 rad/s finite floats): one kernel call (the :class:`kfusion.tracker.Tracker`
        validates every sample before it fuses it, and calls :meth:`predict_valid_with`)."""
        counters = self._counters
        rejected = counters[_IMU_REJECTED]
        compiled.packed_predict(t, a0, a1, a2, g0, g1, g2, self._state, self._config,
                                counters, self.size)
        return REJECTED if counters[_IMU_REJECTED] != rejected else PREDICTED

    def predict_valid_with(self, shadow: CompiledFusion | None, t: float, a0: float, a1: float,
                           a2: float, g0: float, g1: float, g2: float) -> float:
        """:meth:`predict_valid` of one checked sample on this filter and on ``shadow`` (a
        filter built with the same arguments: the consistency monitor's shadow while a shadow
        gap runs, :attr:`kfusion.monitor.ConsistencyMonitor.gap_shadow`; None: none) in one
        kernel call, as two :meth:`predict_valid` calls would; returns this filter's
        :meth:`dead_reckoning_until` after the sample, s."""
        if shadow is None:
            shadow_state, shadow_counters = _NO_STATE, _NO_COUNTERS
        else:
            if shadow is not self._checked_shadow:
                self._check_shadow(shadow)
            shadow_state, shadow_counters = shadow._state, shadow._counters
        return compiled.packed_predict_with_shadow(
            t, a0, a1, a2, g0, g1, g2, self._state, self._counters, shadow_state,
            shadow_counters, self._config, self.size)

    def _check_shadow(self, shadow: CompiledFusion) -> None:
        """ValueError unless ``shadow`` is a CompiledFusion of this configuration (its kernel
        call uses this filter's configuration array); remembered as checked."""
        if not isinstance(shadow, CompiledFusion) or shadow._configuration != self._configuration:
            raise ValueError("predict_valid_with: shadow: expected a CompiledFusion built with "
                             "the same parameters, imu_to_body, gravity and lever_arm")
        self._checked_shadow = shadow

    def update(self, t: float, position: ArrayLike | None,
               quaternion: ArrayLike | None = None) -> UpdateOutcome:
        """:meth:`KalmanFusion.update` (same checks, outcomes and errors)."""
        t, z, q_global_body = checked_frame(t, self.time, position, quaternion)
        kind, nis, y, S = compiled.packed_update(
            t, z is not None, _NO_POSITION if z is None else np.ascontiguousarray(z),
            self._no_quaternion if q_global_body is None else np.ascontiguousarray(q_global_body),
            q_global_body is not None, self._state, self._config, self._counters, self.size)
        fused = not math.isnan(y[0])
        return UpdateOutcome(t, compiled.OUTCOME_NAMES[kind], float(nis),
                             y=y if fused else None, S=S if fused else None)

    def estimate(self, t: float | None = None) -> FilterEstimate:
        """:meth:`KalmanFusion.estimate`: the estimate at t (s; default: the state's time)."""
        time = self.time
        if time is None:
            raise ValueError("estimate: no event yet; feed predict() or update() first")
        t = time if t is None else float(t)
        if not t >= time:
            raise ValueError(f"estimate: time {t!r} s is before the state's time "
                             f"({time!r} s); expected t >= {time!r}")
        x, P, quaternion, angle_variance = compiled.extrapolate(
            t, self._x, self._P, self._orientation, self._scalars, self._config)
        last_nis = float(self._scalars[compiled.LAST_NIS])
        if not self.initialised:
            nan3 = np.full(3, np.nan)
            return FilterEstimate(t, nan3, np.full((3, 3), np.nan), nan3, nan3, nan3, nan3,
                                  quaternion, np.full(P.shape, np.nan), LOST, math.inf,
                                  last_nis, np.full((3, 3), np.nan))
        H, offset = compiled.output_map(quaternion, self.size, self._config)
        position = model.output_point(H, x, offset)
        position_covariance = model.output_covariance(H, P)
        orientation_covariance = model.orientation_error_covariance(
            model.output_arm(x, position), float(angle_variance))
        last_fix = self._scalars[compiled.LAST_FIX]
        since = math.inf if math.isnan(last_fix) else t - float(last_fix)
        status = streamhealth.tracking_status(
            since, bool(self._scalars[compiled.LAST_FRAME_FUSED] != 0.0),
            fix_timeout_s=streamhealth.FIX_TIMEOUT_S, max_bridge_s=self.params.max_bridge_s,
            beyond_dead_reckoning=t > self.dead_reckoning_until())
        return FilterEstimate(
            t, position, position_covariance, np.sqrt(np.diag(position_covariance)),
            x[model.VELOCITY].copy(), x[model.BIAS].copy(), self._lever_in_use(x),
            quaternion, P, status, since, last_nis, orientation_covariance)

    @property
    def last_impact_t(self) -> float:
        """:attr:`KalmanFusion.last_impact_t`: the time of the last impact, s (-inf: none)."""
        return float(self._scalars[compiled.LAST_IMPACT])

    @property
    def angle_variance(self) -> float:
        """:attr:`KalmanFusion.angle_variance`: the orientation's angle variance now, rad^2."""
        return float(self._orientation[7])

    def output_map(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(H (3, n), c (3,)): the rigid-body point is ``H x + c`` at the current orientation."""
        H, offset = compiled.output_map(self._orientation[0:4].copy(), self.size, self._config)
        return H, offset

    def _lever_in_use(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        if self.estimates_lever_arm:
            return np.array(x[model.LEVER], dtype=float)
        if self._config[compiled.C_LEVER_GIVEN] != 0.0:
            return self._config[compiled.C_LEVER:compiled.C_LEVER + 3].copy()
        return np.zeros(3)

    # ------------------------------------------------------------------ save / restore

    def snapshot(self) -> CompiledSnapshot:
        """A copy of the whole state; :meth:`restore` continues from it bit-exactly."""
        return CompiledSnapshot(self._configuration, self._state.copy(), self._counters.copy())

    def restore(self, snapshot: CompiledSnapshot) -> None:
        """Continue from ``snapshot`` (taken from a filter with the same configuration)."""
        if not isinstance(snapshot, CompiledSnapshot):
            raise ValueError(f"restore: expected a CompiledSnapshot, got "
                             f"{type(snapshot).__name__}")
        if snapshot.configuration != self._configuration:
            raise ValueError("restore: the snapshot was taken from a filter with other "
                             "parameters, imu_to_body, gravity or lever_arm; expected the same")
        self._state[:] = snapshot.state
        self._counters[:] = snapshot.counters


_IMU_REJECTED: Final = compiled.COUNTER_INDEX["imu_rejected"]
_IMU_DUPLICATES: Final = compiled.COUNTER_INDEX["imu_duplicates"]
_NO_POSITION: Final = np.zeros(3)  # read by no kernel: an occluded frame's z
_NO_STATE: Final = np.zeros(0)  # no shadow (CompiledFusion.predict_valid_with)
_NO_COUNTERS: Final = np.zeros(0, dtype=np.int64)


def _three_floats(value: object) -> list[float] | None:
    """``value``'s entries as floats when it is a float64 array of shape (3,) or a tuple or list
    of 3 floats (what the Tracker, the monitor and the batch driver pass), else None (the caller
    then runs the full checks)."""
    kind = type(value)
    if kind is np.ndarray:
        array: NDArray[np.float64] = value  # type: ignore[assignment]
        return array.tolist() if array.dtype == np.float64 and array.shape == (3,) else None
    if kind is tuple or kind is list:
        items: Any = value
        if len(items) == 3 and all(type(item) is float for item in items):
            return list(items)
    return None


def _optional(value: Any) -> float | None:
    """NaN (the kernels' None) -> None."""
    value = float(value)
    return None if math.isnan(value) else value
