"""Gap error before and after a calibration (benchmark and notebook 04).

Not imported by :mod:`kfusion.calibration` itself: it runs the trackers, which use the
calibration's clock model.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import NDArray

from kfusion.calibration.recording import SelfCalibration
from kfusion.evaluate import GappedRecording, cut_gaps, gap_errors, metrics_from_errors
from kfusion.methods import track_with_method
from kfusion.recording import Recording


def with_calibration(recording: Recording, calibration: SelfCalibration) -> Recording:
    """The recording with the calibrated ``recording.yaml`` content (its IMU profile name
    kept: the calibration measures noise, not the profile)."""
    info = dataclasses.replace(calibration.info, imu=recording.info.imu)
    return dataclasses.replace(recording, info=info)


def gap_rms_and_lost(recording: Recording, truth_position: NDArray[np.float64],
                     gap_mask: NDArray[np.bool_], method: str = "kalman"
                     ) -> tuple[float, float]:
    """(RMS gap error over the bridged gap samples, mm; gap samples called lost, %). A lost
    sample is not scored in the RMS, so both are needed."""
    metrics = metrics_from_errors(gap_errors(track_with_method(recording, method),
                                             truth_position, gap_mask))
    return float(metrics["rms_mm"]), 100.0 * float(metrics["lost_fraction"])


def seeded_gaps(recording: Recording, seed: int = 0) -> GappedRecording:
    """:func:`kfusion.evaluate.cut_gaps` (0.1-0.3 s) with ``default_rng(seed)``."""
    return cut_gaps(recording, rng=np.random.default_rng(seed))
