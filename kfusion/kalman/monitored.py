"""The batch filter with the consistency monitor on the compiled engine in two passes
(:func:`monitored_rows`), the same bits as event by event.

The monitor never changes the main filter, and when its shadow gaps start and end depends only
on the main filter's outcomes and times. So:

1. the whole-loop kernel (:func:`kfusion.kalman.compiled.run_kernel`) runs the main filter over
   the recording, keeping its state every :data:`CHECKPOINT_ROWS` rows;
2. the monitor's bookkeeping (:meth:`kfusion.monitor.ConsistencyMonitor.mocap`, unchanged) runs
   row by row on the kernel's outcomes, without a filter call per event: where it restores its
   shadow filter from the main one, the main state after that row is recomputed from the last
   kept state (:class:`kfusion.kalman.compiled.Checkpoints`: the same loop, the same
   arithmetic), and the shadow gap runs at once in the same kernel with its frames occluded
   (what the event-by-event shadow is fed: the IMU samples, ``update(t, None, None)`` at each
   frame), from which the shadow's estimates at the gap's rows are read. The filter's estimate
   before a frame (needed while a gated fix is pending) and after it (at a step in the fixes,
   :meth:`MainAtRow.estimate`) are recomputed the same way.

The event-by-event path (:func:`kfusion.kalman.batch.process_recording` with
:class:`kfusion.kalman.compiled_fusion.CompiledFusion`) stays the reference; tests compare the
two bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Final, NamedTuple, cast

import numpy as np
from numpy.typing import NDArray

from kfusion.kalman import compiled, model
from kfusion.kalman.compiled_fusion import CompiledFusion, CompiledSnapshot
from kfusion.kalman.events import MOCAP_STREAM
from kfusion.kalman.filter import FilterEstimate, KalmanFusion, UpdateOutcome
from kfusion.kalman.parameters import KalmanParameters
from kfusion.monitor import ConsistencyMonitor, MonitorParameters
from kfusion.recording import Recording

CHECKPOINT_ROWS: Final = 32
"""Rows between the main filter's kept states: a state at any row is recomputed from the last
kept one over fewer than this many rows (memory: one packed state per this many rows). The
run keeps them every ``gcd(CHECKPOINT_ROWS, SAVE_EVERY)`` rows (32 with the smoother's
:data:`kfusion.kalman.compiled.SAVE_EVERY` of 1024), so that the smoother's are among them."""


@dataclass(frozen=True)
class RowSnapshot(CompiledSnapshot):
    """A :class:`CompiledSnapshot` of the main filter right after the frame of ``row``."""

    row: int = -1


class ShadowEstimate(NamedTuple):
    """What the monitor reads of its shadow's estimate at a frame: the rigid-body point (3,) m,
    its covariance (3, 3) m^2 and the velocity (3,) m/s (:class:`kfusion.kalman.filter.
    FilterEstimate`'s fields of those names, computed as :meth:`CompiledFusion.estimate` does;
    a named tuple: one is made per shadow row)."""

    position: NDArray[np.float64]
    position_covariance: NDArray[np.float64]
    velocity: NDArray[np.float64]


class MainAtRow:
    """The main filter as the monitor reads it (:meth:`snapshot`) after the frame of ``row``."""

    def __init__(self, checkpoints: compiled.Checkpoints, configuration: tuple[float, ...],
                 row_event: list[int], reader: CompiledFusion,
                 last_impact: list[float]) -> None:
        self.checkpoints = checkpoints
        self.reader = reader
        self.configuration = configuration
        self.row_event = row_event
        self.last_impacts = last_impact  # per row (KernelRun.last_impact)
        self.row = -1

    @property
    def last_impact_t(self) -> float:
        """:attr:`KalmanFusion.last_impact_t` after the frame of ``row``."""
        return self.last_impacts[self.row]

    def snapshot(self) -> RowSnapshot:
        state = self.checkpoints.state_before(self.row_event[self.row] + 1)
        return RowSnapshot(self.configuration, state, _no_counters(), row=self.row)

    def estimate(self, t: float) -> FilterEstimate:
        """The filter's estimate at t (s) after the frame of ``row`` (the monitor reads it at a
        step in the fixes): ``reader`` restored from :meth:`snapshot`, as the event-by-event
        filter would give it."""
        self.reader.restore(self.snapshot())
        return self.reader.estimate(t)


class GapShadow:
    """The monitor's shadow filter in a two-pass run: :meth:`restore` from a
    :class:`RowSnapshot` runs the shadow gap's events at once (up to the first frame
    ``window_s`` after the row, where the monitor ends the gap at the latest) in the kernel with
    the frames occluded; :meth:`update` steps to the next frame and :meth:`estimate` reads it."""

    def __init__(self, fusion: CompiledFusion, checkpoints: compiled.Checkpoints,
                 row_event: list[int], mocap_t: list[float], window_s: float) -> None:
        self.params = fusion.params
        self._fusion = fusion  # holds the gap's first state: its estimate there
        self._checkpoints = checkpoints
        self._row_event = row_event
        self._mocap_t = mocap_t
        self._window_s = window_s
        self._first = self._row = -1
        self._rows: tuple[NDArray[np.float64], ...] = ()
        self._points: tuple[NDArray[np.float64], ...] | None = None  # _selected_points

    def restore(self, snapshot: RowSnapshot) -> None:
        row = snapshot.row
        self._fusion.restore(snapshot)
        times = self._mocap_t
        last = row
        while last + 1 < len(times):
            last += 1
            if times[last] - times[row] >= self._window_s:
                break
        self._first = self._row = row
        self._rows = () if last == row else self._checkpoints.run(
            snapshot.state.copy(), self._row_event[row] + 1, self._row_event[last] + 1,
            row + 1, last - row, hidden=True)
        self._points = _selected_points(*self._rows) if self._rows else None

    def update(self, t: float, position: None, quaternion: None) -> None:
        self._row += 1
        if position is not None or quaternion is not None or not self._rows \
                or self._row - self._first > len(self._rows[0]) \
                or self._mocap_t[self._row] != t:
            raise RuntimeError(f"shadow gap from row {self._first}: frame at {t!r} s is not the "
                               f"next occluded frame of the gap")

    def estimate(self) -> ShadowEstimate:
        if self._row == self._first:
            estimate = self._fusion.estimate()
            return ShadowEstimate(estimate.position, estimate.position_covariance,
                                  estimate.velocity)
        index = self._row - self._first - 1
        if self._points is not None:
            position, covariance, velocity = self._points
            return ShadowEstimate(position[index], covariance[index], velocity[index])
        x, P, H, offset = (rows[index] for rows in self._rows)
        return ShadowEstimate(model.output_point(H, x, offset), model.output_covariance(H, P),
                              x[model.VELOCITY].copy())


def _selected_points(x: NDArray[np.float64], P: NDArray[np.float64], H: NDArray[np.float64],
                     offset: NDArray[np.float64]
                     ) -> tuple[NDArray[np.float64], ...] | None:
    """The rigid-body points (k, 3) m, their covariances (k, 3, 3) m^2 and the velocities
    (k, 3) m/s of k rows (states (k, n), covariances (k, n, n), output maps H (k, 3, n) and c
    (k, 3)) at once, where every H is ``[I 0 0]`` (no lever-arm states) and the states are
    finite: ``H x + c`` is then ``x[:3] + c`` and ``H P H^T`` is ``P[:3, :3]`` to the bit
    (:func:`kfusion.kalman.model.output_point`'s products are the selected entries and exact
    zeros). None otherwise (each row is computed as the Tracker does)."""
    if not (np.array_equal(H, model.output_matrices(len(H), x.shape[1], False))
            and np.isfinite(x).all() and np.isfinite(P).all()):
        return None
    return (x[:, model.POSITION] + offset, P[:, model.POSITION, model.POSITION],
            x[:, model.VELOCITY])


def _no_counters() -> NDArray[np.int64]:
    return np.zeros(len(compiled.COUNTER_INDEX), dtype=np.int64)


def monitored_rows(recording: Recording, params: KalmanParameters,
                   settings: MonitorParameters, reference: KalmanFusion,
                   inputs: tuple[NDArray[Any], ...], recorder_class: Any,
                   smoothing: bool = False
                   ) -> tuple[Any, ConsistencyMonitor, compiled.Replay] | None:
    """The recorder (``recorder_class``: :class:`kfusion.kalman.batch._RowRecorder`), the
    monitor and the smoother's replay (:class:`kfusion.kalman.compiled.Replay`, the states
    after every :data:`~kfusion.kalman.compiled.SAVE_EVERY`-th row) of a two-pass run (module
    docstring) over ``inputs`` (:func:`kfusion.kalman.batch.kernel_inputs` of
    ``recording``), with ``reference``'s configuration; with ``smoothing`` the replay keeps
    each row's packed prediction (:func:`kfusion.kalman.compiled.pack_prediction`). None when
    the kernel stops at an event it cannot handle (the caller runs the event-by-event path)."""
    imu_t, force, rate, mocap_t, position, quaternion, visible, stream, index = inputs
    frames = np.flatnonzero(np.asarray(stream) == MOCAP_STREAM)
    order = np.asarray(index)[frames]
    if not np.array_equal(order, np.arange(len(mocap_t))):
        return None  # frames out of row order: the shadow gaps' rows are not consecutive
    config = reference.kernel_config()
    size = reference.size
    every = math.gcd(CHECKPOINT_ROWS, compiled.SAVE_EVERY)
    run = compiled.run_kernel(imu_t, force, rate, mocap_t, position, quaternion, visible,
                              stream, index, config, size, smoothing, save_every=every)
    if run.failed_event >= 0 or run.replay is None:
        return None
    checkpoints = compiled.Checkpoints(run.replay, size, every)
    events = frames.tolist()  # each row's event
    times = np.asarray(mocap_t, dtype=float).tolist()
    info = recording.info
    shadow = GapShadow(CompiledFusion(info.imu_to_body, info.gravity, params,
                                      lever_arm=info.lever_arm),
                       checkpoints, events, times, settings.shadow_window_s)
    monitor = ConsistencyMonitor(cast(KalmanFusion, shadow), settings, info.gravity)
    configuration = tuple(config.tolist())
    before = CompiledFusion(info.imu_to_body, info.gravity, params, lever_arm=info.lever_arm)
    main = MainAtRow(checkpoints, configuration, events, before, run.last_impact.tolist())
    recorder = recorder_class.from_kernel(reference, run)
    recorder.monitor = monitor
    recorder.scale_tables = np.ones((len(times), len(settings.horizon_edges_s)))
    initialised = recorder.initialised.tolist()
    kinds = run.outcome.tolist()
    nis = run.nis.tolist()
    fused = np.isfinite(run.y[:, 0]).tolist()  # rows with an innovation (UpdateOutcome.y)
    shown = np.asarray(visible, dtype=bool).tolist()
    fixes = np.asarray(position, dtype=float)
    for row in range(len(times)):
        t = times[row]
        prior = None
        if monitor.wants_prior(t, shown[row]):  # the filter's estimate before this frame
            before.restore(CompiledSnapshot(configuration,
                                            checkpoints.state_before(events[row]),
                                            _no_counters()))
            prior = before.estimate(t)
        outcome = UpdateOutcome(t, kinds[row], nis[row], y=run.y[row] if fused[row] else None,
                                S=run.S[row] if fused[row] else None)
        main.row = row
        # (it copies the positions it keeps; run.y and run.S rows it keeps are never written)
        monitor.mocap(t, fixes[row] if shown[row] else None, outcome,
                      cast(KalmanFusion, main), prior)
        recorder.record_monitor(row, outcome, initialised[row])
    recorder.widen_fixes()
    kept = run.replay
    step = compiled.SAVE_EVERY // every  # the smoother's states among the kept ones
    replay = compiled.Replay(kept.inputs, config, kept.first_state,
                             kept.saved_states[step - 1::step], kept.predictions)
    return recorder, monitor, replay
