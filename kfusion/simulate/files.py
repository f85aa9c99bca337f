"""Writing a simulation to disk: a recording folder plus ``truth.csv``.

``truth.csv`` has one row per mocap frame: ``t, x, y, z, occluded`` (s, m in the global frame,
the true rigid-body position; ``occluded`` is 1 where the mocap frame is hidden, else 0).
Readers of recordings ignore it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from kfusion.conventions import TRUTH_COLUMNS
from kfusion.guards import atomic_write
from kfusion.recording import TRUTH_FILE, RecordingError, write_recording
from kfusion.simulate.simulation import Simulation, Truth


def write_simulation(simulation: Simulation, folder: str | Path) -> Path:
    """Write the recording folder and ``truth.csv`` into ``folder`` (created); returns it."""
    folder = write_recording(simulation.recording, folder)
    truth = simulation.truth
    frame = pd.DataFrame(np.column_stack([truth.t, truth.position]),
                         columns=list(TRUTH_COLUMNS[:4]))
    frame[TRUTH_COLUMNS[4]] = truth.occluded.astype(int)
    # floats are written with repr(), so they read back exactly
    atomic_write(folder / TRUTH_FILE, lambda temporary: frame.to_csv(temporary, index=False))
    return folder


def read_truth(source: str | Path) -> Truth:
    """Read ``truth.csv``: ``source`` is a simulated recording folder or the CSV itself.

    Returns a :class:`Truth` with ``t``, ``position`` and ``occluded``; the other fields are None.
    Raises :class:`~kfusion.recording.RecordingError` if the file is missing or malformed.
    """
    path = Path(source)
    # a folder (or a path without a file suffix, taken as a folder) holds truth.csv
    path = path / TRUTH_FILE if path.is_dir() or not path.suffix else path
    name = path.name
    if not path.is_file():
        raise RecordingError(name, f"file not found in {path.parent}")
    try:
        table = pd.read_csv(path, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as error:
        raise RecordingError(name, f"cannot be parsed as CSV ({error})") from None
    table.columns = [str(c).strip() for c in table.columns]
    missing = [c for c in TRUTH_COLUMNS if c not in table.columns]
    if missing:
        raise RecordingError(name, f"missing column(s) {missing}; expected "
                             f"{list(TRUTH_COLUMNS)}, found {list(table.columns)}",
                             column=missing[0])
    values = table[list(TRUTH_COLUMNS)].apply(pd.to_numeric, errors="coerce").to_numpy(float)
    bad = ~np.isfinite(values)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise RecordingError(name, f"expected a finite number, got "
                             f"{table.iat[row, table.columns.get_loc(TRUTH_COLUMNS[col])]!r}",
                             row=int(row) + 1, column=TRUTH_COLUMNS[col])
    flags = values[:, 4]
    not_flag = (flags != 0) & (flags != 1)
    if not_flag.any():
        row = int(np.flatnonzero(not_flag)[0])
        raise RecordingError(name, f"expected 0 or 1, got {flags[row]:g}", row=row + 1,
                             column="occluded")
    return Truth(t=values[:, 0], position=values[:, 1:4], occluded=flags.astype(bool))
