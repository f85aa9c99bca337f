"""Speed of ``kfusion convert c3d`` (issue 12 target: a 3-minute, 4-marker, 100 Hz take in < 5 s).

Builds a take with a known truth: a 4-marker forearm cluster (4-7 cm from its centroid) moving
on smooth reaches (sinusoids, up to ~0.5 m/s and ~1.5 rad/s), with 0.2 mm marker noise (seeded)
and partial occlusions: runs of 0.05-0.5 s in which one marker (most runs), two, or all four
are hidden, about 8 % of marker samples in all. It is written as C3D (mm, first frame 1001) with
:func:`kfusion.readers.c3d.write_c3d_markers`, plus a 200 Hz IMU file (still; its content does
not matter here). Then ``kfusion convert c3d`` runs end to end (read C3D, estimate the cluster,
Kabsch per frame, write and read back the folder) and each stage is timed alone too.

Prints a markdown table: wall time per stage (best of ``--repeats``), frames solved, and the pose
error against the truth (position: of the cluster centroid, which is the body origin; rotation:
relative to the first full frame, whose noise gives the body frame a small constant offset that
the mount calibration absorbs: printed apart). Not a timed test.

Run: ``python benchmarks/c3d.py [--quick] [--minutes 3] [--rate 100] [--repeats 3]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import platform
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from kfusion.cli import main
from kfusion.readers.c3d import read_c3d_markers, write_c3d_markers
from kfusion.recording import MarkerFrames, read_mocap
from kfusion.rigid_body import estimate_cluster, solve_poses

NAMES = ("ELB", "WRU", "WRR", "TOP")
BODY = np.array([[0.07, 0.0, 0.0], [-0.03, 0.04, 0.0], [-0.03, -0.03, 0.02],
                 [-0.01, -0.01, -0.02]])
"""m, cluster around its centroid (columns sum to 0)."""
NOISE = 0.0002
"""m, marker noise per axis."""
FIRST_FRAME = 1001


def truth(t: np.ndarray) -> tuple[np.ndarray, Rotation]:
    """Centroid (k, 3), m, and orientation (body -> global) of the cluster."""
    position = np.column_stack([0.4 + 0.15 * np.sin(0.9 * t), 1.1 + 0.1 * np.sin(1.3 * t + 1),
                                0.2 * np.cos(0.7 * t)])
    angles = np.column_stack([0.6 * np.sin(1.1 * t), 0.4 * np.sin(0.8 * t + 0.5),
                              0.8 * np.sin(0.6 * t + 1.0)])
    return position, Rotation.from_rotvec(angles)


def occlusions(rng: np.random.Generator, count: int, rate: float) -> np.ndarray:
    """(k, 4) True where hidden: runs of 0.05-0.5 s, 70 % hide one marker, 25 % two, 5 % all."""
    hidden = np.zeros((count, len(NAMES)), dtype=bool)
    for _ in range(int(count / rate / 3.0)):  # one run every 3 s on average
        start = int(rng.integers(0, count))
        stop = min(count, start + int(rng.uniform(0.05, 0.5) * rate))
        size = int(rng.choice([1, 2, 4], p=[0.7, 0.25, 0.05]))
        hidden[start:stop, rng.choice(len(NAMES), size, replace=False)] = True
    return hidden


def make_take(folder: Path, minutes: float, rate: float, seed: int) -> tuple[Path, Path]:
    rng = np.random.default_rng(seed)
    count = int(round(minutes * 60 * rate))
    t = (FIRST_FRAME - 1 + np.arange(count)) / rate
    centroid, rotation = truth(t)
    position = centroid[:, None, :] + np.stack([rotation.apply(b) for b in BODY], axis=1)
    position += rng.normal(0, NOISE, position.shape)
    position[occlusions(rng, count, rate)] = np.nan
    c3d = write_c3d_markers(folder / "take.c3d", MarkerFrames(t, NAMES, position))
    imu_t = np.arange(t[0] - 1.0, t[-1] + 1.0, 1 / 200.0)
    rows = np.column_stack([imu_t, np.tile([0.0, 0.0, 9.81, 0.0, 0.0, 0.0], (len(imu_t), 1))])
    imu = folder / "imu.csv"
    np.savetxt(imu, rows, delimiter=",", header="t,ax,ay,az,gx,gy,gz", comments="", fmt="%.17g")
    return c3d, imu


def best_of(repeats: int, action: Callable[[], object]) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        action()
        times.append(time.perf_counter() - start)
    return min(times)


def run(minutes: float, rate: float, repeats: int, seed: int) -> None:
    with tempfile.TemporaryDirectory() as directory:
        folder = Path(directory)
        c3d, imu = make_take(folder, minutes, rate, seed)
        markers = read_c3d_markers(c3d, NAMES).markers
        cluster = estimate_cluster(NAMES, markers.position)

        def convert() -> None:
            with contextlib.redirect_stdout(io.StringIO()):
                status = main(["convert", "c3d", str(c3d), "--imu", str(imu), "--markers",
                               ",".join(NAMES), "--out", str(folder / "rec"), "--force"])
            if status != 0:
                raise SystemExit(f"convert c3d failed with status {status}")

        stages = [
            ("read C3D (ezc3d, units, gaps)", lambda: read_c3d_markers(c3d, NAMES)),
            ("estimate cluster (Procrustes, 2 passes)",
             lambda: estimate_cluster(NAMES, markers.position)),
            ("solve poses (Kabsch per frame)",
             lambda: solve_poses(markers.position, cluster.body_positions)),
            ("kfusion convert c3d, end to end", convert),
        ]
        timings = [(label, best_of(repeats, action)) for label, action in stages]

        mocap = read_mocap(folder / "rec" / "mocap.csv")
        centroid, rotation = truth(mocap.t)
        solved = mocap.visible
        first_full = int(np.flatnonzero(markers.visible.all(axis=1))[0])
        # Converted body frame: the global axes at the first full frame, so R' = R(t) R(t1)^T.
        expected = rotation * rotation[first_full].inv()
        fitted = Rotation.from_quat(mocap.quaternion[solved], scalar_first=True)
        difference = expected[solved].inv() * fitted
        angle = np.degrees(difference.magnitude())
        # The body frame's axes come from one noisy frame: a constant offset, absorbed by the
        # mount calibration. What varies frame to frame is the error around it.
        offset = np.degrees(difference.mean().magnitude())
        varying = np.degrees((difference.mean().inv() * difference).magnitude())
        error = np.linalg.norm(mocap.position[solved] - centroid[solved], axis=1) * 1e3
        seen = markers.visible.sum(axis=1)

    print(f"C3D conversion, {minutes:g} min at {rate:g} Hz, {len(NAMES)} markers "
          f"({len(markers)} frames), {NOISE * 1e3:g} mm noise, seed {seed}; "
          f"Python {platform.python_version()}, best of {repeats}")
    print()
    print("| stage | wall time (s) |")
    print("|---|---:|")
    for label, seconds in timings:
        print(f"| {label} | {seconds:.3f} |")
    print()
    print("| frames | all 4 seen | 3 seen | < 3 seen (occluded) | solved |")
    print("|---:|---:|---:|---:|---:|")
    print(f"| {len(seen)} | {int((seen == 4).sum())} | {int((seen == 3).sum())} | "
          f"{int((seen < 3).sum())} | {int(solved.sum())} |")
    print()
    print("| pose error vs truth | median | 99th pct | max |")
    print("|---|---:|---:|---:|")
    print(f"| position (mm) | {np.median(error):.3f} | {np.percentile(error, 99):.3f} | "
          f"{error.max():.3f} |")
    print(f"| rotation (deg) | {np.median(angle):.4f} | {np.percentile(angle, 99):.4f} | "
          f"{angle.max():.4f} |")
    print(f"| rotation about its mean (deg) | {np.median(varying):.4f} | "
          f"{np.percentile(varying, 99):.4f} | {varying.max():.4f} |")
    print()
    print(f"constant rotation offset of the body frame (axes from the first full frame, noisy): "
          f"{offset:.4f} deg")


def parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="30 s take, 1 repeat")
    parser.add_argument("--minutes", type=float, default=3.0)
    parser.add_argument("--rate", type=float, default=100.0, help="Hz")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    return parser.parse_args(argv)


if __name__ == "__main__":
    arguments = parse(sys.argv[1:])
    if arguments.quick:
        arguments.minutes, arguments.repeats = 0.5, 1
    run(arguments.minutes, arguments.rate, arguments.repeats, arguments.seed)
