"""Reader of OptiTrack Motive CSV exports (rigid-body position and quaternion).

Layout of a Motive 2.x / 3.x export (format versions 1.2x), one line each::

    Format Version,1.25,Take Name,...,Rotation Type,Quaternion,Length Units,Millimeters,
        Coordinate Space,Global                      <- key, value pairs
    (blank)
    ,Type,Rigid Body,Rigid Body,...,Rigid Body Marker,...,Marker,...
    ,Name,Forearm,Forearm,...
    ,ID,1,1,...
    ,Parent,...                                      <- Motive 3.x only
    ,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Mean Marker Error,...
    Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,,...
    0,0.000000,0.001,0.002,...                       <- one line per frame

With ``Rotation Type`` Quaternion a rigid body's rotation is exported as the four columns
X, Y, Z, W (scalar last); kfusion reorders them to ``[w, x, y, z]``. Positions are in the
``Length Units`` of the header (Meters, Centimeters or Millimeters) and are converted to m.
A frame where the rigid body was not tracked has blank cells: it becomes an occluded frame (NaN).
Motive's default world is y-up, so gravity is ``[0, -9.81, 0]`` unless the export changed the axes.

Every problem raises :class:`kfusion.recording.RecordingError` naming the file, the data row, its
line in the file and the column.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from kfusion.readers.markers import match_markers
from kfusion.recording import (
    MarkerFrames,
    MocapFrames,
    RecordingError,
    check_mocap_values,
    check_times,
)

METERS_PER_UNIT_DIVISOR = {"meters": 1.0, "centimeters": 100.0, "millimeters": 1000.0}
"""Length unit of the header -> divisor giving m. Dividing by an exact integer (rather than
multiplying by 0.001) returns the double nearest to the decimal value, so ``1200.5`` mm reads
as exactly ``float("1.2005")`` m."""

RIGID_BODY = "Rigid Body"
MARKER = "Marker"
"""Type of a measured (labelled) marker's columns. ``Rigid Body Marker`` columns hold where the
rigid body expects its markers, not measurements, and are not read."""
TIME_HEADER = "Time (Seconds)"
ROTATION_AXES = ("W", "X", "Y", "Z")
"""Order of the rotation columns in kfusion's ``[w, x, y, z]`` (Motive writes X, Y, Z, W)."""
POSITION_AXES = ("X", "Y", "Z")
LABEL_ROWS = ("Type", "Name", "ID", "Parent")


@dataclass(frozen=True)
class MotiveHeader:
    """The header of a Motive CSV export.

    Attributes:
        metadata: key -> value pairs of the first line (``"Length Units": "Millimeters"``, ...).
        labels: ``"Type"``, ``"Name"``, ``"ID"`` (and ``"Parent"``) rows, one cell per column.
        categories: the ``Rotation`` / ``Position`` row, one cell per column.
        axes: the ``Frame, Time (Seconds), X, Y, Z, W, ...`` row.
        data_line: 1-based line of the first data row.
    """

    metadata: dict[str, str]
    labels: dict[str, list[str]]
    categories: list[str]
    axes: list[str]
    data_line: int

    def cell(self, row: str, column: int) -> str:
        """The ``row`` label (``"Type"``, ``"Name"``, ...) of a 0-based column, or ``""``."""
        cells = self.labels.get(row, [])
        return cells[column].strip() if column < len(cells) else ""


@dataclass(frozen=True)
class RigidBodyColumns:
    """0-based columns of one rigid body: rotation in ``[w, x, y, z]`` order, position x, y, z."""

    name: str
    rotation: tuple[int, int, int, int]
    position: tuple[int, int, int]


def _cell(row: Sequence[str], index: int) -> str:
    return row[index].strip() if index < len(row) else ""


def read_motive_header(path: str | Path) -> MotiveHeader:
    """Parse the multi-line header of a Motive CSV export (does not read the frames)."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(path.name, f"file not found in {path.parent}")
    lines: list[list[str]] = []
    with path.open(newline="", encoding="utf-8-sig", errors="replace") as handle:
        for row in csv.reader(handle):
            lines.append(row)
            if _cell(row, 0).lower() == "frame" and _cell(row, 1).lower().startswith("time"):
                break
            if len(lines) > 50:
                break
    if not lines or _cell(lines[0], 0) != "Format Version":
        first = ",".join(lines[0])[:60] if lines else ""
        raise RecordingError(path.name, "not a Motive CSV export: expected the first line to start "
                             f"with 'Format Version', got {first!r}")
    axes = lines[-1]
    if not (_cell(axes, 0).lower() == "frame" and _cell(axes, 1).lower().startswith("time")):
        raise RecordingError(path.name, "no column header line 'Frame,Time (Seconds),X,Y,Z,...' in "
                             f"the first {len(lines)} lines; expected a Motive CSV export with "
                             "its header enabled")
    pairs = [cell.strip() for cell in lines[0]]
    metadata = dict(zip(pairs[0::2], pairs[1::2], strict=False))
    labels = {_cell(row, 1): row for row in lines[1:-1] if _cell(row, 0) == ""
              and _cell(row, 1) in LABEL_ROWS}
    categories = lines[-2] if len(lines) >= 3 else []
    return MotiveHeader(metadata=metadata, labels=labels, categories=categories, axes=axes,
                        data_line=len(lines) + 1)


def length_divisor(file: str, metadata: dict[str, str]) -> float:
    """Divisor turning the export's positions into m, from its ``Length Units`` header value."""
    unit = metadata.get("Length Units")
    if unit is None:
        raise RecordingError(file, "no 'Length Units' in the header line; expected one of "
                             "Meters, Centimeters, Millimeters", key="Length Units")
    try:
        return METERS_PER_UNIT_DIVISOR[unit.lower()]
    except KeyError:
        raise RecordingError(file, f"length units {unit!r}; expected one of Meters, Centimeters, "
                             "Millimeters", key="Length Units") from None


def _check_export_settings(file: str, metadata: dict[str, str]) -> None:
    rotation = metadata.get("Rotation Type", "Quaternion")
    if rotation.lower() != "quaternion":
        raise RecordingError(file, f"rotation type {rotation!r} (Euler angles); expected "
                             "Quaternion: export again with Rotation Type = Quaternion",
                             key="Rotation Type")
    space = metadata.get("Coordinate Space", "Global")
    if space.lower() != "global":
        raise RecordingError(file, f"coordinate space {space!r}; expected Global: export again "
                             "with global coordinates", key="Coordinate Space")


def _rigid_body_names(header: MotiveHeader) -> list[str]:
    names: list[str] = []
    for column in range(2, len(header.axes)):
        if header.cell("Type", column) == RIGID_BODY:
            name = header.cell("Name", column)
            if name not in names:
                names.append(name)
    return names


def motive_rigid_bodies(path: str | Path) -> list[str]:
    """Names of the rigid bodies in a Motive CSV export, in column order."""
    return _rigid_body_names(read_motive_header(path))


def _rigid_body_columns(file: str, header: MotiveHeader, name: str) -> RigidBodyColumns:
    found: dict[tuple[str, str], int] = {}
    ids: set[str] = set()
    for column in range(2, len(header.axes)):
        if header.cell("Type", column) != RIGID_BODY or header.cell("Name", column) != name:
            continue
        ids.add(header.cell("ID", column))
        key = (_cell(header.categories, column), _cell(header.axes, column).upper())
        if key in found:
            raise RecordingError(file, f"rigid body name {name!r} is ambiguous: it names "
                                 f"{len(ids)} rigid bodies (IDs {sorted(ids)}); rename one in "
                                 "Motive", column=f"{name} {key[0]} {key[1]}")
        found[key] = column
    wanted = [("Rotation", axis) for axis in ROTATION_AXES] + [
        ("Position", axis) for axis in POSITION_AXES]
    missing = [f"{category} {axis}" for category, axis in wanted if (category, axis) not in found]
    if missing:
        raise RecordingError(file, f"rigid body {name!r} has no column(s) {missing}; expected "
                             "Rotation X, Y, Z, W and Position X, Y, Z (Rotation Type Quaternion)")
    w, x, y, z = (found[("Rotation", axis)] for axis in ROTATION_AXES)
    position_x, position_y, position_z = (found[("Position", axis)] for axis in POSITION_AXES)
    return RigidBodyColumns(name=name, rotation=(w, x, y, z),
                            position=(position_x, position_y, position_z))


def choose_rigid_body(file: str, names: list[str], rigid_body: str | None) -> str:
    """The rigid body to read: ``rigid_body`` if given, else the only one in the export."""
    if not names:
        raise RecordingError(file, "no rigid body columns; expected a Motive export with "
                             "'Rigid Bodies' enabled", key="Type")
    if rigid_body is None:
        if len(names) > 1:
            raise RecordingError(file, f"several rigid bodies {names}; choose one "
                                 "(rigid_body=... or --rigid-body NAME)")
        return names[0]
    if rigid_body not in names:
        raise RecordingError(file, f"no rigid body named {rigid_body!r}; expected one of {names}")
    return rigid_body


def _parse_cells(file: str, raw: pd.DataFrame, labels: list[str], first_line: int
                 ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Strings -> floats; empty or ``nan`` cells are NaN and flagged in the returned mask."""
    stripped = raw.apply(lambda s: s.fillna("").str.strip())
    empty = stripped.eq("").to_numpy() | stripped.apply(
        lambda s: s.str.lower().eq("nan")).to_numpy()
    numeric = stripped.apply(pd.to_numeric, errors="coerce").to_numpy(dtype=float)
    bad = np.isnan(numeric) & ~empty
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise RecordingError(file, f"non-numeric value {stripped.iat[row, col]!r}; expected a "
                             "number", row=int(row) + 1, line=first_line + int(row),
                             column=labels[col])
    return numeric, empty


def _check_field_counts(file: str, path: Path, header: MotiveHeader) -> None:
    """Every data line has as many fields as the header line (Motive writes blank cells)."""
    width = len(header.axes)
    row = 0
    with path.open(newline="", encoding="utf-8-sig", errors="replace") as handle:
        for number, line in enumerate(handle, start=1):
            if number < header.data_line or not line.strip():
                continue
            row += 1
            fields = line.count(",") + 1
            if fields != width:
                raise RecordingError(file, f"{fields} fields; expected {width} as in the header "
                                     "line 'Frame,Time (Seconds),...'", row=row, line=number)


def _read_frames(file: str, path: Path, header: MotiveHeader, columns: list[int]
                 ) -> pd.DataFrame:
    """The data lines' cells (as text) of ``columns``; one column per entry, in that order."""
    _check_field_counts(file, path, header)
    try:
        # Only the wanted columns are parsed: a take may have hundreds of marker columns.
        raw = pd.read_csv(path, skiprows=header.data_line - 1, header=None, dtype=str,
                          keep_default_na=False, names=range(len(header.axes)),
                          usecols=columns, encoding="utf-8-sig")
    except (pd.errors.ParserError, UnicodeDecodeError) as error:
        message = str(error).strip().replace("\n", " ")
        raise RecordingError(file, f"frames cannot be parsed as CSV ({message})") from None
    if len(raw) == 0:
        raise RecordingError(file, "no frames after the header; expected at least one frame")
    return raw[columns]


def _relocated(error: RecordingError, first_line: int, columns: dict[str, str],
               note: str = "") -> RecordingError:
    """Re-issue a check's error with the Motive file's line and column names."""
    line = None if error.row is None else first_line + error.row - 1
    column = None if error.column is None else columns.get(error.column, error.column)
    return RecordingError(error.file, error.reason + note, row=error.row, column=column,
                          line=line)


def read_motive_csv(path: str | Path, *, rigid_body: str | None = None,
                    zero_position_means_occluded: bool = False) -> MocapFrames:
    """Read one rigid body of an OptiTrack Motive CSV export as validated mocap frames.

    Args:
        path: the ``.csv`` exported by Motive (header enabled, Rotation Type Quaternion).
        rigid_body: name of the rigid body; default: the only rigid body in the export
            (several rigid bodies without a name is an error listing them).
        zero_position_means_occluded: read a position of exactly (0, 0, 0) as occluded.

    Returns:
        MocapFrames with t (m,) in s from ``Time (Seconds)``, position (m, 3) in m (converted
        from ``Length Units``), quaternion (m, 4) ``[w, x, y, z]`` body -> global; NaN rows where
        the rigid body's cells are blank (occluded).

    Raises:
        RecordingError: naming the file, row, line and column of the first problem.
    """
    path = Path(path)
    file = path.name
    header = read_motive_header(path)
    _check_export_settings(file, header.metadata)
    divisor = length_divisor(file, header.metadata)
    name = choose_rigid_body(file, _rigid_body_names(header), rigid_body)
    body = _rigid_body_columns(file, header, name)

    columns = [1, *body.position, *body.rotation]
    labels = [TIME_HEADER] + [f"{name} Position {axis}" for axis in POSITION_AXES] + [
        f"{name} Rotation {axis}" for axis in ROTATION_AXES]
    raw = _read_frames(file, path, header, columns)
    values, empty = _parse_cells(file, raw, labels, header.data_line)
    # The same checks as a recording folder's mocap.csv, named in Motive's terms.
    names = dict(zip(("t", "x", "y", "z", "qw", "qx", "qy", "qz"), labels, strict=True))
    try:
        check_times(file, values[:, 0], empty[:, 0])
    except RecordingError as error:
        raise _relocated(error, header.data_line, names) from None

    cells = values[:, 1:]
    missing = empty[:, 1:]
    infinite = np.isinf(cells)
    if infinite.any():
        row, col = np.argwhere(infinite)[0]
        raise RecordingError(file, "infinite value; expected a number or a blank cell (occluded)",
                             row=int(row) + 1, line=header.data_line + int(row),
                             column=labels[col + 1])
    partial = missing.any(axis=1) & ~missing.all(axis=1)
    if partial.any():
        row = int(np.flatnonzero(partial)[0])
        col = int(np.flatnonzero(missing[row])[0])
        raise RecordingError(file, "rigid body cells partly blank; expected all 7 filled, or all "
                             "blank for an occluded frame", row=row + 1,
                             line=header.data_line + row, column=labels[col + 1])
    occluded: NDArray[np.bool_] = np.all(missing, axis=1)
    if zero_position_means_occluded:
        occluded = occluded | np.all(cells[:, :3] == 0, axis=1)
    position = np.where(occluded[:, None], np.nan, cells[:, :3] / divisor)
    quaternion = np.where(occluded[:, None], np.nan, cells[:, 3:])
    try:
        check_mocap_values(file, position, quaternion, ~occluded)
    except RecordingError as error:
        units = header.metadata["Length Units"]
        note = f" (the header says Length Units {units})" if error.column in ("x", "y", "z") else ""
        raise _relocated(error, header.data_line, names, note) from None
    return MocapFrames(t=values[:, 0], position=position, quaternion=quaternion)


def _marker_columns(file: str, header: MotiveHeader) -> dict[str, tuple[int, int, int]]:
    """Name -> 0-based (X, Y, Z) position columns of every ``Marker`` in the export."""
    found: dict[str, dict[str, int]] = {}
    for column in range(2, len(header.axes)):
        if header.cell("Type", column) != MARKER or _cell(header.categories, column) != "Position":
            continue
        axes = found.setdefault(header.cell("Name", column), {})
        axis = _cell(header.axes, column).upper()
        if axis in axes:
            raise RecordingError(file, f"marker name {header.cell('Name', column)!r} names "
                                 "several markers; rename one in Motive",
                                 column=f"{header.cell('Name', column)} Position {axis}")
        axes[axis] = column
    return {name: (axes["X"], axes["Y"], axes["Z"]) for name, axes in found.items()
            if set(POSITION_AXES) <= set(axes)}


def read_motive_markers(path: str | Path, names: Sequence[str], *,
                        zero_position_means_occluded: bool = False) -> MarkerFrames:
    """Read the named markers (``Marker`` columns) of a Motive CSV export.

    Args:
        path: the ``.csv`` exported by Motive with markers enabled.
        names: marker names, each matching a label exactly or the part after its ``:``
            (``Marker1`` finds ``Forearm:Marker1``); the result keeps these names.
        zero_position_means_occluded: read a marker at exactly (0, 0, 0) as occluded.

    Returns:
        MarkerFrames: t (k,) s, position (k, n, 3) m (from ``Length Units``), NaN where the
        marker's cells are blank.

    Raises:
        RecordingError: naming the file, row, line and column; a missing name lists the
            export's markers.
    """
    path = Path(path)
    file = path.name
    header = read_motive_header(path)
    divisor = length_divisor(file, header.metadata)
    available = _marker_columns(file, header)
    labels = list(available)
    chosen = [labels[i] for i in match_markers(file, names, labels, "the 'Marker' columns")]
    columns = [1] + [column for label in chosen for column in available[label]]
    texts = [TIME_HEADER] + [f"{label} Position {axis}" for label in chosen
                             for axis in POSITION_AXES]
    raw = _read_frames(file, path, header, columns)
    values, empty = _parse_cells(file, raw, texts, header.data_line)
    try:
        check_times(file, values[:, 0], empty[:, 0])
    except RecordingError as error:
        raise _relocated(error, header.data_line, {"t": TIME_HEADER}) from None
    cells = values[:, 1:].reshape(len(values), len(chosen), 3)
    missing: NDArray[np.bool_] = empty[:, 1:].reshape(len(values), len(chosen), 3)
    partial = np.any(missing, axis=2) & ~np.all(missing, axis=2)
    bad = np.isinf(cells) | partial[:, :, None]
    if bad.any():
        row, marker, axis = np.argwhere(bad)[0]
        raise RecordingError(file, "marker cells partly blank or infinite; expected X, Y, Z all "
                             "numbers, or all blank when occluded", row=int(row) + 1,
                             line=header.data_line + int(row),
                             column=texts[1 + 3 * int(marker) + int(axis)])
    occluded: NDArray[np.bool_] = np.all(missing, axis=2)
    if zero_position_means_occluded:
        occluded = occluded | np.all(cells == 0, axis=2)
    position = np.where(occluded[:, :, None], np.nan, cells / divisor)
    return MarkerFrames(t=values[:, 0], names=tuple(names), position=position)
