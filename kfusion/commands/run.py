"""``kfusion run CONFIG``: run one experiment from a YAML config.

Prints the gap-error table per gap and aggregated per method, and writes ``summary.csv``,
``per_recording.csv``, ``per_gap.csv`` and PNG figures (trajectory with gaps, error against gap
length) to the output folder.
"""

from __future__ import annotations

import argparse

from kfusion.config import QUICK_RECORDING_S, QUICK_SIMULATION_S, load_run_config
from kfusion.experiment import format_table
from kfusion.sweep import run_experiment

NAME = "run"
HELP = "Run one experiment from a YAML config; print gap-error tables, write CSVs and PNG plots."
ORDER = 50


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", metavar="CONFIG", help="run config (YAML), e.g. "
                        "configs/arm_lift_type1.yaml")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the config's "
                        "output.directory, else kfusion-output/<name>)")
    parser.add_argument("--quick", action="store_true",
                        help=f"smoke run on small data: first seed, {QUICK_SIMULATION_S:g} s "
                        f"simulations, {QUICK_RECORDING_S:g} s of the first real recording")
    parser.add_argument("--gap-rows", type=int, default=40, metavar="N",
                        help="gaps shown in the per-gap table (all are in per_gap.csv; "
                        "default 40)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    config = load_run_config(args.config, quick=args.quick)
    directory = config.output_directory(args.out)
    result = run_experiment(config, progress=not args.no_progress)
    gaps = result.per_gap_wide(config.output.plots.metric)
    print(f"{config.name}: {len(result.recordings)} recording(s), seeds {config.seeds}, "
          f"methods {list(config.methods)}, {result.seconds:.1f} s"
          + (" [quick]" if config.quick else ""))
    print()
    print(f"Per gap ({config.output.plots.metric}):")
    if gaps.empty:
        print("(no gaps)")
    else:
        print(gaps.head(args.gap_rows).to_string(index=False, float_format="{:.3f}".format))
        if len(gaps) > args.gap_rows:
            print(f"... {len(gaps) - args.gap_rows} more gaps in per_gap.csv")
    print()
    print("Aggregated over all gap samples (coverage = fraction inside 3 sigma):")
    print(format_table(result.summary()))
    written = result.write(directory)
    print()
    print(f"wrote {directory}/: " + ", ".join(path.name for path in written))
    return 0
