"""``kfusion track`` writes the documented CSV for every method, one row per mocap row."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from kfusion.cli import main
from kfusion.conventions import LOST, STATUSES, TRACK_COLUMNS
from kfusion.methods import METHODS
from kfusion.recording import read_recording
from kfusion.simulate import OcclusionSpec, simulate, write_simulation


@pytest.fixture(scope="module")
def recording_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("recording")
    simulation = simulate("arm_lift", seed=4, duration=12.0,
                          occlusions=OcclusionSpec(gap_range=(0.1, 0.3), spacing=1.5))
    write_simulation(simulation, folder)
    return folder


@pytest.mark.parametrize("method", sorted(METHODS))
def test_track_writes_one_row_per_mocap_row(method, recording_folder, tmp_path, capsys):
    out = tmp_path / "track.csv"
    assert main(["track", str(recording_folder), "--method", method, "--out", str(out)]) == 0
    assert f"{method}: wrote" in capsys.readouterr().out
    table = pd.read_csv(out, keep_default_na=True)
    mocap = read_recording(recording_folder).mocap
    assert list(table.columns) == list(TRACK_COLUMNS)
    np.testing.assert_array_equal(table["t"].to_numpy(), mocap.t)
    assert set(table["status"]) <= set(STATUSES)
    lost = table["status"] == LOST
    assert table.loc[~lost, ["x", "y", "z"]].notna().all().all()
    assert table.loc[lost, ["x", "y", "z"]].isna().all().all()
    # rows with a mocap fix that was used echo (baseline) or closely follow (filters) the fix
    tracked = (table["status"] == "tracked").to_numpy()
    assert tracked.sum() > 0.5 * len(table)
    error = table.loc[tracked, ["x", "y", "z"]].to_numpy() - mocap.position[tracked]
    assert np.abs(error).max() < 0.005
    std_filled = table.loc[~lost, ["std_x", "std_y", "std_z"]].notna().all().all()
    assert std_filled == (method != "baseline")


def test_track_rejects_unknown_option(recording_folder, tmp_path, capsys):
    status = main(["track", str(recording_folder), "--method", "kalman", "--out",
                   str(tmp_path / "x.csv"), "--set", "no_such_parameter=1"])
    assert status == 2
    assert "no_such_parameter" in capsys.readouterr().err


def test_track_rejects_malformed_option(recording_folder, tmp_path, capsys):
    status = main(["track", str(recording_folder), "--out", str(tmp_path / "x.csv"),
                   "--set", "max_bridge_s"])
    assert status == 2
    assert "--set: expected KEY=VALUE, got 'max_bridge_s'" in capsys.readouterr().err


def test_lost_rows_carry_no_estimate_in_memory():
    from kfusion.track_file import TrackResult

    result = TrackResult(t=np.array([0.0, 0.01]), position=np.ones((2, 3)), std=np.ones((2, 3)),
                         status=np.array(["tracked", LOST]), time_since_fix=np.zeros(2))
    assert np.isfinite(result.position[0]).all() and np.isnan(result.position[1]).all()
    assert np.isnan(result.std[1]).all()
