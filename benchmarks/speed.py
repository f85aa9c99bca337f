"""Speed of the filter engines (issue 11). Prints a markdown table.

Rows: a bare filterpy 9-state predict/update loop (the yardstick: the ratio column divides each
rate by its rate); the batch filter and the smoother per engine (``compiled``: numba kernels,
``filterpy``: KalmanFusion), without and with the consistency monitor (the default of ``kfusion
track``; with it the compiled engine runs in two passes, :mod:`kfusion.kalman.monitored`); a
sweep of N runs of 60 s recordings (IMU 200 Hz) on 2 processes, without and with the monitor,
extrapolated to 1000 runs;
``Tracker.push_imu``'s median (the best of 3 runs), also in step times of a bare loop run just
before it (the machine's speed varies from hour to hour; issue 11's target of 20 µs was 2.6
steps on a machine doing 130k steps/s, so machines compare by the steps); the smoother's stored
bytes per row against the state's; numba's import and the cold start (first call in a fresh
process with an empty JIT cache, then with the cache written).

Run: ``python benchmarks/speed.py [--quick] [--monitor-only]``. ``--monitor-only`` times just
the yardstick and the batch filter and smoother rows with and without the monitor (compiled
engine; with ``--quick`` on the 20 s recording), and splits the monitored batch run into its
kernels (the main filter, the shadow gaps, states recomputed from checkpoints) and the
monitor's Python, with the ratio the kernels alone would reach. Numbers are one run on a
shared machine.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from kfusion.kalman import run_filter, run_smoother
from kfusion.recording import Recording
from kfusion.simulate import OcclusionSpec, simulate

IMU_RATE = 200.0
MOCAP_RATE = 100.0


def recording(seconds: float, seed: int = 0) -> Recording:
    """A simulated arm lift of ``seconds`` with 0.1-0.3 s gaps (IMU 200 Hz, mocap 100 Hz)."""
    return simulate("arm_lift", seed=seed, duration=seconds, imu_rate=IMU_RATE,
                    mocap_rate=MOCAP_RATE,
                    occlusions=OcclusionSpec(gap_range=(0.1, 0.3), spacing=1.0)).recording


def bare_filterpy_loop(steps: int) -> float:
    """Steps per second of filterpy's KalmanFilter: 9 states, one predict per step (F, B, Q,
    u given) and an update every second step."""
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=9, dim_z=3, dim_u=9)
    kf.x = np.zeros(9)
    kf.P = np.eye(9)
    kf.R = np.eye(3) * 1e-6
    F = np.eye(9)
    F[0:3, 3:6] = np.eye(3) * 0.005
    B = np.zeros((9, 9))
    B[0:6, 0:3] = 1e-4
    Q = np.eye(9) * 1e-8
    H = np.zeros((3, 9))
    H[:, 0:3] = np.eye(3)
    u = np.ones(9)
    z = np.zeros(3)
    start = time.perf_counter()
    for step in range(steps):
        kf.predict(u=u, B=B, F=F, Q=Q)
        if step % 2:
            kf.update(z, H=H)
    return steps / (time.perf_counter() - start)


def timed(function, *args, repeat: int = 1, **kwargs) -> float:  # type: ignore[no-untyped-def]
    """Best wall time (s) of ``repeat`` calls."""
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        function(*args, **kwargs)
        best = min(best, time.perf_counter() - start)
    return float(best)


def sweep_task(arguments: tuple[int, float, str, bool]) -> float:
    """One sweep run: simulate a recording and filter it; returns the filtering seconds."""
    seed, seconds, engine, monitor = arguments
    data = recording(seconds, seed)
    start = time.perf_counter()
    if monitor:
        run_filter(data, engine=engine)
    else:
        run_filter(data, monitor=None, engine=engine)
    return time.perf_counter() - start


def sweep(runs: int, seconds: float, engine: str, monitor: bool) -> tuple[float, float]:
    """(wall s, filtering s summed) of ``runs`` runs on 2 worker processes; each worker
    compiles (or loads) the kernels once and reuses them for all its runs."""
    start = time.perf_counter()
    with ProcessPoolExecutor(max_workers=2) as pool:
        # one warm-up task per worker: loading numba and the cached kernels, not per run
        list(pool.map(sweep_task, [(1000 + w, 5.0, engine, monitor) for w in range(2)]))
        warm = time.perf_counter()
        filtering = list(pool.map(sweep_task, [(seed, seconds, engine, monitor)
                                               for seed in range(runs)]))
    end = time.perf_counter()
    del start
    return end - warm, float(sum(filtering))


def smoother_bytes_per_row(seconds: float, estimate_lever_arm: bool = False
                           ) -> tuple[int, int, int, int]:
    """(state size n, bytes of x and P per row, bytes the compiled smoother keeps per row, the
    same with the output maps). Kept: one x and P per row (the backward pass overwrites the
    filtered state with the smoothed one, in place), the forward filter's point estimates
    (position and variance per axis: the filtered rows' result), and the packed states the
    forward pass saves every SAVE_EVERY rows and each row's packed prediction (x, the upper
    triangle of P and the transition product's 19 free entries), which the backward pass
    reads (measured on the forward kernel's run). The output maps (H, c per row) turn
    states into points; they are counted in the last number, as the memory they hold (H is
    one (3, n) matrix for all rows without the lever-arm states: a view with row stride 0).
    ``estimate_lever_arm``: the recording's lever arm left out, so the filter estimates it
    (12 states, H per row); else it is given (9 states)."""
    from dataclasses import replace

    from kfusion.kalman import compiled
    from kfusion.kalman.batch import compiled_rows, make_fusion, resolve_parameters

    data = recording(seconds)
    if estimate_lever_arm:
        data = replace(data, info=replace(data.info, lever_arm=None))
    run = run_smoother(data, monitor=None, engine="compiled")
    assert run.output_matrix is not None
    forward = compiled_rows(data, make_fusion(data, resolve_parameters(data, None, {})),
                            smoothing=True)
    assert forward is not None and forward[1].replay is not None
    rows, n = run.x.shape
    state = 8 * (n + n * n)
    kept = run.x.nbytes + run.P.nbytes + 2 * run.filtered.position.nbytes
    kept += compiled.kept_bytes(forward[1].replay)
    maps = run.output_matrix.strides[0] * rows + forward[0].output_offset.nbytes
    return n, state, int(round(kept / rows)), int(round((kept + maps) / rows))


def push_imu_median(engine: str, seconds: float, steps: int, repeat: int = 3
                    ) -> tuple[float, float]:
    """(median s per ``Tracker.push_imu``, bare loop steps/s just before it): ``repeat`` runs
    over a recording of ``seconds`` (in order, a mocap frame pushed after its IMU samples; a
    new Tracker each), each after a bare loop of ``steps`` (:func:`bare_filterpy_loop`: the
    machine's speed at that moment); the run with the least median (the one other processes
    disturbed least) with its loop."""
    data = recording(seconds)
    runs = []
    for _ in range(repeat):
        bare = bare_filterpy_loop(steps)
        runs.append((push_imu_run(engine, data), bare))
    return min(runs)


def push_imu_run(engine: str, data: Recording) -> float:
    """Median s per ``Tracker.push_imu`` over ``data`` pushed in order by a new Tracker."""
    from kfusion.tracker import Tracker

    info = data.info
    tracker = Tracker(info.imu_to_body, info.gravity, lever_arm=info.lever_arm, engine=engine)
    imu, mocap = data.imu, data.mocap
    durations = []
    frame = 0
    for row in range(len(imu.t)):
        while frame < len(mocap.t) and mocap.t[frame] < imu.t[row]:
            visible = bool(mocap.visible[frame])
            tracker.push_mocap(mocap.t[frame], mocap.position[frame] if visible else None,
                               mocap.quaternion[frame] if visible else None)
            frame += 1
        start = time.perf_counter()
        tracker.push_imu(imu.t[row], imu.accelerometer[row], imu.gyroscope[row])
        durations.append(time.perf_counter() - start)
    return float(np.median(durations))


COLD_SCRIPT = """
import time
start = time.perf_counter()
import numba
numba_import = time.perf_counter() - start
from kfusion.kalman import run_filter
from kfusion.simulate import simulate
data = simulate("arm_lift", seed=0, duration=5.0).recording
start = time.perf_counter()
run_filter(data, monitor=None, engine="compiled")
print(numba_import, time.perf_counter() - start)
"""


def cold_start() -> tuple[float, float, float]:
    """(numba import s, first call with an empty cache s, first call with the cache written s),
    each in a fresh process; the cache goes to a temporary NUMBA_CACHE_DIR."""
    with tempfile.TemporaryDirectory() as cache:
        environment = {**os.environ, "NUMBA_CACHE_DIR": cache}
        results = []
        for _ in range(2):
            output = subprocess.run([sys.executable, "-c", COLD_SCRIPT], env=environment,
                                    capture_output=True, text=True, check=True).stdout.split()
            results.append((float(output[0]), float(output[1])))
    return results[1][0], results[0][1], results[1][1]


def import_time() -> float:
    """s to import kfusion.tracker in a fresh process (``python -X importtime``)."""
    output = subprocess.run([sys.executable, "-X", "importtime", "-c", "import kfusion.tracker"],
                            capture_output=True, text=True, check=True).stderr
    last = [line for line in output.splitlines() if line.rstrip().endswith("kfusion.tracker")]
    return int(last[-1].split("|")[1]) * 1e-6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true",
                        help="short recordings, 10 sweep runs, no cold start")
    parser.add_argument("--sweep-runs", type=int, default=None, metavar="N",
                        help="compiled sweep runs (default: 10 with --quick, else 40); "
                        "1000 measures the issue's target directly (about 2 min)")
    parser.add_argument("--monitor-only", action="store_true",
                        help="only the yardstick and the compiled batch filter and smoother "
                        "rows, with and without the consistency monitor")
    args = parser.parse_args()
    if args.monitor_only:
        print_table(*monitor_rows(20.0 if args.quick else 60.0))
        return
    seconds = 20.0 if args.quick else 60.0
    runs = args.sweep_runs or (10 if args.quick else 40)
    rows: list[tuple[str, str, str]] = []
    bare = bare_filterpy_loop(5000 if args.quick else 20000)
    rows.append(("bare filterpy 9-state predict/update loop", f"{bare:,.0f} steps/s", "1.00x"))
    data = recording(seconds)
    samples = len(data.imu)
    run_filter(recording(5.0), monitor=None, engine="compiled")  # load or compile the kernels
    for label, function in (("batch kalman", run_filter), ("smoother", run_smoother)):
        for engine in ("compiled", "filterpy"):
            for monitor in (False, True):
                if monitor and (args.quick or function is run_smoother):
                    continue
                options = {} if monitor else {"monitor": None}
                seconds_taken = timed(function, data, engine=engine, repeat=1 if monitor else 2,
                                      **options)
                rate = samples / seconds_taken
                rows.append((f"{label}, engine {engine}" + (", monitor on" if monitor
                                                             else ", no monitor"),
                             f"{rate:,.0f} IMU samples/s", f"{rate / bare:.2f}x"))
    for engine, count, monitor in (("compiled", runs, False), ("compiled", runs, True),
                                   ("filterpy", min(max(4, runs // 4), 10), False)):
        wall, filtering = sweep(count, 60.0, engine, monitor=monitor)
        rows.append((f"sweep, {count} runs of 60 s at 200 Hz, 2 processes, engine {engine}, "
                     + ("monitor on (the default of configs)" if monitor else "no monitor"),
                     f"{wall:.1f} s wall ({filtering:.1f} s filtering)",
                     f"1000 runs: {wall * 1000 / count:.0f} s"
                     + ("" if count == 1000 else " (extrapolated)")))
    for engine in ("compiled", "filterpy"):
        median, bare_now = push_imu_median(engine, 10.0, 5000 if args.quick else 20000)
        rows.append((f"Tracker.push_imu in order, engine {engine}", f"median {median * 1e6:.0f} µs",
                     f"{median * bare_now:.2f} bare steps (loop at {bare_now:,.0f} steps/s just "
                     "before the run)"))
    for estimate_lever_arm in (False, True):
        n, state, kept, with_maps = smoother_bytes_per_row(seconds, estimate_lever_arm)
        rows.append((f"compiled smoother memory per row ({n} states): x, P, filtered points, "
                     "saved states, packed predictions",
                     f"{kept} bytes ({with_maps} with the output maps H, c)",
                     f"{kept / state:.3f}x the state's {state} bytes (x, P); "
                     f"{with_maps / state:.3f}x with the maps"))
    rows.append(("import kfusion.tracker (no numba)", f"{import_time() * 1e3:.0f} ms", ""))
    if not args.quick:
        numba_import, cold, warm = cold_start()
        rows.append(("import numba", f"{numba_import:.2f} s", ""))
        rows.append(("first compiled call, empty JIT cache", f"{cold:.1f} s", ""))
        rows.append(("first compiled call, cache written", f"{warm:.2f} s", ""))
    print_table(seconds, samples, rows)


def monitor_rows(seconds: float) -> tuple[float, int, list[tuple[str, str, str]]]:
    """The yardstick and the compiled batch filter and smoother without and with the
    consistency monitor, on one recording of ``seconds``, back to back."""
    bare = bare_filterpy_loop(20000)
    rows = [("bare filterpy 9-state predict/update loop", f"{bare:,.0f} steps/s", "1.00x")]
    data = recording(seconds)
    samples = len(data.imu)
    run_filter(recording(5.0), engine="compiled")  # load or compile the kernels
    for label, function in (("batch kalman", run_filter), ("smoother", run_smoother)):
        for monitor in (False, True):
            options = {} if monitor else {"monitor": None}
            rate = samples / timed(function, data, engine="compiled", repeat=2, **options)
            rows.append((f"{label}, engine compiled, " + ("monitor on" if monitor
                                                           else "no monitor"),
                         f"{rate:,.0f} IMU samples/s", f"{rate / bare:.2f}x"))
    total, parts = monitored_kernel_time(data)
    kernels = sum(parts.values())
    rows.append(("batch kalman, monitor on: its kernels' share (main filter, shadow gaps, "
                 "states recomputed from checkpoints; the rest is the monitor's Python)",
                 f"{total:.3f} s = " + " + ".join(f"{value:.3f}" for value in parts.values())
                 + f" + {total - kernels:.3f} s",
                 f"{samples / kernels / bare:.2f}x with the Python at zero"))
    return seconds, samples, rows


def monitored_kernel_time(data: Recording, repeat: int = 3) -> tuple[float, dict[str, float]]:
    """The fastest of ``repeat`` monitored compiled batch runs over ``data`` (s) and, in it, the
    seconds spent in the main filter's kernel (``compiled.run_kernel``), in the shadow gaps'
    kernel runs (``Checkpoints.run``) and in recomputing the main filter's state at a row from
    its last checkpoint (``Checkpoints.state_before``): each wrapped with a timer for the
    runs, then restored."""
    from kfusion.kalman import compiled

    spent = {"run_kernel": 0.0, "run": 0.0, "state_before": 0.0}
    owners = {"run_kernel": compiled, "run": compiled.Checkpoints,
              "state_before": compiled.Checkpoints}
    originals = {name: getattr(owner, name) for name, owner in owners.items()}

    def timer(name: str):  # type: ignore[no-untyped-def]
        function = originals[name]

        def timed_call(*args, **kwargs):  # type: ignore[no-untyped-def]
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                spent[name] += time.perf_counter() - start
        return timed_call

    best, parts = math.inf, dict(spent)
    try:
        for name, owner in owners.items():
            setattr(owner, name, timer(name))
        for _ in range(repeat):
            spent.update(dict.fromkeys(spent, 0.0))
            start = time.perf_counter()
            run_filter(data, engine="compiled")
            total = time.perf_counter() - start
            if total < best:
                best, parts = total, dict(spent)
    finally:
        for name, owner in owners.items():
            setattr(owner, name, originals[name])
    return best, parts


def print_table(seconds: float, samples: int, rows: list[tuple[str, str, str]]) -> None:
    """The markdown table of ``rows`` (path, speed, ratio) under a line naming the recording."""
    print(f"Recording: {seconds:.0f} s simulated arm lift, {samples} IMU samples at 200 Hz, "
          f"mocap 100 Hz with 0.1-0.3 s gaps.\n")
    print("| path | speed | ratio |")
    print("|---|---|---|")
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
