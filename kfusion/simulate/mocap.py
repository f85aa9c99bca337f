"""The motion-capture system's error model.

* position: ``p_measured = p + e``, ``e ~ N(0, position_noise^2)`` per axis, white;
* orientation: ``q_measured = q ⊗ exp(½ δ)``, ``δ ~ N(0, orientation_noise^2)`` per body axis,
  a small random rotation in the body frame, white;
* occluded frames are NaN in both (the recording's convention), never zeros.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from kfusion.conventions import quaternion_multiply
from kfusion.profiles import MocapProfile

Array = NDArray[np.float64]


def rotation_vector_quaternion(rotation_vector: Array) -> Array:
    """``exp(½ δ) = [cos(|δ|/2), sin(|δ|/2) δ/|δ|]`` for rows δ (n, 3), rad; (n, 4)."""
    delta = np.asarray(rotation_vector, dtype=float)
    angle = np.linalg.norm(delta, axis=1)
    # sin(x/2)/x, with its limit 1/2 at x = 0
    factor = np.where(angle > 1e-12, np.sin(angle / 2) / np.where(angle > 0, angle, 1.0), 0.5)
    return np.column_stack([np.cos(angle / 2), factor[:, None] * delta])


def measure_mocap(rng: np.random.Generator, profile: MocapProfile, position: Array,
                  quaternion: Array, occluded: NDArray[np.bool_]) -> tuple[Array, Array]:
    """Noisy mocap position (m, 3) m and quaternion (m, 4) body -> global [w, x, y, z], NaN on
    ``occluded`` rows. Draws 3 m + 3 m standard normals whatever the profile's numbers."""
    m = int(np.asarray(position).shape[0])
    position_error = profile.position_noise * rng.standard_normal((m, 3))
    rotation_error = profile.orientation_noise * rng.standard_normal((m, 3))
    measured_position = np.asarray(position, dtype=float) + position_error
    measured_quaternion = quaternion_multiply(quaternion,
                                              rotation_vector_quaternion(rotation_error))
    measured_quaternion /= np.linalg.norm(measured_quaternion, axis=1, keepdims=True)
    measured_quaternion = canonical_sign(measured_quaternion)
    hidden = np.asarray(occluded, dtype=bool)[:, None]
    return (np.where(hidden, np.nan, measured_position),
            np.where(hidden, np.nan, measured_quaternion))


def canonical_sign(quaternion: Array) -> Array:
    """The same rotations (n, 4) with w >= 0, as :func:`kfusion.conventions.wxyz_from_rotation`
    writes them."""
    return np.where(np.asarray(quaternion)[:, :1] < 0, -quaternion, quaternion)
