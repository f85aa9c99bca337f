"""Smooth limb trajectories with exact (analytic) derivatives.

Every curve returns its value and its first and second time derivatives from closed-form
expressions, so the simulated accelerometer and gyroscope are exact, never finite-differenced.

* :class:`QuinticSpline`: piecewise quintic Hermite interpolation of knots that carry a value, a
  first and a second derivative. With zero rates at both ends a segment is the minimum-jerk
  profile of human reaching (Flash & Hogan, 1985); with nonzero knot rates it passes through
  a turn-around or a moving via point without stopping. Twice continuously differentiable.
* :class:`PolarCurve`: a roughly circular path ``c(t) + r(t) (u cos phi(t) + v sin phi(t))``.
* :class:`LinearCombination`: ``offset + sum_i A_i x_i(t)``, for angles coupled to position.
* :class:`AngleChainOrientation`: ``q(t) = q0 ⊗ exp(θ1 a1) ⊗ ... ⊗ exp(θk ak)``, a chain of
  rotations by smooth angles about fixed axes, with its exact body-frame angular rate.
* :class:`Motion`: a position curve and an orientation, evaluated into a :class:`MotionState`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kfusion.conventions import quaternion_about_axis, quaternion_multiply

Array = NDArray[np.float64]
CurveValue = tuple[Array, Array, Array]
"""(value, first derivative, second derivative), each of shape (n, d)."""

TIME_TOLERANCE = 1e-9
"""s: how far outside its knot range a curve may be evaluated (floating-point slack)."""


class Curve(Protocol):
    """A smooth vector function of time with exact derivatives."""

    @property
    def dimension(self) -> int:
        """Number of components d."""
        ...

    def evaluate(self, t: ArrayLike) -> CurveValue:
        """Value, first and second derivative at times ``t`` (n,), each of shape (n, d)."""
        ...


def _times(t: ArrayLike) -> Array:
    times = np.asarray(t, dtype=float)
    if times.ndim != 1:
        raise ValueError(f"t: expected a 1-D array of times in s, got shape {times.shape}")
    return times


# --------------------------------------------------------------------------------------------
# Quintic Hermite spline
# --------------------------------------------------------------------------------------------


def quintic_coefficients(
    duration: ArrayLike,
    start: tuple[ArrayLike, ArrayLike, ArrayLike],
    end: tuple[ArrayLike, ArrayLike, ArrayLike],
) -> Array:
    """Coefficients of the quintic joining two (value, rate, acceleration) states.

    With ``h`` the segment duration, ``s`` the time since its start and
    ``x(s) = c0 + c1 s + c2 s^2 + c3 s^3 + c4 s^4 + c5 s^5``:

        c0 = x0,  c1 = v0,  c2 = a0 / 2
        dx = x1 - x0 - v0 h - a0 h^2 / 2,   dv = v1 - v0 - a0 h,   da = a1 - a0
        c3 = (10 dx - 4 dv h + da h^2 / 2) / h^3
        c4 = (-15 dx + 7 dv h - da h^2) / h^4
        c5 = (6 dx - 3 dv h + da h^2 / 2) / h^5

    Shapes: ``duration`` (k,), each state entry (k, d); returns (k, 6, d).
    """
    h = np.asarray(duration, dtype=float)[:, None]
    x0, v0, a0 = (np.asarray(v, dtype=float) for v in start)
    x1, v1, a1 = (np.asarray(v, dtype=float) for v in end)
    dx = x1 - x0 - v0 * h - a0 * h**2 / 2
    dv = v1 - v0 - a0 * h
    da = a1 - a0
    c3 = (10 * dx - 4 * dv * h + da * h**2 / 2) / h**3
    c4 = (-15 * dx + 7 * dv * h - da * h**2) / h**4
    c5 = (6 * dx - 3 * dv * h + da * h**2 / 2) / h**5
    return np.stack([x0, v0, a0 / 2, c3, c4, c5], axis=1)


@dataclass(frozen=True)
class QuinticSpline:
    """Piecewise quintic through knots with prescribed value, rate and acceleration.

    Attributes:
        knots: (K,) strictly increasing knot times, s, K >= 2.
        value: (K, d) value at each knot.
        first: (K, d) first time derivative at each knot (per s).
        second: (K, d) second time derivative at each knot (per s^2).
    """

    knots: Array
    value: Array
    first: Array
    second: Array
    coefficients: Array = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        knots = np.asarray(self.knots, dtype=float)
        arrays = [np.asarray(a, dtype=float) for a in (self.value, self.first, self.second)]
        arrays = [a[:, None] if a.ndim == 1 else a for a in arrays]
        if knots.ndim != 1 or knots.shape[0] < 2 or not np.all(np.diff(knots) > 0):
            raise ValueError(f"QuinticSpline.knots: expected K >= 2 strictly increasing times, "
                             f"got {knots!r}")
        shape = arrays[0].shape
        if shape[0] != knots.shape[0] or any(a.shape != shape for a in arrays):
            raise ValueError("QuinticSpline: expected value, first and second of shape (K, d) "
                             f"with K = {knots.shape[0]}, got {[a.shape for a in arrays]}")
        value, first, second = arrays
        coefficients = quintic_coefficients(
            np.diff(knots), (value[:-1], first[:-1], second[:-1]),
            (value[1:], first[1:], second[1:]))
        object.__setattr__(self, "knots", knots)
        object.__setattr__(self, "value", value)
        object.__setattr__(self, "first", first)
        object.__setattr__(self, "second", second)
        object.__setattr__(self, "coefficients", coefficients)

    @property
    def dimension(self) -> int:
        return int(self.value.shape[1])

    def evaluate(self, t: ArrayLike) -> CurveValue:
        """Value, first and second derivative at ``t`` (n,) inside the knot range; (n, d) each.

        Horner's rule on ``x(s) = sum_j c_j s^j`` and its derivatives.
        """
        times = _times(t)
        low, high = self.knots[0], self.knots[-1]
        if times.size and (times.min() < low - TIME_TOLERANCE
                           or times.max() > high + TIME_TOLERANCE):
            raise ValueError(f"t: expected times inside [{low}, {high}] s, got "
                             f"[{times.min()}, {times.max()}]")
        segment = np.clip(np.searchsorted(self.knots, times, side="right") - 1,
                          0, len(self.knots) - 2)
        s = (times - self.knots[segment])[:, None]
        c = self.coefficients[segment]  # (n, 6, d)
        value = c[:, 5]
        for j in (4, 3, 2, 1, 0):
            value = value * s + c[:, j]
        first = 5 * c[:, 5]
        for j in (4, 3, 2, 1):
            first = first * s + j * c[:, j]
        second = 20 * c[:, 5]
        for j, factor in ((4, 12), (3, 6), (2, 2)):
            second = second * s + factor * c[:, j]
        return value, first, second


class KnotList:
    """Builder of a :class:`QuinticSpline`: append knots in time order, then :meth:`spline`."""

    def __init__(self, dimension: int) -> None:
        self.dimension = dimension
        self.times: list[float] = []
        self.values: list[Array] = []
        self.firsts: list[Array] = []
        self.seconds: list[Array] = []

    def _vector(self, value: ArrayLike | None) -> Array:
        if value is None:
            return np.zeros(self.dimension)
        vector = np.broadcast_to(np.asarray(value, dtype=float), (self.dimension,))
        return np.array(vector)

    def add(self, time: float, value: ArrayLike, first: ArrayLike | None = None,
            second: ArrayLike | None = None) -> None:
        """Append a knot at ``time`` (s, after the previous knot); rates default to zero."""
        if self.times and time <= self.times[-1]:
            raise ValueError(f"knot time {time} s is not after the previous {self.times[-1]} s")
        self.times.append(float(time))
        self.values.append(self._vector(value))
        self.firsts.append(self._vector(first))
        self.seconds.append(self._vector(second))

    @property
    def last_time(self) -> float:
        return self.times[-1]

    def hold_until(self, time: float) -> None:
        """Stay at rest at the last value until ``time`` (no knot if ``time`` is not later)."""
        if time > self.times[-1]:
            self.add(time, self.values[-1])

    def spline(self) -> QuinticSpline:
        return QuinticSpline(np.array(self.times), np.array(self.values),
                             np.array(self.firsts), np.array(self.seconds))


# --------------------------------------------------------------------------------------------
# Composite curves
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PolarCurve:
    """A roughly circular path in a plane: ``p = c + r e``, ``e = u cos(phi) + v sin(phi)``.

    With ``n = -u sin(phi) + v cos(phi)`` (so ``de/dphi = n``, ``dn/dphi = -e``):

        p'  = c' + r' e + r phi' n
        p'' = c'' + r'' e + (2 r' phi' + r phi'') n - r phi'^2 e

    Attributes:
        centre: curve (d = 3), m.
        radius: curve (d = 1), m.
        phase: curve (d = 1), rad.
        plane: (2, 3) orthonormal in-plane directions u, v (global frame).
    """

    centre: Curve
    radius: Curve
    phase: Curve
    plane: Array

    @property
    def dimension(self) -> int:
        return 3

    def evaluate(self, t: ArrayLike) -> CurveValue:
        times = _times(t)
        c, c1, c2 = self.centre.evaluate(times)
        r, r1, r2 = self.radius.evaluate(times)
        phi, phi1, phi2 = self.phase.evaluate(times)
        u, v = np.asarray(self.plane, dtype=float)
        e = np.cos(phi) * u + np.sin(phi) * v
        n = -np.sin(phi) * u + np.cos(phi) * v
        value = c + r * e
        first = c1 + r1 * e + r * phi1 * n
        second = c2 + r2 * e + (2 * r1 * phi1 + r * phi2) * n - r * phi1**2 * e
        return value, first, second


@dataclass(frozen=True)
class LinearCombination:
    """``x(t) = offset + sum_i A_i y_i(t)``; derivatives are the same combination of theirs.

    Attributes:
        terms: pairs (A_i of shape (d, d_i), curve y_i of dimension d_i).
        offset: (d,) constant.
    """

    terms: tuple[tuple[Array, Curve], ...]
    offset: Array

    @property
    def dimension(self) -> int:
        return int(np.asarray(self.offset).shape[0])

    def evaluate(self, t: ArrayLike) -> CurveValue:
        times = _times(t)
        value = np.broadcast_to(np.asarray(self.offset, dtype=float),
                                (times.shape[0], self.dimension)).copy()
        first = np.zeros_like(value)
        second = np.zeros_like(value)
        for matrix, curve in self.terms:
            y, y1, y2 = curve.evaluate(times)
            matrix = np.asarray(matrix, dtype=float)
            value += y @ matrix.T
            first += y1 @ matrix.T
            second += y2 @ matrix.T
        return value, first, second


# --------------------------------------------------------------------------------------------
# Orientation
# --------------------------------------------------------------------------------------------


def chain_quaternion(base: ArrayLike, axes: ArrayLike, angles: Array) -> Array:
    """``q0 ⊗ exp(θ1 a1) ⊗ ... ⊗ exp(θk ak)`` for base q0 (4,) [w, x, y, z], unit axes (k, 3)
    and angles (n, k) rad; (n, 4), not normalised."""
    angles = np.asarray(angles, dtype=float)
    quaternion = np.broadcast_to(np.asarray(base, dtype=float), (angles.shape[0], 4))
    for index, axis in enumerate(np.asarray(axes, dtype=float)):
        quaternion = quaternion_multiply(quaternion, quaternion_about_axis(axis, angles[:, index]))
    return quaternion


def rotate_about_axis(vectors: Array, axis: ArrayLike, angle: Array) -> Array:
    """Rodrigues: ``R(a, θ) v = v cosθ + (a × v) sinθ + a (a·v)(1 - cosθ)``; (n, 3)."""
    a = np.asarray(axis, dtype=float)
    cos, sin = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return vectors * cos + np.cross(a, vectors) * sin + np.outer(vectors @ a, a) * (1 - cos)


@dataclass(frozen=True)
class AngleChainOrientation:
    """``q(t) = q0 ⊗ exp(θ1(t) a1) ⊗ ... ⊗ exp(θk(t) ak)``: body -> global.

    Each rotation is about a fixed unit axis of the frame left by the rotations before it.
    With ``R = R0 R1 ... Rk`` and ``Ri = R(ai, θi)``, ``Rᵀ dR/dt = [ω]×`` gives the body-frame
    angular rate

        ω = sum_i (R_{i+1} ... R_k)ᵀ ai θi',

    accumulated as ``w <- R_iᵀ w + ai θi'`` for i = 1..k.

    Attributes:
        base: (4,) q0, [w, x, y, z].
        axes: (k, 3) unit rotation axes.
        angles: curve of dimension k, rad.
    """

    base: Array
    axes: Array
    angles: Curve

    def evaluate(self, t: ArrayLike) -> tuple[Array, Array]:
        """Quaternion body -> global (n, 4) [w, x, y, z] and body-frame rate (n, 3) rad/s."""
        times = _times(t)
        theta, theta_rate, _ = self.angles.evaluate(times)
        quaternion = chain_quaternion(self.base, self.axes, theta)
        rate = np.zeros((times.shape[0], 3))
        for index, axis in enumerate(np.asarray(self.axes, dtype=float)):
            rate = rotate_about_axis(rate, axis, -theta[:, index])
            rate = rate + np.outer(theta_rate[:, index], axis)
        quaternion = quaternion / np.linalg.norm(quaternion, axis=1, keepdims=True)
        return quaternion, rate


@dataclass(frozen=True)
class MotionState:
    """Exact kinematic state of the rigid body at times ``t``.

    Attributes:
        t: (n,) s.
        position: (n, 3) m, global.  velocity: (n, 3) m/s.  acceleration: (n, 3) m/s^2.
        quaternion: (n, 4) body -> global, [w, x, y, z].
        angular_rate: (n, 3) rad/s, body frame.
    """

    t: Array
    position: Array
    velocity: Array
    acceleration: Array
    quaternion: Array
    angular_rate: Array


@dataclass(frozen=True)
class Motion:
    """A rigid body's motion: position curve (global, m) and orientation (body -> global).

    Attributes:
        position: curve of dimension 3.
        orientation: the body's orientation.
        duration: s; the motion is defined on [0, duration].
    """

    position: Curve
    orientation: AngleChainOrientation
    duration: float

    def state(self, t: ArrayLike) -> MotionState:
        times = _times(t)
        position, velocity, acceleration = self.position.evaluate(times)
        quaternion, rate = self.orientation.evaluate(times)
        return MotionState(times, position, velocity, acceleration, quaternion, rate)

