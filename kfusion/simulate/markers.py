"""Marker clusters with partial occlusions (opt-in: :func:`kfusion.simulate.simulate`'s
``markers``).

The rigid body carries n markers at fixed body-frame positions ``m_i`` (m, a few cm from its
origin). Each is seen at ``p + R_global_body m_i + e_i``, ``e_i ~ N(0, noise^2)`` per axis,
white and independent between markers.

Occlusions come in episodes, placed like the rigid-body gaps (:class:`OcclusionSpec`: length,
placement, spacing). An episode is something passing between the cameras and the forearm; it
hides a random subset of the markers, of a size drawn from ``hidden_count_weights`` (by default
most episodes hide one or two markers, few hide all), and each hidden marker has its own
interval inside the episode: one marker is hidden throughout, each other one from a start
delayed by up to ``stagger`` of the episode's length to an end advanced by up to as much (a
marker dips out and back at its own frames). Which markers, and their intervals, are drawn
independently per episode.

The rigid body written to ``mocap.csv`` is what Motive does: a Kabsch fit of the visible
markers where 3 or more are seen (:func:`kfusion.rigid_body.solve_poses`), empty otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kfusion.recording import occlusion_runs

DEFAULT_BODY_POSITIONS: tuple[tuple[float, float, float], ...] = (
    (0.045, 0.020, 0.010),
    (-0.035, 0.030, -0.015),
    (0.010, -0.040, 0.020),
    (-0.025, -0.015, -0.035),
)
"""m: a forearm cluster of four markers 4-5 cm from the rigid-body origin, not coplanar."""


@dataclass(frozen=True)
class MarkerSpec:
    """A simulated marker cluster and how its markers are occluded.

    Attributes:
        body_positions: (n, 3) marker positions in the body frame, m; n >= 3.
        noise: 1-sigma per axis of each marker's position, m, >= 0.
        hidden_count_weights: relative weights of an episode hiding 1, 2, ..., n markers
            (length n); the default for 4 markers is 45 %, 35 %, 10 %, 10 %.
        stagger: fraction of an episode's length (0 to 0.5) by which the other hidden markers'
            intervals may start later and end earlier than the episode.
        names: marker names (default M1, M2, ...).
    """

    body_positions: tuple[tuple[float, float, float], ...] = DEFAULT_BODY_POSITIONS
    noise: float = 0.5e-3
    hidden_count_weights: tuple[float, ...] = (0.45, 0.35, 0.10, 0.10)
    stagger: float = 0.3
    names: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        body = np.asarray(self.body_positions, dtype=float)
        if body.ndim != 2 or body.shape[1] != 3 or len(body) < 3 or not np.isfinite(body).all():
            raise ValueError(f"MarkerSpec.body_positions: expected (n, 3) finite positions in m "
                             f"with n >= 3, got shape {body.shape}")
        from kfusion.rigid_body import refuse_collinear

        refuse_collinear("MarkerSpec.body_positions", body)
        if not (math.isfinite(self.noise) and self.noise >= 0):
            raise ValueError(f"MarkerSpec.noise: expected a finite number >= 0 (m), got "
                             f"{self.noise!r}")
        weights = np.asarray(self.hidden_count_weights, dtype=float)
        if weights.shape != (len(body),) or not (np.isfinite(weights).all()
                                                 and (weights >= 0).all() and weights.sum() > 0):
            raise ValueError(f"MarkerSpec.hidden_count_weights: expected {len(body)} "
                             f"non-negative weights (1 to {len(body)} markers hidden), got "
                             f"{self.hidden_count_weights!r}")
        if not 0 <= self.stagger <= 0.5:
            raise ValueError(f"MarkerSpec.stagger: expected a fraction in [0, 0.5], got "
                             f"{self.stagger!r}")
        names = self.names or tuple(f"M{i + 1}" for i in range(len(body)))
        if len(names) != len(body) or len(set(names)) != len(names):
            raise ValueError(f"MarkerSpec.names: expected {len(body)} distinct names, got "
                             f"{names!r}")
        object.__setattr__(self, "names", tuple(names))

    @property
    def marker_names(self) -> tuple[str, ...]:
        """The marker names (n,)."""
        assert self.names is not None
        return self.names


def hidden_markers(episodes: NDArray[np.bool_], spec: MarkerSpec, rng: np.random.Generator
                   ) -> NDArray[np.bool_]:
    """Hidden mask (m, n) from the episode mask (m,) (module docstring)."""
    count = len(spec.body_positions)
    weights = np.asarray(spec.hidden_count_weights, dtype=float)
    hidden = np.zeros((len(episodes), count), dtype=bool)
    for start, stop in occlusion_runs(~np.asarray(episodes, dtype=bool)):
        how_many = int(rng.choice(np.arange(1, count + 1), p=weights / weights.sum()))
        chosen = rng.permutation(count)[:how_many]
        length = stop - start
        for order, marker in enumerate(chosen):
            first, last = start, stop
            if order > 0:
                most = int(spec.stagger * length)
                first += int(rng.integers(0, most + 1))
                last -= int(rng.integers(0, most + 1))
                last = max(last, first + 1)
            hidden[first:last, marker] = True
    return hidden


def observe_markers(position: NDArray[np.float64], rotation: NDArray[np.float64],
                    spec: MarkerSpec, hidden: NDArray[np.bool_], rng: np.random.Generator
                    ) -> NDArray[np.float64]:
    """Seen marker positions (m, n, 3), m: ``p + R m_i + e_i``, NaN where hidden.

    Args:
        position: (m, 3) true rigid-body origin, m.
        rotation: (m, 3, 3) true R_global_body.
        spec: the cluster.
        hidden: (m, n) hidden mask.
        rng: draws m n 3 standard normals.
    """
    body = np.asarray(spec.body_positions, dtype=float)
    true = position[:, None, :] + np.einsum("kij,nj->kni", rotation, body)
    seen = true + spec.noise * rng.standard_normal(true.shape)
    return np.where(hidden[:, :, None], np.nan, seen)
