"""Several bodies: ``convert c3d`` into one folder per body, ``track`` over a folder of bodies,
and the binding body with its margin |robot - body| - S_p (hand-derived numbers, a hypothesis
property, the batch form over tracks, and the README's example run as written)."""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from kfusion.bodies import body_folders, for_each_body, read_body_tracks
from kfusion.cli import main
from kfusion.conventions import BRIDGED, LOST, TRACKED
from kfusion.recording import MarkerFrames, read_markers, read_mocap
from kfusion.safety import (
    BodyEstimate,
    binding_body,
    binding_margins,
    protective_separation_distance,
)
from kfusion.simulate import OcclusionSpec, simulate, write_simulation
from kfusion.track_file import TrackResult, read_track, write_track_csv

README = Path(__file__).resolve().parents[1] / "README.md"

# ------------------------------------------------------------------------------------------
# convert c3d: several bodies
# ------------------------------------------------------------------------------------------

CLUSTER = np.array([[0.06, 0.0, 0.0], [-0.02, 0.04, 0.0], [-0.02, -0.04, 0.02],
                    [-0.02, 0.0, -0.02]])
"""m, a scalene 4-marker cluster with its centroid at the origin (each column sums to 0)."""
MARKERS = ("A", "B", "C", "D")
RATE = 100.0
FRAMES = 60


def origins(t: np.ndarray) -> dict[str, np.ndarray]:
    """m, (k, 3): each body's centroid; the clusters translate without rotating, so the body
    frame (global axes at the first full frame, origin at the centroid) keeps the cluster's
    shape and the converted mocap position is the centroid itself."""
    return {"Left": np.column_stack([0.2 + 0.1 * t, 1.0 + 0 * t, 0.3 + 0 * t]),
            "Right": np.column_stack([-0.2 + 0 * t, 1.1 - 0.05 * t, 0.3 + 0.02 * t])}


def write_bodies_c3d(path: Path, hidden: dict[tuple[str, str], list[int]] | None = None) -> Path:
    """Two 4-marker bodies ``Left:A..D`` and ``Right:A..D`` (plus one unprefixed marker) as a C3D
    file, written by kfusion's own writer (ezc3d); ``hidden`` (body, marker) -> frames."""
    from kfusion.readers.c3d import write_c3d_markers

    pytest.importorskip("ezc3d", reason="ezc3d not installed: pip install 'kfusion[c3d]'")
    t = np.arange(FRAMES) / RATE
    names, columns = [], []
    for body, origin in origins(t).items():
        for marker, offset in zip(MARKERS, CLUSTER, strict=True):
            names.append(f"{body}:{marker}")
            columns.append(origin + offset)
    names.append("Loose")
    columns.append(np.tile([1.0, 1.0, 1.0], (FRAMES, 1)))
    position = np.stack(columns, axis=1)
    for (body, marker), frames in (hidden or {}).items():
        position[frames, names.index(f"{body}:{marker}")] = np.nan
    markers = MarkerFrames(t=t, names=tuple(names), position=position)
    return write_c3d_markers(path, markers, up_axis="+Y")


def write_imu(path: Path) -> Path:
    rows = ["t,ax,ay,az,gx,gy,gz"] + [f"{i / 200.0!r},0.0,9.81,0.0,0.0,0.0,0.0"
                                      for i in range(130)]
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.fixture
def take(tmp_path):
    """(c3d path, {body: imu path})"""
    imus = {body: write_imu(tmp_path / f"imu_{body}.csv") for body in ("Left", "Right")}
    return write_bodies_c3d(tmp_path / "two.c3d"), imus


def convert(capsys, *arguments: str) -> tuple[int, str, str]:
    status = main(["convert", "c3d", *arguments])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def imu_options(imus: dict[str, Path], bodies=("Left", "Right")) -> list[str]:
    return [option for body in bodies for option in ("--imu", f"{body}={imus[body]}")]


def check_body_folder(folder: Path, body: str) -> None:
    t = np.arange(FRAMES) / RATE
    markers = read_markers(folder / "markers.csv")
    assert markers.names == tuple(f"{body}:{marker}" for marker in MARKERS)
    np.testing.assert_allclose(markers.position, origins(t)[body][:, None] + CLUSTER,
                               atol=1e-6, rtol=0)
    mocap = read_mocap(folder / "mocap.csv")
    np.testing.assert_allclose(mocap.position, origins(t)[body], atol=1e-6, rtol=0)
    np.testing.assert_allclose(np.abs(mocap.quaternion[:, 0]), 1.0, atol=1e-9)
    metadata = yaml.safe_load((folder / "recording.yaml").read_text())
    assert "imu_to_body" not in metadata and metadata["gravity"] == [0.0, -9.81, 0.0]
    assert metadata["name"] == f"two-{body}"
    positions = np.array([metadata["markers"][f"{body}:{marker}"] for marker in MARKERS])
    np.testing.assert_allclose(positions, CLUSTER, atol=1e-6, rtol=0)


@pytest.mark.parametrize("choice", [[], ["--body", "Left", "--body", "Right"], ["--all-bodies"]])
def test_convert_writes_one_folder_per_body(take, tmp_path, capsys, choice):
    path, imus = take
    out = tmp_path / "bodies"
    status, stdout, err = convert(capsys, str(path), *imu_options(imus), *choice,
                                  "--out", str(out))
    assert (status, err) == (0, ""), err
    assert [folder.name for folder in body_folders(out)] == ["Left", "Right"]
    for body in ("Left", "Right"):
        check_body_folder(out / body, body)
        assert f"c3d: body {body}: wrote {out / body}" in stdout
    assert "2 bodies (Left, Right)" in stdout and f"kfusion track {out}" in stdout
    ignored = "--all-bodies: ignored 1 label(s) without a BODY: prefix (no body): Loose"
    assert (ignored in stdout) == (choice == ["--all-bodies"])


def test_convert_one_body_of_several_with_explicit_markers(take, tmp_path, capsys):
    path, imus = take
    status, _, err = convert(capsys, str(path), "--imu", f"Right={imus['Right']}",
                             "--markers", "C,A,B", "--out", str(tmp_path / "bodies"))
    assert (status, err) == (0, ""), err
    assert [folder.name for folder in body_folders(tmp_path / "bodies")] == ["Right"]
    assert read_markers(tmp_path / "bodies" / "Right" / "markers.csv").names == (
        "Right:C", "Right:A", "Right:B")


def error_of(capsys, *arguments: str) -> str:
    status, _, err = convert(capsys, *arguments)
    assert status == 2 and err.count("\n") == 1, err
    assert "Traceback" not in err
    return err


def test_every_body_needs_its_own_imu(take, tmp_path, capsys):
    path, imus = take
    out = str(tmp_path / "out")
    err = error_of(capsys, str(path), "--imu", f"Left={imus['Left']}", "--body", "Left",
                   "--body", "Right", "--out", out)
    assert "body 'Right' has no IMU file; expected --imu Right=IMU.csv" in err
    err = error_of(capsys, str(path), "--imu", str(imus["Left"]), "--body", "Left", "--body",
                   "Right", "--out", out)
    assert "every body needs its own IMU; expected --imu BODY=IMU.csv for each body" in err
    err = error_of(capsys, str(path), "--imu", str(imus["Left"]), "--all-bodies", "--out", out)
    assert "--all-bodies with one --imu" in err
    err = error_of(capsys, str(path), "--imu", f"Left={imus['Left']}", "--all-bodies",
                   "--out", out)
    assert "body 'Right' has no IMU file" in err
    err = error_of(capsys, str(path), *imu_options(imus), "--body", "Left", "--out", out)
    assert "--imu Right=...: no body 'Right' among the bodies converted ['Left']" in err
    err = error_of(capsys, str(path), "--imu", f"Left={imus['Left']}", "--imu",
                   f"Left={imus['Right']}", "--out", out)
    assert "--imu names body 'Left' twice" in err
    err = error_of(capsys, str(path), "--imu", f"Left={imus['Left']}", "--imu",
                   str(imus["Right"]), "--out", out)
    assert "expected either one IMU file (one body) or BODY=IMU.csv for every body" in err
    err = error_of(capsys, str(path), "--imu", f"Left={imus['Left']}", "--imu",
                   f"Right={imus['Left']}", "--out", out)
    assert f"--imu Left= and --imu Right= name the same file {imus['Left']}" in err
    assert not Path(out).exists()


def test_errors_name_the_body_marker_or_file_and_write_nothing(take, tmp_path, capsys):
    path, imus = take
    out = tmp_path / "out"
    err = error_of(capsys, str(path), "--imu", f"Left={imus['Left']}", "--imu",
                   f"Arm={imus['Right']}", "--out", str(out))
    assert "body 'Arm': two.c3d: no label 'BODY:NAME' with BODY 'Arm'; expected one of the " \
        "prefixes ['Left', 'Right'] in POINT:LABELS" in err
    err = error_of(capsys, str(path), *imu_options(imus), "--markers", "A,B,E", "--out",
                   str(out))
    assert "body 'Left': two.c3d: no marker named 'Left:E'" in err
    bad = tmp_path / "bad_imu.csv"
    bad.write_text("t,ax,ay,az,gx,gy,gz\n0.0,0,9.81,0,0,0,0\n0.005,0,nan,0,0,0,0\n")
    err = error_of(capsys, str(path), "--imu", f"Left={imus['Left']}", "--imu",
                   f"Right={bad}", "--out", str(out))
    assert "body 'Right': bad_imu.csv" in err and "row 2" in err
    err = error_of(capsys, str(path), "--imu", f"Left={imus['Left']}", "--imu",
                   f"Right={tmp_path / 'missing.csv'}", "--out", str(out))
    assert "missing.csv" in err
    err = error_of(capsys, str(path), *imu_options(imus), "--imu-to-body", "1", "0", "0", "0",
                   "--out", str(out))
    assert "--imu-to-body describes one body's IMU; with several bodies leave it out" in err
    err = error_of(capsys, str(path), "--imu", f"../x={imus['Left']}", "--out", str(out))
    assert "body '../x' cannot name a folder" in err
    assert not out.exists()  # no body written when any body fails


def test_existing_body_folder_is_refused_before_any_is_written(take, tmp_path, capsys):
    path, imus = take
    out = tmp_path / "out"
    (out / "Right").mkdir(parents=True)
    (out / "Right" / "mocap.csv").write_text("keep me")
    err = error_of(capsys, str(path), *imu_options(imus), "--out", str(out))
    assert f"{out / 'Right'} already holds mocap.csv" in err and "--force" in err
    assert not (out / "Left").exists()
    assert (out / "Right" / "mocap.csv").read_text() == "keep me"
    status, _, err = convert(capsys, str(path), *imu_options(imus), "--out", str(out),
                             "--force")
    assert (status, err) == (0, "")
    check_body_folder(out / "Right", "Right")


def test_all_bodies_needs_prefixed_labels(tmp_path, capsys):
    from kfusion.readers.c3d import write_c3d_markers

    pytest.importorskip("ezc3d")
    t = np.arange(10) / RATE
    markers = MarkerFrames(t=t, names=MARKERS, position=np.tile(CLUSTER, (10, 1, 1)))
    path = write_c3d_markers(tmp_path / "plain.c3d", markers)
    err = error_of(capsys, str(path), "--imu", f"X={write_imu(tmp_path / 'i.csv')}",
                   "--all-bodies", "--out", str(tmp_path / "out"))
    assert "plain.c3d: no label 'BODY:NAME' in POINT:LABELS" in err and "'A'" in err


# ------------------------------------------------------------------------------------------
# track: a folder of bodies
# ------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def bodies_folder(tmp_path_factory):
    """Two simulated bodies (different seeds) in one folder, plus a file that is not a body."""
    folder = tmp_path_factory.mktemp("bodies")
    for seed, body in enumerate(("LeftForearm", "RightForearm")):
        simulation = simulate("arm_lift", seed=seed, duration=6.0,
                              occlusions=OcclusionSpec(gap_range=(0.1, 0.3), spacing=1.5))
        write_simulation(simulation, folder / body)
    (folder / "notes.txt").write_text("not a body")
    return folder


def test_track_writes_one_track_per_body_equal_to_the_single_folder_track(
        bodies_folder, tmp_path, capsys):
    out = tmp_path / "tracks"
    assert main(["track", str(bodies_folder), "--out", str(out)]) == 0
    stdout = capsys.readouterr().out
    assert sorted(path.name for path in out.iterdir()) == ["LeftForearm.csv",
                                                           "RightForearm.csv"]
    assert "body LeftForearm: kalman: wrote" in stdout
    assert f"2 of 2 bodies tracked into {out}" in stdout
    single = tmp_path / "single.csv"
    assert main(["track", str(bodies_folder / "RightForearm"), "--out", str(single)]) == 0
    assert (out / "RightForearm.csv").read_bytes() == single.read_bytes()
    tracks = read_body_tracks(out)
    assert list(tracks) == ["LeftForearm", "RightForearm"]


def test_a_failing_body_is_named_and_the_others_complete(bodies_folder, tmp_path, capsys):
    import shutil

    folder = tmp_path / "bodies"
    shutil.copytree(bodies_folder, folder)
    shutil.copytree(folder / "LeftForearm", folder / "Broken")
    lines = (folder / "Broken" / "imu.csv").read_text().splitlines()
    lines[5] = ",".join(["nan"] + lines[5].split(",")[1:])
    (folder / "Broken" / "imu.csv").write_text("\n".join(lines) + "\n")
    out = tmp_path / "tracks"
    assert main(["track", str(folder), "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert "body Broken: error: imu.csv" in captured.err and "row 5" in captured.err
    assert "2 of 3 bodies tracked" in captured.out and "failed: Broken" in captured.out
    assert sorted(path.name for path in out.iterdir()) == ["LeftForearm.csv",
                                                           "RightForearm.csv"]


def test_track_of_bodies_wants_an_output_folder(bodies_folder, tmp_path, capsys):
    assert main(["track", str(bodies_folder), "--out", str(tmp_path / "t.csv")]) == 2
    err = capsys.readouterr().err
    assert "is a folder of 2 bodies (LeftForearm, RightForearm); expected an output folder" in err
    assert not (tmp_path / "t.csv").exists()


def test_interrupted_track_keeps_the_finished_bodies(bodies_folder, tmp_path, capsys,
                                                     monkeypatch):
    import kfusion.commands.track as track_command

    real = track_command.track_with_method
    calls = []

    def interrupted_on_second_body(*arguments, **options):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*arguments, **options)

    monkeypatch.setattr(track_command, "track_with_method", interrupted_on_second_body)
    out = tmp_path / "tracks"
    assert main(["track", str(bodies_folder), "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert "stopped at body RightForearm; finished: LeftForearm" in err
    assert [path.name for path in out.iterdir()] == ["LeftForearm.csv"]
    assert len(read_track(out / "LeftForearm.csv")) > 0


# ------------------------------------------------------------------------------------------
# binding body
# ------------------------------------------------------------------------------------------

ROBOT = dict(robot_speed=1.0, reaction_time=0.1, stopping_time=0.3, stopping_distance=0.2,
             robot_position_uncertainty=0.01, intrusion_distance=0.1, human_speed=1.0)
"""S_p = S_h + S_r + S_s + C + Z_d + Z_r = 1.0 * 0.4 + 1.0 * 0.1 + 0.2 + 0.1 + Z_d + 0.01
= 0.81 m + Z_d."""
BASE = 0.81


@dataclass(frozen=True)
class FakeEstimate:
    """Stands in for kfusion.tracker.Estimate: t, status, position and a bound."""

    t: float
    status: str
    position: tuple[float, float, float]
    radius: float

    def bound(self, confidence: float = 0.99) -> float:
        return math.inf if self.status == LOST else self.radius


def test_hand_derived_margins_and_the_binding_body():
    estimates = {
        "near": FakeEstimate(0.0, TRACKED, (0.0, 0.0, 2.0), 0.5),   # 2 - (0.81 + 0.5) = 0.69
        "far": FakeEstimate(0.0, BRIDGED, (3.0, 4.0, 0.0), 0.02),   # 5 - 0.83 = 4.17
        "wide": FakeEstimate(0.0, BRIDGED, (0.0, 1.6, 0.0), 0.2),   # 1.6 - 1.01 = 0.59
    }
    result = binding_body([0.0, 0.0, 0.0], estimates, **ROBOT)
    assert result.known and result.reason == "" and result.unknown_bodies == ()
    assert result.body == "wide"  # not the nearest body: its bound is larger
    assert result.margin == pytest.approx(0.59, abs=1e-12)
    assert result.distance == pytest.approx(1.6, abs=1e-15)
    assert result.separation is not None
    assert result.separation.value == pytest.approx(BASE + 0.2, abs=1e-12)
    assert dict(result.margins) == pytest.approx({"near": 0.69, "far": 4.17, "wide": 0.59},
                                                 abs=1e-12)
    assert result.permits()
    # the robot moves next to "far": 5 m -> 0.5 m from it, margin 0.5 - 0.83 < 0
    result = binding_body([3.0, 3.5, 0.0], estimates, **ROBOT)
    assert result.body == "far" and result.margin == pytest.approx(-0.33, abs=1e-12)
    assert not result.permits()


def test_any_lost_body_makes_the_result_unknown():
    estimates = {"left": FakeEstimate(0.0, TRACKED, (0.0, 0.0, 5.0), 0.01),
                 "right": FakeEstimate(0.0, LOST, (math.nan,) * 3, math.inf)}
    result = binding_body([0.0, 0.0, 0.0], estimates, **ROBOT)
    assert not result.known and result.body is None and result.separation is None
    assert result.margin == -math.inf and math.isnan(result.distance)
    assert result.unknown_bodies == ("right",) and "'right'" in result.reason
    assert not result.permits()
    assert not result.margin >= 0  # a caller that only compares still gets "not safe"
    assert result.margins["left"] == pytest.approx(5.0 - BASE - 0.01)
    empty = binding_body([0.0, 0.0, 0.0], {}, **ROBOT)
    assert not empty.known and empty.margin == -math.inf and "no body estimates" in empty.reason
    # no usable bound (the baseline's) is unknown as well
    baseline = {"left": BodyEstimate(t=0.0, position=np.zeros(3), std=np.full(3, np.nan),
                                     status=TRACKED)}
    assert not binding_body([1.0, 0.0, 0.0], baseline, **ROBOT).known


def test_body_estimate_bound_is_the_chi_square_radius_of_its_largest_sigma():
    estimate = BodyEstimate(t=1.0, position=np.array([1.0, 0.0, 0.0]),
                            std=np.array([0.01, 0.03, 0.02]), status=BRIDGED)
    expected = 0.03 * math.sqrt(chi2.ppf(0.95, 3))
    assert estimate.bound(0.95) == pytest.approx(expected, rel=1e-12)
    result = binding_body([4.0, 0.0, 0.0], {"only": estimate}, confidence=0.95, **ROBOT)
    assert result.margin == pytest.approx(3.0 - BASE - expected, abs=1e-12)


def test_bad_arguments_raise_value_error_naming_them():
    estimates = {"a": FakeEstimate(0.0, TRACKED, (1.0, 0.0, 0.0), 0.1)}
    with pytest.raises(ValueError, match=r"robot_position: expected 3 finite numbers \(m\), "
                       r"got shape \(2,\)"):
        binding_body([0.0, 0.0], estimates, **ROBOT)
    with pytest.raises(ValueError, match=r"got shape \(3,\) \[0.0, nan, 0.0\]"):
        binding_body([0.0, math.nan, 0.0], estimates, **ROBOT)
    with pytest.raises(ValueError, match=r"estimates\['b'\]: expected an estimate with t, status"):
        binding_body([0.0, 0.0, 0.0], {"b": 0.1}, **ROBOT)  # type: ignore[dict-item]
    with pytest.raises(ValueError, match="robot_speed: expected a finite number >= 0"):
        binding_body([0.0, 0.0, 0.0], estimates, **{**ROBOT, "robot_speed": -1.0})



def test_tracker_estimates_of_two_forearms():
    """Two Tracker instances at rest fed mocap fixes: the margin of each is |robot - p| - S_p of
    its Estimate; a third never fed fixes is lost, and so are both once the streams stop: the
    result is unknown."""
    from kfusion import Tracker

    def tracker_at(position, fixes: bool) -> Tracker:
        tracker = Tracker(imu_to_body=[1, 0, 0, 0], gravity=[0, -9.81, 0])
        for i in range(201):  # 1 s at rest: 200 Hz IMU, 100 Hz mocap
            t = i / 200
            tracker.push_imu(t, [0.0, 9.81, 0.0], [0.0, 0.0, 0.0])
            if fixes and i % 2 == 0:  # 20 um of noise: a repeated pose is no measurement
                tracker.push_mocap(t, np.asarray(position) + 2e-5 * np.sin(
                    t * 100.0 * np.array([1.0, 1.7, 2.3])), [1.0, 0.0, 0.0, 0.0])
        return tracker

    left = tracker_at([0.5, 1.2, 0.3], fixes=True)
    right = tracker_at([-0.4, 1.1, 0.3], fixes=True)
    now = 1.01
    estimates = {"left": left.estimate(now), "right": right.estimate(now)}
    assert {estimate.status for estimate in estimates.values()} <= {TRACKED, BRIDGED}
    result = binding_body([2.0, 1.0, 0.3], estimates, now=now, **ROBOT)
    expected = {name: float(np.linalg.norm(np.array([2.0, 1.0, 0.3]) - estimate.position))
                - protective_separation_distance(estimate, now=now, **ROBOT).value
                for name, estimate in estimates.items()}
    assert result.body == "left" and result.known
    assert dict(result.margins) == pytest.approx(expected, abs=1e-12)
    # 0.5 s after both streams stopped nothing is dead-reckoned: both lost, so unknown
    later = binding_body([2.0, 1.0, 0.3], {name: tracker.estimate(now + 0.5) for name, tracker
                                           in (("left", left), ("right", right))},
                         now=now + 0.5, **ROBOT)
    assert not later.known and later.unknown_bodies == ("left", "right")
    assert later.margin == -math.inf and not later.permits()
    estimates["right"] = tracker_at([-0.4, 1.1, 0.3], fixes=False).estimate(now)
    assert estimates["right"].status == LOST
    unknown = binding_body([2.0, 1.0, 0.3], estimates, now=now, **ROBOT)
    assert not unknown.known and unknown.unknown_bodies == ("right",)

body_states = st.tuples(
    st.tuples(*[st.floats(-5, 5, allow_nan=False)] * 3),
    st.floats(0.0, 1.0, allow_nan=False),
    st.sampled_from([TRACKED, BRIDGED, BRIDGED, TRACKED, LOST]))


@settings(max_examples=200, deadline=None)
@given(robot=st.tuples(*[st.floats(-5, 5, allow_nan=False)] * 3),
       states=st.lists(body_states, min_size=1, max_size=5))
def test_binding_body_minimises_the_margin_and_any_lost_body_is_unknown(robot, states):
    estimates = {f"body{i}": FakeEstimate(0.0, status, position, radius)
                 for i, (position, radius, status) in enumerate(states)}
    result = binding_body(robot, estimates, **ROBOT)
    if any(status == LOST for _, _, status in states):
        assert not result.known and result.margin == -math.inf and result.body is None
        assert set(result.unknown_bodies) == {name for name, estimate in estimates.items()
                                              if estimate.status == LOST}
        return
    expected = {name: math.dist(robot, estimate.position) - BASE - estimate.radius
                for name, estimate in estimates.items()}
    assert result.known and result.body is not None
    assert result.margin == pytest.approx(min(expected.values()), abs=1e-12)
    assert result.margin == pytest.approx(expected[result.body], abs=1e-12)
    assert all(result.margin <= margin + 1e-12 for margin in expected.values())


# ------------------------------------------------------------------------------------------
# batch over tracks
# ------------------------------------------------------------------------------------------


def two_tracks() -> dict[str, TrackResult]:
    t = np.array([0.0, 0.01, 0.02, 0.03])
    left = TrackResult(t=t, position=np.array([[1.0, 0, 0], [1.5, 0, 0], [2.0, 0, 0],
                                               [2.0, 0, 0]]),
                       std=np.full((4, 3), 0.01),
                       status=np.array([TRACKED, TRACKED, BRIDGED, TRACKED]),
                       time_since_fix=np.zeros(4))
    right = TrackResult(t=t, position=np.array([[0, 2.0, 0], [0, 1.2, 0], [0, 1.2, 0],
                                                [0, 1.0, 0]]),
                        std=np.array([[0.01] * 3, [0.01] * 3, [0.01] * 3, [0.01] * 3]),
                        status=np.array([TRACKED, BRIDGED, TRACKED, LOST]),
                        time_since_fix=np.zeros(4))
    return {"left": left, "right": right}


def test_batch_over_tracks_is_the_single_helper_row_by_row():
    tracks = two_tracks()
    margins = binding_margins([0.0, 0.0, 0.0], tracks, **ROBOT)
    bound = 0.01 * math.sqrt(chi2.ppf(0.99, 3))
    np.testing.assert_array_equal(margins.body, ["left", "right", "right", ""])
    np.testing.assert_array_equal(margins.known, [True, True, True, False])
    np.testing.assert_allclose(margins.margin[:3], np.array([1.0, 1.2, 1.2]) - BASE - bound,
                               atol=1e-12)
    assert margins.margin[3] == -math.inf and margins.names == ("left", "right")
    robot = np.array([[0.0, 0, 0], [0.0, 0, 0], [1.9, 0, 0], [0.0, 0, 0]])
    moving = binding_margins(robot, tracks, **ROBOT)
    assert moving.body[2] == "left"
    assert moving.margin[2] == pytest.approx(0.1 - BASE - bound, abs=1e-12)


def test_batch_refuses_tracks_on_different_times():
    tracks = two_tracks()
    shifted = tracks["right"]
    tracks["right"] = TrackResult(t=shifted.t + 0.005, position=shifted.position,
                                  std=shifted.std, status=shifted.status,
                                  time_since_fix=shifted.time_since_fix)
    with pytest.raises(ValueError, match="track 'right' has 4 rows .* expected the times of "
                       "track 'left'"):
        binding_margins([0.0, 0.0, 0.0], tracks, **ROBOT)
    with pytest.raises(ValueError, match=r"expected shape \(3,\) or \(4, 3\)"):
        binding_margins(np.zeros((2, 3)), two_tracks(), **ROBOT)
    with pytest.raises(ValueError, match="expected at least one body's track"):
        binding_margins([0.0, 0.0, 0.0], {}, **ROBOT)
    with pytest.raises(ValueError, match="'now' is not accepted; each row is used at its own t"):
        binding_margins([0.0, 0.0, 0.0], two_tracks(), now=1.0, **ROBOT)


def test_separation_is_the_existing_iso_composition():
    estimate = FakeEstimate(0.0, TRACKED, (0.0, 3.0, 0.0), 0.04)
    options = dict(robot_speed=0.5, reaction_time=0.1, stopping_time=0.2, stopping_distance=0.1,
                   robot_position_uncertainty=0.005)
    result = binding_body([0.0, 0.0, 0.0], {"a": estimate}, **options)
    expected = 3.0 - protective_separation_distance(estimate, **options).value
    assert result.margin == pytest.approx(expected, abs=1e-15)


# ------------------------------------------------------------------------------------------
# README
# ------------------------------------------------------------------------------------------


def test_readme_several_bodies_examples_run(tmp_path, monkeypatch, capsys):
    text = README.read_text(encoding="utf-8")
    section = text.split("\n## Several bodies\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.DOTALL)
    assert len(blocks) == 2
    monkeypatch.chdir(tmp_path)
    (tmp_path / "tracks").mkdir()
    for name, track in two_tracks().items():  # what `kfusion track bodies/ --out tracks/` writes
        write_track_csv(track, tmp_path / "tracks" / f"{name}.csv")
    namespace: dict = {}
    for index, block in enumerate(blocks):
        exec(compile(block, f"README.md (Several bodies, example {index + 1})", "exec"),
             namespace)
    # the first example prints what its comments show (0.200 m: see the hand derivation in
    # test_readme_margin_by_hand); the robot is outside S_p, so nothing else is printed
    comments = [line.split("# ", 1)[1] for line in blocks[0].splitlines()
                if line.startswith("print(") and "# " in line]
    assert capsys.readouterr().out.splitlines()[:2] == comments
    assert namespace["result"].known and not namespace["lost"].known
    assert namespace["margins"].names == ("left", "right")
    assert (tmp_path / "margins.png").stat().st_size > 0


def test_readme_margin_by_hand():
    # The README's left forearm: robot at (2.5, 1.0, 0.3), body at (0.5, 1.2, 0.3):
    # |d| = sqrt(2^2 + 0.2^2) = sqrt(4.04). S_p with the ISO 13855 rule: T = 0.1 + 0.3 = 0.4 s,
    # 2.0 * 0.4 + 0.85 = 1.65 > 0.5 -> S_h + C = 1.6 * 0.4 + 0.85 = 1.49; S_r = 0.1, S_s = 0.2,
    # Z_r = 0.01, Z_d = 0.003 * sqrt(chi2_3(0.99)) (its largest sigma).
    z_d = 0.003 * math.sqrt(chi2.ppf(0.99, 3))
    expected = math.sqrt(4.04) - (1.49 + 0.1 + 0.2 + 0.01 + z_d)
    left = BodyEstimate(t=2.0, position=np.array([0.5, 1.2, 0.3]),
                        std=np.array([0.002, 0.002, 0.003]), status=BRIDGED)
    result = binding_body([2.5, 1.0, 0.3], {"left": left},
                          robot_speed=1.0, reaction_time=0.1, stopping_time=0.3,
                          stopping_distance=0.2, robot_position_uncertainty=0.01)
    assert result.margin == pytest.approx(expected, abs=1e-12)
    assert f"{expected:.3f}" == "0.200"

def test_margin_figure_draws_each_binding_body_and_shades_the_unknown_rows():
    from kfusion.plots import binding_margin_figure

    margins = binding_margins([0.0, 0.0, 0.0], two_tracks(), **ROBOT)
    figure = binding_margin_figure(margins)
    ax = figure.axes[0]
    drawn = {line.get_label(): line.get_ydata() for line in ax.lines}
    np.testing.assert_array_equal(np.isfinite(drawn["left binds"]), [True, False, False, False])
    np.testing.assert_array_equal(np.isfinite(drawn["right binds"]), [False, True, True, False])
    spans = [(patch.get_x(), patch.get_x() + patch.get_width()) for patch in ax.patches]
    assert spans == [pytest.approx((0.03, 0.04))]  # the last row, where "right" is lost
    assert "(m)" in ax.get_ylabel()


# ------------------------------------------------------------------------------------------
# real data: the bundled BROAD excerpt as two bodies
# ------------------------------------------------------------------------------------------

SHIFT = np.array([0.25, 0.0, 0.0])
"""m: the second body is the excerpt's forearm moved 0.25 m along x (same IMU)."""


def test_real_excerpt_as_two_bodies_tracks_and_binds_as_derived(tmp_path, capsys):
    """BROAD trial 21's excerpt as body "near", and a copy moved 0.25 m towards the robot with a
    1.5 s occlusion (longer than max_bridge_s = 1 s) as body "shifted": the CLI tracks both, and
    the batch margin's binding body and unknown rows match a direct numpy derivation."""
    import shutil

    import pandas as pd

    from kfusion.datasets import broad_excerpt

    folder = tmp_path / "bodies"
    shutil.copytree(broad_excerpt(), folder / "near")
    shutil.copytree(broad_excerpt(), folder / "shifted")
    mocap = pd.read_csv(folder / "shifted" / "mocap.csv")
    mocap[["x", "y", "z"]] += SHIFT
    gap = (mocap["t"] > mocap["t"].iloc[0] + 10.0) & (mocap["t"] < mocap["t"].iloc[0] + 11.5)
    mocap.loc[gap, ["x", "y", "z", "qw", "qx", "qy", "qz"]] = np.nan
    mocap.to_csv(folder / "shifted" / "mocap.csv", index=False, na_rep="")
    out = tmp_path / "tracks"
    assert main(["track", str(folder), "--out", str(out)]) == 0
    assert "2 of 2 bodies tracked" in capsys.readouterr().out
    tracks = read_body_tracks(out)
    lost = {name: track.status == LOST for name, track in tracks.items()}
    assert lost["shifted"].sum() > 0 and not lost["near"].any()

    robot = np.array([2.0, -0.4, 1.9])  # on the +x side: "shifted" is the nearer body
    margins = binding_margins(robot, tracks, **ROBOT)
    radius = {name: np.max(track.std, axis=1) * math.sqrt(chi2.ppf(0.99, 3))
              for name, track in tracks.items()}
    derived = {name: np.linalg.norm(track.position - robot, axis=1) - BASE - radius[name]
               for name, track in tracks.items()}
    unknown = lost["near"] | lost["shifted"]
    np.testing.assert_array_equal(margins.known, ~unknown)
    expected = np.where(derived["shifted"] <= derived["near"], "shifted", "near")
    np.testing.assert_array_equal(margins.body[~unknown], expected[~unknown])
    np.testing.assert_allclose(margins.margin[~unknown],
                               np.minimum(derived["near"], derived["shifted"])[~unknown],
                               atol=1e-12, rtol=0)
    assert (margins.margin[unknown] == -math.inf).all()
    assert (margins.body == "shifted").mean() > 0.9


def test_binding_body_refuses_bad_estimates_and_ages_older_ones():
    """A status typo, a NaN time or a negative sigma is refused naming the body; without ``now``
    the newest t is now, so an estimate 100 s old is aged (its S_p grows), not used as current."""
    good = BodyEstimate(t=0.0, position=np.zeros(3), std=np.full(3, 1e-3), status=TRACKED)
    robot = [1.0, 0.0, 0.0]
    bad = {"status 'Lost' is not one of": dataclasses.replace(good, status="Lost"),
           "status '' is not one of": dataclasses.replace(good, status=""),
           r"t = nan s": dataclasses.replace(good, t=math.nan),
           "negative sigma": dataclasses.replace(good, std=np.full(3, -0.5))}
    for message, estimate in bad.items():
        with pytest.raises(ValueError, match=r"estimates\['right'\]: .*" + message):
            binding_body(robot, {"left": good, "right": estimate}, **ROBOT)
    old = dataclasses.replace(good, t=-100.0)
    implicit = binding_body(robot, {"left": good, "right": old}, **ROBOT)
    explicit = binding_body(robot, {"left": good, "right": old}, now=0.0, **ROBOT)
    assert implicit.body == "right" and implicit.margin == explicit.margin
    assert implicit.margins["left"] == pytest.approx(
        binding_body(robot, {"left": good}, **ROBOT).margin, abs=1e-15)
    assert implicit.margin < implicit.margins["left"] - 100.0  # 100 s of human and robot motion


def test_a_failed_body_s_old_output_is_removed_and_the_failure_says_so(tmp_path, capsys):
    """A body that failed on this run must not leave an earlier run's BODY.csv behind as if it
    were current; the one that succeeded keeps its file."""
    folders = [tmp_path / "L", tmp_path / "R"]
    out = tmp_path / "tracks"
    out.mkdir()
    for folder in folders:
        (out / f"{folder.name}.csv").write_text("old\n")

    def action(folder: Path) -> str:
        if folder.name == "R":
            raise ValueError("R: bad mount")
        return f"body {folder.name}: ok"

    failures = for_each_body(folders, action, description="test", progress=False,
                             output=lambda folder: out / f"{folder.name}.csv")
    assert [failure.body for failure in failures] == ["R"]
    assert f"removed its out-of-date {out / 'R.csv'}" in failures[0].reason
    assert not (out / "R.csv").exists() and (out / "L.csv").exists()
    assert "removed its out-of-date" in capsys.readouterr().err
