"""Are real mocap frames next to an occlusion worse than the others? Prints a table.

On every BROAD trial (all frames, ~285 Hz), each frame's position is compared with a cubic
fitted to the visible frames 4 to 15 before it (``pre``: frames 1-3 before an occlusion) or 4 to
15 after it (``post``: frames 1-3 after one), extrapolated to the frame's time. The same is done
for 300 randomly chosen frames per trial whose 16 preceding frames are visible (``interior``;
``np.random.default_rng(0)``). The deviation includes the extrapolation's own error, the same
for every group, so the groups are compared with each other, not with zero.

This is the evidence behind the fail-safe benchmark's occlusion-edge rows
(:func:`kfusion.simulate.faults.occlusion_edge_offsets`): a rigid body solved while its
markers disappear or re-appear may be off by more than the mocap noise.

Run: ``python benchmarks/occlusion_edges.py`` (about 10 s; needs ``../shared/data/broad``).
"""

from __future__ import annotations

import sys

import numpy as np
from numpy.typing import NDArray

from kfusion.datasets import broad_trials
from kfusion.readers.broad import read_broad
from kfusion.recording import occlusion_runs

FIT_NEAR, FIT_FAR = 4, 15  # frames used for the cubic: FIT_NEAR .. FIT_FAR away
EDGE_FRAMES = 3
INTERIOR_PER_TRIAL = 300


def extrapolation_deviation(t: NDArray[np.float64], position: NDArray[np.float64],
                            visible: NDArray[np.bool_], row: int, side: int) -> float | None:
    """|p(row) - c(t_row)| in mm, c the least-squares cubic through the frames ``FIT_NEAR`` to
    ``FIT_FAR`` before (``side`` -1) or after (+1) ``row``; None when any is missing."""
    offsets = np.arange(FIT_NEAR, FIT_FAR + 1)
    rows = row - offsets[::-1] if side < 0 else row + offsets
    if rows.min() < 0 or rows.max() >= len(t) or not visible[rows].all():
        return None
    coefficients = np.polyfit(t[rows] - t[row], position[rows], 3)
    return 1000.0 * float(np.linalg.norm(coefficients[-1] - position[row]))


def main() -> int:
    try:
        paths = broad_trials()
    except (ValueError, FileNotFoundError) as error:
        print(f"occlusion_edges: {error}", file=sys.stderr)
        return 2
    groups: dict[str, list[float]] = {name: [] for name in
                                      ("pre 1", "pre 2", "pre 3", "post 1", "post 2", "post 3",
                                       "interior")}
    occlusions = 0
    rng = np.random.default_rng(0)
    for path in paths:
        mocap = read_broad(path, mocap_step=1).mocap
        t, position = np.asarray(mocap.t), np.asarray(mocap.position)
        visible = np.asarray(mocap.visible)
        runs = occlusion_runs(visible)
        occlusions += len(runs)
        for start, stop in runs:
            for k in range(1, EDGE_FRAMES + 1):
                edges = ((f"pre {k}", start - k, -1), (f"post {k}", stop + k - 1, 1))
                for name, row, side in edges:
                    if 0 <= row < len(t) and visible[row]:
                        value = extrapolation_deviation(t, position, visible, row, side)
                        if value is not None:
                            groups[name].append(value)
        for row in rng.choice(np.arange(FIT_FAR + 1, len(t)), INTERIOR_PER_TRIAL, replace=False):
            if visible[row]:
                value = extrapolation_deviation(t, position, visible, int(row), -1)
                if value is not None:
                    groups["interior"].append(value)
    print(f"BROAD, {len(paths)} trials, {occlusions} occlusions: deviation of a frame from the "
          f"cubic through the frames {FIT_NEAR}-{FIT_FAR} away, mm\n")
    print("| frames | n | median | 90th percentile | 99th percentile |\n|---|---|---|---|---|")
    for name, values in groups.items():
        if values:
            array = np.array(values)
            print(f"| {name} | {len(array)} | {np.median(array):.2f} | "
                  f"{np.quantile(array, 0.9):.2f} | {np.quantile(array, 0.99):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
