"""``kfusion track DIR --method NAME --out OUT.csv``: run an estimator over a recording folder."""

from __future__ import annotations

import argparse
from typing import Any

import numpy as np
import yaml

from kfusion.calibration.diagnosis import diagnose
from kfusion.conventions import STATUSES
from kfusion.methods import METHODS, track_recording
from kfusion.recording import read_recording
from kfusion.track import write_track_csv

NAME = "track"
HELP = "Estimate the position at every mocap row of a recording and write the track CSV."
ORDER = 30


def parse_options(pairs: list[str] | None) -> dict[str, Any]:
    """``["key=value", ...]`` -> dict, with values parsed as YAML scalars (numbers, true/false)."""
    options: dict[str, Any] = {}
    for pair in pairs or []:
        key, separator, value = pair.partition("=")
        if not separator or not key:
            raise ValueError(f"--set: expected KEY=VALUE, got {pair!r}")
        options[key.strip()] = yaml.safe_load(value)
    return options


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folder", metavar="DIR", help="recording folder")
    parser.add_argument("--method", choices=sorted(METHODS), default="kalman",
                        help="estimator (default: kalman)")
    parser.add_argument("--out", required=True, metavar="OUT.csv",
                        help="output CSV: t, x, y, z, std_x, std_y, std_z, status")
    parser.add_argument("--set", action="append", metavar="KEY=VALUE", dest="options",
                        help="override one of the method's parameters (repeatable), "
                        "e.g. --set max_bridge_s=0.5")
    parser.add_argument("--zeros-occluded", action="store_true",
                        help="read a mocap position of exactly (0, 0, 0) as occluded")
    parser.add_argument("--force", action="store_true",
                        help="track even when the recording fails kfusion check's consistency "
                        "tests (clock, mount, gravity)")


def run(args: argparse.Namespace) -> int:
    recording = read_recording(args.folder, zero_position_means_occluded=args.zeros_occluded)
    diagnosis = diagnose(recording)
    if not diagnosis.ok and not args.force:
        raise ValueError(f"{args.folder}: {diagnosis.problems[0]} (or pass --force)")
    result = track_recording(recording, args.method, **parse_options(args.options))
    path = write_track_csv(result, args.out)
    counts = {status: int(np.sum(result.status == status)) for status in STATUSES}
    summary = ", ".join(f"{count} {status}" for status, count in counts.items())
    print(f"{args.method}: wrote {len(result)} rows to {path} ({summary})")
    return 0
