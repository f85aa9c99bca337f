"""Orientation for the position filter: mocap while visible, gyroscope integration through gaps.

Choice (issue 4, section 2): gyroscope integration from the last seen orientation, with a
gyroscope bias learned while the mocap is visible. The position filter is linear only if the
rotation ``R_global_imu`` entering its transition is known, so orientation is kept outside it, in
a small filter of its own:

* the orientation ``q_global_imu`` is integrated from the gyroscope, minus the learned bias, at
  every IMU step (``q <- q ⊗ Exp((omega_mean - b_g) dt)``, omega_mean the mean of the rates at the
  two ends of the step: the first-order hold of :mod:`kfusion.kalman.model`);
* every accepted mocap fix corrects it towards ``q_global_body ⊗ q_body_imu`` and updates the
  bias with the gains of a two-state Kalman filter per axis, state ``[dtheta, db_g]`` (angle error
  and bias error, IMU frame). So while visible the orientation is the mocap's, smoothed by the
  gyroscope over a few frames (the mocap's own orientation noise is 0.2 deg);
* through a gap nothing corrects it: the orientation is the gyroscope integrated from the last
  fix with the bias learned while visible, and its variance grows as the model says (gyroscope
  noise, bias uncertainty, and a scale-error term growing with the rotation since the fix).

Why not an orientation error state inside the position filter (a 15-state error-state filter)?
It would let position fixes correct tilt, but it makes the model nonlinear (the transition
depends on the state), breaks the linear form that filterpy and the RTS smoother use as they are,
and costs a 15x15 covariance product per IMU sample. Mocap orientation is far better than what
position fixes could add, so the gain is small while visible; in a gap neither variant has a fix.
What the decoupled design loses is the *covariance* link between tilt error and position; it is
put back as process noise by :func:`kfusion.kalman.model.orientation_leak_variance`, using the
angle variance computed here. (Measured on the BROAD trials: replacing the gyroscope orientation
in 0.1-0.3 s gaps by the hidden mocap orientation changed the gap RMS by at most 0.2 mm on the
four fast trials, so, with this design, orientation is not where the error is.)

The two-state filter shares its variances between the three axes (isotropic noise, and the
small-angle error dynamics ``dtheta' = dtheta - dt db_g`` are the same on each axis), so its
covariance is three scalars. The rotation of the error frame by ``omega dt`` is neglected: it
leaves an isotropic covariance unchanged.

The maths is written on Python floats: at IMU rate a 4-element numpy operation costs more in call
overhead than the arithmetic. The quaternion operations are the per-sample forms in
:mod:`kfusion.conventions` (re-exported here for the filters that import them from this module).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import NDArray

from kfusion.conventions import (
    Quaternion,
    Vector,
    conjugate,
    matrix_from_quaternion,
    normalise,
    quaternion_exp,
    quaternion_log,
    quaternion_product,
    quaternion_step,
)

__all__ = [
    "OrientationState", "OrientationTracker", "PERSISTENCE_LIMIT", "Quaternion", "Vector",
    "absorbed_rotation", "conjugate", "persistent_innovations",
    "matrix_from_quaternion", "normalise", "propagate_orientation_covariance",
    "quaternion_exp", "quaternion_log", "quaternion_product", "quaternion_step",
]


PERSISTENCE_FIXES: Final = 25
"""Fixes the orientation innovations' exponential mean spans (:func:`persistent_innovations`):
0.25 s at 100 Hz, short enough to see a gyroscope bias step while its angle error builds."""
MEAN_WEIGHT: Final = 1.0 / PERSISTENCE_FIXES
MEAN_KEEP: Final = 1.0 - MEAN_WEIGHT
MEAN_NORMALISER: Final = (1.0 + MEAN_KEEP) / MEAN_WEIGHT
"""``(1 + lambda) / (1 - lambda)``: the inverse of the mean's variance per axis for white
unit-variance innovations, ``Var(m) = (1 - lambda) / (1 + lambda)``."""
PERSISTENCE_LIMIT: Final = 21.107513
"""The chi-square(3) quantile at 1 - 1e-4 (scipy.stats.chi2.ppf(0.9999, 3), checked in the
tests): a white innovation sequence crosses it about once in 10^4 fixes."""


def persistent_innovations(mean: Vector, square: float, innovation: Vector, variance: float
                           ) -> tuple[Vector, float, float]:
    """The orientation innovations checked against the model: per axis ``u = z / sqrt(S)`` is
    white with unit variance while the gyroscope's bias follows its random walk and its scale
    error stays within the profile. Their exponential mean, the mean of ``|u|^2``, and the test
    statistic::

        m <- lambda m + (1 - lambda) u                  (lambda = 1 - 1 / PERSISTENCE_FIXES)
        q <- lambda q + (1 - lambda) |u|^2              (3 for the model: the start)
        T  = |m|^2 (1 + lambda) / (1 - lambda) / max((q - |m|^2) / 3, 1)

    ``T`` is chi-square(3) for white innovations; the spread ``(q - |m|^2) / 3`` scales it down
    where the innovations are white but noisier than the model (a mocap orientation noisier
    than its profile: that is not a persistent error, and a covariance scaled for it made the
    tilt follow the noise). A bias step or drift, or a scale error beyond the profile, makes
    the innovations persistent (one sign for many fixes) well before any single one is large:
    with marker fits (8 mrad) and a 0.06 rad/s step, each fix's innovation stayed within its S
    while the angle error reached 20 mrad, 83 times its variance. Returns (m, q, T)."""
    root = math.sqrt(variance)
    ux, uy, uz = innovation[0] / root, innovation[1] / root, innovation[2] / root
    mx = MEAN_KEEP * mean[0] + MEAN_WEIGHT * ux
    my = MEAN_KEEP * mean[1] + MEAN_WEIGHT * uy
    mz = MEAN_KEEP * mean[2] + MEAN_WEIGHT * uz
    square = MEAN_KEEP * square + MEAN_WEIGHT * (ux * ux + uy * uy + uz * uz)
    length = mx * mx + my * my + mz * mz
    spread = max((square - length) / 3.0, 1.0)
    return (mx, my, mz), square, length * MEAN_NORMALISER / spread


def absorbed_rotation(rotation: Vector, gain_angle: float) -> Vector:
    """The rotation (3,) rad that a gyroscope scale error still acts on after an orientation
    fix of angle gain ``K_t`` (:meth:`OrientationTracker.correct`)::

        r <- (1 - K_t) r

    A scale and cross-axis error S is constant, so the angle error it builds, ``-S r``, is not
    white: a fix removes the fraction ``K_t`` of it and the rest stays. Resetting r at every fix
    counted ``S omega dt`` as a new independent increment each frame; with marker fits
    (``K_t`` about 0.05) the tracker then claimed 1.8 mrad against 2-3.4 mrad of error under a
    1 % scale error, and a lever of 8-15 cm carried that to the rigid-body point."""
    keep = 1.0 - gain_angle
    return (keep * rotation[0], keep * rotation[1], keep * rotation[2])


def propagate_orientation_covariance(
    covariance: tuple[float, float, float],
    dt: float,
    gyroscope_noise_density: float,
    gyroscope_bias_random_walk: float,
    extra_angle_variance: float = 0.0,
) -> tuple[float, float, float]:
    """Per-axis covariance ``(P_tt, P_tb, P_bb)`` of ``[dtheta, db_g]`` over dt.

    Continuous model ``dtheta' = -db_g + w_g``, ``db_g' = w_b`` (white noise densities sigma_g in
    rad/s/sqrt(Hz) and sigma_bg in rad/s^2/sqrt(Hz)); exact discretisation with
    ``F = [[1, -dt], [0, 1]]``::

        Q = [[sigma_g^2 dt + sigma_bg^2 dt^3/3, -sigma_bg^2 dt^2/2],
             [-sigma_bg^2 dt^2/2,               sigma_bg^2 dt     ]]
        P' = F P F^T + Q   (+ extra_angle_variance on P_tt, e.g. a saturated gyroscope)
    """
    angle, cross, bias = covariance
    g2 = gyroscope_noise_density * gyroscope_noise_density
    b2 = gyroscope_bias_random_walk * gyroscope_bias_random_walk
    angle_new = (angle - 2.0 * dt * cross + dt * dt * bias + g2 * dt + b2 * dt * dt * dt / 3.0
                 + extra_angle_variance)
    cross_new = cross - dt * bias - 0.5 * b2 * dt * dt
    bias_new = bias + b2 * dt
    return angle_new, cross_new, bias_new


@dataclass
class OrientationState:
    """Mutable state of :class:`OrientationTracker` (plain floats, so copies are cheap and exact).

    Attributes:
        quaternion: ``q_global_imu`` (w, x, y, z).
        gyroscope_bias: (3,) rad/s, IMU frame, subtracted from the gyroscope.
        covariance: per-axis ``(P_tt rad^2, P_tb rad^2/s, P_bb rad^2/s^2)``.
        rotation_since_fix: (3,) rad, IMU frame: the integrated rate since the last correction.
        scale_variance_peak: rad^2, the scale-error angle variance reached since then.
        innovation_mean: (3,) the exponential mean of the normalised innovations
            (:func:`persistent_innovations`), dimensionless.
        innovation_square: the exponential mean of their squared norm (3 for the model).
        initialised: False until the first mocap orientation.
    """

    quaternion: Quaternion = (1.0, 0.0, 0.0, 0.0)
    gyroscope_bias: Vector = (0.0, 0.0, 0.0)
    covariance: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_since_fix: Vector = (0.0, 0.0, 0.0)
    scale_variance_peak: float = 0.0
    innovation_mean: Vector = (0.0, 0.0, 0.0)
    innovation_square: float = 3.0
    initialised: bool = False

    def copy(self) -> OrientationState:
        """An independent copy (every field is immutable, so a shallow copy is exact)."""
        return dataclasses.replace(self)


class OrientationTracker:
    """Gyroscope integration with a bias learned from mocap orientations (see module docstring).

    Args:
        gyroscope_noise_density: rad/s/sqrt(Hz).
        gyroscope_bias_random_walk: rad/s^2/sqrt(Hz).
        mocap_orientation_noise: 1-sigma per axis of a mocap orientation, rad.
        initial_gyroscope_bias_std: 1-sigma of the gyroscope bias before the first fix, rad/s.
        gyroscope_scale_error: 1-sigma scale and cross-axis error (fraction); the angle variance
            grows by ``scale_error^2 |rotation since the last fix|^2`` (peak-held, see
            :func:`kfusion.kalman.model.scale_error_variance`).
    """

    def __init__(self, gyroscope_noise_density: float, gyroscope_bias_random_walk: float,
                 mocap_orientation_noise: float, initial_gyroscope_bias_std: float,
                 gyroscope_scale_error: float = 0.0) -> None:
        self.gyroscope_noise_density = gyroscope_noise_density
        self.gyroscope_bias_random_walk = gyroscope_bias_random_walk
        self.measurement_variance = mocap_orientation_noise ** 2
        self.initial_bias_variance = initial_gyroscope_bias_std ** 2
        self.scale_variance = gyroscope_scale_error ** 2
        self.state = OrientationState()

    @property
    def angle_variance(self) -> float:
        """Per-axis variance of the orientation error, rad^2."""
        return self.state.covariance[0]

    def matrix(self) -> NDArray[np.float64]:
        """``R_global_imu`` (3, 3) of the current estimate."""
        return matrix_from_quaternion(self.state.quaternion)

    def initialise(self, q_global_imu: Quaternion) -> None:
        """Start from a mocap orientation: angle variance sigma_m^2, bias 0 with its turn-on
        variance."""
        self.state = OrientationState(
            quaternion=normalise(q_global_imu),
            covariance=(self.measurement_variance, 0.0, self.initial_bias_variance),
            initialised=True)

    def propagate(self, gyroscope_start: Vector, gyroscope_end: Vector, dt: float,
                  extra_angle_variance: float = 0.0) -> None:
        """Integrate over dt (s) the gyroscope (rad/s, IMU frame) taken as linear between its
        values at the start and end of the interval, i.e. at their mean rate:
        ``q <- q ⊗ Exp(((omega0 + omega1)/2 - b_g) dt)``; grow the covariance
        (:func:`propagate_orientation_covariance`, plus the scale-error term and
        ``extra_angle_variance``)."""
        state = self.state
        if not state.initialised or dt <= 0:
            return
        bx, by, bz = state.gyroscope_bias
        rate = (0.5 * (gyroscope_start[0] + gyroscope_end[0]) - bx,
                0.5 * (gyroscope_start[1] + gyroscope_end[1]) - by,
                0.5 * (gyroscope_start[2] + gyroscope_end[2]) - bz)
        state.quaternion = quaternion_step(state.quaternion, rate, dt)
        if self.scale_variance > 0.0:
            rx, ry, rz = state.rotation_since_fix
            rx, ry, rz = rx + rate[0] * dt, ry + rate[1] * dt, rz + rate[2] * dt
            state.rotation_since_fix = (rx, ry, rz)
            peak = max(state.scale_variance_peak, self.scale_variance * (rx * rx + ry * ry
                                                                         + rz * rz))
            extra_angle_variance += peak - state.scale_variance_peak
            state.scale_variance_peak = peak
        state.covariance = propagate_orientation_covariance(
            state.covariance, dt, self.gyroscope_noise_density, self.gyroscope_bias_random_walk,
            extra_angle_variance)

    def correct(self, q_global_imu: Quaternion,
                measurement_variance: float | None = None) -> Vector:
        """Fuse a mocap orientation; returns the innovation ``Log(q_est^-1 ⊗ q_mocap)``, rad.

        ``measurement_variance`` (rad^2 per axis): this orientation's noise sigma_m^2 when it is
        not the configured one (a Kabsch fit of a few markers); None: the configured one.

        Per axis, with ``H = [1, 0]``::

            S = P_tt + sigma_m^2,  K = [P_tt, P_tb] / S
            dtheta = K_t z,  db_g = K_b z        (z: the innovation on that axis)
            q <- q ⊗ Exp(dtheta),  b_g <- b_g + db_g
            P <- (I - K H) P

        Signs: ``q_true = q_est ⊗ Exp(dtheta)`` and ``db_g = b_g,true - b_g,est``; the estimate
        turns at ``omega + db_g``, so ``dtheta' = -db_g`` and ``P_tb`` becomes negative, which
        makes a lagging truth (negative innovation) raise the bias estimate.

        The scale-error record keeps what the fix did not absorb (:func:`absorbed_rotation`):
        ``r <- (1 - K_t) r`` and the peak restarts at ``scale_error^2 |r|^2``.

        The innovations are checked against the model first (:func:`persistent_innovations`):
        where their mean is beyond ``PERSISTENCE_LIMIT``, the covariance (angle, cross and bias
        terms) is scaled by ``T / 3``, the factor the innovations exceed their model by, before
        this fix is fused (covariance matching), and the mean starts again. The angle variance
        then covers the error the bias or scale error built, and the larger bias variance lets
        the bias be learnt again within a few fixes.
        """
        state = self.state
        innovation = quaternion_log(quaternion_product(conjugate(state.quaternion),
                                                       q_global_imu))
        angle, cross, bias = state.covariance
        noise = self.measurement_variance if measurement_variance is None \
            else measurement_variance
        S = angle + noise
        if S <= 0.0:
            # exact orientation and exact prediction: take the measurement as it is
            state.rotation_since_fix = (0.0, 0.0, 0.0)
            state.scale_variance_peak = 0.0
            state.quaternion = normalise(q_global_imu)
            return innovation
        mean, square, statistic = persistent_innovations(
            state.innovation_mean, state.innovation_square, innovation, S)
        if statistic > PERSISTENCE_LIMIT:
            factor = statistic / 3.0
            angle, cross, bias = factor * angle, factor * cross, factor * bias
            S = angle + noise
            mean, square = (0.0, 0.0, 0.0), 3.0
        state.innovation_mean = mean
        state.innovation_square = square
        gain_angle = angle / S
        rx, ry, rz = absorbed_rotation(state.rotation_since_fix, gain_angle)
        state.rotation_since_fix = (rx, ry, rz)
        state.scale_variance_peak = self.scale_variance * (rx * rx + ry * ry + rz * rz)
        gain_bias = cross / S
        correction = (gain_angle * innovation[0], gain_angle * innovation[1],
                      gain_angle * innovation[2])
        state.quaternion = normalise(quaternion_product(state.quaternion,
                                                        quaternion_exp(correction)))
        bx, by, bz = state.gyroscope_bias
        state.gyroscope_bias = (bx + gain_bias * innovation[0], by + gain_bias * innovation[1],
                                bz + gain_bias * innovation[2])
        state.covariance = ((1.0 - gain_angle) * angle, (1.0 - gain_angle) * cross,
                            bias - gain_bias * cross)
        return innovation
