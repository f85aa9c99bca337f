"""Registry of estimation methods: name -> function ``(recording, **options) -> TrackResult``.

Every method returns a :class:`kfusion.track_file.TrackResult` with one row per mocap row. The
``kfusion track``, ``run``, ``sweep`` and ``demo`` commands and the benchmarks all go through
:func:`track_with_method`, so a method added here shows up everywhere.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any

from kfusion.recording import Recording
from kfusion.track_file import TrackResult

METHODS: dict[str, str] = {
    "baseline": "kfusion.baseline:track_recording",
    "kalman": "kfusion.kalman:filter_recording",
    "smoother": "kfusion.kalman:smooth_recording",
}
"""Method name -> ``module:function``, imported on first use."""


def method_function(name: str) -> Callable[..., TrackResult]:
    """The tracking function of method ``name``; ValueError listing the known names otherwise."""
    if name not in METHODS:
        raise ValueError(f"unknown method {name!r}; expected one of {sorted(METHODS)}")
    module_name, function_name = METHODS[name].split(":")
    return getattr(importlib.import_module(module_name), function_name)


def track_with_method(recording: Recording, method: str, **options: Any) -> TrackResult:
    """Run method ``method`` over ``recording``; ``options`` go to the method's parameters.

    Each method applies the IMU clock model of ``recording.info`` (``imu_time_offset``,
    ``imu_clock_drift_ppm``) itself, in its batch driver (:func:`kfusion.recording.on_mocap_clock`).
    """
    return method_function(method)(recording, **options)
