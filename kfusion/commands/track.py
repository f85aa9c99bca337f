"""``kfusion track DIR --method NAME --out OUT.csv``: run an estimator over a recording folder.

With a folder of recording folders (one per body, as ``kfusion convert c3d --imu BODY=...``
writes), ``--out`` is a folder and each body's track is written to ``OUT/BODY.csv``
(:mod:`kfusion.bodies`).
"""

from __future__ import annotations

import argparse
import contextlib
import io
from pathlib import Path
from typing import Any

import numpy as np

from kfusion.bodies import TRACK_SUFFIX, body_folders, for_each_body
from kfusion.calibration.diagnosis import diagnose
from kfusion.config import check_methods
from kfusion.conventions import STATUSES
from kfusion.guards import YamlError, load_yaml_text, short_repr
from kfusion.methods import METHODS, track_with_method
from kfusion.recording import read_recording
from kfusion.track_file import write_track_csv

NAME = "track"
HELP = "Estimate the position at every mocap row of a recording and write the track CSV."
ORDER = 30


def parse_options(pairs: list[str] | None, method: str | None = None) -> dict[str, Any]:
    """``["key=value", ...]`` -> dict, values read as YAML scalars (numbers, true/false, null)
    by the bounded loader. With ``method``, each value is checked and converted to its field's
    type (``1e-3`` -> 0.001) as a config's overrides are; ValueError naming ``--set KEY``."""
    options: dict[str, Any] = {}
    for pair in pairs or []:
        key, separator, value = pair.partition("=")
        key = key.strip()
        if not separator or not key:
            raise ValueError(f"--set: expected KEY=VALUE, got {short_repr(pair)}")
        try:
            options[key] = load_yaml_text(value, f"--set {key}")
        except YamlError as error:
            raise ValueError(f"--set {short_repr(key).strip(chr(39))}: expected a number, "
                             f"true/false or null, got {short_repr(value)} ({error.reason})"
                             ) from None
    if method is None or not options:
        return options
    converted, issues = check_methods({method: options})
    if issues:
        prefix = f"methods.{method}"
        raise ValueError("; ".join(
            f"--set {issue.path.removeprefix(prefix + '.')}: {issue.message}"
            if issue.path.startswith(prefix + ".") else f"--set: {issue.message}"
            for issue in issues))
    return converted[method]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("folder", metavar="DIR", help="recording folder, or a folder of "
                        "recording folders (one per body: then --out is a folder and each "
                        "body's track is OUT/BODY.csv)")
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
    bodies = body_folders(args.folder)
    if bodies:
        return track_bodies(args, bodies)
    recording = read_recording(args.folder, zero_position_means_occluded=args.zeros_occluded)
    diagnosis = diagnose(recording)
    if not diagnosis.ok and not args.force:
        raise ValueError(f"{args.folder}: {diagnosis.problems[0]} (or pass --force)")
    result = track_with_method(recording, args.method, **parse_options(args.options, args.method))
    path = write_track_csv(result, args.out)
    counts = {status: int(np.sum(result.status == status)) for status in STATUSES}
    summary = ", ".join(f"{count} {status}" for status, count in counts.items())
    print(f"{args.method}: wrote {len(result)} rows to {path} ({summary})")
    return 0


def track_bodies(args: argparse.Namespace, bodies: list[Path]) -> int:
    """Run the single-folder ``track`` on each body folder, writing ``--out/BODY.csv``; a body
    that fails is reported and the others complete (exit 2 if any failed)."""
    out = Path(args.out)
    if out.suffix.lower() == TRACK_SUFFIX or out.is_file():
        raise ValueError(f"--out {out}: {args.folder} is a folder of {len(bodies)} bodies "
                         f"({', '.join(body.name for body in bodies)}); expected an output "
                         "folder (one BODY.csv per body)")
    out.mkdir(parents=True, exist_ok=True)

    def track_one(folder: Path) -> str:
        output = io.StringIO()
        with contextlib.redirect_stdout(output):
            run(argparse.Namespace(**{**vars(args), "folder": str(folder),
                                      "out": str(out / f"{folder.name}{TRACK_SUFFIX}")}))
        return f"body {folder.name}: {output.getvalue().strip()}"

    failures = for_each_body(bodies, track_one, description="track")
    print(f"{len(bodies) - len(failures)} of {len(bodies)} bodies tracked into {out}"
          + (f"; failed: {', '.join(failure.body for failure in failures)}" if failures else ""))
    return 2 if failures else 0
