"""The optional marker parts of a recording folder (markers.csv, recording.yaml's markers) and the
marker columns of a Motive export (read_motive_markers, convert motive --markers)."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation
from test_recording import assert_same_bits, assert_same_recording, make_recording

from kfusion.cli import main
from kfusion.readers.motive import read_motive_csv, read_motive_markers
from kfusion.recording import (
    MarkerFrames,
    Recording,
    RecordingError,
    read_markers,
    read_recording,
    write_recording,
)
from kfusion.rigid_body import markers_in_body_frame

FIXTURES = Path(__file__).parent / "fixtures"
TAKE = FIXTURES / "motive_take.csv"
AWKWARD = (0.1 + 0.2, 1e-17, -0.0, 5e-324, 1.0 / 3.0)


def with_markers(recording: Recording, rng: np.random.Generator) -> Recording:
    """``recording`` plus 3 markers on its mocap clock (some occluded) and their body positions."""
    names = ("LEFT", "R_ELB", "Forearm:M3")
    position = rng.uniform(-2, 2, (len(recording.mocap), 3, 3))
    position[0, 0] = AWKWARD[:3]
    position[5, 1] = np.nan
    position[10:15] = np.nan
    markers = MarkerFrames(t=recording.mocap.t, names=names, position=position)
    body = {"LEFT": [0.05, 0.0, 1e-17], "R_ELB": [0.1 + 0.2, -0.01, 0.0],
            "Forearm:M3": [0.0, 0.0, -0.04]}
    info = dataclasses.replace(recording.info, name="markers", markers=body)
    return Recording(imu=recording.imu, mocap=recording.mocap, info=info, markers=markers)


@pytest.fixture
def folder(tmp_path) -> Path:
    recording = with_markers(make_recording(np.random.default_rng(3)), np.random.default_rng(4))
    return write_recording(recording, tmp_path / "rec")


# ------------------------------------------------------------------------------------------
# Round trip and absence
# ------------------------------------------------------------------------------------------


def test_markers_round_trip_bit_exact(tmp_path):
    recording = with_markers(make_recording(np.random.default_rng(1)), np.random.default_rng(2))
    read = read_recording(write_recording(recording, tmp_path / "rec"))
    assert_same_recording(recording, read)
    assert read.markers is not None and read.markers.names == recording.markers.names
    assert_same_bits(recording.markers.t, read.markers.t)
    assert_same_bits(recording.markers.position, read.markers.position)
    assert list(read.info.markers) == ["LEFT", "R_ELB", "Forearm:M3"]
    for name, position in recording.info.markers.items():
        assert_same_bits(position, read.info.markers[name])
    header = (tmp_path / "rec" / "markers.csv").read_text().splitlines()[0]
    assert header == ("t,LEFT_x,LEFT_y,LEFT_z,R_ELB_x,R_ELB_y,R_ELB_z,Forearm:M3_x,Forearm:M3_y,"
                      "Forearm:M3_z")
    # Occluded markers are empty cells: row 6 (index 5) hides R_ELB only.
    assert (tmp_path / "rec" / "markers.csv").read_text().splitlines()[6].split(",")[4:7] == \
        ["", "", ""]


def test_without_markers_nothing_changes_and_a_stale_file_is_removed(tmp_path):
    recording = make_recording(np.random.default_rng(5))
    folder = write_recording(recording, tmp_path / "rec")
    read = read_recording(folder)
    assert read.markers is None and read.info.markers is None
    assert "markers" not in yaml.safe_load((folder / "recording.yaml").read_text())
    assert not (folder / "markers.csv").exists()
    write_recording(with_markers(recording, np.random.default_rng(6)), folder)
    assert (folder / "markers.csv").exists()
    write_recording(recording, folder)
    assert not (folder / "markers.csv").exists() and read_recording(folder).markers is None


def test_markers_csv_without_yaml_markers_is_valid(folder):
    data = yaml.safe_load((folder / "recording.yaml").read_text())
    del data["markers"]
    (folder / "recording.yaml").write_text(yaml.safe_dump(data))
    read = read_recording(folder)
    assert read.markers is not None and read.info.markers is None


def test_marker_frames_are_read_only_and_checked():
    markers = MarkerFrames(t=[0.0, 1.0], names=("a", "b"), position=np.zeros((2, 2, 3)))
    with pytest.raises(ValueError, match="read-only"):
        markers.position[0, 0, 0] = 1.0
    np.testing.assert_array_equal(markers.visible, [[True, True], [True, True]])
    with pytest.raises(ValueError, match=r"expected t \(k,\) and position \(k, 2, 3\)"):
        MarkerFrames(t=[0.0], names=("a", "b"), position=np.zeros((1, 3, 3)))
    with pytest.raises(ValueError, match="one or more unique names"):
        MarkerFrames(t=[0.0], names=("a", "a"), position=np.zeros((1, 2, 3)))
    with pytest.raises(KeyError, match="no marker 'c'"):
        markers.marker("c")


def test_summary_mentions_markers(folder):
    from kfusion.commands.check import summarise

    summary = summarise(read_recording(folder))
    # 120 frames: rows 10-14 hide all 3 markers, row 5 hides one.
    assert ("markers: 3 (LEFT, R_ELB, Forearm:M3) in 120 frames; all seen in 95.0 %, 3 or more "
            "in 95.0 %, none in 4.2 %") in summary
    assert "body-frame marker positions: 3 in recording.yaml (LEFT, R_ELB, Forearm:M3)" in summary


# ------------------------------------------------------------------------------------------
# Refusals
# ------------------------------------------------------------------------------------------


def edit_markers_csv(folder: Path, edit) -> None:
    path = folder / "markers.csv"
    lines = path.read_text().splitlines()
    edit(lines)
    path.write_text("\n".join(lines) + "\n")


def set_cell(lines: list[str], row: int, column: int, value: str) -> None:
    cells = lines[row].split(",")
    cells[column] = value
    lines[row] = ",".join(cells)


def set_markers(folder: Path, value: object) -> None:
    data = yaml.safe_load((folder / "recording.yaml").read_text())
    data["markers"] = value
    (folder / "recording.yaml").write_text(yaml.safe_dump(data))


CSV_CASES = [
    ("first column", lambda lines: lines.__setitem__(0, lines[0].replace("t,", "time,", 1)),
     r"markers\.csv, column 'time': first column is \['time'\]; expected t, then NAME_x"),
    ("not triplets", lambda lines: lines.__setitem__(0, lines[0].rsplit(",", 1)[0]),
     r"markers\.csv: 8 marker columns, not a positive multiple of 3"),
    ("axis order", lambda lines: lines.__setitem__(0, lines[0].replace("LEFT_y,LEFT_z",
                                                                       "LEFT_z,LEFT_y")),
     r"markers\.csv, column 'LEFT_z': columns \['LEFT_x', 'LEFT_z', 'LEFT_y'\]"),
    ("duplicate", lambda lines: lines.__setitem__(0, lines[0].replace("R_ELB", "LEFT")),
     r"markers\.csv, column 'LEFT_x': marker 'LEFT' appears twice"),
    ("partial", lambda lines: set_cell(lines, 3, 2, ""),
     r"markers\.csv, row 3 \(line 4\), column 'LEFT_y': marker 'LEFT' is partly empty"),
    ("text", lambda lines: set_cell(lines, 2, 5, "abc"),
     r"markers\.csv, row 2 \(line 3\), column 'R_ELB_y': non-numeric value 'abc'"),
    ("infinite", lambda lines: set_cell(lines, 2, 7, "inf"),
     r"markers\.csv, row 2 \(line 3\), column 'Forearm:M3_x': infinite value"),
    ("mm", lambda lines: set_cell(lines, 4, 3, "1500.0"),
     r"markers\.csv, row 4 \(line 5\), column 'LEFT_z': position 1500 looks like mm"),
    ("implausible", lambda lines: set_cell(lines, 4, 3, "1e300"),
     r"markers\.csv, row 4 \(line 5\), column 'LEFT_z': position 1e\+300 is implausible "
     r"\(not even mm\); expected m \(\|coordinate\| <= 10 m\)$"),
    ("time order", lambda lines: lines.__setitem__(3, lines[2]),
     r"markers\.csv, row 3 \(line 4\), column 't': timestamp .* is duplicated"),
]


YAML_CASES = [
    ("not a mapping", [1, 2], r"recording\.yaml, key 'markers': expected a non-empty mapping"),
    ("empty", {}, r"key 'markers': expected a non-empty mapping"),
    ("short vector", {"LEFT": [1, 2]},
     r"key 'markers\.LEFT': expected a list of 3 finite numbers, got \[1, 2\]"),
    ("mm", {"LEFT": [50.0, 0, 0]}, r"key 'markers\.LEFT': marker is 50 from the rigid-body "
     r"origin, which looks like mm"),
    ("name", {"a,b": [0, 0, 0]}, r"key 'markers\.'a,b'': marker name 'a,b' is not usable"),
    ("number name", {7: [0, 0, 0]}, r"key 'markers\.7': expected a marker name \(a string\)"),
    ("csv marker unknown", {"LEFT": [0, 0, 0], "R_ELB": [0, 0, 0]},
     r"markers\.csv, column 'Forearm:M3_x': marker 'Forearm:M3' has no body-frame position in "
     r"recording\.yaml's markers; expected one of \['LEFT', 'R_ELB'\]"),
]

CASES = [(f"markers.csv {name}", lambda folder, edit=edit: edit_markers_csv(folder, edit), pattern)
         for name, edit, pattern in CSV_CASES] + [
        (f"recording.yaml {name}", lambda folder, value=value: set_markers(folder, value), pattern)
        for name, value, pattern in YAML_CASES]


@pytest.mark.parametrize(("name", "mutate", "pattern"), CASES, ids=[c[0] for c in CASES])
def test_marker_refusals_name_file_row_column_or_key(folder, name, mutate, pattern):
    mutate(folder)
    with pytest.raises(RecordingError, match=pattern):
        read_recording(folder)


def test_read_markers_alone_and_zeros(tmp_path):
    path = tmp_path / "markers.csv"
    path.write_text("t,a_x,a_y,a_z\n0.0,0,0,0\n0.01,1,2,3\n0.02,,,\n")
    plain = read_markers(path)
    np.testing.assert_array_equal(plain.visible[:, 0], [True, True, False])
    zeros = read_markers(path, zero_position_means_occluded=True)
    np.testing.assert_array_equal(zeros.visible[:, 0], [False, True, False])
    with pytest.raises(RecordingError, match=r"^absent\.csv: file not found"):
        read_markers(tmp_path / "absent.csv")


# ------------------------------------------------------------------------------------------
# Motive marker columns
# ------------------------------------------------------------------------------------------


def test_motive_marker_columns_by_hand():
    markers = read_motive_markers(TAKE, ["Marker1"])
    assert markers.names == ("Marker1",) and len(markers) == 20
    # Line 9 (frame 0): the 'Marker' columns are 130.1, 1210.55, -355.27 mm (the 'Rigid Body
    # Marker' columns, 130, 1210.5, -355.25, are not read).
    assert_same_bits([float("0.1301"), float("1.21055"), float("-0.35527")],
                     markers.position[0, 0])
    np.testing.assert_array_equal(np.flatnonzero(~markers.visible[:, 0]), [8, 9, 10])
    same = read_motive_markers(TAKE, ["Forearm:Marker1"])
    assert_same_bits(markers.position, same.position)


def test_motive_marker_name_missing_lists_the_markers():
    with pytest.raises(RecordingError, match=re.escape(
            "motive_take.csv: no marker named 'Nope'; expected names from the 'Marker' columns: "
            "['Forearm:Marker1']")):
        read_motive_markers(TAKE, ["Nope"])


def test_markers_in_body_frame_against_scipy():
    mocap = read_motive_csv(TAKE, rigid_body="Forearm")
    markers = read_motive_markers(TAKE, ["Marker1"])
    body = markers_in_body_frame(mocap, markers)
    both = mocap.visible & markers.visible[:, 0]
    rotation = Rotation.from_quat(mocap.quaternion[both], scalar_first=True)
    expected = rotation.inv().apply(markers.position[both, 0] - mocap.position[both])
    np.testing.assert_allclose(body.positions[0], expected.mean(axis=0), atol=1e-12)
    assert body.frames == int(both.sum()) == 17


def test_convert_motive_with_markers_writes_markers_csv(tmp_path, capsys):
    imu = tmp_path / "imu_in.csv"
    imu.write_text("t,ax,ay,az,gx,gy,gz\n" + "".join(
        f"{i / 200!r},0.01,9.81,-0.02,0.001,0.1,0.0\n" for i in range(40)))
    out = tmp_path / "rec"
    status = main(["convert", "motive", str(TAKE), "--imu", str(imu), "--rigid-body", "Forearm",
                   "--markers", "Marker1", "--imu-to-body", "1", "0", "0", "0", "--out",
                   str(out)])
    stdout = capsys.readouterr().out
    assert status == 0
    assert "markers: 1 (Marker1); body-frame positions from 17 frames" in stdout
    recording = read_recording(out)
    assert recording.markers is not None and recording.markers.names == ("Marker1",)
    assert_same_bits(read_motive_markers(TAKE, ["Marker1"]).position, recording.markers.position)
    expected = markers_in_body_frame(read_motive_csv(TAKE, rigid_body="Forearm"),
                                     recording.markers).positions[0]
    np.testing.assert_allclose(recording.info.markers["Marker1"], expected, atol=1e-15)


def test_self_calibration_keeps_the_body_frame_markers():
    from kfusion.calibration import calibrate_recording
    from kfusion.recording import info_to_dict
    from kfusion.simulate import simulate

    recording = simulate("random_reach", seed=0, duration=20.0).recording
    body = {"A": [0.01, 0.0, 0.0], "B": [0.0, 0.02, 0.0]}
    recording = dataclasses.replace(recording, info=dataclasses.replace(recording.info,
                                                                        markers=body))
    calibration = calibrate_recording(recording)
    assert info_to_dict(calibration.info)["markers"] == body


def test_a_marker_layout_in_mm_is_refused_wherever_it_is_given():
    """recording.yaml refused it already; given to RecordingInfo or the Tracker directly a 5 cm
    cluster in mm (50 m) fitted no frame, and the Tracker stayed lost without a word."""
    from kfusion.recording import RecordingInfo
    from kfusion.tracker import Tracker

    layout = {"A": [50.0, 0.0, 0.0], "B": [0.0, 40.0, 0.0], "C": [0.0, 0.0, 30.0]}
    with pytest.raises(ValueError, match=r"^RecordingInfo\.markers\['A'\]: marker is 50 from "
                       r"the rigid-body origin, which looks like mm; expected m"):
        RecordingInfo(imu_to_body=(1.0, 0.0, 0.0, 0.0), gravity=(0.0, 0.0, -9.81),
                      markers=layout)
    with pytest.raises(ValueError, match=r"^Tracker: markers\['A'\]: marker is 50 from the "
                       r"rigid-body origin, which looks like mm"):
        Tracker((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, -9.81), markers=layout)
    metres = {name: [value / 1000 for value in position] for name, position in layout.items()}
    Tracker((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, -9.81), markers=metres)  # the same in m is fine
