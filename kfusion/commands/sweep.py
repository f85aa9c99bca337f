"""``kfusion sweep CONFIG --out DIR``: run a grid of experiments from a YAML sweep config.

Each finished run is written to ``DIR/runs/`` as it finishes; a rerun skips finished runs. At the
end ``DIR/results.parquet`` (one row per grid point and seed), ``DIR/summary.csv`` and heat maps
are written. Runs use local processes, or a Dask cluster with ``--scheduler ADDRESS``.
"""

from __future__ import annotations

import argparse
import sys

from kfusion.config import load_sweep_config
from kfusion.guards import finite_float
from kfusion.sweep import SweepStore, format_summary, plan_sweep, run_sweep

NAME = "sweep"
HELP = "Run a parameter grid from a YAML sweep config; write a Parquet results table."
ORDER = 60
SHOWN_FAILURES = 5


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", metavar="CONFIG", help="sweep config (YAML with a grid)")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: the config's "
                        "output.directory, else kfusion-output/<name>)")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="local worker processes (default: number of CPUs)")
    parser.add_argument("--scheduler", metavar="ADDRESS",
                        help="run on a Dask distributed cluster, e.g. tcp://scheduler-host:8786")
    parser.add_argument("--scheduler-timeout", type=finite_float, default=20.0, metavar="SECONDS",
                        help="how long to try connecting to the scheduler (default 20 s)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: first two values per grid axis, first seed, small data")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    config = load_sweep_config(args.config, quick=args.quick)
    directory = config.output_directory(args.out)
    tasks, skipped = plan_sweep(config, SweepStore(directory))
    pending = len(tasks)
    where = f"Dask scheduler {args.scheduler}" if args.scheduler else "local processes"
    print(f"{config.name}: {len(config.points)} grid points x {len(config.seeds)} seed(s); "
          f"{pending + skipped} distinct runs, {skipped} already done (skipped), {pending} to run "
          f"on {where}" + (" [quick]" if config.base.quick else ""))
    result = run_sweep(config, directory, workers=args.workers, scheduler=args.scheduler,
                       scheduler_timeout_s=args.scheduler_timeout,
                       progress=not args.no_progress)
    print(f"ran {result.ran}, skipped {result.skipped}, failed {len(result.failed)}")
    for name, error in result.failed[:SHOWN_FAILURES]:
        print(f"failed: {name}: {error}", file=sys.stderr)
    if len(result.failed) > SHOWN_FAILURES:
        print(f"... {len(result.failed) - SHOWN_FAILURES} more failures", file=sys.stderr)
    if not result.summary.empty:
        print()
        print("Summary (mean over seeds):")
        print(format_summary(result.summary))
    print()
    files = ["runs/", "results.parquet", "summary.csv", *(p.name for p in result.figures)]
    print(f"wrote {directory}/: " + ", ".join(files))
    return 1 if result.failed else 0
