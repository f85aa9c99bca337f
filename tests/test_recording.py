"""The recording folder: exact round trips and every validation message of kfusion.recording."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from kfusion.recording import (
    ImuSamples,
    MocapFrames,
    Recording,
    RecordingError,
    RecordingInfo,
    occlusion_durations,
    occlusion_runs,
    read_imu,
    read_info,
    read_mocap,
    read_recording,
    write_recording,
)

# floats whose text form must round-trip bit for bit; the last is 17 significant digits within
# a gyroscope's range (MAX_GYROSCOPE_VALUE: 1.2e8 rad/s is refused as corrupt)
AWKWARD = (0.1 + 0.2, 1e-17, -0.0, 5e-324, 1.0 / 3.0, 2.2250738585072014e-308, 987.6543210987654)


def unit_quaternions(rng: np.random.Generator, count: int) -> np.ndarray:
    quaternion = rng.normal(size=(count, 4))
    return quaternion / np.linalg.norm(quaternion, axis=1, keepdims=True)


def make_recording(rng: np.random.Generator, *, imu_count: int = 400, mocap_count: int = 120,
                   hidden: tuple[tuple[int, int], ...] = ((10, 15), (60, 61))) -> Recording:
    """A valid recording: IMU ~200 Hz, mocap ~60 Hz, occluded rows ``hidden`` ([start, stop))."""
    imu_t = np.concatenate([[1e-17, 0.1 + 0.2], 0.1 + 0.2 + np.cumsum(
        rng.uniform(0.004, 0.006, imu_count - 2))])
    accelerometer = np.array([0.3, -0.2, 9.81]) + rng.normal(scale=0.5, size=(imu_count, 3))
    gyroscope = rng.normal(size=(imu_count, 3)) * 10.0 ** rng.uniform(-20, 0, (imu_count, 3))
    accelerometer[:3, 0] = AWKWARD[:3]
    gyroscope[: len(AWKWARD), 1] = AWKWARD
    mocap_t = np.concatenate([[0.1 + 0.2], 0.1 + 0.2 + np.cumsum(
        rng.uniform(0.015, 0.018, mocap_count - 1))])
    position = rng.uniform(-2.0, 2.0, (mocap_count, 3))
    position[0] = [0.1 + 0.2, 1e-17, -0.0]
    quaternion = unit_quaternions(rng, mocap_count)
    for start, stop in hidden:
        position[start:stop] = np.nan
        quaternion[start:stop] = np.nan
    info = RecordingInfo(imu_to_body=unit_quaternions(rng, 1)[0],
                         gravity=[0.1 + 0.2, -9.80665, 1e-17], name="yes",
                         imu="mpu9255", lever_arm=[0.01, -0.02, 1e-17])
    return Recording(imu=ImuSamples(imu_t, accelerometer, gyroscope),
                     mocap=MocapFrames(mocap_t, position, quaternion), info=info)


def assert_same_bits(expected: np.ndarray, actual: np.ndarray) -> None:
    """Equal shapes, NaN in the same cells, and every other value bit for bit (-0.0 != 0.0)."""
    expected, actual = np.asarray(expected), np.asarray(actual)
    assert expected.shape == actual.shape
    np.testing.assert_array_equal(np.isnan(expected), np.isnan(actual))
    finite = ~np.isnan(expected)
    np.testing.assert_array_equal(expected[finite].view(np.int64), actual[finite].view(np.int64))


def assert_same_recording(expected: Recording, actual: Recording) -> None:
    for name in ("t", "accelerometer", "gyroscope"):
        assert_same_bits(getattr(expected.imu, name), getattr(actual.imu, name))
    for name in ("t", "position", "quaternion"):
        assert_same_bits(getattr(expected.mocap, name), getattr(actual.mocap, name))
    for name in ("imu_to_body", "gravity", "lever_arm"):
        assert_same_bits(getattr(expected.info, name), getattr(actual.info, name))
    assert (expected.info.name, expected.info.imu) == (actual.info.name, actual.info.imu)


# ------------------------------------------------------------------------------------------
# Round trips
# ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_write_then_read_is_bit_identical(tmp_path, seed):
    recording = make_recording(np.random.default_rng(seed))
    folder = write_recording(recording, tmp_path / "rec")
    assert_same_recording(recording, read_recording(folder))


def test_round_trip_keeps_awkward_floats_and_occlusions(tmp_path):
    recording = make_recording(np.random.default_rng(5))
    read = read_recording(write_recording(recording, tmp_path))
    assert read.imu.t[0] == 1e-17 and read.imu.t[1] == 0.30000000000000004
    assert read.imu.gyroscope[3, 1] == 5e-324
    assert np.signbit(read.mocap.position[0, 2]) and read.mocap.position[0, 2] == 0.0
    assert occlusion_runs(read.mocap.visible) == [(10, 15), (60, 61)]


def test_occluded_rows_are_written_as_empty_cells(tmp_path):
    recording = make_recording(np.random.default_rng(6))
    write_recording(recording, tmp_path)
    lines = (tmp_path / "mocap.csv").read_text().splitlines()
    assert lines[0] == "t,x,y,z,qw,qx,qy,qz"
    assert lines[11] == f"{float(recording.mocap.t[10])!r},,,,,,,"
    assert ",," not in lines[10] and "nan" not in lines[10].lower()


def test_optional_info_keys_are_omitted_and_other_files_ignored(tmp_path):
    recording = make_recording(np.random.default_rng(7))
    bare = RecordingInfo(imu_to_body=[1.0, 0.0, 0.0, 0.0], gravity=[0.0, 0.0, -9.81])
    folder = write_recording(Recording(recording.imu, recording.mocap, bare), tmp_path)
    assert set(yaml.safe_load((folder / "recording.yaml").read_text())) == {"imu_to_body",
                                                                              "gravity"}
    (folder / "truth.csv").write_text("whatever,is,here\n1,2\n")
    read = read_recording(folder)
    assert read.info.name is None and read.info.imu is None and read.info.lever_arm is None
    assert read.source == str(folder)


def test_arrays_are_read_only_and_with_mocap_replaces_frames(tmp_path):
    recording = make_recording(np.random.default_rng(8))
    with pytest.raises(ValueError, match="read-only"):
        recording.imu.accelerometer[0, 0] = 1.0
    other = MocapFrames([0.0, 1.0], [[0, 0, 0], [1, 1, 1]], [[1, 0, 0, 0], [1, 0, 0, 0]])
    replaced = recording.with_mocap(other)
    assert replaced.mocap is other and replaced.imu is recording.imu


def test_occlusion_runs_and_durations_by_hand():
    t = np.array([0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    visible = np.array([False, True, False, False, True, True, False])
    assert occlusion_runs(visible) == [(0, 1), (2, 4), (6, 7)]
    # start gap: t[1] - t[0]; middle: t[4] - t[1]; end gap: t[6] - t[5]
    np.testing.assert_allclose(occlusion_durations(t, visible), [0.1, 0.3, 0.1], atol=1e-15)
    assert occlusion_runs(np.ones(3, bool)) == []


# ------------------------------------------------------------------------------------------
# Zeros convention and occlusion reading
# ------------------------------------------------------------------------------------------


def test_zero_position_is_real_unless_told_otherwise(tmp_path):
    recording = make_recording(np.random.default_rng(9))
    write_recording(recording, tmp_path)
    set_cells(tmp_path / "mocap.csv", 30, {"x": "0", "y": "0.0", "z": "0"})
    default = read_mocap(tmp_path / "mocap.csv")
    assert default.visible[29] and np.array_equal(default.position[29], [0.0, 0.0, 0.0])
    zeros = read_mocap(tmp_path / "mocap.csv", zero_position_means_occluded=True)
    assert not zeros.visible[29]
    assert np.isnan(zeros.position[29]).all() and np.isnan(zeros.quaternion[29]).all()
    assert (~zeros.visible).sum() == (~default.visible).sum() + 1


def test_nan_text_marks_an_occluded_row(tmp_path):
    write_recording(make_recording(np.random.default_rng(10)), tmp_path)
    set_cells(tmp_path / "mocap.csv", 40, dict.fromkeys(("x", "y", "z", "qw", "qx", "qy", "qz"),
                                                        "NaN"))
    frames = read_mocap(tmp_path / "mocap.csv")
    assert not frames.visible[39] and frames.visible[38]


# ------------------------------------------------------------------------------------------
# Every error message
# ------------------------------------------------------------------------------------------


def set_cells(path: Path, row: int, values: dict[str, str]) -> None:
    """Overwrite cells of 1-based data ``row`` in a recording CSV (column name -> text)."""
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[row].split(",")
    for column, value in values.items():
        cells[header.index(column)] = value
    lines[row] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def scale_column(path: Path, columns: tuple[str, ...], factor: float) -> None:
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    for index in range(1, len(lines)):
        cells = lines[index].split(",")
        for column in columns:
            cells[header.index(column)] = repr(float(cells[header.index(column)]) * factor)
        lines[index] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")


def set_info(folder: Path, **changes: object) -> None:
    data = yaml.safe_load((folder / "recording.yaml").read_text())
    data.update(changes)
    (folder / "recording.yaml").write_text(yaml.safe_dump(data))


def copy_time(folder: Path, file: str, row: int, from_row: int) -> None:
    lines = (folder / file).read_text().splitlines()
    set_cells(folder / file, row, {"t": lines[from_row].split(",")[0]})


Mutation = Callable[[Path], None]

CASES: list[tuple[str, Mutation, str]] = [
    ("no yaml", lambda f: (f / "recording.yaml").unlink(),
     r"^recording\.yaml: file not found in "),
    ("bad yaml", lambda f: (f / "recording.yaml").write_text("gravity: [0, 0\nname: x\n"),
     r"^recording\.yaml: not valid YAML \(.*\)$"),
    ("yaml list", lambda f: (f / "recording.yaml").write_text("- 1\n- 2\n"),
     r"^recording\.yaml: expected a mapping with keys \['imu_to_body', .*\], got list$"),
    ("yaml empty", lambda f: (f / "recording.yaml").write_text(""),
     r"^recording\.yaml: expected a mapping .*got NoneType$"),
    ("unknown key", lambda f: set_info(f, frame_rate=100),
     r"^recording\.yaml, key 'frame_rate': unknown key; expected only \['imu_to_body', "),
    ("no gravity", lambda f: set_info(f, gravity=None),
     r"^recording\.yaml, key 'gravity': missing; expected a list of 3 numbers$"),
    ("gravity text", lambda f: set_info(f, gravity="down"),
     r"^recording\.yaml, key 'gravity': expected a list of 3 numbers, got 'down'$"),
    ("gravity short", lambda f: set_info(f, gravity=[0, -9.81]),
     r"^recording\.yaml, key 'gravity': expected a list of 3 finite numbers, got \[0, -9\.81\]$"),
    ("gravity nan", lambda f: set_info(f, gravity=[float("nan"), 0, -9.81]),
     r"^recording\.yaml, key 'gravity': expected a list of 3 finite numbers, got \[nan, "),
    ("gravity in g", lambda f: set_info(f, gravity=[0, 0, -1]),
     r"^recording\.yaml, key 'gravity': gravity length is 1 m/s\^2; expected about 9\.81 "
     r"\(between 9\.7 and 9\.9\)$"),
    ("rotation not unit", lambda f: set_info(f, imu_to_body=[2, 0, 0, 0]),
     r"^recording\.yaml, key 'imu_to_body': quaternion norm is 2; expected a unit quaternion "),
    ("imu_to_body short", lambda f: set_info(f, imu_to_body=[1, 0, 0]),
     r"^recording\.yaml, key 'imu_to_body': expected a list of 4 finite numbers, got \[1, 0, 0\]"),
    ("lever arm mm", lambda f: set_info(f, lever_arm=[30, 0, 0]),
     r"^recording\.yaml, key 'lever_arm': lever arm length is 30, which looks like mm; "
     r"expected m \(at most 2 m\)$"),
    ("name not text", lambda f: set_info(f, name=12),
     r"^recording\.yaml, key 'name': expected a string, got 12$"),
    ("imu not text", lambda f: set_info(f, imu=["mpu9255"]),
     r"^recording\.yaml, key 'imu': expected a string, got \['mpu9255'\]$"),
    ("no imu file", lambda f: (f / "imu.csv").unlink(), r"^imu\.csv: file not found in "),
    ("imu not utf8", lambda f: (f / "imu.csv").write_bytes(b"t,ax\n\xff\xfe,1\n"),
     r"^imu\.csv: cannot be parsed as CSV \("),
    ("mocap extra field", lambda f: set_cells(f / "mocap.csv", 3, {"qz": "0.5,0.1"}),
     r"^mocap\.csv: cannot be parsed as CSV \(.*Expected 8 fields in line 4, saw 9"),
    ("missing column", lambda f: (f / "imu.csv").write_text(
        (f / "imu.csv").read_text().replace("gy,gz", "gy,g_z", 1)),
     r"^imu\.csv, column 'gz': missing column\(s\) \['gz'\]; expected \['t', 'ax', .*found "),
    ("non-numeric", lambda f: set_cells(f / "imu.csv", 3, {"ay": "9;81"}),
     r"^imu\.csv, row 3 \(line 4\), column 'ay': non-numeric value '9;81'; expected a number$"),
    ("empty time", lambda f: set_cells(f / "mocap.csv", 5, {"t": ""}),
     r"^mocap\.csv, row 5 \(line 6\), column 't': empty timestamp; expected a time in s$"),
    ("infinite time", lambda f: set_cells(f / "imu.csv", 7, {"t": "inf"}),
     r"^imu\.csv, row 7 \(line 8\), column 't': non-finite timestamp inf$"),
    ("duplicated time", lambda f: copy_time(f, "imu.csv", 4, 3),
     r"^imu\.csv, row 4 \(line 5\), column 't': timestamp 0\.3\d* is duplicated \(0\.3\d*\); "
     r"expected strictly increasing times$"),
    ("time going back", lambda f: copy_time(f, "mocap.csv", 9, 2),
     r"^mocap\.csv, row 9 \(line 10\), column 't': timestamp \d\.\d+ is earlier than the "
     r"previous row \(\d\.\d+\); expected strictly increasing times$"),
    ("imu inf", lambda f: set_cells(f / "imu.csv", 6, {"gy": "-inf"}),
     r"^imu\.csv, row 6 \(line 7\), column 'gy': non-finite or empty IMU value -inf; IMU "
     r"samples must be finite$"),
    ("imu empty", lambda f: set_cells(f / "imu.csv", 6, {"az": ""}),
     r"^imu\.csv, row 6 \(line 7\), column 'az': non-finite or empty IMU value \(empty or NaN\)"),
    ("imu nan", lambda f: set_cells(f / "imu.csv", 8, {"gx": "NaN"}),
     r"^imu\.csv, row 8 \(line 9\), column 'gx': non-finite or empty IMU value "
     r"\(empty or NaN\); IMU samples must be finite$"),
    ("no samples", lambda f: (f / "imu.csv").write_text("t,ax,ay,az,gx,gy,gz\n"),
     r"^imu\.csv: no samples$"),
    ("imu in g", lambda f: scale_column(f / "imu.csv", ("ax", "ay", "az"), 1 / 9.81),
     r"^imu\.csv, column 'ax': median accelerometer magnitude is 1(\.\d*)?, which looks like g; "
     r"expected m/s\^2 \(about 9\.81 at rest\): multiply by 9\.80665$"),
    ("imu in mm/s2", lambda f: scale_column(f / "imu.csv", ("ax", "ay", "az"), 1000.0),
     r"^imu\.csv, column 'ax': median accelerometer magnitude is 9\.\d+e\+03 m/s\^2; expected "
     r"about 9\.81 m/s\^2 for a worn IMU"),
    ("gyro deg/s", lambda f: scale_column(f / "imu.csv", ("gx", "gy", "gz"), 1e5),
     r"^imu\.csv, column 'gx': 99th-percentile angular rate is .*, which looks like deg/s; "
     r"expected rad/s$"),
    ("no frames", lambda f: (f / "mocap.csv").write_text("t,x,y,z,qw,qx,qy,qz\n"),
     r"^mocap\.csv: no frames; expected at least one mocap row$"),
    ("mocap inf", lambda f: set_cells(f / "mocap.csv", 2, {"y": "inf"}),
     r"^mocap\.csv, row 2 \(line 3\), column 'y': infinite value; expected a number or an "
     r"empty cell \(occluded\)$"),
    ("partly empty", lambda f: set_cells(f / "mocap.csv", 4, {"qx": "", "qz": ""}),
     r"^mocap\.csv, row 4 \(line 5\), column 'qx': row is partly empty; expected all of x\.\.qz "
     r"filled, or all empty for an occluded frame$"),
    ("partly empty position", lambda f: set_cells(f / "mocap.csv", 11, {"z": "1.0"}),
     r"^mocap\.csv, row 11 \(line 12\), column 'x': row is partly empty"),
    ("not unit", lambda f: set_cells(f / "mocap.csv", 2, {"qw": "2", "qx": "0", "qy": "0",
                                                            "qz": "0"}),
     r"^mocap\.csv, row 2 \(line 3\), column 'qw': quaternion norm is 2; expected a unit "
     r"quaternion \[w, x, y, z\] \(\|norm - 1\| <= 0\.001\)$"),
    ("mocap in mm", lambda f: set_cells(f / "mocap.csv", 2, {"y": "1000"}),
     r"^mocap\.csv, row 2 \(line 3\), column 'y': position 1000 looks like mm; expected m "
     r"\(\|coordinate\| <= 10 m\): divide by 1000$"),
]


@pytest.mark.parametrize(("name", "mutate", "pattern"), CASES, ids=[case[0] for case in CASES])
def test_every_refusal_names_file_row_and_column(tmp_path, name, mutate, pattern):
    folder = write_recording(make_recording(np.random.default_rng(11)), tmp_path / "rec")
    mutate(folder)
    with pytest.raises(RecordingError, match=pattern) as error:
        read_recording(folder)
    assert "\n" not in str(error.value).strip()


def test_not_a_folder(tmp_path):
    with pytest.raises(RecordingError, match=r"missing: not a recording folder \(expected a "
                       r"directory holding imu\.csv, mocap\.csv and recording\.yaml\)$"):
        read_recording(tmp_path / "missing")


def test_single_file_readers_name_their_file(tmp_path):
    folder = write_recording(make_recording(np.random.default_rng(12)), tmp_path)
    assert len(read_imu(folder / "imu.csv")) == 400
    assert len(read_mocap(folder / "mocap.csv")) == 120
    assert read_info(folder / "recording.yaml").name == "yes"
    with pytest.raises(RecordingError, match=r"^nothing\.yaml: file not found in "):
        read_info(folder / "nothing.yaml")


def test_error_attributes_and_line_override():
    error = RecordingError("take.csv", "bad", row=3, column="x")
    assert (error.file, error.row, error.line, error.column, error.reason) == (
        "take.csv", 3, 4, "x", "bad")
    assert str(error) == "take.csv, row 3 (line 4), column 'x': bad"
    moved = RecordingError("take.csv", "bad", row=3, column="x", line=11)
    assert str(moved) == "take.csv, row 3 (line 11), column 'x': bad"
    assert str(RecordingError("r.yaml", "bad", key="gravity")) == "r.yaml, key 'gravity': bad"
    assert RecordingError("r.yaml", "bad").line is None


def test_typed_objects_refuse_wrong_shapes():
    with pytest.raises(ValueError, match=re.escape(
            "ImuSamples.accelerometer: expected shape (n, 3) with t of shape (n,), got t (2,) "
            "and accelerometer (2, 2)")):
        ImuSamples([0.0, 1.0], np.zeros((2, 2)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=re.escape(
            "ImuSamples.gyroscope: expected shape (n, 3) with t of shape (n,), got t (2,) and "
            "gyroscope (3, 3)")):
        ImuSamples([0.0, 1.0], np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match=re.escape(
            "MocapFrames: expected t (m,), position (m, 3), quaternion (m, 4); got (2,), (2, 3), "
            "(2, 3)")):
        MocapFrames([0.0, 1.0], np.zeros((2, 3)), np.zeros((2, 3)))
