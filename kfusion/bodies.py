"""Several bodies: a folder of recording folders, one per body, and their tracks.

``kfusion convert c3d ... --imu BODY=IMU.csv ...`` writes one recording folder per body under one
folder; ``kfusion track FOLDER --out TRACKS`` then writes ``TRACKS/BODY.csv`` for each, and
:func:`read_body_tracks` reads them back as the input of
:func:`kfusion.safety.binding_margins`. A body that fails is reported by name and the others
still complete (:func:`for_each_body`); each track is written atomically, so an interruption
keeps every finished track and leaves no partial file.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from kfusion.recording import IMU_FILE, META_FILE, MOCAP_FILE
from kfusion.track_file import TrackResult, read_track

RECORDING_FILES = (IMU_FILE, MOCAP_FILE, META_FILE)
"""A folder holding any of these is a recording, not a folder of recordings."""
TRACK_SUFFIX = ".csv"


def is_recording(folder: Path) -> bool:
    """True when ``folder`` holds a recording's file (``imu.csv``, ``mocap.csv`` or
    ``recording.yaml``)."""
    return any((folder / name).is_file() for name in RECORDING_FILES)


def body_folders(folder: str | Path) -> list[Path]:
    """The recording sub-folders of a folder of bodies, sorted by name; empty when ``folder``
    is itself a recording (or not a folder)."""
    folder = Path(folder)
    if not folder.is_dir() or is_recording(folder):
        return []
    return sorted(child for child in folder.iterdir()
                  if child.is_dir() and not child.name.startswith(".") and is_recording(child))


@dataclass(frozen=True)
class BodyFailure:
    """A body whose run failed: its name and the one-line reason."""

    body: str
    reason: str


def for_each_body(folders: Sequence[Path], action: Callable[[Path], str], *,
                  description: str, progress: bool | None = None,
                  output: Callable[[Path], Path] | None = None) -> list[BodyFailure]:
    """Run ``action`` on each body folder in turn; a body that fails does not stop the others.

    ``action(folder)`` returns a line to print (stdout). A user mistake in one body (ValueError,
    OSError) is printed to stderr as ``body NAME: error: ...`` and returned; anything else (a
    bug, KeyboardInterrupt) stops the loop, after printing which bodies were done. ``progress``
    shows a tqdm bar over the bodies on stderr (None: only on a terminal). ``output(folder)``,
    when given, is the file the action writes for that body: when the body fails, an older file
    there (from an earlier run) is removed and the failure line says so, so that it is never read
    afterwards as if it were this run's result.
    """
    from tqdm import tqdm

    from kfusion.cli import error_line

    failures: list[BodyFailure] = []
    done: list[str] = []
    with tqdm(folders, desc=description, unit="body",
              disable=None if progress is None else not progress, file=sys.stderr,
              leave=False) as bar:
        for folder in bar:
            bar.set_postfix_str(folder.name)
            try:
                line = action(folder)
            except (ValueError, OSError) as error:
                reason = error_line(error)
                stale = None if output is None else output(folder)
                if stale is not None and stale.is_file():
                    stale.unlink()
                    reason += f"; removed its out-of-date {stale}"
                failures.append(BodyFailure(folder.name, reason))
                tqdm.write(f"body {folder.name}: error: {failures[-1].reason}", file=sys.stderr)
                continue
            except BaseException:
                finished = ", ".join(done) or "none"
                tqdm.write(f"stopped at body {folder.name}; finished: {finished}",
                           file=sys.stderr)
                raise
            done.append(folder.name)
            tqdm.write(line, file=sys.stdout)
    return failures


def read_body_tracks(folder: str | Path) -> dict[str, TrackResult]:
    """Every ``BODY.csv`` track in ``folder`` (as ``kfusion track`` writes for a folder of
    bodies), by body name, sorted. ValueError when there is none."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder; expected the folder of tracks kfusion track "
                         "wrote for a folder of bodies")
    paths = sorted(folder.glob(f"*{TRACK_SUFFIX}"))
    if not paths:
        raise ValueError(f"{folder}: no {TRACK_SUFFIX} track; expected one BODY.csv per body")
    return {path.stem: read_track(path) for path in paths}
