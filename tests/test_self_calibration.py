"""Self-calibration (kfusion.calibration) and the consistency diagnosis (kfusion check/track).

Layers: each estimator on hand-made numbers; the whole chain on simulated recordings with a
known clock, mount and lever arm; the diagnosis on every mistake it must name and on clean
simulated and real (BROAD) recordings, which must pass.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from kfusion.calibration import calibrate_recording
from kfusion.calibration.clock import (
    drift_from_window_offsets,
    normalised_cross_correlation,
    parabola_peak,
)
from kfusion.calibration.diagnosis import diagnose
from kfusion.calibration.mount import (
    force_from_mount_columns,
    fuse_mount,
    information_axes,
    marginal_information,
)
from kfusion.calibration.noise import third_difference_std
from kfusion.calibration.specific_force import (
    ANTISYMMETRIC_PAIRS,
    SCALE_ERROR_BASIS,
    UNKNOWNS,
    fit_accelerometer_offset,
    lever_arm_matrix,
    mount_columns,
    residual_correlation,
    symmetric_scale_design,
)
from kfusion.cli import main
from kfusion.conventions import imu_time_to_mocap, rotation_from_wxyz
from kfusion.methods import track_with_method
from kfusion.recording import (
    ImuSamples,
    MocapFrames,
    RecordingError,
    info_to_dict,
    on_mocap_clock,
    parse_info,
    read_info,
    write_recording,
)
from kfusion.simulate import simulate
from kfusion.tracker import Tracker


def test_clock_model_by_hand():
    # t_mocap = (1 + 100e-6) * 10 + 0.5 = 10.501
    assert imu_time_to_mocap(10.0, 0.5, 100.0) == pytest.approx(10.501, abs=1e-12)
    np.testing.assert_allclose(imu_time_to_mocap([0.0, 2.0], -1.0, 0.0), [-1.0, 1.0])


def test_cross_correlation_finds_a_known_lag():
    rng = np.random.default_rng(0)
    x = rng.standard_normal(500)
    y = np.concatenate([np.zeros(7), x[:-7]])  # y[n] = x[n - 7]
    mask = np.ones(500)
    mask_y = mask.copy()
    mask_y[:7] = 0
    lags, r = normalised_cross_correlation(x, mask, y, mask_y, min_overlap=100)
    assert lags[np.nanargmax(r)] == 7
    assert np.nanmax(r) == pytest.approx(1.0, abs=1e-9)


def test_parabola_peak_by_hand():
    # y = -(k - 0.25)^2 at k = -1, 0, 1: -1.5625, -0.0625, -0.5625 -> peak at 0.25
    assert parabola_peak([-1.5625, -0.0625, -0.5625]) == pytest.approx(0.25)
    assert parabola_peak([1.0, 1.0, 1.0]) == 0.0


def test_drift_from_window_offsets_recovers_a_line():
    tau = np.array([10.0, 20.0, 30.0, 40.0])
    offsets = 0.137 + 50e-6 * tau  # 50 ppm
    fit = drift_from_window_offsets(tau, offsets)
    assert fit.offset == pytest.approx(0.137, abs=1e-12)
    assert fit.drift_ppm == pytest.approx(50.0, abs=1e-6)


def test_lever_arm_matrix_by_hand():
    # omega = z, r = x: omega x (omega x r) = z x y = -x (centripetal); alpha = z: alpha x r = y
    L = lever_arm_matrix([[0.0, 0.0, 1.0]], [[0.0, 0.0, 1.0]])
    np.testing.assert_allclose(L[0] @ [1.0, 0.0, 0.0], [-1.0, 1.0, 0.0], atol=1e-15)


def test_third_differences_measure_white_noise_under_a_smooth_signal():
    rng = np.random.default_rng(1)
    t = np.arange(20000) / 200
    values = np.column_stack([np.sin(t), 0.01 * t**2]) + 0.05 * rng.standard_normal((20000, 2))
    np.testing.assert_allclose(third_difference_std(values), 0.05, rtol=0.05)


@pytest.fixture(scope="module")
def shifted():
    """random_reach, 90 s, IMU clock 1.3 s behind and 60 ppm slow, 2 cm lever arm."""
    return simulate("random_reach", seed=2, duration=90.0, imu_time_offset=1.3,
                    imu_clock_drift_ppm=60.0, lever_arm=[0.02, -0.02, 0.01])


def test_self_calibration_recovers_clock_mount_and_lever_arm(shifted):
    recording = shifted.recording
    unknown = dataclasses.replace(recording.info, imu_to_body=np.full(4, np.nan),
                                  gravity=np.full(3, np.nan), lever_arm=None)
    result = calibrate_recording(dataclasses.replace(recording, info=unknown))
    info = result.info
    assert abs(info.imu_time_offset - 1.3) < 1e-3
    assert abs(info.imu_clock_drift_ppm - 60.0) < 10.0
    mount_error = (rotation_from_wxyz(info.imu_to_body).inv()
                   * rotation_from_wxyz(recording.info.imu_to_body)).magnitude()
    assert np.degrees(mount_error) < 1.0
    assert info.lever_arm is not None
    assert np.max(np.abs(info.lever_arm - [0.02, -0.02, 0.01])) < 0.005
    assert np.degrees(np.arccos(info.gravity @ [0, -9.81, 0] / 9.81**2)) < 1.0
    assert 0.5 < info.imu_noise.accelerometer_noise_density / 300e-6 / 9.80665 < 2.0
    assert result.complete and "imu_time_offset" not in result.undetermined


def _accelerometer_delayed(recording, delay_s):
    """The recording with the accelerometer alone read ``delay_s`` late: each sample holds the
    specific force of ``delay_s`` before its stamp, so the accelerometer's stamps map onto the
    mocap clock with ``offset - delay_s``. The gyroscope is untouched."""
    imu = recording.imu
    delayed = np.column_stack([np.interp(imu.t - delay_s, imu.t, imu.accelerometer[:, axis])
                               for axis in range(3)])
    return dataclasses.replace(recording, imu=ImuSamples(imu.t, delayed, imu.gyroscope))


def test_the_accelerometer_is_timed_on_its_own(shifted):
    # started 3 ms off, Gauss-Newton on the specific force comes back to the true offset; an
    # accelerometer read 1.5 ms late moves its own offset by -1.5 ms
    recording, truth = shifted.recording, 1.3
    info = recording.info
    start = truth + 0.003
    found = fit_accelerometer_offset(recording, start, 60.0, info.imu_to_body)
    assert abs(found.offset - truth) < 3e-4 and found.offset_std < 3e-4
    assert 1 < found.iterations <= 4
    delayed = fit_accelerometer_offset(_accelerometer_delayed(recording, 0.0015), start, 60.0,
                                       info.imu_to_body)
    assert abs(delayed.offset - (truth - 0.0015)) < 3e-4


def test_a_slow_arm_lift_is_timed_by_the_accelerometer():
    # arm_lift rotates too little for the gyroscope to time the clock within 2 ms (std 5-9 ms):
    # the accelerometer does, so offset, mount and gravity are all determined
    simulation = simulate("arm_lift", seed=1, duration=60.0, imu_time_offset=-0.4)
    recording = simulation.recording
    unknown = dataclasses.replace(recording.info, imu_to_body=np.full(4, np.nan),
                                  gravity=np.full(3, np.nan), lever_arm=None)
    result = calibrate_recording(dataclasses.replace(recording, info=unknown))
    assert result.clock_and_mount.fit.offset_std > 0.002
    assert result.accelerometer_clock is not None
    assert "imu_time_offset" not in result.undetermined
    assert abs(result.info.imu_time_offset + 0.4) < 1e-3
    assert result.imu_time_offset_std < 1e-3
    assert any("from the accelerometer" in line for line in result.report())


def _with_clock(recording, offset, drift_ppm=0.0):
    """The recording with recording.yaml's clock fields replaced (the stamps untouched)."""
    return dataclasses.replace(recording, info=dataclasses.replace(
        recording.info, imu_time_offset=offset, imu_clock_drift_ppm=drift_ppm))


def test_check_times_a_slow_arm_lift_by_the_accelerometer():
    # the gyroscope's correlation cannot time arm_lift, so check used to pass a clock written
    # 100 ms wrong; the accelerometer times it (and a right one passes)
    recording = simulate("arm_lift", seed=0, duration=15.0).recording
    assert diagnose(recording).ok
    diagnosis = diagnose(_with_clock(recording, 0.1))
    assert not diagnosis.ok
    assert re.match(r"IMU clock about (99\.\d|100\.\d) ms ahead of the mocap \(timed by the "
                    "accelerometer", diagnosis.problems[0]), diagnosis.problems
    # a latency the filter would apply is part of the clock tested
    assert not diagnose(recording, imu_latency_s=0.05).ok


def test_check_finds_a_drift_that_recording_yaml_leaves_out():
    # the IMU's clock runs 600 ppm slow (9 ms over 15 s, 0 on average); recording.yaml says
    # nothing of it (a simulated recording's yaml never does), then says it right
    simulation = simulate("random_reach", seed=0, duration=15.0, imu_time_offset=-0.0045,
                          imu_clock_drift_ppm=600.0)
    recording = simulation.recording
    diagnosis = diagnose(recording)
    assert not diagnosis.ok and "IMU clock drifts" in diagnosis.problems[0], diagnosis.problems
    assert diagnose(_with_clock(recording, -0.0045, 600.0)).ok


def test_calibrate_measures_the_drift_by_the_accelerometer_when_the_gyroscope_cannot():
    simulation = simulate("arm_lift", seed=2, duration=120.0, imu_time_offset=0.037,
                          imu_clock_drift_ppm=-80.0)
    result = calibrate_recording(_with_clock(simulation.recording, 0.0))
    assert "imu_clock_drift_ppm" not in result.undetermined
    assert abs(result.info.imu_clock_drift_ppm + 80.0) < 10.0
    assert abs(result.info.imu_time_offset - 0.037) < 1e-3


def _turning_about_vertical():
    """30 s of a limb turning about body z, which is the global vertical, IMU mounted at
    20, 30, 40 deg (xyz Euler), gravity [0, 0, -9.81]."""
    rng = np.random.default_rng(3)
    t = np.arange(0, 30, 0.01)
    angle = np.cumsum(2.0 * np.sin(1.3 * t) * 0.01)
    q_global_body = Rotation.from_rotvec(np.outer(angle, [0, 0, 1]))
    R_body_imu = Rotation.from_euler("xyz", [20, 30, 40], degrees=True)
    imu_t = np.arange(0, 30, 0.005)
    rate = np.outer(np.interp(imu_t, t, 2.0 * np.sin(1.3 * t)), [0, 0, 1])
    gyroscope = R_body_imu.inv().apply(rate) + 0.001 * rng.standard_normal(rate.shape)
    f_global = np.tile([0.0, 0.0, 9.81], (len(imu_t), 1))
    imu_q = Rotation.from_rotvec(np.outer(np.interp(imu_t, t, angle), [0, 0, 1])) * R_body_imu
    accelerometer = imu_q.inv().apply(f_global)
    recording = shifted_recording = simulate("circle", seed=0).recording
    recording = dataclasses.replace(
        shifted_recording, imu=ImuSamples(imu_t, accelerometer, gyroscope),
        mocap=MocapFrames(t, np.zeros((len(t), 3)), q_global_body.as_quat(scalar_first=True)),
        info=dataclasses.replace(shifted_recording.info, gravity=np.array([0, 0, -9.81])))
    return recording


def test_rotation_about_one_axis_leaves_the_mount_undetermined():
    # the limb only turns about body z: the mount's rotation about it cannot be seen
    result = calibrate_recording(_turning_about_vertical())
    assert "imu_to_body" in result.undetermined
    assert "one axis only" in result.undetermined["imu_to_body"]
    assert not result.complete


@pytest.fixture(scope="module")
def clean():
    return simulate("pick_tool", seed=1).recording


def _mistakes(recording):
    info, mocap, imu = recording.info, recording.mocap, recording.imu
    return {
        r"IMU clock about 13[6-8] ms behind the mocap: run kfusion calibrate":
            dataclasses.replace(recording, info=dataclasses.replace(info,
                                                                    imu_time_offset=-0.137)),
        "gravity sign flipped": dataclasses.replace(recording, info=dataclasses.replace(
            info, gravity=-info.gravity)),
        "gravity wrong axis": dataclasses.replace(recording, info=dataclasses.replace(
            info, gravity=np.array([0.0, 0.0, -9.81]))),
        "mount wrong": dataclasses.replace(recording, info=dataclasses.replace(
            info, imu_to_body=np.array([1.0, 0.0, 0.0, 0.0]))),
        "quaternion columns look like x, y, z, w": recording.with_mocap(MocapFrames(
            mocap.t, mocap.position, mocap.quaternion[:, [1, 2, 3, 0]])),
        "IMU time looks like ms": dataclasses.replace(recording, imu=ImuSamples(
            imu.t * 1000, imu.accelerometer, imu.gyroscope)),
        "no time overlap": dataclasses.replace(recording, imu=ImuSamples(
            imu.t + 1000, imu.accelerometer, imu.gyroscope)),
    }


def test_a_clean_simulated_recording_passes(clean):
    assert diagnose(clean).ok


@pytest.mark.parametrize("expected", list(_mistakes(simulate("pick_tool", seed=1,
                                                             duration=5).recording)))
def test_the_diagnosis_names_each_mistake(clean, expected):
    diagnosis = diagnose(_mistakes(clean)[expected])
    assert len(diagnosis.problems) == 1
    assert re.search(expected, diagnosis.problems[0]), diagnosis.problems[0]


def test_every_broad_trial_passes_the_diagnosis():
    try:
        from kfusion.datasets import broad_trials
        trials = broad_trials()
    except ValueError:
        pytest.skip("BROAD trials not found (../shared/data/broad): skipping the real-data check")
    from kfusion.readers.broad import read_broad

    for path in trials:
        diagnosis = diagnose(read_broad(path, mocap_step=3))
        assert diagnosis.ok, (path.stem, diagnosis.problems)


@pytest.mark.parametrize("degrees_per_second", [300.0, 400.0])
def test_a_gyroscope_clipping_below_its_range_is_named_not_read_as_a_clock_offset(
        degrees_per_second: float):
    """The bundled BROAD excerpt (fast arm motion) with its gyroscope flat at 300 or 400 dps,
    below its profile's 2000: the diagnosis names the clipping in a note and finds no mistake.
    At 300 dps 69 % of the samples clip, and the clock is not timed by the rest (before, it
    was timed on the flat tops too)."""
    from kfusion.datasets import broad_excerpt
    from kfusion.recording import read_recording
    from kfusion.simulate import faults

    recording = read_recording(broad_excerpt())
    assert diagnose(recording).ok
    level = np.radians(degrees_per_second)
    clipped = faults.imu_clips(faults.Streams.of(recording), None, level).recording
    diagnosis = diagnose(clipped)
    assert diagnosis.ok, diagnosis.problems
    assert any(note.startswith(f"gyroscope clips at {level:.3g} rad/s "
                               f"({degrees_per_second:.3g} dps) on ")
               for note in diagnosis.notes), diagnosis.notes
    timed = any(note.startswith("clock: offset") for note in diagnosis.notes)
    assert timed == (degrees_per_second == 400.0), diagnosis.notes


def test_a_broad_trial_clipping_at_250_dps_is_not_read_as_a_clock_offset():
    """BROAD trial 21's first 40 s with the gyroscope flat at 250 dps (the MPU-9250's power-on
    range) and the accelerometer at 2 g: before, the flat tops moved the rate correlation's
    peak and ``kfusion check`` and ``kfusion track`` refused the recording with "IMU clock
    about 23 ms behind the mocap", a clock fix that would have made it wrong."""
    try:
        from kfusion.datasets import broad_trials
        trials = [path for path in broad_trials() if path.name.startswith("21")]
    except ValueError:
        pytest.skip("BROAD trials not found (../shared/data/broad): skipping the real-data check")
    from kfusion.config import first_seconds
    from kfusion.readers.broad import read_broad
    from kfusion.simulate import faults

    recording = first_seconds(read_broad(trials[0], mocap_step=3), 40.0)
    clipped = faults.imu_clips(faults.Streams.of(recording), 2.0 * 9.80665,
                               np.radians(250.0)).recording
    diagnosis = diagnose(clipped)
    assert diagnosis.ok, diagnosis.problems
    assert [note.split(" on ")[0] for note in diagnosis.notes if " clips at " in note] == [
        "accelerometer clips at 19.6 m/s^2 (2 g)", "gyroscope clips at 4.36 rad/s (250 dps)"]
    offset = [note for note in diagnosis.notes if note.startswith("clock: offset")]
    assert offset and abs(float(offset[0].split()[2])) < 5.0, offset  # ms


def test_recording_info_clock_and_noise_keys():
    data = {"imu_to_body": [1, 0, 0, 0], "gravity": [0, -9.81, 0], "imu_time_offset": 0.137,
            "imu_clock_drift_ppm": -20, "imu_noise": {"accelerometer_noise_density": 0.003}}
    info = parse_info(data)
    assert info.imu_time_offset == 0.137 and info.imu_clock_drift_ppm == -20.0
    assert info.imu_noise.overrides() == {"accelerometer_noise_density": 0.003}
    assert info_to_dict(parse_info(info_to_dict(info))) == info_to_dict(info)
    for key, value, message in (
            ("imu_time_offset", "soon", r"expected a number \(s\)"),
            ("imu_clock_drift_ppm", 1e6, r"within \+-10000"),
            ("imu_noise", {"gyro": 1.0}, "unknown key"),
            ("imu_noise", {"gyroscope_noise_density": -1.0}, "positive")):
        with pytest.raises(RecordingError, match=message):
            parse_info({**data, key: value})
    with pytest.raises(RecordingError, match="kfusion calibrate DIR --out DIR/recording.yaml"):
        parse_info({"gravity": [0, -9.81, 0]})
    assert np.isnan(parse_info({}, require_mount=False).imu_to_body).all()


def test_clock_values_written_as_users_write_them(tmp_path):
    # YAML 1.1 reads `1e-3` (no dot) as text: recording.yaml and Tracker.from_yaml used to
    # refuse it; an IMU stamped in Unix time (offset -1.7e9 s) must be describable
    path = tmp_path / "recording.yaml"
    path.write_text("imu_to_body: [1, 0, 0, 0]\ngravity: [0, -9.81, 0]\n"
                    "imu_time_offset: -1.7e9\nimu_noise: {accelerometer_noise_density: 3e-3}\n")
    info = read_info(path)
    assert info.imu_time_offset == -1.7e9
    assert info.imu_noise.accelerometer_noise_density == 0.003
    assert Tracker.from_yaml(path).imu_clock == (-1.7e9, 0.0)
    # the Python API checks what parse_info checks: no bool, text, list or NaN offset
    for value in (True, "0.003", [0.003], float("nan"), 1e11):
        with pytest.raises(ValueError, match="imu_time_offset: expected a finite number"):
            dataclasses.replace(info, imu_time_offset=value)
        with pytest.raises(ValueError, match="Tracker: imu_time_offset"):
            Tracker(info.imu_to_body, info.gravity, imu_time_offset=value)


def test_the_quick_cut_is_taken_on_the_mocap_clock():
    from kfusion.config import first_seconds

    recording = simulate("random_reach", seed=0, duration=12.0).recording
    imu = recording.imu
    late = dataclasses.replace(_with_clock(recording, -1000.0),
                               imu=ImuSamples(imu.t + 1000.0, imu.accelerometer, imu.gyroscope))
    cut, reference = first_seconds(late, 5.0), first_seconds(recording, 5.0)
    assert len(cut.imu) == len(reference.imu) > 900
    assert len(cut.mocap) == len(reference.mocap)


def test_every_method_and_the_tracker_honour_the_clock_model(shifted):
    synced = on_mocap_clock(dataclasses.replace(shifted.recording, info=dataclasses.replace(
        shifted.recording.info, imu_time_offset=1.3, imu_clock_drift_ppm=60.0)))
    np.testing.assert_allclose(synced.imu.t, shifted.truth.imu_t, atol=1e-9)
    calibrated = dataclasses.replace(shifted.recording, info=dataclasses.replace(
        shifted.recording.info, imu_time_offset=1.3, imu_clock_drift_ppm=60.0))
    for method in ("baseline", "kalman", "smoother"):
        via_info = track_with_method(calibrated, method)
        direct = track_with_method(synced, method)
        np.testing.assert_array_equal(via_info.position, direct.position)
    tracker = Tracker.from_recording_info(calibrated.info)
    reference = Tracker.from_recording_info(synced.info)
    imu = calibrated.imu
    for k in range(200):
        a = tracker.push_imu(imu.t[k], imu.accelerometer[k], imu.gyroscope[k])
        b = reference.push_imu(synced.imu.t[k], imu.accelerometer[k], imu.gyroscope[k])
        assert a == b
    assert tracker.health.as_dict() == reference.health.as_dict()


def test_calibrate_check_and_track_commands(tmp_path, capsys):
    simulation = simulate("random_reach", seed=4, duration=60.0, imu_time_offset=-0.137)
    folder = write_recording(simulation.recording, tmp_path / "recording")
    # check and track refuse the unsynchronised recording, naming the fix
    assert main(["check", str(folder)]) == 2
    assert re.search("IMU clock about 13[6-8] ms ahead of the mocap: run kfusion calibrate",
                     capsys.readouterr().err)
    out = tmp_path / "track.csv"
    assert main(["track", str(folder), "--out", str(out)]) == 2
    assert "--force" in capsys.readouterr().err and not out.exists()
    assert main(["track", str(folder), "--out", str(out), "--force"]) == 0
    capsys.readouterr()
    # calibrate from imu.csv and mocap.csv alone
    (folder / "recording.yaml").unlink()
    assert main(["check", str(folder)]) == 2
    assert main(["calibrate", str(folder), "--out", str(folder / "recording.yaml")]) == 0
    printed = capsys.readouterr().out
    assert re.search(r"imu_time_offset: -13[6-8]\.\d+ ms \+- ", printed), printed
    info = read_info(folder / "recording.yaml")
    assert abs(info.imu_time_offset + 0.137) < 1e-3
    assert yaml.safe_load((folder / "recording.yaml").read_text())["imu_noise"]
    assert main(["check", str(folder)]) == 0
    assert main(["track", str(folder), "--out", str(out)]) == 0


def test_track_tests_the_clock_with_an_overridden_latency(tmp_path, capsys):
    folder = write_recording(simulate("random_reach", seed=1, duration=10.0).recording,
                             tmp_path / "recording")
    out = tmp_path / "track.csv"
    assert main(["track", str(folder), "--set", "imu_latency_s=0.2", "--out", str(out)]) == 2
    error = capsys.readouterr().err
    assert "IMU clock about 200 ms" in error and "imu_latency_s" in error and not out.exists()


def test_the_papers_calibration_pairs_samples_on_the_mocap_clock(tmp_path, capsys):
    # IMU stamped 1.234 s behind, stated in recording.yaml: the still poses and rate pairs
    # must be taken on the mocap clock (the mount came out 172 deg off)
    truth = simulate("random_reach", seed=1, duration=20.0).recording
    stamps = truth.imu.t - 1.234
    shifted = dataclasses.replace(
        _with_clock(truth, 1.234),
        imu=ImuSamples(stamps, truth.imu.accelerometer, truth.imu.gyroscope))
    folder = write_recording(shifted, tmp_path / "recording")
    assert main(["calibrate", str(folder), "--paper", "--angular-rate",
                 "--out", str(tmp_path / "paper.yaml")]) == 0
    capsys.readouterr()
    mount = read_info(tmp_path / "paper.yaml").imu_to_body
    error = (rotation_from_wxyz(mount).inv() * rotation_from_wxyz(truth.info.imu_to_body))
    assert np.degrees(error.magnitude()) < 5.0


def test_a_still_limb_names_the_clock_and_does_not_accuse_the_gravity(tmp_path, capsys):
    # the first 6 s of circle are a rest (the noise estimate finds them all still): nothing
    # times the IMU against the mocap, so the mount cannot be fitted and a correct gravity must
    # not be reported as contradicting the data (it used to be, through a noise-fitted mount)
    simulation = simulate("circle", seed=0, duration=6.0, imu_time_offset=1.234)
    folder = write_recording(simulation.recording, tmp_path / "still")
    (folder / "recording.yaml").write_text("gravity: [0, -9.81, 0]\n")
    out = folder / "calibrated.yaml"
    assert main(["calibrate", str(folder), "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert "imu_time_offset undetermined" in captured.err and "too little rotation" in \
        captured.err, captured.err
    assert "gravity" not in captured.err and not out.exists()
    assert "imu_to_body: undetermined: not fitted: the clock is undetermined" in captured.out
    assert "as given, not checked" in captured.out


def test_the_scale_error_basis_spans_every_matrix():
    # 9 independent matrices: any first-order scale and misalignment error E is a combination
    basis = SCALE_ERROR_BASIS.reshape(9, 9)
    assert np.linalg.matrix_rank(basis) == 9
    assert np.allclose(SCALE_ERROR_BASIS[-1], np.eye(3))
    assert all(np.trace(matrix) == 0 for matrix in SCALE_ERROR_BASIS[:-1])


def test_every_batch_entry_point_applies_the_recordings_clock_model():
    # A recording whose IMU runs on its own clock, described in its info: the filter, the
    # smoother, the baseline and the numpy reference, called directly (not through kfusion
    # track), must track as on the mapped stamps; ignoring the clock is a different result.
    from kfusion.baseline import track_recording as baseline_track
    from kfusion.kalman import filter_recording, run_smoother
    from kfusion.kalman.parameters import KalmanParameters
    from kfusion.kalman.reference import reference_filter

    shifted = simulate("random_reach", seed=2, duration=8.0, imu_time_offset=0.4,
                       imu_clock_drift_ppm=60.0).recording
    recording = dataclasses.replace(shifted, info=dataclasses.replace(  # the true clock, declared
        shifted.info, imu_time_offset=0.4, imu_clock_drift_ppm=60.0))
    mapped = on_mocap_clock(recording)
    ignored = dataclasses.replace(recording, info=dataclasses.replace(
        recording.info, imu_time_offset=0.0, imu_clock_drift_ppm=0.0))
    for run in (lambda r: filter_recording(r).position, lambda r: run_smoother(r).result.position,
                lambda r: baseline_track(r).position,
                lambda r: reference_filter(r, KalmanParameters.from_profiles(
                    r.info.imu)).position):
        np.testing.assert_array_equal(run(recording), run(mapped))
        assert not np.allclose(run(recording), run(ignored), equal_nan=True)


# --- the mount from rates and specific force together (kfusion.calibration.mount) ---


def test_mount_columns_are_the_derivative_of_the_rotated_force():
    # y(theta) = R_global_body exp([theta]x) f_body changes by R (theta x f) = -C theta for a
    # small theta, so y(0) = A x + C theta when the model is y(theta) = A x
    rng = np.random.default_rng(11)
    R_global_body = Rotation.random(5, random_state=12).as_matrix()
    force_body = rng.normal(0.0, 5.0, (5, 3)) + [0.0, 0.0, 9.81]
    theta = np.array([1e-6, -2e-6, 1.5e-6])
    moved = np.einsum("nij,nj->ni", R_global_body,
                      Rotation.from_rotvec(theta).apply(force_body))
    still = np.einsum("nij,nj->ni", R_global_body, force_body)
    # second order: |theta|^2 |f| / 2 ~ 6e-11
    assert np.allclose(moved - still, -mount_columns(R_global_body, force_body) @ theta,
                       atol=1e-9)


def test_the_symmetric_scale_design_cannot_rotate_the_force():
    # E's antisymmetric part is the mount's rotation: once E is held symmetric its columns
    # cannot reproduce theta x f, while a symmetric E is still spanned
    rng = np.random.default_rng(5)
    force = rng.normal(0.0, 9.81, (40, 3))
    design = np.zeros((40, 3, UNKNOWNS))
    design[:, :, 9:] = np.einsum("jkl,nl->nkj", SCALE_ERROR_BASIS, force)
    constrained = symmetric_scale_design(design)
    for first, second in ANTISYMMETRIC_PAIRS:
        assert np.all(constrained[:, :, second] == 0.0)
        assert np.allclose(constrained[:, :, first], design[:, :, first] + design[:, :, second])
    rotations = np.stack([np.cross(axis, force).reshape(-1) for axis in np.eye(3)], axis=1)
    free = design[:, :, 9:].reshape(-1, 9)
    held = constrained[:, :, [9, 10, 12, 15, 16, 17]].reshape(-1, 6)
    # the nine free columns already hold the three rotations; the six symmetric ones do not
    assert np.linalg.matrix_rank(np.hstack([free, rotations])) == 9
    assert np.linalg.matrix_rank(np.hstack([held, rotations])) == 9
    assert np.linalg.matrix_rank(held) == 6


def test_marginal_information_by_hand():
    # H = [[4, 2], [2, 2]], b = [6, 4]: on the first parameter I = 4 - 2 * 2 / 2 = 2,
    # h = 6 - 2 * 4 / 2 = 2, so p_0 = 1 (the full solution is [1, 1]) and I^-1 = (H^-1)_00
    information, vector = marginal_information([[4.0, 2.0], [2.0, 2.0]], [6.0, 4.0], [0])
    assert np.allclose(information, [[2.0]]) and np.allclose(vector, [2.0])
    assert np.isclose(1.0 / information[0, 0], np.linalg.inv([[4.0, 2.0], [2.0, 2.0]])[0, 0])
    # a nuisance the data never see (zero row and column) changes nothing
    information, vector = marginal_information(
        [[4.0, 2.0, 0.0], [2.0, 2.0, 0.0], [0.0, 0.0, 0.0]], [6.0, 4.0, 0.0], [0])
    assert np.allclose(information, [[2.0]]) and np.allclose(vector, [2.0])


def test_fuse_mount_by_hand():
    # rates blind about z, specific force blind about x: each fills in the other's axis and
    # the shared y is the information-weighted mean (1 * 0.2 + 4 * 0.3) / 5 = 0.28
    rates = np.diag([1.0, 1.0, 0.0])
    force = np.diag([0.0, 4.0, 4.0])
    theta, total, chi2, dof = fuse_mount(rates, [0.1, 0.2, 0.0], force,
                                         force @ [0.0, 0.3, 0.5])
    assert np.allclose(theta, [0.1, 0.28, 0.5]) and np.allclose(total, np.diag([1, 5, 4]))
    # what is left: (0.28 - 0.2)^2 * 1 + (0.28 - 0.3)^2 * 4 on the one axis both see
    assert np.isclose(chi2, 0.08**2 + 4 * 0.02**2) and dof == 2
    # neither sees x: left at 0 and reported with infinite 1-sigma
    theta, total, _, _ = fuse_mount(np.diag([0.0, 1.0, 1.0]), [0.0, 0.2, 0.0],
                                    np.diag([0.0, 4.0, 4.0]), [0.0, 1.2, 2.0])
    std, axes = information_axes(total)
    assert theta[0] == 0.0 and np.isinf(std[0]) and np.allclose(np.abs(axes[:, 0]), [1, 0, 0])


def test_the_force_direction_is_read_back_from_the_mount_columns():
    rng = np.random.default_rng(2)
    force = rng.normal(0.0, 3.0, (6, 3))
    columns = mount_columns(Rotation.random(6, random_state=3).as_matrix(), force)
    found = force_from_mount_columns(columns)
    assert np.allclose(np.abs(np.einsum("ni,ni->n", found, force)),
                       np.sum(force**2, axis=1))


@pytest.mark.parametrize("seed", [0, 1])
def test_a_slow_arm_lift_gets_its_mount_from_the_specific_force(seed):
    # the arm turns at about 0.1 rad/s RMS: the rates alone pin the mount to 1-2 deg, and the
    # accelerometer's gravity, tilting through the body frame, pins it within 1 deg; the
    # error lies inside 3 sigma of the 1-sigma reported
    simulation = simulate("arm_lift", seed=seed, duration=90.0, imu_time_offset=-0.7,
                          imu_clock_drift_ppm=40.0)
    truth = simulation.recording.info.imu_to_body
    result = calibrate_recording(dataclasses.replace(simulation.recording, info=dataclasses.replace(
        simulation.recording.info, imu_to_body=np.full(4, np.nan), gravity=np.full(3, np.nan))))
    assert np.max(result.clock_and_mount.fit.mount_std_deg) > 1.0  # the rates alone cannot
    assert "imu_to_body" not in result.undetermined and result.mount is not None
    error = (rotation_from_wxyz(result.info.imu_to_body) * rotation_from_wxyz(truth).inv())
    assert np.degrees(error.magnitude()) < 1.0
    assert np.all(np.abs(np.degrees(error.as_rotvec())) < 3.0 * result.mount.std_deg)
    assert "from rates and specific force together" in "\n".join(result.report())


def test_a_turn_about_the_vertical_leaves_the_mount_undetermined_about_it():
    # body z is vertical and the only rotation axis: the rates cannot see the mount about it
    # and gravity stays along it in the body frame: the reason names that axis and both causes
    recording = _turning_about_vertical()
    result = calibrate_recording(recording)
    reason = result.undetermined["imu_to_body"]
    assert result.mount is not None and np.allclose(np.abs(result.mount.weakest_axis),
                                                    [0, 0, 1], atol=0.05)
    assert "about body axis" in reason and "one axis only" in reason
    assert "specific force stayed near body direction" in reason


@pytest.mark.broad
def test_broad_trial_15_mount_from_rates_and_specific_force():
    # the rates alone put this fast-translation trial's mount about 1.2 deg from the
    # dataset's alignment (about body y, in every window of the trial, at any clock offset
    # within +-5 ms); the accelerometer agrees with it within about 0.5 deg. The joint fit
    # reports the disagreement and covers it in its 1-sigma
    from kfusion.datasets import broad_trials
    from kfusion.readers.broad import read_broad

    path = next(p for p in broad_trials() if p.stem.startswith("15_"))
    result = calibrate_recording(read_broad(path, mocap_step=3))
    mount = result.mount
    assert mount is not None and mount.birge > 3.0
    error = rotation_from_wxyz(result.info.imu_to_body).as_rotvec()  # identity is the truth
    assert np.all(np.abs(np.degrees(error)) < 3.0 * mount.std_deg)
    assert "disagree beyond their noise" in "\n".join(result.report())


def test_a_recording_without_occlusions_is_fitted_inside_the_imu_span():
    """A recording without occlusions is one visible mocap run; where the IMU starts after the
    mocap and stops before it, the part of the run inside the IMU's span is fitted. Before, the
    whole run was skipped and `kfusion check` refused the recording with "no visible mocap run
    of at least 1 s" (a mocap that repeats its last pose through occlusions, the fail-safe row,
    is such a recording)."""
    from kfusion.calibration.specific_force import specific_force_system

    recording = simulate("arm_lift", seed=3, duration=6.0, occlusions=None).recording
    assert recording.mocap.visible.all()
    imu = recording.imu
    keep = (imu.t >= 0.5) & (imu.t <= 5.5)
    late = dataclasses.replace(recording, imu=ImuSamples(
        imu.t[keep], imu.accelerometer[keep], imu.gyroscope[keep]))
    info = recording.info
    y, design = specific_force_system(late, info.imu_time_offset, info.imu_clock_drift_ppm,
                                      info.imu_to_body)
    full, _ = specific_force_system(recording, info.imu_time_offset, info.imu_clock_drift_ppm,
                                    info.imu_to_body)
    assert len(y) == len(design) > 0
    # the fitted rows are the run's frames inside 0.5-5.5 s, less the trims at both ends
    mocap_t = recording.mocap.t
    assert len(y) == pytest.approx(len(full) * ((mocap_t >= 0.5) & (mocap_t <= 5.5)).sum()
                                   / len(mocap_t), rel=0.1)


def test_residual_correlation_counts_frames_per_independent_residual():
    # low-passed at 4 Hz, a 100 Hz stream's residuals are independent every 100 / 8 frames;
    # a stream slower than twice the cut-off has every frame independent
    assert residual_correlation(np.arange(0.0, 1.0, 0.01), 4.0) == pytest.approx(12.5)
    assert residual_correlation(np.arange(0.0, 10.0, 0.2), 4.0) == 1.0
