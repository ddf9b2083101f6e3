"""CLI ``rfmitsuba reproduce``: resumes a finished run, refuses another configuration."""
from __future__ import annotations


def test_cli_resumes_finished_run(tiny_reproduction, capsys):
    from rfmitsuba.cli import main

    out, _, report, _ = tiny_reproduction
    assert main(["reproduce", "--size", "tiny", "--out", str(out), "--quiet"]) == 0
    assert f"report: {report}" in capsys.readouterr().out


def test_cli_other_config_error(tiny_reproduction, capsys):
    from rfmitsuba.cli import main

    out, _, _, _ = tiny_reproduction
    assert main(["reproduce", "--size", "tiny", "--out", str(out), "--set", "train.batch_views=3", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "another experiment configuration" in err and "train.batch_views" in err


def test_cli_bad_arguments(tmp_path, capsys):
    from rfmitsuba.cli import main

    assert main(["reproduce", "--quick", "--config", str(tmp_path / "x.toml"), "--out", str(tmp_path)]) == 2
    assert "either --config or --quick" in capsys.readouterr().err
