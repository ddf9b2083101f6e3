"""CLI ``rfmitsuba train``: without --config or --model it chooses the field by validation (model = "auto")."""
import json

from stage1_data import make_dataset

TINY = ["--set", "iterations=40", "--set", "downsample=5", "--set", "val_every=10", "--set", "checkpoint_every=10",
        "--set", "field.init='random'", "--set", "field.num_gaussians=100", "--set", "coherent_gaussians.scatterers=4",
        "--quiet"]


def test_train_cli_defaults_to_auto_and_takes_a_model(tmp_path, capsys):
    from rfmitsuba.cli import main

    ds = make_dataset(tmp_path / "ds", num_antennas=24, task="tx")
    assert main(["train", str(ds), "--out", str(tmp_path / "auto")] + TINY) == 0
    choice = json.loads((tmp_path / "auto" / "select" / "choice.json").read_text())
    assert choice["chosen"] in ("coherent_gaussians", "splat")
    assert f'model = "{choice["chosen"]}"' in (tmp_path / "auto" / "config.toml").read_text()
    assert main(["train", str(ds), "--out", str(tmp_path / "splat"), "--model", "splat", "--split", "block",
                 "--set", "val_positions=slab"] + TINY) == 0
    assert not (tmp_path / "splat" / "select").exists()
    text = (tmp_path / "splat" / "config.toml").read_text()
    assert 'model = "splat"' in text and 'split = "block"' in text and 'val_positions = "slab"' in text
    # with val_positions = "slab", validation is the training block's own outer slab (it measures
    # extrapolation; the default draws it at random: tests/train/test_trainer.py)
    split = json.loads((tmp_path / "splat" / "split.json").read_text())
    from rfmitsuba.data.views import TrainData

    x = TrainData.open(ds).antenna_pos[:, 0]
    assert len(split["val"]) >= 1
    assert x[split["val"]].min() >= x[split["fit"]].max() and x[split["val"]].max() < x[split["test"]].min()
    assert main(["eval", str(tmp_path / "splat")]) == 0
    metrics = json.loads((tmp_path / "splat" / "eval" / "metrics.json").read_text())
    assert metrics["anchored"]["use"] in ("field", "anchored") and 0 < metrics["anchored"]["test"]["mean"] <= 1
    assert main(["train", str(ds), "--out", str(tmp_path / "bad"), "--model", "nerf"] + TINY) == 2
    assert "unknown field kind 'nerf'" in capsys.readouterr().err


def test_train_cli_ensemble_chooses_the_field_once_and_trains_it_as_members(tmp_path, capsys):
    """``--set members=2`` without --model: the trials train one field each, the chosen kind
    trains as two members, and the closing line says so."""
    from rfmitsuba.cli import main

    ds = make_dataset(tmp_path / "ds", num_antennas=24, task="tx")
    out = tmp_path / "ens"
    assert main(["train", str(ds), "--out", str(out), "--set", "members=2"] + TINY) == 0
    chosen = json.loads((out / "select" / "choice.json").read_text())["chosen"]
    assert not any((out / "select").glob("*/members"))            # each trial: one field
    for k in ("0", "1"):
        assert f'model = "{chosen}"' in (out / "members" / k / "config.toml").read_text()
    assert "(2 members, their mean PAS)" in capsys.readouterr().out
    assert main(["eval", str(out)]) == 0
    assert json.loads((out / "eval" / "metrics.json").read_text())["members"] == 2
