"""The compiled engine: the position filter of :mod:`kfusion.kalman.filter` as numba kernels.

:class:`kfusion.kalman.KalmanFusion` (on filterpy) is the readable reference; this module computes
the same thing with small pure step functions compiled by numba (``njit(cache=True)``: the
machine code is cached on disk next to this file, or in numba's fallback cache directory), and
a whole-loop kernel, :func:`filter_events`, that runs a recording's merged events
(:func:`kfusion.kalman.events.merge_order`, called outside the kernel) in one call. Every step
is the filter's, equation for equation and branch for branch (first-order hold, IMU outages,
saturation, orientation gating, chi-square gate, re-acquisition, resets), so the two engines
agree to rounding (tests/test_compiled_engine.py: within 1e-9 m, same outcomes and statuses).
The hot path allocates nothing per event: the predict forms ``F P F^T`` from F's blocks
(:func:`structured_predict`), the update uses a 3x3 adjugate inverse and the Joseph form,
in filterpy's order on a far looser prior (:func:`position_update`); the general forms
(:func:`covariance_predict`, :func:`covariance_update`) are kept as their cross-check. The
smoother's forward pass keeps each row's prediction packed (:func:`pack_prediction`: P's upper
triangle and the transition product's 19 free entries, the only ones it accumulates:
:func:`accumulate_transition`), and its backward pass (:func:`smooth_rows`) reads them; a
forward pass run step by step keeps states every :data:`SAVE_EVERY` rows instead, from which
the backward pass recomputes the predictions with the same bits.

State, in flat float arrays (numba compiles plain arrays best):

* ``x`` (n,), ``P`` (n, n): the position filter, layout from :mod:`kfusion.kalman.layout`;
* ``orientation`` (:data:`ORIENTATION_SIZE`,): ``q_global_imu`` [w, x, y, z] (0:4), gyroscope
  bias (4:7, rad/s), covariance ``(P_tt, P_tb, P_bb)`` (7:10), rotation since the last fix
  (10:13, rad), scale variance peak (13), initialised flag (14), the innovations' mean (15:18)
  and mean square (18) (:class:`kfusion.kalman.orientation.OrientationState`);
* ``scalars`` (:data:`SCALAR_COUNT`,): times, the held sample and flags; ``NaN`` stands for the
  reference filter's ``None``;
* ``counters`` (:data:`COUNTER_NAMES` order) as int64.

Parameters go in as one float array ``config`` (:func:`pack_config`). numba is imported only
when a kernel is first needed (:func:`kernels`), so ``import kfusion.kalman`` stays light.
"""

from __future__ import annotations

import math
from typing import Final

import numpy as np
from numba import njit
from numpy.typing import NDArray

from kfusion import streamhealth
from kfusion.conventions import BRIDGED, LOST, SMALL_ANGLE, TRACKED
from kfusion.kalman import model
from kfusion.kalman.filter import (
    ACCEPTED,
    GATED,
    INITIALISED,
    OCCLUDED,
    REACQUIRED,
)
from kfusion.kalman.layout import layout_for
from kfusion.kalman.orientation import PERSISTENCE_LIMIT, persistent_innovations
from kfusion.kalman.parameters import KalmanParameters

OUTCOME_NAMES: Final = (ACCEPTED, OCCLUDED, GATED, REACQUIRED, INITIALISED)
"""Outcome codes of the kernels: the index in this tuple."""
_ACCEPTED, _OCCLUDED, _GATED, _REACQUIRED, _INITIALISED = range(5)

# scalars: indices into the filter's scalar state
TIME, IMU_STAMP, IMU_TIME = 0, 1, 2
ACCELEROMETER, GYROSCOPE = 3, 6  # held sample (3 each)
ACCELEROMETER_EXTRA, GYROSCOPE_EXTRA = 9, 10
LOW_PASS = 11  # low-passed specific force (3); NaN in LOW_PASS: none yet
LAST_FIX, LAST_NIS, LAST_ORIENTATION_FIX, IMU_INTERVAL = 14, 15, 16, 17
INITIALISED_FLAG, LAST_FRAME_FUSED, OUTAGE_SINCE_FIX = 18, 19, 20
LAST_IMPACT = 21  # time of the last impact, s (-inf: none; KalmanFusion.last_impact_t)
ACCELEROMETER_PLATEAU, GYROSCOPE_PLATEAU = 22, 28  # (tops (3), repeats (3)): model.plateau_step
SCALAR_COUNT: Final = 34
ORIENTATION_SIZE: Final = 19
INNOVATION_MEAN, INNOVATION_SQUARE = 15, 18  # OrientationState.innovation_mean (3), _square

# config: indices into the packed parameters
(C_ACC_DENSITY, C_ACC_WALK, C_GYRO_DENSITY, C_GYRO_WALK, C_POSITION_NOISE,
 C_ORIENTATION_VARIANCE, C_INITIAL_BIAS_STD, C_INITIAL_GYRO_BIAS_VARIANCE, C_INITIAL_VELOCITY_STD,
 C_ACC_SCALE, C_GYRO_SCALE_VARIANCE, C_LEVER_STD, C_LATENCY, C_ACC_RANGE, C_GYRO_RANGE, C_GATE,
 C_GATE_MIN, C_REACQUIRE, C_MAX_BRIDGE, C_DROPOUT, C_TILT_INFLATION, C_GATING) = range(22)
C_Q_BODY_IMU = 22  # (4)
C_R_IMU_BODY = 26  # (9) row-major
C_GRAVITY = 35  # (3)
C_LEVER = 38  # (3) given lever arm
C_LEVER_GIVEN = 41
C_POSITION, C_VELOCITY, C_BIAS, C_LEVER_STATE = 42, 43, 44, 45  # layout block starts (-1: none)
C_TIMESTAMP_JITTER = 46  # s, 1-sigma IMU stamp error (model.stamp_jitter_variance)
C_IMPACT_JERK = 47  # m/s^3 (KalmanParameters.impact_jerk; model.is_impact)
CONFIG_SIZE: Final = 48

COUNTER_INDEX: Final = {name: index for index, name in enumerate(
    ("predictions", "imu_rejected", "imu_duplicates", "imu_dropouts", "imu_late",
     "accelerometer_saturated", "gyroscope_saturated", "updates", "occluded", "gated",
     "reacquired", "initialised", "no_orientation", "resets", "imu_outages",
     "orientation_gated", "markers_used", "markers_gated"))}
"""Position of each of :data:`kfusion.kalman.filter.COUNTER_NAMES` in the counters array (the
kernels index it by these numbers; the marker counts stay 0: no marker-level fusion here)."""


def pack_config(params: KalmanParameters, q_body_imu: tuple[float, float, float, float],
                R_imu_body: NDArray[np.float64], gravity: NDArray[np.float64],
                lever_arm: NDArray[np.float64] | None, size: int) -> NDArray[np.float64]:
    """The kernels' parameter array (:data:`CONFIG_SIZE`,) from the filter's configuration."""
    config = np.zeros(CONFIG_SIZE)
    config[C_ACC_DENSITY] = params.accelerometer_noise_density
    config[C_ACC_WALK] = params.accelerometer_bias_random_walk
    config[C_GYRO_DENSITY] = params.gyroscope_noise_density
    config[C_GYRO_WALK] = params.gyroscope_bias_random_walk
    config[C_POSITION_NOISE] = params.mocap_position_noise
    config[C_ORIENTATION_VARIANCE] = params.mocap_orientation_noise ** 2
    config[C_INITIAL_BIAS_STD] = params.initial_bias_std
    config[C_INITIAL_GYRO_BIAS_VARIANCE] = params.initial_gyroscope_bias_std ** 2
    config[C_INITIAL_VELOCITY_STD] = params.initial_velocity_std
    config[C_ACC_SCALE] = params.accelerometer_scale_error
    config[C_GYRO_SCALE_VARIANCE] = params.gyroscope_scale_error ** 2
    config[C_LEVER_STD] = params.lever_arm_std
    config[C_LATENCY] = params.imu_latency_s
    config[C_ACC_RANGE] = params.accelerometer_range
    config[C_GYRO_RANGE] = params.gyroscope_range
    config[C_GATE] = model.gate_threshold(params.gate_probability)
    config[C_GATE_MIN] = params.gate_min_innovation
    config[C_REACQUIRE] = params.reacquire_after_s
    config[C_MAX_BRIDGE] = params.max_bridge_s
    config[C_DROPOUT] = params.imu_dropout_s
    config[C_TILT_INFLATION] = params.tilt_error_inflation
    config[C_TIMESTAMP_JITTER] = params.timestamp_jitter
    config[C_IMPACT_JERK] = params.impact_jerk
    config[C_GATING] = 1.0 if params.gating else 0.0
    config[C_Q_BODY_IMU:C_Q_BODY_IMU + 4] = q_body_imu
    config[C_R_IMU_BODY:C_R_IMU_BODY + 9] = np.asarray(R_imu_body, dtype=float).ravel()
    config[C_GRAVITY:C_GRAVITY + 3] = gravity
    if lever_arm is not None:
        config[C_LEVER:C_LEVER + 3] = lever_arm
        config[C_LEVER_GIVEN] = 1.0
    layout = layout_for(size == model.LEVER_SIZE)
    config[C_POSITION] = layout.start("position")
    config[C_VELOCITY] = layout.start("velocity")
    config[C_BIAS] = layout.start("bias")
    config[C_LEVER_STATE] = layout.start("lever_arm") if layout.has("lever_arm") else -1
    return config


def initial_scalars() -> NDArray[np.float64]:
    """The scalar state of a new filter: every time None (NaN), nothing held, flags off."""
    scalars = np.full(SCALAR_COUNT, np.nan)
    scalars[ACCELEROMETER_EXTRA] = scalars[GYROSCOPE_EXTRA] = 0.0
    scalars[INITIALISED_FLAG] = scalars[LAST_FRAME_FUSED] = scalars[OUTAGE_SINCE_FIX] = 0.0
    scalars[LAST_IMPACT] = -math.inf
    scalars[ACCELEROMETER_PLATEAU:ACCELEROMETER_PLATEAU + 6] = 0.0
    scalars[GYROSCOPE_PLATEAU:GYROSCOPE_PLATEAU + 6] = 0.0
    return scalars


def initial_orientation() -> NDArray[np.float64]:
    """An uninitialised orientation state (:func:`clear_orientation`)."""
    orientation = np.empty(ORIENTATION_SIZE)
    clear_orientation(orientation)
    return orientation


# ---------------------------------------------------------------------------------------------
# The step functions, compiled by numba (machine code cached on disk: cache=True).
# ---------------------------------------------------------------------------------------------


_SMALL_ANGLE = SMALL_ANGLE
_UNKNOWN_VARIANCE = streamhealth.ORIENTATION_UNKNOWN_VARIANCE
_NO_IMU_DENSITY = streamhealth.NO_IMU_ACCELERATION_DENSITY
_HOLD_MIN = streamhealth.HOLD_MIN_S
_HOLD_INTERVALS = streamhealth.HOLD_INTERVALS
_ORIENTATION_MIN_ANGLE = streamhealth.ORIENTATION_GATE_MIN_ANGLE
_LOW_PASS_TAU = model.LOW_PASS_TIME_CONSTANT
_SCALE_COHERENCE = model.SCALE_ERROR_COHERENCE_S
_motion_acceleration_variance = njit(cache=True)(model.motion_acceleration_variance)
_stamp_jitter_variance = njit(cache=True)(model.stamp_jitter_variance)
_is_impact = njit(cache=True)(model.is_impact)
_saturation_variance = njit(cache=True)(model.saturation_variance)
_interpolation_variance = njit(cache=True)(model.interpolation_variance)
_persistent_innovations = njit(cache=True)(persistent_innovations)
_SATURATION_FRACTION = model.SATURATION_FRACTION
_PLATEAU_REPEATS = model.PLATEAU_REPEATS
_PLATEAU_TOLERANCE = model.PLATEAU_TOLERANCE
_PLATEAU_FLOOR_ACCELEROMETER = model.PLATEAU_FLOOR_ACCELEROMETER
_PLATEAU_FLOOR_GYROSCOPE = model.PLATEAU_FLOOR_GYROSCOPE
_IMPLAUSIBLE = model.IMPLAUSIBLE_SAMPLE


@njit(cache=True)
def quaternion_product(a, b):
    """Hamilton product ``a ⊗ b`` (4,) of [w, x, y, z] quaternions."""
    out = np.empty(4)
    out[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]
    out[1] = a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2]
    out[2] = a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1]
    out[3] = a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]
    return out


@njit(cache=True)
def normalise(q):
    """``q / |q|``."""
    inverse = 1.0 / math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    out = np.empty(4)
    for i in range(4):
        out[i] = q[i] * inverse
    return out


@njit(cache=True)
def quaternion_exp(x, y, z):
    """``Exp(theta) = [cos(|theta|/2), sin(|theta|/2) theta/|theta|]``; ``[1, theta/2]``
    below SMALL_ANGLE; NaN for a non-finite theta."""
    out = np.empty(4)
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < _SMALL_ANGLE:
        out[0], out[1], out[2], out[3] = 1.0, 0.5 * x, 0.5 * y, 0.5 * z
    elif not math.isfinite(angle):
        out[:] = math.nan
    else:
        scale = math.sin(0.5 * angle) / angle
        out[0], out[1], out[2], out[3] = math.cos(0.5 * angle), scale * x, scale * y, scale * z
    return out


@njit(cache=True)
def quaternion_log(q):
    """Rotation vector theta (3,) rad with ``Exp(theta) = ±q``."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    if w < 0:
        w, x, y, z = -w, -x, -y, -z
    out = np.empty(3)
    norm = math.sqrt(x * x + y * y + z * z)
    if norm < _SMALL_ANGLE:
        out[0], out[1], out[2] = 2.0 * x, 2.0 * y, 2.0 * z
        return out
    scale = 2.0 * math.atan2(norm, w) / norm
    out[0], out[1], out[2] = scale * x, scale * y, scale * z
    return out


@njit(cache=True)
def rotate(orientation, x, y, z):
    """``q <- normalise(q ⊗ Exp([x, y, z]))`` on ``orientation[0:4]`` in place
    (:func:`quaternion_exp`, :func:`quaternion_product`, :func:`normalise`, same arithmetic,
    no temporary arrays)."""
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < _SMALL_ANGLE:
        b0, b1, b2, b3 = 1.0, 0.5 * x, 0.5 * y, 0.5 * z
    elif not math.isfinite(angle):
        b0 = b1 = b2 = b3 = math.nan
    else:
        scale = math.sin(0.5 * angle) / angle
        b0, b1, b2, b3 = math.cos(0.5 * angle), scale * x, scale * y, scale * z
    a0, a1, a2, a3 = orientation[0], orientation[1], orientation[2], orientation[3]
    q0 = a0 * b0 - a1 * b1 - a2 * b2 - a3 * b3
    q1 = a0 * b1 + a1 * b0 + a2 * b3 - a3 * b2
    q2 = a0 * b2 - a1 * b3 + a2 * b0 + a3 * b1
    q3 = a0 * b3 + a1 * b2 - a2 * b1 + a3 * b0
    inverse = 1.0 / math.sqrt(q0 * q0 + q1 * q1 + q2 * q2 + q3 * q3)
    orientation[0] = q0 * inverse
    orientation[1] = q1 * inverse
    orientation[2] = q2 * inverse
    orientation[3] = q3 * inverse


@njit(cache=True)
def conjugate(q):
    """``q* = [w, -x, -y, -z]``."""
    out = np.empty(4)
    out[0], out[1], out[2], out[3] = q[0], -q[1], -q[2], -q[3]
    return out


@njit(cache=True)
def rotation_matrix(q):
    """``R`` (3, 3) of a unit quaternion (kfusion.conventions' entries)."""
    R = np.empty((3, 3))
    rotation_into(q, R)
    return R


@njit(cache=True)
def rotation_into(q, R):
    """:func:`rotation_matrix` into ``R`` (3, 3), in place."""
    w, x, y, z = q[0], q[1], q[2], q[3]
    R[0, 0] = 1 - 2 * (y * y + z * z)
    R[0, 1] = 2 * (x * y - w * z)
    R[0, 2] = 2 * (x * z + w * y)
    R[1, 0] = 2 * (x * y + w * z)
    R[1, 1] = 1 - 2 * (x * x + z * z)
    R[1, 2] = 2 * (y * z - w * x)
    R[2, 0] = 2 * (x * z - w * y)
    R[2, 1] = 2 * (y * z + w * x)
    R[2, 2] = 1 - 2 * (x * x + y * y)


@njit(cache=True)
def matmul(A, B):
    """``A B`` by plain loops (small matrices: cheaper than a BLAS call)."""
    out = np.empty((A.shape[0], B.shape[1]))
    matmul_into(A, B, out)
    return out


@njit(cache=True)
def matmul_into(A, B, out):
    """``out = A B``, in place (``out`` must be neither A nor B): row i of ``out`` is the sum
    over k of ``A[i, k]`` times row k of B, in k's order."""
    rows, inner = A.shape
    columns = B.shape[1]
    out[:, :] = 0.0
    for i in range(rows):
        for k in range(inner):
            a = A[i, k]
            if a != 0.0:
                for j in range(columns):
                    out[i, j] += a * B[k, j]


@njit(cache=True)
def matvec(A, v):
    """``A v``."""
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        total = 0.0
        for k in range(A.shape[1]):
            total += A[i, k] * v[k]
        out[i] = total
    return out


@njit(cache=True)
def symmetrise(P):
    """``P <- (P + P^T) / 2`` in place."""
    n = P.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            value = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = value
            P[j, i] = value


@njit(cache=True)
def covariance_predict(x, P, F, B, u, Q):
    """Kalman predict in place: ``x <- F x + B u``, ``P <- F P F^T + Q``, then
    symmetrised."""
    x[:] = matvec(F, x) + matvec(B, u)
    # F P F^T = F (F P)^T for a symmetric P: both products have the sparse F on the left
    P[:, :] = matmul(F, matmul(F, P).T.copy()) + Q
    symmetrise(P)


@njit(cache=True)
def covariance_update(x, P, z, H, R):
    """Kalman update in place (filterpy's Joseph form), then symmetrised::

        y = z - H x,  S = H P H^T + R,  K = P H^T S^-1
        x <- x + K y,  P <- (I - K H) P (I - K H)^T + K R K^T
    """
    n = x.shape[0]
    y = z - matvec(H, x)
    PHT = matmul(P, H.T.copy())
    S = matmul(H, PHT) + R
    K = matmul(PHT, np.linalg.inv(S))
    x[:] = x + matvec(K, y)
    I_KH = np.eye(n) - matmul(K, H)
    P[:, :] = matmul(matmul(I_KH, P), I_KH.T.copy()) + matmul(matmul(K, R), K.T.copy())
    symmetrise(P)


@njit(cache=True)
def imu_blocks(R0, R1, dt, blocks):
    """The transition's bias blocks into ``blocks`` (2, 3, 3), in place (the entries of
    :func:`interval_matrices`, same arithmetic)::

        F_pb = -dt^2 (R0/3 + R1/6)  (blocks[0]),  F_vb = -dt (R0 + R1)/2  (blocks[1])
    """
    dt2 = dt * dt
    for i in range(3):
        for j in range(3):
            blocks[0, i, j] = -(R0[i, j] * (dt2 / 3.0) + R1[i, j] * (dt2 / 6.0))
            blocks[1, i, j] = -(R0[i, j] * (0.5 * dt) + R1[i, j] * (0.5 * dt))


@njit(cache=True)
def transition_times(A, out, dt, blocks, config):
    """``out = F A`` for the IMU transition ``F = I + [[0, dt I, F_pb], [0, 0, F_vb], 0]``
    (:func:`interval_matrices`' F, ``blocks`` from :func:`imu_blocks`; zero blocks: the no-IMU
    transition) without forming F: rows of A combined, the terms in :func:`matmul`'s order.
    ``out`` must not be ``A``."""
    p, v, b = int(config[C_POSITION]), int(config[C_VELOCITY]), int(config[C_BIAS])
    n = A.shape[0]
    columns = A.shape[1]
    for i in range(n):
        for j in range(columns):
            out[i, j] = A[i, j]
    for i in range(3):
        for j in range(columns):
            out[p + i, j] = ((((A[p + i, j] + dt * A[v + i, j]) + blocks[0, i, 0] * A[b, j])
                              + blocks[0, i, 1] * A[b + 1, j]) + blocks[0, i, 2] * A[b + 2, j])
            out[v + i, j] = (((A[v + i, j] + blocks[1, i, 0] * A[b, j])
                              + blocks[1, i, 1] * A[b + 1, j]) + blocks[1, i, 2] * A[b + 2, j])


@njit(cache=True)
def structured_predict(x, P, dt, blocks, control, pp, pv, vv, bb, config, work, interval):
    """Kalman predict in place with the IMU transition in blocks (:func:`transition_times`)::

        x <- F x + c,  P <- F (F P)^T + Q  (= F P F^T + Q for a symmetric P), symmetrised
    with ``c`` the control term ``B u`` (:func:`control_term`: position and velocity rows)
    and Q's nonzero entries per axis ``Q_pp, Q_pv, Q_vv, Q_bb`` (:func:`process_noise`).
    ``work`` (2, n, n) scratch; ``interval`` (:data:`TRANSITION_SIZE`,) becomes ``F interval``
    (:func:`accumulate_transition`) unless empty.
    Allocation-free: the compiled engine's hot path (equal to :func:`covariance_predict` with
    those F, B u, Q up to the sign of exact zeros)."""
    p, v, b = int(config[C_POSITION]), int(config[C_VELOCITY]), int(config[C_BIAS])
    n = x.shape[0]
    for i in range(3):
        position = (((x[p + i] + dt * x[v + i]) + blocks[0, i, 0] * x[b])
                    + blocks[0, i, 1] * x[b + 1]) + blocks[0, i, 2] * x[b + 2]
        velocity = ((x[v + i] + blocks[1, i, 0] * x[b]) + blocks[1, i, 1] * x[b + 1]
                    ) + blocks[1, i, 2] * x[b + 2]
        x[p + i] = position + control[p + i]
        x[v + i] = velocity + control[v + i]
    FP = work[0]
    transition_times(P, FP, dt, blocks, config)
    transposed = work[1]
    for i in range(n):
        for j in range(n):
            transposed[i, j] = FP[j, i]
    transition_times(transposed, P, dt, blocks, config)
    for i in range(3):
        P[p + i, p + i] += pp
        P[p + i, v + i] += pv
        P[v + i, p + i] += pv
        P[v + i, v + i] += vv
        P[b + i, b + i] += bb
    symmetrise(P)
    accumulate_transition(interval, dt, blocks)


@njit(cache=True)
def control_term(R0, R1, dt, f0, f1, config, control):
    """``c = B u`` (n,) in place, ``u = [f0; f1; g]`` (:func:`interval_matrices`' B, in
    :func:`matvec`'s order)::

        c_p = dt^2 (R0 f0/3 + R1 f1/6) + dt^2/2 g,  c_v = dt (R0 f0 + R1 f1)/2 + dt g
    """
    p, v = int(config[C_POSITION]), int(config[C_VELOCITY])
    control[:] = 0.0
    dt2 = dt * dt
    for i in range(3):
        position = 0.0
        velocity = 0.0
        for j in range(3):
            position += R0[i, j] * (dt2 / 3.0) * f0[j]
            velocity += R0[i, j] * (0.5 * dt) * f0[j]
        for j in range(3):
            position += R1[i, j] * (dt2 / 6.0) * f1[j]
            velocity += R1[i, j] * (0.5 * dt) * f1[j]
        control[p + i] = position + 0.5 * dt2 * config[C_GRAVITY + i]
        control[v + i] = velocity + dt * config[C_GRAVITY + i]


@njit(cache=True)
def noise_terms(dt, acceleration_variance, bias_variance, config):
    """Q's entries per axis ``(Q_pp, Q_pv, Q_vv, Q_bb)`` (:func:`process_noise`'s formula)."""
    a2 = config[C_ACC_DENSITY] * config[C_ACC_DENSITY]
    extra = acceleration_variance
    dt2 = dt * dt
    pp = a2 * dt2 * dt + extra * dt2 * dt2 / 4.0
    pv = a2 * dt2 + extra * dt2 * dt / 2.0
    vv = a2 * dt + extra * dt2
    bb = config[C_ACC_WALK] * config[C_ACC_WALK] * dt + bias_variance
    return pp, pv, vv, bb


@njit(cache=True)
def inverse3(S, out):
    """``out = S^-1`` for a 3x3 matrix by its adjugate: ``S^-1 = adj(S) / det(S)`` (NaN or inf
    entries when S is singular or not finite)."""
    c00 = S[1, 1] * S[2, 2] - S[1, 2] * S[2, 1]
    c01 = S[1, 2] * S[2, 0] - S[1, 0] * S[2, 2]
    c02 = S[1, 0] * S[2, 1] - S[1, 1] * S[2, 0]
    inverse_det = 1.0 / (S[0, 0] * c00 + S[0, 1] * c01 + S[0, 2] * c02)
    out[0, 0] = c00 * inverse_det
    out[1, 0] = c01 * inverse_det
    out[2, 0] = c02 * inverse_det
    out[0, 1] = (S[0, 2] * S[2, 1] - S[0, 1] * S[2, 2]) * inverse_det
    out[1, 1] = (S[0, 0] * S[2, 2] - S[0, 2] * S[2, 0]) * inverse_det
    out[2, 1] = (S[0, 1] * S[2, 0] - S[0, 0] * S[2, 1]) * inverse_det
    out[0, 2] = (S[0, 1] * S[1, 2] - S[0, 2] * S[1, 1]) * inverse_det
    out[1, 2] = (S[0, 2] * S[1, 0] - S[0, 0] * S[1, 2]) * inverse_det
    out[2, 2] = (S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]) * inverse_det


@njit(cache=True)
def innovation_covariance(P, H, noise_variance, PHT, S):
    """``P H^T`` into PHT (n, 3) and ``S = H P H^T + r I`` into S (3, 3), in place."""
    n = P.shape[0]
    for i in range(n):
        for k in range(3):
            total = 0.0
            for j in range(n):
                h = H[k, j]
                if h != 0.0:
                    total += P[i, j] * h
            PHT[i, k] = total
    for k in range(3):
        for m in range(3):
            total = 0.0
            for i in range(n):
                h = H[k, i]
                if h != 0.0:
                    total += h * PHT[i, m]
            S[k, m] = total + (noise_variance if k == m else 0.0)


LOOSE_PRIOR: Final = 1e4
"""``S_kk / R`` beyond which :func:`position_update` applies the Joseph form in filterpy's order
rather than expanded: the expanded form's error, a few eps times the prior, is then below
1e-11 of the posterior."""


@njit(cache=True)
def position_update(x, P, y, S_inverse, S, H, noise_variance, PHT, K, A, position, lever):
    """Kalman update in place with the innovation y (3,), ``S^-1`` and S (3, 3), H (3, n)
    (the output map of :func:`output_map_into`: I on the states from index ``position``, and
    nonzero on those from ``lever`` only when ``lever >= 0``), ``R = noise_variance I``,
    ``P H^T`` (n, 3) (:func:`innovation_covariance`; overwritten) and scratch K (n, 3) and A
    (n, n); filterpy's Joseph form, symmetrised (:meth:`KalmanFusion._symmetrise`)::

        K = P H^T S^-1,  x <- x + K y,
        P <- (I - K H) P (I - K H)^T + K R K^T

    Where a diagonal entry of S is more than :data:`LOOSE_PRIOR` times R (a fix on a far looser
    prior), in filterpy's order::

        A = (I - K H) P = P - K (P H^T)^T,
        P <- (M + M^T) / 2 + R K K^T  with  M = A (I - K H)^T = A - (A H^T) K^T

    so that an error in A, of the order of eps |P|, is multiplied by ``I - K H`` (near 0
    there) again; ``A H^T`` is read from the A computed (its error cancels in
    ``A - (A H^T) K^T``; from ``P H^T - K H P H^T`` it would not). Elsewhere expanded, about
    40 % cheaper: ``P - K (P H^T)^T - (P H^T) K^T + K S K^T`` (``S = H P H^T + R``), whose error
    of a few eps |P| is then below 1e-11 of the posterior. Expanded everywhere, after 500 s
    without data (a prior position variance of 3.8e10 m^2 against R = 9e-8 m^2) the posterior
    position std came out 3.91 mm against the exact 3.56 mm, which filterpy's order gives.
    Products with 3 inner terms, no n x n x n product."""
    n = x.shape[0]
    for i in range(n):
        for k in range(3):
            K[i, k] = PHT[i, 0] * S_inverse[0, k] + PHT[i, 1] * S_inverse[1, k] + PHT[i, 2] * (
                S_inverse[2, k])
    for i in range(n):
        x[i] += K[i, 0] * y[0] + K[i, 1] * y[1] + K[i, 2] * y[2]
    limit = LOOSE_PRIOR * noise_variance
    if not (S[0, 0] > limit or S[1, 1] > limit or S[2, 2] > limit):
        for i in range(n):
            KS0 = K[i, 0] * S[0, 0] + K[i, 1] * S[1, 0] + K[i, 2] * S[2, 0]
            KS1 = K[i, 0] * S[0, 1] + K[i, 1] * S[1, 1] + K[i, 2] * S[2, 1]
            KS2 = K[i, 0] * S[0, 2] + K[i, 1] * S[1, 2] + K[i, 2] * S[2, 2]
            for j in range(i, n):
                value = (P[i, j] - (K[i, 0] * PHT[j, 0] + K[i, 1] * PHT[j, 1]
                                    + K[i, 2] * PHT[j, 2])
                         - (PHT[i, 0] * K[j, 0] + PHT[i, 1] * K[j, 1] + PHT[i, 2] * K[j, 2])
                         + (KS0 * K[j, 0] + KS1 * K[j, 1] + KS2 * K[j, 2]))
                P[i, j] = value
                P[j, i] = value
        return
    for i in range(n):  # A = (I - K H) P
        k0, k1, k2 = K[i, 0], K[i, 1], K[i, 2]
        for j in range(n):
            A[i, j] = P[i, j] - (k0 * PHT[j, 0] + k1 * PHT[j, 1] + k2 * PHT[j, 2])
    AHT = PHT  # P H^T is spent: A H^T in its place, from H's nonzero columns
    for i in range(n):
        for k in range(3):
            total = A[i, position + k]
            if lever >= 0:
                total = ((total + A[i, lever] * H[k, lever]) + A[i, lever + 1] * H[k, lever + 1]
                         ) + A[i, lever + 2] * H[k, lever + 2]
            AHT[i, k] = total
    for i in range(n):  # (M + M^T) / 2 with M = A - (A H^T) K^T, then + R K K^T (symmetric)
        k0, k1, k2 = K[i, 0], K[i, 1], K[i, 2]
        h0, h1, h2 = AHT[i, 0], AHT[i, 1], AHT[i, 2]
        for j in range(i, n):
            upper = A[i, j] - (h0 * K[j, 0] + h1 * K[j, 1] + h2 * K[j, 2])
            lower = A[j, i] - (AHT[j, 0] * k0 + AHT[j, 1] * k1 + AHT[j, 2] * k2)
            value = 0.5 * (upper + lower) + noise_variance * (
                k0 * K[j, 0] + k1 * K[j, 1] + k2 * K[j, 2])
            P[i, j] = value
            P[j, i] = value


@njit(cache=True)
def interval_matrices(R0, R1, dt, n, config):
    """F (n, n) and B (n, 9) over dt with ``R_global_imu`` R0, R1 at the ends::

        F = [[I, dt I, -dt^2 (R0/3 + R1/6)], [0, I, -dt (R0 + R1)/2], [0, 0, I]] (+ I on l)
        B = [[dt^2 R0/3, dt^2 R1/6, dt^2/2 I], [dt R0/2, dt R1/2, dt I], [0, 0, 0]]
    (:func:`kfusion.kalman.model.fill_interval`)."""
    p, v, b = int(config[C_POSITION]), int(config[C_VELOCITY]), int(config[C_BIAS])
    F = np.eye(n)
    B = np.zeros((n, 9))
    dt2 = dt * dt
    for i in range(3):
        F[p + i, v + i] = dt
        for j in range(3):
            position_start = R0[i, j] * (dt2 / 3.0)
            position_end = R1[i, j] * (dt2 / 6.0)
            velocity_start = R0[i, j] * (0.5 * dt)
            velocity_end = R1[i, j] * (0.5 * dt)
            F[p + i, b + j] = -(position_start + position_end)
            F[v + i, b + j] = -(velocity_start + velocity_end)
            B[p + i, j] = position_start
            B[p + i, 3 + j] = position_end
            B[v + i, j] = velocity_start
            B[v + i, 3 + j] = velocity_end
        B[p + i, 6 + i] = 0.5 * dt2
        B[v + i, 6 + i] = dt
    return F, B


@njit(cache=True)
def process_noise(dt, n, acceleration_variance, bias_variance, config):
    """Q (n, n) (:func:`kfusion.kalman.model.process_noise`)::

        Q_pp = sigma_a^2 dt^3 + e dt^4/4,  Q_pv = sigma_a^2 dt^2 + e dt^3/2,
        Q_vv = sigma_a^2 dt + e dt^2,      Q_bb = sigma_b^2 dt + bias_variance
    """
    p, v, b = int(config[C_POSITION]), int(config[C_VELOCITY]), int(config[C_BIAS])
    Q = np.zeros((n, n))
    pp, pv, vv, bb = noise_terms(dt, acceleration_variance, bias_variance, config)
    for axis in range(3):
        Q[p + axis, p + axis] = pp
        Q[p + axis, v + axis] = pv
        Q[v + axis, p + axis] = pv
        Q[v + axis, v + axis] = vv
        Q[b + axis, b + axis] = bb
    return Q


@njit(cache=True)
def hold_horizon(imu_interval, dropout):
    """``min(dropout, max(HOLD_MIN_S, HOLD_INTERVALS interval))`` (HOLD_MIN_S while the
    interval is unknown) (:func:`kfusion.streamhealth.hold_horizon`)."""
    if not math.isfinite(imu_interval):
        return min(dropout, _HOLD_MIN)
    return min(dropout, max(_HOLD_MIN, _HOLD_INTERVALS * imu_interval))


@njit(cache=True)
def dead_reckoning_until(scalars, config):
    """-inf without IMU or after an outage since the fix, else imu_time + hold
    (:func:`kfusion.streamhealth.dead_reckoning_until`)."""
    if math.isnan(scalars[IMU_TIME]) or scalars[OUTAGE_SINCE_FIX] != 0.0:
        return -math.inf
    return scalars[IMU_TIME] + hold_horizon(scalars[IMU_INTERVAL], config[C_DROPOUT])


@njit(cache=True)
def orientation_propagate(orientation, w0, w1, dt, extra, config):
    """``q <- normalise(q ⊗ Exp(((w0 + w1)/2 - b_g) dt))``, covariance
    ``P' = F P F^T + Q`` with ``F = [[1, -dt], [0, 1]]``
    (:meth:`kfusion.kalman.orientation.OrientationTracker.propagate`)."""
    if orientation[14] == 0.0 or dt <= 0:
        return
    rate0 = 0.5 * (w0[0] + w1[0]) - orientation[4]
    rate1 = 0.5 * (w0[1] + w1[1]) - orientation[5]
    rate2 = 0.5 * (w0[2] + w1[2]) - orientation[6]
    rotate(orientation, rate0 * dt, rate1 * dt, rate2 * dt)
    scale_variance = config[C_GYRO_SCALE_VARIANCE]
    if scale_variance > 0.0:
        rx = orientation[10] + rate0 * dt
        ry = orientation[11] + rate1 * dt
        rz = orientation[12] + rate2 * dt
        orientation[10], orientation[11], orientation[12] = rx, ry, rz
        peak = max(orientation[13], scale_variance * (rx * rx + ry * ry + rz * rz))
        extra += peak - orientation[13]
        orientation[13] = peak
    angle, cross, bias = orientation[7], orientation[8], orientation[9]
    g2 = config[C_GYRO_DENSITY] * config[C_GYRO_DENSITY]
    b2 = config[C_GYRO_WALK] * config[C_GYRO_WALK]
    orientation[7] = (angle - 2.0 * dt * cross + dt * dt * bias + g2 * dt
                      + b2 * dt * dt * dt / 3.0 + extra)
    orientation[8] = cross - dt * bias - 0.5 * b2 * dt * dt
    orientation[9] = bias + b2 * dt


@njit(cache=True)
def orientation_correct(orientation, q_measured, config):
    """Two-state Kalman correction per axis: ``S = P_tt + sigma_m^2``,
    ``K = [P_tt, P_tb] / S``, ``q <- q ⊗ Exp(K_t z)``, ``b_g <- b_g + K_b z``,
    ``P <- (I - K H) P``; the rotation a scale error acts on keeps ``(1 - K_t) r``
    (:meth:`OrientationTracker.correct`, :func:`kfusion.kalman.orientation.absorbed_rotation`);
    first the innovations' persistence test
    (:func:`kfusion.kalman.orientation.persistent_innovations`), which scales the covariance by
    ``T / 3`` beyond its limit."""
    innovation = quaternion_log(quaternion_product(conjugate(orientation[0:4]),
                                                   q_measured))
    angle, cross, bias = orientation[7], orientation[8], orientation[9]
    S = angle + config[C_ORIENTATION_VARIANCE]
    if S <= 0.0:
        orientation[10:14] = 0.0
        orientation[0:4] = normalise(q_measured)
        return
    mean = INNOVATION_MEAN
    (mx, my, mz), square, statistic = _persistent_innovations(
        (orientation[mean], orientation[mean + 1], orientation[mean + 2]),
        orientation[INNOVATION_SQUARE], innovation, S)
    if statistic > PERSISTENCE_LIMIT:
        factor = statistic / 3.0
        angle, cross, bias = factor * angle, factor * cross, factor * bias
        S = angle + config[C_ORIENTATION_VARIANCE]
        mx = my = mz = 0.0
        square = 3.0
    orientation[mean], orientation[mean + 1], orientation[mean + 2] = mx, my, mz
    orientation[INNOVATION_SQUARE] = square
    gain_angle = angle / S
    keep = 1.0 - gain_angle
    rx, ry, rz = keep * orientation[10], keep * orientation[11], keep * orientation[12]
    orientation[10], orientation[11], orientation[12] = rx, ry, rz
    orientation[13] = config[C_GYRO_SCALE_VARIANCE] * (rx * rx + ry * ry + rz * rz)
    gain_bias = cross / S
    correction = quaternion_exp(gain_angle * innovation[0], gain_angle * innovation[1],
                                gain_angle * innovation[2])
    orientation[0:4] = normalise(quaternion_product(orientation[0:4], correction))
    for i in range(3):
        orientation[4 + i] = orientation[4 + i] + gain_bias * innovation[i]
    orientation[7] = (1.0 - gain_angle) * angle
    orientation[8] = (1.0 - gain_angle) * cross
    orientation[9] = bias - gain_bias * cross


_FORGOTTEN_VARIANCE = model.FORGOTTEN_POSITION_STD ** 2


@njit(cache=True)
def state_usable(x, P, orientation, p):
    """False when a propagation overflowed or left a position variance (the block from index p)
    beyond :data:`kfusion.kalman.model.FORGOTTEN_POSITION_STD` squared
    (:func:`kfusion.kalman.model.state_usable`)."""
    total = orientation[7] + orientation[8] + orientation[9] + (
        orientation[0] + orientation[1] + orientation[2] + orientation[3])
    if not math.isfinite(total):
        return False
    n = x.shape[0]
    for i in range(n):
        if not math.isfinite(x[i]):
            return False
        for j in range(n):
            if not math.isfinite(P[i, j]):
                return False
    for i in range(3):
        if not P[p + i, p + i] <= _FORGOTTEN_VARIANCE:
            return False
    return True


@njit(cache=True)
def clear_orientation(orientation):
    """An uninitialised orientation state, in place: identity quaternion, zero bias and
    covariance, no rotation since a fix, the innovations' mean square at the model's 3
    (:class:`kfusion.kalman.orientation.OrientationState`'s defaults)."""
    orientation[:] = 0.0
    orientation[0] = 1.0
    orientation[INNOVATION_SQUARE] = 3.0


@njit(cache=True)
def reset(x, P, orientation, scalars, counters):
    """Forget position and orientation (``resets``): lost until the next fix."""
    scalars[INITIALISED_FLAG] = 0.0
    clear_orientation(orientation)
    x[:] = 0.0
    P[:, :] = np.eye(x.shape[0])
    scalars[LAST_FIX] = math.nan
    scalars[LAST_ORIENTATION_FIX] = math.nan
    counters[13] += 1


@njit(cache=True)
def accumulate_transition(transition, dt, blocks):
    """``Phi <- F Phi`` for ``F = I + [[0, dt I, F_pb], [0, 0, F_vb], 0]`` (``blocks`` (2, 3,
    3): F_pb, F_vb from :func:`imu_blocks`; zeros: the no-IMU transition), in place on Phi's
    free entries (:func:`pack_prediction`'s form, ``transition`` (TRANSITION_SIZE,): the
    product of the transitions since the last mocap row, which the smoother needs,
    ``cov(x_k, x_{k+1|k}) = P_k Phi^T``). Every such F keeps the form, and the product's free
    entries are::

        T <- T + dt,  Phi_pb <- (Phi_pb + dt Phi_vb) + F_pb,  Phi_vb <- Phi_vb + F_vb
    the bits of the whole (n, n) product (:func:`transition_times` on it, or :func:`matmul`),
    whose other terms add exact zeros (up to the sign of an exact zero). An empty
    ``transition``: not kept."""
    if transition.shape[0] == 0:
        return
    transition[0] = transition[0] + dt
    for i in range(3):
        for j in range(3):
            pb, vb = 1 + 3 * i + j, 10 + 3 * i + j
            transition[pb] = (transition[pb] + dt * transition[vb]) + blocks[0, i, j]
            transition[vb] = transition[vb] + blocks[1, i, j]


@njit(cache=True)
def work_size(n):
    """Length of the scratch array of the prediction and the update (:func:`work_views`,
    :func:`update_views`)."""
    return 2 * n * n + n + 18 + 12 + 18 + 6 + 9 * n + 24


@njit(cache=True, inline="always")
def update_views(work, n):
    """Views ``(H (3, n), offset (3,), y (3,), P H^T (n, 3), S (3, 3), S^-1 (3, 3), K (n, 3))``
    into the scratch array after :func:`work_views`' (the update's temporaries)."""
    start = 2 * n * n + n + 18 + 12 + 18 + 6
    H = work[start:start + 3 * n].reshape((3, n))
    start += 3 * n
    offset, y = work[start:start + 3], work[start + 3:start + 6]
    start += 6
    PHT = work[start:start + 3 * n].reshape((n, 3))
    start += 3 * n
    S = work[start:start + 9].reshape((3, 3))
    S_inverse = work[start + 9:start + 18].reshape((3, 3))
    start += 18
    return H, offset, y, PHT, S, S_inverse, work[start:start + 3 * n].reshape((n, 3))


@njit(cache=True, inline="always")
def work_views(work, n):
    """Views ``(products (2, n, n), blocks (2, 3, 3), control (n,), f0 (3,), omega0 (3,),
    previous low-pass (3,), R0 (3, 3), R1 (3, 3), f (3,), omega (3,))`` into one scratch array
    (:func:`work_size`): the IMU prediction's temporaries, allocated once per kernel call
    instead of once per sample."""
    end = 2 * n * n
    products = work[0:end].reshape((2, n, n))
    blocks = work[end:end + 18].reshape((2, 3, 3))
    end += 18
    control = work[end:end + n]
    end += n
    f0, omega0, previous_low_pass = work[end:end + 3], work[end + 3:end + 6], work[end + 6:end + 9]
    end += 12
    R0 = work[end:end + 9].reshape((3, 3))
    R1 = work[end + 9:end + 18].reshape((3, 3))
    end += 18
    return (products, blocks, control, f0, omega0, previous_low_pass, R0, R1,
            work[end:end + 3], work[end + 3:end + 6])


@njit(cache=True)
def advance_without_imu(t, x, P, orientation, scalars, config, counters, interval):
    """No IMU over [time, t]: ``p' = p + v dt``, ``v' = v``, white acceleration q::

        Q_pp = q^2 dt^3/3, Q_pv = q^2 dt^2/2, Q_vv = q^2 dt, Q_bb = sigma_b^2 dt
    and the orientation becomes unknown (:meth:`KalmanFusion._advance_without_imu`)."""
    dt = t - scalars[TIME]
    n = x.shape[0]
    if scalars[INITIALISED_FLAG] != 0.0:
        p, v, b = int(config[C_POSITION]), int(config[C_VELOCITY]), int(config[C_BIAS])
        F = np.eye(n)
        Q = np.zeros((n, n))
        q2 = _NO_IMU_DENSITY * _NO_IMU_DENSITY
        walk2 = config[C_ACC_WALK] * config[C_ACC_WALK]
        for i in range(3):
            F[p + i, v + i] = dt
            Q[p + i, p + i] = q2 * dt ** 3 / 3.0
            Q[p + i, v + i] = q2 * dt ** 2 / 2.0
            Q[v + i, p + i] = q2 * dt ** 2 / 2.0
            Q[v + i, v + i] = q2 * dt
            Q[b + i, b + i] = walk2 * dt
        covariance_predict(x, P, F, np.zeros((n, 9)), np.zeros(9), Q)
        accumulate_transition(interval, dt, np.zeros((2, 3, 3)))
        if scalars[OUTAGE_SINCE_FIX] == 0.0:
            counters[14] += 1
        scalars[OUTAGE_SINCE_FIX] = 1.0
        if not state_usable(x, P, orientation, int(config[C_POSITION])):
            reset(x, P, orientation, scalars, counters)
    if orientation[14] != 0.0:
        orientation[7] = _UNKNOWN_VARIANCE
        orientation[8] = 0.0
    scalars[TIME] = t


@njit(cache=True)
def squared_distance(a, b):
    dx, dy, dz = a[0] - b[0], a[1] - b[1], a[2] - b[2]
    return dx * dx + dy * dy + dz * dz


@njit(cache=True, inline="always")
def advance_with_imu(t, new_sample, f_end, omega_end, x, P, orientation, scalars, config,
                     counters, interval, work):
    """Predict over [time, t] with the IMU (:meth:`KalmanFusion._advance_with_imu`): the
    specific force and rate linear between the interval's ends (or the held sample held),
    the orientation propagated, then ``x <- F x + B u``, ``P <- F P F^T + Q`` with
    ``u = [f0; f1; g]`` (:mod:`kfusion.kalman.model`). ``work``: scratch (:func:`work_views`;
    its f, omega may be ``f_end``, ``omega_end``)."""
    dt = t - scalars[TIME]
    n = x.shape[0]
    if not math.isnan(scalars[ACCELEROMETER]) and orientation[14] != 0.0:
        (products, blocks, control, f0, omega0, previous_low_pass, R0, R1, _,
         _) = work_views(work, n)
        for i in range(3):
            f0[i] = scalars[ACCELEROMETER + i]
            omega0[i] = scalars[GYROSCOPE + i]
        if new_sample:
            f1 = f_end
            omega1 = omega_end
            if scalars[TIME] > scalars[IMU_TIME]:
                weight = ((scalars[TIME] - scalars[IMU_TIME])
                          / (t - scalars[IMU_TIME]))
                for i in range(3):
                    f0[i] = f0[i] + weight * (f_end[i] - f0[i])
                    omega0[i] = omega0[i] + weight * (omega_end[i] - omega0[i])
        else:
            f1 = f0
            omega1 = omega0
        noise_variance = config[C_ACC_DENSITY] ** 2 / dt
        impact = _is_impact(squared_distance(f0, f1), dt, config[C_IMPACT_JERK],
                            noise_variance)
        if impact:
            scalars[LAST_IMPACT] = t
        rotation_into(orientation[0:4], R0)
        angle_variance = orientation[7]
        orientation_propagate(orientation, omega0, omega1, dt,
                              scalars[GYROSCOPE_EXTRA] * dt * dt, config)
        rotation_into(orientation[0:4], R1)
        had_low_pass = not math.isnan(scalars[LOW_PASS])
        for i in range(3):
            previous_low_pass[i] = scalars[LOW_PASS + i]
        if had_low_pass:
            weight = -math.expm1(-dt / _LOW_PASS_TAU)
            for i in range(3):
                scalars[LOW_PASS + i] = (previous_low_pass[i]
                                         + weight * (f1[i] - previous_low_pass[i]))
        else:
            scalars[LOW_PASS:LOW_PASS + 3] = f1
        if scalars[INITIALISED_FLAG] != 0.0:
            force_squared = 0.5 * (f0[0] * f0[0] + f0[1] * f0[1] + f0[2] * f0[2]
                                   + f1[0] * f1[0] + f1[1] * f1[1] + f1[2] * f1[2])
            bias_variance = config[C_TILT_INFLATION] * force_squared * max(
                orientation[7] - angle_variance, 0.0)
            scale = config[C_ACC_SCALE]
            if scale > 0.0 and had_low_pass and dt > 0.0:
                change = squared_distance(scalars[LOW_PASS:LOW_PASS + 3], previous_low_pass)
                bias_variance += scale * scale * change * _SCALE_COHERENCE / dt
            acceleration_variance = scalars[ACCELEROMETER_EXTRA] + _interpolation_variance(
                squared_distance(f0, f1), noise_variance, impact) + _motion_acceleration_variance(
                    squared_distance(f1, scalars[LOW_PASS:LOW_PASS + 3]), dt, scale,
                    _LOW_PASS_TAU) + _stamp_jitter_variance(
                        squared_distance(f0, f1), dt, config[C_TIMESTAMP_JITTER])
            imu_blocks(R0, R1, dt, blocks)
            control_term(R0, R1, dt, f0, f1, config, control)
            pp, pv, vv, bb = noise_terms(dt, acceleration_variance, bias_variance, config)
            structured_predict(x, P, dt, blocks, control, pp, pv, vv, bb, config, products,
                               interval)
        if not state_usable(x, P, orientation, int(config[C_POSITION])):
            reset(x, P, orientation, scalars, counters)
    scalars[TIME] = t


@njit(cache=True, inline="always")
def advance(t, new_sample, f_end, omega_end, x, P, orientation, scalars, config, counters,
            interval, work):
    """Propagate to t: with the IMU where it covers the interval, the no-IMU model
    after (:func:`kfusion.streamhealth.imu_interval_split`)."""
    if math.isnan(scalars[TIME]):
        scalars[TIME] = t
        return
    if t - scalars[TIME] <= 0.0:
        return
    state_time = scalars[TIME]
    imu_time = scalars[IMU_TIME]
    if math.isnan(imu_time):
        covered = state_time
    elif new_sample:
        covered = t if t - imu_time <= config[C_DROPOUT] else state_time
    else:
        hold = hold_horizon(scalars[IMU_INTERVAL], config[C_DROPOUT])
        covered = min(max(imu_time + hold, state_time), t)
    if covered < t:
        if covered > state_time:
            advance_with_imu(covered, False, f_end, omega_end, x, P, orientation, scalars,
                             config, counters, interval, work)
        advance_without_imu(t, x, P, orientation, scalars, config, counters, interval)
        return
    advance_with_imu(t, new_sample, f_end, omega_end, x, P, orientation, scalars, config,
                     counters, interval, work)


@njit(cache=True)
def limit(sample, sensor_range):
    """Clip a saturated sample (an axis at 99.9 % of the range or beyond) to the range;
    returns (sample, extra variance ``(range/2)^2`` or 0)."""
    clipped = np.empty(3)
    extra = limit_into(sample, sensor_range, clipped)
    return clipped, extra


@njit(cache=True)
def limit_into(sample, sensor_range, out):
    """:func:`limit` into ``out`` (3,); returns the extra variance."""
    largest = max(abs(sample[0]), abs(sample[1]), abs(sample[2]))
    if largest < _SATURATION_FRACTION * sensor_range:
        out[0], out[1], out[2] = sample[0], sample[1], sample[2]
        return 0.0
    for i in range(3):
        out[i] = min(max(sample[i], -sensor_range), sensor_range)
    return _saturation_variance(sensor_range)


@njit(cache=True, inline="always")
def plateau_level(sample, scalars, held, plateau, floor):
    """:func:`kfusion.kalman.model.plateau_step` of ``sample`` (3,) against the held sample
    ``scalars[held:held + 3]``, on the test's state ``scalars[plateau:plateau + 6]`` (tops (3),
    repeats (3)), in place. Returns the largest level of an axis saturating the sample on its
    plateau, else 0."""
    level = 0.0
    for axis in range(3):
        value = abs(sample[axis])
        top = scalars[plateau + axis]
        repeats = scalars[plateau + 3 + axis]
        if value > top:
            top = value
            repeats = 0.0
        if value >= floor and value >= _SATURATION_FRACTION * top \
                and sample[axis] == scalars[held + axis]:
            repeats += 1.0
        if repeats >= _PLATEAU_REPEATS and value >= _PLATEAU_TOLERANCE * top:
            level = max(level, top)
        scalars[plateau + axis] = top
        scalars[plateau + 3 + axis] = repeats
    return level


@njit(cache=True, inline="always")
def predict_step(stamp, f_raw, omega_raw, x, P, orientation, scalars, config, counters,
                 interval, work):
    """One finite IMU sample with a stamp after the last (:meth:`KalmanFusion.
    _predict_valid`): reject _IMPLAUSIBLE values, clip saturated ones, advance to
    ``t = stamp - latency`` with the first-order hold, hold the sample. ``work``: scratch
    (:func:`work_views`)."""
    largest = 0.0
    for i in range(3):
        largest = max(largest, abs(f_raw[i]), abs(omega_raw[i]))
    if largest > _IMPLAUSIBLE:
        counters[1] += 1
        return
    f, omega = work_views(work, x.shape[0])[8:10]
    acc_extra = limit_into(f_raw, config[C_ACC_RANGE], f)
    level = plateau_level(f_raw, scalars, ACCELEROMETER, ACCELEROMETER_PLATEAU,
                          _PLATEAU_FLOOR_ACCELEROMETER)
    if acc_extra == 0.0 and level > 0.0:  # clipping below the range: a plateau
        acc_extra = _saturation_variance(level)
    if acc_extra != 0.0:
        counters[5] += 1
    gyro_extra = limit_into(omega_raw, config[C_GYRO_RANGE], omega)
    level = plateau_level(omega_raw, scalars, GYROSCOPE, GYROSCOPE_PLATEAU,
                          _PLATEAU_FLOOR_GYROSCOPE)
    if gyro_extra == 0.0 and level > 0.0:
        gyro_extra = _saturation_variance(level)
    if gyro_extra != 0.0:
        counters[6] += 1
    t = stamp - config[C_LATENCY]
    imu_time = scalars[IMU_TIME]
    if not math.isnan(imu_time) and t - imu_time > config[C_DROPOUT]:
        counters[3] += 1
    if not math.isnan(scalars[TIME]) and t <= scalars[TIME] and not math.isnan(imu_time):
        if t < scalars[TIME]:
            counters[4] += 1
    else:
        advance(t, True, f, omega, x, P, orientation, scalars, config, counters, interval,
                work)
    scalars[ACCELEROMETER:ACCELEROMETER + 3] = f
    scalars[GYROSCOPE:GYROSCOPE + 3] = omega
    scalars[ACCELEROMETER_EXTRA] = acc_extra
    scalars[GYROSCOPE_EXTRA] = gyro_extra
    if not math.isnan(imu_time):
        scalars[IMU_INTERVAL] = t - imu_time
    scalars[IMU_STAMP] = stamp
    scalars[IMU_TIME] = t
    counters[0] += 1


@njit(cache=True)
def output_map(q_global_imu, n, config):
    """(H, c): rigid-body point ``= H x + c`` at ``q_global_imu``
    (:meth:`KalmanFusion._output_map`)."""
    H = np.empty((3, n))
    offset = np.empty(3)
    output_map_into(q_global_imu, config, H, offset, np.empty((3, 3)))
    return H, offset


@njit(cache=True)
def output_map_into(q_global_imu, config, H, offset, rotation):
    """:func:`output_map` into H (3, n) and ``offset`` (3,); ``rotation`` (3, 3) scratch::

        H = [I 0 0] (and -R_global_body on the lever-arm states), c = -R_global_body l
    with ``R_global_body = R(q_global_imu) R_imu_body`` (the terms in :func:`matmul`'s and
    :func:`matvec`'s order)."""
    p = int(config[C_POSITION])
    lever_state = int(config[C_LEVER_STATE])
    H[:, :] = 0.0
    offset[:] = 0.0
    for i in range(3):
        H[i, p + i] = 1.0
    if config[C_LEVER_GIVEN] == 0.0 and lever_state < 0:
        return
    rotation_into(q_global_imu, rotation)
    for i in range(3):
        body0 = 0.0
        body1 = 0.0
        body2 = 0.0
        for k in range(3):
            a = rotation[i, k]
            if a != 0.0:
                body0 += a * config[C_R_IMU_BODY + 3 * k]
                body1 += a * config[C_R_IMU_BODY + 3 * k + 1]
                body2 += a * config[C_R_IMU_BODY + 3 * k + 2]
        if lever_state >= 0:
            H[i, lever_state] = -body0
            H[i, lever_state + 1] = -body1
            H[i, lever_state + 2] = -body2
        else:
            offset[i] = -(((0.0 + body0 * config[C_LEVER]) + body1 * config[C_LEVER + 1])
                          + body2 * config[C_LEVER + 2])


@njit(cache=True)
def mark_fix(t, scalars, counters):
    scalars[OUTAGE_SINCE_FIX] = 0.0
    scalars[LAST_FIX] = t
    scalars[LAST_FRAME_FUSED] = 1.0
    counters[7] += 1


@njit(cache=True)
def initialise(t, z, H, offset, x, P, scalars, config, counters):
    """First fix: ``x = [z - c, 0, 0(, 0)]``, ``P = P0`` (:func:`kfusion.kalman.model.
    initial_covariance`, with the lever-arm correlation ``sigma_l^2 R_gb``)."""
    p, v, b = int(config[C_POSITION]), int(config[C_VELOCITY]), int(config[C_BIAS])
    lever_state = int(config[C_LEVER_STATE])
    x[:] = 0.0
    P[:, :] = 0.0
    position_variance = config[C_POSITION_NOISE] ** 2
    velocity_variance = config[C_INITIAL_VELOCITY_STD] ** 2
    bias_variance = config[C_INITIAL_BIAS_STD] ** 2
    for i in range(3):
        x[p + i] = z[i] - offset[i]
        P[p + i, p + i] = position_variance
        P[v + i, v + i] = velocity_variance
        P[b + i, b + i] = bias_variance
    if lever_state >= 0:
        lever_variance = config[C_LEVER_STD] ** 2
        for i in range(3):
            P[p + i, p + i] += lever_variance
            P[lever_state + i, lever_state + i] = lever_variance
            for j in range(3):
                R = -H[i, lever_state + j]  # R_global_body
                P[p + i, lever_state + j] = lever_variance * R
                P[lever_state + j, p + i] = lever_variance * R
    scalars[INITIALISED_FLAG] = 1.0
    mark_fix(t, scalars, counters)
    counters[11] += 1


@njit(cache=True, inline="always")
def update_step(t, visible, z, q_global_body, has_quaternion, x, P, orientation, scalars,
                config, counters, interval, prior_x, prior_P, work):
    """One mocap frame (:meth:`KalmanFusion._update_valid`): advance to t holding the
    sample, gate the orientation, initialise or gate and fuse the position::

        y = z - c - H x,  S = H P H^T + R,  NIS = y^T S^-1 y
        gated if NIS > gate and |y| > gate_min while the prediction is valid
    Returns (outcome code, NIS, True when the fix was fused into a prediction, whose state and
    covariance are then in ``prior_x``, ``prior_P``)."""
    n = x.shape[0]
    advance(t, False, scalars[ACCELEROMETER:ACCELEROMETER + 3],
            scalars[GYROSCOPE:GYROSCOPE + 3], x, P, orientation, scalars, config, counters,
            interval, work)
    scalars[LAST_FRAME_FUSED] = 0.0
    if not visible:
        counters[8] += 1
        return _OCCLUDED, math.nan, False
    has_orientation = has_quaternion
    q_global_imu = orientation[0:4].copy()
    if has_quaternion:
        q_global_imu = normalise(quaternion_product(q_global_body,
                                                    config[C_Q_BODY_IMU:C_Q_BODY_IMU + 4]))
    if (has_quaternion and orientation[14] != 0.0 and config[C_GATING] != 0.0
            and not math.isnan(scalars[LAST_ORIENTATION_FIX])
            and t - scalars[LAST_ORIENTATION_FIX] <= config[C_MAX_BRIDGE]):
        innovation = quaternion_log(quaternion_product(conjugate(orientation[0:4]),
                                                       q_global_imu))
        angle_squared = innovation[0] ** 2 + innovation[1] ** 2 + innovation[2] ** 2
        if angle_squared > _ORIENTATION_MIN_ANGLE * _ORIENTATION_MIN_ANGLE:
            S_angle = orientation[7] + config[C_ORIENTATION_VARIANCE]
            if not (S_angle > 0.0 and angle_squared / S_angle <= config[C_GATE]):
                counters[15] += 1
                has_orientation = False
    if orientation[14] == 0.0:
        if not has_orientation:
            counters[12] += 1
            counters[8] += 1
            return _OCCLUDED, math.nan, False
        clear_orientation(orientation)
        orientation[0:4] = normalise(q_global_imu)
        orientation[7] = config[C_ORIENTATION_VARIANCE]
        orientation[9] = config[C_INITIAL_GYRO_BIAS_VARIANCE]
        orientation[14] = 1.0
        scalars[LAST_ORIENTATION_FIX] = t
    H, offset, y, PHT, S, S_inverse, K = update_views(work, n)
    output_map_into(q_global_imu if has_orientation else orientation[0:4], config, H, offset,
                    work_views(work, n)[6])
    if scalars[INITIALISED_FLAG] == 0.0:
        initialise(t, z, H, offset, x, P, scalars, config, counters)
        return _INITIALISED, math.nan, False
    noise_variance = config[C_POSITION_NOISE] ** 2
    for k in range(3):
        total = 0.0
        for j in range(n):
            total += H[k, j] * x[j]
        y[k] = (z[k] - offset[k]) - total
    innovation_covariance(P, H, noise_variance, PHT, S)
    inverse3(S, S_inverse)
    nis = 0.0
    for k in range(3):
        for m in range(3):
            nis += y[k] * S_inverse[k, m] * y[m]
    if not math.isfinite(nis):
        nis = math.inf
    scalars[LAST_NIS] = nis
    y_squared = y[0] * y[0] + y[1] * y[1] + y[2] * y[2]
    if not (math.isfinite(nis) and math.isfinite(y_squared)):
        counters[9] += 1
        return _GATED, nis, False
    since = math.inf if math.isnan(scalars[LAST_FIX]) else t - scalars[LAST_FIX]
    kind = _ACCEPTED
    failed = nis > config[C_GATE] and y_squared > config[C_GATE_MIN] ** 2
    if failed and since <= config[C_MAX_BRIDGE]:
        counters[9] += 1
        return _GATED, nis, False
    if since >= config[C_REACQUIRE]:
        kind = _REACQUIRED
        if nis > config[C_GATE]:
            # kfusion.kalman.model.reacquisition_inflation
            position_variance = y_squared / 3.0
            tau = max(since, 1e-3)
            velocity_variance = 4.0 * position_variance / (tau * tau)
            p, v = int(config[C_POSITION]), int(config[C_VELOCITY])
            for i in range(3):
                P[p + i, p + i] += position_variance
                P[v + i, v + i] += velocity_variance
    prior_x[:] = x
    prior_P[:, :] = P
    if kind == _REACQUIRED and nis > config[C_GATE]:  # P inflated: S again
        innovation_covariance(P, H, noise_variance, PHT, S)
        inverse3(S, S_inverse)
    scratch = work_views(work, n)[0][0]  # the prediction's first product, free here
    position_update(x, P, y, S_inverse, S, H, noise_variance, PHT, K, scratch,
                    int(config[C_POSITION]), int(config[C_LEVER_STATE]))
    if has_orientation:
        orientation_correct(orientation, q_global_imu, config)
        scalars[LAST_ORIENTATION_FIX] = t
    mark_fix(t, scalars, counters)
    if kind == _REACQUIRED:
        counters[10] += 1
    return kind, nis, True


def packed_size(n: int) -> int:
    """Length of a packed filter state with n states (:func:`state_views`)."""
    return n + n * n + ORIENTATION_SIZE + SCALAR_COUNT + n + n * n


@njit(cache=True, inline="always")
def state_views(state, n):
    """Views ``(x (n,), P (n, n), orientation (ORIENTATION_SIZE,), scalars, prior_x (n,),
    prior_P (n, n))``
    into one packed state array (:func:`packed_size`): one argument per kernel call (numba
    unboxes each array argument on every call) and one copy per snapshot."""
    P_end = n + n * n
    orientation_end = P_end + ORIENTATION_SIZE
    scalars_end = orientation_end + SCALAR_COUNT
    return (state[0:n], state[n:P_end].reshape((n, n)), state[P_end:orientation_end],
            state[orientation_end:scalars_end], state[scalars_end:scalars_end + n],
            state[scalars_end + n:scalars_end + n + n * n].reshape((n, n)))


@njit(cache=True)
def packed_predict(stamp, a0, a1, a2, g0, g1, g2, state, config, counters, n):
    """:func:`predict_step` on a packed state (:func:`state_views`) for a sample its caller
    validated (finite, stamp after the last: :meth:`kfusion.kalman.compiled_fusion.
    CompiledFusion.predict`); the sample as six floats."""
    f, omega = sample_arrays(a0, a1, a2, g0, g1, g2)
    predict_packed_state(stamp, f, omega, state, config, counters, n, np.empty(work_size(n)))


@njit(cache=True)
def packed_predict_with_shadow(stamp, a0, a1, a2, g0, g1, g2, state, counters, shadow_state,
                               shadow_counters, config, n):
    """:func:`packed_predict` of one sample on a filter's packed state and on a second
    filter's of the same configuration (the consistency monitor's shadow, :mod:`kfusion.
    monitor`; an empty ``shadow_state``: none), in one call: one Python -> numba transition
    per sample instead of two. Returns the first filter's :func:`dead_reckoning_until` after
    the sample, s (the :class:`kfusion.tracker.Tracker` reads it at every sample)."""
    f, omega = sample_arrays(a0, a1, a2, g0, g1, g2)
    work = np.empty(work_size(n))  # scratch: nothing carries over from one filter's step
    predict_packed_state(stamp, f, omega, state, config, counters, n, work)
    if shadow_state.shape[0] > 0:
        predict_packed_state(stamp, f, omega, shadow_state, config, shadow_counters, n, work)
    return dead_reckoning_until(state_views(state, n)[3], config)


@njit(cache=True)
def sample_arrays(a0, a1, a2, g0, g1, g2):
    """An IMU sample's six floats as (specific force (3,) m/s^2, rate (3,) rad/s)."""
    f = np.empty(3)
    omega = np.empty(3)
    f[0], f[1], f[2] = a0, a1, a2
    omega[0], omega[1], omega[2] = g0, g1, g2
    return f, omega


@njit(cache=True)
def predict_packed_state(stamp, f, omega, state, config, counters, n, work):
    """:func:`predict_step` of a validated sample (``f`` (3,) m/s^2 and ``omega`` (3,) rad/s,
    read only) on a packed state (:func:`state_views`); ``work``: scratch
    (:func:`work_size`)."""
    x, P, orientation, scalars, _, _ = state_views(state, n)
    predict_step(stamp, f, omega, x, P, orientation, scalars, config, counters, np.zeros(0),
                 work)


@njit(cache=True)
def packed_update(t, visible, z, q_global_body, has_quaternion, state, config, counters, n):
    """:func:`update_step` on a packed state (:func:`state_views`); returns (outcome code,
    NIS, y (3,) m, S (3, 3) m^2): the innovation and its covariance when the fix was fused
    into a prediction, else NaN (:attr:`kfusion.kalman.filter.UpdateOutcome.y`)."""
    x, P, orientation, scalars, prior_x, prior_P = state_views(state, n)
    work = np.empty(work_size(n))
    kind, nis, fused = update_step(t, visible, z, q_global_body, has_quaternion, x, P,
                                   orientation, scalars, config, counters, np.zeros(0),
                                   prior_x, prior_P, work)
    y = np.full(3, math.nan)
    S = np.full((3, 3), math.nan)
    if fused:
        _, _, y_work, _, S_work, _, _ = update_views(work, n)
        y[:] = y_work
        S[:, :] = S_work
    return kind, nis, y, S


def initial_state(n: int) -> NDArray[np.float64]:
    """A new filter's packed state (:func:`state_views`): x = 0, P = I, orientation and
    scalars as :func:`initial_orientation`, :func:`initial_scalars`."""
    state = np.zeros(packed_size(n))
    x, P, orientation, scalars, _, _ = state_views(state, n)
    P[:, :] = np.eye(n)
    orientation[:] = initial_orientation()
    scalars[:] = initial_scalars()
    return state


@njit(cache=True)
def filter_events(stream, index, begin, end, imu_t, accelerometer, gyroscope, imu_finite,
                  mocap_t, mocap_position, mocap_quaternion, visible, config, state, counters,
                  row_offset, out_x, out_P, out_H, out_offset, out_outcome, out_nis,
                  out_y, out_S, out_dead_reckoned, out_angle_variance, out_last_impact,
                  out_x_predicted, out_P_predicted, out_transition, save_every, saved_states,
                  saved_events):
    """The batch loop over merged events ``begin`` to ``end`` - 1 (stream 0 IMU, 1 mocap; index
    its row) from the packed ``state`` (:func:`state_views`, updated in place). Fills one row
    of the outputs per mocap row (row ``r`` at ``r - row_offset``). Returns -1, or the event
    number the kernel cannot handle (a non-increasing stamp that is not an identical
    duplicate): the caller then runs the filterpy engine, whose error message names it.
    ``out_H`` may have no rows, where H is the same on every row (no lever-arm states:
    :func:`kfusion.kalman.model.output_matrices`); the offsets are kept either way.
    ``out_angle_variance`` and ``out_last_impact`` (each (m,) or empty: not kept) take the
    orientation's angle variance and the time of the last impact (``LAST_IMPACT``) after each
    row's frame.

For the smoother (``out_transition`` with rows; empty arrays otherwise) it also keeps per
row the prediction the row's fix was fused into (the filtered state where none was) and the
product of the transitions since the previous row, packed (:func:`pack_prediction`:
``out_x_predicted`` (m, n), ``out_P_predicted`` (m, n (n + 1) / 2), ``out_transition`` (m,
TRANSITION_SIZE)). With ``save_every`` > 0 it saves the state after every ``save_every``-th
row (rows ``save_every - 1``, ``2 save_every - 1``, ...) in ``saved_states`` and the next
event in ``saved_events``: a backward pass without the kept predictions runs the loop again
from there (:func:`smooth_rows`)."""
    size = out_x.shape[1]
    x, P, orientation, scalars, prior_x, prior_P = state_views(state, size)
    smoothing = out_transition.shape[0] > 0
    interval = np.zeros(TRANSITION_SIZE if smoothing else 0)  # Phi, packed
    work = np.empty(work_size(size))
    same_H = np.empty((3, size))  # where out_H has no rows (the same H on every row)
    for event in range(begin, end):
        row = index[event]
        if stream[event] == 0:
            stamp = imu_t[row]
            if not math.isfinite(stamp):
                return event
            if not imu_finite[row]:
                counters[1] += 1
                continue
            if not math.isnan(scalars[IMU_STAMP]) and stamp <= scalars[IMU_STAMP]:
                f, _ = limit(accelerometer[row], config[C_ACC_RANGE])
                omega, _ = limit(gyroscope[row], config[C_GYRO_RANGE])
                if (stamp == scalars[IMU_STAMP]
                        and (f == scalars[ACCELEROMETER:ACCELEROMETER + 3]).all()
                        and (omega == scalars[GYROSCOPE:GYROSCOPE + 3]).all()):
                    counters[2] += 1
                    continue
                return event
            predict_step(stamp, accelerometer[row], gyroscope[row], x, P, orientation,
                         scalars, config, counters, interval, work)
            continue
        t = mocap_t[row]
        if not visible[row] and not math.isnan(scalars[TIME]) and t < scalars[TIME]:
            return event
        kind, nis, fused = update_step(t, visible[row], mocap_position[row],
                                       mocap_quaternion[row], True, x, P, orientation,
                                       scalars, config, counters, interval, prior_x,
                                       prior_P, work)
        out = row - row_offset
        out_outcome[out] = kind
        out_nis[out] = nis
        if fused and out_y.shape[0] > 0:  # the innovation and its S (UpdateOutcome.y, .S)
            _, _, y, _, S, _, _ = update_views(work, size)
            out_y[out] = y
            out_S[out] = S
        out_dead_reckoned[out] = t <= dead_reckoning_until(scalars, config)
        if out_last_impact.shape[0] > 0:  # KalmanFusion.last_impact_t after the frame
            out_last_impact[out] = scalars[LAST_IMPACT]
        if scalars[INITIALISED_FLAG] != 0.0:
            out_x[out] = x
            out_P[out] = P
            output_map_into(orientation[0:4], config,
                            out_H[out] if out_H.shape[0] > 0 else same_H, out_offset[out],
                            work_views(work, size)[6])
            if out_angle_variance.shape[0] > 0:
                out_angle_variance[out] = orientation[7]
            if smoothing:
                pack_prediction(prior_x if fused else x, prior_P if fused else P, interval,
                                out_x_predicted[out], out_P_predicted[out], out_transition[out])
        if smoothing:
            interval[:] = 0.0  # the identity
        if save_every > 0 and (row + 1) % save_every == 0:
            saved_states[(row + 1) // save_every - 1] = state
            saved_events[(row + 1) // save_every - 1] = event + 1
    return -1


TRANSITION_SIZE: Final = 19
"""Length of a packed transition product (:func:`pack_prediction`): the p-v time (1), F_pb
(9) and F_vb (9), row-major."""


@njit(cache=True)
def triangle_size(n):
    """Length of a packed symmetric (n, n) matrix: its upper triangle, ``n (n + 1) / 2``."""
    return n * (n + 1) // 2


@njit(cache=True)
def pack_prediction(x, P, transition, out_x, out_P, out_transition):
    """Keep one row's prediction for the smoother in about 0.8 of an (x, P) (the smoother's
    memory target is 2 (x, P) per row): ``out_x`` (n,) = x; ``out_P`` (n (n + 1) / 2,) = the
    upper triangle of the symmetric P, row by row; ``out_transition`` (TRANSITION_SIZE,) =
    ``transition``, the product of the transitions since the previous row in its packed form.
    That product is the identity except its position-velocity time T (T I), its position-bias
    block F_pb and its velocity-bias block F_vb (each transition is ``I + [[0, dt I, F_pb],
    [0, 0, F_vb], 0]``: :func:`transition_times`, :func:`advance_without_imu`; products of
    such keep the form, :func:`accumulate_transition` keeps those 19 entries)::

        Phi = I + [[0, T I, F_pb], [0, 0, F_vb], 0]
    Returns False, with ``out_transition[0]`` NaN (the smoother does not smooth across the
    row: :func:`rts_row`'s caller), where P is not exactly symmetric (then
    :func:`unpack_prediction` would not give its bits back) or Phi is not finite (a NaN or an
    infinity from a non-finite product). Reviews found neither on the simulated fault cases
    nor on the 7 BROAD trials (about 714,000 rows); only a reset by stamps near 1e308 s, whose
    product overflows to an infinity on the row that starts the new segment (the backward pass
    does not smooth across it either way)."""
    n = x.shape[0]
    out_x[:] = x
    exact = True
    k = 0
    for i in range(n):
        for j in range(i, n):
            out_P[k] = P[i, j]
            k += 1
            if not (P[j, i] == P[i, j] or (math.isnan(P[i, j]) and math.isnan(P[j, i]))):
                exact = False
    for k in range(TRANSITION_SIZE):
        out_transition[k] = transition[k]
        if not math.isfinite(transition[k]):
            exact = False
    if not exact:
        out_transition[0] = math.nan
    return exact


@njit(cache=True)
def unpack_prediction(packed_P, packed_transition, config, P, transition):
    """The full prediction covariance P (n, n) and transition product (n, n), in place, from
    :func:`pack_prediction`'s forms: the same bits (up to the sign of exact zeros)."""
    n = P.shape[0]
    p, v, b = int(config[C_POSITION]), int(config[C_VELOCITY]), int(config[C_BIAS])
    k = 0
    for i in range(n):
        for j in range(i, n):
            P[i, j] = packed_P[k]
            P[j, i] = packed_P[k]
            k += 1
    for i in range(n):
        for j in range(n):
            transition[i, j] = 1.0 if i == j else 0.0
    for i in range(3):
        transition[p + i, v + i] = packed_transition[0]
        for j in range(3):
            transition[p + i, b + j] = packed_transition[1 + 3 * i + j]
            transition[v + i, b + j] = packed_transition[10 + 3 * i + j]


@njit(cache=True)
def solve_into(A, B, out, work):
    """``out = A^-1 B`` for A (n, n) and B (n, r) by Gaussian elimination with partial pivoting
    (the method of LAPACK's ``gesv``, not its bits), into ``out`` (n, r); ``work`` (n, n)
    scratch. Returns False, with ``out`` undefined, where a pivot is zero or the result is not
    finite (a singular A: the caller falls back on ``np.linalg.solve``, which raises)."""
    n, r = B.shape
    for i in range(n):
        for j in range(n):
            work[i, j] = A[i, j]
        for j in range(r):
            out[i, j] = B[i, j]
    for column in range(n):
        pivot = column
        largest = abs(work[column, column])
        for row in range(column + 1, n):
            if abs(work[row, column]) > largest:
                largest = abs(work[row, column])
                pivot = row
        if largest == 0.0:
            return False
        if pivot != column:
            for j in range(n):
                work[column, j], work[pivot, j] = work[pivot, j], work[column, j]
            for j in range(r):
                out[column, j], out[pivot, j] = out[pivot, j], out[column, j]
        for row in range(column + 1, n):
            multiplier = work[row, column] / work[column, column]
            if multiplier != 0.0:
                for j in range(column, n):
                    work[row, j] -= multiplier * work[column, j]
                for j in range(r):
                    out[row, j] -= multiplier * out[column, j]
    for row in range(n - 1, -1, -1):
        for j in range(r):
            total = out[row, j]
            for k in range(row + 1, n):
                total -= work[row, k] * out[k, j]
            out[row, j] = total / work[row, row]
            if not math.isfinite(out[row, j]):
                return False
    return True


@njit(cache=True)
def rts_row(x, P, k, x_predicted, P_predicted, transitions, j, config, work):
    """One RTS backward step (:func:`kfusion.kalman.smoother.rts_step`) in place on row k of
    ``x`` (m, n) and ``P`` (m, n, n), which hold its filtered state and become its smoothed one,
    from row k + 1 (smoothed) and the prediction of row k + 1 from row k, ``x_predicted[j]``,
    ``P_predicted[j]``, with the transitions' product ``transitions[j]`` (packed:
    :func:`pack_prediction`)::

        C_k   = P_k Phi_{k+1}^T P_{k+1|k}^-1    (solved: C^T = P_{k+1|k}^-1 Phi P_k)
        x_k^s = x_k + C_k (x_{k+1}^s - x_{k+1|k})
        P_k^s = P_k + C_k (P_{k+1}^s - P_{k+1|k}) C_k^T,  symmetrised
    ``work`` (7, n, n) scratch. No allocation (:func:`solve_into`, :func:`matmul_into`):
    numpy's solve and the products' temporaries took about 3 of a row's 3.2 us, now 1.9."""
    n = x.shape[1]
    product, C_transposed, difference, CD, scratch = work[0], work[1], work[2], work[3], work[4]
    predicted, transition = work[5], work[6]
    unpack_prediction(P_predicted[j], transitions[j], config, predicted, transition)
    matmul_into(transition, P[k], product)  # Phi P_k
    if not solve_into(predicted, product, C_transposed, scratch):
        C_transposed[:, :] = np.linalg.solve(predicted, product)
    for i in range(n):
        for c in range(n):
            difference[i, c] = P[k + 1, i, c] - predicted[i, c]
    for i in range(n):  # x_k += C (x_{k+1} - x_predicted), C = C_transposed^T
        total = 0.0
        for m in range(n):
            total += C_transposed[m, i] * (x[k + 1, m] - x_predicted[j, m])
        x[k, i] += total
    matmul_into(C_transposed.T, difference, CD)  # C D
    matmul_into(CD, C_transposed, scratch)  # (C D) C^T: the rows of C^T are C_transposed's
    for i in range(n):  # P_k + C D C^T, symmetrised
        for c in range(i, n):
            value = 0.5 * ((P[k, i, c] + scratch[i, c]) + (P[k, c, i] + scratch[c, i]))
            P[k, i, c] = value
            P[k, c, i] = value


@njit(cache=True)
def smooth_rows(stream, index, row_event, imu_t, accelerometer, gyroscope, imu_finite,
                mocap_t, mocap_position, mocap_quaternion, visible, config, first_state,
                save_every, saved_states, saved_events, segment, x, P, counters,
                kept_x_predicted, kept_P_predicted, kept_transitions):
    """The RTS backward pass (:func:`rts_row`) over rows m-1..0, in place: ``x`` (m, n) and
    ``P`` (m, n, n) hold the filtered states and become the smoothed ones (row k's filtered
    state is read once, by the step that writes its smoothed one; row k+1 is smoothed by then).
    Each row's prediction and transition product come from the forward pass
    (``kept_x_predicted`` (m, n), ``kept_P_predicted``, ``kept_transitions``: packed,
    :func:`pack_prediction`), or, where those are empty (a forward pass that did not keep them:
    the step-by-step one), are recomputed: blocks of ``save_every`` rows, last block first, run
    the forward loop again (:func:`filter_events`, the same arithmetic: the same bits) from the
    state saved before the block (``first_state`` for the first block). Row k is smoothed from
    row k+1 where both are in one ``segment`` (m,) (-1: no state, set to NaN) and row k+1's
    transition was packed exactly; the last row of a segment keeps its filtered state.
    ``row_event`` (m,): each row's event; ``counters``: scratch."""
    m, n = x.shape
    work = np.empty((7, n, n))
    if kept_x_predicted.shape[0] == m:
        for k in range(m - 2, -1, -1):
            if (segment[k] >= 0 and segment[k + 1] == segment[k]
                    and not math.isnan(kept_transitions[k + 1, 0])):
                rts_row(x, P, k, kept_x_predicted, kept_P_predicted, kept_transitions, k + 1,
                        config, work)
    else:
        x_predicted = np.full((save_every, n), math.nan)
        P_predicted = np.full((save_every, triangle_size(n)), math.nan)
        transitions = np.full((save_every, TRANSITION_SIZE), math.nan)
        scratch_x = np.empty((save_every, n))
        scratch_P = np.empty((save_every, n, n))
        scratch_H = np.empty((save_every, 3, n))
        scratch_offset = np.empty((save_every, 3))
        scratch_outcome = np.empty(save_every, dtype=np.int64)
        scratch_nis = np.empty(save_every)
        scratch_dead_reckoned = np.empty(save_every, dtype=np.bool_)
        no_states = np.zeros((0, 0))
        no_events = np.zeros(0, dtype=np.int64)
        no_innovations = np.zeros((0, 3))
        no_innovation_covariances = np.zeros((0, 3, 3))
        blocks = (m + save_every - 1) // save_every
        for block in range(blocks - 1, -1, -1):
            first_row = block * save_every
            last_row = min(m, first_row + save_every) - 1
            if block == 0:
                state = first_state.copy()
                begin = 0
            else:
                state = saved_states[block - 1].copy()
                begin = saved_events[block - 1]
            x_predicted[:] = math.nan
            transitions[:] = math.nan
            filter_events(stream, index, begin, row_event[last_row] + 1, imu_t, accelerometer,
                          gyroscope, imu_finite, mocap_t, mocap_position, mocap_quaternion,
                          visible, config, state, counters, first_row, scratch_x, scratch_P,
                          scratch_H, scratch_offset, scratch_outcome, scratch_nis,
                          no_innovations, no_innovation_covariances, scratch_dead_reckoned,
                          np.zeros(0), np.zeros(0), x_predicted, P_predicted, transitions, 0,
                          no_states, no_events)
            for k in range(last_row - 1, first_row - 2, -1):
                if k < 0 or segment[k] < 0 or segment[k + 1] != segment[k]:
                    continue
                j = k + 1 - first_row
                if not math.isnan(transitions[j, 0]):
                    rts_row(x, P, k, x_predicted, P_predicted, transitions, j, config, work)
    for k in range(m):
        if segment[k] < 0:
            x[k] = math.nan
            P[k] = math.nan


@njit(cache=True)
def point_rows(output_matrix, x, offset, P):
    """Rigid-body point ``H x + c`` (m, 3) and its variance per axis ``diag(H P H^T)`` (m, 3)
    from per-row output maps (m, 3, n), or one for every row (1, 3, n), states (m, n),
    offsets (m, 3) and covariances (m, n, n) (:func:`kfusion.kalman.batch.point_estimates`);
    NaN rows stay NaN. ValueError for any other number of maps (numba checks no bounds: a
    (0, 3, n) array read as one map would read memory past it)."""
    rows, n = x.shape
    if output_matrix.shape[0] != rows and output_matrix.shape[0] != 1:
        raise ValueError("point_rows: expected one output map per row, or one for every row")
    shared = output_matrix.shape[0] != rows  # one H (kfusion.kalman.model.output_matrices)
    position = np.empty((rows, 3))
    variance = np.empty((rows, 3))
    for row in range(rows):
        H = output_matrix[0] if shared else output_matrix[row]
        for i in range(3):
            total = 0.0
            for j in range(n):
                total += H[i, j] * x[row, j]
            position[row, i] = total + offset[row, i]
            total = 0.0
            for j in range(n):
                inner = 0.0
                for k in range(n):
                    inner += P[row, j, k] * H[i, k]
                total += H[i, j] * inner
            variance[row, i] = total
    return position, variance


@njit(cache=True)
def extrapolate(t, x, P, orientation, scalars, config):
    """State, covariance, ``q_global_imu`` and its angle variance (rad^2) at t >= the state's
    time holding the last sample, without changing the state
    (:meth:`KalmanFusion._extrapolate`): the orientation propagated
    at the held rate, then ``x' = F x + B u``, ``P' = F P F^T + Q`` (symmetrised) with
    ``u = [f; f; g]`` and the held sample's extra variance."""
    dt = t - scalars[TIME]
    if (dt <= 0.0 or math.isnan(scalars[ACCELEROMETER]) or orientation[14] == 0.0
            or scalars[INITIALISED_FLAG] == 0.0):
        return x.copy(), P.copy(), orientation[0:4].copy(), orientation[7]
    n = x.shape[0]
    scratch = orientation.copy()
    f = scalars[ACCELEROMETER:ACCELEROMETER + 3].copy()
    omega = scalars[GYROSCOPE:GYROSCOPE + 3].copy()
    R0 = rotation_matrix(scratch[0:4])
    angle_variance = scratch[7]
    orientation_propagate(scratch, omega, omega, dt, scalars[GYROSCOPE_EXTRA] * dt * dt, config)
    R1 = rotation_matrix(scratch[0:4])
    bias_variance = config[C_TILT_INFLATION] * (f[0] * f[0] + f[1] * f[1] + f[2] * f[2]) * max(
        scratch[7] - angle_variance, 0.0)
    u = np.empty(9)
    u[0:3] = f
    u[3:6] = f
    u[6:9] = config[C_GRAVITY:C_GRAVITY + 3]
    Q = process_noise(dt, n, scalars[ACCELEROMETER_EXTRA], bias_variance, config)
    F, B = interval_matrices(R0, R1, dt, n, config)
    x_next = matvec(F, x) + matvec(B, u)
    P_next = matmul(matmul(F, P), F.T.copy()) + Q
    return x_next, 0.5 * (P_next + P_next.T), scratch[0:4].copy(), scratch[7]


# ---------------------------------------------------------------------------------------------
# The batch driver's side: arrays in, per-row arrays out
# ---------------------------------------------------------------------------------------------


class KernelRun:
    """What :func:`filter_events` produced over a recording, one row per mocap row (the arrays
    of :class:`kfusion.kalman.batch.FilterRun`), or ``failed_event`` >= 0."""

    def __init__(self, x: NDArray[np.float64], P: NDArray[np.float64],
                 output_matrix: NDArray[np.float64], output_offset: NDArray[np.float64],
                 outcome: NDArray[np.str_], nis: NDArray[np.float64],
                 dead_reckoned: NDArray[np.bool_], counters: dict[str, int],
                 failed_event: int, y: NDArray[np.float64] | None = None,
                 S: NDArray[np.float64] | None = None,
                 angle_variance: NDArray[np.float64] | None = None,
                 last_impact: NDArray[np.float64] | None = None) -> None:
        self.x = x
        self.P = P
        self.output_matrix = output_matrix
        self.output_offset = output_offset
        self.outcome = outcome
        self.nis = nis
        self.dead_reckoned = dead_reckoned
        self.counters = counters
        self.failed_event = failed_event
        # per row, the innovation y (m, 3) m and its S (m, 3, 3) m^2 where the row's fix was
        # fused into a prediction, NaN elsewhere (UpdateOutcome.y, .S; run_kernel's)
        self.y = np.full((len(nis), 3), np.nan) if y is None else y
        self.S = np.full((len(nis), 3, 3), np.nan) if S is None else S
        # per row, the orientation tracker's angle variance (m,) rad^2 (NaN before the filter
        # is initialised): the orientation's part of the output (model.orientation_error_
        # variance)
        self.angle_variance = np.full(len(nis), np.nan) if angle_variance is None \
            else angle_variance
        # per row, the time of the last impact (m,) s after the row's frame (-inf: none;
        # KalmanFusion.last_impact_t), which the consistency monitor reads
        self.last_impact = np.full(len(nis), -math.inf) if last_impact is None \
            else last_impact
        # smoother support (run_kernel(smoothing=True)): the kernel inputs, configuration,
        # each row's packed prediction and the states saved every SAVE_EVERY rows, for
        # smooth_in_place
        self.replay: Replay | None = None


def _kernel_array(values: NDArray[np.generic], dtype: type) -> NDArray[np.generic]:
    """C-contiguous and writeable (a read-only array is another numba type: one more
    compilation)."""
    return np.require(values, dtype=dtype, requirements=["C", "W"])


SAVE_EVERY: Final = 1024
"""Rows between the states the forward pass saves for the smoother's backward pass
(:func:`smooth_rows`): per row it keeps 1/SAVE_EVERY of a packed state."""


def kernel_inputs(imu_t: NDArray[np.float64], accelerometer: NDArray[np.float64],
                  gyroscope: NDArray[np.float64], mocap_t: NDArray[np.float64],
                  mocap_position: NDArray[np.float64], mocap_quaternion: NDArray[np.float64],
                  visible: NDArray[np.bool_], stream: NDArray[np.int64],
                  index: NDArray[np.int64]) -> tuple:
    """The recording arguments of :func:`filter_events` and :func:`smooth_rows` in their order
    (``stream``, ``index``, IMU t, accelerometer, gyroscope, each sample's finiteness, mocap t,
    position, quaternion, visible): C-contiguous writeable arrays of the kernels' types."""
    force = _kernel_array(accelerometer, float)
    rate = _kernel_array(gyroscope, float)
    finite = np.isfinite(force).all(axis=1) & np.isfinite(rate).all(axis=1)
    return (_kernel_array(stream, np.int64), _kernel_array(index, np.int64),
            _kernel_array(imu_t, float), force, rate, finite,
            _kernel_array(mocap_t, float), _kernel_array(mocap_position, float),
            _kernel_array(mocap_quaternion, float), _kernel_array(visible, bool))


class Replay:
    """What the compiled backward pass (:func:`smooth_in_place`) needs of a forward pass: the
    kernel inputs (:func:`kernel_inputs`), ``config``, and either each row's packed prediction
    (``predictions``: x (m, n), P (m, n (n + 1) / 2), transition (m, TRANSITION_SIZE);
    :func:`pack_prediction`), which the whole-loop kernel keeps, or the first packed state and
    the states saved after every :data:`SAVE_EVERY`-th row (``saved_states`` (m // SAVE_EVERY,
    packed size)), from which the backward pass recomputes them (a step-by-step forward pass on
    the same events)."""

    def __init__(self, inputs: tuple, config: NDArray[np.float64],
                 first_state: NDArray[np.float64], saved_states: NDArray[np.float64],
                 predictions: tuple[NDArray[np.float64], NDArray[np.float64],
                                    NDArray[np.float64]] | None = None) -> None:
        self.inputs = inputs
        self.config = config
        self.first_state = first_state
        self.saved_states = saved_states
        self.predictions = predictions
        # the event after each saved state's row (run_kernel with save_every)
        self.saved_events = np.zeros(0, dtype=np.int64)

    def without_predictions(self) -> Replay:
        """The same forward pass as its saved states alone (the backward pass then recomputes
        the predictions: the cross-check of the kept ones). The states must be saved every
        :data:`SAVE_EVERY` rows."""
        return Replay(self.inputs, self.config, self.first_state, self.saved_states)


def run_kernel(imu_t: NDArray[np.float64], accelerometer: NDArray[np.float64],
               gyroscope: NDArray[np.float64], mocap_t: NDArray[np.float64],
               mocap_position: NDArray[np.float64], mocap_quaternion: NDArray[np.float64],
               visible: NDArray[np.bool_], stream: NDArray[np.int64], index: NDArray[np.int64],
               config: NDArray[np.float64], size: int, smoothing: bool = False,
               save_every: int = 0) -> KernelRun:
    """Run :func:`filter_events` over merged events (``stream``, ``index`` (e,) each:
    :func:`kfusion.kalman.events.merge_order`). Shapes: IMU (n,), (n, 3), (n, 3); mocap (m,),
    (m, 3), (m, 4), (m,); ``config`` from :func:`pack_config`; n states ``size``. With
    ``smoothing`` the run keeps what :func:`smooth_in_place` needs (``replay``: the inputs and
    each row's packed prediction, :func:`pack_prediction`); ``save_every`` > 0 keeps the
    states saved every ``save_every`` rows (``replay`` too: :class:`Checkpoints` continues from
    them; with ``smoothing`` and ``save_every`` :data:`SAVE_EVERY`, the backward pass can
    recompute the predictions from them: :meth:`Replay.without_predictions`)."""
    rows = len(mocap_t)
    inputs = kernel_inputs(imu_t, accelerometer, gyroscope, mocap_t, mocap_position,
                           mocap_quaternion, visible, stream, index)
    out_x = np.full((rows, size), np.nan)
    out_P = np.full((rows, size, size), np.nan)
    varies = output_matrix_varies(config)
    out_H = np.zeros((rows if varies else 0, 3, size))  # else one H (model.output_matrices)
    out_offset = np.zeros((rows, 3))
    out_outcome = np.full(rows, -1, dtype=np.int64)
    out_nis = np.full(rows, np.nan)
    out_y = np.full((rows, 3), np.nan)
    out_S = np.full((rows, 3, 3), np.nan)
    out_dead_reckoned = np.zeros(rows, dtype=bool)
    out_angle_variance = np.full(rows, np.nan)
    out_last_impact = np.full(rows, -math.inf)
    counters = np.zeros(len(COUNTER_INDEX), dtype=np.int64)
    kept = rows if smoothing else 0
    predictions = (np.full((kept, size), np.nan), np.full((kept, triangle_size(size)), np.nan),
                   np.full((kept, TRANSITION_SIZE), np.nan))
    first_state = initial_state(size)
    state = first_state.copy()
    save_every = SAVE_EVERY if smoothing and save_every == 0 else save_every
    saved = rows // save_every if save_every > 0 else 0
    saved_states = np.zeros((saved, len(state)))
    saved_events = np.zeros(saved, dtype=np.int64)
    failed = filter_events(  # type: ignore[call-arg]
        inputs[0], inputs[1], 0, len(stream), *inputs[2:], config, state, counters, 0, out_x,
        out_P, out_H, out_offset, out_outcome, out_nis, out_y, out_S, out_dead_reckoned,
        out_angle_variance, out_last_impact, *predictions, save_every, saved_states,
        saved_events)
    run = KernelRun(out_x, out_P, out_H if varies else model.output_matrices(rows, size, False),
                    out_offset, _OUTCOME_LOOKUP[out_outcome], out_nis,
                    out_dead_reckoned, dict(zip(COUNTER_INDEX, counters.tolist(), strict=True)),
                    int(failed), out_y, out_S, out_angle_variance, out_last_impact)
    if save_every > 0 or smoothing:
        run.replay = Replay(inputs, config, first_state, saved_states,
                            predictions if smoothing else None)
        run.replay.saved_events = saved_events
    return run


def output_matrix_varies(config: NDArray[np.float64]) -> bool:
    """True when the output map's H changes from row to row: with the lever-arm states
    (:func:`output_map_into`; without them H is ``[I 0 0]`` on every row)."""
    return bool(config[C_LEVER_STATE] >= 0)


class Checkpoints:
    """The filter's packed state after any event of a whole-loop run, recomputed from the
    states it saved (:func:`run_kernel` with ``save_every``): :func:`filter_events` again from
    the last saved state before that event (the same arithmetic: the same bits), and the same
    loop over a range of events with every mocap frame occluded (``hidden``: the consistency
    monitor's shadow filter, which runs on the IMU alone)."""

    def __init__(self, replay: Replay, size: int, save_every: int) -> None:
        self.replay = replay
        self.size = size
        self.save_every = save_every
        self.inputs = replay.inputs
        self.hidden = np.zeros(len(self.inputs[9]), dtype=bool)
        self.counters = np.zeros(len(COUNTER_INDEX), dtype=np.int64)  # scratch

    def state_before(self, event: int) -> NDArray[np.float64]:
        """The packed state after events 0 .. ``event`` - 1 (a new array)."""
        saved_events = self.replay.saved_events
        last = int(np.searchsorted(saved_events, event, side="right")) - 1
        if last < 0:
            state, begin, first_row = self.replay.first_state.copy(), 0, 0
        else:
            state = self.replay.saved_states[last].copy()
            begin, first_row = int(saved_events[last]), (last + 1) * self.save_every
        self.run(state, begin, event, first_row, self.save_every + 1, hidden=False)
        return state

    def run(self, state: NDArray[np.float64], begin: int, end: int, first_row: int,
            rows: int, hidden: bool) -> tuple[NDArray[np.float64], ...]:
        """:func:`filter_events` over events ``begin`` .. ``end`` - 1 from the packed ``state``
        (in place), the frames from ``first_row`` on, at most ``rows`` of them; occluded with
        ``hidden``. Returns the rows' x (rows, n), P (rows, n, n), H (rows, 3, n) and offset
        (rows, 3) (NaN x where not initialised). RuntimeError where the kernel stops (the
        whole-loop run did not: these are its events)."""
        n = self.size
        out_x = np.full((rows, n), np.nan)
        out_P = np.full((rows, n, n), np.nan)
        out_H = np.zeros((rows, 3, n))
        out_offset = np.zeros((rows, 3))
        inputs = self.inputs
        visible = self.hidden if hidden else inputs[9]
        failed = filter_events(  # type: ignore[call-arg]
            inputs[0], inputs[1], begin, end, *inputs[2:9], visible, self.replay.config,
            state, self.counters, first_row, out_x, out_P, out_H, out_offset,
            np.full(rows, -1, dtype=np.int64), np.full(rows, np.nan), np.zeros((0, 3)),
            np.zeros((0, 3, 3)), np.zeros(rows, dtype=bool), np.zeros(0), np.zeros(0),
            np.zeros((0, n)), np.zeros((0, triangle_size(n))), np.zeros((0, TRANSITION_SIZE)),
            0, np.zeros((0, len(state))), np.zeros(0, dtype=np.int64))
        if failed >= 0:
            raise RuntimeError(f"replay of events {begin}..{end}: the kernel stopped at "
                               f"event {failed}, which the whole-loop run passed")
        return out_x, out_P, out_H, out_offset


def smooth_in_place(replay: Replay, x: NDArray[np.float64], P: NDArray[np.float64],
                    segments: list[tuple[int, int]]) -> None:
    """Smooth the filtered states ``x`` (m, n), ``P`` (m, n, n) of a forward pass in place
    (:func:`smooth_rows`), each of ``segments`` ((first, stop) row ranges) on its own, NaN
    elsewhere. ``replay``: that forward pass's (:class:`Replay`: its kept predictions, or its
    saved states, from which they are recomputed).

    The recomputing blocks assume row k is the k-th frame of the merged events (a block runs
    the events from the state saved after its first row's predecessor to its last row, and
    writes each frame's outputs at its row). A frame stamped out of row order (a mocap stamp
    far ahead, which the reader refuses but the API accepts) breaks that, and the kernel wrote
    past its block's arrays: then the predictions are recomputed in one block over every
    event, with scratch of the size of the rows' (x, P)."""
    inputs = replay.inputs
    m = x.shape[0]
    segment = np.full(m, -1, dtype=np.int64)
    for number, (first, stop) in enumerate(segments):
        segment[first:stop] = number
    row_event = np.flatnonzero(inputs[0] == 1).astype(np.int64)
    saved = len(replay.saved_states)
    # the event after the saved row (rows SAVE_EVERY - 1, 2 SAVE_EVERY - 1, ...)
    saved_events = row_event[SAVE_EVERY - 1::SAVE_EVERY][:saved] + 1
    in_row_order = np.array_equal(inputs[1][row_event], np.arange(m))
    block = SAVE_EVERY if in_row_order or replay.predictions is not None else max(m, 1)
    n = x.shape[1]
    predictions = replay.predictions or (np.zeros((0, n)), np.zeros((0, triangle_size(n))),
                                         np.zeros((0, TRANSITION_SIZE)))
    if m:
        smooth_rows(inputs[0], inputs[1], row_event, *inputs[2:], replay.config,  # type: ignore[call-arg]
                    replay.first_state, block, replay.saved_states, saved_events,
                    segment, x, P, np.zeros(len(COUNTER_INDEX), dtype=np.int64), *predictions)


def kept_bytes(replay: Replay) -> int:
    """Bytes the compiled smoother keeps for its backward pass beyond its (x, P) per row: the
    packed predictions and the saved states (which only the recomputing path reads: 1 / 1024
    of a packed state per row, kept so that :meth:`Replay.without_predictions` can check the
    kept predictions)."""
    arrays = [replay.saved_states, *(replay.predictions or ())]
    return sum(array.nbytes for array in arrays)


_OUTCOME_LOOKUP: Final = np.array(OUTCOME_NAMES + ("",))
"""Outcome names by code (-1, the last: a row the kernel did not reach)."""


@njit(cache=True)
def status_codes(time_since_fix, fused, dead_reckoned, fix_timeout_s, max_bridge_s):
    """:func:`kfusion.streamhealth.tracking_status` per row as codes into
    :data:`STATUS_NAMES` (the rule, row by row, for the batch driver's rows;
    :func:`kfusion.kalman.batch.row_statuses` is the reference)::

        tracked  if fused and time_since_fix <= fix_timeout_s
        lost     if not time_since_fix <= max_bridge_s, or not dead_reckoned
        bridged  otherwise
    """
    codes = np.empty(time_since_fix.shape[0], dtype=np.int64)
    for row in range(time_since_fix.shape[0]):
        since = time_since_fix[row]
        if fused[row] and since <= fix_timeout_s:
            codes[row] = 0
        elif not since <= max_bridge_s or not dead_reckoned[row]:
            codes[row] = 2
        else:
            codes[row] = 1
    return codes


STATUS_NAMES: Final = np.array([TRACKED, BRIDGED, LOST])
"""Status names by :func:`status_codes` code."""
