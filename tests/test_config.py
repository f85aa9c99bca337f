"""Experiment configs: every file in configs/ loads and smoke-runs; mistakes are one-line errors
naming the file and the key path; grids expand and validate point by point."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from kfusion.cli import main
from kfusion.config import (
    QUICK_GRID_VALUES,
    BroadData,
    ConfigError,
    FolderData,
    GapsConfig,
    RunConfig,
    SimulateData,
    SweepConfig,
    config_directory,
    find_config,
    first_seconds,
    load_config,
    load_run_config,
    load_sweep_config,
    parse_config,
    recording_with_gaps,
)
from kfusion.evaluate import cut_gaps
from kfusion.methods import METHODS
from kfusion.recording import write_recording
from kfusion.simulate import simulate
from kfusion.sweep import run_identity

CONFIG_DIRECTORY = Path(__file__).resolve().parents[1] / "configs"
CONFIG_FILES = sorted(CONFIG_DIRECTORY.glob("*.yaml"))


def needs_full_broad(path: Path) -> bool:
    """True for a config whose data are the BROAD ``.mat`` trials found by kfusion.datasets."""
    data = yaml.safe_load(path.read_text()).get("data", {})
    return data.get("kind") == "broad" and data.get("directory") is None


SMOKE_CASES = [pytest.param(path, id=path.stem,
                            marks=[pytest.mark.broad] if needs_full_broad(path) else [])
               for path in CONFIG_FILES]

SIMULATED = {"kind": "simulate", "scenario": "arm_lift", "duration": 8.0}


def write_yaml(path: Path, content: dict | str) -> Path:
    text = content if isinstance(content, str) else yaml.safe_dump(content, sort_keys=False)
    path.write_text(text)
    return path


def error_of(path: Path, command: str, capsys: pytest.CaptureFixture[str]) -> str:
    """Run ``kfusion COMMAND path`` expecting a user error; return its one stderr line."""
    status = main([command, str(path), "--out", str(path.parent / "out"), "--no-progress"])
    err = capsys.readouterr().err
    assert status == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith(f"kfusion {command}: error: {path}: ")
    return err


# --------------------------------------------------------------------------------------------
# the bundled configs


def test_configs_cover_the_paper_experiments_broad_and_sweeps():
    configs = {path.stem: load_config(path) for path in CONFIG_FILES}
    runs = {name: c for name, c in configs.items() if isinstance(c, RunConfig)}
    sweeps = {name: c for name, c in configs.items() if isinstance(c, SweepConfig)}
    simulated = [(c.data.scenario, c.data.imu, c.data.occlusions.placement)
                 for c in runs.values() if isinstance(c.data, SimulateData)]
    assert ("arm_lift", "mpu9255", "mid_motion") in simulated  # Type 1
    assert ("arm_lift", "mpu9255", "direction_change") in simulated  # Type 2
    assert any(scenario == "circle" for scenario, _, _ in simulated)
    assert ("pick_tool", "mpu9255") in {(s, i) for s, i, _ in simulated}
    assert ("pick_tool", "um7") in {(s, i) for s, i, _ in simulated}
    assert any(isinstance(c.data, BroadData) and c.data.trials is None for c in runs.values())
    axes = {axis for sweep in sweeps.values() for axis in sweep.grid}
    assert {"data.occlusions.gap_range", "data.imu", "method",
            "methods.kalman.accelerometer_noise_density",
            "methods.baseline.buffer_size"} <= axes


@pytest.mark.parametrize("path", SMOKE_CASES)
def test_every_config_smoke_runs(path, tmp_path, capsys):
    config = load_config(path)
    out = tmp_path / "out"
    if isinstance(config, SweepConfig):
        status = main(["sweep", str(path), "--out", str(out), "--quick", "--workers", "1",
                       "--no-progress"])
        printed = capsys.readouterr().out
        assert status == 0, printed
        results = pd.read_parquet(out / "results.parquet")
        quick = load_sweep_config(path, quick=True)
        assert len(results) == len(quick.points) * len(quick.seeds)
        assert results["rms_mm"].notna().all()
        assert (out / "summary.csv").is_file()
        assert all(path.is_file() for path in out.glob("heatmap_*.png"))
        assert len(list(out.glob("heatmap_*.png"))) == len(quick.heatmaps)
    else:
        status = main(["run", str(path), "--out", str(out), "--quick", "--no-progress"])
        printed = capsys.readouterr().out
        assert status == 0, printed
        summary = pd.read_csv(out / "summary.csv", index_col="method")
        assert list(summary.index) == list(config.methods)
        assert (summary["samples"] > 0).all() and summary["rms_mm"].notna().all()
        assert "Per gap" in printed and "Aggregated" in printed
        for method in config.methods:
            assert re.search(rf"^{method}\s+\d+\s+[\d.]+", printed, re.MULTILINE)
        assert (out / "per_gap.csv").is_file() and (out / "error_by_gap.png").is_file()
        assert list(out.glob("trajectory_*.png"))


def test_find_config_and_config_directory():
    assert config_directory() == CONFIG_DIRECTORY
    assert find_config("circle") == CONFIG_DIRECTORY / "circle.yaml"
    with pytest.raises(ValueError, match=r"config 'nope' not found .*expected one of"):
        find_config("nope")


# --------------------------------------------------------------------------------------------
# schema and defaults


def test_defaults_and_seed_shorthand(tmp_path):
    config = load_run_config(write_yaml(tmp_path / "exp.yaml", {"data": SIMULATED, "seeds": 3}))
    assert config.name == "exp"
    assert config.seeds == [0, 1, 2]
    assert list(config.methods) == list(METHODS)
    assert config.data.imu == "mpu9255" and config.data.occlusions.gap_range == (0.1, 0.3)
    assert config.output_directory() == Path("kfusion-output") / "exp"
    assert config.output_directory(tmp_path / "x") == tmp_path / "x"
    assert not config.quick
    quick = load_run_config(tmp_path / "exp.yaml", quick=True)
    assert quick.quick and quick.seeds == [0]


def test_models_are_frozen(tmp_path):
    config = load_run_config(write_yaml(tmp_path / "exp.yaml", {"data": SIMULATED}))
    with pytest.raises(Exception, match="frozen"):
        config.seeds = [4]  # type: ignore[misc]


def test_method_parameters_are_converted_to_the_dataclass_types(tmp_path):
    config = load_run_config(write_yaml(tmp_path / "exp.yaml", {
        "data": SIMULATED,
        "methods": {"kalman": {"accelerometer_noise_density": "1e-3"},
                    "baseline": {"buffer_size": 10}}}))
    assert config.methods["kalman"]["accelerometer_noise_density"] == 0.001
    assert config.methods["baseline"] == {"buffer_size": 10}


def test_broad_trials_accept_all_or_keys(tmp_path):
    trials = tmp_path / "trials"
    trials.mkdir()
    for name in ("01_slow", "06_fast", "21_combined"):  # selection only reads the file names
        (trials / f"{name}.mat").write_bytes(b"")
    data = {"kind": "broad", "trials": "all", "directory": "trials"}
    config = load_run_config(write_yaml(tmp_path / "a.yaml", {"data": data}))
    assert isinstance(config.data, BroadData) and config.data.trials is None
    assert [path.name[:2] for path in config.data.trial_paths()] == ["01", "06", "21"]
    data = {"kind": "broad", "trials": ["01", 21], "directory": "trials"}
    config = load_run_config(write_yaml(tmp_path / "b.yaml", {"data": data}))
    assert isinstance(config.data, BroadData)
    assert config.data.trials == ["01", "21"]
    assert [path.name[:2] for path in config.data.trial_paths()] == ["01", "21"]


def test_paths_resolve_relative_to_the_config_file(tmp_path):
    simulation = simulate("arm_lift", seed=2, duration=10.0, occlusions=None)
    write_recording(simulation.recording, tmp_path / "data" / "rec")
    (tmp_path / "configs").mkdir()
    path = write_yaml(tmp_path / "configs" / "folder.yaml", {
        "data": {"kind": "folder", "folders": ["../data/rec"],
                 "gaps": {"gap_range": [0.1, 0.2], "spacing": 1.0}},
        "methods": {"baseline": {}}})
    config = load_run_config(path)
    assert isinstance(config.data, FolderData)
    assert Path(config.data.folders[0]).resolve() == (tmp_path / "data" / "rec").resolve()
    (scored,) = config.scored_recordings(seed=0)
    hidden = scored.gap_mask
    assert hidden.any()
    assert np.isnan(scored.recording.mocap.position[hidden]).all()
    np.testing.assert_allclose(scored.truth_position[hidden],
                               simulation.recording.mocap.position[hidden])
    # the same seed cuts the same gaps; another seed other gaps
    np.testing.assert_array_equal(config.scored_recordings(seed=0)[0].gap_mask, hidden)
    assert not np.array_equal(config.scored_recordings(seed=1)[0].gap_mask, hidden)


def test_first_seconds_keeps_the_start_of_both_streams():
    recording = simulate("circle", seed=0, duration=10.0, occlusions=None).recording
    short = first_seconds(recording, 2.0)
    start = min(recording.imu.t[0], recording.mocap.t[0])
    assert short.imu.t[-1] <= start + 2.0 < recording.imu.t[len(short.imu)]
    assert short.mocap.t[-1] <= start + 2.0 < recording.mocap.t[len(short.mocap)]
    np.testing.assert_array_equal(short.mocap.position,
                                  recording.mocap.position[: len(short.mocap)])


def test_quick_simulation_is_shorter_but_keeps_its_gaps(tmp_path):
    raw = {"data": {"kind": "simulate", "scenario": "arm_lift",
                    "occlusions": {"placement": "mid_motion"}}}
    full = parse_config(raw).scored_recordings(0)[0]
    quick = parse_config(raw, quick=True).scored_recordings(0)[0]
    assert len(quick.recording.mocap) < len(full.recording.mocap)
    assert quick.gap_mask.any()


def test_combined_data_is_its_parts_labelled():
    part = {**SIMULATED, "occlusions": {"placement": "direction_change"}}
    combined = parse_config({"data": {"kind": "combined",
                                      "parts": {"type2": part, "plain": SIMULATED}}})
    scored = combined.scored_recordings(3)
    assert [one.name for one in scored] == ["type2/arm_lift/mpu9255/seed3",
                                            "plain/arm_lift/mpu9255/seed3"]
    alone = parse_config({"data": part}).scored_recordings(3)[0]
    np.testing.assert_array_equal(scored[0].gap_mask, alone.gap_mask)
    np.testing.assert_array_equal(scored[0].recording.imu.accelerometer,
                                  alone.recording.imu.accelerometer)
    assert not np.array_equal(scored[0].gap_mask, scored[1].gap_mask)


def test_gap_seeding_per_recording_or_shared():
    recording = simulate("circle", seed=0, duration=12.0, occlusions=None).recording
    shared = GapsConfig(seeding="shared")
    # shared: the generator of the seed alone, as cut_gaps with default_rng(seed)
    expected = cut_gaps(recording, rng=np.random.default_rng(4)).gap_mask
    for name in ("one", "two"):
        np.testing.assert_array_equal(recording_with_gaps(name, recording, shared, 4).gap_mask,
                                      expected)
    # per recording: the name enters the seed, so two names get two patterns
    first = recording_with_gaps("one", recording, GapsConfig(), 4)
    second = recording_with_gaps("two", recording, GapsConfig(), 4)
    assert first.name == "one/seed4" and first.gap_mask.any()
    assert not np.array_equal(first.gap_mask, second.gap_mask)


# --------------------------------------------------------------------------------------------
# mistakes: one line naming the file and the key path


@pytest.mark.parametrize(("content", "expected"), [
    ({"data": {**SIMULATED, "imux": "um7"}},
     r"data\.imux: unknown key; expected one of \['duration', 'imu', 'kind', 'occlusions', "
     r"'scenario'\]"),
    ({"data": SIMULATED, "output": {"plots": {"axis": ["y"]}}},
     r"output\.plots\.axis: unknown key; expected one of \[.*'axes'"),
    ({"data": SIMULATED, "sedes": 3}, r": sedes: unknown key; expected one of \[.*'seeds'"),
    ({"data": {**SIMULATED, "duration": "long"}},
     r"data\.duration: Input should be a valid number.*got 'long'"),
    ({"data": {**SIMULATED, "duration": -1}},
     r"data\.duration: Input should be greater than 0, got -1"),
    ({"data": {**SIMULATED, "occlusions": {"gap_range": [0.3, 0.1]}}},
     r"data\.occlusions\.gap_range: expected \[min, max\] seconds with 0 < min <= max, "
     r"got \[0\.3, 0\.1\]"),
    ({"data": {**SIMULATED, "occlusions": {"placement": "middle"}}},
     r"data\.occlusions\.placement: Input should be 'random', 'mid_motion' or "
     r"'direction_change', got 'middle'"),
    ({"data": {**SIMULATED, "scenario": "juggling"}},
     r"data\.scenario: unknown scenario; expected one of \['arm_lift', .*got 'juggling'"),
    ({"data": {**SIMULATED, "imu": "mpu6050"}},
     r"data\.imu: unknown IMU profile; expected one of \[.*'mpu9255', 'um7'\], got 'mpu6050'"),
    ({"data": {"kind": "optical"}},
     r"data\.kind: expected one of \['broad', 'combined', 'folder', 'simulate'\], "
     r"got 'optical'"),
    ({"data": {"kind": "combined", "parts": {"a": {**SIMULATED, "imux": "um7"}}}},
     r"data\.parts\.a\.imux: unknown key; expected one of \['duration', 'imu', 'kind', "),
    ({"data": {"kind": "combined", "parts": {"a": {"kind": "combined", "parts": {}}}}},
     r"data\.parts\.a\.kind: expected one of \['broad', 'folder', 'simulate'\], "
     r"got 'combined'"),
    ({"data": {"kind": "combined", "parts": {"a/b": SIMULATED}}},
     r"data\.parts: expected a plain name"),
    ({"data": {"kind": "combined", "parts": {}}}, r"data\.parts: .*at least 1 item"),
    ({"data": {"kind": "broad", "gaps": {"seeding": "sometimes"}}},
     r"data\.gaps\.seeding: Input should be 'per_recording' or 'shared', got 'sometimes'"),
    ({"data": {"scenario": "circle"}}, r"data\.kind: expected one of"),
    ({"seeds": 2}, r": data: required key is missing"),
    ({"data": {"kind": "broad", "trials": "some"}},
     r"data\.trials: expected 'all' or a list of trial keys"),
    ({"data": {"kind": "broad", "mocap_step": 0}},
     r"data\.mocap_step: Input should be greater than or equal to 1, got 0"),
    ({"data": {"kind": "broad", "trials": ["01", ["21"]]}},
     r"data\.trials\[1\]: Input should be a valid string"),
    ({"data": SIMULATED, "seeds": [1, 1]}, r"seeds: expected distinct non-negative seeds"),
    ({"data": SIMULATED, "seeds": 0}, r"seeds: expected a positive number of seeds"),
    ({"data": SIMULATED, "methods": {"kalmann": {}}},
     r"methods\.kalmann: unknown method; expected one of \['baseline', 'kalman', 'smoother'\]"),
    ({"data": SIMULATED, "methods": {"kalman": {"acelerometer_noise": 1.0}}},
     r"methods\.kalman\.acelerometer_noise: unknown parameter; expected one of "
     r"\[.*'accelerometer_noise_density'"),
    ({"data": SIMULATED, "methods": {"baseline": {"buffer_size": "big"}}},
     r"methods\.baseline\.buffer_size: Input should be a valid integer.*got 'big'"),
    ({"data": SIMULATED, "methods": {"baseline": {"buffer_size": 1}}},
     r"methods\.baseline: BaselineParameters\.buffer_size: expected an integer >= 3, got 1"),
    ({"data": SIMULATED, "methods": {"kalman": {"accelerometer_noise_density": -1.0}}},
     r"methods\.kalman: KalmanParameters\.accelerometer_noise_density: expected"),
    ({"data": SIMULATED, "methods": {"kalman": 3}}, r"methods\.kalman: Input should be a valid "
     r"dictionary"),
])
def test_mistakes_name_the_file_and_key_path(content, expected, tmp_path, capsys):
    path = write_yaml(tmp_path / "bad.yaml", content)
    with pytest.raises(ConfigError, match=expected) as error:
        load_config(path)
    assert str(error.value).startswith(f"{path}: ")
    err = error_of(path, "run", capsys)
    assert re.search(expected, err)


def test_every_mistake_in_a_file_is_reported(tmp_path):
    path = write_yaml(tmp_path / "bad.yaml", {
        "data": {**SIMULATED, "imu": "x", "occlusions": {"spacing": 0}},
        "methods": {"baseline": {"bufer_size": 3}}, "seeds": "many"})
    with pytest.raises(ConfigError) as error:
        load_config(path)
    paths = [issue.path for issue in error.value.issues]
    assert paths == ["data.imu", "data.occlusions.spacing", "seeds",
                     "methods.baseline.bufer_size"]


@pytest.mark.parametrize(("text", "expected"), [
    ("data: {kind: simulate\n", r"invalid YAML at line 2, column 1"),
    ("data: {kind: simulate, scenario: circle}\nseeds: 1\nseeds: 2\n",
     r"invalid YAML at line 3, column 1: duplicate key 'seeds'"),
    ("- data\n- seeds\n", r"expected a mapping of keys \(data, methods, \.\.\.\), got list"),
])
def test_unreadable_yaml_is_one_line(text, expected, tmp_path, capsys):
    path = write_yaml(tmp_path / "bad.yaml", text)
    assert re.search(expected, error_of(path, "run", capsys))


def test_missing_file_and_wrong_command(tmp_path, capsys):
    status = main(["run", str(tmp_path / "none.yaml")])
    assert status == 2 and "config file not found" in capsys.readouterr().err
    sweep = write_yaml(tmp_path / "s.yaml", {"data": SIMULATED, "grid": {"data.imu": ["um7"]}})
    assert "this is a sweep config" in error_of(sweep, "run", capsys)
    run = write_yaml(tmp_path / "r.yaml", {"data": SIMULATED})
    assert "grid: required key is missing" in error_of(run, "sweep", capsys)


# --------------------------------------------------------------------------------------------
# grids


def test_grid_expands_to_the_product_with_one_method_per_point(tmp_path):
    path = write_yaml(tmp_path / "s.yaml", {
        "data": SIMULATED, "methods": {"baseline": {}, "kalman": {}}, "seeds": 2,
        "grid": {"data.occlusions.gap_range": [[0.1, 0.3], [0.3, 0.6]],
                 "data.imu": ["mpu9255", "um7"],
                 "methods.kalman.accelerometer_noise_density": [0.001, 0.01, 0.1]}})
    config = load_sweep_config(path)
    assert config.axes == ["data.occlusions.gap_range", "data.imu",
                           "methods.kalman.accelerometer_noise_density", "method"]
    assert len(config.points) == 2 * 2 * 3 * 2
    assert config.seeds == [0, 1]
    for point in config.points:
        assert list(point.config.methods) == [point.parameters["method"]]
        assert point.config.data.imu == point.parameters["data.imu"]
        assert list(point.config.data.occlusions.gap_range) == \
            point.parameters["data.occlusions.gap_range"]
        if point.method == "kalman":
            assert point.config.methods["kalman"] == {
                "accelerometer_noise_density":
                    point.parameters["methods.kalman.accelerometer_noise_density"]}
    # the baseline does not read the Kalman noise: those points share one run each
    identities = {run_identity(point.config) for point in config.points}
    assert len(identities) == 2 * 2 * 3 + 2 * 2
    assert config.heatmaps == ()  # four varying axes: no default heat map


def test_explicit_method_axis_keeps_the_users_order(tmp_path):
    path = write_yaml(tmp_path / "s.yaml", {
        "data": SIMULATED,
        "grid": {"method": ["smoother", "baseline"], "data.imu": ["mpu9255", "um7"]}})
    config = load_sweep_config(path)
    assert config.axes == ["method", "data.imu"]
    assert [point.method for point in config.points] == ["smoother"] * 2 + ["baseline"] * 2
    (heatmap,) = config.heatmaps
    assert (heatmap.rows, heatmap.columns, heatmap.value) == ("method", "data.imu", "rms_mm")


def test_quick_keeps_two_values_per_axis_and_one_seed(tmp_path):
    path = write_yaml(tmp_path / "s.yaml", {
        "data": SIMULATED, "methods": {"baseline": {}}, "seeds": 4,
        "grid": {"methods.baseline.buffer_size": [10, 20, 40, 80]}})
    config = load_sweep_config(path, quick=True)
    assert [p.parameters["methods.baseline.buffer_size"] for p in config.points] == \
        [10, 20, 40, 80][:QUICK_GRID_VALUES]
    assert config.seeds == [0]
    assert all(point.config.quick for point in config.points)


@pytest.mark.parametrize(("grid", "expected"), [
    ({"data.imu": ["mpu9255", "um8"]},
     r"grid\.data\.imu\[1\]: unknown IMU profile; expected one of .*got 'um8'"),
    ({"data.occlusions.gap_range": [[0.1, 0.3], [0.6, 0.3]]},
     r"grid\.data\.occlusions\.gap_range\[1\]: expected \[min, max\] seconds"),
    ({"data.occlusions.gap_range": [[0.1, "a"]]},
     r"grid\.data\.occlusions\.gap_range\[0\]\[1\]: Input should be a valid number"),
    ({"data.imux": ["um7"]}, r"grid\.data\.imux: unknown key; expected one of \["),
    ({"methods.kalman.acelerometer_noise": [0.1]},
     r"grid\.methods\.kalman\.acelerometer_noise: unknown parameter; expected one of"),
    ({"methods.baseline.buffer_size": [20, 2]},
     r"grid\.methods\.baseline\.buffer_size\[1\]: BaselineParameters\.buffer_size: expected "
     r"an integer >= 3, got 2"),
    ({"method": ["baseline", "kalmn"]},
     r"grid\.method\[1\]: unknown method 'kalmn'; expected one of"),
    ({"seeds": [1, 2]}, r"grid\.seeds: expected 'method' or a dotted key path starting with"),
    ({"data.imu": []}, r"grid\.data\.imu: expected a non-empty list of values, got \[\]"),
    ({"data.imu": "um7"}, r"grid\.data\.imu: Input should be a valid list, got 'um7'"),
    ({}, r"grid: expected at least one axis"),
    ({"data.kind.x": [1]}, r"grid\.data\.kind\.x: data\.kind is not a mapping"),
])
def test_bad_grid_values_are_named_by_grid_key_before_anything_runs(grid, expected, tmp_path,
                                                                    capsys):
    path = write_yaml(tmp_path / "s.yaml", {"data": SIMULATED, "grid": grid})
    with pytest.raises(ConfigError, match=expected):
        load_config(path)
    err = error_of(path, "sweep", capsys)
    assert re.search(expected, err)
    assert not (tmp_path / "out").exists()


def test_heatmap_axes_must_be_grid_axes(tmp_path):
    path = write_yaml(tmp_path / "s.yaml", {
        "data": SIMULATED, "grid": {"data.imu": ["um7"]},
        "heatmaps": [{"rows": "data.imu", "columns": "gap", "value": "rms_mm"}]})
    with pytest.raises(ConfigError, match=r"heatmaps\[0\]\.columns: 'gap' is not a grid axis"):
        load_config(path)
    path = write_yaml(tmp_path / "t.yaml", {
        "data": SIMULATED, "grid": {"data.imu": ["um7"]},
        "heatmaps": [{"rows": "data.imu", "columns": "method", "value": "speed"}]})
    with pytest.raises(ConfigError, match=r"heatmaps\[0\]\.value: unknown metric 'speed'"):
        load_config(path)
