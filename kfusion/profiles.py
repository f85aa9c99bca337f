"""Sensor profiles: datasheet figures for IMUs and a motion-capture system, in SI units.

One frozen object per sensor. The simulator draws errors from them and the Kalman filter takes its
noise model from them, so both read the same numbers. Bias random-walk densities are not on the
datasheets; the figure used and its reasoning is next to each.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from kfusion.conventions import STANDARD_GRAVITY
from kfusion.guards import short_repr

MILLI_G = 1e-3 * STANDARD_GRAVITY
MICRO_G = 1e-6 * STANDARD_GRAVITY
DEGREE = np.pi / 180.0


@dataclass(frozen=True)
class ImuProfile:
    """Error model of a 6-axis IMU (accelerometer + gyroscope).

    Attributes (all SI):
        name: profile name as used in recording.yaml's ``imu`` key.
        accelerometer_noise_density: white-noise density, m/s^2/sqrt(Hz).
        accelerometer_bias_random_walk: bias random-walk density, m/s^3/sqrt(Hz)
            (bias std grows as this * sqrt(t)).
        accelerometer_turn_on_bias: 1-sigma bias at power-on, per axis, m/s^2.
        accelerometer_scale_error: 1-sigma scale-factor error, fraction.
        accelerometer_cross_axis: 1-sigma cross-axis sensitivity, fraction.
        accelerometer_range: full-scale range, m/s^2 (saturates at +-range).
        accelerometer_resolution: one LSB, m/s^2.
        gyroscope_*: the same for the gyroscope in rad/s (noise density rad/s/sqrt(Hz),
            random walk rad/s^2/sqrt(Hz)).
    """

    name: str
    accelerometer_noise_density: float
    accelerometer_bias_random_walk: float
    accelerometer_turn_on_bias: float
    accelerometer_scale_error: float
    accelerometer_cross_axis: float
    accelerometer_range: float
    accelerometer_resolution: float
    gyroscope_noise_density: float
    gyroscope_bias_random_walk: float
    gyroscope_turn_on_bias: float
    gyroscope_scale_error: float
    gyroscope_cross_axis: float
    gyroscope_range: float
    gyroscope_resolution: float


@dataclass(frozen=True)
class MocapProfile:
    """Error model of an optical motion-capture system.

    Attributes:
        name: profile name.
        position_noise: 1-sigma white noise per axis on the rigid-body position, m.
        orientation_noise: 1-sigma white noise per axis on the rigid-body orientation, rad.
        rate: frame rate, Hz.
    """

    name: str
    position_noise: float
    orientation_noise: float
    rate: float


# InvenSense MPU-9250 product specification rev 1.1 (the MPU9255 is the same die):
# accelerometer noise 300 ug/sqrt(Hz), zero-g tolerance +-60 mg (x, y) / +-80 mg (z),
# sensitivity tolerance +-3 %, cross-axis +-2 %, 16-bit ADC; gyroscope noise 0.01 dps/sqrt(Hz),
# zero-rate offset +-5 dps, sensitivity +-3 %, cross-axis +-2 %. The +-limits are treated as
# 3-sigma bounds (turn-on bias 1-sigma = 60 mg / 3 = 20 mg). Full scale: +-8 g and +-1000 dps, a
# setting that keeps a fast forearm (peaks ~3 g, ~600 dps) inside the range.
# Bias random walk is not specified; the zero-g drift of 1.5 mg/K over a few kelvin of warm-up in
# minutes is modelled as a walk reaching ~1 mg in 60 s: 1 mg / sqrt(60 s) ~ 0.13 mg/sqrt(s).
MPU9255 = ImuProfile(
    name="mpu9255",
    accelerometer_noise_density=300 * MICRO_G,
    accelerometer_bias_random_walk=0.13 * MILLI_G,
    accelerometer_turn_on_bias=20 * MILLI_G,
    accelerometer_scale_error=0.01,
    accelerometer_cross_axis=0.0067,
    accelerometer_range=8 * STANDARD_GRAVITY,
    accelerometer_resolution=16 * STANDARD_GRAVITY / 2**16,
    gyroscope_noise_density=0.01 * DEGREE,
    gyroscope_bias_random_walk=0.002 * DEGREE,
    gyroscope_turn_on_bias=5 / 3 * DEGREE,
    gyroscope_scale_error=0.01,
    gyroscope_cross_axis=0.0067,
    gyroscope_range=1000 * DEGREE,
    gyroscope_resolution=2000 * DEGREE / 2**16,
)

# CH Robotics UM7 datasheet: factory-calibrated board (temperature-compensated biases, scale and
# misalignment), so its residual errors are several times smaller than the raw MPU9255's.
# Accelerometer +-8 g, 16-bit; gyroscope +-2000 dps, 16-bit. Noise densities as printed for
# its sensors: 400 ug/sqrt(Hz) accelerometer, 0.005 dps/sqrt(Hz) gyroscope.
UM7 = ImuProfile(
    name="um7",
    accelerometer_noise_density=400 * MICRO_G,
    accelerometer_bias_random_walk=0.05 * MILLI_G,
    accelerometer_turn_on_bias=5 * MILLI_G,
    accelerometer_scale_error=0.003,
    accelerometer_cross_axis=0.002,
    accelerometer_range=8 * STANDARD_GRAVITY,
    accelerometer_resolution=16 * STANDARD_GRAVITY / 2**16,
    gyroscope_noise_density=0.005 * DEGREE,
    gyroscope_bias_random_walk=0.001 * DEGREE,
    gyroscope_turn_on_bias=0.2 * DEGREE,
    gyroscope_scale_error=0.003,
    gyroscope_cross_axis=0.002,
    gyroscope_range=2000 * DEGREE,
    gyroscope_resolution=4000 * DEGREE / 2**16,
)

# Real BROAD recordings (myon aktos-t), used for the Kalman defaults on real data. The sensor's
# datasheet is not public; noise densities measured on the still parts of the seven trials here
# (longest run with movement == 0, 35-44 s each): median of the Welch PSD between 5 and 100 Hz,
# density = sqrt(PSD_one_sided / 2), which matches std / sqrt(rate). Per axis the accelerometer
# gave 245-263 / 267-303 / 398-442 ug/sqrt(Hz) (x / y / z) and the gyroscope 0.0049-0.0077
# dps/sqrt(Hz); the largest axis, rounded up, is taken for all three.
BROAD_IMU = ImuProfile(
    name="broad",
    accelerometer_noise_density=450 * MICRO_G,
    accelerometer_bias_random_walk=0.13 * MILLI_G,
    accelerometer_turn_on_bias=20 * MILLI_G,
    accelerometer_scale_error=0.01,
    accelerometer_cross_axis=0.0067,
    accelerometer_range=16 * STANDARD_GRAVITY,
    accelerometer_resolution=32 * STANDARD_GRAVITY / 2**16,
    gyroscope_noise_density=0.008 * DEGREE,
    gyroscope_bias_random_walk=0.002 * DEGREE,
    gyroscope_turn_on_bias=1 * DEGREE,
    gyroscope_scale_error=0.01,
    gyroscope_cross_axis=0.0067,
    gyroscope_range=2000 * DEGREE,
    gyroscope_resolution=4000 * DEGREE / 2**16,
)

# OptiTrack with Flex 3 / Flex 13 cameras on a ~3 m volume: sub-millimetre rigid-body jitter.
OPTITRACK = MocapProfile(name="optitrack", position_noise=0.3e-3, orientation_noise=0.2 * DEGREE,
                         rate=100.0)

IMU_PROFILES: dict[str, ImuProfile] = {p.name: p for p in (MPU9255, UM7, BROAD_IMU)}
MOCAP_PROFILES: dict[str, MocapProfile] = {OPTITRACK.name: OPTITRACK}


def imu_profile(name: str) -> ImuProfile:
    """The IMU profile called ``name``; ValueError listing the known names otherwise."""
    if isinstance(name, str) and name.lower() in IMU_PROFILES:
        return IMU_PROFILES[name.lower()]
    raise ValueError(f"unknown IMU profile {short_repr(name)}; expected one of "
                     f"{sorted(IMU_PROFILES)}")


def mocap_profile(name: str) -> MocapProfile:
    """The mocap profile called ``name``; ValueError listing the known names otherwise."""
    if isinstance(name, str) and name.lower() in MOCAP_PROFILES:
        return MOCAP_PROFILES[name.lower()]
    raise ValueError(f"unknown mocap profile {short_repr(name)}; expected one of "
                     f"{sorted(MOCAP_PROFILES)}")
