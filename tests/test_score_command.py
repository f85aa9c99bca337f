"""``kfusion score TRACK.csv TRUTH``: gap errors against a truth file, checked by hand and
against the scoring the experiments use (kfusion.evaluate)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from kfusion.cli import main
from kfusion.evaluate import gap_metrics
from kfusion.simulate import OcclusionSpec, simulate
from kfusion.simulate.files import write_simulation
from kfusion.track_file import read_track

TRACK_HEADER = "t,x,y,z,std_x,std_y,std_z,status"
TRUTH_HEADER = "t,x,y,z,occluded"


def score(capsys, *arguments: str) -> tuple[int, str, str]:
    status = main(["score", *arguments])
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def write_lines(path, *lines: str):
    path.write_text("\n".join(lines) + "\n")
    return path


def test_hand_computed_gap_errors(tmp_path, capsys):
    # Truth at the origin; gap rows 1-4 err by 1, 2, 3, 4 mm along x, std 1 mm; row 5 is lost.
    track = write_lines(tmp_path / "track.csv", TRACK_HEADER,
                        "0.0,0.0,0.0,0.0,0.001,0.001,0.001,tracked",
                        "0.01,0.001,0.0,0.0,0.001,0.001,0.001,bridged",
                        "0.02,0.002,0.0,0.0,0.001,0.001,0.001,bridged",
                        "0.03,-0.003,0.0,0.0,0.001,0.001,0.001,bridged",
                        "0.04,0.004,0.0,0.0,0.001,0.001,0.001,bridged",
                        "0.05,,,,,,,lost")
    truth = write_lines(tmp_path / "reference.csv", TRUTH_HEADER, "0.0,0,0,0,0",
                        "0.01,0,0,0,1", "0.02,0,0,0,1", "0.03,0,0,0,1", "0.04,0,0,0,1",
                        "0.05,0,0,0,1")
    status, out, err = score(capsys, str(track), str(truth))
    assert (status, err) == (0, "")
    assert "gap samples: 4 scored, 1 lost (of 5 occluded rows; 6 track rows)" in out
    # rms = sqrt((1 + 4 + 9 + 16) / 4) = 2.74; p95 of [1, 2, 3, 4] = 3 + 0.85 (4 - 3) = 3.85
    assert "rms 2.74 mm, max 4.00 mm, p95 3.85 mm" in out
    assert "coverage 3-sigma: 75.0 % of scored gap samples" in out  # 4 mm > 3 sigma


def test_folder_form_agrees_with_the_experiment_scoring(tmp_path, capsys):
    simulation = simulate("arm_lift", seed=3, duration=10.0,
                          occlusions=OcclusionSpec(gap_range=(0.1, 0.3)))
    folder = write_simulation(simulation, tmp_path / "rec")
    assert main(["track", str(folder), "--method", "kalman", "--out",
                 str(tmp_path / "track.csv")]) == 0
    capsys.readouterr()
    status, out, _ = score(capsys, str(tmp_path / "track.csv"), str(folder))
    assert status == 0
    expected = gap_metrics(read_track(tmp_path / "track.csv"), simulation.truth.position,
                           simulation.truth.occluded)
    assert expected["samples"] > 50
    assert f"gap samples: {int(expected['samples'])} scored" in out
    assert f"rms {expected['rms_mm']:.2f} mm, max {expected['max_mm']:.2f} mm" in out
    assert f"coverage 3-sigma: {100 * expected['coverage_3sigma']:.1f} %" in out


def test_baseline_track_has_no_coverage(tmp_path, capsys):
    track = write_lines(tmp_path / "track.csv", TRACK_HEADER, "0.0,0,0,0,,,,tracked",
                        "0.01,0.002,0,0,,,,bridged")
    truth = write_lines(tmp_path / "truth.csv", TRUTH_HEADER, "0.0,0,0,0,0", "0.01,0,0,0,1")
    status, out, _ = score(capsys, str(track), str(tmp_path))
    assert status == 0 and "rms 2.00 mm" in out and "n/a (the track has no std columns)" in out
    assert truth.is_file()


@pytest.mark.parametrize(("track_rows", "truth_rows", "pattern"), [
    (["0.0,0,0,0,,,,tracked"], ["0.0,0,0,0,0", "0.5,0,0,0,1"],
     r"^kfusion score: error: truth\.csv, row 2 \(line 3\), column 't': t = 0\.5 s has no "
     r"track row within 1e-06 s; "
     r"expected the track of the same recording"),
    (["0.0,0,0,0,,,,tracking"], ["0.0,0,0,0,0"],
     r"^kfusion score: error: track\.csv, row 1 \(line 2\), column 'status': expected one of "
     r"\['tracked', 'bridged', 'lost'\], got 'tracking'"),
    (["0.0,0,zero,0,,,,tracked"], ["0.0,0,0,0,0"],
     r"^kfusion score: error: track\.csv, row 1 \(line 2\), column 'y': expected a number, "
     r"got 'zero'"),
    (["0.0,0,0,0,,,,tracked"], ["0.0,0,0,0,2"],
     r"^kfusion score: error: truth\.csv, row 1 \(line 2\), column 'occluded': expected 0 "
     r"or 1, got 2$"),
])
def test_mistakes_are_one_line(tmp_path, capsys, track_rows, truth_rows, pattern):
    track = write_lines(tmp_path / "track.csv", TRACK_HEADER, *track_rows)
    write_lines(tmp_path / "truth.csv", TRUTH_HEADER, *truth_rows)
    status, out, err = score(capsys, str(track), str(tmp_path / "truth.csv"))
    assert status == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and re.search(pattern, err), err


def test_missing_truth_names_what_is_expected(tmp_path, capsys):
    track = write_lines(tmp_path / "track.csv", TRACK_HEADER, "0.0,0,0,0,,,,tracked")
    status, _, err = score(capsys, str(track), str(tmp_path))
    assert status == 2 and "truth.csv: file not found; expected a truth CSV" in err


def test_score_needs_no_numerical_library_to_list_itself():
    assert np.isfinite(1.0)  # the command module imports numpy only inside run()
    from kfusion.cli import command_specs
    assert "score" in [spec.name for spec in command_specs()]
