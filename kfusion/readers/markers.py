"""Choosing markers by name in a file's labels (shared by the C3D and Motive readers)."""

from __future__ import annotations

from collections.abc import Sequence

from kfusion.recording import RecordingError, marker_name_problem

MAX_LISTED_LABELS = 30
"""An error lists at most this many of a file's labels."""


def listed(labels: Sequence[str]) -> str:
    """The labels for an error message, cut to :data:`MAX_LISTED_LABELS`."""
    shown = [str(label) for label in labels[:MAX_LISTED_LABELS]]
    more = len(labels) - len(shown)
    return f"{shown}" + (f" and {more} more" if more > 0 else "")


def parse_marker_names(text: str, file: str = "command line") -> tuple[str, ...]:
    """``"M1,M2,M3"`` -> ``("M1", "M2", "M3")``: 3 or more unique usable names (``--markers``)."""
    names = tuple(name.strip() for name in text.split(","))
    for name in names:
        problem = marker_name_problem(name)
        if problem is not None:
            raise RecordingError(file, problem, key="markers")
    if len(set(names)) != len(names):
        raise RecordingError(file, f"marker names {list(names)} repeat a name; expected each "
                             "marker once", key="markers")
    return names


def match_markers(file: str, wanted: Sequence[str], labels: Sequence[str], where: str
                  ) -> list[int]:
    """Index in ``labels`` of each wanted marker name.

    A name matches a label exactly, or, when no label matches it exactly, the part after the
    last ``:`` of exactly one label (``M1`` finds ``Forearm:M1``, as Vicon and Motive prefix
    the subject or rigid body).

    Raises:
        RecordingError: naming ``file``, the missing or ambiguous name and the available labels
            (``where`` names them, e.g. ``POINT:LABELS``).
    """
    cleaned = [str(label).strip() for label in labels]
    indices = []
    for name in wanted:
        exact = [i for i, label in enumerate(cleaned) if label == name]
        found = exact or [i for i, label in enumerate(cleaned)
                          if label.rpartition(":")[2] == name]
        if not found:
            raise RecordingError(file, f"no marker named {name!r}; expected names from {where}: "
                                 f"{listed(cleaned)}")
        if len(exact) > 1:
            raise RecordingError(file, f"marker label {name!r} appears {len(exact)} times in "
                                 f"{where} (columns {exact}); rename the duplicates in the "
                                 "capture software and export again, or drop the marker from "
                                 "the body")
        if len(found) > 1:
            raise RecordingError(file, f"marker name {name!r} is ambiguous: it matches "
                                 f"{[cleaned[i] for i in found]} in {where}; give the full label")
        indices.append(found[0])
    if len(set(indices)) != len(indices):
        raise RecordingError(file, f"marker names {list(wanted)} name one label twice")
    return indices
