"""Reader of C3D files: the marker trajectories that OptiTrack, Vicon and Qualisys all export.

A C3D file holds *points* (markers), not rigid bodies: ``POINT:LABELS`` names them,
``POINT:UNITS`` gives their length unit (``mm``, ``cm`` or ``m``), ``POINT:RATE`` the frame rate
(Hz), and the header the number of the first frame (1-based). kfusion reads it with **ezc3d**
(pyomeca, MIT licence, a C++ core with Python wheels for 3.11-3.13): it reads the integer and
floating-point variants of every processor type the exporters write, it also *writes* C3D files
(the tests build theirs with it), and it is maintained. The pure-Python ``c3d`` package reads and
writes as well, but decodes frame by frame in Python; ezc3d's C++ decoding keeps the conversion
of a long take fast. ezc3d is an optional dependency (``pip install 'kfusion[c3d]'``).

Conventions applied here, once:

* frame ``i`` (0-based) of a file whose first frame is ``F`` (1-based, as in the header) is at
  ``t = (F - 1 + i) / rate`` s, so frame 1 is at t = 0 as in Motive's and Vicon's exports;
* positions are divided by the ``POINT:UNITS`` divisor to give m;
* a point is occluded (NaN) where its residual is negative (the C3D flag of an invalid point),
  where its coordinates are NaN, and where it is exactly (0, 0, 0) (the zero-filled gaps many
  exporters write; a real marker is never at the origin to the last bit);
* a point whose residual is exactly 0 was not measured: the C3D standard's glossary ("Residual")
  gives measured points a positive residual and reserves 0 for coordinates "estimated by
  interpolation, affected by filtering, or simulated". Where any chosen marker has a positive
  residual (the exporter writes them), such points are read as occluded, not as fixes: gaps
  filled by the exporter's spline made ``kfusion track`` fuse invented positions as
  measurements (3-9 % of the rows beyond the 99 % bound, up to 7x, with gaps of up to 0.6 s
  filled). A file without a positive residual among them carries no residuals at all
  (simulated data, or an exporter that writes 0 throughout), and its points are kept. So is a
  file whose residuals are quantised: C3D stores a residual in whole multiples of
  ``|POINT:SCALE|``, and with a scale of 1 mm a calibrated system's 0.3-1 mm residuals are
  stored as 0 or 1 step. Where at least :data:`QUANTISED_SHARE` of the positive residuals are
  a single step (:func:`residuals_quantised`), a 0 may be a measured point rounded down (with
  that rule alone 87 % of a simulated take's measured points were dropped), and every point is
  kept;
* ``POINT:Y_SCREEN`` (``+Z`` for Vicon and Qualisys) names the up axis when present; gravity then
  points along its negative.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kfusion.readers.markers import listed, match_markers
from kfusion.recording import (
    MAX_PLAUSIBLE_POSITION,
    MarkerFrames,
    RecordingError,
)

METERS_PER_UNIT_DIVISOR = {"mm": 1000.0, "cm": 100.0, "m": 1.0}
"""``POINT:UNITS`` -> divisor giving m (dividing by an exact integer gives the double nearest to
the decimal value in m)."""
GRAVITY_MAGNITUDE = 9.81
"""m/s^2, the length of the gravity vector derived from ``POINT:Y_SCREEN``."""
INSTALL_HINT = "reading C3D needs ezc3d: pip install 'kfusion[c3d]' (or pip install ezc3d)"
QUANTISED_SHARE = 0.1
"""Share of the positive residuals at one ``|POINT:SCALE|`` step from which a file's residuals
count as quantised (:func:`residuals_quantised`). Residuals resolved in steps of 0.1 mm or finer
put well under 1 % there; a scale of 1 mm with residuals of 0.3-1.3 mm puts nearly all."""


def residuals_quantised(positive: NDArray[np.float64], step: float) -> bool:
    """True when the positive residuals (n,) (file units) reach down to one step of the stored
    resolution ``step`` (``|POINT:SCALE|``, file units) in at least :data:`QUANTISED_SHARE` of
    them: the residual distribution is cut off by the quantisation, and a stored 0 may be a
    measured point rounded down rather than a point not measured."""
    if len(positive) == 0 or not step > 0:
        return False
    return float(np.mean(positive <= 1.5 * step)) >= QUANTISED_SHARE


@dataclass(frozen=True)
class C3dMarkers:
    """Chosen markers of a C3D file, in kfusion's units.

    Attributes:
        markers: the markers' positions, m, global frame, NaN where occluded; t in s.
        rate: frame rate, Hz (``POINT:RATE``).
        first_frame: the file's first frame number, 1-based (header).
        units: the file's ``POINT:UNITS``.
        labels: every label of ``POINT:LABELS`` (and ``LABELS2``, ... when present).
        gravity: (3,) m/s^2 from ``POINT:Y_SCREEN``, or None when the file does not say.
        residual_flagged: number of chosen marker samples flagged invalid (residual < 0 or NaN).
        zero_filled: number of chosen marker samples at exactly (0, 0, 0) with a valid residual.
        interpolated: number of chosen marker samples read as occluded because their residual
            is 0 (not measured) in a file that gives measured points a positive one.
        residuals_given: False when no chosen marker sample has a positive residual (the file
            cannot tell measured points from filled ones; they are all kept).
        residuals_quantised: True when the residuals are stored too coarsely to tell a
            measured point from a filled one (:func:`residuals_quantised`; all are kept).
    """

    markers: MarkerFrames
    rate: float
    first_frame: int
    units: str
    labels: tuple[str, ...]
    gravity: tuple[float, float, float] | None
    residual_flagged: int
    zero_filled: int
    interpolated: int = 0
    residuals_given: bool = False
    residuals_quantised: bool = False


def c3d_frame_times(first_frame: int, count: int, rate: float) -> NDArray[np.float64]:
    """Times (count,), s, of the frames of a C3D file: ``t_i = (first_frame - 1 + i) / rate``
    with ``first_frame`` 1-based as in the header."""
    return (first_frame - 1 + np.arange(count, dtype=float)) / rate


def _parameter(file: str, parameters: dict[str, Any], group: str, name: str) -> list[Any]:
    try:
        value = parameters[group][name]["value"]
    except KeyError:
        raise RecordingError(file, "missing from the file's parameters",
                             key=f"{group}:{name}") from None
    return list(np.atleast_1d(value))


def _labels(parameters: dict[str, Any], count: int) -> tuple[str, ...]:
    """``POINT:LABELS`` followed by ``LABELS2``, ``LABELS3``, ... (files with > 255 points)."""
    point = parameters.get("POINT", {})
    labels: list[str] = []
    for key in ["LABELS"] + [f"LABELS{i}" for i in range(2, 100)]:
        if key not in point:
            break
        labels.extend(str(label).strip() for label in np.atleast_1d(point[key]["value"]))
    return tuple(labels[:count]) + ("",) * max(0, count - len(labels))


def _gravity(parameters: dict[str, Any]) -> tuple[float, float, float] | None:
    """Gravity along minus the ``POINT:Y_SCREEN`` axis (``+Z`` -> (0, 0, -9.81)), or None."""
    try:
        axis = str(np.atleast_1d(parameters["POINT"]["Y_SCREEN"]["value"])[0]).strip().upper()
    except (KeyError, IndexError):
        return None
    if len(axis) != 2 or axis[0] not in "+-" or axis[1] not in "XYZ":
        return None
    gravity = [0.0, 0.0, 0.0]
    gravity["XYZ".index(axis[1])] = -GRAVITY_MAGNITUDE if axis[0] == "+" else GRAVITY_MAGNITUDE
    return (gravity[0], gravity[1], gravity[2])


def up_axis(gravity: ArrayLike) -> str | None:
    """The ``POINT:Y_SCREEN`` value whose axis is up for ``gravity`` (m/s^2, global frame), the
    inverse of the reading rule: up is minus gravity, (0, -9.81, 0) -> ``+Y``; None when gravity
    is not along one axis (no single axis to name) or not finite."""
    vector = np.asarray(gravity, dtype=float)
    if vector.shape != (3,) or not np.isfinite(vector).all() or not vector.any():
        return None
    axis = int(np.argmax(np.abs(vector)))
    if np.count_nonzero(vector) != 1:
        return None
    return ("-" if vector[axis] > 0 else "+") + "XYZ"[axis]


def _load(path: Path) -> dict[str, Any]:
    try:
        import ezc3d
    except ImportError:
        raise RecordingError(path.name, INSTALL_HINT) from None
    if not path.is_file():
        raise RecordingError(path.name, f"file not found in {path.parent}")
    try:
        content: dict[str, Any] = ezc3d.c3d(str(path), extract_forceplat_data=False)
    except (OSError, RuntimeError, ValueError) as error:  # ezc3d's errors on a malformed file
        message = str(error).strip().replace("\n", " ")
        raise RecordingError(path.name, f"cannot be read as C3D ({message})") from None
    return content


def body_prefixes(labels: Sequence[str]) -> tuple[str, ...]:
    """The bodies named in labels ``BODY:NAME`` (the part before the last ``:``), sorted."""
    return tuple(sorted({label.rpartition(":")[0] for label in labels if ":" in label}))


def body_marker_names(file: str, labels: Sequence[str], body: str) -> tuple[str, ...]:
    """The markers of one body: the labels ``BODY:NAME`` (Vicon's subject prefix, Motive's rigid
    body), as ``BODY:NAME``. Raises RecordingError listing the prefixes when there are none."""
    chosen = tuple(label for label in labels if label.rpartition(":")[0] == body)
    if not chosen:
        raise RecordingError(file, f"no label 'BODY:NAME' with BODY {body!r}; expected one of "
                             f"the prefixes {list(body_prefixes(labels))} in POINT:LABELS")
    return chosen


def read_c3d_labels(path: str | Path) -> tuple[str, ...]:
    """Every label of a C3D file's ``POINT:LABELS``, in column order."""
    content = _load(Path(path))
    points = np.asarray(content["data"]["points"], dtype=float)
    return _labels(content["parameters"], points.shape[1] if points.ndim == 3 else 0)


def labelled_bodies(file: str, labels: Sequence[str]) -> tuple[str, ...]:
    """The prefixes of the ``BODY:NAME`` labels, sorted. Raises RecordingError naming ``file``
    when there are none."""
    bodies = body_prefixes(labels)
    if not bodies:
        raise RecordingError(file, "no label 'BODY:NAME' in POINT:LABELS, so no body to "
                             f"convert; labels: {listed(labels)} (give --markers instead)")
    return bodies


def read_c3d_markers(path: str | Path, names: Sequence[str] | None = None, *,
                     body: str | None = None, keep_unmeasured: bool = False) -> C3dMarkers:
    """Read the named markers of a C3D file (see the module docstring for the conventions).

    Args:
        path: the ``.c3d`` file.
        names: marker names, each matching a label exactly or the part after its last ``:``
            (``M1`` finds ``Forearm:M1``); the returned markers keep these names. With
            ``body``, a name ``N`` means the label ``BODY:N``; without names, every
            ``BODY:...`` label is read.
        body: optional label prefix naming one body (``Forearm`` for ``Forearm:M1``, ...).
        keep_unmeasured: keep the points whose residual is 0 in a file that gives measured
            points a positive residual (by default read as occluded; module docstring). For an
            exporter whose small residuals round to 0 at a coarse ``POINT:SCALE`` (the residual
            is stored in whole multiples of it).

    Raises:
        RecordingError: one line naming the file and the parameter, label or frame at fault;
            for a missing name it lists the file's labels.
    """
    path = Path(path)
    file = path.name
    content = _load(path)
    parameters = content["parameters"]
    points = np.asarray(content["data"]["points"], dtype=float)  # (4, n, k)
    count = points.shape[2] if points.ndim == 3 else 0
    labels = _labels(parameters, points.shape[1] if points.ndim == 3 else 0)
    if body is not None:
        names = [f"{body}:{name}" for name in names] if names is not None else \
            list(body_marker_names(file, labels, body))
    if names is None:
        raise ValueError("read_c3d_markers: expected names, a body, or both")
    indices = match_markers(file, names, labels, "POINT:LABELS")
    if count == 0:
        raise RecordingError(file, "no point frames; expected at least one frame")

    units = str(_parameter(file, parameters, "POINT", "UNITS")[0]).strip()
    divisor = METERS_PER_UNIT_DIVISOR.get(units.lower())
    if divisor is None:
        raise RecordingError(file, f"length unit {units!r}; expected one of "
                             f"{list(METERS_PER_UNIT_DIVISOR)}", key="POINT:UNITS")
    rate = float(_parameter(file, parameters, "POINT", "RATE")[0])
    if not np.isfinite(rate) or rate <= 0:
        raise RecordingError(file, f"frame rate {rate!r}; expected a positive number (Hz)",
                             key="POINT:RATE")
    # ezc3d counts frames from 0: its first_frame is the header's 1-based number minus one.
    first_frame = int(content["header"]["points"]["first_frame"]) + 1

    chosen = np.transpose(points[:3, indices, :], (2, 1, 0))  # (k, m, 3), file units
    residuals = np.asarray(content["data"]["meta_points"]["residuals"], dtype=float)
    flagged = np.isnan(chosen).any(axis=2)
    interpolated = np.zeros_like(flagged)
    given = quantised = False
    if residuals.shape == (1, points.shape[1], count):
        residual = residuals[0][indices].T  # (k, m)
        flagged |= residual < 0
        given = bool((residual > 0).any())
        scale = _parameter(file, parameters, "POINT", "SCALE") \
            if "SCALE" in parameters.get("POINT", {}) else [0.0]
        quantised = given and residuals_quantised(residual[residual > 0],
                                                  abs(float(scale[0])))
        if given and not quantised and not keep_unmeasured:  # 0: not measured (module doc)
            interpolated = ~flagged & (residual == 0)
    zeros = ~flagged & ~interpolated & (chosen == 0).all(axis=2)
    position = np.where((flagged | interpolated | zeros)[:, :, None], np.nan, chosen / divisor)
    far = np.abs(np.nan_to_num(position)) > MAX_PLAUSIBLE_POSITION
    if far.any():
        frame, marker, axis = np.argwhere(far)[0]
        raise RecordingError(file, f"marker {names[marker]!r} at {'xyz'[axis]} = "
                             f"{position[frame, marker, axis]:.6g} m in frame "
                             f"{first_frame + int(frame)} (POINT:UNITS says {units!r}); expected "
                             f"|coordinate| <= {MAX_PLAUSIBLE_POSITION:g} m: wrong unit?",
                             key="POINT:UNITS")
    markers = MarkerFrames(t=c3d_frame_times(first_frame, count, rate), names=tuple(names),
                           position=position)
    return C3dMarkers(markers=markers, rate=rate, first_frame=first_frame, units=units,
                      labels=labels, gravity=_gravity(parameters),
                      residual_flagged=int(flagged.sum()), zero_filled=int(zeros.sum()),
                      interpolated=int(interpolated.sum()), residuals_given=given,
                      residuals_quantised=quantised)


def write_c3d_markers(path: str | Path, markers: MarkerFrames, *, units: str = "mm",
                      up_axis: str | None = None) -> Path:
    """Write markers as a C3D file (ezc3d), the inverse of :func:`read_c3d_markers`.

    The times must be frames of one rate on the C3D grid, ``t_i = (F - 1 + i) / rate`` with an
    integer first frame ``F >= 1``; rate and F are taken from them. Occluded markers are written
    as (0, 0, 0) with residual -1 (the C3D flag of an invalid point), the others with residual 0
    (the standard's value for points not derived from camera rays: kfusion writes simulated or
    converted data; :func:`read_c3d_markers` keeps them, since no residual is positive).
    Coordinates are stored as 32-bit floats in ``units`` (0.1 um resolution for mm at a few
    metres).

    Args:
        path: the ``.c3d`` file to write.
        markers: positions, m, NaN where occluded; at least 2 frames.
        units: ``mm``, ``cm`` or ``m``.
        up_axis: optional ``POINT:Y_SCREEN`` value such as ``+Z``.

    Raises:
        ValueError: times not on one frame grid, or an unknown unit.
    """
    try:
        import ezc3d
    except ImportError:
        raise ValueError(INSTALL_HINT) from None
    if units not in METERS_PER_UNIT_DIVISOR:
        raise ValueError(f"write_c3d_markers: unit {units!r}; expected one of "
                         f"{list(METERS_PER_UNIT_DIVISOR)}")
    t = markers.t
    if len(t) < 2:
        raise ValueError(f"write_c3d_markers: expected at least 2 frames, got {len(t)}")
    rate = float((len(t) - 1) / (t[-1] - t[0]))
    first_frame = int(round(t[0] * rate)) + 1
    grid = c3d_frame_times(first_frame, len(t), rate)
    if first_frame < 1 or not np.allclose(t, grid, rtol=0, atol=1e-6 / rate):
        raise ValueError("write_c3d_markers: expected times t_i = (F - 1 + i) / rate with an "
                         f"integer first frame F >= 1; got {t[0]!r}..{t[-1]!r} s for "
                         f"{len(t)} frames")
    hidden = ~markers.visible  # (k, n)
    points = np.ones((4, len(markers.names), len(t)))
    scaled = np.where(hidden[:, :, None], 0.0, markers.position * METERS_PER_UNIT_DIVISOR[units])
    points[:3] = np.transpose(scaled, (2, 1, 0))
    residuals = np.where(hidden.T, -1.0, 0.0)[None]
    content = ezc3d.c3d()
    content["parameters"]["POINT"]["RATE"]["value"] = [rate]
    content["parameters"]["POINT"]["LABELS"]["value"] = tuple(markers.names)
    content["parameters"]["POINT"]["UNITS"]["value"] = [units]
    if up_axis is not None:
        content.add_parameter("POINT", "Y_SCREEN", [up_axis])
    content["data"]["points"] = points
    content["data"]["meta_points"] = {
        "residuals": residuals,
        "camera_masks": np.zeros((7, len(markers.names), len(t)), dtype=bool)}
    content["header"]["points"]["first_frame"] = first_frame - 1  # ezc3d counts from 0
    content.write(str(path))
    return Path(path)
