"""IMU white-noise densities and biases: from still stretches, else from local residuals.

Density convention (as the profiles and the simulator): white noise of density ``N``
(unit/sqrt(Hz)) sampled every dt has per-sample std ``sigma = N / sqrt(dt)``, so
``N = sigma sqrt(dt)``.

* Still stretches (gyroscope magnitude below a threshold for at least a second) are used when
  there are any (the gyroscope's mean there is its bias), else the whole recording;
* either way, third differences remove a local quadratic of the (slow) motion,
  ``d3_k = x_k+3 - 3 x_k+2 + 3 x_k+1 - x_k``, and for white noise
  ``var(d3) = 20 sigma^2`` (1 + 9 + 9 + 1). A robust std (1.4826 MAD) keeps the motion's rare
  jerks out.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kfusion.conventions import median_interval
from kfusion.recording import ImuSamples, occlusion_runs

Array = NDArray[np.float64]

STILL_RATE: Final = 0.05
"""rad/s: below this gyroscope magnitude (after removing the median) the IMU counts as still."""
MIN_STILL_S: Final = 1.0
"""s: shortest still stretch used."""


def robust_std(values: ArrayLike) -> float:
    """``1.4826 median(|x - median(x)|)``: the std of Gaussian data, ignoring outliers."""
    x = np.asarray(values, dtype=float)
    return float(1.4826 * np.median(np.abs(x - np.median(x))))


def third_difference_std(values: ArrayLike) -> Array:
    """Per-column white-noise std from third differences: ``robust_std(d3) / sqrt(20)``;
    values (n, c) with n >= 4."""
    x = np.asarray(values, dtype=float)
    d3 = x[3:] - 3 * x[2:-1] + 3 * x[1:-2] - x[:-3]
    return np.array([robust_std(d3[:, column]) for column in range(x.shape[1])]) / np.sqrt(20)


def still_stretches(imu: ImuSamples, *, threshold: float = STILL_RATE,
                    min_duration: float = MIN_STILL_S) -> list[tuple[int, int]]:
    """Index ranges ``[start, stop)`` where ``|gyro - median(gyro)|`` stays below
    ``threshold`` for at least ``min_duration`` s."""
    centred = imu.gyroscope - np.median(imu.gyroscope, axis=0)
    still = np.linalg.norm(centred, axis=1) < threshold
    return [(start, stop) for start, stop in occlusion_runs(~still)
            if imu.t[stop - 1] - imu.t[start] >= min_duration]


@dataclass(frozen=True)
class NoiseEstimate:
    """Result of :func:`estimate_noise`.

    Attributes:
        accelerometer_noise_density: m/s^2/sqrt(Hz) (largest axis).
        gyroscope_noise_density: rad/s/sqrt(Hz) (largest axis).
        per_axis_accelerometer, per_axis_gyroscope: (3,) the same per axis.
        gyroscope_bias: (3,) rad/s, mean over the still stretches (NaN without any).
        source: ``"still"`` (seconds of still data) or ``"residual"``.
        still_seconds: total still time used, s.
    """

    accelerometer_noise_density: float
    gyroscope_noise_density: float
    per_axis_accelerometer: Array
    per_axis_gyroscope: Array
    gyroscope_bias: Array
    source: str
    still_seconds: float


def estimate_noise(imu: ImuSamples) -> NoiseEstimate:
    """Noise densities (module docstring): from still stretches when there are any, else from
    third differences of the whole recording."""
    dt = median_interval(imu.t)
    spans = still_stretches(imu)
    if spans:
        # third differences inside each stretch: the slow sway of a limb held "still" is
        # removed too
        sigma = np.sqrt(np.average(
            [third_difference_std(np.hstack([imu.accelerometer[a:b], imu.gyroscope[a:b]]))**2
             for a, b in spans], axis=0, weights=[b - a for a, b in spans]))
        bias = np.mean(np.vstack([imu.gyroscope[a:b] for a, b in spans]), axis=0)
        source, seconds = "still", float(sum(imu.t[b - 1] - imu.t[a] for a, b in spans))
    else:
        sigma = third_difference_std(np.hstack([imu.accelerometer, imu.gyroscope]))
        bias, source, seconds = np.full(3, np.nan), "residual", 0.0
    density = sigma * np.sqrt(dt)
    return NoiseEstimate(accelerometer_noise_density=float(np.max(density[:3])),
                         gyroscope_noise_density=float(np.max(density[3:])),
                         per_axis_accelerometer=density[:3], per_axis_gyroscope=density[3:],
                         gyroscope_bias=bias, source=source, still_seconds=seconds)
