"""Scoring gap filling: cut artificial gaps into real recordings and measure errors inside gaps.

Definitions used in every table kfusion prints:

* a *gap sample* is a mocap row hidden from the estimator whose true position is known (the
  simulator's truth, or the hidden mocap of a real recording);
* the *error* of a sample is ``e = estimate - truth`` (m, global frame) and its size ``|e|``;
* ``rms_mm = 1000 sqrt(mean |e|^2)`` and ``max_mm = 1000 max |e|`` over gap samples;
  ``p95_mm`` (``kfusion score``) is the 95th percentile of ``1000 |e|`` (linear interpolation);
* ``coverage_3sigma`` is the fraction of gap samples with ``|e_i| <= 3 std_i`` on every axis
  i = x, y, z (for a calibrated Gaussian estimate, 0.9973^3 = 0.992 is expected); NaN for
  methods without an uncertainty;
* a gap sample whose status is ``lost`` has no estimate: it counts in ``lost_fraction`` and not
  in the error statistics.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from kfusion.conventions import LOST
from kfusion.recording import MarkerFrames, MocapFrames, Recording, occlusion_runs
from kfusion.track_file import TrackResult


@dataclass(frozen=True)
class GappedRecording:
    """A real recording with artificial gaps cut where the mocap was valid.

    Attributes:
        recording: the recording with the gap rows' mocap set to NaN (occluded).
        truth_position: (m, 3) the hidden mocap positions (NaN where the original was occluded).
        gap_mask: (m,) True on rows inside an artificial gap.
    """

    recording: Recording
    truth_position: NDArray[np.float64]
    gap_mask: NDArray[np.bool_]


def cut_gaps(
    recording: Recording,
    *,
    rng: np.random.Generator,
    gap_range: tuple[float, float] = (0.1, 0.3),
    spacing: float = 1.0,
    count: int | None = None,
) -> GappedRecording:
    """Hide runs of valid mocap frames to score gap filling against the hidden positions.

    Gaps are placed from the start of the recording onwards. Each gap's length L is drawn
    uniformly from ``gap_range`` (s), and hides the frames with ``start < t <= start + L``. A gap
    is only cut where the original mocap is visible for ``spacing`` seconds before it, through it,
    and on the frame after it (so estimators learn before and re-acquire after); after each gap
    the next candidate start is at least ``spacing`` s later, plus a uniform random offset in
    ``[0, spacing]`` so gaps do not fall on a fixed rhythm.

    Args:
        recording: the recording to cut.
        rng: random generator (seeded by the caller).
        gap_range: (min, max) gap length, s; 0 < min <= max.
        spacing: visible time required before each gap, s; > 0.
        count: maximum number of gaps (None: as many as fit).
    """
    low, high = gap_range
    if not 0 < low <= high:
        raise ValueError(f"gap_range: expected 0 < min <= max, got {gap_range}")
    if spacing <= 0:
        raise ValueError(f"spacing: expected a positive number of seconds, got {spacing}")
    mocap = recording.mocap
    t = mocap.t
    visible = mocap.visible
    # time of the most recent invalid frame at or before each row (-inf if none)
    invalid_time = np.where(~visible, t, -np.inf)
    last_invalid = np.maximum.accumulate(invalid_time)

    gap_mask = np.zeros(len(t), dtype=bool)
    cursor = t[0] + spacing
    gaps = 0
    while count is None or gaps < count:
        length = rng.uniform(low, high)
        start = cursor + rng.uniform(0.0, spacing)
        first = int(np.searchsorted(t, start, side="right"))
        stop = int(np.searchsorted(t, start + length, side="right"))  # one past the last hidden
        if stop >= len(t) or first >= stop:
            break
        # the frame after the gap must be visible, and everything from start-spacing to it
        if last_invalid[stop] >= t[first] - spacing:
            cursor = max(cursor, last_invalid[stop] + spacing)
            continue
        gap_mask[first:stop] = True
        gaps += 1
        cursor = t[stop] + spacing

    return hide_frames(recording, gap_mask)


def hide_frames(recording: Recording, gap_mask: NDArray[np.bool_]) -> GappedRecording:
    """``recording`` with the mocap rows where ``gap_mask`` (m,) is True hidden (position and
    quaternion NaN, and every marker of them when the markers share the mocap's stamps), the
    hidden positions kept as the truth (NaN where the mocap was not visible). The last step of
    :func:`cut_gaps`, for gaps placed another way."""
    mocap = recording.mocap
    t = mocap.t
    position = np.where(gap_mask[:, None], np.nan, mocap.position)
    quaternion = np.where(gap_mask[:, None], np.nan, mocap.quaternion)
    gapped = recording.with_mocap(MocapFrames(t=t, position=position, quaternion=quaternion))
    markers = recording.markers
    if markers is not None and np.array_equal(markers.t, t):  # a cut gap hides every marker
        gapped = dataclasses.replace(gapped, markers=MarkerFrames(
            t=markers.t, names=markers.names,
            position=np.where(gap_mask[:, None, None], np.nan, markers.position)))
    truth = np.where(mocap.visible[:, None], mocap.position, np.nan)
    return GappedRecording(recording=gapped, truth_position=truth, gap_mask=gap_mask)


@dataclass(frozen=True)
class GapErrors:
    """Per-sample errors inside gaps.

    Attributes:
        error: (k, 3) estimate - truth, m, for gap samples with an estimate.
        std: (k, 3) the estimator's 1-sigma per axis, m (NaN if it gives none).
        lost: number of gap samples with status lost (not in ``error``).
    """

    error: NDArray[np.float64]
    std: NDArray[np.float64]
    lost: int

    @staticmethod
    def concatenate(parts: Iterable[GapErrors]) -> GapErrors:
        """Pool several runs' gap errors."""
        parts = list(parts)
        if not parts:
            return GapErrors(np.empty((0, 3)), np.empty((0, 3)), 0)
        return GapErrors(
            error=np.concatenate([p.error for p in parts]),
            std=np.concatenate([p.std for p in parts]),
            lost=sum(p.lost for p in parts),
        )


def gap_errors(result: TrackResult, truth_position: NDArray, gap_mask: NDArray) -> GapErrors:
    """Errors of ``result`` on rows where ``gap_mask`` is True and the truth is known.

    Shapes: ``truth_position`` (m, 3) in m, ``gap_mask`` (m,) with m = len(result).
    """
    truth_position = np.asarray(truth_position, dtype=float)
    gap_mask = np.asarray(gap_mask, dtype=bool)
    if truth_position.shape != (len(result), 3) or gap_mask.shape != (len(result),):
        raise ValueError(
            f"expected truth_position ({len(result)}, 3) and gap_mask ({len(result)},), got "
            f"{truth_position.shape} and {gap_mask.shape}"
        )
    known = gap_mask & np.isfinite(truth_position).all(axis=1)
    lost = known & (np.asarray(result.status) == LOST)
    scored = known & ~lost
    return GapErrors(
        error=result.position[scored] - truth_position[scored],
        std=np.asarray(result.std, dtype=float)[scored],
        lost=int(lost.sum()),
    )


def metrics_from_errors(errors: GapErrors) -> dict[str, float]:
    """Summary statistics of gap errors (see the module docstring for definitions)."""
    samples = errors.error.shape[0]
    total = samples + errors.lost
    if samples == 0:
        return {"samples": 0.0, "rms_mm": np.nan, "max_mm": np.nan, "mean_mm": np.nan,
                "coverage_3sigma": np.nan, "lost_fraction": 1.0 if total else np.nan}
    size = np.linalg.norm(errors.error, axis=1)
    if np.isnan(errors.std).any():
        coverage = np.nan
    else:
        coverage = float(np.mean((np.abs(errors.error) <= 3 * errors.std).all(axis=1)))
    return {
        "samples": float(samples),
        "rms_mm": 1000 * float(np.sqrt(np.mean(size**2))),
        "max_mm": 1000 * float(size.max()),
        "mean_mm": 1000 * float(size.mean()),
        "coverage_3sigma": coverage,
        "lost_fraction": errors.lost / total,
    }


def error_percentile_mm(errors: GapErrors, percent: float) -> float:
    """The ``percent``-th percentile of the error sizes ``1000 |e|``, mm (NaN without samples)."""
    if errors.error.shape[0] == 0:
        return float("nan")
    return 1000 * float(np.percentile(np.linalg.norm(errors.error, axis=1), percent))


def gap_metrics(result: TrackResult, truth_position: NDArray, gap_mask: NDArray
                ) -> dict[str, float]:
    """:func:`metrics_from_errors` of :func:`gap_errors` for one run."""
    return metrics_from_errors(gap_errors(result, truth_position, gap_mask))


def per_gap_errors(result: TrackResult, truth_position: NDArray, gap_mask: NDArray
                   ) -> pd.DataFrame:
    """One row per gap: start (s), duration (s, from the last fix before to the first after),
    samples, rms_mm, max_mm, coverage_3sigma, lost_fraction."""
    rows = []
    t = np.asarray(result.t, dtype=float)
    for start, stop in occlusion_runs(~np.asarray(gap_mask, dtype=bool)):
        mask = np.zeros(len(t), dtype=bool)
        mask[start:stop] = True
        metrics = gap_metrics(result, truth_position, mask)
        before = t[start - 1] if start > 0 else t[start]
        after = t[stop] if stop < len(t) else t[stop - 1]
        rows.append({"gap_start_s": t[start], "duration_s": after - before, **metrics})
    return pd.DataFrame(rows)
