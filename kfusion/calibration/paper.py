"""The paper's two offline calibrations: the IMU -> body rotation (Kabsch) and the gain K.

IMU -> body rotation (paper, section "IMU data"): pairs of vectors seen in both frames, collected
in roughly orthogonal poses, give the optimal rotation by the Kabsch algorithm. Here the pairs are

* gravity (the paper's example): in each still pose the accelerometer reads
  ``f_imu = R_imu_body R_body_global (-g)``, so its mean pairs with ``R_body_global (-g)`` from the
  mocap orientation;
* optionally, angular rate while the limb turns: the gyroscope reads
  ``w_imu = R_imu_body w_body``, paired with the body rate from successive mocap orientations.
  Useful when a recording has too few distinct still poses; off by default (the paper uses poses).

Gain K (paper, eq. 8): "calculated offline, only once, from the difference between the velocity
obtained by differentiating the position readings and integrating the acceleration readings". In
windows where the mocap is seen, the change of mocap velocity (central differences) is compared
with the integral of the accelerometer rotated to the global frame with the mocap orientation. A
constant acceleration per window (gravity plus the accelerometer offset, which the tracker removes
through its offset) is projected out of both, and K is the least-squares ratio of the remaining
velocity changes. The lever arm is ignored, as in the paper.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation, Slerp

from kfusion.conventions import matrix_from_wxyz, rotation_from_wxyz, wxyz_from_rotation
from kfusion.recording import Recording, occlusion_runs

DEFAULT_GYROSCOPE_THRESHOLD: Final = 0.15
"""rad/s: below this the limb counts as still (8.6 deg/s: above a cheap gyroscope's turn-on bias,
up to ~5 deg/s for the MPU9255, and slow enough that the kinematic acceleration is negligible)."""
DEFAULT_GRAVITY_TOLERANCE: Final = 0.5
"""m/s^2: a still sample's accelerometer magnitude must be within this of |g| (room for a 20 mg
offset and a 1 % scale error)."""
DEFAULT_STILL_DURATION: Final = 0.5
"""s: shortest still period that counts as a pose."""
DEFAULT_MIN_POSE_ANGLE: Final = 20.0
"""deg: the gravity directions must span at least this angle, or the rotation about gravity is
unobservable."""
DEFAULT_MAX_ROTATION: Final = 15.0
"""deg: gain windows in which the limb turns more than this are skipped (see calibrate_gain)."""
DEFAULT_MIN_ANGULAR_RATE: Final = 0.5
"""rad/s: angular-rate pairs are used only above this rate (well above the gyroscope bias)."""


# --------------------------------------------------------------------------------------------
# Kabsch
# --------------------------------------------------------------------------------------------


def kabsch(vectors_a: ArrayLike, vectors_b: ArrayLike, weights: ArrayLike | None = None
           ) -> NDArray[np.float64]:
    """Proper rotation R (3, 3) minimising ``sum_i w_i |a_i - R b_i|^2`` (so ``a ~ R b``).

    Kabsch (1976): ``H = sum_i w_i b_i a_i^T = U S V^T``,
    ``R = V diag(1, 1, d) U^T`` with ``d = sign(det(V U^T))`` so that det(R) = +1 (never a
    reflection). The vectors are used as given (not centred): they are directions, not points.

    Args:
        vectors_a: (n, 3) vectors in frame a, or (k, n, 3): k independent problems solved at
            once (one batched SVD; the rigid-body fit of every mocap frame).
        vectors_b: the same vectors in frame b, same shape.
        weights: (n,) non-negative weights (default all 1), shared by the k problems.

    Returns:
        R_a_b, shape (3, 3), or (k, 3, 3) for stacked input.
    """
    a = np.asarray(vectors_a, dtype=float)
    b = np.asarray(vectors_b, dtype=float)
    if a.ndim not in (2, 3) or a.shape[-1:] != (3,) or a.shape != b.shape:
        raise ValueError(f"kabsch: expected two arrays of shape (n, 3), got {a.shape} and "
                         f"{b.shape} (or both of shape (k, n, 3))")
    count = a.shape[-2]
    if count < 2:
        raise ValueError(f"kabsch: expected at least 2 vector pairs, got {count}")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError("kabsch: expected finite vectors, got NaN or inf")
    w = np.ones(count) if weights is None else np.asarray(weights, dtype=float)
    if w.shape != (count,) or not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
        raise ValueError(f"kabsch: expected {count} non-negative finite weights with a "
                         f"positive sum, got shape {w.shape}")
    H = np.swapaxes(b * w[:, None], -1, -2) @ a  # sum_i w_i b_i a_i^T
    U, _, Vt = np.linalg.svd(H)
    V, Ut = np.swapaxes(Vt, -1, -2), np.swapaxes(U, -1, -2)
    d = np.sign(np.linalg.det(V @ Ut))
    d = np.where(d == 0, 1.0, d)
    # V diag(1, 1, d) scales V's last column by d.
    scale = np.stack([np.ones_like(d), np.ones_like(d), d], axis=-1)[..., None, :]
    rotation: NDArray[np.float64] = (V * scale) @ Ut
    return rotation


def angles_between(vectors_a: ArrayLike, vectors_b: ArrayLike) -> NDArray[np.float64]:
    """Angle between paired vectors (n, 3), degrees."""
    a = np.asarray(vectors_a, dtype=float)
    b = np.asarray(vectors_b, dtype=float)
    cosine = np.sum(a * b, axis=-1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


# --------------------------------------------------------------------------------------------
# IMU -> body rotation
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ImuToBodyCalibration:
    """Result of :func:`calibrate_imu_to_body`.

    Attributes:
        imu_to_body: (4,) rotation IMU -> body, [w, x, y, z] (``recording.yaml``'s key).
        poses: number of still poses used (gravity pairs).
        rate_pairs: number of angular-rate pairs used.
        spread_deg: largest angle between two poses' gravity directions, degrees.
        residual_deg: RMS angle between the rotated IMU gravity and the body gravity over the
            poses, degrees (0 for perfect data; cheap accelerometers give about 1).
    """

    imu_to_body: NDArray[np.float64]
    poses: int
    rate_pairs: int
    spread_deg: float
    residual_deg: float


def still_periods(recording: Recording, *,
                  gyroscope_threshold: float = DEFAULT_GYROSCOPE_THRESHOLD,
                  gravity_tolerance: float = DEFAULT_GRAVITY_TOLERANCE,
                  min_duration: float = DEFAULT_STILL_DURATION) -> list[tuple[float, float]]:
    """Time spans ``(start, end)`` in s where the IMU is still for at least ``min_duration``.

    Still: ``|gyroscope| < gyroscope_threshold`` (rad/s) and ``| |f| - |g| | <
    gravity_tolerance`` (m/s^2), with |g| from ``recording.info.gravity``.
    """
    imu = recording.imu
    gravity = float(np.linalg.norm(recording.info.gravity))
    still = ((np.linalg.norm(imu.gyroscope, axis=1) < gyroscope_threshold)
             & (np.abs(np.linalg.norm(imu.accelerometer, axis=1) - gravity) < gravity_tolerance))
    spans = []
    for start, stop in occlusion_runs(~still):  # runs of still samples
        if imu.t[stop - 1] - imu.t[start] >= min_duration:
            spans.append((float(imu.t[start]), float(imu.t[stop - 1])))
    return spans


def gravity_pairs(recording: Recording, spans: list[tuple[float, float]]
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Per still span: (body-frame ``R_body_global (-g)``, mean accelerometer), each (k, 3).

    Spans without a visible mocap frame are skipped.
    """
    imu, mocap = recording.imu, recording.mocap
    visible = mocap.visible
    up_global = -np.asarray(recording.info.gravity, dtype=float)
    body, sensor = [], []
    for start, end in spans:
        frames = visible & (mocap.t >= start) & (mocap.t <= end)
        if not frames.any():
            continue
        R_global_body = matrix_from_wxyz(mocap.quaternion[frames])
        body.append(np.mean(np.einsum("nji,j->ni", R_global_body, up_global), axis=0))
        samples = (imu.t >= start) & (imu.t <= end)
        sensor.append(imu.accelerometer[samples].mean(axis=0))
    return np.reshape(body, (-1, 3)), np.reshape(sensor, (-1, 3))


def angular_rate_pairs(recording: Recording, *, min_rate: float = DEFAULT_MIN_ANGULAR_RATE
                       ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(body rate from mocap, gyroscope) pairs, each (k, 3) in rad/s, where |rate| > min_rate.

    The body rate between successive visible frames is ``rotvec(q_k^-1 q_k+1) / dt``, referred
    to the middle of the interval; the gyroscope is interpolated linearly to that time.
    """
    imu, mocap = recording.imu, recording.mocap
    visible = mocap.visible
    both = visible[:-1] & visible[1:]
    if not both.any():
        return np.empty((0, 3)), np.empty((0, 3))
    index = np.flatnonzero(both)
    first = rotation_from_wxyz(mocap.quaternion[index])
    second = rotation_from_wxyz(mocap.quaternion[index + 1])
    dt = mocap.t[index + 1] - mocap.t[index]
    rate_body = (first.inv() * second).as_rotvec() / dt[:, None]
    middle = 0.5 * (mocap.t[index] + mocap.t[index + 1])
    inside = (middle >= imu.t[0]) & (middle <= imu.t[-1])
    gyroscope = np.column_stack([np.interp(middle, imu.t, imu.gyroscope[:, axis])
                                 for axis in range(3)])
    keep = inside & (np.linalg.norm(rate_body, axis=1) > min_rate)
    return rate_body[keep], gyroscope[keep]


def calibrate_imu_to_body(recording: Recording, *,
                          gyroscope_threshold: float = DEFAULT_GYROSCOPE_THRESHOLD,
                          gravity_tolerance: float = DEFAULT_GRAVITY_TOLERANCE,
                          still_duration: float = DEFAULT_STILL_DURATION,
                          min_pose_angle: float = DEFAULT_MIN_POSE_ANGLE,
                          use_angular_rate: bool = False,
                          min_angular_rate: float = DEFAULT_MIN_ANGULAR_RATE
                          ) -> ImuToBodyCalibration:
    """Estimate the IMU -> body rotation by Kabsch from still poses (and optionally rates).

    Each still period (see :func:`still_periods`) gives one pair of unit gravity directions with
    weight 1. With ``use_angular_rate``, the angular-rate pairs (:func:`angular_rate_pairs`,
    raw vectors in rad/s) are added with weights scaled so that they count as much, in total,
    as the poses (or weight 1 each when there are no poses).

    Args:
        recording: a recording whose mocap sees the limb in the still poses; the
            ``info.imu_to_body`` it carries is ignored, ``info.gravity`` is used.
        gyroscope_threshold, gravity_tolerance, still_duration: still-period detection
            (rad/s, m/s^2, s).
        min_pose_angle: degrees; the poses' gravity directions must span at least this angle
            (unless angular-rate pairs are used).
        use_angular_rate: also pair gyroscope and mocap rates.
        min_angular_rate: rad/s, smallest rate used for a pair.

    Returns:
        :class:`ImuToBodyCalibration`. Raises ValueError when the data cannot determine the
        rotation, saying what was found.
    """
    spans = still_periods(recording, gyroscope_threshold=gyroscope_threshold,
                          gravity_tolerance=gravity_tolerance, min_duration=still_duration)
    body, sensor = gravity_pairs(recording, spans)
    body_unit = body / np.linalg.norm(body, axis=1, keepdims=True)
    sensor_unit = sensor / np.linalg.norm(sensor, axis=1, keepdims=True)
    spread = float(np.max(angles_between(body_unit[:, None, :], body_unit[None, :, :]))
                   ) if len(body) else 0.0
    rate_body, rate_sensor = (angular_rate_pairs(recording, min_rate=min_angular_rate)
                              if use_angular_rate else (np.empty((0, 3)), np.empty((0, 3))))
    if spread < min_pose_angle and len(rate_body) < 2:
        hint = "" if use_angular_rate else "; record still poses in different orientations " \
            "(roughly orthogonal, as in the paper) or use the angular-rate pairs"
        raise ValueError(
            f"cannot determine the IMU -> body rotation: expected still poses whose gravity "
            f"directions span at least {min_pose_angle:g} deg, found {len(body)} pose(s) "
            f"spanning {spread:.1f} deg{hint}")
    vectors_a = [body_unit]
    vectors_b = [sensor_unit]
    weights = [np.ones(len(body))]
    if len(rate_body):
        vectors_a.append(rate_body)
        vectors_b.append(rate_sensor)
        total = np.sum(np.linalg.norm(rate_body, axis=1) ** 2)
        scale = len(body) / total if len(body) else 1.0
        weights.append(np.full(len(rate_body), scale))
    R_body_imu = kabsch(np.concatenate(vectors_a), np.concatenate(vectors_b),
                        np.concatenate(weights))
    residual = (float(np.sqrt(np.mean(angles_between(body_unit, sensor_unit @ R_body_imu.T)**2)))
                if len(body) else float("nan"))
    quaternion = wxyz_from_rotation(Rotation.from_matrix(R_body_imu))
    return ImuToBodyCalibration(imu_to_body=quaternion, poses=len(body),
                                rate_pairs=len(rate_body), spread_deg=spread,
                                residual_deg=residual)


# --------------------------------------------------------------------------------------------
# Gain K
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class GainCalibration:
    """Result of :func:`calibrate_gain`.

    Attributes:
        gain: K of eq. 8 (dimensionless).
        windows: number of windows used.
        residual_rms: RMS of ``mocap velocity change - K * IMU velocity change`` after the
            per-window constant acceleration is removed, m/s.
    """

    gain: float
    windows: int
    residual_rms: float


def _detrend(values: NDArray[np.float64], elapsed: NDArray[np.float64]) -> NDArray[np.float64]:
    """Residual of values (k, 3) after a least-squares fit of c0 + c1 * elapsed per column."""
    basis = np.column_stack([np.ones_like(elapsed), elapsed])
    coefficients, *_ = np.linalg.lstsq(basis, values, rcond=None)
    residual: NDArray[np.float64] = values - basis @ coefficients
    return residual


def calibrate_gain(recording: Recording, imu_to_body: ArrayLike | None = None, *,
                   window_s: float = 1.0, max_rotation_deg: float = DEFAULT_MAX_ROTATION
                   ) -> GainCalibration:
    """Estimate K by comparing velocity from mocap differentiation with integrated acceleration.

    In each window of ``window_s`` seconds where every mocap frame is visible:

    * ``w(t) = v_mocap(t) - v_mocap(t0)``, with ``v_mocap`` by central differences of position;
    * ``u(t) = integral_t0^t R_global_imu f dt`` (trapezoid at IMU rate, the orientation slerped
      from the mocap), read at the mocap times;
    * a constant acceleration (gravity plus offset) is removed from both: the least-squares
      line in time is subtracted per window and axis;
    * ``K = sum <u, w> / sum <u, u>`` over all windows (least squares for ``w = K u``).

    Windows in which the limb turns by more than ``max_rotation_deg`` are skipped: there the
    accelerometer's per-axis scale errors on gravity (0.25 m/s^2 for 2.5 %) change with the
    orientation, are not removed as a constant, and would bias the scalar K. Calibrate on mostly
    translational motion, as the paper's arm lift.

    Args:
        recording: recording with visible mocap stretches longer than ``window_s``.
        imu_to_body: (4,) IMU -> body [w, x, y, z]; default ``recording.info.imu_to_body``.
        window_s: window length, s.
        max_rotation_deg: largest orientation change within a window, degrees.

    Returns:
        :class:`GainCalibration`; ValueError if no window fits or there is no motion.
    """
    if not window_s > 0:
        raise ValueError(f"window_s: expected a positive number of seconds, got {window_s}")
    if not max_rotation_deg >= 0:
        raise ValueError(f"max_rotation_deg: expected a non-negative angle in degrees, got "
                         f"{max_rotation_deg}")
    q_body_imu = np.asarray(recording.info.imu_to_body if imu_to_body is None else imu_to_body,
                            dtype=float)
    if q_body_imu.shape != (4,):
        raise ValueError(f"imu_to_body: expected shape (4,) [w, x, y, z], got {q_body_imu.shape}")
    R_body_imu = matrix_from_wxyz(q_body_imu)
    imu, mocap = recording.imu, recording.mocap
    numerator = denominator = 0.0
    pairs: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = []  # (u, w) per window
    windows = 0
    for start, stop in _visible_runs(mocap.visible):
        t = mocap.t[start:stop]
        if len(t) < 3 or t[-1] - t[0] < window_s:
            continue
        velocity = np.gradient(mocap.position[start:stop], t, axis=0)
        slerp = Slerp(t, rotation_from_wxyz(mocap.quaternion[start:stop]))
        samples = (imu.t >= t[0]) & (imu.t <= t[-1])
        if samples.sum() < 2:
            continue
        imu_t = imu.t[samples]
        R_global_imu = slerp(imu_t).as_matrix() @ R_body_imu
        acceleration = np.einsum("nij,nj->ni", R_global_imu, imu.accelerometer[samples])
        integral = np.concatenate([np.zeros((1, 3)), np.cumsum(
            0.5 * (acceleration[1:] + acceleration[:-1]) * np.diff(imu_t)[:, None], axis=0)])
        window_start = t[0]
        while window_start + window_s <= t[-1]:
            frames = (t >= window_start) & (t <= window_start + window_s)
            frames &= (t >= imu_t[0]) & (t <= imu_t[-1])
            turn = 0.0
            if frames.sum() >= 3:
                orientations = rotation_from_wxyz(mocap.quaternion[start:stop][frames])
                turn = float(np.degrees(np.max((orientations[0].inv() * orientations)
                                               .magnitude())))
            if frames.sum() >= 3 and turn <= max_rotation_deg:
                tw = t[frames]
                elapsed = tw - tw[0]
                u = np.column_stack([np.interp(tw, imu_t, integral[:, axis]) for axis in range(3)])
                w = velocity[frames]
                u_residual, w_residual = _detrend(u, elapsed), _detrend(w, elapsed)
                numerator += float(np.sum(u_residual * w_residual))
                denominator += float(np.sum(u_residual * u_residual))
                pairs.append((u_residual, w_residual))
                windows += 1
            window_start += window_s
    if windows == 0 or denominator <= 0:
        raise ValueError(f"cannot estimate the gain: expected visible mocap stretches of at "
                         f"least {window_s:g} s with motion and at most {max_rotation_deg:g} deg "
                         f"of rotation, found {windows} window(s)")
    gain = numerator / denominator
    misfit = np.concatenate([w - gain * u for u, w in pairs])
    return GainCalibration(gain=gain, windows=windows,
                           residual_rms=float(np.sqrt(np.mean(misfit**2))))


def _visible_runs(visible: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """Index ranges ``[start, stop)`` of consecutive visible frames."""
    return occlusion_runs(~np.asarray(visible, dtype=bool))
