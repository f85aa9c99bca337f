"""``kfusion simulate SCENARIO --seed N --out DIR``: write a simulated recording plus truth.csv."""

from __future__ import annotations

import argparse

import numpy as np

from kfusion.guards import finite_float
from kfusion.recording import occlusion_durations
from kfusion.simulate import (
    PLACEMENTS,
    SCENARIOS,
    MarkerSpec,
    OcclusionSpec,
    simulate,
    write_simulation,
)

NAME = "simulate"
HELP = "Simulate a forearm scenario and write a recording folder plus truth.csv."
ORDER = 20


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenario", metavar="SCENARIO",
                        help=f"scenario name: {', '.join(SCENARIOS)}")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="output recording folder (created; existing files are replaced)")
    parser.add_argument("--imu", default="mpu9255",
                        help="IMU profile: mpu9255, um7 or broad (default: mpu9255)")
    parser.add_argument("--gap-min", type=finite_float, default=0.1, metavar="S",
                        help="shortest occlusion, s (default: 0.1)")
    parser.add_argument("--gap-max", type=finite_float, default=0.3, metavar="S",
                        help="longest occlusion, s (default: 0.3)")
    parser.add_argument("--placement", default="random", choices=PLACEMENTS,
                        help="where occlusions fall: random, mid_motion (Type 1, at speed) or "
                        "direction_change (Type 2, where the arm turns round) (default: random)")
    parser.add_argument("--spacing", type=finite_float, default=1.5, metavar="S",
                        help="visible mocap required before each occlusion, s (default: 1.5)")
    parser.add_argument("--markers", action="store_true",
                        help="simulate a 4-marker cluster: occlusions hide some of its markers "
                        "(most one or two), markers.csv and recording.yaml markers: are written "
                        "and mocap.csv is the rigid body where 3 or more markers are seen")
    parser.add_argument("--c3d", metavar="FILE.c3d", default=None,
                        help="with --markers: also write the simulated markers as a C3D file "
                        "(needs ezc3d)")
    parser.add_argument("--duration", type=finite_float, default=None, metavar="S",
                        help="length of the simulation, s (default: the scenario's, 30-45 s)")


def run(args: argparse.Namespace) -> int:
    spec = OcclusionSpec(gap_range=(args.gap_min, args.gap_max), placement=args.placement,
                         spacing=args.spacing)
    if args.c3d is not None and not args.markers:
        raise ValueError("--c3d: expected --markers too (a C3D file holds markers)")
    simulation = simulate(args.scenario, seed=args.seed, imu=args.imu, occlusions=spec,
                          duration=args.duration, markers=MarkerSpec() if args.markers else None)
    folder = write_simulation(simulation, args.out)
    recording = simulation.recording
    if recording.markers is not None:
        visible = recording.markers.visible.sum(axis=1)
        counts = ", ".join(f"{int(np.sum(visible == k))} with {k}" for k in range(
            recording.markers.visible.shape[1]))
        print(f"markers: {', '.join(recording.markers.names)}; frames with fewer than all "
              f"markers seen: {counts}")
        if args.c3d is not None:
            from kfusion.readers.c3d import up_axis, write_c3d_markers

            written = write_c3d_markers(args.c3d, recording.markers,
                                        up_axis=up_axis(recording.info.gravity))
            print(f"wrote {written}")
    durations = occlusion_durations(recording.mocap.t, recording.mocap.visible)
    print(f"wrote {folder}: {args.scenario} seed {args.seed}, {recording.imu.t[-1]:.1f} s, "
          f"{len(recording.imu)} IMU samples ({recording.info.imu}), {len(recording.mocap)} "
          f"mocap frames with {len(durations)} occlusions of {np.min(durations):.2f}-"
          f"{np.max(durations):.2f} s ({args.placement}), truth.csv")
    return 0
