"""Self-calibration benchmark (issue 10): clock, mount, lever arm, gap error and run time.

Simulated: random_reach, pick_tool, circle and arm_lift (mpu9255, IMU 200 Hz, mocap 100 Hz,
0.1-0.3 s occlusions), each seed with a random IMU clock offset in +-2 s, drift in +-100 ppm and a
random lever arm of 2-5 cm; calibrated from imu.csv + mocap.csv alone (mount, gravity and lever
arm unknown). Gap RMS (kalman) after calibration is compared with the same simulation on one
clock with the true recording.yaml ("synchronised"), and with the uncalibrated clock ("before").

BROAD: every trial (mocap every 3rd sample), IMU stamps shifted and scaled artificially,
``t' = (t - c) / (1 + d 1e-6)``; the expected calibration is then ``c + c0`` and ``d + d0`` with
(c0, d0) what the calibration finds on the original trial (the real IMU's own latency, a few ms).
The mount is compared with the identity that kfusion uses for BROAD (the dataset defines opt_quat
as the IMU box's own orientation, so IMU -> body is identity by construction).

Run: ``python benchmarks/calibration.py [--seeds 3] [--quick]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np
import pandas as pd

from kfusion.calibration import (
    SelfCalibration,
    calibrate_recording,
    restamped,
    without_calibration,
)
from kfusion.calibration.evaluation import gap_rms_and_lost
from kfusion.calibration.mount import joint_mount
from kfusion.conventions import rotation_from_wxyz
from kfusion.datasets import broad_trials
from kfusion.evaluate import cut_gaps
from kfusion.readers.broad import read_broad
from kfusion.recording import Recording
from kfusion.simulate import simulate

SCENARIOS = ("random_reach", "pick_tool", "circle", "arm_lift")


def angle_deg(first: np.ndarray, second: np.ndarray) -> float:
    return float(np.degrees((rotation_from_wxyz(first).inv()
                             * rotation_from_wxyz(second)).magnitude()))


def mount_columns(calibration: SelfCalibration, recording: Recording, truth: np.ndarray
                  ) -> dict:
    """The mount's sources against the truth (deg): the rates alone, the specific force alone
    (the joint fit with the rates' information dropped), the joint fit's largest 1-sigma and
    its error in sigma (``sqrt(e^T C^-1 e / 3)``, about 1 when the 1-sigma is honest), and the
    rates-against-force chi2 per degree of freedom."""
    fit = calibration.clock_and_mount.fit
    row = {"mount_rates_deg": angle_deg(fit.imu_to_body, truth),
           "mount_rates_std_deg": float(np.max(fit.mount_std_deg))}
    mount = calibration.mount
    if mount is None:
        return row
    offset = (calibration.accelerometer_clock.offset if calibration.accelerometer_clock
              else fit.offset)
    drift = (calibration.accelerometer_clock.drift_ppm if calibration.accelerometer_clock
             else fit.drift_ppm)
    alone = joint_mount(recording, offset, drift, fit.imu_to_body, np.zeros((3, 3)),
                        start=mount.imu_to_body)
    row["mount_force_deg"] = angle_deg(alone.imu_to_body, truth)
    error = (rotation_from_wxyz(mount.imu_to_body) * rotation_from_wxyz(truth).inv()).as_rotvec()
    covariance = np.diag(np.radians(mount.std_deg) ** 2)  # about body x, y, z
    row["mount_std_deg"] = float(np.max(mount.std_deg))
    row["mount_sigmas"] = float(np.sqrt(error @ np.linalg.solve(covariance, error) / 3.0))
    row["rates_vs_force_chi2_dof"] = mount.chi2 / max(mount.dof, 1)
    return row


def gap_rms_mm(recording: Recording, truth: np.ndarray, mask: np.ndarray) -> float:
    """Kalman gap RMS, mm, over the gap samples the tracker bridged."""
    return gap_rms_and_lost(recording, truth, mask)[0]


TARGETS = {"offset_error_ms": 1.0, "drift_error_ppm": 10.0, "mount_error_deg": 1.0,
           "mount_vs_identity_deg": 1.0, "lever_error_mm": 5.0, "calibrate_s_per_3_min": 10.0}
"""Issue 10's targets: |value| at most this (run time: below)."""


def mark_targets(row: dict) -> None:
    """Add ``met``: the targets this row misses (or "all"); NaN (undetermined) misses."""
    missed = [key for key, limit in TARGETS.items()
              if key in row and not abs(row[key]) <= limit
              and not (key == "lever_error_mm" and np.isnan(row[key]))]  # "where observable"
    if "gap_rms_after_mm" in row and "gap_rms_synced_mm" in row and not (
            row["gap_rms_after_mm"] <= 1.2 * row["gap_rms_synced_mm"] + 0.5):
        missed.append("gap")
    row["missed"] = ",".join(missed) or "-"


def simulated_rows(seeds: int, duration: float, scenarios: tuple[str, ...] = SCENARIOS
                   ) -> list[dict]:
    rows = []
    for number, scenario in enumerate(SCENARIOS):
        if scenario not in scenarios:
            continue
        for seed in range(seeds):
            # a clock, drift and lever arm of their own for every recording (one draw per seed
            # shared by all scenarios left 12 rows with 3 offsets, none beyond 0.5 s)
            rng = np.random.default_rng(1000 + 100 * number + seed)
            offset = float(rng.uniform(-2, 2))
            drift = float(rng.uniform(-100, 100))
            direction = rng.standard_normal(3)
            lever = direction / np.linalg.norm(direction) * rng.uniform(0.02, 0.05)
            shifted = simulate(scenario, seed=seed, duration=duration, imu_time_offset=offset,
                               imu_clock_drift_ppm=drift, lever_arm=lever)
            synced = simulate(scenario, seed=seed, duration=duration, lever_arm=lever)
            start = time.perf_counter()
            calibration = calibrate_recording(without_calibration(shifted.recording))
            seconds = time.perf_counter() - start
            info = calibration.info
            truth, mask = shifted.truth.position, shifted.truth.occluded
            row = {"recording": f"{scenario}/{seed}", "offset_s": offset, "drift_ppm": drift,
                   "offset_error_ms": (info.imu_time_offset - offset) * 1e3
                   if "imu_time_offset" not in calibration.undetermined else np.nan,
                   "offset_std_ms": calibration.imu_time_offset_std * 1e3,
                   "drift_error_ppm": info.imu_clock_drift_ppm - drift
                   if "imu_clock_drift_ppm" not in calibration.undetermined else np.nan,
                   "mount_error_deg": angle_deg(info.imu_to_body,
                                                shifted.recording.info.imu_to_body)
                   if calibration.complete else np.nan,
                   **mount_columns(calibration, shifted.recording,
                                   shifted.recording.info.imu_to_body),
                   "lever_error_mm": float(np.max(np.abs(info.lever_arm - lever)) * 1e3)
                   if info.lever_arm is not None else np.nan,
                   "undetermined": ",".join(sorted(calibration.undetermined)) or "-",
                   "calibrate_s_per_3_min": seconds * 180.0 / duration}
            row["gap_rms_synced_mm"] = gap_rms_mm(synced.recording, synced.truth.position,
                                                  synced.truth.occluded)
            # before: the true mount and lever arm, the clock uncalibrated (lost gaps unscored)
            row["gap_rms_before_mm"], row["lost_before_%"] = gap_rms_and_lost(
                shifted.recording, truth, mask)
            if calibration.complete:
                calibrated = dataclasses.replace(shifted.recording, info=info)
                row["gap_rms_after_mm"], row["lost_after_%"] = gap_rms_and_lost(calibrated, truth,
                                                                           mask)
            else:
                row["gap_rms_after_mm"] = row["lost_after_%"] = np.nan
            mark_targets(row)
            rows.append(row)
    return rows


def broad_rows(trials: int | None, only: tuple[str, ...] = ()) -> list[dict]:
    rows = []
    rng = np.random.default_rng(7)
    for path in broad_trials()[:trials]:
        offset_draw = (float(rng.uniform(-2, 2)), float(rng.uniform(-100, 100)))
        if only and not path.stem.startswith(only):
            continue
        original = read_broad(path, mocap_step=3)
        own = calibrate_recording(original).info
        offset, drift = offset_draw
        shifted = restamped(original, offset, drift)
        start = time.perf_counter()
        calibration = calibrate_recording(shifted)
        seconds = time.perf_counter() - start
        info = calibration.info
        expected_offset = offset * (1 + own.imu_clock_drift_ppm * 1e-6) + own.imu_time_offset
        gapped = cut_gaps(original, rng=np.random.default_rng(0))
        gapped_shifted = restamped(gapped.recording, offset, drift)
        truth, mask = gapped.truth_position, gapped.gap_mask
        minutes = float(original.imu.t[-1] - original.imu.t[0]) / 60.0
        row = {
            "recording": path.stem, "minutes": minutes, "offset_s": offset, "drift_ppm": drift,
            "own_offset_ms": own.imu_time_offset * 1e3, "own_drift_ppm": own.imu_clock_drift_ppm,
            "offset_error_ms": (info.imu_time_offset - expected_offset) * 1e3
            if "imu_time_offset" not in calibration.undetermined else np.nan,
            # against the artificial shift alone (the dataset's clocks taken as one: its README)
            "offset_vs_shift_ms": (info.imu_time_offset - offset) * 1e3,
            "drift_error_ppm": info.imu_clock_drift_ppm - drift - own.imu_clock_drift_ppm
            if "imu_clock_drift_ppm" not in calibration.undetermined else np.nan,
            "mount_vs_identity_deg": angle_deg(info.imu_to_body, original.info.imu_to_body)
            if calibration.complete else np.nan,
            **mount_columns(calibration, shifted, original.info.imu_to_body),
            "undetermined": ",".join(sorted(calibration.undetermined)) or "-",
            "calibrate_s_per_3_min": seconds * 3.0 / minutes,
            "gap_rms_today_mm": gap_rms_mm(gapped.recording, truth, mask),
            "gap_rms_shifted_uncalibrated_mm": gap_rms_mm(gapped_shifted, truth, mask),
            "lost_shifted_uncalibrated_%": gap_rms_and_lost(gapped_shifted, truth, mask)[1],
            "gap_rms_after_mm": gap_rms_mm(dataclasses.replace(
                gapped_shifted, info=dataclasses.replace(info, imu=original.info.imu)), truth,
                mask) if calibration.complete else np.nan,
        }
        mark_targets(row)
        rows.append(row)
    return rows


def summary(table: pd.DataFrame) -> str:
    numeric = table.select_dtypes("number").abs()
    return "max |value| over recordings:\n" + numeric.max().to_string(float_format="{:.3f}".format)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="seeds per scenario")
    parser.add_argument("--duration", type=float, default=180.0,
                        help="simulated recording length, s (default 180: 3 minutes)")
    parser.add_argument("--quick", action="store_true",
                        help="1 seed of 60 s per scenario, 2 BROAD trials")
    parser.add_argument("--only", choices=("simulated", "broad"),
                        help="run one half only (each takes about 5 minutes in full)")
    parser.add_argument("--scenarios", nargs="+", choices=SCENARIOS, default=SCENARIOS,
                        help="simulated scenarios to run (default: all)")
    parser.add_argument("--trials", nargs="+", default=(),
                        help="BROAD trials to run, by number prefix (e.g. 15 21; default: all)")
    args = parser.parse_args()
    seeds, duration = (1, 60.0) if args.quick else (args.seeds, args.duration)
    pd.set_option("display.width", 250)
    pd.set_option("display.max_columns", 30)
    start = time.perf_counter()
    print("targets: |offset error| <= 1 ms, |drift error| <= 10 ppm, mount <= 1 deg, lever arm "
          "<= 5 mm where observable, gap RMS after <= 1.2 x synchronised + 0.5 mm, calibrate "
          "< 10 s per 3 minutes; 'missed' lists the targets a row misses (undetermined = missed)")
    if args.only != "broad":
        simulated = pd.DataFrame(simulated_rows(seeds, duration, tuple(args.scenarios))
                                 ).set_index("recording")
        print(f"\n### simulated, {duration:.0f} s, IMU 200 Hz / mocap 100 Hz, {seeds} seed(s)\n")
        print(simulated.to_string(float_format="{:.3f}".format))
        print(summary(simulated))
    if args.only != "simulated":
        broad = pd.DataFrame(broad_rows(2 if args.quick else None, tuple(args.trials))
                             ).set_index("recording")
        print("\n### BROAD, mocap every 3rd sample, IMU stamps shifted and scaled\n")
        print(broad.to_string(float_format="{:.3f}".format))
        print(summary(broad))
    print(f"\n(total benchmark time {time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
