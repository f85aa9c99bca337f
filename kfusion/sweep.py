"""Running experiments from configs: one experiment (:func:`run_experiment`, ``kfusion run``) or a
grid of them (:func:`run_sweep`, ``kfusion sweep``).

A sweep's unit of work is a *run*: one method with one set of parameters on the data of one grid
point and one seed. Runs are identified by a fingerprint of what decides their result (the data
section, quick mode, the method and its parameter overrides), so grid points that differ only in
another method's parameters share one run, computed once. Runs on the same data set and seed are
submitted next to each other and each process keeps its last data sets, so the data are usually
simulated or read once per process.

The store in the output directory ``DIR``:

* ``DIR/runs/<run id>-seed<k>.parquet``: one row per finished run, written atomically (temporary
  file, then ``os.replace``) by the coordinating process as soon as the run finishes. An
  interrupted sweep keeps every finished run; a rerun skips runs whose file exists.
* ``DIR/results.parquet``: one row per grid point and seed: the grid parameters, ``seed``,
  ``run_id``, the metrics (:mod:`kfusion.evaluate`, pooled over the data set's recordings),
  ``gaps``, ``recordings``, the run times ``tracking_s`` (the method's own time), ``runtime_s``
  (tracking plus scoring), ``data_s`` (simulating or reading the data; 0 when the process had
  them from an earlier run) and ``total_s``, and the run's ``config`` as JSON.
* ``DIR/summary.csv``: mean and standard deviation over seeds per grid point;
  ``DIR/heatmap_*.png`` for the configured heat maps; ``DIR/sweep.json``: the sweep as run.

Runs execute on local processes (:class:`LocalExecutor`, ``concurrent.futures``) or on a Dask
distributed cluster (:class:`DaskExecutor`); both yield finished runs in completion order.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import sys
import tempfile
import time
import traceback
from collections.abc import Generator, Mapping, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import pandas as pd
from matplotlib.figure import Figure
from tqdm import tqdm

import kfusion
from kfusion.config import RunConfig, SweepConfig, fingerprint
from kfusion.evaluate import GapErrors, metrics_from_errors
from kfusion.experiment import (
    MethodRun,
    ScoredRecording,
    engine_options,
    run_method,
    summary_table,
    write_table_csv,
)
from kfusion.guards import atomic_write, atomic_write_text
from kfusion.track_file import TrackResult

AXIS_INDEX = {"x": 0, "y": 1, "z": 2}
RUNS_FOLDER = "runs"
RESULTS_FILE = "results.parquet"
SUMMARY_FILE = "summary.csv"
METRIC_COLUMNS = ("samples", "rms_mm", "max_mm", "mean_mm", "coverage_3sigma", "lost_fraction",
                  "imu_per_second")
"""Gap metrics of one run, pooled over its recordings (definitions in kfusion.evaluate)."""


# --------------------------------------------------------------------------------------------
# one experiment


@dataclass(frozen=True)
class ExperimentResult:
    """Every method's run on every recording of an experiment.

    Attributes:
        config: the run config.
        recordings: recording name -> scored recording (names carry the seed).
        runs: recording name -> one :class:`MethodRun` per method, in the config's order.
        seconds: wall time of the whole experiment, s.
    """

    config: RunConfig
    recordings: dict[str, ScoredRecording]
    runs: dict[str, list[MethodRun]]
    seconds: float

    @property
    def all_runs(self) -> list[MethodRun]:
        return [run for runs in self.runs.values() for run in runs]

    def summary(self) -> pd.DataFrame:
        """Per method, pooling every gap sample of every recording and seed
        (:func:`kfusion.experiment.summary_table`)."""
        return summary_table(self.all_runs)

    def per_recording(self) -> pd.DataFrame:
        """One row per (recording, method): gap metrics and the tracking time."""
        rows = []
        for name, runs in self.runs.items():
            for run in runs:
                rows.append({"recording": name, "method": run.method,
                             "gaps": len(run.per_gap), **run.metrics})
        return pd.DataFrame(rows).set_index(["recording", "method"])

    def per_gap(self) -> pd.DataFrame:
        """One row per (recording, method, gap) (:func:`kfusion.evaluate.per_gap_errors`)."""
        frames = [run.per_gap for run in self.all_runs if len(run.per_gap)]
        return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()

    def per_gap_wide(self, metric: str = "max_mm") -> pd.DataFrame:
        """One row per gap, one ``metric`` column per method (for printing)."""
        table = self.per_gap()
        if table.empty:
            return table
        wide = table.pivot_table(index=["recording", "gap_start_s", "duration_s"],
                                 columns="method", values=metric, sort=False)
        wide.columns = [f"{method} {metric}" for method in wide.columns]
        return wide.reset_index()

    def results_for(self, name: str) -> dict[str, TrackResult]:
        """Method -> track of recording ``name``."""
        return {run.method: run.result for run in self.runs[name]}

    def trajectory_figure(self, name: str | None = None, *, path: str | Path | None = None
                          ) -> Figure:
        """Trajectory with gaps of recording ``name`` (default: the first), like the paper's
        figures: mocap, each method inside the gaps, truth, and a zoom on the worst gaps; axes
        and window length from ``output.plots``, the window where the IMU turns fastest
        (:func:`kfusion.plots.motion_window`)."""
        from kfusion.plots import motion_window, trajectory_figure

        name = name if name is not None else next(iter(self.recordings))
        scored = self.recordings[name]
        plots = self.config.output.plots
        window = None
        if plots.window_s is not None:
            window = motion_window(scored.recording, scored.gap_mask, plots.window_s)
        return trajectory_figure(scored.recording.mocap.t, scored.recording.mocap.position,
                                 self.results_for(name), scored.gap_mask,
                                 truth=scored.truth_position,
                                 axes=[AXIS_INDEX[axis] for axis in plots.axes], window=window,
                                 title=f"{self.config.name}: {name}", path=path)

    def error_by_gap_figure(self, *, path: str | Path | None = None) -> Figure:
        """Per-gap error (``output.plots.metric``) against gap length, per method."""
        from kfusion.plots import error_by_gap_length_figure, per_gap_label

        metric = self.config.output.plots.metric
        return error_by_gap_length_figure(self.per_gap(), metric=metric,
                                          title=f"{self.config.name}: {per_gap_label(metric)}",
                                          path=path)

    def write(self, directory: str | Path) -> list[Path]:
        """Write ``summary.csv``, ``per_recording.csv``, ``per_gap.csv`` and the PNG figures
        chosen in ``output.plots``; return the paths written."""
        import matplotlib.pyplot as plt

        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        written = []
        for file_name, table, index in (("summary.csv", self.summary(), True),
                                        ("per_recording.csv", self.per_recording(), True),
                                        ("per_gap.csv", self.per_gap(), False)):
            write_table_csv(table, directory / file_name, index=index)
            written.append(directory / file_name)
        plots = self.config.output.plots
        if plots.trajectory:
            first_seed = f"seed{self.config.seeds[0]}"
            for name in self.recordings:
                if name.endswith(first_seed):
                    path = directory / f"trajectory_{_file_label(name)}.png"
                    plt.close(self.trajectory_figure(name, path=path))
                    written.append(path)
        if plots.error_by_gap and not self.per_gap().empty:
            path = directory / "error_by_gap.png"
            plt.close(self.error_by_gap_figure(path=path))
            written.append(path)
        return written


def _file_label(text: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in text).strip("_")


def run_experiment(config: RunConfig, *, progress: bool = False) -> ExperimentResult:
    """Run every method of ``config`` on its recordings for every seed.

    ``progress`` shows a tqdm bar over recordings on stderr.
    """
    start = time.perf_counter()
    recordings: dict[str, ScoredRecording] = {}
    runs: dict[str, list[MethodRun]] = {}
    with tqdm(total=len(config.seeds), desc=config.name, unit="seed", disable=not progress,
              file=sys.stderr, leave=False) as bar:
        for seed in config.seeds:
            for scored in config.scored_recordings(seed):
                recordings[scored.name] = scored
                runs[scored.name] = [run_method(scored, method,
                                                {**options,
                                                 **engine_options(method, config.engine)})
                                     for method, options in config.methods.items()]
            bar.update()
    return ExperimentResult(config=config, recordings=recordings, runs=runs,
                            seconds=time.perf_counter() - start)


# --------------------------------------------------------------------------------------------
# sweep tasks


@dataclass(frozen=True)
class SweepTask:
    """One run: a single-method config (its data, quick mode, method and overrides) and a seed.

    Attributes:
        run_id: :func:`run_identity` of ``config``.
        config: the grid point's run config, holding one method.
        seed: the seed.
    """

    run_id: str
    config: RunConfig
    seed: int

    @property
    def method(self) -> str:
        return next(iter(self.config.methods))


def run_identity(config: RunConfig) -> str:
    """Fingerprint of what decides a single-method config's result: data, quick mode, method
    and its overrides (not name, seeds or output)."""
    return fingerprint({"data": config.data.model_dump(mode="json"), "quick": config.quick,
                        "methods": config.methods})


def _data_identity(config: RunConfig, seed: int) -> str:
    return fingerprint({"data": config.data.model_dump(mode="json"), "quick": config.quick,
                        "seed": seed})


DATA_CACHE_SIZE = 2
"""Data sets (recordings of one data section and seed) kept per process between runs."""
_data_cache: dict[str, list[ScoredRecording]] = {}


def _recordings(config: RunConfig, seed: int) -> tuple[list[ScoredRecording], float]:
    """The scored recordings of ``config`` and ``seed``, and the seconds spent building them
    (0 when this process built them for an earlier run: runs on one data set are submitted
    together, so a worker usually simulates or reads the data once)."""
    key = _data_identity(config, seed)
    if key in _data_cache:
        return _data_cache[key], 0.0
    start = time.perf_counter()
    recordings = config.scored_recordings(seed)
    while len(_data_cache) >= DATA_CACHE_SIZE:
        _data_cache.pop(next(iter(_data_cache)))
    _data_cache[key] = recordings
    return recordings, time.perf_counter() - start


def execute_task(task: SweepTask) -> dict[str, Any]:
    """Do one run: its row of results (metrics pooled over the data set's recordings).

    A run that raises gives a row with ``error`` set and no metrics, instead of stopping the
    sweep. Runs in worker processes, so it takes and returns plain picklable values.
    """
    start = time.perf_counter()
    identity = {"run_id": task.run_id, "seed": task.seed, "method": task.method}
    try:
        recordings, data_seconds = _recordings(task.config, task.seed)
        run_start = time.perf_counter()
        options = task.config.methods[task.method]
        options = {**options, **engine_options(task.method, task.config.engine)}
        runs = [run_method(scored, task.method, options) for scored in recordings]
    except Exception as error:  # reported with the run; the sweep goes on
        return {**identity, "error": _error_text(error)}
    metrics = metrics_from_errors(GapErrors.concatenate(run.errors for run in runs))
    tracking = sum(run.seconds for run in runs)
    samples = sum(run.imu_samples for run in runs)
    return {
        **identity,
        **{name: float(metrics[name]) for name in METRIC_COLUMNS if name in metrics},
        "imu_per_second": samples / tracking if tracking else float("nan"),
        "gaps": int(sum(len(run.per_gap) for run in runs)),
        "recordings": len(runs),
        "tracking_s": tracking,
        "runtime_s": time.perf_counter() - run_start,
        "data_s": data_seconds,
        "total_s": time.perf_counter() - start,
        "config": task.config.model_dump_json(exclude={"output"}),
        "kfusion_version": kfusion.__version__,
        "error": None,
    }


def _error_text(error: BaseException) -> str:
    where = traceback.extract_tb(error.__traceback__)
    last = f" ({Path(where[-1].filename).name}:{where[-1].lineno})" if where else ""
    return f"{type(error).__name__}: {error}{last}".replace("\n", " ")


# --------------------------------------------------------------------------------------------
# executors


class Executor(Protocol):
    """Runs tasks and yields each task's result row as soon as it finishes (any order)."""

    def run(self, tasks: Sequence[SweepTask]) -> Generator[dict[str, Any], None, None]: ...

    def close(self) -> None: ...


class LocalExecutor:
    """Local processes (``concurrent.futures.ProcessPoolExecutor``); one worker runs in-process.

    Args:
        workers: number of processes (default ``os.cpu_count()``).
    """

    def __init__(self, workers: int | None = None) -> None:
        if workers is not None and workers < 1:
            raise ValueError(f"--workers: expected a positive number of processes, got {workers}")
        self.workers = workers or os.cpu_count() or 1

    def run(self, tasks: Sequence[SweepTask]) -> Generator[dict[str, Any], None, None]:
        if self.workers == 1 or len(tasks) <= 1:
            for task in tasks:
                yield execute_task(task)
            return
        pool = ProcessPoolExecutor(max_workers=min(self.workers, len(tasks)),
                                   initializer=_ignore_interrupts)
        futures: list[Future[dict[str, Any]]] = []
        finished = False
        try:
            futures = [pool.submit(execute_task, task) for task in tasks]
            for future in as_completed(futures):
                yield future.result()
            finished = True
        finally:
            if not finished:  # interrupted or failed: stop the runs in progress now
                _terminate_workers(pool)
            pool.shutdown(wait=finished, cancel_futures=True)

    def close(self) -> None:
        """Nothing to release: the pool lives only inside :meth:`run`."""


def _terminate_workers(pool: ProcessPoolExecutor) -> None:
    """End the pool's worker processes at once (their unfinished runs are lost, finished ones
    are already stored). Python 3.14 has ``terminate_workers``; before it, the processes are
    reached through the pool's ``_processes`` mapping."""
    terminate = getattr(pool, "terminate_workers", None)
    if terminate is not None:
        terminate()
        return
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.terminate()


def _ignore_interrupts() -> None:
    """Worker processes leave Ctrl-C to the coordinating process, which stops the sweep; a
    worker finishes its current task and exits."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


class DaskExecutor:
    """A Dask distributed cluster, reached through its scheduler address
    (``tcp://host:8786``). The workers need kfusion installed; results come back to this
    process, which writes them, so the workers need no shared file system."""

    def __init__(self, address: str, *, timeout_s: float = 20.0) -> None:
        if timeout_s <= 0:
            raise ValueError(f"--scheduler-timeout: expected a positive number of seconds, "
                             f"got {timeout_s}")
        from distributed import Client

        try:
            self.client = Client(address, timeout=timeout_s)
        except (OSError, TimeoutError, ValueError) as error:
            raise ValueError(f"--scheduler: cannot connect to the Dask scheduler at "
                             f"{address!r}: {error}") from None

    def run(self, tasks: Sequence[SweepTask]) -> Generator[dict[str, Any], None, None]:
        from distributed import as_completed as dask_as_completed

        futures = [self.client.submit(execute_task, task, pure=False) for task in tasks]
        try:
            for future in dask_as_completed(futures):
                yield future.result()
        finally:
            self.client.cancel(futures)

    def close(self) -> None:
        self.client.close()


# --------------------------------------------------------------------------------------------
# the store


class SweepStore:
    """Run files of a sweep: ``DIR/runs/<run id>-seed<k>.parquet``, one row each."""

    def __init__(self, directory: str | Path) -> None:
        self.directory = Path(directory)
        self.runs_directory = self.directory / RUNS_FOLDER

    def path(self, run_id: str, seed: int) -> Path:
        return self.runs_directory / f"{run_id}-seed{seed}.parquet"

    def done(self, run_id: str, seed: int) -> bool:
        return self.path(run_id, seed).is_file()

    def write(self, row: Mapping[str, Any]) -> Path:
        """Write one finished run atomically (temporary file in the same folder, then
        ``os.replace``), so a run file is either complete or absent."""
        self.runs_directory.mkdir(parents=True, exist_ok=True)
        path = self.path(str(row["run_id"]), int(row["seed"]))
        frame = pd.DataFrame([dict(row)])
        return atomic_write(path, lambda temporary: frame.to_parquet(temporary, index=False))

    def read(self, run_id: str, seed: int) -> dict[str, Any]:
        path = self.path(run_id, seed)
        try:
            frame = pd.read_parquet(path)
        except Exception as error:
            raise ValueError(f"{path}: unreadable run file ({error}); delete it to rerun "
                             "that run") from None
        return dict(frame.iloc[0])


# --------------------------------------------------------------------------------------------
# the sweep


@dataclass(frozen=True)
class SweepResult:
    """What :func:`run_sweep` did and produced.

    Attributes:
        directory: the output folder.
        results: one row per grid point and seed (see the module docstring).
        summary: mean and std over seeds per grid point.
        ran: runs executed now; skipped: runs found finished in the store;
        failed: (run file name, error) of runs that raised (no file written; a rerun retries).
        figures: heat map PNGs written.
    """

    directory: Path
    results: pd.DataFrame
    summary: pd.DataFrame
    ran: int
    skipped: int
    failed: list[tuple[str, str]] = field(default_factory=list)
    figures: list[Path] = field(default_factory=list)


def plan_sweep(config: SweepConfig, store: SweepStore) -> tuple[list[SweepTask], int]:
    """The runs not yet in ``store`` (each distinct run once, runs on the same data set and
    seed next to each other), and the number of runs skipped because their file exists."""
    pending: dict[tuple[str, int], SweepTask] = {}
    skipped: set[tuple[str, int]] = set()
    for point in config.points:
        run_id = run_identity(point.config)
        for seed in config.seeds:
            if store.done(run_id, seed):
                skipped.add((run_id, seed))
            else:
                pending.setdefault((run_id, seed), SweepTask(run_id, point.config, seed))
    tasks = sorted(pending.values(),
                   key=lambda task: (_data_identity(task.config, task.seed), task.method))
    return tasks, len(skipped)


def _parameter_value(value: Any) -> Any:
    """Grid values as table cells: scalars as they are, lists and mappings as JSON text."""
    if isinstance(value, (list, tuple, dict)):
        return json.dumps(value)
    return value


def collect_results(config: SweepConfig, store: SweepStore) -> pd.DataFrame:
    """One row per grid point and seed whose run is in the store: parameters, seed, then the
    run's columns."""
    rows = []
    cache: dict[tuple[str, int], dict[str, Any]] = {}
    for point in config.points:
        run_id = run_identity(point.config)
        for seed in config.seeds:
            if not store.done(run_id, seed):
                continue
            if (run_id, seed) not in cache:
                cache[(run_id, seed)] = store.read(run_id, seed)
            run = {key: value for key, value in cache[(run_id, seed)].items()
                   if key not in ("seed", "method", "error")}
            rows.append({**{axis: _parameter_value(value)
                            for axis, value in point.parameters.items()},
                         "seed": seed, **run})
    table = pd.DataFrame(rows)
    for axis in config.axes:  # one type per column, so Parquet can store it
        if axis in table and len({type(value) for value in table[axis]}) > 1 and \
                not pd.api.types.is_numeric_dtype(table[axis]):
            table[axis] = table[axis].map(str)
    return table


def summarise_results(results: pd.DataFrame, axes: Sequence[str]) -> pd.DataFrame:
    """Mean and std over seeds of the metrics per grid point, plus the number of seeds."""
    if results.empty:
        return pd.DataFrame()
    metrics = [c for c in (*METRIC_COLUMNS, "tracking_s", "runtime_s") if c in results]
    grouped = results.groupby(list(axes), sort=False, dropna=False)
    summary = grouped[metrics].agg(["mean", "std"])
    summary.columns = [f"{metric}_{statistic}" for metric, statistic in summary.columns]
    summary.insert(0, "seeds", grouped.size())
    keep = ["seeds", *[c for c in summary.columns if c.endswith("_mean")],
            "rms_mm_std", "max_mm_std"]
    return summary[[c for c in keep if c in summary.columns]]


SUMMARY_PRINTED = {"seeds": "seeds", "rms_mm_mean": "rms_mm", "rms_mm_std": "rms_std",
                   "max_mm_mean": "max_mm", "coverage_3sigma_mean": "coverage",
                   "lost_fraction_mean": "lost", "runtime_s_mean": "runtime_s"}
"""Summary columns printed by ``kfusion sweep`` (all are in summary.csv) and their labels."""


def format_summary(summary: pd.DataFrame) -> str:
    """Fixed-width text of a sweep summary's main columns (means over seeds)."""
    shown = summary[[c for c in SUMMARY_PRINTED if c in summary.columns]].copy()
    for column in shown.columns:
        if column == "seeds":
            continue
        digits = 3 if column.startswith(("coverage", "lost")) else 2
        shown[column] = [("-" if pd.isna(v) else f"{v:,.{digits}f}") for v in shown[column]]
    return shown.rename(columns=SUMMARY_PRINTED).to_string()


def draw_heatmaps(config: SweepConfig, results: pd.DataFrame, directory: Path) -> list[Path]:
    """The config's heat maps as PNGs in ``directory``."""
    import matplotlib.pyplot as plt

    from kfusion.plots import heatmap_figure, quantity_label

    written = []
    for heatmap in config.heatmaps:
        if results.empty or heatmap.value not in results:
            continue
        parts = [heatmap.value, heatmap.rows, "x", heatmap.columns]
        if heatmap.facet:
            parts += ["by", heatmap.facet]
        path = directory / f"heatmap_{_file_label('_'.join(parts))}.png"
        figure = heatmap_figure(results, rows=heatmap.rows, columns=heatmap.columns,
                                value=heatmap.value, facet=heatmap.facet,
                                title=f"{config.name}: {quantity_label(heatmap.value)}, "
                                      "mean over seeds",
                                path=path)
        plt.close(figure)
        written.append(path)
    return written


def run_sweep(config: SweepConfig, out: str | Path | None = None, *, workers: int | None = None,
              scheduler: str | None = None, scheduler_timeout_s: float = 20.0,
              progress: bool = True, executor: Executor | None = None) -> SweepResult:
    """Run every grid point and seed of ``config`` not yet in the store, then write
    ``results.parquet``, ``summary.csv`` and heat maps.

    Args:
        config: the validated sweep.
        out: output folder; None: a new temporary folder, left in place (notebooks use
            :func:`temporary_sweep`, which removes it).
        workers: local processes (default: CPU count); ignored with ``scheduler``.
        scheduler: Dask scheduler address; runs on that cluster instead of local processes.
        scheduler_timeout_s: how long to try connecting to the scheduler, s.
        progress: tqdm bar over runs on stderr.
        executor: a ready executor (overrides ``workers`` and ``scheduler``).

    Each finished run is written as it finishes; on KeyboardInterrupt the finished runs stay and
    the interrupt propagates.
    """
    directory = Path(out) if out is not None else Path(tempfile.mkdtemp(prefix="kfusion-sweep-"))
    store = SweepStore(directory)
    tasks, skipped = plan_sweep(config, store)
    directory.mkdir(parents=True, exist_ok=True)
    atomic_write_text(directory / "sweep.json", json.dumps(
        {"name": config.name, "grid": config.grid, "seeds": config.seeds,
         "base": config.base.model_dump(mode="json")}, indent=2, default=str) + "\n")
    ran = 0
    failed: list[tuple[str, str]] = []
    if tasks:
        own_executor = executor is None
        if executor is None:
            executor = (DaskExecutor(scheduler, timeout_s=scheduler_timeout_s) if scheduler
                        else LocalExecutor(workers))
        try:
            with tqdm(total=len(tasks), desc=config.name, unit="run", disable=not progress,
                      file=sys.stderr) as bar, contextlib.closing(executor.run(tasks)) as stream:
                for row in stream:
                    if row.get("error"):
                        failed.append((store.path(row["run_id"], row["seed"]).name,
                                       str(row["error"])))
                    else:
                        store.write(row)
                        ran += 1
                    bar.update()
        finally:
            if own_executor:
                executor.close()
    results = collect_results(config, store)
    if not results.empty:
        atomic_write(directory / RESULTS_FILE,
                     lambda temporary: results.to_parquet(temporary, index=False))
    summary = summarise_results(results, config.axes)
    write_table_csv(summary, directory / SUMMARY_FILE)
    figures = draw_heatmaps(config, results, directory)
    return SweepResult(directory=directory, results=results, summary=summary, ran=ran,
                       skipped=skipped, failed=failed, figures=figures)


@contextlib.contextmanager
def temporary_sweep(config: SweepConfig, **options: Any) -> Generator[SweepResult, None, None]:
    """:func:`run_sweep` into a new temporary folder that is removed when the ``with`` block
    ends, so notebooks leave nothing behind in the temporary directory; ``options`` go to
    :func:`run_sweep`. Read what you need (``load_results``) inside the block."""
    with tempfile.TemporaryDirectory(prefix="kfusion-sweep-") as folder:
        yield run_sweep(config, folder, **options)


def load_results(directory: str | Path) -> pd.DataFrame:
    """``DIR/results.parquet`` of a finished sweep."""
    path = Path(directory) / RESULTS_FILE
    if not path.is_file():
        raise FileNotFoundError(f"no sweep results at {path}")
    return pd.read_parquet(path)
