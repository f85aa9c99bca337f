"""Offline fixed-interval Rauch-Tung-Striebel smoother over the filter's model, with B u included.

filterpy's ``rts_smoother`` recomputes the prediction as ``F x`` and so drops the control input
``B u`` (filterpy issue #164): with the IMU as control input that is wrong at every step. Here the
backward pass runs over the *stored* predicted and filtered states of the forward filter, in which
``B u`` is already contained, so the control input needs no special treatment.

The forward pass is :class:`kfusion.kalman.KalmanFusion` itself. Between two mocap rows k and k+1
it runs many IMU predictions; the smoother only needs the rows, so it keeps per row:

* ``x_k, P_k``: filtered state after row k;
* ``x_{k+1|k}, P_{k+1|k}``: predicted state at row k+1 before its update (equal to the filtered
  one when the row is occluded or gated; including any re-acquisition inflation);
* ``Phi_{k+1}``: the product of the transition matrices F of the IMU steps between them.

Since the steps in between are linear, ``cov(x_k, x_{k+1|k}) = P_k Phi_{k+1}^T`` exactly, and the
RTS recursion over rows is::

    C_k   = P_k Phi_{k+1}^T P_{k+1|k}^-1
    x_k^s = x_k + C_k (x_{k+1}^s - x_{k+1|k})
    P_k^s = P_k + C_k (P_{k+1}^s - P_{k+1|k}) C_k^T

starting from the last filtered row (``x^s = x``). Orientation is the forward filter's.

Consistency (:mod:`kfusion.monitor`): the forward filter carries the online monitor, and the
smoothed bound is checked offline by *hold-out gaps*, the smoother's shadow gaps. Fixes where
the mocap is visible are hidden in a copy of the recording, in gaps as long as the recording's
own (:func:`holdout_scales`); the copy is smoothed, and the errors at the hidden fixes against
the smoothed covariance give a variance scale per horizon (distance to the nearest fix), matched
at the bound's confidence exactly as the online shadow gaps are. The real gaps' covariance is
scaled by it, or the rows are ``lost`` when the scale needed exceeds ``max_std_scale``. It costs
one more smoother pass over the recording (skipped when it has no gap to bridge). The rows at
fixes, which the hold-out never samples (and whose P, far below the fixes' noise R, no test
against the fixes can check), carry the forward monitor's scale when it found the IMU model too
confident (:func:`model_scale`) and reach any fix that contradicts them
(:func:`fix_residual_rivals`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Final

import numpy as np
from numpy.typing import NDArray

from kfusion.conventions import BRIDGED, LOST, TRACKED, median_interval
from kfusion.kalman.batch import (
    BODY,
    MARKERS,
    _RowRecorder,
    apply_monitor,
    check_engine,
    compiled_points,
    compiled_rows,
    fix_only_rows,
    kernel_inputs,
    make_fusion,
    make_monitor,
    marker_fix_parameters,
    marker_inputs,
    measurement_engine,
    monitored_kernel_rows,
    monitored_output,
    orientation_rows,
    point_estimates,
    process_recording,
    resolve_parameters,
    row_position_covariances,
    status_from_fixes,
)
from kfusion.kalman.engines import DEFAULT_ENGINE
from kfusion.kalman.filter import ACCEPTED, GATED, INITIALISED, USED_OUTCOMES, UpdateOutcome
from kfusion.kalman.markers import shared_run_lengths
from kfusion.kalman.parameters import KalmanParameters
from kfusion.monitor import (
    ConsistencyMonitor,
    HorizonScales,
    MonitorParameters,
    MonitorReport,
    bridging_allowed,
    chi2_quantile,
    edge_frames,
    edge_sensitivity,
    edge_variance_needed,
    fixes_before_gaps,
    mean_beyond_limit,
    nis_matching_scale,
    normalised_error_squared,
    quantile_matching_scale,
    required_scales,
    smoothed_edge_sensitivity,
    step_offset_variance,
)
from kfusion.recording import (
    MarkerFrames,
    MocapFrames,
    Recording,
    occlusion_durations,
    occlusion_runs,
    without_held_frames,
)
from kfusion.track_file import TrackResult, bounded_rows

if TYPE_CHECKING:
    from kfusion.kalman.compiled import Replay  # numba: loaded with the compiled engine only


def rts_step(x_filtered: NDArray[np.float64], P_filtered: NDArray[np.float64],
             x_predicted: NDArray[np.float64], P_predicted: NDArray[np.float64],
             transition: NDArray[np.float64], x_smoothed_next: NDArray[np.float64],
             P_smoothed_next: NDArray[np.float64]
             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """One backward RTS step (equations in the module docstring); shapes (9,) and (9, 9).

    ``x_predicted, P_predicted`` are the next row's prediction (with ``B u`` included) and
    ``transition`` the product of F from this row to the next.
    """
    # C = P_k Phi^T P_pred^-1  <=>  C^T = P_pred^-1 Phi P_k  (both covariances symmetric)
    C = np.linalg.solve(P_predicted, transition @ P_filtered).T
    x = x_filtered + C @ (x_smoothed_next - x_predicted)
    P = P_filtered + C @ (P_smoothed_next - P_predicted) @ C.T
    return x, 0.5 * (P + P.T)


def rts_backward(x_filtered: NDArray[np.float64], P_filtered: NDArray[np.float64],
                 x_predicted: NDArray[np.float64], P_predicted: NDArray[np.float64],
                 transitions: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Backward pass over rows 0..n-1: (n, 9), (n, 9, 9) arrays where row k+1 holds the
    prediction from row k and ``transitions[k+1]`` the product of F from row k to k+1 (row 0's
    prediction and transition are unused). Returns the smoothed states and covariances."""
    x_smoothed = np.array(x_filtered, dtype=float, copy=True)
    P_smoothed = np.array(P_filtered, dtype=float, copy=True)
    for k in range(len(x_filtered) - 2, -1, -1):
        x_smoothed[k], P_smoothed[k] = rts_step(
            x_filtered[k], P_filtered[k], x_predicted[k + 1], P_predicted[k + 1],
            transitions[k + 1], x_smoothed[k + 1], P_smoothed[k + 1])
    return x_smoothed, P_smoothed


@dataclass(frozen=True)
class SmootherRun:
    """Smoother output with the forward filter's, one row per mocap row.

    The forward filter's rows are kept as point estimates (``filtered``), not as states: the
    compiled backward pass overwrites each filtered state with the smoothed one, so a run keeps
    one (x, P) per row. The filtered states are :func:`kfusion.kalman.run_filter`'s (the same
    forward filter; the monitor never changes its state).

    Attributes:
        result: smoothed TrackResult (method ``smoother``).
        filtered: the forward filter's TrackResult (method ``kalman``) from the same pass.
        x: (m, n) smoothed state (n = 9 or 12; NaN before the first fix).
        P: (m, n, n) smoothed covariance.
        outcome: (m,) update outcomes of the forward pass.
        nis: (m,) NIS of each row's fix in the forward pass (NaN where none was compared).
        params: the parameters used.
        monitor: the forward filter's consistency report (None without a monitor).
        holdout: the hold-out gaps' scales (None without a monitor or without gaps).
        output_matrix: (m, 3, n) H at each row (rigid-body point ``H x + c``). Without the
            lever-arm states it is ``[I 0 0]`` on every row, a read-only view of one (3, n)
            matrix (:func:`kfusion.kalman.model.output_matrices`); a pickled run comes back
            with a full copy.
    """

    result: TrackResult
    filtered: TrackResult
    x: NDArray[np.float64]
    P: NDArray[np.float64]
    outcome: NDArray[np.str_]
    nis: NDArray[np.float64]
    params: KalmanParameters
    monitor: MonitorReport | None = None
    holdout: HorizonScales | None = None
    output_matrix: NDArray[np.float64] | None = None


def contested_fixes(outcome: NDArray[np.str_]) -> NDArray[np.bool_]:
    """(m,) True at a fix fused after gated ones (since the previous fused fix): the gate
    rejected frames in between, so the data contradict either this fix or the prediction it
    replaced (a marker swap passing the gate once the prediction grew loose, or the marker's
    return). The backward pass does not smooth across it."""
    outcome = np.asarray(outcome).astype(str)
    used = np.isin(outcome, USED_OUTCOMES)
    contested = np.zeros(len(outcome), dtype=bool)
    gated_since_fix = False
    for row, kind in enumerate(outcome.tolist()):
        if used[row]:
            contested[row] = gated_since_fix
            gated_since_fix = False
        elif kind == GATED:
            gated_since_fix = True
    return contested


def first_fix_rows(t: NDArray[np.float64], outcome: NDArray[np.str_], window_s: float
                   ) -> NDArray[np.bool_]:
    """Rows (m,) bool less than ``window_s`` s after a fix that initialised the state (a
    recording's first, or the first after a reset), from that fix on: the rows resting on a
    body's first fixes, which nothing before them checked (:attr:`kfusion.monitor.
    ConsistencyMonitor.model_tested`)."""
    starts = np.asarray(t, dtype=float)[np.asarray(outcome) == INITIALISED]
    if len(starts) == 0:
        return np.zeros(len(t), dtype=bool)
    index = np.searchsorted(starts, t, side="right") - 1
    since = np.where(index >= 0, t - starts[np.maximum(index, 0)], np.inf)
    return since < window_s


def initialised_segments(outcome: NDArray[np.str_], initialised: NDArray[np.bool_]
                         ) -> list[tuple[int, int]]:
    """Row ranges ``[first, stop)`` over which the filter ran without a re-initialisation and
    without a contested fix (:func:`contested_fixes`): each starts at an ``initialised`` or a
    contested fix and stops before the next one or where the state was forgotten (an overflow
    reset). The backward pass runs over each separately."""
    segments = []
    starts = np.flatnonzero((outcome == INITIALISED) | contested_fixes(outcome))
    for index, first in enumerate(starts):
        limit = int(starts[index + 1]) if index + 1 < len(starts) else len(outcome)
        lost = np.flatnonzero(~initialised[first:limit])
        stop = int(first + lost[0]) if len(lost) else limit
        segments.append((int(first), stop))
    return segments


def smoother_status(t: NDArray[np.float64], fixed: NDArray[np.bool_], max_bridge_s: float,
                    dead_reckoned: NDArray[np.bool_] | None = None, *,
                    engine: str = "filterpy") -> NDArray[np.str_]:
    """Smoother status per row: the status rule (:func:`kfusion.streamhealth.tracking_status`)
    as the forward filter applies it: ``tracked`` at used fixes; ``lost`` before the first fix
    (the forward pass had no state there), in a gap the IMU did not cover (not
    ``dead_reckoned``; None: every row is) and more than ``max_bridge_s`` after the last fix;
    ``bridged`` in between. ``engine``: that of :func:`kfusion.kalman.batch.row_statuses`.

    The fix after a row does not shorten the time it is measured from. The backward pass
    carries that fix back through the IMU samples rotated by the forward filter's orientation,
    which in a long gap has run on the gyroscope alone since the last fix: after a 60 s
    occlusion (simulated ``random_reach``, seed 1) the orientation was 3 degrees off (its own
    1-sigma), and the rows in the last second before the re-acquiring fix, bridged from it,
    were 4-435 mm off (0.43 m/s^2 times tau^2) against 99 % bounds of 1.3-71 mm, 8x at worst
    (an adversarial review). The smoothed covariance holds no term for that orientation
    error, so the rows more than ``max_bridge_s`` after a fix are lost, as the filter's are
    (within it the orientation is the one the monitor's shadow gaps test). That is the filter's
    :func:`kfusion.kalman.batch.status_from_fixes` with every row initialised."""
    initialised = np.ones(len(np.asarray(t)), dtype=bool)
    return status_from_fixes(t, fixed, initialised, max_bridge_s, dead_reckoned,
                             engine=engine)[0]


def nearest_fix_distance(t: NDArray[np.float64], fixed: NDArray[np.bool_]
                         ) -> NDArray[np.float64]:
    """Per row, s to the nearest used fix before or after it (0 at fixes, inf without one)."""
    t = np.asarray(t, dtype=float)
    fixed = np.asarray(fixed, dtype=bool)
    last = np.maximum.accumulate(np.where(fixed, t, -np.inf))
    following = np.minimum.accumulate(np.where(fixed, t, np.inf)[::-1])[::-1]
    return np.minimum(t - last, following - t)


def partial_occlusion_floor(recording: Recording, smoothed_variance: NDArray[np.float64],
                            filtered_variance: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per-axis variance (m, 3) m^2 of the smoothed rows, at least the forward filter's on the
    rows with 1 or 2 visible markers (marker-level fusion).

    There the markers are placed with the gyroscope's orientation, the forward filter's: the
    smoother does not smooth the orientation, and its backward pass combines frames whose
    orientation errors are one slowly drifting error, so the smoothed covariance would claim
    more than the data give (measured on simulated partial occlusions: 3 sigma coverage 0.96
    on one-marker rows, with errors that follow the episode's orientation drift). The forward
    bound there is honest (coverage 0.994); the smoothed position is kept."""
    counts = np.isfinite(marker_inputs(recording)[0]).all(axis=2).sum(axis=1)
    few = ((counts > 0) & (shared_run_lengths(counts) > 0))[:, None]
    floored = np.maximum(smoothed_variance, filtered_variance)
    return np.where(few & np.isfinite(filtered_variance), floored, smoothed_variance)


def fix_noise_variance(params: KalmanParameters, nis: NDArray[np.float64],
                       outcome: NDArray[np.str_]) -> float:
    """The fixes' noise variance (m^2 per axis): R, matched down by a forward pass's NIS over
    its accepted fixes when that shows R pessimistic (mean NIS below 3), as in the online
    monitor's shadow innovations."""
    accepted = np.asarray(nis)[np.asarray(outcome).astype(str) == ACCEPTED]
    return float(params.mocap_position_noise ** 2 * min(1.0, nis_matching_scale(accepted)))


def model_scale(std_scale: float) -> float:
    """Variance scale (>= 1) of the smoothed rows at fixes from the forward monitor's std
    scale (:attr:`kfusion.monitor.MonitorReport.std_scale`, the largest its shadow gaps or
    innovations needed): ``max(1, std_scale^2)``.

    The hold-out (:func:`holdout_scales`) never samples a fix, and no test against the fixes
    can check a smoothed P far below their noise R there: the smoothed row at a fix rests on
    the IMU model that carries its neighbours' fixes to it. The forward pass's shadow gaps
    reach horizons where that model dominates; where they found it too confident, the row
    carries their scale: ``s P+``, the upper bound of
    :func:`kfusion.monitor.fix_covariance_under_scale` (equal to it when P+ is far below R).
    Measured with the IMU's noise 4 times its profile: the smoothed rows at fixes needed a
    standard-deviation scale of 1.14 against the truth and the monitor's was 1.14. A scale
    below 1 (a pessimistic profile) leaves the rows as they are."""
    return max(1.0, std_scale * std_scale)


def fix_residual_rivals(fixed: NDArray[np.bool_], residual: NDArray[np.float64],
                        noise_variance: float, confidence: float = 0.99
                        ) -> NDArray[np.float64]:
    """Per-axis variance (m, 3) m^2 a smoothed row at a fix needs to reach its fix when the
    fix contradicts it.

    At a fused fix the smoothed residual ``r = z - x^s`` (fix minus smoothed position, (m, 3)
    m; NaN where there is no fix) has covariance ``R - P^s`` under the model, at most R. A
    residual beyond ``|r|^2 / R > F^-1_chi2(3)(c)`` is a fix the smoother averaged away with
    the IMU model (motion the model does not have, or an IMU worse than its profile): the data
    then leave two positions open, and the bound holds both, as it holds the monitor's gated
    fixes (:meth:`kfusion.monitor.ConsistencyMonitor.cover_rivals`): the row gets ``r_i^2`` per
    axis. Zero at every other row (the rows between fixes are the hold-out's,
    :func:`holdout_scales`) and where ``noise_variance`` is not positive."""
    residual = np.asarray(residual, dtype=float)
    rival = np.zeros((len(residual), 3))
    marked = np.asarray(fixed, dtype=bool) & np.isfinite(residual).all(axis=1)
    if not noise_variance > 0.0:
        return rival
    square = np.where(marked[:, None], residual, 0.0) ** 2
    beyond = marked & (square.sum(axis=1) > noise_variance * chi2_quantile(confidence, 3))
    rival[beyond] = square[beyond]
    return rival


def holdout_scales(recording: Recording, params: KalmanParameters, monitor: MonitorParameters,
                   seed: int = 0, measurement: str = BODY, engine: str = DEFAULT_ENGINE
                   ) -> HorizonScales | None:
    """The smoother's shadow gaps: hide visible fixes in gaps as long as the recording's own
    (those up to ``max_bridge_s``), smooth the copy, and collect per gap the variance scale
    each hidden fix needed (:func:`kfusion.monitor.required_scale`) by its distance to the
    nearest fix, in the bins ``monitor.holdout_edges_s``. The error is taken against the
    smoothed covariance plus the hidden fix's noise R, with R matched down by the forward pass's
    NIS when that is below 3 (the smoothed P is of the order of the mocap noise, so a wrong R
    decides the scale). None when the recording has no gap to
    bridge or no room for a hold-out gap. Hold-out gaps sit where the mocap is visible for
    0.5 s before and through them."""
    mocap = recording.mocap
    durations = occlusion_durations(mocap.t, mocap.visible)
    durations = durations[durations <= params.max_bridge_s]
    if len(durations) == 0:
        return None
    frame = median_interval(mocap.t, default=0.01)
    low = max(float(durations.min()) - frame, frame)
    high = max(float(durations.max()) - frame, low)
    from kfusion.evaluate import cut_gaps  # pandas: kept out of kfusion.tracker's imports

    hidden = cut_gaps(recording, rng=np.random.default_rng(seed), gap_range=(low, high),
                      spacing=0.5)
    if not hidden.gap_mask.any():
        return None
    run = run_smoother(hidden.recording, params, monitor=None, measurement=measurement,
                       engine=engine)
    fixed = run.result.status == TRACKED
    assert run.output_matrix is not None
    horizon = nearest_fix_distance(mocap.t, fixed)
    # the hidden fix's noise: R, matched down by the NIS when that shows it pessimistic (as in
    # the online monitor's shadow innovations)
    noise = fix_noise_variance(params, run.nis, run.outcome)
    # matched at the bound's own confidence: the hold-out gaps sample the same recording the
    # real gaps are in (the online monitor's shadows predict gaps still to come)
    scales = HorizonScales(dataclasses.replace(monitor, memory=len(mocap.t),
                                               horizon_edges_s=monitor.holdout_edges_s,
                                               max_std_scale=monitor.holdout_max_std_scale,
                                               matching_quantile=monitor.confidence))
    bridged = run.result.status == BRIDGED
    for start, stop in occlusion_runs(~hidden.gap_mask):
        rows = start + np.flatnonzero(bridged[start:stop])
        covariance = row_position_covariances(run.P, run.output_matrix, rows) + noise * np.eye(3)
        scales.add_gap(horizon[rows], required_scales(
            run.result.position[rows] - hidden.truth_position[rows], covariance,
            monitor.confidence))
    return scales


EDGE_DOUBLINGS: Final = 3
"""How many times :func:`edge_holdout` may double the fixes it hides before each gap, from the
first span that disagreed (8 times it: 0.24 s at 100 Hz from ``edge_s``, 0.64 s from the
80 ms of ``longer_edges_s``)."""


def edge_rows(t: NDArray[np.float64], fixed: NDArray[np.bool_], monitor: MonitorParameters,
              frames: int) -> NDArray[np.bool_]:
    """(m,) True at the last ``frames`` fixes before each gap
    (:func:`kfusion.monitor.fixes_before_gaps`, gaps of at least ``settle_after_s``)."""
    before, _ = fixes_before_gaps(t, fixed, monitor.settle_after_s)
    return (before >= 0) & (before < frames)


def _hidden_edge_fixes(recording: Recording, params: KalmanParameters,
                       monitor: MonitorParameters, before: NDArray[np.int64], frames: int,
                       measurement: str, engine: str
                       ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Hide the last ``frames`` fixes before each gap (``before`` (m,): each fix's count of
    fixes to the next gap, :func:`kfusion.monitor.fixes_before_gaps`), smooth the copy
    without the monitor, and compare each hidden fix z with the smoothed point there,
    ``r = z - p_s``, against ``S = P_s + R`` (R matched down by the copy's NIS when that
    shows it pessimistic, :func:`fix_noise_variance`). Returns the hidden rows (k,) that the
    smoother did not lose, their NIS ``r^T S^-1 r`` (k,) and the offset variance each needed
    (k,) (:func:`kfusion.monitor.edge_variance_needed` with shape 1: the offset adds to the
    fix)."""
    mocap = recording.mocap
    hidden_rows = (before >= 0) & (before < frames)
    if not hidden_rows.any():
        return np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0)
    position = np.where(hidden_rows[:, None], np.nan, mocap.position)
    quaternion = np.where(hidden_rows[:, None], np.nan, mocap.quaternion)
    hidden = recording.with_mocap(MocapFrames(t=mocap.t, position=position,
                                              quaternion=quaternion))
    if recording.markers is not None and np.array_equal(recording.markers.t, mocap.t):
        hidden = dataclasses.replace(hidden, markers=MarkerFrames(
            t=recording.markers.t, names=recording.markers.names,
            position=np.where(hidden_rows[:, None, None], np.nan,
                              recording.markers.position)))
    run = run_smoother(hidden, params, monitor=None, measurement=measurement, engine=engine)
    assert run.output_matrix is not None
    rows = np.flatnonzero(hidden_rows & (run.result.status != LOST)
                          & np.isfinite(mocap.position).all(axis=1))
    noise = fix_noise_variance(params, run.nis, run.outcome)
    covariance = row_position_covariances(run.P, run.output_matrix, rows) + noise * np.eye(3)
    residual = mocap.position[rows] - run.result.position[rows]
    nis = np.array([normalised_error_squared(residual[k], covariance[k])
                    for k in range(len(rows))])
    needed = np.array([edge_variance_needed(residual[k], covariance[k], 1.0,
                                            monitor.confidence) for k in range(len(rows))])
    return rows, nis, needed


def edge_holdout(recording: Recording, params: KalmanParameters, monitor: MonitorParameters,
                 measurement: str = BODY, engine: str = DEFAULT_ENGINE) -> tuple[float, int]:
    """(per-axis variance m^2, fixes): an offset on the last fixes before the recording's gaps
    (a marker cluster partly occluded as the occlusion begins shifts the solved body), tested
    offline by hiding them (:func:`_hidden_edge_fixes`).

    The fixes within ``edge_s`` are hidden first. When their NIS's mean is within the windowed
    test's upper limit at ``nis_probability`` they agree with the motion around them, and the
    fixes within each of ``longer_edges_s`` are hidden in turn (the offset fixes left before a
    hidden few pull the smoothed point toward them: on the body 0.7 mm off on the 5 frames
    before each occlusion, 2 of 5 simulated seeds passed the 30 ms hold-out and had 2.5 % and
    3.2 % of the rows beyond the 99 % bound); when none fails: (0, ``edge_s``'s fixes). Else,
    from the first that fails, twice as many are hidden, and while the outer half of them
    fails the same test too (the offset is longer than assumed), twice as many again, up to
    :data:`EDGE_DOUBLINGS` times; when the outer half agrees but the whole hold-out still
    disagrees, the hold-out's length is returned (an offset a little longer than the span shows
    in few outer fixes, deep in the hold-out where the smoothed point is loose: 0.7 mm on 10
    frames, seeds 0-4, 1.80 % of the rows beyond the 99 % bound returning the span, 0.91 %
    returning the hold-out; 1 mm on 9 frames 0.49 % -> 0.09 %; a 3-frame offset is covered
    over 6, its gap rows' median bound / error 4.6 -> 5.0 for 0.7 mm). The variance is the
    ``matching_quantile`` of
    what the first fixes needed, and of what each failing outer half needed, whichever is
    largest: each is measured where its hold-out is shortest (a long hold-out's inner fixes
    are extrapolated further, and on a tapping trial one of them set a 6.6 mm offset where the
    fixes were 1.5 mm off). (0, 0) without gaps."""
    before, period = fixes_before_gaps(recording.mocap.t, recording.mocap.visible,
                                       monitor.settle_after_s)
    if not period > 0 or not (before >= 0).any():
        return 0.0, 0
    spans = [edge_frames(span, period) for span in monitor.edge_spans_s]
    for frames in sorted(set(spans)):
        _, nis, needed = _hidden_edge_fixes(recording, params, monitor, before, frames,
                                            measurement, engine)
        if mean_beyond_limit(nis, monitor.nis_probability):
            break
    else:
        return 0.0, spans[0]
    variance = quantile_matching_scale(needed, monitor.matching_quantile)
    for _ in range(EDGE_DOUBLINGS):
        rows, nis, needed = _hidden_edge_fixes(recording, params, monitor, before,
                                               2 * frames, measurement, engine)
        outer = before[rows] >= frames
        if not mean_beyond_limit(nis[outer], monitor.nis_probability):
            # the outer half agreeing does not show the offset ends within frames: an offset a
            # little longer shows in few of the outer fixes, and those lie deep in the longer
            # hold-out, extrapolated far, with small NIS whatever their offset; while the whole
            # hold-out still disagrees, it is the cover
            if mean_beyond_limit(nis, monitor.nis_probability):
                frames *= 2
            break
        variance = max(variance,
                       quantile_matching_scale(needed[outer], monitor.matching_quantile))
        frames *= 2
    return variance, frames


def smoothed_edge_shape(t: NDArray[np.float64], fixed: NDArray[np.bool_],
                        time_since_fix_s: NDArray[np.float64], params: KalmanParameters,
                        monitor: MonitorParameters, frames: int) -> NDArray[np.float64]:
    """(m,) factor of the edge offset's variance (:func:`edge_holdout`, on the last ``frames``
    fixes before each gap) in each smoothed row (times ``t`` (m,) s, ``fixed`` (m,) bool,
    ``time_since_fix_s`` (m,) s): at a fix j fixes before a gap, the square of the smoothed
    rows' sensitivity to an offset on the last fixes before it
    (:func:`kfusion.monitor.smoothed_edge_sensitivity`); in a gap h s after such a fix, the
    forward filter's ``(a + b h)^2`` (:func:`kfusion.monitor.edge_sensitivity`: the smoothed
    row leans on it from the gap's near side, and on clean fixes from the far side, so its
    error is at most that); 0 elsewhere."""
    before, period = fixes_before_gaps(t, fixed, monitor.settle_after_s)
    shape = np.zeros(len(t))
    if not period > 0:
        return shape
    reach = np.asarray(smoothed_edge_sensitivity(
        params.accelerometer_noise_density, params.mocap_position_noise, period, frames,
        max(60, 2 * frames)))
    near = (before >= 0) & (before < len(reach))
    shape[near] = reach[before[near]] ** 2
    # in a gap: rows without a fix after a fix that ends a run before a gap (before == 0)
    last_fix = np.maximum.accumulate(np.where(fixed, np.arange(len(t)), -1))
    in_gap = ~fixed & (last_fix >= 0) & np.isfinite(time_since_fix_s)
    in_gap[in_gap] = before[last_fix[in_gap]] == 0
    a, b = edge_sensitivity(params.accelerometer_noise_density, params.mocap_position_noise,
                            period, frames)
    shape[in_gap] = (a + b * time_since_fix_s[in_gap]) ** 2
    return shape


def compiled_steps(recording: Recording, params: KalmanParameters,
                   watcher: ConsistencyMonitor | None, *, stepwise: bool = False
                   ) -> tuple[_RowRecorder, Replay]:
    """The smoother's forward pass on the compiled engine with the consistency monitor: in two
    passes (:func:`kfusion.kalman.batch.monitored_kernel_rows`, the recorder's ``monitor`` is
    then the two-pass run's; the whole-loop kernel keeps each row's packed prediction), or,
    with ``stepwise`` or where the kernel cannot run it, step by step
    (:class:`kfusion.kalman.compiled_fusion.CompiledFusion` fed by :func:`kfusion.kalman.batch.
    process_recording`, watched by the consistency monitor ``watcher``), keeping each row's
    filtered state and the packed state after every :data:`~kfusion.kalman.compiled.
    SAVE_EVERY`-th row, from which the compiled backward pass recomputes the per-row
    predictions (:func:`kfusion.kalman.compiled.smooth_in_place`): the monitor only reads the
    filter (snapshots for its shadow filter, estimates as priors), so the kernel's replay of the
    same events gives the same predictions."""
    from kfusion.kalman import compiled

    if watcher is not None and not stepwise:
        monitored = monitored_kernel_rows(recording, params, watcher.params, smoothing=True)
        if monitored is not None:
            return monitored[0], monitored[2]
    inputs = kernel_inputs(recording, params.imu_latency_s)
    fusion: Any = make_fusion(recording, params, "compiled")
    recorder = _RowRecorder(fusion, len(recording.mocap), watcher)
    every = compiled.SAVE_EVERY
    saved_states = np.zeros((len(recording.mocap) // every, compiled.packed_size(fusion.size)))

    def on_row(row: int, outcome: UpdateOutcome) -> None:
        recorder.record(row, outcome)
        if (row + 1) % every == 0:
            saved_states[(row + 1) // every - 1] = fusion.snapshot().state

    process_recording(recording, fusion, on_row, watcher)
    recorder.finish()
    config = make_fusion(recording, params).kernel_config()  # CompiledFusion's, built alike
    replay = compiled.Replay(compiled.kernel_inputs(*inputs), config,
                             compiled.initial_state(fusion.size), saved_states)
    return recorder, replay


def frames_in_time_order(t: NDArray[np.float64]) -> None:
    """ValueError naming the first mocap row stamped before the row above it (``t`` (m,) s).

    The filter fuses the frames in time order whatever their rows, but the backward pass pairs
    each row with the next row's prediction, which was made from the row fused before it in
    time: a frame stamped 1000 s ahead (the readers refuse it; a recording built in code may
    hold it) got the backward step of a row it was never predicted from, and a smoothed
    variance of -7e-8 m^2: ``tracked`` with a NaN std, in either engine."""
    steps = np.diff(np.asarray(t, dtype=float))
    if (steps < 0).any():
        row = int(np.flatnonzero(steps < 0)[0]) + 1
        raise ValueError(f"smoother: mocap.t: row {row} ({float(t[row])!r} s) is earlier than "
                         f"row {row - 1} ({float(t[row - 1])!r} s); the smoother needs the "
                         "frames in time order")


def run_smoother(recording: Recording, params: KalmanParameters | None = None, *,
                 monitor: MonitorParameters | None = MonitorParameters(),  # noqa: B008 (frozen)
                 measurement: str = BODY, engine: str = DEFAULT_ENGINE,
                 stepwise: bool = False, **overrides: Any) -> SmootherRun:
    """Forward :class:`KalmanFusion` pass storing rows, then the RTS backward pass; with a
    ``monitor`` (default), the forward filter's online monitor and the hold-out check of the
    smoothed bound (module docstring). ``measurement``: ``body`` or ``markers``
    (:func:`kfusion.kalman.batch.process_recording`, offline: with markers the forward pass
    counts each partial-occlusion run's gyroscope orientation error once per run, so its
    ``filtered`` rows there are more cautious than :func:`kfusion.kalman.run_filter`'s).
    ``engine``: ``compiled`` runs both passes as numba kernels
    (:func:`kfusion.kalman.compiled.filter_events`, :func:`~kfusion.kalman.compiled.
    smooth_rows`: the forward pass keeps each row's prediction and transition product packed,
    in about 0.8 of an (x, P), and the backward pass reads them) when there is no monitor (which
    watches a filter event by event);
    ``filterpy`` runs :class:`KalmanFusion` and the numpy backward pass; marker-level fusion
    runs on filterpy (:func:`kfusion.kalman.batch.measurement_engine`). With a monitor the
    compiled forward pass runs in two passes (:func:`compiled_steps`), or event by event with
    ``stepwise`` (the reference the two passes equal bit for bit). ValueError when a mocap
    stamp is earlier than the row before it (:func:`frames_in_time_order`)."""
    check_engine(engine)
    engine = measurement_engine(engine, measurement)
    frames_in_time_order(recording.mocap.t)
    recording, _ = without_held_frames(recording)  # poses held through occlusions
    params = resolve_parameters(recording, params, overrides)
    if measurement == MARKERS:
        params = marker_fix_parameters(params, marker_inputs(recording)[1])
    watcher = make_monitor(recording, params, monitor, engine)
    m = len(recording.mocap)
    rows: tuple[_RowRecorder, Replay] | None = None
    if engine == "compiled" and watcher is None:
        # the whole forward loop in one kernel, keeping each row's packed prediction
        kernel = compiled_rows(recording, make_fusion(recording, params), smoothing=True)
        rows = None if kernel is None else (kernel[0], kernel[1].replay)
    elif engine == "compiled":
        # the monitor watches the filter event by event: the compiled filter step by step
        rows = compiled_steps(recording, params, watcher, stepwise=stepwise)
        watcher = rows[0].monitor  # the two-pass run's monitor, or watcher itself
    replay = None
    if rows is not None:
        recorder, replay = rows
    else:
        fusion = make_fusion(recording, params)
        size = fusion.size
        recorder = _RowRecorder(fusion, m, watcher)
        x_predicted = np.full((m, size), np.nan)
        P_predicted = np.full((m, size, size), np.nan)
        transitions = np.full((m, size, size), np.nan)
        fusion._interval = np.eye(size)

        def on_row(row: int, outcome: UpdateOutcome) -> None:
            recorder.record(row, outcome)
            if fusion.initialised:
                prior = fusion._prior
                if prior is None:  # nothing fused at this row: the prediction is the state
                    prior = (recorder.x[row], recorder.P[row])
                x_predicted[row], P_predicted[row] = prior
                transitions[row] = fusion._interval
            fusion._interval = np.eye(size)

        process_recording(recording, fusion, on_row, watcher, measurement, offline=True)
        recorder.finish()
    segments = initialised_segments(recorder.outcome.astype(str), recorder.initialised)
    t = np.array(recording.mocap.t)
    fixed = recorder.fixed
    status_engine = "compiled" if replay is not None else "filterpy"
    filtered_status, since = status_from_fixes(t, fixed, recorder.initialised,
                                               params.max_bridge_s, recorder.dead_reckoned,
                                               engine=status_engine)
    # a gap the IMU did not cover (the forward pass's no-IMU rows) is lost for the smoother too
    smoothed_status = smoother_status(t, fixed, params.max_bridge_s, recorder.dead_reckoned,
                                      engine=status_engine)

    position, variance = (compiled_points(recorder) if replay is not None else
                          point_estimates(recorder.x, recorder.P, recorder.output_matrix,
                                          recorder.output_offset))
    # the forward rows as run_filter reports them, with the orientation's error times the lever
    orientation = orientation_rows(recorder.angle_variance, recorder.x, position)
    if watcher is not None:
        filtered_status, position, variance, _ = monitored_output(
            filtered_status, position, variance, recorder, since,
            watcher.params.horizon_edges_s, orientation)
    else:
        variance = variance + orientation
    filtered_status, filtered_std = bounded_rows(filtered_status, variance)
    filtered = TrackResult(t=t, position=position, std=filtered_std,
                           status=filtered_status, time_since_fix=since, method="kalman")
    if replay is not None:
        # in place: the recorder's filtered states become the smoothed ones (the filtered
        # rows' point estimates are in `filtered`); the backward pass reads the per-row
        # predictions the forward kernel kept, or recomputes them from its saved states
        from kfusion.kalman import compiled

        compiled.smooth_in_place(replay, recorder.x, recorder.P, segments)
        x_smoothed, P_smoothed = recorder.x, recorder.P
    else:
        x_smoothed = np.full((m, recorder.x.shape[1]), np.nan)
        P_smoothed = np.full(recorder.P.shape, np.nan)
        for first, stop in segments:
            x_smoothed[first:stop], P_smoothed[first:stop] = rts_backward(
                recorder.x[first:stop], recorder.P[first:stop], x_predicted[first:stop],
                P_predicted[first:stop], transitions[first:stop])
    status = smoothed_status
    filtered_variance = variance
    position, variance = (compiled_points(recorder, x_smoothed, P_smoothed)
                          if replay is not None else
                          point_estimates(x_smoothed, P_smoothed, recorder.output_matrix,
                                          recorder.output_offset))
    # the orientation is the forward filter's (not smoothed): its error times the lever, at
    # the forward filter's angle variance, is part of every smoothed row below
    variance = variance + orientation_rows(recorder.angle_variance, x_smoothed, position)
    if measurement == MARKERS:
        variance = partial_occlusion_floor(recording, variance, filtered_variance)
    report = None if watcher is None else watcher.report()
    # a body's first fixes may be solved off by as much as the step rule lets through, as the
    # forward pass shows them (ConsistencyMonitor.fix_only); the smoothed rows on them carry it
    # too (with a reset's first 10 frames 3 mm off: 4.5-6.2x beyond the bound without it, and
    # 3.7x at a recording's start)
    first_variance = np.zeros((m, 1)) if watcher is None else np.where(
        first_fix_rows(t, recorder.outcome.astype(str), watcher.params.reacquisition_rival_s),
        step_offset_variance(params.mocap_position_noise ** 2, watcher.params), 0.0)[:, None]
    if report is not None:
        # the smoothed rows at fixes rest on the forward pass's IMU model: where its shadow
        # gaps or innovations found it too confident, they carry that scale (model_scale)
        variance = np.where(fixed[:, None], variance * model_scale(report.std_scale), variance)
        # where the forward monitor widened a fused fix (its prediction, or the innovations,
        # found worse than the model says: ConsistencyMonitor.at_fix), the smoothed row rests
        # on the same fix and model: it is not presented as surer than that
        variance = np.where(np.isfinite(recorder.at_fix_variance),
                            np.maximum(variance, recorder.at_fix_variance), variance)
        variance = variance + first_variance
    edge_variance, edge_fixes = (0.0, 0) if monitor is None else edge_holdout(
        recording, params, monitor, measurement=measurement, engine=engine)
    if edge_variance > 0 and monitor is not None:
        shape = smoothed_edge_shape(t, fixed, since, params, monitor, edge_fixes)
        variance = variance + edge_variance * shape[:, None]
    holdout = None if monitor is None else holdout_scales(recording, params, monitor,
                                                          measurement=measurement,
                                                          engine=engine)
    if holdout is not None:
        bins = len(holdout.params.horizon_edges_s)
        table = np.broadcast_to(holdout.scale_table(), (m, bins))
        allowed = np.full(m, bridging_allowed(math.sqrt(float(table.max())), holdout.gaps,
                                              holdout.params))
        status, variance, _ = apply_monitor(status, variance, table, allowed,
                                            nearest_fix_distance(t, fixed),
                                            holdout.params.horizon_edges_s, forward=False)
    # the forward pass's rival hypotheses, less its edge term at fixes: online no fix is known
    # to end before an occlusion, so the filter covers every fix while the edge test is on;
    # offline the hold-out knows which do and covers those (edge_holdout, above)
    forward_rivals = np.maximum(recorder.rival_variance - recorder.fix_edge_variance[:, None],
                                0.0)
    if watcher is not None:
        # the forward pass's rival hypotheses (a gated fix, or the prediction a fix replaced
        # after gating) are positions the data left open, and so are the fixes the smoothed
        # rows miss by more than their noise: the smoothed bound holds them too
        noise = fix_noise_variance(params, recorder.nis, recorder.outcome)
        variance = (variance + forward_rivals
                    + fix_residual_rivals(fixed, recording.mocap.position - position, noise,
                                          watcher.params.confidence))
    # the smoothed rows are built on the IMU model wherever they are: when the hold-out or the
    # forward monitor (anywhere in the recording, once it had tested the model) refused it, or
    # the model was never tested (too few fixes), a row with a fix is that fix alone and every
    # other row is lost
    trusted = (holdout is None or bool(allowed.all())) and bool(recorder.tested.any()) and \
        bool(recorder.allowed[recorder.tested].all())
    if not trusted:
        fix_position = np.where(fixed[:, None], recording.mocap.position, np.nan)
        noise = params.mocap_position_noise ** 2
        widened = np.where(np.isfinite(recorder.at_fix_variance),
                           np.maximum(recorder.at_fix_variance, noise), noise)
        fix_variance = widened + forward_rivals
        fix_variance = fix_variance + first_variance  # a body's first fixes, as above
        if edge_variance > 0 and monitor is not None:
            # a fix shown alone is the offset fix itself (edge_holdout)
            fix_variance = fix_variance + np.where(edge_rows(t, fixed, monitor, edge_fixes),
                                                   edge_variance, 0.0)[:, None]
        status, position, variance = fix_only_rows(status, position, variance,
                                                   np.zeros(m, dtype=bool), fix_position,
                                                   fix_variance)
    # the marker layout's common error (kfusion.kalman.marker_layout): the same in every frame,
    # so no smoothing averages it down; the forward filter's at each row
    variance = variance + recorder.layout_variance[:, None]
    status, std = bounded_rows(status, variance)
    return SmootherRun(
        result=TrackResult(t=t, position=position, std=std, status=status,
                           time_since_fix=since, method="smoother"),
        filtered=filtered, x=x_smoothed, P=P_smoothed, outcome=recorder.outcome.astype(str),
        nis=recorder.nis,
        params=params, monitor=report, holdout=holdout,
        output_matrix=recorder.output_matrix)


def smooth_recording(recording: Recording, params: KalmanParameters | None = None, *,
                     monitor: MonitorParameters | None = MonitorParameters(),  # noqa: B008
                     measurement: str = BODY, engine: str = DEFAULT_ENGINE,
                     **overrides: Any) -> TrackResult:
    """Method ``smoother``: fixed-interval RTS estimate at every mocap row (offline gap filling).

    Args:
        recording: the recording (occluded mocap rows are NaN).
        params: parameters; None builds them from ``recording.info.imu``.
        measurement: ``body`` (rigid-body fixes) or ``markers`` (marker-level fusion).
        engine: ``compiled`` or ``filterpy`` (see :func:`run_smoother`).
        overrides: parameter fields to replace.

    Returns:
        TrackResult: smoothed position (m), 1-sigma per axis from the smoothed P (m), status
        (:func:`smoother_status`) and time since the last accepted fix (s, forward in time).
    """
    return run_smoother(recording, params, monitor=monitor, measurement=measurement,
                        engine=engine, **overrides).result
