"""The four simulated forearm scenarios, shaped on the paper's experiments (Amorim et al. 2021).

World: OptiTrack's default y-up frame. The subject faces +z (forward), +x is to the side.
Body frame (the mocap rigid body on the forearm tube): x along the forearm towards the hand,
y up when the palm faces down, z = x × y. At zero angles the forearm points forward and level
(``BASE_QUATERNION``). Orientation is ``BASE ⊗ exp(yaw y) ⊗ exp(pitch z) ⊗ exp(roll x)``
(body axes): yaw turns the forearm sideways (+ towards +x), pitch lifts the hand (+ up), roll is
pronation/supination about the forearm.

Every scenario starts with 2-3 s at rest (estimators initialise) and ends at rest. Speeds,
accelerations and rates stay within a human forearm's: peak speeds up to ~2 m/s, accelerations
below ~20 m/s^2, angular rates up to a few rad/s.

* ``arm_lift``: the paper's first test, an upward and downward forearm movement along global y
  of 0.70-0.80 m per stroke, at varying speeds (a cosine-like profile whose nominal peak speed
  is uniform in 0.5-1.8 m/s per stroke; the quintic's actual peaks reach ~2.1 m/s). The arm
  turns round at the top without stopping (the change of direction of Type 2 occlusions) and
  sometimes rests at the bottom. The paper's movement is a translation "without rotating the
  arm"; a real arm still tilts a little, so the pitch follows the height by 3-8 degrees over the
  stroke, plus a +-3 degree wobble.
* ``circle``: the paper's second test, a roughly circular trajectory in the global x-y plane
  (radius 0.25-0.35 m, varying by +-10 %, period 1.5-4 s), in blocks of turns that reverse
  direction without stopping (an abrupt change of motion). The forearm's yaw and pitch follow
  the hand round the circle and it rolls by up to +-45 degrees.
* ``pick_tool``: the paper's use case. A seated worker does small assembly moves at the bench
  (up to 0.2 m, peak speed below 0.45 m/s, mostly with a pause between moves), and every 4-8 s
  reaches down and forward to pick a tool off the floor (about 0.75 m down, mostly in the
  global YZ plane, peak speed 1.0-1.8 m/s), pitching the forearm down by 50-75 degrees and
  rolling it by 40-90 degrees to grasp, pausing there or turning straight round, then comes
  back to the bench.
* ``random_reach``: point-to-point reaches (minimum-jerk, 0.25-0.8 m, peak speed up to
  2.0 m/s, slower when the rotation needs it) between random targets in front of the body, each
  with a large rotation of the forearm (90-180 degrees between successive orientations, peak
  rate 3-6 rad/s per angle), half of them straight on from the previous one, half after a pause.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from kfusion.conventions import rotation_angle
from kfusion.simulate.trajectories import (
    AngleChainOrientation,
    Array,
    Curve,
    KnotList,
    LinearCombination,
    Motion,
    PolarCurve,
    chain_quaternion,
)

DEGREE = np.pi / 180.0

BASE_QUATERNION = np.array([np.sqrt(0.5), 0.0, -np.sqrt(0.5), 0.0])
"""Body -> global at zero angles: -90 degrees about global y, so body x (forearm) = global +z."""

ANGLE_AXES = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
"""Body axes of the yaw, pitch and roll rotations, applied in that order."""

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
"""The identity quaternion [w, x, y, z]."""

MINIMUM_JERK_PEAK = 1.875
"""Peak speed of a rest-to-rest minimum-jerk move is 15/8 D / T."""
MINIMUM_JERK_PEAK_ACCELERATION = 5.774
"""Peak acceleration of a rest-to-rest minimum-jerk move is 10 sqrt(3)/3 D / T^2."""
MAX_ACCELERATION = 20.0
"""m/s^2: no simulated move is faster than this peak acceleration."""

START_REST = (2.0, 3.0)
"""s: still period at the start of every scenario."""
END_REST = 1.0
"""s: at least this long at rest at the end."""
MIN_DURATION = 5.0
"""s: shortest scenario accepted."""
MAX_DURATION = 3600.0
"""s: longest scenario accepted (an hour: about 720 000 IMU samples at 200 Hz; ``kfusion
simulate --duration 1e9`` ran for minutes without an end), the limit run configs have too."""


def minimum_jerk_duration(distance: float, peak_speed: float) -> float:
    """Duration of a rest-to-rest minimum-jerk move, s: ``T = max(15/8 D / v, sqrt(5.77 D / a))``
    so that its peak speed is at most ``peak_speed`` and its peak acceleration at most
    :data:`MAX_ACCELERATION`."""
    return max(MINIMUM_JERK_PEAK * distance / peak_speed,
               float(np.sqrt(MINIMUM_JERK_PEAK_ACCELERATION * distance / MAX_ACCELERATION)))


def _orientation(angles: Curve) -> AngleChainOrientation:
    return AngleChainOrientation(base=BASE_QUATERNION, axes=ANGLE_AXES, angles=angles)


def _wobble(rng: np.random.Generator, start: float, end: float, duration: float,
            amplitude: Array, interval: tuple[float, float]) -> KnotList:
    """Rest-to-rest random excursions between ``start`` and ``end``, zero outside: knots
    ``interval`` s apart (the last at least ``interval[0]`` before ``end``), each component
    uniform in +-``amplitude``."""
    zero = np.zeros(len(amplitude))
    knots = KnotList(len(amplitude))
    knots.add(0.0, zero)
    time = start
    knots.add(time, zero)
    while True:
        step = rng.uniform(*interval)
        if time + step + interval[0] > end:
            break
        time += step
        knots.add(time, rng.uniform(-amplitude, amplitude))
    if end > knots.last_time:
        knots.add(end, zero)
    knots.hold_until(duration)
    return knots


# --------------------------------------------------------------------------------------------
# arm_lift
# --------------------------------------------------------------------------------------------


def turn_accelerations(times: Array, heights: Array) -> Array:
    """Acceleration at each knot of an up/down motion, m/s^2.

    At a turn (a top or bottom with motion on both sides) the knot takes the acceleration of a
    cosine stroke, ``a = -/+ (D/2) (pi/T)^2``, using the smaller of the two neighbouring strokes'
    values so neither quintic overshoots; next to a rest, and at the ends, it is zero.
    """
    accelerations = np.zeros(len(times))
    for i in range(1, len(times) - 1):
        before, after = heights[i] - heights[i - 1], heights[i + 1] - heights[i]
        if before == 0 or after == 0 or np.sign(before) == np.sign(after):
            continue
        magnitude = min(abs(before) / 2 * (np.pi / (times[i] - times[i - 1])) ** 2,
                        abs(after) / 2 * (np.pi / (times[i + 1] - times[i])) ** 2)
        accelerations[i] = -np.sign(before) * magnitude
    return accelerations


def arm_lift(rng: np.random.Generator, duration: float) -> Motion:
    """Up/down strokes of 0.70-0.80 m along global y at varying speeds (see module docstring)."""
    bottom = rng.uniform(0.80, 0.90)
    side, forward = rng.uniform(0.10, 0.30), rng.uniform(0.35, 0.50)
    start = rng.uniform(*START_REST)
    times, heights, lateral = [0.0, start], [bottom, bottom], [[side, forward]] * 2
    time = start
    while True:
        travel_up = rng.uniform(0.70, 0.80)
        top = heights[-1] + travel_up
        new_bottom = bottom + rng.uniform(-0.03, 0.03)
        # cosine stroke: peak speed (D/2)(pi/T)  =>  T = pi D / (2 v)
        time_up = np.pi * travel_up / (2 * rng.uniform(0.5, 1.8))
        time_down = np.pi * (top - new_bottom) / (2 * rng.uniform(0.5, 1.8))
        dwell = rng.uniform(0.3, 1.0) if rng.random() < 0.4 else 0.0
        jitter = [side + rng.uniform(-0.03, 0.03), forward + rng.uniform(-0.03, 0.03)]
        if time + time_up + time_down + dwell + END_REST > duration:
            break
        time += time_up
        times.append(time)
        heights.append(top)
        lateral.append(jitter)
        time += time_down
        times.append(time)
        heights.append(new_bottom)
        lateral.append([side, forward])
        if dwell:
            time += dwell
            times.append(time)
            heights.append(new_bottom)
            lateral.append([side, forward])
    if duration > times[-1]:
        times.append(duration)
        heights.append(heights[-1])
        lateral.append([side, forward])
    time_array, height_array = np.array(times), np.array(heights)
    lateral_array = np.array(lateral)
    values = np.column_stack([lateral_array[:, 0], height_array, lateral_array[:, 1]])
    second = np.zeros_like(values)
    second[:, 1] = turn_accelerations(time_array, height_array)
    knots = KnotList(3)
    for t, value, acceleration in zip(time_array, values, second, strict=True):
        knots.add(t, value, None, acceleration)
    position = knots.spline()

    pitch_gain = rng.uniform(3.0, 8.0) * DEGREE / 0.75  # rad per m of height
    coupling = np.zeros((3, 3))
    coupling[1, 1] = pitch_gain
    wobble = _wobble(rng, start, time, duration, np.full(3, 3.0 * DEGREE), (0.8, 1.6))
    angles = LinearCombination(
        terms=((coupling, position), (np.eye(3), wobble.spline())),
        offset=np.array([0.0, -pitch_gain * (bottom + 0.375), 0.0]),
    )
    return Motion(position=position, orientation=_orientation(angles), duration=duration)


# --------------------------------------------------------------------------------------------
# circle
# --------------------------------------------------------------------------------------------


def phase_knots(times: Array, rates: Array, start_phase: float) -> KnotList:
    """Phase knots (rad) for prescribed angular rates (rad/s) at ``times``.

    Phase by the trapezoid rule, ``phi_{k+1} = phi_k + h (w_k + w_{k+1}) / 2``; knot
    acceleration by central differences ``(w_{k+1} - w_{k-1}) / (t_{k+1} - t_{k-1})``, except
    zero next to a rest (two successive zero rates) and at the ends.
    """
    knots = KnotList(1)
    phase = start_phase
    for k, (time, rate) in enumerate(zip(times, rates, strict=True)):
        if k > 0:
            phase += (time - times[k - 1]) * (rate + rates[k - 1]) / 2
        acceleration = 0.0
        if 0 < k < len(times) - 1:
            resting = (rate == 0 and rates[k - 1] == 0) or (rate == 0 and rates[k + 1] == 0)
            if not resting:
                acceleration = (rates[k + 1] - rates[k - 1]) / (times[k + 1] - times[k - 1])
        knots.add(time, [phase], [rate], [acceleration])
    return knots


def circle(rng: np.random.Generator, duration: float) -> Motion:
    """Roughly circular hand path in the global x-y plane with a rolling forearm."""
    centre = np.array([rng.uniform(-0.05, 0.15), rng.uniform(1.10, 1.30), rng.uniform(0.40, 0.50)])
    radius = rng.uniform(0.25, 0.35)
    start = rng.uniform(*START_REST)
    times, rates = [0.0, start], [0.0, 0.0]
    direction = rng.choice([-1.0, 1.0])
    time = start
    while True:
        block_times, block_rates = [], []
        block_time = time
        for _ in range(int(rng.integers(3, 7))):
            block_time += rng.uniform(0.6, 1.2)
            block_times.append(block_time)
            block_rates.append(direction * 2 * np.pi / rng.uniform(1.5, 4.0))
        block_time += rng.uniform(0.5, 0.8)
        block_times.append(block_time)
        block_rates.append(0.0)
        reverse = rng.random() < 0.7
        dwell = 0.0 if reverse else rng.uniform(0.3, 1.0)
        if block_time + END_REST > duration:
            break
        times += block_times
        rates += block_rates
        time = block_time
        if dwell:
            time += dwell
            times.append(time)
            rates.append(0.0)
        direction = -direction if reverse else rng.choice([-1.0, 1.0])
    if duration > times[-1]:
        times.append(duration)
        rates.append(0.0)
    phase = phase_knots(np.array(times), np.array(rates), rng.uniform(0, 2 * np.pi)).spline()
    centre_wobble = _wobble(rng, start, time, duration, np.array([0.03, 0.03, 0.04]), (1.5, 3.0))
    centre_curve = LinearCombination(terms=((np.eye(3), centre_wobble.spline()),), offset=centre)
    radius_wobble = _wobble(rng, start, time, duration, np.array([0.1 * radius]), (0.8, 1.5))
    radius_curve = LinearCombination(terms=((np.eye(1), radius_wobble.spline()),),
                                     offset=np.array([radius]))
    plane = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    position = PolarCurve(centre=centre_curve, radius=radius_curve, phase=phase, plane=plane)

    coupling = np.zeros((3, 3))
    coupling[0, 0] = rng.uniform(0.6, 1.2)  # yaw follows the hand sideways, rad/m
    coupling[1, 1] = rng.uniform(0.6, 1.2)  # pitch follows it up and down, rad/m
    roll = _wobble(rng, start, time, duration, np.array([0.0, 0.0, 45.0 * DEGREE]), (0.7, 1.5))
    angles = LinearCombination(terms=((coupling, position), (np.eye(3), roll.spline())),
                               offset=-coupling @ centre)
    return Motion(position=position, orientation=_orientation(angles), duration=duration)


# --------------------------------------------------------------------------------------------
# Rest-to-rest moves: pick_tool and random_reach
# --------------------------------------------------------------------------------------------


class MoveSequence:
    """Rest-to-rest minimum-jerk moves of position (m) and yaw/pitch/roll (rad), with holds."""

    def __init__(self, position: Array, angles: Array, start: float) -> None:
        self.position = KnotList(3)
        self.angles = KnotList(3)
        for time in (0.0, start):
            self.position.add(time, position)
            self.angles.add(time, angles)

    @property
    def time(self) -> float:
        return self.position.last_time

    def move(self, duration: float, position: Array, angles: Array, hold: float = 0.0) -> None:
        """Move to ``position``/``angles`` in ``duration`` s, then hold still ``hold`` s."""
        self.position.add(self.time + duration, position)
        self.angles.add(self.angles.last_time + duration, angles)
        if hold > 0:
            self.position.hold_until(self.time + hold)
            self.angles.hold_until(self.angles.last_time + hold)

    def motion(self, duration: float) -> Motion:
        self.position.hold_until(duration)
        self.angles.hold_until(duration)
        return Motion(position=self.position.spline(),
                      orientation=_orientation(self.angles.spline()), duration=duration)


def pick_tool(rng: np.random.Generator, duration: float) -> Motion:
    """Bench work, with reaches down to the floor to pick up a tool (the paper's use case)."""
    home = np.array([rng.uniform(-0.05, 0.05), rng.uniform(0.85, 0.92), rng.uniform(0.35, 0.45)])
    home_angles = np.array([0.0, rng.uniform(-15, -5), rng.uniform(-10, 10)]) * DEGREE
    moves = MoveSequence(home, home_angles, rng.uniform(*START_REST))
    position = home
    next_pick = moves.time + rng.uniform(4.0, 7.0)
    while True:
        if moves.time >= next_pick:
            floor = np.array([home[0] + rng.uniform(-0.10, 0.10), rng.uniform(0.08, 0.15),
                              home[2] + rng.uniform(0.20, 0.35)])
            grasp = np.array([rng.uniform(-20, 20), rng.uniform(-75, -50),
                              rng.choice([-1, 1]) * rng.uniform(40, 90)]) * DEGREE
            back = home + np.array([rng.uniform(-0.1, 0.1), rng.uniform(-0.02, 0.04),
                                    rng.uniform(-0.05, 0.05)])
            time_down = minimum_jerk_duration(float(np.linalg.norm(floor - position)),
                                              rng.uniform(1.0, 1.8))
            # a grasp at the floor: sometimes a pause, sometimes a straight turn-around
            hold_down = rng.uniform(0.3, 0.8) if rng.random() < 0.5 else 0.0
            time_up = minimum_jerk_duration(float(np.linalg.norm(back - floor)),
                                            rng.uniform(0.8, 1.5))
            hold_up = rng.uniform(0.3, 0.8)
            if moves.time + time_down + hold_down + time_up + hold_up + END_REST <= duration:
                moves.move(time_down, floor, grasp, hold_down)
                moves.move(time_up, back, home_angles, hold_up)
                position = back
                next_pick = moves.time + rng.uniform(4.0, 8.0)
                continue
            next_pick = np.inf
        target = home + np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.03, 0.06),
                                  rng.uniform(-0.08, 0.10)])
        target_angles = home_angles + np.array([rng.uniform(-15, 15), rng.uniform(-10, 10),
                                                rng.uniform(-30, 30)]) * DEGREE
        move_time = max(0.4, minimum_jerk_duration(float(np.linalg.norm(target - position)),
                                                   rng.uniform(0.2, 0.45)))
        hold = rng.uniform(0.2, 0.8) if rng.random() < 0.7 else 0.0
        if moves.time + move_time + hold + END_REST > duration:
            break
        moves.move(move_time, target, target_angles, hold)
        position = target
    return moves.motion(duration)


REACH_BOX = (np.array([-0.35, 0.75, 0.20]), np.array([0.45, 1.55, 0.65]))
"""m: (low, high) corners of the region the random reaches go to, global frame."""
REACH_ANGLE_BOX = (np.array([-60.0, -60.0, -100.0]) * DEGREE,
                   np.array([60.0, 45.0, 100.0]) * DEGREE)
"""rad: (low, high) yaw, pitch and roll of the random reaches."""


def random_reach(rng: np.random.Generator, duration: float) -> Motion:
    """Minimum-jerk reaches between random targets, each with a 90-180 degree rotation."""
    low, high = REACH_BOX
    position = (low + high) / 2 + rng.uniform(-0.1, 0.1, 3)
    angles = np.zeros(3)
    moves = MoveSequence(position, angles, rng.uniform(*START_REST))
    while True:
        for _ in range(100):
            target = rng.uniform(low, high)
            distance = float(np.linalg.norm(target - position))
            if 0.25 <= distance <= 0.8:
                break
        current = chain_quaternion(IDENTITY, ANGLE_AXES, angles[None, :])[0]
        for _ in range(200):
            target_angles = rng.uniform(*REACH_ANGLE_BOX)
            turn = rotation_angle(
                current, chain_quaternion(IDENTITY, ANGLE_AXES, target_angles[None, :])[0])
            if 90 * DEGREE <= turn <= 180 * DEGREE:
                break
        angle_change = float(np.linalg.norm(target_angles - angles))
        move_time = max(minimum_jerk_duration(distance, rng.uniform(0.6, 2.0)),
                        MINIMUM_JERK_PEAK * angle_change / rng.uniform(3.0, 6.0), 0.4)
        hold = rng.uniform(0.1, 0.5) if rng.random() < 0.5 else 0.0
        if moves.time + move_time + hold + END_REST > duration:
            break
        moves.move(move_time, target, target_angles, hold)
        position, angles = target, target_angles
    return moves.motion(duration)


ScenarioBuilder = Callable[[np.random.Generator, float], Motion]

BUILDERS: dict[str, ScenarioBuilder] = {
    "arm_lift": arm_lift,
    "circle": circle,
    "pick_tool": pick_tool,
    "random_reach": random_reach,
}
"""Scenario name -> builder ``(rng, duration) -> Motion``."""

DEFAULT_DURATIONS: dict[str, float] = {
    "arm_lift": 40.0,
    "circle": 30.0,
    "pick_tool": 45.0,
    "random_reach": 40.0,
}
"""s: default length of each scenario."""
