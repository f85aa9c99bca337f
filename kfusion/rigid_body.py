"""Rigid-body pose from individual markers: the body-frame cluster and a Kabsch fit per frame.

A rigid body carries n markers at fixed body-frame positions ``b_i`` (m). In a frame where the
markers are seen at ``g_i`` (m, global frame), the pose ``(p, R_global_body)`` satisfies
``g_i = p + R_global_body b_i`` up to noise; :func:`fit_pose` solves it in the least-squares sense
from any 3 or more non-collinear markers (Kabsch, via :func:`kfusion.calibration.paper.kabsch`).

The body frame (:func:`estimate_cluster`): its origin is the centroid of all n markers and its
axes are the global axes at the first frame where all n markers are seen. That is the convention
of OptiTrack Motive, which aligns a new rigid body with the world axes and puts its pivot at the
markers' centroid; any fixed body frame serves kfusion, because ``kfusion calibrate`` estimates
the IMU mount (``imu_to_body``) against whichever frame the recording uses. The marker positions
are the mean shape over the frames where all markers are seen (a Procrustes average), not one
frame's noisy shape.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations
from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from kfusion.calibration.paper import kabsch
from kfusion.conventions import matrix_from_wxyz, wxyz_from_rotation
from kfusion.recording import MarkerFrames, MocapFrames

MIN_MARKERS: Final = 3
"""Fewest visible markers that fix a rigid body's orientation."""
MIN_CLUSTER_SPREAD: Final = 0.005
"""m: visible markers whose RMS distance from their best-fit line is below this are (nearly)
collinear; the rotation about that line is then undetermined and the frame is not solved."""
DEFAULT_MAX_RESIDUAL: Final = 0.010
"""m: a frame whose worst marker lies farther than this from the fitted cluster is not solved
(a swapped or mislabelled marker), rather than written as a wrong pose."""
MAX_SHAPE_FRAMES: Final = 1000
"""The mean cluster shape is averaged over at most this many evenly spaced full frames."""
SHAPE_ITERATIONS: Final = 3


def fit_pose(body_points: ArrayLike, global_points: ArrayLike
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rigid transform ``(R_global_body, p)`` minimising ``sum_i |g_i - p - R b_i|^2``.

    With centroids ``b_c = mean b_i`` and ``g_c = mean g_i``, the rotation is the Kabsch fit of
    the centred points, ``R = argmin sum_i |(g_i - g_c) - R (b_i - b_c)|^2``, and
    ``p = g_c - R b_c``.

    Args:
        body_points: (n, 3) marker positions in the body frame, m; n >= 2 (3 for a unique R).
        global_points: (n, 3) the same markers seen in the global frame, m; or (k, n, 3) for k
            frames fitted at once.

    Returns:
        R_global_body (3, 3) and p (3,), m; or (k, 3, 3) and (k, 3).
    """
    body = np.asarray(body_points, dtype=float)
    seen = np.asarray(global_points, dtype=float)
    body_centroid = body.mean(axis=0)
    seen_centroid = seen.mean(axis=-2)
    centred_body = np.broadcast_to(body - body_centroid, seen.shape)
    rotation = kabsch(seen - seen_centroid[..., None, :], centred_body)
    return rotation, seen_centroid - rotation @ body_centroid


def line_spread(points: ArrayLike) -> float:
    """RMS distance of points (n, 3) from their best-fit line, m: the second singular value of
    the centred points over sqrt(n) (0 for collinear points)."""
    array = np.asarray(points, dtype=float)
    singular = np.linalg.svd(array - array.mean(axis=0), compute_uv=False)
    return float(np.hypot(*singular[1:3]) / np.sqrt(len(array))) if len(singular) > 1 else 0.0


def refuse_collinear(what: str, positions: ArrayLike) -> None:
    """ValueError naming ``what`` when the markers (n, 3), m, lie within MIN_CLUSTER_SPREAD
    (RMS, :func:`line_spread`) of a line: the rotation about it is undetermined, so the Kabsch
    solver cannot fix the body's orientation (a nearly collinear or a too small cluster)."""
    spread = line_spread(positions)
    if spread < MIN_CLUSTER_SPREAD:
        raise ValueError(f"{what} are nearly collinear (RMS {spread * 1e3:.2f} mm off a line, "
                         f"expected at least {MIN_CLUSTER_SPREAD * 1e3:g} mm): the orientation "
                         "is undetermined")


def mean_shape(full_frames: ArrayLike, iterations: int = SHAPE_ITERATIONS
               ) -> NDArray[np.float64]:
    """Mean cluster shape (n, 3), m, in the body frame defined in the module docstring.

    Generalised Procrustes: centre each frame ``c_k = g_k - mean g_k``; starting from
    ``S = c_1``, rotate every frame onto S (``R_k = kabsch(S, c_k)``) and average,
    ``S = mean_k c_k R_k^T``, ``iterations`` times. Finally turn S onto the first frame,
    ``S <- S R_1^T`` with ``R_1 = kabsch(c_1, S)``, so the pose fitted to that frame has
    ``R = I`` and ``p`` = its centroid.

    Args:
        full_frames: (k, n, 3) positions of all n markers in k >= 1 frames, m.
    """
    frames = np.asarray(full_frames, dtype=float)
    centred = frames - frames.mean(axis=1, keepdims=True)
    shape = centred[0]
    for _ in range(iterations if len(centred) > 1 else 0):
        rotations = kabsch(np.broadcast_to(shape, centred.shape), centred)  # (k, 3, 3)
        shape = np.einsum("kij,knj->ni", rotations, centred) / len(centred)  # mean_k R_k c_k
    shape = shape - shape.mean(axis=0)
    result: NDArray[np.float64] = shape @ kabsch(centred[0], shape).T
    return result


@dataclass(frozen=True)
class PoseSolution:
    """Rigid-body poses solved per frame (NaN rows where not solved).

    Attributes:
        position: (k, 3) rigid-body origin, m, global frame.
        quaternion: (k, 4) body -> global, [w, x, y, z] with w >= 0.
        residual: (k,) largest distance of a visible marker from the fitted cluster, m.
        visible: (k,) number of visible markers.
        solved: (k,) True where a pose was solved.
        rejected: (k,) True where >= 3 markers were seen but the fit was refused: residual above
            the limit (a swapped marker) or the visible markers nearly collinear.
    """

    position: NDArray[np.float64]
    quaternion: NDArray[np.float64]
    residual: NDArray[np.float64]
    visible: NDArray[np.int_]
    solved: NDArray[np.bool_]
    rejected: NDArray[np.bool_]


def solve_poses(marker_positions: ArrayLike, body_positions: ArrayLike, *,
                max_residual: float = DEFAULT_MAX_RESIDUAL) -> PoseSolution:
    """Solve the pose in every frame with :data:`MIN_MARKERS` or more visible markers.

    Args:
        marker_positions: (k, n, 3) global positions, m, NaN where a marker is occluded.
        body_positions: (n, 3) body-frame positions of the same markers, m.
        max_residual: m; a fit whose worst marker misses by more is refused.
    """
    seen = np.asarray(marker_positions, dtype=float)
    body = np.asarray(body_positions, dtype=float)
    if seen.ndim != 3 or seen.shape[2] != 3 or body.shape != (seen.shape[1], 3):
        raise ValueError(f"solve_poses: expected marker_positions (k, n, 3) and body_positions "
                         f"(n, 3), got {seen.shape} and {body.shape}")
    if not max_residual > 0:
        raise ValueError(f"solve_poses: expected max_residual > 0 m, got {max_residual!r}")
    count = len(seen)
    visible = ~np.isnan(seen).any(axis=2)
    position = np.full((count, 3), np.nan)
    matrices = np.tile(np.eye(3), (count, 1, 1))
    residual = np.full(count, np.nan)
    rejected = np.zeros(count, dtype=bool)
    enough = visible.sum(axis=1) >= MIN_MARKERS
    # Frames with the same visible markers are fitted together (one batched Kabsch each).
    patterns, group = np.unique(visible[enough], axis=0, return_inverse=True)
    frames_with_enough = np.flatnonzero(enough)
    for index, mask in enumerate(patterns):
        frames = frames_with_enough[group.ravel() == index]
        if line_spread(body[mask]) < MIN_CLUSTER_SPREAD:
            rejected[frames] = True
            continue
        points = seen[frames][:, mask]  # (g, m, 3)
        rotation, origin = fit_pose(body[mask], points)
        misses = points - origin[:, None, :] - np.einsum("gij,mj->gmi", rotation, body[mask])
        residual[frames] = np.sqrt((misses**2).sum(axis=2).max(axis=1))
        good = residual[frames] <= max_residual
        rejected[frames[~good]] = True
        position[frames[good]], matrices[frames[good]] = origin[good], rotation[good]
    solved = ~np.isnan(position).any(axis=1)
    quaternion = np.full((count, 4), np.nan)
    if solved.any():
        quaternion[solved] = wxyz_from_rotation(Rotation.from_matrix(matrices[solved]))
    return PoseSolution(position=position, quaternion=quaternion, residual=residual,
                        visible=visible.sum(axis=1), solved=solved, rejected=rejected)


@dataclass(frozen=True)
class ClusterEstimate:
    """Body-frame marker positions estimated from the frames where all markers are seen.

    Attributes:
        names: (n,) marker names.
        body_positions: (n, 3) positions in the body frame, m.
        full_frames: number of frames where all n markers were seen and fit the cluster.
        outlier_frames: frames where all n markers were seen but one missed the first-pass
            cluster by more than the residual limit (a swapped marker); left out of the shape
            and of the spread.
        distance_spread: (n(n-1)/2,) standard deviation of each inter-marker distance over the
            full frames, m (a rigid cluster: well under a millimetre).
        distance_range: (n(n-1)/2,) max - min of each inter-marker distance, m.
        pairs: (n(n-1)/2,) the marker pairs, in :func:`itertools.combinations` order.
    """

    names: tuple[str, ...]
    body_positions: NDArray[np.float64]
    full_frames: int
    outlier_frames: int
    distance_spread: NDArray[np.float64]
    distance_range: NDArray[np.float64]
    pairs: tuple[tuple[str, str], ...]

    def rigidity_line(self) -> str:
        """One line for the user: the worst pair's distance spread, mm."""
        worst = int(np.argmax(self.distance_spread))
        return (f"cluster rigidity: inter-marker distance std at most "
                f"{self.distance_spread[worst] * 1e3:.2f} mm ({'-'.join(self.pairs[worst])}), "
                f"range at most {self.distance_range.max() * 1e3:.2f} mm over "
                f"{self.full_frames} frames with all {len(self.names)} markers seen"
                + (f" ({self.outlier_frames} more left out: a marker off by more than the "
                   "residual limit)" if self.outlier_frames else ""))


def estimate_cluster(names: tuple[str, ...], marker_positions: ArrayLike, *,
                     max_residual: float = DEFAULT_MAX_RESIDUAL) -> ClusterEstimate:
    """Estimate the body-frame marker positions (see :func:`mean_shape`) and the cluster's
    rigidity from the frames where all markers are seen.

    Two passes: the shape of all full frames, then again without the full frames whose worst
    marker misses that shape by more than ``max_residual`` (a swapped or mislabelled marker).

    Args:
        names: (n,) marker names, n >= 3.
        marker_positions: (k, n, 3) global positions, m, NaN where occluded.
        max_residual: m, see :func:`solve_poses`.

    Raises:
        ValueError: fewer than 3 markers, no frame with all of them seen, or a collinear cluster.
    """
    seen = np.asarray(marker_positions, dtype=float)
    if len(names) < MIN_MARKERS or seen.ndim != 3 or seen.shape[1:] != (len(names), 3):
        raise ValueError(f"estimate_cluster: expected {MIN_MARKERS} or more markers and positions "
                         f"(k, n, 3) for n names; got {len(names)} names and {seen.shape}")
    full = seen[~np.isnan(seen).any(axis=(1, 2))]
    if len(full) == 0:
        raise ValueError(f"no frame where all {len(names)} markers {list(names)} are seen; "
                         "expected at least one to define the rigid body")
    step = max(1, int(np.ceil(len(full) / MAX_SHAPE_FRAMES)))
    body = mean_shape(full[::step])
    refuse_collinear(f"markers {list(names)}", body)
    fits = solve_poses(full, body, max_residual=max_residual)
    outliers = int(fits.rejected.sum())
    if outliers:
        full = full[fits.solved]
        if len(full) == 0:
            raise ValueError(f"no frame where all {len(names)} markers {list(names)} fit one "
                             "rigid cluster; expected at least one")
        step = max(1, int(np.ceil(len(full) / MAX_SHAPE_FRAMES)))
        body = mean_shape(full[::step])
    pairs = tuple(combinations(range(len(names)), 2))
    distances = np.stack([np.linalg.norm(full[:, i] - full[:, j], axis=1) for i, j in pairs],
                         axis=1)
    return ClusterEstimate(names=tuple(names), body_positions=body, full_frames=len(full),
                           outlier_frames=outliers,
                           distance_spread=distances.std(axis=0),
                           distance_range=np.ptp(distances, axis=0),
                           pairs=tuple((names[i], names[j]) for i, j in pairs))


LABEL_JUMP_M = 20e-3
"""m: a marker this far from its place in the body frame has jumped to another label (a swap),
rather than moved: cluster markers sit several cm apart. Twice the filter's
``gate_min_innovation``."""


@dataclass(frozen=True)
class BodyMarkers:
    """Marker positions in a given rigid body's frame (see :func:`markers_in_body_frame`).

    Attributes:
        positions: (n, 3) mean body-frame positions, m.
        spread: (n,) RMS distance of the per-frame positions from the mean, m.
        frames: fewest frames any marker was averaged over.
    """

    positions: NDArray[np.float64]
    spread: NDArray[np.float64]
    frames: int


def points_in_body_frame(position: NDArray[np.float64], quaternion: NDArray[np.float64],
                         points: NDArray[np.float64]) -> NDArray[np.float64]:
    """Global points in the body frame of each pose: ``b = R_global_body^T (g - p)``. Shapes:
    position (k, 3) m, quaternion (k, 4) [w, x, y, z], points (k, n, 3) m; result (k, n, 3)
    (NaN where a point or pose is NaN)."""
    rotations = matrix_from_wxyz(quaternion)  # (k, 3, 3) R_global_body
    with np.errstate(invalid="ignore"):
        return np.einsum("kji,knj->kni", rotations, points - position[:, None, :])


def markers_in_body_frame(mocap: MocapFrames, markers: MarkerFrames) -> BodyMarkers:
    """Body-frame marker positions from rigid-body poses and markers seen in the same frames.

    Each frame where the pose and marker i are seen gives ``b_i = R_global_body^T (g_i - p)``;
    the result is their mean over the frames within :data:`LABEL_JUMP_M` of their per-axis
    median (a label swapped for a while moves a marker by the cluster's size, and a plain mean
    over 10 % swapped frames put two markers 8 mm off), and the spread their RMS distance from
    it. ``kfusion check`` then tests the positions against every frame
    (:mod:`kfusion.calibration.marker_fit`), so a loose marker is reported there.

    Raises:
        ValueError: the two have different times, or a marker is never seen with the pose.
    """
    if len(mocap) != len(markers) or not np.array_equal(mocap.t, markers.t):
        raise ValueError("markers_in_body_frame: expected the mocap and marker frames at the same "
                         f"times, got {len(mocap)} and {len(markers)} frames")
    both = mocap.visible[:, None] & markers.visible
    seen = np.flatnonzero(mocap.visible)
    body = points_in_body_frame(mocap.position[seen], mocap.quaternion[seen],
                                markers.position[seen])
    positions = np.zeros((len(markers.names), 3))
    spread = np.zeros(len(markers.names))
    for index, name in enumerate(markers.names):
        samples = body[both[seen, index], index]
        if len(samples) == 0:
            raise ValueError(f"marker {name!r} is never seen in a frame with the rigid body; "
                             "expected at least one to place it in the body frame")
        median = np.median(samples, axis=0)
        kept = samples[np.linalg.norm(samples - median, axis=1) <= LABEL_JUMP_M]
        positions[index] = kept.mean(axis=0)
        spread[index] = np.sqrt(((kept - positions[index]) ** 2).sum(axis=1).mean())
    return BodyMarkers(positions=positions, spread=spread, frames=int(both.sum(axis=0).min()))
