"""The linear model of the position filter, as small pure functions.

State ``x = [p, v, b]`` (9,), or ``[p, v, b, l]`` (12,) when the lever arm is estimated:
position p (m) and velocity v (m/s) of the IMU in the global frame, accelerometer bias b (m/s^2)
in the IMU frame, lever arm l (m, body frame: the IMU's position relative to the rigid-body
origin, constant).

Transition over ``[t0, t1]``, dt = t1 - t0. The IMU specific force f (m/s^2, IMU frame) is taken
as linear in time between its values at the two ends, ``f0`` and ``f1`` (first-order hold: the
samples are instantaneous values, and a sample at the end of the interval is known when it is
integrated), and so is the global acceleration
``a(t) = R(t) (f(t) - b) + g`` between ``a0 = R0 (f0 - b) + g`` and ``a1 = R1 (f1 - b) + g``
(R0, R1: ``R_global_imu`` at the ends). Integrating a linear acceleration exactly::

    v1 = v0 + dt (a0 + a1) / 2
    p1 = p0 + v0 dt + dt^2 (a0 / 3 + a1 / 6)
    b1 = b0 + w_b,   l1 = l0

i.e. ``x1 = F x0 + B u`` with ``u = [f0; f1; g]`` (9,), ``Rp = R0/3 + R1/6``, ``Rv = (R0 + R1)/2``::

    F = [[I, dt I, -dt^2 Rp, 0],      B = [[dt^2 R0/3, dt^2 R1/6, dt^2/2 I],
         [0,    I,    -dt Rv, 0],           [ dt R0/2,   dt R1/2,    dt I ],
         [0,    0,         I, 0],           [       0,         0,       0 ],
         [0,    0,         0, I]]           [       0,         0,       0 ]]

With ``R0 = R1 = R`` and ``f0 = f1 = f`` this is the zero-order-hold form
``p1 = p0 + v0 dt + dt^2/2 (R (f - b) + g)``, ``v1 = v0 + dt (R (f - b) + g)``; the filter uses
that when the end sample is not known yet (a mocap fix between two IMU samples, or extrapolation).

Measurement: the mocap gives the rigid-body point ``z = p - R_global_body l + r``, so
``H = [I 0 0 -R_global_body]`` with ``R_z = sigma_p^2 I``; without the lever-arm states
``H = [I 0 0]`` and a known lever arm enters as the offset ``c = -R_global_body l``:
``z = H x + c + r``.

Where a function takes ``out`` it fills that preallocated array in place (the streaming filter
calls them at IMU rate) and returns it; every entry is written. :func:`fill_interval` refills
only the interval-dependent entries of a preallocated F and B.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.stats import chi2

from kfusion.conventions import STANDARD_GRAVITY
from kfusion.kalman.layout import BASE_LAYOUT, LEVER_LAYOUT, layout_for

BASE_SIZE = BASE_LAYOUT.size
LEVER_SIZE = LEVER_LAYOUT.size
CONTROL_SIZE = 9
MEASUREMENT_SIZE = 3
POSITION = LEVER_LAYOUT.slice("position")
VELOCITY = LEVER_LAYOUT.slice("velocity")
BIAS = LEVER_LAYOUT.slice("bias")
LEVER = LEVER_LAYOUT.slice("lever_arm")

SATURATION_FRACTION = 0.999
"""A sample axis at or beyond this fraction of the sensor range counts as saturated."""
IMPLAUSIBLE_SAMPLE = 1e6
"""An IMU value beyond this (m/s^2 or rad/s: 100 000 g, 160 000 rev/s) is corrupt: rejected."""

# A sensor clipping below its declared range (a chip left at its power-on +-2 g / +-250 dps while
# the profile says 16 g / 2000 dps) reports a flat top the declared range does not catch. The
# plateau test (:func:`plateau_step`) finds that level in the data.
PLATEAU_REPEATS = 4
"""Samples repeating an axis's previous value exactly at that axis's largest magnitude so far
(within ``SATURATION_FRACTION``) that make that magnitude a clipping level: a clipped channel
repeats its full-scale code; a real peak, even quantised, does so once or twice (on BROAD's seven
trials and 40 simulated recordings, none reached 4 without clipping)."""
PLATEAU_TOLERANCE = 0.98
"""Once an axis's plateau is found, a sample with that axis at this fraction of its level or
beyond is saturated (its two sides clip a little apart once a bias is subtracted)."""
PLATEAU_FLOOR_ACCELEROMETER = 0.9 * 2.0 * STANDARD_GRAVITY
"""m/s^2: 90 % of the smallest full scale of MEMS accelerometers (+-2 g): a flat top below it
is a still or slow sensor's quantisation, not a range."""
PLATEAU_FLOOR_GYROSCOPE = 0.9 * math.radians(125.0)
"""rad/s: 90 % of the smallest full scale of MEMS gyroscopes (+-125 dps)."""

Triple = tuple[float, float, float]


def plateau_step(sample: Triple | NDArray[np.float64],
                 previous: Triple | NDArray[np.float64] | None,
                 tops: Triple, repeats: Triple, floor: float) -> tuple[Triple, Triple, float]:
    """One sample of the plateau test for a sensor clipping below its declared range, axis by
    axis (each axis keeps its own level: calibration moves the axes' full scales apart).

    ``tops`` are the largest magnitudes each axis has shown (the sensor's units), ``repeats``
    how often the axis has since repeated its ``previous`` value exactly at ``|v| >=
    SATURATION_FRACTION top`` and ``>= floor``. A larger value raises the axis's top and clears
    its repeats (it was a peak, not a level). With ``repeats >= PLATEAU_REPEATS`` an axis at
    ``PLATEAU_TOLERANCE top`` or beyond saturates the sample, which then gets
    ``saturation_variance(level)`` as if that level were the declared range. Returns ``(tops,
    repeats, level)``, ``level`` the largest top of an axis saturating the sample, else 0."""
    new_tops, new_repeats, level = list(tops), list(repeats), 0.0
    for axis in range(3):
        value = abs(sample[axis])
        if value > new_tops[axis]:
            new_tops[axis], new_repeats[axis] = value, 0.0
        if previous is not None and value >= floor \
                and value >= SATURATION_FRACTION * new_tops[axis] \
                and sample[axis] == previous[axis]:
            new_repeats[axis] += 1.0
        if new_repeats[axis] >= PLATEAU_REPEATS and value >= PLATEAU_TOLERANCE * new_tops[axis]:
            level = max(level, new_tops[axis])
    return ((new_tops[0], new_tops[1], new_tops[2]),
            (new_repeats[0], new_repeats[1], new_repeats[2]), level)


def clipping_levels(values: NDArray[np.float64], floor: float) -> NDArray[np.float64]:
    """The level (the sensor's units) at which each axis of a whole stream of samples ``values``
    (n, 3) clips, (3,), 0 where it does not: :func:`plateau_step` run over the stream, each
    axis's top when its test ends on a plateau. Offline (``kfusion check``): the filter
    saturates samples from a plateau's fourth repeat on, this names the levels for the whole
    stream."""
    tops: Triple = (0.0, 0.0, 0.0)
    repeats: Triple = (0.0, 0.0, 0.0)
    previous = None
    for sample in np.asarray(values, dtype=float).tolist():
        tops, repeats, _ = plateau_step(sample, previous, tops, repeats, floor)
        previous = sample
    return np.where(np.asarray(repeats) >= PLATEAU_REPEATS, np.asarray(tops), 0.0)


def state_size(estimate_lever_arm: bool) -> int:
    """9, or 12 with the lever-arm states (:func:`kfusion.kalman.layout.layout_for`)."""
    return layout_for(estimate_lever_arm).size


def fill_interval(F: NDArray[np.float64], B: NDArray[np.float64], R_start: ArrayLike,
                  R_end: ArrayLike, dt: float) -> None:
    """Write into F (n, n) and B (n, 9) the entries that depend on the interval: dt and the
    rotations ``R_global_imu`` (3, 3) at its start and end (see the module docstring).

    F and B must already hold the constant structure (identity diagonal of F, zeros elsewhere)
    as :func:`transition_matrix` and :func:`control_matrix` build it; the streaming filter keeps
    one pair and refills it at every IMU step.
    """
    R0 = np.asarray(R_start, dtype=float)
    R1 = np.asarray(R_end, dtype=float)
    dt2 = dt * dt
    position_start = R0 * (dt2 / 3.0)
    position_end = R1 * (dt2 / 6.0)
    velocity_start = R0 * (0.5 * dt)
    velocity_end = R1 * (0.5 * dt)
    F[0, 3] = F[1, 4] = F[2, 5] = dt
    np.negative(position_start + position_end, out=F[POSITION, BIAS])
    np.negative(velocity_start + velocity_end, out=F[VELOCITY, BIAS])
    B[POSITION, 0:3] = position_start
    B[POSITION, 3:6] = position_end
    B[VELOCITY, 0:3] = velocity_start
    B[VELOCITY, 3:6] = velocity_end
    B[0, 6] = B[1, 7] = B[2, 8] = 0.5 * dt2
    B[3, 6] = B[4, 7] = B[5, 8] = dt


def transition_matrix(R_start: ArrayLike, R_end: ArrayLike, dt: float,
                      size: int = BASE_SIZE) -> NDArray[np.float64]:
    """F (size, size) over dt (s) with ``R_global_imu`` (3, 3) at the start and end of the
    interval (equations in the module docstring)."""
    F = np.eye(size)
    fill_interval(F, np.zeros((size, CONTROL_SIZE)), R_start, R_end, dt)
    return F


def control_matrix(R_start: ArrayLike, R_end: ArrayLike, dt: float,
                   size: int = BASE_SIZE) -> NDArray[np.float64]:
    """B (size, 9) mapping ``u = [f0; f1; g]`` over dt (s); see the module docstring."""
    B = np.zeros((size, CONTROL_SIZE))
    fill_interval(np.eye(size), B, R_start, R_end, dt)
    return B


def control_input(accelerometer_start: ArrayLike, accelerometer_end: ArrayLike,
                  gravity: ArrayLike, out: NDArray[np.float64] | None = None
                  ) -> NDArray[np.float64]:
    """``u = [f0; f1; g]`` (9,): specific force at both ends (m/s^2, IMU frame), gravity (m/s^2,
    global frame)."""
    u = np.empty(CONTROL_SIZE) if out is None else out
    u[0:3] = accelerometer_start
    u[3:6] = accelerometer_end
    u[6:9] = gravity
    return u


def process_noise(
    dt: float,
    accelerometer_noise_density: float,
    accelerometer_bias_random_walk: float,
    *,
    acceleration_variance: float = 0.0,
    bias_variance: float = 0.0,
    size: int = BASE_SIZE,
    out: NDArray[np.float64] | None = None,
) -> NDArray[np.float64]:
    """Q (size, size) over dt (s): accelerometer white noise, bias random walk, extras.

    White noise. Each sample carries noise w of variance ``Var(w) = sigma_a^2 / dt`` per axis
    (``sigma_a`` the density, m/s^2/sqrt(Hz); the simulator draws std ``sigma_a / sqrt(dt)``
    per sample). Under the first-order hold the sample at t_k enters the interval before it and
    the one after it, each with half of its velocity change ``dt w_k``; one step later
    (at t_{k+1}) its whole effect is ``dp = dt^2 w_k``, ``dv = dt w_k``, exactly that of a
    velocity impulse ``dt w_k`` at t_k. Taking the start sample's noise as that impulse makes
    the noise of successive intervals independent, and with ``R R^T = I``::

        Q_pp = Var(w) dt^4 I = sigma_a^2 dt^3 I
        Q_pv = Var(w) dt^3 I = sigma_a^2 dt^2 I
        Q_vv = Var(w) dt^2 I = sigma_a^2 dt   I

    (the end sample's half kick, already inside the interval, is counted in the next one: an
    offset of one sample in the p-v covariance). A zero-order hold would give dt^3/4 and dt^2/2,
    continuous white acceleration dt^3/3 and dt^2/2; with the first-order hold these two are
    inconsistent (the velocity NEES of a model-matched simulation comes out 10 % low with the
    first, 60 % high with the exact within-interval form, and 2 % off with this one).

    Extras. ``acceleration_variance`` ((m/s^2)^2, per axis) is an error of this interval's
    acceleration alone (a saturated sample, :func:`interpolation_variance`), held over it:
    ``[dt^4/4, dt^3/2, dt^2]`` times it. The bias walks with ``sigma_b^2 dt`` (sigma_b in
    m/s^3/sqrt(Hz)) plus ``bias_variance`` ((m/s^2)^2: :func:`orientation_leak_variance`,
    :func:`scale_error_variance`). The lever arm is constant: no process noise.
    """
    Q = np.empty((size, size)) if out is None else out
    Q.fill(0.0)
    a2 = accelerometer_noise_density * accelerometer_noise_density
    extra = acceleration_variance
    dt2 = dt * dt
    pp = a2 * dt2 * dt + extra * dt2 * dt2 / 4.0
    pv = a2 * dt2 + extra * dt2 * dt / 2.0
    vv = a2 * dt + extra * dt2
    bb = accelerometer_bias_random_walk * accelerometer_bias_random_walk * dt + bias_variance
    for axis in range(3):
        Q[axis, axis] = pp
        Q[axis, axis + 3] = Q[axis + 3, axis] = pv
        Q[axis + 3, axis + 3] = vv
        Q[axis + 6, axis + 6] = bb
    return Q


def output_point(H: NDArray[np.float64], x: NDArray[np.float64],
                 offset: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rigid-body point (3,) m from the state (n,): ``H x + c`` (H (3, n) and c (3,) from
    the filter's output map). The filter, the batch driver and the Tracker all compute it here,
    in one order of operations, so that they agree to the bit."""
    return H @ x + offset


def output_matrices(rows: int, size: int, varies: bool) -> NDArray[np.float64]:
    """H (rows, 3, n) of a run's rows (:func:`output_point`). With the lever-arm states
    (``varies``: H holds ``-R_global_body``, which turns with the body) zeros for the run to
    fill row by row. Without them H is ``[I 0 0]`` on every row, whatever the orientation: then
    a read-only view of that one (3, n) matrix, which takes no memory per row (only the offset
    c changes from row to row, with a known lever arm)."""
    if varies:
        return np.zeros((rows, MEASUREMENT_SIZE, size))
    selector = np.zeros((MEASUREMENT_SIZE, size))
    selector[:, POSITION] = np.eye(MEASUREMENT_SIZE)
    return np.broadcast_to(selector, (rows, MEASUREMENT_SIZE, size))


def output_matrix_rows(output_matrix: NDArray[np.float64], rows: NDArray[np.intp]
                       ) -> NDArray[np.float64]:
    """``output_matrix[rows]`` (k, 3, n) for row indices ``rows`` (k,), still one shared H
    where ``output_matrix`` is (:func:`output_matrices`; indexing would copy it per row)."""
    if output_matrix.strides[0] == 0 and len(output_matrix):
        return np.broadcast_to(output_matrix[0], (len(rows), *output_matrix.shape[1:]))
    return output_matrix[rows]


def output_covariance(H: NDArray[np.float64], P: NDArray[np.float64]) -> NDArray[np.float64]:
    """The state's part of the rigid-body point's covariance (3, 3) m^2: ``H P H^T`` (see
    :func:`output_point`). The orientation's part is :func:`orientation_error_covariance`."""
    return H @ P @ H.T


def orientation_error_variance(arm: NDArray[np.float64], angle_variance: ArrayLike
                               ) -> NDArray[np.float64]:
    """Per axis (..., 3) m^2: the diagonal of :func:`orientation_error_covariance`, for one
    arm (3,) or rows of them (m, 3) with their angle variances (m,)::

        sigma_theta^2 (|a|^2 - a_i^2)
    (elementwise, in one order, so that a row and a batch of rows agree to the bit; exactly 0
    where ``|a|^2 - a_i^2`` is 0, whatever the angle variance: no lever, no term)."""
    a = np.asarray(arm, dtype=float)
    squared = a[..., 0] * a[..., 0] + a[..., 1] * a[..., 1] + a[..., 2] * a[..., 2]
    difference = squared[..., None] - a * a
    variance = np.broadcast_to(np.asarray(angle_variance, dtype=float)[..., None],
                               difference.shape)
    return np.multiply(variance, difference, out=np.zeros(difference.shape),
                       where=difference != 0.0)


def orientation_error_covariance(arm: NDArray[np.float64], angle_variance: float
                                 ) -> NDArray[np.float64]:
    """The orientation's part (3, 3) m^2 of the rigid-body point's covariance.

    The point is ``o = p - R_global_body l``: the IMU point p less the arm
    ``a = R_global_body l = p - o`` (3,) m, global frame. R is not a state of the position
    filter (the orientation tracker's); its error ``R_true = Exp(dtheta) R`` with per-axis
    variance sigma_theta^2 (rad^2, :attr:`OrientationTracker.angle_variance`) moves the point
    by ``-dtheta x a = a x dtheta``::

        Cov = sigma_theta^2 [a x][a x]^T = sigma_theta^2 (|a|^2 I - a a^T)

    Zero without a lever arm. The position fixes do not reduce it (they update p, not R), so
    it is added to the output and left out of ``H P H^T``; the cross-covariance of p and
    dtheta is left out (it is negative where measured: conservative)."""
    x, y, z = (float(value) for value in arm)
    if x == 0.0 and y == 0.0 and z == 0.0:
        return np.zeros((3, 3))
    squared = x * x + y * y + z * z  # the order of orientation_error_variance: the same bits
    variance = float(angle_variance)

    def term(difference: float) -> float:  # 0 where the arm leaves no term, whatever sigma^2
        return variance * difference if difference != 0.0 else 0.0

    xy, xz, yz = term(-(x * y)), term(-(x * z)), term(-(y * z))
    return np.array([[term(squared - x * x), xy, xz],
                     [xy, term(squared - y * y), yz],
                     [xz, yz, term(squared - z * z)]])


def output_arm(x: NDArray[np.float64], point: NDArray[np.float64]) -> NDArray[np.float64]:
    """The arm ``a = p - o`` (..., 3) m from the rigid-body point ``point`` (..., 3) to the
    IMU point ``p`` of the state ``x`` (..., n): ``R_global_body l`` (zero without a lever)."""
    return x[..., POSITION] - point


def measurement_matrix(size: int = BASE_SIZE, R_global_body: ArrayLike | None = None,
                       out: NDArray[np.float64] | None = None) -> NDArray[np.float64]:
    """H (3, size): ``[I 0 0]``, or ``[I 0 0 -R_global_body]`` with the lever-arm states.

    The same matrix maps the state to the rigid-body point for the output."""
    H = np.empty((MEASUREMENT_SIZE, size)) if out is None else out
    H.fill(0.0)
    H[0, 0] = H[1, 1] = H[2, 2] = 1.0
    if size == LEVER_SIZE:
        if R_global_body is None:
            raise ValueError("measurement_matrix: the lever-arm states need R_global_body (3, 3)")
        np.negative(np.asarray(R_global_body, dtype=float), out=H[:, LEVER])
    return H


def measurement_noise(position_noise: float) -> NDArray[np.float64]:
    """R_z = sigma_p^2 I (3, 3), sigma_p in m."""
    return np.eye(MEASUREMENT_SIZE) * position_noise ** 2


def initial_state(point: ArrayLike, size: int = BASE_SIZE) -> NDArray[np.float64]:
    """x0: position at the first fix's IMU point (3,), m; zero velocity, bias and lever arm."""
    x = np.zeros(size)
    x[POSITION] = point
    return x


def initial_covariance(position_noise: float, velocity_std: float, bias_std: float,
                       lever_arm_std: float = 0.0, size: int = BASE_SIZE,
                       R_global_body: ArrayLike | None = None) -> NDArray[np.float64]:
    """P0 (size, size) at the first fix.

    ``diag(sigma_p^2 I, sigma_v^2 I, sigma_b^2 I)``, and with the lever-arm states
    ``sigma_l^2 I`` on l. The first fix fixes the rigid-body point ``p - R_gb l`` to sigma_p, so
    with ``p = z + R_gb l`` the IMU point inherits the lever-arm uncertainty and the two are
    correlated: ``P_pp = sigma_p^2 I + sigma_l^2 I``, ``P_pl = sigma_l^2 R_gb``.
    """
    P = np.zeros((size, size))
    P[POSITION, POSITION] = position_noise ** 2 * np.eye(3)
    P[VELOCITY, VELOCITY] = velocity_std ** 2 * np.eye(3)
    P[BIAS, BIAS] = bias_std ** 2 * np.eye(3)
    if size == LEVER_SIZE:
        if R_global_body is None:
            raise ValueError("initial_covariance: the lever-arm states need R_global_body")
        R = np.asarray(R_global_body, dtype=float)
        lever_variance = lever_arm_std ** 2
        P[POSITION, POSITION] += lever_variance * np.eye(3)
        P[POSITION, LEVER] = lever_variance * R
        P[LEVER, POSITION] = lever_variance * R.T
        P[LEVER, LEVER] = lever_variance * np.eye(3)
    return P


def gate_threshold(probability: float | None, dof: int = MEASUREMENT_SIZE) -> float:
    """Chi-square quantile: innovations with NIS above it are rejected. inf when gating is off
    (``probability`` None or 1)."""
    if probability is None or probability >= 1.0:
        return math.inf
    return float(chi2.ppf(probability, dof))


def normalised_innovation_squared(y: ArrayLike, S: ArrayLike) -> float:
    """NIS = y^T S^-1 y for innovation y (3,) and its covariance S (3, 3); inf when it
    overflows (an absurd fix, e.g. 1e200 m away: gated, without a numpy warning)."""
    y = np.asarray(y, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        nis = float(y @ np.linalg.solve(np.asarray(S, dtype=float), y))
    return nis if math.isfinite(nis) else math.inf


def orientation_leak_variance(specific_force_squared: float, angle_variance_increase: float,
                              inflation: float = 1.0) -> float:
    """Bias-increment variance ((m/s^2)^2) standing for orientation error grown over a step.

    An orientation error dtheta (rad, IMU frame) turns the specific force f into a wrong global
    acceleration: ``R (I + [dtheta x]) f - R f = -R [f x] dtheta``. In the IMU frame this is an
    additive error ``e = -[f x] dtheta``, which acts like an accelerometer bias and, like one,
    varies slowly. Its per-axis variance is at most ``|f|^2 Var(dtheta)``. So when the
    orientation's angle variance grows by ``d Var`` over a step (gyroscope noise, bias and scale
    error through a gap), the bias variance grows by::

        Q_bb,extra = inflation |f|^2 max(d Var, 0)

    1 deg of tilt leaks 0.17 m/s^2 of gravity. ``specific_force_squared`` is ``|f|^2``.
    """
    return inflation * specific_force_squared * max(angle_variance_increase, 0.0)


def scale_error_variance(scale_error: float, change_squared: float, dt: float,
                         coherence_time: float | None = None) -> float:
    """Bias-increment variance ((m/s^2)^2) for a scale-factor error over a step of dt (s).

    A scale and cross-axis error S (1-sigma ``scale_error`` per entry) adds ``e = S f`` to the
    specific force f, an error that changes only as f changes:
    ``Var(e(t2) - e(t1)) = scale_error^2 |f(t2) - f(t1)|^2`` per axis. The filter carries it in
    the bias state as a random walk. Motion is coherent over about tau (the low-pass time
    constant of f), so the walk is matched to the change over tau, ``|df/dt|^2 tau^2``: with
    ``|df|^2`` the squared change of the low-passed f over the step (``change_squared``)::

        Q_bb,extra = scale_error^2 |df|^2 tau / dt

    It lets the bias follow ``S f`` while fixes arrive and grows it honestly through a gap.
    """
    tau = SCALE_ERROR_COHERENCE_S if coherence_time is None else coherence_time
    if dt <= 0.0:
        return 0.0
    return scale_error * scale_error * change_squared * tau / dt


def motion_acceleration_variance(dynamic_force_squared: float, dt: float, scale_error: float,
                                 correlation_time: float) -> float:
    """Acceleration variance (per axis, (m/s^2)^2, held over one interval of dt s: the
    ``acceleration_variance`` of :func:`process_noise`) for the fast part of the scale error,
    which no state carries.

    A scale and cross-axis error S (1-sigma ``scale_error`` per entry) adds ``e = S f`` to the
    specific force f. The bias state follows its slow part, ``S f_lp`` (f_lp the low-passed
    force, time constant tau: :func:`scale_error_variance`); the rest, ``S (f - f_lp)``, is an
    acceleration error of per-axis variance at most ``sigma^2 = scale_error^2 |f - f_lp|^2``
    (``dynamic_force_squared`` = ``|f - f_lp|^2``), high-passed at tau and so correlated over
    about tau (``correlation_time``). Over times longer than tau a correlated error of variance
    sigma^2 acts as white acceleration noise of density ``sigma^2 tau``, a per-interval
    variance ``sigma^2 tau / dt``::

        acceleration_variance = scale_error^2 |f - f_lp|^2 tau / dt

    Zero at rest and in slow motion, where the profile's white noise dominates; in a fast
    reach (|f - f_lp| ~ 5 m/s^2 with a 1.2 % error: 0.06 m/s^2 held over 0.1 s) it is the
    largest velocity noise, and it makes the velocity covariance at the last fix before a gap
    honest after fast motion. Plain float arithmetic, so that the compiled engine compiles this
    same function.
    """
    if dt <= 0.0:
        return 0.0
    return scale_error * scale_error * dynamic_force_squared * correlation_time / dt


def stamp_jitter_variance(change_squared: float, dt: float, timestamp_jitter: float) -> float:
    """Acceleration variance (per axis, (m/s^2)^2, held over one interval of dt s: the
    ``acceleration_variance`` of :func:`process_noise`) for IMU timestamps with random errors
    of 1-sigma ``timestamp_jitter`` (s).

    Sample k, taken at tau_k, is stamped ``t_k = tau_k + d_k``. The filter integrates the mean
    acceleration a_k of an interval over the stamped length, so the velocity increment is off by
    ``a_k (d_(k+1) - d_k)``. Summed over a run of intervals this telescopes::

        sum_k a_k (d_(k+1) - d_k) = a_(n-1) d_n - a_0 d_0 - sum_(k=1..n-1) d_k (a_k - a_(k-1))

    The end terms are the velocity the stamps of the two ends mislabel (bounded, re-observed at
    every fix); the sum is a random walk with independent steps of per-axis variance at most
    ``timestamp_jitter^2 |a_k - a_(k-1)|^2``. Held over dt, that is an acceleration variance::

        acceleration_variance = timestamp_jitter^2 |da|^2 / dt^2

    with ``change_squared`` = ``|da|^2`` the squared change of the acceleration over the step
    (the filter uses the change of the measured specific force, ``|f1 - f0|^2``, which also holds
    the rotation of gravity in the IMU frame: an upper bound). Zero without jitter (a clock
    that stamps on the sample instant) and at rest. Plain float arithmetic, so that the
    compiled engine compiles this same function.
    """
    if dt <= 0.0:
        return 0.0
    return timestamp_jitter * timestamp_jitter * change_squared / (dt * dt)


def timestamp_jitter(t: NDArray[np.float64]) -> float:
    """1-sigma random error (s) of a stream's timestamps t (n,) s, measured from the scatter of
    its sample intervals around their median.

    With stamps ``t_k = tau_k + d_k`` on a regular clock and independent errors d_k of
    variance s^2, each interval ``t_(k+1) - t_k = dt + d_(k+1) - d_k`` scatters with variance
    ``2 s^2``, so::

        s = 1.4826 median(|interval - median(interval)|) / sqrt(2)

    (the median absolute deviation, scaled to a standard deviation, is blind to the few
    dropouts and bursts that a mean square would count as jitter). 0.0 for fewer than three
    stamps or a regular clock.
    """
    stamps = np.asarray(t, dtype=float)
    stamps = stamps[np.isfinite(stamps)]
    if len(stamps) < 3:
        return 0.0
    intervals = np.diff(stamps)
    deviation = float(np.median(np.abs(intervals - np.median(intervals))))
    return 1.482602218505602 * deviation / math.sqrt(2.0)


NOISE_CHANGE_QUANTILE = float(chi2.ppf(0.99, 3))
"""99 % quantile of chi-square(3): sample-to-sample changes below it are left to the noise."""


def interpolation_variance(change_squared: float, noise_variance: float,
                           impact: bool = False) -> float:
    """Variance (per axis) of the error of the linear interpolation between two samples whose
    values differ by ``sqrt(change_squared)`` (a 3-vector difference).

    What the signal does between two samples is unknown; taking it uniform within half the
    change on either side of the straight line gives ``(Delta_i)^2 / 12`` on axis i, on average
    ``|Delta|^2 / 36``. On an impact (:func:`is_impact`: the housing rings faster than the
    samples resolve) the signal may swing by the whole change along its direction: an
    oscillation of amplitude ``|Delta| / 2`` either side of the line, of mean square
    ``|Delta|^2 / 8`` along the knock. Q is isotropic, so that goes on every axis, three times
    the knock's own total: spread over the axes as the ``/ 36`` rule spreads its
    ``|Delta|^2 / 12`` (``|Delta|^2 / 24`` per axis), the knock's direction would get a third
    of it (and trial 24's rows below barely move: 248 -> 223 and 32 -> 31).
    White sensor noise alone makes ``|Delta|^2`` a ``2 noise_variance`` times chi-square(3)
    variable (``noise_variance`` per sample and axis), already in Q; only the part beyond its
    99 % quantile (11.34) is counted::

        max(|Delta|^2 - 2 * 11.34 noise_variance, 0) / 36   (/ 8 on an impact)

    It matters on impacts (a tap on a table rings at hundreds of m/s^2 from one sample to the
    next), where it makes the filter read the jumps as velocity noise instead of learning them as
    bias; on smooth motion it is negligible. With ``/ 36`` on impacts too, the gap rows of BROAD
    trial 24 (tapping) with a tap since their gap's last fix were 8.7 % beyond their 99 % bound
    (32 of 367 rows, gaps cut with seeds 0-2), and 18 % (248 of 1383) with the gaps placed at
    the trial's most violent moments; with ``/ 8``, 1.1 % and 6.9 %. The cost, measured by an
    adversarial review on simulated knocks of 200 m/s^2 clipped at the sensor's 8 g (8 seeds of
    60 s): gap rows beyond their bound 0.75 -> 0.94 % (kalman) and 1.89 -> 2.04 % (smoother,
    whose worst row falls from 3.12x to 1.98x).
    """
    excess = max(change_squared - 2.0 * NOISE_CHANGE_QUANTILE * noise_variance, 0.0)
    return excess / 8.0 if impact else excess / 36.0


def is_impact(change_squared: float, dt: float, impact_jerk: float,
              noise_variance: float) -> bool:
    """True when an IMU interval of dt (s) whose specific force changes by
    ``sqrt(change_squared)`` (m/s^2) is an impact: the change beyond what the sensor's white
    noise explains (as in :func:`interpolation_variance`: ``noise_variance`` per sample and
    axis, (m/s^2)^2) is faster than ``impact_jerk`` (m/s^3;
    :attr:`kfusion.kalman.KalmanParameters.impact_jerk`)::

        |f1 - f0|^2 - 2 * 11.34 noise_variance > impact_jerk^2 dt^2

    (noise alone grows the change as ``1 / sqrt(dt)``: a fast IMU's noise would otherwise read
    as knocks). An interval split by a mocap frame: the part before the frame holds the last
    sample (the next is not known yet) and changes by nothing; the part after it has the whole
    interval's rate of change, so the impact is found there. False for dt <= 0 and for an infinite
    ``impact_jerk``. Plain float arithmetic, so that the compiled engine compiles this same
    function.
    """
    if dt <= 0.0 or impact_jerk == math.inf:
        return False
    limit = impact_jerk * dt
    return change_squared - 2.0 * NOISE_CHANGE_QUANTILE * noise_variance > limit * limit


LOW_PASS_TIME_CONSTANT = 0.1
"""s: time constant of the low-passed specific force used for the scale-error term (long enough
to average out the ringing of an impact, short against a limb movement)."""
SCALE_ERROR_COHERENCE_S = 0.5
"""s: time over which a limb's specific force changes coherently (a reach lasts 0.5-1 s)."""
FORGOTTEN_POSITION_STD = 1.0e5
"""m: a prediction whose position 1-sigma exceeds this (100 km) on some axis says nothing about
where the body is. The state is then forgotten (``resets``), as when a propagation overflows:
``lost`` until a fix with an orientation initialises it again, as a recording's first
(:func:`state_usable`). The no-IMU model (``Q_pp = q^2 dt^3 / 3`` with q = 30 m/s^2/sqrt(Hz))
gets there after about 320 s without IMU samples or fixes; the IMU alone after about 10 minutes
without fixes. A fix on a prior far beyond that is fused into a covariance 1e20 or more times its
own noise, where rounding is all that is left of the posterior: after a 1e5 s pause the two
engines parted by 1e-9 m, after 1e7 s by 4e-6 m, and three frames 1e15 s apart came out 1-3 mm
off with 1 mm bounds. Up to this std the update keeps the posterior (filterpy's Joseph order,
:func:`kfusion.kalman.compiled.position_update`: 2e-12 m between the engines after a 500 s pause,
a prior 4e17 times R), and the prediction a re-acquiring fix replaced stays its rival
(:meth:`kfusion.monitor.ConsistencyMonitor._reacquisition_rival`): at 1 km (a minute of IMU
alone) a reset made the first fixes a recording's first, and a body solved 3 mm off on its first
10 frames at re-entry was then tracked 4.4x beyond its bound, where the rival covered it."""


def state_usable(x: NDArray[np.float64], P: NDArray[np.float64], position: slice) -> bool:
    """True when the state x (n,) and its covariance P (n, n) are finite and no position
    variance (the ``position`` block's diagonal, m^2) exceeds ``FORGOTTEN_POSITION_STD^2``."""
    if not (np.isfinite(x).all() and np.isfinite(P).all()):
        return False
    return bool(np.diagonal(P)[position].max() <= FORGOTTEN_POSITION_STD ** 2)


def low_pass_weight(dt: float, time_constant: float = LOW_PASS_TIME_CONSTANT) -> float:
    """Weight of a new value in a first-order low-pass over dt (s): ``1 - exp(-dt / tau)``."""
    return -math.expm1(-dt / time_constant)


def saturation_variance(sensor_range: float) -> float:
    """Variance (per axis, squared sensor unit) given to a saturated sample: ``(range / 2)^2``,
    the true value lies somewhere beyond the clipped one."""
    return 0.25 * sensor_range * sensor_range


def reacquisition_inflation(innovation: ArrayLike, time_since_fix: float
                            ) -> tuple[float, float]:
    """Variances (per axis) added to position and velocity to re-initialise on a fix whose
    innovation failed the gate after a long gap.

    The drift ``|y|`` (m) over ``tau`` s is taken as the effect of an unmodelled constant
    acceleration e, ``|y| = e tau^2 / 2``, which leaves a velocity error ``e tau = 2 |y| / tau``::

        position: |y|^2 / 3        velocity: 4 |y|^2 / (3 tau^2)
    """
    y = np.asarray(innovation, dtype=float)
    position = float(y @ y) / 3.0
    tau = max(time_since_fix, 1e-3)
    return position, 4.0 * position / (tau * tau)
