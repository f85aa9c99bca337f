"""Kalman reformulation: a linear filter on filterpy, fed by the IMU, corrected by the mocap.

State ``[p, v, b]`` (9): IMU position and velocity (global frame), accelerometer bias (IMU
frame); plus the lever arm ``l`` (12 states) when the recording does not give one.

Public API::

    KalmanParameters          frozen noise model, from profiles or a mapping
    KalmanFusion              streaming filter: predict(t, f, omega), update(t, p, q), estimate(t)
    FilterEstimate, UpdateOutcome  its outputs
    filter_recording          method "kalman": the filter over a recording -> TrackResult
    smooth_recording          method "smoother": fixed-interval RTS over the same model
    run_filter, run_smoother  the same, keeping per-row states and outcomes

Modules: :mod:`~kfusion.kalman.model` (F, B, Q, H as pure functions),
:mod:`~kfusion.kalman.orientation` (gyroscope integration with a learned bias),
:mod:`~kfusion.kalman.filter` (the streaming class), :mod:`~kfusion.kalman.batch` (recording
runs), :mod:`~kfusion.kalman.smoother` (RTS with the control input),
:mod:`~kfusion.kalman.reference` (the same equations in plain numpy, for cross-checks),
:mod:`~kfusion.kalman.events` (the event-merge policy the batch driver and the Tracker share).
"""

from kfusion.kalman.batch import FilterRun, filter_recording, run_filter
from kfusion.kalman.filter import (
    ACCEPTED,
    GATED,
    INITIALISED,
    OCCLUDED,
    REACQUIRED,
    FilterEstimate,
    KalmanFusion,
    KalmanSnapshot,
    UpdateOutcome,
)
from kfusion.kalman.parameters import KalmanParameters
from kfusion.kalman.smoother import SmootherRun, run_smoother, smooth_recording

__all__ = [
    "ACCEPTED", "GATED", "INITIALISED", "OCCLUDED", "REACQUIRED",
    "FilterEstimate", "FilterRun", "KalmanFusion", "KalmanParameters", "KalmanSnapshot",
    "SmootherRun", "UpdateOutcome", "filter_recording", "run_filter", "run_smoother",
    "smooth_recording",
]
