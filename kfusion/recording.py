"""The recording folder: typed objects, reader, writer and validation.

A recording is a folder holding

* ``imu.csv``: ``t, ax, ay, az, gx, gy, gz`` (s, m/s^2 specific force, rad/s; IMU frame);
* ``mocap.csv``: ``t, x, y, z, qw, qx, qy, qz`` (s, m in the global frame, unit quaternion
  body -> global). An occluded frame has every cell but ``t`` empty (or NaN);
* ``recording.yaml``: ``imu_to_body: [w, x, y, z]`` (IMU -> body rotation),
  ``gravity: [gx, gy, gz]`` (m/s^2, global frame), optional ``name``, ``imu`` (profile name),
  ``lever_arm`` (m, body frame), ``imu_time_offset`` (s) and ``imu_clock_drift_ppm`` (the IMU
  clock: ``t_mocap = (1 + drift * 1e-6) t_imu + offset``, see
  :func:`kfusion.conventions.imu_time_to_mocap`; both default to 0) and ``imu_noise`` (measured
  noise densities that override the IMU profile's, see :class:`ImuNoise`) and ``markers``
  (``{NAME: [bx, by, bz]}``: each marker's position in the body frame relative to the rigid-body
  origin, m);
* optionally ``markers.csv``: ``t``, then ``NAME_x, NAME_y, NAME_z`` for each marker (s; m in the
  global frame, on the mocap clock). An empty cell means that marker is occluded in that row; a
  marker's three cells are all filled or all empty. When ``recording.yaml`` has ``markers``, every
  marker of ``markers.csv`` must be listed there. Without the file, :attr:`Recording.markers`
  is None and nothing else changes.

Other files in the folder (``truth.csv`` from the simulator, say) are ignored.

Occlusions are explicit: :attr:`MocapFrames.position` and :attr:`MocapFrames.quaternion` are NaN on
occluded rows, never zeros. Some exporters write ``0, 0, 0`` for a lost rigid body; pass
``zero_position_means_occluded=True`` to :func:`read_recording` to read those rows as occluded.
Without it, a position of exactly (0, 0, 0) is a real position.

Every validation failure raises :class:`RecordingError` naming the file, row and column.
"""

from __future__ import annotations

import csv
import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray

if TYPE_CHECKING:
    import pandas as pd

from kfusion.conventions import (
    GRAVITY_MAGNITUDE_RANGE,
    IMU_COLUMNS,
    MAX_ACCELEROMETER_VALUE,
    MAX_GYROSCOPE_VALUE,
    MAX_LEVER_ARM_M,
    MOCAP_COLUMNS,
    QUATERNION_NORM_TOLERANCE,
    imu_time_to_mocap,
    vector_length,
)
from kfusion.guards import (
    YamlError,
    atomic_write,
    atomic_write_text,
    load_yaml,
    real_number,
    refuse_masked,
    short_repr,
)
from kfusion.profiles import IMU_PROFILES, imu_profile
from kfusion.streamhealth import RECENT_POSES

IMU_FILE = "imu.csv"
MOCAP_FILE = "mocap.csv"
META_FILE = "recording.yaml"
TRUTH_FILE = "truth.csv"
MARKERS_FILE = "markers.csv"
MARKER_AXES = ("x", "y", "z")
"""Suffixes of a marker's three columns in ``markers.csv``: ``NAME_x, NAME_y, NAME_z``."""
MAX_MARKER_NAME_CHARS = 100
MAX_PLAUSIBLE_MARKER_OFFSET = 2.0
"""m: a body-frame marker position farther than this from the rigid-body origin looks like mm."""

MAX_PLAUSIBLE_POSITION = 10.0
"""m: a mocap coordinate beyond this looks like millimetres."""


def far_position_message(value: float) -> str:
    """Why a coordinate beyond MAX_PLAUSIBLE_POSITION is refused: within 1000 times the limit it
    looks like mm (divide by 1000); beyond that (e.g. 1e300) even mm would put it over 10 km away,
    so it is named an implausible value rather than given the mm advice."""
    limit = f"expected m (|coordinate| <= {MAX_PLAUSIBLE_POSITION:g} m)"
    if abs(value) <= 1000.0 * MAX_PLAUSIBLE_POSITION:
        return f"position {value:.6g} looks like mm; {limit}: divide by 1000"
    return f"position {value:.6g} is implausible (not even mm); {limit}"

G_UNIT_MAGNITUDE_RANGE = (0.5, 2.0)
"""Median accelerometer magnitude in this range looks like g units, not m/s^2."""
PLAUSIBLE_ACCELEROMETER_MEDIAN = (4.0, 30.0)
"""m/s^2: the median specific-force magnitude of a worn IMU is near 9.81."""
MAX_PLAUSIBLE_ANGULAR_RATE = 40.0
"""rad/s: a 99th-percentile gyroscope magnitude above this looks like deg/s."""


class RecordingError(ValueError):
    """A recording file is malformed. ``str()`` is one line naming file, row, column or key.

    Attributes:
        file: file name (or path) at fault.
        row: 1-based data row (the header is not counted), or None.
        column: column name, or None.
        key: YAML key path, or None.
        reason: what is wrong, stating what was expected and what was found.
        line: 1-based line of the row in the file; ``row + 1`` (one header line) unless given,
            for files with a longer header such as a Motive export.
    """

    def __init__(
        self,
        file: str | Path,
        reason: str,
        *,
        row: int | None = None,
        column: str | None = None,
        key: str | None = None,
        line: int | None = None,
    ) -> None:
        self.file = str(file)
        self.row = row
        self.column = column
        self.key = key
        self.reason = reason
        self.line = line if line is not None or row is None else row + 1
        where = [self.file]
        if row is not None:
            where.append(f"row {row} (line {self.line})")
        if column is not None:
            where.append(f"column '{column}'")
        if key is not None:
            where.append(f"key '{key}'")
        super().__init__(", ".join(where) + ": " + reason)


def _frozen(array: NDArray, where: str = "array") -> NDArray:
    refuse_masked(where, array)
    array = np.array(array, dtype=float, copy=True)
    array.flags.writeable = False
    return array


def _frozen_times(array: NDArray, where: str) -> NDArray:
    """:func:`_frozen` stamps (s), ValueError naming the first row that is NaN or infinite.

    A stamp that is not finite has no place in the fusion order: the engines met it at
    different points (a fused fix took an infinite time without a word, the monitor's shadow
    refused it, an occluded one raised), so a recording refuses it where it is built, as the
    readers refuse it in a file (:func:`check_times`)."""
    times = _frozen(array, where)
    bad = np.flatnonzero(~np.isfinite(times)) if times.ndim == 1 else np.zeros(0, dtype=int)
    if len(bad):
        row = int(bad[0])
        raise ValueError(f"{where}: row {row}: expected a finite time in s, got "
                         f"{float(times[row])!r}" + (f" ({len(bad)} such rows)"
                                                     if len(bad) > 1 else ""))
    return times


@dataclass(frozen=True)
class ImuSamples:
    """IMU samples, read-only arrays.

    Attributes:
        t: (n,) sample times, s, strictly increasing.
        accelerometer: (n, 3) specific force, m/s^2, IMU frame.
        gyroscope: (n, 3) angular rate, rad/s, IMU frame.
    """

    t: NDArray[np.float64]
    accelerometer: NDArray[np.float64]
    gyroscope: NDArray[np.float64]

    def __post_init__(self) -> None:
        t = _frozen_times(self.t, "ImuSamples.t")
        accelerometer = _frozen(self.accelerometer, "ImuSamples.accelerometer")
        gyroscope = _frozen(self.gyroscope, "ImuSamples.gyroscope")
        n = t.shape[0] if t.ndim == 1 else -1
        for name, value, shape in (("accelerometer", accelerometer, (n, 3)),
                                   ("gyroscope", gyroscope, (n, 3))):
            if t.ndim != 1 or value.shape != shape:
                raise ValueError(f"ImuSamples.{name}: expected shape (n, 3) with t of shape (n,),"
                                 f" got t {t.shape} and {name} {value.shape}")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "accelerometer", accelerometer)
        object.__setattr__(self, "gyroscope", gyroscope)

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True)
class MocapFrames:
    """Mocap rigid-body frames, read-only arrays; occluded rows are NaN in position and quaternion.

    Attributes:
        t: (m,) frame times, s, strictly increasing.
        position: (m, 3) rigid-body position, m, global frame; NaN where occluded.
        quaternion: (m, 4) body -> global, [w, x, y, z]; NaN where occluded.
    """

    t: NDArray[np.float64]
    position: NDArray[np.float64]
    quaternion: NDArray[np.float64]

    def __post_init__(self) -> None:
        t = _frozen_times(self.t, "MocapFrames.t")
        position = _frozen(self.position, "MocapFrames.position")
        quaternion = _frozen(self.quaternion, "MocapFrames.quaternion")
        n = t.shape[0] if t.ndim == 1 else -1
        if t.ndim != 1 or position.shape != (n, 3) or quaternion.shape != (n, 4):
            raise ValueError(
                "MocapFrames: expected t (m,), position (m, 3), quaternion (m, 4); got "
                f"{t.shape}, {position.shape}, {quaternion.shape}"
            )
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "position", position)
        object.__setattr__(self, "quaternion", quaternion)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def visible(self) -> NDArray[np.bool_]:
        """(m,) True where the frame holds a position and an orientation."""
        return np.asarray(~(np.isnan(self.position).any(axis=1)
                            | np.isnan(self.quaternion).any(axis=1)))


def marker_columns(names: Sequence[str]) -> list[str]:
    """The columns of ``markers.csv``: ``["t", "A_x", "A_y", "A_z", "B_x", ...]``."""
    return ["t"] + [f"{name}_{axis}" for name in names for axis in MARKER_AXES]


def marker_name_problem(name: object) -> str | None:
    """Why ``name`` cannot name a marker (None when it can): a non-empty string of at most
    :data:`MAX_MARKER_NAME_CHARS` printable characters without commas or quotes and without
    leading or trailing spaces, so that it is a CSV column prefix and a YAML key as it stands."""
    if not isinstance(name, str):
        return f"expected a marker name (a string), got {short_repr(name, 40)}"
    if not name or len(name) > MAX_MARKER_NAME_CHARS or name != name.strip() \
            or any(c in name for c in ",\"'") or not name.isprintable():
        return (f"marker name {short_repr(name, 40)} is not usable; expected 1 to "
                f"{MAX_MARKER_NAME_CHARS} printable characters without commas, quotes or "
                "leading/trailing spaces")
    return None


def marker_offset_problem(position: ArrayLike) -> str | None:
    """Why a marker's body-frame position (3,) cannot be one in m (None when it can): farther
    than :data:`MAX_PLAUSIBLE_MARKER_OFFSET` from the rigid-body origin, which looks like mm.
    (Given in mm, a 5 cm cluster reads as 50 m: no frame fits it, and the track stayed lost
    without a word.)"""
    length = float(vector_length(np.asarray(position, dtype=float)))
    if length > MAX_PLAUSIBLE_MARKER_OFFSET:
        return (f"marker is {length:.4g} from the rigid-body origin, which looks like mm; "
                f"expected m (at most {MAX_PLAUSIBLE_MARKER_OFFSET:g})")
    return None


@dataclass(frozen=True)
class MarkerFrames:
    """Positions of individual markers (``markers.csv``), read-only arrays.

    Attributes:
        t: (k,) frame times, s, strictly increasing, on the mocap clock.
        names: (n,) marker names, unique.
        position: (k, n, 3) marker positions, m, global frame; NaN where occluded.
    """

    t: NDArray[np.float64]
    names: tuple[str, ...]
    position: NDArray[np.float64]

    def __post_init__(self) -> None:
        t = _frozen_times(self.t, "MarkerFrames.t")
        position = _frozen(self.position, "MarkerFrames.position")
        names = tuple(self.names)
        for name in names:
            problem = marker_name_problem(name)
            if problem is not None:
                raise ValueError(f"MarkerFrames.names: {problem}")
        if len(set(names)) != len(names) or not names:
            raise ValueError(f"MarkerFrames.names: expected one or more unique names, got "
                             f"{short_repr(list(names))}")
        if t.ndim != 1 or position.shape != (t.shape[0], len(names), 3):
            raise ValueError(f"MarkerFrames: expected t (k,) and position (k, {len(names)}, 3) "
                             f"for {len(names)} names; got {t.shape} and {position.shape}")
        object.__setattr__(self, "t", t)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "position", position)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def visible(self) -> NDArray[np.bool_]:
        """(k, n) True where the marker was seen."""
        return np.asarray(~np.isnan(self.position).any(axis=2))

    def marker(self, name: str) -> NDArray[np.float64]:
        """(k, 3) positions of one marker, m (NaN where occluded); KeyError for an unknown name."""
        if name not in self.names:
            raise KeyError(f"no marker {name!r}; expected one of {list(self.names)}")
        return self.position[:, self.names.index(name)]


IMU_NOISE_KEYS = ("accelerometer_noise_density", "gyroscope_noise_density")
"""Keys of ``recording.yaml``'s ``imu_noise`` section."""
MAX_CLOCK_DRIFT_PPM = 10_000.0
"""ppm: a larger IMU clock drift (1 %) is a unit or clock mistake, not a crystal's drift."""
MAX_CLOCK_OFFSET_S = 1e10
"""s: the largest IMU clock offset (an IMU stamped in Unix time is about 1.7e9 s off)."""


def check_clock(imu_time_offset: object, imu_clock_drift_ppm: object, where: str
                ) -> tuple[float, float]:
    """The clock model's two numbers as floats; ValueError naming ``where`` and the field
    unless each is a real number (not a bool), the offset finite within
    +-:data:`MAX_CLOCK_OFFSET_S` s and the drift within +-:data:`MAX_CLOCK_DRIFT_PPM` ppm."""
    values = []
    for name, value, limit, unit in (("imu_time_offset", imu_time_offset, MAX_CLOCK_OFFSET_S, "s"),
                                     ("imu_clock_drift_ppm", imu_clock_drift_ppm,
                                      MAX_CLOCK_DRIFT_PPM, "ppm")):
        number = real_number(value)
        if number is None or not abs(number) <= limit:
            raise ValueError(f"{where}: {name}: expected a finite number within +-{limit:g} "
                             f"{unit}, got {short_repr(value)}")
        values.append(number)
    return values[0], values[1]


@dataclass(frozen=True)
class ImuNoise:
    """Measured IMU noise (``recording.yaml``'s ``imu_noise`` section), overriding the profile.

    This is the documented way to describe your own IMU: name the closest profile in ``imu``
    and give the densities you measured (``kfusion calibrate`` writes them). None keeps the
    profile's figure.

    Attributes:
        accelerometer_noise_density: white-noise density, m/s^2/sqrt(Hz), or None.
        gyroscope_noise_density: white-noise density, rad/s/sqrt(Hz), or None.
    """

    accelerometer_noise_density: float | None = None
    gyroscope_noise_density: float | None = None

    def overrides(self) -> dict[str, float]:
        """The densities that are set, as :class:`kfusion.profiles.ImuProfile` field names."""
        return {key: float(value) for key in IMU_NOISE_KEYS
                if (value := getattr(self, key)) is not None}


@dataclass(frozen=True)
class RecordingInfo:
    """Contents of ``recording.yaml``.

    Attributes:
        imu_to_body: (4,) rotation IMU -> body, [w, x, y, z]; all NaN when not given (only
            with ``parse_info(..., require_mount=False)``, as ``kfusion calibrate`` reads).
        gravity: (3,) gravity in the global frame, m/s^2; all NaN when not given (idem).
        name: optional recording name.
        imu: optional IMU profile name (see :mod:`kfusion.profiles`).
        lever_arm: optional (3,) IMU position in the body frame relative to the rigid-body
            origin, m.
        imu_time_offset: s, and imu_clock_drift_ppm: the IMU clock model
            (:func:`kfusion.conventions.imu_time_to_mocap`).
        imu_noise: measured noise overriding the profile's, or None.
        markers: optional marker name -> (3,) position in the body frame relative to the
            rigid-body origin, m (read-only mapping of read-only arrays).
    """

    imu_to_body: NDArray[np.float64]
    gravity: NDArray[np.float64]
    name: str | None = None
    imu: str | None = None
    lever_arm: NDArray[np.float64] | None = None
    imu_time_offset: float = 0.0
    imu_clock_drift_ppm: float = 0.0
    imu_noise: ImuNoise | None = None
    markers: Mapping[str, NDArray[np.float64]] | None = None

    def __post_init__(self) -> None:
        offset, drift = check_clock(self.imu_time_offset, self.imu_clock_drift_ppm,
                                    "RecordingInfo")
        object.__setattr__(self, "imu_time_offset", offset)
        object.__setattr__(self, "imu_clock_drift_ppm", drift)
        object.__setattr__(self, "imu_to_body", _frozen(self.imu_to_body))
        object.__setattr__(self, "gravity", _frozen(self.gravity))
        if self.lever_arm is not None:
            object.__setattr__(self, "lever_arm", _frozen(self.lever_arm))
        if self.markers is not None:
            markers = {}
            for name, position in self.markers.items():
                problem = marker_name_problem(name)
                if problem is not None:
                    raise ValueError(f"RecordingInfo.markers: {problem}")
                frozen = _frozen(position, f"RecordingInfo.markers[{name!r}]")
                if frozen.shape != (3,):
                    raise ValueError(f"RecordingInfo.markers[{name!r}]: expected shape (3,), got "
                                     f"{frozen.shape}")
                problem = marker_offset_problem(frozen)
                if problem is not None:
                    raise ValueError(f"RecordingInfo.markers[{name!r}]: {problem}")
                markers[name] = frozen
            object.__setattr__(self, "markers", MappingProxyType(markers))


@dataclass(frozen=True)
class Recording:
    """One recording: IMU samples, mocap frames, their metadata and, when the folder has
    ``markers.csv``, the individual markers (None otherwise)."""

    imu: ImuSamples
    mocap: MocapFrames
    info: RecordingInfo
    source: str | None = field(default=None, compare=False)
    markers: MarkerFrames | None = None

    def with_mocap(self, mocap: MocapFrames) -> Recording:
        """A copy with other mocap frames (for example with artificial gaps cut)."""
        return dataclasses.replace(self, mocap=mocap)


# --------------------------------------------------------------------------------------------
# Pure helpers
# --------------------------------------------------------------------------------------------


def held_frames(mocap: MocapFrames) -> NDArray[np.bool_]:
    """(m,) True where a visible frame repeats bit for bit the pose (position and quaternion)
    of one of the :data:`~kfusion.streamhealth.RECENT_POSES` visible frames before it
    (:func:`kfusion.streamhealth.repeats_pose`: the rule and why; the Tracker keeps the same
    :class:`~kfusion.streamhealth.RecentPoses` at push). The BROAD trials have none."""
    visible = np.flatnonzero(np.asarray(mocap.visible, dtype=bool))
    pose = np.hstack([np.asarray(mocap.position), np.asarray(mocap.quaternion)])[visible]
    repeated = np.zeros(len(visible), dtype=bool)
    for lag in range(1, min(RECENT_POSES, len(visible) - 1) + 1):
        repeated[lag:] |= (pose[lag:] == pose[:-lag]).all(axis=1)
    held = np.zeros(len(mocap.visible), dtype=bool)
    held[visible] = repeated
    return held


def without_held_frames(recording: Recording) -> tuple[Recording, int]:
    """``recording`` with its :func:`held_frames` occluded (position and quaternion NaN), and
    how many there were; the same object when there are none."""
    mocap = recording.mocap
    held = held_frames(mocap)
    count = int(held.sum())
    if count == 0:
        return recording, 0
    position, quaternion = np.array(mocap.position), np.array(mocap.quaternion)
    position[held], quaternion[held] = np.nan, np.nan
    return recording.with_mocap(dataclasses.replace(mocap, position=position,
                                                    quaternion=quaternion)), count


def occlusion_runs(visible: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Index ranges ``[start, stop)`` of consecutive occluded frames (``visible`` False)."""
    hidden = ~np.asarray(visible, dtype=bool)
    padded = np.concatenate([[False], hidden, [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    return [(int(start), int(stop)) for start, stop in zip(edges[::2], edges[1::2], strict=True)]


def occlusion_durations(t: NDArray[np.float64], visible: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Duration of each occlusion, s: from the last visible frame before to the first after.

    A gap at the start or end of the recording is measured to the recording's first or last frame.
    """
    t = np.asarray(t, dtype=float)
    durations = []
    for start, stop in occlusion_runs(visible):
        before = t[start - 1] if start > 0 else t[0]
        after = t[stop] if stop < len(t) else t[-1]
        durations.append(after - before)
    return np.asarray(durations, dtype=float)


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def _read_table(path: Path, columns: Sequence[str]) -> tuple[pd.DataFrame, NDArray[np.bool_]]:
    """Read a CSV as floats; return the frame and a mask of cells that were empty in the file."""
    import pandas as pd  # on first use: `import kfusion.tracker` stays light

    if not path.is_file():
        raise RecordingError(path.name, f"file not found in {path.parent}")
    try:
        raw = pd.read_csv(path, dtype=str, keep_default_na=False, skipinitialspace=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as error:
        message = str(error).strip().replace("\n", " ")
        raise RecordingError(path.name, f"cannot be parsed as CSV ({message})") from None
    raw.columns = [str(c).strip() for c in raw.columns]
    missing = [c for c in columns if c not in raw.columns]
    if missing:
        raise RecordingError(
            path.name,
            f"missing column(s) {missing}; expected {list(columns)}, found {list(raw.columns)}",
            column=missing[0],
        )
    raw = raw[list(columns)]
    stripped = raw.apply(lambda s: s.str.strip())
    empty = stripped.eq("").to_numpy() | stripped.apply(
        lambda s: s.str.lower().eq("nan")).to_numpy()
    numeric = stripped.apply(pd.to_numeric, errors="coerce")
    bad = numeric.isna().to_numpy() & ~empty
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise RecordingError(
            path.name,
            f"non-numeric value {short_repr(raw.iat[row, col])}; expected a number",
            row=int(row) + 1,
            column=columns[col],
        )
    return numeric.astype(float), empty


def check_times(path_name: str, t: NDArray[np.float64], empty: NDArray[np.bool_]) -> None:
    if empty.any():
        row = int(np.flatnonzero(empty)[0])
        raise RecordingError(path_name, "empty timestamp; expected a time in s", row=row + 1,
                             column="t")
    if not np.isfinite(t).all():
        row = int(np.flatnonzero(~np.isfinite(t))[0])
        raise RecordingError(path_name, f"non-finite timestamp {float(t[row])!r}", row=row + 1,
                             column="t")
    steps = np.diff(t)
    if (steps <= 0).any():
        row = int(np.flatnonzero(steps <= 0)[0]) + 1
        kind = "duplicated" if steps[row - 1] == 0 else "earlier than the previous row"
        raise RecordingError(
            path_name,
            f"timestamp {float(t[row])!r} is {kind} ({float(t[row - 1])!r}); expected strictly "
            "increasing times",
            row=row + 1,
            column="t",
        )


def check_mapped_times(path_name: str, t: NDArray[np.float64], info: RecordingInfo) -> None:
    """The IMU stamps ``t`` (s, strictly increasing) must stay strictly increasing once mapped
    onto the mocap clock (:func:`kfusion.conventions.imu_time_to_mocap` with ``info``'s
    ``imu_time_offset`` and ``imu_clock_drift_ppm``): a large offset can round two close
    stamps to one double (at 1e9 s doubles are 1.2e-7 s apart). RecordingError naming the
    row otherwise."""
    if info.imu_time_offset == 0.0 and info.imu_clock_drift_ppm == 0.0:
        return
    with np.errstate(all="ignore"):
        mapped = imu_time_to_mocap(t, info.imu_time_offset, info.imu_clock_drift_ppm)
    if not np.isfinite(mapped).all():
        row = int(np.flatnonzero(~np.isfinite(mapped))[0])
        raise RecordingError(path_name, f"timestamp {float(t[row])!r} maps onto the mocap clock "
                             f"as {float(mapped[row])!r} (imu_time_offset "
                             f"{info.imu_time_offset!r} s, imu_clock_drift_ppm "
                             f"{info.imu_clock_drift_ppm!r}); expected a finite time",
                             row=row + 1, column="t")
    steps = np.diff(mapped)
    if (steps <= 0).any():
        row = int(np.flatnonzero(steps <= 0)[0]) + 1
        raise RecordingError(
            path_name,
            f"timestamp {float(t[row])!r} maps onto the mocap clock at {float(mapped[row])!r} s, "
            f"not after the previous row's {float(mapped[row - 1])!r} s (imu_time_offset "
            f"{info.imu_time_offset!r} s, imu_clock_drift_ppm {info.imu_clock_drift_ppm!r}; "
            f"doubles there are {float(np.spacing(mapped[row])):.2g} s apart); expected stamps "
            "that stay apart on the mocap clock: store times nearer zero",
            row=row + 1, column="t")


def read_imu(path: str | Path) -> ImuSamples:
    """Read and validate ``imu.csv`` (see module docstring). Raises :class:`RecordingError`."""
    path = Path(path)
    table, empty = _read_table(path, IMU_COLUMNS)
    values = table.to_numpy()
    check_times(path.name, values[:, 0], empty[:, 0])
    finite = np.isfinite(values) & ~empty
    if not finite.all():
        row, col = np.argwhere(~finite)[0]
        shown = "(empty or NaN)" if empty[row, col] else repr(float(table.iat[row, col]))
        raise RecordingError(
            path.name,
            f"non-finite or empty IMU value {shown}; IMU samples must be finite",
            row=int(row) + 1,
            column=IMU_COLUMNS[col],
        )
    samples = ImuSamples(t=values[:, 0], accelerometer=values[:, 1:4], gyroscope=values[:, 4:7])
    check_imu_units(path.name, samples)
    return samples


def check_imu_units(file: str, samples: ImuSamples) -> None:
    """RecordingError naming ``file`` when the samples look like the wrong units (g or mm/s^2
    for m/s^2, deg/s for rad/s), then when an axis is beyond any body-worn sensor
    (:func:`check_imu_values`; after the units, which get their own advice)."""
    _check_imu_magnitudes(file, samples)
    check_imu_values(file, samples)


def check_imu_values(file: str, samples: ImuSamples) -> None:
    """RecordingError naming ``file``, row and column of the first axis beyond
    ``MAX_ACCELEROMETER_VALUE`` (m/s^2) or ``MAX_GYROSCOPE_VALUE`` (rad/s) of
    :mod:`kfusion.conventions`: corrupt, not saturated (the Tracker rejects such a sample as
    ``implausible_value``)."""
    for first, values, kind, limit, unit in (
            (1, samples.accelerometer, "accelerometer", MAX_ACCELEROMETER_VALUE, "m/s^2"),
            (4, samples.gyroscope, "gyroscope", MAX_GYROSCOPE_VALUE, "rad/s")):
        beyond = np.abs(np.asarray(values)) > limit
        if beyond.any():
            row, col = np.argwhere(beyond)[0]
            raise RecordingError(
                file, f"{kind} value {float(values[row, col]):.6g} is beyond any body-worn "
                f"sensor's range; expected |value| <= {limit:g} {unit}",
                row=int(row) + 1, column=IMU_COLUMNS[first + col])


def _check_imu_magnitudes(file: str, samples: ImuSamples) -> None:
    if len(samples) == 0:
        raise RecordingError(file, "no samples")
    magnitude = float(np.median(vector_length(samples.accelerometer, axis=1)))
    low, high = G_UNIT_MAGNITUDE_RANGE
    if low <= magnitude <= high:
        raise RecordingError(
            file,
            f"median accelerometer magnitude is {magnitude:.3g}, which looks like g; expected "
            "m/s^2 (about 9.81 at rest): multiply by 9.80665",
            column="ax",
        )
    low, high = PLAUSIBLE_ACCELEROMETER_MEDIAN
    if not low <= magnitude <= high:
        raise RecordingError(
            file,
            f"median accelerometer magnitude is {magnitude:.3g} m/s^2; expected about 9.81 m/s^2 "
            "for a worn IMU (wrong unit or not specific force?)",
            column="ax",
        )
    rate = float(np.percentile(vector_length(samples.gyroscope, axis=1), 99))
    if rate > MAX_PLAUSIBLE_ANGULAR_RATE:
        raise RecordingError(
            file,
            f"99th-percentile angular rate is {rate:.3g}, which looks like deg/s; expected rad/s",
            column="gx",
        )


def read_mocap(path: str | Path, *, zero_position_means_occluded: bool = False) -> MocapFrames:
    """Read and validate ``mocap.csv``. Occluded rows become NaN. Raises :class:`RecordingError`.

    A row is occluded when all of x..qz are empty or NaN, or, with
    ``zero_position_means_occluded``, when x = y = z = 0 exactly. A row with only some cells empty
    is an error.
    """
    path = Path(path)
    table, empty = _read_table(path, MOCAP_COLUMNS)
    values = table.to_numpy()
    if len(values) == 0:
        raise RecordingError(path.name, "no frames; expected at least one mocap row")
    check_times(path.name, values[:, 0], empty[:, 0])
    cells = values[:, 1:]
    missing = empty[:, 1:] | np.isnan(cells)
    if np.isinf(cells).any():
        row, col = np.argwhere(np.isinf(cells))[0]
        raise RecordingError(path.name, "infinite value; expected a number or an empty cell "
                             "(occluded)", row=int(row) + 1, column=MOCAP_COLUMNS[col + 1])
    partial = missing.any(axis=1) & ~missing.all(axis=1)
    if partial.any():
        row = int(np.flatnonzero(partial)[0])
        col = int(np.flatnonzero(missing[row])[0])
        raise RecordingError(
            path.name,
            "row is partly empty; expected all of x..qz filled, or all empty for an occluded frame",
            row=row + 1,
            column=MOCAP_COLUMNS[col + 1],
        )
    occluded = missing.all(axis=1)
    if zero_position_means_occluded:
        occluded |= ~occluded & (cells[:, :3] == 0).all(axis=1)
    cells = np.where(occluded[:, None], np.nan, cells)
    position, quaternion = cells[:, :3], cells[:, 3:]
    check_mocap_values(path.name, position, quaternion, ~occluded)
    return MocapFrames(t=values[:, 0], position=position, quaternion=quaternion)


def check_mocap_values(file: str, position: NDArray, quaternion: NDArray,
                        visible: NDArray[np.bool_]) -> None:
    norm_error = np.abs(vector_length(quaternion, axis=1) - 1.0)
    bad = visible & (norm_error > QUATERNION_NORM_TOLERANCE)
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise RecordingError(
            file,
            f"quaternion norm is {vector_length(quaternion[row]):.6g}; expected a unit "
            f"quaternion [w, x, y, z] (|norm - 1| <= {QUATERNION_NORM_TOLERANCE})",
            row=row + 1,
            column="qw",
        )
    far = visible & (np.abs(position) > MAX_PLAUSIBLE_POSITION).any(axis=1)
    if far.any():
        row = int(np.flatnonzero(far)[0])
        col = int(np.argmax(np.abs(position[row])))
        raise RecordingError(
            file,
            far_position_message(float(position[row, col])),
            row=row + 1,
            column="xyz"[col],
        )


def printable_text(text: str) -> bool:
    """True when ``text`` has no control characters and encodes as UTF-8 (no lone
    surrogates)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return False
    return text.isprintable()


def _vector(file: str, data: dict, key: str, length: int, required: bool = True
            ) -> NDArray[np.float64] | None:
    if key not in data or data[key] is None:
        if required:
            raise RecordingError(file, f"missing; expected a list of {length} numbers", key=key)
        return None
    value = data[key]
    listed = value.tolist() if isinstance(value, np.ndarray) else value
    if not isinstance(listed, (list, tuple)) or any(
            isinstance(item, (bool, str)) for item in listed):
        # np.asarray(dtype=float) took [true, false, false, false] and ["0", "-9.81", "0"]
        # (scalar keys never take a bool or a string)
        raise RecordingError(file, f"expected a list of {length} numbers, got "
                             f"{short_repr(value)}", key=key)
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise RecordingError(file, f"expected a list of {length} numbers, got "
                             f"{short_repr(value)}", key=key) from None
    except OverflowError:
        raise RecordingError(file, f"expected a list of {length} finite numbers, got "
                             f"{short_repr(value)}", key=key) from None
    if array.shape != (length,) or not np.isfinite(array).all():
        raise RecordingError(file, f"expected a list of {length} finite numbers, got "
                             f"{short_repr(value)}", key=key)
    return array


KNOWN_INFO_KEYS = ("imu_to_body", "gravity", "name", "imu", "lever_arm", "imu_time_offset",
                   "imu_clock_drift_ppm", "imu_noise", "markers")
CALIBRATE_HINT = "estimate it with kfusion calibrate DIR --out DIR/recording.yaml --force"


def _number(file: str, data: dict, key: str, unit: str, limit: float, *,
            positive: bool = False) -> float | None:
    """The optional finite number at ``key`` (None when absent), within +-limit (or (0, limit]
    with ``positive``); never a bool. The message shows a short form of a bad value."""
    if key not in data or data[key] is None:
        return None
    value = data[key]
    shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise RecordingError(file, f"expected a number ({unit}), got {shown}", key=key)
    number = float(value) if abs(value) < 1e300 else float("inf")
    if not np.isfinite(number) or abs(number) > limit or (positive and number <= 0):
        expected = f"a positive number up to {limit:g}" if positive else \
            f"a finite number within +-{limit:g}"
        raise RecordingError(file, f"expected {expected} ({unit}), got {shown}", key=key)
    return number


def _imu_noise(file: str, data: dict) -> ImuNoise | None:
    section = data.get("imu_noise")
    if section is None:
        return None
    if not isinstance(section, dict):
        raise RecordingError(file, f"expected a mapping with some of {list(IMU_NOISE_KEYS)}, "
                             f"got {type(section).__name__}", key="imu_noise")
    unknown = sorted(map(str, set(section) - set(IMU_NOISE_KEYS)))
    if unknown:
        raise RecordingError(file, f"unknown key; expected some of {list(IMU_NOISE_KEYS)}",
                             key=f"imu_noise.{unknown[0]}")
    densities = {}
    for key, unit in zip(IMU_NOISE_KEYS, ("m/s^2/sqrt(Hz)", "rad/s/sqrt(Hz)"), strict=True):
        try:
            densities[key] = _number(file, section, key, unit, 10.0, positive=True)
        except RecordingError as error:
            raise RecordingError(file, error.reason, key=f"imu_noise.{key}") from None
    return ImuNoise(**densities)


def _marker_positions(file: str, data: dict) -> dict[str, NDArray[np.float64]] | None:
    """``markers: {NAME: [bx, by, bz]}`` (m, body frame) or None when absent."""
    section = data.get("markers")
    if section is None:
        return None
    if not isinstance(section, dict) or not section:
        raise RecordingError(file, "expected a non-empty mapping {NAME: [bx, by, bz]} (m, body "
                             f"frame), got {short_repr(section)}", key="markers")
    positions = {}
    for name in section:
        problem = marker_name_problem(name)
        if problem is not None:
            raise RecordingError(file, problem, key=f"markers.{short_repr(name, 40)}")
        try:
            position = _vector(file, section, name, 3, required=False)
        except RecordingError as error:
            raise RecordingError(file, error.reason, key=f"markers.{name}") from None
        if position is None:
            raise RecordingError(file, "missing; expected a list of 3 numbers (m, body frame)",
                                 key=f"markers.{name}")
        problem = marker_offset_problem(position)
        if problem is not None:
            raise RecordingError(file, problem, key=f"markers.{name}")
        positions[name] = position
    return positions


def parse_info(data: object, file: str = META_FILE, *, require_mount: bool = True
               ) -> RecordingInfo:
    """Validate the mapping loaded from ``recording.yaml`` and build a :class:`RecordingInfo`.

    With ``require_mount=False`` (``kfusion calibrate``, which estimates them), a missing
    ``imu_to_body`` or ``gravity`` is read as all NaN instead of an error; given values are
    still validated.
    """
    if not isinstance(data, dict):
        raise RecordingError(file, f"expected a mapping with keys {list(KNOWN_INFO_KEYS)}, "
                             f"got {type(data).__name__}")
    unknown = sorted(map(str, set(data) - set(KNOWN_INFO_KEYS)))
    if unknown:
        raise RecordingError(file, f"unknown key; expected only {list(KNOWN_INFO_KEYS)}",
                             key=short_repr(unknown[0]).strip("'"))
    if require_mount and data.get("imu_to_body") is None:
        raise RecordingError(file, f"missing; expected [w, x, y, z], the IMU -> body rotation: "
                             f"{CALIBRATE_HINT}", key="imu_to_body")
    imu_to_body = _vector(file, data, "imu_to_body", 4, required=False)
    if imu_to_body is None:
        imu_to_body = np.full(4, np.nan)
    elif abs(vector_length(imu_to_body) - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise RecordingError(file, f"quaternion norm is {vector_length(imu_to_body):.6g}; "
                             "expected a unit quaternion [w, x, y, z]", key="imu_to_body")
    gravity = _vector(file, data, "gravity", 3, required=require_mount)
    if gravity is None:
        gravity = np.full(3, np.nan)
    low, high = GRAVITY_MAGNITUDE_RANGE
    if np.isfinite(gravity).all() and not low <= vector_length(gravity) <= high:
        raise RecordingError(file, f"gravity length is {vector_length(gravity):.4g} m/s^2; "
                             f"expected about 9.81 (between {low} and {high})", key="gravity")
    lever_arm = _vector(file, data, "lever_arm", 3, required=False)
    if lever_arm is not None and (length := vector_length(lever_arm)) > MAX_LEVER_ARM_M:
        advice = "which looks like mm" if length <= 1000 * MAX_LEVER_ARM_M else \
            "implausible even in mm"
        raise RecordingError(file, f"lever arm length is {length:.4g}, {advice}; expected m "
                             f"(at most {MAX_LEVER_ARM_M:g} m)", key="lever_arm")
    for key in ("name", "imu"):
        if key in data and data[key] is not None and not isinstance(data[key], str):
            raise RecordingError(file, f"expected a string, got {short_repr(data[key])}",
                                 key=key)
        if isinstance(data.get(key), str) and not printable_text(data[key]):
            # a lone surrogate ("\ud800") let check print "ok" and then fail to encode it; a
            # terminal escape would reach the user's terminal through every message naming it
            raise RecordingError(file, f"expected printable text, got {short_repr(data[key])}",
                                 key=key)
    offset = _number(file, data, "imu_time_offset", "s", MAX_CLOCK_OFFSET_S)
    drift = _number(file, data, "imu_clock_drift_ppm", "ppm", MAX_CLOCK_DRIFT_PPM)
    return RecordingInfo(imu_to_body=imu_to_body, gravity=gravity, name=data.get("name"),
                         imu=data.get("imu"), lever_arm=lever_arm,
                         imu_time_offset=offset or 0.0, imu_clock_drift_ppm=drift or 0.0,
                         imu_noise=_imu_noise(file, data),
                         markers=_marker_positions(file, data))


def read_info(path: str | Path, *, require_mount: bool = True) -> RecordingInfo:
    """Read and validate ``recording.yaml`` (``require_mount``: see :func:`parse_info`).
    Raises :class:`RecordingError`."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(path.name, f"file not found in {path.parent}")
    try:
        data = load_yaml(path, label=path.name)
    except YamlError as error:
        reason = f"not valid YAML ({error.reason})" if error.syntax else error.reason
        raise RecordingError(path.name, reason) from None
    info = parse_info(data, path.name, require_mount=require_mount)
    check_imu_profile(info, path.name)
    return info


def check_imu_profile(info: RecordingInfo, file: str = META_FILE) -> None:
    """RecordingError (key ``imu``) when ``info.imu`` names no known IMU profile: the same
    lookup (:func:`kfusion.profiles.imu_profile`) the methods use, so ``kfusion check`` refuses
    what ``kfusion track`` would."""
    if info.imu is None:
        return
    try:
        imu_profile(info.imu)
    except ValueError:
        raise RecordingError(file, f"unknown IMU profile {short_repr(info.imu)}; expected one of "
                             f"{sorted(IMU_PROFILES)} (or no imu key for the default)",
                             key="imu") from None


def _marker_names(path: Path) -> list[str]:
    """Marker names from the header line of ``markers.csv`` (``t, A_x, A_y, A_z, B_x, ...``)."""
    if not path.is_file():
        raise RecordingError(path.name, f"file not found in {path.parent}")
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            header = [cell.strip() for cell in next(csv.reader(handle), [])]
    except (UnicodeDecodeError, csv.Error) as error:
        raise RecordingError(path.name, f"cannot be parsed as CSV ({error})") from None
    expected = "expected t, then NAME_x, NAME_y, NAME_z for each marker"
    if not header or header[0] != "t":
        raise RecordingError(path.name, f"first column is {short_repr(header[:1])}; {expected}",
                             column=header[0] if header else None)
    if len(header) < 4 or (len(header) - 1) % 3:
        raise RecordingError(path.name, f"{len(header) - 1} marker columns, not a positive "
                             f"multiple of 3; {expected}")
    names: list[str] = []
    for start in range(1, len(header), 3):
        name = header[start].rpartition("_")[0]
        wanted = [f"{name}_{axis}" for axis in MARKER_AXES]
        found = header[start:start + 3]
        if found != wanted or not name:
            column = next((f for f, w in zip(found, wanted, strict=True) if f != w), found[0])
            raise RecordingError(path.name, f"columns {short_repr(found)}; {expected} (here "
                                 f"{wanted})", column=column)
        problem = marker_name_problem(name)
        if problem is not None:
            raise RecordingError(path.name, problem, column=header[start])
        if name in names:
            raise RecordingError(path.name, f"marker {name!r} appears twice; expected each "
                                 "marker once", column=header[start])
        names.append(name)
    return names


def read_markers(path: str | Path, *, zero_position_means_occluded: bool = False
                 ) -> MarkerFrames:
    """Read and validate ``markers.csv``. Empty (or NaN) cells are occluded markers; with
    ``zero_position_means_occluded`` a marker at exactly (0, 0, 0) is occluded too. A marker's
    three cells partly empty is an error. Raises :class:`RecordingError`."""
    path = Path(path)
    names = _marker_names(path)
    columns = marker_columns(names)
    table, empty = _read_table(path, columns)
    values = table.to_numpy()
    if len(values) == 0:
        raise RecordingError(path.name, "no frames; expected at least one row")
    check_times(path.name, values[:, 0], empty[:, 0])
    cells = values[:, 1:]
    if np.isinf(cells).any():
        row, col = np.argwhere(np.isinf(cells))[0]
        raise RecordingError(path.name, "infinite value; expected a number or an empty cell "
                             "(occluded)", row=int(row) + 1, column=columns[col + 1])
    missing = (empty[:, 1:] | np.isnan(cells)).reshape(len(values), len(names), 3)
    partial = missing.any(axis=2) & ~missing.all(axis=2)
    if partial.any():
        row, marker = np.argwhere(partial)[0]
        axis = int(np.flatnonzero(missing[row, marker])[0])
        raise RecordingError(path.name, f"marker {names[marker]!r} is partly empty; expected "
                             "its x, y, z all filled, or all empty when occluded",
                             row=int(row) + 1, column=columns[1 + 3 * int(marker) + axis])
    position = cells.reshape(len(values), len(names), 3)
    occluded = missing.all(axis=2)
    if zero_position_means_occluded:
        occluded |= (position == 0).all(axis=2)
    position = np.where(occluded[:, :, None], np.nan, position)
    far = np.abs(np.nan_to_num(position)) > MAX_PLAUSIBLE_POSITION
    if far.any():
        row, marker, axis = np.argwhere(far)[0]
        raise RecordingError(path.name, far_position_message(float(position[row, marker, axis])),
                             row=int(row) + 1,
                             column=columns[1 + 3 * int(marker) + int(axis)])
    return MarkerFrames(t=values[:, 0], names=tuple(names), position=position)


def check_marker_names(markers: MarkerFrames, info: RecordingInfo,
                       file: str = MARKERS_FILE) -> None:
    """RecordingError unless every marker of ``markers.csv`` has a body-frame position in
    ``recording.yaml``'s ``markers`` (when that key is given)."""
    if info.markers is None:
        return
    unknown = [name for name in markers.names if name not in info.markers]
    if unknown:
        raise RecordingError(file, f"marker {unknown[0]!r} has no body-frame position in "
                             f"{META_FILE}'s markers; expected one of {list(info.markers)}",
                             column=f"{unknown[0]}_x")


def recording_files(folder: str | Path) -> list[Path]:
    """The files of a recording folder that :func:`read_recording` reads or may read
    (``recording.yaml``, ``imu.csv``, ``mocap.csv``, ``markers.csv``, ``truth.csv``), present
    or not: what no command's output may replace."""
    folder = Path(folder)
    return [folder / name for name in (META_FILE, IMU_FILE, MOCAP_FILE, MARKERS_FILE,
                                       TRUTH_FILE)]


def read_recording(folder: str | Path, *, zero_position_means_occluded: bool = False) -> Recording:
    """Read and validate a recording folder. Raises :class:`RecordingError` on any fault.

    ``markers.csv`` is read when present (``zero_position_means_occluded`` applies to it too).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise RecordingError(folder, "not a recording folder (expected a directory holding "
                             f"{IMU_FILE}, {MOCAP_FILE} and {META_FILE})")
    info = read_info(folder / META_FILE)
    imu = read_imu(folder / IMU_FILE)
    check_mapped_times(IMU_FILE, imu.t, info)
    mocap = read_mocap(folder / MOCAP_FILE,
                       zero_position_means_occluded=zero_position_means_occluded)
    markers = None
    if (folder / MARKERS_FILE).exists():
        markers = read_markers(folder / MARKERS_FILE,
                               zero_position_means_occluded=zero_position_means_occluded)
        check_marker_names(markers, info)
    return Recording(imu=imu, mocap=mocap, info=info, source=str(folder), markers=markers)


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


def _write_csv(path: Path, columns: Sequence[str], values: NDArray) -> None:
    import pandas as pd  # on first use: `import kfusion.tracker` stays light

    # pandas writes floats with repr(), the shortest string that reads back to the same double,
    # so write -> read round-trips exactly. NaN becomes an empty cell.
    frame = pd.DataFrame(np.asarray(values, dtype=float), columns=list(columns))
    atomic_write(path, lambda temporary: frame.to_csv(temporary, index=False, na_rep=""))


def info_to_dict(info: RecordingInfo) -> dict:
    """The plain mapping written to ``recording.yaml`` (optional keys only when set)."""
    data: dict = {"imu_to_body": [float(v) for v in info.imu_to_body],
                  "gravity": [float(v) for v in info.gravity]}
    if info.name is not None:
        data["name"] = info.name
    if info.imu is not None:
        data["imu"] = info.imu
    if info.lever_arm is not None:
        data["lever_arm"] = [float(v) for v in info.lever_arm]
    if info.imu_time_offset != 0.0:
        data["imu_time_offset"] = float(info.imu_time_offset)
    if info.imu_clock_drift_ppm != 0.0:
        data["imu_clock_drift_ppm"] = float(info.imu_clock_drift_ppm)
    if info.imu_noise is not None and info.imu_noise.overrides():
        data["imu_noise"] = info.imu_noise.overrides()
    if info.markers is not None:
        data["markers"] = {name: [float(v) for v in position]
                           for name, position in info.markers.items()}
    return data


def write_markers(markers: MarkerFrames, path: str | Path) -> None:
    """Write ``markers.csv`` (occluded markers as empty cells); round-trips exactly."""
    _write_csv(Path(path), marker_columns(markers.names),
               np.column_stack([markers.t, markers.position.reshape(len(markers), -1)]))


def write_recording(recording: Recording, folder: str | Path) -> Path:
    """Write a recording folder (creating it); returns its path. Round-trips exactly.

    ``markers.csv`` is written when ``recording.markers`` is set; otherwise one left in the
    folder by an earlier recording is removed, so that the folder reads back as written.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    imu = recording.imu
    _write_csv(folder / IMU_FILE, IMU_COLUMNS,
               np.column_stack([imu.t, imu.accelerometer, imu.gyroscope]))
    mocap = recording.mocap
    _write_csv(folder / MOCAP_FILE, MOCAP_COLUMNS,
               np.column_stack([mocap.t, mocap.position, mocap.quaternion]))
    if recording.markers is not None:
        write_markers(recording.markers, folder / MARKERS_FILE)
    else:
        (folder / MARKERS_FILE).unlink(missing_ok=True)
    atomic_write_text(folder / META_FILE,
                      yaml.safe_dump(info_to_dict(recording.info), sort_keys=False))
    return folder


def on_mocap_clock(recording: Recording) -> Recording:
    """The recording with its IMU stamps mapped onto the mocap clock
    (:func:`kfusion.conventions.imu_time_to_mocap` with ``info.imu_time_offset`` and
    ``info.imu_clock_drift_ppm``) and those two fields set to 0; unchanged when both are 0.

    Every estimator runs on the result (:func:`kfusion.methods.track_with_method`), so the clock
    model is applied in one place.
    """
    info = recording.info
    if info.imu_time_offset == 0.0 and info.imu_clock_drift_ppm == 0.0:
        return recording
    imu = recording.imu
    mapped = ImuSamples(t=imu_time_to_mocap(imu.t, info.imu_time_offset,
                                            info.imu_clock_drift_ppm),
                        accelerometer=imu.accelerometer, gyroscope=imu.gyroscope)
    synced = dataclasses.replace(info, imu_time_offset=0.0, imu_clock_drift_ppm=0.0)
    return dataclasses.replace(recording, imu=mapped, info=synced)
