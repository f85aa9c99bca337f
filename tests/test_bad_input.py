"""Bad input that used to escape: each case gets one line naming the file, row or key, exit 2 at
the command line, and nothing overwritten (the guide's bad-input table, issue 9 item 8)."""

from __future__ import annotations

import errno
import math
import shutil
import time
import warnings

import numpy as np
import pandas as pd
import pytest

from kfusion.baseline import BaselineParameters, BaselineTracker
from kfusion.cli import main
from kfusion.config import ConfigError, load_config, parse_config
from kfusion.guards import (
    MAX_YAML_NODES,
    YamlError,
    atomic_write,
    load_yaml,
    load_yaml_text,
    real_number,
    short_repr,
)
from kfusion.kalman import KalmanFusion, KalmanParameters
from kfusion.recording import ImuSamples, MarkerFrames, MocapFrames, read_info
from kfusion.simulate import OcclusionSpec, simulate, write_simulation
from kfusion.tracker import Tracker

# 434 bytes: nine levels of nine aliases, 9^9 ~ 387 million values once expanded
ALIAS_BOMB = "\n".join(
    ["a0: &a0 [1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    + [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, 9)]
) + "\n"
HUGE_INTEGER = int("9" * 400)


@pytest.fixture(scope="module")
def source_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("source") / "rec"
    write_simulation(simulate("circle", seed=1, duration=6.0,
                              occlusions=OcclusionSpec(gap_range=(0.15, 0.3), spacing=1.0)),
                     folder)
    return folder


@pytest.fixture
def folder(source_folder, tmp_path):
    copy = tmp_path / "rec"
    shutil.copytree(source_folder, copy)
    return copy


def edit_yaml(folder, old, new):
    path = folder / "recording.yaml"
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new))


def cli_error(capsys, argv):
    status = main(argv)
    err = capsys.readouterr().err
    assert status == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err
    return err


# ------------------------------------------------------------------------------ YAML


def test_alias_bomb_in_recording_yaml_is_refused_quickly(folder, capsys):
    (folder / "recording.yaml").write_text(ALIAS_BOMB + "imu_to_body: *a8\n"
                                           "gravity: [0, -9.81, 0]\n")
    start = time.perf_counter()
    err = cli_error(capsys, ["check", str(folder)])
    elapsed = time.perf_counter() - start
    assert f"recording.yaml: aliases expand to more than {MAX_YAML_NODES} values" in err
    assert len(err) < 300
    assert elapsed < 10  # a guard against expansion (it took 22 s and 1.6 GB), not a timing test


def test_alias_bomb_in_a_config_and_a_tracker_file(tmp_path):
    config = tmp_path / "bomb.yaml"
    config.write_text(ALIAS_BOMB + "data: {kind: simulate, scenario: circle}\nseeds: *a8\n")
    with pytest.raises(ConfigError, match=r"bomb\.yaml: aliases expand to more than"):
        load_config(config)
    with pytest.raises(ValueError, match=r"bomb\.yaml: aliases expand to more than"):
        Tracker.from_yaml(config)


def test_a_merge_key_bomb_is_measured_before_it_is_flattened():
    text = "a0: &a0 {k: 1}\n" + "".join(
        f"a{i}: &a{i} {{<<: [" + ", ".join([f"*a{i - 1}"] * 9) + f"], k{i}: 1}}\n"
        for i in range(1, 9))
    with pytest.raises(YamlError, match="aliases expand to more than"):
        load_yaml_text(text, "merge.yaml")


@pytest.mark.parametrize(("text", "message"), [
    ("a: &a [*a]\n", r"x\.yaml: an alias refers to a collection containing it"),
    ("a: " + "[" * 100 + "]" * 100 + "\n", r"x\.yaml: nested deeper than 64 levels"),
    ("a: 1\na: 2\n", r"x\.yaml: line 2, column 1: duplicate key 'a'"),
    ("a: [1\n", r"x\.yaml: line 2, column 1: expected ',' or ']'"),
])
def test_yaml_loader_refusals(text, message):
    with pytest.raises(YamlError, match=message):
        load_yaml_text(text, "x.yaml")


def test_plain_anchors_still_load():
    assert load_yaml_text("a: &a [1, 2]\nb: *a\nc: {<<: {x: 1}, y: 2}\n", "x.yaml") == {
        "a": [1, 2], "b": [1, 2], "c": {"x": 1, "y": 2}}


def test_non_utf8_recording_yaml_names_the_file(folder, capsys):
    with open(folder / "recording.yaml", "ab") as handle:
        handle.write(b"name: caf\xe9\n")
    err = cli_error(capsys, ["check", str(folder)])
    assert "recording.yaml: not UTF-8 text (byte 0xe9 on line" in err
    with pytest.raises(ValueError, match=r"recording\.yaml: not UTF-8 text"):
        read_info(folder / "recording.yaml")


def test_oversized_yaml_is_refused(tmp_path):
    path = tmp_path / "big.yaml"
    path.write_text("# " + "x" * 1_100_000 + "\n")
    with pytest.raises(YamlError, match=r"big\.yaml: file is 1100003 bytes; expected a YAML "
                       r"file of at most 1000000 bytes"):
        load_yaml(path)


def test_a_400_digit_gravity_is_one_short_line(folder, capsys):
    edit_yaml(folder, "- -9.81", f"- {HUGE_INTEGER}")
    err = cli_error(capsys, ["check", str(folder)])
    assert "recording.yaml, key 'gravity': expected a list of 3 finite numbers, got " in err
    assert "<an integer of 400 digits>" in err and len(err) < 200


def test_tracker_file_with_huge_and_unhashable_values(tmp_path):
    path = tmp_path / "tracker.yaml"
    path.write_text(f"imu_to_body: [1, 0, 0, 0]\ngravity: [0, 0, -9.81]\n"
                    f"tracker: {{fix_timeout_s: {HUGE_INTEGER}}}\n")
    with pytest.raises(ValueError, match=r"TrackerOptions\.fix_timeout_s: expected a finite "
                       r"number > 0, got <an integer of 400 digits>"):
        Tracker.from_yaml(path)
    path.write_text("imu_to_body: [1, 0, 0, 0]\ngravity: [0, 0, -9.81]\nmethod: [kalman]\n")
    with pytest.raises(ValueError, match=r"method: expected one of \['kalman', 'baseline'\], "
                       r"got \['kalman'\]"):
        Tracker.from_yaml(path)
    path.write_text("imu_to_body: [1, 0, 0, 0]\ngravity: [0, 0, -9.81]\nimu: 5\n")
    with pytest.raises(ValueError, match=r"imu: unknown IMU profile 5"):
        Tracker.from_yaml(path)


def test_short_repr_never_prints_a_whole_value():
    assert short_repr("abc") == "'abc'"
    assert short_repr(HUGE_INTEGER) == "<an integer of 400 digits>"
    nested = [[list(range(1000))] * 1000] * 1000
    assert len(short_repr(nested)) <= 60
    assert short_repr("x" * 500, limit=20) == "'xxxxxxxxxxxxxxxx..."
    assert real_number(HUGE_INTEGER) == math.inf and real_number(-HUGE_INTEGER) == -math.inf
    assert real_number(True) is None and real_number("1") is None and real_number(2) == 2.0


# ------------------------------------------------------------------------------ writing


def test_track_out_naming_a_folder(folder, tmp_path, capsys):
    err = cli_error(capsys, ["track", str(folder), "--out", str(tmp_path)])
    assert f"{tmp_path}: is a folder; expected the path of a file to write" in err


def _half_then_fail(number):
    original = pd.DataFrame.to_csv

    def failing(self, path=None, *args, **kwargs):
        text = original(self, None, *args, **kwargs)
        with open(path, "w") as handle:
            handle.write(text[: len(text) // 2])
        raise OSError(number, {errno.ENOSPC: "No space left on device",
                               errno.EIO: "Input/output error"}[number])

    return failing


@pytest.mark.parametrize("method", ["kalman", "baseline"])
def test_a_failed_track_write_keeps_the_previous_file(folder, tmp_path, capsys, monkeypatch,
                                                      method):
    out = tmp_path / "track.csv"
    assert main(["track", str(folder), "--method", method, "--out", str(out)]) == 0
    before = out.read_bytes()
    monkeypatch.setattr(pd.DataFrame, "to_csv", _half_then_fail(errno.ENOSPC))
    err = cli_error(capsys, ["track", str(folder), "--method", method, "--out", str(out),
                             "--set", "max_bridge_s=0.2"])
    assert f"{out}: cannot write (No space left on device); any previous file is unchanged" \
        in err
    assert out.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rec", "track.csv"]  # no temp left


def test_atomic_write_keeps_the_old_file_on_any_failure(tmp_path):
    path = tmp_path / "out.txt"
    path.write_text("old")

    def crash(temporary):
        temporary.write_text("half")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        atomic_write(path, crash)
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["out.txt"]
    atomic_write(path, lambda temporary: temporary.write_text("new"))
    assert path.read_text() == "new"


def test_calibrate_out_is_written_atomically(tmp_path, capsys, monkeypatch):
    # a recording rich enough in rotation for calibrate to determine everything
    folder = tmp_path / "rich"
    write_simulation(simulate("random_reach", seed=0, duration=20.0), folder)
    out = tmp_path / "calibrated.yaml"
    out.write_text("previous\n")
    monkeypatch.setattr("pathlib.Path.write_text", lambda self, text, **kw: (_ for _ in ()).throw(
        OSError(errno.EIO, "Input/output error")))
    err = cli_error(capsys, ["calibrate", str(folder), "--out", str(out), "--force",
                             "--angular-rate"])
    assert "cannot write (Input/output error)" in err
    assert out.read_bytes() == b"previous\n"


def test_a_failed_sweep_table_write_keeps_the_previous_table(tmp_path, monkeypatch):
    from kfusion.sweep import SweepStore

    store = SweepStore(tmp_path)
    row = {"run_id": "abc", "seed": 0, "rms_mm": 1.0}
    path = store.write(row)
    before = path.read_bytes()
    monkeypatch.setattr(pd.DataFrame, "to_parquet", lambda self, target, **kw: (
        open(target, "wb").write(b"PAR"), (_ for _ in ()).throw(OSError(errno.ENOSPC, "full"))))
    with pytest.raises(OSError, match="cannot write"):
        store.write({**row, "rms_mm": 2.0})
    assert path.read_bytes() == before


# ------------------------------------------------------------------------------ --set


@pytest.mark.parametrize(("value", "message"), [
    ("max_bridge_s=[1", r"--set max_bridge_s: expected a number, true/false or null, got '\[1' "
     r"\(line 1, column 3: expected ',' or '\]'"),
    (f"max_bridge_s={HUGE_INTEGER}", r"--set max_bridge_s: Input should be a valid number, got "
     r"<an integer of 400 digits>"),
    ("max_bridge_s=&a [*a]", r"--set max_bridge_s: .*recursive alias"),
    ("max_bridge_s=1e300", r"max_bridge_s: expected at most 60 s, got 1e\+300"),
    ("accelerometer_noise_density=0", r"accelerometer_noise_density: expected a number > 0"),
    ("gate_probability=two", r"--set gate_probability: .*got 'two'"),
    ("imu_latency_s=1e300", r"imu_latency_s: expected at most 1 s either way .*got 1e\+300"),
    ("mocap_position_noise=1e-300", r"mocap_position_noise: expected at least 1e-06 m"),
    ("=3", r"--set: expected KEY=VALUE, got '=3'"),
    ("max_bridge_s=true", r"--set max_bridge_s: expected a number, got true"),  # was 1.0 s
    ("gate_probability=false", r"--set gate_probability: expected a number, got false"),
])
def test_malformed_set_values(folder, tmp_path, capsys, value, message):
    import re

    err = cli_error(capsys, ["track", str(folder), "--out", str(tmp_path / "t.csv"),
                             "--set", value])
    assert re.search(message, err), err
    assert not (tmp_path / "t.csv").exists()


def test_set_values_are_converted_like_config_values(folder, tmp_path, capsys):
    out = tmp_path / "t.csv"
    assert main(["track", str(folder), "--out", str(out), "--set", "max_bridge_s=1e-1"]) == 0
    assert "lost" in set(pd.read_csv(out)["status"])  # 0.1 s is shorter than the gaps


# ------------------------------------------------------------------------------ check = track


@pytest.mark.parametrize("name", ["bogus_imu", "mpu6050"])
@pytest.mark.parametrize("command", ["check", "track"])
def test_check_and_track_refuse_an_unknown_imu_profile_alike(folder, tmp_path, capsys, name,
                                                             command):
    edit_yaml(folder, "imu: mpu9255", f"imu: {name}")
    extra = ["--out", str(tmp_path / "t.csv"), "--method", "baseline"] if command == "track" \
        else []
    err = cli_error(capsys, [command, str(folder), *extra])
    assert (f"recording.yaml, key 'imu': unknown IMU profile '{name}'; expected one of "
            "['broad', 'mpu9255', 'um7']") in err


def test_a_known_profile_in_any_case_passes(folder, capsys):
    edit_yaml(folder, "imu: mpu9255", "imu: UM7")
    assert main(["check", str(folder)]) == 0


# ------------------------------------------------------------------------------ configs


@pytest.mark.parametrize("name", ["../../x", "/tmp/x", "..", "a/b", "a\\b", "C:x", " x"])
def test_a_config_name_cannot_leave_the_output_folder(name):
    with pytest.raises(ConfigError, match=r"<config>: name: expected a plain name"):
        parse_config({"name": name, "data": {"kind": "simulate", "scenario": "circle"}})


def test_a_plain_config_name_is_kept():
    config = parse_config({"name": "arm lift 2", "data": {"kind": "simulate",
                                                          "scenario": "circle"}})
    assert str(config.output_directory()) == "kfusion-output/arm lift 2"


# ------------------------------------------------------------------------------ arrays, parameters


def test_masked_arrays_are_refused_everywhere():
    masked = np.ma.array([0.0, 0.0, 9.81], mask=[False, True, False])
    gyro = np.zeros(3)
    pattern = r"expected a plain array or sequence \(NaN marks a missing value\), got a masked " \
        r"array \(numpy\.ma\)"
    tracker = Tracker([1, 0, 0, 0], [0, 0, -9.81])
    with pytest.raises(ValueError, match="push_imu: acc: " + pattern):
        tracker.push_imu(0.0, masked, gyro)
    with pytest.raises(ValueError, match="push_mocap: position: " + pattern):
        tracker.push_mocap(0.0, np.ma.array([0.1, 0.2, 0.3], mask=True), [1, 0, 0, 0])
    fusion = KalmanFusion([1, 0, 0, 0], [0, 0, -9.81], KalmanParameters.from_profiles())
    with pytest.raises(ValueError, match="accelerometer: " + pattern):
        fusion.predict(0.0, masked, gyro)
    with pytest.raises(ValueError, match="gyroscope: " + pattern):
        BaselineTracker([1, 0, 0, 0]).push_imu(0.0, [0, 0, 9.81], np.ma.array(gyro))
    with pytest.raises(ValueError, match="ImuSamples.t: " + pattern):
        ImuSamples(np.ma.array([0.0, 0.01]), np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="MocapFrames.position: " + pattern):
        MocapFrames(np.zeros(1), np.ma.zeros((1, 3)), np.zeros((1, 4)))


@pytest.mark.parametrize("stamp", [math.nan, math.inf, -math.inf])
def test_a_stream_refuses_a_stamp_that_is_not_finite_where_it_is_built(stamp):
    # Before, each engine met such a stamp at a different point: a fused fix took an infinite
    # time without a word (whole-loop kernel, filterpy), the monitored smoother fell back to
    # filterpy with the compiled monitor ("restore: expected a CompiledSnapshot"), and the
    # step-by-step engines refused it. The reader refuses it in a file; a recording built in
    # code now does too, naming the stream and the row.
    times = np.array([0.0, 0.01, stamp, 0.03])
    with pytest.raises(ValueError, match=rf"^ImuSamples\.t: row 2: expected a finite time in s, "
                       rf"got {stamp!r}$"):
        ImuSamples(times, np.zeros((4, 3)), np.zeros((4, 3)))
    with pytest.raises(ValueError, match=rf"^MocapFrames\.t: row 2: expected a finite time in "
                       rf"s, got {stamp!r}$"):
        MocapFrames(times, np.zeros((4, 3)), np.tile([1.0, 0, 0, 0], (4, 1)))
    with pytest.raises(ValueError, match=r"^MarkerFrames\.t: row 1: .* \(2 such rows\)$"):
        MarkerFrames(np.array([0.0, stamp, stamp]), ("A",), np.zeros((3, 1, 3)))
    recording = simulate("arm_lift", seed=0, duration=5.0).recording
    stamps = recording.mocap.t.copy()
    stamps[-1] = stamp
    with pytest.raises(ValueError, match=r"MocapFrames\.t: row \d+: expected a finite time"):
        recording.with_mocap(MocapFrames(stamps, recording.mocap.position,
                                         recording.mocap.quaternion))


@pytest.mark.parametrize("name", ["accelerometer_noise_density",
                                  "accelerometer_bias_random_walk"])
def test_zero_accelerometer_noise_densities_are_refused(name):
    with pytest.raises(ValueError, match=rf"KalmanParameters\.{name}: expected a number > 0, "
                       r"got 0"):
        KalmanParameters.from_profiles(**{name: 0})


def test_a_noise_free_gyroscope_is_allowed_and_the_smoother_stays_regular():
    # every other noise term zero too: what made the smoother's covariance singular before
    from kfusion.methods import track_with_method

    recording = simulate("circle", seed=0, duration=6.0,
                         occlusions=OcclusionSpec(gap_range=(0.1, 0.2))).recording
    zero = {name: 0.0 for name in ("gyroscope_noise_density", "gyroscope_bias_random_walk",
                                   "initial_bias_std", "initial_gyroscope_bias_std",
                                   "mocap_orientation_noise", "accelerometer_scale_error",
                                   "gyroscope_scale_error", "lever_arm_std",
                                   "tilt_error_inflation")}
    result = track_with_method(recording, "smoother", **zero)
    assert np.isfinite(result.std[result.status != "lost"]).all()


def test_absurd_bridging_times_are_refused():
    with pytest.raises(ValueError, match=r"KalmanParameters\.max_bridge_s: expected at most "
                       r"60 s, got 1e\+300"):
        KalmanParameters.from_profiles(max_bridge_s=1e300)
    with pytest.raises(ValueError, match=r"BaselineParameters\.max_bridge_s: expected a "
                       r"positive number of seconds, at most 60, got 1e\+300"):
        BaselineParameters(max_bridge_s=1e300)
    with pytest.raises(ValueError, match=r"KalmanParameters\.max_bridge_s: expected a finite "
                       r"number, got <an integer of 400 digits>"):
        KalmanParameters.from_profiles(max_bridge_s=HUGE_INTEGER)
    with pytest.raises(ValueError, match=r"BaselineParameters\.buffer_size: expected an "
                       r"integer <= 10000, got <an integer of 400 digits>"):
        BaselineParameters(buffer_size=HUGE_INTEGER)
    assert KalmanParameters.from_profiles(max_bridge_s=60).max_bridge_s == 60.0


def test_imu_stamps_colliding_on_the_mocap_clock_name_the_row(folder, capsys):
    # raw stamps 1e-8 s apart, an offset of 1e9 s: one double on the mocap clock (check passed
    # with numpy warnings and track failed in the filter without naming the row)
    imu = pd.read_csv(folder / "imu.csv")
    mocap = pd.read_csv(folder / "mocap.csv")
    mocap["t"] += 1e9
    imu.loc[5, "t"] = imu.loc[4, "t"] + 1e-8
    imu.to_csv(folder / "imu.csv", index=False, float_format="%.17g")
    mocap.to_csv(folder / "mocap.csv", index=False, float_format="%.17g")
    with open(folder / "recording.yaml", "a") as stream:
        stream.write("imu_time_offset: 1000000000.0\n")
    for command in (["check", str(folder)], ["track", str(folder), "--out",
                                              str(folder / "t.csv")]):
        assert main(command) == 2
        error = capsys.readouterr().err.strip().splitlines()
        assert len(error) == 1
        assert "imu.csv, row 6 (line 7), column 't'" in error[0]
        assert "maps onto the mocap clock" in error[0]
    assert not (folder / "t.csv").exists()


# ------------------------------------------------------------------------------------------
# Found by a fuzzing pass (each gave a traceback, a hang or lost data)
# ------------------------------------------------------------------------------------------


def test_a_control_character_in_any_yaml_is_one_line(folder, tmp_path, capsys):
    """PyYAML's reader refuses raw control characters while the loader is built, before the
    loader's own try: a ReaderError escaped as a traceback from recording.yaml, configs and
    --set."""
    edit_yaml(folder, "name:", "bell: \"a\x07b\"\nname:")
    message = cli_error(capsys, ["check", str(folder)])
    assert "recording.yaml" in message and "#x0007" in message
    with pytest.raises(YamlError, match="#x0000"):
        load_yaml_text("name: a\x00", "x.yaml")


@pytest.mark.parametrize("name", ["mocap.csv", "imu.csv", "recording.yaml"])
def test_track_never_writes_over_its_own_inputs(folder, capsys, name):
    """``kfusion track DIR --out DIR/mocap.csv`` exited 0 and replaced the recording's mocap with
    the track."""
    before = (folder / name).read_bytes()
    message = cli_error(capsys, ["track", str(folder), "--out", str(folder / name)])
    assert "--out" in message and "an input of this run" in message
    assert (folder / name).read_bytes() == before


@pytest.mark.parametrize("name", ["mocap_position_noise", "accelerometer_noise_density",
                                  "initial_velocity_std", "gate_min_innovation",
                                  "gyroscope_scale_error"])
def test_huge_finite_parameters_are_refused(folder, tmp_path, capsys, name):
    """From about 1.4e154 Python's x ** 2 raised OverflowError out of kfusion track (some on
    every engine, some on filterpy only: the engines also disagreed)."""
    with pytest.raises(ValueError, match=f"KalmanParameters.{name}: expected at most 1e\\+06"):
        KalmanParameters.from_profiles(**{name: 1e200})
    message = cli_error(capsys, ["track", str(folder), "--out", str(tmp_path / "t.csv"),
                                 "--set", f"{name}=1e300"])
    assert name in message and not (tmp_path / "t.csv").exists()


def test_a_simulation_longer_than_an_hour_is_refused(tmp_path, capsys):
    """``kfusion simulate --duration 1e9`` ran for minutes without an end."""
    message = cli_error(capsys, ["simulate", "circle", "--duration", "1e9", "--out",
                                 str(tmp_path / "s")])
    assert "duration: expected 5-3600 s" in message and not (tmp_path / "s").exists()


def test_paper_tables_longer_than_an_hour_are_refused(tmp_path, capsys):
    """``kfusion paper --duration`` goes through the same limit (untried by the fuzzing)."""
    message = cli_error(capsys, ["paper", "--duration", "1e9", "--out", str(tmp_path / "p")])
    assert "duration: expected 5-3600 s" in message and not (tmp_path / "p").exists()


@pytest.mark.parametrize("value", ["1e9", "-1", "0"])
def test_calibrate_max_offset_must_be_a_sane_search_range(folder, capsys, value):
    """``--max-offset 1e9`` asked numpy for 2.9 TiB (MemoryError), -1 printed "+- -1 s" (nan,
    which gave "arange: cannot compute length", is refused as a number option:
    :func:`test_number_options_must_be_finite`)."""
    message = cli_error(capsys, ["calibrate", str(folder), "--max-offset", value])
    assert "max offset: expected a number of seconds in (0, 3600]" in message


def test_a_huge_csv_cell_is_shown_short(folder, capsys):
    path = folder / "imu.csv"
    lines = path.read_text().splitlines()
    cells = lines[3].split(",")
    cells[1] = "1" * 200_000
    lines[3] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    message = cli_error(capsys, ["check", str(folder)])
    assert "imu.csv, row 3" in message and len(message) < 300


def test_bounds_refuse_what_is_not_a_covariance_or_a_probability():
    """A negative definite covariance gave a zero bound (the unsafe answer); a confidence of
    10**400 an OverflowError; a lost estimate took any confidence."""
    from kfusion.tracker import position_bound

    with pytest.raises(ValueError, match="largest eigenvalue"):
        position_bound(-np.eye(3))
    assert position_bound(np.zeros((3, 3))) == 0.0
    tracker = Tracker([1, 0, 0, 0], [0, 0, -9.81])
    for index in range(400):
        t = index * 0.005
        tracker.push_imu(t, [0, 0, 9.81], [0, 0, 0])
        tracker.push_mocap(t, [0, 0, 0], [1, 0, 0, 0])
    estimate = tracker.estimate(tracker.newest_time)
    for confidence in (10 ** 400, 1.5, math.nan, True):
        with pytest.raises(ValueError, match="confidence"):
            estimate.bound(confidence)
    lost = tracker.estimate(tracker.newest_time + 100.0)
    assert lost.status == "lost" and lost.bound() == math.inf
    with pytest.raises(ValueError, match="confidence"):
        lost.bound(1.5)


def test_python_dash_m_kfusion_is_the_command():
    import subprocess
    import sys

    done = subprocess.run([sys.executable, "-m", "kfusion", "--version"], capture_output=True,
                          text=True, timeout=120, check=False)
    assert done.returncode == 0 and done.stdout.strip()


def test_recording_yaml_vectors_take_numbers_only(folder, capsys):
    """np.asarray(dtype=float) took imu_to_body: [true, false, false, false] and gravity as
    strings, where scalar keys never take a bool or a string."""
    import yaml

    data = yaml.safe_load((folder / "recording.yaml").read_text())
    data["lever_arm"] = [True, True, True]
    (folder / "recording.yaml").write_text(yaml.safe_dump(data))
    message = cli_error(capsys, ["check", str(folder)])
    assert "key 'lever_arm': expected a list of 3 numbers, got [True, True, True]" in message
    data["lever_arm"], data["gravity"] = [0.0, 0.0, 0.0], ["0", "-9.81", "0"]
    (folder / "recording.yaml").write_text(yaml.safe_dump(data))
    message = cli_error(capsys, ["check", str(folder)])
    assert "key 'gravity': expected a list of 3 numbers" in message


@pytest.mark.parametrize("name", ["\ud800", "a\x1b[31mb"])
def test_a_recording_name_must_be_printable(folder, capsys, name):
    """A lone surrogate let check print "ok" and then fail to encode it; an escape sequence
    reached the terminal in every message naming the recording."""
    escaped = name.encode("unicode_escape").decode("ascii")
    (folder / "recording.yaml").write_text(
        (folder / "recording.yaml").read_text() + f'name: "{escaped}"\n'
        if "name:" not in (folder / "recording.yaml").read_text()
        else "\n".join(line if not line.startswith("name:") else f'name: "{escaped}"'
                       for line in (folder / "recording.yaml").read_text().splitlines()) + "\n")
    message = cli_error(capsys, ["check", str(folder)])
    assert "key 'name': expected printable text" in message
    assert "ok:" not in capsys.readouterr().out


def test_no_time_overlap_names_the_visible_mocap(folder, capsys):
    """With one visible frame the message said the mocap spanned the whole recording (its
    occluded rows) and that the overlap was 0: it contradicted itself."""
    lines = (folder / "mocap.csv").read_text().splitlines()
    columns = lines[0].count(",")
    kept = lines[:2] + [line.split(",")[0] + "," * columns for line in lines[2:]]
    (folder / "mocap.csv").write_text("\n".join(kept) + "\n")
    message = cli_error(capsys, ["check", str(folder)])
    assert "the visible mocap" in message and "(1 frames;" in message


def test_track_out_with_a_trailing_separator_is_a_folder(folder, tmp_path, capsys):
    message = cli_error(capsys, ["track", str(folder), "--out", str(tmp_path / "new") + "/"])
    assert "names a folder; expected a file" in message and not (tmp_path / "new").exists()


# ------------------------------------------------------------------------------ values near 1e308


@pytest.mark.parametrize(("key", "value", "message"), [
    ("imu_to_body", [1e308, 1e308, 0.0, 0.0], "key 'imu_to_body': quaternion norm is inf"),
    ("gravity", [1e308, 1e308, 0.0], "key 'gravity': gravity length is inf"),
    ("lever_arm", [1e308, 1e308, 0.0],
     "key 'lever_arm': lever arm length is inf, implausible even in mm; expected m (at most 2 m)"),
])
def test_values_near_the_float_limit_in_recording_yaml_are_one_line(folder, capsys, key, value,
                                                                    message):
    """Their squares overflowed: numpy printed a RuntimeWarning before the error (and a lever
    arm of 1e308 m was said to look like mm)."""
    import yaml

    data = yaml.safe_load((folder / "recording.yaml").read_text())
    data[key] = value
    (folder / "recording.yaml").write_text(yaml.safe_dump(data))
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        assert message in cli_error(capsys, ["check", str(folder)])


@pytest.mark.parametrize(("column", "message"), [
    ("ay", "column 'ay': accelerometer value 1e+308 is beyond any body-worn sensor's range; "
           "expected |value| <= 10000 m/s^2"),
    ("gz", "column 'gz': gyroscope value -2000 is beyond any body-worn sensor's range; "
           "expected |value| <= 1000 rad/s"),
])
def test_an_imu_value_beyond_any_sensor_is_refused_with_its_row(folder, capsys, column, message):
    """A 1e308 accelerometer value passed check ("gravity not checked: Eigenvalues did not
    converge", after RuntimeWarnings) and was fused as merely saturated; a 1e308 gyroscope value
    was fused as an ordinary sample, turning the orientation by a random angle."""
    table = pd.read_csv(folder / "imu.csv")
    table.loc[7, column] = 1e308 if column == "ay" else -2000.0
    table.to_csv(folder / "imu.csv", index=False)
    for command in ("check", "track"):
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            argv = [command, str(folder)] + (["--out", str(folder / "out.csv")]
                                             if command == "track" else [])
            error = cli_error(capsys, argv)
        assert f"imu.csv, row 8 (line 9), {message}" in error
    assert not (folder / "out.csv").exists()


def _pushed_alongside(bad_pushes):
    """Two trackers fed the same circle; the second also gets ``bad_pushes`` (callables of the
    tracker and t) at t = 1.0025 s. Returns the estimates (first, second) at the end and the
    second's outcomes of the bad pushes."""
    simulation = simulate("circle", seed=1, duration=5.0)
    recording = simulation.recording
    trackers = [Tracker.from_recording_info(recording.info) for _ in range(2)]
    outcomes = []
    for stream, index in _arrival_order(recording):
        for number, tracker in enumerate(trackers):
            if stream == 0:
                imu = recording.imu
                t = float(imu.t[index])
                tracker.push_imu(t, imu.accelerometer[index], imu.gyroscope[index])
                if number == 1 and abs(t - 1.0) < 1e-9:
                    outcomes = [push(tracker, t + 0.0025) for push in bad_pushes]
            else:
                mocap = recording.mocap
                tracker.push_mocap(mocap.t[index], mocap.position[index],
                                   mocap.quaternion[index])
    end = float(recording.imu.t[-1])
    return trackers[0].estimate(end), trackers[1].estimate(end), outcomes, trackers[1]


def _arrival_order(recording):
    imu_t, mocap_t = np.asarray(recording.imu.t), np.asarray(recording.mocap.t)
    events = [(t, 0, i) for i, t in enumerate(imu_t)] + [(t, 1, i) for i, t in enumerate(mocap_t)]
    return [(stream, index) for _, stream, index in sorted(events)]


def test_corrupt_values_in_the_tracker_are_rejected_and_leave_the_state_untouched():
    """A 1e308 accelerometer value was fused as saturated, a 1e308 gyroscope value as an
    ordinary sample, and a 1e308 mocap coordinate reached the gate, whose rival cover overflowed
    with a RuntimeWarning. Each is now rejected ``implausible_value`` and counted."""
    gravity_force = [0.0, 9.81, 0.0]
    pushes = [
        lambda tracker, t: tracker.push_imu(t, [1e308, 0.0, 0.0], [0.0, 0.0, 0.0]),
        lambda tracker, t: tracker.push_imu(t, gravity_force, [0.0, 0.0, -1e308]),
        lambda tracker, t: tracker.push_imu(t, gravity_force, [0.0, 1001.0, 0.0]),
        lambda tracker, t: tracker.push_mocap(t, [0.0, 11.0, 0.0], [1.0, 0.0, 0.0, 0.0]),
        lambda tracker, t: tracker.push_mocap(t, [1e308, 0.0, 0.0], None),
    ]
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        plain, fed, outcomes, tracker = _pushed_alongside(pushes)
    assert [outcome.reason for outcome in outcomes] == ["implausible_value"] * 5
    assert tracker.health.imu_rejected["implausible_value"] == 3
    assert tracker.health.mocap_rejected["implausible_value"] == 2
    assert fed.status == plain.status
    np.testing.assert_array_equal(fed.position, plain.position)
    np.testing.assert_array_equal(fed.covariance, plain.covariance)


def test_a_tracker_lever_arm_longer_than_a_limb_is_refused():
    with pytest.raises(ValueError, match=r"^Tracker: lever_arm: expected at most 2 m long "
                                         r"\(m, not mm\), got 120$"):
        Tracker(imu_to_body=[1.0, 0.0, 0.0, 0.0], gravity=[0.0, -9.81, 0.0],
                lever_arm=[0.0, 120.0, 0.0])


@pytest.mark.parametrize("argv", [["stream", "DIR", "--start", "nan"],
                                  ["stream", "DIR", "--start", "inf"],
                                  ["calibrate", "DIR", "--gravity-tolerance", "nan"],
                                  ["calibrate", "DIR", "--max-offset", "nan"],
                                  ["simulate", "circle", "--out", "DIR/x", "--spacing", "inf"]])
def test_number_options_must_be_finite(folder, capsys, argv):
    """`stream --start nan` printed from the start and `--start inf` printed nothing, exit 0;
    `calibrate --gravity-tolerance nan` ran."""
    argv = [str(folder) if part == "DIR" else part.replace("DIR", str(folder)) for part in argv]
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert f"error: argument {argv[-2]}: expected a finite number, got '{argv[-1]}'" in err


def test_stream_start_after_the_recording_is_refused(folder, capsys):
    message = cli_error(capsys, ["stream", str(folder), "--start", "1e9"])
    assert "--start: expected a time up to the last mocap frame's, 6.000 s, got 1e+09" in message


def test_a_two_row_imu_file_is_not_called_milliseconds(folder, capsys):
    """Its 5 ms span against the mocap's 6 s made check advise dividing mocap.csv's t by 1000;
    the mocap's 10 ms step says it is in seconds."""
    lines = (folder / "imu.csv").read_text().splitlines()
    (folder / "imu.csv").write_text("\n".join(lines[:3]) + "\n")
    message = cli_error(capsys, ["check", str(folder)])
    assert "looks like ms" not in message and "no time overlap" in message
