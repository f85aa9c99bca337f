"""``kfusion score TRACK.csv TRUTH.csv`` (or ``DIR`` holding ``truth.csv``): gap errors of a track.

The track is a ``kfusion track`` CSV; the truth is ``t, x, y, z, occluded`` (the format of the
simulator's ``truth.csv``, one row per mocap row, ``occluded`` 1 where the mocap was hidden).
Gap samples are the truth rows flagged occluded; each is matched to the track row with the same
``t`` (within :data:`TIME_TOLERANCE_S`). Printed: samples, lost, RMS, max, 95th percentile and
3-sigma coverage (definitions in :mod:`kfusion.evaluate`).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

NAME = "score"
HELP = "Score a track CSV against a truth file: gap RMS, max, p95 and 3-sigma coverage."
ORDER = 35

TIME_TOLERANCE_S = 1e-6
"""s: a truth row and a track row closer in time than this are the same mocap row."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("track", metavar="TRACK.csv", help="output of kfusion track")
    parser.add_argument("truth", metavar="TRUTH",
                        help="truth CSV (t, x, y, z, occluded), or a recording folder holding "
                        "truth.csv (kfusion simulate writes one)")


def truth_file(argument: str) -> Path:
    """The truth CSV named by ``argument``: the file itself, or ``truth.csv`` in a folder."""
    from kfusion.recording import TRUTH_FILE

    path = Path(argument)
    return path / TRUTH_FILE if path.is_dir() else path


def matching_rows(track_t: NDArray[np.float64], truth_t: NDArray[np.float64], truth_name: str
                  ) -> NDArray[np.intp]:
    """Index of the track row at each truth time; ValueError naming the first truth row that
    has none (the track must come from the same recording)."""
    import numpy as np

    from kfusion.recording import RecordingError

    truth_t = np.asarray(truth_t, dtype=float)
    track_t = np.asarray(track_t, dtype=float)
    index = np.clip(np.searchsorted(track_t, truth_t), 1, max(len(track_t) - 1, 1))
    before = np.abs(track_t[index - 1] - truth_t)
    after = np.abs(track_t[np.minimum(index, len(track_t) - 1)] - truth_t)
    nearest = np.where(before <= after, index - 1, np.minimum(index, len(track_t) - 1))
    missing = np.abs(track_t[nearest] - truth_t) > TIME_TOLERANCE_S
    if missing.any():
        row = int(np.flatnonzero(missing)[0])
        raise RecordingError(truth_name, f"t = {float(truth_t[row])!r} s has no track row within "
                             f"{TIME_TOLERANCE_S:g} s; expected the track of the same recording "
                             "(kfusion track DIR --out TRACK.csv)", row=row + 1, column="t")
    return nearest


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from kfusion.evaluate import error_percentile_mm, gap_errors, metrics_from_errors
    from kfusion.simulate.files import read_truth
    from kfusion.track_file import read_track

    track = read_track(args.track)
    path = truth_file(args.truth)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: file not found; expected a truth CSV (t, x, y, z, "
                                "occluded) or a recording folder holding truth.csv")
    truth = read_truth(path)
    rows = matching_rows(track.t, truth.t, path.name)
    truth_position = np.full((len(track), 3), np.nan)
    truth_position[rows] = truth.position
    gap_mask = np.zeros(len(track), dtype=bool)
    gap_mask[rows] = truth.occluded
    errors = gap_errors(track, truth_position, gap_mask)
    metrics = metrics_from_errors(errors)
    coverage = metrics["coverage_3sigma"]
    print(f"score: {args.track} against {path}")
    print(f"gap samples: {int(metrics['samples'])} scored, {errors.lost} lost "
          f"(of {int(gap_mask.sum())} occluded rows; {len(track)} track rows)")
    if metrics["samples"] == 0:
        print("no gap sample has an estimate: nothing to score")
        return 0
    print(f"rms {metrics['rms_mm']:.2f} mm, max {metrics['max_mm']:.2f} mm, "
          f"p95 {error_percentile_mm(errors, 95):.2f} mm")
    print("coverage 3-sigma: " + ("n/a (the track has no std columns)" if np.isnan(coverage)
                                  else f"{100 * coverage:.1f} % of scored gap samples"))
    return 0
