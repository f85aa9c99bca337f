"""``kfusion convert {motive,broad} SOURCE --out DIR``: turn a real format into a recording folder.

* ``motive TAKE.csv --imu IMU.csv``: an OptiTrack Motive CSV export (one rigid body) plus an IMU
  file in the ``imu.csv`` layout on the same clock. Motive's world is y-up by default, hence the
  default gravity ``[0, -9.81, 0]``. The IMU mount is never guessed: without ``--imu-to-body``
  ``recording.yaml`` has no ``imu_to_body`` and the command prints the next step,
  ``kfusion calibrate DIR --out DIR/recording.yaml``.
* ``broad FILE.mat``: a BROAD trial; ``--mocap-step 3`` keeps every 3rd mocap frame (~95 Hz).

The files written are read back and validated (as ``kfusion check`` does) before the summary is
printed. A folder converted with its mount given passes ``kfusion check`` at once; one without
passes it once ``kfusion calibrate`` has written the mount.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import yaml

from kfusion.commands.check import summarise
from kfusion.conventions import OPTITRACK_GRAVITY
from kfusion.profiles import imu_profile
from kfusion.readers.broad import read_broad
from kfusion.readers.motive import read_motive_csv
from kfusion.recording import (
    IMU_FILE,
    META_FILE,
    MOCAP_FILE,
    ImuSamples,
    MocapFrames,
    Recording,
    info_to_dict,
    parse_info,
    read_imu,
    read_mocap,
    read_recording,
    write_recording,
)

NAME = "convert"
HELP = "Convert an OptiTrack Motive CSV export (plus an IMU file) or a BROAD trial to a recording."
ORDER = 20

COMMAND_LINE = "command line"
"""File name used in error messages about values given as options."""


def _add_output(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="DIR", help="recording folder to write")
    parser.add_argument("--force", action="store_true",
                        help="overwrite a recording already in DIR")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    formats = parser.add_subparsers(dest="format", metavar="FORMAT", required=True)

    motive = formats.add_parser("motive", help="OptiTrack Motive CSV export + imu.csv-style file",
                                description="Convert one rigid body of a Motive CSV export "
                                "(Rotation Type Quaternion; Length Units converted to m) and an "
                                "IMU file in the imu.csv layout (t, ax, ay, az, gx, gy, gz on the "
                                "mocap clock; s, m/s^2, rad/s).")
    motive.add_argument("take", metavar="TAKE.csv", help="Motive CSV export")
    motive.add_argument("--imu", required=True, metavar="IMU.csv",
                        help="IMU samples: t, ax, ay, az, gx, gy, gz (s, m/s^2, rad/s)")
    motive.add_argument("--rigid-body", metavar="NAME",
                        help="rigid body to read (default: the only one in the export)")
    motive.add_argument("--imu-to-body", nargs=4, type=float, metavar=("W", "X", "Y", "Z"),
                        help="unit quaternion IMU -> rigid body, if known (default: left out "
                        "of recording.yaml; then run kfusion calibrate DIR --out "
                        "DIR/recording.yaml)")
    motive.add_argument("--gravity", nargs=3, type=float, metavar=("GX", "GY", "GZ"),
                        default=list(OPTITRACK_GRAVITY),
                        help="gravity in the mocap world, m/s^2 (default: y-up 0 -9.81 0)")
    motive.add_argument("--lever-arm", nargs=3, type=float, metavar=("X", "Y", "Z"),
                        help="IMU position in the rigid-body frame, m (optional)")
    motive.add_argument("--imu-profile", metavar="NAME",
                        help="IMU profile name written as recording.yaml's imu (optional)")
    motive.add_argument("--name", help="recording name (default: the take file's stem)")
    motive.add_argument("--zeros-occluded", action="store_true",
                        help="read a rigid-body position of exactly (0, 0, 0) as occluded")
    _add_output(motive)
    motive.set_defaults(_convert=_convert_motive)

    broad = formats.add_parser("broad", help="BROAD trial (.mat)",
                               description="Convert a BROAD trial: gravity [0, 0, -9.81], "
                               "imu_to_body identity, dropouts where opt_quat is NaN.")
    broad.add_argument("trial", metavar="FILE.mat", help="BROAD trial file")
    broad.add_argument("--mocap-step", type=int, default=1, metavar="N",
                       help="keep every N-th mocap frame (default 1: 285.7 Hz; 3: ~95 Hz)")
    _add_output(broad)
    broad.set_defaults(_convert=_convert_broad)


def check_same_clock(imu: ImuSamples, mocap: MocapFrames) -> None:
    """ValueError unless the IMU and mocap time spans overlap (both must be on one clock, s)."""
    if imu.t[-1] < mocap.t[0] or mocap.t[-1] < imu.t[0]:
        raise ValueError(f"IMU times {imu.t[0]:.3f}..{imu.t[-1]:.3f} s do not overlap the mocap "
                         f"times {mocap.t[0]:.3f}..{mocap.t[-1]:.3f} s; expected both on one "
                         "clock (shift the IMU file's t)")


UNKNOWN_MOUNT_PLACEHOLDER = (1.0, 0.0, 0.0, 0.0)
"""Validates the other options when --imu-to-body is absent; never written to a file."""


def next_step(folder: Path) -> str:
    """What to run after converting without ``--imu-to-body``."""
    return (f"imu_to_body: not given, left out of {folder / META_FILE}; next: kfusion calibrate "
            f"{folder} --out {folder / META_FILE} (or convert again with --imu-to-body W X Y Z "
            f"if the mount is known), then kfusion check {folder}")


def _convert_motive(args: argparse.Namespace) -> Recording:
    take = Path(args.take)
    mocap = read_motive_csv(take, rigid_body=args.rigid_body,
                            zero_position_means_occluded=args.zeros_occluded)
    imu = read_imu(args.imu)
    check_same_clock(imu, mocap)
    if args.imu_profile is not None:
        imu_profile(args.imu_profile)  # ValueError listing the known profiles
    mount = args.imu_to_body if args.imu_to_body is not None else UNKNOWN_MOUNT_PLACEHOLDER
    options = {"imu_to_body": mount, "gravity": args.gravity,
               "name": args.name or take.stem, "imu": args.imu_profile,
               "lever_arm": args.lever_arm}
    info = parse_info(options, COMMAND_LINE)
    return Recording(imu=imu, mocap=mocap, info=info, source=str(take))


def _convert_broad(args: argparse.Namespace) -> Recording:
    return read_broad(args.trial, mocap_step=args.mocap_step)


def check_output_folder(folder: Path, force: bool) -> None:
    """Refuse to overwrite an existing recording unless ``force``; FileExistsError otherwise."""
    existing = [name for name in (IMU_FILE, MOCAP_FILE, META_FILE) if (folder / name).exists()]
    if existing and not force:
        raise FileExistsError(f"{folder} already holds {', '.join(existing)}; expected a new or "
                              "empty folder (use --force to overwrite)")
    if folder.exists() and not folder.is_dir():
        raise FileExistsError(f"{folder} exists and is not a folder; expected a folder path")


def write_without_mount(recording: Recording, folder: Path) -> Recording:
    """Write the folder with ``recording.yaml`` lacking ``imu_to_body``; returns the CSVs read
    back (validated as ``kfusion check`` does) with the in-memory metadata."""
    write_recording(recording, folder)
    metadata = {key: value for key, value in info_to_dict(recording.info).items()
                if key != "imu_to_body"}
    (folder / META_FILE).write_text(yaml.safe_dump(metadata, sort_keys=False))
    return Recording(imu=read_imu(folder / IMU_FILE), mocap=read_mocap(folder / MOCAP_FILE),
                     info=recording.info, source=str(folder))


def run(args: argparse.Namespace) -> int:
    folder = Path(args.out)
    check_output_folder(folder, args.force)
    recording = args._convert(args)
    mount_unknown = args.format == "motive" and args.imu_to_body is None
    if mount_unknown:
        written = write_without_mount(recording, folder)
    else:
        write_recording(recording, folder)
        # Read back with the folder reader, so what was written is exactly what `check` accepts.
        written = read_recording(folder)
    print(f"{args.format}: wrote {folder}")
    print(summarise(written))
    print(next_step(folder) if mount_unknown else f"next: kfusion check {folder}, then "
          f"kfusion track {folder} --method kalman --out track.csv")
    return 0
