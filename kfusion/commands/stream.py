"""``kfusion stream DIR``: feed a recording to :class:`kfusion.tracker.Tracker` sample by sample.

It shows what safety software calling kfusion in-process would see: the samples go in the fusion
order of :mod:`kfusion.kalman.events` (the batch driver's) and after every N-th mocap frame one
line is printed::

    t=12.340 s  status=bridged  pos=(0.1234, 1.2345, 0.4567) m  bound99=4.2 mm  since_fix=0.120 s

A lost estimate prints ``pos=unknown  bound99=unknown``: never a number.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray

from kfusion.commands.track import measurement_mode
from kfusion.conventions import LOST, imu_time_to_mocap
from kfusion.guards import finite_float
from kfusion.kalman.events import IMU_STREAM, merge_events
from kfusion.recording import Recording, read_recording
from kfusion.tracker import METHODS, Estimate, Tracker

NAME = "stream"
HELP = "Stream a recording through the online Tracker and print statuses and bounds."
ORDER = 45


def stream_recording(recording: Recording, tracker: Tracker | None = None, *,
                     measurement: str = "body") -> Iterator[tuple[int, Estimate]]:
    """Feed ``recording`` to ``tracker`` in the fusion order of :mod:`kfusion.kalman.events`
    (an IMU sample at its stamp on the mocap clock minus the latency, the IMU sample first at
    equal times); yield ``(mocap row, estimate)`` right after each mocap row.

    ``tracker`` None builds one from the recording's metadata (Kalman, default parameters).
    ``measurement``: ``body`` pushes ``mocap.csv``'s rigid body (:meth:`Tracker.push_mocap`),
    ``markers`` the row's markers from ``markers.csv`` (:meth:`Tracker.push_markers`; a
    tracker with the recording's ``markers``, as ``kfusion track --measurement markers``).
    """
    if tracker is None:
        tracker = Tracker.from_recording_info(recording.info)
    imu, mocap = recording.imu, recording.mocap
    frames = marker_frames(recording) if measurement == "markers" else None
    imu_t = imu.t.tolist()
    accelerometer, gyroscope = imu.accelerometer, imu.gyroscope
    mapped = imu_time_to_mocap(imu.t, *tracker.imu_clock).tolist()
    for t, stream, index in merge_events(mapped, mocap.t.tolist(), tracker.imu_latency_s):
        if stream == IMU_STREAM:
            tracker.push_imu(imu_t[index], accelerometer[index], gyroscope[index])
            continue
        if frames is not None:
            tracker.push_markers(t, frames[index])
        else:
            visible = bool(mocap.visible[index])
            tracker.push_mocap(t, mocap.position[index] if visible else None,
                               mocap.quaternion[index] if visible else None)
        yield index, tracker.estimate(t)  # "now" is the frame's time on the recording's clock


def marker_frames(recording: Recording) -> list[dict[str, NDArray[np.float64] | None]]:
    """Per mocap row, ``{NAME: (3,) m or None}`` of ``markers.csv`` (None where hidden), as
    :meth:`Tracker.push_markers` takes it. ValueError (naming the files) without
    ``markers.csv`` and ``recording.yaml``'s ``markers``, or with marker rows at other times
    than ``mocap.csv``'s (:func:`kfusion.kalman.batch.marker_inputs`)."""
    from kfusion.kalman.batch import marker_inputs  # on use: filterpy

    observed, _ = marker_inputs(recording)
    assert recording.markers is not None  # marker_inputs checked it
    names = recording.markers.names
    return [{name: (point if np.isfinite(point).all() else None)
             for name, point in zip(names, row, strict=True)} for row in observed]


def format_estimate(estimate: Estimate, confidence: float = 0.99) -> str:
    """One line: time, status, position (m), bound at ``confidence`` (mm), time since fix (s)."""
    label = f"bound{_percent(confidence)}"
    if estimate.status == LOST:
        where = f"pos=unknown  {label}=unknown"
    else:
        x, y, z = (float(v) for v in estimate.position)
        bound = estimate.bound(confidence)
        size = f"{1000 * bound:.1f} mm" if math.isfinite(bound) else "unknown"
        where = f"pos=({x:.4f}, {y:.4f}, {z:.4f}) m  {label}={size}"
    since = estimate.time_since_fix
    since_text = f"{since:.3f} s" if math.isfinite(since) else "never"
    return f"t={estimate.t:.3f} s  status={estimate.status:<7}  {where}  since_fix={since_text}"


def stream_lines(recording: Recording, *, count: int | None = None, every: int = 10,
                 confidence: float = 0.99, method: str = "kalman",
                 start: float | None = None, measurement: str = "body") -> list[str]:
    """Lines of :func:`format_estimate` after every ``every``-th mocap row (at most ``count``).

    Args:
        recording: the recording to stream.
        count: stop after this many lines (None: the whole recording).
        every: print after every N-th mocap row, N >= 1.
        confidence: the bound's probability, in (0, 1).
        method: ``kalman`` or ``baseline``.
        start: s; print only rows at or after this time (earlier rows are still streamed).
        measurement: ``body`` or ``markers`` (:func:`stream_recording`).
    """
    if isinstance(every, bool) or not isinstance(every, int) or every < 1:
        raise ValueError(f"every: expected a positive integer, got {every!r}")
    if count is not None and (isinstance(count, bool) or not isinstance(count, int) or count < 1):
        raise ValueError(f"count: expected a positive integer or None, got {count!r}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: expected a probability in (0, 1), got {confidence!r}")
    tracker = Tracker.from_recording_info(recording.info, method=method)
    lines: list[str] = []
    printed = 0
    for _, estimate in stream_recording(recording, tracker, measurement=measurement):
        if start is not None and estimate.t < start:
            continue
        if printed % every == 0:
            lines.append(format_estimate(estimate, confidence))
            if count is not None and len(lines) >= count:
                break
        printed += 1
    return lines


def _percent(confidence: float) -> str:
    text = f"{100 * confidence:.10g}"
    return text.replace(".", "_")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folder", metavar="DIR", help="recording folder")
    parser.add_argument("--every", type=int, default=10, metavar="N",
                        help="print a line after every N-th mocap frame (default: 10)")
    parser.add_argument("--confidence", type=finite_float, default=0.99,
                        help="probability of the printed bound (default: 0.99)")
    parser.add_argument("--method", choices=METHODS, default="kalman",
                        help="estimator (default: kalman)")
    parser.add_argument("--count", type=int, default=None, metavar="K",
                        help="stop after K lines (default: the whole recording)")
    parser.add_argument("--start", type=finite_float, default=None, metavar="S",
                        help="print only from this time on, s (earlier samples are still "
                        "streamed, so the tracker has its history)")
    parser.add_argument("--health", action="store_true",
                        help="print the tracker's health counters at the end")
    parser.add_argument("--zeros-occluded", action="store_true",
                        help="read a mocap position of exactly (0, 0, 0) as occluded")
    parser.add_argument("--measurement", choices=("markers", "body"), default=None,
                        help="fuse each visible marker of markers.csv (markers) or mocap.csv's "
                        "rigid body (body); default: markers when the folder has markers.csv "
                        "and recording.yaml's markers and the method is kalman, as kfusion "
                        "track")


def run(args: argparse.Namespace) -> int:
    recording = read_recording(args.folder, zero_position_means_occluded=args.zeros_occluded)
    if args.every < 1:
        raise ValueError(f"--every: expected a positive integer, got {args.every}")
    if not 0.0 < args.confidence < 1.0:
        raise ValueError(f"--confidence: expected a probability in (0, 1), got "
                         f"{args.confidence}")
    if args.count is not None and args.count < 1:
        raise ValueError(f"--count: expected a positive integer, got {args.count}")
    last = float(recording.mocap.t[-1])
    if args.start is not None and args.start > last:
        raise ValueError(f"--start: expected a time up to the last mocap frame's, "
                         f"{last:.3f} s, got {args.start:g}")
    measurement = measurement_mode(recording, args.method, args.measurement)
    tracker = Tracker.from_recording_info(recording.info, method=args.method)
    printed = shown = 0
    for _, estimate in stream_recording(recording, tracker, measurement=measurement):
        if args.start is not None and estimate.t < args.start:
            continue
        if shown % args.every == 0:
            print(format_estimate(estimate, args.confidence))
            printed += 1
            if args.count is not None and printed >= args.count:
                break
        shown += 1
    if args.health:
        health = tracker.health.as_dict()
        for key, value in health.items():
            if isinstance(value, float):
                value = round(value, 6)
            print(f"{key}: {value}")
    return 0
