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

from typing import Final

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

MAX_BRIDGE_LIMIT_S: Final = 60.0
"""Largest ``max_bridge_s`` (s) any method accepts. Dead reckoning a limb from a consumer IMU
drifts by metres within tens of seconds, and kfusion targets 0.1-1 s occlusions; a larger value
(say 1e300) is a mistake, refused rather than bridged "forever"."""

QUATERNION_NORM_TOLERANCE: Final = 1e-3
"""Largest accepted | |q| - 1 | for a quaternion read from a file."""


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


def wxyz_from_rotation(rotation: Rotation) -> NDArray[np.float64]:
    """Scalar-first quaternion(s) ``[w, x, y, z]`` with w >= 0, shape (4,) or (n, 4)."""
    quaternion = rotation.as_quat(scalar_first=True)
    sign = np.where(quaternion[..., :1] < 0, -1.0, 1.0)
    return quaternion * sign


def matrix_from_wxyz(quaternion: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix of a unit quaternion ``[w, x, y, z]``; shape (3, 3) or (n, 3, 3).

    Plain numpy (no scipy object), because the filters call it at IMU rate:

        R = [[1-2(y²+z²), 2(xy-wz),   2(xz+wy)],
             [2(xy+wz),   1-2(x²+z²), 2(yz-wx)],
             [2(xz-wy),   2(yz+wx),   1-2(x²+y²)]]
    """
    q = np.asarray(quaternion, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    matrix = np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    )
    return matrix.reshape(q.shape[:-1] + (3, 3))


def quaternion_multiply(left: ArrayLike, right: ArrayLike) -> NDArray[np.float64]:
    """Hamilton product ``left ⊗ right`` of scalar-first quaternions (broadcasts over rows).

    With ``q_a_b ⊗ q_b_c = q_a_c``, rotations compose as matrices do.
    """
    a = np.asarray(left, dtype=float)
    b = np.asarray(right, dtype=float)
    w1, x1, y1, z1 = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    w2, x2, y2, z2 = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ],
        axis=-1,
    )


def integrate_gyroscope(
    q_global_imu: ArrayLike, angular_rate_imu: ArrayLike, dt: float
) -> NDArray[np.float64]:
    """Propagate orientation one step with a constant body rate (exact for constant rate).

        q(t + dt) = q(t) ⊗ exp(½ ω dt),  exp(½ θ) = [cos(|θ|/2), sin(|θ|/2) θ/|θ|]

    ``angular_rate_imu`` is in rad/s in the IMU frame, shape (3,); returns a unit quaternion.
    """
    rotation_vector = np.asarray(angular_rate_imu, dtype=float) * dt
    angle = float(np.linalg.norm(rotation_vector))
    if angle < 1e-12:
        increment = np.array([1.0, *(0.5 * rotation_vector)])
    else:
        axis = rotation_vector / angle
        increment = np.array([np.cos(angle / 2), *(np.sin(angle / 2) * axis)])
    result = quaternion_multiply(q_global_imu, increment)
    return result / np.linalg.norm(result)


def specific_force(
    R_imu_global: ArrayLike, acceleration_global: ArrayLike, gravity_global: ArrayLike
) -> NDArray[np.float64]:
    """What an ideal accelerometer reads: ``f_imu = R_imu_global @ (a_global - g_global)``.

    Shapes: R (3, 3) or (n, 3, 3); accelerations (3,) or (n, 3); result (3,) or (n, 3).
    """
    difference = np.asarray(acceleration_global, dtype=float) - np.asarray(gravity_global, float)
    return np.einsum("...ij,...j->...i", np.asarray(R_imu_global, dtype=float), difference)
