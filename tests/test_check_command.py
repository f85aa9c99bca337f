"""``kfusion check DIR``: summary of a good folder; one stderr line and exit 2 for each bad one."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from kfusion.cli import main
from kfusion.conventions import matrix_from_wxyz
from kfusion.recording import (
    ImuSamples,
    MocapFrames,
    Recording,
    RecordingInfo,
    write_recording,
)

IMU_RATE = 200.0
MOCAP_RATE = 100.0
HIDDEN = ((50, 60), (120, 125))
"""Occluded mocap rows [start, stop): 10 and 5 frames."""


def good_recording(seed: int = 0) -> Recording:
    """2 s at rest-ish: IMU 401 samples at 200 Hz, mocap 201 frames at 100 Hz, 2 occlusions."""
    rng = np.random.default_rng(seed)
    imu_t = np.arange(401) / IMU_RATE
    # at rest the accelerometer reads R_imu_global (-g): consistent with the quaternion below
    up_imu = matrix_from_wxyz([0.5, 0.5, -0.5, 0.5]).T @ np.array([0.0, 9.81, 0.0])
    accelerometer = up_imu + rng.normal(scale=0.05, size=(401, 3))
    gyroscope = rng.normal(scale=0.01, size=(401, 3))
    mocap_t = np.arange(201) / MOCAP_RATE
    position = np.column_stack([0.2 + 0.1 * mocap_t, np.full(201, 1.1), -0.3 * mocap_t])
    quaternion = np.tile([0.5, 0.5, -0.5, 0.5], (201, 1))
    for start, stop in HIDDEN:
        position[start:stop] = np.nan
        quaternion[start:stop] = np.nan
    info = RecordingInfo(imu_to_body=[1.0, 0.0, 0.0, 0.0], gravity=[0.0, -9.81, 0.0],
                         name="forearm")
    return Recording(imu=ImuSamples(imu_t, accelerometer, gyroscope),
                     mocap=MocapFrames(mocap_t, position, quaternion), info=info)


@pytest.fixture
def folder(tmp_path) -> Path:
    return write_recording(good_recording(), tmp_path / "recording")


def run_check(capsys, *arguments: str) -> tuple[int, str, str]:
    status = main(["check", *arguments])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_good_folder_prints_the_summary(folder, capsys):
    status, out, err = run_check(capsys, str(folder))
    assert status == 0 and err == ""
    lines = [line for line in out.splitlines() if not line.startswith("consistency:")]
    assert lines[0] == f"ok: {folder}"
    # Occlusions measured from the last frame seen to the next: t[60] - t[49] = 0.11 s,
    # t[125] - t[119] = 0.06 s; median of two = 0.085 s.
    assert lines[1:] == [
        "recording: forearm",
        "duration: 2.000 s",
        "imu: 401 samples at 200.0 Hz",
        "mocap: 201 frames at 100.0 Hz, 15 occluded",
        "occlusions: 2",
        "occlusion length: min 0.060 s, median 0.085 s, max 0.110 s",
    ]


def test_recording_without_occlusions_has_no_length_line(tmp_path, capsys):
    recording = good_recording()
    mocap = recording.mocap
    seen = MocapFrames(mocap.t, np.nan_to_num(mocap.position, nan=0.5),
                       np.nan_to_num(mocap.quaternion, nan=0.5))
    folder = write_recording(recording.with_mocap(seen), tmp_path / "clean")
    status, out, _ = run_check(capsys, str(folder))
    assert status == 0
    assert "occlusions: 0" in out and "occlusion length" not in out


def zero_rows(folder: Path, rows: range) -> None:
    lines = (folder / "mocap.csv").read_text().splitlines()
    for row in rows:
        cells = lines[row].split(",")
        cells[1:4] = ["0.0", "0.0", "0.0"]
        lines[row] = ",".join(cells)
    (folder / "mocap.csv").write_text("\n".join(lines) + "\n")


def test_zeros_convention_is_off_unless_asked(folder, capsys):
    zero_rows(folder, range(31, 34))  # data rows 31-33 -> indices 30-32
    status, out, _ = run_check(capsys, str(folder))
    assert status == 0
    assert "15 occluded" in out and "occlusions: 2" in out
    status, out, _ = run_check(capsys, str(folder), "--zeros-occluded")
    assert status == 0
    # Indices 30-32 join: t[33] - t[29] = 0.04 s is the new shortest occlusion.
    assert "18 occluded" in out and "occlusions: 3" in out
    assert "min 0.040 s" in out


# ------------------------------------------------------------------------------------------
# Bad folders
# ------------------------------------------------------------------------------------------


def edit_cell(folder: Path, file: str, row: int, column: str, value: str) -> None:
    lines = (folder / file).read_text().splitlines()
    index = lines[0].split(",").index(column)
    cells = lines[row].split(",")
    cells[index] = value
    lines[row] = ",".join(cells)
    (folder / file).write_text("\n".join(lines) + "\n")


def scale(folder: Path, file: str, columns: tuple[str, ...], factor: float) -> None:
    lines = (folder / file).read_text().splitlines()
    header = lines[0].split(",")
    for row in range(1, len(lines)):
        cells = lines[row].split(",")
        for column in columns:
            index = header.index(column)
            if cells[index]:
                cells[index] = repr(float(cells[index]) * factor)
        lines[row] = ",".join(cells)
    (folder / file).write_text("\n".join(lines) + "\n")


def set_key(folder: Path, key: str, value: object) -> None:
    data = yaml.safe_load((folder / "recording.yaml").read_text())
    data[key] = value
    (folder / "recording.yaml").write_text(yaml.safe_dump(data))


def drop_column(folder: Path, file: str, column: str) -> None:
    lines = (folder / file).read_text().splitlines()
    index = lines[0].split(",").index(column)
    kept = [",".join(c for i, c in enumerate(line.split(",")) if i != index) for line in lines]
    (folder / file).write_text("\n".join(kept) + "\n")


BAD: list[tuple[str, Callable[[Path], None], str]] = [
    ("missing column", lambda f: drop_column(f, "mocap.csv", "qy"),
     r"mocap\.csv, column 'qy': missing column\(s\) \['qy'\]"),
    ("non-numeric cell", lambda f: edit_cell(f, "imu.csv", 10, "gz", "0.1rad"),
     r"imu\.csv, row 10 \(line 11\), column 'gz': non-numeric value '0\.1rad'"),
    ("non-finite imu", lambda f: edit_cell(f, "imu.csv", 12, "ax", "inf"),
     r"imu\.csv, row 12 \(line 13\), column 'ax': non-finite or empty IMU value inf"),
    ("empty imu cell", lambda f: edit_cell(f, "imu.csv", 12, "ay", ""),
     r"imu\.csv, row 12 \(line 13\), column 'ay': non-finite or empty IMU value \(empty or NaN\)"),
    ("duplicated timestamp", lambda f: edit_cell(f, "mocap.csv", 21, "t", "0.19"),
     r"mocap\.csv, row 21 \(line 22\), column 't': timestamp 0\.19 is duplicated \(0\.19\)"),
    ("decreasing timestamp", lambda f: edit_cell(f, "imu.csv", 21, "t", "0.05"),
     r"imu\.csv, row 21 \(line 22\), column 't': timestamp 0\.05 is earlier than the previous "
     r"row \(0\.095\)"),
    ("quaternion not unit", lambda f: edit_cell(f, "mocap.csv", 7, "qw", "0.6"),
     r"mocap\.csv, row 7 \(line 8\), column 'qw': quaternion norm is 1\.05357; expected a "
     r"unit quaternion"),
    ("accelerometer in g", lambda f: scale(f, "imu.csv", ("ax", "ay", "az"), 1 / 9.81),
     r"imu\.csv, column 'ax': median accelerometer magnitude is 1, which looks like g; "
     r"expected m/s\^2"),
    ("gyroscope in deg/s", lambda f: scale(f, "imu.csv", ("gx", "gy", "gz"), 3000.0),
     r"imu\.csv, column 'gx': 99th-percentile angular rate is .*, which looks like deg/s"),
    ("positions in mm", lambda f: scale(f, "mocap.csv", ("x", "y", "z"), 1000.0),
     r"mocap\.csv, row 1 \(line 2\), column 'y': position 1100 looks like mm; expected m"),
    ("gravity length", lambda f: set_key(f, "gravity", [0.0, -9.0, 0.0]),
     r"recording\.yaml, key 'gravity': gravity length is 9 m/s\^2; expected about 9\.81"),
    ("partly empty mocap row", lambda f: edit_cell(f, "mocap.csv", 30, "qz", ""),
     r"mocap\.csv, row 30 \(line 31\), column 'qz': row is partly empty"),
    ("empty mocap", lambda f: (f / "mocap.csv").write_text("t,x,y,z,qw,qx,qy,qz\n"),
     r"mocap\.csv: no frames"),
    ("missing yaml", lambda f: (f / "recording.yaml").unlink(),
     r"recording\.yaml: file not found in "),
    ("broken csv", lambda f: edit_cell(f, "imu.csv", 5, "gz", "0,0"),
     r"imu\.csv: cannot be parsed as CSV \(.*line 6"),
]


@pytest.mark.parametrize(("name", "mutate", "pattern"), BAD, ids=[case[0] for case in BAD])
def test_bad_folder_exits_2_with_one_line(folder, capsys, name, mutate, pattern):
    mutate(folder)
    status, out, err = run_check(capsys, str(folder))
    assert status == 2
    assert out == ""
    assert err.count("\n") == 1 and err.endswith("\n")
    assert "Traceback" not in err
    assert err.startswith("kfusion check: error: ")
    assert re.search(pattern, err), err


def test_not_a_folder_is_one_line(tmp_path, capsys):
    (tmp_path / "file.txt").write_text("hello")
    status, _, err = run_check(capsys, str(tmp_path / "file.txt"))
    assert status == 2 and err.count("\n") == 1
    assert "file.txt: not a recording folder" in err
