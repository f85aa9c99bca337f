"""The ``kfusion`` command line.

Each subcommand lives in its own module in :mod:`kfusion.commands`, which defines

* ``NAME`` (the subcommand), ``HELP`` (one line), ``ORDER`` (position in ``--help``);
* ``add_arguments(parser)`` and ``run(args) -> int``.

The modules are found at start-up, so a new command needs no edit here. A user mistake
(``ValueError``, including :class:`kfusion.recording.RecordingError`, or a missing file) prints one
line ``kfusion NAME: error: ...`` and exits with status 2, never a traceback. ``KFUSION_DEBUG=1``
shows the traceback.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys
from collections.abc import Sequence
from types import ModuleType

import kfusion
import kfusion.commands


def _command_modules() -> list[ModuleType]:
    modules = [
        importlib.import_module(f"kfusion.commands.{info.name}")
        for info in pkgutil.iter_modules(kfusion.commands.__path__)
        if not info.name.startswith("_")
    ]
    return sorted((m for m in modules if hasattr(m, "NAME")), key=lambda m: (m.ORDER, m.NAME))


def build_parser() -> argparse.ArgumentParser:
    """The top-level parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="kfusion",
        description="Fuse optical motion capture with a limb IMU through occlusions.",
    )
    parser.add_argument("--version", action="version", version=f"kfusion {kfusion.__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in _command_modules():
        sub = subparsers.add_parser(module.NAME, help=module.HELP, description=module.HELP)
        module.add_arguments(sub)
        sub.set_defaults(_run=module.run, _name=module.NAME)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``kfusion`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except (ValueError, FileNotFoundError, NotADirectoryError, FileExistsError) as error:
        if os.environ.get("KFUSION_DEBUG"):
            raise
        message = str(error).replace("\n", " ")
        print(f"kfusion {args._name}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"kfusion {args._name}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # output piped into a reader that closed early (e.g. `| head`): not an error; point
        # stdout at devnull so the interpreter's final flush does not complain either
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
