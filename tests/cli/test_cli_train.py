"""CLI ``rfmitsuba train``: without --config or --model it chooses the field by validation (model = "auto")."""
import json

from stage1_data import make_dataset

TINY = ["--set", "iterations=40", "--set", "downsample=5", "--set", "val_every=10", "--set", "checkpoint_every=10",
        "--set", "splat.init='random'", "--set", "splat.num_gaussians=100", "--set", "coherent_gaussians.scatterers=4",
        "--quiet"]


def test_train_cli_defaults_to_auto_and_takes_a_model(tmp_path, capsys):
    from rfmitsuba.cli import main

    ds = make_dataset(tmp_path / "ds", num_antennas=24, task="tx")
    assert main(["train", str(ds), "--out", str(tmp_path / "auto")] + TINY) == 0
    choice = json.loads((tmp_path / "auto" / "select" / "choice.json").read_text())
    # synthetic spectra record no ray tracer, so the Gaussian-process field is a candidate too
    assert set(choice["trials"]) == {"coherent_gaussians", "splat", "gaussian_process"}
    assert choice["chosen"] in choice["trials"]
    assert f'model = "{choice["chosen"]}"' in (tmp_path / "auto" / "config.toml").read_text()
    assert main(["train", str(ds), "--out", str(tmp_path / "splat"), "--model", "splat", "--split", "block"]
                + TINY) == 0
    assert not (tmp_path / "splat" / "select").exists()
    text = (tmp_path / "splat" / "config.toml").read_text()
    assert 'model = "splat"' in text and 'split = "block"' in text
    assert main(["eval", str(tmp_path / "splat")]) == 0
    metrics = json.loads((tmp_path / "splat" / "eval" / "metrics.json").read_text())
    assert metrics["anchored"]["use"] in ("field", "anchored") and 0 < metrics["anchored"]["test"]["mean"] <= 1
    assert main(["train", str(ds), "--out", str(tmp_path / "bad"), "--model", "nerf"] + TINY) == 2
    assert "unknown field kind 'nerf'" in capsys.readouterr().err


def test_auto_refuses_a_folder_that_is_not_a_run_before_any_trial(tmp_path, capsys):
    """``train`` (model "auto") into a folder holding other files is refused before the trials
    write anything into it."""
    from rfmitsuba.cli import main

    ds = make_dataset(tmp_path / "ds", num_antennas=24, task="tx")
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "notes.txt").write_text("mine")
    assert main(["train", str(ds), "--out", str(notes)] + TINY) == 2
    assert "is not empty and holds no config.toml" in capsys.readouterr().err
    assert sorted(p.name for p in notes.iterdir()) == ["notes.txt"]
