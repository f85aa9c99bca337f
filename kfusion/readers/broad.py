"""Reader of BROAD trials (Laidig et al., Data 6(7):72, 2021; ``shared/data/broad/README.md``).

A trial is a MATLAB file (``scipy.io.loadmat``) holding, on one clock at ``sampling_rate``
(285.714 Hz, mocap resampled onto the IMU clock):

* ``imu_acc`` (N, 3) specific force, m/s^2, and ``imu_gyr`` (N, 3), rad/s, in the sensor frame;
* ``opt_pos`` (N, 3) OptiTrack rigid-body position, m, z-up world;
* ``opt_quat`` (N, 4) ``[w, x, y, z]`` sensor -> mocap world (so IMU -> body is identity).

Mocap dropouts are where ``opt_quat`` is NaN. At the start and end of some trials ``opt_pos`` is
held constant there instead of NaN, so a frame is occluded wherever the quaternion (or the
position) has a NaN, and both are set to NaN on it: a held value is never trusted.

The IMU's stamps run about 3 ms late against the mocap's: the recording's ``imu_time_offset`` is
:data:`BROAD_IMU_TIME_OFFSET_S` (written to ``recording.yaml`` by ``kfusion convert broad``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.io
from numpy.typing import NDArray

from kfusion.conventions import Z_UP_GRAVITY
from kfusion.profiles import BROAD_IMU
from kfusion.recording import (
    ImuSamples,
    MocapFrames,
    Recording,
    RecordingError,
    RecordingInfo,
    check_imu_units,
    check_mocap_values,
)

BROAD_KEYS = {"imu_acc": 3, "imu_gyr": 3, "opt_pos": 3, "opt_quat": 4}
"""Arrays read from a trial and their number of columns."""
IDENTITY_QUATERNION = (1.0, 0.0, 0.0, 0.0)

BROAD_IMU_TIME_OFFSET_S = -0.003
"""``imu_time_offset`` of every BROAD trial, s: the IMU's stamps run about one sample (3 ms at
285.7 Hz) late against the mocap's, ``t_mocap = t_imu - 0.003`` (the dataset's README: the
clocks agree within one sample). Measured by minimising the mean NIS of every mocap fix (no
artificial gaps, mocap every 3rd sample, gating off), geometric mean over the seven trials:
0.372 / 0.252 / 0.221 / 0.221 / 0.231 / 0.295 at 0 / 1.5 / 2.5 / 3.0 / 3.5 / 4.5 ms; five
trials have their minimum at 2.5-3.0 ms. ``kfusion calibrate`` measures the gyroscope's own
offset from the angular rates instead (3.7-4.3 ms on the seven trials): see README
"Self-calibration"."""


def occluded_frames(position: NDArray[np.float64], quaternion: NDArray[np.float64]
                    ) -> NDArray[np.bool_]:
    """(N,) True where the mocap frame is a dropout: any NaN in the quaternion or the position.

    Args:
        position: (N, 3) positions, m. quaternion: (N, 4) ``[w, x, y, z]``.
    """
    return np.asarray(np.isnan(quaternion).any(axis=1) | np.isnan(position).any(axis=1))


def mask_occluded(position: NDArray[np.float64], quaternion: NDArray[np.float64]
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Copies of position (N, 3) and quaternion (N, 4) with every occluded row all NaN."""
    occluded = occluded_frames(position, quaternion)[:, None]
    return np.where(occluded, np.nan, position), np.where(occluded, np.nan, quaternion)


def subsample_indices(count: int, step: int) -> NDArray[np.intp]:
    """Indices ``0, step, 2 step, ...`` below ``count`` (every ``step``-th mocap frame)."""
    return np.arange(0, count, step)


def _load(path: Path) -> dict:
    if not path.is_file():
        raise RecordingError(path.name, f"file not found in {path.parent}")
    try:
        return scipy.io.loadmat(path)
    # scipy raises any of these for a file that is not a (readable) MATLAB file.
    except (scipy.io.matlab.MatReadError, ValueError, TypeError, IndexError, OSError,
            NotImplementedError) as error:
        message = str(error).replace("\n", " ")
        raise RecordingError(path.name, f"cannot be read as a MATLAB file ({message})") from None


def _array(file: str, data: dict, key: str, width: int, rows: int | None) -> NDArray[np.float64]:
    if key not in data:
        raise RecordingError(file, f"missing; expected a BROAD trial with keys "
                             f"{[*BROAD_KEYS, 'sampling_rate']}", key=key)
    try:
        array = np.asarray(data[key], dtype=float)
    except (TypeError, ValueError):
        raise RecordingError(file, f"expected numbers, got {data[key].dtype}", key=key) from None
    expected = f"({'N' if rows is None else rows}, {width})"
    if array.ndim != 2 or array.shape[1] != width or (rows is not None and len(array) != rows):
        raise RecordingError(file, f"shape {array.shape}; expected {expected}", key=key)
    return array


def _sampling_rate(file: str, data: dict) -> float:
    if "sampling_rate" not in data:
        raise RecordingError(file, f"missing; expected a BROAD trial with keys "
                             f"{[*BROAD_KEYS, 'sampling_rate']}", key="sampling_rate")
    value = np.asarray(data["sampling_rate"], dtype=float)
    if value.size != 1 or not np.isfinite(value).all() or value.item() <= 0:
        raise RecordingError(file, f"expected one positive rate in Hz, got {value.tolist()}",
                             key="sampling_rate")
    return float(value.item())


def _first_bad(file: str, key: str, bad: NDArray[np.bool_], what: str, array: NDArray) -> None:
    if bad.any():
        row, col = (int(i) for i in np.argwhere(bad)[0])
        raise RecordingError(file, f"{what} {float(array[row, col])!r} at sample {row} "
                             f"(0-based), column {col}", key=f"{key}[{row}, {col}]")


def read_broad(path: str | Path, *, mocap_step: int = 1) -> Recording:
    """Read a BROAD trial as a validated :class:`~kfusion.recording.Recording`.

    Args:
        path: the trial's ``.mat`` file.
        mocap_step: keep every ``mocap_step``-th mocap frame (1: all, 285.7 Hz; 3: ~95 Hz, a
            typical OptiTrack rate). The IMU keeps every sample.

    Returns:
        Recording with IMU t_i = i / sampling_rate (s), specific force (m/s^2) and rates
        (rad/s); mocap frames at t of the kept rows, position (m, z-up world) and quaternion
        ``[w, x, y, z]``, NaN on dropouts; info: ``imu_to_body`` identity, gravity
        ``[0, 0, -9.81]``, ``imu`` ``"broad"``, ``name`` the file stem.

    Raises:
        ValueError: ``mocap_step`` is not an integer >= 1.
        RecordingError: naming the file and key (``"imu_acc[row, column]"``) of a problem.
    """
    if isinstance(mocap_step, bool) or not isinstance(mocap_step, (int, np.integer)) \
            or mocap_step < 1:
        raise ValueError(f"mocap_step: expected an integer >= 1, got {mocap_step!r}")
    path = Path(path)
    file = path.name
    data = _load(path)
    accelerometer = _array(file, data, "imu_acc", 3, None)
    count = len(accelerometer)
    if count == 0:
        raise RecordingError(file, "no samples; expected a non-empty trial", key="imu_acc")
    gyroscope = _array(file, data, "imu_gyr", 3, count)
    position = _array(file, data, "opt_pos", 3, count)
    quaternion = _array(file, data, "opt_quat", 4, count)
    rate = _sampling_rate(file, data)

    for key, array in (("imu_acc", accelerometer), ("imu_gyr", gyroscope)):
        _first_bad(file, key, ~np.isfinite(array), "non-finite IMU value", array)
    for key, array in (("opt_pos", position), ("opt_quat", quaternion)):
        _first_bad(file, key, np.isinf(array), "infinite value", array)

    t = np.arange(count) / rate
    imu = ImuSamples(t=t, accelerometer=accelerometer, gyroscope=gyroscope)
    try:
        check_imu_units(file, imu)
    except RecordingError as error:
        key = "imu_acc" if error.column in ("ax", "ay", "az") else "imu_gyr"
        if error.row is not None:  # one sample's axis (check_imu_values): name it as _first_bad
            axis = "xyz".index(str(error.column)[-1])
            key = f"{key}[{error.row - 1}, {axis}]"
        raise RecordingError(file, error.reason, key=key) from None

    kept = subsample_indices(count, int(mocap_step))
    position, quaternion = mask_occluded(position[kept], quaternion[kept])
    visible = ~occluded_frames(position, quaternion)
    try:
        check_mocap_values(file, position, quaternion, visible)
    except RecordingError as error:
        row = int(kept[(error.row or 1) - 1])
        key = "opt_quat" if error.column == "qw" else "opt_pos"
        column = 0 if error.column == "qw" else "xyz".index(error.column or "x")
        raise RecordingError(file, error.reason, key=f"{key}[{row}, {column}]") from None
    mocap = MocapFrames(t=t[kept], position=position, quaternion=quaternion)
    info = RecordingInfo(imu_to_body=np.array(IDENTITY_QUATERNION),
                         gravity=np.array(Z_UP_GRAVITY), name=path.stem, imu=BROAD_IMU.name,
                         imu_time_offset=BROAD_IMU_TIME_OFFSET_S)
    return Recording(imu=imu, mocap=mocap, info=info, source=str(path))
