"""Gravity, lever arm and accelerometer bias: linear least squares on the specific force.

With the clock and the mount known, the accelerometer at mocap time t reads (IMU at lever arm r
from the rigid-body origin, body frame):

    R_global_imu f = a_global - g + R_global_body (alpha x r + omega x (omega x r))
                     + R_global_imu (b_acc + E f)

``a_global`` from the mocap position (low-passed, then central second differences), omega and
alpha (body frame) from the gyroscope through the mount. ``E`` is the accelerometer's scale and
misalignment error to first order (``f = (I + E) f_true + b_acc``, so
``f_true ~ f - E f - b_acc``), ``E = sum_j e_j B_j`` over 9 basis matrices
(:data:`SCALE_ERROR_BASIS`). Its isotropic part ``e_iso`` is told from the length of gravity
by the limb's own acceleration only, so the gravity reported is the one the accelerometer
measures, ``g (1 + e_iso)``, which the data pin down even when the two factors are not. A
cheap MEMS accelerometer's 1-3 % scale and misalignment errors otherwise leak into the lever
arm (20 mm on a simulated circle, where the centripetal acceleration and
``omega x (omega x r)`` point the same way). Unknowns ``x = [g, r, b_acc, e]`` (18) enter
linearly: ``y = A x`` with ``y = R_global_imu f - a_global``,
``A = [-I, R_global_body L(omega, alpha), R_global_imu, R_global_imu [B_1 f .. B_9 f]]`` and
``L = [alpha]x + [omega]x^2``. The same
zero-phase low-pass filter is applied to ``y`` and to every column of ``A`` (a linear filter
commutes with the linear model), so the doubly differentiated mocap noise is filtered out
consistently. Edges of each visible run are trimmed where the filter rings.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import signal

from kfusion.calibration.clock import mocap_to_imu_time
from kfusion.conventions import matrix_from_wxyz, median_interval
from kfusion.recording import Recording, occlusion_runs

Array = NDArray[np.float64]

CUTOFF_HZ: Final = 4.0
"""Hz: low-pass cut-off applied to both sides (arm motion lies below it; the doubly
differentiated mocap noise above it)."""
MIN_RUN_S: Final = 1.0
"""s: shortest visible mocap run used."""
TRIM_S: Final = 0.2
"""s: trimmed at both ends of a run, where the zero-phase filter rings."""
MAX_LEVER_ARM_STD: Final = 0.002
"""m: a lever-arm axis fitted less precisely than this makes the lever arm undetermined."""
MAX_BIAS_STD: Final = 0.05
"""m/s^2: a bias fitted less precisely than this is confounded with gravity (too little change
of orientation): the fit is repeated with the bias and the scale errors fixed at 0."""


def scale_error_basis() -> Array:
    """(9, 3, 3): the 6 off-diagonal unit matrices, diag(1, -1, 0), diag(0, 1, -1) and the
    identity (the isotropic scale, last)."""
    basis = []
    for row in range(3):
        for column in range(3):
            if row != column:
                unit = np.zeros((3, 3))
                unit[row, column] = 1.0
                basis.append(unit)
    basis += [np.diag([1.0, -1.0, 0.0]), np.diag([0.0, 1.0, -1.0]), np.eye(3)]
    return np.asarray(basis)


SCALE_ERROR_BASIS: Final = scale_error_basis()
OUTLIER_FACTOR: Final = 4.0
"""A filtered sample whose misfit exceeds this many times the median is an outlier (for
Gaussian 3-axis misfits the median is 1.54 sigma, so about 6 sigma)."""
MAX_REJECTION_PASSES: Final = 10
UNKNOWNS: Final = 18
"""g (3), r (3), b_acc (3), e (9)."""
MAX_TIME_SHIFT_ITERATIONS: Final = 4
TIME_SHIFT_TOLERANCE_S: Final = 2e-5
"""s: Gauss-Newton on the accelerometer's clock offset stops below this step."""


def cross_matrix(vectors: ArrayLike) -> Array:
    """``[v]x`` (..., 3, 3) such that ``[v]x u = v x u``."""
    v = np.asarray(vectors, dtype=float)
    zero = np.zeros(v.shape[:-1])
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1),
                     np.stack([-y, x, zero], -1)], -2)


def lever_arm_matrix(angular_rate: ArrayLike, angular_acceleration: ArrayLike) -> Array:
    """``L = [alpha]x + [omega]x [omega]x`` (n, 3, 3): ``L r = alpha x r + omega x (omega x r)``,
    the acceleration of a point r on a rigid body relative to its origin (body frame)."""
    omega = cross_matrix(angular_rate)
    return np.asarray(cross_matrix(angular_acceleration) + omega @ omega)


def mount_columns(R_global_body: ArrayLike, force_body: ArrayLike) -> Array:
    """``R_global_body [f_body]x`` (n, 3, 3): the change of ``y = R_global_imu f - a`` per
    small mount rotation theta (rad, body frame), ``R_body_imu <- exp([theta]x) R_body_imu``.

    ``y(theta) = R_global_body exp([theta]x) f_body - a ~ y(0) + R_global_body (theta x
    f_body)`` and ``theta x f = -f x theta = -[f]x theta``, so in ``y(0) = A x + C theta`` (the
    model ``y(theta) = A x`` moved to the measured side) ``C = +R_global_body [f_body]x``.
    Inputs (n, 3, 3) and (n, 3) m/s^2."""
    return np.asarray(np.asarray(R_global_body, dtype=float) @ cross_matrix(force_body))


ANTISYMMETRIC_PAIRS: Final = ((9, 11), (10, 13), (12, 14))
"""Columns of the scale-error coefficients (E_xy, E_yx), (E_xz, E_zx), (E_yz, E_zy) in the
design (:func:`scale_error_basis` after g, r, b_acc)."""


def symmetric_scale_design(design: ArrayLike) -> Array:
    """The design with the scale error ``E`` constrained symmetric, ``E_ji = E_ij``: each pair's
    second column added into the first and zeroed (its coefficient is then 0 and carries no
    information). ``E``'s antisymmetric part is a rotation of the accelerometer's axes, the same
    as a mount rotation (``[theta]x f = theta x f``), so the two cannot both be free."""
    constrained = np.array(design, dtype=float)
    for first, second in ANTISYMMETRIC_PAIRS:
        constrained[:, :, first] += constrained[:, :, second]
        constrained[:, :, second] = 0.0
    return constrained


@dataclass(frozen=True)
class SpecificForceFit:
    """Result of :func:`fit_specific_force`.

    Attributes:
        gravity, gravity_std: (3,) m/s^2, global frame.
        lever_arm, lever_arm_std: (3,) m, body frame.
        accelerometer_bias, accelerometer_bias_std: (3,) m/s^2, IMU frame (0 and NaN when it
            could not be separated from gravity).
        accelerometer_scale_error: (9,) scale and misalignment coefficients ``e``
            (module docstring), dimensionless (0 when not fitted).
        residual_rms: RMS misfit per axis after the fit, m/s^2 (filtered).
        residual_before_rms: the same with the lever arm and bias at 0 and the fitted gravity,
            m/s^2.
        samples: filtered samples used.
    """

    gravity: Array
    gravity_std: Array
    lever_arm: Array
    lever_arm_std: Array
    accelerometer_bias: Array
    accelerometer_bias_std: Array
    accelerometer_scale_error: Array
    residual_rms: float
    residual_before_rms: float
    samples: int


@functools.lru_cache(maxsize=64)
def _butter(cutoff: float, rate: float) -> tuple[Array, Array]:
    b, a = signal.butter(4, cutoff, fs=rate)
    return np.asarray(b), np.asarray(a)


def _filter(values: Array, rate: float, cutoff: float) -> Array:
    """Zero-phase 4th-order Butterworth low-pass along axis 0 (the rate rounded to 1e-6 Hz,
    so the coefficients of a recording's runs are designed once)."""
    b, a = _butter(float(cutoff), round(float(rate), 6))
    return np.asarray(signal.filtfilt(b, a, values, axis=0))


def _runs_inside(mocap_t: Array, visible: NDArray[np.bool_], imu_t: Array, offset: float,
                 drift_ppm: float) -> list[tuple[int, int]]:
    """Index ranges ``[start, stop)`` of the visible mocap runs of at least :data:`MIN_RUN_S`
    (and 10 frames) that lie inside the IMU's span ``imu_t`` at the clock ``offset`` (s),
    ``drift_ppm``. When none does, the parts of the runs inside the span: a recording without
    occlusions is one run, which the IMU may start after or stop before (runs wholly inside
    are preferred, since an offset search moves the span's edges across the runs at its
    ends, and on BROAD 28's first 40 s the part of an end run moved the accelerometer's
    timing by 2.8 ms)."""
    runs = occlusion_runs(~np.asarray(visible, dtype=bool))  # runs of visible frames
    whole: list[tuple[int, int]] = []
    parts: list[tuple[int, int]] = []
    for start, stop in runs:
        tau = mocap_to_imu_time(mocap_t[start:stop], offset, drift_ppm)
        inside = np.flatnonzero((tau >= imu_t[0]) & (tau <= imu_t[-1]))
        if len(inside) == 0:
            continue
        part = (start + int(inside[0]), start + int(inside[-1]) + 1)
        if part[1] - part[0] < 10 or mocap_t[part[1] - 1] - mocap_t[part[0]] < MIN_RUN_S:
            continue
        (whole if part == (start, stop) else parts).append(part)
    return whole or parts


def specific_force_system(recording: Recording, offset: float, drift_ppm: float,
                          imu_to_body: ArrayLike, *, cutoff_hz: float = CUTOFF_HZ,
                          time_shift: bool = False, drift_shift: bool = False,
                          reference_time: float = 0.0, mount_shift: bool = False
                          ) -> tuple[Array, Array]:
    """The filtered linear system ``y (k, 3) = A (k, 3, 18) x`` of the module docstring, over
    every visible mocap run of at least :data:`MIN_RUN_S` inside the IMU's span.

    With ``time_shift`` A has a 19th column for a correction ``delta_c`` (s) of ``offset``, and
    with ``drift_shift`` also a 20th for a correction ``delta_d`` (ppm) of ``drift_ppm``. The
    IMU is read at ``tau = (t - offset) / (1 + drift_ppm 1e-6)``; against the true clock,
    ``tau - tau_true ~ delta_c + tau delta_d 1e-6``, so to first order

        R_global_imu f(tau) = R_global_imu f(tau_true) + R_global_imu f'(tau) (delta_m
                              + (tau - tau_ref) delta_d 1e-6)

    with ``delta_m = delta_c + tau_ref delta_d 1e-6`` the correction at ``tau_ref =
    reference_time`` (IMU clock, s; the recording's middle keeps the two columns apart)
    (:func:`fit_accelerometer_offset`).

    With ``mount_shift`` A has 3 more columns, last, for a small rotation ``theta`` (rad, body
    frame) of the mount, ``R_body_imu <- exp([theta]x) R_body_imu``: to first order
    ``R_global_imu f <- R_global_imu f + R_global_body (theta x f_body)``, so with
    ``f_body = R_body_imu f`` the columns are :func:`mount_columns` (and the antisymmetric
    part of the scale error ``E``, which is the same rotation, must then be held at 0:
    :func:`symmetric_scale_design`)."""
    imu, mocap = recording.imu, recording.mocap
    R_body_imu = matrix_from_wxyz(imu_to_body)
    angular_acceleration = np.gradient(imu.gyroscope, imu.t, axis=0)
    force_rate = np.gradient(imu.accelerometer, imu.t, axis=0) if time_shift else None
    rows_y, rows_a = [], []
    for start, stop in _runs_inside(mocap.t, mocap.visible, imu.t, offset, drift_ppm):
        t = mocap.t[start:stop]
        tau = mocap_to_imu_time(t, offset, drift_ppm)
        rate = (len(t) - 1) / (t[-1] - t[0])
        if cutoff_hz >= 0.45 * rate:
            raise ValueError(f"cutoff_hz: expected below half the mocap rate ({rate:.0f} Hz), "
                             f"got {cutoff_hz}")
        position = _filter(mocap.position[start:stop], rate, cutoff_hz)
        acceleration = np.gradient(np.gradient(position, t, axis=0), t, axis=0)

        def at(values: Array, times: Array = tau) -> Array:
            return np.column_stack([np.interp(times, imu.t, values[:, axis])
                                    for axis in range(3)])

        force, omega, alpha = at(imu.accelerometer), at(imu.gyroscope), at(angular_acceleration)
        R_global_body = matrix_from_wxyz(mocap.quaternion[start:stop])
        R_global_imu = R_global_body @ R_body_imu
        lever = R_global_body @ lever_arm_matrix(omega @ R_body_imu.T, alpha @ R_body_imu.T)
        y = np.einsum("nij,nj->ni", R_global_imu, force) - acceleration
        # R_global_imu B_j f for each basis matrix: (n, 3, 9)
        scale = np.einsum("nik,jkl,nl->nij", R_global_imu, SCALE_ERROR_BASIS, force)
        blocks = [np.broadcast_to(-np.eye(3), lever.shape), lever, R_global_imu, scale]
        if force_rate is not None:
            shift = np.einsum("nij,nj->ni", R_global_imu, at(force_rate))[:, :, None]
            blocks.append(shift)
            if drift_shift:
                blocks.append(shift * ((tau - reference_time) * 1e-6)[:, None, None])
        if mount_shift:
            blocks.append(mount_columns(R_global_body, force @ R_body_imu.T))
        design = np.concatenate(blocks, axis=2)
        # filter the IMU side like the mocap side (the acceleration is already filtered)
        y = _filter(y + acceleration, rate, cutoff_hz) - acceleration
        design = _filter(design.reshape(len(t), -1), rate, cutoff_hz).reshape(
            len(t), 3, design.shape[2])
        keep = (t >= t[0] + TRIM_S) & (t <= t[-1] - TRIM_S)
        rows_y.append(y[keep])
        rows_a.append(design[keep])
    if not rows_y:
        raise ValueError(f"cannot fit gravity and lever arm: no visible mocap run of at least "
                         f"{MIN_RUN_S:g} s inside the IMU's span")
    return np.concatenate(rows_y), np.concatenate(rows_a)


def solve_specific_force(y: Array, design: Array, *, fit_bias: bool = True,
                         correlation: float = 1.0) -> tuple[Array, Array, Array]:
    """Least squares of ``y = A x``; returns (x (m,), covariance (m, m), residual (k', 3)
    of the inliers), m = ``design.shape[2]`` (18, or 19 with a time-shift column last).

    Without ``fit_bias`` the bias and scale-error columns are dropped (x[6:18] = 0, their
    covariance NaN). ``correlation`` multiplies the covariance: filtered samples are not
    independent (about ``rate / (2 cutoff)`` samples per independent one).
    """
    unknowns = design.shape[2]
    used = np.arange(unknowns) if fit_bias else np.r_[0:6, UNKNOWNS:unknowns]
    columns = len(used)
    A = design[:, :, used].reshape(-1, columns)
    b = y.reshape(-1)
    solution, inlier = robust_least_squares(A, b)
    rows = np.repeat(inlier, 3)
    A, b = A[rows], b[rows]
    residual = b - A @ solution
    sigma2 = float(residual @ residual) / max(len(b) - columns, 1)
    covariance = np.linalg.pinv(A.T @ A) * sigma2 * correlation
    x = np.zeros(unknowns)
    full = np.full((unknowns, unknowns), np.nan)
    x[used] = solution
    full[np.ix_(used, used)] = covariance
    return x, full, residual.reshape(-1, 3)


def normal_least_squares(A: Array, b: Array) -> Array:
    """Least squares of ``b = A x`` (A (n, m)) by the normal equations on unit-norm columns:
    ``x = D^-1 (A_s^T A_s)^+ A_s^T b`` with ``A_s = A D^-1``, D the column norms (1 for a zero
    column, whose coefficient is then 0). Five times faster than an SVD on the tall systems
    here; directions whose singular value is below 1e-6 of the largest count as unseen."""
    norms = np.linalg.norm(A, axis=0)
    norms = np.where(norms > 0.0, norms, 1.0)
    scaled = A / norms
    return np.asarray(np.linalg.pinv(scaled.T @ scaled, rcond=1e-12, hermitian=True)
                      @ (scaled.T @ b) / norms, dtype=float)


def robust_least_squares(A: Array, b: Array) -> tuple[Array, NDArray[np.bool_]]:
    """Least squares of ``b (3k,) = A (3k, m) x`` (:func:`normal_least_squares`) with the
    outlier rejection of :func:`solve_specific_force`; returns (x (m,), inlier (k,) per
    3-axis sample)."""
    solution = normal_least_squares(A, b)
    # outlier rejection, repeated until the inliers settle: samples whose misfit exceeds
    # OUTLIER_FACTOR times the median (a mocap glitch or marker swap, a tap on the IMU, spread
    # by the filter) are dropped and the fit repeated. One pass is not enough when the
    # outliers are many: the first fit is pulled, so the median misfit is inflated (on BROAD's
    # tapping trial a single pass left the lever arm 35 mm off)
    A_all, b_all = A, b
    inlier = np.ones(len(b_all) // 3, dtype=bool)
    for _ in range(MAX_REJECTION_PASSES):
        misfit = np.linalg.norm((b_all - A_all @ solution).reshape(-1, 3), axis=1)
        updated = misfit <= OUTLIER_FACTOR * np.median(misfit)
        if np.array_equal(updated, inlier):
            break
        inlier = updated
        rows = np.repeat(inlier, 3)
        solution = normal_least_squares(A_all[rows], b_all[rows])
    return np.asarray(solution, dtype=float), inlier


def measured_gravity(x: Array, covariance: Array) -> tuple[Array, Array]:
    """Gravity as the accelerometer measures it, ``h = g (1 + e_iso)`` (x[:3], x[-1]), and its
    1-sigma from ``J C J^T`` with ``J = dh/d(g, e_iso) = [(1 + e_iso) I, g]``; just ``g`` when
    the scale was not fitted (its covariance NaN)."""
    if not np.isfinite(covariance[-1, -1]):
        return x[:3], np.sqrt(np.maximum(np.diag(covariance)[:3], 0.0))
    index = [0, 1, 2, UNKNOWNS - 1]
    jacobian = np.hstack([(1.0 + x[-1]) * np.eye(3), x[:3, None]])
    covariance_h = jacobian @ covariance[np.ix_(index, index)] @ jacobian.T
    return x[:3] * (1.0 + x[-1]), np.sqrt(np.maximum(np.diag(covariance_h), 0.0))


@dataclass(frozen=True)
class AccelerometerClock:
    """Result of :func:`fit_accelerometer_offset`.

    Attributes:
        offset, offset_std: s, the IMU clock offset that times the accelerometer against the
            mocap's acceleration (``c`` of the clock model, at IMU time 0), and its 1-sigma.
        middle_offset, middle_offset_std: s, the offset at the middle of the recording,
            ``c + d 1e-6 tau_middle`` (what the whole recording is shifted by on average).
        drift_ppm, drift_std_ppm: the drift used (fitted, or as given with std NaN).
        iterations: Gauss-Newton steps taken.
        residual_rms: RMS misfit per axis at ``offset``, m/s^2 (filtered).
        converged: the last step was below :data:`TIME_SHIFT_TOLERANCE_S`.
    """

    offset: float
    offset_std: float
    middle_offset: float
    middle_offset_std: float
    drift_ppm: float
    drift_std_ppm: float
    iterations: int
    residual_rms: float
    converged: bool


def residual_correlation(mocap_t: ArrayLike, cutoff_hz: float = CUTOFF_HZ) -> float:
    """Frames per independent residual of a fit on signals low-passed at ``cutoff_hz`` (Hz):
    ``max(1, rate / (2 cutoff))``, rate the mocap's median frame rate (Hz; frame times
    ``mocap_t`` s). The least-squares covariance is multiplied by it, since neighbouring
    residuals of a low-passed signal are not independent."""
    rate = 1.0 / median_interval(mocap_t)
    return max(1.0, rate / (2.0 * cutoff_hz))


def fit_accelerometer_offset(recording: Recording, offset: float, drift_ppm: float,
                             imu_to_body: ArrayLike, *, cutoff_hz: float = CUTOFF_HZ,
                             fit_drift: bool = False,
                             max_iterations: int = MAX_TIME_SHIFT_ITERATIONS
                             ) -> AccelerometerClock:
    """The clock offset (s), and with ``fit_drift`` the drift (ppm), at which the accelerometer
    best matches the mocap's specific force, starting from ``offset`` and ``drift_ppm`` (the
    gyroscope's): Gauss-Newton on the linear system of :func:`specific_force_system` with its
    time-shift columns,

        y(offset, drift) = A x + R_global_imu f'(tau) (delta_m + (tau - tau_m) delta_d 1e-6),
        offset <- offset + delta_m - tau_m delta_d 1e-6,  drift <- drift + delta_d,

(``tau_m`` the middle of the IMU's span, where offset and drift are uncorrelated)
    repeated until ``|delta_c|`` < :data:`TIME_SHIFT_TOLERANCE_S`. The accelerometer is what the
    filter dead-reckons with, and an IMU's accelerometer and gyroscope can lag by different
    amounts (their on-chip filters differ: on BROAD the accelerometer is timed about 1 ms
    later than the gyroscope), so this is the offset a gap's position error depends on.
    ValueError as :func:`specific_force_system`."""
    correlation = residual_correlation(recording.mocap.t, cutoff_hz)
    middle = 0.5 * float(recording.imu.t[0] + recording.imu.t[-1])
    delta, middle_std, std, drift_std = np.inf, np.inf, np.inf, np.nan
    residual = np.full((1, 3), np.nan)
    iterations = 0
    while iterations < max_iterations and abs(delta) >= TIME_SHIFT_TOLERANCE_S:
        y, design = specific_force_system(recording, offset, drift_ppm, imu_to_body,
                                          cutoff_hz=cutoff_hz, time_shift=True,
                                          drift_shift=fit_drift, reference_time=middle)
        x, covariance, residual = solve_specific_force(y, design, correlation=correlation)
        if not np.max(np.sqrt(np.diag(covariance)[6:9])) <= MAX_BIAS_STD:
            x, covariance, residual = solve_specific_force(y, design, fit_bias=False,
                                                           correlation=correlation)
        delta = float(x[UNKNOWNS])
        middle_std = std = float(np.sqrt(max(covariance[UNKNOWNS, UNKNOWNS], 0.0)))
        if fit_drift:
            # c = m - tau_m d 1e-6: J = [1, -tau_m 1e-6] on (delta_m, delta_d)
            jacobian = np.array([1.0, -middle * 1e-6])
            clock = covariance[UNKNOWNS:, UNKNOWNS:]
            std = float(np.sqrt(max(jacobian @ clock @ jacobian, 0.0)))
            drift_std = float(np.sqrt(max(clock[1, 1], 0.0)))
            drift_ppm += float(x[UNKNOWNS + 1])
            offset += delta - middle * 1e-6 * float(x[UNKNOWNS + 1])
        else:
            offset += delta
        iterations += 1
    middle_offset = offset + middle * 1e-6 * drift_ppm
    return AccelerometerClock(offset=offset, offset_std=std, middle_offset=middle_offset,
                              middle_offset_std=middle_std, drift_ppm=drift_ppm,
                              drift_std_ppm=drift_std, iterations=iterations,
                              residual_rms=float(np.sqrt(np.mean(residual**2))),
                              converged=abs(delta) < TIME_SHIFT_TOLERANCE_S)


def fit_specific_force(recording: Recording, offset: float, drift_ppm: float,
                       imu_to_body: ArrayLike, *, cutoff_hz: float = CUTOFF_HZ
                       ) -> SpecificForceFit:
    """Gravity, lever arm and accelerometer bias (module docstring); the bias is dropped when
    the orientation changes too little to separate it from gravity (:data:`MAX_BIAS_STD`)."""
    y, design = specific_force_system(recording, offset, drift_ppm, imu_to_body,
                                      cutoff_hz=cutoff_hz)
    correlation = residual_correlation(recording.mocap.t, cutoff_hz)
    x, covariance, residual = solve_specific_force(y, design, correlation=correlation)
    if not np.max(np.sqrt(np.diag(covariance)[6:9])) <= MAX_BIAS_STD:
        x, covariance, residual = solve_specific_force(y, design, fit_bias=False,
                                                       correlation=correlation)
    std = np.sqrt(np.maximum(np.diag(covariance), 0.0))
    before = y.reshape(-1) - design[:, :, :3].reshape(-1, 3) @ x[:3]
    gravity, gravity_std = measured_gravity(x, covariance)
    return SpecificForceFit(gravity=gravity, gravity_std=gravity_std, lever_arm=x[3:6],
                            lever_arm_std=std[3:6], accelerometer_bias=x[6:9],
                            accelerometer_bias_std=std[6:9], accelerometer_scale_error=x[9:],
                            residual_rms=float(np.sqrt(np.mean(residual**2))),
                            residual_before_rms=float(np.sqrt(np.mean(before**2))),
                            samples=len(y))
