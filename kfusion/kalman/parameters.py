"""Tunable parameters of the Kalman tracker: one frozen, validated object built from profiles.

Every noise figure comes from :mod:`kfusion.profiles` (the same numbers the simulator draws its
errors from), so nothing needs tuning for a profiled sensor. Units are SI throughout.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

from kfusion.conventions import MAX_BRIDGE_LIMIT_S
from kfusion.guards import real_number, short_repr
from kfusion.profiles import (
    OPTITRACK,
    ImuProfile,
    MocapProfile,
    imu_profile,
    mocap_profile,
)

DEFAULT_IMU_PROFILE: Final = "mpu9255"
"""IMU profile used when neither the caller nor ``recording.yaml`` names one (the paper's IMU)."""
DEFAULT_MOCAP_PROFILE: Final = OPTITRACK.name
"""Mocap profile used when the caller names none."""
MAX_LATENCY_S: Final = 1.0
"""s: the largest ``|imu_latency_s|``: a lag longer than a second is a clock offset
(recording.yaml's ``imu_time_offset``); 1e300 left every sample too late with a 900-character
message."""
MIN_POSITION_NOISE: Final = 1e-6
"""m: the smallest mocap and marker position noise (a micrometre): below it the innovation
covariance underflows (1e-300 stopped ``kfusion track`` with "Eigenvalues did not converge")."""
MAX_MAGNITUDE: Final = 1e6
"""The largest value (SI units) of a noise density, standard deviation, scale error, time or
factor among the parameters (all but the ranges, and ``max_bridge_s`` and ``imu_latency_s``,
which have their own limits): far beyond any sensor, and small enough that its square and the
covariances built on it stay finite (from about 1.4e154 Python's ``x ** 2`` raised
OverflowError out of ``kfusion track``)."""


@dataclass(frozen=True)
class KalmanParameters:
    """Noise model and behaviour of :class:`kfusion.kalman.KalmanFusion`.

    Attributes (SI units):
        accelerometer_noise_density: white-noise density sigma_a, m/s^2/sqrt(Hz), > 0.
        accelerometer_bias_random_walk: bias random-walk density sigma_b, m/s^3/sqrt(Hz), > 0.
        gyroscope_noise_density: white-noise density, rad/s/sqrt(Hz), >= 0.
        gyroscope_bias_random_walk: bias random-walk density, rad/s^2/sqrt(Hz), >= 0.
        mocap_position_noise: 1-sigma per axis of a mocap position, m, at least 1e-6.
        mocap_orientation_noise: 1-sigma per axis of a mocap orientation, rad, >= 0.
        initial_bias_std: 1-sigma of the accelerometer bias before any fix, m/s^2, >= 0
            (the profile's turn-on bias).
        initial_gyroscope_bias_std: 1-sigma of the gyroscope bias before any fix, rad/s, >= 0
            (the profile's turn-on bias).
        initial_velocity_std: 1-sigma of the velocity at the first fix, m/s, > 0.
        accelerometer_scale_error: 1-sigma of the accelerometer's scale and cross-axis error,
            combined per entry as ``sqrt(scale^2 + cross_axis^2)`` (fraction), >= 0. The error
            ``S f`` it causes is carried by the bias state as a random walk driven by the
            change of f (:func:`kfusion.kalman.model.scale_error_variance`).
        gyroscope_scale_error: the same for the gyroscope; it adds orientation error of
            variance up to ``scale_error^2 |rotation since the fix|^2``.
        lever_arm_std: 1-sigma per axis, m, >= 0, of the lever arm when the recording does not
            give one: the filter then estimates it (12 states). 0 ignores an unknown lever arm
            (9 states, the IMU point taken as the rigid-body point).
        imu_latency_s: how late the IMU timestamps are against the mocap clock, s (a sample
            stamped t describes the motion at ``t - imu_latency_s``), on top of the
            recording's clock model. Finite; default 0: a recording's clock offset belongs in
            ``recording.yaml`` (``imu_time_offset``, which ``kfusion calibrate`` measures and
            the BROAD reader sets), so that it is applied once.
        accelerometer_range: full scale, m/s^2, > 0 (``math.inf``: never saturates). A sample
            with an axis at 99.9 % of it or beyond is flagged as saturated and its noise inflated.
        gyroscope_range: full scale, rad/s, > 0, used the same way for the orientation.
        gate_probability: probability mass of the chi-square (3 dof) gate on the mocap position
            innovation, in (0, 1]; ``None`` or 1.0 disables gating. 0.9999 rejects a consistent
            fix once in 10 000 frames.
        gate_min_innovation: a fix whose innovation (distance between the fix and the
            prediction) is at most this (m, >= 0) is never gated. A marker swap or a jump moves
            the rigid body by centimetres; the floor keeps a filter that is briefly
            over-confident (an impact the IMU could not sample) from rejecting good fixes and
            drifting away from them.
        reacquire_after_s: a fix arriving this long (s) or longer after the last accepted fix is
            accepted without gating (re-acquisition); if its innovation would have failed the
            gate, the position covariance is first inflated so that the fix re-initialises it.
            >= 0.
        max_bridge_s: longest time (s) after the last accepted fix for which the output is
            ``bridged``; later it is ``lost``. > 0 and at most
            :data:`kfusion.conventions.MAX_BRIDGE_LIMIT_S` (60 s).
        imu_dropout_s: an interval between IMU samples longer than this (s) is counted as a
            dropout (the prediction still runs over the real interval). > 0.
        tilt_error_inflation: scale (>= 0) of the process noise that accounts for the
            orientation error growing through a gap (see :func:`kfusion.kalman.model.
            orientation_leak_variance`); 0 switches it off, 1 is the derived value.
        marker_position_noise: 1-sigma per axis of one marker's position, m, > 0 (marker-level
            fusion, :meth:`kfusion.kalman.KalmanFusion.update_markers`). A rigid body solved
            from k markers has about ``marker_position_noise / sqrt(k)``.
        timestamp_jitter: 1-sigma random error of each IMU timestamp, s, >= 0. It adds
            acceleration noise wherever the acceleration changes
            (:func:`kfusion.kalman.model.stamp_jitter_variance`). The batch runs measure it from
            the recording's own IMU intervals (:func:`kfusion.kalman.model.timestamp_jitter`)
            unless the caller gives it; 0 for a clock that stamps on the sample instant.
        impact_jerk: m/s^3, > 0 (``math.inf``: never). An IMU interval whose specific force
            changes faster than this (``|f1 - f0| / dt``) is an impact: a tap or a knock, which
            the samples cannot resolve. The filter keeps the time of the last one
            (:attr:`kfusion.kalman.KalmanFusion.last_impact_t`); the consistency monitor
            learns its scales for gaps near impacts apart from the others
            (:class:`kfusion.monitor.MonitorParameters`, ``impact_memory_s``). 1000 m/s^3
            (about 100 g/s) is above the voluntary arm motion of BROAD's undisturbed trials
            (their 99.9th percentile is 270-1160 m/s^3, the simulated scenarios' largest 160)
            and below its tapping trial's knocks (1.7 % of its samples, up to 80 000 m/s^3).
    """

    accelerometer_noise_density: float
    accelerometer_bias_random_walk: float
    gyroscope_noise_density: float
    gyroscope_bias_random_walk: float
    mocap_position_noise: float
    mocap_orientation_noise: float
    initial_bias_std: float
    initial_gyroscope_bias_std: float
    initial_velocity_std: float = 1.0
    accelerometer_scale_error: float = 0.0
    gyroscope_scale_error: float = 0.0
    lever_arm_std: float = 0.02
    imu_latency_s: float = 0.0
    accelerometer_range: float = math.inf
    gyroscope_range: float = math.inf
    gate_probability: float | None = 0.9999
    gate_min_innovation: float = 0.01
    reacquire_after_s: float = 0.5
    max_bridge_s: float = 1.0
    imu_dropout_s: float = 0.1
    tilt_error_inflation: float = 1.0
    marker_position_noise: float = 0.5e-3
    timestamp_jitter: float = 0.0
    impact_jerk: float = 1000.0

    def __post_init__(self) -> None:
        non_negative = (
            "gyroscope_noise_density", "gyroscope_bias_random_walk", "mocap_orientation_noise",
            "initial_bias_std", "initial_gyroscope_bias_std", "reacquire_after_s",
            "tilt_error_inflation", "accelerometer_scale_error", "gyroscope_scale_error",
            "lever_arm_std", "gate_min_innovation", "timestamp_jitter",
        )
        # The accelerometer's densities are the only process noise of the position, velocity
        # and bias states: zero claims a noiseless accelerometer, the covariance collapses (with
        # every other term zero too: errors 10-150x the 99 % bound on a simulated recording) and
        # the smoother's predicted covariance becomes singular. The gyroscope's may be zero (a
        # noise-free gyroscope, as in model-matched simulations): the orientation covariance is
        # never inverted.
        positive = ("accelerometer_noise_density", "accelerometer_bias_random_walk",
                    "mocap_position_noise", "initial_velocity_std", "accelerometer_range",
                    "gyroscope_range", "max_bridge_s", "imu_dropout_s", "marker_position_noise",
                    "impact_jerk")
        for name in non_negative + positive + ("imu_latency_s",):
            value = getattr(self, name)
            number = real_number(value)
            if number is None:
                raise ValueError(f"KalmanParameters.{name}: expected a number, "
                                 f"got {short_repr(value)}")
            infinite_allowed = name.endswith("_range") or name == "impact_jerk"
            if math.isnan(number) or (math.isinf(number) and not infinite_allowed):
                raise ValueError(f"KalmanParameters.{name}: expected a finite number, "
                                 f"got {short_repr(value)}")
            if name in positive and not number > 0:
                raise ValueError(f"KalmanParameters.{name}: expected a number > 0, "
                                 f"got {short_repr(value)}")
            if name in non_negative and not number >= 0:
                raise ValueError(f"KalmanParameters.{name}: expected a number >= 0, "
                                 f"got {short_repr(value)}")
            own_limit = name in ("max_bridge_s", "imu_latency_s")  # (checked below)
            if not (infinite_allowed or own_limit) and abs(number) > MAX_MAGNITUDE:
                raise ValueError(f"KalmanParameters.{name}: expected at most {MAX_MAGNITUDE:g} "
                                 f"(SI units), got {short_repr(value)}")
            object.__setattr__(self, name, number)
        if abs(self.imu_latency_s) > MAX_LATENCY_S:
            raise ValueError(f"KalmanParameters.imu_latency_s: expected at most {MAX_LATENCY_S:g} "
                             f"s either way (a longer lag is a clock offset: imu_time_offset in "
                             f"recording.yaml), got {short_repr(self.imu_latency_s)}")
        for name in ("mocap_position_noise", "marker_position_noise"):
            if getattr(self, name) < MIN_POSITION_NOISE:
                raise ValueError(f"KalmanParameters.{name}: expected at least "
                                 f"{MIN_POSITION_NOISE:g} m (a micrometre), got "
                                 f"{short_repr(getattr(self, name))}")
        if self.max_bridge_s > MAX_BRIDGE_LIMIT_S:
            raise ValueError(f"KalmanParameters.max_bridge_s: expected at most "
                             f"{MAX_BRIDGE_LIMIT_S:g} s, got {short_repr(self.max_bridge_s)}")
        gate = self.gate_probability
        if gate is not None:
            number = real_number(gate)
            if number is None or not 0 < number <= 1:
                raise ValueError("KalmanParameters.gate_probability: expected None or a "
                                 f"probability in (0, 1], got {short_repr(gate)}")
            object.__setattr__(self, "gate_probability", number)

    @property
    def gating(self) -> bool:
        """True when mocap fixes are gated (``gate_probability`` set and below 1)."""
        return self.gate_probability is not None and self.gate_probability < 1.0

    @classmethod
    def from_profiles(
        cls,
        imu: ImuProfile | str | None = None,
        mocap: MocapProfile | str | None = None,
        **overrides: Any,
    ) -> KalmanParameters:
        """Parameters from an IMU and a mocap profile (objects or names), then ``overrides``.

        ``imu`` None means :data:`DEFAULT_IMU_PROFILE`, ``mocap`` None
        :data:`DEFAULT_MOCAP_PROFILE`. ``overrides`` are field names; an unknown one is a
        ValueError listing the fields.
        """
        imu_object = imu_profile(imu or DEFAULT_IMU_PROFILE) if not isinstance(
            imu, ImuProfile) else imu
        mocap_object = mocap_profile(mocap or DEFAULT_MOCAP_PROFILE) if not isinstance(
            mocap, MocapProfile) else mocap
        _check_keys(overrides, "override")
        values: dict[str, Any] = {
            "accelerometer_noise_density": imu_object.accelerometer_noise_density,
            "accelerometer_bias_random_walk": imu_object.accelerometer_bias_random_walk,
            "gyroscope_noise_density": imu_object.gyroscope_noise_density,
            "gyroscope_bias_random_walk": imu_object.gyroscope_bias_random_walk,
            "mocap_position_noise": mocap_object.position_noise,
            "mocap_orientation_noise": mocap_object.orientation_noise,
            "initial_bias_std": imu_object.accelerometer_turn_on_bias,
            "initial_gyroscope_bias_std": imu_object.gyroscope_turn_on_bias,
            "accelerometer_range": imu_object.accelerometer_range,
            "gyroscope_range": imu_object.gyroscope_range,
            "accelerometer_scale_error": math.hypot(imu_object.accelerometer_scale_error,
                                                    imu_object.accelerometer_cross_axis),
            "gyroscope_scale_error": math.hypot(imu_object.gyroscope_scale_error,
                                                imu_object.gyroscope_cross_axis),
        }
        values.update(overrides)
        return cls(**values)

    @classmethod
    def from_mapping(cls, mapping: Mapping[str, Any]) -> KalmanParameters:
        """Parameters from a plain mapping (e.g. loaded from YAML).

        Optional keys ``imu`` and ``mocap`` name the base profiles; every other key must be a
        field name and overrides the profile value. Unknown keys are a ValueError.
        """
        if not isinstance(mapping, Mapping):
            raise ValueError(f"KalmanParameters: expected a mapping, got {type(mapping).__name__}")
        values = dict(mapping)
        imu = values.pop("imu", None)
        mocap = values.pop("mocap", None)
        _check_keys(values, "key")
        return cls.from_profiles(imu, mocap, **values)

    def to_mapping(self) -> dict[str, Any]:
        """Plain mapping of every field (round-trips through :meth:`from_mapping`)."""
        return dataclasses.asdict(self)


FIELD_NAMES: Final = tuple(f.name for f in dataclasses.fields(KalmanParameters))


def _check_keys(values: Mapping[str, Any], what: str) -> None:
    unknown = sorted(set(map(str, values)) - set(FIELD_NAMES))
    if unknown:
        raise ValueError(f"KalmanParameters: unknown {what} {short_repr(unknown[0])}; expected "
                         f"one of {list(FIELD_NAMES)}")
