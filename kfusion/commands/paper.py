"""``kfusion paper``: the paper's two tables, reproduced with the baseline on the simulator.

A thin driver of :func:`kfusion.paper.reproduce` (experiment design and definitions there): it
writes the tables as CSV and the markdown report, and prints the report.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from kfusion.experiment import write_table_csv
from kfusion.guards import atomic_write_text, finite_float

NAME = "paper"
HELP = "Reproduce the paper's Table 1 and use-case table with the baseline on the simulator."
ORDER = 80


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seeds", type=int, default=5,
                        help="number of experiments (simulation seeds 1..N) for each table "
                        "(default 5, as the paper's Table 1)")
    parser.add_argument("--out", default="paper-output", metavar="DIR",
                        help="folder for table1.csv, use_case.csv, per_gap.csv and report.md "
                        "(default: paper-output)")
    parser.add_argument("--duration", type=finite_float, default=None, metavar="S",
                        help="length of each simulation, s (at least 5; default: the "
                        "scenario's, 40 s arm lift and 45 s pick tool)")


def run(args: argparse.Namespace) -> int:
    from kfusion.paper import report, reproduce

    run_tables = reproduce(args.seeds, args.duration)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_table_csv(run_tables.table1, out / "table1.csv", index=False)
    write_table_csv(run_tables.use_case, out / "use_case.csv", index=False)
    write_table_csv(run_tables.per_gap, out / "per_gap.csv", index=False)
    text = report(run_tables, args.seeds, args.duration)
    atomic_write_text(out / "report.md", text)
    print(text)
    print(f"wrote {out}/: table1.csv, use_case.csv, per_gap.csv, report.md")
    return 0
