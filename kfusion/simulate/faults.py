"""Fault injection: recordings that break one of kfusion's assumptions, for fail-safe tests and
``benchmarks/failsafe.py``.

Each function takes :class:`Streams` (a recording plus the time each sample *arrives*, on the
mocap clock) and returns new :class:`Streams`; the input is never modified. Stamps are what the
sensors write; arrival times are when a live system would receive each sample, so a stream can
carry a wrong stamp (a clock offset, milliseconds, a glitch far in the future) while still being
delivered in real time. Ground truth stays that of the original recording: faults never add,
remove or reorder mocap rows, so truth rows line up with the output rows.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from kfusion.conventions import matrix_from_wxyz, quaternion_about_axis, quaternion_multiply
from kfusion.recording import ImuSamples, MocapFrames, Recording, occlusion_runs

HALF_TURN_ABOUT_X = np.array([0.0, 1.0, 0.0, 0.0])
"""[w, x, y, z] of a 180 degree rotation about the body x axis."""


@dataclass(frozen=True)
class Streams:
    """A recording as a live system receives it.

    Attributes:
        recording: samples with the stamps the sensors wrote.
        imu_arrival: (n,) s on the mocap clock, when each IMU sample arrives.
        mocap_arrival: (m,) s, when each mocap frame arrives.
    """

    recording: Recording
    imu_arrival: NDArray[np.float64]
    mocap_arrival: NDArray[np.float64]

    @classmethod
    def of(cls, recording: Recording) -> Streams:
        """Streams that arrive exactly at their stamps (no fault)."""
        return cls(recording, np.array(recording.imu.t, dtype=float),
                   np.array(recording.mocap.t, dtype=float))

    def events(self) -> list[tuple[float, int, int]]:
        """``(arrival, stream, index)`` in arrival order; stream 0 = IMU, 1 = mocap (the IMU
        first at equal arrival times)."""
        events = [(float(t), 0, i) for i, t in enumerate(self.imu_arrival)]
        events += [(float(t), 1, i) for i, t in enumerate(self.mocap_arrival)]
        return sorted(events)


def _imu(streams: Streams, keep: NDArray[np.bool_] | None = None,
         t: NDArray[np.float64] | None = None, accelerometer: NDArray[np.float64] | None = None,
         gyroscope: NDArray[np.float64] | None = None) -> Streams:
    """``streams`` with the IMU samples where ``keep``, and the stamps or readings given."""
    imu = streams.recording.imu
    keep = np.ones(len(imu), dtype=bool) if keep is None else keep
    stamps = imu.t if t is None else t
    accelerometer = imu.accelerometer if accelerometer is None else accelerometer
    gyroscope = imu.gyroscope if gyroscope is None else gyroscope
    samples = ImuSamples(stamps[keep], accelerometer[keep], gyroscope[keep])
    return Streams(dataclasses.replace(streams.recording, imu=samples),
                   streams.imu_arrival[keep], streams.mocap_arrival)


def _mocap(streams: Streams, *, t: NDArray | None = None, position: NDArray | None = None,
           quaternion: NDArray | None = None) -> Streams:
    mocap = streams.recording.mocap
    frames = MocapFrames(mocap.t if t is None else t,
                         mocap.position if position is None else position,
                         mocap.quaternion if quaternion is None else quaternion)
    return Streams(streams.recording.with_mocap(frames), streams.imu_arrival,
                   streams.mocap_arrival)


def _info(streams: Streams, **changes: object) -> Streams:
    recording = streams.recording
    info = dataclasses.replace(recording.info, **changes)  # type: ignore[arg-type]
    return Streams(dataclasses.replace(recording, info=info), streams.imu_arrival,
                   streams.mocap_arrival)


def _fraction_time(streams: Streams, fraction: float) -> float:
    t = streams.recording.mocap.t
    return float(t[0] + fraction * (t[-1] - t[0]))


# ------------------------------------------------------------------------------ IMU stream


def imu_silent(streams: Streams) -> Streams:
    """The IMU delivers nothing."""
    return _imu(streams, np.zeros(len(streams.recording.imu), dtype=bool))


def imu_stops(streams: Streams, fraction: float = 0.4) -> Streams:
    """The IMU stops ``fraction`` of the way through the recording; the mocap goes on."""
    return _imu(streams, streams.imu_arrival < _fraction_time(streams, fraction))


def imu_misses_inside_gaps(streams: Streams, duration: float = 0.3) -> Streams:
    """The IMU misses ``duration`` s (centred) inside every mocap occlusion (all of a shorter
    occlusion)."""
    mocap_t = streams.recording.mocap.t
    drop = np.zeros(len(streams.recording.imu), dtype=bool)
    for start, stop in occlusion_runs(streams.recording.mocap.visible):
        first = mocap_t[start - 1] if start > 0 else mocap_t[0]
        last = mocap_t[stop] if stop < len(mocap_t) else mocap_t[-1]
        middle = 0.5 * (first + last)
        low, high = max(first, middle - duration / 2), min(last, middle + duration / 2)
        drop |= (streams.imu_arrival > low) & (streams.imu_arrival < high)
    return _imu(streams, ~drop)


def imu_rate_drops(streams: Streams, keep_every: int = 8, fraction: float = 0.5) -> Streams:
    """From ``fraction`` of the way through the recording, only every ``keep_every``-th IMU
    sample arrives (the stream's rate divided with no anti-aliasing filter: each kept sample
    keeps its own noise, which no longer averages over the interval it now spans)."""
    late = streams.imu_arrival >= _fraction_time(streams, fraction)
    index = np.cumsum(late) - 1  # 0, 1, 2, ... among the late samples
    return _imu(streams, ~late | (index % keep_every == 0))


def imu_clips(streams: Streams, accelerometer_range: float | None = None,
              gyroscope_range: float | None = None) -> Streams:
    """The IMU reports at most ``accelerometer_range`` (m/s^2) and ``gyroscope_range`` (rad/s)
    per axis (None: as recorded), below the range its profile declares: a chip left at its
    power-on full scale (the MPU-9250's +-2 g and +-250 dps) while the profile says 8 g and
    1000 dps. A clipped axis repeats its full-scale value, as the sensor does."""
    imu = streams.recording.imu
    accelerometer = imu.accelerometer if accelerometer_range is None else np.clip(
        imu.accelerometer, -accelerometer_range, accelerometer_range)
    gyroscope = imu.gyroscope if gyroscope_range is None else np.clip(
        imu.gyroscope, -gyroscope_range, gyroscope_range)
    return _imu(streams, accelerometer=accelerometer, gyroscope=gyroscope)


def imu_knocks(streams: Streams, every_s: float = 0.7, amplitude: float = 60.0,
               frequency: float = 90.0, duration_s: float = 0.04, seed: int = 0) -> Streams:
    """Knocks on the IMU (taps on its housing, or on the table under the arm) about every
    ``every_s`` s (0.5 to 1.5 times it, at a random phase of the sampling): the housing rings
    against the body, along a random direction, with the displacement::

        d(t) = D sin(2 pi f t) sin^2(pi t / T),   0 <= t <= T,   D = amplitude / (2 pi f)^2

    (f = ``frequency`` Hz, T = ``duration_s`` s; ``amplitude`` m/s^2 is about the peak of
    ``d''``), and the accelerometer reads ``d''(t)`` on top of the arm's motion. The housing
    ends where it started, at rest: the mocap and the truth are unchanged, and the ringing
    integrates to no velocity. What its samples integrate to is an error: at 100-300 Hz
    without an anti-aliasing filter they do not catch the ringing's shape. BROAD's tapping
    trial has knocks of this size (up to 150 m/s^2 from one sample to the next)."""
    imu = streams.recording.imu
    rng = np.random.default_rng(seed)
    t = np.asarray(imu.t, dtype=float)
    accelerometer = np.array(imu.accelerometer, dtype=float)
    omega = 2.0 * np.pi * frequency
    window = np.pi / duration_s
    size = amplitude / (omega * omega)
    start = float(t[0]) + rng.uniform(0.0, every_s)
    while start < t[-1]:
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        since = t - start
        inside = (since >= 0.0) & (since <= duration_s)
        u = since[inside]
        # d'' = D (s'' h + 2 s' h' + s h''), s = sin(omega u), h = sin^2(window u)
        s, ds, dds = np.sin(omega * u), omega * np.cos(omega * u), -omega ** 2 * np.sin(omega * u)
        h = np.sin(window * u) ** 2
        dh = window * np.sin(2.0 * window * u)
        ddh = 2.0 * window ** 2 * np.cos(2.0 * window * u)
        accelerometer[inside] += (size * (dds * h + 2.0 * ds * dh + s * ddh))[:, None] \
            * direction
        start += every_s * rng.uniform(0.5, 1.5)
    return _imu(streams, accelerometer=accelerometer)


def imu_mount_turns(streams: Streams, degrees: float = 3.0, fraction: float = 0.6,
                    seed: int = 0) -> Streams:
    """The IMU turns in its mount by ``degrees`` about a random axis (drawn with
    ``np.random.default_rng(seed)``) at the fraction ``fraction`` of the recording's mocap
    span, and stays turned (a strap slipping): from then on its samples are those of a sensor
    frame rotated by R, ``f' = R^T f`` and ``omega' = R^T omega``, while ``imu_to_body`` still
    says the old mount. A fault that switches on after the monitor has learned the recording."""
    imu = streams.recording.imu
    axis = np.random.default_rng(seed).standard_normal(3)
    rotation = matrix_from_wxyz(quaternion_about_axis(axis / np.linalg.norm(axis),
                                                      [np.radians(degrees)])[0])
    turned = np.asarray(imu.t) >= _fraction_time(streams, fraction)
    accelerometer = np.array(imu.accelerometer, dtype=float)
    gyroscope = np.array(imu.gyroscope, dtype=float)
    accelerometer[turned] = accelerometer[turned] @ rotation  # rows: (R^T f)^T = f^T R
    gyroscope[turned] = gyroscope[turned] @ rotation
    return _imu(streams, accelerometer=accelerometer, gyroscope=gyroscope)


def imu_clock_offset(streams: Streams, offset_s: float) -> Streams:
    """IMU stamps ``offset_s`` s off the mocap clock (``stamp = true time + offset_s``; negative:
    the IMU clock is behind); samples still arrive in real time."""
    return _imu(streams, t=streams.recording.imu.t + offset_s)


def imu_time_in_milliseconds(streams: Streams) -> Streams:
    """IMU stamps written in ms instead of s."""
    return _imu(streams, t=streams.recording.imu.t * 1000.0)


# ------------------------------------------------------------------------------ mocap stream


def mocap_future_stamp(streams: Streams, fraction: float = 0.4, ahead_s: float = 1000.0
                       ) -> Streams:
    """One visible mocap frame, ``fraction`` of the way through, stamped ``ahead_s`` s ahead
    (it still arrives on time)."""
    mocap = streams.recording.mocap
    index = _visible_index_after(mocap, _fraction_time(streams, fraction))
    t = np.array(mocap.t)
    t[index] += ahead_s
    return _mocap(streams, t=t)


def mocap_frame_stamped_ahead(streams: Streams, ahead_s: float = 0.15,
                              every_s: float | None = None, seed: int = 0) -> Streams:
    """Visible mocap frames stamped ``ahead_s`` s ahead of their true time (a frame counter
    or a host timestamp glitching by a few frames), below the Tracker's ``max_time_jump_s``
    so that the stamp is plausible. ``every_s`` None: one frame, the first visible frame
    after a time drawn uniformly in the middle 80 % of the recording; else one per
    ``every_s`` s window (a random visible frame in each, ``every_s`` > ``ahead_s``).
    Choices use ``np.random.default_rng(seed)``.

    Arrival order: every frame, the glitched one included, still arrives at its true time
    (the stamp is wrong, the delivery real time), so a live system receives the glitched
    frame between its true neighbours, then frames stamped before it. The frame's pose is
    that of its true time (the stale pose at the future stamp). The recording's mocap
    stamps are no longer increasing: written to a folder it is refused by the reader
    (``kfusion check``/``track`` name the row), as with :func:`mocap_future_stamp`."""
    if every_s is not None and not every_s > ahead_s:
        raise ValueError(f"every_s: expected more than ahead_s ({ahead_s}), got {every_s}")
    mocap = streams.recording.mocap
    rng = np.random.default_rng(seed)
    t = np.array(mocap.t)
    start, end = float(t[0]), float(t[-1])
    if every_s is None:
        draws = [start + (0.1 + 0.8 * rng.random()) * (end - start)]
    else:
        edges = np.arange(start, end - ahead_s, every_s)
        draws = [float(edge + rng.random() * (every_s - ahead_s)) for edge in edges]
    for draw in draws:
        index = _visible_index_after(mocap, draw)
        t[index] = mocap.t[index] + ahead_s
    return _mocap(streams, t=t)


def mocap_orientation_drift(streams: Streams, degrees: float = 5.0, seed: int = 0
                            ) -> Streams:
    """The rigid body's orientation biased by a rotation about a fixed random axis (drawn with
    ``np.random.default_rng(seed)``, in the body frame) that grows linearly from 0 at the first
    frame to ``degrees`` at the last (markers creeping on a soft strap, a rigid-body definition
    slowly re-fitted): ``q' = q ⊗ Exp(theta(t) axis)``. Positions unchanged; a drift, not a
    jump, so no single frame disagrees with the gyroscope."""
    mocap = streams.recording.mocap
    axis = np.random.default_rng(seed).standard_normal(3)
    t = np.asarray(mocap.t, dtype=float)
    span = max(float(t[-1] - t[0]), 1e-9)
    bias = quaternion_about_axis(axis / np.linalg.norm(axis),
                                 np.radians(degrees) * (t - t[0]) / span)
    return _mocap(streams, quaternion=quaternion_multiply(mocap.quaternion, bias))


def orientation_flip_before_gaps(streams: Streams) -> Streams:
    """The last visible frame before each occlusion reports its orientation turned 180 degrees
    about the body x axis."""
    mocap = streams.recording.mocap
    quaternion = np.array(mocap.quaternion)
    for start, _ in occlusion_runs(mocap.visible):
        if start > 0:
            quaternion[start - 1] = quaternion_multiply(quaternion[start - 1], HALF_TURN_ABOUT_X)
    return _mocap(streams, quaternion=quaternion)


def marker_swap(streams: Streams, fraction: float = 0.5, duration_s: float = 1.0,
                offset: tuple[float, float, float] = (0.2, 0.0, 0.0)) -> Streams:
    """For ``duration_s`` s from ``fraction`` of the way through, the rigid body is solved on
    swapped markers: every visible frame is displaced by ``offset`` (m, global) and turned 180
    degrees about the body x axis."""
    mocap = streams.recording.mocap
    start = _fraction_time(streams, fraction)
    inside = (mocap.t >= start) & (mocap.t < start + duration_s) & mocap.visible
    position = np.array(mocap.position)
    quaternion = np.array(mocap.quaternion)
    position[inside] += np.asarray(offset)
    quaternion[inside] = quaternion_multiply(quaternion[inside], HALF_TURN_ABOUT_X)
    return _mocap(streams, position=position, quaternion=quaternion)


def sub_gate_glitches(streams: Streams, size_m: float = 0.004, frames: int = 10,
                      rate: float = 0.005, seed: int = 0) -> Streams:
    """A marker of the cluster dropping out for a while: from ``rate`` of the frames (chosen
    with ``np.random.default_rng(seed)``), the rigid body is solved ``size_m`` m off in a
    random direction for ``frames`` frames (the visible ones among them), below the gate's
    floor (``gate_min_innovation``, 10 mm); orientation unchanged. A glitch may begin inside
    an occlusion."""
    mocap = streams.recording.mocap
    rng = np.random.default_rng(seed)
    count = max(1, round(rate * len(mocap)))
    starts = np.sort(rng.choice(len(mocap), size=min(count, len(mocap)), replace=False))
    position = np.array(mocap.position)
    for start in starts.tolist():
        direction = rng.standard_normal(3)
        position[start:start + frames] += size_m * direction / np.linalg.norm(direction)
    return _mocap(streams, position=position)


def mocap_holds_last_pose(streams: Streams) -> Streams:
    """Every occluded frame repeats the last visible frame's pose (a streaming client that
    holds the last value, NatNet's untracked rigid body read without its valid flag, NaN
    filled forward): no frame is NaN."""
    mocap = streams.recording.mocap
    position, quaternion = np.array(mocap.position), np.array(mocap.quaternion)
    for row in range(1, len(position)):
        if not mocap.visible[row]:
            position[row], quaternion[row] = position[row - 1], quaternion[row - 1]
    return _mocap(streams, position=position, quaternion=quaternion)


def occlusion_edge_offsets(streams: Streams, size_m: float = 0.0015, frames: int = 3,
                           side: str = "before", seed: int = 0) -> Streams:
    """The rigid body solved ``size_m`` m off (a random direction per occlusion, drawn with
    ``np.random.default_rng(seed)``) on the ``frames`` frames just before each occlusion
    (``side`` "before": a marker's blob partly hidden pulls its centroid as the body is lost)
    or just after it ("after": the body re-solved on part of its cluster as it re-appears).
    Orientation unchanged. On BROAD's 79 real occlusions the 3 frames on either side deviate
    from a cubic through the frames 4-15 away 1.3-2.3 times as much as other frames (median
    0.33-0.48 against 0.25 mm, 90th percentile 1.35-1.96 against 0.86 mm;
    ``benchmarks/occlusion_edges.py``; part of it may be that occlusions come in faster
    motion, where the cubic extrapolates worse)."""
    return _edge_shift(streams, size_m, np.ones(frames), side, seed)


def occlusion_edge_drift(streams: Streams, size_m: float = 0.0015, frames: int = 5,
                         seed: int = 0) -> Streams:
    """The rigid body drifting linearly to ``size_m`` m off (a random direction per occlusion)
    over the ``frames`` frames before each occlusion: frame i of them (i = 1 .. frames) is
    ``i / frames`` of the way (a blob shrinking as its marker disappears)."""
    return _edge_shift(streams, size_m, np.arange(1, frames + 1) / frames, "before", seed)


def _edge_shift(streams: Streams, size_m: float, profile: NDArray[np.float64], side: str,
                seed: int) -> Streams:
    """Shift the ``len(profile)`` frames before (``side`` "before") or after ("after") each
    occlusion by ``profile * size_m`` along a random unit direction per occlusion."""
    if side not in ("before", "after"):
        raise ValueError(f"side: expected 'before' or 'after', got {side!r}")
    mocap = streams.recording.mocap
    rng = np.random.default_rng(seed)
    position = np.array(mocap.position)
    frames = len(profile)
    for start, stop in occlusion_runs(mocap.visible):
        direction = rng.standard_normal(3)
        shift = size_m * profile[:, None] * (direction / np.linalg.norm(direction))
        if side == "before" and start >= frames:
            position[start - frames:start] += shift
        elif side == "after" and stop + frames <= len(position):
            position[stop:stop + frames] += shift
    return _mocap(streams, position=position)


def quaternion_columns_xyzw(streams: Streams) -> Streams:
    """Mocap quaternions written ``x, y, z, w`` instead of ``w, x, y, z``."""
    quaternion = streams.recording.mocap.quaternion
    return _mocap(streams, quaternion=np.roll(quaternion, -1, axis=1))


# ------------------------------------------------------------------------------ metadata


def gravity_sign_flipped(streams: Streams) -> Streams:
    """``recording.yaml``'s gravity with the wrong sign."""
    return _info(streams, gravity=-np.asarray(streams.recording.info.gravity))


def mount_identity(streams: Streams) -> Streams:
    """``imu_to_body`` given as the identity instead of the real mount."""
    return _info(streams, imu_to_body=np.array([1.0, 0.0, 0.0, 0.0]))


def _visible_index_after(mocap: MocapFrames, t: float) -> int:
    candidates = np.flatnonzero(mocap.visible & (mocap.t >= t))
    if not len(candidates):
        raise ValueError(f"no visible mocap frame after t = {t:.3f} s")
    return int(candidates[0])
