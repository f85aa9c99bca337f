"""``kfusion check DIR``: validate a recording, test that it agrees with itself, summarise it.

Exit 2 with one line naming the likely mistake and its fix when the data contradict
``recording.yaml`` (clock offset, mount, quaternion order, gravity, time units, no overlap):
see :mod:`kfusion.calibration.diagnosis`.
"""

from __future__ import annotations

import argparse

import numpy as np

from kfusion.calibration.diagnosis import diagnose
from kfusion.recording import Recording, occlusion_durations, read_recording

NAME = "check"
HELP = ("Validate a recording folder, test its consistency (clock, mount, gravity) and print a "
        "summary.")
ORDER = 10


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folder", metavar="DIR", help="recording folder (imu.csv, mocap.csv, "
                        "recording.yaml; markers.csv optional)")
    parser.add_argument("--zeros-occluded", action="store_true",
                        help="read a mocap position of exactly (0, 0, 0) as occluded "
                        "(some exporters write zeros for a lost rigid body); default: off")


def summarise(recording: Recording) -> str:
    """Multi-line human-readable summary of a valid recording."""
    imu, mocap = recording.imu, recording.mocap
    start = min(imu.t[0], mocap.t[0])
    end = max(imu.t[-1], mocap.t[-1])
    imu_rate = (len(imu) - 1) / (imu.t[-1] - imu.t[0]) if len(imu) > 1 else float("nan")
    mocap_rate = (len(mocap) - 1) / (mocap.t[-1] - mocap.t[0]) if len(mocap) > 1 else float("nan")
    durations = occlusion_durations(mocap.t, mocap.visible)
    lines = [
        f"recording: {recording.info.name or recording.source}",
        f"duration: {end - start:.3f} s",
        f"imu: {len(imu)} samples at {imu_rate:.1f} Hz",
        f"mocap: {len(mocap)} frames at {mocap_rate:.1f} Hz, "
        f"{int((~mocap.visible).sum())} occluded",
        f"occlusions: {len(durations)}",
    ]
    if len(durations):
        lines.append(
            f"occlusion length: min {durations.min():.3f} s, median {np.median(durations):.3f} s,"
            f" max {durations.max():.3f} s"
        )
    lines.extend(marker_lines(recording))
    return "\n".join(lines)


def marker_lines(recording: Recording) -> list[str]:
    """Summary lines about ``markers.csv`` and ``recording.yaml``'s ``markers`` (none when the
    recording has neither)."""
    lines = []
    markers, positions = recording.markers, recording.info.markers
    if markers is not None:
        seen = markers.visible.sum(axis=1)
        count = len(markers.names)
        lines.append(
            f"markers: {count} ({', '.join(markers.names)}) in {len(markers)} frames; all seen in "
            f"{100 * np.mean(seen == count):.1f} %, 3 or more in {100 * np.mean(seen >= 3):.1f} "
            f"%, none in {100 * np.mean(seen == 0):.1f} %")
    if positions is not None:
        lines.append(f"body-frame marker positions: {len(positions)} in recording.yaml "
                     f"({', '.join(positions)})")
    return lines


def run(args: argparse.Namespace) -> int:
    recording = read_recording(args.folder, zero_position_means_occluded=args.zeros_occluded)
    diagnosis = diagnose(recording)
    if not diagnosis.ok:
        raise ValueError(f"{args.folder}: {diagnosis.problems[0]}")
    print(f"ok: {args.folder}")
    print(summarise(recording))
    for note in diagnosis.notes:
        print(f"consistency: {note}")
    return 0
