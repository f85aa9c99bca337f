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

Its mean over N frames, ``rbar_i``, estimates the layout error less the rigid part the fit
absorbed. So, online:

- **correct**: a marker whose mean residual is significant (``N |rbar_i|^2 / sigma_m^2`` beyond
  chi-square(3) at 0.999, :data:`SIGNIFICANCE`; N >= :data:`MIN_FRAMES`) is placed at
  ``m_i + rbar_i``, so every subset agrees with the whole cluster's pose;
- **cover** what stays unknown (:func:`origin_variance`), as a common error added to the bound,
  never averaged: the rigid part, from the layout errors' per-axis variance
  ``sigma_delta^2 = sum_i |rbar_i|^2 / (3n - 6)`` (a rigid fit takes 6 of the 3n coordinates:
  ``E sum |r_i|^2 = (3n - 6) sigma^2`` for independent errors of variance sigma^2 per axis),
  carried to the origin as a Kabsch fit carries noise, ``sigma_delta^2 (1/n + |mbar|^2 /
  lambda_min(J))`` (:func:`kfusion.kalman.markers.fit_angle_variance`); plus ``|rbar_i|^2 / 3``
  of the largest mean residual left uncorrected (a subset's fix moves by at most that).

Without a layout error the mean residuals are the noise's, ``E |rbar_i|^2 ~ sigma_m^2 / N``, so
the term is what N frames leave unknown about the layout and fades as they accumulate (0.01 mm
after 10 s at 100 Hz); with one, it stays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kfusion.kalman.markers import fit_angle_variance

SIGNIFICANCE = 16.27
"""chi-square(3) at 0.999: ``N |rbar_i|^2 / sigma_m^2`` beyond it corrects marker i's layout."""

MIN_FRAMES = 10
"""Frames with every marker fused before any correction."""


@dataclass(frozen=True)
class LayoutResiduals:
    """The layout and its residuals so far (thin state; replaced, never changed in place).

    Attributes:
        body: (n, 3) the declared layout, m, body frame.
        residual_sum: (n, 3) sum of each marker's residual ``r_i`` (m) over ``frames``.
        frames: frames with every marker fused.
    """

    body: NDArray[np.float64]
    residual_sum: NDArray[np.float64]
    frames: int = 0

    @classmethod
    def start(cls, body_positions: ArrayLike) -> LayoutResiduals:
        body = np.array(body_positions, dtype=float).reshape(-1, 3)
        return cls(body, np.zeros_like(body))

    def matches(self, body_positions: NDArray[np.float64]) -> bool:
        """This is the layout ``body_positions`` (n, 3) m."""
        return bool(body_positions.shape == self.body.shape
                    and np.array_equal(body_positions, self.body))

    def with_frame(self, points: ArrayLike) -> LayoutResiduals:
        """After one more frame of every marker (n, 3) m, global frame (:func:`residuals`)."""
        return LayoutResiduals(self.body, self.residual_sum + residuals(points, self.body),
                               self.frames + 1)

    @property
    def mean(self) -> NDArray[np.float64]:
        """(n, 3) ``rbar_i``, m (zeros before any frame)."""
        return self.residual_sum / max(self.frames, 1)


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


def corrected_markers(mean: ArrayLike, frames: int, marker_variance: float
                      ) -> NDArray[np.bool_]:
    """(n,) the markers whose mean residual ``rbar_i`` (n, 3) m over ``frames`` is significant:
    ``frames |rbar_i|^2 / sigma_m^2 > SIGNIFICANCE`` (``marker_variance`` sigma_m^2, m^2 per
    axis), once ``frames >= MIN_FRAMES``."""
    mean = np.asarray(mean, dtype=float).reshape(-1, 3)
    if frames < MIN_FRAMES or not marker_variance > 0:
        return np.zeros(len(mean), dtype=bool)
    return np.asarray(frames * np.sum(mean * mean, axis=1) / marker_variance > SIGNIFICANCE)


def origin_variance(mean: ArrayLike, body_positions: ArrayLike,
                    corrected: ArrayLike) -> float:
    """Per-axis variance (m^2) of the body origin's error the layout leaves (module docstring)::

        sigma_delta^2 (1/n + |mbar|^2 / lambda_min(J)) + max_{i uncorrected} |rbar_i|^2 / 3

    with ``sigma_delta^2 = sum_i |rbar_i|^2 / (3n - 6)``.

    Args:
        mean: (n, 3) mean residuals ``rbar_i``, m.
        body_positions: (n, 3) the layout, m; n >= 3.
        corrected: (n,) the markers placed at ``m_i + rbar_i`` (:func:`corrected_markers`).
    """
    mean = np.asarray(mean, dtype=float).reshape(-1, 3)
    body = np.asarray(body_positions, dtype=float).reshape(-1, 3)
    count = len(body)
    squared = np.sum(mean * mean, axis=1)
    layout_variance = float(np.sum(squared)) / (3 * count - 6)
    centroid = body.mean(axis=0)
    rigid = layout_variance / count + float(centroid @ centroid) * fit_angle_variance(
        body, layout_variance)
    left = squared[~np.asarray(corrected, dtype=bool)]
    return rigid + (float(left.max()) / 3.0 if len(left) else 0.0)
