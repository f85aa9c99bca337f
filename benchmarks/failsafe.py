"""Fail-safe benchmark (issue 9, "Show"): one row per broken assumption, per path.

For every fault (built by :mod:`kfusion.simulate.faults` on simulated recordings with truth, and
on the real BROAD trials when ``../shared`` holds them) each path is run the way a user would:

* ``tracker``: the streaming :class:`kfusion.tracker.Tracker` (Kalman), samples pushed in
  arrival order, ``estimate(now)`` asked after each mocap frame at its arrival time (when the
  tracker refuses a now behind its newest sample, the caller has no position: scored as lost,
  and counted);
* ``kalman`` and ``smoother``: ``kfusion check`` then ``kfusion track`` on the recording folder
  written to disk; a refusal by ``kfusion track`` (exit 2) counts as the tool refusing, never as
  confidently wrong.

Columns: samples scored (rows with truth), ``wrong`` = fraction of scored samples confidently
wrong (status not lost and |error| > bound(0.99)), ``worst`` = largest |error| / bound(0.99) over
rows not lost, the status mix, and what kfusion did (refusals with their message, fallbacks,
health counters). The batch bound is :func:`kfusion.tracker.position_bound` of the diagonal
covariance from the CSV's std columns. Target once the fail-safe issue lands: wrong <= 1 % and
worst <= 3 in every row.

The simulated recordings have occlusions of 0.1-0.5 s every 1.5 s or more, placed at random; the
row "IMU misses 0.3 s" has 0.4-0.6 s, and the clipping row has its occlusions at speed peaks
(``mid_motion``), where a clipped sensor misleads the dead reckoning.

Run: ``python benchmarks/failsafe.py --quick`` (< 2 minutes) or ``python benchmarks/failsafe.py``
(``--only TEXT``: the rows whose assumption contains TEXT).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import sys
import tempfile
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from kfusion.cli import main as cli
from kfusion.conventions import LOST, STANDARD_GRAVITY, median_interval
from kfusion.recording import write_recording
from kfusion.simulate import OcclusionSpec, faults, simulate
from kfusion.simulate.faults import Streams
from kfusion.tracker import DEFAULT_CONFIDENCE, Tracker, position_bound

CONFIDENCE = DEFAULT_CONFIDENCE
TARGET_WRONG = 0.01
TARGET_WORST = 3.0
BATCH_METHODS = ("kalman", "smoother")
SCENARIO = "random_reach"
REFUSED = "refused"


# ------------------------------------------------------------------------------ scoring


@dataclass
class Outcome:
    """One path's result on one recording: per scored row status, error and bound, or a
    refusal; ``notes`` counts what kfusion did."""

    status: list[str] = field(default_factory=list)
    error: list[float] = field(default_factory=list)
    bound: list[float] = field(default_factory=list)
    notes: Counter = field(default_factory=Counter)
    refusal: str | None = None

    def add(self, status: str, position: np.ndarray, bound: float, truth: np.ndarray) -> None:
        if not np.isfinite(truth).all():
            return
        self.status.append(status)
        self.error.append(float(np.linalg.norm(position - truth)) if status != LOST else math.nan)
        self.bound.append(bound)


def merge(outcomes: list[Outcome]) -> Outcome:
    total = Outcome()
    for outcome in outcomes:
        total.status += outcome.status
        total.error += outcome.error
        total.bound += outcome.bound
        total.notes += outcome.notes
        if outcome.refusal is not None:
            total.notes[f"{REFUSED}: {outcome.refusal}"] += 1
    return total


def summarise(name: str, path: str, outcome: Outcome) -> dict[str, Any]:
    status = np.array(outcome.status, dtype=object)
    error = np.array(outcome.error, dtype=float)
    bound = np.array(outcome.bound, dtype=float)
    live = status != LOST
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(live, error / bound, 0.0)
    wrong = live & (error > bound)
    refusals = sum(count for note, count in outcome.notes.items() if note.startswith(REFUSED))
    mix = Counter(status.tolist())
    samples = len(status)
    statuses = ", ".join(f"{key[0]} {100 * mix[key] / samples:.0f}%"
                         for key in ("tracked", "bridged", "lost") if mix[key]) if samples else ""
    did = "; ".join(f"{note} x{count}" if count > 1 else note
                    for note, count in outcome.notes.most_common(4))
    return {"assumption broken": name, "path": path, "samples": samples,
            "wrong": float(wrong.mean()) if samples else 0.0,
            "worst": float(np.nanmax(ratio)) if samples and live.any() else 0.0,
            "statuses": statuses or (REFUSED if refusals else "-"), "what kfusion did": did}


def health_notes(tracker: Tracker) -> Counter:
    """Non-zero health counters (whatever fields the tracker's Health has)."""
    notes: Counter = Counter()
    skip = ("pushed", "accepted", "fused", "time_", "longest", "occluded")
    for key, value in tracker.health.as_dict().items():
        if any(part in key for part in skip):
            continue
        if isinstance(value, dict):
            for reason, count in value.items():
                if count:
                    notes[f"{key}.{reason}={count}"] += 1
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and value:
            notes[f"{key}={value:g}"] += 1
        elif isinstance(value, str) and value:
            notes[f"{key}={value}"] += 1
    return notes


# ------------------------------------------------------------------------------ paths


def new_tracker(streams: Streams) -> Tracker:
    return Tracker.from_recording_info(streams.recording.info)


def _push(tracker: Tracker, streams: Streams, stream: int, index: int) -> None:
    recording = streams.recording
    if stream == 0:
        imu = recording.imu
        tracker.push_imu(imu.t[index], imu.accelerometer[index], imu.gyroscope[index])
    else:
        mocap = recording.mocap
        tracker.push_mocap(mocap.t[index], mocap.position[index], mocap.quaternion[index])


def _estimate(tracker: Tracker, t: float, notes: Counter):  # type: ignore[no-untyped-def]
    """``estimate(now)``; None (no position: scored as lost) when the tracker refuses a now
    behind its newest sample (samples stamped after now, as from an IMU clock ahead)."""
    try:
        return tracker.estimate(t)
    except ValueError:
        notes["estimate(now) refused: samples stamped after now"] += 1
        return None


def run_tracker(streams: Streams, truth: np.ndarray) -> Outcome:
    """Push in arrival order; score ``estimate(arrival)`` after each mocap frame."""
    outcome = Outcome()
    try:
        tracker = new_tracker(streams)
    except ValueError as error:
        outcome.refusal = f"Tracker: {str(error)[:120]}"
        return outcome
    for arrival, stream, index in streams.events():
        try:
            _push(tracker, streams, stream, index)
        except (ValueError, OverflowError) as error:
            outcome.notes[f"push raised {type(error).__name__}"] += 1
            continue
        if stream == 1:
            estimate = _estimate(tracker, arrival, outcome.notes)
            if estimate is None:
                outcome.add(LOST, np.full(3, np.nan), math.inf, truth[index])
            else:
                outcome.add(estimate.status, estimate.position, estimate.bound(CONFIDENCE),
                            truth[index])
    outcome.notes += health_notes(tracker)
    return outcome


def run_tracker_without_t(streams: Streams, truth: np.ndarray, stop_fraction: float = 0.5
                          ) -> Outcome:
    """Both streams stop at ``stop_fraction``; afterwards the caller polls ``estimate()``
    without ``t`` at every later mocap time and the limb keeps moving."""
    outcome = Outcome()
    tracker = new_tracker(streams)
    mocap_t = streams.recording.mocap.t
    stop = float(mocap_t[0] + stop_fraction * (mocap_t[-1] - mocap_t[0]))
    for arrival, stream, index in streams.events():
        if arrival >= stop:
            break
        _push(tracker, streams, stream, index)
    for index in np.flatnonzero(streams.mocap_arrival >= stop):
        try:
            estimate = tracker.estimate()
        except (TypeError, ValueError) as error:
            outcome.refusal = f"estimate(): {str(error)[:100]}"
            return outcome
        outcome.add(estimate.status, estimate.position, estimate.bound(CONFIDENCE),
                    truth[index])
    outcome.notes += health_notes(tracker)
    return outcome


def run_tracker_threads(streams: Streams, dense_t: np.ndarray, dense_position: np.ndarray
                        ) -> Outcome:
    """One thread pushes as fast as it can; another calls ``estimate(t)`` at the newest pushed
    arrival time meanwhile. Each reader estimate is scored against the truth at its t."""
    outcome = Outcome()
    tracker = new_tracker(streams)
    newest = [-math.inf]
    done = threading.Event()
    readings: list = []

    def pusher() -> None:
        try:
            for arrival, stream, index in streams.events():
                _push(tracker, streams, stream, index)
                newest[0] = arrival
        finally:
            done.set()

    def reader() -> None:
        while not done.is_set():
            t = newest[0]
            if not math.isfinite(t):
                continue
            try:
                readings.append(tracker.estimate(t))
            except ValueError:
                outcome.notes["estimate(t) raced past by the pusher (ValueError)"] += 1
            except Exception as error:  # a corrupted state may fail in any way: report it
                outcome.notes[f"estimate(t) raised {type(error).__name__}"] += 1

    threads = [threading.Thread(target=pusher), threading.Thread(target=reader)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    # one score per distinct t: while the pusher is preempted the reader reads one state
    # thousands of times, and its repetitions would weigh that moment by the scheduler's luck
    # (0-7 % "wrong" from run to run on the same data)
    distinct: dict[float, Any] = {}
    for reading in readings:
        distinct.setdefault(reading.t, reading)
    readings = list(distinct.values())
    truth = np.column_stack([np.interp([r.t for r in readings], dense_t, dense_position[:, k])
                             for k in range(3)]) if readings else np.zeros((0, 3))
    for reading, true_position in zip(readings, truth, strict=True):
        outcome.add(reading.status, reading.position, reading.bound(CONFIDENCE), true_position)
    outcome.notes += health_notes(tracker)
    return outcome


def run_batch(streams: Streams, truth: np.ndarray, method: str, folder: Path) -> Outcome:
    """``kfusion check`` and ``kfusion track`` on the recording written to ``folder``."""
    outcome = Outcome()
    write_recording(streams.recording, folder)
    check_status, check_message = _cli(["check", str(folder)])
    outcome.notes["check: ok" if check_status == 0 else f"check refused: {check_message}"] += 1
    out = folder / f"track_{method}.csv"
    status, message = _cli(["track", str(folder), "--method", method, "--out", str(out)])
    if status != 0:
        outcome.refusal = f"track: {message}"
        return outcome
    table = pd.read_csv(out)
    std = table[["std_x", "std_y", "std_z"]].to_numpy(dtype=float)
    position = table[["x", "y", "z"]].to_numpy(dtype=float)
    for row, status_text in enumerate(table["status"].astype(str)):
        bound = math.inf if status_text == LOST else position_bound(np.diag(std[row] ** 2),
                                                                    CONFIDENCE)
        outcome.add(status_text, position[row], bound, truth[row])
    return outcome


def _cli(argv: list[str]) -> tuple[int, str]:
    """Exit status and the last line printed (the recording folder, ``argv[1]``, as DIR)."""
    folder = argv[1]
    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        status = cli(argv)
    message = err.getvalue().strip().splitlines()
    text = message[-1] if message else ""
    text = text.replace(folder, "DIR")
    return status, text.split("error: ", 1)[-1][:90]


# ------------------------------------------------------------------------------ data


@dataclass(frozen=True)
class Case:
    """A recording with truth at its mocap rows (NaN where unknown), dense truth if any."""

    name: str
    streams: Streams
    truth: np.ndarray
    dense_t: np.ndarray | None = None
    dense_position: np.ndarray | None = None


def simulated_cases(seeds: int, duration: float, gap_range: tuple[float, float],
                    placement: str = "random") -> list[Case]:
    """The simulated recordings, with occlusions of ``gap_range`` s every 1.5 s or more at
    ``placement`` (:class:`kfusion.simulate.OcclusionSpec`)."""
    cases = []
    for seed in range(seeds):
        simulation = simulate(SCENARIO, seed=seed, imu="mpu9255", duration=duration,
                              occlusions=OcclusionSpec(gap_range=gap_range, spacing=1.5,
                                                       placement=placement))
        truth = simulation.truth
        cases.append(Case(f"{SCENARIO}/{seed}", Streams.of(simulation.recording),
                          np.asarray(truth.position), truth.imu_t, truth.imu_position))
    return cases


def broad_cases(keys: list[str] | None, seconds: float) -> list[Case]:
    """BROAD trials (``keys``: file-name prefixes, None: all) cut to their first ``seconds`` s,
    with held-out-style gaps (0.1-0.3 s cut where the mocap is valid); [] when ``../shared``
    is absent."""
    try:
        from kfusion.datasets import broad_trials

        paths = broad_trials()
    except (ValueError, FileNotFoundError):
        return []
    from kfusion.config import first_seconds
    from kfusion.evaluate import cut_gaps
    from kfusion.readers.broad import read_broad

    cases = []
    for path in paths:
        if keys is not None and not any(path.name.startswith(key) for key in keys):
            continue
        recording = first_seconds(read_broad(path, mocap_step=3), seconds)
        gapped = cut_gaps(recording, rng=np.random.default_rng(0), gap_range=(0.1, 0.3))
        truth = np.array(gapped.truth_position)
        visible = gapped.recording.mocap.visible
        truth[visible] = gapped.recording.mocap.position[visible]
        cases.append(Case(path.stem, Streams.of(gapped.recording), truth))
    return cases


def aliased_knocks(streams: Streams) -> Streams:
    """:func:`kfusion.simulate.faults.imu_knocks` of 2 m/s^2 about every 4 s, ringing 5 Hz
    below the IMU's sample rate: sampled, each knock is a slow 5 Hz swing of the specific
    force, which the impact test (a jump between samples) does not see."""
    rate = 1.0 / median_interval(streams.recording.imu.t)
    return faults.imu_knocks(streams, every_s=4.0, amplitude=2.0, frequency=rate - 5.0,
                             duration_s=0.04)


Fault = Callable[[Streams], Streams]
FAULTS: list[tuple[str, Fault, str]] = [
    ("none (nominal)", lambda s: s, "sim"),
    ("IMU delivers nothing", faults.imu_silent, "sim"),
    ("IMU stops while mocap goes on", faults.imu_stops, "sim"),
    ("IMU misses 0.3 s inside an occlusion", faults.imu_misses_inside_gaps, "long"),
    ("one mocap frame stamped 1000 s ahead", faults.mocap_future_stamp, "sim"),
    ("a mocap frame stamped 0.15 s ahead every 2 s",
     lambda s: faults.mocap_frame_stamped_ahead(s, 0.15, every_s=2.0), "sim"),
    ("orientation flips 180 deg before a gap", faults.orientation_flip_before_gaps, "sim"),
    ("marker swap lasting 1 s", faults.marker_swap, "sim"),
    ("marker dropout: body 4 mm off for 10 frames", faults.sub_gate_glitches, "sim"),
    ("marker dropout: body 1.5 mm off for 10 frames",
     lambda s: faults.sub_gate_glitches(s, size_m=0.0015), "sim"),
    ("body 1.5 mm off on the 3 frames before each occlusion", faults.occlusion_edge_offsets,
     "sim"),
    ("body drifting 1.5 mm off over the 5 frames before each occlusion",
     faults.occlusion_edge_drift, "sim"),
    ("body 0.7 mm off on the 5 frames before each occlusion",
     lambda s: faults.occlusion_edge_offsets(s, 0.0007, 5), "sim"),
    ("body 4 mm off on the 10 frames after each occlusion",
     lambda s: faults.occlusion_edge_offsets(s, 0.004, 10, "after"), "sim"),
    ("mocap repeats the last pose through occlusions", faults.mocap_holds_last_pose, "sim"),
    ("IMU rate 8x lower from halfway, no anti-aliasing", faults.imu_rate_drops, "sim"),
    ("knocks on the IMU housing about every 0.7 s", faults.imu_knocks, "sim"),
    ("knocks every 4 s ringing 5 Hz below the IMU rate (aliased; below the impact test)",
     aliased_knocks, "sim"),
    ("IMU mount turns 3 deg at 60 % of the recording (a strap slipping)",
     faults.imu_mount_turns, "sim"),
    ("IMU clips below its declared range: gyroscope at 150 dps (the motion reaches 1.9x), "
     "accelerometer at 2 g; the profile says 1000 dps and 8 g; gaps at speed peaks",
     lambda s: faults.imu_clips(s, 2.0 * STANDARD_GRAVITY, math.radians(150.0)), "mid"),
    ("mocap orientation drifting to 5 deg over the recording", faults.mocap_orientation_drift,
     "sim"),
    ("IMU clock 5 ms behind", lambda s: faults.imu_clock_offset(s, -0.005), "sim"),
    ("IMU clock 5 ms ahead", lambda s: faults.imu_clock_offset(s, 0.005), "sim"),
    ("IMU clock 10 ms behind", lambda s: faults.imu_clock_offset(s, -0.010), "sim"),
    ("IMU clock 20 ms behind", lambda s: faults.imu_clock_offset(s, -0.020), "sim"),
    ("IMU clock 137 ms behind", lambda s: faults.imu_clock_offset(s, -0.137), "sim"),
    ("IMU clock 100 ms ahead", lambda s: faults.imu_clock_offset(s, 0.100), "sim"),
    ("gravity sign flipped", faults.gravity_sign_flipped, "sim"),
    ("mount given as identity", faults.mount_identity, "sim"),
    ("quaternion columns x,y,z,w", faults.quaternion_columns_xyzw, "sim"),
    ("IMU time in ms", faults.imu_time_in_milliseconds, "sim"),
]
FAST_TRIALS = ("21", "06")
"""BROAD trials with fast motion (combined, rotation) used for the fault rows."""
BROAD_FAULTS: list[tuple[str, Fault]] = [
    ("real fast motion (BROAD, held-out gaps)", lambda s: s),
    ("BROAD + IMU clock 137 ms behind", lambda s: faults.imu_clock_offset(s, -0.137)),
    ("BROAD + gravity sign flipped", faults.gravity_sign_flipped),
    ("BROAD + body 1.5 mm off on the 3 frames before each occlusion",
     faults.occlusion_edge_offsets),
    ("BROAD + body 0.7 mm off on the 5 frames before each occlusion",
     lambda s: faults.occlusion_edge_offsets(s, 0.0007, 5)),
    ("BROAD + IMU mount turns 6 deg at 60 %", lambda s: faults.imu_mount_turns(s, 6.0)),
    ("BROAD + body 3 mm off on the 10 frames after each occlusion",
     lambda s: faults.occlusion_edge_offsets(s, 0.003, 10, "after")),
    ("BROAD + IMU rate 8x lower from halfway, no anti-aliasing", faults.imu_rate_drops),
    ("BROAD + IMU clips at 250 dps and 2 g (the chip's power-on range; the profile says "
     "2000 dps and 16 g)",
     lambda s: faults.imu_clips(s, 2.0 * STANDARD_GRAVITY, math.radians(250.0))),
]


COLUMNS = ("assumption broken", "path", "samples", "wrong", "worst", "statuses",
           "what kfusion did", "meets target")


def meets_target(row: dict[str, Any]) -> bool:
    return float(row["wrong"]) <= TARGET_WRONG and float(row["worst"]) <= TARGET_WORST


def markdown_row(row: dict[str, Any]) -> str:
    """One markdown table line; ``wrong`` as a percentage, ``worst`` to 3 digits."""
    cells = {**row, "wrong": f"{100 * float(row['wrong']):.1f} %",
             "worst": f"{float(row['worst']):.3g}",
             "meets target": "yes" if meets_target(row) else "NO"}
    return "| " + " | ".join(str(cells[column]).replace("|", "/") for column in COLUMNS) + " |"


def record(rows: list[dict[str, Any]], row: dict[str, Any]) -> None:
    """Keep ``row`` and print it at once (a long run shows its rows as they come)."""
    rows.append(row)
    print(markdown_row(row), flush=True)


def evaluate(name: str, cases: list[Case], fault: Fault, workdir: Path,
             rows: list[dict[str, Any]]) -> None:
    faulted = [(case, fault(case.streams)) for case in cases]
    record(rows, summarise(name, "tracker", merge([run_tracker(streams, case.truth)
                                                   for case, streams in faulted])))
    for method in BATCH_METHODS:
        outcomes = []
        for number, (case, streams) in enumerate(faulted):
            folder = workdir / f"{len(rows)}_{method}_{number}"
            outcomes.append(run_batch(streams, case.truth, method, folder))
        record(rows, summarise(name, method, merge(outcomes)))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="1 seed of 20 s; BROAD: the first 30 s of trial 21 (< 2 minutes)")
    parser.add_argument("--seeds", type=int, default=2, help="simulation seeds (full mode)")
    parser.add_argument("--duration", type=float, default=20.0,
                        help="simulated seconds per seed (full mode)")
    parser.add_argument("--broad-seconds", type=float, default=40.0,
                        help="seconds kept of each BROAD trial (full mode: all seven trials "
                        "for the nominal row, the fast 06 and 21 for the fault rows)")
    parser.add_argument("--only", default=None, metavar="TEXT",
                        help="only the rows whose assumption contains TEXT")
    args = parser.parse_args()

    def wanted(name: str) -> bool:
        return args.only is None or args.only in name

    seeds, duration = (1, 20.0) if args.quick else (args.seeds, args.duration)
    start = time.perf_counter()
    broad_seconds = 30.0 if args.quick else args.broad_seconds
    mode = "quick" if args.quick else f"full, {seeds} seeds"
    print(f"Fail-safe benchmark ({mode}; simulated {SCENARIO} {duration:g} s, mpu9255; BROAD "
          f"first {broad_seconds:g} s per trial; bound at {CONFIDENCE:g}); wrong = status not "
          "lost and error > bound\n")
    print("| " + " | ".join(COLUMNS) + " |\n|" + "---|" * len(COLUMNS), flush=True)
    cases = simulated_cases(seeds, duration, (0.1, 0.5))
    long_gaps = simulated_cases(seeds, duration, (0.4, 0.6))
    mid_motion = simulated_cases(seeds, duration, (0.1, 0.5), "mid_motion") \
        if any(wanted(name) for name, _, data in FAULTS if data == "mid") else []
    case_sets = {"sim": cases, "long": long_gaps, "mid": mid_motion}
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="kfusion-failsafe-") as directory:
        workdir = Path(directory)
        for name, fault, data in FAULTS:
            if wanted(name):
                evaluate(name, case_sets[data], fault, workdir, rows)
        name = "estimate() without t after both streams stop"
        if wanted(name):
            record(rows, summarise(name, "tracker",
                                   merge([run_tracker_without_t(case.streams, case.truth)
                                          for case in cases])))
        name = "estimate(t) from another thread while pushing"
        if wanted(name):
            record(rows, summarise(name, "tracker",
                                   merge([run_tracker_threads(case.streams, case.dense_t,
                                                              case.dense_position)
                                          for case in cases if case.dense_t is not None])))
        every = broad_cases(FAST_TRIALS[:1] if args.quick else None, broad_seconds) \
            if any(wanted(name) for name, _ in BROAD_FAULTS) else []
        if every:
            if wanted(BROAD_FAULTS[0][0]):
                evaluate(BROAD_FAULTS[0][0], every, BROAD_FAULTS[0][1], workdir, rows)
            if not args.quick:
                fast = [case for case in every if case.name.startswith(FAST_TRIALS)]
                for name, fault in BROAD_FAULTS[1:]:
                    if wanted(name):
                        evaluate(name, fast, fault, workdir, rows)
        elif any(wanted(name) for name, _ in BROAD_FAULTS):
            print("BROAD rows skipped: ../shared/data/broad not found", file=sys.stderr)
    met = sum(meets_target(row) for row in rows)
    print(f"\n{met} of {len(rows)} rows meet the target (wrong <= {100 * TARGET_WRONG:g} %, "
          f"worst <= {TARGET_WORST:g}); {time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
