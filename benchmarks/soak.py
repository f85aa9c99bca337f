"""Soak benchmark of the online Tracker (issue 6 §5): a simulated hour at 1 kHz IMU, 100 Hz mocap.

The stream is generated on the fly in chunks (10 s each), so the benchmark itself holds only one
chunk in memory, and fed to one :class:`kfusion.Tracker` in time order:

* motion: a smooth, endless synthetic forearm motion, not one of ``kfusion.simulate``'s finite
  scenarios. Position: three sinusoids per axis (0.07-0.55 Hz, 0.04-0.15 m), peak acceleration
  ~1.5 m/s^2. Orientation: yaw-pitch-roll angles, each two sinusoids (0.05-0.4 Hz, up to 0.6
  rad), peak rate ~2 rad/s. Every derivative is exact (analytic);
* IMU: mounted 90 degrees about the forearm (``kfusion.simulate``'s nominal mount), MPU9255
  error model from :mod:`kfusion.simulate.imu` (scale and cross-axis matrix, turn-on bias, bias
  random walk carried across chunks, white noise, clipping, quantisation);
* mocap: OptiTrack noise from :mod:`kfusion.simulate.mocap`; occlusions as a renewal process:
  visible runs of 1-4 s, gaps of 0.1-0.5 s, and every 5 minutes one 1.5 s gap (past the
  1.0 s bridging horizon: lost, then re-acquired).

Reported per block (default 6 blocks of 10 minutes): RMS and max error of the estimate while
tracked (against the true position; mocap noise level is 0.3 mm per axis) and while bridged,
the fraction of bridged samples inside the 99 % bound, the mean 99 % bound, and memory: the
tracker's pickled snapshot size, the event log and checkpoint counts, and the process RSS. With
``--tracemalloc`` the traced current/peak memory is reported too (slower).

``--no-scale-errors`` is a labelled control run: the same stream without the MPU9255's
scale-factor and cross-axis errors, which the Kalman filter's noise model does not include.

Run: ``python benchmarks/soak.py [--minutes 60] [--blocks 6] [--seed 0] [--tracemalloc]
[--no-scale-errors]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import pickle
import sys
import time
import tracemalloc
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from kfusion.conventions import OPTITRACK_GRAVITY, matrix_from_wxyz
from kfusion.profiles import MPU9255, OPTITRACK, ImuProfile
from kfusion.simulate.imu import error_matrix, measure, white_noise_std
from kfusion.simulate.mocap import measure_mocap
from kfusion.simulate.simulation import NOMINAL_MOUNT
from kfusion.tracker import Tracker

Array = NDArray[np.float64]
IMU_RATE = 1000
MOCAP_EVERY = 10  # one mocap frame every 10 IMU samples: 100 Hz
CHUNK_SECONDS = 10


def _rotation_x(angle: Array) -> Array:
    c, s = np.cos(angle), np.sin(angle)
    zero, one = np.zeros_like(angle), np.ones_like(angle)
    return np.stack([one, zero, zero, zero, c, -s, zero, s, c], axis=-1).reshape(-1, 3, 3)


def _rotation_y(angle: Array) -> Array:
    c, s = np.cos(angle), np.sin(angle)
    zero, one = np.zeros_like(angle), np.ones_like(angle)
    return np.stack([c, zero, s, zero, one, zero, -s, zero, c], axis=-1).reshape(-1, 3, 3)


def _rotation_z(angle: Array) -> Array:
    c, s = np.cos(angle), np.sin(angle)
    zero, one = np.zeros_like(angle), np.ones_like(angle)
    return np.stack([c, -s, zero, s, c, zero, zero, zero, one], axis=-1).reshape(-1, 3, 3)


def _quaternion_from_matrix(R: Array) -> Array:
    """[w, x, y, z] (n, 4) of rotation matrices (n, 3, 3), w >= 0 (Shepperd's method)."""
    from scipy.spatial.transform import Rotation

    from kfusion.conventions import wxyz_from_rotation

    return wxyz_from_rotation(Rotation.from_matrix(R))


@dataclass
class Motion:
    """Sum-of-sinusoids position (m) and yaw-pitch-roll orientation (rad), exact derivatives."""

    centre: Array
    amplitude: Array  # (3 axes, 3 terms), m
    frequency: Array  # Hz
    phase: Array
    angle_amplitude: Array  # (3 angles, 2 terms), rad
    angle_frequency: Array
    angle_phase: Array

    @classmethod
    def draw(cls, rng: np.random.Generator) -> Motion:
        return cls(
            centre=np.array([0.3, 1.1, 0.2]),
            amplitude=rng.uniform(0.04, 0.15, (3, 3)),
            frequency=rng.uniform(0.07, 0.55, (3, 3)),
            phase=rng.uniform(0, 2 * np.pi, (3, 3)),
            angle_amplitude=rng.uniform(0.1, 0.3, (3, 2)),
            angle_frequency=rng.uniform(0.05, 0.4, (3, 2)),
            angle_phase=rng.uniform(0, 2 * np.pi, (3, 2)),
        )

    @staticmethod
    def _sines(t: Array, amplitude: Array, frequency: Array, phase: Array
               ) -> tuple[Array, Array, Array]:
        """Value, first and second derivative of sum_k A_k sin(2 pi f_k t + phi_k), (n, rows)."""
        w = 2 * np.pi * frequency  # (rows, terms)
        argument = w[None] * t[:, None, None] + phase[None]
        value = (amplitude[None] * np.sin(argument)).sum(-1)
        first = (amplitude[None] * w[None] * np.cos(argument)).sum(-1)
        second = -(amplitude[None] * w[None] ** 2 * np.sin(argument)).sum(-1)
        return value, first, second

    def position(self, t: Array) -> tuple[Array, Array, Array]:
        """Position (n, 3) m, velocity m/s, acceleration m/s^2, global frame."""
        value, first, second = self._sines(t, self.amplitude, self.frequency, self.phase)
        return self.centre + value, first, second

    def orientation(self, t: Array) -> tuple[Array, Array]:
        """R_global_body (n, 3, 3) = Rz(yaw) Ry(pitch) Rx(roll), and the body-frame rate (n, 3):

            omega_body = Rx^T Ry^T [0, 0, yaw'] + Rx^T [0, pitch', 0] + [roll', 0, 0]
        """
        angles, rates, _ = self._sines(t, self.angle_amplitude, self.angle_frequency,
                                       self.angle_phase)
        yaw, pitch, roll = angles.T
        Rx, Ry, Rz = _rotation_x(roll), _rotation_y(pitch), _rotation_z(yaw)
        R = Rz @ Ry @ Rx
        zeros = np.zeros_like(yaw)
        yaw_rate = np.stack([zeros, zeros, rates[:, 0]], axis=1)
        pitch_rate = np.stack([zeros, rates[:, 1], zeros], axis=1)
        roll_rate = np.stack([rates[:, 2], zeros, zeros], axis=1)
        RxT = np.transpose(Rx, (0, 2, 1))
        RyT = np.transpose(Ry, (0, 2, 1))
        omega = (np.einsum("nij,njk,nk->ni", RxT, RyT, yaw_rate)
                 + np.einsum("nij,nj->ni", RxT, pitch_rate) + roll_rate)
        return R, omega


@dataclass
class Chunk:
    """One chunk of the stream: IMU samples and mocap frames, with the truth at mocap times."""

    imu_t: Array
    accelerometer: Array
    gyroscope: Array
    mocap_t: Array
    position: Array
    quaternion: Array
    truth: Array


@dataclass
class SoakStream:
    """An endless stream generated chunk by chunk (see the module docstring).

    Attributes:
        seed: random seed.
        profile: IMU error model.
        long_gap_every_s: s between the 1.5 s gaps (past the bridging horizon).
    """

    seed: int = 0
    profile: ImuProfile = MPU9255
    long_gap_every_s: float = 300.0
    imu_to_body: Array = field(default_factory=lambda: NOMINAL_MOUNT.copy())
    gravity: Array = field(default_factory=lambda: np.array(OPTITRACK_GRAVITY))

    def __post_init__(self) -> None:
        rng = np.random.default_rng(self.seed)
        self._motion_rng, self._imu_rng, self._mocap_rng, self._gap_rng = rng.spawn(4)
        self.motion = Motion.draw(self._motion_rng)
        p = self.profile
        self._accelerometer_matrix = error_matrix(self._imu_rng.standard_normal(3),
                                                  self._imu_rng.standard_normal(6),
                                                  p.accelerometer_scale_error,
                                                  p.accelerometer_cross_axis)
        self._gyroscope_matrix = error_matrix(self._imu_rng.standard_normal(3),
                                              self._imu_rng.standard_normal(6),
                                              p.gyroscope_scale_error, p.gyroscope_cross_axis)
        self._accelerometer_bias = p.accelerometer_turn_on_bias * self._imu_rng.standard_normal(3)
        self._gyroscope_bias = p.gyroscope_turn_on_bias * self._imu_rng.standard_normal(3)
        self._R_body_imu = matrix_from_wxyz(self.imu_to_body)
        self._next_gap = float(self._gap_rng.uniform(1.0, 4.0))
        self._gaps: list[tuple[float, float]] = []
        self._next_long_gap = self.long_gap_every_s

    def _walk(self, start: Array, density: float, n: int) -> Array:
        """Bias random walk over n samples continuing from ``start`` (3,)."""
        dt = 1.0 / IMU_RATE
        steps = density * math.sqrt(dt) * self._imu_rng.standard_normal((n, 3))
        return start + np.cumsum(steps, axis=0)

    def _occluded(self, t: Array) -> NDArray[np.bool_]:
        """Gaps as a renewal process over the mocap times ``t`` (increasing, one chunk); a gap
        that straddles the chunk's end is kept for the next chunk."""
        end = t[-1]
        while self._next_gap <= end:
            start = self._next_gap
            if start >= self._next_long_gap:
                length = 1.5
                self._next_long_gap += self.long_gap_every_s
            else:
                length = float(self._gap_rng.uniform(0.1, 0.5))
            self._gaps.append((start, start + length))
            self._next_gap = start + length + float(self._gap_rng.uniform(1.0, 4.0))
        hidden = np.zeros(len(t), dtype=bool)
        for start, stop in self._gaps:
            hidden |= (t > start) & (t < stop)
        self._gaps = [gap for gap in self._gaps if gap[1] > end]
        return hidden

    def chunks(self, seconds: float) -> Iterator[Chunk]:
        """Chunks of ``CHUNK_SECONDS`` covering [0, seconds)."""
        p = self.profile
        dt = 1.0 / IMU_RATE
        samples = CHUNK_SECONDS * IMU_RATE
        total = round(seconds * IMU_RATE)
        for first in range(0, total, samples):
            k = np.arange(first, min(first + samples, total))
            t = k / IMU_RATE
            _, _, acceleration = self.motion.position(t)
            R_global_body, omega_body = self.motion.orientation(t)
            R_global_imu = R_global_body @ self._R_body_imu
            force = np.einsum("nji,nj->ni", R_global_imu, acceleration - self.gravity)
            rate = omega_body @ self._R_body_imu  # R_imu_body omega_body, row-wise
            accelerometer_bias = self._walk(self._accelerometer_bias,
                                            p.accelerometer_bias_random_walk, len(t))
            gyroscope_bias = self._walk(self._gyroscope_bias, p.gyroscope_bias_random_walk,
                                        len(t))
            self._accelerometer_bias = accelerometer_bias[-1]
            self._gyroscope_bias = gyroscope_bias[-1]
            accelerometer = measure(
                force, self._accelerometer_matrix, accelerometer_bias,
                white_noise_std(p.accelerometer_noise_density, dt)
                * self._imu_rng.standard_normal((len(t), 3)),
                p.accelerometer_range, p.accelerometer_resolution)
            gyroscope = measure(
                rate, self._gyroscope_matrix, gyroscope_bias,
                white_noise_std(p.gyroscope_noise_density, dt)
                * self._imu_rng.standard_normal((len(t), 3)),
                p.gyroscope_range, p.gyroscope_resolution)
            on_frame = k % MOCAP_EVERY == 0
            mocap_t = t[on_frame]
            truth = self.motion.position(mocap_t)[0]
            occluded = self._occluded(mocap_t)
            quaternion = _quaternion_from_matrix(R_global_body[on_frame])
            position, quaternion = measure_mocap(self._mocap_rng, OPTITRACK, truth, quaternion,
                                                 occluded)
            yield Chunk(t, accelerometer, gyroscope, mocap_t, position, quaternion, truth)

    def tracker(self, **kwargs: object) -> Tracker:
        """A Kalman tracker for this stream's mounting and IMU."""
        return Tracker(self.imu_to_body, self.gravity, imu=self.profile, **kwargs)  # type: ignore[arg-type]


@dataclass
class Running:
    """Count, sum of squares and maximum of a stream of errors (m), in constant memory."""

    count: int = 0
    squares: float = 0.0
    largest: float = 0.0

    def add(self, value: float) -> None:
        self.count += 1
        self.squares += value * value
        self.largest = max(self.largest, value)

    def rms_mm(self) -> str:
        return f"{1000 * math.sqrt(self.squares / self.count):.3f}" if self.count else "-"

    def max_mm(self, digits: int) -> str:
        return f"{1000 * self.largest:.{digits}f}" if self.count else "-"


@dataclass
class BlockStats:
    """Errors and resources over one block of the soak (constant memory per block)."""

    start_s: float
    end_s: float
    tracked: Running = field(default_factory=Running)
    bridged: Running = field(default_factory=Running)
    bridged_inside: int = 0
    bound_sum: float = 0.0
    bound_count: int = 0
    lost: int = 0
    seconds: float = 0.0
    snapshot_bytes: int = 0
    log_events: int = 0
    checkpoints: int = 0
    rss_kb: int = 0
    traced_kb: tuple[float, float] | None = None

    def row(self) -> str:
        inside = self.bridged_inside / max(self.bridged.count, 1)
        traced = ("" if self.traced_kb is None
                  else f" | {self.traced_kb[0]:.0f} / {self.traced_kb[1]:.0f}")
        bound = 1000 * self.bound_sum / max(self.bound_count, 1)
        return (f"| {self.start_s / 60:g}-{self.end_s / 60:g} | {self.tracked.rms_mm()} | "
                f"{self.tracked.max_mm(2)} | {self.bridged.rms_mm()} | "
                f"{self.bridged.max_mm(1)} | {inside:.3f} | {bound:.2f} | {self.lost} | "
                f"{self.snapshot_bytes} | {self.log_events} / {self.checkpoints} | "
                f"{self.rss_kb}{traced} | {self.seconds:.0f} |")


def rss_kb() -> int:
    """Resident set size of this process, kB (Linux /proc; 0 elsewhere)."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


@dataclass
class ChunkResult:
    """Per mocap frame of a chunk: time (s), status, error |estimate - truth| (m, NaN when
    lost) and the 99 % bound (m, inf when lost)."""

    t: Array
    status: NDArray[np.str_]
    error: Array
    bound: Array


def feed(tracker: Tracker, chunk: Chunk) -> ChunkResult:
    """Push one chunk in time order (IMU first at equal times); estimate after each frame."""
    imu_t = chunk.imu_t.tolist()
    visible = (~np.isnan(chunk.position[:, 0])).tolist()
    accelerometer, gyroscope = chunk.accelerometer, chunk.gyroscope
    push_imu, push_mocap, estimate = tracker.push_imu, tracker.push_mocap, tracker.estimate
    m = len(chunk.mocap_t)
    status = np.empty(m, dtype="<U7")
    error = np.full(m, np.nan)
    bound = np.full(m, np.inf)
    i, n = 0, len(imu_t)
    for row, t in enumerate(chunk.mocap_t.tolist()):
        while i < n and imu_t[i] <= t:
            push_imu(imu_t[i], accelerometer[i], gyroscope[i])
            i += 1
        push_mocap(t, chunk.position[row] if visible[row] else None,
                   chunk.quaternion[row] if visible[row] else None)
        result = estimate(t)  # now = the frame time
        status[row] = result.status
        if result.status != "lost":
            error[row] = float(np.linalg.norm(result.position - chunk.truth[row]))
            bound[row] = result.bound(0.99)
    while i < n:
        push_imu(imu_t[i], accelerometer[i], gyroscope[i])
        i += 1
    return ChunkResult(chunk.mocap_t, status, error, bound)


def soak(minutes: float, blocks: int, seed: int, *, trace: bool = False,
         stream: SoakStream | None = None, tracker: Tracker | None = None
         ) -> tuple[list[BlockStats], Tracker]:
    """Stream ``minutes`` of data; statistics per block (errors at the mocap times)."""
    stream = stream or SoakStream(seed=seed)
    tracker = tracker or stream.tracker()
    seconds = minutes * 60.0
    edges = np.linspace(0.0, seconds, blocks + 1)
    stats = [BlockStats(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]
    block = 0
    started = time.perf_counter()
    if trace:
        tracemalloc.start()
    for chunk in stream.chunks(seconds):
        result = feed(tracker, chunk)
        for t, status, error, bound in zip(result.t.tolist(), result.status.tolist(),
                                           result.error.tolist(), result.bound.tolist(),
                                           strict=True):
            while block < blocks - 1 and t >= stats[block].end_s:
                _close(stats[block], tracker, started, trace)
                started = time.perf_counter()
                block += 1
            current = stats[block]
            if status == "lost":
                current.lost += 1
                continue
            current.bound_sum += bound
            current.bound_count += 1
            if status == "tracked":
                current.tracked.add(error)
            else:
                current.bridged.add(error)
                current.bridged_inside += error <= bound
    _close(stats[block], tracker, started, trace)
    if trace:
        tracemalloc.stop()
    return stats, tracker


def _close(stats: BlockStats, tracker: Tracker, started: float, trace: bool) -> None:
    stats.seconds = time.perf_counter() - started
    stats.snapshot_bytes = len(pickle.dumps(tracker.snapshot()))
    stats.log_events = len(tracker._log)
    stats.checkpoints = len(tracker._checkpoints)
    stats.rss_kb = rss_kb()
    if trace:
        current, peak = tracemalloc.get_traced_memory()
        stats.traced_kb = (current / 1024, peak / 1024)
        tracemalloc.reset_peak()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--blocks", type=int, default=6)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tracemalloc", action="store_true",
                        help="trace Python allocations (about 4x slower)")
    parser.add_argument("--no-scale-errors", action="store_true",
                        help="control run: the MPU9255 model without its scale-factor and "
                        "cross-axis errors (which the Kalman model does not include)")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    profile = MPU9255
    if args.no_scale_errors:
        profile = dataclasses.replace(MPU9255, accelerometer_scale_error=0.0,
                                      accelerometer_cross_axis=0.0, gyroscope_scale_error=0.0,
                                      gyroscope_cross_axis=0.0)
    stats, tracker = soak(args.minutes, args.blocks, args.seed, trace=args.tracemalloc,
                          stream=SoakStream(seed=args.seed, profile=profile))
    elapsed = time.perf_counter() - started
    model = "MPU9255 model" + (" without scale/cross-axis errors" if args.no_scale_errors
                               else "")
    print(f"# Tracker soak: {args.minutes:g} simulated minutes, 1 kHz IMU ({model}), "
          f"100 Hz mocap, seed {args.seed}")
    print()
    traced = " | traced current / peak (kB)" if args.tracemalloc else ""
    print("| minutes | tracked RMS (mm) | tracked max (mm) | bridged RMS (mm) | bridged max (mm) "
          "| bridged inside bound99 | mean bound99 (mm) | lost frames | snapshot (bytes) "
          f"| log / checkpoints | RSS (kB){traced} | wall (s) |")
    print("|" + "---|" * (12 + bool(args.tracemalloc)))
    for block in stats:
        print(block.row())
    health = tracker.health
    print()
    print(f"wall time {elapsed:.0f} s ({elapsed / (args.minutes * 60):.3f} s per simulated s); "
          f"health: {health.imu_accepted} IMU accepted, {health.mocap_fused} fixes fused, "
          f"{health.mocap_occluded} occluded, {health.gate_rejections} gated, "
          f"{health.reacquisitions} re-acquisitions, {health.lost_transitions} lost transitions, "
          f"{health.state_resets} state resets; tracked {health.time_tracked_s:.0f} s, bridged "
          f"{health.time_bridged_s:.0f} s, lost {health.time_lost_s:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
