"""The position filter written out directly in numpy, without filterpy: a cross-check.

:func:`reference_filter` runs the same model and the same event policy as
:func:`kfusion.kalman.run_filter` (first-order hold, latency, orientation leak, scale-error and
interpolation noise, gating, re-acquisition, lever arm), but every equation is spelled out here
instead of going through ``filterpy.kalman.KalmanFilter`` and :mod:`kfusion.kalman.model`:

* the mean moves by the kinematic equations themselves, ``v1 = v0 + dt (a0 + a1)/2`` and
  ``p1 = p0 + v0 dt + dt^2 (a0/3 + a1/6)`` with ``a = R (f - b) + g``, not by ``F x + B u``;
* the covariance by its Jacobian blocks, written out;
* the update in the form ``P = P - K S K^T`` (equal to filterpy's Joseph form for the optimal
  gain), with ``K = P H^T S^-1``.

Shared with the filter are only the parameters, four model constants, the orientation tracker
(its output, the rotation, is an input of the position filter) and the chi-square quantile.
Tests require the two to agree to 1e-9 over whole recordings with gaps. Not written out here:
the stream-health rules of :mod:`kfusion.streamhealth` (IMU outages, orientation gating, poses
held through occlusions), which the recordings it is compared on never trigger; the two engines
of :mod:`kfusion.kalman` are cross-tested on those.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from kfusion.kalman.events import imu_event_time
from kfusion.kalman.model import (  # the state's blocks come from kfusion.kalman.layout
    BIAS,
    IMPLAUSIBLE_SAMPLE,
    LEVER,
    LOW_PASS_TIME_CONSTANT,
    POSITION,
    SATURATION_FRACTION,
    SCALE_ERROR_COHERENCE_S,
    VELOCITY,
)
from kfusion.kalman.orientation import (
    OrientationTracker,
    matrix_from_quaternion,
    normalise,
    quaternion_product,
)
from kfusion.kalman.parameters import KalmanParameters
from kfusion.recording import Recording, on_mocap_clock


@dataclass(frozen=True)
class ReferenceRun:
    """Per mocap row: state (m, n), covariance (m, n, n), rigid-body point (m, 3), its 1-sigma
    (m, 3), the update's outcome (m,) and NIS (m,)."""

    x: NDArray[np.float64]
    P: NDArray[np.float64]
    position: NDArray[np.float64]
    std: NDArray[np.float64]
    outcome: NDArray[np.str_]
    nis: NDArray[np.float64]


class _Reference:
    def __init__(self, recording: Recording, params: KalmanParameters) -> None:
        info = recording.info
        self.params = params
        self.lever = None if info.lever_arm is None else np.array(info.lever_arm, dtype=float)
        self.estimate_lever = self.lever is None and params.lever_arm_std > 0
        self.n = 12 if self.estimate_lever else 9
        q = info.imu_to_body
        self.q_body_imu = normalise((float(q[0]), float(q[1]), float(q[2]), float(q[3])))
        self.R_imu_body = matrix_from_quaternion(self.q_body_imu).T
        self.g = np.array(info.gravity, dtype=float)
        self.gate = (math.inf if params.gate_probability is None or params.gate_probability >= 1
                     else float(chi2.ppf(params.gate_probability, 3)))
        self.orientation = OrientationTracker(
            params.gyroscope_noise_density, params.gyroscope_bias_random_walk,
            params.mocap_orientation_noise, params.initial_gyroscope_bias_std,
            params.gyroscope_scale_error)
        self.x = np.zeros(self.n)
        self.P = np.eye(self.n)
        self.time: float | None = None
        self.sample_time: float | None = None
        self.f: NDArray[np.float64] | None = None
        self.omega: NDArray[np.float64] | None = None
        self.f_extra = 0.0
        self.omega_extra = 0.0
        self.low_pass: NDArray[np.float64] | None = None
        self.initialised = False
        self.last_fix: float | None = None

    # ---------------------------------------------------------------- prediction

    def sample(self, stamp: float, f: NDArray[np.float64], omega: NDArray[np.float64]) -> None:
        params = self.params
        if max(np.max(np.abs(f)), np.max(np.abs(omega))) > IMPLAUSIBLE_SAMPLE:
            return
        f_extra = omega_extra = 0.0
        if np.max(np.abs(f)) >= SATURATION_FRACTION * params.accelerometer_range:
            f = np.clip(f, -params.accelerometer_range, params.accelerometer_range)
            f_extra = (params.accelerometer_range / 2) ** 2
        if np.max(np.abs(omega)) >= SATURATION_FRACTION * params.gyroscope_range:
            omega = np.clip(omega, -params.gyroscope_range, params.gyroscope_range)
            omega_extra = (params.gyroscope_range / 2) ** 2
        t = imu_event_time(stamp, params.imu_latency_s)
        if not (self.time is not None and t <= self.time and self.sample_time is not None):
            self.advance(t, f, omega)
        self.f, self.omega, self.sample_time = f, omega, t
        self.f_extra, self.omega_extra = f_extra, omega_extra

    def advance(self, t: float, f_end: NDArray[np.float64] | None = None,
                omega_end: NDArray[np.float64] | None = None) -> None:
        if self.time is None:
            self.time = t
            return
        dt = t - self.time
        if dt <= 0:
            return
        if self.f is not None and self.omega is not None and \
                self.orientation.state.initialised:
            if f_end is None or omega_end is None:
                f0, f1, w0, w1 = self.f, self.f, self.omega, self.omega
            else:
                assert self.sample_time is not None
                f0, w0 = self.f, self.omega
                if self.time > self.sample_time:
                    weight = (self.time - self.sample_time) / (t - self.sample_time)
                    f0 = f0 + weight * (f_end - f0)
                    w0 = w0 + weight * (omega_end - w0)
                f1, w1 = f_end, omega_end
            R0 = self.orientation.matrix()
            angle_variance = self.orientation.angle_variance
            self.orientation.propagate(tuple(w0), tuple(w1), dt,  # type: ignore[arg-type]
                                       self.omega_extra * dt * dt)
            R1 = self.orientation.matrix()
            previous_low_pass = self.low_pass
            weight = 1.0 - math.exp(-dt / LOW_PASS_TIME_CONSTANT)
            self.low_pass = f1.copy() if previous_low_pass is None else \
                previous_low_pass + weight * (f1 - previous_low_pass)
            if self.initialised:
                self.propagate(dt, R0, R1, f0, f1, angle_variance, previous_low_pass)
        self.time = t

    def propagate(self, dt: float, R0: NDArray, R1: NDArray, f0: NDArray, f1: NDArray,
                  angle_variance_before: float, previous_low_pass: NDArray | None) -> None:
        params = self.params
        p, v, b = self.x[POSITION], self.x[VELOCITY], self.x[BIAS]
        # mean: linear acceleration between the ends, integrated exactly
        a0 = R0 @ (f0 - b) + self.g
        a1 = R1 @ (f1 - b) + self.g
        x = self.x.copy()
        x[POSITION] = p + v * dt + dt * dt * (a0 / 3.0 + a1 / 6.0)
        x[VELOCITY] = v + dt * (a0 + a1) / 2.0
        # Jacobian of the new state with respect to the old one
        J = np.eye(self.n)
        J[POSITION, VELOCITY] = dt * np.eye(3)
        J[POSITION, BIAS] = -dt * dt * (R0 / 3.0 + R1 / 6.0)
        J[VELOCITY, BIAS] = -dt * (R0 + R1) / 2.0
        # process noise: held white noise, its extras, the bias walk and its extras
        force_squared = 0.5 * (f0 @ f0 + f1 @ f1)
        leak = params.tilt_error_inflation * force_squared * max(
            self.orientation.angle_variance - angle_variance_before, 0.0)
        scale = 0.0
        if params.accelerometer_scale_error > 0 and previous_low_pass is not None:
            assert self.low_pass is not None
            change = self.low_pass - previous_low_pass
            scale = (params.accelerometer_scale_error ** 2 * (change @ change)
                     * SCALE_ERROR_COHERENCE_S / dt)
        white = params.accelerometer_noise_density ** 2 / dt  # per-sample noise variance
        # the change between the samples beyond their noise: linear interpolation's error,
        # |df|^2 / 36 per axis, or / 8 where it is faster than impact_jerk (an impact)
        excess = (f1 - f0) @ (f1 - f0) - 2 * 11.3448667 * white
        impact = dt > 0 and excess > (params.impact_jerk * dt) ** 2
        held = self.f_extra + max(excess, 0.0) / (8.0 if impact else 36.0)
        # the scale error's fast part S (f - f_lp), correlated over the low-pass time constant
        assert self.low_pass is not None
        fast = f1 - self.low_pass
        held += (params.accelerometer_scale_error ** 2 * (fast @ fast)
                 * LOW_PASS_TIME_CONSTANT / dt)
        # stamp errors d_k: the velocity misses a_k (d_(k+1) - d_k); a random walk of steps
        # jitter^2 |a_k - a_(k-1)|^2, held over dt (model.stamp_jitter_variance)
        held += params.timestamp_jitter ** 2 * ((f1 - f0) @ (f1 - f0)) / dt ** 2
        Q = np.zeros((self.n, self.n))
        Q[POSITION, POSITION] = (white * dt ** 4 + held * dt ** 4 / 4) * np.eye(3)
        Q[POSITION, VELOCITY] = Q[VELOCITY, POSITION] = (
            (white * dt ** 3 + held * dt ** 3 / 2) * np.eye(3))
        Q[VELOCITY, VELOCITY] = (white * dt ** 2 + held * dt ** 2) * np.eye(3)
        Q[BIAS, BIAS] = (params.accelerometer_bias_random_walk ** 2 * dt + leak + scale) * np.eye(3)
        self.x = x
        P = J @ self.P @ J.T + Q
        self.P = (P + P.T) / 2

    # ---------------------------------------------------------------- update

    def measurement(self, q_global_imu: tuple[float, float, float, float]
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        H = np.zeros((3, self.n))
        H[:, POSITION] = np.eye(3)
        c = np.zeros(3)
        if self.lever is not None or self.estimate_lever:
            R_global_body = matrix_from_quaternion(q_global_imu) @ self.R_imu_body
            if self.estimate_lever:
                H[:, LEVER] = -R_global_body
            else:
                assert self.lever is not None
                c = -R_global_body @ self.lever
        return H, c

    def arm(self, q_global_imu: tuple[float, float, float, float]) -> NDArray[np.float64]:
        """``R_global_body l`` (3,) m: the lever arm in use in the global frame (zeros
        without one)."""
        if self.estimate_lever:
            lever = self.x[LEVER]
        elif self.lever is not None:
            lever = self.lever
        else:
            return np.zeros(3)
        return matrix_from_quaternion(q_global_imu) @ self.R_imu_body @ lever

    def fix(self, t: float, z: NDArray[np.float64] | None, q: NDArray[np.float64] | None
            ) -> tuple[str, float]:
        params = self.params
        self.advance(t)
        if z is None:
            return "occluded", math.nan
        q_imu = None if q is None else normalise(quaternion_product(
            (float(q[0]), float(q[1]), float(q[2]), float(q[3])), self.q_body_imu))
        if not self.orientation.state.initialised:
            if q_imu is None:
                return "occluded", math.nan
            self.orientation.initialise(q_imu)
        H, c = self.measurement(q_imu if q_imu is not None else
                                self.orientation.state.quaternion)
        if not self.initialised:
            self.x = np.zeros(self.n)
            self.x[POSITION] = z - c
            P = np.diag(np.repeat([params.mocap_position_noise ** 2,
                                   params.initial_velocity_std ** 2,
                                   params.initial_bias_std ** 2], 3))
            if self.estimate_lever:
                R_global_body = -H[:, LEVER]
                s2 = params.lever_arm_std ** 2
                P = np.pad(P, ((0, 3), (0, 3)))
                P[POSITION, POSITION] += s2 * np.eye(3)
                P[POSITION, LEVER] = s2 * R_global_body
                P[LEVER, POSITION] = s2 * R_global_body.T
                P[LEVER, LEVER] = s2 * np.eye(3)
            self.P = P
            self.initialised = True
            self.last_fix = t
            return "initialised", math.nan
        R_z = params.mocap_position_noise ** 2 * np.eye(3)
        y = z - c - H @ self.x
        S = H @ self.P @ H.T + R_z
        nis = float(y @ np.linalg.inv(S) @ y)
        since = t - self.last_fix if self.last_fix is not None else math.inf
        kind = "accepted"
        if since >= params.reacquire_after_s:
            kind = "reacquired"
            if nis > self.gate:
                position = float(y @ y) / 3
                tau = max(since, 1e-3)
                self.P = self.P.copy()
                self.P[POSITION, POSITION] += position * np.eye(3)
                self.P[VELOCITY, VELOCITY] += 4 * position / tau ** 2 * np.eye(3)
                S = H @ self.P @ H.T + R_z
        elif nis > self.gate and float(y @ y) > params.gate_min_innovation ** 2:
            return "gated", nis
        K = self.P @ H.T @ np.linalg.inv(S)
        self.x = self.x + K @ y
        P = self.P - K @ S @ K.T
        self.P = (P + P.T) / 2
        if q_imu is not None:
            self.orientation.correct(q_imu)
        self.last_fix = t
        return kind, nis


def reference_filter(recording: Recording, params: KalmanParameters) -> ReferenceRun:
    """Run the reference over ``recording`` (events in time order, an IMU sample at
    :func:`kfusion.kalman.events.imu_event_time`, IMU first at equal times; the recording's
    clock model applied first, as in the batch driver)."""
    recording = on_mocap_clock(recording)
    filter_ = _Reference(recording, params)
    imu, mocap = recording.imu, recording.mocap
    m, n = len(mocap), filter_.n
    x = np.full((m, n), np.nan)
    P = np.full((m, n, n), np.nan)
    position = np.full((m, 3), np.nan)
    std = np.full((m, 3), np.nan)
    outcome = np.empty(m, dtype=object)
    nis = np.full(m, np.nan)
    visible = mocap.visible
    i = 0
    for row, t in enumerate(mocap.t):
        while i < len(imu) and imu_event_time(imu.t[i], params.imu_latency_s) <= t:
            if np.isfinite(imu.accelerometer[i]).all() and np.isfinite(imu.gyroscope[i]).all():
                filter_.sample(float(imu.t[i]), imu.accelerometer[i].astype(float),
                               imu.gyroscope[i].astype(float))
            i += 1
        if visible[row]:
            outcome[row], nis[row] = filter_.fix(float(t), mocap.position[row].copy(),
                                                 mocap.quaternion[row].copy())
        else:
            outcome[row], nis[row] = filter_.fix(float(t), None, None)
        if filter_.initialised:
            x[row], P[row] = filter_.x, filter_.P
            H, c = filter_.measurement(filter_.orientation.state.quaternion)
            position[row] = H @ filter_.x + c
            # plus the orientation's error dtheta (per-axis variance sigma^2) times the arm
            # a = R_global_body l: the point moves by a x dtheta = [a x] dtheta
            arm = filter_.arm(filter_.orientation.state.quaternion)
            cross = np.array([[0.0, -arm[2], arm[1]], [arm[2], 0.0, -arm[0]],
                              [-arm[1], arm[0], 0.0]])
            covariance = H @ filter_.P @ H.T + filter_.orientation.angle_variance * (
                cross @ cross.T)
            std[row] = np.sqrt(np.diag(covariance))
    return ReferenceRun(x=x, P=P, position=position, std=std, outcome=outcome.astype(str),
                        nis=nis)
