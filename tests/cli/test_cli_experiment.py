"""rfmitsuba experiment splits from the command line: bad options are named before any run starts."""
from __future__ import annotations

from rfmitsuba import cli


def test_splits_names_bad_seeds_and_fields(tmp_path, capsys):
    from stage1_data import make_dataset

    ds = make_dataset(tmp_path / "ds", num_antennas=20, task="tx")
    out = tmp_path / "sp"
    assert cli.main(["experiment", "splits", str(ds), "--out", str(out), "--seeds", "0,one"]) != 0
    assert "--seeds: 'one' is not a whole number >= 0" in capsys.readouterr().err
    assert cli.main(["experiment", "splits", str(ds), "--out", str(out), "--fields", "coherent_gaussians,nope"]) != 0
    assert "unknown field kind 'nope'" in capsys.readouterr().err
    assert cli.main(["experiment", "splits", "--out", str(out)]) != 0
    assert "needs a dataset folder" in capsys.readouterr().err
    assert not out.exists()
