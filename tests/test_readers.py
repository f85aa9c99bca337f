"""Readers of real formats (Motive CSV, BROAD .mat) and ``kfusion convert``."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.io
import yaml

from kfusion.cli import main
from kfusion.datasets import broad_excerpt, broad_trial, broad_trials
from kfusion.readers import motive_rigid_bodies, read_broad, read_motive_csv
from kfusion.recording import (
    RecordingError,
    occlusion_runs,
    read_imu,
    read_mocap,
    read_recording,
    write_recording,
)

FIXTURES = Path(__file__).parent / "fixtures"
TAKE = FIXTURES / "motive_take.csv"
FIRST_DATA_LINE = 9
"""Line of data row 1 in the fixture: header, blank, Type, Name, ID, Parent, categories, axes."""


def assert_same_bits(expected: np.ndarray, actual: np.ndarray) -> None:
    expected, actual = np.asarray(expected, dtype=float), np.asarray(actual, dtype=float)
    assert expected.shape == actual.shape
    np.testing.assert_array_equal(np.isnan(expected), np.isnan(actual))
    finite = ~np.isnan(expected)
    np.testing.assert_array_equal(expected[finite].view(np.int64), actual[finite].view(np.int64))


# ------------------------------------------------------------------------------------------
# Motive CSV
# ------------------------------------------------------------------------------------------


def test_motive_fixture_lists_rigid_bodies_not_markers():
    assert motive_rigid_bodies(TAKE) == ["Forearm", "Table"]


def test_motive_forearm_values_by_hand():
    frames = read_motive_csv(TAKE, rigid_body="Forearm")
    assert len(frames) == 20
    # Time (Seconds) as written by Motive (6 decimals).
    assert frames.t[0] == 0.0 and frames.t[1] == 0.008333 and frames.t[19] == 0.158333
    # Row 1: Position 100.000000, 1200.500000, -350.250000 mm -> m.
    assert_same_bits([0.1, 1.2005, -0.35025], frames.position[0])
    # Row 1: Rotation X, Y, Z, W = 0.1, 0.2, 0.3, 0.927362 -> [w, x, y, z].
    assert_same_bits([0.927362, 0.1, 0.2, 0.3], frames.quaternion[0])
    # Row 6: X 112.5 mm, Y 1194.25 mm, Z -347.75 mm; rotation Y 0.25, W 0.91515.
    assert_same_bits([0.1125, 1.19425, -0.34775], frames.position[5])
    assert_same_bits([0.91515, 0.1, 0.25, 0.3], frames.quaternion[5])
    # Frames 8-10 have blank cells: occluded, NaN (never zeros).
    np.testing.assert_array_equal(np.flatnonzero(~frames.visible), [8, 9, 10])
    assert np.isnan(frames.position[8:11]).all() and np.isnan(frames.quaternion[8:11]).all()


def test_motive_second_rigid_body():
    table = read_motive_csv(TAKE, rigid_body="Table")
    np.testing.assert_array_equal(np.flatnonzero(~table.visible), [3])
    assert_same_bits([0.5, 0.75, -0.02], table.position[0])
    assert_same_bits([1.0, 0.0, 0.0, 0.0], table.quaternion[0])


def test_motive_needs_a_name_when_there_are_several():
    with pytest.raises(RecordingError, match=re.escape(
            "motive_take.csv: several rigid bodies ['Forearm', 'Table']; choose one")):
        read_motive_csv(TAKE)
    with pytest.raises(RecordingError, match=re.escape(
            "motive_take.csv: no rigid body named 'Forearm:Marker1'; expected one of "
            "['Forearm', 'Table']")):
        read_motive_csv(TAKE, rigid_body="Forearm:Marker1")


SINGLE_BODY_CM = """\
Format Version,1.23,Take Name,hand,Take Notes,,Capture Frame Rate,100.000000,\
Export Frame Rate,100.000000,Capture Start Time,2021-06-02 11.09.45.344 AM,\
Total Frames in Take,5,Total Exported Frames,5,Rotation Type,Quaternion,\
Length Units,Centimeters,Coordinate Space,Global

,Type,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body,Rigid Body
,Name,Hand,Hand,Hand,Hand,Hand,Hand,Hand,Hand
,ID,7,7,7,7,7,7,7,7
,,Rotation,Rotation,Rotation,Rotation,Position,Position,Position,Mean Marker Error
Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,
0,0.000000,0.000000,0.000000,0.000000,1.000000,10.500000,120.250000,-3.000000,0.000100
1,0.010000,0.000000,0.000000,0.600000,0.800000,11.000000,120.000000,-3.500000,0.000100
2,0.020000,,,,,,,,
3,0.030000,0.000000,0.707107,0.000000,0.707107,0.000000,0.000000,0.000000,0.000100
4,0.040000,0.000000,0.000000,0.000000,1.000000,12.000000,119.500000,-4.000000,0.000100
"""
"""Motive 2.x layout (format 1.23: no Parent row), one rigid body, centimetres."""


def write_take(tmp_path: Path, text: str, name: str = "take.csv") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_motive_single_body_is_the_default_and_centimetres_convert(tmp_path):
    frames = read_motive_csv(write_take(tmp_path, SINGLE_BODY_CM))
    assert_same_bits([0.0, 0.01, 0.02, 0.03, 0.04], frames.t)
    # 10.5 cm, 120.25 cm, -3 cm -> m
    assert_same_bits([0.105, 1.2025, -0.03], frames.position[0])
    # Rotation X, Y, Z, W = 0, 0, 0.6, 0.8 -> [w, x, y, z] = [0.8, 0, 0, 0.6]
    assert_same_bits([0.8, 0.0, 0.0, 0.6], frames.quaternion[1])
    np.testing.assert_array_equal(frames.visible, [True, True, False, True, True])
    # (0, 0, 0) is a position unless the zeros convention is asked for.
    assert_same_bits([0.0, 0.0, 0.0], frames.position[3])
    zeros = read_motive_csv(write_take(tmp_path, SINGLE_BODY_CM), rigid_body="Hand",
                            zero_position_means_occluded=True)
    np.testing.assert_array_equal(zeros.visible, [True, True, False, False, True])
    assert np.isnan(zeros.quaternion[3]).all()


def test_motive_meters_are_kept(tmp_path):
    text = SINGLE_BODY_CM.replace("Length Units,Centimeters", "Length Units,Meters")
    text = text.replace("10.500000,120.250000,-3.000000", "0.105000,1.202500,-0.030000")
    text = text.replace("11.000000,120.000000,-3.500000", "0.110000,1.200000,-0.035000")
    text = text.replace("12.000000,119.500000,-4.000000", "0.120000,1.195000,-0.040000")
    frames = read_motive_csv(write_take(tmp_path, text))
    assert_same_bits([0.105, 1.2025, -0.03], frames.position[0])


def fixture_with(old: str, new: str, count: int = 1) -> str:
    text = TAKE.read_text()
    assert old in text, old
    return text.replace(old, new, count)


def edit_fixture_row(row: int, column: int, value: str) -> str:
    """The fixture with 0-based ``column`` of 1-based data ``row`` replaced."""
    lines = TAKE.read_text().splitlines()
    index = FIRST_DATA_LINE - 1 + row - 1
    cells = lines[index].split(",")
    cells[column] = value
    lines[index] = ",".join(cells)
    return "\r\n".join(lines) + "\r\n"


# Forearm columns in the fixture (0-based): rotation X 2, Y 3, Z 4, W 5; position X 6, Y 7, Z 8.
MOTIVE_ERRORS = [
    ("euler", fixture_with("Rotation Type,Quaternion", "Rotation Type,XYZ"), {},
     r"^take\.csv, key 'Rotation Type': rotation type 'XYZ' \(Euler angles\); expected "
     r"Quaternion: export again with Rotation Type = Quaternion$"),
    ("no units", fixture_with("Length Units,Millimeters,", ""), {},
     r"^take\.csv, key 'Length Units': no 'Length Units' in the header line; expected one of "
     r"Meters, Centimeters, Millimeters$"),
    ("inches", fixture_with("Length Units,Millimeters", "Length Units,Inches"), {},
     r"^take\.csv, key 'Length Units': length units 'Inches'; expected one of Meters, "
     r"Centimeters, Millimeters$"),
    ("local", fixture_with("Coordinate Space,Global", "Coordinate Space,Local"), {},
     r"^take\.csv, key 'Coordinate Space': coordinate space 'Local'; expected Global"),
    ("not motive", "t,x,y,z\n0,1,2,3\n", {},
     r"^take\.csv: not a Motive CSV export: expected the first line to start with 'Format "
     r"Version', got 't,x,y,z'$"),
    ("no axes row", fixture_with("Frame,Time (Seconds)", "Frames,Time (Seconds)"), {},
     r"^take\.csv: no column header line 'Frame,Time \(Seconds\),X,Y,Z,\.\.\.' in the first "
     r"\d+ lines; expected a Motive CSV export with its header enabled$"),
    ("no rigid body", fixture_with("Rigid Body,", "Bone,", -1), {},
     r"^take\.csv, key 'Type': no rigid body columns; expected a Motive export with 'Rigid "
     r"Bodies' enabled$"),
    ("no W column", fixture_with("Frame,Time (Seconds),X,Y,Z,W", "Frame,Time (Seconds),X,Y,Z,V"),
     {"rigid_body": "Forearm"},
     r"^take\.csv: rigid body 'Forearm' has no column\(s\) \['Rotation W'\]; expected Rotation "
     r"X, Y, Z, W and Position X, Y, Z \(Rotation Type Quaternion\)$"),
    ("duplicate name", fixture_with(",Table,Table,Table,Table,Table,Table,Table,Table,",
                                    ",Forearm,Forearm,Forearm,Forearm,Forearm,Forearm,Forearm,"
                                    "Forearm,"), {"rigid_body": "Forearm"},
     r"^take\.csv, column 'Forearm Rotation X': rigid body name 'Forearm' is ambiguous: it names "
     r"2 rigid bodies \(IDs \['1', '2'\]\); rename one in Motive$"),
    ("non-numeric", edit_fixture_row(4, 7, "1196.75mm"), {"rigid_body": "Forearm"},
     r"^take\.csv, row 4 \(line 12\), column 'Forearm Position Y': non-numeric value "
     r"'1196\.75mm'; expected a number$"),
    ("partly blank", edit_fixture_row(6, 4, ""), {"rigid_body": "Forearm"},
     r"^take\.csv, row 6 \(line 14\), column 'Forearm Rotation Z': rigid body cells partly "
     r"blank; expected all 7 filled, or all blank for an occluded frame$"),
    ("partly blank occluded", edit_fixture_row(10, 6, "5.0"), {"rigid_body": "Forearm"},
     r"^take\.csv, row 10 \(line 18\), column 'Forearm Position Y': rigid body cells partly "
     r"blank"),
    ("infinite", edit_fixture_row(2, 8, "inf"), {"rigid_body": "Forearm"},
     r"^take\.csv, row 2 \(line 10\), column 'Forearm Position Z': infinite value; expected a "
     r"number or a blank cell \(occluded\)$"),
    ("not unit", edit_fixture_row(3, 5, "0.5"), {"rigid_body": "Forearm"},
     r"^take\.csv, row 3 \(line 11\), column 'Forearm Rotation W': quaternion norm is 0\.631189; "
     r"expected a unit quaternion \[w, x, y, z\]"),
    ("time back", edit_fixture_row(5, 1, "0.008333"), {"rigid_body": "Table"},
     r"^take\.csv, row 5 \(line 13\), column 'Time \(Seconds\)': timestamp 0\.008333 is earlier "
     r"than the previous row \(0\.025\); expected strictly increasing times$"),
    ("empty time", edit_fixture_row(7, 1, ""), {"rigid_body": "Table"},
     r"^take\.csv, row 7 \(line 15\), column 'Time \(Seconds\)': empty timestamp"),
    ("mm labelled meters", fixture_with("Length Units,Millimeters", "Length Units,Meters"),
     {"rigid_body": "Forearm"},
     r"^take\.csv, row 1 \(line 9\), column 'Forearm Position Y': position 1200\.5 looks like mm; "
     r"expected m \(\|coordinate\| <= 10 m\): divide by 1000 \(the header says Length Units "
     r"Meters\)$"),
    ("no frames", "\r\n".join(TAKE.read_text().splitlines()[:8]) + "\r\n", {"rigid_body": "Table"},
     r"^take\.csv: no frames after the header; expected at least one frame$"),
    ("extra field", edit_fixture_row(2, 24, "1.0,2.0"), {"rigid_body": "Table"},
     r"^take\.csv, row 2 \(line 10\): 26 fields; expected 25 as in the header line"),
    ("truncated last line", TAKE.read_text()[:-120], {"rigid_body": "Forearm"},
     r"^take\.csv, row 20 \(line 28\): \d+ fields; expected 25 as in the header line"),
]


@pytest.mark.parametrize(("name", "text", "options", "pattern"), MOTIVE_ERRORS,
                         ids=[case[0] for case in MOTIVE_ERRORS])
def test_motive_refusals_name_file_line_and_column(tmp_path, name, text, options, pattern):
    path = write_take(tmp_path, text)
    with pytest.raises(RecordingError, match=pattern) as error:
        read_motive_csv(path, **options)
    assert "\n" not in str(error.value)


def test_motive_missing_file(tmp_path):
    with pytest.raises(RecordingError, match=r"^absent\.csv: file not found in "):
        read_motive_csv(tmp_path / "absent.csv")


# ------------------------------------------------------------------------------------------
# BROAD: a synthetic trial (every branch) and the smallest real trial
# ------------------------------------------------------------------------------------------

SYNTHETIC_RATE = 200.0


def synthetic_trial(count: int = 600, seed: int = 0) -> dict[str, np.ndarray]:
    """A BROAD-shaped trial: held position with NaN quaternion at the start, a NaN dropout."""
    rng = np.random.default_rng(seed)
    angle = np.linspace(0.0, 1.0, count)
    quaternion = np.column_stack([np.cos(angle / 2), np.zeros(count), np.zeros(count),
                                  np.sin(angle / 2)])
    position = np.column_stack([np.sin(angle), np.cos(angle), 0.5 + 0.1 * angle])
    quaternion[:20] = np.nan  # start of a trial: position held, quaternion NaN
    position[:20] = position[20]
    quaternion[300:311] = np.nan
    position[300:311] = np.nan
    return {
        "imu_acc": np.array([0.0, 0.0, 9.81]) + rng.normal(scale=0.1, size=(count, 3)),
        "imu_gyr": rng.normal(scale=0.05, size=(count, 3)),
        "imu_mag": rng.normal(size=(count, 3)),
        "opt_pos": position,
        "opt_quat": quaternion,
        "movement": np.ones((count, 1), dtype=np.uint8),
        "sampling_rate": np.array([[SYNTHETIC_RATE]]),
    }


def save_trial(tmp_path: Path, data: dict, name: str = "07_synthetic_trial.mat") -> Path:
    path = tmp_path / name
    scipy.io.savemat(path, data)
    return path


def test_broad_masks_held_positions_and_subsamples(tmp_path):
    data = synthetic_trial()
    path = save_trial(tmp_path, data)
    recording = read_broad(path)
    assert_same_bits(np.arange(600) / SYNTHETIC_RATE, recording.imu.t)
    assert_same_bits(data["imu_acc"], recording.imu.accelerometer)
    assert_same_bits(data["imu_gyr"], recording.imu.gyroscope)
    hidden = np.zeros(600, bool)
    hidden[:20] = hidden[300:311] = True
    np.testing.assert_array_equal(~recording.mocap.visible, hidden)
    assert np.isnan(recording.mocap.position[:20]).all()  # the held value is not trusted
    assert_same_bits(data["opt_pos"][20:300], recording.mocap.position[20:300])
    assert_same_bits(data["opt_quat"][20:300], recording.mocap.quaternion[20:300])
    info = recording.info
    assert_same_bits([1.0, 0.0, 0.0, 0.0], info.imu_to_body)
    assert_same_bits([0.0, 0.0, -9.81], info.gravity)
    assert (info.name, info.imu, info.lever_arm) == ("07_synthetic_trial", "broad", None)

    third = read_broad(path, mocap_step=3)
    assert len(third.imu) == 600 and len(third.mocap) == 200
    assert_same_bits(recording.mocap.t[::3], third.mocap.t)
    assert_same_bits(recording.mocap.position[::3], third.mocap.position)
    assert_same_bits(recording.mocap.quaternion[::3], third.mocap.quaternion)
    assert len(read_broad(path, mocap_step=7).mocap) == math.ceil(600 / 7)


def with_changes(**changes: object) -> dict:
    data = synthetic_trial()
    for key, value in changes.items():
        if value is None:
            del data[key]
        else:
            data[key] = value
    return data


def altered(key: str, row: int, column: int, value: float) -> dict:
    data = synthetic_trial()
    data[key] = np.array(data[key], dtype=float)
    data[key][row, column] = value
    return data


def scaled(key: str, factor: float) -> dict:
    data = synthetic_trial()
    data[key] = data[key] * factor
    return data


BROAD_ERRORS = [
    ("missing key", with_changes(opt_quat=None), {},
     r"^trial\.mat, key 'opt_quat': missing; expected a BROAD trial with keys \['imu_acc', "
     r"'imu_gyr', 'opt_pos', 'opt_quat', 'sampling_rate'\]$"),
    ("missing rate", with_changes(sampling_rate=None), {},
     r"^trial\.mat, key 'sampling_rate': missing; expected a BROAD trial"),
    ("bad rate", with_changes(sampling_rate=np.array([[0.0]])), {},
     r"^trial\.mat, key 'sampling_rate': expected one positive rate in Hz, got \[\[0\.0\]\]$"),
    ("short gyro", with_changes(imu_gyr=np.zeros((599, 3))), {},
     r"^trial\.mat, key 'imu_gyr': shape \(599, 3\); expected \(600, 3\)$"),
    ("wide acc", with_changes(imu_acc=np.zeros((600, 4))), {},
     r"^trial\.mat, key 'imu_acc': shape \(600, 4\); expected \(N, 3\)$"),
    ("text", with_changes(opt_pos=np.array(["abc"])), {},
     r"^trial\.mat, key 'opt_pos': expected numbers, got <U3$"),
    ("empty", with_changes(imu_acc=np.zeros((0, 3))), {},
     r"^trial\.mat, key 'imu_acc': (no samples|shape)"),
    ("nan imu", altered("imu_acc", 5, 1, float("nan")), {},
     r"^trial\.mat, key 'imu_acc\[5, 1\]': non-finite IMU value nan at sample 5 \(0-based\), "
     r"column 1$"),
    ("inf position", altered("opt_pos", 40, 2, float("inf")), {},
     r"^trial\.mat, key 'opt_pos\[40, 2\]': infinite value inf at sample 40"),
    ("acc in g", scaled("imu_acc", 1 / 9.81), {},
     r"^trial\.mat, key 'imu_acc': median accelerometer magnitude is 1, which looks like g; "
     r"expected m/s\^2"),
    ("gyro in deg/s", scaled("imu_gyr", 180 / np.pi * 10), {},
     r"^trial\.mat, key 'imu_gyr': 99th-percentile angular rate is .*, which looks like deg/s"),
    ("not unit", altered("opt_quat", 99, 0, 3.0), {"mocap_step": 3},
     r"^trial\.mat, key 'opt_quat\[99, 0\]': quaternion norm is 3\.\d+; expected a unit "
     r"quaternion"),
    ("position mm", scaled("opt_pos", 1000.0), {},
     r"^trial\.mat, key 'opt_pos\[20, 1\]': position 999\.443 looks like mm; expected m"),
    # a corrupt sample, as imu.csv refuses it (it was fused, as merely saturated)
    ("gyro beyond any sensor", altered("imu_gyr", 7, 2, 1e308), {},
     r"^trial\.mat, key 'imu_gyr\[7, 2\]': gyroscope value 1e\+308 is beyond any body-worn "
     r"sensor's range; expected \|value\| <= 1000 rad/s$"),
    ("acc beyond any sensor", altered("imu_acc", 3, 1, -2e4), {},
     r"^trial\.mat, key 'imu_acc\[3, 1\]': accelerometer value -20000 is beyond"),
]


@pytest.mark.parametrize(("name", "data", "options", "pattern"), BROAD_ERRORS,
                         ids=[case[0] for case in BROAD_ERRORS])
def test_broad_refusals_name_file_and_key(tmp_path, name, data, options, pattern):
    path = save_trial(tmp_path, data, "trial.mat")
    with pytest.raises(RecordingError, match=pattern):
        read_broad(path, **options)


@pytest.mark.parametrize("step", [0, -3, 1.5, True, "3"])
def test_broad_mocap_step_must_be_a_positive_integer(tmp_path, step):
    with pytest.raises(ValueError, match=r"^mocap_step: expected an integer >= 1, got "):
        read_broad(tmp_path / "any.mat", mocap_step=step)


def test_broad_file_problems(tmp_path):
    with pytest.raises(RecordingError, match=r"^none\.mat: file not found in "):
        read_broad(tmp_path / "none.mat")
    (tmp_path / "text.mat").write_text("not a MATLAB file at all")
    with pytest.raises(RecordingError, match=r"^text\.mat: cannot be read as a MATLAB file \("):
        read_broad(tmp_path / "text.mat")


@pytest.fixture(scope="module")
def smallest_trial() -> Path:
    try:
        trials = broad_trials()
    except ValueError as error:
        pytest.skip(str(error))
    return min(trials, key=lambda path: path.stat().st_size)


def test_real_broad_trial(smallest_trial, tmp_path):
    raw = scipy.io.loadmat(smallest_trial)
    count = len(raw["imu_acc"])
    quaternion_nan = np.isnan(raw["opt_quat"]).any(axis=1)
    full = read_broad(smallest_trial)
    assert len(full.imu) == len(full.mocap) == count
    assert_same_bits(np.arange(count) / raw["sampling_rate"].item(), full.imu.t)
    assert_same_bits(raw["imu_acc"], full.imu.accelerometer)
    # Positions are masked exactly where the quaternion is NaN; elsewhere the file's values.
    np.testing.assert_array_equal(~full.mocap.visible, quaternion_nan)
    assert np.isnan(full.mocap.position[quaternion_nan]).all()
    assert_same_bits(raw["opt_pos"][~quaternion_nan], full.mocap.position[~quaternion_nan])
    assert_same_bits(raw["opt_quat"][~quaternion_nan], full.mocap.quaternion[~quaternion_nan])

    third = read_broad(smallest_trial, mocap_step=3)
    assert len(third.mocap) == math.ceil(count / 3)
    assert_same_bits(full.mocap.t[::3], third.mocap.t)
    assert_same_bits(full.mocap.position[::3], third.mocap.position)
    np.testing.assert_allclose(1.0 / np.diff(third.mocap.t), 2000.0 / 21.0, rtol=1e-9)  # ~95 Hz

    # Written and read back: passes the folder validation and is bit-identical.
    read = read_recording(write_recording(third, tmp_path / "broad"))
    assert_same_bits(third.imu.t, read.imu.t)
    assert_same_bits(third.imu.gyroscope, read.imu.gyroscope)
    assert_same_bits(third.mocap.position, read.mocap.position)
    assert_same_bits(third.mocap.quaternion, read.mocap.quaternion)
    assert read.info.name == smallest_trial.stem and read.info.imu == "broad"


EXCERPT_WINDOW_S = (56.0, 92.0)
"""Trial 21's clock window kept in the bundled excerpt (kfusion/data/README.md)."""


def test_bundled_broad_excerpt_is_a_valid_recording_with_real_dropouts(capsys):
    excerpt = read_recording(broad_excerpt())
    assert excerpt.info.name == "21_undisturbed_fast_combined" and excerpt.info.imu == "broad"
    assert_same_bits([0.0, 0.0, -9.81], excerpt.info.gravity)
    assert len(excerpt.imu) == 10286 and len(excerpt.mocap) == 3428
    assert EXCERPT_WINDOW_S[0] <= excerpt.imu.t[0] and excerpt.imu.t[-1] < EXCERPT_WINDOW_S[1]
    np.testing.assert_allclose(np.diff(excerpt.mocap.t), 3 * 0.0035, rtol=1e-6)  # every 3rd
    # real occlusions inside the motion: 31 rows from 64.63 s and 8 rows from 87.64 s
    runs = [(excerpt.mocap.t[start], stop - start) for start, stop in
            occlusion_runs(excerpt.mocap.visible)]
    assert [(round(start, 2), rows) for start, rows in runs] == [(64.63, 31), (87.64, 8)]
    # real fast motion: gyroscope beyond 10 rad/s, specific force beyond 2 g
    assert np.linalg.norm(excerpt.imu.gyroscope, axis=1).max() > 10.0
    assert np.linalg.norm(excerpt.imu.accelerometer, axis=1).max() > 2 * 9.81
    assert main(["check", str(broad_excerpt())]) == 0
    capsys.readouterr()


@pytest.mark.broad
def test_bundled_excerpt_is_trial_21_read_every_third_frame():
    trial = read_broad(broad_trial("21"), mocap_step=3)
    excerpt = read_recording(broad_excerpt())
    start, stop = EXCERPT_WINDOW_S
    imu_kept = (trial.imu.t >= start) & (trial.imu.t < stop)
    mocap_kept = (trial.mocap.t >= start) & (trial.mocap.t < stop)
    assert_same_bits(trial.imu.t[imu_kept], excerpt.imu.t)
    assert_same_bits(trial.imu.accelerometer[imu_kept], excerpt.imu.accelerometer)
    assert_same_bits(trial.imu.gyroscope[imu_kept], excerpt.imu.gyroscope)
    assert_same_bits(trial.mocap.t[mocap_kept], excerpt.mocap.t)
    assert_same_bits(trial.mocap.position[mocap_kept], excerpt.mocap.position)
    assert_same_bits(trial.mocap.quaternion[mocap_kept], excerpt.mocap.quaternion)


# ------------------------------------------------------------------------------------------
# kfusion convert
# ------------------------------------------------------------------------------------------


def write_imu(path: Path, count: int = 40, rate: float = 200.0) -> Path:
    rows = ["t,ax,ay,az,gx,gy,gz"]
    rows += [f"{i / rate!r},0.01,9.81,-0.02,0.001,0.1,0.0" for i in range(count)]
    path.write_text("\n".join(rows) + "\n")
    return path


def convert(capsys, *arguments: str) -> tuple[int, str, str]:
    status = main(["convert", *arguments])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def test_convert_motive_leaves_the_unknown_mount_out_and_names_the_next_step(tmp_path, capsys):
    imu = write_imu(tmp_path / "imu_in.csv")
    out = tmp_path / "rec"
    status, stdout, err = convert(capsys, "motive", str(TAKE), "--imu", str(imu), "--rigid-body",
                                  "Forearm", "--out", str(out))
    assert (status, err) == (0, "")
    assert "mocap: 20 frames at 120.0 Hz, 3 occluded" in stdout and "occlusions: 1" in stdout
    assert f"next: kfusion calibrate {out} --out {out / 'recording.yaml'} --force" in stdout
    assert "--imu-to-body" in stdout.splitlines()[-1]
    metadata = yaml.safe_load((out / "recording.yaml").read_text())
    assert metadata == {"gravity": [0.0, -9.81, 0.0], "name": "motive_take"}  # Motive: y-up
    expected = read_motive_csv(TAKE, rigid_body="Forearm")
    written = read_mocap(out / "mocap.csv")
    assert_same_bits(expected.position, written.position)
    assert_same_bits(expected.quaternion, written.quaternion)
    assert len(read_imu(out / "imu.csv")) == 40


def test_convert_motive_with_a_known_mount_is_ready_to_check(tmp_path, capsys):
    imu = write_imu(tmp_path / "imu_in.csv")
    out = tmp_path / "rec"
    status, stdout, _ = convert(capsys, "motive", str(TAKE), "--imu", str(imu), "--rigid-body",
                                "Forearm", "--imu-to-body", "1", "0", "0", "0", "--out", str(out))
    assert status == 0 and f"next: kfusion check {out}, then kfusion track {out}" in stdout
    recording = read_recording(out)
    assert_same_bits([1.0, 0.0, 0.0, 0.0], recording.info.imu_to_body)
    assert recording.info.name == "motive_take" and len(recording.imu) == 40


def test_convert_motive_options(tmp_path, capsys):
    imu = write_imu(tmp_path / "imu_in.csv")
    half = math.sqrt(0.5)
    status, _, err = convert(
        capsys, "motive", str(TAKE), "--imu", str(imu), "--rigid-body", "Table",
        "--imu-to-body", repr(half), "0", repr(-half), "0", "--gravity", "0", "0", "-9.81",
        "--lever-arm", "0.01", "0.02", "-0.03", "--imu-profile", "mpu9255", "--name", "table",
        "--out", str(tmp_path / "rec"))
    assert (status, err) == (0, "")
    info = read_recording(tmp_path / "rec").info
    assert_same_bits([half, 0.0, -half, 0.0], info.imu_to_body)
    assert_same_bits([0.0, 0.0, -9.81], info.gravity)
    assert_same_bits([0.01, 0.02, -0.03], info.lever_arm)
    assert (info.name, info.imu) == ("table", "mpu9255")


def test_convert_motive_zeros_occluded_passthrough(tmp_path, capsys):
    take = write_take(tmp_path, SINGLE_BODY_CM, "hand.csv")
    imu = write_imu(tmp_path / "imu_in.csv")
    status, stdout, _ = convert(capsys, "motive", str(take), "--imu", str(imu), "--out",
                                str(tmp_path / "plain"))
    assert status == 0 and "5 frames at 100.0 Hz, 1 occluded" in stdout
    status, stdout, _ = convert(capsys, "motive", str(take), "--imu", str(imu),
                                "--zeros-occluded", "--out", str(tmp_path / "zeros"))
    assert status == 0 and "5 frames at 100.0 Hz, 2 occluded" in stdout
    # The folder now holds an explicit occlusion (empty cells), not zeros.
    assert (tmp_path / "zeros" / "mocap.csv").read_text().splitlines()[4] == "0.03,,,,,,,"


def test_convert_broad(tmp_path, capsys):
    trial = save_trial(tmp_path, synthetic_trial())
    status, stdout, err = convert(capsys, "broad", str(trial), "--mocap-step", "3", "--out",
                                  str(tmp_path / "rec"))
    assert (status, err) == (0, "")
    assert "imu: 600 samples at 200.0 Hz" in stdout
    assert "mocap: 200 frames at 66.7 Hz" in stdout
    recording = read_recording(tmp_path / "rec")
    assert recording.info.name == "07_synthetic_trial" and len(recording.mocap) == 200


@pytest.mark.parametrize(("arguments", "pattern"), [
    (["motive", str(TAKE), "--imu", "IMU", "--out", "OUT"],
     r"motive_take\.csv: several rigid bodies \['Forearm', 'Table'\]"),
    (["motive", str(TAKE), "--imu", "IMU", "--rigid-body", "Forearm", "--imu-to-body", "1", "1",
      "0", "0", "--out", "OUT"],
     r"command line, key 'imu_to_body': quaternion norm is 1\.41421; expected a unit quaternion"),
    (["motive", str(TAKE), "--imu", "IMU", "--rigid-body", "Forearm", "--gravity", "0", "-1", "0",
      "--out", "OUT"], r"command line, key 'gravity': gravity length is 1 m/s\^2"),
    (["motive", str(TAKE), "--imu", "IMU", "--rigid-body", "Forearm", "--imu-profile", "mpu6050",
      "--out", "OUT"], r"unknown IMU profile 'mpu6050'; expected one of \['broad', "),
    (["motive", str(TAKE), "--imu", "MISSING", "--rigid-body", "Forearm", "--out", "OUT"],
     r"missing\.csv: file not found in "),
    (["broad", "TRIAL", "--mocap-step", "0", "--out", "OUT"],
     r"mocap_step: expected an integer >= 1, got 0"),
])
def test_convert_mistakes_are_one_line(tmp_path, capsys, arguments, pattern):
    write_imu(tmp_path / "imu.csv")
    save_trial(tmp_path, synthetic_trial(), "trial.mat")
    names = {"IMU": str(tmp_path / "imu.csv"), "MISSING": str(tmp_path / "missing.csv"),
             "TRIAL": str(tmp_path / "trial.mat"), "OUT": str(tmp_path / "out")}
    status, stdout, err = convert(capsys, *[names.get(a, a) for a in arguments])
    assert status == 2 and stdout == ""
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("kfusion convert: error: ") and re.search(pattern, err), err
    assert not (tmp_path / "out" / "recording.yaml").exists()


def test_convert_motive_refuses_an_imu_on_another_clock(tmp_path, capsys):
    imu = tmp_path / "late.csv"
    imu.write_text("t,ax,ay,az,gx,gy,gz\n1000.0,0,9.81,0,0,0,0\n1000.005,0,9.81,0,0,0,0\n")
    status, _, err = convert(capsys, "motive", str(TAKE), "--imu", str(imu), "--rigid-body",
                             "Forearm", "--out", str(tmp_path / "rec"))
    assert status == 2 and err.count("\n") == 1
    assert "IMU times 1000.000..1000.005 s do not overlap the mocap times 0.000..0.158 s" in err


def test_convert_refuses_to_overwrite_unless_forced(tmp_path, capsys):
    trial = save_trial(tmp_path, synthetic_trial())
    out = str(tmp_path / "rec")
    assert convert(capsys, "broad", str(trial), "--out", out)[0] == 0
    status, _, err = convert(capsys, "broad", str(trial), "--mocap-step", "2", "--out", out)
    assert status == 2 and err.count("\n") == 1
    assert re.search(r"rec already holds imu\.csv, mocap\.csv, recording\.yaml; expected a new "
                     r"or empty folder \(use --force to overwrite\)", err)
    assert len(read_recording(out).mocap) == 600
    assert convert(capsys, "broad", str(trial), "--mocap-step", "2", "--out", out, "--force")[0] \
        == 0
    assert len(read_recording(out).mocap) == 300
