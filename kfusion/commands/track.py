"""``kfusion track DIR --method NAME --out OUT.csv``: run an estimator over a recording folder.

With a folder of recording folders (one per body, as ``kfusion convert c3d --imu BODY=...``
writes), ``--out`` is a folder and each body's track is written to ``OUT/BODY.csv``
(:mod:`kfusion.bodies`).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
from pathlib import Path
from typing import Any

import numpy as np

from kfusion.bodies import TRACK_SUFFIX, body_folders, for_each_body
from kfusion.calibration.diagnosis import diagnose
from kfusion.config import check_methods
from kfusion.conventions import STATUSES
from kfusion.experiment import engine_options
from kfusion.guards import YamlError, load_yaml_text, refuse_overwriting, short_repr
from kfusion.kalman.engines import DEFAULT_ENGINE, ENGINES
from kfusion.methods import METHODS, track_with_method
from kfusion.recording import Recording, read_recording, recording_files
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


MARKER_METHODS = ("kalman", "smoother")
"""Methods with marker-level fusion (``--measurement markers``)."""


def track_engine(requested: str | None, measurement: str) -> str:
    """``--engine``: as requested, by default ``compiled``, except for marker-level fusion,
    which runs on ``filterpy`` (ValueError when ``compiled`` is asked for with it)."""
    if measurement == "markers":
        if requested == "compiled":
            raise ValueError("--engine compiled: marker-level fusion runs on the filterpy engine "
                             "only; leave --engine out or add --measurement body")
        return "filterpy"
    return requested or DEFAULT_ENGINE


def measurement_mode(recording: Recording, method: str, requested: str | None) -> str:
    """``--measurement``: as requested, or by default ``markers`` when the recording has them
    and the method fuses them (:func:`kfusion.kalman.batch.default_measurement`), else
    ``body``. ValueError for markers the method or the folder cannot give."""
    from kfusion.kalman.batch import BODY, MARKERS, default_measurement  # on use: filterpy

    if requested is None:
        return default_measurement(recording) if method in MARKER_METHODS else BODY
    if requested == MARKERS:
        if method not in MARKER_METHODS:
            raise ValueError(f"--measurement markers: method {method!r} fuses rigid bodies "
                             f"only; expected one of {list(MARKER_METHODS)}")
        if default_measurement(recording) != MARKERS:
            raise ValueError(f"--measurement markers: {recording.source or 'the folder'} needs "
                             "markers.csv and a markers: section in recording.yaml")
    return requested


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
    parser.add_argument("--measurement", choices=("markers", "body"), default=None,
                        help="kalman and smoother: fuse each visible marker of markers.csv "
                        "(markers) or the rigid body of mocap.csv (body) (default: markers when "
                        "the folder has markers.csv and recording.yaml has markers:, else body)")
    parser.add_argument("--engine", choices=ENGINES, default=None,
                        help="Kalman filter engine for --method kalman and smoother: compiled "
                        f"(numba; the default, {DEFAULT_ENGINE}, except with --measurement "
                        "markers, which runs on filterpy) or filterpy (the reference)")
    parser.add_argument("--zeros-occluded", action="store_true",
                        help="read a mocap position of exactly (0, 0, 0) as occluded")
    parser.add_argument("--force", action="store_true",
                        help="track even when the recording fails kfusion check's consistency "
                        "tests (clock, mount, gravity)")


def run(args: argparse.Namespace) -> int:
    bodies = body_folders(args.folder)
    if bodies:
        return track_bodies(args, bodies)
    if str(args.out).endswith(("/", os.sep)):
        # (a missing folder named so got a file of that name)
        raise ValueError(f"--out {args.out}: names a folder; expected a file (OUT.csv)")
    refuse_overwriting(args.out, recording_files(args.folder))
    recording = read_recording(args.folder, zero_position_means_occluded=args.zeros_occluded)
    options = parse_options(args.options, args.method)
    # the clock is tested as the filter will take it: with an overridden IMU latency
    latency = float(options.get("imu_latency_s", 0.0))
    diagnosis = diagnose(recording, imu_latency_s=latency)
    if not diagnosis.ok and not args.force:
        shifted = f" with imu_latency_s = {latency:g} s" if latency else ""
        raise ValueError(f"{args.folder}{shifted}: {diagnosis.problems[0]} (or pass --force)")
    measurement = measurement_mode(recording, args.method, args.measurement)
    engine = track_engine(args.engine, measurement)
    if args.method in MARKER_METHODS:
        options["measurement"] = measurement
    result = track_with_method(recording, args.method, **options,
                               **engine_options(args.method, engine))
    path = write_track_csv(result, args.out)
    counts = {status: int(np.sum(result.status == status)) for status in STATUSES}
    summary = ", ".join(f"{count} {status}" for status, count in counts.items())
    engine_text = f", engine: {engine}" if engine_options(args.method, engine) else ""
    print(f"{args.method}: wrote {len(result)} rows to {path} ({summary}; measurement: "
          f"{measurement}{engine_text})")
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

    failures = for_each_body(bodies, track_one, description="track",
                             output=lambda folder: out / f"{folder.name}{TRACK_SUFFIX}")
    print(f"{len(bodies) - len(failures)} of {len(bodies)} bodies tracked into {out}"
          + (f"; failed: {', '.join(failure.body for failure in failures)}" if failures else ""))
    return 2 if failures else 0
