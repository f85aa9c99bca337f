"""Experiments and sweeps: results against the shared scoring code, a resumable store,
local-process and Dask execution giving the same table, figures, and the paper tables."""

from __future__ import annotations

import multiprocessing
import signal
import tempfile
import time
from collections.abc import Generator, Sequence
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
import yaml

from kfusion import paper, sweep
from kfusion.cli import main
from kfusion.config import SweepConfig, load_sweep_config, parse_config
from kfusion.conventions import BRIDGED, TRACKED
from kfusion.evaluate import gap_errors, per_gap_errors
from kfusion.experiment import MethodRun, ScoredRecording, run_method, summary_table
from kfusion.plots import heatmap_figure, sweep_lines_figure
from kfusion.recording import ImuSamples, MocapFrames, Recording, RecordingInfo
from kfusion.sweep import (
    ExperimentResult,
    LocalExecutor,
    SweepStore,
    SweepTask,
    execute_task,
    plan_sweep,
    run_experiment,
    run_sweep,
)
from kfusion.track_file import TrackResult

DATA = {"kind": "simulate", "scenario": "arm_lift", "duration": 8.0,
        "occlusions": {"gap_range": [0.1, 0.3], "spacing": 1.0}}
METRICS = ["samples", "rms_mm", "max_mm", "mean_mm", "coverage_3sigma", "lost_fraction", "gaps"]
TIMING = ["imu_per_second", "tracking_s", "runtime_s", "data_s", "total_s"]


def sweep_file(tmp_path: Path, **extra: Any) -> Path:
    content = {"name": "tiny", "data": DATA, "methods": {"baseline": {}, "kalman": {}},
               "seeds": 2,
               "grid": {"data.imu": ["mpu9255", "um7"],
                        "methods.baseline.buffer_size": [10, 20]}, **extra}
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(content, sort_keys=False))
    return path


def comparable(results: pd.DataFrame) -> pd.DataFrame:
    """Results without the timing columns, in a fixed order."""
    keys = ["data.imu", "methods.baseline.buffer_size", "method", "seed"]
    return results.drop(columns=TIMING).sort_values(keys).reset_index(drop=True)


# --------------------------------------------------------------------------------------------
# one experiment


def test_run_experiment_matches_the_shared_scoring():
    config = parse_config({"data": DATA, "seeds": [3, 5], "methods": {
        "baseline": {"buffer_size": 10}, "kalman": {}}})
    result = run_experiment(config)
    assert list(result.recordings) == ["arm_lift/mpu9255/seed3", "arm_lift/mpu9255/seed5"]
    scored = config.scored_recordings(5)[0]
    np.testing.assert_array_equal(result.recordings["arm_lift/mpu9255/seed5"].gap_mask,
                                  scored.gap_mask)
    again = run_method(scored, "baseline", {"buffer_size": 10})
    mine = result.runs["arm_lift/mpu9255/seed5"][0]
    np.testing.assert_allclose(mine.result.position, again.result.position)
    assert mine.metrics["rms_mm"] == pytest.approx(again.metrics["rms_mm"])
    table = result.summary()
    expected = summary_table(result.all_runs)
    pd.testing.assert_frame_equal(table.drop(columns="imu_per_second"),
                                  expected.drop(columns="imu_per_second"))
    per_recording = result.per_recording()
    assert per_recording.loc[("arm_lift/mpu9255/seed5", "baseline"), "rms_mm"] == \
        pytest.approx(again.metrics["rms_mm"])
    wide = result.per_gap_wide("max_mm")
    assert len(wide) == len(result.per_gap()) // 2
    assert {"baseline max_mm", "kalman max_mm"} <= set(wide.columns)


def test_experiment_writes_tables_and_figures(tmp_path):
    config = parse_config({"data": DATA, "seeds": 2, "methods": {"baseline": {}}})
    written = run_experiment(config).write(tmp_path)
    names = sorted(path.name for path in written)
    assert names == ["error_by_gap.png", "per_gap.csv", "per_recording.csv", "summary.csv",
                     "trajectory_arm_lift_mpu9255_seed0.png"]
    assert all(path.stat().st_size > 0 for path in written)


# --------------------------------------------------------------------------------------------
# sweeps


def test_sweep_table_has_one_row_per_point_and_seed(tmp_path):
    config = load_sweep_config(sweep_file(tmp_path))
    result = run_sweep(config, tmp_path / "out", workers=1, progress=False)
    table = result.results
    assert len(table) == len(config.points) * 2
    assert list(table.columns[:4]) == ["data.imu", "methods.baseline.buffer_size", "method",
                                       "seed"]
    assert set(METRICS + TIMING + ["run_id", "config"]) <= set(table.columns)
    # 2 imus x (2 baseline sizes + 1 kalman) distinct runs x 2 seeds
    assert result.ran == 2 * 3 * 2 and result.skipped == 0
    assert table["run_id"].nunique() == 2 * 3
    kalman = table[table["method"] == "kalman"]
    # the Kalman filter does not read the baseline's N: identical rows across that axis
    pivot = kalman.pivot_table(index=["data.imu", "seed"],
                               columns="methods.baseline.buffer_size", values="rms_mm")
    np.testing.assert_array_equal(pivot[10], pivot[20])
    # each row is the run of its own point, scored by the shared code
    row = table[(table["data.imu"] == "um7") & (table["method"] == "baseline")
                & (table["methods.baseline.buffer_size"] == 10) & (table["seed"] == 1)].iloc[0]
    scored = parse_config({"data": {**DATA, "imu": "um7"}}).scored_recordings(1)[0]
    direct = run_method(scored, "baseline", {"buffer_size": 10}).metrics
    for metric in ("rms_mm", "max_mm", "samples"):
        assert row[metric] == pytest.approx(direct[metric])
    stored = pd.read_parquet(tmp_path / "out" / "results.parquet")
    pd.testing.assert_frame_equal(stored, table)
    # summary: mean over seeds per point
    summary = pd.read_csv(tmp_path / "out" / "summary.csv")
    assert len(summary) == len(config.points)
    assert (summary["seeds"] == 2).all()
    first = summary.iloc[0]
    mask = ((table["data.imu"] == first["data.imu"]) & (table["method"] == first["method"])
            & (table["methods.baseline.buffer_size"] == first["methods.baseline.buffer_size"]))
    assert first["rms_mm_mean"] == pytest.approx(table.loc[mask, "rms_mm"].mean())


def test_rerun_skips_finished_runs_and_redoes_a_deleted_one(tmp_path, capsys):
    path = sweep_file(tmp_path)
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    first = pd.read_parquet(out / "results.parquet")
    capsys.readouterr()
    run_files = sorted((out / "runs").glob("*.parquet"))
    assert len(run_files) == 12
    assert not list((out / "runs").glob(".*tmp"))
    run_files[3].unlink()
    assert main(["sweep", str(path), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "12 distinct runs, 11 already done (skipped), 1 to run" in printed
    assert "ran 1, skipped 11, failed 0" in printed
    second = pd.read_parquet(out / "results.parquet")
    pd.testing.assert_frame_equal(comparable(first), comparable(second))
    # a third run has nothing to do
    result = run_sweep(load_sweep_config(path), out, progress=False)
    assert (result.ran, result.skipped) == (0, 12)


class InterruptingExecutor:
    """Does the first ``finish`` runs, then raises KeyboardInterrupt (like Ctrl-C)."""

    def __init__(self, finish: int) -> None:
        self.finish = finish

    def run(self, tasks: Sequence[SweepTask]) -> Generator[dict[str, Any], None, None]:
        for task in tasks[: self.finish]:
            yield execute_task(task)
        raise KeyboardInterrupt

    def close(self) -> None:
        pass


def test_interrupted_sweep_keeps_finished_runs(tmp_path):
    config = load_sweep_config(sweep_file(tmp_path))
    out = tmp_path / "out"
    tasks, _ = plan_sweep(config, SweepStore(out))
    assert len(tasks) == 12  # 2 imus x 2 seeds x (2 baseline sizes + 1 kalman)
    # runs on one data set and seed come together
    data = [(task.config.data.imu, task.seed) for task in tasks]
    assert len({key: None for key in data}) == 4 and data[::3] == data[1::3] == data[2::3]
    with pytest.raises(KeyboardInterrupt):
        run_sweep(config, out, executor=InterruptingExecutor(finish=5), progress=False)
    assert len(list((out / "runs").glob("*.parquet"))) == 5
    result = run_sweep(config, out, workers=1, progress=False)
    assert (result.ran, result.skipped) == (7, 5)
    assert len(result.results) == 16


def test_stopping_local_processes_mid_sweep_ends_the_workers(tmp_path):
    config = load_sweep_config(sweep_file(tmp_path))
    tasks, _ = plan_sweep(config, SweepStore(tmp_path / "out"))
    stream = LocalExecutor(2).run(tasks)
    first = next(stream)
    assert first["error"] is None and first["rms_mm"] > 0
    workers = multiprocessing.active_children()
    assert len(workers) == 2
    stream.close()  # what an interrupt in run_sweep does
    # the pool's manager thread reaps the workers too; a join racing it can read exitcode None
    # for a process that has already ended, so wait until the exit codes are known
    deadline = time.monotonic() + 30
    while any(worker.exitcode is None for worker in workers) and time.monotonic() < deadline:
        for worker in workers:
            worker.join(timeout=0.1)
    # ended by SIGTERM in the middle of the remaining runs, not after finishing them
    assert [worker.exitcode for worker in workers] == [-signal.SIGTERM] * 2


def test_data_are_built_once_per_data_set_in_a_process(tmp_path):
    config = load_sweep_config(sweep_file(tmp_path))
    tasks, _ = plan_sweep(config, SweepStore(tmp_path / "out"))
    rows = [execute_task(task) for task in tasks]
    built = [row["data_s"] > 0 for row in rows]
    assert built == [True, False, False] * 4
    assert all(row["total_s"] >= row["runtime_s"] >= row["tracking_s"] > 0 for row in rows)


def test_local_processes_and_dask_give_the_same_results(tmp_path, capsys):
    distributed = pytest.importorskip("distributed")
    path = sweep_file(tmp_path)
    single = run_sweep(load_sweep_config(path), tmp_path / "one", workers=1, progress=False)
    pooled = run_sweep(load_sweep_config(path), tmp_path / "two", workers=2, progress=False)
    pd.testing.assert_frame_equal(comparable(single.results), comparable(pooled.results))
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster:
        status = main(["sweep", str(path), "--out", str(tmp_path / "dask"), "--scheduler",
                       cluster.scheduler_address, "--no-progress"])
    printed = capsys.readouterr().out
    assert status == 0
    assert f"on Dask scheduler {cluster.scheduler_address}" in printed
    assert "ran 12, skipped 0, failed 0" in printed
    on_dask = pd.read_parquet(tmp_path / "dask" / "results.parquet")
    pd.testing.assert_frame_equal(comparable(single.results), comparable(on_dask))


def test_unreachable_scheduler_is_a_one_line_error(tmp_path, capsys):
    pytest.importorskip("distributed")
    status = main(["sweep", str(sweep_file(tmp_path)), "--out", str(tmp_path / "o"),
                   "--scheduler", "tcp://127.0.0.1:1", "--scheduler-timeout", "1",
                   "--no-progress"])
    err = capsys.readouterr().err
    assert status == 2
    assert err.startswith("kfusion sweep: error: --scheduler: cannot connect to the Dask "
                          "scheduler at 'tcp://127.0.0.1:1'")


def test_a_failing_run_is_reported_and_retried_on_rerun(tmp_path, monkeypatch, capsys):
    path = sweep_file(tmp_path)
    original = sweep.run_method

    def failing(scored: ScoredRecording, method: str, options: Any = None) -> MethodRun:
        if method == "kalman":
            raise RuntimeError("filter diverged")
        return original(scored, method, options)

    monkeypatch.setattr(sweep, "run_method", failing)
    out = tmp_path / "out"
    status = main(["sweep", str(path), "--out", str(out), "--workers", "1", "--no-progress"])
    captured = capsys.readouterr()
    assert status == 1
    assert "ran 8, skipped 0, failed 4" in captured.out
    assert "failed: " in captured.err and "RuntimeError: filter diverged" in captured.err
    table = pd.read_parquet(out / "results.parquet")
    assert set(table["method"]) == {"baseline"}
    monkeypatch.setattr(sweep, "run_method", original)
    result = run_sweep(load_sweep_config(path), out, workers=1, progress=False)
    assert (result.ran, result.skipped, result.failed) == (4, 8, [])


def test_store_writes_atomically_and_reads_back(tmp_path):
    store = SweepStore(tmp_path)
    row = {"run_id": "abc", "seed": 3, "rms_mm": 1.5, "config": "{}"}
    path = store.write(row)
    assert path == tmp_path / "runs" / "abc-seed3.parquet"
    assert store.done("abc", 3) and not store.done("abc", 4)
    assert store.read("abc", 3) == row
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["abc-seed3.parquet"]
    path.write_text("not parquet")
    with pytest.raises(ValueError, match=r"abc-seed3\.parquet: unreadable run file"):
        store.read("abc", 3)


def test_worker_count_must_be_positive():
    with pytest.raises(ValueError, match=r"--workers: expected a positive number of processes, "
                                         r"got 0"):
        LocalExecutor(0)


def test_heatmaps_follow_the_config(tmp_path):
    path = sweep_file(tmp_path, heatmaps=[
        {"rows": "methods.baseline.buffer_size", "columns": "method", "value": "rms_mm",
         "facet": "data.imu"}])
    config = load_sweep_config(path)
    result = run_sweep(config, tmp_path / "out", workers=1, progress=False)
    assert [p.name for p in result.figures] == [
        "heatmap_rms_mm_methods_baseline_buffer_size_x_method_by_data_imu.png"]
    assert result.figures[0].is_file()


def test_sweep_without_out_uses_a_new_temporary_folder(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    config = parse_config({"data": DATA, "methods": {"baseline": {}},
                           "grid": {"methods.baseline.buffer_size": [10]}})
    assert isinstance(config, SweepConfig)
    result = run_sweep(config, progress=False)
    assert result.directory.parent == tmp_path
    assert result.directory.name.startswith("kfusion-sweep-")
    assert (result.directory / "results.parquet").is_file()
    pd.testing.assert_frame_equal(sweep.load_results(result.directory), result.results)


# --------------------------------------------------------------------------------------------
# figures


def test_heatmap_and_line_figures_average_over_seeds():
    table = pd.DataFrame({
        "gap": ["a", "a", "b", "b"] * 2, "method": ["baseline"] * 4 + ["kalman"] * 4,
        "imu": ["m", "u"] * 4, "rms_mm": [1.0, 3.0, 5.0, 7.0, 2.0, 2.0, 4.0, 8.0]})
    figure = heatmap_figure(table, rows="gap", columns="method", value="rms_mm")
    image = figure.axes[0].images[0].get_array()
    np.testing.assert_allclose(image, [[2.0, 2.0], [6.0, 6.0]])
    plt.close(figure)
    figure = heatmap_figure(table, rows="gap", columns="method", value="rms_mm", facet="imu")
    panels = [ax for ax in figure.axes if ax.images]
    assert [ax.get_title() for ax in panels] == ["imu: m", "imu: u"]
    np.testing.assert_allclose(panels[1].images[0].get_array(), [[3.0, 2.0], [7.0, 8.0]])
    plt.close(figure)
    figure = sweep_lines_figure(table, x="gap", value="rms_mm")
    lines = {line.get_label(): line.get_ydata() for line in figure.axes[0].lines}
    np.testing.assert_allclose(lines["baseline"], [2.0, 6.0])
    np.testing.assert_allclose(lines["kalman"], [2.0, 6.0])
    plt.close(figure)


# --------------------------------------------------------------------------------------------
# paper tables


def hand_made_result() -> ExperimentResult:
    """One recording, 10 mocap rows, one gap on rows 3-5 with known errors."""
    t = np.arange(10) * 0.01
    truth = np.zeros((10, 3))
    gap = np.zeros(10, dtype=bool)
    gap[3:6] = True
    position = truth.copy()
    position[3] = [0.001, -0.004, 0.0]
    position[4] = [0.0, 0.002, 0.003]
    position[5] = [-0.002, 0.0, 0.0]
    status = np.where(gap, BRIDGED, TRACKED)
    track = TrackResult(t=t, position=position, std=np.full((10, 3), 0.01), status=status,
                        time_since_fix=np.zeros(10), method="kalman")
    recording = Recording(
        imu=ImuSamples(t, np.tile([0, 9.81, 0], (10, 1)), np.zeros((10, 3))),
        mocap=MocapFrames(t, np.where(gap[:, None], np.nan, truth), np.tile([1.0, 0, 0, 0],
                                                                             (10, 1))),
        info=RecordingInfo(imu_to_body=[1, 0, 0, 0], gravity=[0, -9.81, 0]))
    scored = ScoredRecording("r/seed0", recording, truth, gap)
    run = MethodRun(method="kalman", result=track, errors=gap_errors(track, truth, gap),
                    seconds=1.0, imu_samples=10,
                    per_gap=per_gap_errors(track, truth, gap).assign(
                        recording="r/seed0", method="kalman"))
    config = parse_config({"data": DATA, "methods": {"kalman": {}}})
    assert not isinstance(config, SweepConfig)
    return ExperimentResult(config=config, recordings={"r/seed0": scored},
                            runs={"r/seed0": [run]}, seconds=1.0)


def test_per_gap_axis_errors_by_hand():
    (row,) = paper.per_gap_axis_errors(hand_made_result()).to_dict("records")
    assert row["x_mm"] == pytest.approx(2.0)
    assert row["y_mm"] == pytest.approx(4.0)
    assert row["z_mm"] == pytest.approx(3.0)
    assert row["total_mm"] == pytest.approx(1000 * np.hypot(0.001, 0.004))


def test_paper_tables_sit_beside_ours():
    result = hand_made_result()
    table = paper.table_1_comparison(result, result)
    assert list(table.columns) == ["paper type1", "kalman type1", "paper type2", "kalman type2"]
    assert list(table["paper type1"][:5]) == [16.7, 28.4, 25.3, 12.0, 16.1]
    assert table.loc[1, "kalman type1"] == pytest.approx(1000 * np.hypot(0.001, 0.004))
    assert table.loc["mean", "paper type2"] == pytest.approx(np.mean([36.7, 26.5, 12.7, 43.1,
                                                                      31.6]))
    use_case = paper.use_case_comparison({"um7": result})
    assert use_case.loc[("um7", "paper"), "y_mm"] == 5.8
    assert use_case.loc[("um7", "kalman"), "y_mm"] == pytest.approx(4.0)
    assert use_case.loc[("um7", "kalman"), "gaps"] == 1
    with pytest.raises(ValueError, match="statistic: expected 'median', 'max' or 'mean'"):
        paper.table_1_comparison(result, result, statistic="mode")

