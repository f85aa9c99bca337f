"""Latency of the online Tracker in CPython (issue 6 §6). A benchmark, not a timed test.

Streams a simulated recording (``random_reach``, MPU9255, 1 kHz IMU, 100 Hz mocap, 0.1-0.5 s
occlusions) through :class:`kfusion.Tracker` in time order and times every call with
``time.perf_counter_ns``:

* ``push_imu`` (target: median <= 50 us per IMU sample);
* ``push_mocap`` and ``estimate`` alone, and ``push_mocap + estimate`` (what safety software does
  at each frame);
* ``estimate`` at IMU rate (after each ``push_imu``), for callers that read every sample.

Configurations: the default Tracker (replay buffer for out-of-step streams, ``max_delay_s`` 0.1),
the Tracker without it (``max_delay_s`` 0: no checkpoints), the baseline method, and the bare
``kfusion.kalman.KalmanFusion`` (public predict/update) for reference. The garbage collector stays
on, as in a real process. Prints a markdown table.

Run: ``python benchmarks/latency.py [--seconds 40] [--seed 0]``.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from collections.abc import Callable

import numpy as np

from kfusion.kalman import KalmanFusion, KalmanParameters
from kfusion.recording import Recording
from kfusion.simulate import OcclusionSpec, simulate
from kfusion.tracker import Tracker

Timings = dict[str, list[int]]


def time_tracker(recording: Recording, tracker: Tracker, *, estimate_every_imu: bool) -> Timings:
    """Feed ``recording`` in time order; nanoseconds per call, by operation."""
    timings: Timings = {"push_imu": [], "push_mocap": [], "estimate": [],
                        "push_mocap + estimate": []}
    imu, mocap = recording.imu, recording.mocap
    imu_t = imu.t.tolist()
    accelerometer, gyroscope = imu.accelerometer, imu.gyroscope
    visible = mocap.visible.tolist()
    clock = time.perf_counter_ns
    i, n = 0, len(imu_t)
    for row, t in enumerate(mocap.t.tolist()):
        while i < n and imu_t[i] <= t:
            start = clock()
            tracker.push_imu(imu_t[i], accelerometer[i], gyroscope[i])
            timings["push_imu"].append(clock() - start)
            if estimate_every_imu:
                start = clock()
                tracker.estimate(imu_t[i])
                timings["estimate"].append(clock() - start)
            i += 1
        position = mocap.position[row] if visible[row] else None
        quaternion = mocap.quaternion[row] if visible[row] else None
        start = clock()
        tracker.push_mocap(t, position, quaternion)
        middle = clock()
        tracker.estimate(t)
        end = clock()
        timings["push_mocap"].append(middle - start)
        timings["push_mocap + estimate"].append(end - start)
        if not estimate_every_imu:
            timings["estimate"].append(end - middle)
    return timings


def time_fusion(recording: Recording) -> Timings:
    """The bare KalmanFusion (public methods), same stream."""
    info = recording.info
    fusion = KalmanFusion(info.imu_to_body, info.gravity,
                          KalmanParameters.from_profiles(info.imu), lever_arm=info.lever_arm)
    timings: Timings = {"push_imu": [], "push_mocap": [], "estimate": [],
                        "push_mocap + estimate": []}
    imu, mocap = recording.imu, recording.mocap
    imu_t = imu.t.tolist()
    visible = mocap.visible.tolist()
    clock = time.perf_counter_ns
    i, n = 0, len(imu_t)
    for row, t in enumerate(mocap.t.tolist()):
        while i < n and imu_t[i] <= t:
            start = clock()
            fusion.predict(imu_t[i], imu.accelerometer[i], imu.gyroscope[i])
            timings["push_imu"].append(clock() - start)
            i += 1
        start = clock()
        fusion.update(t, mocap.position[row] if visible[row] else None,
                      mocap.quaternion[row] if visible[row] else None)
        middle = clock()
        fusion.estimate()
        end = clock()
        timings["push_mocap"].append(middle - start)
        timings["estimate"].append(end - middle)
        timings["push_mocap + estimate"].append(end - start)
    return timings


def rows(label: str, timings: Timings) -> list[str]:
    """Table rows; the first 2.5 % of each call's timings (warm-up) are left out."""
    lines = []
    for operation, values in timings.items():
        if not values:
            continue
        micro = np.asarray(values[len(values) // 40:], dtype=float) / 1000.0
        lines.append(f"| {label} | {operation} | {len(micro)} | {np.median(micro):.1f} | "
                     f"{np.percentile(micro, 99):.1f} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=40.0,
                        help="simulated seconds (default 40: 40 000 IMU samples)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    simulation = simulate("random_reach", seed=args.seed, duration=args.seconds, imu_rate=1000.0,
                          occlusions=OcclusionSpec(gap_range=(0.1, 0.5), spacing=1.0))
    recording = simulation.recording
    runs: list[tuple[str, Callable[[], Timings]]] = [
        ("Tracker (kalman, default)",
         lambda: time_tracker(recording, Tracker.from_recording_info(recording.info),
                              estimate_every_imu=False)),
        ("Tracker (kalman, max_delay_s=0)",
         lambda: time_tracker(recording, Tracker.from_recording_info(
             recording.info, options={"max_delay_s": 0.0}), estimate_every_imu=False)),
        ("Tracker (kalman), estimate after every IMU sample",
         lambda: time_tracker(recording, Tracker.from_recording_info(recording.info),
                              estimate_every_imu=True)),
        ("Tracker (baseline)",
         lambda: time_tracker(recording, Tracker.from_recording_info(recording.info,
                                                                     method="baseline"),
                              estimate_every_imu=False)),
        ("KalmanFusion alone (reference)", lambda: time_fusion(recording)),
    ]
    print(f"# Tracker latency: {len(recording.imu)} IMU samples, {len(recording.mocap)} mocap "
          f"frames ({args.seconds:g} s simulated, random_reach, 1 kHz / 100 Hz)")
    print(f"Python {platform.python_version()} on {platform.machine()}, "
          f"{platform.processor() or platform.platform()}")
    print()
    print("| configuration | call | calls | median (us) | p99 (us) |")
    print("|---|---|---:|---:|---:|")
    for label, run in runs:
        timings = run()
        for line in rows(label, timings):
            print(line)
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
