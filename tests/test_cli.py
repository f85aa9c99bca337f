"""The command line: every subcommand has --help; user mistakes give one line, no traceback."""

from __future__ import annotations

import pytest

from kfusion.cli import _command_modules, build_parser, main


def command_names() -> list[str]:
    return [module.NAME for module in _command_modules()]


def test_expected_commands_exist():
    assert {"check", "convert", "simulate", "track", "calibrate", "demo", "run", "sweep",
            "stream"} <= set(command_names())


@pytest.mark.parametrize("name", command_names())
def test_every_subcommand_has_help(name, capsys):
    with pytest.raises(SystemExit) as exit_info:
        main([name, "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: kfusion {name}")


def test_top_level_help_lists_commands(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["--help"])
    out = capsys.readouterr().out
    for name in command_names():
        assert name in out


def test_user_mistake_is_one_line_without_traceback(tmp_path, capsys):
    status = main(["check", str(tmp_path / "missing")])
    err = capsys.readouterr().err
    assert status == 2
    assert err.count("\n") == 1
    assert err.startswith("kfusion check: error: ")
    assert "missing" in err and "Traceback" not in err
