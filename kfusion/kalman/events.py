"""The event-merge policy: which time an IMU sample or a mocap frame stands for, and the order
in which the filter sees them. The batch driver (:func:`kfusion.kalman.batch.process_recording`),
the :class:`kfusion.tracker.Tracker` (its arrival-order replay), ``kfusion stream`` and the
filter itself (:meth:`kfusion.kalman.KalmanFusion.predict`) all use these functions, so a batch
run and a stream of the same recording fuse the same events in the same order.

Time of an event, on the mocap clock (the reference, GUIDE §2):

* mocap frame: its stamp ``t``;
* IMU sample stamped ``t_imu`` on the IMU's clock:

      t_mapped = (1 + imu_clock_drift_ppm 1e-6) t_imu + imu_time_offset
      t_event  = t_mapped - imu_latency_s

  The first line is the clock model, written once in
  :func:`kfusion.conventions.imu_time_to_mocap` and applied where the stream enters
  (:func:`kfusion.recording.on_mocap_clock` for a recording, :meth:`Tracker.push_imu` for a
  stream); the second is :func:`imu_event_time`. A sample stamped ``t_mapped`` describes the
  motion at ``t_event``: with a latency larger than the gap between a mocap frame and the next
  IMU stamp, a sample stamped after a frame describes the motion before it and must be fused
  before it.

Order: by :func:`event_key`, ``(t_event, stream)`` with ``IMU_STREAM = 0 < MOCAP_STREAM = 1``:
increasing time, and at equal times the IMU sample first, so that the fix lands on a state that
holds that sample. Two events of one stream never tie (each stream is strictly increasing).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Final, overload

import numpy as np
from numpy.typing import NDArray

IMU_STREAM: Final = 0
"""Stream rank of IMU samples: first at equal times."""
MOCAP_STREAM: Final = 1
"""Stream rank of mocap frames."""

@overload
def imu_event_time(mapped_stamp: float, latency_s: float) -> float: ...


@overload
def imu_event_time(mapped_stamp: NDArray[np.float64], latency_s: float
                   ) -> NDArray[np.float64]: ...


def imu_event_time(mapped_stamp: float | NDArray[np.float64], latency_s: float
                   ) -> float | NDArray[np.float64]:
    """Time (s, mocap clock) an IMU sample describes: ``t_event = t_mapped - latency_s``, with
    ``t_mapped`` its stamp on the mocap clock. A float or an array (elementwise, the same
    double arithmetic)."""
    return mapped_stamp - latency_s


def event_key(time: float, stream: int, latency_s: float = 0.0) -> tuple[float, int]:
    """Sort key of an event in the fusion order: ``(t_event, stream)``.

    Args:
        time: s on the mocap clock: a mocap frame's stamp, or an IMU sample's mapped stamp.
        stream: :data:`IMU_STREAM` or :data:`MOCAP_STREAM`.
        latency_s: the IMU's latency (``KalmanParameters.imu_latency_s``); subtracted from IMU
            stamps only (:func:`imu_event_time`).
    """
    if stream == IMU_STREAM:
        return imu_event_time(time, latency_s), IMU_STREAM
    return time, MOCAP_STREAM


def merge_order(imu_stamps: NDArray[np.float64] | Sequence[float],
                mocap_times: NDArray[np.float64] | Sequence[float], latency_s: float = 0.0
                ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64]]:
    """Every IMU sample and mocap frame of a recording in fusion order, as arrays: ``(t_event,
    stream, index)`` each (n + m,), sorted by :func:`event_key` (a stable sort: ``np.lexsort``
    on time, then stream). Stamps must not be NaN (the order of a NaN is undefined).

    Args:
        imu_stamps: (n,) IMU stamps on the mocap clock, s, increasing.
        mocap_times: (m,) mocap frame times, s, increasing.
        latency_s: IMU latency, s.
    """
    imu = imu_event_time(np.asarray(imu_stamps, dtype=float), latency_s)
    mocap = np.asarray(mocap_times, dtype=float)
    times = np.concatenate([imu, mocap])
    stream = np.concatenate([np.full(len(imu), IMU_STREAM, dtype=np.int64),
                             np.full(len(mocap), MOCAP_STREAM, dtype=np.int64)])
    index = np.concatenate([np.arange(len(imu), dtype=np.int64),
                            np.arange(len(mocap), dtype=np.int64)])
    order = np.lexsort((stream, times))
    return times[order], stream[order], index[order]


def merge_events(imu_stamps: Sequence[float], mocap_times: Sequence[float],
                 latency_s: float = 0.0) -> list[tuple[float, int, int]]:
    """Every IMU sample and mocap frame of a recording in fusion order.

    Args:
        imu_stamps: (n,) IMU stamps on the mocap clock, s, increasing.
        mocap_times: (m,) mocap frame times, s, increasing.
        latency_s: IMU latency, s.

    Returns:
        ``(t_event, stream, index)`` for the n + m events, sorted by :func:`event_key`; index is
        the row in its stream (:func:`merge_order`; a NaN stamp, which has no place in the
        order, stays where a stable sort by that key leaves it, so the filter meets it and
        names it).
    """
    if not (np.isnan(np.asarray(imu_stamps, dtype=float)).any()
            or np.isnan(np.asarray(mocap_times, dtype=float)).any()):
        times, stream, index = merge_order(imu_stamps, mocap_times, latency_s)
        return list(zip(times.tolist(), stream.tolist(), index.tolist(), strict=True))
    events = [(*event_key(float(t), IMU_STREAM, latency_s), index)
              for index, t in enumerate(imu_stamps)]
    events += [(*event_key(float(t), MOCAP_STREAM), index)
               for index, t in enumerate(mocap_times)]
    events.sort(key=lambda event: (event[0], event[1]))
    return events
