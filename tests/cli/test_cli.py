"""Tests of rfmitsuba.cli: the command table and error handling."""
import pytest

from rfmitsuba import cli


def test_every_command_registers():
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert list(sub.choices) == cli.COMMANDS


def test_info_runs(capsys, variant):
    assert cli.main(["info"]) == 0
    out = capsys.readouterr().out
    assert "libLLVM" in out and "llvm_ad_mono_polarized" in out


def test_no_command_prints_help(capsys):
    assert cli.main([]) == 2


def test_unknown_command_errors():
    with pytest.raises(SystemExit):
        cli.main(["no-such-command"])
