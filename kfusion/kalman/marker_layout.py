"""The marker layout checked against the data: each marker's mean miss from the cluster's pose.

``recording.yaml``'s ``markers`` (the layout ``m_i``, body frame) is an assumption: a marker
knocked or re-taped after the rigid body was defined sits ``delta_i`` away from it. Marker-level
fusion places the body from whichever markers are visible, so a layout error moves the fix:

- with every marker seen, the Kabsch fit spreads the error over the cluster: the origin moves
  by about the mean of the ``delta_i`` (a rigid part the data cannot see: any rigid motion of
  the whole layout is only another choice of body frame);
- with a subset seen, the fix moves by that subset's own errors, up to a whole ``delta_i`` for
  a lone marker.

Measured (a 4-marker cluster, one marker 1 mm off its layout, 0.5 mm noise): 12 % of the
filter's rows with every marker seen and 17 % with three lay beyond their 99 % bound, and half
of the smoother's, which averages the noise down to 0.25 mm but not the common error.

What the data show is the non-rigid part: at a frame where every marker is fused, marker i's
residual from the Kabsch pose of all of them, in the body frame::

    r_i = R^T (z_i - p) - m_i        (the noise averages out; a layout error does not)

Its mean ``rbar_i`` estimates the layout error less the rigid part the fit absorbed. Two means
are kept: a long one (about :data:`LONG_FRAMES` frames, exponential memory) and a recent one
(about :data:`SHORT_FRAMES`); where the recent one leaves the long one (a marker knocked during
the take), the long one restarts from it (:meth:`LayoutResiduals.with_frame`: a mean over every
frame since the start lagged a knock at 10 s, and left 3.8 % of the rows beyond); the marker
then stays unsettled for :data:`UNSETTLED_FRAMES`, covered by its largest recent residual. A
marker whose residuals spread beyond its noise's share (:func:`spread_excess`: a loose base
wobbling faster than the means follow) is covered at the wobble's peak. So, online:

- **correct**: a marker whose long mean is significant (``N |rbar_i|^2 / sigma_m^2`` beyond
  chi-square(3) at 0.999, :data:`SIGNIFICANCE`; N >= :data:`MIN_FRAMES`) is placed at
  ``m_i + rbar_i``, so every subset agrees with the whole cluster's pose;
- **cover** what stays unknown (:func:`origin_variance`), as a common error added to the bound,
  never averaged: the rigid part, from the layout errors' per-axis variance
  ``sigma_delta^2 = sum_i |rbar_i|^2 / (3n - 6)`` (a rigid fit takes 6 of the 3n coordinates:
  ``E sum |r_i|^2 = (3n - 6) sigma^2`` for independent errors of variance sigma^2 per axis),
  carried to the origin as a Kabsch fit carries noise, ``sigma_delta^2 (1/n + |mbar|^2 /
  lambda_min(J))`` (:func:`kfusion.kalman.markers.fit_angle_variance`), and once a residual is
  significant at least one marker's worst case, ``kappa sum_i |rbar_i|^2 / 3``
  (:func:`single_marker_gain`); plus ``|e_i|^2 / 3`` of the largest residual the placement
  leaves (an uncorrected marker's, or a recent one's beyond its correction: a subset's fix
  moves by at most that).

Without a layout error the mean residuals are the noise's, ``E |rbar_i|^2 ~ sigma_m^2 / N``, so
the term is what the frames leave unknown about the layout and fades as they accumulate (to
about 0.01 mm after 5 s at 100 Hz); with one, it stays. A 3-marker cluster leaves a marker moved
out of its plane no residual at all: that error is not seen and not covered.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kfusion.kalman.markers import fit_angle_variance

SIGNIFICANCE = 16.27
"""chi-square(3) at 0.999: ``N |rbar_i|^2 / sigma_m^2`` beyond it makes a mean residual over N
frames significant."""

MIN_FRAMES = 10
"""Frames with every marker fused before any correction."""

LONG_FRAMES = 500
"""Memory (frames) of the mean residual the correction uses: each frame weighs
``1 / min(N, LONG_FRAMES)`` (5 s at 100 Hz), so a layout that changes is followed."""

SHORT_FRAMES = 20
"""Memory (frames) of the recent mean residual that watches for a change (0.2 s at 100 Hz)."""

SPREAD_FRAMES = 100
"""Memory (frames) of each marker's mean squared residual about its long mean (1 s at 100 Hz):
the wobble a mean cannot show (:func:`spread_excess`)."""

UNSETTLED_FRAMES = 200
"""Frames after a change during which a marker is unsettled (2 s at 100 Hz): not corrected,
and covered by the largest recent mean residual it has shown since the change. A marker that
keeps changing (a loose base wobbling 1 mm at 1 Hz) stays unsettled: each restart made its
long mean follow the wobble, and the bound read it near zero at every crossing (2.7-4.4 % of
the rows beyond)."""


@dataclass(frozen=True)
class LayoutResiduals:
    """The layout and its residuals so far (thin state; replaced, never changed in place).

    Attributes:
        body: (n, 3) the declared layout, m, body frame.
        long_mean: (n, 3) each marker's mean residual ``rbar_i`` (m) over its last
            :data:`LONG_FRAMES` frames or so (exponential memory), since its last change.
        long_frames: (n,) frames in ``long_mean`` (capped at :data:`LONG_FRAMES`).
        short_mean: (n, 3) the same over the last :data:`SHORT_FRAMES` or so, m.
        frames: frames with every marker fused.
        gain: :func:`single_marker_gain` of ``body`` (NaN: computed on use).
        since_change: (n,) frames since each marker's last change (None: no change yet).
        peak: (n,) m^2, the largest ``|short_i|^2`` (or long mean left at a change) since the
            change, while the marker is unsettled (:data:`UNSETTLED_FRAMES`); 0 once settled.
        spread: (n,) m^2, each marker's mean ``|r_i - long_i|^2`` over the last
            :data:`SPREAD_FRAMES` or so (None before a frame).
        shares: :func:`residual_shares` of ``body`` (None: computed on use).
    """

    body: NDArray[np.float64]
    long_mean: NDArray[np.float64]
    long_frames: NDArray[np.int_]
    short_mean: NDArray[np.float64]
    frames: int = 0
    gain: float = math.nan
    since_change: NDArray[np.int_] | None = None
    peak: NDArray[np.float64] | None = None
    spread: NDArray[np.float64] | None = None
    shares: NDArray[np.float64] | None = None

    @classmethod
    def start(cls, body_positions: ArrayLike) -> LayoutResiduals:
        body = np.array(body_positions, dtype=float).reshape(-1, 3)
        return cls(body, np.zeros_like(body), np.zeros(len(body), dtype=int),
                   np.zeros_like(body), 0, single_marker_gain(body),
                   shares=residual_shares(body))

    @property
    def unsettled(self) -> NDArray[np.bool_]:
        """(n,) markers changed within the last :data:`UNSETTLED_FRAMES` frames."""
        if self.since_change is None:
            return np.zeros(len(self.body), dtype=bool)
        return np.asarray(self.since_change < UNSETTLED_FRAMES)

    def matches(self, body_positions: NDArray[np.float64]) -> bool:
        """This is the layout ``body_positions`` (n, 3) m."""
        return bool(body_positions.shape == self.body.shape
                    and np.array_equal(body_positions, self.body))

    def with_frame(self, points: ArrayLike, marker_variance: float) -> LayoutResiduals:
        """After one more frame of every marker (n, 3) m, global frame (:func:`residuals`).

        Both means move by ``(r_i - mean) / min(N, memory)``. Where the recent mean leaves the
        long one (:func:`changed`), the marker's layout has changed (knocked, re-taped): its
        long mean restarts from the recent one, counted as one frame, so that the frames after
        the change soon outweigh the recent mean's lag, and the marker stays uncorrected
        (:func:`corrected_markers`, covered whole by :func:`origin_variance`) for
        :data:`MIN_FRAMES` frames."""
        r = residuals(points, self.body)
        frames = self.frames + 1
        about = np.sum((r - self.long_mean) ** 2, axis=1)
        spread = about if self.spread is None else \
            self.spread + (about - self.spread) / min(frames, SPREAD_FRAMES)
        short = self.short_mean + (r - self.short_mean) / min(frames, SHORT_FRAMES)
        long_frames = np.minimum(self.long_frames + 1, LONG_FRAMES)
        long = self.long_mean + (r - self.long_mean) / long_frames[:, None]
        moved = changed(short, long, frames, marker_variance)
        since = None
        peak = None
        if moved.any() or self.since_change is not None:
            previous = (np.full(len(self.body), UNSETTLED_FRAMES) if self.since_change is None
                        else self.since_change)
            since = np.where(moved, 0, np.minimum(previous + 1, UNSETTLED_FRAMES))
            held = np.zeros(len(self.body)) if self.peak is None else self.peak
            left = np.where(moved, np.sum(long * long, axis=1), 0.0)  # the layout it left
            peak = np.where(since < UNSETTLED_FRAMES,
                            np.maximum(np.maximum(held, left), np.sum(short * short, axis=1)),
                            0.0)
        long = np.where(moved[:, None], short, long)
        long_frames = np.where(moved, 1, long_frames)
        return LayoutResiduals(self.body, long, long_frames, short, frames, self.gain, since,
                               peak, spread, self.shares)


def spread_excess(layout: LayoutResiduals, marker_variance: float) -> NDArray[np.float64]:
    """(n,) m^2: each marker's residual spread beyond its noise's, where significant, else 0.

    A rigid fit of n markers of noise sigma_m^2 per axis leaves each residual
    ``E |r_i|^2 = s_i sigma_m^2`` (:func:`residual_shares`, summing to ``3n - 6``).
    A marker whose layout error varies (a loose base wobbling faster than the means follow)
    has more; beyond 1.5 times that (noise alone's reached 1.28 over 4 simulated takes), after
    :data:`SPREAD_FRAMES` / 2 frames, the excess counts (a sine of amplitude A adds ``A^2 / 2``;
    :func:`origin_variance` covers ``2 x excess``, its peak). A marker noisier than
    ``marker_position_noise`` shows the same, and is covered alike."""
    count = len(layout.body)
    if layout.spread is None or layout.frames < SPREAD_FRAMES // 2 or not marker_variance > 0:
        return np.zeros(count)
    shares = residual_shares(layout.body) if layout.shares is None else layout.shares
    expected = shares * marker_variance
    return np.where(layout.spread > 1.5 * expected, layout.spread - expected, 0.0)


def residual_shares(body_positions: ArrayLike) -> NDArray[np.float64]:
    """(n,) ``E |r_i|^2 / sigma_m^2`` of each marker's residual from a rigid fit of all n, for
    independent noise: the trace of marker i's 3x3 block of ``I - M M^+`` (M of
    :func:`single_marker_gain`; they sum to ``3n - 6``). A marker far from the others keeps
    less of its noise in its residual (the fit follows it more)."""
    body = np.asarray(body_positions, dtype=float).reshape(-1, 3)
    _, residual_map = rigid_fit_maps(body)
    return np.array([float(np.trace(residual_map[3 * i:3 * i + 3, 3 * i:3 * i + 3]))
                     for i in range(len(body))])


def changed(short_mean: ArrayLike, long_mean: ArrayLike, frames: int,
            marker_variance: float) -> NDArray[np.bool_]:
    """(n,) markers whose recent mean residual (n, 3) m differs significantly from their long
    one: ``min(N, SHORT_FRAMES) |short_i - long_i|^2 / sigma_m^2 > SIGNIFICANCE`` (the long
    mean's own noise is the smaller), once N >= :data:`SHORT_FRAMES`."""
    difference = np.asarray(short_mean, dtype=float) - np.asarray(long_mean, dtype=float)
    if frames < SHORT_FRAMES or not marker_variance > 0:
        return np.zeros(len(difference), dtype=bool)
    return np.asarray(SHORT_FRAMES * np.sum(difference * difference, axis=1) / marker_variance
                      > SIGNIFICANCE)


def rigid_fit_maps(body_positions: ArrayLike
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(M^+ (6, 3n), I - M M^+ (3n, 3n))`` of the linearised rigid fit of n markers (body
    frame, m): stacked marker displacements d give the fit's translation and small rotation
    ``M^+ d`` and the residuals ``(I - M M^+) d``, with rows ``[I, -[m_i x]]`` of M."""
    from kfusion.kalman.markers import skew

    body = np.asarray(body_positions, dtype=float).reshape(-1, 3)
    M = np.vstack([np.hstack([np.eye(3), -skew(marker)]) for marker in body])  # (3n, 6)
    pseudo_inverse = np.linalg.pinv(M)
    return pseudo_inverse, np.eye(3 * len(body)) - M @ pseudo_inverse


def single_marker_gain(body_positions: ArrayLike) -> float:
    """The largest ``|o|^2 / sum_i |r_i|^2`` a layout error on one marker can give (inf where
    one leaves no residual): o the fitted origin's error, r the residuals it leaves.

    Linearised (body frame), marker j off by delta moves the stacked points by ``d = E_j
    delta``; the fit takes the translation t and small rotation w minimising
    ``sum_i |d_i - t - w x m_i|^2``, i.e. ``x = M^+ d`` with rows ``[I, -[m_i x]]`` of M, so
    ``o = t = [I 0] M^+ E_j delta`` and ``r = (I - M M^+) E_j delta``. The gain is the largest
    generalised eigenvalue of ``(B_j^T B_j, A_j^T A_j)`` over j (``B_j = [I 0] M^+ E_j``,
    ``A_j = (I - M M^+) E_j``). A knocked marker is one structured error, not the independent
    ones :func:`origin_variance`'s ``sigma_delta^2`` assumes: with the origin 5 cm from the
    cluster, one marker 1 mm off moved it 0.78 mm where that term's 99 % radius was 0.55.

    Args:
        body_positions: (n, 3) the layout, m; n >= 3.
    """
    body = np.asarray(body_positions, dtype=float).reshape(-1, 3)
    count = len(body)
    pseudo_inverse, residual_map = rigid_fit_maps(body)
    largest = 0.0
    for marker in range(count):
        columns = slice(3 * marker, 3 * marker + 3)
        A = residual_map[:, columns]  # (3n, 3)
        B = pseudo_inverse[:3, columns]  # (3, 3)
        seen = A.T @ A
        values, vectors = np.linalg.eigh(seen)
        if values[0] <= 1e-12 * max(values[-1], 1e-30):
            return math.inf  # a direction of this marker's error leaves no residual
        whiten = vectors / np.sqrt(values)  # W with W^T (A^T A) W = I
        moved = whiten.T @ (B.T @ B) @ whiten
        largest = max(largest, float(np.linalg.eigvalsh(moved)[-1]))
    return largest


def residuals(points: ArrayLike, body_positions: ArrayLike) -> NDArray[np.float64]:
    """Each marker's miss from the Kabsch pose of all of them, body frame (n, 3) m::

        r_i = R^T (z_i - p) - m_i,   (R, p) = argmin sum_i |z_i - p - R m_i|^2

    Args:
        points: (n, 3) the markers seen, m, global frame.
        body_positions: (n, 3) the layout, m, body frame; n >= 3, not collinear.
    """
    from kfusion.rigid_body import fit_pose  # kfusion.rigid_body imports kfusion.calibration

    body = np.asarray(body_positions, dtype=float)
    rotation, origin = fit_pose(body, points)
    return (np.asarray(points, dtype=float) - origin) @ rotation - body


def corrected_markers(layout: LayoutResiduals, marker_variance: float) -> NDArray[np.bool_]:
    """(n,) the markers placed at ``m_i + rbar_i``: their long mean residual is significant,
    ``N_i |rbar_i|^2 / sigma_m^2 > SIGNIFICANCE`` over ``N_i >= MIN_FRAMES`` frames
    (``marker_variance`` sigma_m^2, m^2 per axis)."""
    mean = layout.long_mean
    if not marker_variance > 0:
        return np.zeros(len(mean), dtype=bool)
    frames = layout.long_frames
    return np.asarray((frames >= MIN_FRAMES) & ~layout.unsettled
                      & (frames * np.sum(mean * mean, axis=1) / marker_variance > SIGNIFICANCE))


def origin_variance(layout: LayoutResiduals, marker_variance: float) -> float:
    """Per-axis variance (m^2) of the body origin's error the layout leaves (module docstring)::

        sigma_delta^2 (1/n + |mbar|^2 / lambda_min(J)) + max_i |e_i|^2 / 3

    with ``sigma_delta^2 = sum_i |d_i|^2 / (3n - 6)``, ``d_i`` each marker's current residual
    (the recent mean where it left what the correction applies, else the long mean) and
    ``e_i`` what the placement leaves of it (``d_i`` less the correction applied). Once a
    marker's residual is significant, the first term is at least ``kappa sum_i |d_i|^2 / 3``
    (``kappa``: :func:`single_marker_gain`; the origin's error of one marker off, as a vector
    of unknown direction), unless one marker's error can hide (kappa infinite: a 3-marker
    cluster does not see a marker moved out of its plane). An unsettled marker's ``|d_i|^2``
    and ``|e_i|^2`` are at least its peak since its change, and any marker's at least twice
    its :func:`spread_excess`."""
    body = layout.body
    count = len(body)
    corrected = corrected_markers(layout, marker_variance)
    applied = np.where(corrected[:, None], layout.long_mean, 0.0)
    recent = layout.short_mean - applied
    moved = changed(layout.short_mean, applied, layout.frames, marker_variance)
    current = np.where(moved[:, None], layout.short_mean, layout.long_mean)
    left = np.where(moved[:, None], recent, np.where(corrected[:, None], 0.0, current))
    current_squared = np.sum(current * current, axis=1)
    left_squared = np.sum(left * left, axis=1)
    if layout.peak is not None:  # unsettled markers: the largest residual since their change
        current_squared = np.maximum(current_squared, layout.peak)
        left_squared = np.maximum(left_squared, layout.peak)
    wobble = 2.0 * spread_excess(layout, marker_variance)  # a varying error's peak
    current_squared = np.maximum(current_squared, wobble)
    left_squared = np.maximum(left_squared, wobble)
    squared = float(np.sum(current_squared))
    layout_variance = squared / (3 * count - 6)
    centroid = body.mean(axis=0)
    rigid = layout_variance / count + float(centroid @ centroid) * fit_angle_variance(
        body, layout_variance)
    gain = single_marker_gain(body) if math.isnan(layout.gain) else layout.gain
    if (corrected.any() or moved.any() or layout.unsettled.any() or wobble.any()) \
            and math.isfinite(gain):
        # a layout error the data show is more likely one marker's than independent ones
        rigid = max(rigid, gain * squared / 3.0)
    return rigid + float(np.max(left_squared)) / 3.0
