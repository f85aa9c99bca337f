"""Where the mocap is occluded: gap lengths and placement.

A gap hides ``k`` consecutive mocap frames. Its length is measured as kfusion measures every
occlusion (:func:`kfusion.recording.occlusion_durations`): from the last visible frame before it
to the first visible frame after it, ``(k + 1) / rate``. Each gap's length is drawn uniformly from
``gap_range`` and rounded to whole frames inside that range.

Placements (the paper's two occlusion types, and a neutral one):

* ``"random"``: gaps anywhere, the free time shared out at random;
* ``"mid_motion"`` (Type 1): centred on a peak of speed of at least :data:`MOTION_SPEED`, the
  arm going up or down;
* ``"direction_change"`` (Type 2): centred on a minimum of speed where the motion turns by more
  than 90 degrees (the velocity 0.1 s before and 0.1 s after has a negative dot product), as when
  the arm changes from upward to downward. Stops with a rest in between do not count.

Spacing: before each gap, and after the last one, at least ``spacing`` s of visible mocap (from
the end of the previous gap, or from the start of the recording), so estimators can re-learn.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

PLACEMENTS = ("random", "mid_motion", "direction_change")
MOTION_SPEED = 0.5
"""m/s: a speed peak must reach this to host a ``mid_motion`` gap."""
TURN_WINDOW = 0.1
"""s: velocities this far before and after a speed minimum are compared to detect a turn."""
FRAME_TOLERANCE = 1e-9
"""Slack when converting seconds to whole frames."""


@dataclass(frozen=True)
class OcclusionSpec:
    """How to occlude the simulated mocap.

    Attributes:
        gap_range: (min, max) length of each gap, s, drawn uniformly; 0 < min <= max.
        placement: ``"random"``, ``"mid_motion"`` (Type 1: at high speed) or
            ``"direction_change"`` (Type 2: at a velocity reversal / speed minimum).
        spacing: visible mocap required before each gap (and after the last), s; > 0.
        count: number of gaps; None places as many as fit with the spacing.
    """

    gap_range: tuple[float, float] = (0.1, 0.3)
    placement: str = "random"
    spacing: float = 1.5
    count: int | None = None

    def __post_init__(self) -> None:
        try:
            low, high = (float(v) for v in self.gap_range)
        except (TypeError, ValueError):
            raise ValueError(f"OcclusionSpec.gap_range: expected (min, max) in s, got "
                             f"{self.gap_range!r}") from None
        if not (math.isfinite(low) and math.isfinite(high) and 0 < low <= high):
            raise ValueError(f"OcclusionSpec.gap_range: expected 0 < min <= max (s), got "
                             f"{self.gap_range!r}")
        object.__setattr__(self, "gap_range", (low, high))
        if self.placement not in PLACEMENTS:
            raise ValueError(f"OcclusionSpec.placement: expected one of {list(PLACEMENTS)}, got "
                             f"{self.placement!r}")
        if not (isinstance(self.spacing, (int, float)) and math.isfinite(self.spacing)
                and self.spacing > 0):
            raise ValueError(f"OcclusionSpec.spacing: expected a positive number of seconds, got "
                             f"{self.spacing!r}")
        if self.count is not None and (not isinstance(self.count, (int, np.integer))
                                       or isinstance(self.count, bool) or self.count < 1):
            raise ValueError(f"OcclusionSpec.count: expected None or a positive integer, got "
                             f"{self.count!r}")


def gap_frame_limits(gap_range: tuple[float, float], rate: float) -> tuple[int, int]:
    """Fewest and most hidden frames k of a gap in ``gap_range`` s at ``rate`` Hz.

    A gap of k hidden frames lasts ``(k + 1) / rate``, so ``k + 1`` lies in
    ``[ceil(min rate), floor(max rate)]``, and k >= 1.
    """
    low, high = gap_range
    fewest = max(1, math.ceil(low * rate - FRAME_TOLERANCE) - 1)
    most = math.floor(high * rate + FRAME_TOLERANCE) - 1
    if most < fewest:
        raise ValueError(f"gap_range {gap_range} s holds no whole number of frames at {rate:g} Hz; "
                         f"expected a range containing a multiple of {1 / rate:g} s of at least "
                         f"{2 / rate:g} s")
    return fewest, most


def hidden_frames(lengths: NDArray[np.float64], rate: float, limits: tuple[int, int]
                  ) -> NDArray[np.int64]:
    """Hidden-frame counts for gap lengths (s): ``k = round(L rate) - 1``, kept inside limits."""
    counts = np.round(np.asarray(lengths, dtype=float) * rate).astype(np.int64) - 1
    return np.clip(counts, *limits)


def speed_peaks(velocity: NDArray[np.float64], minimum_speed: float = MOTION_SPEED
                ) -> NDArray[np.int64]:
    """Frames where the speed |v| (velocity (m, 3), m/s) has a local maximum >= minimum_speed."""
    speed = np.linalg.norm(velocity, axis=1)
    middle = speed[1:-1]
    peak = (middle >= speed[:-2]) & (middle > speed[2:]) & (middle >= minimum_speed)
    return np.flatnonzero(peak) + 1


def direction_changes(velocity: NDArray[np.float64], window: int) -> NDArray[np.int64]:
    """Frames where the speed has a local minimum and the velocity ``window`` frames before and
    after points in opposite half-spaces (``v[i - w] · v[i + w] < 0``)."""
    speed = np.linalg.norm(velocity, axis=1)
    index = np.arange(max(1, window), len(speed) - max(1, window))
    if index.size == 0:
        return index
    minimum = (speed[index] <= speed[index - 1]) & (speed[index] < speed[index + 1])
    turning = np.einsum("ij,ij->i", velocity[index - window], velocity[index + window]) < 0
    return index[minimum & turning]


def _random_gaps(m: int, gap_frames: NDArray[np.int64], spacing_frames: int,
                 count: int | None, rng: np.random.Generator) -> list[tuple[int, int]]:
    """Gaps anywhere: each needs ``spacing_frames + 1`` frames before it plus its own, and
    ``spacing_frames`` after the last; the leftover frames are shared out at random."""
    available = m - 1 - spacing_frames
    cost = np.cumsum(gap_frames + spacing_frames + 1)
    fits = int(np.searchsorted(cost, available, side="right"))
    if count is not None:
        if count > fits:
            raise ValueError(f"OcclusionSpec.count: {count} gaps requested but only {fits} fit "
                             f"in {m} frames with the required spacing")
        fits = count
    if fits == 0:
        return []
    slack = available - int(cost[fits - 1])
    cuts = np.sort(rng.integers(0, slack + 1, size=fits))
    extra = np.diff(np.concatenate([[0], cuts]))
    gaps = []
    previous = 0
    for frames, shift in zip(gap_frames[:fits], extra, strict=True):
        first = previous + spacing_frames + 1 + int(shift)
        gaps.append((first, first + int(frames)))
        previous = first + int(frames)
    return gaps


def _centred_gaps(m: int, centres: NDArray[np.int64], gap_frames: NDArray[np.int64],
                  spacing_frames: int, count: int | None, rng: np.random.Generator
                  ) -> list[tuple[int, int]]:
    """Gaps centred on candidate frames, taken in time order whenever the spacing allows
    (which fits the most); with ``count``, a random subset of those."""
    gaps: list[tuple[int, int]] = []
    previous = 0
    for centre, frames in zip(centres, gap_frames, strict=True):
        first = int(centre) - int(frames) // 2
        stop = first + int(frames)
        if first - 1 - previous >= spacing_frames and m - 1 - stop >= spacing_frames:
            gaps.append((first, stop))
            previous = stop
    if count is not None:
        if count > len(gaps):
            raise ValueError(f"OcclusionSpec.count: {count} gaps requested but only {len(gaps)} "
                             "fit at the chosen placement with the required spacing")
        chosen = np.sort(rng.choice(len(gaps), size=count, replace=False))
        gaps = [gaps[i] for i in chosen]
    return gaps


def place_occlusions(t: NDArray[np.float64], velocity: NDArray[np.float64], spec: OcclusionSpec,
                     rng: np.random.Generator) -> NDArray[np.bool_]:
    """Occluded mask (m,) for mocap frames at times ``t`` (m,) s, uniformly spaced, given the
    true velocity (m, 3) m/s at those frames. Raises ValueError when no gap fits."""
    t = np.asarray(t, dtype=float)
    m = t.shape[0]
    rate = (m - 1) / (t[-1] - t[0])
    limits = gap_frame_limits(spec.gap_range, rate)
    spacing_frames = math.ceil(spec.spacing * rate - FRAME_TOLERANCE)
    if spec.placement == "random":
        most = max(1, m // (spacing_frames + 1 + limits[0]) + 1)
        lengths = rng.uniform(*spec.gap_range, size=most)
        gaps = _random_gaps(m, hidden_frames(lengths, rate, limits), spacing_frames, spec.count,
                            rng)
    else:
        if spec.placement == "mid_motion":
            centres = speed_peaks(velocity)
        else:
            centres = direction_changes(velocity, max(1, round(TURN_WINDOW * rate)))
        lengths = rng.uniform(*spec.gap_range, size=len(centres))
        gaps = _centred_gaps(m, centres, hidden_frames(lengths, rate, limits), spacing_frames,
                             spec.count, rng)
    if not gaps:
        found = "" if spec.placement == "random" else f" ({len(centres)} candidate frames)"
        raise ValueError(f"no occlusion fits: placement {spec.placement!r}{found} with gaps of "
                         f"{spec.gap_range} s and {spec.spacing} s spacing in {t[-1] - t[0]:.3g} s "
                         "of mocap; expected a longer duration, a shorter spacing or another "
                         "placement")
    occluded = np.zeros(m, dtype=bool)
    for first, stop in gaps:
        occluded[first:stop] = True
    return occluded
