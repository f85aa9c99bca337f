"""kfusion check's marker step (kfusion.calibration.marker_fit): markers.csv against
recording.yaml's markers: and mocap.csv's rigid body."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from kfusion.calibration.diagnosis import diagnose
from kfusion.calibration.marker_fit import (
    body_frame_offsets,
    marker_problem,
    windowed_medians,
)
from kfusion.simulate import MarkerSpec, simulate


@pytest.fixture(scope="module")
def recording():
    return simulate("random_reach", seed=0, duration=12.0, markers=MarkerSpec()).recording


def _with_body(recording, name, delta):
    markers = dict(recording.info.markers)
    markers[name] = markers[name] + np.asarray(delta)
    return dataclasses.replace(recording, info=dataclasses.replace(recording.info,
                                                                   markers=markers))


def _with_markers(recording, position):
    return dataclasses.replace(recording, markers=dataclasses.replace(recording.markers,
                                                                      position=position))


def test_offsets_by_hand(recording):
    # the rigid body's own frame: a marker exactly where markers: says has offset 0, and one
    # moved 3 mm along body x (whatever the orientation) has offset (3 mm, 0, 0)
    t, offsets = body_frame_offsets(recording)
    assert np.nanmax(np.abs(np.nanmedian(offsets, axis=0))) < 2e-4
    moved = _with_body(recording, "M1", [-0.003, 0.0, 0.0])
    t, offsets = body_frame_offsets(moved)
    column = recording.markers.names.index("M1")
    np.testing.assert_allclose(np.nanmedian(offsets[:, column], axis=0), [0.003, 0, 0],
                               atol=2e-4)
    starts, medians = windowed_medians(t, offsets[:, [column]], window_s=4.0, min_frames=20)
    full = np.isfinite(medians[:, 0, 0])
    assert full.sum() >= 3 and np.all(np.abs(medians[full, 0, 0] - 0.003) < 3e-4)


def test_a_clean_recording_passes(recording):
    assert marker_problem(recording) is None
    assert diagnose(recording).ok


def test_a_wrong_body_position_is_refused(recording):
    problem = marker_problem(_with_body(recording, "M2", [0.0, 0.008, 0.0]))
    assert problem is not None
    assert re.match(r"markers.csv: marker .M2. is (7.9|8.0|8.1) mm", problem)
    assert not diagnose(_with_body(recording, "M2", [0.0, 0.008, 0.0])).ok


def test_a_loose_marker_is_refused(recording):
    position = np.array(recording.markers.position)
    fraction = (recording.markers.t - recording.markers.t[0]) / np.ptp(recording.markers.t)
    position[:, 0, 0] += 0.005 * fraction
    problem = marker_problem(_with_markers(recording, position))
    assert problem is not None and "moves against the rigid body by up to" in problem


def test_labels_swapped_for_good_are_named_and_a_short_swap_is_left_to_the_filter(recording):
    names = recording.markers.names
    position = np.array(recording.markers.position)
    position[:, [0, 1]] = position[:, [1, 0]]
    problem = marker_problem(_with_markers(recording, position))
    assert problem is not None and f"sits where recording.yaml puts {names[1]!r}" in problem
    position = np.array(recording.markers.position)
    brief = (recording.markers.t >= 5.0) & (recording.markers.t < 6.0)
    position[brief, 0], position[brief, 1] = (recording.markers.position[brief, 1],
                                              recording.markers.position[brief, 0])
    assert marker_problem(_with_markers(recording, position)) is None


def test_a_mocap_with_no_visible_frame_is_named():
    recording = simulate("random_reach", seed=0, duration=5.0).recording
    mocap = recording.mocap
    hidden = dataclasses.replace(mocap, position=np.full(mocap.position.shape, np.nan))
    diagnosis = diagnose(recording.with_mocap(hidden))
    assert diagnosis.problems[0].startswith("mocap.csv has no visible (solved) frame")


def test_body_frame_positions_ignore_a_label_swapped_for_a_while(recording):
    # M1/M2 swapped in 10 % of the frames: a plain mean put both 8 mm off
    from kfusion.rigid_body import markers_in_body_frame

    position = np.array(recording.markers.position)
    rows = (recording.markers.t >= 5.0) & (recording.markers.t < 6.2)
    position[rows, 0], position[rows, 1] = (recording.markers.position[rows, 1],
                                            recording.markers.position[rows, 0])
    swapped = _with_markers(recording, position)
    body = markers_in_body_frame(swapped.mocap, swapped.markers)
    expected = np.array([recording.info.markers[name] for name in recording.markers.names])
    assert np.max(np.linalg.norm(body.positions - expected, axis=1)) < 3e-4
    assert np.max(body.spread) < 2e-3
