"""``kfusion calibrate DIR --out FILE``: self-calibration of a recording from ordinary motion.

DIR needs only ``imu.csv`` and ``mocap.csv``. Its ``recording.yaml`` is optional and may lack
``imu_to_body``: a given ``gravity`` (or ``--gravity``) is checked against the data, an absent one
estimated; ``name`` and ``imu`` are kept. The estimators (:mod:`kfusion.calibration`) give
``imu_to_body``, ``gravity``, ``imu_time_offset``, ``imu_clock_drift_ppm``, ``lever_arm`` (when
observable) and ``imu_noise``; each is printed with its 1-sigma uncertainty and fit residual, or
with the reason the motion leaves it undetermined. An undetermined optional key is left out; an
undetermined mount or gravity writes nothing (exit 2) rather than a guess.

``--paper`` runs the paper's own calibrations instead: the Kabsch mount from still poses and the
baseline's gain K (``--gain-out``, a baseline-parameters YAML file, since K is not a
``recording.yaml`` key).
"""

from __future__ import annotations

import argparse
import dataclasses
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
    calibrate_recording,
)
from kfusion.conventions import OPTITRACK_GRAVITY
from kfusion.guards import atomic_write_text, finite_float
from kfusion.recording import (
    IMU_FILE,
    META_FILE,
    MOCAP_FILE,
    Recording,
    RecordingError,
    info_to_dict,
    on_mocap_clock,
    parse_info,
    read_imu,
    read_info,
    read_mocap,
)

NAME = "calibrate"
HELP = ("Estimate the IMU's clock offset and drift, mount, gravity, lever arm and noise from a "
        "recording and write a complete recording.yaml.")
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
    parser.add_argument("--gravity", nargs=3, type=finite_float, metavar=("GX", "GY", "GZ"),
                        help="gravity in the mocap frame, m/s^2, checked against the data "
                        "(default: recording.yaml's, else estimated; with --paper 0 -9.81 0)")
    parser.add_argument("--max-offset", type=finite_float, default=5.0, metavar="S",
                        help="search the IMU clock offset within +-S s (default 5)")
    parser.add_argument("--paper", action="store_true",
                        help="the paper's calibrations instead: Kabsch mount from still poses "
                        "and the gain K; the options below apply to it")
    parser.add_argument("--angular-rate", action="store_true",
                        help="also pair gyroscope rates with mocap rates (for recordings "
                        "without still poses in different orientations)")
    parser.add_argument("--gyroscope-threshold", type=finite_float,
                        default=DEFAULT_GYROSCOPE_THRESHOLD,
                        metavar="RAD_S", help="still when |gyroscope| is below this, rad/s "
                        f"(default {DEFAULT_GYROSCOPE_THRESHOLD})")
    parser.add_argument("--gravity-tolerance", type=finite_float, default=DEFAULT_GRAVITY_TOLERANCE,
                        metavar="M_S2", help="still when ||f| - |g|| is below this, m/s^2 "
                        f"(default {DEFAULT_GRAVITY_TOLERANCE})")
    parser.add_argument("--still-duration", type=finite_float, default=DEFAULT_STILL_DURATION,
                        metavar="S", help=f"shortest still pose, s (default "
                        f"{DEFAULT_STILL_DURATION})")
    parser.add_argument("--min-pose-angle", type=finite_float, default=DEFAULT_MIN_POSE_ANGLE,
                        metavar="DEG", help="poses must span this angle, degrees (default "
                        f"{DEFAULT_MIN_POSE_ANGLE:g})")
    parser.add_argument("--zeros-occluded", action="store_true",
                        help="read a mocap position of exactly (0, 0, 0) as occluded")


def load_for_calibration(folder: Path, gravity: list[float] | None,
                         zeros_occluded: bool = False) -> Recording:
    """The recording in ``folder``; ``recording.yaml`` optional and may lack ``imu_to_body``
    and ``gravity`` (read as NaN: unknown); ``gravity`` replaces the file's."""
    if not folder.is_dir():
        raise RecordingError(folder, f"not a recording folder (expected a directory holding "
                             f"{IMU_FILE} and {MOCAP_FILE})")
    if (folder / META_FILE).is_file():
        info = read_info(folder / META_FILE, require_mount=False)
    else:
        info = parse_info({}, META_FILE, require_mount=False)
    if gravity is not None:
        data = {**info_to_dict(info), "gravity": list(gravity)}
        data.pop("imu_to_body")
        info = parse_info(data, "--gravity", require_mount=False)
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
    if args.gain_out and not args.paper:
        raise ValueError("--gain-out: the gain K comes from the paper's calibration: add --paper")
    recording = load_for_calibration(Path(args.folder), args.gravity, args.zeros_occluded)
    if args.paper:
        return _run_paper(args, recording)
    calibration = calibrate_recording(recording, max_offset=args.max_offset)
    print("\n".join(f"# {line}" for line in calibration.report()))
    if not calibration.complete:
        # name the root cause first: the mount needs the clock, gravity needs both
        missing = [key for key in ("imu_time_offset", "imu_to_body", "gravity")
                   if key in calibration.undetermined]
        raise ValueError(f"{args.folder}: {missing[0]} undetermined: "
                         f"{calibration.undetermined[missing[0]]}; nothing written")
    text = yaml.safe_dump(info_to_dict(calibration.info), sort_keys=False)
    print(text, end="")
    if args.out:
        _write(Path(args.out), text, args.force)
        print(f"# wrote {args.out}")
    return 0


def _run_paper(args: argparse.Namespace, recording: Recording) -> int:
    """The paper's Kabsch mount from still poses and its gain K."""
    if not np.isfinite(recording.info.gravity).all():
        recording = dataclasses.replace(recording, info=dataclasses.replace(
            recording.info, gravity=np.asarray(OPTITRACK_GRAVITY)))
    # the still poses and rate pairs pair IMU and mocap samples in time: on the mocap clock
    timed = on_mocap_clock(recording)
    rotation = calibrate_imu_to_body(
        timed, gyroscope_threshold=args.gyroscope_threshold,
        gravity_tolerance=args.gravity_tolerance, still_duration=args.still_duration,
        min_pose_angle=args.min_pose_angle, use_angular_rate=args.angular_rate)
    gain = calibrate_gain(timed, rotation.imu_to_body)
    info = dataclasses.replace(recording.info, imu_to_body=rotation.imu_to_body)
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
