"""``kfusion convert {motive,c3d,broad} SOURCE --out DIR``: turn a real format into a recording.

* ``motive TAKE.csv --imu IMU.csv``: an OptiTrack Motive CSV export (one rigid body) plus an IMU
  file in the ``imu.csv`` layout on the same clock. Motive's world is y-up by default, hence the
  default gravity ``[0, -9.81, 0]``. The IMU mount is never guessed: without ``--imu-to-body``
  ``recording.yaml`` has no ``imu_to_body`` and the command prints the next step,
  ``kfusion calibrate DIR --out DIR/recording.yaml --force``. With ``--markers A,B,C`` the export's
  ``Marker`` columns of those names are written to ``markers.csv`` too, and their body-frame
  positions (relative to Motive's rigid body) to ``recording.yaml``'s ``markers``.
* ``c3d FILE.c3d --imu IMU.csv --markers M1,M2,M3[,...]``: the named markers of a C3D file
  (:mod:`kfusion.readers.c3d`). The body frame and the marker positions in it are estimated from
  the frames where all markers are seen, and the rigid-body pose is solved by Kabsch in each
  frame where 3 or more are (:mod:`kfusion.rigid_body`); other frames are occluded. Writes
  ``mocap.csv``, ``markers.csv`` and ``recording.yaml`` with ``markers``; the IMU and the mount
  are handled as for ``motive``. ``--body NAME`` takes the labels ``NAME:...``.
* Several bodies of one C3D file: ``--imu BODY=IMU.csv`` once per body (every body needs its own
  IMU), with ``--body BODY`` repeated, ``--all-bodies`` (every label prefix) or neither (the
  bodies named by ``--imu``). Each body is written to ``DIR/BODY/``, without ``imu_to_body``
  (calibrate each). Every folder is checked and every body converted before any is written.
* ``broad FILE.mat``: a BROAD trial; ``--mocap-step 3`` keeps every 3rd mocap frame (~95 Hz).

The files written are read back and validated (as ``kfusion check`` does) before the summary is
printed. A folder converted with its mount given passes ``kfusion check`` at once; one without
passes it once ``kfusion calibrate`` has written the mount.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from kfusion.commands.check import summarise
from kfusion.conventions import OPTITRACK_GRAVITY, Z_UP_GRAVITY
from kfusion.guards import finite_float
from kfusion.profiles import imu_profile
from kfusion.readers.broad import read_broad
from kfusion.readers.c3d import (
    C3dMarkers,
    labelled_bodies,
    read_c3d_labels,
    read_c3d_markers,
)
from kfusion.readers.markers import parse_marker_names
from kfusion.readers.motive import read_motive_csv, read_motive_markers
from kfusion.recording import (
    IMU_FILE,
    MARKERS_FILE,
    META_FILE,
    MOCAP_FILE,
    ImuSamples,
    MarkerFrames,
    MocapFrames,
    Recording,
    info_to_dict,
    parse_info,
    read_imu,
    read_markers,
    read_mocap,
    read_recording,
    write_recording,
)
from kfusion.rigid_body import (
    DEFAULT_MAX_RESIDUAL,
    MIN_MARKERS,
    estimate_cluster,
    markers_in_body_frame,
    solve_poses,
)

NAME = "convert"
HELP = ("Convert an OptiTrack Motive CSV export or a C3D file (plus an IMU file), or a BROAD "
        "trial, to a recording.")
ORDER = 20

COMMAND_LINE = "command line"
"""File name used in error messages about values given as options."""


def _add_output(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="DIR", help="recording folder to write")
    parser.add_argument("--force", action="store_true",
                        help="overwrite a recording already in DIR")


def _add_imu_options(parser: argparse.ArgumentParser, body: str, *,
                     several_bodies: bool = False) -> None:
    """The IMU file and the recording.yaml options shared by ``motive`` and ``c3d``
    (``several_bodies``: ``--imu`` may be repeated as ``BODY=IMU.csv``)."""
    if several_bodies:
        parser.add_argument("--imu", required=True, action="append", metavar="[BODY=]IMU.csv",
                            help="IMU samples: t, ax, ay, az, gx, gy, gz (s, m/s^2, rad/s); "
                            "for several bodies BODY=IMU.csv, once per body (each body needs "
                            "its own IMU)")
    else:
        parser.add_argument("--imu", required=True, metavar="IMU.csv",
                            help="IMU samples: t, ax, ay, az, gx, gy, gz (s, m/s^2, rad/s)")
    parser.add_argument("--imu-to-body", nargs=4, type=finite_float, metavar=("W", "X", "Y", "Z"),
                        help=f"unit quaternion IMU -> {body}, if known (default: left out "
                        "of recording.yaml; then run kfusion calibrate DIR --out "
                        "DIR/recording.yaml --force)")
    parser.add_argument("--lever-arm", nargs=3, type=finite_float, metavar=("X", "Y", "Z"),
                        help=f"IMU position in the {body} frame, m (optional)")
    parser.add_argument("--imu-profile", metavar="NAME",
                        help="IMU profile name written as recording.yaml's imu (optional)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    formats = parser.add_subparsers(dest="format", metavar="FORMAT", required=True)

    motive = formats.add_parser("motive", help="OptiTrack Motive CSV export + imu.csv-style file",
                                description="Convert one rigid body of a Motive CSV export "
                                "(Rotation Type Quaternion; Length Units converted to m) and an "
                                "IMU file in the imu.csv layout (t, ax, ay, az, gx, gy, gz on the "
                                "mocap clock; s, m/s^2, rad/s).")
    motive.add_argument("take", metavar="TAKE.csv", help="Motive CSV export")
    _add_imu_options(motive, "rigid body")
    motive.add_argument("--rigid-body", metavar="NAME",
                        help="rigid body to read (default: the only one in the export)")
    motive.add_argument("--gravity", nargs=3, type=finite_float, metavar=("GX", "GY", "GZ"),
                        default=list(OPTITRACK_GRAVITY),
                        help="gravity in the mocap world, m/s^2 (default: y-up 0 -9.81 0)")
    motive.add_argument("--name", help="recording name (default: the take file's stem)")
    motive.add_argument("--zeros-occluded", action="store_true",
                        help="read a position of exactly (0, 0, 0) as occluded (rigid body and "
                        "markers)")
    motive.add_argument("--markers", metavar="M1,M2,...",
                        help="also write these markers ('Marker' columns; a name matches a "
                        "label or the part after its ':') to markers.csv (optional)")
    _add_output(motive)
    motive.set_defaults(_convert=_convert_motive)

    c3d = formats.add_parser("c3d", help="C3D file (markers) + imu.csv-style file",
                             description="Convert the markers of one rigid cluster in a C3D file "
                             "(POINT:UNITS converted to m; frame i at (first_frame - 1 + i) / "
                             "rate s; residual < 0 or exactly 0, 0, 0 is occluded) and an IMU "
                             "file in the imu.csv layout on the same clock. Solves the rigid-body "
                             "pose by Kabsch wherever 3 or more of the markers are seen; the "
                             "rigid body's origin is the markers' centroid, its axes the global "
                             "axes at the first frame where all are seen. Several bodies (labels "
                             "BODY:NAME): --imu BODY=IMU.csv for each, with --body BODY "
                             "repeated or --all-bodies; each is written to DIR/BODY. Needs ezc3d "
                             "(pip install 'kfusion[c3d]').")
    c3d.add_argument("c3d", metavar="FILE.c3d", help="C3D file")
    c3d.add_argument("--markers", metavar="M1,M2,M3[,...]",
                     help="the cluster's markers, 3 or more (a name matches a POINT:LABELS "
                     "label, or the part after its last ':'); required for one body without --body")
    c3d.add_argument("--body", metavar="NAME", action="append",
                     help="one body's markers: the labels NAME:... (all of them, or those of "
                     "--markers); repeat it for several bodies, with --imu NAME=IMU.csv each")
    c3d.add_argument("--all-bodies", action="store_true",
                     help="convert every body of the file (every prefix NAME of a label "
                     "NAME:...), with --imu NAME=IMU.csv for each")
    _add_imu_options(c3d, "rigid body", several_bodies=True)
    c3d.add_argument("--gravity", nargs=3, type=finite_float, metavar=("GX", "GY", "GZ"),
                     help="gravity in the mocap world, m/s^2 (default: minus the file's "
                     "POINT:Y_SCREEN axis, else z-up 0 0 -9.81 as Vicon and Qualisys)")
    c3d.add_argument("--max-residual", type=finite_float, default=DEFAULT_MAX_RESIDUAL * 1e3,
                     metavar="MM", help="a frame whose worst marker misses the fitted cluster by "
                     "more is left occluded (a swapped marker), mm (default %(default)g)")
    c3d.add_argument("--keep-unmeasured", action="store_true",
                     help="keep points whose residual is 0 in a file that gives measured ones a "
                     "positive residual (the C3D mark of an interpolated or filtered point; "
                     "default: read as occluded, since kfusion fills gaps itself). For an "
                     "exporter whose residuals round to 0 at its POINT:SCALE")
    c3d.add_argument("--name", help="recording name (default: the file's stem; for several "
                     "bodies NAME-BODY)")
    _add_output(c3d)
    c3d.set_defaults(_convert=_convert_c3d)

    broad = formats.add_parser("broad", help="BROAD trial (.mat)",
                               description="Convert a BROAD trial: gravity [0, 0, -9.81], "
                               "imu_to_body identity, dropouts where opt_quat is NaN.")
    broad.add_argument("trial", metavar="FILE.mat", help="BROAD trial file")
    broad.add_argument("--mocap-step", type=int, default=1, metavar="N",
                       help="keep every N-th mocap frame (default 1: 285.7 Hz; 3: ~95 Hz)")
    _add_output(broad)
    broad.set_defaults(_convert=_convert_broad)


def check_same_clock(imu: ImuSamples, mocap: MocapFrames) -> None:
    """ValueError unless the IMU and mocap time spans overlap (both must be on one clock, s)."""
    if imu.t[-1] < mocap.t[0] or mocap.t[-1] < imu.t[0]:
        raise ValueError(f"IMU times {imu.t[0]:.3f}..{imu.t[-1]:.3f} s do not overlap the mocap "
                         f"times {mocap.t[0]:.3f}..{mocap.t[-1]:.3f} s; expected both on one "
                         "clock (shift the IMU file's t)")


UNKNOWN_MOUNT_PLACEHOLDER = (1.0, 0.0, 0.0, 0.0)
"""Validates the other options when --imu-to-body is absent; never written to a file."""


def next_step(folder: Path) -> str:
    """What to run after converting without ``--imu-to-body``."""
    return (f"imu_to_body: not given, left out of {folder / META_FILE}; next: kfusion calibrate "
            f"{folder} --out {folder / META_FILE} --force (it adds the mount to the file written "
            f"here; or convert again with --imu-to-body W X Y Z "
            f"if the mount is known), then kfusion check {folder}")


def _with_imu(args: argparse.Namespace, source: Path, mocap: MocapFrames,
              gravity: Sequence[float], markers: MarkerFrames | None = None,
              body_positions: dict[str, list[float]] | None = None) -> Recording:
    """The recording of ``mocap`` with the ``--imu`` file and the recording.yaml options."""
    imu = read_imu(args.imu)
    check_same_clock(imu, mocap)
    if args.imu_profile is not None:
        imu_profile(args.imu_profile)  # ValueError listing the known profiles
    mount = args.imu_to_body if args.imu_to_body is not None else UNKNOWN_MOUNT_PLACEHOLDER
    options = {"imu_to_body": mount, "gravity": list(gravity),
               "name": args.name or source.stem, "imu": args.imu_profile,
               "lever_arm": args.lever_arm, "markers": body_positions}
    info = parse_info(options, COMMAND_LINE)
    return Recording(imu=imu, mocap=mocap, info=info, source=str(source), markers=markers)


def _convert_motive(args: argparse.Namespace) -> tuple[Recording, list[str]]:
    take = Path(args.take)
    mocap = read_motive_csv(take, rigid_body=args.rigid_body,
                            zero_position_means_occluded=args.zeros_occluded)
    if args.markers is None:
        return _with_imu(args, take, mocap, args.gravity), []
    markers = read_motive_markers(take, parse_marker_names(args.markers),
                                  zero_position_means_occluded=args.zeros_occluded)
    body = markers_in_body_frame(mocap, markers)
    notes = [f"markers: {len(markers.names)} ({', '.join(markers.names)}); body-frame positions "
             f"from {body.frames} frames with the rigid body and the marker seen, their spread "
             f"at most {body.spread.max() * 1e3:.2f} mm (RMS)"]
    positions = {name: [float(v) for v in position]
                 for name, position in zip(markers.names, body.positions, strict=True)}
    return _with_imu(args, take, mocap, args.gravity, markers, positions), notes


def _unmeasured_note(take: C3dMarkers, keep_unmeasured: bool) -> str:
    """What the reader did with the samples of residual 0 (not measured), for the summary."""
    if take.interpolated:
        return (f"{take.interpolated} not measured (residual 0: interpolated or filtered by the "
                "exporter) read as occluded (--keep-unmeasured keeps them)")
    if take.residuals_quantised:
        return ("residuals quantised at POINT:SCALE (a 0 may be a measured point rounded "
                "down): residual-0 samples kept")
    if not take.residuals_given:
        return "no residuals in the file (measured and gap-filled samples look alike)"
    return "residual-0 samples kept (--keep-unmeasured)" if keep_unmeasured \
        else "none not measured"


def _convert_c3d(args: argparse.Namespace) -> tuple[Recording, list[str]]:
    path = Path(args.c3d)
    if args.markers is None and args.body is None:
        raise ValueError(f"{COMMAND_LINE}: expected --markers M1,M2,M3[,...] (the cluster's "
                         "markers) or --body NAME (the labels NAME:...)")
    names = None if args.markers is None else parse_marker_names(args.markers)
    if not args.max_residual > 0:
        raise ValueError(f"{COMMAND_LINE}: --max-residual {args.max_residual!r}; expected a "
                         "positive number of mm")
    take = read_c3d_markers(path, names, body=args.body, keep_unmeasured=args.keep_unmeasured)
    markers = take.markers
    if len(markers.names) < MIN_MARKERS:
        raise ValueError(f"{COMMAND_LINE}: {len(markers.names)} marker(s) "
                         f"{list(markers.names)}; expected {MIN_MARKERS} or more to solve a rigid "
                         "body's pose")
    try:
        cluster = estimate_cluster(markers.names, markers.position,
                                   max_residual=args.max_residual * 1e-3)
    except ValueError as error:
        hint = (f" ({take.interpolated} samples with residual 0 were read as not measured: "
                "--keep-unmeasured keeps them)") if take.interpolated else ""
        raise ValueError(f"{path.name}: {error}{hint}") from None
    poses = solve_poses(markers.position, cluster.body_positions,
                        max_residual=args.max_residual * 1e-3)
    mocap = MocapFrames(t=markers.t, position=poses.position, quaternion=poses.quaternion)
    if args.gravity is not None:
        gravity, origin = list(args.gravity), "--gravity"
    elif take.gravity is not None:
        gravity, origin = list(take.gravity), "the file's POINT:Y_SCREEN (up axis)"
    else:
        gravity, origin = list(Z_UP_GRAVITY), ("no POINT:Y_SCREEN in the file: z-up assumed "
                                               "(give --gravity if the lab's world is not)")
    solved = int(poses.solved.sum())
    residual = poses.residual[poses.solved]
    notes = [
        f"c3d: {len(markers)} frames at {take.rate:g} Hz from frame {take.first_frame} "
        f"(t = {markers.t[0]:.6g} s), POINT:UNITS {take.units}; {take.residual_flagged} marker "
        f"samples flagged invalid, {take.zero_filled} zero-filled, "
        f"{_unmeasured_note(take, args.keep_unmeasured)}",
        cluster.rigidity_line(),
        f"solvable frames: {solved} of {len(markers)} ({100 * solved / len(markers):.1f} %) with "
        f">= {MIN_MARKERS} markers seen; {int(poses.rejected.sum())} refused (fit residual > "
        f"{args.max_residual:g} mm or collinear markers)"
        + (f"; fit residual median {np.median(residual) * 1e3:.2f} mm, max "
           f"{residual.max() * 1e3:.2f} mm" if solved else ""),
        f"gravity: {gravity} m/s^2 from {origin}",
    ]
    positions = {name: [float(v) for v in position]
                 for name, position in zip(markers.names, cluster.body_positions, strict=True)}
    return _with_imu(args, path, mocap, gravity, markers, positions), notes


@dataclass(frozen=True)
class C3dBodies:
    """The bodies of a several-body ``convert c3d``: body name -> its IMU file, in order."""

    imu: dict[str, str]
    ignored: tuple[str, ...] = ()
    """--all-bodies: the labels without a ``BODY:`` prefix, which belong to no body."""


def split_imu_options(values: Sequence[str]) -> tuple[str | None, dict[str, str]]:
    """``--imu`` values -> (the one plain IMU file or None, {BODY: IMU file}).

    A value ``BODY=FILE`` names a body's IMU unless it is itself an existing file. Plain files
    and ``BODY=FILE`` cannot be mixed; a plain file is given once, each body once.
    """
    plain: list[str] = []
    per_body: dict[str, str] = {}
    for value in values:
        body, separator, file = value.partition("=")
        if not separator or Path(value).is_file():
            plain.append(value)
            continue
        if not body or not file:
            raise ValueError(f"{COMMAND_LINE}: --imu {value!r}; expected BODY=IMU.csv with a "
                             "body name and a file")
        if body in per_body:
            raise ValueError(f"{COMMAND_LINE}: --imu names body {body!r} twice; expected one "
                             "IMU file per body")
        per_body[body] = file
    if plain and per_body:
        raise ValueError(f"{COMMAND_LINE}: --imu {plain[0]!r} and --imu "
                         f"{next(iter(per_body))}=...: expected either one IMU file (one body) "
                         "or BODY=IMU.csv for every body")
    if len(plain) > 1:
        raise ValueError(f"{COMMAND_LINE}: --imu given {len(plain)} times without BODY=; "
                         "expected one IMU file, or BODY=IMU.csv for each of several bodies")
    return (plain[0] if plain else None), per_body


def folder_name_problem(body: str) -> str | None:
    """Why a body name cannot name its recording folder (None when it can)."""
    if body in ("", ".", "..") or any(c in body for c in "/\\") or not body.isprintable() \
            or body != body.strip():
        return (f"body {body!r} cannot name a folder; expected a name without '/', '\\', "
                "leading or trailing spaces")
    return None


def plan_c3d_bodies(args: argparse.Namespace) -> C3dBodies | None:
    """Resolve ``--imu``, ``--body`` and ``--all-bodies`` of ``convert c3d``.

    One plain ``--imu FILE`` converts one body (at most one ``--body``) into ``--out``: returns
    None and leaves ``args.imu`` a file and ``args.body`` a name or None. ``--imu BODY=FILE``
    (or ``--all-bodies``) converts several, each into ``--out/BODY``: returns the bodies, which
    are those of ``--body``, else every body of the file with ``--all-bodies``, else those of
    ``--imu``; each must have exactly one IMU file. ValueError naming the body at fault.
    """
    imu, per_body = split_imu_options(args.imu)
    bodies = list(args.body or [])
    if len(set(bodies)) != len(bodies):
        raise ValueError(f"{COMMAND_LINE}: --body names {bodies} repeat a body; expected each "
                         "body once")
    if args.all_bodies and bodies:
        raise ValueError(f"{COMMAND_LINE}: --all-bodies and --body {bodies[0]}: expected one "
                         "of them")
    if imu is not None:
        if args.all_bodies or len(bodies) > 1:
            chosen = "--all-bodies" if args.all_bodies else f"--body {' --body '.join(bodies)}"
            raise ValueError(f"{COMMAND_LINE}: {chosen} with one --imu {imu}: every body needs "
                             "its own IMU; expected --imu BODY=IMU.csv for each body")
        args.imu, args.body = imu, (bodies[0] if bodies else None)
        return None
    if args.imu_to_body is not None or args.lever_arm is not None:
        option = "--imu-to-body" if args.imu_to_body is not None else "--lever-arm"
        raise ValueError(f"{COMMAND_LINE}: {option} describes one body's IMU; with several "
                         "bodies leave it out and run kfusion calibrate on each body's folder "
                         "(or convert the bodies one at a time)")
    ignored: tuple[str, ...] = ()
    if args.all_bodies:
        labels = read_c3d_labels(args.c3d)
        bodies = list(labelled_bodies(Path(args.c3d).name, labels))
        ignored = tuple(label for label in labels if ":" not in label)
    elif not bodies:
        bodies = list(per_body)
    for body in bodies:
        problem = folder_name_problem(body)
        if problem is not None:
            raise ValueError(f"{COMMAND_LINE}: {problem}")
        if body not in per_body:
            raise ValueError(f"{COMMAND_LINE}: body {body!r} has no IMU file; expected --imu "
                             f"{body}=IMU.csv (every body needs its own IMU)")
    shared = [(first, second) for index, first in enumerate(bodies) for second in bodies[index + 1:]
              if Path(per_body[first]).resolve() == Path(per_body[second]).resolve()]
    if shared:
        first, second = shared[0]
        raise ValueError(f"{COMMAND_LINE}: --imu {first}= and --imu {second}= name the same file "
                         f"{per_body[first]}; expected one IMU per body (one sensor cannot be on "
                         "both)")
    extra = [body for body in per_body if body not in bodies]
    if extra:
        raise ValueError(f"{COMMAND_LINE}: --imu {extra[0]}=...: no body {extra[0]!r} among the "
                         f"bodies converted {bodies}")
    return C3dBodies(imu={body: per_body[body] for body in bodies}, ignored=ignored)


def _convert_c3d_bodies(args: argparse.Namespace, bodies: C3dBodies) -> int:
    """Convert several bodies of a C3D file, each into ``--out/BODY``: every folder is checked
    and every body converted in memory before the first folder is written."""
    out = Path(args.out)
    for body in bodies.imu:
        check_output_folder(out / body, args.force)
    stem = args.name or Path(args.c3d).stem
    converted = []
    for body, imu in bodies.imu.items():
        options = argparse.Namespace(**{**vars(args), "imu": imu, "body": body,
                                        "name": f"{stem}-{body}"})
        try:
            converted.append((body, *_convert_c3d(options)))
        except ValueError as error:
            raise ValueError(f"body {body!r}: {error}") from None
    if bodies.ignored:
        print(f"--all-bodies: ignored {len(bodies.ignored)} label(s) without a BODY: prefix "
              f"(no body): {', '.join(bodies.ignored)}")
    for body, recording, notes in converted:
        written = write_without_mount(recording, out / body)
        print(f"c3d: body {body}: wrote {out / body}")
        for note in notes:
            print(note)
        print(summarise(written))
    print(f"{len(converted)} bodies ({', '.join(bodies.imu)}) in {out}; imu_to_body left out of "
          f"each {META_FILE}; next: kfusion calibrate {out / 'BODY'} --out "
          f"{out / 'BODY' / META_FILE} --force for each body, then kfusion track {out} --out "
          "TRACKS/ (one track per body)")
    return 0


def _convert_broad(args: argparse.Namespace) -> tuple[Recording, list[str]]:
    return read_broad(args.trial, mocap_step=args.mocap_step), []


def check_output_folder(folder: Path, force: bool) -> None:
    """Refuse to overwrite an existing recording unless ``force``; FileExistsError otherwise."""
    existing = [name for name in (IMU_FILE, MOCAP_FILE, META_FILE, MARKERS_FILE)
                if (folder / name).exists()]
    if existing and not force:
        raise FileExistsError(f"{folder} already holds {', '.join(existing)}; expected a new or "
                              "empty folder (use --force to overwrite)")
    if folder.exists() and not folder.is_dir():
        raise FileExistsError(f"{folder} exists and is not a folder; expected a folder path")


def write_without_mount(recording: Recording, folder: Path) -> Recording:
    """Write the folder with ``recording.yaml`` lacking ``imu_to_body``; returns the CSVs read
    back (validated as ``kfusion check`` does) with the in-memory metadata."""
    write_recording(recording, folder)
    metadata = {key: value for key, value in info_to_dict(recording.info).items()
                if key != "imu_to_body"}
    (folder / META_FILE).write_text(yaml.safe_dump(metadata, sort_keys=False))
    markers = None if recording.markers is None else read_markers(folder / MARKERS_FILE)
    return Recording(imu=read_imu(folder / IMU_FILE), mocap=read_mocap(folder / MOCAP_FILE),
                     info=recording.info, source=str(folder), markers=markers)


def run(args: argparse.Namespace) -> int:
    if args.format == "c3d":
        bodies = plan_c3d_bodies(args)
        if bodies is not None:
            return _convert_c3d_bodies(args, bodies)
    folder = Path(args.out)
    check_output_folder(folder, args.force)
    recording, notes = args._convert(args)
    mount_unknown = args.format in ("motive", "c3d") and args.imu_to_body is None
    if mount_unknown:
        written = write_without_mount(recording, folder)
    else:
        write_recording(recording, folder)
        # Read back with the folder reader, so what was written is exactly what `check` accepts.
        written = read_recording(folder)
    print(f"{args.format}: wrote {folder}")
    for note in notes:
        print(note)
    print(summarise(written))
    print(next_step(folder) if mount_unknown else f"next: kfusion check {folder}, then "
          f"kfusion track {folder} --method kalman --out track.csv")
    return 0
