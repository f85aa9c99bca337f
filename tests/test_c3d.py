"""C3D files: the reader, the rigid-body solving and ``kfusion convert c3d``.

The C3D files are written with ezc3d itself: a hand-made 4-marker cluster moving on a known
trajectory (mm units, first frame 51, residual-flagged and zero-filled gaps, one swapped marker).
The expected poses are derived by hand from that trajectory (see :func:`expected_pose`).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from kfusion.cli import main
from kfusion.readers.c3d import c3d_frame_times, read_c3d_markers, residuals_quantised
from kfusion.recording import RecordingError, read_markers, read_mocap, read_recording
from kfusion.rigid_body import estimate_cluster, fit_pose, mean_shape, solve_poses

ezc3d = pytest.importorskip("ezc3d", reason="ezc3d not installed: pip install 'kfusion[c3d]'")

LABELS = ("A", "B", "C", "D")
BODY = np.array([[0.06, 0.0, 0.0], [-0.02, 0.04, 0.0], [-0.02, -0.04, 0.02],
                 [-0.02, 0.0, -0.02]])
"""m, the cluster in its own frame; centroid at the origin (each column sums to 0)."""
RATE = 100.0
FIRST_FRAME = 51
"""1-based, so frame i is at t = (50 + i) / 100 s."""
FRAMES = 200
FLAGGED = {0: [3], 20: [0, 1], 21: [0, 1], 22: [0, 1], 23: [0, 1], 24: [0, 1], 30: [0, 1, 2, 3],
           40: [2], 41: [2], 42: [2]}
"""frame -> markers with residual -1 (invalid)."""
ZEROED = {10: [0], 11: [0], 12: [0], 13: [0], 14: [0], 40: [1], 41: [1], 42: [1]}
"""frame -> markers written as exactly (0, 0, 0) with a valid residual."""
SWAPPED = 60
"""In this frame markers A and C are written swapped."""
UNSOLVABLE = {20, 21, 22, 23, 24, 30, 40, 41, 42}
"""Frames with fewer than 3 markers seen."""


def angle(t: np.ndarray) -> np.ndarray:
    """rad, rotation of the cluster about the global y axis."""
    return 0.4 * t + 0.3


def origin(t: np.ndarray) -> np.ndarray:
    """m, (k, 3) the cluster's centroid in the global frame."""
    return np.column_stack([0.3 + 0.1 * t, 1.0 + 0.0 * t, -0.2 + 0.05 * np.sin(2 * t)])


def rotation_y(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def true_markers(t: np.ndarray) -> np.ndarray:
    """(k, 4, 3) m: g_i = p(t) + Ry(angle(t)) b_i."""
    return np.stack([origin(t)[k] + BODY @ rotation_y(a).T for k, a in enumerate(angle(t))])


def expected_pose(t: np.ndarray, t_first_full: float) -> tuple[np.ndarray, np.ndarray]:
    """Pose in the converted body frame (axes = global axes at the first full frame t1):
    R' = Ry(angle(t) - angle(t1)), so q = [cos(d/2), 0, sin(d/2), 0] with d = angle(t) - angle(t1);
    the origin is the centroid, p(t)."""
    half = (angle(t) - angle(np.array([t_first_full]))) / 2
    quaternion = np.column_stack([np.cos(half), 0 * half, np.sin(half), 0 * half])
    return origin(t), quaternion


def write_c3d(path: Path, positions_m: np.ndarray, *, labels=LABELS, units: str = "mm",
              scale: float = 1000.0, first_frame: int = FIRST_FRAME, rate: float = RATE,
              flagged=None, zeroed=None, y_screen: str | None = None,
              measured_residual=0.0, interpolated=None) -> Path:
    """Write a C3D file with ezc3d: positions (k, n, 3) in m, written in ``units`` (times
    ``scale``); ``flagged`` points get residual -1 and zeros, ``zeroed`` points (0, 0, 0); the
    others residual ``measured_residual`` (a float, or (frames, markers)), except
    ``interpolated`` points: 0 (not measured). ezc3d stores residuals in whole multiples of
    ``|POINT:SCALE|`` (1 here)."""
    count, n = positions_m.shape[:2]
    points = np.ones((4, n, count))
    points[:3] = np.transpose(positions_m * scale, (2, 1, 0))
    residuals = np.broadcast_to(np.asarray(measured_residual, dtype=float),
                                (count, n)).T[None].copy()
    for frame, markers in (interpolated or {}).items():
        residuals[0, markers, frame] = 0.0
    for frame, markers in (flagged or {}).items():
        for marker in markers:
            points[:3, marker, frame] = 0.0
            residuals[0, marker, frame] = -1.0
    for frame, markers in (zeroed or {}).items():
        for marker in markers:
            points[:3, marker, frame] = 0.0
    content = ezc3d.c3d()
    content["parameters"]["POINT"]["RATE"]["value"] = [rate]
    content["parameters"]["POINT"]["LABELS"]["value"] = tuple(labels)
    content["parameters"]["POINT"]["UNITS"]["value"] = [units]
    if y_screen is not None:
        content.add_parameter("POINT", "Y_SCREEN", [y_screen])
    content["data"]["points"] = points
    content["data"]["meta_points"] = {"residuals": residuals,
                                      "camera_masks": np.zeros((7, n, count), dtype=bool)}
    content["header"]["points"]["first_frame"] = first_frame - 1  # ezc3d counts from 0
    content.write(str(path))
    return path


def frame_times(count: int = FRAMES) -> np.ndarray:
    return (FIRST_FRAME - 1 + np.arange(count)) / RATE


def cluster_file(tmp_path: Path, name: str = "take.c3d", **options) -> Path:
    positions = true_markers(frame_times())
    positions[SWAPPED, [0, 2]] = positions[SWAPPED, [2, 0]]
    options = {"flagged": FLAGGED, "zeroed": ZEROED, **options}
    return write_c3d(tmp_path / name, positions, **options)


def write_imu(path: Path, start: float = 0.4, count: int = 600, rate: float = 200.0) -> Path:
    rows = ["t,ax,ay,az,gx,gy,gz"]
    rows += [f"{start + i / rate!r},0.01,0.02,9.81,0.001,0.1,0.0" for i in range(count)]
    path.write_text("\n".join(rows) + "\n")
    return path


def convert(capsys, *arguments: str) -> tuple[int, str, str]:
    status = main(["convert", "c3d", *arguments])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


# ------------------------------------------------------------------------------------------
# Pure functions
# ------------------------------------------------------------------------------------------


def test_frame_times_start_at_first_frame_minus_one():
    np.testing.assert_array_equal(c3d_frame_times(51, 3, 100.0), [0.5, 0.51, 0.52])
    np.testing.assert_array_equal(c3d_frame_times(1, 2, 120.0), [0.0, 1 / 120])


def test_fit_pose_recovers_a_hand_made_pose_from_three_markers():
    rotation = rotation_y(0.7)
    position = np.array([0.1, -0.2, 0.3])
    seen = position + BODY @ rotation.T
    for subset in ([0, 1, 2], [0, 1, 2, 3], [1, 2, 3]):
        fitted_rotation, fitted_position = fit_pose(BODY[subset], seen[subset])
        np.testing.assert_allclose(fitted_rotation, rotation, atol=1e-12)
        np.testing.assert_allclose(fitted_position, position, atol=1e-12)


def test_mean_shape_takes_the_first_frame_axes_and_the_centroid_origin():
    t = np.array([0.0, 0.5, 1.0])
    shape = mean_shape(true_markers(t))
    # First frame at angle 0.3: body positions are Ry(0.3) b_i (the centroid is already 0).
    np.testing.assert_allclose(shape, BODY @ rotation_y(0.3).T, atol=1e-12)


def test_solve_poses_needs_three_markers_and_refuses_a_swap():
    t = np.array([0.0, 0.1, 0.2, 0.3])
    seen = true_markers(t)
    seen[1, 0] = np.nan  # 3 left: solved
    seen[2, :2] = np.nan  # 2 left: not solved
    seen[3, [0, 2]] = seen[3, [2, 0]]  # swapped: refused
    body = BODY @ rotation_y(0.3).T
    poses = solve_poses(seen, body)
    np.testing.assert_array_equal(poses.solved, [True, True, False, False])
    np.testing.assert_array_equal(poses.rejected, [False, False, False, True])
    np.testing.assert_array_equal(poses.visible, [4, 3, 2, 4])
    expected_position, expected_quaternion = expected_pose(t, 0.0)
    np.testing.assert_allclose(poses.position[:2], expected_position[:2], atol=1e-12)
    np.testing.assert_allclose(poses.quaternion[:2], expected_quaternion[:2], atol=1e-12)
    assert np.isnan(poses.position[2:]).all() and np.isnan(poses.quaternion[2:]).all()


def test_estimate_cluster_refuses_collinear_markers_and_no_full_frame():
    line = np.array([[[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0]]])
    with pytest.raises(ValueError, match="nearly collinear"):
        estimate_cluster(("a", "b", "c"), line)
    partial = true_markers(np.array([0.0]))
    partial[0, 1] = np.nan
    with pytest.raises(ValueError, match=r"no frame where all 4 markers \['A', 'B', 'C', 'D'\]"):
        estimate_cluster(LABELS, partial)


def test_rigidity_of_a_noisy_cluster_is_reported_in_mm():
    rng = np.random.default_rng(7)
    seen = true_markers(np.linspace(0, 2, 400)) + rng.normal(0, 0.0005, (400, 4, 3))
    cluster = estimate_cluster(LABELS, seen)
    # Each distance is the difference of two points with 0.5 mm noise per axis: its std is
    # about 0.5 * sqrt(2) = 0.71 mm.
    assert 0.6e-3 < cluster.distance_spread.min() and cluster.distance_spread.max() < 0.8e-3
    assert "cluster rigidity: inter-marker distance std at most 0.7" in cluster.rigidity_line()


# ------------------------------------------------------------------------------------------
# Reader
# ------------------------------------------------------------------------------------------


def test_reader_honours_units_first_frame_residuals_and_zeros(tmp_path):
    take = read_c3d_markers(cluster_file(tmp_path), ["B", "A", "D", "C"])
    assert (take.rate, take.first_frame, take.units) == (RATE, FIRST_FRAME, "mm")
    assert take.labels == LABELS and take.gravity is None
    flagged_b_a_d_c = sum(len(set(m) & {0, 1, 2, 3}) for m in FLAGGED.values())
    assert take.residual_flagged == flagged_b_a_d_c == 18
    assert take.zero_filled == 8
    markers = take.markers
    assert markers.names == ("B", "A", "D", "C")
    np.testing.assert_allclose(markers.t, frame_times(), rtol=0, atol=1e-15)
    assert markers.t[0] == 0.5
    truth = true_markers(frame_times())[:, [1, 0, 3, 2]]
    truth[SWAPPED, [1, 3]] = truth[SWAPPED, [3, 1]]
    for frame, hidden in [*FLAGGED.items(), *ZEROED.items()]:
        truth[frame, [[1, 0, 3, 2].index(marker) for marker in hidden]] = np.nan
    np.testing.assert_array_equal(np.isnan(markers.position), np.isnan(truth))
    # float32 mm in the file: about 1e-4 mm resolution at 1.3 m.
    np.testing.assert_allclose(markers.position, truth, atol=1e-6, rtol=0)


def test_reader_reads_unmeasured_points_as_occluded_where_the_file_gives_residuals(tmp_path):
    """Residual 0 marks a point not derived from camera rays (interpolated, filtered or
    simulated: the C3D standard's glossary); measured points have a positive one."""
    filled = {100: [0], 101: [0], 102: [0], 150: [1, 3]}
    # residuals are stored in whole multiples of |POINT:SCALE| (1 here): 2 mm
    path = cluster_file(tmp_path, measured_residual=2.0, interpolated=filled)
    take = read_c3d_markers(path, list(LABELS))
    assert take.residuals_given and take.interpolated == 5
    assert take.residual_flagged == 18 and take.zero_filled == 8  # unchanged
    for frame, markers in filled.items():
        assert np.isnan(take.markers.position[frame, markers]).all()
        others = [marker for marker in range(4) if marker not in markers]
        assert np.isfinite(take.markers.position[frame, others]).all()
    kept = read_c3d_markers(path, list(LABELS), keep_unmeasured=True)
    assert kept.residuals_given and kept.interpolated == 0
    assert np.isfinite(kept.markers.position[100, 0]).all()
    # a file whose residuals are all 0 or -1 (no exporter residuals: simulated data) keeps them
    plain = read_c3d_markers(cluster_file(tmp_path, "plain.c3d", interpolated=filled),
                             list(LABELS))
    assert not plain.residuals_given and plain.interpolated == 0
    assert np.isfinite(plain.markers.position[100, 0]).all()


def test_reader_keeps_residual_zero_points_where_the_residuals_are_quantised(tmp_path):
    """With POINT:SCALE 1 mm, measured residuals of 0.3-1.3 mm are stored as 0 or 1: a 0 may be
    a measured point rounded down, so nothing is read as not measured (the rule alone dropped
    87 % of a simulated take's measured points)."""
    residual = np.random.default_rng(3).uniform(0.3, 1.3, (FRAMES, 4))
    path = cluster_file(tmp_path, measured_residual=residual, interpolated={100: [0]})
    take = read_c3d_markers(path, list(LABELS))
    assert take.residuals_given and take.residuals_quantised and take.interpolated == 0
    assert np.isfinite(take.markers.position[100, 0]).all()
    # one step per positive residual is the cut-off: 10 % of them at 1 step is quantised
    assert residuals_quantised(np.array([1.0] + [3.0] * 9), 1.0)
    assert not residuals_quantised(np.array([1.0] + [3.0] * 10), 1.0)
    assert not residuals_quantised(np.array([2.0, 3.0]), 1.0)
    assert not residuals_quantised(np.zeros(0), 1.0)


def test_convert_names_the_unmeasured_samples_when_too_few_frames_are_left(tmp_path, capsys):
    filled = {frame: [1] for frame in range(FRAMES)}  # marker B never measured
    path = cluster_file(tmp_path, measured_residual=2.0, interpolated=filled)
    imu = write_imu(tmp_path / "imu_in.csv")
    status, _, err = convert(capsys, str(path), "--imu", str(imu), "--markers", "A,B,C,D",
                             "--out", str(tmp_path / "rec"))
    assert status == 2
    assert re.search(r"take\.c3d: no frame where all 4 markers .* \(\d+ samples with residual 0 "
                     r"were read as not measured: --keep-unmeasured keeps them\)", err), err


def test_reader_converts_metres_and_centimetres_and_reads_the_up_axis(tmp_path):
    truth = true_markers(frame_times(5))
    for units, scale in (("m", 1.0), ("cm", 100.0)):
        path = write_c3d(tmp_path / f"{units}.c3d", truth, units=units, scale=scale,
                         y_screen="+Y")
        take = read_c3d_markers(path, LABELS)
        np.testing.assert_allclose(take.markers.position, truth, atol=1e-6, rtol=0)
        assert take.gravity == (0.0, -9.81, 0.0)


def test_reader_matches_a_prefixed_label_by_its_marker_name(tmp_path):
    truth = true_markers(frame_times(3))
    path = write_c3d(tmp_path / "prefixed.c3d", truth,
                     labels=("Forearm:A", "Forearm:B", "Forearm:C", "Other:A"))
    take = read_c3d_markers(path, ["B", "C", "Forearm:A"])
    np.testing.assert_allclose(take.markers.position, truth[:, [1, 2, 0]], atol=1e-6, rtol=0)
    with pytest.raises(RecordingError, match=r"prefixed\.c3d: marker name 'A' is ambiguous: it "
                       r"matches \['Forearm:A', 'Other:A'\]"):
        read_c3d_markers(path, ["A", "B", "C"])
    # a full label given twice: "give the full label" cannot help; say to rename the duplicate
    duplicated = write_c3d(tmp_path / "duplicated.c3d", truth, labels=("A", "B", "A", "C"))
    with pytest.raises(RecordingError, match=r"duplicated\.c3d: marker label 'A' appears 2 times "
                       r"in POINT:LABELS \(columns \[0, 2\]\); rename the duplicates"):
        read_c3d_markers(duplicated, ["A", "B", "C"])


@pytest.mark.parametrize(("options", "names", "pattern"), [
    ({}, ["A", "B", "X"], r"take\.c3d: no marker named 'X'; expected names from POINT:LABELS: "
     r"\['A', 'B', 'C', 'D'\]"),
    ({"units": "in"}, ["A", "B", "C"], r"take\.c3d, key 'POINT:UNITS': length unit 'in'; "
     r"expected one of \['mm', 'cm', 'm'\]"),
    ({"units": "m"}, ["A", "B", "C"], r"take\.c3d, key 'POINT:UNITS': marker 'A' at x = 402\.655 m "
     r"in frame 51 \(POINT:UNITS says 'm'\).*wrong unit"),
    ({"rate": -5.0}, ["A", "B", "C"], r"key 'POINT:RATE': frame rate -5\.0; expected a positive"),
])
def test_reader_refusals_name_the_file_and_what_is_wrong(tmp_path, options, names, pattern):
    path = cluster_file(tmp_path, **options)
    with pytest.raises(RecordingError, match=pattern):
        read_c3d_markers(path, names)


def test_reader_refuses_a_file_that_is_not_c3d(tmp_path):
    path = tmp_path / "notes.c3d"
    path.write_text("not a c3d file\n")
    with pytest.raises(RecordingError, match=r"^notes\.c3d: cannot be read as C3D \("):
        read_c3d_markers(path, LABELS)
    with pytest.raises(RecordingError, match=r"^absent\.c3d: file not found in "):
        read_c3d_markers(tmp_path / "absent.c3d", LABELS)


# ------------------------------------------------------------------------------------------
# kfusion convert c3d
# ------------------------------------------------------------------------------------------


def test_convert_c3d_poses_match_the_hand_derived_truth(tmp_path, capsys):
    path = cluster_file(tmp_path)
    imu = write_imu(tmp_path / "imu_in.csv")
    out = tmp_path / "rec"
    status, stdout, err = convert(capsys, str(path), "--imu", str(imu), "--markers", "A,B,C,D",
                                  "--out", str(out))
    assert (status, err) == (0, ""), err
    solved = FRAMES - len(UNSOLVABLE) - 1  # minus the swapped frame
    assert f"solvable frames: {solved} of {FRAMES} (95.0 %) with >= 3 markers seen; 1 refused" \
        in stdout
    assert "from frame 51 (t = 0.5 s), POINT:UNITS mm; 18 marker samples flagged invalid, " \
        "8 zero-filled" in stdout
    # Full frames: 200 minus the 15 frames with a marker hidden (0, 10-14, 20-24, 30, 40-42) =
    # 185, of which the swapped frame 60 is left out: 184. Three or more seen: 200 - 9 = 191.
    assert re.search(r"cluster rigidity: inter-marker distance std at most 0\.00 mm \(.-.\), "
                     r"range at most 0\.00 mm over 184 frames with all 4 markers seen \(1 more "
                     r"left out: a marker off by more than the residual limit\)", stdout)
    assert "gravity: [0.0, 0.0, -9.81] m/s^2 from no POINT:Y_SCREEN in the file" in stdout
    assert f"next: kfusion calibrate {out} --out {out / 'recording.yaml'} --force" in stdout
    assert ("markers: 4 (A, B, C, D) in 200 frames; all seen in 92.5 %, 3 or more in 95.5 %, "
            "none in 0.5 %") in stdout

    t = frame_times()
    mocap = read_mocap(out / "mocap.csv")
    np.testing.assert_array_equal(mocap.t, read_markers(out / "markers.csv").t)
    np.testing.assert_allclose(mocap.t, t, rtol=0, atol=1e-15)
    expected_hidden = np.zeros(FRAMES, dtype=bool)
    expected_hidden[sorted(UNSOLVABLE | {SWAPPED})] = True
    np.testing.assert_array_equal(~mocap.visible, expected_hidden)
    # The first frame with all markers seen is frame 1 (frame 0 lacks D): its axes are the
    # body frame's.
    position, quaternion = expected_pose(t, t_first_full=t[1])
    np.testing.assert_allclose(mocap.position[~expected_hidden], position[~expected_hidden],
                               atol=2e-6, rtol=0)
    np.testing.assert_allclose(mocap.quaternion[~expected_hidden],
                               quaternion[~expected_hidden], atol=2e-5, rtol=0)

    metadata = yaml.safe_load((out / "recording.yaml").read_text())
    assert "imu_to_body" not in metadata and metadata["gravity"] == [0.0, 0.0, -9.81]
    assert list(metadata["markers"]) == ["A", "B", "C", "D"]
    body = np.array([metadata["markers"][name] for name in LABELS])
    np.testing.assert_allclose(body, BODY @ rotation_y(angle(t[1:2])[0]).T, atol=2e-6, rtol=0)


def test_convert_c3d_reads_gap_filled_points_as_occluded_and_says_how_many(tmp_path, capsys):
    """An export after "fill gaps": the filled points carry residual 0, the measured ones a
    positive residual. They are left occluded (kfusion bridges gaps itself), counted in the
    summary, and kept with --keep-unmeasured."""
    filled = {f: [2] for f in range(100, 110)}
    path = cluster_file(tmp_path, measured_residual=2.0, interpolated=filled)
    imu = write_imu(tmp_path / "imu_in.csv")
    status, stdout, err = convert(capsys, str(path), "--imu", str(imu), "--markers", "A,B,C,D",
                                  "--out", str(tmp_path / "rec"))
    assert (status, err) == (0, ""), err
    assert "8 zero-filled, 10 not measured (residual 0: interpolated or filtered by the " \
        "exporter) read as occluded (--keep-unmeasured keeps them)" in stdout
    markers = read_markers(tmp_path / "rec" / "markers.csv")
    assert np.isnan(markers.position[100:110, 2]).all()
    status, stdout, err = convert(capsys, str(path), "--imu", str(imu), "--markers", "A,B,C,D",
                                  "--out", str(tmp_path / "kept"), "--keep-unmeasured")
    assert (status, err) == (0, ""), err
    assert "residual-0 samples kept (--keep-unmeasured)" in stdout
    assert np.isfinite(read_markers(tmp_path / "kept" / "markers.csv").position[100:110, 2]).all()


def test_convert_c3d_with_three_markers_and_a_mount_passes_the_reader(tmp_path, capsys):
    path = cluster_file(tmp_path)
    imu = write_imu(tmp_path / "imu_in.csv")
    out = tmp_path / "rec"
    status, stdout, err = convert(capsys, str(path), "--imu", str(imu), "--markers", "C,A,B",
                                  "--imu-to-body", "1", "0", "0", "0", "--gravity", "0", "-9.81",
                                  "0", "--name", "three", "--out", str(out))
    assert (status, err) == (0, ""), err
    recording = read_recording(out)
    assert recording.markers is not None and recording.markers.names == ("C", "A", "B")
    assert recording.info.name == "three" and list(recording.info.markers) == ["C", "A", "B"]
    # Three markers: any frame missing A, B or C is unsolvable. The A-C swap of frame 60 is
    # NOT caught here: swapped, the triangle A, B, C changes its sides by only 7 mm, so the fit
    # misses by less than the 10 mm limit (a 3-marker cluster should be clearly scalene).
    seen = recording.markers.visible.sum(axis=1)
    np.testing.assert_array_equal(recording.mocap.visible, seen == 3)
    assert f"next: kfusion check {out}" in stdout


def test_convert_c3d_noisy_markers_give_poses_within_noise(tmp_path, capsys):
    rng = np.random.default_rng(12)
    t = frame_times()
    noisy = true_markers(t) + rng.normal(0, 0.0003, (FRAMES, 4, 3))
    path = write_c3d(tmp_path / "noisy.c3d", noisy)
    imu = write_imu(tmp_path / "imu_in.csv")
    status, stdout, _ = convert(capsys, str(path), "--imu", str(imu), "--markers", "A,B,C,D",
                                "--out", str(tmp_path / "rec"))
    assert status == 0
    mocap = read_mocap(tmp_path / "rec" / "mocap.csv")
    # The body frame comes from the (noisy) first frame, so compare the centroid's path and the
    # rotation relative to frame 0: the origin error is about 0.3 mm / sqrt(4) = 0.15 mm.
    error = np.linalg.norm(mocap.position - origin(t), axis=1)
    assert np.sqrt(np.mean(error**2)) < 0.3e-3
    assert "solvable frames: 200 of 200 (100.0 %)" in stdout


@pytest.mark.parametrize(("arguments", "pattern"), [
    (["--markers", "A,B,X"], r"take\.c3d: no marker named 'X'; expected names from "
     r"POINT:LABELS: \['A', 'B', 'C', 'D'\]"),
    (["--markers", "A,B"], r"command line: 2 marker\(s\) \['A', 'B'\]; expected 3 or more"),
    (["--max-residual", "5"], r"command line: expected --markers M1,M2,M3\[,\.\.\.\] \(the "
     r"cluster's markers\) or --body NAME"),
    (["--markers", "A,A,B"], r"command line, key 'markers': marker names \['A', 'A', 'B'\] repeat"),
    (["--markers", "A,,B"], r"command line, key 'markers': marker name '' is not usable"),
    (["--markers", "A,B,C", "--max-residual", "0"], r"--max-residual 0\.0; expected a positive"),
    (["--markers", "A,B,C", "--imu", "LATE"], r"IMU times 1000\.000\.\.1000\.005 s do not overlap"),
])
def test_convert_c3d_mistakes_are_one_line_with_exit_2(tmp_path, capsys, arguments, pattern):
    path = cluster_file(tmp_path)
    imu = write_imu(tmp_path / "imu_in.csv")
    late = tmp_path / "late.csv"
    late.write_text("t,ax,ay,az,gx,gy,gz\n1000.0,0,0,9.81,0,0,0\n1000.005,0,0,9.81,0,0,0\n")
    names = {"LATE": str(late)}
    arguments = [names.get(a, a) for a in arguments]
    if "--imu" not in arguments:
        arguments += ["--imu", str(imu)]
    status, stdout, err = convert(capsys, str(path), *arguments, "--out", str(tmp_path / "out"))
    assert status == 2 and stdout == ""
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("kfusion convert: error: ") and re.search(pattern, err), err
    assert not (tmp_path / "out").exists()


def test_convert_c3d_refuses_a_cluster_never_fully_seen(tmp_path, capsys):
    path = cluster_file(tmp_path, flagged={i: [3] for i in range(FRAMES)}, zeroed={})
    imu = write_imu(tmp_path / "imu_in.csv")
    status, _, err = convert(capsys, str(path), "--imu", str(imu), "--markers", "A,B,C,D",
                             "--out", str(tmp_path / "out"))
    assert status == 2
    assert "take.c3d: no frame where all 4 markers ['A', 'B', 'C', 'D'] are seen" in err


def test_convert_c3d_refuses_to_overwrite_markers_without_force(tmp_path, capsys):
    path = cluster_file(tmp_path)
    imu = write_imu(tmp_path / "imu_in.csv")
    out = tmp_path / "rec"
    out.mkdir()
    (out / "markers.csv").write_text("t,A_x,A_y,A_z\n0,0,0,0\n")
    status, _, err = convert(capsys, str(path), "--imu", str(imu), "--markers", "A,B,C",
                             "--out", str(out))
    assert status == 2 and "already holds markers.csv" in err


def test_write_c3d_markers_round_trips_within_float32(tmp_path):
    from kfusion.readers.c3d import write_c3d_markers
    from kfusion.recording import MarkerFrames

    t = (119 + np.arange(50)) / 120.0  # first frame 120 at 120 Hz: t0 = 119 / 120 s
    position = true_markers(t)
    position[5, 2] = np.nan
    position[7] = np.nan
    markers = MarkerFrames(t=t, names=LABELS, position=position)
    path = write_c3d_markers(tmp_path / "out.c3d", markers, up_axis="+Z")
    take = read_c3d_markers(path, LABELS)
    assert (take.first_frame, take.rate, take.units) == (120, 120.0, "mm")
    assert take.gravity == (0.0, 0.0, -9.81) and take.residual_flagged == 5
    np.testing.assert_allclose(take.markers.t, t, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(np.isnan(take.markers.position), np.isnan(position))
    np.testing.assert_allclose(take.markers.position, position, atol=1e-6, rtol=0)
    uneven = MarkerFrames(t=[0.0, 0.01, 0.03], names=LABELS, position=np.zeros((3, 4, 3)))
    with pytest.raises(ValueError, match=r"expected times t_i = \(F - 1 \+ i\) / rate"):
        write_c3d_markers(tmp_path / "uneven.c3d", uneven)


def test_convert_c3d_body_picks_the_prefixed_labels(tmp_path, capsys):
    truth = true_markers(frame_times(40))
    path = write_c3d(tmp_path / "bodies.c3d", truth,
                     labels=("Forearm:A", "Forearm:B", "Forearm:C", "Other:A"))
    imu = write_imu(tmp_path / "imu_in.csv")
    status, _, err = convert(capsys, str(path), "--imu", str(imu), "--body", "Forearm",
                             "--out", str(tmp_path / "rec"))
    assert (status, err) == (0, ""), err
    markers = read_markers(tmp_path / "rec" / "markers.csv")
    assert markers.names == ("Forearm:A", "Forearm:B", "Forearm:C")
    np.testing.assert_allclose(markers.position, truth[:, :3], atol=1e-6, rtol=0)
    status, _, err = convert(capsys, str(path), "--imu", str(imu), "--body", "Forearm",
                             "--markers", "C,A,B", "--out", str(tmp_path / "rec2"))
    assert status == 0
    assert read_markers(tmp_path / "rec2" / "markers.csv").names == (
        "Forearm:C", "Forearm:A", "Forearm:B")
    status, _, err = convert(capsys, str(path), "--imu", str(imu), "--body", "Arm",
                             "--out", str(tmp_path / "rec3"))
    assert status == 2 and err.count("\n") == 1
    assert "bodies.c3d: no label 'BODY:NAME' with BODY 'Arm'; expected one of the prefixes " \
        "['Forearm', 'Other'] in POINT:LABELS" in err


def test_without_ezc3d_the_message_says_how_to_install(tmp_path, monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "ezc3d", None)  # import ezc3d raises ImportError
    with pytest.raises(RecordingError, match=re.escape(
            "take.c3d: reading C3D needs ezc3d: pip install 'kfusion[c3d]'")):
        read_c3d_markers(tmp_path / "take.c3d", LABELS)


def test_up_axis_is_minus_gravity_along_one_axis():
    from kfusion.readers.c3d import up_axis

    assert up_axis([0.0, -9.81, 0.0]) == "+Y" and up_axis([0.0, 0.0, 9.81]) == "-Z"
    assert up_axis([-9.81, 0.0, 0.0]) == "+X"
    assert up_axis([0.0, -6.0, -7.0]) is None and up_axis([np.nan] * 3) is None
