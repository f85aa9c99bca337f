"""Protective separation distance for speed and separation monitoring (ISO/TS 15066).

ISO/TS 15066:2016, clause 5.5.4.2.3, gives the protective separation distance at time t0 as

    S_p(t0) = S_h + S_r + S_s + C + Z_d + Z_r

with constant speeds over the intervals, as this module assumes:

=====  ================================================  ==========================================
term   meaning (unit: m)                                 computed here as (source)
=====  ================================================  ==========================================
S_h    distance the human moves while the robot          v_h (T_r + T_s) (ISO/TS 15066; v_h by the
       reacts and stops                                  ISO 13855 rule below)
S_r    distance the robot moves in its reaction          v_r T_r (ISO/TS 15066)
       time
S_s    distance the robot travels while stopping         given by the caller (measured stopping
                                                         distance, ISO 10218-1 annex B)
C      intrusion distance: how far a body part can       given by the caller; default 0.85 m, the
       reach past the sensed point undetected            ISO 13855 reach value (see below)
Z_d    position uncertainty of the sensed human          the tracker's bound at ``confidence``
                                                         (:meth:`kfusion.tracker.Estimate.bound`)
Z_r    position uncertainty of the robot                 given by the caller (accuracy of the
                                                         robot's position measurement)
=====  ================================================  ==========================================

T_r is the reaction time of the whole chain. It includes the sensing latency: pass the
controller's reaction time as ``reaction_time`` and the delay from a measurement to its use as
``sensing_latency`` (or pass ``now``: the estimate's age, ``now - estimate.t``, is added too).

Human speed (ISO 13855:2010, 6.2.3, eq. (1) with K = 2000 mm/s, then K = 1600 mm/s): the
standard's minimum distance is S = K T + C. It is computed with K = 2.0 m/s; if that exceeds
0.5 m it is recomputed with K = 1.6 m/s, and the result is not allowed below 0.5 m. In ISO/TS 15066
terms K T + C is S_h + C with T = T_r + T_s, so the rule is applied to S_h + C: when the 0.5 m
floor binds, S_h is raised so that S_h + C = 0.5 m. Applying the switch to S_h + C rather than to
the whole S_p uses 2.0 m/s in more cases, so it is the conservative reading. An explicit
``human_speed`` replaces the rule (for example a measured, monitored speed).

Intrusion distance C (ISO 13855:2010): for an electro-sensitive device of detection capability d,
C = 8 (d - 14) mm for d <= 40 mm, and C = 850 mm (arm reach) beyond. kfusion senses one rigid
body on the forearm, not every body part: the hand and fingers beyond it are not detected, so the
default is the reach value 0.85 m. A smaller C needs a risk assessment of what the tracked point
does not cover; :func:`intrusion_distance_for_detection_capability` gives the standard's value.

Unknown is explicit. When the tracker is lost, when no estimate is given, or when the estimate
has no usable uncertainty (the baseline method has none), the result has ``known=False`` and
``value=math.inf`` with a reason. It is never a small number, and because the value is infinite
even a caller that only compares ``current_distance >= result.value`` gets "not safe".

Several bodies (two forearms): :func:`binding_body` computes each body's margin
``|robot - body| - S_p`` (m), with S_p as above and that body's bound as Z_d, and returns the
body with the smallest margin. The result is unknown (``known=False``, ``margin=-math.inf``) as
soon as any body's S_p is unknown: a lost body is never skipped, since it may be the nearest.
:func:`binding_margins` applies it row by row to ``kfusion track`` outputs.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from numbers import Real
from types import MappingProxyType
from typing import Any, Final, Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kfusion.conventions import LOST, STATUSES

HAND_APPROACH_SPEED: Final = 2.0
"""m/s, ISO 13855 K = 2000 mm/s, the first speed of the rule."""
BODY_APPROACH_SPEED: Final = 1.6
"""m/s, ISO 13855 K = 1600 mm/s, used when S with 2.0 m/s exceeds 0.5 m."""
SPEED_SWITCH_DISTANCE: Final = 0.5
"""m, ISO 13855: the threshold of the speed rule and the floor of S = K T + C after the switch."""
REACH_INTRUSION_DISTANCE: Final = 0.85
"""m, ISO 13855 C for detection capability above 40 mm (arm reach): the default C here."""
DEFAULT_CONFIDENCE: Final = 0.99
"""Probability that the human's sensed point lies within Z_d under the filter's model."""


@runtime_checkable
class HasBound(Protocol):
    """What :func:`protective_separation_distance` needs from an estimate: ``t`` (s), ``status``
    and ``bound(confidence)`` (m); read-only, so frozen dataclasses qualify."""

    @property
    def t(self) -> float: ...

    @property
    def status(self) -> str: ...

    def bound(self, confidence: float = DEFAULT_CONFIDENCE) -> float: ...


@dataclass(frozen=True)
class SeparationDistance:
    """The protective separation distance S_p and each of its terms (all in m, times in s).

    Attributes:
        known: False when S_p cannot be given (tracker lost, no estimate, no uncertainty).
        value: S_p, m; ``math.inf`` when not known, never a small number.
        reason: why it is not known ("" when known).
        human_motion: S_h = v_h (T_r + T_s), m (after the ISO 13855 floor, see module docstring).
        robot_motion: S_r = v_r T_r, m.
        stopping_distance: S_s, m.
        intrusion_distance: C, m.
        position_uncertainty: Z_d, m (the estimate's bound; ``math.inf`` when not known).
        robot_position_uncertainty: Z_r, m.
        human_speed: v_h used, m/s.
        robot_speed: v_r, m/s.
        reaction_time: T_r used, s (reaction time + sensing latency + estimate age).
        stopping_time: T_s, s.
        confidence: probability attached to Z_d.
        status: the estimate's status, or None when a bare bound was given.
    """

    known: bool
    value: float
    reason: str
    human_motion: float
    robot_motion: float
    stopping_distance: float
    intrusion_distance: float
    position_uncertainty: float
    robot_position_uncertainty: float
    human_speed: float
    robot_speed: float
    reaction_time: float
    stopping_time: float
    confidence: float
    status: str | None

    def permits(self, separation: float) -> bool:
        """True only if S_p is known and ``separation`` (m, human to robot) is at least S_p."""
        return self.known and float(separation) >= self.value


# ------------------------------------------------------------------------------------------
# Pure terms
# ------------------------------------------------------------------------------------------


def human_motion_distance(human_speed: float, reaction_time: float, stopping_time: float) -> float:
    """S_h = v_h (T_r + T_s), m: the human's travel while the robot reacts and stops."""
    return human_speed * (reaction_time + stopping_time)


def robot_motion_distance(robot_speed: float, reaction_time: float) -> float:
    """S_r = v_r T_r, m: the robot's travel before it starts stopping."""
    return robot_speed * reaction_time


def iso13855_human_motion(
    response_time: float, intrusion_distance: float
) -> tuple[float, float]:
    """ISO 13855 speed rule applied to S = K T + C; returns (S_h, v_h) with S_h = S - C.

        S = 2.0 T + C; if S > 0.5 m:  S = max(1.6 T + C, 0.5 m)

    ``response_time`` is T = T_r + T_s (s) and ``intrusion_distance`` is C (m).
    """
    distance = HAND_APPROACH_SPEED * response_time + intrusion_distance
    if distance <= SPEED_SWITCH_DISTANCE:
        return distance - intrusion_distance, HAND_APPROACH_SPEED
    distance = max(BODY_APPROACH_SPEED * response_time + intrusion_distance,
                   SPEED_SWITCH_DISTANCE)
    return distance - intrusion_distance, BODY_APPROACH_SPEED


def intrusion_distance_for_detection_capability(detection_capability: float) -> float:
    """ISO 13855 intrusion distance C (m) for a sensor of detection capability d (m).

        C = 8 (d - 14 mm), not below 0,   for d <= 40 mm
        C = 850 mm,                       for d > 40 mm
    """
    d = _non_negative("detection_capability", detection_capability)
    if d <= 0.040:
        return max(8.0 * (d - 0.014), 0.0)
    return REACH_INTRUSION_DISTANCE


def protective_separation_distance(
    estimate: HasBound | float | None,
    *,
    robot_speed: float,
    reaction_time: float,
    stopping_time: float,
    stopping_distance: float,
    robot_position_uncertainty: float,
    intrusion_distance: float = REACH_INTRUSION_DISTANCE,
    sensing_latency: float = 0.0,
    now: float | None = None,
    human_speed: float | None = None,
    confidence: float = DEFAULT_CONFIDENCE,
) -> SeparationDistance:
    """ISO/TS 15066 protective separation distance S_p = S_h + S_r + S_s + C + Z_d + Z_r.

    Args:
        estimate: a tracker estimate (:class:`kfusion.tracker.Estimate`, anything with ``t``,
            ``status`` and ``bound(confidence)``), a bare Z_d in m, or None (no estimate).
        robot_speed: v_r, m/s, robot speed towards the human.
        reaction_time: T_r, s, from detection to the robot starting to stop.
        stopping_time: T_s, s, time the robot takes to stop.
        stopping_distance: S_s, m, distance the robot travels while stopping.
        robot_position_uncertainty: Z_r, m.
        intrusion_distance: C, m (default 0.85 m, ISO 13855 reach; see module docstring).
        sensing_latency: s, from a measurement to its use; added to T_r.
        now: s, on the tracker's clock; ``now - estimate.t`` is added to T_r as well
            (ignored when ``estimate`` is a bare bound, which has no time).
        human_speed: v_h, m/s; None applies the ISO 13855 rule (2.0 m/s, or 1.6 m/s beyond 0.5 m).
        confidence: probability for Z_d = ``estimate.bound(confidence)``, in (0, 1).

    Returns:
        :class:`SeparationDistance`. It is ``known=False, value=math.inf`` when the estimate is
        None, lost, or has no finite bound; the other terms are still filled in.

    Raises:
        ValueError: a negative or non-finite argument, a confidence outside (0, 1), an estimate
            of the wrong type, or ``now`` before the estimate's time.
    """
    robot_speed = _non_negative("robot_speed", robot_speed)
    reaction_time = _non_negative("reaction_time", reaction_time)
    stopping_time = _non_negative("stopping_time", stopping_time)
    stopping_distance = _non_negative("stopping_distance", stopping_distance)
    robot_position_uncertainty = _non_negative("robot_position_uncertainty",
                                               robot_position_uncertainty)
    intrusion_distance = _non_negative("intrusion_distance", intrusion_distance)
    sensing_latency = _non_negative("sensing_latency", sensing_latency)
    confidence = _confidence(confidence)

    age = 0.0
    if now is not None and isinstance(estimate, HasBound):
        now = _finite("now", now)
        age = now - float(estimate.t)
        if age < 0.0:
            raise ValueError(f"now: expected a time at or after the estimate's t = "
                             f"{float(estimate.t)!r} s, got {now!r}")
    total_reaction = reaction_time + sensing_latency + age

    if human_speed is None:
        human, speed = iso13855_human_motion(total_reaction + stopping_time, intrusion_distance)
    else:
        speed = _non_negative("human_speed", human_speed)
        human = human_motion_distance(speed, total_reaction, stopping_time)
    robot = robot_motion_distance(robot_speed, total_reaction)

    position_uncertainty, status, reason = _position_uncertainty(estimate, confidence)
    known = not reason
    value = (human + robot + stopping_distance + intrusion_distance + position_uncertainty
             + robot_position_uncertainty) if known else math.inf
    return SeparationDistance(
        known=known, value=value, reason=reason, human_motion=human, robot_motion=robot,
        stopping_distance=stopping_distance, intrusion_distance=intrusion_distance,
        position_uncertainty=position_uncertainty if known else math.inf,
        robot_position_uncertainty=robot_position_uncertainty, human_speed=speed,
        robot_speed=robot_speed, reaction_time=total_reaction, stopping_time=stopping_time,
        confidence=confidence, status=status,
    )


# ------------------------------------------------------------------------------------------
# Helpers
# ------------------------------------------------------------------------------------------


def _position_uncertainty(
    estimate: HasBound | float | None, confidence: float
) -> tuple[float, str | None, str]:
    """(Z_d in m, status, reason); a non-empty reason means S_p is unknown."""
    if estimate is None:
        return math.inf, None, "no estimate: position unknown"
    if isinstance(estimate, bool) or not isinstance(estimate, (Real, HasBound)):
        raise ValueError("estimate: expected a tracker estimate (with t, status and "
                         "bound(confidence)), a bound in m, or None; got "
                         f"{type(estimate).__name__}")
    if isinstance(estimate, Real):
        bound = float(estimate)
        if bound < 0:
            raise ValueError(f"estimate: expected a bound >= 0 m, got {bound!r}")
        if not math.isfinite(bound):
            return math.inf, None, f"position uncertainty is {bound!r}: position unknown"
        return bound, None, ""
    status = str(estimate.status)
    if status == LOST:
        return math.inf, status, "tracker lost: position unknown"
    bound = float(estimate.bound(confidence))
    if not math.isfinite(bound) or bound < 0:
        return math.inf, status, (f"no usable position uncertainty (bound {bound!r}): "
                                  "position unknown")
    return bound, status, ""


def _finite(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, Real):
        raise ValueError(f"{name}: expected a finite number, got {type(value).__name__}")
    number = float(value)
    if not math.isfinite(number):
        raise ValueError(f"{name}: expected a finite number, got {number!r}")
    return number


def _non_negative(name: str, value: float) -> float:
    number = _finite(name, value)
    if number < 0:
        raise ValueError(f"{name}: expected a finite number >= 0, got {number!r}")
    return number


def _confidence(value: float) -> float:
    number = _finite("confidence", value)
    if not 0.0 < number < 1.0:
        raise ValueError(f"confidence: expected a probability in (0, 1), got {number!r}")
    return number


# ------------------------------------------------------------------------------------------
# Several bodies: the binding body and its margin
# ------------------------------------------------------------------------------------------


@runtime_checkable
class HasPosition(HasBound, Protocol):
    """What :func:`binding_body` needs from a body's estimate: ``t`` (s), ``status``,
    ``bound(confidence)`` (m) and ``position`` ((3,) m, global frame), as
    :class:`kfusion.tracker.Estimate` and :class:`BodyEstimate` have."""

    @property
    def position(self) -> Any: ...


@dataclass(frozen=True)
class BodyEstimate:
    """One body's estimate from a ``kfusion track`` row (or any position with per-axis sigmas).

    Attributes:
        t: time, s.
        position: (3,) m, global frame; NaN when lost.
        std: (3,) 1-sigma per axis, m; NaN when the method gives none.
        status: ``tracked``, ``bridged`` or ``lost``.
    """

    t: float
    position: NDArray[np.float64]
    std: NDArray[np.float64]
    status: str

    def bound(self, confidence: float = DEFAULT_CONFIDENCE) -> float:
        """Z_d, m: :func:`kfusion.tracker.position_bound` of the covariance diag(std^2), as
        :meth:`kfusion.tracker.Estimate.bound` (``math.inf`` when lost or without std)."""
        from kfusion.tracker import position_bound  # scipy and filterpy only when used

        if self.status == LOST:
            return math.inf
        return position_bound(np.diag(np.square(np.asarray(self.std, dtype=float))), confidence)


@dataclass(frozen=True)
class BindingBody:
    """The body nearest to violating the protective separation distance (all lengths in m).

    margin_i = |robot - body_i| - S_p,i, with S_p,i from :func:`protective_separation_distance`
    for body i's estimate (its bound is that body's Z_d); the binding body has the smallest margin.
    A negative margin means the robot is closer to that body than S_p: not permitted.

    Unknown is explicit: when any body's S_p is unknown (lost, no usable bound, no position) or no
    body is given, ``known`` is False, ``body`` is None and ``margin`` is ``-math.inf``, so even a
    caller that only checks ``margin >= 0`` gets "not safe". A lost body is never skipped: the
    body nobody can see may be the nearest.

    Attributes:
        known: False when the margin cannot be given.
        body: the binding body's name (None when unknown).
        margin: the binding body's margin, m; ``-math.inf`` when unknown.
        distance: |robot - body| of the binding body, m; NaN when unknown.
        separation: the binding body's :class:`SeparationDistance` (None when unknown).
        margins: every body's margin, m, in the order given (``-math.inf`` for an unknown one).
        unknown_bodies: the bodies whose S_p is unknown, in the order given.
        reason: why the result is unknown ("" when known).
    """

    known: bool
    body: str | None
    margin: float
    distance: float
    separation: SeparationDistance | None
    margins: Mapping[str, float]
    unknown_bodies: tuple[str, ...]
    reason: str

    def permits(self) -> bool:
        """True only if the margin is known and at least 0 m."""
        return self.known and self.margin >= 0.0


def body_margin(robot_position: NDArray[np.float64], position: ArrayLike,
                separation: SeparationDistance) -> tuple[float, float]:
    """(margin, distance), m: distance = |robot - body|, margin = distance - S_p.

    ``(-math.inf, NaN)`` when S_p is unknown or the body's position is not finite."""
    body = np.asarray(position, dtype=float)
    if not separation.known or body.shape != (3,) or not np.isfinite(body).all():
        return -math.inf, math.nan
    distance = float(np.linalg.norm(robot_position - body))
    return distance - separation.value, distance


def binding_body(robot_position: ArrayLike, estimates: Mapping[str, HasPosition],
                 **separation: Any) -> BindingBody:
    """The binding body among several and its margin |robot - body| - S_p (m).

    Args:
        robot_position: (3,) m, global frame: the robot's point nearest to the human.
        estimates: body name -> estimate (:class:`kfusion.tracker.Estimate`,
            :class:`BodyEstimate`, or anything with ``t``, ``status``, ``bound(confidence)`` and
            ``position``).
        **separation: the keyword arguments of :func:`protective_separation_distance`
            (``robot_speed``, ``reaction_time``, ``stopping_time``, ``stopping_distance``,
            ``robot_position_uncertainty``, and optionally ``intrusion_distance``,
            ``sensing_latency``, ``now``, ``human_speed``, ``confidence``), shared by every body.

    Returns:
        :class:`BindingBody`; unknown (``margin = -math.inf``) when any body is lost or has no
        usable bound, or when ``estimates`` is empty. Ties go to the first body given.

    Raises:
        ValueError: a robot position that is not 3 finite numbers, an estimate of the wrong type,
            an estimate (named) whose status is not one of ``tracked``, ``bridged``, ``lost``,
            whose ``t`` is not finite or whose ``std`` (when it has one) is negative, or a bad
            separation argument (as :func:`protective_separation_distance`).

    Without ``now`` the newest estimate's ``t`` is taken as now, and every older estimate is aged
    by ``now - t`` (added to T_r as with an explicit ``now``): an estimate 100 s older than the
    others is never used as if it were current.
    """
    robot = np.asarray(robot_position, dtype=float)
    if robot.shape != (3,) or not np.isfinite(robot).all():
        raise ValueError(f"robot_position: expected 3 finite numbers (m), got shape "
                         f"{robot.shape}" + ("" if robot.shape != (3,) else f" {robot.tolist()}"))
    for name, estimate in estimates.items():
        _check_body_estimate(name, estimate)
    if separation.get("now") is None and estimates:
        separation = {**separation,
                      "now": max(float(estimate.t) for estimate in estimates.values())}
    margins: dict[str, float] = {}
    best: tuple[str, float, float, SeparationDistance] | None = None
    unknown: list[str] = []
    for name, estimate in estimates.items():
        distance_to_stop = protective_separation_distance(estimate, **separation)
        margin, distance = body_margin(robot, estimate.position, distance_to_stop)
        margins[name] = margin
        if margin == -math.inf:
            unknown.append(name)
        elif best is None or margin < best[1]:
            best = (name, margin, distance, distance_to_stop)
    if unknown or best is None:
        reason = (f"{', '.join(repr(name) for name in unknown)}: position unknown (lost or no "
                  "usable bound)" if unknown else "no body estimates: position unknown")
        return BindingBody(known=False, body=None, margin=-math.inf, distance=math.nan,
                           separation=None, margins=MappingProxyType(margins),
                           unknown_bodies=tuple(unknown), reason=reason)
    name, margin, distance, distance_to_stop = best
    return BindingBody(known=True, body=name, margin=margin, distance=distance,
                       separation=distance_to_stop, margins=MappingProxyType(margins),
                       unknown_bodies=(), reason="")


def _check_body_estimate(name: str, estimate: object) -> None:
    """Raise ValueError naming body ``name`` for an estimate binding_body cannot use as given:
    not an estimate, a status outside STATUSES (a typo such as "Lost" must not pass as tracked),
    a non-finite t, or a negative std (a sigma is >= 0; NaN std means "none given" and stays
    allowed: it makes the body unknown)."""
    if not isinstance(estimate, HasPosition):
        raise ValueError(f"estimates[{name!r}]: expected an estimate with t, status, "
                         f"bound(confidence) and position, got {type(estimate).__name__}")
    if estimate.status not in STATUSES:
        raise ValueError(f"estimates[{name!r}]: status {estimate.status!r} is not one of "
                         f"{', '.join(STATUSES)}")
    t = float(estimate.t)
    if not math.isfinite(t):
        raise ValueError(f"estimates[{name!r}]: t = {t!r} s; expected a finite time")
    std = getattr(estimate, "std", None)
    if std is not None and bool(np.any(np.asarray(std, dtype=float) < 0)):
        raise ValueError(f"estimates[{name!r}]: std {np.asarray(std).tolist()} m has a negative "
                         "sigma; expected values >= 0 (NaN when none)")


@dataclass(frozen=True)
class BindingMargins:
    """:func:`binding_body` at every row of several bodies' tracks (lengths in m, times in s).

    Attributes:
        t: (m,) the tracks' times, s.
        body: (m,) the binding body's name per row ("" where unknown).
        margin: (m,) its margin |robot - body| - S_p, m; ``-inf`` where unknown.
        known: (m,) False where any body is lost or has no usable bound.
        names: the bodies, in the order given.
    """

    t: NDArray[np.float64]
    body: NDArray[np.str_]
    margin: NDArray[np.float64]
    known: NDArray[np.bool_]
    names: tuple[str, ...]


def binding_margins(robot_position: ArrayLike, tracks: Mapping[str, Any],
                    **separation: Any) -> BindingMargins:
    """:func:`binding_body` row by row over several bodies' tracks on one time base.

    Args:
        robot_position: (3,) m, a fixed robot point, or (m, 3) m, one per row.
        tracks: body name -> :class:`kfusion.track_file.TrackResult` (e.g.
            :func:`kfusion.track_file.read_track` of each file ``kfusion track`` wrote for a
            folder of bodies); all with the same times, s.
        **separation: as :func:`binding_body` (``now`` is not accepted: each row is used at its
            own time).

    Raises:
        ValueError: no tracks, tracks whose times differ (naming the body), a robot position of
            the wrong shape, or a bad separation argument.
    """
    if "now" in separation:
        raise ValueError("binding_margins: 'now' is not accepted; each row is used at its own t")
    if not tracks:
        raise ValueError("binding_margins: expected at least one body's track, got none")
    names = tuple(tracks)
    t = np.asarray(tracks[names[0]].t, dtype=float)
    for name in names[1:]:
        other = np.asarray(tracks[name].t, dtype=float)
        if other.shape != t.shape or not np.array_equal(other, t):
            raise ValueError(f"binding_margins: track {name!r} has {other.shape[0]} rows "
                             f"({other[0] if len(other) else 'none'}.. s); expected the times "
                             f"of track {names[0]!r} ({t.shape[0]} rows)")
    robot = np.asarray(robot_position, dtype=float)
    if robot.shape == (3,):
        robot = np.broadcast_to(robot, (t.shape[0], 3))
    if robot.shape != (t.shape[0], 3):
        raise ValueError(f"robot_position: expected shape (3,) or ({t.shape[0]}, 3) m, got "
                         f"{robot.shape}")
    body = np.full(t.shape[0], "", dtype=object)
    margin = np.full(t.shape[0], -math.inf)
    for row in range(t.shape[0]):
        result = binding_body(robot[row], {
            name: BodyEstimate(t=float(t[row]), position=track.position[row],
                               std=track.std[row], status=str(track.status[row]))
            for name, track in tracks.items()}, **separation)
        body[row] = result.body or ""
        margin[row] = result.margin
    return BindingMargins(t=t, body=body.astype(str), margin=margin,
                          known=np.isfinite(margin), names=names)
