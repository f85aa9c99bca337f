"""``simulate``: a seeded scenario turned into a recording plus its ground truth.

Pipeline (each step a small function):

1. the scenario builder draws a smooth :class:`~kfusion.simulate.trajectories.Motion` of the
   mocap rigid body, with exact velocity, acceleration, orientation and angular rate;
2. the IMU is mounted on the rigid body with a non-identity rotation ``q_body_imu`` (nominally
   -90 degrees about the forearm, plus a 2-degree std misalignment per axis) at its origin: the
   lever arm is zero, so the IMU's position and acceleration are the body's;
3. at the IMU times: ``f_imu = R_imu_global (a_global - g_global)``
   (:func:`kfusion.conventions.specific_force`) and ``ω_imu = R_imu_body ω_body``, measured
   with the IMU profile's errors (:mod:`kfusion.simulate.imu`);
4. at the mocap times: the occlusion generator picks hidden frames
   (:mod:`kfusion.simulate.occlusions`), and the visible ones get the mocap profile's noise
   (:mod:`kfusion.simulate.mocap`).

Clock: by default both sensors share it. IMU samples at ``k / imu_rate``, mocap frames at
``k / mocap_rate`` for k = 0, 1, ... up to the duration, so the first mocap frame coincides with
the first IMU sample (at 200 Hz and 100 Hz every mocap time is also an IMU time). With
``imu_time_offset`` c and ``imu_clock_drift_ppm`` d the IMU runs on its own clock
(:func:`kfusion.conventions.imu_time_to_mocap`): it ticks every ``1 / imu_rate`` s of its own
clock, sample k is taken at mocap time ``k (1 + d 1e-6) / imu_rate`` and stamped
``k / imu_rate - c / (1 + d 1e-6)``. The recording's info keeps c = d = 0 (what an uncalibrated
recording says); :attr:`Simulation.imu_clock` holds the truth.

Lever arm: ``lever_arm`` r (body frame, m) puts the IMU off the rigid-body origin; it then feels
``a_imu = a_body + R_global_body (alpha x r + omega x (omega x r))`` (alpha, omega body frame;
alpha by a central difference of the exact rate, h = 1e-5 s, one-sided at the ends).

Random streams: ``numpy.random.default_rng(seed)`` is split (``Generator.spawn``) into
independent streams for the trajectory and mount, the IMU, the mocap noise and the occlusions,
so changing the occlusion spec or the sensor profiles leaves the trajectory unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kfusion.conventions import (
    OPTITRACK_GRAVITY,
    matrix_from_wxyz,
    quaternion_exp_rows,
    quaternion_multiply,
    specific_force,
)
from kfusion.profiles import ImuProfile, MocapProfile, imu_profile, mocap_profile
from kfusion.recording import ImuSamples, MarkerFrames, MocapFrames, Recording, RecordingInfo
from kfusion.simulate.imu import (
    UnmodelledErrors,
    apply_unmodelled,
    jittered_stamps,
    simulate_imu,
)
from kfusion.simulate.markers import MarkerSpec, hidden_markers, observe_markers
from kfusion.simulate.mocap import measure_mocap
from kfusion.simulate.occlusions import OcclusionSpec, place_occlusions
from kfusion.simulate.scenarios import BUILDERS, DEFAULT_DURATIONS, MAX_DURATION, MIN_DURATION

Array = NDArray[np.float64]

SCENARIOS: tuple[str, ...] = ("arm_lift", "circle", "pick_tool", "random_reach")
"""Names accepted by :func:`simulate`."""

NOMINAL_MOUNT = np.array([np.sqrt(0.5), -np.sqrt(0.5), 0.0, 0.0])
"""q_body_imu before misalignment: -90 degrees about the forearm (body x), so IMU z = body y
(the accelerometer reads about +9.81 on z with the forearm level) and IMU y = body -z."""
MOUNT_MISALIGNMENT = 2.0 * np.pi / 180.0
"""rad: std per axis of the IMU board's misalignment on the forearm tube."""


def _frozen(value: object) -> Array | None:
    if value is None:
        return None
    array = np.array(value, copy=True)
    array.flags.writeable = False
    return array


@dataclass(frozen=True)
class Truth:
    """Ground truth of a simulation (read-only arrays).

    At the mocap times:
        t: (m,) s.
        position: (m, 3) true rigid-body position, m, global frame.
        occluded: (m,) bool, True where the mocap frame is hidden.
        quaternion: (m, 4) true body -> global, [w, x, y, z] (None when read from disk).

    Dense, at the IMU times (None when read from disk):
        imu_t: (n,) s, the IMU sample instants on the mocap clock.
        imu_position, imu_velocity, imu_acceleration: (n, 3) of the IMU (the rigid-body
            origin plus the lever arm), m, m/s, m/s^2, global frame.
        imu_quaternion: (n, 4) true IMU -> global (q_global_imu), [w, x, y, z].
        imu_angular_rate: (n, 3) true angular rate, rad/s, IMU frame.
        imu_specific_force: (n, 3) true specific force, m/s^2, IMU frame.
        accelerometer_bias, gyroscope_bias: (n, 3) true biases, IMU frame (m/s^2, rad/s).

    Constant over the run (None when read from disk):
        accelerometer_matrix, gyroscope_matrix: (3, 3) scale and cross-axis matrices M, with
            ``measured = M true + bias + noise`` before clipping and quantisation.
    """

    t: Array
    position: Array
    occluded: NDArray[np.bool_]
    quaternion: Array | None = None
    imu_t: Array | None = None
    imu_position: Array | None = None
    imu_velocity: Array | None = None
    imu_acceleration: Array | None = None
    imu_quaternion: Array | None = None
    imu_angular_rate: Array | None = None
    imu_specific_force: Array | None = None
    accelerometer_bias: Array | None = None
    gyroscope_bias: Array | None = None
    accelerometer_matrix: Array | None = None
    gyroscope_matrix: Array | None = None

    def __post_init__(self) -> None:
        t = np.asarray(self.t, dtype=float)
        position = np.asarray(self.position, dtype=float)
        occluded = np.asarray(self.occluded)
        if t.ndim != 1 or position.shape != (t.shape[0], 3) or occluded.shape != t.shape:
            raise ValueError(f"Truth: expected t (m,), position (m, 3), occluded (m,); got "
                             f"{t.shape}, {position.shape}, {occluded.shape}")
        for item in fields(self):
            value = getattr(self, item.name)
            if item.name == "occluded":
                value = np.asarray(value, dtype=bool)
            elif value is not None:
                value = np.asarray(value, dtype=float)
            object.__setattr__(self, item.name, _frozen(value))


@dataclass(frozen=True)
class Simulation:
    """A simulated recording and its ground truth.

    Attributes:
        recording: the recording an estimator sees (occluded mocap rows NaN).
        truth: the ground truth.
        scenario: scenario name.
        seed: the seed it was drawn from.
        imu_profile, mocap_profile: the sensor error models used (set by :func:`simulate`).
    """

    recording: Recording
    truth: Truth
    scenario: str
    seed: int
    imu_profile: ImuProfile | None = field(default=None, repr=False)
    mocap_profile: MocapProfile | None = field(default=None, repr=False)
    imu_clock: tuple[float, float] = (0.0, 0.0)
    """The true IMU clock (imu_time_offset s, imu_clock_drift_ppm)."""


def sample_times(duration: float, rate: float) -> Array:
    """``k / rate`` for k = 0 .. floor(duration rate), s (exact multiples, no accumulation)."""
    return np.arange(math.floor(duration * rate + 1e-9) + 1) / rate


def mount_quaternion(rng: np.random.Generator) -> Array:
    """q_body_imu: :data:`NOMINAL_MOUNT` ⊗ exp(½ δ), δ ~ N(0, MOUNT_MISALIGNMENT^2) per axis."""
    misalignment = quaternion_exp_rows(MOUNT_MISALIGNMENT * rng.standard_normal((1, 3)))
    quaternion = quaternion_multiply(NOMINAL_MOUNT, misalignment[0])
    return quaternion / np.linalg.norm(quaternion)


def _check_rate(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
            math.isfinite(value) and value > 0):
        raise ValueError(f"{name}: expected a positive rate in Hz, got {value!r}")
    return float(value)


def _resolve_profiles(imu: str | ImuProfile, mocap: str | MocapProfile
                      ) -> tuple[ImuProfile, MocapProfile]:
    imu_object = imu_profile(imu) if isinstance(imu, str) else imu
    mocap_object = mocap_profile(mocap) if isinstance(mocap, str) else mocap
    if not isinstance(imu_object, ImuProfile):
        raise ValueError(f"imu: expected a profile name or an ImuProfile, got {imu!r}")
    if not isinstance(mocap_object, MocapProfile):
        raise ValueError(f"mocap: expected a profile name or a MocapProfile, got {mocap!r}")
    return imu_object, mocap_object


def simulate(
    scenario: str,
    *,
    seed: int,
    imu: str | ImuProfile = "mpu9255",
    mocap: str | MocapProfile = "optitrack",
    occlusions: OcclusionSpec | None = OcclusionSpec(),  # noqa: B008 (frozen, immutable)
    duration: float | None = None,
    imu_rate: float = 200.0,
    mocap_rate: float | None = None,
    imu_time_offset: float = 0.0,
    imu_clock_drift_ppm: float = 0.0,
    lever_arm: ArrayLike | None = None,
    unmodelled: UnmodelledErrors | None = None,
    markers: MarkerSpec | None = None,
) -> Simulation:
    """Simulate ``scenario`` (one of :data:`SCENARIOS`) and return recording plus truth.

    Args:
        scenario: ``"arm_lift"``, ``"circle"``, ``"pick_tool"`` or ``"random_reach"``.
        seed: non-negative integer; the same seed gives the same simulation.
        imu: IMU profile name or :class:`~kfusion.profiles.ImuProfile` (any, e.g. error-free).
        mocap: mocap profile name or :class:`~kfusion.profiles.MocapProfile`.
        occlusions: occlusion spec; None for no occlusions.
        duration: s, 5-3600; None for the scenario's default (30-45 s).
        imu_rate: IMU sample rate, Hz.
        mocap_rate: mocap frame rate, Hz; None for the mocap profile's rate.
        imu_time_offset: s, and imu_clock_drift_ppm: the IMU's own clock (module docstring);
            the recording's info does not say them.
        lever_arm: (3,) IMU position in the body frame, m (default zero); written to the
            recording's info.
        unmodelled: IMU error sources the filter's model does not have (misalignment,
            g-sensitivity, temperature drift, timestamp jitter); None or all zero: none, and
            the simulation is the same as without the argument.
        markers: a marker cluster (:mod:`kfusion.simulate.markers`): the occlusion episodes
            hide some of its markers, ``markers.csv`` and ``recording.yaml``'s ``markers`` are
            written, and the mocap rigid body is the Kabsch fit of the visible markers where 3
            or more are seen (NaN elsewhere; ``truth.occluded`` marks those rows). None (the
            default): no markers, and the simulation is the same as without the argument.

    Raises ValueError on an unknown scenario or profile, bad numbers, or when the occlusion spec
    fits no gap.
    """
    if scenario not in BUILDERS:
        raise ValueError(f"unknown scenario {scenario!r}; expected one of {list(SCENARIOS)}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed: expected a non-negative integer, got {seed!r}")
    imu_object, mocap_object = _resolve_profiles(imu, mocap)
    length = DEFAULT_DURATIONS[scenario] if duration is None else duration
    if isinstance(length, bool) or not isinstance(length, (int, float)) or not (
            math.isfinite(length) and MIN_DURATION <= length <= MAX_DURATION):
        raise ValueError(f"duration: expected {MIN_DURATION:g}-{MAX_DURATION:g} s, got "
                         f"{duration!r}")
    imu_rate = _check_rate("imu_rate", imu_rate)
    mocap_rate = _check_rate("mocap_rate",
                             mocap_object.rate if mocap_rate is None else mocap_rate)
    for name, value, limit in (("imu_time_offset", imu_time_offset, 1e6),
                               ("imu_clock_drift_ppm", imu_clock_drift_ppm, 1e4)):
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not (
                math.isfinite(value) and abs(value) <= limit):
            raise ValueError(f"{name}: expected a finite number within +-{limit:g}, got "
                             f"{value!r}")
    arm = np.zeros(3) if lever_arm is None else np.asarray(lever_arm, dtype=float)
    if arm.shape != (3,) or not np.isfinite(arm).all():
        raise ValueError(f"lever_arm: expected 3 finite numbers (m), got shape {arm.shape}")
    if occlusions is not None and not isinstance(occlusions, OcclusionSpec):
        raise ValueError(f"occlusions: expected an OcclusionSpec or None, got {occlusions!r}")

    motion_rng, imu_rng, mocap_rng, occlusion_rng = np.random.default_rng(int(seed)).spawn(4)
    motion = BUILDERS[scenario](motion_rng, float(length))
    q_body_imu = mount_quaternion(motion_rng)
    gravity = np.array(OPTITRACK_GRAVITY)

    # dense truth at the IMU sample instants (mocap clock)
    scale = 1.0 + imu_clock_drift_ppm * 1e-6
    imu_t = sample_times(length / scale, imu_rate) * scale
    imu_stamps = imu_t / scale - imu_time_offset / scale
    dense = motion.state(imu_t)
    q_global_imu = quaternion_multiply(dense.quaternion, q_body_imu)
    R_imu_body = matrix_from_wxyz(q_body_imu).T
    R_imu_global = np.transpose(matrix_from_wxyz(q_global_imu), (0, 2, 1))
    imu_position, imu_velocity, imu_acceleration = (dense.position, dense.velocity,
                                                    dense.acceleration)
    if arm.any():
        step = 1e-5
        low, high = np.maximum(imu_t - step, 0.0), np.minimum(imu_t + step, length)
        alpha = (motion.state(high).angular_rate - motion.state(low).angular_rate) / (
            high - low)[:, None]
        omega = dense.angular_rate
        lever = np.cross(alpha, arm) + np.cross(omega, np.cross(omega, arm))
        R_global_body = matrix_from_wxyz(dense.quaternion)
        imu_position = imu_position + R_global_body @ arm
        imu_velocity = imu_velocity + np.einsum("nij,nj->ni", R_global_body,
                                                np.cross(omega, arm))
        imu_acceleration = imu_acceleration + np.einsum("nij,nj->ni", R_global_body, lever)
    true_force = specific_force(R_imu_global, imu_acceleration, gravity)
    true_rate = dense.angular_rate @ R_imu_body.T
    sensed_force, sensed_rate = true_force, true_rate
    if unmodelled is not None and unmodelled.active:
        # a stream of its own, so that the other draws stay the same
        extra_rng = np.random.default_rng([int(seed), 0x756E6D6F])
        sensed_force, sensed_rate = apply_unmodelled(extra_rng, unmodelled, imu_t, true_force,
                                                     true_rate)
        imu_stamps = jittered_stamps(extra_rng, imu_stamps, unmodelled.timestamp_jitter)
    measured = simulate_imu(imu_rng, imu_object, 1.0 / imu_rate, sensed_force, sensed_rate)

    # mocap frames
    mocap_t = sample_times(length, mocap_rate)
    frames = motion.state(mocap_t)
    if occlusions is None:
        occluded = np.zeros(len(mocap_t), dtype=bool)
    else:
        occluded = place_occlusions(mocap_t, frames.velocity, occlusions, occlusion_rng)
    marker_frames = None
    if markers is not None:
        if not isinstance(markers, MarkerSpec):
            raise ValueError(f"markers: expected a MarkerSpec or None, got {markers!r}")
        # streams of their own, so that the other draws stay the same
        marker_rng = np.random.default_rng([int(seed), 0x6D61726B])
        hidden = hidden_markers(occluded, markers, marker_rng)
        seen = observe_markers(frames.position, matrix_from_wxyz(frames.quaternion), markers,
                               hidden, marker_rng)
        from kfusion.rigid_body import solve_poses  # imports kfusion.calibration

        poses = solve_poses(seen, np.asarray(markers.body_positions, dtype=float))
        position, quaternion = poses.position, poses.quaternion
        occluded = ~poses.solved
        marker_frames = MarkerFrames(t=mocap_t, names=markers.marker_names, position=seen)
    else:
        position, quaternion = measure_mocap(mocap_rng, mocap_object, frames.position,
                                             frames.quaternion, occluded)

    recording = Recording(
        imu=ImuSamples(t=imu_stamps, accelerometer=measured.accelerometer,
                       gyroscope=measured.gyroscope),
        mocap=MocapFrames(t=mocap_t, position=position, quaternion=quaternion),
        info=RecordingInfo(imu_to_body=q_body_imu, gravity=gravity,
                           name=f"{scenario} (simulated, seed {seed})", imu=imu_object.name,
                           lever_arm=arm,
                           markers=None if markers is None else dict(zip(
                               markers.marker_names, np.asarray(markers.body_positions),
                               strict=True))),
        markers=marker_frames,
    )
    truth = Truth(
        t=mocap_t, position=frames.position, occluded=occluded, quaternion=frames.quaternion,
        imu_t=imu_t, imu_position=imu_position, imu_velocity=imu_velocity,
        imu_acceleration=imu_acceleration, imu_quaternion=q_global_imu,
        imu_angular_rate=true_rate, imu_specific_force=true_force,
        accelerometer_bias=measured.accelerometer_errors.bias,
        gyroscope_bias=measured.gyroscope_errors.bias,
        accelerometer_matrix=measured.accelerometer_errors.matrix,
        gyroscope_matrix=measured.gyroscope_errors.matrix,
    )
    return Simulation(recording=recording, truth=truth, scenario=scenario, seed=int(seed),
                      imu_profile=imu_object, mocap_profile=mocap_object,
                      imu_clock=(float(imu_time_offset), float(imu_clock_drift_ppm)))
