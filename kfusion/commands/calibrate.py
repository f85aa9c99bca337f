"""``kfusion calibrate DIR``: the paper's offline calibrations (IMU -> body rotation, gain K).

Prints ``recording.yaml`` content with the estimated ``imu_to_body`` (and writes it with
``--out``). The gain K is not a ``recording.yaml`` key (that file holds only ``imu_to_body``,
``gravity``, ``name``, ``imu`` and ``lever_arm``), so it goes to a separate baseline-parameters
YAML file with ``--gain-out`` (``gain: K``), which :meth:`kfusion.baseline.BaselineParameters.
from_mapping` reads.

DIR needs ``imu.csv`` and ``mocap.csv``. Its ``recording.yaml`` is optional: when present, its
gravity, name, IMU profile and lever arm are kept and its ``imu_to_body`` is replaced; when absent,
gravity comes from ``--gravity`` (default OptiTrack's y-up ``0 -9.81 0``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import yaml

from kfusion.calibration import (
    DEFAULT_GRAVITY_TOLERANCE,
    DEFAULT_GYROSCOPE_THRESHOLD,
    DEFAULT_MIN_POSE_ANGLE,
    DEFAULT_STILL_DURATION,
    calibrate_gain,
    calibrate_imu_to_body,
)
from kfusion.conventions import OPTITRACK_GRAVITY
from kfusion.guards import atomic_write_text
from kfusion.recording import (
    IMU_FILE,
    META_FILE,
    MOCAP_FILE,
    Recording,
    RecordingError,
    RecordingInfo,
    info_to_dict,
    parse_info,
    read_imu,
    read_info,
    read_mocap,
)

NAME = "calibrate"
HELP = "Estimate the IMU -> body rotation (Kabsch) and the baseline's gain K from a recording."
ORDER = 40


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folder", metavar="DIR",
                        help="recording folder (imu.csv, mocap.csv; recording.yaml optional)")
    parser.add_argument("--out", metavar="FILE",
                        help="write the recording.yaml content here (refuses to overwrite "
                        "without --force)")
    parser.add_argument("--gain-out", metavar="FILE",
                        help="write the gain K as baseline parameters YAML (gain: K)")
    parser.add_argument("--force", action="store_true", help="overwrite existing output files")
    parser.add_argument("--gravity", nargs=3, type=float, metavar=("GX", "GY", "GZ"),
                        help="gravity in the mocap frame, m/s^2 (default: recording.yaml's, "
                        "else 0 -9.81 0)")
    parser.add_argument("--angular-rate", action="store_true",
                        help="also pair gyroscope rates with mocap rates (for recordings "
                        "without still poses in different orientations)")
    parser.add_argument("--gyroscope-threshold", type=float, default=DEFAULT_GYROSCOPE_THRESHOLD,
                        metavar="RAD_S", help="still when |gyroscope| is below this, rad/s "
                        f"(default {DEFAULT_GYROSCOPE_THRESHOLD})")
    parser.add_argument("--gravity-tolerance", type=float, default=DEFAULT_GRAVITY_TOLERANCE,
                        metavar="M_S2", help="still when ||f| - |g|| is below this, m/s^2 "
                        f"(default {DEFAULT_GRAVITY_TOLERANCE})")
    parser.add_argument("--still-duration", type=float, default=DEFAULT_STILL_DURATION,
                        metavar="S", help=f"shortest still pose, s (default "
                        f"{DEFAULT_STILL_DURATION})")
    parser.add_argument("--min-pose-angle", type=float, default=DEFAULT_MIN_POSE_ANGLE,
                        metavar="DEG", help="poses must span this angle, degrees (default "
                        f"{DEFAULT_MIN_POSE_ANGLE:g})")
    parser.add_argument("--zeros-occluded", action="store_true",
                        help="read a mocap position of exactly (0, 0, 0) as occluded")


def load_for_calibration(folder: Path, gravity: list[float] | None,
                         zeros_occluded: bool = False) -> Recording:
    """The recording in ``folder``; without ``recording.yaml``, an identity mounting and
    ``gravity`` (default OptiTrack's)."""
    if not folder.is_dir():
        raise RecordingError(folder, f"not a recording folder (expected a directory holding "
                             f"{IMU_FILE} and {MOCAP_FILE})")
    if (folder / META_FILE).is_file():
        info = read_info(folder / META_FILE)
        if gravity is not None:
            data = info_to_dict(info)
            data["gravity"] = list(gravity)
            info = parse_info(data, "--gravity")
    else:
        info = parse_info({"imu_to_body": [1.0, 0.0, 0.0, 0.0],
                           "gravity": list(gravity or OPTITRACK_GRAVITY)}, "--gravity")
    imu = read_imu(folder / IMU_FILE)
    mocap = read_mocap(folder / MOCAP_FILE, zero_position_means_occluded=zeros_occluded)
    return Recording(imu=imu, mocap=mocap, info=info, source=str(folder))


def _write(path: Path, text: str, force: bool) -> None:
    if path.exists() and not force:
        raise FileExistsError(f"{path} exists; pass --force to overwrite it")
    atomic_write_text(path, text)


def run(args: argparse.Namespace) -> int:
    for target in (args.out, args.gain_out):
        if target and Path(target).exists() and not args.force:
            raise FileExistsError(f"{target} exists; pass --force to overwrite it")
    recording = load_for_calibration(Path(args.folder), args.gravity, args.zeros_occluded)
    rotation = calibrate_imu_to_body(
        recording, gyroscope_threshold=args.gyroscope_threshold,
        gravity_tolerance=args.gravity_tolerance, still_duration=args.still_duration,
        min_pose_angle=args.min_pose_angle, use_angular_rate=args.angular_rate)
    gain = calibrate_gain(recording, rotation.imu_to_body)
    info = RecordingInfo(imu_to_body=rotation.imu_to_body, gravity=recording.info.gravity,
                         name=recording.info.name, imu=recording.info.imu,
                         lever_arm=recording.info.lever_arm)
    text = yaml.safe_dump(info_to_dict(info), sort_keys=False)
    summary = [
        f"# imu_to_body from {rotation.poses} still pose(s) spanning {rotation.spread_deg:.1f} deg"
        + (f" and {rotation.rate_pairs} angular-rate pairs" if rotation.rate_pairs else "")
        + f"; gravity residual {rotation.residual_deg:.2f} deg RMS",
        f"# baseline gain K = {gain.gain:.4f} from {gain.windows} window(s) (not a "
        "recording.yaml key: use --gain-out)",
    ]
    print("\n".join(summary))
    print(text, end="")
    if args.out:
        _write(Path(args.out), text, args.force)
        print(f"# wrote {args.out}")
    if args.gain_out:
        gain_text = ("# baseline parameters (kfusion.baseline.BaselineParameters): gain K of "
                     f"eq. 8, from kfusion calibrate {args.folder}\n"
                     + yaml.safe_dump({"gain": float(np.round(gain.gain, 6))}, sort_keys=False))
        _write(Path(args.gain_out), gain_text, args.force)
        print(f"# wrote {args.gain_out}")
    return 0
