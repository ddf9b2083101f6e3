"""Tests of the ``rfmitsuba generate`` and ``rfmitsuba show`` commands."""
import json

import numpy as np
import pytest

from rfmitsuba import cli
from rfmitsuba.data import store as D


def test_generate_quick_matches_python_api_and_resumes(quick_dataset, tmp_path, capsys):
    out = tmp_path / "ds"
    assert cli.main(["generate", "bedroom", "--task", "rx", "--quick", "--out", str(out)]) == 0
    assert "PAS/s" in capsys.readouterr().out
    a, b = D.open_dataset(out), quick_dataset
    for s in range(a.num_states):
        assert np.array_equal(a.pas(s), b.pas(s))
    # running again does nothing and keeps every chunk
    assert cli.main(["generate", "bedroom", "--task", "rx", "--quick", "--out", str(out)]) == 0
    assert "nothing to do" in capsys.readouterr().out


def test_generate_bad_input(tmp_path, capsys):
    assert cli.main(["generate", "no_such_room", "--out", str(tmp_path / "x")]) == 2
    assert "no_such_room" in capsys.readouterr().err
    assert cli.main(["generate", str(tmp_path / "gone.xml"), "--out", str(tmp_path / "x")]) == 2
    assert "gone.xml" in capsys.readouterr().err
    assert cli.main(["generate", "bedroom", "--quick", "--positions", "0", "--out", str(tmp_path / "x")]) == 2
    assert "--positions" in capsys.readouterr().err
    assert cli.main(["generate", "bedroom", "--quick", "--samples", "-3", "--out", str(tmp_path / "x")]) == 2
    assert "--samples" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["generate", "bedroom", "--task", "sideways", "--out", str(tmp_path / "x")])


def test_generate_other_configuration_names_key(quick_dataset, tmp_path, capsys):
    import shutil

    out = tmp_path / "copy"
    shutil.copytree(quick_dataset.path, out)
    assert cli.main(["generate", "bedroom", "--quick", "--seed", "5", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "holds a dataset of another configuration" in err and "there and" in err and "in this call" in err


def test_show_writes_pngs(quick_dataset, tmp_path, capsys):
    out = tmp_path / "show"
    assert cli.main(["show", str(quick_dataset.path), "--out", str(out)]) == 0
    for name in ("pas_grid.png", "top_view.png", "ssim_hist.png"):
        assert (out / name).stat().st_size > 1000
    s = json.loads((out / "summary.json").read_text())
    assert 0 < s["ssim_mean"] <= 1 and 0 <= s["share_below_0.9"] <= 1
    assert "below 0.9" in capsys.readouterr().out


def test_show_missing_dataset(tmp_path, capsys):
    assert cli.main(["show", str(tmp_path / "none"), "--out", str(tmp_path / "o")]) == 2
    assert "meta.json" in capsys.readouterr().err


def test_generate_array_option(tmp_path, capsys):
    with pytest.raises(SystemExit):
        cli.main(["generate", "bedroom", "--array", "bogus", "--out", str(tmp_path / "x")])
    assert "invalid choice: 'bogus'" in capsys.readouterr().err
    assert cli.main(["generate", "bedroom", "--array", "exact", "--positions", "900", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "exact" in err and "got 900, at most 200" in err
    assert not (tmp_path / "x").exists()
