"""Calibration: the paper's offline calibrations and kfusion's self-calibration.

* :mod:`~kfusion.calibration.paper`: the paper's Kabsch mount from still poses and its gain K;
* :mod:`~kfusion.calibration.clock`: the IMU clock's offset (cross-correlation) and drift
  (windows; :func:`kfusion.recording.on_mocap_clock` applies the clock model);
* :mod:`~kfusion.calibration.rates`: mount, clock and gyroscope bias from paired angular rates;
* :mod:`~kfusion.calibration.specific_force`: gravity, lever arm and accelerometer bias;
* :mod:`~kfusion.calibration.mount`: the mount from rates and specific force together;
* :mod:`~kfusion.calibration.noise`: noise densities;
* :mod:`~kfusion.calibration.recording`: all of them on one recording (``kfusion calibrate``);
* :mod:`~kfusion.calibration.diagnosis`: the consistency check (``kfusion check``,
  ``kfusion track``), on the same estimators.
"""

from kfusion.calibration.clock import coarse_clock_offset
from kfusion.calibration.paper import (
    DEFAULT_GRAVITY_TOLERANCE,
    DEFAULT_GYROSCOPE_THRESHOLD,
    DEFAULT_MAX_ROTATION,
    DEFAULT_MIN_ANGULAR_RATE,
    DEFAULT_MIN_POSE_ANGLE,
    DEFAULT_STILL_DURATION,
    GainCalibration,
    ImuToBodyCalibration,
    angles_between,
    angular_rate_pairs,
    calibrate_gain,
    calibrate_imu_to_body,
    gravity_pairs,
    kabsch,
    still_periods,
)
from kfusion.calibration.recording import (
    SelfCalibration,
    calibrate_recording,
    restamped,
    without_calibration,
)

__all__ = [
    "DEFAULT_GRAVITY_TOLERANCE",
    "DEFAULT_GYROSCOPE_THRESHOLD",
    "DEFAULT_MAX_ROTATION",
    "DEFAULT_MIN_ANGULAR_RATE",
    "DEFAULT_MIN_POSE_ANGLE",
    "DEFAULT_STILL_DURATION",
    "GainCalibration",
    "ImuToBodyCalibration",
    "SelfCalibration",
    "angles_between",
    "angular_rate_pairs",
    "calibrate_gain",
    "calibrate_imu_to_body",
    "calibrate_recording",
    "coarse_clock_offset",
    "gravity_pairs",
    "kabsch",
    "restamped",
    "still_periods",
    "without_calibration",
]
