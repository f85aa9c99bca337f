"""Do ``markers.csv`` and ``recording.yaml``'s ``markers:`` agree with ``mocap.csv``'s rigid body?

Marker-level fusion takes each marker as ``z_i = p + R m_i`` with ``m_i`` from ``markers:``. A
body-frame position that is wrong by a few millimetres, a marker that works loose, or labels that
do not match make that model wrong, and the filter then trusts it to its marker noise (0.5 mm):
an 8 mm error put 95 % of a simulated recording's rows beyond the 99 % bound. Wherever a frame
has both the rigid body and a marker, the marker's offset in the body frame,

    o_i(t) = R(t)^T (z_i(t) - p(t)) - m_i        (3,), m,

should be noise. :func:`marker_problem` (step 0 of :mod:`kfusion.calibration.diagnosis`)
reports the first marker whose median offset over a window exceeds
:data:`MARKER_TOLERANCE_M`, and says whether it is off throughout (a wrong position, or labels
that match another marker's position) or moves (a loose marker). Frames where a marker is
further than :data:`JUMP_M` from its place are label jumps (swaps), which the filter's gates
reject; they count only when they are most of the marker's frames.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from typing import Final

import numpy as np
from numpy.typing import NDArray

from kfusion.recording import Recording
from kfusion.rigid_body import LABEL_JUMP_M, points_in_body_frame

MARKER_TOLERANCE_M: Final = 1e-3
"""m: a marker whose windowed median offset from its ``markers:`` position exceeds this is
reported: twice the filter's default ``marker_position_noise`` (0.5 mm). A simulated cluster's
offsets are medians of 0.5 mm noise over about 200 frames (below 0.1 mm); a marker 2 mm loose
already leaves a third of the smoother's rows beyond its bound."""
WINDOW_S: Final = 2.0
"""s: the windows the offsets' medians are taken over (a loose marker moves within a take)."""
JUMP_M: Final = LABEL_JUMP_M
"""m: a frame's offset beyond this is a label jump (a swap), left to the filter: the marker
fails its own gate while the prediction holds, and it disagrees with the frame's other markers
(:func:`kfusion.kalman.markers.consistent_markers`). A marker beyond it in most of its frames
is wrongly placed or labelled for good."""
MIN_FRAMES: Final = 20
"""Frames with both the rigid body and the marker needed for a window's median."""


def body_frame_offsets(recording: Recording) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(t (k,), offsets (k, n, 3) m): each marker's ``o_i = R^T (z_i - p) - m_i`` at the frames
    ``markers.csv`` and ``mocap.csv`` share (same time), NaN where either is not seen. Needs
    ``recording.markers`` and ``recording.info.markers``."""
    markers, positions = recording.markers, recording.info.markers
    assert markers is not None and positions is not None
    mocap = recording.mocap
    t, in_mocap, in_markers = np.intersect1d(mocap.t, markers.t, assume_unique=True,
                                             return_indices=True)
    body = np.array([positions[name] for name in markers.names], dtype=float)
    offsets = points_in_body_frame(mocap.position[in_mocap], mocap.quaternion[in_mocap],
                                   markers.position[in_markers]) - body[None, :, :]
    offsets[~mocap.visible[in_mocap]] = np.nan
    return t, offsets


def _nanmedian(values: NDArray[np.float64], axis: int = 0) -> NDArray[np.float64]:
    """``np.nanmedian`` without the warning for an all-NaN slice (NaN there)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.asarray(np.nanmedian(values, axis=axis))


def windowed_medians(t: NDArray[np.float64], offsets: NDArray[np.float64],
                     window_s: float = WINDOW_S, min_frames: int = MIN_FRAMES
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(starts (w,) s, medians (w, n, 3) m): per window of ``window_s`` from ``t[0]``, the
    per-axis median of each marker's offsets (NaN with fewer than ``min_frames`` seen)."""
    if len(t) == 0:
        return np.zeros(0), np.zeros((0,) + offsets.shape[1:])
    index = np.floor((t - t[0]) / window_s).astype(int)
    starts, medians = [], []
    for window in np.unique(index):
        rows = offsets[index == window]
        seen = np.isfinite(rows).all(axis=2).sum(axis=0)
        median = _nanmedian(rows)
        median[seen < min_frames] = np.nan
        starts.append(t[0] + window * window_s)
        medians.append(median)
    return np.array(starts), np.array(medians)


def marker_problem(recording: Recording) -> str | None:
    """One line naming the first marker that disagrees with ``mocap.csv``'s rigid body (see the
    module docstring), or None; None also when the recording has no markers, no ``markers:``
    or no frame where both are seen."""
    if recording.markers is None or recording.info.markers is None:
        return None
    t, offsets = body_frame_offsets(recording)
    names = recording.markers.names
    body = recording.info.markers
    fix = ("fix markers: in recording.yaml (kfusion convert c3d re-estimates them from frames "
           "where every marker is seen), or track with --measurement body")
    with np.errstate(invalid="ignore"):
        jumped = np.linalg.norm(offsets, axis=2) > JUMP_M  # (k, n); NaN compares False
    seen_frames = np.isfinite(offsets).all(axis=2).sum(axis=0)
    for column, name in enumerate(names):
        if seen_frames[column] and jumped[:, column].sum() > 0.5 * seen_frames[column]:
            overall = _nanmedian(offsets[:, column]) + body[name]
            return _misplaced(name, float(np.linalg.norm(overall - body[name])), overall,
                              names, body, f"in {jumped[:, column].sum()} of "
                              f"{seen_frames[column]} frames", fix)
    offsets = np.where(jumped[:, :, None], np.nan, offsets)
    starts, medians = windowed_medians(t, offsets)
    if len(starts) == 0:
        return None
    size = np.linalg.norm(medians, axis=2)  # (w, n), NaN where too few frames
    for column, name in enumerate(names):
        seen = np.isfinite(size[:, column])
        if not seen.any() or np.max(size[seen, column]) <= MARKER_TOLERANCE_M:
            continue
        worst = int(np.flatnonzero(seen)[np.argmax(size[seen, column])])
        smallest = float(np.min(size[seen, column]))
        where = f"{starts[worst]:.0f}-{starts[worst] + WINDOW_S:.0f} s"
        if smallest <= MARKER_TOLERANCE_M:
            return (f"markers.csv: marker {name!r} moves against the rigid body by up to "
                    f"{size[worst, column] * 1e3:.1f} mm (median over {WINDOW_S:g} s, at "
                    f"{where}; within {MARKER_TOLERANCE_M * 1e3:g} mm elsewhere): a loose "
                    f"marker?; {fix}")
        overall = _nanmedian(offsets[:, column]) + body[name]
        return _misplaced(name, float(size[worst, column]), overall, names, body,
                          f"median over {WINDOW_S:g} s at {where}; at least "
                          f"{smallest * 1e3:.1f} mm throughout", fix)
    return None


def _misplaced(name: str, distance: float, where_seen: NDArray[np.float64],
               names: tuple[str, ...], body: Mapping[str, NDArray[np.float64]], how: str,
               fix: str) -> str:
    """The line for a marker off its ``markers:`` position throughout, naming the marker whose
    position it takes when there is one (``where_seen``: its median body-frame position, m)."""
    match = [other for other in names if other != name
             and np.linalg.norm(where_seen - body[other]) <= MARKER_TOLERANCE_M]
    swapped = (f" (it sits where recording.yaml puts {match[0]!r}: labels swapped between "
               "markers.csv and recording.yaml?)") if match else ""
    return (f"markers.csv: marker {name!r} is {distance * 1e3:.1f} mm from where "
            f"recording.yaml's markers: put it on mocap.csv's rigid body ({how}){swapped}; "
            f"{fix}")
