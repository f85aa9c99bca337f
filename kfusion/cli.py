"""The ``kfusion`` command line.

Each subcommand lives in its own module in :mod:`kfusion.commands`, which defines

* ``NAME`` (the subcommand), ``HELP`` (one line), ``ORDER`` (position in ``--help``);
* ``add_arguments(parser)`` and ``run(args) -> int``.

The modules are found at start-up, so a new command needs no edit here. A user mistake
(``ValueError``, including :class:`kfusion.recording.RecordingError`, or an ``OSError``: a missing
file, a folder given for a file, no permission, a full disk) prints one line
``kfusion NAME: error: ...`` and exits with status 2, never a traceback. ``KFUSION_DEBUG=1``
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

MAX_MESSAGE_CHARS = 2000
"""An error line is cut to this length (messages state expected and received values shortly,
but a value from a file must never flood the terminal)."""


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


def error_line(error: BaseException) -> str:
    """One line for the user: the message of a ValueError; ``FILE: reason`` for an OSError
    (missing file, a folder where a file was expected, no permission, disk full), cut to
    :data:`MAX_MESSAGE_CHARS` characters."""
    if isinstance(error, OSError) and error.strerror:
        message = f"{error.filename}: {error.strerror}" if error.filename else error.strerror
    else:
        message = str(error)
    message = " ".join(message.split())
    if len(message) > MAX_MESSAGE_CHARS:
        message = message[: MAX_MESSAGE_CHARS - 3] + "..."
    return message


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``kfusion`` console script; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except BrokenPipeError:
        # output piped into a reader that closed early (e.g. `| head`): not an error; point
        # stdout at devnull so the interpreter's final flush does not complain either
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (ValueError, OSError) as error:
        if os.environ.get("KFUSION_DEBUG"):
            raise
        print(f"kfusion {args._name}: error: {error_line(error)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"kfusion {args._name}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
