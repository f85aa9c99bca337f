"""The mount from the gyroscope's rates and the accelerometer's specific force together.

The rates (:mod:`kfusion.calibration.rates`) see the mount's rotation about an axis only when
the limb turns about another axis; the specific force (:mod:`kfusion.calibration.specific_force`)
sees it about every axis perpendicular to the force's direction in the body frame, which
gravity dominates: as the limb tilts, gravity sweeps through the body frame and pins the
axes a slow turn about one axis leaves loose. Each source gives an information matrix on a
small rotation theta (rad, body frame) of the mount, ``R_body_imu = exp([theta]x) R_0``, with
its own nuisance parameters marginalised (:func:`marginal_information`): offset, drift and
gyroscope bias for the rates; gravity, lever arm, accelerometer bias and the symmetric scale
error for the specific force. The accelerometer bias stays free: a bias constant in the IMU
frame and a tilt look alike while gravity stays put in the body frame, and only the change
of the force's direction tells them apart, which the marginalised information measures. The
joint estimate is the Gauss-Newton step of the summed weighted least squares
(:func:`fuse_mount`), relinearised until it settles (:func:`joint_mount`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from kfusion.calibration.specific_force import (
    CUTOFF_HZ,
    residual_correlation,
    robust_least_squares,
    specific_force_system,
    symmetric_scale_design,
)
from kfusion.conventions import rotation_from_wxyz, wxyz_from_rotation
from kfusion.recording import Recording

Array = NDArray[np.float64]

MAX_MOUNT_ITERATIONS: Final = 4
MOUNT_TOLERANCE_RAD: Final = 1e-4
"""rad (0.006 deg, far below any 1-sigma): the joint mount's Gauss-Newton stops below this
step."""
INFORMATION_FLOOR: Final = 1e-12
"""Relative eigenvalue below which an information direction counts as empty."""


def marginal_information(normal: ArrayLike, vector: ArrayLike, target: ArrayLike
                         ) -> tuple[Array, Array]:
    """Information on the ``target`` parameters with the others marginalised (Schur
    complement): for normal equations ``H p = b`` split into target t and nuisance n,

        I = H_tt - H_tn H_nn^+ H_nt,   h = b_t - H_tn H_nn^+ b_n,

    so that ``I p_t = h`` is the least-squares estimate of ``p_t`` and ``I^-1`` its covariance.
    A nuisance direction the data do not see (``H_nn`` singular) is handled by the
    pseudo-inverse (``A_n v = 0`` implies ``H_tn v = 0``). Inputs: H (m, m), b (m,), target
    indices (t,); the pseudo-inverse is taken on H scaled to unit diagonal."""
    H = np.asarray(normal, dtype=float)
    b = np.asarray(vector, dtype=float)
    t = np.asarray(target, dtype=int)
    n = np.setdiff1d(np.arange(len(H)), t)
    if len(n) == 0:
        return H[np.ix_(t, t)].copy(), b[t].copy()
    H_nn = H[np.ix_(n, n)]
    scale = np.sqrt(np.maximum(np.diag(H_nn), np.finfo(float).tiny))
    inverse = np.linalg.pinv(H_nn / np.outer(scale, scale), rcond=1e-12) / np.outer(scale, scale)
    H_tn = H[np.ix_(t, n)]
    information = H[np.ix_(t, t)] - H_tn @ inverse @ H_tn.T
    return 0.5 * (information + information.T), b[t] - H_tn @ inverse @ b[n]


def information_axes(information: ArrayLike) -> tuple[Array, Array]:
    """1-sigma (rad) along the principal axes of an information matrix (3, 3), weakest first,
    and the axes as columns: ``std_i = 1 / sqrt(lambda_i)`` (inf where the information is
    empty, below :data:`INFORMATION_FLOOR` of the largest)."""
    values, vectors = np.linalg.eigh(np.asarray(information, dtype=float))
    floor = INFORMATION_FLOOR * max(float(values[-1]), np.finfo(float).tiny)
    std = np.where(values > floor, 1.0 / np.sqrt(np.maximum(values, floor)), np.inf)
    return std, vectors


def fuse_mount(rate_information: ArrayLike, rate_theta: ArrayLike,
               force_information: ArrayLike, force_vector: ArrayLike
               ) -> tuple[Array, Array, float, int]:
    """One Gauss-Newton step on theta (rad, body frame) of the summed least squares

        J(theta) = (theta - theta_r)^T I_r (theta - theta_r) + theta^T I_f theta
                   - 2 h_f^T theta + const,

    with ``theta_r`` the rates' mount and ``(I_f, h_f)`` the specific force's marginal
    information at theta = 0: ``theta = (I_r + I_f)^-1 (I_r theta_r + h_f)``, restricted to
    the directions with information (others left at 0). Returns (theta (3,), information
    ``I_r + I_f`` (3, 3), the two sources' disagreement chi-square, its degrees of freedom):
    ``chi2 = (theta - theta_r)^T I_r (theta - theta_r) + (theta - theta_f)^T I_f (theta -
    theta_f)`` with ``I_f theta_f = h_f``, the mismatch left when both must agree, on the
    directions both determine (dof: the rank of ``I_f`` where ``I_r`` is also informative)."""
    I_r = np.asarray(rate_information, dtype=float)
    I_f = np.asarray(force_information, dtype=float)
    theta_r = np.asarray(rate_theta, dtype=float)
    h_f = np.asarray(force_vector, dtype=float)
    total = I_r + I_f
    std, axes = information_axes(total)
    seen = np.isfinite(std)
    values = 1.0 / std[seen] ** 2
    right = axes.T @ (I_r @ theta_r + h_f)
    theta = axes[:, seen] @ (right[seen] / values)
    # theta_f on the force's own informative directions
    force_std, force_axes = information_axes(I_f)
    force_seen = np.isfinite(force_std)
    theta_f = force_axes[:, force_seen] @ ((force_axes[:, force_seen].T @ h_f)
                                           * force_std[force_seen] ** 2)
    rate_std, _ = information_axes(I_r)
    dof = int(min(force_seen.sum(), np.isfinite(rate_std).sum()))
    d_r, d_f = theta - theta_r, theta - theta_f
    chi2 = float(d_r @ I_r @ d_r + d_f @ I_f @ d_f) if dof else 0.0
    return theta, total, chi2, dof


@dataclass(frozen=True)
class ForceMountInformation:
    """What the specific force says about the mount, at a given mount and clock.

    Attributes:
        information: (3, 3) rad^-2, on theta (body frame), nuisance marginalised.
        vector: (3,) the matching ``h`` (:func:`marginal_information`), rad^-1.
        force_body: (3,) mean direction (unit) of the filtered specific force in the body
            frame over the samples used, and ``spread_deg``: RMS angle of the samples'
            direction from it (how much the force turned in the body frame).
        residual_rms: m/s^2 per axis after the fit. samples: filtered samples used.
    """

    information: Array
    vector: Array
    force_body: Array
    spread_deg: float
    residual_rms: float
    samples: int


def force_mount_information(recording: Recording, offset: float, drift_ppm: float,
                            imu_to_body: ArrayLike, *, cutoff_hz: float = CUTOFF_HZ
                            ) -> ForceMountInformation:
    """The specific force's information on a mount rotation theta at ``imu_to_body``: the
    system of :func:`specific_force_system` with its mount columns, the scale error held
    symmetric (:func:`symmetric_scale_design`), the accelerometer bias free, solved robustly;
    ``H = A^T A / (sigma^2 c)`` and ``b = A^T y / (sigma^2 c)`` over the inliers, with
    ``c = rate / (2 cutoff)`` the filtered samples per independent one, then
    :func:`marginal_information`. ValueError as :func:`specific_force_system`."""
    y, design = specific_force_system(recording, offset, drift_ppm, imu_to_body,
                                      cutoff_hz=cutoff_hz, mount_shift=True)
    design = symmetric_scale_design(design)
    columns = design.shape[2]
    A, b = design.reshape(-1, columns), y.reshape(-1)
    solution, inlier = robust_least_squares(A, b)
    rows = np.repeat(inlier, 3)
    A, b = A[rows], b[rows]
    residual = b - A @ solution
    used = int(np.sum(np.any(A != 0.0, axis=0)))
    sigma2 = float(residual @ residual) / max(len(b) - used, 1)
    correlation = residual_correlation(recording.mocap.t, cutoff_hz)
    weight = 1.0 / (sigma2 * correlation)
    target = np.arange(columns - 3, columns)
    information, vector = marginal_information(A.T @ A * weight, A.T @ b * weight, target)
    # the force's direction in the body frame: the mount columns are R_global_body [f_body]x,
    # so f_body is read back from them (column j of [f]x is e_j x f)
    force_body = force_from_mount_columns(design[inlier][:, :, -3:])
    direction, spread = mean_direction(force_body)
    return ForceMountInformation(information=information, vector=vector, force_body=direction,
                                 spread_deg=spread, residual_rms=float(np.sqrt(np.mean(
                                     residual**2))), samples=int(inlier.sum()))


def force_from_mount_columns(columns: ArrayLike) -> Array:
    """``f_body`` (n, 3) from mount columns ``C = R [f]x`` (n, 3, 3): ``C^T C = [f]x^T [f]x =
    |f|^2 I - f f^T``, so ``f f^T = (tr(C^T C) / 2) I - C^T C``; f is its principal
    eigenvector scaled by sqrt of the eigenvalue (sign lost, which the spread ignores)."""
    C = np.asarray(columns, dtype=float)
    gram = np.einsum("nki,nkj->nij", C, C)
    outer = 0.5 * np.trace(gram, axis1=1, axis2=2)[:, None, None] * np.eye(3) - gram
    values, vectors = np.linalg.eigh(outer)
    return np.asarray(vectors[:, :, -1] * np.sqrt(np.maximum(values[:, -1], 0.0))[:, None])


def mean_direction(vectors: ArrayLike) -> tuple[Array, float]:
    """Principal direction (unit, (3,)) of sign-free vectors (n, 3), the top eigenvector of
    ``sum v v^T``, and the RMS angle (deg) of the vectors from that axis (sign ignored)."""
    v = np.asarray(vectors, dtype=float)
    v = v[np.linalg.norm(v, axis=1) > 0]
    if len(v) == 0:
        return np.full(3, np.nan), float("nan")
    _, axes = np.linalg.eigh(v.T @ v)
    direction = axes[:, -1]
    cosine = np.abs(v @ direction) / np.linalg.norm(v, axis=1)
    return direction, float(np.degrees(np.sqrt(np.mean(np.arccos(np.clip(cosine, 0, 1))**2))))


@dataclass(frozen=True)
class JointMount:
    """Result of :func:`joint_mount`.

    Attributes:
        imu_to_body: (4,) [w, x, y, z], the joint estimate.
        information: (3, 3) rad^-2 on theta at it (rates + specific force).
        std_deg: (3,) 1-sigma about the body x, y, z axes, degrees (inflated by the Birge ratio
            ``sqrt(chi2 / dof)`` when the two sources disagree beyond their noise, and with the
            systematic term of :func:`joint_mount` added in quadrature).
        weakest_axis: (3,) body-frame axis of the largest uncertainty, and ``weakest_std_deg``.
        rate_only_deg, force_only_deg: (3,) the rates' and the specific force's own 1-sigma
            about the joint estimate's principal axes (weakest first; conditional, the other
            two axes held), deg, ``1 / sqrt(a^T I a)``.
        chi2, dof: the sources' disagreement (:func:`fuse_mount`); ``birge``: sqrt(chi2 / dof)
            when above 1, else 1.
        force: the specific force's information at the joint estimate.
        iterations: relinearisations.
        systematic_deg: the triad misalignment added in quadrature (:func:`joint_mount`).
    """

    imu_to_body: Array
    information: Array
    std_deg: Array
    weakest_axis: Array
    weakest_std_deg: float
    rate_only_deg: Array
    force_only_deg: Array
    chi2: float
    dof: int
    birge: float
    force: ForceMountInformation
    iterations: int
    systematic_deg: float = 0.0


def joint_mount(recording: Recording, offset: float, drift_ppm: float,
                rate_mount: ArrayLike, rate_information: ArrayLike, *,
                start: ArrayLike | None = None, systematic_deg: float = 0.0,
                cutoff_hz: float = CUTOFF_HZ) -> JointMount:
    """The mount from rates and specific force together, starting at the rates' mount
    ``rate_mount`` ([w, x, y, z]) whose information is ``rate_information`` (3, 3, rad^-2):
    at the current mount R, the specific force's information (:func:`force_mount_information`)
    and the rates' (centred on ``theta_r = log(R_rate R^-1)``) give a step
    (:func:`fuse_mount`), ``R <- exp([theta]x) R``, repeated until below
    :data:`MOUNT_TOLERANCE_RAD`. The covariance is ``(I_r + I_f)^-1``, scaled by chi2 / dof
    when that exceeds 1, and ``systematic_deg`` (the triad's own axis misalignment, which no
    fit separates from the mount) is added in quadrature about each body axis. ``start``: the
    first linearisation point (default: the rates' mount). ValueError as
    :func:`specific_force_system`."""
    R_rate = rotation_from_wxyz(rate_mount)
    I_r = np.asarray(rate_information, dtype=float)
    R = R_rate if start is None else rotation_from_wxyz(start)
    iterations = 0
    while True:
        force = force_mount_information(recording, offset, drift_ppm, wxyz_from_rotation(R),
                                        cutoff_hz=cutoff_hz)
        theta_r = (R_rate * R.inv()).as_rotvec()
        theta, total, chi2, dof = fuse_mount(I_r, theta_r, force.information, force.vector)
        iterations += 1
        if np.linalg.norm(theta) < MOUNT_TOLERANCE_RAD or iterations >= MAX_MOUNT_ITERATIONS:
            break
        R = Rotation.from_rotvec(theta) * R
    birge = float(np.sqrt(chi2 / dof)) if dof and chi2 > dof else 1.0
    covariance = np.linalg.pinv(total) * birge**2
    std, axes = information_axes(total)
    std = std * birge
    project = axes.T
    rate_std = np.sqrt(1.0 / np.maximum(np.einsum("ij,jk,ik->i", project, I_r, project),
                                        np.finfo(float).tiny))
    force_std = np.sqrt(1.0 / np.maximum(np.einsum("ij,jk,ik->i", project, force.information,
                                                   project), np.finfo(float).tiny))
    body_std = np.where(np.isfinite(std).all(), np.sqrt(np.maximum(np.diag(covariance), 0.0)),
                        np.inf)
    return JointMount(imu_to_body=wxyz_from_rotation(Rotation.from_rotvec(theta) * R),
                      information=total,
                      std_deg=np.hypot(np.degrees(body_std), systematic_deg),
                      weakest_axis=axes[:, 0],
                      weakest_std_deg=float(np.hypot(np.degrees(std[0]), systematic_deg)),
                      rate_only_deg=np.degrees(rate_std), force_only_deg=np.degrees(force_std),
                      chi2=chi2, dof=dof, birge=birge, force=force, iterations=iterations,
                      systematic_deg=systematic_deg)
