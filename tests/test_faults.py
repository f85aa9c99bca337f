"""Fault injection (kfusion.simulate.faults): each fault changes what it says and nothing else."""

from __future__ import annotations

import numpy as np
import pytest

from kfusion.conventions import matrix_from_wxyz
from kfusion.recording import occlusion_runs
from kfusion.simulate import OcclusionSpec, simulate
from kfusion.simulate import faults as fault
from kfusion.simulate.faults import Streams


@pytest.fixture(scope="module")
def streams():
    simulation = simulate("random_reach", seed=2, duration=10.0,
                          occlusions=OcclusionSpec(gap_range=(0.4, 0.6), spacing=1.5))
    return Streams.of(simulation.recording)


def test_streams_arrive_at_their_stamps_in_order(streams):
    events = streams.events()
    assert len(events) == len(streams.recording.imu) + len(streams.recording.mocap)
    arrivals = [event[0] for event in events]
    assert arrivals == sorted(arrivals)
    # at equal times the IMU sample comes first
    same = [(a, b) for a, b in zip(events, events[1:], strict=False) if a[0] == b[0]]
    assert same and all(a[1] == 0 and b[1] == 1 for a, b in same)


def test_imu_faults_change_only_the_imu(streams):
    silent = fault.imu_silent(streams)
    assert len(silent.recording.imu) == 0 and len(silent.imu_arrival) == 0
    stopped = fault.imu_stops(streams, fraction=0.5)
    middle = 0.5 * (streams.recording.mocap.t[0] + streams.recording.mocap.t[-1])
    assert stopped.recording.imu.t.max() < middle <= streams.recording.imu.t.max()
    for changed in (silent, stopped):
        assert changed.recording.mocap is streams.recording.mocap


def test_imu_misses_three_tenths_inside_each_gap(streams):
    missing = fault.imu_misses_inside_gaps(streams, duration=0.3)
    kept = set(missing.recording.imu.t.tolist())
    dropped = np.array([t for t in streams.recording.imu.t if t not in kept])
    mocap = streams.recording.mocap
    runs = occlusion_runs(mocap.visible)
    assert len(runs) >= 2
    for start, stop in runs:
        inside = dropped[(dropped > mocap.t[start - 1]) & (dropped < mocap.t[stop])]
        # 0.3 s at 200 Hz: 59 or 60 samples strictly inside the window
        assert 58 <= len(inside) <= 60
        assert inside.max() - inside.min() <= 0.3
    assert len(dropped) == len(streams.recording.imu) - len(missing.recording.imu)


def test_clock_faults_change_stamps_not_arrival(streams):
    behind = fault.imu_clock_offset(streams, -0.137)
    np.testing.assert_allclose(behind.recording.imu.t, streams.recording.imu.t - 0.137)
    np.testing.assert_array_equal(behind.imu_arrival, streams.imu_arrival)
    milliseconds = fault.imu_time_in_milliseconds(streams)
    np.testing.assert_allclose(milliseconds.recording.imu.t, streams.recording.imu.t * 1000)
    future = fault.mocap_future_stamp(streams, ahead_s=1000.0)
    changed = np.flatnonzero(future.recording.mocap.t != streams.recording.mocap.t)
    assert len(changed) == 1 and streams.recording.mocap.visible[changed[0]]
    assert future.recording.mocap.t[changed[0]] - streams.recording.mocap.t[changed[0]] == \
        pytest.approx(1000.0)
    np.testing.assert_array_equal(future.mocap_arrival, streams.mocap_arrival)


def test_frames_stamped_ahead_keep_their_pose_and_arrival(streams):
    mocap = streams.recording.mocap
    one = fault.mocap_frame_stamped_ahead(streams, ahead_s=0.15, seed=3)
    changed = np.flatnonzero(one.recording.mocap.t != mocap.t)
    assert len(changed) == 1 and mocap.visible[changed[0]]
    assert one.recording.mocap.t[changed[0]] - mocap.t[changed[0]] == pytest.approx(0.15)
    # the pose is the frame's own (stale at its new stamp), it arrives at its true time: the
    # frames after it arrive stamped before it
    np.testing.assert_array_equal(one.recording.mocap.position, mocap.position)
    np.testing.assert_array_equal(one.mocap_arrival, streams.mocap_arrival)
    assert one.recording.imu is streams.recording.imu
    assert one.recording.mocap.t[changed[0] + 1] < one.recording.mocap.t[changed[0]]
    again = fault.mocap_frame_stamped_ahead(streams, ahead_s=0.15, seed=3)
    np.testing.assert_array_equal(again.recording.mocap.t, one.recording.mocap.t)
    several = fault.mocap_frame_stamped_ahead(streams, ahead_s=0.2, every_s=1.0)
    rows = np.flatnonzero(several.recording.mocap.t != mocap.t)
    duration = mocap.t[-1] - mocap.t[0]
    assert len(rows) == int(np.ceil((duration - 0.2) / 1.0))
    assert mocap.visible[rows].all() and (np.diff(mocap.t[rows]) > 0.2).all()
    with pytest.raises(ValueError, match="every_s"):
        fault.mocap_frame_stamped_ahead(streams, ahead_s=0.2, every_s=0.2)


def test_orientation_flip_is_a_half_turn_on_the_frame_before_each_gap(streams):
    flipped = fault.orientation_flip_before_gaps(streams)
    before = streams.recording.mocap.quaternion
    after = flipped.recording.mocap.quaternion
    rows = np.flatnonzero(~np.all(np.isclose(before, after) | np.isnan(before), axis=1))
    assert rows.tolist() == [start - 1 for start, _ in
                             occlusion_runs(streams.recording.mocap.visible) if start > 0]
    for row in rows:
        relative = matrix_from_wxyz(before[row]).T @ matrix_from_wxyz(after[row])
        np.testing.assert_allclose(relative, np.diag([1.0, -1.0, -1.0]), atol=1e-12)


def test_marker_swap_moves_visible_frames_for_one_second(streams):
    swapped = fault.marker_swap(streams, fraction=0.5, duration_s=1.0, offset=(0.2, 0, 0))
    mocap = streams.recording.mocap
    moved = np.flatnonzero(np.any(swapped.recording.mocap.position != mocap.position, axis=1)
                           & mocap.visible)
    assert 0.9 <= mocap.t[moved[-1]] - mocap.t[moved[0]] < 1.0
    np.testing.assert_allclose(swapped.recording.mocap.position[moved] - mocap.position[moved],
                               np.tile([0.2, 0.0, 0.0], (len(moved), 1)), atol=1e-12)


def test_metadata_and_column_order_faults(streams):
    info = streams.recording.info
    np.testing.assert_array_equal(fault.gravity_sign_flipped(streams).recording.info.gravity,
                                  -info.gravity)
    np.testing.assert_array_equal(fault.mount_identity(streams).recording.info.imu_to_body,
                                  [1.0, 0.0, 0.0, 0.0])
    xyzw = fault.quaternion_columns_xyzw(streams).recording.mocap.quaternion
    np.testing.assert_array_equal(xyzw[:, 3], streams.recording.mocap.quaternion[:, 0])
    np.testing.assert_array_equal(xyzw[:, :3], streams.recording.mocap.quaternion[:, 1:])


@pytest.mark.parametrize("side", ["before", "after"])
def test_occlusion_edge_offsets_shift_the_frames_next_to_each_gap(streams, side):
    shifted = fault.occlusion_edge_offsets(streams, size_m=0.0015, frames=3, side=side)
    mocap = streams.recording.mocap
    difference = shifted.recording.mocap.position - mocap.position
    moved = np.flatnonzero(np.any(np.nan_to_num(difference) != 0.0, axis=1))
    runs = occlusion_runs(mocap.visible)
    expected = [row for start, stop in runs
                for row in (range(start - 3, start) if side == "before" else range(stop, stop + 3))
                if 0 <= row < len(mocap)]
    assert moved.tolist() == expected
    for start, stop in runs:  # one shift of 1.5 mm per occlusion, the same on its 3 frames
        rows = range(start - 3, start) if side == "before" else range(stop, stop + 3)
        block = difference[list(rows)]
        np.testing.assert_allclose(np.linalg.norm(block, axis=1), 0.0015, rtol=1e-9)
        np.testing.assert_allclose(block, np.tile(block[0], (3, 1)), atol=1e-15)
    np.testing.assert_array_equal(shifted.recording.mocap.quaternion, mocap.quaternion)
    with pytest.raises(ValueError, match="side: expected 'before' or 'after'"):
        fault.occlusion_edge_offsets(streams, side="during")


def test_occlusion_edge_drift_ramps_to_its_size(streams):
    drifted = fault.occlusion_edge_drift(streams, size_m=0.002, frames=5)
    mocap = streams.recording.mocap
    for start, _ in occlusion_runs(mocap.visible):
        block = (drifted.recording.mocap.position - mocap.position)[start - 5:start]
        # frame i of 5 is i/5 of the way to 2 mm, along one direction
        np.testing.assert_allclose(np.linalg.norm(block, axis=1),
                                   [0.0004, 0.0008, 0.0012, 0.0016, 0.002], rtol=1e-9)
        np.testing.assert_allclose(block / np.linalg.norm(block, axis=1)[:, None],
                                   np.tile(block[-1] / 0.002, (5, 1)), atol=1e-12)


def test_imu_rate_drops_keeps_every_eighth_sample_from_halfway(streams):
    dropped = fault.imu_rate_drops(streams, keep_every=8, fraction=0.5)
    imu = streams.recording.imu
    middle = 0.5 * (streams.recording.mocap.t[0] + streams.recording.mocap.t[-1])
    early, late = imu.t < middle, imu.t >= middle
    kept = dropped.recording.imu.t
    np.testing.assert_array_equal(kept[kept < middle], imu.t[early])
    np.testing.assert_array_equal(kept[kept >= middle], imu.t[late][::8])
    # 200 Hz becomes 25 Hz: every interval after the first late sample is 40 ms
    np.testing.assert_allclose(np.diff(kept[kept >= middle]), 0.04, atol=1e-9)
    assert dropped.recording.mocap is streams.recording.mocap


def test_mocap_holds_last_pose_fills_every_occlusion_forward(streams):
    held = fault.mocap_holds_last_pose(streams)
    mocap = streams.recording.mocap
    assert held.recording.mocap.visible.all()
    for start, stop in occlusion_runs(mocap.visible):
        for row in range(start, stop):
            np.testing.assert_array_equal(held.recording.mocap.position[row],
                                          mocap.position[start - 1])
            np.testing.assert_array_equal(held.recording.mocap.quaternion[row],
                                          mocap.quaternion[start - 1])
    visible = mocap.visible
    np.testing.assert_array_equal(held.recording.mocap.position[visible], mocap.position[visible])


def test_imu_mount_turns_rotates_the_samples_after_its_onset(streams):
    turned = fault.imu_mount_turns(streams, degrees=90.0, fraction=0.5, seed=3)
    imu, before = turned.recording.imu, streams.recording.imu
    onset = 0.5 * (streams.recording.mocap.t[0] + streams.recording.mocap.t[-1])
    late = imu.t >= onset
    assert late.any() and (~late).any()
    for new, old in ((imu.accelerometer, before.accelerometer),
                     (imu.gyroscope, before.gyroscope)):
        np.testing.assert_array_equal(new[~late], old[~late])
        # a quarter turn about the seed's axis a: the part along a stays, the rest turns by
        # 90 degrees and keeps its length
        axis = np.random.default_rng(3).standard_normal(3)
        axis /= np.linalg.norm(axis)
        along_new, along_old = new[late] @ axis, old[late] @ axis
        np.testing.assert_allclose(along_new, along_old, atol=1e-9)
        rest_new = new[late] - along_new[:, None] * axis
        rest_old = old[late] - along_old[:, None] * axis
        np.testing.assert_allclose(np.linalg.norm(rest_new, axis=1),
                                   np.linalg.norm(rest_old, axis=1), atol=1e-9)
        np.testing.assert_allclose(np.sum(rest_new * rest_old, axis=1), 0.0, atol=1e-9)
    assert turned.recording.mocap is streams.recording.mocap


def test_mocap_orientation_drift_grows_linearly_to_its_size(streams):
    drifted = fault.mocap_orientation_drift(streams, degrees=5.0, seed=1)
    mocap, before = drifted.recording.mocap, streams.recording.mocap
    visible = np.flatnonzero(before.visible)
    first, last = visible[0], visible[-1]
    middle = visible[np.argmin(np.abs(before.t[visible] - 0.5 * (before.t[0] + before.t[-1])))]
    fraction = (before.t - before.t[0]) / (before.t[-1] - before.t[0])
    for row in (first, middle, last):
        # the relative rotation R_old^T R_new is the bias, 5 degrees times the time fraction
        relative = matrix_from_wxyz(before.quaternion[row]).T @ matrix_from_wxyz(
            mocap.quaternion[row])
        angle = np.degrees(np.arccos(np.clip((np.trace(relative) - 1) / 2, -1, 1)))
        assert angle == pytest.approx(5.0 * fraction[row], abs=1e-6)
    np.testing.assert_array_equal(mocap.position, before.position)


def test_imu_clips_flattens_each_axis_at_its_level(streams):
    clipped = fault.imu_clips(streams, accelerometer_range=10.0, gyroscope_range=0.5)
    imu, before = clipped.recording.imu, streams.recording.imu
    np.testing.assert_array_equal(imu.accelerometer, np.clip(before.accelerometer, -10.0, 10.0))
    np.testing.assert_array_equal(imu.gyroscope, np.clip(before.gyroscope, -0.5, 0.5))
    assert (np.abs(before.accelerometer) > 10.0).any()  # the levels do cut this recording
    assert (np.abs(before.gyroscope) > 0.5).any()
    assert clipped.recording.mocap is streams.recording.mocap
    only_gyroscope = fault.imu_clips(streams, gyroscope_range=0.5).recording.imu
    np.testing.assert_array_equal(only_gyroscope.accelerometer, before.accelerometer)
