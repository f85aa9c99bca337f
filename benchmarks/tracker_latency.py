"""Cost of :class:`kfusion.Tracker` calls by arrival order (issue 11 §3). A benchmark, not a test.

Streams a simulated recording (``random_reach``, MPU9255, IMU at ``--imu-rate`` Hz, mocap at
100 Hz, 0.1-0.5 s occlusions; with the default 200 Hz every other IMU stamp equals a mocap
stamp) through a Tracker in four arrival orders and times every call with
``time.perf_counter_ns``:

* ``in order``: the fusion order of :mod:`kfusion.kalman.events` (what ``kfusion stream`` feeds);
* ``mocap first``: every mocap frame arrives before the IMU sample with the same stamp;
* ``mocap late``: every mocap frame arrives ``--lag`` s after its stamp, behind later IMU
  samples (a mocap system with a processing delay);
* ``jitter``: each sample arrives at its stamp plus a uniform delay in [0, ``--jitter``] s, each
  stream keeping its own order.

Safety software reads the tracker at frame rate, so ``estimate(now)`` follows every
``push_mocap`` (``now``: the newest stamp that has arrived). Per order the table gives the
median, p90 and p99 of ``push_imu``, ``push_mocap`` and ``estimate`` in µs, the mean work per
pushed sample (all push time / samples: the cost a sample has whichever stream arrives first)
and the replays (``health.replays``).

Rows ``no-op estimator`` run the same Tracker with an estimator that does nothing (the
Tracker's own overhead: validation, ordering, bookkeeping, checkpoints); rows ``estimator
alone`` call the Tracker's Kalman estimator (filterpy ``KalmanFusion`` and the consistency
monitor) directly in fusion order, without the Tracker. The garbage collector stays on, as in a
real process; the first 2.5 % of each call's timings (warm-up) are left out.

Clock: ``--clock cpu`` (default) times each call with the thread's CPU time
(``time.thread_time_ns``), minus the median of an empty timed interval (the clock's own cost),
so that other processes on a shared machine do not inflate the numbers; ``--clock wall`` uses
``time.perf_counter_ns`` (what a caller waits, preemptions included).

Run: ``python benchmarks/tracker_latency.py [--quick] [--seconds 40] [--imu-rate 200]
[--clock cpu|wall]``.
"""

from __future__ import annotations

import argparse
import math
import platform
import sys
import time
from collections.abc import Callable

import numpy as np

from kfusion.kalman.events import IMU_STREAM, MOCAP_STREAM, merge_events
from kfusion.recording import Recording
from kfusion.simulate import OcclusionSpec, simulate
from kfusion.tracker import Tracker

Order = list[tuple[int, int]]
"""(stream, row) in arrival order."""
Timings = dict[str, list[int]]


def arrival_orders(recording: Recording, lag: float, jitter: float, seed: int
                   ) -> dict[str, Order]:
    """The four arrival orders (module docstring) of ``recording`` (no clock model, latency 0:
    a stamp is the time the sample describes)."""
    imu_t, mocap_t = recording.imu.t, recording.mocap.t
    in_order = [(stream, index) for _, stream, index in merge_events(imu_t.tolist(),
                                                                      mocap_t.tolist())]
    mocap_first = sorted([(float(t), 1, IMU_STREAM, i) for i, t in enumerate(imu_t)]
                         + [(float(t), 0, MOCAP_STREAM, j) for j, t in enumerate(mocap_t)])
    late = sorted([(float(t), IMU_STREAM, i) for i, t in enumerate(imu_t)]
                  + [(float(t) + lag, MOCAP_STREAM, j) for j, t in enumerate(mocap_t)])
    rng = np.random.default_rng(seed)
    imu_arrival = np.maximum.accumulate(imu_t + rng.uniform(0.0, jitter, len(imu_t)))
    mocap_arrival = np.maximum.accumulate(mocap_t + rng.uniform(0.0, jitter, len(mocap_t)))
    jittered = sorted([(float(t), IMU_STREAM, i) for i, t in enumerate(imu_arrival)]
                      + [(float(t), MOCAP_STREAM, j) for j, t in enumerate(mocap_arrival)])
    return {"in order": in_order,
            "mocap first": [(stream, index) for _, _, stream, index in mocap_first],
            f"mocap late {1000 * lag:g} ms": [(stream, index) for _, stream, index in late],
            f"jitter {1000 * jitter:g} ms": [(stream, index) for _, stream, index in jittered]}


CLOCK: dict[str, Callable[[], int]] = {"cpu": time.thread_time_ns, "wall": time.perf_counter_ns}
clock = time.thread_time_ns
"""The clock of every timing (``--clock``)."""
overhead = 0
"""ns: median of an empty timed interval, subtracted from every timing."""


def clock_overhead() -> int:
    """Median ns of an empty interval timed with :data:`clock`."""
    empty = []
    for _ in range(20000):
        start = clock()
        empty.append(clock() - start)
    return int(np.median(empty))


def time_tracker(recording: Recording, tracker: Tracker, order: Order) -> Timings:
    """Push ``order``; nanoseconds per call. ``estimate(now)`` after every frame."""
    imu, mocap = recording.imu, recording.mocap
    imu_t, mocap_t = imu.t.tolist(), mocap.t.tolist()
    accelerometer, gyroscope = list(imu.accelerometer), list(imu.gyroscope)
    visible = mocap.visible.tolist()
    positions = [p if v else None for p, v in zip(mocap.position, visible, strict=True)]
    quaternions = [q if v else None for q, v in zip(mocap.quaternion, visible, strict=True)]
    timings: Timings = {"push_imu": [], "push_mocap": [], "estimate": []}
    push_imu, push_mocap, estimate = tracker.push_imu, tracker.push_mocap, tracker.estimate
    now = -math.inf
    for stream, index in order:
        if stream == IMU_STREAM:
            t = imu_t[index]
            start = clock()
            push_imu(t, accelerometer[index], gyroscope[index])
            timings["push_imu"].append(clock() - start)
            now = max(now, t)
            continue
        t = mocap_t[index]
        start = clock()
        push_mocap(t, positions[index], quaternions[index])
        middle = clock()
        now = max(now, t, tracker.newest_time)
        estimate(now)
        timings["push_mocap"].append(middle - start)
        timings["estimate"].append(clock() - middle)
    return timings


def time_estimator(recording: Recording) -> Timings:
    """The Tracker's Kalman estimator (fusion + monitor) alone, fusion order, nanoseconds."""
    tracker = Tracker.from_recording_info(recording.info)
    estimator = tracker._estimator  # the same object the Tracker drives
    imu, mocap = recording.imu, recording.mocap
    timings: Timings = {"push_imu": [], "push_mocap": [], "estimate": []}
    for t, stream, index in merge_events(imu.t.tolist(), mocap.t.tolist()):
        if stream == IMU_STREAM:
            # the Tracker's form of a validated sample (kfusion.tracker._three): 3-tuples
            accelerometer = tuple(imu.accelerometer[index].tolist())
            gyroscope = tuple(imu.gyroscope[index].tolist())
            start = clock()
            estimator.predict(t, accelerometer, gyroscope)
            timings["push_imu"].append(clock() - start)
            continue
        visible = bool(mocap.visible[index])
        start = clock()
        estimator.update(t, mocap.position[index] if visible else None,
                         mocap.quaternion[index] if visible else None)
        middle = clock()
        estimator.read(t)
        timings["push_mocap"].append(middle - start)
        timings["estimate"].append(clock() - middle)
    return timings


class NoOpEstimator:
    """An estimator that does nothing (the Tracker's estimator interface), for the Tracker's
    own overhead: every fix is accepted, the IMU always dead-reckons, a fixed reading."""

    method = "kalman"
    has_covariance = True
    imu_latency_s = 0.0
    max_bridge_s = 1.0
    imu_dropout_s = 0.1
    accelerometer_range = 160.0

    def __init__(self) -> None:
        from kfusion.tracker import _Reading

        zero = np.zeros(3)
        self._reading = _Reading(zero, zero, np.eye(3) * 1e-6, np.full(3, 1e-3))

    def predict(self, t: float, accelerometer: object, gyroscope: object) -> None:
        return None

    def update(self, t: float, position: object, quaternion: object) -> str:
        return "accepted"

    def read(self, t: float, trust_model: bool = True,
             suspected_clock: tuple[float, float] | None = None) -> object:
        return self._reading

    def note_gap_frame(self, t: float,
                       suspected_clock: tuple[float, float] | None = None) -> None:
        return None

    def finite(self) -> bool:
        return True

    def resets(self) -> int:
        return 0

    def dead_reckoning_until(self) -> float:
        return math.inf

    def orientation_gated(self) -> int:
        return 0

    def snapshot(self) -> object:
        return None

    def restore(self, snapshot: object) -> None:
        return None


def no_op_tracker(recording: Recording) -> Tracker:
    tracker = Tracker.from_recording_info(recording.info)
    tracker._new_estimator = NoOpEstimator  # type: ignore[method-assign]
    tracker.reset()  # starts again with the no-op estimator
    return tracker


def percentiles(values: list[int]) -> str:
    micro = (np.asarray(values[len(values) // 40:], dtype=float) - overhead) / 1000.0
    if len(micro) == 0:
        return "| - | - | - "
    return (f"| {np.median(micro):.1f} | {np.percentile(micro, 90):.1f} | "
            f"{np.percentile(micro, 99):.1f} ")


def row(label: str, order: str, timings: Timings, samples: int, replays: int | str) -> str:
    calls = len(timings["push_imu"]) + len(timings["push_mocap"])
    total = sum(timings["push_imu"]) + sum(timings["push_mocap"]) - calls * overhead
    work = total / samples / 1000.0
    return (f"| {label} | {order} {percentiles(timings['push_imu'])}"
            f"{percentiles(timings['push_mocap'])}{percentiles(timings['estimate'])}"
            f"| {work:.1f} | {replays} |")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=40.0, help="simulated s (default 40)")
    parser.add_argument("--quick", action="store_true", help="10 simulated s")
    parser.add_argument("--imu-rate", type=float, default=200.0, help="Hz (default 200)")
    parser.add_argument("--lag", type=float, default=0.005,
                        help="mocap delay of the 'mocap late' order, s (default 0.005)")
    parser.add_argument("--jitter", type=float, default=0.01,
                        help="largest arrival delay of the 'jitter' order, s (default 0.01)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--clock", choices=sorted(CLOCK), default="cpu",
                        help="thread CPU time (default) or wall time")
    args = parser.parse_args(argv)
    global clock, overhead
    clock = CLOCK[args.clock]
    overhead = clock_overhead()
    seconds = 10.0 if args.quick else args.seconds
    recording = simulate("random_reach", seed=args.seed, duration=seconds,
                         imu_rate=args.imu_rate, mocap_rate=100.0,
                         occlusions=OcclusionSpec(gap_range=(0.1, 0.5), spacing=1.0)).recording
    orders = arrival_orders(recording, args.lag, args.jitter, args.seed)
    samples = len(recording.imu) + len(recording.mocap)
    print(f"# Tracker latency by arrival order: {len(recording.imu)} IMU samples, "
          f"{len(recording.mocap)} mocap frames ({seconds:g} s of random_reach, "
          f"{args.imu_rate:g} Hz / 100 Hz)")
    print(f"Python {platform.python_version()} on {platform.machine()}; {args.clock} time, "
          f"µs per call (median | p90 | p99; clock cost {overhead} ns subtracted); "
          f"work = all push time / samples")
    print()
    print("| tracker | arrival | push_imu p50 | p90 | p99 | push_mocap p50 | p90 | p99 | "
          "estimate p50 | p90 | p99 | work/sample | replays |")
    print("|---|---|" + "---:|" * 11)
    # numba and the cached kernels load at the first Tracker's first sample: not timed
    time_tracker(recording, Tracker.from_recording_info(recording.info), orders["in order"][:200])
    builders: list[tuple[str, Callable[[], Tracker]]] = [
        ("kalman", lambda: Tracker.from_recording_info(recording.info)),
        ("no-op estimator", lambda: no_op_tracker(recording)),
    ]
    for label, build in builders:
        for name, order in orders.items():
            tracker = build()
            timings = time_tracker(recording, tracker, order)
            print(row(label, name, timings, samples, tracker.health.replays))
            sys.stdout.flush()
    print(row("estimator alone", "in order", time_estimator(recording), samples, "-"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
