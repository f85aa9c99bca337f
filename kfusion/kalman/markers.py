"""Marker-level measurements for the position filter, as small pure functions.

A rigid body carries markers at body-frame positions ``m_i`` (m, ``recording.yaml``'s
``markers``). The filter's state holds the IMU point ``p`` (m, global frame); the rigid-body
origin is ``p - R l`` (``R = R_global_body``, l the lever arm, 0 when ignored), so marker i is
seen at::

    z_i = p + R (m_i - l) + r_i = H x + c + R m_i + r_i

with ``H x + c`` the filter's rigid-body point (:func:`kfusion.kalman.model.output_point`) and
``r_i ~ N(0, sigma_m^2 I)`` the marker's own noise. One visible marker thus constrains the
position in all three axes, given the orientation.

The orientation is not a state of the position filter (:mod:`kfusion.kalman.orientation`): it is
known with an error ``dtheta`` (rad, IMU frame, per-axis variance ``sigma_theta^2``),
``R_true = R_global_imu Exp(dtheta) R_imu_body``. To first order the arm ``a_i = R (m_i - l)``
(m, global frame) then moves by ``-[a_i x] R_global_imu dtheta``, and since the orientation
covariance is isotropic (``sigma_theta^2 I`` in any frame)::

    Cov(e_i, e_j) = sigma_theta^2 [a_i x] [a_j x]^T
                  = sigma_theta^2 ((a_i . a_j) I - a_j a_i^T)

One ``dtheta`` moves every marker, so the term is correlated between markers: the markers of a
frame are fused as one stacked measurement (3k rows) with the full noise matrix
(:func:`marker_noise`), never as k independent ones (which would average the orientation error
away as if it were white). Where the frame's own pose (3 or more markers) is the orientation
fix, ``dtheta`` is those markers' noise, not independent of it: the frame is then fused once as
its fitted origin with :func:`origin_covariance` (the stacked rows left the lever's part of the
bound at 0.5-0.7 of its size with the origin 15 cm from the cluster).

Correlated orientation error. With fewer than 3 markers the orientation is the gyroscope's, and
its error ``dtheta`` barely changes from one frame to the next: it is common to every frame fused
with it since the last orientation fix, while the filter takes each frame's noise as new. N
measurements ``z_k = p + c + w_k`` with a common error c (variance sigma_c^2) and independent
ones w_k (sigma_w^2), fused as if independent with the common part's variance inflated to
``N sigma_c^2``, give ``Var(p) = sigma_c^2 + sigma_w^2 / N``: the true variance of their mean
(:func:`common_error_variance`). So the k-th frame since the orientation fix takes
``sigma_theta^2 k`` in its noise: the bound never averages the orientation error away, at the
price of some information. A smoother combines each frame with the *later* frames of the same
run too, which share the error; offline, every frame of a run of K frames takes
``sigma_theta^2 K``, and any subset S of them fused as independent then has
``(K sigma_c^2 + sigma_w^2) / |S| >= sigma_c^2 + sigma_w^2 / |S|``: covered.

Gate: each marker is tested alone against its own 3x3 innovation covariance
(:func:`marker_nis`), so a swapped marker is rejected while the others are fused; two or more
must also agree among themselves (:func:`consistent_markers`), and a lone marker, which nothing
else checks, and a pair, only count when the prediction tells their labels from any other
labelling by the cluster's markers (:func:`labels_ambiguous`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from itertools import combinations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def skew(vector: ArrayLike) -> NDArray[np.float64]:
    """``[v x]`` (3, 3): the matrix with ``[v x] w = v x w`` for v (3,)."""
    x, y, z = (float(value) for value in np.asarray(vector, dtype=float))
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def marker_arms(R_global_body: ArrayLike, body_positions: ArrayLike,
                lever_arm: ArrayLike) -> NDArray[np.float64]:
    """Arms ``a_i = R_global_body (m_i - l)`` (k, 3), m, global frame: from the IMU point (the
    filter's position state) to each marker.

    Args:
        R_global_body: (3, 3) body -> global.
        body_positions: (k, 3) markers in the body frame, m.
        lever_arm: (3,) IMU position in the body frame, m (zeros when ignored).
    """
    body = np.asarray(body_positions, dtype=float) - np.asarray(lever_arm, dtype=float)
    return body @ np.asarray(R_global_body, dtype=float).T


def marker_noise(arms: ArrayLike, marker_variance: float, angle_variance: float
                 ) -> NDArray[np.float64]:
    """Noise matrix (3k, 3k) m^2 of k markers fused together (module docstring)::

        R_ij = delta_ij sigma_m^2 I + sigma_theta^2 [a_i x] [a_j x]^T

    Args:
        arms: (k, 3) arms ``a_i`` (:func:`marker_arms`), m.
        marker_variance: ``sigma_m^2``, m^2, per axis.
        angle_variance: ``sigma_theta^2``, rad^2, per axis of the orientation error.
    """
    arms = np.asarray(arms, dtype=float).reshape(-1, 3)
    blocks = np.stack([skew(arm) for arm in arms]) if len(arms) else np.zeros((0, 3, 3))
    stacked = blocks.reshape(-1, 3)  # (3k, 3): the [a_i x] stacked
    R = angle_variance * (stacked @ stacked.T)
    R[np.diag_indices_from(R)] += marker_variance
    return R


def stacked_measurement(H: ArrayLike, offset: ArrayLike, R_global_body: ArrayLike,
                        body_positions: ArrayLike
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(H_k, c_k) of k markers, ``z = H_k x + c_k``: (3k, n) and (3k,).

    ``H`` (3, n) and ``offset`` c (3,) map the state to the rigid-body origin (``H x + c``,
    the filter's output map); marker i lies ``R_global_body m_i`` from it, so its rows are H
    and its offset ``c + R m_i``."""
    H = np.asarray(H, dtype=float)
    body = np.asarray(body_positions, dtype=float).reshape(-1, 3)
    offsets = np.asarray(offset, dtype=float)[None, :] + body @ np.asarray(
        R_global_body, dtype=float).T
    return np.tile(H, (len(body), 1)), offsets.ravel()


def fit_angle_variance(body_positions: ArrayLike, marker_variance: float) -> float:
    """Per-axis variance (rad^2) of the orientation a Kabsch fit of these markers gives,
    taken at its worst axis.

    The fit's rotation error dtheta moves centred marker i by ``-[c_i x] dtheta``
    (``c_i = m_i - mean m``, body frame); least squares over markers of noise sigma_m^2 gives
    ``Cov(dtheta) = sigma_m^2 J^-1`` with ``J = sum_i [c_i x]^T [c_i x]
    = sum_i (|c_i|^2 I - c_i c_i^T)``. The orientation filter keeps one variance for all axes,
    so the largest, ``sigma_m^2 / lambda_min(J)``, is returned. (inf for collinear markers.)

    Args:
        body_positions: (k, 3) the fitted markers in the body frame, m; k >= 3.
        marker_variance: sigma_m^2, m^2 per axis.
    """
    body = np.asarray(body_positions, dtype=float).reshape(-1, 3)
    centred = body - body.mean(axis=0)
    J = np.sum(centred * centred) * np.eye(3) - centred.T @ centred
    smallest = float(np.linalg.eigvalsh(J)[0])
    return marker_variance / smallest if smallest > 0 else float("inf")


def shared_run_lengths(counts: ArrayLike, enough: int = 3) -> NDArray[np.int_]:
    """Per frame (m,), the length of the run of consecutive frames with fewer than ``enough``
    visible markers it belongs to (0 for frames with enough): the frames that share one
    gyroscope orientation error (offline ``shared_frames`` of the filter)."""
    few = np.asarray(counts) < enough
    lengths = np.zeros(len(few), dtype=int)
    padded = np.concatenate([[False], few, [False]])
    edges = np.flatnonzero(np.diff(padded.astype(np.int8)))
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        lengths[start:stop] = stop - start
    return lengths


def common_error_variance(variance: float, frames: int) -> float:
    """Variance (same unit) to give a common error in the ``frames``-th (>= 1) measurement that
    shares it: ``frames variance`` (module docstring, "Correlated orientation error")."""
    return variance * max(int(frames), 1)


def marker_gate(nis: Sequence[float], innovations: ArrayLike, threshold: float,
                min_innovation: float, prediction_valid: bool) -> NDArray[np.bool_]:
    """Which of k markers pass their own gate (k,): a marker fails when its NIS
    (:func:`marker_nis`, 3 dof) exceeds ``threshold`` *and* its innovation (3,) m is longer
    than ``min_innovation`` (m), as a rigid-body fix does
    (:class:`kfusion.kalman.KalmanFusion`); failing markers are rejected only while the
    prediction is valid (``prediction_valid``: at most ``max_bridge_s`` after the last fix;
    later every marker re-acquires). A marker whose innovation overflowed never passes."""
    values = np.asarray(nis, dtype=float)
    y = np.asarray(innovations, dtype=float).reshape(-1, 3)
    with np.errstate(over="ignore", invalid="ignore"):
        length_squared = np.sum(y * y, axis=1)
    failed = (values > threshold) & (length_squared > min_innovation ** 2)
    absurd = ~np.isfinite(values) | ~np.isfinite(y).all(axis=1)
    return ~absurd & ~(failed & prediction_valid)


def consistent_markers(innovations: ArrayLike, R: ArrayLike, threshold: float,
                       min_innovation: float, max_markers: int = 12) -> NDArray[np.bool_]:
    """The markers of one frame that agree with each other about where the body is (k,): the
    unique largest set of at least 2 markers that are pairwise consistent, else none. Used
    with :func:`marker_gate`, which tests each marker against the prediction alone (and lets
    every marker through when there is none).

    Marker i's innovation is ``y_i = z_i - c_i - H x`` (every marker has the same H,
    :func:`stacked_measurement`), so ``y_i - y_j = z_i - z_j - R (m_i - m_j)`` does not
    depend on the state: it is how far the two markers disagree about the body's position.
    Its covariance is ``C_ij = R_ii + R_jj - R_ij - R_ji`` (blocks of the stacked noise R,
    :func:`marker_noise`, orientation error included), and the pair is consistent when
    ``d^T C_ij^-1 d <= threshold`` or ``|d| <= min_innovation``. A marker swapped with
    another, or labels cycled among three, disagree with the rest by centimetres; two
    groups of equal size, one marker alone, or more than ``max_markers`` markers (the search
    is over subsets) give none: the frame cannot tell which markers to trust.

    Shapes: innovations (k, 3) m, R (3k, 3k) m^2."""
    y = np.asarray(innovations, dtype=float).reshape(-1, 3)
    noise = np.asarray(R, dtype=float)
    count = len(y)
    none = np.zeros(count, dtype=bool)
    if count < 2 or count > max_markers:
        return none
    blocks = noise.reshape(count, 3, count, 3).transpose(0, 2, 1, 3)  # blocks[i, j] = R_ij
    agree = np.eye(count, dtype=bool)
    for i in range(count):
        for j in range(i + 1, count):
            d = y[i] - y[j]
            C = blocks[i, i] + blocks[j, j] - blocks[i, j] - blocks[j, i]
            agree[i, j] = agree[j, i] = bool(
                np.all(np.isfinite(d)) and (float(d @ d) <= min_innovation ** 2
                                            or marker_nis(d, C) <= threshold))
    for size in range(count, 1, -1):
        found = [members for members in combinations(range(count), size)
                 if agree[np.ix_(members, members)].all()]
        if len(found) > 1:
            return none
        if found:
            keep = none.copy()
            keep[list(found[0])] = True
            return keep
    return none


MAX_LABELLINGS = 200
"""Relabellings of a pair :func:`labels_ambiguous` tries one by one; beyond, the labels count as
ambiguous (each passes its gate under that many label pairs: a prediction looser than the
cluster). 132 for a 12-marker cluster, a few ms."""


def labels_ambiguous(innovations: ArrayLike, point_covariance: ArrayLike, arms: ArrayLike,
                     other_arms: ArrayLike, marker_variance: float, angle_variance: float,
                     threshold: float) -> bool:
    """True when the prediction cannot tell the labels of one or two visible markers from
    another labelling by the cluster's markers: each marker, read under the other label, would
    pass its gate too, and two would still agree with each other.

    One or two markers carry too little geometry to check their own labels (a pose needs
    three), and a labeller guesses the labels of markers that reappear alone or in a pair. Marker
    i's innovation under its label is ``y_i = z_i - H x - c - a_i`` (``a_i`` its arm,
    :func:`marker_arms`); labelled as marker j (arm ``a_j``)::

        y_i' = y_i + a_i - a_j,   S_j = H P H^T + sigma_m^2 I + sigma_theta^2 [a_j x] [a_j x]^T

    and a labelling is possible when every ``y_i'^T S_j^-1 y_i' <= threshold`` and, for two
    markers relabelled as j and l, their disagreement ``y_1' - y_2'`` passes
    :func:`consistent_markers`' test with ``C_jl``. A tight prediction (a few mm, against
    markers 3-7 cm apart) rules every other labelling out; one grown looser than the cluster
    does not. Two markers on a cluster whose pairs are translations of each other (a
    rectangle) agree under the other pair's labels, 4 cm off: 6.1-6.5 % of the rows beyond the
    bound, up to 34.5x, before this test.

    Shapes: innovations (k, 3) m and arms (k, 3) m of the k visible markers (k = 1 or 2; more
    give False: three or more are checked by their pose), point_covariance ``H P H^T`` (3, 3)
    m^2, other_arms (h, 3) m (the cluster's markers not seen); marker_variance m^2,
    angle_variance rad^2 (:func:`marker_noise`)."""
    y = np.asarray(innovations, dtype=float).reshape(-1, 3)
    own = np.asarray(arms, dtype=float).reshape(-1, 3)
    if len(y) not in (1, 2):
        return False
    labels = np.vstack([own, np.asarray(other_arms, dtype=float).reshape(-1, 3)])
    covariance = np.asarray(point_covariance, dtype=float)
    # which label each marker could carry: its own gate under that label
    possible = [[label for label in range(len(labels))
                 if marker_nis(y[i] + own[i] - labels[label], covariance + marker_noise(
                     labels[label][None], marker_variance, angle_variance)) <= threshold]
                for i in range(len(y))]
    if len(y) == 1:
        return any(label != 0 for label in possible[0])
    pairs = [(first, second) for first in possible[0] for second in possible[1]
             if first != second and (first, second) != (0, 1)]
    if len(pairs) > MAX_LABELLINGS:
        return True  # too many to tell apart (a prediction far looser than a large cluster)
    for first, second in pairs:
        chosen = [first, second]
        relabelled = y + own - labels[chosen]
        noise = marker_noise(labels[chosen], marker_variance, angle_variance)
        C = noise[:3, :3] + noise[3:, 3:] - noise[:3, 3:] - noise[3:, :3]
        if marker_nis(relabelled[0] - relabelled[1], C) <= threshold:
            return True
    return False


def marker_nis(y: ArrayLike, S: ArrayLike) -> float:
    """``y^T S^-1 y`` for one marker's innovation y (3,) m and covariance S (3, 3) m^2; inf when
    it overflows or S is singular."""
    y = np.asarray(y, dtype=float)
    with np.errstate(over="ignore", invalid="ignore"):
        try:
            nis = float(y @ np.linalg.solve(np.asarray(S, dtype=float), y))
        except np.linalg.LinAlgError:
            return float("inf")
    return nis if np.isfinite(nis) else float("inf")


def pooled_innovation(y: ArrayLike, S: ArrayLike) -> tuple[NDArray[np.float64],
                                                            NDArray[np.float64]]:
    """The position part of k markers' stacked innovation: (y_o (3,) m, S_o (3, 3) m^2), for
    the stacked innovation y (3k,) m and its covariance S (3k, 3k) m^2.

    Each marker's predicted point moves one for one with the body's position (``G`` = k
    stacked 3x3 identities), so the generalised least-squares position offset that explains
    the innovations, and its covariance, are::

        S_o = (G^T S^-1 G)^-1,   y_o = S_o G^T S^-1 y

    and ``y_o ~ N(0, S_o)`` exactly when ``y ~ N(0, S)``: a 3-vector that the consistency
    monitor's block test (:func:`kfusion.monitor.block_nis`) can sum across frames whose
    marker sets differ. One marker: y and S themselves; k markers with S = diag(R, ..., R):
    their mean and R / k."""
    innovation = np.asarray(y, dtype=float)
    covariance = np.asarray(S, dtype=float)
    k = len(innovation) // 3
    G = np.tile(np.eye(3), (k, 1))
    weighted = np.linalg.solve(covariance, np.column_stack([G, innovation]))  # S^-1 [G y]
    information = G.T @ weighted[:, :3]
    S_o = np.linalg.inv(information)
    y_o = S_o @ (G.T @ weighted[:, 3])
    return y_o, 0.5 * (S_o + S_o.T)


def marker_pose(points: ArrayLike, body_positions: ArrayLike, max_residual: float | None = None
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """The rigid-body pose ``(p (3,) m, q_global_body (4,) [w, x, y, z], w >= 0)`` from visible
    markers (k, 3) and their body positions (k, 3): the Kabsch fit of
    :func:`kfusion.rigid_body.fit_pose`, with the checks of
    :func:`kfusion.rigid_body.solve_poses` for one frame. None with fewer than
    :data:`~kfusion.rigid_body.MIN_MARKERS` markers, nearly collinear ones (the rotation about
    their line is undetermined), or a marker missing the fitted cluster by more than
    ``max_residual`` (m; default :data:`~kfusion.rigid_body.DEFAULT_MAX_RESIDUAL`, the
    converter's) (a swapped marker)."""
    from scipy.spatial.transform import Rotation

    from kfusion.conventions import wxyz_from_rotation
    from kfusion.rigid_body import (  # kfusion.rigid_body imports kfusion.calibration
        DEFAULT_MAX_RESIDUAL,
        MIN_CLUSTER_SPREAD,
        MIN_MARKERS,
        fit_pose,
        line_spread,
    )

    seen = np.asarray(points, dtype=float)
    body = np.asarray(body_positions, dtype=float)
    if len(seen) < MIN_MARKERS or line_spread(body) < MIN_CLUSTER_SPREAD:
        return None
    rotation, origin = fit_pose(body, seen)
    misses = seen - origin - body @ rotation.T
    limit = DEFAULT_MAX_RESIDUAL if max_residual is None else max_residual
    if float(np.max(np.sum(misses * misses, axis=1))) > limit ** 2:
        return None
    return origin, wxyz_from_rotation(Rotation.from_matrix(rotation))


def origin_covariance(body_positions: ArrayLike, marker_variance: float) -> NDArray[np.float64]:
    """Covariance (3, 3) m^2, body frame, of the rigid-body origin a Kabsch fit of these markers
    (k >= 3, body frame, m) gives, each marker of noise sigma_m^2 per axis.

    The fit's origin is ``o = mean z - R mean m``; its error is ``mean r + [R mbar x] dtheta``
    (mbar the markers' mean, dtheta the fit's rotation error, uncorrelated with mean r), so::

        Cov(o) = sigma_m^2 / k I + sigma_m^2 [mbar x] J^-1 [mbar x]^T

    (J of :func:`fit_angle_variance`, in the body frame; rotate by R for the global frame).
    The second term grows with the distance from the markers to the origin: 1.2 mm per axis
    for a 4-5 cm cluster 15 cm away at 0.5 mm marker noise, against 0.25 mm at the origin.
    LinAlgError for collinear markers (no pose)."""
    body = np.asarray(body_positions, dtype=float).reshape(-1, 3)
    mean = body.mean(axis=0)
    centred = body - mean
    J = np.sum(centred * centred) * np.eye(3) - centred.T @ centred
    arm = skew(mean)
    return marker_variance * (np.eye(3) / len(body) + arm @ np.linalg.solve(J, arm.T))


def marker_fix_noise(body_positions: ArrayLike, marker_variance: float,
                     mocap_position_noise: float) -> float:
    """The noise (m, per axis) of a marker-level fix, the cluster's fitted origin, as the
    consistency monitor and a fix shown alone take it: the larger of ``mocap_position_noise``
    and the square root of the largest eigenvalue of :func:`origin_covariance` of all the
    markers. With the origin 15 cm from a 4-5 cm cluster the fitted origin is 1.2 mm noisy per
    axis; taken at the rigid body's 0.3 mm, the monitor read its own fixes as the IMU model
    failing, refused it from the first row, and showed fixes alone with a 2 mm bound: 24 % of
    the rows beyond it, up to 5.2x."""
    try:
        covariance = origin_covariance(body_positions, marker_variance)
    except np.linalg.LinAlgError:  # collinear: never a pose, never a fitted origin
        return float(mocap_position_noise)
    largest = float(np.linalg.eigvalsh(covariance)[-1])
    return max(float(mocap_position_noise), math.sqrt(max(largest, 0.0)))
