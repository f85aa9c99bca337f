"""The IMU's error model: what a real accelerometer and gyroscope make of the true motion.

For each triad (accelerometer, then gyroscope), drawn once per run from the profile
(:class:`kfusion.profiles.ImuProfile`):

* scale-factor and cross-axis matrix ``M = I + diag(s) + C``, ``s_i ~ N(0, scale_error^2)``,
  off-diagonal ``C_ij ~ N(0, cross_axis^2)``;
* turn-on bias ``b_0 ~ N(0, turn_on_bias^2)`` per axis;

and per sample, with ``dt`` the sample interval:

* bias random walk ``b_{k+1} = b_k + bias_random_walk sqrt(dt) N(0, 1)``;
* white noise of std ``sigma_d = noise_density / sqrt(dt)`` (Kalibr's discrete-time convention);
* measured ``y_k = quantise(clip(M x_k + b_k + n_k, -range, +range))``, where ``quantise``
  rounds to a multiple of the resolution; a resolution of 0 means no quantisation.

The same standard-normal draws are taken whatever the profile's numbers, so a run with an
error-free profile sees the same trajectory and the same random stream as one with errors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kfusion.profiles import ImuProfile

Array = NDArray[np.float64]


def error_matrix(scale_normals: Array, cross_normals: Array, scale_error: float,
                 cross_axis: float) -> Array:
    """``M = I + diag(scale_error s) + cross_axis C``, with s (3,) and the six off-diagonal
    entries of C (row by row) from ``cross_normals`` (6,) standard normals; (3, 3)."""
    matrix = np.eye(3) + np.diag(scale_error * np.asarray(scale_normals, dtype=float))
    rows, cols = np.nonzero(~np.eye(3, dtype=bool))
    matrix[rows, cols] += cross_axis * np.asarray(cross_normals, dtype=float)
    return matrix


def bias_walk(turn_on_bias: Array, random_walk: float, dt: float, step_normals: Array) -> Array:
    """Bias at each sample, (n, 3): ``b_0 = turn_on_bias``, ``b_{k+1} = b_k + rw sqrt(dt) w_k``
    with ``w_k`` the rows of ``step_normals`` (n - 1, 3)."""
    steps = random_walk * np.sqrt(dt) * np.asarray(step_normals, dtype=float)
    return np.asarray(turn_on_bias, dtype=float) + np.vstack([np.zeros((1, 3)),
                                                              np.cumsum(steps, axis=0)])


def white_noise_std(noise_density: float, dt: float) -> float:
    """Per-sample std of white noise of density ``noise_density`` (unit/sqrt(Hz)) sampled every
    ``dt`` s: ``sigma_d = noise_density / sqrt(dt)``."""
    return noise_density / np.sqrt(dt)


def quantise(values: Array, resolution: float) -> Array:
    """Round to the nearest multiple of ``resolution``; unchanged when ``resolution`` is 0."""
    if resolution <= 0:
        return np.asarray(values, dtype=float)
    return resolution * np.round(np.asarray(values, dtype=float) / resolution)


def measure(true_values: Array, matrix: Array, bias: Array, noise: Array, limit: float,
            resolution: float) -> Array:
    """``quantise(clip(M x + b + n, -limit, limit))`` for rows x of ``true_values`` (n, 3)."""
    raw = np.asarray(true_values, dtype=float) @ matrix.T + bias + noise
    return quantise(np.clip(raw, -limit, limit), resolution)


@dataclass(frozen=True)
class TriadErrors:
    """Errors drawn for one sensor triad over a run.

    Attributes:
        matrix: (3, 3) scale and cross-axis matrix M.
        bias: (n, 3) bias at each sample, sensor units.
        noise: (n, 3) white noise at each sample, sensor units.
    """

    matrix: Array
    bias: Array
    noise: Array


def draw_triad_errors(rng: np.random.Generator, n: int, dt: float, *, noise_density: float,
                      bias_random_walk: float, turn_on_bias: float, scale_error: float,
                      cross_axis: float) -> TriadErrors:
    """Draw one triad's errors for ``n`` samples ``dt`` s apart (always the same draws:
    3 scale, 6 cross-axis, 3 turn-on, (n - 1) x 3 walk steps, n x 3 noise)."""
    scale_normals = rng.standard_normal(3)
    cross_normals = rng.standard_normal(6)
    turn_on = turn_on_bias * rng.standard_normal(3)
    walk_normals = rng.standard_normal((max(n - 1, 0), 3))
    noise = white_noise_std(noise_density, dt) * rng.standard_normal((n, 3))
    return TriadErrors(
        matrix=error_matrix(scale_normals, cross_normals, scale_error, cross_axis),
        bias=bias_walk(turn_on, bias_random_walk, dt, walk_normals)[:n],
        noise=noise,
    )


@dataclass(frozen=True)
class ImuMeasurement:
    """Simulated IMU output and the errors that made it.

    Attributes:
        accelerometer: (n, 3) measured specific force, m/s^2, IMU frame.
        gyroscope: (n, 3) measured angular rate, rad/s, IMU frame.
        accelerometer_errors, gyroscope_errors: the drawn errors.
    """

    accelerometer: Array
    gyroscope: Array
    accelerometer_errors: TriadErrors
    gyroscope_errors: TriadErrors


def simulate_imu(rng: np.random.Generator, profile: ImuProfile, dt: float,
                 specific_force: Array, angular_rate: Array) -> ImuMeasurement:
    """Measure true specific force (n, 3) m/s^2 and angular rate (n, 3) rad/s (IMU frame),
    sampled every ``dt`` s, with the errors of ``profile``."""
    n = int(np.asarray(specific_force).shape[0])
    accelerometer = draw_triad_errors(
        rng, n, dt, noise_density=profile.accelerometer_noise_density,
        bias_random_walk=profile.accelerometer_bias_random_walk,
        turn_on_bias=profile.accelerometer_turn_on_bias,
        scale_error=profile.accelerometer_scale_error,
        cross_axis=profile.accelerometer_cross_axis)
    gyroscope = draw_triad_errors(
        rng, n, dt, noise_density=profile.gyroscope_noise_density,
        bias_random_walk=profile.gyroscope_bias_random_walk,
        turn_on_bias=profile.gyroscope_turn_on_bias,
        scale_error=profile.gyroscope_scale_error,
        cross_axis=profile.gyroscope_cross_axis)
    return ImuMeasurement(
        accelerometer=measure(specific_force, accelerometer.matrix, accelerometer.bias,
                              accelerometer.noise, profile.accelerometer_range,
                              profile.accelerometer_resolution),
        gyroscope=measure(angular_rate, gyroscope.matrix, gyroscope.bias, gyroscope.noise,
                          profile.gyroscope_range, profile.gyroscope_resolution),
        accelerometer_errors=accelerometer,
        gyroscope_errors=gyroscope,
    )


# ---------------------------------------------------------------------------------------------
# Error sources the filter's model does not have (off by default)
# ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class UnmodelledErrors:
    """IMU errors outside :class:`~kfusion.profiles.ImuProfile` and outside the Kalman model, to
    test whether the bound still holds (issue 9). All zero by default: a simulation without them
    is unchanged, draw for draw. :data:`TYPICAL_UNMODELLED` holds datasheet-like magnitudes.

    Attributes:
        axis_misalignment: rad, 1-sigma per axis of the rotation between the accelerometer and
            gyroscope triads (the accelerometer measures ``R(delta) f``, the gyroscope the
            IMU-frame rate). Consumer MEMS parts state about +-1 deg between sensor axes (the
            MPU-9250's +-2 % cross-axis sensitivity is 1.1 deg); +-1 deg as 3 sigma: 0.33 deg.
        gyroscope_g_sensitivity: (rad/s)/(m/s^2), 1-sigma of each entry of G in
            ``omega_measured += G f``. MPU-6500/MPU-9250 product specification: linear
            acceleration sensitivity 0.1 deg/s/g (typical).
        temperature_rise: K, warm-up of the sensor after power-on, ``T(t) = rise (1 - exp(-t /
            tau))``. A sensor strapped to a forearm warms by several kelvin; 10 K.
        temperature_time_constant: s, tau. 120 s.
        accelerometer_temperature_coefficient: m/s^2/K, 1-sigma per axis of the bias change with
            temperature (added to the true specific force before the triad's scale matrix).
            MPU-9250: zero-g level change +-1.5 mg/K (x, y); as 3 sigma: 0.5 mg/K.
        gyroscope_temperature_coefficient: rad/s/K, the same for the gyroscope. MPU-9250: zero-rate
            output variation +-30 deg/s over -40..85 deg C, +-0.24 deg/s/K; as 3 sigma: 0.08.
        timestamp_jitter: s, 1-sigma of the error of each IMU timestamp (host-side stamping over
            USB or a serial link: 0.5 ms), clipped to 0.4 sample intervals so stamps stay in
            order. The samples are taken at the true instants; only their stamps move.
    """

    axis_misalignment: float = 0.0
    gyroscope_g_sensitivity: float = 0.0
    temperature_rise: float = 0.0
    temperature_time_constant: float = 120.0
    accelerometer_temperature_coefficient: float = 0.0
    gyroscope_temperature_coefficient: float = 0.0
    timestamp_jitter: float = 0.0

    def __post_init__(self) -> None:
        for name in ("axis_misalignment", "gyroscope_g_sensitivity", "temperature_rise",
                     "temperature_time_constant", "accelerometer_temperature_coefficient",
                     "gyroscope_temperature_coefficient", "timestamp_jitter"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and np.isfinite(value) and value >= 0):
                raise ValueError(f"UnmodelledErrors.{name}: expected a finite number >= 0, "
                                 f"got {value!r}")
        if self.temperature_time_constant <= 0:
            raise ValueError(f"UnmodelledErrors.temperature_time_constant: expected > 0 s, got "
                             f"{self.temperature_time_constant!r}")

    @property
    def active(self) -> bool:
        """True when any error source is switched on."""
        return any((self.axis_misalignment, self.gyroscope_g_sensitivity,
                    self.temperature_rise * (self.accelerometer_temperature_coefficient
                                             + self.gyroscope_temperature_coefficient),
                    self.timestamp_jitter))


_DEGREE = np.pi / 180.0
TYPICAL_UNMODELLED = UnmodelledErrors(
    axis_misalignment=(1.0 / 3.0) * _DEGREE,
    gyroscope_g_sensitivity=0.1 * _DEGREE / 9.80665,
    temperature_rise=10.0,
    temperature_time_constant=120.0,
    accelerometer_temperature_coefficient=0.5e-3 * 9.80665,
    gyroscope_temperature_coefficient=0.08 * _DEGREE,
    timestamp_jitter=0.5e-3,
)
"""Datasheet-like magnitudes of every unmodelled error source (see :class:`UnmodelledErrors`)."""


def small_rotation_matrix(rotation_vector: Array) -> Array:
    """Rotation matrix of a rotation vector delta (3,) rad (Rodrigues):
    ``R = I + sin(a) K + (1 - cos(a)) K^2`` with a = |delta| and K the cross matrix of delta/a."""
    delta = np.asarray(rotation_vector, dtype=float)
    angle = float(np.linalg.norm(delta))
    if angle == 0.0:
        return np.eye(3)
    k = delta / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def temperature_bias(t: Array, coefficient: Array, rise: float, time_constant: float) -> Array:
    """Bias from warming, (n, 3): ``c (rise (1 - exp(-t / tau)))`` for times t (n,) s and
    per-axis coefficients c (3,) (unit/K)."""
    temperature = rise * (1.0 - np.exp(-np.asarray(t, dtype=float) / time_constant))
    return temperature[:, None] * np.asarray(coefficient, dtype=float)[None, :]


def apply_unmodelled(rng: np.random.Generator, errors: UnmodelledErrors, t: Array,
                     specific_force: Array, angular_rate: Array) -> tuple[Array, Array]:
    """What the triads sense, before their profile errors, with the unmodelled errors: the
    accelerometer ``R(delta) f + b_T,a(t)``, the gyroscope ``omega + G f + b_T,g(t)``. Inputs
    (n, 3) in the IMU frame, times (n,) s; always the same draws (3 + 9 + 3 + 3 normals)."""
    misalignment = errors.axis_misalignment * rng.standard_normal(3)
    sensitivity = errors.gyroscope_g_sensitivity * rng.standard_normal((3, 3))
    accelerometer_coefficient = errors.accelerometer_temperature_coefficient \
        * rng.standard_normal(3)
    gyroscope_coefficient = errors.gyroscope_temperature_coefficient * rng.standard_normal(3)
    force = np.asarray(specific_force, dtype=float)
    rate = np.asarray(angular_rate, dtype=float)
    sensed_force = force @ small_rotation_matrix(misalignment).T + temperature_bias(
        t, accelerometer_coefficient, errors.temperature_rise, errors.temperature_time_constant)
    sensed_rate = rate + force @ sensitivity.T + temperature_bias(
        t, gyroscope_coefficient, errors.temperature_rise, errors.temperature_time_constant)
    return sensed_force, sensed_rate


def jittered_stamps(rng: np.random.Generator, t: Array, jitter: float) -> Array:
    """Timestamps ``t + clip(N(0, jitter^2), -0.4 dt, 0.4 dt)`` for sample instants t (n,) s with
    dt their smallest spacing: still strictly increasing."""
    t = np.asarray(t, dtype=float)
    if len(t) < 2:
        return t.copy()
    limit = 0.4 * float(np.min(np.diff(t)))
    return t + np.clip(jitter * rng.standard_normal(len(t)), -limit, limit)
