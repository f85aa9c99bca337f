"""ISO/TS 15066 protective separation distance: terms against hand-computed numbers, the ISO 13855
speed rule's branches, and "unknown" that can never pass for a small distance."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.stats import chi2

from kfusion.safety import (
    REACH_INTRUSION_DISTANCE,
    intrusion_distance_for_detection_capability,
    iso13855_human_motion,
    protective_separation_distance,
)

ROBOT = dict(robot_speed=1.0, reaction_time=0.1, stopping_time=0.3, stopping_distance=0.2,
             robot_position_uncertainty=0.01)


@dataclass(frozen=True)
class FakeEstimate:
    """Stands in for kfusion.tracker.Estimate: t, status and a bound."""

    t: float
    status: str
    radius: float

    def bound(self, confidence: float = 0.99) -> float:
        return self.radius


def test_hand_computed_total_with_speed_switch():
    # T = T_r + T_s = 0.4 s; C = 0.1 m: 2.0 * 0.4 + 0.1 = 0.9 > 0.5 -> 1.6 * 0.4 + 0.1 = 0.74
    result = protective_separation_distance(0.02, intrusion_distance=0.1, **ROBOT)
    assert result.known and result.reason == ""
    assert result.human_speed == 1.6
    assert result.human_motion == pytest.approx(0.64, abs=1e-15)
    assert result.robot_motion == pytest.approx(0.1, abs=1e-15)
    assert result.value == pytest.approx(0.64 + 0.1 + 0.2 + 0.1 + 0.02 + 0.01, abs=1e-15)
    terms = (result.human_motion + result.robot_motion + result.stopping_distance
             + result.intrusion_distance + result.position_uncertainty
             + result.robot_position_uncertainty)
    assert result.value == pytest.approx(terms, abs=1e-15)


def test_iso13855_rule_branches():
    # below 0.5 m with 2.0 m/s: keep 2.0
    assert iso13855_human_motion(0.1, 0.0) == pytest.approx((0.2, 2.0))
    # above with 2.0, above with 1.6: 1.6
    human, speed = iso13855_human_motion(0.5, 0.0)
    assert speed == 1.6 and human == pytest.approx(0.8)
    # above with 2.0 (0.6), below with 1.6 (0.48): floored at 0.5 m
    human, speed = iso13855_human_motion(0.3, 0.0)
    assert speed == 1.6 and human == pytest.approx(0.5)
    # the floor applies to S_h + C
    human, speed = iso13855_human_motion(0.2, 0.15)  # 0.55 -> 0.47 -> 0.5
    assert speed == 1.6 and human + 0.15 == pytest.approx(0.5)
    # exactly 0.5 with 2.0 stays at 2.0 (the switch is "exceeds")
    assert iso13855_human_motion(0.25, 0.0) == pytest.approx((0.5, 2.0))


def test_explicit_human_speed_replaces_the_rule():
    result = protective_separation_distance(0.0, human_speed=1.0, intrusion_distance=0.0,
                                            **ROBOT)
    assert result.human_speed == 1.0
    assert result.human_motion == pytest.approx(0.4)


def test_default_intrusion_distance_is_reach():
    result = protective_separation_distance(0.0, **ROBOT)
    assert result.intrusion_distance == REACH_INTRUSION_DISTANCE == 0.85


@pytest.mark.parametrize(("capability_mm", "expected_m"),
                         [(14, 0.0), (10, 0.0), (30, 0.128), (40, 0.208), (41, 0.85), (70, 0.85)])
def test_intrusion_distance_for_detection_capability(capability_mm, expected_m):
    value = intrusion_distance_for_detection_capability(capability_mm / 1000)
    assert value == pytest.approx(expected_m, abs=1e-12)


def test_latency_and_estimate_age_add_to_reaction_time():
    estimate = FakeEstimate(t=10.0, status="bridged", radius=0.005)
    result = protective_separation_distance(estimate, sensing_latency=0.02, now=10.03,
                                            human_speed=2.0, intrusion_distance=0.0, **ROBOT)
    assert result.reaction_time == pytest.approx(0.1 + 0.02 + 0.03)
    assert result.robot_motion == pytest.approx(1.0 * 0.15)
    assert result.human_motion == pytest.approx(2.0 * (0.15 + 0.3))
    assert result.position_uncertainty == 0.005
    assert result.status == "bridged"


def test_z_d_is_the_estimate_bound_at_the_requested_confidence():
    from kfusion.tracker import Estimate

    sigma = 0.004
    covariance = np.eye(3) * sigma**2
    estimate = Estimate(t=1.0, position=np.zeros(3), velocity=np.zeros(3),
                        covariance=covariance, std=np.full(3, sigma), status="bridged",
                        time_since_fix=0.2, method="kalman")
    for confidence in (0.9, 0.99, 0.999):
        result = protective_separation_distance(estimate, confidence=confidence, **ROBOT)
        expected = sigma * math.sqrt(chi2.ppf(confidence, 3))
        assert result.position_uncertainty == pytest.approx(expected, rel=1e-12)
        assert result.confidence == confidence


def test_lost_is_explicitly_unknown_and_never_small():
    lost = FakeEstimate(t=5.0, status="lost", radius=0.0)  # even a (bogus) zero bound
    result = protective_separation_distance(lost, **ROBOT)
    assert result.known is False
    assert result.value == math.inf
    assert result.reason == "tracker lost: position unknown"
    assert result.position_uncertainty == math.inf
    assert not result.permits(1e9)
    # the other terms are still reported
    assert result.robot_motion == pytest.approx(0.1)


def test_real_lost_tracker_estimate_is_unknown():
    from kfusion.tracker import Tracker

    tracker = Tracker(imu_to_body=[1, 0, 0, 0], gravity=[0, -9.81, 0])
    estimate = tracker.estimate(tracker.newest_time)  # no data at all
    assert estimate.status == "lost"
    result = protective_separation_distance(estimate, **ROBOT)
    assert not result.known and result.value == math.inf
    assert result.reason == "tracker lost: position unknown"


@pytest.mark.parametrize("estimate", [None, math.inf, math.nan,
                                      FakeEstimate(1.0, "tracked", math.inf),
                                      FakeEstimate(1.0, "bridged", math.nan)])
def test_missing_uncertainty_is_unknown(estimate):
    result = protective_separation_distance(estimate, **ROBOT)
    assert not result.known
    assert result.value == math.inf
    assert "unknown" in result.reason
    assert not result.permits(100.0)


def test_permits_compares_with_the_known_distance():
    result = protective_separation_distance(0.01, **ROBOT)
    assert result.permits(result.value + 1e-9)
    assert not result.permits(result.value - 1e-9)


def test_bigger_uncertainty_means_bigger_distance():
    small = protective_separation_distance(0.001, **ROBOT)
    large = protective_separation_distance(0.050, **ROBOT)
    assert large.value - small.value == pytest.approx(0.049)


@pytest.mark.parametrize(("name", "value", "match"), [
    ("robot_speed", -1.0, r"robot_speed: expected a finite number >= 0, got -1.0"),
    ("reaction_time", math.nan, r"reaction_time: expected a finite number, got nan"),
    ("stopping_time", "0.3", r"stopping_time: expected a finite number, got str"),
    ("confidence", 1.0, r"confidence: expected a probability in \(0, 1\), got 1.0"),
    ("human_speed", -0.5, r"human_speed: expected a finite number >= 0, got -0.5"),
])
def test_bad_arguments_raise_value_error(name, value, match):
    arguments = {**ROBOT, name: value}
    with pytest.raises(ValueError, match=match):
        protective_separation_distance(0.01, **arguments)


def test_bad_estimate_type_and_negative_bound_raise():
    with pytest.raises(ValueError, match=r"estimate: expected a tracker estimate .* got str"):
        protective_separation_distance("close", **ROBOT)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"estimate: expected a bound >= 0 m, got -0.1"):
        protective_separation_distance(-0.1, **ROBOT)


def test_now_before_the_estimate_raises():
    estimate = FakeEstimate(t=2.0, status="tracked", radius=0.001)
    with pytest.raises(ValueError, match=r"now: expected a time at or after the estimate's t"):
        protective_separation_distance(estimate, now=1.9, **ROBOT)
