"""The estimator output: one row per mocap row, and the ``kfusion track`` CSV format.

Columns (stable: other tools read them): ``t, x, y, z, std_x, std_y, std_z, status``.

* ``t`` equals the mocap row's time, s;
* ``x, y, z`` the position estimate, m, global frame; empty where ``status`` is ``lost``;
* ``std_x, std_y, std_z`` the 1-sigma uncertainty per axis, m; empty where a method has none;
* ``status`` is ``tracked`` (the mocap fix at this row was used), ``bridged`` (estimate inside a
  gap) or ``lost`` (no estimate: before the first fix or past the bridging horizon).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    import pandas as pd

from kfusion.conventions import LOST, STATUSES, TRACK_COLUMNS
from kfusion.guards import atomic_write
from kfusion.recording import RecordingError


def bounded_rows(status: NDArray[np.str_], variance: NDArray[np.float64]
                 ) -> tuple[NDArray[np.str_], NDArray[np.float64]]:
    """(status (m,), std (m, 3) m) of rows with per-axis variances ``variance`` (m, 3) m^2: a
    row whose variance is not a finite number >= 0 on every axis has no bound and is ``lost``
    (a filter's covariance rounded below zero, or overflowed, is no promise); the std of a lost
    row is NaN (never the square root of a negative number)."""
    variance = np.asarray(variance, dtype=float)
    usable = np.isfinite(variance).all(axis=1) & (variance >= 0.0).all(axis=1)
    usable &= np.asarray(status) != LOST
    std = np.full(variance.shape, np.nan)
    std[usable] = np.sqrt(variance[usable])
    return np.where(usable, status, LOST).astype(str), std


@dataclass(frozen=True)
class TrackResult:
    """An estimator's output at the mocap timestamps.

    Attributes:
        t: (m,) times, s (the mocap rows' times).
        position: (m, 3) estimate, m, global frame; NaN where lost.
        std: (m, 3) 1-sigma per axis, m; NaN where the method gives none or where lost.
        status: (m,) strings from :data:`kfusion.conventions.STATUSES`.
        time_since_fix: (m,) s since the last accepted mocap fix (inf before the first).
        method: name of the method that produced it.
    """

    t: NDArray[np.float64]
    position: NDArray[np.float64]
    std: NDArray[np.float64]
    status: NDArray[np.str_]
    time_since_fix: NDArray[np.float64]
    method: str = ""

    def __post_init__(self) -> None:
        m = np.asarray(self.t).shape[0]
        shapes = {"position": (m, 3), "std": (m, 3), "status": (m,), "time_since_fix": (m,)}
        for name, shape in shapes.items():
            if np.shape(getattr(self, name)) != shape:
                raise ValueError(f"TrackResult.{name}: expected shape {shape}, "
                                 f"got {np.shape(getattr(self, name))}")
        unknown = set(np.unique(self.status)) - set(STATUSES)
        if unknown:
            raise ValueError(f"TrackResult.status: expected values in {STATUSES}, got {unknown}")
        # a lost row has no estimate, whatever the method left in its arrays
        lost = (np.asarray(self.status) == LOST)[:, None]
        object.__setattr__(self, "position", np.where(lost, np.nan, self.position))
        object.__setattr__(self, "std", np.where(lost, np.nan, np.asarray(self.std, float)))

    def __len__(self) -> int:
        return int(np.asarray(self.t).shape[0])

    def to_frame(self) -> pd.DataFrame:
        """The ``kfusion track`` table as a DataFrame (NaN where a cell is empty)."""
        import pandas as pd  # on first use: `import kfusion.tracker` stays light

        frame = pd.DataFrame(np.column_stack([self.t, self.position, self.std]),
                             columns=TRACK_COLUMNS[:7])
        frame["status"] = np.asarray(self.status, dtype=str)
        return frame


def write_track_csv(result: TrackResult, path: str | Path) -> Path:
    """Write the ``kfusion track`` CSV atomically (:func:`kfusion.guards.atomic_write`: a failed
    write leaves any previous file intact). Empty cells for NaN. Returns the path."""
    frame = result.to_frame()
    return atomic_write(path, lambda temporary: frame.to_csv(temporary, index=False, na_rep=""))


def read_track(path: str | Path) -> TrackResult:
    """A ``kfusion track`` CSV as a :class:`TrackResult` (``time_since_fix`` is not in the file:
    NaN). :class:`~kfusion.recording.RecordingError` naming the file, row and column of a
    non-numeric cell or an unknown status."""
    import pandas as pd  # on first use: `import kfusion.tracker` stays light

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: file not found; expected a kfusion track CSV")
    frame = pd.read_csv(path)
    missing = [c for c in TRACK_COLUMNS if c not in frame.columns]
    if missing:
        raise ValueError(f"{path}: missing column(s) {missing}; expected {list(TRACK_COLUMNS)}")
    frame = frame[list(TRACK_COLUMNS)]
    numbers = frame[list(TRACK_COLUMNS[:7])].apply(pd.to_numeric, errors="coerce")
    bad = numbers.isna().to_numpy() & frame[list(TRACK_COLUMNS[:7])].notna().to_numpy()
    bad[:, 0] |= numbers["t"].isna().to_numpy()
    if bad.any():
        row, column = np.argwhere(bad)[0]
        raise RecordingError(path.name, f"expected a number, got {frame.iat[row, column]!r}",
                             row=int(row) + 1, column=TRACK_COLUMNS[column])
    status = frame["status"].astype(str).to_numpy()
    unknown = ~np.isin(status, STATUSES)
    if unknown.any():
        row = int(np.flatnonzero(unknown)[0])
        raise RecordingError(path.name, f"expected one of {list(STATUSES)}, got {status[row]!r}",
                             row=row + 1, column="status")
    values = numbers.to_numpy(dtype=float)
    return TrackResult(t=values[:, 0], position=values[:, 1:4], std=values[:, 4:7],
                       status=status, time_since_fix=np.full(len(values), np.nan))
