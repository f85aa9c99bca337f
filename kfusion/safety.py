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
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Real
from typing import Final, Protocol, runtime_checkable

from kfusion.conventions import LOST

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
    """What :func:`protective_separation_distance` needs from an estimate."""

    t: float
    status: str

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
