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
