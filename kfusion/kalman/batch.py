"""Run the streaming filter over a whole recording: :func:`filter_recording` (method ``kalman``).

Events are merged by :mod:`kfusion.kalman.events` (the one policy the Tracker uses too): in time
order on the mocap clock, an IMU sample at its stamp minus ``imu_latency_s``, and at equal times
the IMU sample first, then the mocap frame. The output has one row per mocap row (same t): the
estimate right after that row was processed.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from kfusion.conventions import BRIDGED, LOST
from kfusion.kalman.engines import DEFAULT_ENGINE, ENGINES
from kfusion.kalman.events import IMU_STREAM, MOCAP_STREAM, merge_events, merge_order
from kfusion.kalman.filter import USED_OUTCOMES, KalmanFusion, UpdateOutcome
from kfusion.kalman.markers import marker_fix_noise, shared_run_lengths
from kfusion.kalman.model import (
    BASE_SIZE,
    POSITION,
    orientation_error_variance,
    output_arm,
    output_covariance,
    output_matrices,
    output_matrix_rows,
    output_point,
    timestamp_jitter,
)
from kfusion.kalman.parameters import FIELD_NAMES, KalmanParameters
from kfusion.monitor import (
    ConsistencyMonitor,
    MonitorParameters,
    MonitorReport,
    fix_covariances_widened,
    held_at_frame,
    horizon_bins,
    scale_beyond_evidence,
)
from kfusion.recording import Recording, on_mocap_clock, without_held_frames
from kfusion.streamhealth import FIX_TIMEOUT_S, tracking_status
from kfusion.track_file import TrackResult, bounded_rows


def resolve_parameters(recording: Recording, params: KalmanParameters | None,
                       overrides: dict[str, Any]) -> KalmanParameters:
    """``params`` with ``overrides`` applied, or parameters from the recording's IMU profile
    (``recording.info.imu``; the default profile when unset), its measured ``imu_noise`` and
    ``overrides``."""
    if params is None:
        measured = recording.info.imu_noise.overrides() if recording.info.imu_noise else {}
        measured = {**measured, "timestamp_jitter": timestamp_jitter(recording.imu.t)}
        return KalmanParameters.from_profiles(recording.info.imu, None,
                                              **{**measured, **overrides})
    if not isinstance(params, KalmanParameters):
        raise ValueError(f"params: expected KalmanParameters or None, got "
                         f"{type(params).__name__}")
    unknown = sorted(set(overrides) - set(FIELD_NAMES))
    if unknown:
        raise ValueError(f"KalmanParameters: unknown override {unknown[0]!r}; expected one of "
                         f"{list(FIELD_NAMES)}")
    return dataclasses.replace(params, **overrides) if overrides else params


def marker_fix_parameters(params: KalmanParameters, body_positions: ArrayLike
                          ) -> KalmanParameters:
    """``params`` for marker-level fusion of markers at ``body_positions`` (n, 3) m: their
    ``mocap_position_noise`` raised to the fitted origin's (:func:`kfusion.kalman.markers.
    marker_fix_noise`), which the monitor compares its shadow gaps with and a fix shown alone
    carries. The markers' own noise is ``marker_position_noise``, unchanged."""
    noise = marker_fix_noise(body_positions, params.marker_position_noise ** 2,
                             params.mocap_position_noise)
    if noise == params.mocap_position_noise:
        return params
    return dataclasses.replace(params, mocap_position_noise=noise)


def make_fusion(recording: Recording, params: KalmanParameters, engine: str = "filterpy"
                ) -> KalmanFusion:
    """A :class:`KalmanFusion` (``engine`` filterpy) or a :class:`kfusion.kalman.
    compiled_fusion.CompiledFusion` (compiled: the same interface) configured from the
    recording's metadata."""
    info = recording.info
    if engine == "compiled":
        from kfusion.kalman.compiled_fusion import CompiledFusion  # numba loads here

        compiled: Any = CompiledFusion(info.imu_to_body, info.gravity, params,
                                       lever_arm=info.lever_arm)
        return cast(KalmanFusion, compiled)  # the same public interface
    return KalmanFusion(info.imu_to_body, info.gravity, params, lever_arm=info.lever_arm)


def make_monitor(recording: Recording, params: KalmanParameters,
                 monitor: MonitorParameters | None, engine: str = "filterpy"
                 ) -> ConsistencyMonitor | None:
    """The consistency monitor of a run (None when ``monitor`` is None), with its own shadow
    filter built like the main one."""
    if monitor is None:
        return None
    return ConsistencyMonitor(make_fusion(recording, params, engine), monitor,
                              recording.info.gravity)


BODY = "body"
"""Measurement mode: each mocap row's rigid-body pose (``mocap.csv``) is one fix."""
MARKERS = "markers"
"""Measurement mode: each visible marker of ``markers.csv`` is a measurement
(:meth:`KalmanFusion.update_markers`)."""
MEASUREMENTS = (BODY, MARKERS)


def default_measurement(recording: Recording) -> str:
    """``markers`` when the recording has ``markers.csv`` and ``recording.yaml``'s ``markers``,
    else ``body``."""
    has_markers = recording.markers is not None and recording.info.markers is not None
    return MARKERS if has_markers else BODY


def marker_inputs(recording: Recording) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The markers seen at each mocap row (m, n, 3) m (NaN where occluded) and their body-frame
    positions (n, 3) m, for ``--measurement markers``.

    Raises:
        ValueError: no ``markers.csv`` or no ``markers`` in ``recording.yaml``, or marker frames
            at other times than the mocap rows.
    """
    markers, body = recording.markers, recording.info.markers
    if markers is None or body is None:
        raise ValueError("measurement 'markers': expected markers.csv and a markers: section "
                         "in recording.yaml; use measurement 'body'")
    if not np.array_equal(markers.t, recording.mocap.t):
        raise ValueError(f"markers.csv: expected the times of mocap.csv ({len(recording.mocap)} "
                         f"rows), got {len(markers)} rows at other times")
    return (np.asarray(markers.position, dtype=float),
            np.array([body[name] for name in markers.names], dtype=float))


def measurement_engine(engine: str, measurement: str) -> str:
    """The engine that runs ``measurement``: ``engine``, except marker-level fusion, which has
    no compiled path yet and runs on ``filterpy``."""
    return "filterpy" if measurement == MARKERS else engine


def process_recording(recording: Recording, fusion: KalmanFusion,
                      on_row: Callable[[int, UpdateOutcome], None],
                      monitor: ConsistencyMonitor | None = None,
                      measurement: str = BODY, offline: bool = False) -> None:
    """Feed every IMU sample and mocap row to ``fusion`` in the fusion order
    (:func:`kfusion.kalman.events.merge_events`: by time on the mocap clock, an IMU sample at its
    stamp minus ``imu_latency_s``, the IMU sample first at equal times) and call
    ``on_row(row, outcome)`` right after each mocap row. IMU samples after the last mocap row
    are not fed (no output row would use them). ``monitor`` sees the same events (after the
    filter).

    The recording's clock model is applied here (:func:`kfusion.recording.on_mocap_clock`), so
    every batch path (``filter_recording``, ``run_smoother``, ``kfusion track``) uses it.

    ``measurement``: ``body`` fuses each row's rigid-body pose, ``markers`` each row's visible
    markers (:func:`marker_inputs`; the monitor then sees the markers' Kabsch pose, where 3 or
    more fit). ``offline`` (the smoother): each marker frame is told how many frames share its
    gyroscope orientation error (``shared_frames`` of :meth:`KalmanFusion.update_markers`)."""
    if measurement not in MEASUREMENTS:
        raise ValueError(f"measurement: expected one of {list(MEASUREMENTS)}, got "
                         f"{measurement!r}")
    observed, body = marker_inputs(recording) if measurement == MARKERS else (None, None)
    shared = (shared_run_lengths(np.isfinite(observed).all(axis=2).sum(axis=1)).tolist()
              if observed is not None and offline else None)
    recording = on_mocap_clock(recording)
    imu = recording.imu
    mocap = recording.mocap
    stamps = imu.t.tolist()
    accelerometer = imu.accelerometer.tolist()
    gyroscope = imu.gyroscope.tolist()
    finite: list[bool] = np.logical_and(np.isfinite(imu.accelerometer).all(axis=1),
                                        np.isfinite(imu.gyroscope).all(axis=1)).tolist()
    visible: list[bool] = mocap.visible.tolist()
    events = merge_events(stamps, mocap.t.tolist(), fusion.params.imu_latency_s)
    while events and events[-1][1] == IMU_STREAM:
        events.pop()
    fast = type(fusion) is KalmanFusion  # its validated internals; other engines: public API
    # the compiled engine's checked entry for it and, in a shadow gap, the monitor's compiled
    # shadow in one call (CompiledFusion.predict_valid_with), as the Tracker predicts them
    predict_valid_with = getattr(fusion, "predict_valid_with", None) if not fast else None
    paired = monitor is not None and monitor.takes_checked_samples
    latest = -math.inf  # the latest finite stamp fed: no filter holds a later one
    for t, stream, index in events:
        if stream == IMU_STREAM:
            stamp = stamps[index]
            if predict_valid_with is not None and finite[index] and stamp > latest:
                # what predict() checks (finite, after the held stamp) holds: its kernel call
                latest = stamp
                a0, a1, a2 = accelerometer[index]
                g0, g1, g2 = gyroscope[index]
                shadow = monitor.gap_shadow if paired and monitor is not None else None
                predict_valid_with(shadow, stamp, a0, a1, a2, g0, g1, g2)
                if monitor is not None and not paired:
                    monitor.imu(stamp, accelerometer[index], gyroscope[index])
                continue
            if finite[index]:
                latest = max(latest, stamp)
            if fast and finite[index] and (fusion._imu_stamp is None
                                           or stamp > fusion._imu_stamp):
                f, omega = accelerometer[index], gyroscope[index]
                fusion._predict_valid(stamp, (f[0], f[1], f[2]), (omega[0], omega[1], omega[2]))
            else:  # the public path rejects, skips or raises with its message
                fusion.predict(stamp, accelerometer[index], gyroscope[index])
            if monitor is not None:
                monitor.imu(stamp, accelerometer[index], gyroscope[index])
            continue
        seen = visible[index] if observed is None or body is None \
            else bool(np.isfinite(observed[index]).any())  # the frame carries a fix
        prior = fusion.estimate(t) if monitor is not None and monitor.wants_prior(t, seen) \
            else None
        if observed is not None and body is not None:
            outcome = fusion.update_markers(
                t, observed[index], body,
                shared_frames=None if shared is None else shared[index] or None)
            if monitor is not None:
                origin = outcome.marker_origin
                monitor.mocap(t, None if origin is None else np.array(origin), outcome, fusion,
                              prior)
            on_row(index, outcome)
            continue
        position = mocap.position[index].copy() if visible[index] else None
        if position is not None and fast:
            outcome = fusion._update_valid(t, position, mocap.quaternion[index].copy())
        elif position is not None:
            outcome = fusion.update(t, position, mocap.quaternion[index].copy())
        else:
            outcome = fusion.update(t, None, None)
        if monitor is not None:
            monitor.mocap(t, position, outcome, fusion, prior)
        on_row(index, outcome)


@dataclass(frozen=True)
class FilterRun:
    """Everything the filter produced over a recording, one row per mocap row.

    Attributes:
        result: the :class:`kfusion.track_file.TrackResult` (method ``kalman``).
        x: (m, n) state after each row (n = 9, or 12 with the lever arm; NaN before the first
            fix).
        P: (m, n, n) its covariance.
        output_matrix: (m, 3, n) H at each row: the rigid-body point is ``H x + output_offset``.
            Without the lever-arm states it is ``[I 0 0]`` on every row, a read-only view of
            one (3, n) matrix (:func:`kfusion.kalman.model.output_matrices`); a pickled run
            comes back with a full copy.
        output_offset: (m, 3) m.
        outcome: (m,) what the update did (accepted, occluded, gated, reacquired, initialised).
        nis: (m,) NIS of the row's fix (NaN where none was compared).
        counters: final :attr:`KalmanFusion.counters`.
        params: the parameters used.
        monitor: what the consistency monitor found at the end (None without a monitor).
        variance_scale: (m,) factor applied to the row's position covariance by the monitor
            (1 on tracked rows and without a monitor).
    """

    result: TrackResult
    x: NDArray[np.float64]
    P: NDArray[np.float64]
    output_matrix: NDArray[np.float64]
    output_offset: NDArray[np.float64]
    outcome: NDArray[np.str_]
    nis: NDArray[np.float64]
    counters: dict[str, int]
    params: KalmanParameters
    monitor: MonitorReport | None = None
    variance_scale: NDArray[np.float64] | None = None


def status_from_fixes(t: NDArray[np.float64], fixed: NDArray[np.bool_], initialised:
                      NDArray[np.bool_], max_bridge_s: float,
                      dead_reckoned: NDArray[np.bool_] | None = None, *,
                      engine: str = "filterpy"
                      ) -> tuple[NDArray[np.str_], NDArray[np.float64]]:
    """Status and time since the last fix (s) at each row: the status rule
    (:func:`kfusion.streamhealth.tracking_status`) at the row's time, right after its frame.

    The row's frame is the last one, so a row is ``tracked`` where its fix was used; otherwise
    ``bridged`` while the time since the last used fix is at most ``max_bridge_s`` and the row
    is ``dead_reckoned`` (IMU-propagated since the last fix:
    :meth:`KalmanFusion.dead_reckoning_until`; None: every row), else ``lost``. Rows where the
    filter is not ``initialised`` (before the first fix, after a reset) are lost. ``engine``:
    :func:`row_statuses`'.
    """
    t = np.asarray(t, dtype=float)
    fix_time = np.where(fixed, t, -np.inf)
    last_fix = np.maximum.accumulate(fix_time) if len(t) else fix_time
    since = t - last_fix
    status = row_statuses(np.where(initialised, since, np.inf), fixed, max_bridge_s,
                          dead_reckoned, engine=engine)
    return status, since


def row_statuses(time_since_fix: NDArray[np.float64], fused: NDArray[np.bool_],
                 max_bridge_s: float, dead_reckoned: NDArray[np.bool_] | None = None, *,
                 engine: str = "filterpy") -> NDArray[np.str_]:
    """:func:`kfusion.streamhealth.tracking_status` at each of m rows, right after the row's
    frame (the last frame is the row's own: ``fused`` (m,) says whether its fix was used).

    Args:
        time_since_fix: (m,) s from the fix the row goes from (inf: none).
        fused: (m,) the row's fix was used.
        max_bridge_s: s.
        dead_reckoned: (m,) the row is within the dead-reckoning horizon; None: every row.
        engine: ``compiled`` applies the rule in one compiled loop
            (:func:`kfusion.kalman.compiled.status_codes`), ``filterpy`` row by row here.
    """
    reckoned = (np.ones(len(fused), dtype=bool) if dead_reckoned is None
                else np.asarray(dead_reckoned, dtype=bool))
    if engine == "compiled":
        from kfusion.kalman import compiled

        codes = compiled.status_codes(np.ascontiguousarray(time_since_fix, dtype=float),
                                      np.ascontiguousarray(fused, dtype=bool), reckoned,
                                      FIX_TIMEOUT_S, float(max_bridge_s))
        return compiled.STATUS_NAMES[codes]
    rows = zip(np.asarray(time_since_fix, dtype=float).tolist(),
               np.asarray(fused, dtype=bool).tolist(), reckoned.tolist(), strict=True)
    return np.array([tracking_status(since, last_fused, fix_timeout_s=FIX_TIMEOUT_S,
                                     max_bridge_s=max_bridge_s,
                                     beyond_dead_reckoning=not reckoning)
                     for since, last_fused, reckoning in rows], dtype=str)


def point_estimates(x: NDArray[np.float64], P: NDArray[np.float64],
                    output_matrix: NDArray[np.float64], output_offset: NDArray[np.float64]
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rigid-body point ``H x + c`` (m, 3) m and its variance per axis ``diag(H P H^T)``
    (m, 3) m^2 from per-row states (m, n), covariances (m, n, n) and output maps.

    Variances, not standard deviations: the monitor's scale and the rivals' variance are added
    before the one square root, in the order the Tracker uses, so both give the same bits."""
    position = np.array([output_point(H, state, offset) for H, state, offset
                         in zip(output_matrix, x, output_offset, strict=True)]).reshape(-1, 3)
    variance = np.diagonal(position_covariances(P, output_matrix), axis1=1, axis2=2)
    return position, variance


def row_position_covariances(P: NDArray[np.float64], output_matrix: NDArray[np.float64],
                             rows: NDArray[np.intp]) -> NDArray[np.float64]:
    """:func:`position_covariances` (k, 3, 3) of rows ``rows`` (k,) of per-row covariances
    (m, n, n) and output maps (m, 3, n), a shared H kept shared
    (:func:`kfusion.kalman.model.output_matrix_rows`)."""
    return position_covariances(P[rows], output_matrix_rows(output_matrix, rows))


def position_covariances(P: NDArray[np.float64], output_matrix: NDArray[np.float64]
                         ) -> NDArray[np.float64]:
    """Rigid-body point covariance ``H P H^T`` per row (m, 3, 3) from (m, n, n) and (m, 3, n)
    (:func:`kfusion.kalman.model.output_covariance`, row by row: the filter's own order of
    operations). Where H is the one ``[I 0 0]`` of every row (no lever-arm states:
    :func:`kfusion.kalman.model.output_matrices`) and P is finite, P's position block: the same
    bits, since the products are the selected entries plus exact zeros (up to the sign of an
    exact zero)."""
    if len(P) and output_matrix.strides[0] == 0 \
            and np.array_equal(output_matrix[0], output_matrices(1, P.shape[1], False)[0]) \
            and np.isfinite(P).all():
        return P[:, POSITION, POSITION].copy()
    return np.array([output_covariance(H, covariance) for H, covariance
                     in zip(output_matrix, P, strict=True)]).reshape(-1, 3, 3)


def previous_frame_horizons(frames: NDArray[np.bool_], horizon_s: NDArray[np.float64]
                            ) -> NDArray[np.float64]:
    """(m,) s: for each row, the horizon of the last row of ``frames`` (the bridged rows the
    monitor allows) before it in the same gap (the rows since a fix, ``horizon_s`` <= 0 at
    one), 0 when there is none (the gap's fix)."""
    gap = np.cumsum(horizon_s <= 0.0)  # the rows since the same fix share a number
    index = np.flatnonzero(frames)
    last = np.full(len(horizon_s), -1)
    last[index] = index
    last = np.maximum.accumulate(last)  # the latest frame at or before each row
    before = np.concatenate([[-1], last[:-1]])  # ... strictly before it
    found = before >= 0
    same = found & (gap[np.maximum(before, 0)] == gap)
    return np.where(same, horizon_s[np.maximum(before, 0)], 0.0)


def apply_monitor(status: NDArray[np.str_], variance: NDArray[np.float64],
                  scale_tables: NDArray[np.float64], allowed: NDArray[np.bool_],
                  horizon_s: NDArray[np.float64], edges_s: tuple[float, ...], *,
                  forward: bool = True
                  ) -> tuple[NDArray[np.str_], NDArray[np.float64], NDArray[np.float64]]:
    """Bridged rows' variance (m, 3) m^2 times ``scale``, the row's monitor table (m, bins) at
    its horizon (s since the fix), and ``lost`` where the monitor refused to bridge. Returns
    (status, variance, per-row scale).

    ``forward`` (the filter, whose horizon grows through a gap): the larger of the scales at
    the row's horizon and at the horizon of the gap's previous bridged row
    (:func:`previous_frame_horizons`). Between two frames the horizon may cross a bin edge,
    and a reading there (the Tracker at IMU rate) has the scale of the bin before the edge up
    to it; the frame after the edge holds both, so that no reading between the frames is
    wider than it (with :func:`held_in_gaps`, a gap's bound never shrinks). False (the
    smoother's hold-out scales, at the distance to the nearest fix): the row's bin alone."""
    bridged = status == BRIDGED
    rows = np.arange(len(status))
    scale = scale_beyond_evidence(scale_tables[rows, horizon_bins(horizon_s, edges_s)],
                                  horizon_s, edges_s)
    if forward:
        previous = previous_frame_horizons(bridged & allowed, horizon_s)
        scale = np.maximum(scale, scale_beyond_evidence(
            scale_tables[rows, horizon_bins(previous, edges_s)], previous, edges_s))
    scale = np.where(bridged, scale, 1.0)
    scale = np.where(np.isfinite(scale), scale, 1.0)
    variance = variance * scale[:, None]
    status = np.where(bridged & ~allowed, LOST, status)
    return status.astype(str), variance, scale


def held_in_gaps(status: NDArray[np.str_], variance: NDArray[np.float64],
                 horizon_s: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per-axis variance (m, 3) m^2 with each bridged row's scaled up (:func:`held_at_frame`)
    to the largest per-axis variance of the bridged rows before it in the same gap (the rows
    since the last fix, ``horizon_s`` <= 0 at a fix), so that within a gap the bound never
    shrinks.

    Without a measurement the position error does not shrink either: it is continuous, and a
    gap's error at h s carries its error at any earlier h' plus what came after. The filter's
    own P grows in a gap, but the monitor's scale is matched per horizon bin
    (:class:`kfusion.monitor.HorizonScales`), and a bin whose rows needed less than the bin
    before it made the bound fall at the edge between them: on BROAD trial 24 from 2.8 to 1.4
    mm within 10 ms at 0.1 s, with the error unchanged at 1.8-2.0 mm (the recording's largest
    misses). The Tracker keeps the same peak over a gap's frames
    (:meth:`kfusion.tracker.Tracker.estimate`)."""
    result = np.array(variance, dtype=float)
    peak = 0.0
    for row in np.flatnonzero((status == BRIDGED) | (horizon_s <= 0.0)).tolist():
        if horizon_s[row] <= 0.0:  # a fix: the next gap starts from it
            peak = 0.0
            continue
        factor, peak = held_at_frame(peak, result[row])
        if factor > 1.0:
            result[row] = result[row] * factor
    return result


def monitored_output(status: NDArray[np.str_], position: NDArray[np.float64],
                     variance: NDArray[np.float64], recorder: Any,
                     horizon_s: NDArray[np.float64], edges_s: tuple[float, ...],
                     orientation: NDArray[np.float64]
                     ) -> tuple[NDArray[np.str_], NDArray[np.float64], NDArray[np.float64],
                                NDArray[np.float64]]:
    """The filter's rows as the consistency monitor reports them, from the recorder's
    (:class:`_RowRecorder`) reads: gaps scaled or ``lost`` (:func:`apply_monitor`), fixes
    widened (:func:`at_fix_rows`), the rivals' variance and the orientation's part
    ``orientation`` (m, 3) m^2 (:func:`orientation_rows`) added, the fix alone where the model
    was refused (:func:`fix_only_rows`) and bounds that never shrink within a gap
    (:func:`held_in_gaps`). Returns (status, position (m, 3) m, variance (m, 3) m^2, the
    monitor's scale per row); the Tracker computes each row the same way."""
    status, variance, scale = apply_monitor(status, variance, recorder.scale_tables,
                                            recorder.allowed, horizon_s, edges_s)
    variance = at_fix_rows(variance, recorder.at_fix_variance) + recorder.rival_variance
    variance = variance + orientation
    status, position, variance = fix_only_rows(status, position, variance, recorder.allowed,
                                               recorder.fix_position, recorder.fix_variance)
    return status, position, held_in_gaps(status, variance, horizon_s), scale


def at_fix_rows(variance: NDArray[np.float64], at_fix_variance: NDArray[np.float64]
                ) -> NDArray[np.float64]:
    """Per-axis variance (m, 3) m^2 with the rows where the monitor widened a fused fix
    (finite ``at_fix_variance`` (m, 3), :meth:`kfusion.monitor.ConsistencyMonitor.at_fix`)
    taken from it, as the Tracker reads them."""
    return np.where(np.isfinite(at_fix_variance), at_fix_variance, variance)


def fix_only_rows(status: NDArray[np.str_], position: NDArray[np.float64],
                  variance: NDArray[np.float64], allowed: NDArray[np.bool_],
                  fix_position: NDArray[np.float64], fix_variance: NDArray[np.float64]
                  ) -> tuple[NDArray[np.str_], NDArray[np.float64], NDArray[np.float64]]:
    """Rows where the monitor refused the IMU model (``~allowed``): a row with a fix
    (finite ``fix_position`` (m, 3) m) is that fix alone with ``fix_variance`` (m, 3) m^2 (the
    mocap noise, and the rivals it must hold), any other row is lost, as the Tracker reads it
    (:meth:`kfusion.monitor.ConsistencyMonitor.fix_only`). Returns (status, position,
    variance)."""
    refused = ~allowed
    at_fix = refused & np.isfinite(fix_position).all(axis=1)
    position = np.where(at_fix[:, None], fix_position, position)
    variance = np.where(at_fix[:, None], fix_variance, variance)
    status = np.where(refused & ~at_fix, LOST, status)
    return status.astype(str), position, variance


def orientation_rows(angle_variance: NDArray[np.float64], x: NDArray[np.float64],
                     position: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per axis (m, 3) m^2: the orientation's part of each row's output
    (:func:`kfusion.kalman.model.orientation_error_variance`) from the orientation tracker's
    angle variance (m,) rad^2, the states (m, n) and their rigid-body points (m, 3) m (the arm
    is :func:`kfusion.kalman.model.output_arm`); 0 where the filter is not initialised (NaN).
    The Tracker adds the same term to its reading
    (:attr:`kfusion.kalman.filter.FilterEstimate.orientation_covariance`)."""
    variance = orientation_error_variance(output_arm(x, position), angle_variance)
    return np.where(np.isnan(variance), 0.0, variance)


class _RowRecorder:
    """Collects the filter's state and output map after each mocap row, the monitor's scales
    where the row's fix was not used, and whether the monitor still trusts the IMU model (with
    the fix alone where it does not)."""

    def __init__(self, fusion: KalmanFusion, rows: int,
                 monitor: ConsistencyMonitor | None = None) -> None:
        size = fusion.size
        self.fusion = fusion
        self.monitor = monitor
        bins = len(monitor.params.horizon_edges_s) if monitor is not None else 1
        self.scale_tables = np.ones((rows, bins))
        self.allowed = np.ones(rows, dtype=bool)
        # (m,) True once the monitor had compared enough fixes with the model (model_tested):
        # before, "not allowed" says untested, not refused
        self.tested = np.ones(rows, dtype=bool)
        self.x = np.full((rows, size), np.nan)
        self.P = np.full((rows, size, size), np.nan)
        # (m, 3, n): a read-only view of one H without the lever-arm states
        self.output_matrix = output_matrices(rows, size, fusion.estimates_lever_arm)
        self.output_offset = np.zeros((rows, 3))
        self.outcome = np.empty(rows, dtype=object)
        self.nis = np.full(rows, np.nan)
        self.dead_reckoned = np.zeros(rows, dtype=bool)
        # (m, 3) m^2: variance the monitor's rival hypotheses add per axis (cover_rivals)
        self.rival_variance = np.zeros((rows, 3))
        # (m,) m^2 per axis: the marker layout's common error (KalmanFusion.layout_variance;
        # 0 without marker frames)
        self.layout_variance = np.zeros(rows)
        # (m,) rad^2: the orientation tracker's angle variance (the orientation's part of the
        # output, orientation_rows; NaN where the filter is not initialised)
        self.angle_variance = np.full(rows, np.nan)
        # (m,) m^2: the part of it at a fused fix from the edge-offset term
        # (ConsistencyMonitor.edge_offset_variance at h = 0): the filter's online cover for
        # fixes that may turn out to end before an occlusion; the smoother leaves it out
        self.fix_edge_variance = np.zeros(rows)
        # where the monitor refused the IMU model at a fix: that fix (m) and its variance
        # (m^2, the mocap noise and the rivals), NaN elsewhere
        self.fix_position = np.full((rows, 3), np.nan)
        self.fix_variance = np.full((rows, 3), np.nan)
        # at a fused fix whose prediction the monitor found worse than its P: the variance
        # per axis (m^2) of ConsistencyMonitor.at_fix, NaN elsewhere
        self.at_fix_variance = np.full((rows, 3), np.nan)
        # (row, scale, factor) of ConsistencyMonitor.fix_widening where it widens a fix:
        # widen_fixes turns them into at_fix_variance for all those rows at once
        self.widening: list[tuple[int, float, float]] = []
        self.counters: dict[str, int] = {}
        self._fixed: NDArray[np.bool_] | None = None  # from_kernel: the rows whose fix was used

    def finish(self) -> None:
        """Take the filter's final counters and widen the fixes (:meth:`widen_fixes`)."""
        self.counters = self.fusion.counters
        self.widen_fixes()

    def widen_fixes(self) -> None:
        """``at_fix_variance`` of the rows the monitor widens (:attr:`widening`): the variance
        per axis of :meth:`ConsistencyMonitor.at_fix`, computed for all of them at once
        (:func:`kfusion.monitor.fix_covariances_widened`, the same bits)."""
        if self.monitor is None or not self.widening:
            return
        rows, scales, factors = (np.array(column) for column in zip(*self.widening, strict=True))
        covariances = row_position_covariances(self.P, self.output_matrix, rows)
        widened = fix_covariances_widened(covariances, self.monitor.fix_noise_variance, scales,
                                          factors)
        self.at_fix_variance[rows] = np.diagonal(widened, axis1=1, axis2=2)

    def record(self, row: int, outcome: UpdateOutcome) -> None:
        fusion = self.fusion
        self.outcome[row] = outcome.kind
        self.nis[row] = outcome.nis
        self.dead_reckoned[row] = outcome.t <= fusion.dead_reckoning_until()
        initialised = fusion.initialised
        if initialised:
            self.x[row] = fusion._kf.x
            self.P[row] = fusion._kf.P
            H, offset = fusion.output_map()
            if fusion.estimates_lever_arm:  # else H is output_matrix's one [I 0 0]
                self.output_matrix[row] = H
            self.output_offset[row] = offset
            self.layout_variance[row] = getattr(fusion, "layout_variance", 0.0)
            self.angle_variance[row] = fusion.angle_variance
        if self.monitor is not None:
            self.record_monitor(row, outcome, initialised)

    def record_monitor(self, row: int, outcome: UpdateOutcome, initialised: bool) -> None:
        """The monitor's part of a row (its reads only), with the row's state, covariance and
        output map already recorded (read from them where ``initialised``)."""
        monitor = self.monitor
        assert monitor is not None
        self.allowed[row] = monitor.bridging_allowed
        self.tested[row] = monitor.model_tested
        if not outcome.accepted:
            self.scale_tables[row] = monitor.scale_table()
        fix = None if self.allowed[row] else monitor.fix_only(outcome.t)
        if fix is not None:
            covariance = monitor.cover_rivals(outcome.t, fix[0], fix[1])
            self.fix_position[row] = fix[0]
            self.fix_variance[row] = np.diag(covariance)
        if initialised:
            H = self.output_matrix[row]
            scale, factor = monitor.fix_widening(outcome.t)
            if scale > 1.0 or factor > 1.0:  # widen_fixes computes the covariance
                self.widening.append((row, scale, factor))
            if monitor.has_rivals(outcome.t):  # else the row's zeros stand
                widened = monitor.cover_rivals(
                    outcome.t, output_point(H, self.x[row], self.output_offset[row]),
                    np.zeros((3, 3)))
                self.rival_variance[row] = np.diag(widened)
                if outcome.accepted:
                    self.fix_edge_variance[row] = monitor.edge_offset_variance(outcome.t)

    @classmethod
    def from_kernel(cls, fusion: KalmanFusion, run: Any) -> _RowRecorder:
        """The recorder of a compiled whole-loop run (:class:`kfusion.kalman.compiled.
        KernelRun`): its arrays taken as they are (no per-row copies), no monitor."""
        recorder = cls.__new__(cls)
        rows = len(run.nis)
        recorder.fusion, recorder.monitor = fusion, None
        recorder.scale_tables = np.ones((rows, 1))
        recorder.allowed = np.ones(rows, dtype=bool)
        recorder.tested = np.ones(rows, dtype=bool)
        recorder.rival_variance = np.zeros((rows, 3))
        recorder.layout_variance = np.zeros(rows)
        recorder.angle_variance = run.angle_variance
        recorder.fix_edge_variance = np.zeros(rows)
        recorder.fix_position = np.full((rows, 3), np.nan)
        recorder.fix_variance = np.full((rows, 3), np.nan)
        recorder.at_fix_variance = np.full((rows, 3), np.nan)
        recorder.widening = []
        recorder.x, recorder.P = run.x, run.P
        recorder.output_matrix, recorder.output_offset = run.output_matrix, run.output_offset
        recorder.outcome = run.outcome.astype(object)
        recorder.nis, recorder.dead_reckoned = run.nis, run.dead_reckoned
        recorder.counters = run.counters
        recorder._fixed = np.isin(run.outcome, USED_OUTCOMES)
        return recorder

    @property
    def fixed(self) -> NDArray[np.bool_]:
        if self._fixed is not None:
            return self._fixed
        return np.isin(self.outcome.astype(str), USED_OUTCOMES)

    @property
    def initialised(self) -> NDArray[np.bool_]:
        return np.isfinite(self.x[:, 0])


def check_engine(engine: str) -> str:
    """``engine`` if it names one (:data:`ENGINES`), else a ValueError saying which exist."""
    if engine not in ENGINES:
        raise ValueError(f"engine: expected one of {list(ENGINES)}, got {engine!r}")
    return engine


def compiled_rows(recording: Recording, fusion: KalmanFusion, *, smoothing: bool = False
                  ) -> tuple[_RowRecorder, Any] | None:
    """The per-row arrays of :func:`process_recording` computed by the compiled whole-loop
    kernel (:func:`kfusion.kalman.compiled.filter_events`) over the same merged events, with
    ``fusion``'s configuration (``fusion`` itself is not run). None when the kernel stops at an
    event it cannot handle (an out-of-order stamp): the caller runs the filterpy engine, whose
    error names it. Returns the recorder and the kernel's run (:class:`kfusion.kalman.compiled.
    KernelRun`, with the smoother's per-row predictions and transitions when ``smoothing``)."""
    from kfusion.kalman import compiled  # numba loads on first use of the engine

    inputs = kernel_inputs(recording, fusion.params.imu_latency_s)
    imu_t, force, rate, mocap_t, position, quaternion, visible, stream, index = inputs
    run = compiled.run_kernel(imu_t, force, rate, mocap_t, position, quaternion, visible, stream,
                              index, fusion.kernel_config(), fusion.size, smoothing)
    if run.failed_event >= 0:
        return None
    return _RowRecorder.from_kernel(fusion, run), run


def monitored_kernel_rows(recording: Recording, params: KalmanParameters,
                          monitor: MonitorParameters, smoothing: bool = False
                          ) -> tuple[_RowRecorder, ConsistencyMonitor, Any] | None:
    """The per-row arrays of :func:`process_recording` with the consistency monitor on the
    compiled engine, in two passes (:func:`kfusion.kalman.monitored.monitored_rows`: the
    whole-loop kernel, then the monitor's bookkeeping, the same bits), the monitor and the
    smoother's :class:`kfusion.kalman.compiled.Replay` (with each row's packed prediction when
    ``smoothing``). None when the kernel cannot run the recording (the caller runs it event by
    event)."""
    from kfusion.kalman.monitored import monitored_rows  # numba loads here

    inputs = kernel_inputs(recording, params.imu_latency_s)
    return monitored_rows(recording, params, monitor, make_fusion(recording, params), inputs,
                          _RowRecorder, smoothing)


def kernel_inputs(recording: Recording, latency_s: float) -> tuple[NDArray[Any], ...]:
    """The recording on the mocap clock as the compiled kernels' arguments: IMU t, specific
    force, rate, mocap t, position, quaternion, visible, and the merged events (``stream``,
    ``index``: :func:`kfusion.kalman.events.merge_order`, the order :func:`process_recording`
    feeds) up to the last mocap row (every stamp is finite: the recording's streams refuse
    others where they are built)."""
    recording = on_mocap_clock(recording)
    imu, mocap = recording.imu, recording.mocap
    _, stream, index = merge_order(imu.t, mocap.t, latency_s)
    frames = np.flatnonzero(stream == MOCAP_STREAM)
    end = int(frames[-1]) + 1 if len(frames) else 0  # IMU samples after the last row: unused
    return (imu.t, imu.accelerometer, imu.gyroscope, mocap.t, mocap.position,
            mocap.quaternion, mocap.visible, stream[:end], index[:end])


def compiled_points(recorder: _RowRecorder, x: NDArray[np.float64] | None = None,
                    P: NDArray[np.float64] | None = None
                    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`point_estimates` by the compiled engine (:func:`kfusion.kalman.compiled.
    point_rows`) for the recorder's rows, or for states ``x``, ``P`` at its output maps."""
    from kfusion.kalman import compiled

    maps = recorder.output_matrix
    if maps.strides[0] == 0:  # one H for every row (model.output_matrices), as (1, 3, n)
        maps = np.array(maps[:1])  # a copy: a read-only view is another numba type
    position, variance = compiled.point_rows(
        maps, recorder.x if x is None else x, recorder.output_offset,
        recorder.P if P is None else P)
    return position, variance


def run_filter(recording: Recording, params: KalmanParameters | None = None, *,
               monitor: MonitorParameters | None = MonitorParameters(),  # noqa: B008 (frozen)
               measurement: str = BODY, engine: str = DEFAULT_ENGINE,
               stepwise: bool = False, **overrides: Any) -> FilterRun:
    """Run the filter over ``recording`` and keep its per-row states and outcomes.

    ``monitor``: the consistency monitor's settings (:mod:`kfusion.monitor`); None runs the
    filter alone (the bound is then the profile's). ``measurement``: ``body`` or ``markers``
    (:func:`process_recording`). ``engine``: ``compiled`` (the numba whole-loop kernel,
    :mod:`kfusion.kalman.compiled`) or ``filterpy`` (:class:`KalmanFusion` step by step). With
    a monitor the compiled engine runs in two passes (:func:`monitored_kernel_rows`: the
    kernel, then the monitor's bookkeeping with its shadow gaps in the kernel), or, with
    ``stepwise``, event by event (:class:`kfusion.kalman.compiled_fusion.CompiledFusion` for
    the filter and the monitor's shadow filter: the reference the two passes equal bit for
    bit). Marker-level fusion runs on filterpy whatever the engine
    (:func:`measurement_engine`)."""
    check_engine(engine)
    engine = measurement_engine(engine, measurement)
    recording, held = without_held_frames(recording)  # poses held through occlusions
    params = resolve_parameters(recording, params, overrides)
    if measurement == MARKERS:
        params = marker_fix_parameters(params, marker_inputs(recording)[1])
    watcher = make_monitor(recording, params, monitor, engine)
    # without a monitor the compiled engine runs the whole loop in one kernel; with one (it
    # watches the filter event by event), the compiled step functions (CompiledFusion)
    fusion = make_fusion(recording, params, "filterpy" if watcher is None else engine)
    rows = compiled_rows(recording, fusion) if engine == "compiled" and watcher is None else None
    monitored = (monitored_kernel_rows(recording, params, watcher.params)
                 if engine == "compiled" and watcher is not None and not stepwise else None)
    if rows is not None:
        recorder = rows[0]
    elif monitored is not None:
        recorder, watcher, _ = monitored
    else:
        recorder = _RowRecorder(fusion, len(recording.mocap), watcher)
        process_recording(recording, fusion, recorder.record, watcher, measurement)
        recorder.finish()
    kernel = rows is not None or monitored is not None  # the compiled whole-loop kernel ran
    status, since = status_from_fixes(recording.mocap.t, recorder.fixed, recorder.initialised,
                                      params.max_bridge_s, recorder.dead_reckoned,
                                      engine="compiled" if kernel else "filterpy")
    # the compiled points have the bits of the filter's own (model.output_point, the Tracker's)
    # where H = [I 0 0] selects the position (no lever-arm states): a sum of the selected
    # entry and exact zeros, in any order
    position, variance = (compiled_points(recorder)
                          if rows is not None or (kernel and recorder.x.shape[1] == BASE_SIZE)
                          else point_estimates(recorder.x, recorder.P, recorder.output_matrix,
                                               recorder.output_offset))
    # the orientation's error times the lever: scaled by nothing, held in gaps with the rest
    orientation = orientation_rows(recorder.angle_variance, recorder.x, position)
    scale = np.ones(len(status))
    if watcher is not None:
        status, position, variance, scale = monitored_output(
            status, position, variance, recorder, since, watcher.params.horizon_edges_s,
            orientation)
    else:
        variance = variance + orientation
    # the marker layout's common error, last: the Tracker adds it to its reading's covariance
    variance = variance + recorder.layout_variance[:, None]
    status, std = bounded_rows(status, variance)
    result = TrackResult(t=np.array(recording.mocap.t), position=position, std=std,
                         status=status, time_since_fix=since, method="kalman")
    return FilterRun(result=result, x=recorder.x, P=recorder.P,
                     output_matrix=recorder.output_matrix, output_offset=recorder.output_offset,
                     outcome=recorder.outcome.astype(str), nis=recorder.nis,
                     counters={**recorder.counters, "held_poses": held}, params=params,
                     monitor=None if watcher is None else watcher.report(),
                     variance_scale=scale)


def filter_recording(recording: Recording, params: KalmanParameters | None = None, *,
                     monitor: MonitorParameters | None = MonitorParameters(),  # noqa: B008
                     measurement: str = BODY, engine: str = DEFAULT_ENGINE,
                     **overrides: Any) -> TrackResult:
    """Method ``kalman``: the streaming filter's estimate at every mocap row.

    Args:
        recording: the recording (occluded mocap rows are NaN).
        params: parameters; None builds them from ``recording.info.imu`` (see
            :meth:`KalmanParameters.from_profiles`).
        monitor: consistency monitor settings (None: off).
        measurement: ``body`` (rigid-body fixes) or ``markers`` (marker-level fusion).
        engine: ``compiled`` or ``filterpy`` (see :func:`run_filter`).
        overrides: parameter fields to replace (e.g. ``max_bridge_s=0.5``).

    Returns:
        TrackResult with one row per mocap row: position (m), 1-sigma per axis from P scaled by
        the monitor in gaps (m), status tracked/bridged/lost and time since the last accepted
        fix (s).
    """
    return run_filter(recording, params, monitor=monitor, measurement=measurement,
                      engine=engine, **overrides).result
