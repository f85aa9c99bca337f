"""Is the orientation tracker's angle variance honest on real data? Prints a table.

The position filter takes its orientation from the tracker of :mod:`kfusion.kalman.orientation`
(gyroscope integration corrected by the mocap orientation), and its angle variance enters the
bound twice: as the tilt's leak into the bias noise and, with a lever arm, as the orientation's
error times the lever (:func:`kfusion.kalman.model.orientation_error_covariance`). This checks that
variance against BROAD's mocap orientation: every trial, mocap every 3rd sample, 0.1-0.3 s gaps
cut where the mocap is valid (as ``benchmarks/bound_coverage.py``); the tracker runs on the gapped
recording, and each row's orientation is compared with the mocap's, hidden or not.

Per trial and kind of row (``gap``: hidden from the tracker; ``fix``: the tracker has just taken
that orientation): the mean NEES per axis ``|Log(q_est^-1 q_mocap)|^2 / (3 P_tt)`` (1 for an
honest variance; the mocap's own noise is in the error, so slightly above 1 is honest too), its
median, the fraction of rows beyond the chi-square(3) 0.99 quantile (1 % for an honest
variance) and the RMS error per axis against ``sqrt(P_tt)``.

Run: ``python benchmarks/orientation_consistency.py`` (needs the BROAD trials: ``../shared`` or
``KFUSION_BROAD_DIR``; about 20 s).
"""

from __future__ import annotations

import sys

import numpy as np
from scipy.stats import chi2

from kfusion.datasets import broad_trials
from kfusion.evaluate import cut_gaps
from kfusion.kalman.batch import make_fusion, process_recording, resolve_parameters
from kfusion.kalman.filter import UpdateOutcome
from kfusion.kalman.orientation import conjugate, quaternion_log, quaternion_product
from kfusion.readers.broad import read_broad

LIMIT = float(chi2.ppf(0.99, 3))
"""The chi-square(3) 0.99 quantile: an honest 3-axis angle error is beyond it on 1 % of rows."""


def angle_errors(estimated: np.ndarray, mocap: np.ndarray,
                 q_body_imu: tuple[float, float, float, float]) -> np.ndarray:
    """Per row (m, 3) rad: ``Log(q_est^-1 ⊗ q_global_body ⊗ q_body_imu)``, NaN where either is
    unknown (estimated ``q_global_imu`` (m, 4), mocap ``q_global_body`` (m, 4), [w, x, y, z])."""
    errors = np.full((len(estimated), 3), np.nan)
    for row, (estimate, body) in enumerate(zip(estimated, mocap, strict=True)):
        if np.isfinite(estimate).all() and np.isfinite(body).all():
            truth = quaternion_product(tuple(body), q_body_imu)
            errors[row] = quaternion_log(quaternion_product(conjugate(tuple(estimate)), truth))
    return errors


def trial_rows(path: object) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The angle errors (k, 3) rad and angle variances (k,) rad^2 of one trial's gap and fix
    rows."""
    recording = read_broad(path, mocap_step=3)
    gapped = cut_gaps(recording, rng=np.random.default_rng(0), gap_range=(0.1, 0.3))
    hidden = gapped.recording
    fusion = make_fusion(hidden, resolve_parameters(hidden, None, {}), "filterpy")
    rows = len(hidden.mocap)
    quaternion = np.full((rows, 4), np.nan)
    variance = np.full(rows, np.nan)

    def on_row(row: int, outcome: UpdateOutcome) -> None:
        if fusion.initialised:
            quaternion[row] = fusion.estimate().orientation
            variance[row] = fusion.angle_variance

    process_recording(hidden, fusion, on_row)
    errors = angle_errors(quaternion, recording.mocap.quaternion, fusion._q_body_imu)
    known = np.isfinite(errors).all(axis=1) & np.isfinite(variance)
    visible = hidden.mocap.visible
    return {"gap": (errors[known & ~visible], variance[known & ~visible]),
            "fix": (errors[known & visible], variance[known & visible])}


def summary(errors: np.ndarray, variance: np.ndarray) -> str:
    nees = np.sum(errors ** 2, axis=1) / variance
    return (f"{np.mean(nees) / 3:.2f} | {np.median(nees) / 3:.2f} | {np.mean(nees > LIMIT):.3f} | "
            f"{1e3 * np.sqrt(np.mean(errors ** 2)):.2f} / {1e3 * np.sqrt(np.mean(variance)):.2f}")


def main() -> int:
    try:
        paths = broad_trials()
    except (ValueError, FileNotFoundError) as error:
        print(f"orientation_consistency: {error}", file=sys.stderr)
        return 2
    print("| trial | rows | NEES per axis, mean | median | beyond chi2(3) 0.99 | "
          "RMS / sqrt(P_tt) mrad |")
    print("|---|---|---|---|---|---|")
    pooled: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {"gap": [], "fix": []}
    for path in paths:
        for kind, (errors, variance) in trial_rows(path).items():
            pooled[kind].append((errors, variance))
            print(f"| {path.stem[:24]} | {kind} {len(variance)} | {summary(errors, variance)} |")
    for kind, parts in pooled.items():
        errors = np.concatenate([part[0] for part in parts])
        variance = np.concatenate([part[1] for part in parts])
        print(f"| **all** | {kind} {len(variance)} | {summary(errors, variance)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
