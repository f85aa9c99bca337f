"""The motion-capture system's error model.

* position: ``p_measured = p + e``, ``e ~ N(0, position_noise^2)`` per axis, white;
* orientation: ``q_measured = q ⊗ exp(½ δ)``, ``δ ~ N(0, orientation_noise^2)`` per body axis,
  a small random rotation in the body frame, white;
* occluded frames are NaN in both (the recording's convention), never zeros.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from kfusion.conventions import canonical_wxyz, quaternion_exp_rows, quaternion_multiply
from kfusion.profiles import MocapProfile

Array = NDArray[np.float64]


def measure_mocap(rng: np.random.Generator, profile: MocapProfile, position: Array,
                  quaternion: Array, occluded: NDArray[np.bool_]) -> tuple[Array, Array]:
    """Noisy mocap position (m, 3) m and quaternion (m, 4) body -> global [w, x, y, z], NaN on
    ``occluded`` rows. Draws 3 m + 3 m standard normals whatever the profile's numbers."""
    m = int(np.asarray(position).shape[0])
    position_error = profile.position_noise * rng.standard_normal((m, 3))
    rotation_error = profile.orientation_noise * rng.standard_normal((m, 3))
    measured_position = np.asarray(position, dtype=float) + position_error
    measured_quaternion = quaternion_multiply(quaternion,
                                              quaternion_exp_rows(rotation_error))
    measured_quaternion /= np.linalg.norm(measured_quaternion, axis=1, keepdims=True)
    measured_quaternion = canonical_wxyz(measured_quaternion)
    hidden = np.asarray(occluded, dtype=bool)[:, None]
    return (np.where(hidden, np.nan, measured_position),
            np.where(hidden, np.nan, measured_quaternion))

