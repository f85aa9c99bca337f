"""The one place that fixes kfusion's conventions.

Units
    SI everywhere: s, m, m/s, m/s^2, rad, rad/s. Readers convert; algorithms never do.

Quaternions
    Files and public APIs use scalar-first ``[w, x, y, z]``. scipy's ``Rotation.from_quat``
    defaults to ``[x, y, z, w]``; every conversion goes through :func:`rotation_from_wxyz` or
    :func:`matrix_from_wxyz` in this module, never through scipy directly.

Rotation names
    ``R_a_b`` (read "b -> a") takes a vector from frame b to frame a: ``v_a = R_a_b @ v_b``.
    Frames: ``global`` (mocap world), ``body`` (mocap rigid body), ``imu`` (sensor axes).
    The mocap quaternion is ``q_global_body``; ``recording.yaml``'s ``imu_to_body`` is
    ``q_body_imu``. Hence ``R_global_imu = R_global_body @ R_body_imu``.

Accelerometer
    Reads specific force in the IMU frame: ``f_imu = R_imu_global @ (a_global - g_global)``.
    At rest it reads +9.81 m/s^2 along "up". OptiTrack's default world is y-up
    (``g_global = [0, -9.81, 0]``); BROAD's is z-up (``[0, 0, -9.81]``).

Time
    Float seconds. The mocap clock is the reference. An IMU on its own clock maps onto it as
    ``t_mocap = (1 + imu_clock_drift_ppm * 1e-6) * t_imu + imu_time_offset``
    (:func:`imu_time_to_mocap`, the one place this model is written); both default to 0.

Track output status
    ``tracked``: the mocap fix at this row was used; ``bridged``: estimate inside a gap;
    ``lost``: no estimate can be given (before the first fix, or past the bridging horizon).
"""

from __future__ import annotations

import math
from typing import Any, Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

STANDARD_GRAVITY: Final = 9.80665
"""m/s^2, used only to convert g units to m/s^2 (ISO 80000-3)."""

GRAVITY_MAGNITUDE_RANGE: Final = (9.70, 9.90)
"""m/s^2, accepted length of a recording's gravity vector (Earth's surface: 9.78-9.83)."""

OPTITRACK_GRAVITY: Final = (0.0, -9.81, 0.0)
"""m/s^2, gravity in OptiTrack's default y-up world."""

Z_UP_GRAVITY: Final = (0.0, 0.0, -9.81)
"""m/s^2, gravity in a z-up world such as BROAD's."""

IMU_COLUMNS: Final = ("t", "ax", "ay", "az", "gx", "gy", "gz")
MOCAP_COLUMNS: Final = ("t", "x", "y", "z", "qw", "qx", "qy", "qz")
TRUTH_COLUMNS: Final = ("t", "x", "y", "z", "occluded")
TRACK_COLUMNS: Final = ("t", "x", "y", "z", "std_x", "std_y", "std_z", "status")

TRACKED: Final = "tracked"
BRIDGED: Final = "bridged"
LOST: Final = "lost"
STATUSES: Final = (TRACKED, BRIDGED, LOST)

# what the Kalman filter's update did with a mocap frame (kfusion.kalman.filter.UpdateOutcome)
ACCEPTED: Final = "accepted"
"""The fix passed the gate and was fused."""
OCCLUDED: Final = "occluded"
"""No usable position (None or NaN): nothing fused."""
GATED: Final = "gated"
"""The fix failed the chi-square gate (marker swap, jump): rejected, counted."""
REACQUIRED: Final = "reacquired"
"""Fix fused at least ``reacquire_after_s`` after the last accepted one (passing the gate, or
after the state was lost, ``max_bridge_s``, when it re-initialises the position)."""
INITIALISED: Final = "initialised"
"""First fix ever: the state was initialised from it."""
USED_OUTCOMES: Final = (ACCEPTED, REACQUIRED, INITIALISED)

MAX_BRIDGE_LIMIT_S: Final = 60.0
"""Largest ``max_bridge_s`` (s) any method accepts. Dead reckoning a limb from a consumer IMU
drifts by metres within tens of seconds, and kfusion targets 0.1-1 s occlusions; a larger value
(say 1e300) is a mistake, refused rather than bridged "forever"."""

QUATERNION_NORM_TOLERANCE: Final = 1e-3
"""Largest accepted | |q| - 1 | for a quaternion read from a file."""

MAX_LEVER_ARM_M: Final = 2.0
"""Largest lever arm (m, the IMU's offset from the rigid-body origin) on a limb; a longer one
looks like mm."""

MAX_ACCELEROMETER_VALUE: Final = 1e4
MAX_GYROSCOPE_VALUE: Final = 1e3
"""Largest |value| of one IMU axis that a body-worn sensor can report: 1e4 m/s^2 (about 1000 g;
high-g MEMS accelerometers stop at 200-400 g) and 1e3 rad/s (about 57,000 deg/s; gyroscopes stop
at 4000-5000 deg/s). Beyond it a value is corrupt, like a non-finite one, not a reading at the
range limit (which is fused and flagged ``saturated``)."""


def vector_length(values: ArrayLike, axis: int | None = None) -> Any:
    """Euclidean length ``sqrt(sum v_i^2)`` of ``values`` (along ``axis``); inf, without
    numpy's overflow warning, where the squares overflow (a value near 1e308 in a file), so that
    the message naming the value is the only thing printed."""
    with np.errstate(over="ignore"):
        return np.linalg.norm(values, axis=axis)


def median_interval(t: ArrayLike, default: float = 0.0) -> float:
    """Median step between successive times ``t`` (s, or the file's unit): a stream's nominal
    period, robust to dropped samples and bursts; ``default`` for fewer than two times."""
    times = np.asarray(t, dtype=float)
    if len(times) < 2:
        return default
    return float(np.median(np.diff(times)))


def imu_time_to_mocap(t_imu: ArrayLike, imu_time_offset: float = 0.0,
                      imu_clock_drift_ppm: float = 0.0) -> NDArray[np.float64]:
    """IMU timestamps (s, IMU clock) on the mocap clock (s), shape as given:

        t_mocap = (1 + imu_clock_drift_ppm * 1e-6) * t_imu + imu_time_offset

    A positive offset means the IMU clock is behind the mocap's; a positive drift that it runs
    slow (its second is longer than the mocap's by ``drift`` ppm).
    """
    scale = 1.0 + float(imu_clock_drift_ppm) * 1e-6
    return np.asarray(scale * np.asarray(t_imu, dtype=float) + float(imu_time_offset))


def as_wxyz(quaternion: ArrayLike, *, name: str = "quaternion") -> NDArray[np.float64]:
    """Validate a scalar-first quaternion (shape (4,) or (n, 4)) and return it as float array."""
    array = np.asarray(quaternion, dtype=float)
    if array.shape[-1:] != (4,) or array.ndim not in (1, 2):
        raise ValueError(f"{name}: expected shape (4,) or (n, 4) [w, x, y, z], got {array.shape}")
    return array


def rotation_from_wxyz(quaternion: ArrayLike) -> Rotation:
    """scipy Rotation from scalar-first quaternion(s) ``[w, x, y, z]``, shape (4,) or (n, 4)."""
    return Rotation.from_quat(as_wxyz(quaternion), scalar_first=True)


def canonical_wxyz(quaternion: ArrayLike) -> NDArray[np.float64]:
    """The same rotation(s) with ``w >= 0`` (``q`` and ``-q`` are one rotation); shape as given,
    (4,) or (n, 4)."""
    array = np.asarray(quaternion, dtype=float)
    return np.where(array[..., :1] < 0, -array, array)


def wxyz_from_rotation(rotation: Rotation) -> NDArray[np.float64]:
    """Scalar-first quaternion(s) ``[w, x, y, z]`` with w >= 0, shape (4,) or (n, 4)."""
    return canonical_wxyz(rotation.as_quat(scalar_first=True))


# --------------------------------------------------------------------------------------------
# Quaternion algebra: the one implementation of each operation.
#
# Each formula is written once, on components, and serves two forms: arrays of rows (numpy,
# broadcasting; the simulator, calibration, files) and single quaternions as tuples of Python
# floats (the filters, at IMU rate, where one numpy call costs more than the arithmetic). The
# exponential map is the exception: its small-angle branch is an ``if`` on floats and a
# ``np.where`` on rows, so it has a per-sample and a row form, tested against each other.
# --------------------------------------------------------------------------------------------

Quaternion = tuple[float, float, float, float]
"""One unit quaternion ``(w, x, y, z)`` as Python floats."""
Vector = tuple[float, float, float]
"""One 3-vector as Python floats."""

SMALL_ANGLE: Final = 1e-12
"""rad: below this rotation angle the exponential map uses its first-order form."""


def _hamilton(w1: Any, x1: Any, y1: Any, z1: Any,
              w2: Any, x2: Any, y2: Any, z2: Any) -> tuple[Any, Any, Any, Any]:
    """Components of the Hamilton product (floats or arrays)."""
    return (
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    )


def _matrix_entries(w: Any, x: Any, y: Any, z: Any) -> tuple[Any, ...]:
    """The nine entries, row by row, of the rotation matrix of a unit quaternion::

        R = [[1-2(y²+z²), 2(xy-wz),   2(xz+wy)],
             [2(xy+wz),   1-2(x²+z²), 2(yz-wx)],
             [2(xz-wy),   2(yz+wx),   1-2(x²+y²)]]
    """
    return (
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    )


def matrix_from_wxyz(quaternion: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix of quaternion(s) ``[w, x, y, z]`` (normalised first); shape (3, 3) or
    (n, 3, 3). Entries: :func:`_matrix_entries`."""
    q = np.asarray(quaternion, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    matrix = np.stack(_matrix_entries(q[..., 0], q[..., 1], q[..., 2], q[..., 3]), axis=-1)
    return matrix.reshape(q.shape[:-1] + (3, 3))


def matrix_from_quaternion(quaternion: Quaternion) -> NDArray[np.float64]:
    """Rotation matrix (3, 3) of one unit quaternion given as floats (not normalised again);
    the per-sample form of :func:`matrix_from_wxyz`."""
    return np.array(_matrix_entries(*quaternion)).reshape(3, 3)


def quaternion_multiply(left: ArrayLike, right: ArrayLike) -> NDArray[np.float64]:
    """Hamilton product ``left ⊗ right`` of scalar-first quaternions (broadcasts over rows).

    With ``q_a_b ⊗ q_b_c = q_a_c``, rotations compose as matrices do.
    """
    a = np.asarray(left, dtype=float)
    b = np.asarray(right, dtype=float)
    return np.stack(_hamilton(a[..., 0], a[..., 1], a[..., 2], a[..., 3],
                              b[..., 0], b[..., 1], b[..., 2], b[..., 3]), axis=-1)


def quaternion_product(a: Quaternion, b: Quaternion) -> Quaternion:
    """Hamilton product ``a ⊗ b`` of two quaternions given as floats; the per-sample form of
    :func:`quaternion_multiply`."""
    return _hamilton(*a, *b)


def normalise(quaternion: Quaternion) -> Quaternion:
    """``q / |q|`` of a quaternion given as floats."""
    w, x, y, z = quaternion
    inverse = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    return (w * inverse, x * inverse, y * inverse, z * inverse)


def conjugate(quaternion: Quaternion) -> Quaternion:
    """``q* = [w, -x, -y, -z]`` (the inverse of a unit quaternion), floats."""
    w, x, y, z = quaternion
    return (w, -x, -y, -z)


def quaternion_exp(rotation_vector: Vector) -> Quaternion:
    """Exponential map of one rotation vector theta (rad), floats::

        Exp(theta) = [cos(|theta|/2), sin(|theta|/2) theta/|theta|]

    first order, ``[1, theta/2]``, below :data:`SMALL_ANGLE`; NaN for a non-finite theta.
    """
    x, y, z = rotation_vector
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < SMALL_ANGLE:
        return (1.0, 0.5 * x, 0.5 * y, 0.5 * z)
    if not math.isfinite(angle):  # an overflowed step: no rotation can be given
        return (math.nan, math.nan, math.nan, math.nan)
    scale = math.sin(0.5 * angle) / angle
    return (math.cos(0.5 * angle), scale * x, scale * y, scale * z)


def quaternion_exp_rows(rotation_vectors: ArrayLike) -> NDArray[np.float64]:
    """The exponential map of :func:`quaternion_exp` over rows theta (n, 3), rad; (n, 4)."""
    delta = np.asarray(rotation_vectors, dtype=float)
    angle = np.linalg.norm(delta, axis=1)
    # sin(x/2)/x, with its limit 1/2 at x = 0
    factor = np.where(angle > SMALL_ANGLE,
                      np.sin(angle / 2) / np.where(angle > 0, angle, 1.0), 0.5)
    return np.column_stack([np.cos(angle / 2), factor[:, None] * delta])


def quaternion_about_axis(axis: ArrayLike, angle: ArrayLike) -> NDArray[np.float64]:
    """Rotations by signed angles theta (n,) rad about one unit axis (3,)::

        q = [cos(theta/2), sin(theta/2) axis]

    (the exponential map of ``theta axis``, without its norm); (n, 4)."""
    angles = np.asarray(angle, dtype=float)
    half = angles / 2
    return np.column_stack([np.cos(half), np.sin(half)[:, None] * np.asarray(axis, float)])


def quaternion_log(quaternion: Quaternion) -> Vector:
    """Rotation vector theta (rad, |theta| <= pi) with ``Exp(theta) = ±quaternion``, floats."""
    w, x, y, z = quaternion
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    norm = math.sqrt(x * x + y * y + z * z)
    if norm < SMALL_ANGLE:
        return (2.0 * x, 2.0 * y, 2.0 * z)
    scale = 2.0 * math.atan2(norm, w) / norm
    return (scale * x, scale * y, scale * z)


def rotation_angle(first: ArrayLike, second: ArrayLike) -> float:
    """Angle of the rotation between two unit quaternions (4,), rad, in [0, pi]::

        [w, v] = first* ⊗ second,  angle = 2 atan2(|v|, |w|)

    (well conditioned at small angles, where ``2 acos |<q1, q2>|`` loses half the digits)."""
    a = np.asarray(first, dtype=float)
    b = np.asarray(second, dtype=float)
    w, x, y, z = quaternion_product(conjugate((float(a[0]), float(a[1]), float(a[2]),
                                               float(a[3]))),
                                    (float(b[0]), float(b[1]), float(b[2]), float(b[3])))
    return 2.0 * math.atan2(math.sqrt(x * x + y * y + z * z), abs(w))


def quaternion_step(quaternion: Quaternion, angular_rate: Vector, dt: float) -> Quaternion:
    """One gyroscope step at a constant body rate, exact for a constant rate::

        q(t + dt) = normalise(q(t) ⊗ Exp(omega dt))

    ``angular_rate`` omega in rad/s (IMU frame), ``dt`` in s; floats in and out.
    """
    wx, wy, wz = angular_rate
    return normalise(quaternion_product(quaternion, quaternion_exp((wx * dt, wy * dt, wz * dt))))


def integrate_gyroscope(
    q_global_imu: ArrayLike, angular_rate_imu: ArrayLike, dt: float
) -> NDArray[np.float64]:
    """:func:`quaternion_step` on arrays: ``q_global_imu`` (4,) and ``angular_rate_imu`` (3,)
    rad/s, IMU frame; returns the unit quaternion (4,)."""
    q = np.asarray(q_global_imu, dtype=float)
    rate = np.asarray(angular_rate_imu, dtype=float)
    step = quaternion_step((float(q[0]), float(q[1]), float(q[2]), float(q[3])),
                           (float(rate[0]), float(rate[1]), float(rate[2])), float(dt))
    return np.array(step)


def specific_force(
    R_imu_global: ArrayLike, acceleration_global: ArrayLike, gravity_global: ArrayLike
) -> NDArray[np.float64]:
    """What an ideal accelerometer reads: ``f_imu = R_imu_global @ (a_global - g_global)``.

    Shapes: R (3, 3) or (n, 3, 3); accelerations (3,) or (n, 3); result (3,) or (n, 3).
    """
    difference = np.asarray(acceleration_global, dtype=float) - np.asarray(gravity_global, float)
    return np.einsum("...ij,...j->...i", np.asarray(R_imu_global, dtype=float), difference)
