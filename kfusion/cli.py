"""The ``kfusion`` command line.

Each subcommand lives in its own module in :mod:`kfusion.commands`, which defines

* ``NAME`` (the subcommand), ``HELP`` (one line), ``ORDER`` (position in ``--help``);
* ``add_arguments(parser)`` and ``run(args) -> int``.

The modules are found at start-up, so a new command needs no edit here. Start-up reads only
``NAME``, ``HELP`` and ``ORDER`` from each module's source (literals, read with :mod:`ast`) and
imports just the module of the command being run, so ``kfusion --help`` and ``kfusion --version``
load no numerical library. A user mistake (``ValueError``, including
:class:`kfusion.recording.RecordingError`, or an ``OSError``: a missing file, a folder given for a
file, no permission, a full disk) prints one line ``kfusion NAME: error: ...`` and exits with
status 2, never a traceback. ``KFUSION_DEBUG=1``
shows the traceback.
"""

from __future__ import annotations

import argparse
import ast
import importlib
import os
import pkgutil
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

import kfusion
import kfusion.commands

MAX_MESSAGE_CHARS = 2000
"""An error line is cut to this length (messages state expected and received values shortly,
but a value from a file must never flood the terminal)."""

COMMAND_CONSTANTS = ("NAME", "HELP", "ORDER")


@dataclass(frozen=True)
class CommandSpec:
    """A subcommand as listed by ``kfusion --help``: its module and its three constants."""

    module: str
    name: str
    help: str
    order: int


def _literal_constants(path: Path) -> dict[str, object]:
    """``NAME``, ``HELP`` and ``ORDER`` assigned as literals at the top of a module's source."""
    constants: dict[str, object] = {}
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 \
                and isinstance(node.targets[0], ast.Name) \
                and node.targets[0].id in COMMAND_CONSTANTS:
            try:
                constants[node.targets[0].id] = ast.literal_eval(node.value)
            except ValueError:
                pass  # not a literal: the module is imported instead
    return constants


def command_specs() -> list[CommandSpec]:
    """Every subcommand, in ``--help`` order, read without importing the modules (a module whose
    constants are not literals is imported)."""
    specs = []
    for info in pkgutil.iter_modules(kfusion.commands.__path__):
        if info.name.startswith("_"):
            continue
        module = f"kfusion.commands.{info.name}"
        constants = _literal_constants(Path(kfusion.commands.__path__[0]) / f"{info.name}.py")
        if set(constants) != set(COMMAND_CONSTANTS):
            imported = importlib.import_module(module)
            if not hasattr(imported, "NAME"):
                continue
            constants = {key: getattr(imported, key) for key in COMMAND_CONSTANTS}
        specs.append(CommandSpec(module, str(constants["NAME"]), str(constants["HELP"]),
                                 int(str(constants["ORDER"]))))
    return sorted(specs, key=lambda spec: (spec.order, spec.name))


def _command_modules() -> list[ModuleType]:
    """Every subcommand's module, imported (for tests and tools that need them all)."""
    return [importlib.import_module(spec.module) for spec in command_specs()]


def _chosen_command(argv: Sequence[str]) -> str | None:
    """The subcommand named in ``argv``: its first argument not starting with ``-`` (the
    top-level options ``--help`` and ``--version`` take no value)."""
    return next((argument for argument in argv if not argument.startswith("-")), None)


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The top-level parser. Every subcommand is listed; with ``argv`` only the one it names is
    imported and given its arguments, without it all are."""
    parser = argparse.ArgumentParser(
        prog="kfusion",
        description="Fuse optical motion capture with a limb IMU through occlusions.",
    )
    parser.add_argument("--version", action="version", version=f"kfusion {kfusion.__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    chosen = None if argv is None else _chosen_command(argv)
    for spec in command_specs():
        sub = subparsers.add_parser(spec.name, help=spec.help, description=spec.help)
        if argv is None or spec.name == chosen:
            module = importlib.import_module(spec.module)
            module.add_arguments(sub)
            sub.set_defaults(_run=module.run, _name=spec.name)
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
    arguments = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(arguments)
    args = parser.parse_args(arguments)
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
