"""rfmitsuba.eval.locate.evaluate and .report through ``rfmitsuba locate``: the held-out walk of a
tiny trained comparison scored with its figure and report, one query given as files, and bad
input named."""
from __future__ import annotations

import json

import numpy as np


def _cli(*argv):
    from rfmitsuba.cli import main

    return main(["locate", *argv])


def test_cli_scores_the_held_out_walk_and_one_query(tiny_two_stage, tmp_path, capsys):
    out = tmp_path / "loc"
    fast = ["--views", "3", "--grid", "0.6", "--starts", "1", "--steps", "2", "--downsample", "6", "--quiet"]
    assert _cli(str(tiny_two_stage), "--out", str(out), *fast) == 0
    res = json.loads((out / "locate.json").read_text())
    assert res["jobs"] == ["seed0"] and len(res["truth"]) == len(res["states"]) >= 1
    for key in ("model", "fingerprint", "walk_centroid"):
        assert res["stats"][key]["n"] >= 1 and np.isfinite(res["stats"][key]["median_cm"])
    assert (out / "locate.png").is_file() and "fingerprint" in (out / "report.md").read_text()
    # one query: the PAS of one held-out state at three antennas, given as files
    from rfmitsuba.data.samples import SampleData

    d = SampleData.open_samples(res["dataset"], states="all")
    s = res["states"][0]
    rows = np.flatnonzero(d.states == s)[:3]
    np.save(tmp_path / "q.npy", d.pas(rows))
    np.save(tmp_path / "pos.npy", d.antenna_pos[rows])
    capsys.readouterr()
    assert _cli(str(tiny_two_stage / "seed0" / "ours"), "--pas", str(tmp_path / "q.npy"), "--positions",
                str(tmp_path / "pos.npy"), "--out", str(tmp_path / "one"), *fast[2:]) == 0
    assert "ours: person at x =" in capsys.readouterr().out
    one = json.loads((tmp_path / "one" / "locate.json").read_text())
    assert len(one["estimates"]) == 1 and len(one["estimates"][0]["position"]) == 3


def test_cli_names_bad_input(tiny_two_stage, tmp_path, capsys):
    assert _cli(str(tiny_two_stage / "seed0" / "baseline"), "--out", str(tmp_path / "a")) == 2
    assert "not a two-stage job" in capsys.readouterr().err
    assert _cli(str(tmp_path), "--out", str(tmp_path / "b")) == 2
    assert "holds no two-stage job" in capsys.readouterr().err
    ours = str(tiny_two_stage / "seed0" / "ours")
    np.save(tmp_path / "bad.npy", np.zeros((2, 90, 180), np.float32))
    np.save(tmp_path / "pos.npy", np.zeros((2, 3)))
    assert _cli(ours, "--pas", str(tmp_path / "bad.npy"), "--positions", str(tmp_path / "pos.npy")) == 2
    assert "90, 360" in capsys.readouterr().err
    np.save(tmp_path / "good.npy", np.ones((2, 90, 360), np.float32))
    (tmp_path / "pos.txt").write_text("1 2\n")
    assert _cli(ours, "--pas", str(tmp_path / "good.npy"), "--positions", str(tmp_path / "pos.txt")) == 2
    assert "pos.txt" in capsys.readouterr().err
    assert _cli(ours, "--pas", str(tmp_path / "good.npy")) == 2
    assert "--positions" in capsys.readouterr().err
    assert _cli(ours) == 2
    assert "--out" in capsys.readouterr().err
